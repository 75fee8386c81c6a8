//! Recursive Newton-Euler: inverse dynamics `c = M(q) q̈ + C(q, q̇) q̇ + g(q)`
//! (Featherstone 2008, table 5.1).

use super::coupled::{expand, reduce};
use super::forces::{body_forces, External};
use super::{root_acceleration, velocity_product, Kinematics};
use crate::model::Model;
use crate::spatial::{crf, Vec6};

/// Joint forces needed for accelerations `qdd` at `(q, qd)`, with gravity `gravity`.
pub fn rnea(model: &Model, q: &[f64], qd: &[f64], qdd: &[f64], gravity: [f64; 3]) -> Vec<f64> {
    rnea_with(model, q, qd, qdd, gravity, External::NONE)
}

/// [`rnea`] under external forces and contact forces `ext` (subtracted from the bodies'
/// forces, as Pinocchio's `rnea(model, data, q, v, a, fext)`).
pub fn rnea_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    gravity: [f64; 3],
    ext: External,
) -> Vec<f64> {
    let (qd, qdd) = (expand(model, qd), expand(model, qdd));
    reduce(model, &rnea_joints(model, q, &qd, &qdd, gravity, &body_forces(model, q, ext)))
}

/// [`rnea`] with one q̇, q̈ and force per model joint (see `coupled`), and one external
/// force per body in its own frame.
fn rnea_joints(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    gravity: [f64; 3],
    ext: &[Vec6],
) -> Vec<f64> {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let a0 = root_acceleration(gravity);
    let mut v = vec![Vec6::zeros(); n];
    let mut a = vec![Vec6::zeros(); n];
    let mut f = vec![Vec6::zeros(); n];
    let mut xv = vec![Vec6::zeros(); n];
    // Forward pass: velocities, accelerations, body forces.
    for i in 0..n {
        let (v_parent, a_parent) = match model.joints[i].parent {
            Some(p) => (v[p], a[p]),
            None => (Vec6::zeros(), a0),
        };
        xv[i] = k.x[i] * v_parent;
        v[i] = xv[i] + k.s[i] * qd[i];
        a[i] = k.x[i] * a_parent + k.s[i] * qdd[i] + velocity_product(model, i, &k, &v, &xv, qd);
        f[i] = k.inertia[i] * a[i] + crf(&v[i]) * (k.inertia[i] * v[i]) - ext[i];
    }
    // Backward pass: project onto the joint, pass the rest to the parent.
    let mut tau = vec![0.0; n];
    for i in (0..n).rev() {
        tau[i] = k.s[i].dot(&f[i]);
        if let Some(p) = model.joints[i].parent {
            let fp = k.x[i].transpose() * f[i];
            f[p] += fp;
        }
    }
    tau
}
