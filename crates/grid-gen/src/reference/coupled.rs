//! Coupled mimic joints (`--mimic coupled`, see [`crate::model::Coupling`]) around the
//! joint-level algorithms: with G the nj × nv map from coordinates to joint velocities
//! (G[i][k] = the multiplier of joint i when it moves with coordinate k),
//! q̇_joints = G q̇, c = Gᵀ c_joints, M = Gᵀ M_joints G and the gradients Gᵀ (∂c/∂u) G
//! (the chain rule: the mimic's position is affine in its coordinate). M⁻¹ and forward
//! dynamics come from the joint-level ones under the mimic constraints K q̈_joints = 0
//! (row r of K: e_mimic − multiplier · e_followed, so K G = 0; P picks the coordinate
//! joints, so P G = I):
//!
//! `(Gᵀ M G)⁻¹ = P (M⁻¹ − M⁻¹ Kᵀ (K M⁻¹ Kᵀ)⁻¹ K M⁻¹) Pᵀ`, and q̈ = P (a − M⁻¹ Kᵀ (K M⁻¹ Kᵀ)⁻¹ K a)
//! with a the unconstrained ABA acceleration under τ_joints = Pᵀ τ (the constrained
//! dynamics' Lagrange-multiplier form; Featherstone 2008, §8.1). Without coupled joints
//! G = P = I, K is empty and every function here is the identity.

use nalgebra::DMatrix;

use crate::model::JointIndex;
use crate::model::Model;

/// Per-joint values from per-coordinate ones: `G x` (velocities, accelerations).
pub fn expand(model: &Model, x: &[f64]) -> Vec<f64> {
    if !model.has_coupled() {
        return x.to_vec();
    }
    (0..model.njoints())
        .map(|i| model.multiplier(i) * x[model.coordinate_of(JointIndex(i)).0])
        .collect()
}

/// Per-coordinate forces from per-joint ones: `Gᵀ c`.
pub fn reduce(model: &Model, c: &[f64]) -> Vec<f64> {
    if !model.has_coupled() {
        return c.to_vec();
    }
    let mut out = vec![0.0; model.nv()];
    for (i, ci) in c.iter().enumerate() {
        out[model.coordinate_of(JointIndex(i)).0] += model.multiplier(i) * ci;
    }
    out
}

/// `Gᵀ D G` for a joint-level matrix.
pub fn reduce_matrix(model: &Model, d: DMatrix<f64>) -> DMatrix<f64> {
    // Without a coupled joint G = I: skip the two dense products (O(n³) on a long chain).
    if !model.has_coupled() {
        return d;
    }
    let g = coupling_matrix(model);
    g.transpose() * d * &g
}

fn coupling_matrix(model: &Model) -> DMatrix<f64> {
    DMatrix::from_fn(model.njoints(), model.nv(), |i, k| {
        if model.coordinate_of(JointIndex(i)).0 == k {
            model.multiplier(i)
        } else {
            0.0
        }
    })
}

/// K: one row per coupled joint.
fn constraints(model: &Model) -> DMatrix<f64> {
    let rows: Vec<usize> = (0..model.njoints()).filter(|&i| model.coupling(i).is_some()).collect();
    let mut k = DMatrix::zeros(rows.len(), model.njoints());
    for (r, &i) in rows.iter().enumerate() {
        let c = model.coupling(i).expect("a coupled joint");
        k[(r, i)] += 1.0;
        k[(r, c.of)] -= c.multiplier;
    }
    k
}

/// `W = M⁻¹ Kᵀ` and `(K M⁻¹ Kᵀ)⁻¹` from the joint-level M⁻¹.
fn correction(model: &Model, minv_joints: &DMatrix<f64>) -> (DMatrix<f64>, DMatrix<f64>) {
    let k = constraints(model);
    let w = minv_joints * k.transpose();
    let s = &k * &w;
    // S is symmetric positive definite (M⁻¹ is, and K has full row rank).
    let s_inv = s.cholesky().expect("K M⁻¹ Kᵀ is positive definite when M is").inverse();
    (w, s_inv)
}

fn pick(model: &Model, full: &DMatrix<f64>) -> DMatrix<f64> {
    let joints = model.coordinate_joints();
    DMatrix::from_fn(joints.len(), joints.len(), |a, b| full[(joints[a].0, joints[b].0)])
}

/// The coordinates' M⁻¹ from the joint-level M⁻¹.
pub fn project_inverse(model: &Model, minv_joints: DMatrix<f64>) -> DMatrix<f64> {
    if !model.has_coupled() {
        return minv_joints;
    }
    let (w, s_inv) = correction(model, &minv_joints);
    let constrained = &minv_joints - &w * s_inv * w.transpose();
    pick(model, &constrained)
}

/// Per-joint forces from per-coordinate ones: `Pᵀ τ` (the coordinate's joint takes it).
pub fn place(model: &Model, tau: &[f64]) -> Vec<f64> {
    if !model.has_coupled() {
        return tau.to_vec();
    }
    let mut out = vec![0.0; model.njoints()];
    for (k, &JointIndex(i)) in model.coordinate_joints().iter().enumerate() {
        out[i] = tau[k];
    }
    out
}

/// The coordinates' q̈ from the unconstrained joint-level `a` and M⁻¹.
pub fn project_acceleration(model: &Model, a: Vec<f64>, minv_joints: &DMatrix<f64>) -> Vec<f64> {
    let (w, s_inv) = correction(model, minv_joints);
    let a = nalgebra::DVector::from_vec(a);
    let constrained = &a - &w * (s_inv * (constraints(model) * &a));
    model.coordinate_joints().iter().map(|&JointIndex(i)| constrained[i]).collect()
}
