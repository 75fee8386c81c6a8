//! External forces in the reference dynamics. Two kinds, both turned into one
//! spatial force per body, in the body's own frame, that RNEA subtracts and ABA adds to
//! the bias forces (Featherstone 2008, §5.3):
//!
//! - `fext`: a force per chosen body in its joint's frame, `[linear; angular]`, as
//!   Pinocchio's `fext` (the body of a multi-dof joint is its last member's);
//! - contact forces λ at frames, in `LOCAL_WORLD_ALIGNED` axes at the frame's origin
//!   (Crocoddyl's and GRiD's contact forces): the body sees `[p × Rᵀf + Rᵀτ; Rᵀf]`, with R
//!   the body's world rotation and p the frame's origin in the body.
//!
//! Derivatives hold `fext` fixed in the bodies' frames (Pinocchio's) and λ fixed in world
//! axes, so a contact adds `∂(Jᵀ)/∂q · λ` ([`contact_q_terms`]).

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::coupled::reduce;
use super::{forward_kinematics, minv, motion_subspace, Kinematics};
use crate::model::{ContactKind, Model};
use crate::spatial::{crf, Vec6};

/// External forces at one state, flat as the kernels take them: `fext` 6 per body of
/// [`crate::model::Specialisation::fext`] (`[fx, fy, fz, tx, ty, tz]`), `lambda` 3 or 6 per
/// contact of [`crate::model::Specialisation::contacts`]. An empty slice is all zeros.
#[derive(Clone, Copy, Debug, Default)]
pub struct External<'a> {
    pub fext: &'a [f64],
    pub lambda: &'a [f64],
}

impl External<'_> {
    /// No external force.
    pub const NONE: External<'static> = External { fext: &[], lambda: &[] };
}

/// Pinocchio's `[linear; angular]` as Featherstone's `[angular; linear]`.
fn featherstone(x: &[f64]) -> Vec6 {
    Vec6::new(x[3], x[4], x[5], x[0], x[1], x[2])
}

/// A contact's force on its body in the body's frame: λ turned into the body's axes
/// (`rb` is the body's world rotation), its force moved from the frame's origin `p`.
fn contact_force(rb: &Matrix3<f64>, p: &Vector3<f64>, kind: ContactKind, lambda: &[f64]) -> Vec6 {
    let f = rb.transpose() * Vector3::new(lambda[0], lambda[1], lambda[2]);
    let mut n = p.cross(&f);
    if kind == ContactKind::Wrench {
        n += rb.transpose() * Vector3::new(lambda[3], lambda[4], lambda[5]);
    }
    Vec6::new(n.x, n.y, n.z, f.x, f.y, f.z)
}

/// Each contact with its body, its frame's origin in the body, its kind, and where its
/// entries start in λ.
fn contacts(model: &Model) -> impl Iterator<Item = (usize, Vector3<f64>, ContactKind, usize)> + '_ {
    let mut at = 0;
    model.specialisation.contacts.iter().map(move |c| {
        let frame = &model.frames[c.frame];
        at += c.kind.dim();
        (
            frame.body.expect("contacts are on moving bodies"),
            frame.placement.pos_vector(),
            c.kind,
            at - c.kind.dim(),
        )
    })
}

/// One external force per model joint's body, in its frame (zero where none acts).
pub(crate) fn body_forces(model: &Model, q: &[f64], ext: External) -> Vec<Vec6> {
    let mut out = vec![Vec6::zeros(); model.njoints()];
    if !ext.fext.is_empty() {
        assert_eq!(ext.fext.len(), 6 * model.nfext(), "fext has 6 entries per body");
        for (j, &b) in model.specialisation.fext.iter().enumerate() {
            out[b] += featherstone(&ext.fext[6 * j..6 * j + 6]);
        }
    }
    if !ext.lambda.is_empty() {
        assert_eq!(ext.lambda.len(), model.nlambda(), "lambda has 3 or 6 entries per contact");
        let poses = forward_kinematics(model, q);
        for (b, p, kind, at) in contacts(model) {
            out[b] += contact_force(&poses[b].0, &p, kind, &ext.lambda[at..at + kind.dim()]);
        }
    }
    out
}

/// `J_bᵀ w` per model joint: a force w on body b (in b's frame) projected onto each joint
/// on b's path, as RNEA's backward pass carries it.
fn jacobian_t(model: &Model, k: &Kinematics, b: usize, mut w: Vec6) -> Vec<f64> {
    let mut out = vec![0.0; model.njoints()];
    let mut at = Some(b);
    while let Some(j) = at {
        out[j] = k.s[j].dot(&w);
        w = k.x[j].transpose() * w;
        at = model.joints[j].parent;
    }
    out
}

/// What holding λ fixed in world axes adds to `∂c/∂q` (per model joint): moving joint u
/// turns body b by ω (u's axis in b's frame) under the contact's world-aligned frame, so
/// the body-frame force f changes by `−m × f`, m = `[ω; p × ω]` the rotation about the
/// contact point; RNEA subtracts f, so `∂c/∂q_u` gains `J_bᵀ (m ×* f)`.
pub(crate) fn contact_q_terms(model: &Model, q: &[f64], ext: External) -> DMatrix<f64> {
    let n = model.njoints();
    let mut out = DMatrix::zeros(n, n);
    if ext.lambda.is_empty() {
        return out;
    }
    let k = Kinematics::new(model, q);
    let poses = forward_kinematics(model, q);
    for (b, p, kind, at) in contacts(model) {
        let f = contact_force(&poses[b].0, &p, kind, &ext.lambda[at..at + kind.dim()]);
        for u in model.ancestors(b) {
            if !model.joints[u].joint_type.is_rotation() {
                continue;
            }
            let axis = motion_subspace(&model.joints[u]).fixed_rows::<3>(0).into_owned();
            let w = poses[b].0.transpose() * (poses[u].0 * axis);
            let pw = p.cross(&w);
            let m = Vec6::new(w.x, w.y, w.z, pw.x, pw.y, pw.z);
            let col = jacobian_t(model, &k, b, crf(&m) * f);
            for (i, x) in col.into_iter().enumerate() {
                out[(i, u)] += x;
            }
        }
    }
    out
}

/// The derivatives with respect to the forces themselves, per coordinate, columns in the
/// inputs' order (`fext` body by body `[fx, fy, fz, tx, ty, tz]`, λ contact by contact).
#[derive(Clone, Debug)]
pub struct ForceDerivatives {
    /// `∂c/∂fext = −J_bᵀ` (J_b the body's Jacobian in its joint's frame): nv x 6 nfext.
    pub dc_dfext: DMatrix<f64>,
    /// `∂c/∂λ = −J_cᵀ` (J_c the contact frame's `LOCAL_WORLD_ALIGNED` Jacobian, its three
    /// linear rows for a point contact): nv x nlambda.
    pub dc_dlambda: DMatrix<f64>,
    /// `∂q̈/∂fext = −M⁻¹ ∂c/∂fext`.
    pub dqdd_dfext: DMatrix<f64>,
    /// `∂q̈/∂λ = −M⁻¹ ∂c/∂λ`.
    pub dqdd_dlambda: DMatrix<f64>,
}

/// [`ForceDerivatives`] at `q` (they depend on nothing else: c is affine in the forces).
/// The `dqdd` pair is zero-sized when M is singular.
pub fn force_derivatives(model: &Model, q: &[f64]) -> ForceDerivatives {
    let nv = model.nv();
    let k = Kinematics::new(model, q);
    let column = |b: usize, w: Vec6| -> Vec<f64> { reduce(model, &jacobian_t(model, &k, b, -w)) };
    let mut dc_dfext = DMatrix::zeros(nv, 6 * model.nfext());
    for (j, &b) in model.specialisation.fext.iter().enumerate() {
        for c in 0..6 {
            let mut e = [0.0; 6];
            e[c] = 1.0;
            dc_dfext
                .set_column(6 * j + c, &nalgebra::DVector::from_vec(column(b, featherstone(&e))));
        }
    }
    let mut dc_dlambda = DMatrix::zeros(nv, model.nlambda());
    let poses = forward_kinematics(model, q);
    for (b, p, kind, at) in contacts(model) {
        for c in 0..kind.dim() {
            let mut e = [0.0; 6];
            e[c] = 1.0;
            let w = contact_force(&poses[b].0, &p, ContactKind::Wrench, &e);
            dc_dlambda.set_column(at + c, &nalgebra::DVector::from_vec(column(b, w)));
        }
    }
    let (dqdd_dfext, dqdd_dlambda) = if model.singular.is_some() {
        (DMatrix::zeros(0, 0), DMatrix::zeros(0, 0))
    } else {
        let mi = minv(model, q);
        (-&mi * &dc_dfext, -&mi * &dc_dlambda)
    };
    ForceDerivatives { dc_dfext, dc_dlambda, dqdd_dfext, dqdd_dlambda }
}
