//! Forward dynamics by ABA and its derivatives `∂q̈/∂u = −M⁻¹ ∂c/∂u` evaluated at that q̈
//! (Carpentier & Mansard 2018, eq. 9), as Pinocchio's `computeABADerivatives`.

use nalgebra::DMatrix;

use super::{aba, minv, rnea_derivatives};
use crate::model::Model;

/// Joint accelerations under torques `tau`.
pub fn forward_dynamics(model: &Model, q: &[f64], qd: &[f64], tau: &[f64], gravity: [f64; 3]) -> Vec<f64> {
    aba(model, q, qd, tau, gravity)
}

/// `(q̈, ∂q̈/∂q, ∂q̈/∂q̇)` under torques `tau`.
pub fn forward_dynamics_derivatives(model: &Model, q: &[f64], qd: &[f64], tau: &[f64], gravity: [f64; 3]) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
    let mi = minv(model, q);
    let qdd = aba(model, q, qd, tau, gravity);
    let (dc_dq, dc_dqd) = rnea_derivatives(model, q, qd, &qdd, gravity);
    (qdd, -&mi * dc_dq, -&mi * dc_dqd)
}
