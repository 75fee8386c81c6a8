//! The inverse mass matrix by the direct O(nv²) recursion of Carpentier (Pinocchio's
//! `computeMinverse`, after "Analytical inverse of the joint space inertia matrix", 2018),
//! in body coordinates. M is never formed or factorised.
//!
//! Backward pass: articulated inertias IA_i with U_i = IA_i S_i, D_i = S_iᵀ U_i; row i of
//! M⁻¹ over the subtree of i, and F_i (6 x nv) carrying the coupling to the parent.
//! Forward pass: the remaining entries of the upper triangle from the parents' P_λ
//! (6 x nv, the "acceleration" columns).

use nalgebra::{DMatrix, Matrix6xX};

use super::coupled::project_inverse;
use super::Kinematics;
use crate::model::Model;
use crate::spatial::Vec6;

/// M⁻¹(q), symmetric.
pub fn minv(model: &Model, q: &[f64]) -> DMatrix<f64> {
    project_inverse(model, minv_joints(model, q))
}

/// [`minv`] with a row and column per model joint, before the mimic constraints (see
/// `coupled`).
pub(crate) fn minv_joints(model: &Model, q: &[f64]) -> DMatrix<f64> {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let mut ia = k.inertia.clone();
    let mut f = vec![Matrix6xX::<f64>::zeros(n); n];
    let mut u = vec![Vec6::zeros(); n];
    let mut dinv = vec![0.0; n];
    let mut minv = DMatrix::zeros(n, n);
    for i in (0..n).rev() {
        let end = model.joints[i].subtree_end;
        u[i] = ia[i] * k.s[i];
        dinv[i] = 1.0 / k.s[i].dot(&u[i]);
        minv[(i, i)] = dinv[i];
        for j in i + 1..end {
            minv[(i, j)] = -dinv[i] * k.s[i].dot(&f[i].column(j));
        }
        if let Some(p) = model.joints[i].parent {
            for j in i..end {
                let col = f[i].column(j) + u[i] * minv[(i, j)];
                let moved = k.x[i].transpose() * col;
                let to_parent = f[p].column(j) + moved;
                f[p].set_column(j, &to_parent);
            }
            let ia_a = ia[i] - u[i] * dinv[i] * u[i].transpose();
            let add = k.x[i].transpose() * ia_a * k.x[i];
            ia[p] += add;
        }
    }
    let mut p_acc = vec![Matrix6xX::<f64>::zeros(n); n];
    for i in 0..n {
        if let Some(p) = model.joints[i].parent {
            for j in i..n {
                let xp = k.x[i] * p_acc[p].column(j);
                minv[(i, j)] -= dinv[i] * u[i].dot(&xp);
                p_acc[i].set_column(j, &(xp + k.s[i] * minv[(i, j)]));
            }
        } else {
            for j in i..n {
                p_acc[i].set_column(j, &(k.s[i] * minv[(i, j)]));
            }
        }
    }
    for i in 0..n {
        for j in 0..i {
            minv[(i, j)] = minv[(j, i)];
        }
    }
    minv
}
