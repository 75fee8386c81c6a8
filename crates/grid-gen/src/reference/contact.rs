//! Rigid-contact forward dynamics and its derivatives, as Pinocchio's `constraintDynamics`
//! and `computeConstraintDynamicsDerivatives` with `CONTACT_3D` / `CONTACT_6D` constraints
//! in `LOCAL_WORLD_ALIGNED` (with Baumgarte's corrector on point contacts where [`Baumgarte`]
//! holds gains; none by default): the contacts' accelerations are
//! zero, a point contact's the classical acceleration of its frame's origin, a wrench
//! contact's the frame's spatial acceleration, both in world axes at the frame's origin.
//!
//! The reference solves the whole KKT system `[M Jᵀ; J 0] [q̈; −λ] = [τ − c(q, q̇, 0); −γ]`
//! by LU, and its derivatives by differentiating the two rows (Carpentier & Budhiraja,
//! "Analytical derivatives of rigid body dynamics with constraints", 2021): `M ∂q̈ − Jᵀ ∂λ =
//! −∂c/∂u` (RNEA's derivatives at the solution, λ held in world axes) and `J ∂q̈ =
//! −∂acc/∂u` at fixed q̈. The kernels use the Schur complement instead, so each checks the
//! other.
//!
//! The contacts' accelerations and their derivatives are written over world-frame screws,
//! not the body-frame recursion of `frames.rs`: S_a is joint a's unit motion at the world
//! origin ([angular; linear]), a body's velocity `V = Σ S_a q̇_a` and acceleration
//! `A = Σ S_a q̈_a + (V_a × S_a) q̇_a` over its ancestors (V_a the velocity of the body joint
//! a moves; for a multi-dof joint, the body after its last member). Moving coordinate k
//! along its tangent turns every screw attached downstream of it: `∂S_a/∂δ_k = S_k × S_a`.

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, UnitQuaternion, Vector3};

use super::coupled::expand;
use super::forces::External;
use super::{crba, forward_kinematics, frame_jacobian, rnea_derivatives_with, rnea_with};
use crate::model::JointIndex;
use crate::model::{Contact, ContactKind, Model, ReferenceFrame};
use crate::spatial::{crm, Vec6};

/// Pinocchio's Baumgarte corrector (`RigidConstraintModel` in `LOCAL_WORLD_ALIGNED` with
/// joint2 the universe at the reference, its `BaumgarteCorrectorParameters` set). A point
/// contact's constraint is `a + Kd v + Kp (p − p_ref) = 0`, a, v the point's classical
/// acceleration and velocity and p its position, all in the world. A wrench contact's is
/// `[a; α] + Kd [v; ω] − Kp R_c log6(oMc⁻¹ oMref) = 0` (spatial acceleration and velocity
/// at the frame's origin, world axes). `gains` holds `[Kp, Kd]` per contact, `refs` each
/// contact's reference (a point's position, 3 entries; a wrench's position and quaternion
/// `[x, y, z, qx, qy, qz, qw]`, 7); both empty: no correction (the rigid contact).
#[derive(Clone, Copy, Debug, Default)]
pub struct Baumgarte<'a> {
    pub gains: &'a [f64],
    pub refs: &'a [f64],
}

impl Baumgarte<'_> {
    pub const NONE: Baumgarte<'static> = Baumgarte { gains: &[], refs: &[] };

    /// `(Kp, Kd, reference)` of contact `c` of `contacts`, when the corrector holds it.
    fn of(&self, contacts: &[Contact], c: usize) -> Option<(f64, f64, &[f64])> {
        let g = self.gains.get(2 * c..2 * c + 2)?;
        let at: usize = contacts[..c].iter().map(|c| c.kind.ref_dim()).sum();
        let r = self.refs.get(at..at + contacts[c].kind.ref_dim())?;
        Some((g[0], g[1], r))
    }
}

/// A wrench contact's placement error in world axes, `R_c log6(oMc⁻¹ oMref)` =
/// `[V(ω)⁻¹ (p_ref − p); ω]` with `ω = log3(R_ref R_cᵀ)` (by the quaternion's `atan2`, and
/// V's inverse by an LU solve: a route independent of the kernels' halving of the angle).
fn placement_error(
    rc: &Matrix3<f64>,
    p: &Vector3<f64>,
    reference: &[f64],
) -> (Vector3<f64>, Vector3<f64>) {
    let r_ref = super::step::quaternion(reference, 3);
    let e = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
        r_ref.to_rotation_matrix().into_inner() * rc.transpose(),
    ));
    let omega = super::lie::quaternion_log3(&e);
    let d = Vector3::new(reference[0], reference[1], reference[2]) - p;
    let lin = super::step::so3_jacobians(&omega)
        .0
        .lu()
        .solve(&d)
        .expect("V(ω) is invertible for angles below 2π");
    (lin, omega)
}

/// The first-order change of [`placement_error`] when the frame turns by `dw` (world axes)
/// and its origin moves by `dp`: `dω = −Jexp3(ω)⁻¹ dw` (the error's rotation is multiplied
/// on the right by `exp(−dw)` in the frame's axes, Pinocchio's `Jlog3`), and the change of
/// `V⁻¹(ω) d = d − ½ ω × d + β ω × (ω × d)` (β and β'/θ as `Jexp6` takes them).
fn d_placement_error(
    rc: &Matrix3<f64>,
    p: &Vector3<f64>,
    reference: &[f64],
    dw: &Vector3<f64>,
    dp: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let (_, omega) = placement_error(rc, p, reference);
    let (_, jr) = super::step::so3_jacobians(&omega);
    let dom = -jr.lu().solve(dw).expect("Jexp3 is invertible for angles below 2π");
    let d = Vector3::new(reference[0], reference[1], reference[2]) - p;
    let dd = -dp;
    let (b, db) = super::step::beta(omega.norm());
    let wd = omega.cross(&d);
    let dlin = dd - (dom.cross(&d) + omega.cross(&dd)) * 0.5
        + (dom.cross(&wd) + omega.cross(&(dom.cross(&d) + omega.cross(&dd)))) * b
        + omega.cross(&wd) * (db * omega.dot(&dom));
    (dlin, dom)
}

/// q̈ and the contact forces λ (3 or 6 per contact, world axes at the frame's origin, as
/// Pinocchio's `lambda_c` and the kernels' `lambda` input).
#[derive(Clone, Debug)]
pub struct ContactDynamics {
    pub qdd: Vec<f64>,
    pub lambda: Vec<f64>,
}

/// The derivatives of [`ContactDynamics`], q in the tangent space: `nv x nv` for q̈,
/// `nlambda x nv` for λ.
#[derive(Clone, Debug)]
pub struct ContactDerivatives {
    pub dqdd_dq: DMatrix<f64>,
    pub dqdd_dqd: DMatrix<f64>,
    pub dqdd_dtau: DMatrix<f64>,
    pub dlambda_dq: DMatrix<f64>,
    pub dlambda_dqd: DMatrix<f64>,
    pub dlambda_dtau: DMatrix<f64>,
}

/// The stacked contact Jacobian, `nlambda x nv`: each contact's `LOCAL_WORLD_ALIGNED`
/// frame Jacobian, its three linear rows for a point contact.
pub fn contact_jacobian(model: &Model, contacts: &[Contact], q: &[f64]) -> DMatrix<f64> {
    let rows: usize = contacts.iter().map(|c| c.kind.dim()).sum();
    let mut j = DMatrix::zeros(rows, model.nv());
    let mut at = 0;
    for c in contacts {
        let jf =
            frame_jacobian(model, q, &model.frames[c.frame], ReferenceFrame::LocalWorldAligned);
        j.rows_mut(at, c.kind.dim()).copy_from(&jf.rows(0, c.kind.dim()));
        at += c.kind.dim();
    }
    j
}

/// Per model joint: its world screw, and the velocity of the body it moves.
struct Screws {
    s: Vec<Vec6>,
    v: Vec<Vec6>,
    poses: Vec<(nalgebra::Matrix3<f64>, Vector3<f64>)>,
}

impl Screws {
    fn new(model: &Model, q: &[f64], qd: &[f64]) -> Self {
        let poses = forward_kinematics(model, q);
        let n = model.njoints();
        let (mut s, mut v) = (vec![Vec6::zeros(); n], vec![Vec6::zeros(); n]);
        for a in 0..n {
            let joint = &model.joints[a];
            let (r, p) = poses[a];
            let axis = r * Vector3::from(joint.axis);
            s[a] = if joint.joint_type.is_rotation() {
                join(axis, p.cross(&axis))
            } else {
                join(Vector3::zeros(), axis)
            };
            v[a] = joint.parent.map_or(Vec6::zeros(), |p| v[p]) + s[a] * qd[a];
        }
        Screws { s, v, poses }
    }
}

fn join(a: Vector3<f64>, b: Vector3<f64>) -> Vec6 {
    Vec6::new(a.x, a.y, a.z, b.x, b.y, b.z)
}

fn ang(x: &Vec6) -> Vector3<f64> {
    Vector3::new(x[0], x[1], x[2])
}

fn lin(x: &Vec6) -> Vector3<f64> {
    Vector3::new(x[3], x[4], x[5])
}

/// The body joint a moves: a multi-dof joint's last member's.
fn moved(model: &Model, a: usize) -> usize {
    model.group(a).map_or(a, |g| g.end - 1)
}

/// Whether moving joint k turns joint a's screw: k is an ancestor of a, or a member of
/// a's multi-dof joint (whose screws are fixed in the body after it).
fn turns(model: &Model, k: usize, a: usize) -> bool {
    model.is_ancestor_or_self(k, a) || model.group(a).is_some_and(|g| g.contains(&k))
}

/// One contact's acceleration rows from its body's spatial velocity V and acceleration A
/// (world, at the origin) and its frame's origin p: a point's classical acceleration
/// `A_lin + α × p + ω × (v + ω × p)`, a wrench's spatial acceleration `[A_lin + α × p; α]`.
fn rows(kind: ContactKind, v: &Vec6, a: &Vec6, p: &Vector3<f64>) -> Vec<f64> {
    let at_p = lin(a) + ang(a).cross(p);
    match kind {
        ContactKind::Point => {
            let w = ang(v);
            let vp = lin(v) + w.cross(p);
            (at_p + w.cross(&vp)).iter().copied().collect()
        }
        ContactKind::Wrench => at_p.iter().chain(ang(a).iter()).copied().collect(),
    }
}

/// The first-order change of [`rows`] under changes dv, da, dp of its arguments.
fn d_rows(
    kind: ContactKind,
    (v, a, p): (&Vec6, &Vec6, &Vector3<f64>),
    (dv, da, dp): (&Vec6, &Vec6, &Vector3<f64>),
) -> Vec<f64> {
    let d_at_p = lin(da) + ang(da).cross(p) + ang(a).cross(dp);
    match kind {
        ContactKind::Point => {
            let (w, dw) = (ang(v), ang(dv));
            let vp = lin(v) + w.cross(p);
            let dvp = lin(dv) + dw.cross(p) + w.cross(dp);
            (d_at_p + dw.cross(&vp) + w.cross(&dvp)).iter().copied().collect()
        }
        ContactKind::Wrench => d_at_p.iter().chain(ang(da).iter()).copied().collect(),
    }
}

/// Each contact's body, its frame's origin in world coordinates, and its kind.
fn contact_points<'a>(
    model: &'a Model,
    contacts: &'a [Contact],
    sc: &'a Screws,
) -> impl Iterator<Item = (usize, Vector3<f64>, ContactKind)> + 'a {
    contacts.iter().map(move |c| {
        let frame = &model.frames[c.frame];
        let b = frame.body.expect("contacts are on moving bodies");
        let (r, p) = sc.poses[b];
        (b, p + r * frame.placement.pos_vector(), c.kind)
    })
}

/// A contact frame's world rotation: its body's, times its placement's.
fn frame_rotation(model: &Model, sc: &Screws, c: &Contact) -> Matrix3<f64> {
    let frame = &model.frames[c.frame];
    sc.poses[frame.body.expect("contacts are on moving bodies")].0 * frame.placement.rot_matrix()
}

/// The body's spatial acceleration `Σ S_a q̈_a + (V_a × S_a) q̇_a` over its ancestors.
fn body_acceleration(model: &Model, sc: &Screws, b: usize, qd: &[f64], qdd: &[f64]) -> Vec6 {
    model
        .ancestors(b)
        .into_iter()
        .map(|a| sc.s[a] * qdd[a] + crm(&sc.v[moved(model, a)]) * sc.s[a] * qd[a])
        .sum()
}

/// The contacts' constrained accelerations at (q, q̇, q̈), stacked as λ is: `J q̈ + γ`.
pub fn contact_accelerations(
    model: &Model,
    contacts: &[Contact],
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
) -> Vec<f64> {
    corrected_accelerations(model, contacts, q, qd, qdd, Baumgarte::NONE)
}

/// [`contact_accelerations`] with the corrector's terms `Kd v + Kp (p − p_ref)` added on
/// each point contact it holds.
fn corrected_accelerations(
    model: &Model,
    contacts: &[Contact],
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    corr: Baumgarte,
) -> Vec<f64> {
    let (qd, qdd) = (expand(model, qd), expand(model, qdd));
    let sc = Screws::new(model, q, &qd);
    contact_points(model, contacts, &sc)
        .enumerate()
        .flat_map(|(c, (b, p, kind))| {
            let mut r = rows(kind, &sc.v[b], &body_acceleration(model, &sc, b, &qd, &qdd), &p);
            if let Some((kp, kd, reference)) = corr.of(contacts, c) {
                let w = ang(&sc.v[b]);
                let v = lin(&sc.v[b]) + w.cross(&p);
                match kind {
                    ContactKind::Point => {
                        for i in 0..3 {
                            r[i] += kd * v[i] + kp * (p[i] - reference[i]);
                        }
                    }
                    ContactKind::Wrench => {
                        let rc = frame_rotation(model, &sc, &contacts[c]);
                        let (el, ew) = placement_error(&rc, &p, reference);
                        for i in 0..3 {
                            r[i] += kd * v[i] - kp * el[i];
                            r[3 + i] += kd * w[i] - kp * ew[i];
                        }
                    }
                }
            }
            r
        })
        .collect()
}

/// `(∂acc/∂q, ∂acc/∂q̇)` of [`contact_accelerations`] at fixed q̈, `nlambda x nv` each, q in
/// the tangent space.
pub fn contact_acceleration_derivatives(
    model: &Model,
    contacts: &[Contact],
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
) -> (DMatrix<f64>, DMatrix<f64>) {
    corrected_acceleration_derivatives(model, contacts, q, qd, qdd, Baumgarte::NONE)
}

/// [`contact_acceleration_derivatives`] of [`corrected_accelerations`]: the corrector adds
/// `Kd ∂v + Kp ∂p` (∂v/∂q̇ = ∂p/∂q = the point's linear Jacobian in world axes).
fn corrected_acceleration_derivatives(
    model: &Model,
    contacts: &[Contact],
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    corr: Baumgarte,
) -> (DMatrix<f64>, DMatrix<f64>) {
    let (qd, qdd) = (expand(model, qd), expand(model, qdd));
    let sc = Screws::new(model, q, &qd);
    let n = model.njoints();
    let points: Vec<_> = contact_points(model, contacts, &sc).collect();
    let nl: usize = contacts.iter().map(|c| c.kind.dim()).sum();
    let (mut dq, mut dqd) = (DMatrix::zeros(nl, model.nv()), DMatrix::zeros(nl, model.nv()));
    for k in 0..n {
        let (col, m) = (model.coordinate_of(JointIndex(k)).0, model.multiplier(k));
        // Along δ_k: screws downstream turn by S_k ×, velocities follow.
        let ds: Vec<Vec6> = (0..n)
            .map(|a| if turns(model, k, a) { crm(&sc.s[k]) * sc.s[a] } else { Vec6::zeros() })
            .collect();
        let mut dv = vec![Vec6::zeros(); n];
        for a in 0..n {
            dv[a] = model.joints[a].parent.map_or(Vec6::zeros(), |p| dv[p]) + ds[a] * qd[a];
        }
        // Along q̇_k: the velocities of k's subtree gain S_k.
        let dv_qd: Vec<Vec6> = (0..n)
            .map(|a| if model.is_ancestor_or_self(k, a) { sc.s[k] } else { Vec6::zeros() })
            .collect();
        let mut at = 0;
        for (c, &(b, p, kind)) in points.iter().enumerate() {
            let a_b = body_acceleration(model, &sc, b, &qd, &qdd);
            let moves = model.is_ancestor_or_self(k, b);
            let mut da = Vec6::zeros();
            let mut da_qd = Vec6::zeros();
            for a in model.ancestors(b) {
                let e = moved(model, a);
                da += ds[a] * qdd[a] + (crm(&dv[e]) * sc.s[a] + crm(&sc.v[e]) * ds[a]) * qd[a];
                da_qd += crm(&dv_qd[e]) * sc.s[a] * qd[a];
            }
            if moves {
                da_qd += crm(&sc.v[moved(model, k)]) * sc.s[k];
            }
            let dp = if moves { lin(&sc.s[k]) + ang(&sc.s[k]).cross(&p) } else { Vector3::zeros() };
            let mut by_q = d_rows(kind, (&sc.v[b], &a_b, &p), (&dv[b], &da, &dp));
            let mut by_qd =
                d_rows(kind, (&sc.v[b], &a_b, &p), (&dv_qd[b], &da_qd, &Vector3::zeros()));
            if let Some((kp, kd, reference)) = corr.of(contacts, c) {
                let w = ang(&sc.v[b]);
                let dvp = lin(&dv[b]) + ang(&dv[b]).cross(&p) + w.cross(&dp);
                let dvp_qd = lin(&dv_qd[b]) + ang(&dv_qd[b]).cross(&p);
                match kind {
                    ContactKind::Point => {
                        for i in 0..3 {
                            by_q[i] += kd * dvp[i] + kp * dp[i];
                            by_qd[i] += kd * dvp_qd[i];
                        }
                    }
                    ContactKind::Wrench => {
                        // The frame turns by the screw's angular part where k moves it.
                        let turn = if moves { ang(&sc.s[k]) } else { Vector3::zeros() };
                        let rc = frame_rotation(model, &sc, &contacts[c]);
                        let (del, dew) = d_placement_error(&rc, &p, reference, &turn, &dp);
                        let (dw, dw_qd) = (ang(&dv[b]), ang(&dv_qd[b]));
                        for i in 0..3 {
                            by_q[i] += kd * dvp[i] - kp * del[i];
                            by_q[3 + i] += kd * dw[i] - kp * dew[i];
                            by_qd[i] += kd * dvp_qd[i];
                            by_qd[3 + i] += kd * dw_qd[i];
                        }
                    }
                }
            }
            for (r, (x, y)) in by_q.into_iter().zip(by_qd).enumerate() {
                dq[(at + r, col)] += m * x;
                dqd[(at + r, col)] += m * y;
            }
            at += kind.dim();
        }
    }
    (dq, dqd)
}

/// The KKT matrix `[M Jᵀ; J 0]`, LU-factorised.
fn kkt(
    model: &Model,
    contacts: &[Contact],
    q: &[f64],
) -> nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn> {
    let (nv, j) = (model.nv(), contact_jacobian(model, contacts, q));
    let nl = j.nrows();
    let mut k = DMatrix::zeros(nv + nl, nv + nl);
    k.view_mut((0, 0), (nv, nv)).copy_from(&crba(model, q));
    k.view_mut((0, nv), (nv, nl)).copy_from(&j.transpose());
    k.view_mut((nv, 0), (nl, nv)).copy_from(&j);
    k.lu()
}

/// Rigid-contact forward dynamics under `fext` (the model's external forces, as
/// [`External::fext`]; empty for none): q̈ and λ with every contact's acceleration zero.
/// `None` when the KKT system is singular (the contacts' Jacobian loses rank at q).
pub fn contact_fd(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
) -> Option<ContactDynamics> {
    contact_fd_with(model, q, qd, tau, gravity, fext, Baumgarte::NONE)
}

/// [`contact_fd`] with the contacts stabilised by `corr`.
pub fn contact_fd_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<ContactDynamics> {
    let contacts = &model.specialisation.contacts;
    let nv = model.nv();
    let bias = rnea_with(model, q, qd, &vec![0.0; nv], gravity, External { fext, lambda: &[] });
    let drift = corrected_accelerations(model, contacts, q, qd, &vec![0.0; nv], corr);
    let lu = kkt(model, contacts, q);
    let rhs = DVector::from_iterator(
        nv + drift.len(),
        (0..nv).map(|i| tau[i] - bias[i]).chain(drift.iter().map(|g| -g)),
    );
    let x = lu.solve(&rhs)?;
    Some(ContactDynamics {
        qdd: x.rows(0, nv).iter().copied().collect(),
        lambda: x.rows(nv, drift.len()).iter().map(|l| -l).collect(),
    })
}

/// [`contact_fd`] and its derivatives, fext held in the bodies' frames (as Pinocchio's
/// `computeABADerivatives` holds it).
pub fn contact_fd_derivatives(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
) -> Option<(ContactDynamics, ContactDerivatives)> {
    contact_fd_derivatives_with(model, q, qd, tau, gravity, fext, Baumgarte::NONE)
}

/// [`contact_fd_derivatives`] with the contacts stabilised by `corr` (its references held
/// fixed).
pub fn contact_fd_derivatives_with(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    tau: &[f64],
    gravity: [f64; 3],
    fext: &[f64],
    corr: Baumgarte,
) -> Option<(ContactDynamics, ContactDerivatives)> {
    let contacts = &model.specialisation.contacts;
    let nv = model.nv();
    let sol = contact_fd_with(model, q, qd, tau, gravity, fext, corr)?;
    let nl = sol.lambda.len();
    let (dc_dq, dc_dqd) = rnea_derivatives_with(
        model,
        q,
        qd,
        &sol.qdd,
        gravity,
        External { fext, lambda: &sol.lambda },
    );
    let (da_dq, da_dqd) =
        corrected_acceleration_derivatives(model, contacts, q, qd, &sol.qdd, corr);
    let lu = kkt(model, contacts, q);
    let solve = |top: DMatrix<f64>, bottom: DMatrix<f64>| -> Option<(DMatrix<f64>, DMatrix<f64>)> {
        let mut rhs = DMatrix::zeros(nv + nl, nv);
        rhs.rows_mut(0, nv).copy_from(&top);
        rhs.rows_mut(nv, nl).copy_from(&bottom);
        let x = lu.solve(&rhs)?;
        Some((x.rows(0, nv).into_owned(), -x.rows(nv, nl).into_owned()))
    };
    let (dqdd_dq, dlambda_dq) = solve(-dc_dq, -da_dq)?;
    let (dqdd_dqd, dlambda_dqd) = solve(-dc_dqd, -da_dqd)?;
    let (dqdd_dtau, dlambda_dtau) = solve(DMatrix::identity(nv, nv), DMatrix::zeros(nl, nv))?;
    Some((
        sol,
        ContactDerivatives { dqdd_dq, dqdd_dqd, dqdd_dtau, dlambda_dq, dlambda_dqd, dlambda_dtau },
    ))
}

/// Whether `contacts` constrain independent motions: the rank of their stacked Jacobian at a
/// few generic configurations. `Err` holds a smallest set of contacts (indices into
/// `contacts`) whose Jacobian loses rank at every configuration tried (two wrench contacts
/// on one body, a point contact on a body that moves in fewer than three directions).
pub fn check_contact_rank(model: &Model, contacts: &[Contact]) -> Result<(), Vec<usize>> {
    let full = |set: &[usize]| -> bool {
        let picked: Vec<Contact> = set.iter().map(|&i| contacts[i]).collect();
        let rows: usize = picked.iter().map(|c| c.kind.dim()).sum();
        (0..3).any(|seed| {
            let j = contact_jacobian(model, &picked, &generic_q(model, seed));
            let sv = j.singular_values();
            let top = sv.max();
            // Generic configurations put independent rows' singular values within a few
            // orders of magnitude of the largest; 1e-9 leaves rounding (1e-16) far below.
            top > 0.0 && sv.iter().filter(|&&s| s > 1e-9 * top).count() == rows
        })
    };
    let mut set: Vec<usize> = Vec::new();
    for i in 0..contacts.len() {
        set.push(i);
        if !full(&set) {
            // Drop every earlier contact that is not needed for the loss of rank.
            let mut at = 0;
            while at + 1 < set.len() {
                let mut fewer = set.clone();
                fewer.remove(at);
                if full(&fewer) {
                    at += 1;
                } else {
                    set = fewer;
                }
            }
            return Err(set);
        }
    }
    Ok(())
}

/// A deterministic configuration with no special angles: each scalar coordinate at an
/// irrational multiple of its index, quaternions of irrational angles.
fn generic_q(model: &Model, seed: usize) -> Vec<f64> {
    let v: Vec<f64> = (0..model.nv())
        .map(|k| (0.7 + 0.618_033_988_749_895 * (k + 7 * seed + 1) as f64).sin() * 1.3)
        .collect();
    super::integrate(model, &model.neutral_q(), &v)
}
