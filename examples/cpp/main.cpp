// C++ example: iiwa's forward dynamics and its gradient for a batch of states, through the
// generated C ABI (iiwa14.h), the outputs mapped with Eigen. Reads n, then n states
// (q, qd, tau: 7 numbers each) from stdin; prints each state's qdd, dqdd/dq and dqdd/dqd
// and the RNEA of (q, qd, qdd), which must give back tau.
#include <cstdio>
#include <iostream>
#include <vector>

#include <Eigen/Dense>

#include "iiwa14.h"

constexpr int NV = IIWA14_NV;
using Vector = Eigen::Matrix<double, NV, 1>;
// The kernels write row-major matrices, state after state.
using Matrix = Eigen::Matrix<double, NV, NV, Eigen::RowMajor>;

static void print(const char *label, const double *x, int n) {
    std::printf("%s", label);
    for (int i = 0; i < n; ++i) std::printf(" %.17g", x[i]);
    std::printf("\n");
}

int main() {
    std::size_t n = 0;
    if (!(std::cin >> n) || n == 0) {
        std::fprintf(stderr, "expected the number of states, then q, qd, tau for each\n");
        return 2;
    }
    std::vector<double> q(n * IIWA14_NQ), qd(n * NV), tau(n * NV);
    for (std::size_t i = 0; i < n; ++i) {
        for (int j = 0; j < IIWA14_NQ; ++j) std::cin >> q[i * IIWA14_NQ + j];
        for (int j = 0; j < NV; ++j) std::cin >> qd[i * NV + j];
        for (int j = 0; j < NV; ++j) std::cin >> tau[i * NV + j];
    }
    if (!std::cin) {
        std::fprintf(stderr, "short input: %zu states need %zu numbers\n", n, n * (IIWA14_NQ + 2 * NV));
        return 2;
    }

    std::vector<double> qdd(n * NV), dqdd_dq(n * NV * NV), dqdd_dqd(n * NV * NV), c(n * NV);
    // One call for the whole batch, on every core.
    int status = iiwa14_fd_grad_batch_f64(n, q.data(), qd.data(), tau.data(), qdd.data(), dqdd_dq.data(), dqdd_dqd.data());
    if (status != GRID_GEN_OK) {
        std::fprintf(stderr, "fd_grad failed: %d\n", status);
        return 1;
    }
    status = iiwa14_rnea_batch_f64(n, q.data(), qd.data(), qdd.data(), c.data());
    if (status != GRID_GEN_OK) {
        std::fprintf(stderr, "rnea failed: %d\n", status);
        return 1;
    }
    // A null pointer is a status, not a crash.
    if (iiwa14_fd_grad_f64(nullptr, qd.data(), tau.data(), qdd.data(), dqdd_dq.data(), dqdd_dqd.data()) != GRID_GEN_NULL_POINTER) {
        std::fprintf(stderr, "a null pointer was not reported\n");
        return 1;
    }

    std::printf("joints");
    for (const char *name : IIWA14_JOINT_NAMES) std::printf(" %s", name);
    std::printf("\nthreads %zu\n", iiwa14_threads());
    double worst = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
        Eigen::Map<const Vector> a(&qdd[i * NV]);
        Eigen::Map<const Matrix> da_dq(&dqdd_dq[i * NV * NV]);
        Eigen::Map<const Matrix> da_dqd(&dqdd_dqd[i * NV * NV]);
        Eigen::Map<const Vector> t(&tau[i * NV]), back(&c[i * NV]);
        worst = std::max(worst, (back - t).cwiseAbs().maxCoeff() / std::max(1.0, t.cwiseAbs().maxCoeff()));
        print("qdd", a.data(), NV);
        print("dqdd_dq", da_dq.data(), NV * NV);
        print("dqdd_dqd", da_dqd.data(), NV * NV);
    }
    std::printf("rnea_minus_tau %.3e\n", worst);
    return 0;
}
