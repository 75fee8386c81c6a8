//! Composite-rigid-body algorithm: the joint-space mass matrix M(q)
//! (Featherstone 2008, table 6.2).

use nalgebra::DMatrix;

use super::coupled::reduce_matrix;
use super::Kinematics;
use crate::model::Model;

/// The symmetric mass matrix at `q`.
pub fn crba(model: &Model, q: &[f64]) -> DMatrix<f64> {
    reduce_matrix(model, crba_joints(model, q))
}

/// [`crba`] with a row and column per model joint (see `coupled`).
fn crba_joints(model: &Model, q: &[f64]) -> DMatrix<f64> {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let mut ic = k.inertia.clone();
    for i in (0..n).rev() {
        if let Some(p) = model.joints[i].parent {
            let add = k.x[i].transpose() * ic[i] * k.x[i];
            ic[p] += add;
        }
    }
    let mut m = DMatrix::zeros(n, n);
    for i in 0..n {
        let mut f = ic[i] * k.s[i];
        m[(i, i)] = k.s[i].dot(&f);
        let mut j = i;
        while let Some(p) = model.joints[j].parent {
            f = k.x[j].transpose() * f;
            j = p;
            m[(i, j)] = f.dot(&k.s[j]);
            m[(j, i)] = m[(i, j)];
        }
    }
    m
}
