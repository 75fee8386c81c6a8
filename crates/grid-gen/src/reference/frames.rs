//! Frame kinematics: where a link is, its Jacobian, its velocity and its classical
//! acceleration, in Pinocchio's conventions (`framesForwardKinematics`, `getFrameJacobian`,
//! `getFrameVelocity`, `getFrameClassicalAcceleration`): 6-vectors and Jacobian rows are
//! [linear; angular], in one of the three `ReferenceFrame`s.
//!
//! Two independent routes, so that each checks the other: the Jacobian from the joints'
//! world poses (each column a joint's screw axis), the velocity and acceleration from the
//! body-frame recursion of RNEA's forward pass with no gravity (Featherstone 2008, table 5.1).

use nalgebra::{DMatrix, Matrix3, Vector3};

use super::coupled::expand;
use super::{forward_kinematics, velocity_product, Kinematics};
use crate::model::JointIndex;
use crate::model::{Frame, Model, ReferenceFrame};
use crate::spatial::Vec6;

/// The frame's world placement at `q`: rotation (frame axes in world coordinates) and
/// translation.
pub fn frame_placement(model: &Model, q: &[f64], frame: &Frame) -> (Matrix3<f64>, Vector3<f64>) {
    let poses = forward_kinematics(model, q);
    placement_from(&poses, frame)
}

fn placement_from(
    poses: &[(Matrix3<f64>, Vector3<f64>)],
    frame: &Frame,
) -> (Matrix3<f64>, Vector3<f64>) {
    let (rb, pb) = frame.body.map_or((Matrix3::identity(), Vector3::zeros()), |b| poses[b]);
    (rb * frame.placement.rot_matrix(), pb + rb * frame.placement.pos_vector())
}

/// The frame Jacobian, 6 × nv, rows [linear; angular], columns per coordinate: the
/// world-frame screw of every joint on the path to the root, expressed in `rf`.
pub fn frame_jacobian(model: &Model, q: &[f64], frame: &Frame, rf: ReferenceFrame) -> DMatrix<f64> {
    let poses = forward_kinematics(model, q);
    let (r_f, p_f) = placement_from(&poses, frame);
    let mut j = DMatrix::zeros(6, model.nv());
    let Some(body) = frame.body else { return j };
    for a in model.ancestors(body) {
        let joint = &model.joints[a];
        let (r, p) = poses[a];
        let axis = r * Vector3::from(joint.axis);
        // The joint's unit motion as a spatial velocity at the world origin: [v_O; ω].
        let (v_o, w) = if joint.joint_type.is_rotation() {
            (p.cross(&axis), axis)
        } else {
            (axis, Vector3::zeros())
        };
        let (lin, ang) = express(rf, &r_f, &p_f, v_o, w);
        let k = model.coordinate_of(JointIndex(a)).0;
        let m = model.multiplier(a);
        for r in 0..3 {
            j[(r, k)] += m * lin[r];
            j[(r + 3, k)] += m * ang[r];
        }
    }
    j
}

/// A spatial motion given at the world origin in world axes, `[v_O; ω]`, expressed in `rf`
/// for the frame at `(r_f, p_f)`: the velocity of the point at the frame's origin is
/// `v_O + ω × p_f`.
fn express(
    rf: ReferenceFrame,
    r_f: &Matrix3<f64>,
    p_f: &Vector3<f64>,
    v_o: Vector3<f64>,
    w: Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    match rf {
        ReferenceFrame::World => (v_o, w),
        ReferenceFrame::LocalWorldAligned => (v_o + w.cross(p_f), w),
        ReferenceFrame::Local => (r_f.transpose() * (v_o + w.cross(p_f)), r_f.transpose() * w),
    }
}

/// Every body's velocity and acceleration in its own frame, [angular; linear], with no
/// gravity: RNEA's forward pass.
fn body_motion(model: &Model, q: &[f64], qd: &[f64], qdd: &[f64]) -> (Vec<Vec6>, Vec<Vec6>) {
    let (qd, qdd) = (expand(model, qd), expand(model, qdd));
    let n = model.njoints();
    let k = Kinematics::new(model, q);
    let (mut v, mut a, mut xv) =
        (vec![Vec6::zeros(); n], vec![Vec6::zeros(); n], vec![Vec6::zeros(); n]);
    for i in 0..n {
        let (vp, ap) =
            model.joints[i].parent.map_or((Vec6::zeros(), Vec6::zeros()), |p| (v[p], a[p]));
        xv[i] = k.x[i] * vp;
        v[i] = xv[i] + k.s[i] * qd[i];
        a[i] = k.x[i] * ap + k.s[i] * qdd[i] + velocity_product(model, i, &k, &v, &xv, &qd);
    }
    (v, a)
}

/// A body's motion [angular; linear] in its frame, moved to the frame fixed in it: in the
/// frame's axes, at the frame's origin.
fn to_frame(frame: &Frame, m: &Vec6) -> (Vector3<f64>, Vector3<f64>) {
    let (r, p) = (frame.placement.rot_matrix(), frame.placement.pos_vector());
    let w = Vector3::new(m[0], m[1], m[2]);
    let l = Vector3::new(m[3], m[4], m[5]);
    (r.transpose() * (l + w.cross(&p)), r.transpose() * w)
}

/// The frame's LOCAL velocity and spatial acceleration (each `(linear, angular)`) and its
/// world placement.
#[allow(clippy::type_complexity)]
fn local_motion(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    frame: &Frame,
) -> ((Vector3<f64>, Vector3<f64>), (Vector3<f64>, Vector3<f64>), (Matrix3<f64>, Vector3<f64>)) {
    let (v, a) = body_motion(model, q, qd, qdd);
    let zero = (Vector3::zeros(), Vector3::zeros());
    let (vf, af) = match frame.body {
        Some(b) => (to_frame(frame, &v[b]), to_frame(frame, &a[b])),
        None => (zero, zero),
    };
    (vf, af, frame_placement(model, q, frame))
}

/// A LOCAL motion `(linear, angular)` of the frame at `(r, p)` expressed in `rf`.
fn from_local(
    rf: ReferenceFrame,
    r: &Matrix3<f64>,
    p: &Vector3<f64>,
    (l, w): (Vector3<f64>, Vector3<f64>),
) -> (Vector3<f64>, Vector3<f64>) {
    match rf {
        ReferenceFrame::Local => (l, w),
        ReferenceFrame::LocalWorldAligned => (r * l, r * w),
        ReferenceFrame::World => (r * l + p.cross(&(r * w)), r * w),
    }
}

/// The frame's spatial velocity in `rf`, `[linear; angular]` (Pinocchio's `getFrameVelocity`).
pub fn frame_velocity(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    frame: &Frame,
    rf: ReferenceFrame,
) -> [f64; 6] {
    let zero = vec![0.0; model.nv()];
    let (vf, _, (r, p)) = local_motion(model, q, qd, &zero, frame);
    let (l, w) = from_local(rf, &r, &p, vf);
    [l[0], l[1], l[2], w[0], w[1], w[2]]
}

/// The frame's classical acceleration in `rf` (Pinocchio's `getFrameClassicalAcceleration`):
/// the spatial acceleration's linear part plus `ω × v`, both in `rf`. In `LOCAL` and
/// `LOCAL_WORLD_ALIGNED` that is the acceleration of the frame's origin; in `WORLD`, that of
/// the body point at the world's origin. At q̈ = 0 it is the drift `J̇ q̇`.
pub fn frame_classical_acceleration(
    model: &Model,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    frame: &Frame,
    rf: ReferenceFrame,
) -> [f64; 3] {
    let (vf, af, (r, p)) = local_motion(model, q, qd, qdd, frame);
    let (vl, vw) = from_local(rf, &r, &p, vf);
    let (al, _) = from_local(rf, &r, &p, af);
    let c = al + vw.cross(&vl);
    [c[0], c[1], c[2]]
}
