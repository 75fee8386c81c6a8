//! Forward dynamics by ABA and its derivatives `∂q̈/∂u = −M⁻¹ ∂c/∂u` evaluated at that q̈
//! (Carpentier & Mansard 2018, eq. 9), as Pinocchio's `computeABADerivatives`.

use nalgebra::DMatrix;

use super::forces::External;
use super::{aba_with, minv, rnea_derivatives_with};
use crate::model::Model;

/// Joint accelerations under torques `tau`.
pub fn forward_dynamics(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
) -> Vec<f64> {
    aba_with(model, q, qd, tau, gravity, External::NONE)
}

/// `(q̈, ∂q̈/∂q, ∂q̈/∂q̇)` under torques `tau`.
pub fn forward_dynamics_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
    forward_dynamics_derivatives_with(model, q, qd, tau, gravity, External::NONE)
}

/// [`forward_dynamics_derivatives`] under external forces `ext`, held fixed as
/// [`super::rnea_derivatives_with`] holds them.
pub fn forward_dynamics_derivatives_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    ext: External,
) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
    let mi = minv(model, q);
    let qdd = aba_with(model, q, qd, tau, gravity, ext);
    let (dc_dq, dc_dqd) = rnea_derivatives_with(model, q, qd, &qdd, gravity, ext);
    (qdd, -&mi * dc_dq, -&mi * dc_dqd)
}
