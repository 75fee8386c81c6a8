//! Analytical derivatives of RNEA with respect to q and q̇ (Carpentier & Mansard, RSS
//! 2018, in the body-frame form GRiD uses; see DESIGN.md). Each derivative is a 6 x nv
//! matrix per body: column u is ∂(·)/∂u.

use nalgebra::{DMatrix, Matrix6xX};

use super::coupled::{expand, reduce_matrix};
use super::forces::{body_forces, contact_q_terms, External};
use super::{root_acceleration, velocity_product, Kinematics};
use crate::model::Model;
use crate::spatial::{crf, crm, Vec6};

/// `(∂c/∂q, ∂c/∂q̇)` at `(q, qd, qdd)`, row-major: entry (i, j) is ∂c_i/∂u_j.
pub fn rnea_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    gravity: [f64; 3],
) -> (DMatrix<f64>, DMatrix<f64>) {
    rnea_derivatives_with(model, q, qd, qdd, gravity, External::NONE)
}

/// [`rnea_derivatives`] under external forces `ext`: `fext` held fixed in the bodies'
/// frames (as Pinocchio's `computeRNEADerivatives(..., fext)`), contact forces λ fixed in
/// their `LOCAL_WORLD_ALIGNED` axes (so ∂(Jᵀ)/∂q · λ is included).
pub fn rnea_derivatives_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    gravity: [f64; 3],
    ext: External,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let forces = body_forces(model, q, ext);
    let (mut dq, dqd) = rnea_derivatives_joints(
        model,
        q,
        &expand(model, qd),
        &expand(model, qdd),
        gravity,
        &forces,
    );
    dq += contact_q_terms(model, q, ext);
    (reduce_matrix(model, dq), reduce_matrix(model, dqd))
}

/// [`rnea_derivatives`] per model joint (see `coupled`), one external force per body in
/// its own frame, held fixed there.
fn rnea_derivatives_joints(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    gravity: [f64; 3],
    ext: &[Vec6],
) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let a0 = root_acceleration(gravity);
    let zero = Matrix6xX::<f64>::zeros(n);
    let (mut v, mut a, mut f) =
        (vec![Vec6::zeros(); n], vec![Vec6::zeros(); n], vec![Vec6::zeros(); n]);
    // d?_dq[i] and d?_dqd[i]: 6 x n, column u = derivative with respect to q_u or q̇_u.
    let (mut dv_dq, mut da_dq, mut df_dq) =
        (vec![zero.clone(); n], vec![zero.clone(); n], vec![zero.clone(); n]);
    let (mut dv_dqd, mut da_dqd, mut df_dqd) =
        (vec![zero.clone(); n], vec![zero.clone(); n], vec![zero.clone(); n]);
    let (mut xvs, mut xas) = (vec![Vec6::zeros(); n], vec![Vec6::zeros(); n]);
    for i in 0..n {
        let s = k.s[i];
        let (v_parent, a_parent, parent) = match model.joints[i].parent {
            Some(p) => (v[p], a[p], Some(p)),
            None => (Vec6::zeros(), a0, None),
        };
        xvs[i] = k.x[i] * v_parent;
        xas[i] = k.x[i] * a_parent;
        v[i] = xvs[i] + s * qd[i];
        a[i] = xas[i] + s * qdd[i] + velocity_product(model, i, &k, &v, &xvs, qd);
        // A multi-dof joint is one joint (see `Model::group`): its members' derivative
        // terms see the parent's velocity and acceleration, and only its last member has
        // a velocity-product term (none at the root).
        let group = model.group(i);
        let first = group.as_ref().map_or(i, |g| g.start);
        let (xv, xa) = (xvs[first], xas[first]);
        let product =
            group.as_ref().is_none_or(|g| i + 1 == g.end && model.joints[g.start].parent.is_some());
        let vj: Vec6 = group.clone().unwrap_or(i..i + 1).map(|m| k.s[m] * qd[m]).sum();
        let iv = k.inertia[i] * v[i];
        f[i] = k.inertia[i] * a[i] + crf(&v[i]) * iv - ext[i];

        // ∂v_i = iXλ ∂v_λ + {(iXλ v_λ) × S_i for q_i; S_i for q̇_i}.
        if let Some(p) = parent {
            dv_dq[i] = k.x[i] * &dv_dq[p];
            dv_dqd[i] = k.x[i] * &dv_dqd[p];
            da_dq[i] = k.x[i] * &da_dq[p];
            da_dqd[i] = k.x[i] * &da_dqd[p];
        }
        let mut col = dv_dq[i].column(i) + crm(&xv) * s;
        dv_dq[i].set_column(i, &col);
        col = dv_dqd[i].column(i) + s;
        dv_dqd[i].set_column(i, &col);
        // ∂a_i = iXλ ∂a_λ + ∂v_i × S_i q̇_i + {(iXλ a_λ) × S_i for q_i; v_i × S_i for q̇_i};
        // a multi-dof joint's last member: ∂u × v_J, and v_i × S_k for each member's q̇_k
        // (∂(u × v_J)/∂q̇_k = u × S_k once ∂v_i's S_k is taken back out).
        if product {
            da_dq[i] -= crm(&vj) * &dv_dq[i];
            da_dqd[i] -= crm(&vj) * &dv_dqd[i];
            for m in group.clone().unwrap_or(i..i + 1) {
                col = da_dqd[i].column(m) + crm(&v[i]) * k.s[m];
                da_dqd[i].set_column(m, &col);
            }
        }
        col = da_dq[i].column(i) + crm(&xa) * s;
        da_dq[i].set_column(i, &col);
        // ∂f_i = I ∂a_i + v_i ×* (I ∂v_i) + ∂v_i ×* (I v_i), the last one column by column.
        for (dv, da, df) in
            [(&dv_dq[i], &da_dq[i], &mut df_dq[i]), (&dv_dqd[i], &da_dqd[i], &mut df_dqd[i])]
        {
            *df = k.inertia[i] * da + crf(&v[i]) * (k.inertia[i] * dv);
            for u in 0..n {
                let dvu: Vec6 = dv.column(u).into();
                let c = df.column(u) + crf(&dvu) * iv;
                df.set_column(u, &c);
            }
        }
    }
    let mut dc_dq = DMatrix::zeros(n, n);
    let mut dc_dqd = DMatrix::zeros(n, n);
    for i in (0..n).rev() {
        let s = k.s[i];
        for u in 0..n {
            dc_dq[(i, u)] = s.dot(&df_dq[i].column(u));
            dc_dqd[(i, u)] = s.dot(&df_dqd[i].column(u));
        }
        if let Some(p) = model.joints[i].parent {
            // ∂f_λ += iXλᵀ ∂f_i, plus iXλᵀ (S_i ×* f_i) in the q_i column.
            let xt = k.x[i].transpose();
            let dp = xt * &df_dq[i];
            df_dq[p] += dp;
            let dpd = xt * &df_dqd[i];
            df_dqd[p] += dpd;
            // For a multi-dof joint, at its first member for every member's column (between
            // members the frames coincide and S is constant: no such term).
            let members = match model.group(i) {
                None => i..i + 1,
                Some(g) if g.start == i => g,
                Some(_) => i..i,
            };
            for m in members {
                let extra = xt * (crf(&k.s[m]) * f[i]);
                let col = df_dq[p].column(m) + extra;
                df_dq[p].set_column(m, &col);
            }
            let fp = k.x[i].transpose() * f[i];
            f[p] += fp;
        }
    }
    (dc_dq, dc_dqd)
}
