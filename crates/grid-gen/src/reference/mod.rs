//! Reference dynamics in f64: plain loops over links, written to be checked against the
//! literature line by line. This is the oracle for every generated backend, so it shares
//! nothing with them but the [`Model`].
//!
//! Notation follows Featherstone (2008): `X[i]` is `iXλ(i)`, the motion transform from
//! the parent body to body i at the current q; `S[i]` the joint's motion subspace.

mod aba;
mod contact;
pub mod coupled;
mod crba;
mod fd;
mod forces;
mod frames;
mod lie;
mod minv;
mod rnea;
mod rnea_derivatives;
mod step;

pub use aba::{aba, aba_with};
pub use contact::{
    check_contact_rank, contact_acceleration_derivatives, contact_accelerations, contact_fd,
    contact_fd_derivatives, contact_fd_derivatives_with, contact_fd_with, contact_jacobian,
    Baumgarte, ContactDerivatives, ContactDynamics,
};
pub use crba::crba;
pub use fd::{forward_dynamics, forward_dynamics_derivatives, forward_dynamics_derivatives_with};
pub use forces::{force_derivatives, External, ForceDerivatives};
pub use frames::{frame_classical_acceleration, frame_jacobian, frame_placement, frame_velocity};
pub use lie::{d_difference, difference};
pub use minv::minv;
pub use rnea::{rnea, rnea_with};
pub use rnea_derivatives::{rnea_derivatives, rnea_derivatives_with};
pub use step::{
    d_integrate, integrate, step, step_derivatives, step_derivatives_with, step_lambda,
    step_lambda_with, step_with, StepDerivatives,
};

use nalgebra::{Matrix3, Vector3};

use crate::model::{Joint, Model};
use crate::spatial::{axis_angle, crm, plux, quaternion_matrix, spatial_inertia, Mat6, Vec6};

pub use crate::model::DEFAULT_GRAVITY;
use crate::model::{JointIndex, QIndex};

/// The joint's motion subspace S (a unit twist) in its own frame.
pub fn motion_subspace(joint: &Joint) -> Vec6 {
    let a = Vector3::from(joint.axis);
    let mut s = Vec6::zeros();
    if joint.joint_type.is_rotation() {
        s.fixed_rows_mut::<3>(0).copy_from(&a);
    } else {
        s.fixed_rows_mut::<3>(3).copy_from(&a);
    }
    s
}

/// `iXλ(q_i) = X_J(q_i) X_T`: the tree transform, then the joint motion.
pub fn joint_transform(joint: &Joint, qi: f64) -> Mat6 {
    let x_tree = plux(&joint.tree.rot_matrix().transpose(), &joint.tree.pos_vector());
    let a = Vector3::from(joint.axis);
    let x_joint = if joint.joint_type.is_rotation() {
        plux(&axis_angle(&a, qi).transpose(), &Vector3::zeros())
    } else {
        plux(&Matrix3::identity(), &(a * qi))
    };
    x_joint * x_tree
}

/// Joint i's `iXλ(i)` at `q` (length nq): the first member of a multi-dof joint carries
/// its pose (`X_pose X_T`: the free-flyer's from q's position and quaternion, a spherical
/// joint's rotation from its quaternion) and every member is at its zero position (see
/// [`crate::model`]).
pub fn model_joint_transform(model: &Model, i: usize, q: &[f64]) -> Mat6 {
    let joint = &model.joints[i];
    match model.joint_q(JointIndex(i)) {
        Some((QIndex(k), m, o)) => joint_transform(joint, m * q[k] + o),
        None => match group_pose(model, i, q) {
            Some((r, p)) => plux(&r.transpose(), &p) * joint_transform(joint, 0.0),
            None => joint_transform(joint, 0.0),
        },
    }
}

/// The pose a multi-dof joint's first member `i` carries: the floating base's, or a
/// spherical joint's rotation; `None` for every other joint.
fn group_pose(model: &Model, i: usize, q: &[f64]) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let first = model.group(i).filter(|g| g.start == i)?;
    if model.is_free_flyer(first.start) {
        return Some(base_pose(q));
    }
    let k = model.group_q(JointIndex(i)).0;
    Some((quaternion_matrix([q[k], q[k + 1], q[k + 2], q[k + 3]]), Vector3::zeros()))
}

/// The velocity-product acceleration of joint i: `v_i × S_i q̇_i` (Featherstone 2008,
/// table 5.1), and for a multi-dof joint (see [`Model::group`]) `u × v_J` at its last
/// member only, u the parent's velocity in the joint frame (`xv` of its first member) and
/// v_J its members' `S q̇` together: zero at the root, where u = 0.
pub(crate) fn velocity_product(
    model: &Model,
    i: usize,
    k: &Kinematics,
    v: &[Vec6],
    xv: &[Vec6],
    qd: &[f64],
) -> Vec6 {
    match model.group(i) {
        None => crm(&v[i]) * (k.s[i] * qd[i]),
        Some(g) if i + 1 == g.end && model.joints[g.start].parent.is_some() => {
            let vj: Vec6 = g.clone().map(|m| k.s[m] * qd[m]).sum();
            crm(&xv[g.start]) * vj
        }
        Some(_) => Vec6::zeros(),
    }
}

/// The floating base's pose from q's first seven entries: the rotation of the normalised
/// quaternion `[qx, qy, qz, qw]` (base axes in the parent frame) and the position.
pub fn base_pose(q: &[f64]) -> (Matrix3<f64>, Vector3<f64>) {
    (quaternion_matrix([q[3], q[4], q[5], q[6]]), Vector3::new(q[0], q[1], q[2]))
}

/// The spatial inertia of body i in its own frame.
pub fn body_inertia(joint: &Joint) -> Mat6 {
    spatial_inertia(
        joint.inertia.mass,
        &Vector3::from(joint.inertia.h),
        &joint.inertia.i_origin_matrix(),
    )
}

/// Per-body transforms, subspaces and inertias at `q`.
pub(crate) struct Kinematics {
    pub x: Vec<Mat6>,
    pub s: Vec<Vec6>,
    pub inertia: Vec<Mat6>,
}

impl Kinematics {
    pub fn new(model: &Model, q: &[f64]) -> Self {
        Kinematics {
            x: (0..model.njoints()).map(|i| model_joint_transform(model, i, q)).collect(),
            s: model.joints.iter().map(motion_subspace).collect(),
            inertia: model.joints.iter().map(body_inertia).collect(),
        }
    }
}

/// The root's spatial acceleration that stands in for gravity: a_0 = -g.
pub(crate) fn root_acceleration(gravity: [f64; 3]) -> Vec6 {
    Vec6::new(0.0, 0.0, 0.0, -gravity[0], -gravity[1], -gravity[2])
}

/// Pose of every body frame (the child link frame of each movable joint) in the root
/// link's frame at `q`: the rotation (child axes in root coordinates) and the origin.
pub fn forward_kinematics(model: &Model, q: &[f64]) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
    let mut poses: Vec<(Matrix3<f64>, Vector3<f64>)> = Vec::with_capacity(model.njoints());
    for (i, joint) in model.joints.iter().enumerate() {
        let (r_parent, p_parent) = match joint.parent {
            Some(p) => poses[p],
            None => (Matrix3::identity(), Vector3::zeros()),
        };
        let Some((QIndex(k), m, o)) = model.joint_q(JointIndex(i)) else {
            // A multi-dof joint: the pose after the first member's origin, then at rest.
            let (r, p) = match group_pose(model, i, q) {
                Some((rb, pb)) => {
                    let (rt, pt) = (joint.tree.rot_matrix(), joint.tree.pos_vector());
                    (r_parent * rt * rb, p_parent + r_parent * (pt + rt * pb))
                }
                None => (r_parent, p_parent),
            };
            poses.push((r, p));
            continue;
        };
        let qi = m * q[k] + o;
        let a = Vector3::from(joint.axis);
        let (r_joint, p_joint) = if joint.joint_type.is_rotation() {
            (axis_angle(&a, qi), Vector3::zeros())
        } else {
            (Matrix3::identity(), a * qi)
        };
        let r_tree = joint.tree.rot_matrix();
        let p_tree = joint.tree.pos_vector();
        let r = r_parent * r_tree * r_joint;
        let p = p_parent + r_parent * (p_tree + r_tree * p_joint);
        poses.push((r, p));
    }
    poses
}
