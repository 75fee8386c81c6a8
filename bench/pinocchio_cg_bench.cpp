// Times Pinocchio's code-generation path: CppADCodeGen records computeRNEADerivatives and
// computeABADerivatives (Pinocchio's CodeGenRNEADerivatives / CodeGenABADerivatives, its
// include/pinocchio/codegen/cppadcg-algo.hpp) and prints straight-line C, which gcc compiles
// into a shared library (-O3 -march=native, the flags that made it fastest on the
// development machine); one state per call, on the same seeded states and with the same
// harness as bench/pinocchio_bench.cpp, for the third column of scripts/bench.sh's table.
// An argument `jac@MODEL` also times the other route, the AD Jacobian of rnea and aba
// (CodeGenRNEA / CodeGenABA's evalJacobian, which also returns dtau/da = M or dddq/dtau =
// M^-1), on fixed-base models. Before timing, every route is checked against Pinocchio's
// analytical derivatives on the first state (the largest entry difference is printed).
// Libraries that already exist in the working directory are loaded, not built again:
// scripts/bench.sh runs this program once per measuring process (the placement protocol),
// deletes the libraries before the first, and so compiles each C file once per run.
// Prints one JSON line per model:
// {"robot": ..., "cg_rnea_derivatives_ns": ..., "cg_aba_derivatives_ns": ...,
//  ["cg_rnea_jacobian_ns": ..., "cg_aba_jacobian_ns": ...,] "check": ..., "build_s": ...,
//  "compiled": ...} (build_s: seconds to record the tape, print and compile the C, or to
// record and load when compiled is 0)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "pinocchio/codegen/cppadcg-algo.hpp"
#include "pinocchio/serialization.hpp"

using Clock = std::chrono::steady_clock;

// Median over `rounds` of the mean time per call over `iters` calls, in ns (as in
// bench/pinocchio_bench.cpp).
template <typename F>
double time_ns(F&& f, int iters, int rounds) {
  std::vector<double> samples;
  for (int r = 0; r < rounds; ++r) {
    auto t0 = Clock::now();
    for (int i = 0; i < iters; ++i) f(i);
    auto t1 = Clock::now();
    samples.push_back(std::chrono::duration<double, std::nano>(t1 - t0).count() / iters);
  }
  std::sort(samples.begin(), samples.end());
  return samples[samples.size() / 2];
}

// Pinocchio's CodeGenBase::compileLib puts one flag string in place of gcc's -O2; this
// passes -O3 and -march=native as two flags, then loads the library. Returns whether it
// compiled (false: an earlier process's library was loaded).
template <typename CodeGen>
struct Compiled : CodeGen {
  Compiled(const pinocchio::Model& model, const std::string& function, const std::string& library)
      : CodeGen(model, function, library) {}
  bool build() {
    this->initLib();
    const bool compile = !this->existLib();
    if (compile) {
      CppAD::cg::GccCompiler<double> gcc("/usr/bin/gcc");
      gcc.setCompileFlags({"-O3", "-march=native"});
      this->dynamicLibManager_ptr->createDynamicLibrary(gcc, false);
    }
    this->loadLib(false);
    return compile;
  }
};

// The derivative classes keep their results protected.
struct RneaDerivatives : Compiled<pinocchio::CodeGenRNEADerivatives<double>> {
  using Compiled::Compiled;
  using Compiled::dtau_dq;
  using Compiled::dtau_dv;
};
struct AbaDerivatives : Compiled<pinocchio::CodeGenABADerivatives<double>> {
  using Compiled::Compiled;
  using Compiled::dddq_dq;
  using Compiled::dddq_dv;
};

double max_diff(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) { return (a - b).cwiseAbs().maxCoeff(); }

int main(int argc, char** argv) {
  for (int arg_at = 1; arg_at < argc; ++arg_at) {
    std::string arg(argv[arg_at]);
    bool jacobians = false;
    if (arg.rfind("jac@", 0) == 0) {
      jacobians = true;
      arg = arg.substr(4);
    }
    pinocchio::Model model;
    model.loadFromText(arg);
    pinocchio::Data data(model);
    const std::string stem = arg.substr(arg.find_last_of('/') + 1, arg.find_last_of('.') - arg.find_last_of('/') - 1);
    const int K = 64;  // distinct states, cycled, so nothing is cached between calls
    std::srand(0);
    std::vector<Eigen::VectorXd> q(K), v(K), acc(K), tau(K);
    for (int k = 0; k < K; ++k) {
      q[k] = pinocchio::randomConfiguration(model, -Eigen::VectorXd::Ones(model.nq), Eigen::VectorXd::Ones(model.nq));
      v[k] = Eigen::VectorXd::Random(model.nv);
      acc[k] = Eigen::VectorXd::Random(model.nv);
      tau[k] = Eigen::VectorXd::Random(model.nv);
    }
    const int iters = 2000, rounds = 15;
    auto t0 = Clock::now();
    RneaDerivatives rd(model, "partial_rnea", stem + "_partial_rnea");
    bool compiled = rd.build();
    AbaDerivatives ad(model, "partial_aba", stem + "_partial_aba");
    compiled = ad.build() || compiled;
    double build_s = std::chrono::duration<double>(Clock::now() - t0).count();

    // The same functions as Pinocchio's analytical derivatives, on state 0.
    pinocchio::computeRNEADerivatives(model, data, q[0], v[0], acc[0]);
    Eigen::MatrixXd dtau_dq = data.dtau_dq, dtau_dv = data.dtau_dv;
    pinocchio::computeABADerivatives(model, data, q[0], v[0], tau[0]);
    Eigen::MatrixXd ddq_dq = data.ddq_dq, ddq_dv = data.ddq_dv;
    rd.evalFunction(q[0], v[0], acc[0]);
    ad.evalFunction(q[0], v[0], tau[0]);
    double check = std::max({max_diff(rd.dtau_dq, dtau_dq), max_diff(rd.dtau_dv, dtau_dv), max_diff(ad.dddq_dq, ddq_dq),
                             max_diff(ad.dddq_dv, ddq_dv)});

    double sink = 0.0;
    double rd_ns = time_ns(
        [&](int i) {
          rd.evalFunction(q[i % K], v[i % K], acc[i % K]);
          sink += rd.dtau_dq(0, 0);
        },
        iters, rounds);
    double ad_ns = time_ns(
        [&](int i) {
          ad.evalFunction(q[i % K], v[i % K], tau[i % K]);
          sink += ad.dddq_dq(0, 0);
        },
        iters, rounds);
    std::printf("{\"robot\": \"%s\", \"cg_rnea_derivatives_ns\": %.1f, \"cg_aba_derivatives_ns\": %.1f", arg.c_str(), rd_ns, ad_ns);
    if (jacobians && model.nq == model.nv) {
      t0 = Clock::now();
      Compiled<pinocchio::CodeGenRNEA<double>> rj(model, "rnea", stem + "_rnea");
      compiled = rj.build() || compiled;
      Compiled<pinocchio::CodeGenABA<double>> aj(model, "aba", stem + "_aba");
      compiled = aj.build() || compiled;
      build_s += std::chrono::duration<double>(Clock::now() - t0).count();
      rj.evalJacobian(q[0], v[0], acc[0]);
      aj.evalJacobian(q[0], v[0], tau[0]);
      check = std::max({check, max_diff(rj.dtau_dq, dtau_dq), max_diff(rj.dtau_dv, dtau_dv), max_diff(aj.da_dq, ddq_dq),
                        max_diff(aj.da_dv, ddq_dv)});
      double rj_ns = time_ns(
          [&](int i) {
            rj.evalJacobian(q[i % K], v[i % K], acc[i % K]);
            sink += rj.dtau_dq(0, 0);
          },
          iters, rounds);
      double aj_ns = time_ns(
          [&](int i) {
            aj.evalJacobian(q[i % K], v[i % K], tau[i % K]);
            sink += aj.da_dq(0, 0);
          },
          iters, rounds);
      std::printf(", \"cg_rnea_jacobian_ns\": %.1f, \"cg_aba_jacobian_ns\": %.1f", rj_ns, aj_ns);
    }
    std::printf(", \"check\": %.3g, \"build_s\": %.1f, \"compiled\": %d, \"sink\": %g}\n", check, build_s, compiled ? 1 : 0, sink);
    std::fflush(stdout);
  }
  return 0;
}
