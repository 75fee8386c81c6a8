// Times Pinocchio's computeRNEADerivatives and computeABADerivatives (f64; fixed base, or a free-flyer) on
// a model that Pinocchio's Python bindings built from a URDF and saved as text
// (pinocchio.Model.saveToText; the wheel ships no urdfdom headers), for the side-by-side comparison in scripts/bench.sh. Built from Pinocchio's
// headers with -O3 (see scripts/bench.sh). Prints one JSON line per robot:
// {"robot": ..., "nv": ..., "rnea_derivatives_ns": ..., "aba_derivatives_ns": ..., "rnea_ns": ..., "aba_ns": ...}
// An argument `MODEL:LINK,LINK,...` times the frame functions instead, for those BODY frames, in
// LOCAL_WORLD_ALIGNED: {"robot": ..., "frames": [...], "frame_jacobian_ns": ..., "frame_acceleration_ns": ...},
// computeJointJacobians + getFrameJacobian per frame, and forwardKinematics(q, v, a) +
// getFrameClassicalAcceleration per frame (what a contact constraint or a frame cost calls).
// An argument `step=DT@MODEL` times the semi-implicit Euler step and its [A | B] composed the way a
// user of Pinocchio writes it (computeABADerivatives, integrate, dIntegrate twice and the products,
// every joint but a free-flyer actuated), beside computeABADerivatives alone:
// {"robot": ..., "step_grad_ns": ..., "aba_derivatives_ns": ...}.
// An argument `contact@MODEL:LINK,...` times rigid-contact dynamics with a CONTACT_3D constraint
// at each of those BODY frames in LOCAL_WORLD_ALIGNED: constraintDynamics, and constraintDynamics
// followed by computeConstraintDynamicsDerivatives (what `contact_fd_grad` returns):
// {"robot": ..., "contacts": ..., "contact_fd_ns": ..., "contact_fd_grad_ns": ...}.
// A LINK written `LINK/6d` is a CONTACT_6D there instead (a foot's wrench). With `step=DT@`
// in front (`step=DT@contact@MODEL:LINK,...`), the semi-implicit step under those contacts is
// timed too, composed as above from constraintDynamics and its derivatives (what `step_grad`
// returns, λ's derivatives included): "contact_step_grad_ns".
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "pinocchio/algorithm/aba-derivatives.hpp"
#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/algorithm/constrained-dynamics-derivatives.hpp"
#include "pinocchio/algorithm/constrained-dynamics.hpp"
#include "pinocchio/algorithm/frames.hpp"
#include "pinocchio/algorithm/jacobian.hpp"
#include "pinocchio/algorithm/joint-configuration.hpp"
#include "pinocchio/algorithm/kinematics.hpp"
#include "pinocchio/algorithm/rnea-derivatives.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/multibody.hpp"
#include "pinocchio/serialization.hpp"

using Clock = std::chrono::steady_clock;

// Median over `rounds` of the mean time per call over `iters` calls, in ns.
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

// The semi-implicit Euler step and its [A | B] composed from q̈ and its derivatives the way a
// user of Pinocchio writes it (integrate, dIntegrate twice and the products), every joint but a
// free-flyer actuated; `dtau` is ∂q̈/∂τ (M⁻¹ without contacts), whose actuated columns make B.
struct StepComposer {
  int nv, nu;
  Eigen::VectorXd v1, dq, qn;
  Eigen::MatrixXd Jq, Jv, A, B;
  explicit StepComposer(const pinocchio::Model& model)
      : nv(model.nv),
        nu(model.nv - (model.joints[1].nv() == 6 ? 6 : 0)),
        v1(nv), dq(nv), qn(model.nq), Jq(nv, nv), Jv(nv, nv), A(2 * nv, 2 * nv), B(2 * nv, nu) {}
  // Returns a value read from the results, so that the compiler keeps the work.
  template <typename Ddq, typename Dq, typename Dv, typename Dtau>
  double compose(const pinocchio::Model& model, const Eigen::VectorXd& q, const Eigen::VectorXd& v, double dt,
                 const Ddq& ddq, const Dq& ddq_dq, const Dv& ddq_dv, const Dtau& dtau) {
    v1 = v + dt * ddq;
    dq = dt * v1;
    pinocchio::integrate(model, q, dq, qn);
    pinocchio::dIntegrate(model, q, dq, Jq, pinocchio::ARG0);
    pinocchio::dIntegrate(model, q, dq, Jv, pinocchio::ARG1);
    A.bottomLeftCorner(nv, nv) = dt * ddq_dq;
    A.bottomRightCorner(nv, nv) = dt * ddq_dv;
    A.bottomRightCorner(nv, nv).diagonal().array() += 1.0;
    B.bottomRows(nv) = dt * dtau.rightCols(nu);
    A.topLeftCorner(nv, nv) = Jq;
    A.topLeftCorner(nv, nv).noalias() += dt * Jv * A.bottomLeftCorner(nv, nv);
    A.topRightCorner(nv, nv).noalias() = dt * Jv * A.bottomRightCorner(nv, nv);
    B.topRows(nv).noalias() = dt * Jv * B.bottomRows(nv);
    return A(0, 0) + B(0, 0) + qn[0];
  }
};

int main(int argc, char** argv) {
  for (int a = 1; a < argc; ++a) {
    std::string arg(argv[a]);
    double dt = 0.0;
    bool contact = false;
    if (arg.rfind("step=", 0) == 0) {
      dt = std::stod(arg.substr(5, arg.find('@') - 5));
      arg = arg.substr(arg.find('@') + 1);
    }
    if (arg.rfind("contact@", 0) == 0) {
      contact = true;
      arg = arg.substr(8);
    }
    std::string path = arg.substr(0, arg.find(':'));
    std::vector<std::string> names;
    if (arg.find(':') != std::string::npos) {
      std::string list = arg.substr(arg.find(':') + 1);
      for (size_t at = 0; at <= list.size();) {
        size_t end = list.find(',', at);
        if (end == std::string::npos) end = list.size();
        names.push_back(list.substr(at, end - at));
        at = end + 1;
      }
    }
    pinocchio::Model model;
    model.loadFromText(path);
    pinocchio::Data data(model);
    const int K = 64;  // distinct states, cycled, so nothing is cached between calls
    std::vector<Eigen::VectorXd> q(K), v(K), acc(K), tau(K);
    for (int k = 0; k < K; ++k) {
      q[k] = pinocchio::randomConfiguration(model, -Eigen::VectorXd::Ones(model.nq), Eigen::VectorXd::Ones(model.nq));
      v[k] = Eigen::VectorXd::Random(model.nv);
      acc[k] = Eigen::VectorXd::Random(model.nv);
      tau[k] = Eigen::VectorXd::Random(model.nv);
    }
    const int iters = 2000, rounds = 15;
    if (dt > 0.0 && !contact) {
      StepComposer composer(model);
      Eigen::MatrixXd Minv(model.nv, model.nv);
      double sink = 0.0;
      double step = time_ns(
          [&](int i) {
            const int k = i % K;
            pinocchio::computeABADerivatives(model, data, q[k], v[k], tau[k]);
            Minv = data.Minv;
            Minv.triangularView<Eigen::StrictlyLower>() = Minv.transpose().triangularView<Eigen::StrictlyLower>();
            sink += composer.compose(model, q[k], v[k], dt, data.ddq, data.ddq_dq, data.ddq_dv, Minv);
          },
          iters, rounds);
      double ad = time_ns([&](int i) { pinocchio::computeABADerivatives(model, data, q[i % K], v[i % K], tau[i % K]); }, iters, rounds);
      std::printf("{\"robot\": \"%s\", \"dt\": %g, \"step_grad_ns\": %.1f, \"aba_derivatives_ns\": %.1f, \"sink\": %g}\n", path.c_str(), dt, step, ad, sink);
      continue;
    }
    if (contact) {
      typedef pinocchio::RigidConstraintModel Cm;
      typedef pinocchio::RigidConstraintData Cd;
      PINOCCHIO_STD_VECTOR_WITH_EIGEN_ALLOCATOR(Cm) cms;
      PINOCCHIO_STD_VECTOR_WITH_EIGEN_ALLOCATOR(Cd) cds;
      for (auto n : names) {
        auto type = pinocchio::CONTACT_3D;
        if (n.size() > 3 && n.compare(n.size() - 3, 3, "/6d") == 0) {
          type = pinocchio::CONTACT_6D;
          n = n.substr(0, n.size() - 3);
        }
        const auto& frame = model.frames[model.getFrameId(n, pinocchio::BODY)];
        cms.push_back(Cm(type, model, frame.parentJoint, frame.placement, pinocchio::LOCAL_WORLD_ALIGNED));
      }
      for (auto& cm : cms) cds.push_back(Cd(cm));
      pinocchio::initConstraintDynamics(model, data, cms, cds);
      double sink = 0.0;
      double fd = time_ns(
          [&](int i) { sink += pinocchio::constraintDynamics(model, data, q[i % K], v[i % K], tau[i % K], cms, cds)[0]; }, iters, rounds);
      double grad = time_ns(
          [&](int i) {
            pinocchio::constraintDynamics(model, data, q[i % K], v[i % K], tau[i % K], cms, cds);
            pinocchio::computeConstraintDynamicsDerivatives(model, data, cms, cds);
            sink += data.ddq_dq(0, 0) + data.dlambda_dq(0, 0);
          },
          iters, rounds);
      double step = 0.0;
      if (dt > 0.0) {
        StepComposer composer(model);
        step = time_ns(
            [&](int i) {
              const int k = i % K;
              pinocchio::constraintDynamics(model, data, q[k], v[k], tau[k], cms, cds);
              pinocchio::computeConstraintDynamicsDerivatives(model, data, cms, cds);
              sink += composer.compose(model, q[k], v[k], dt, data.ddq, data.ddq_dq, data.ddq_dv, data.ddq_dtau) +
                      data.dlambda_dq(0, 0);
            },
            iters, rounds);
      }
      std::printf("{\"robot\": \"%s\", \"contacts\": %zu, \"contact_fd_ns\": %.1f, \"contact_fd_grad_ns\": %.1f, \"contact_step_grad_ns\": %.1f, \"sink\": %g}\n",
                  path.c_str(), cms.size(), fd, grad, step, sink);
      continue;
    }
    if (!names.empty()) {
      std::vector<pinocchio::FrameIndex> ids;
      for (auto& n : names) ids.push_back(model.getFrameId(n, pinocchio::BODY));
      pinocchio::Data::Matrix6x J(6, model.nv);
      Eigen::Vector3d sink = Eigen::Vector3d::Zero();
      double jac = time_ns(
          [&](int i) {
            pinocchio::computeJointJacobians(model, data, q[i % K]);
            for (auto id : ids) {
              J.setZero();
              pinocchio::getFrameJacobian(model, data, id, pinocchio::LOCAL_WORLD_ALIGNED, J);
              sink[0] += J(0, 0);
            }
          },
          iters, rounds);
      double acc_ns = time_ns(
          [&](int i) {
            pinocchio::forwardKinematics(model, data, q[i % K], v[i % K], acc[i % K]);
            for (auto id : ids) sink += pinocchio::getFrameClassicalAcceleration(model, data, id, pinocchio::LOCAL_WORLD_ALIGNED).linear();
          },
          iters, rounds);
      std::printf("{\"robot\": \"%s\", \"frames\": %zu, \"frame_jacobian_ns\": %.1f, \"frame_acceleration_ns\": %.1f, \"sink\": %g}\n", path.c_str(), ids.size(), jac,
                  acc_ns, sink.sum());
      continue;
    }
    double rd = time_ns([&](int i) { pinocchio::computeRNEADerivatives(model, data, q[i % K], v[i % K], acc[i % K]); }, iters, rounds);
    double ad = time_ns([&](int i) { pinocchio::computeABADerivatives(model, data, q[i % K], v[i % K], tau[i % K]); }, iters, rounds);
    double r = time_ns([&](int i) { pinocchio::rnea(model, data, q[i % K], v[i % K], acc[i % K]); }, iters, rounds);
    double ab = time_ns([&](int i) { pinocchio::aba(model, data, q[i % K], v[i % K], tau[i % K]); }, iters, rounds);
    std::printf("{\"robot\": \"%s\", \"nv\": %d, \"rnea_derivatives_ns\": %.1f, \"aba_derivatives_ns\": %.1f, \"rnea_ns\": %.1f, \"aba_ns\": %.1f}\n", argv[a],
                model.nv, rd, ad, r, ab);
  }
  return 0;
}
