//! Forward dynamics `q̈ = M⁻¹ (τ − c(q, q̇, 0))` and its derivatives
//! `∂q̈/∂u = −M⁻¹ ∂c/∂u` evaluated at the q̈ just computed (Carpentier & Mansard 2018, eq. 9).

use nalgebra::{DMatrix, DVector};

use super::{minv, rnea, rnea_derivatives};
use crate::model::Model;

/// Joint accelerations under torques `tau`.
pub fn forward_dynamics(model: &Model, q: &[f64], qd: &[f64], tau: &[f64], gravity: [f64; 3]) -> Vec<f64> {
    let n = model.nv();
    let bias = rnea(model, q, qd, &vec![0.0; n], gravity);
    let rhs = DVector::from_iterator(n, tau.iter().zip(&bias).map(|(t, b)| t - b));
    (minv(model, q) * rhs).iter().copied().collect()
}

/// `(q̈, ∂q̈/∂q, ∂q̈/∂q̇)` under torques `tau`.
pub fn forward_dynamics_derivatives(model: &Model, q: &[f64], qd: &[f64], tau: &[f64], gravity: [f64; 3]) -> (Vec<f64>, DMatrix<f64>, DMatrix<f64>) {
    let n = model.nv();
    let mi = minv(model, q);
    let bias = rnea(model, q, qd, &vec![0.0; n], gravity);
    let rhs = DVector::from_iterator(n, tau.iter().zip(&bias).map(|(t, b)| t - b));
    let qdd: Vec<f64> = (&mi * rhs).iter().copied().collect();
    let (dc_dq, dc_dqd) = rnea_derivatives(model, q, qd, &qdd, gravity);
    (qdd, -&mi * dc_dq, -&mi * dc_dqd)
}
