//! The configuration space's `difference` and its Jacobians (Pinocchio's `difference` and
//! `dDifference`), by a route independent of the kernels' halving of the angle: the
//! logarithm by `atan2`, a free-flyer's translation by solving with SO(3)'s left
//! Jacobian, and the Jacobians by inverting `dIntegrate`'s at the difference
//! (`q1 = q ⊕ v(q, q1)`, differentiated on both sides).

use nalgebra::{DMatrix, UnitQuaternion, Vector3};

use super::step::{d_integrate, quaternion, so3_jacobians};
use crate::model::{LieBlock, Model};

/// The rotation vector of `q0⁻¹ q1` (the quaternions at `at` of each), its angle at most π.
fn log3(q0: &[f64], q1: &[f64], at: usize) -> Vector3<f64> {
    quaternion_log3(&(quaternion(q0, at).inverse() * quaternion(q1, at)))
}

/// A unit quaternion's rotation vector, its angle at most π (Pinocchio's
/// `quaternion::log3`, which negates a quaternion whose `w` is negative), by `atan2`.
pub(super) fn quaternion_log3(r: &UnitQuaternion<f64>) -> Vector3<f64> {
    let c = r.quaternion().coords;
    let (mut v, mut w) = (Vector3::new(c[0], c[1], c[2]), c[3]);
    if w < 0.0 {
        v = -v;
        w = -w;
    }
    let n = v.norm();
    if n == 0.0 {
        return Vector3::zeros();
    }
    v * (2.0 * n.atan2(w) / n)
}

/// `q1 ⊖ q0`: the tangent v with `q0 ⊕ v = q1` (Pinocchio's `difference`).
pub fn difference(model: &Model, q0: &[f64], q1: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; model.nv()];
    for block in model.lie_blocks() {
        match block {
            LieBlock::Scalar { v, q } => out[v] = q1[q] - q0[q],
            LieBlock::Spherical { v, q } => {
                out[v..v + 3].copy_from_slice(log3(q0, q1, q).as_slice());
            }
            LieBlock::FreeFlyer => {
                // log6(M0⁻¹ M1): exp6 moves by V(ω) v, so v = V(ω)⁻¹ R0ᵀ (p1 − p0).
                let w = log3(q0, q1, 3);
                let dp = Vector3::new(q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2]);
                let p = quaternion(q0, 3).inverse() * dp;
                let lin = so3_jacobians(&w)
                    .0
                    .lu()
                    .solve(&p)
                    .expect("V(ω) is invertible for angles below 2π");
                out[..3].copy_from_slice(lin.as_slice());
                out[3..6].copy_from_slice(w.as_slice());
            }
        }
    }
    out
}

/// `(∂(q1 ⊖ q0)/∂q0, ∂(q1 ⊖ q0)/∂q1)` in the tangent space (`dDifference`, `ARG0` and
/// `ARG1`): with `(Jq, Jv)` `dIntegrate`'s at v = q1 ⊖ q0, `(−Jv⁻¹ Jq, Jv⁻¹)`.
pub fn d_difference(model: &Model, q0: &[f64], q1: &[f64]) -> (DMatrix<f64>, DMatrix<f64>) {
    let v = difference(model, q0, q1);
    let (jq, jv) = d_integrate(model, &v);
    let inv = jv.try_inverse().expect("dIntegrate's Jacobian is invertible for angles below 2π");
    (-(&inv * jq), inv)
}
