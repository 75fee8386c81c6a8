//! The articulated-body algorithm: forward dynamics in O(n) (Featherstone 2008, table 7.1),
//! as Pinocchio's `aba`. More accurate than `M⁻¹ (τ − c)` when M is ill-conditioned.

use super::coupled::{expand, place, project_acceleration};
use super::forces::{body_forces, External};
use super::minv::minv_joints;
use super::{root_acceleration, velocity_product, Kinematics};
use crate::model::Model;
use crate::spatial::{crf, Vec6};

/// Joint accelerations under torques `tau` at `(q, qd)`, with gravity `gravity`.
pub fn aba(model: &Model, q: &[f64], qd: &[f64], tau: &[f64], gravity: [f64; 3]) -> Vec<f64> {
    aba_with(model, q, qd, tau, gravity, External::NONE)
}

/// [`aba`] under external forces and contact forces `ext` (Pinocchio's
/// `aba(model, data, q, v, tau, fext)`).
pub fn aba_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    ext: External,
) -> Vec<f64> {
    let a = aba_joints(
        model,
        q,
        &expand(model, qd),
        &place(model, tau),
        gravity,
        &body_forces(model, q, ext),
    );
    if !model.has_coupled() {
        return a;
    }
    project_acceleration(model, a, &minv_joints(model, q))
}

/// [`aba`] with a q̇, τ and q̈ per model joint, before the mimic constraints (see `coupled`).
fn aba_joints(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    ext: &[Vec6],
) -> Vec<f64> {
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let mut v = vec![Vec6::zeros(); n];
    let mut c = vec![Vec6::zeros(); n];
    let mut pa = vec![Vec6::zeros(); n];
    let mut xv = vec![Vec6::zeros(); n];
    // Velocities, velocity-product accelerations c, bias forces pA.
    for i in 0..n {
        let v_parent = model.joints[i].parent.map_or(Vec6::zeros(), |p| v[p]);
        xv[i] = k.x[i] * v_parent;
        v[i] = xv[i] + k.s[i] * qd[i];
        c[i] = velocity_product(model, i, &k, &v, &xv, qd);
        pa[i] = crf(&v[i]) * (k.inertia[i] * v[i]) - ext[i];
    }
    // Articulated inertias and bias forces, leaves to root.
    let mut ia = k.inertia.clone();
    let mut u = vec![Vec6::zeros(); n];
    let mut d = vec![0.0; n];
    let mut uu = vec![0.0; n];
    for i in (0..n).rev() {
        u[i] = ia[i] * k.s[i];
        d[i] = k.s[i].dot(&u[i]);
        uu[i] = tau[i] - k.s[i].dot(&pa[i]);
        if let Some(p) = model.joints[i].parent {
            let ia_a = ia[i] - u[i] * u[i].transpose() / d[i];
            let pa_a = pa[i] + ia_a * c[i] + u[i] * (uu[i] / d[i]);
            ia[p] += k.x[i].transpose() * ia_a * k.x[i];
            pa[p] += k.x[i].transpose() * pa_a;
        }
    }
    // Accelerations, root to leaves.
    let a0 = root_acceleration(gravity);
    let mut a = vec![Vec6::zeros(); n];
    let mut qdd = vec![0.0; n];
    for i in 0..n {
        let a_parent = model.joints[i].parent.map_or(a0, |p| a[p]);
        let a_bias = k.x[i] * a_parent + c[i];
        qdd[i] = (uu[i] - u[i].dot(&a_bias)) / d[i];
        a[i] = a_bias + k.s[i] * qdd[i];
    }
    qdd
}
