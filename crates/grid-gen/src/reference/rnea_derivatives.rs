//! Analytical derivatives of RNEA with respect to q and q̇ (Carpentier & Mansard, RSS
//! 2018, in the body-frame form GRiD uses; see DESIGN.md). Each derivative is a 6 x nv
//! matrix per body: column u is ∂(·)/∂u.

use nalgebra::{DMatrix, Matrix6xX};

use super::coupled::{expand, reduce_matrix};
use super::{root_acceleration, Kinematics};
use crate::model::Model;
use crate::spatial::{crf, crm, Vec6};

/// `(∂c/∂q, ∂c/∂q̇)` at `(q, qd, qdd)`, row-major: entry (i, j) is ∂c_i/∂u_j.
pub fn rnea_derivatives(model: &Model, q: &[f64], qd: &[f64], qdd: &[f64], gravity: [f64; 3]) -> (DMatrix<f64>, DMatrix<f64>) {
    let (dq, dqd) = rnea_derivatives_joints(model, q, &expand(model, qd), &expand(model, qdd), gravity);
    (reduce_matrix(model, dq), reduce_matrix(model, dqd))
}

/// [`rnea_derivatives`] per model joint (see `coupled`).
fn rnea_derivatives_joints(model: &Model, q: &[f64], qd: &[f64], qdd: &[f64], gravity: [f64; 3]) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let a0 = root_acceleration(gravity);
    let zero = Matrix6xX::<f64>::zeros(n);
    let (mut v, mut a, mut f) = (vec![Vec6::zeros(); n], vec![Vec6::zeros(); n], vec![Vec6::zeros(); n]);
    // d?_dq[i] and d?_dqd[i]: 6 x n, column u = derivative with respect to q_u or q̇_u.
    let (mut dv_dq, mut da_dq, mut df_dq) = (vec![zero.clone(); n], vec![zero.clone(); n], vec![zero.clone(); n]);
    let (mut dv_dqd, mut da_dqd, mut df_dqd) = (vec![zero.clone(); n], vec![zero.clone(); n], vec![zero.clone(); n]);
    for i in 0..n {
        let s = k.s[i];
        let (v_parent, a_parent, parent) = match model.joints[i].parent {
            Some(p) => (v[p], a[p], Some(p)),
            None => (Vec6::zeros(), a0, None),
        };
        let xv = k.x[i] * v_parent;
        let xa = k.x[i] * a_parent;
        let vj = s * qd[i];
        v[i] = xv + vj;
        // The free-flyer is one joint at the root (see `Model::is_free_flyer`): no
        // velocity-product term, and its derivative terms see the root's v = 0 and a₀.
        let free = model.is_free_flyer(i);
        a[i] = xa + s * qdd[i];
        if !free {
            a[i] += crm(&v[i]) * vj;
        }
        let (xv, xa) = if free { (Vec6::zeros(), k.x[0] * a0) } else { (xv, xa) };
        let iv = k.inertia[i] * v[i];
        f[i] = k.inertia[i] * a[i] + crf(&v[i]) * iv;

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
        // ∂a_i = iXλ ∂a_λ + ∂v_i × S_i q̇_i + {(iXλ a_λ) × S_i for q_i; v_i × S_i for q̇_i}.
        if !free {
            da_dq[i] -= crm(&vj) * &dv_dq[i];
            da_dqd[i] -= crm(&vj) * &dv_dqd[i];
            col = da_dqd[i].column(i) + crm(&v[i]) * s;
            da_dqd[i].set_column(i, &col);
        }
        col = da_dq[i].column(i) + crm(&xa) * s;
        da_dq[i].set_column(i, &col);
        // ∂f_i = I ∂a_i + v_i ×* (I ∂v_i) + ∂v_i ×* (I v_i), the last one column by column.
        for (dv, da, df) in [(&dv_dq[i], &da_dq[i], &mut df_dq[i]), (&dv_dqd[i], &da_dqd[i], &mut df_dqd[i])] {
            *df = &k.inertia[i] * da + crf(&v[i]) * (&k.inertia[i] * dv);
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
            let dp = &xt * &df_dq[i];
            df_dq[p] += dp;
            let dpd = &xt * &df_dqd[i];
            df_dqd[p] += dpd;
            if !model.is_free_flyer(i) {
                let extra = xt * (crf(&s) * f[i]);
                let col = df_dq[p].column(i) + extra;
                df_dq[p].set_column(i, &col);
            }
            let fp = k.x[i].transpose() * f[i];
            f[p] += fp;
        }
    }
    (dc_dq, dc_dqd)
}
