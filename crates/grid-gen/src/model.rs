//! The robot model every later stage reads: movable joints in topological order, their
//! tree transforms, axes and lumped spatial inertias, tree levels and sparsity masks.
//!
//! Order: a depth-first pre-order walk from the root link, visiting each link's child
//! joints in document order. Fixed joints are merged into their parent body. Pre-order
//! makes every subtree a contiguous range of joint indices (`subtree_end`), which the
//! M⁻¹ recursion and the emitters rely on.
//!
//! A floating base is six model joints at the front, [`FREE_FLYER`]: three
//! prismatic and three revolute joints along the base's own axes, massless but the last,
//! which carries the root link. Held at their zero position, their motion subspaces are
//! the columns of the identity in the base frame, so their velocities are Pinocchio's
//! free-flyer velocity (linear, then angular, in the base frame) and derivatives taken
//! along them are Pinocchio's tangent-space derivatives (`q ⊕ ε = q · exp(ε)`, first
//! order). The base's pose comes from q's first seven entries (position, quaternion) and
//! enters as the first of them's joint transform.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use serde::Serialize;

use crate::diagnostic::Diagnostic;
use crate::spatial::{axis_angle, rpy_matrix};
/// What a scene's `round_angles` changed (the URDF front end rounds; the model records it).
pub use crate::urdf::RoundedAngles;
use crate::urdf::{self, JointKind, Pose, Tree, Urdf};

/// How far from 1 the norm of a quaternion (a floating base's, a spherical joint's) may be. Within
/// it, the quaternion is used normalised (the kernels and the reference rotate by q/|q|, which is
/// exact for any nonzero q); beyond it, it is an error, since a quaternion that far from unit is a
/// wrong layout or an uninitialised state rather than drift (f32 storage and integrators drift by
/// ~1e-7 per step).
pub const QUATERNION_TOLERANCE: f64 = 1e-3;

/// Gravity used when none is given: (0, 0, -9.81) m/s² in the root frame. Every default
/// gravity in grid-gen (reference, IR, generation, CLI) is this constant.
pub const DEFAULT_GRAVITY: [f64; 3] = [0.0, 0.0, -9.81];

/// A model joint: one degree of freedom, the index of `Model::joints` and of the body it
/// moves (the free-flyer and each spherical joint are several, see [`Model::group`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct JointIndex(pub usize);

/// A coordinate: an entry of q̇, q̈ and τ and a row of every matrix the kernels return;
/// one per model joint that is not a coupled mimic ([`Model::coordinate_joints`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CoordIndex(pub usize);

/// An entry of q, where a quaternion takes four entries for three coordinates
/// (Pinocchio's `idx_q`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct QIndex(pub usize);

/// A rigid transform: `rot` holds the child frame's axes in parent coordinates and `pos`
/// its origin in parent coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub rot: [[f64; 3]; 3],
    pub pos: [f64; 3],
}

impl Transform {
    pub fn identity() -> Self {
        Transform { rot: Matrix3::identity().into(), pos: [0.0; 3] }
    }

    fn from_pose(p: &Pose) -> Self {
        Transform::from_parts(rpy_matrix(p.rpy), Vector3::from(p.xyz))
    }

    pub fn rot_matrix(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.rot[i][j])
    }

    pub fn pos_vector(&self) -> Vector3<f64> {
        Vector3::from(self.pos)
    }

    fn from_parts(r: Matrix3<f64>, p: Vector3<f64>) -> Self {
        Transform {
            rot: std::array::from_fn(|i| std::array::from_fn(|j| r[(i, j)])),
            pos: p.into(),
        }
    }

    /// `self * other`: `other` is expressed in `self`'s child frame.
    fn compose(&self, other: &Transform) -> Transform {
        let r = self.rot_matrix();
        Transform::from_parts(r * other.rot_matrix(), r * other.pos_vector() + self.pos_vector())
    }
}

/// Rigid-body inertia about a body frame's origin, in that frame: additive, so fixed
/// children are lumped by summing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Inertia {
    pub mass: f64,
    /// First moment of mass, `mass * com`.
    pub h: [f64; 3],
    /// Rotational inertia about the frame origin (row-major, symmetric).
    pub i_origin: [[f64; 3]; 3],
}

/// A body's spatial inertia about its frame's origin, for twists ordered (linear,
/// angular): twice the kinetic energy is m|v|² + 2 vᵀ(ω × h) + ωᵀ I ω.
fn spatial_inertia(b: &Inertia) -> nalgebra::DMatrix<f64> {
    let h = Vector3::from(b.h);
    let mut a = nalgebra::DMatrix::<f64>::zeros(6, 6);
    for k in 0..3 {
        a[(k, k)] = b.mass;
    }
    a.view_mut((0, 3), (3, 3)).copy_from(&(-h.cross_matrix()));
    a.view_mut((3, 0), (3, 3)).copy_from(&h.cross_matrix());
    a.view_mut((3, 3), (3, 3)).copy_from(&b.i_origin_matrix());
    a
}

impl Inertia {
    pub fn zero() -> Self {
        Inertia { mass: 0.0, h: [0.0; 3], i_origin: [[0.0; 3]; 3] }
    }

    fn add(&mut self, o: &Inertia) {
        self.mass += o.mass;
        for k in 0..3 {
            self.h[k] += o.h[k];
            for l in 0..3 {
                self.i_origin[k][l] += o.i_origin[k][l];
            }
        }
    }

    pub fn i_origin_matrix(&self) -> Matrix3<f64> {
        Matrix3::from_fn(|i, j| self.i_origin[i][j])
    }
}

/// The free-flyer's six coordinates, in Pinocchio's velocity order (`JointModelFreeFlyer`:
/// linear velocity, then angular velocity, both in the base frame): the suffix each
/// model joint's name gets, its type and its axis.
pub const FREE_FLYER: [(&str, JointType, [f64; 3]); 6] = [
    ("vx", JointType::Prismatic, [1.0, 0.0, 0.0]),
    ("vy", JointType::Prismatic, [0.0, 1.0, 0.0]),
    ("vz", JointType::Prismatic, [0.0, 0.0, 1.0]),
    ("wx", JointType::Continuous, [1.0, 0.0, 0.0]),
    ("wy", JointType::Continuous, [0.0, 1.0, 0.0]),
    ("wz", JointType::Continuous, [0.0, 0.0, 1.0]),
];

/// A spherical joint's three coordinates (Pinocchio's `JointModelSpherical`: the angular
/// velocity in the child frame): the suffix each model joint's name gets and its axis.
pub const SPHERICAL: [(&str, [f64; 3]); 3] =
    [("wx", [1.0, 0.0, 0.0]), ("wy", [0.0, 1.0, 0.0]), ("wz", [0.0, 0.0, 1.0])];

/// The free-flyer's name when `--floating-base` adds it (Pinocchio's name for the root
/// joint `buildModelFromUrdf` adds).
pub const ROOT_JOINT: &str = "root_joint";

/// Movable joint types after validation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JointType {
    Revolute,
    Continuous,
    Prismatic,
}

impl JointType {
    pub fn as_str(self) -> &'static str {
        match self {
            JointType::Revolute => "revolute",
            JointType::Continuous => "continuous",
            JointType::Prismatic => "prismatic",
        }
    }

    /// Revolute and continuous joints rotate; prismatic joints translate.
    pub fn is_rotation(self) -> bool {
        !matches!(self, JointType::Prismatic)
    }
}

/// One movable joint and the body it carries.
#[derive(Clone, Debug, PartialEq)]
pub struct Joint {
    pub name: String,
    pub joint_type: JointType,
    /// Index of the parent joint, `None` when the parent body is the fixed root.
    pub parent: Option<usize>,
    /// Pose of the joint frame (at q = 0) in the parent body's frame.
    pub tree: Transform,
    /// Unit axis in the joint frame.
    pub axis: [f64; 3],
    /// Inertia of the body this joint moves, with fixed children lumped in, in the joint frame.
    pub inertia: Inertia,
    /// Depth in the tree (children of the root are at level 0).
    pub level: usize,
    /// One past the last joint of this joint's subtree (pre-order makes it a range).
    pub subtree_end: usize,
    /// `(lower, upper)` from `<limit>`, if present.
    pub limit: Option<(f64, f64)>,
    /// `<limit velocity>` (rad/s or m/s), when given and positive.
    pub velocity_limit: Option<f64>,
    /// `<dynamics>` damping and friction (not part of the rigid-body terms).
    pub damping: f64,
    pub friction: f64,
    /// `<mimic>`: (joint, multiplier, offset). An independent joint unless the model
    /// couples mimic joints ([`Model::coupling`]).
    pub mimic: Option<(String, f64, f64)>,
}

/// A mimic joint modelled as coupled (`--mimic coupled`): its position is
/// `multiplier · q_of + offset`, its velocity and acceleration `multiplier` times those
/// of joint `of`, and it has no coordinate of its own (Pinocchio's `JointModelMimic`,
/// `buildModelFromUrdf(..., mimic=True)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coupling {
    /// The model joint it follows, never itself coupled (chains are composed).
    pub of: usize,
    pub multiplier: f64,
    pub offset: f64,
}

/// A fixed-base robot ready for the dynamics.
#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    pub name: String,
    /// The URDF's file name without folders (empty when it came from no file); generated
    /// headers name it.
    pub source: String,
    /// When M is singular (a joint moves no inertia), that joint's name: the kernels that
    /// need M⁻¹ (`minv`, `fd`, `fd_grad`) are not generated or evaluated; the rest are.
    pub singular: Option<String>,
    pub root_link: String,
    pub joints: Vec<Joint>,
    /// A floating base: `joints[..6]` are the free-flyer ([`FREE_FLYER`]) and q is
    /// `[x, y, z, qx, qy, qz, qw, joints[6..]…]` (nq = nv + 1, Pinocchio's layout).
    pub floating: bool,
    /// Spherical joints: the first of the three model joints each one
    /// is ([`SPHERICAL`], like the free-flyer's six: revolute about the joint frame's
    /// axes, held at zero, the first carrying the quaternion's rotation). In model order.
    pub spherical: Vec<JointIndex>,
    /// For each joint, whether it is a coupled mimic joint (`--mimic coupled`); empty when
    /// no joint is coupled (`build` never leaves it all `None`). A coupled joint has
    /// no coordinate: q, q̇, q̈, τ and the matrices have one entry per *coordinate*, the
    /// joints that are not coupled, in model order ([`Model::coordinate_joints`]).
    pub coupling: Vec<Option<Coupling>>,
    /// Every URDF link the model keeps, as a named frame of the body that carries it, in
    /// the order the model walks them (depth-first from the root, children in document order).
    pub frames: Vec<Frame>,
    /// What a scene fixes about the state and the outputs (default: nothing).
    pub specialisation: Specialisation,
    /// The `<origin rpy>` angles a scene's `round_angles` read as multiples of π/2.
    pub rounded_angles: Option<RoundedAngles>,
}

/// A URDF link as a frame: the moving body it is fixed in (after fixed and locked joints
/// are merged) and its constant placement there. Pinocchio's `BODY` frames of
/// `buildModelFromUrdf` are the same frames, named after the links.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// The link's name.
    pub name: String,
    /// The model joint whose body carries the link; `None` for the fixed root body
    /// (Pinocchio's `universe`).
    pub body: Option<usize>,
    /// The link frame in the body's (joint's) frame.
    pub placement: Transform,
}

/// The axes and reference point a frame quantity is expressed in
/// (`pinocchio::ReferenceFrame`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum ReferenceFrame {
    /// The frame's own axes, at its origin.
    Local,
    /// The world's axes, at the world's origin (a spatial quantity of the body).
    World,
    /// The world's axes, at the frame's origin: what position costs and point contacts use.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "local_world_aligned"))]
    LocalWorldAligned,
}

impl ReferenceFrame {
    pub const ALL: [ReferenceFrame; 3] =
        [ReferenceFrame::Local, ReferenceFrame::World, ReferenceFrame::LocalWorldAligned];

    pub fn name(self) -> &'static str {
        match self {
            ReferenceFrame::Local => "local",
            ReferenceFrame::World => "world",
            ReferenceFrame::LocalWorldAligned => "local_world_aligned",
        }
    }

    pub fn parse(name: &str) -> Option<ReferenceFrame> {
        ReferenceFrame::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// How the step kernels integrate one time step (Crocoddyl's integrated action models).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Scheme {
    /// Symplectic Euler, Crocoddyl's default: `qd+ = qd + dt qdd`, `q+ = q ⊕ dt qd+`.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "semi_implicit_euler"))]
    SemiImplicitEuler,
    /// `qd+ = qd + dt qdd`, `q+ = q ⊕ dt qd`.
    #[cfg_attr(feature = "clap", value(name = "explicit_euler"))]
    ExplicitEuler,
    /// Classical Runge-Kutta on the manifold, as Crocoddyl's `IntegratedActionModelRK4`:
    /// four stages `k_i = (qd_i, qdd_i)` at `x ⊕ c_i dt k_(i-1)`, then
    /// `x+ = x ⊕ dt (k_1 + 2 k_2 + 2 k_3 + k_4) / 6`.
    Rk4,
}

impl Scheme {
    pub const ALL: [Scheme; 3] = [Scheme::SemiImplicitEuler, Scheme::ExplicitEuler, Scheme::Rk4];

    pub fn name(self) -> &'static str {
        match self {
            Scheme::SemiImplicitEuler => "semi_implicit_euler",
            Scheme::ExplicitEuler => "explicit_euler",
            Scheme::Rk4 => "rk4",
        }
    }

    pub fn parse(name: &str) -> Option<Scheme> {
        Scheme::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// One discrete step: the scheme and the time step (what the reference integrates).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Step {
    pub scheme: Scheme,
    /// Seconds; finite and positive.
    pub dt: f64,
}

/// The step kernels a model is specialised for: the scheme, and the time step either folded
/// into the kernels as a constant or left to run time, where `step` and `step_grad` take it
/// as their last input (`dt`, one value per state), so that one library serves a horizon
/// whose knots have different time steps.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StepSpec {
    pub scheme: Scheme,
    /// Seconds, finite and positive, folded into the kernels; `None`: an input.
    pub dt: Option<f64>,
}

impl StepSpec {
    /// A step with a folded time step.
    pub fn folded(scheme: Scheme, dt: f64) -> StepSpec {
        StepSpec { scheme, dt: Some(dt) }
    }

    /// A step whose time step the kernels take at run time.
    pub fn at_run_time(scheme: Scheme) -> StepSpec {
        StepSpec { scheme, dt: None }
    }

    /// The step these kernels take at a state whose run-time time step is `dt` (ignored when
    /// the time step is folded: the kernels then take no `dt`).
    pub fn at(self, dt: f64) -> Step {
        Step { scheme: self.scheme, dt: self.dt.unwrap_or(dt) }
    }

    /// Whether the kernels take `dt` as an input.
    pub fn runtime_dt(self) -> bool {
        self.dt.is_none()
    }
}

/// One block of the configuration space, as Pinocchio's joints integrate it: a scalar
/// coordinate adds, a free-flyer moves on SE(3) and a spherical joint on SO(3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LieBlock {
    /// Coordinate `v` (one entry of q̇) at q's entry `q`.
    Scalar { v: usize, q: usize },
    /// The free-flyer: q̇'s entries `0..6` (linear then angular, local), q's `0..7`
    /// (position, then the quaternion `[x, y, z, w]`).
    FreeFlyer,
    /// A spherical joint: q̇'s entries `v..v + 3`, its quaternion at q's `q..q + 4`.
    Spherical { v: usize, q: usize },
}

/// What a scene fixes beyond the robot itself: lowering reads it, so
/// the kernels of every backend shrink with it while keeping their signatures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Specialisation {
    /// `static = true`: q̇ = 0 is known. Every kernel ignores its `qd` argument (the
    /// velocity terms are folded away), and `eval` refuses a state whose q̇ is not 0.
    pub static_velocity: bool,
    /// Rows of the gradient matrices (`dc_dq`, `dc_dqd`, `dqdd_dq`, `dqdd_dqd`) that are
    /// computed, as coordinate indices (model joint indices unless mimic joints are coupled);
    /// every other row is written as 0. `None`: all.
    pub rows: Option<Vec<usize>>,
    /// Columns of the gradient matrices that are computed, as rows are. `None`: all.
    pub columns: Option<Vec<usize>>,
    /// The frames the frame kernels compute, as indices into [`Model::frames`], in the
    /// order asked for. Empty: no frame kernels.
    pub frames: Vec<usize>,
    /// The reference frame of the frame kernels' Jacobian, velocity and acceleration.
    pub reference: ReferenceFrame,
    /// The step the step kernels take; `None`: no step kernels.
    pub step: Option<StepSpec>,
    /// The actuated coordinates (the columns of the step's B and the entries of its τ), in
    /// coordinate order. `None`: every coordinate but a floating base's six.
    pub actuated: Option<Vec<usize>>,
    /// `fd_grad` also returns `∂q̈/∂τ = M⁻¹` (`dqdd_dtau`), for users who integrate
    /// themselves.
    pub fd_grad_minv: bool,
    /// The bodies that take an external force (the dynamics kernels' `fext` input), as
    /// model joints (a multi-dof joint's last member, the one that carries its body), in
    /// the order asked for. Empty: no `fext` input.
    pub fext: Vec<usize>,
    /// `rnea_grad` and `fd_grad` do not return `∂/∂fext` (they do by default): a kernel
    /// that only feels known forces (a disturbance, a payload's push) then pays for the
    /// forces alone, not for `−M⁻¹ Jᵀ` on every force column.
    pub no_fext_derivatives: bool,
    /// The contacts whose forces λ the dynamics kernels take (their `lambda` input), in the
    /// order declared. Empty: no `lambda` input.
    pub contacts: Vec<Contact>,
    /// The contacts are candidates chosen per state: the kernels that solve for their forces
    /// take `active` (one 0 or 1 per contact); an inactive contact has λ = 0 and no
    /// constraint row, so one library serves every contact mode of a gait.
    pub contact_mask: bool,
    /// The contacts are stabilised as Pinocchio's Baumgarte corrector: the kernels that solve
    /// for their forces take `gains` (Kp, Kd per contact) and `contact_ref` (a world position
    /// per contact), and drive each contact's acceleration to `−Kd v − Kp (p − p_ref)`.
    /// Point contacts only.
    pub baumgarte: bool,
}

/// A contact at a frame: the force λ the environment applies there, in
/// `LOCAL_WORLD_ALIGNED` axes at the frame's origin (Crocoddyl's and GRiD's contact
/// forces; Pinocchio's `CONTACT_3D` / `CONTACT_6D`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Contact {
    /// Index into [`Model::frames`]; never a frame of the fixed root.
    pub frame: usize,
    pub kind: ContactKind,
}

/// What a contact transmits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactKind {
    /// A 3-D force at the frame's origin.
    Point,
    /// A 6-D wrench `[force; torque]` (Pinocchio's order) at the frame's origin.
    Wrench,
}

impl ContactKind {
    pub const ALL: [ContactKind; 2] = [ContactKind::Point, ContactKind::Wrench];

    pub fn name(self) -> &'static str {
        match self {
            ContactKind::Point => "point",
            ContactKind::Wrench => "wrench",
        }
    }

    pub fn parse(name: &str) -> Option<ContactKind> {
        ContactKind::ALL.into_iter().find(|k| k.name() == name)
    }

    /// Entries of a Baumgarte reference (`contact_ref`): a point's world position, a
    /// wrench's world placement as position and quaternion `[x, y, z, qx, qy, qz, qw]`.
    pub fn ref_dim(self) -> usize {
        match self {
            ContactKind::Point => 3,
            ContactKind::Wrench => 7,
        }
    }

    /// Entries of λ.
    pub fn dim(self) -> usize {
        match self {
            ContactKind::Point => 3,
            ContactKind::Wrench => 6,
        }
    }
}

impl Specialisation {
    /// Whether entry `(i, j)` of a gradient matrix is computed.
    pub fn keeps(&self, i: usize, j: usize) -> bool {
        self.rows.as_ref().is_none_or(|r| r.contains(&i))
            && self.columns.as_ref().is_none_or(|c| c.contains(&j))
    }

    /// Whether some gradient entries are not computed.
    pub fn selects(&self) -> bool {
        self.rows.is_some() || self.columns.is_some()
    }

    /// Contacts with Baumgarte gains ([`Self::baumgarte`]): every contact, else none.
    pub fn baumgarte_len(&self) -> usize {
        if self.baumgarte {
            self.contacts.len()
        } else {
            0
        }
    }

    /// Entries of `contact_ref` ([`ContactKind::ref_dim`] per contact) when the contacts
    /// are stabilised, else none.
    pub fn contact_ref_len(&self) -> usize {
        if self.baumgarte {
            self.contacts.iter().map(|c| c.kind.ref_dim()).sum()
        } else {
            0
        }
    }

    /// Where contact `c`'s entries of `contact_ref` start.
    pub fn contact_ref_at(&self, c: usize) -> usize {
        self.contacts[..c].iter().map(|c| c.kind.ref_dim()).sum()
    }

    /// Entries of the contact mask `active`: one per contact when the contacts are
    /// masked ([`Self::contact_mask`]), else none.
    pub fn active_len(&self) -> usize {
        if self.contact_mask {
            self.contacts.len()
        } else {
            0
        }
    }
}

/// How many entries of an `nv x nv` matrix are not structurally zero.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct Count {
    pub nonzero: usize,
    pub total: usize,
}

impl Model {
    /// This model holding just the contacts `active` marks (one flag per contact of
    /// [`Specialisation::contacts`]), unmasked: what a masked model computes in that
    /// contact mode, as Pinocchio holding just those contacts.
    pub fn holding_contacts(&self, active: &[bool]) -> Model {
        let mut held = self.clone();
        let spec = &mut held.specialisation;
        let mut flags = active.iter();
        spec.contacts.retain(|_| flags.next().copied().unwrap_or(true));
        spec.contact_mask = false;
        held
    }

    /// Degrees of freedom: entries of q̇, q̈ and τ (the model's joints less the coupled
    /// mimic joints).
    pub fn nv(&self) -> usize {
        self.joints.len() - self.coupling.iter().filter(|c| c.is_some()).count()
    }

    /// Model joints (bodies), coupled mimic joints included: what the algorithms loop over.
    pub fn njoints(&self) -> usize {
        self.joints.len()
    }

    /// Entries of q: nv, plus one for a floating base and one per spherical joint (a
    /// quaternion for three angles).
    /// The actuated coordinates, in coordinate order ([`Specialisation::actuated`]).
    pub fn actuated(&self) -> Vec<usize> {
        match &self.specialisation.actuated {
            Some(a) => a.clone(),
            None => (0..self.nv()).filter(|&k| !(self.floating && k < FREE_FLYER.len())).collect(),
        }
    }

    /// Entries of the step kernels' τ: the actuated coordinates.
    pub fn nu(&self) -> usize {
        self.actuated().len()
    }

    /// Bodies that take an external force ([`Specialisation::fext`]).
    pub fn nfext(&self) -> usize {
        self.specialisation.fext.len()
    }

    /// Entries of the contact forces λ: 3 per point contact, 6 per wrench.
    pub fn nlambda(&self) -> usize {
        self.specialisation.contacts.iter().map(|c| c.kind.dim()).sum()
    }

    /// The body moved by the joint named `name` as Pinocchio names joints (`root_joint`
    /// for a floating base, a spherical joint's own name): for a multi-dof joint its last
    /// member, which carries the body.
    pub fn body_of_joint(&self, name: &str) -> Option<usize> {
        (0..self.njoints())
            .find(|&i| self.group(i).is_none_or(|g| i + 1 == g.end) && self.joint_name(i) == name)
    }

    /// The names [`Model::body_of_joint`] knows, in model order.
    pub fn body_joint_names(&self) -> Vec<&str> {
        (0..self.njoints())
            .filter(|&i| self.group(i).is_none_or(|g| i + 1 == g.end))
            .map(|i| self.joint_name(i))
            .collect()
    }

    /// The configuration space's blocks, in coordinate order: how `integrate` and its
    /// derivatives act on q and the tangent space.
    pub fn lie_blocks(&self) -> Vec<LieBlock> {
        let joints = self.coordinate_joints();
        let mut blocks = Vec::new();
        let mut k = 0;
        while k < joints.len() {
            let j = joints[k].0;
            match self.group(j) {
                Some(_) if self.is_free_flyer(j) => {
                    blocks.push(LieBlock::FreeFlyer);
                    k += FREE_FLYER.len();
                }
                Some(m) => {
                    blocks
                        .push(LieBlock::Spherical { v: k, q: self.group_q(JointIndex(m.start)).0 });
                    k += SPHERICAL.len();
                }
                None => {
                    blocks.push(LieBlock::Scalar {
                        v: k,
                        q: self
                            .q_index(CoordIndex(k))
                            .expect("a one-dof coordinate has a q entry")
                            .0,
                    });
                    k += 1;
                }
            }
        }
        blocks
    }

    /// The joint at `i`.
    pub fn joint(&self, i: JointIndex) -> &Joint {
        &self.joints[i.0]
    }

    pub fn nq(&self) -> usize {
        self.nv() + usize::from(self.floating) + self.spherical.len()
    }

    /// The model joints of the multi-dof joint that joint `i` is part of: the free-flyer's
    /// six, or a spherical joint's three. The algorithms treat each as one joint
    /// (Pinocchio's `JointModelFreeFlyer` / `JointModelSpherical`), not as a chain of
    /// one-dof joints: the chain's velocity-product terms `v × S q̇` between its members
    /// belong to another parametrisation (Euler-angle rates), and so do its derivatives.
    /// What replaces them, with `u = X v_parent` the parent's velocity in the joint frame
    /// and `v_J` the joint's own velocity: one velocity product `u × v_J` at the last member
    /// (zero at the root, where u = 0); in the gradients, every member sees the parent's
    /// velocity and acceleration (not its predecessor's in the chain), the last member's
    /// ∂a/∂q̇ over all members' columns, and no `S ×* f` term between members.
    pub fn group(&self, i: usize) -> Option<std::ops::Range<usize>> {
        if self.is_free_flyer(i) {
            return Some(0..FREE_FLYER.len());
        }
        self.spherical
            .iter()
            .find(|&&JointIndex(s)| s <= i && i < s + SPHERICAL.len())
            .map(|&JointIndex(s)| s..s + SPHERICAL.len())
    }

    /// A lower bound on the pivot D of M's LTDL factorisation at each coordinate, for
    /// every configuration: D is `Sᵀ Iᴬ S` of the articulated inertia Iᴬ ⪰ I (the body's
    /// own inertia: the articulated inertias of its children add positive semidefinite
    /// terms, Featherstone's RBDA §7.3), so D ≥ `Sᵀ I S` for a one-dof joint; a member of a
    /// free-flyer or spherical joint pivots on a Schur complement of that joint's `Sᵀ Iᴬ S`,
    /// which is at least its smallest eigenvalue, so the members share
    /// λ_min(Sᵀ I S) of the joint's body (the last member's). Empty when a joint is
    /// coupled (M is then a projection, with no such pivots). Zero where the body has no
    /// inertia along its joint.
    pub fn pivot_floor(&self) -> Vec<f64> {
        if !self.coupling.is_empty() {
            return Vec::new();
        }
        (0..self.njoints())
            .map(|i| {
                let members = self.group(i).unwrap_or(i..i + 1);
                let a = spatial_inertia(&self.joints[members.end - 1].inertia);
                let s = self.motion_subspace(members);
                let block = s.transpose() * a * &s;
                block.symmetric_eigenvalues().min().max(0.0)
            })
            .collect()
    }

    /// A lower bound on 1 / M⁻¹ᵢᵢ at each coordinate, for every configuration (so M⁻¹ᵢᵢ
    /// is at most its reciprocal). 1 / M⁻¹ᵢᵢ is the least kinetic energy (times two) of a
    /// motion with q̇ᵢ = 1: at least that of the joint's body and its parent body alone,
    /// with the parent's velocity u relaxed to any twist, min_u uᵀ A u + (u + S)ᵀ B (u + S)
    /// ≥ 1 / (1/λ_min(A) + 1/λ_min(B)) for |S| = 1, where A is the parent's inertia moved
    /// into the joint frame (a rotation about the joint's axis leaves its eigenvalues
    /// unchanged) and B the body's. Under the fixed root the parent does not move: the
    /// bound is [`Model::pivot_floor`]. Zero (no bound) where a body's spatial inertia is not
    /// positive definite (none, or a physically implausible `<inertia>`, as GRiD's Atlas
    /// gives `utorso`), and for a prismatic joint under a moving body (its translation
    /// changes A's eigenvalues).
    /// Empty when a joint is coupled.
    pub fn minv_floor(&self) -> Vec<f64> {
        let floor = self.pivot_floor();
        if floor.is_empty() {
            return floor;
        }
        (0..self.njoints())
            .map(|i| {
                let members = self.group(i).unwrap_or(i..i + 1);
                let first = &self.joints[members.start];
                let Some(p) = first.parent else { return floor[i] };
                if !first.joint_type.is_rotation() {
                    return 0.0;
                }
                let b = spatial_inertia(&self.joints[members.end - 1].inertia);
                // Twists of the parent body (its frame) in the joint frame: (v, ω) ↦
                // (Rᵀ(v + ω × p), Rᵀ ω) for the joint frame at (R, p) in the parent's.
                let (r, pos) = (first.tree.rot_matrix(), first.tree.pos_vector());
                let mut x = nalgebra::Matrix6::<f64>::zeros();
                x.fixed_view_mut::<3, 3>(0, 0).copy_from(&r.transpose());
                x.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r.transpose() * pos.cross_matrix()));
                x.fixed_view_mut::<3, 3>(3, 3).copy_from(&r.transpose());
                let Some(xinv) = x.try_inverse() else { return 0.0 };
                let a = xinv.transpose() * spatial_inertia(&self.joints[p].inertia) * xinv;
                let (la, lb) = (a.symmetric_eigenvalues().min(), b.symmetric_eigenvalues().min());
                if la > 0.0 && lb > 0.0 {
                    1.0 / (1.0 / la + 1.0 / lb)
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// The motion subspace of `members` in the body frame, (linear, angular) rows: every
    /// member's frame is the body's (identity transforms between members).
    fn motion_subspace(&self, members: std::ops::Range<usize>) -> nalgebra::DMatrix<f64> {
        nalgebra::DMatrix::from_fn(6, members.len(), |r, c| {
            let j = &self.joints[members.start + c];
            match (r < 3, !j.joint_type.is_rotation()) {
                (true, true) => j.axis[r],
                (false, false) => j.axis[r - 3],
                _ => 0.0,
            }
        })
    }

    /// Whether joint `i` is part of a multi-dof joint whose parent is the fixed root (the
    /// free-flyer, or a spherical joint on the root): its parent's velocity is 0, so no
    /// velocity-product term is needed at all.
    pub fn in_root_group(&self, i: usize) -> bool {
        self.group(i).is_some_and(|g| self.joints[g.start].parent.is_none())
    }

    /// The members of joint `i`'s multi-dof joint when its parent is a moving body.
    pub fn inner_group(&self, i: usize) -> Option<std::ops::Range<usize>> {
        self.group(i).filter(|g| self.joints[g.start].parent.is_some())
    }

    /// Multi-dof joints before model joint `i`: each adds one entry to q.
    fn quaternions_before(&self, i: usize) -> usize {
        usize::from(self.floating && i >= FREE_FLYER.len())
            + self.spherical.iter().filter(|s| s.0 < i).count()
    }

    /// Where in q the multi-dof joint whose first model joint is `first` keeps its pose:
    /// the free-flyer's `[x, y, z, qx, qy, qz, qw]`, a spherical joint's `[qx, qy, qz, qw]`
    /// (Pinocchio's layout: each joint's entries at its `idx_q`, in model order).
    pub fn group_q(&self, first: JointIndex) -> QIndex {
        QIndex(self.coordinate_of(first).0 + self.quaternions_before(first.0))
    }

    /// Whether some joint is a coupled mimic (then coordinates and joints differ).
    pub fn has_coupled(&self) -> bool {
        self.coupling.iter().any(Option::is_some)
    }

    /// Joint `i`'s coupling, when it is a coupled mimic joint.
    pub fn coupling(&self, i: usize) -> Option<Coupling> {
        self.coupling.get(i).copied().flatten()
    }

    /// The joint of each coordinate: every joint that is not a coupled mimic, in order.
    pub fn coordinate_joints(&self) -> Vec<JointIndex> {
        (0..self.njoints()).filter(|&i| self.coupling(i).is_none()).map(JointIndex).collect()
    }

    /// The coordinate joint `i` moves with: its own, or for a coupled mimic joint the
    /// coordinate of the joint it follows.
    pub fn coordinate_of(&self, i: JointIndex) -> CoordIndex {
        // `build` leaves `coupling` empty when nothing is coupled: the common case is O(1).
        if self.coupling.is_empty() {
            return CoordIndex(i.0);
        }
        let own = self.coupling(i.0).map_or(i.0, |c| c.of);
        CoordIndex((0..own).filter(|&j| self.coupling(j).is_none()).count())
    }

    /// Each coordinate's parent coordinate: that of its joint's nearest ancestor that is
    /// not a coupled mimic (`None` under the root).
    pub fn coordinate_parents(&self) -> Vec<Option<usize>> {
        let coordinate_parent = |j: usize| {
            let mut p = self.joints[j].parent;
            while let Some(a) = p.filter(|&a| self.coupling(a).is_some()) {
                p = self.joints[a].parent;
            }
            p.map(|a| self.coordinate_of(JointIndex(a)).0)
        };
        self.coordinate_joints().into_iter().map(|j| coordinate_parent(j.0)).collect()
    }

    /// Joint `i`'s velocity per unit of its coordinate's: 1, or a coupled joint's multiplier.
    pub fn multiplier(&self, i: usize) -> f64 {
        self.coupling(i).map_or(1.0, |c| c.multiplier)
    }

    /// Where coordinate `k`'s position is in q; `None` for the coordinates of a multi-dof
    /// joint, which are always at zero (its pose is in q at [`Model::group_q`] instead).
    pub fn q_index(&self, k: CoordIndex) -> Option<QIndex> {
        if !self.floating && self.spherical.is_empty() {
            return Some(QIndex(k.0));
        }
        let j = if self.coupling.is_empty() { k.0 } else { self.coordinate_joints()[k.0].0 };
        match self.group(j) {
            Some(_) => None,
            None => Some(QIndex(k.0 + self.quaternions_before(j))),
        }
    }

    /// Joint `i`'s position as `(q index, multiplier, offset)`: `q[index] · multiplier +
    /// offset` (1 and 0 unless it is a coupled mimic joint); `None` for the members of a
    /// multi-dof joint.
    pub fn joint_q(&self, i: JointIndex) -> Option<(QIndex, f64, f64)> {
        let k = self.q_index(self.coordinate_of(i))?;
        Some(self.coupling(i.0).map_or((k, 1.0, 0.0), |c| (k, c.multiplier, c.offset)))
    }

    /// Whether joint `i` is one of the free-flyer's six coordinates. The algorithms treat
    /// the six as one 6-dof joint whose parent is the root (Pinocchio's free-flyer): no
    /// velocity-product term `v × S q̇` (the base's acceleration is q̈ itself), and in the
    /// gradients the parent's velocity is 0 and its acceleration the root's, and moving
    /// one of them does not turn the force the others transmit. Taking the chain of six
    /// literally would add those terms, which belong to a different parametrisation.
    pub fn is_free_flyer(&self, i: usize) -> bool {
        self.floating && i < FREE_FLYER.len()
    }

    /// q from one value per coordinate (length nv; the free-flyer's six are ignored) and, with
    /// a floating base, the base pose `[x, y, z, qx, qy, qz, qw]` (ignored without one).
    pub fn q_from_joints(&self, per_joint: &[f64], base: [f64; 7]) -> Vec<f64> {
        let mut q = self.neutral_q();
        if self.floating {
            q[..7].copy_from_slice(&base);
        }
        for (i, &x) in per_joint.iter().enumerate().take(self.nv()) {
            if let Some(k) = self.q_index(CoordIndex(i)) {
                q[k.0] = x;
            }
        }
        q
    }

    /// q at every joint's zero position (a floating base at the origin, unrotated; every
    /// spherical joint unrotated).
    pub fn neutral_q(&self) -> Vec<f64> {
        let mut q = vec![0.0; self.nq()];
        if self.floating {
            q[6] = 1.0;
        }
        for &s in &self.spherical {
            q[self.group_q(s).0 + 3] = 1.0;
        }
        q
    }

    /// Where each quaternion is in q (`[qx, qy, qz, qw]`): the floating base's at 3, then
    /// each spherical joint's.
    pub fn quaternions(&self) -> Vec<QIndex> {
        let base = self.floating.then_some(QIndex(3));
        base.into_iter().chain(self.spherical.iter().map(|&s| self.group_q(s))).collect()
    }

    /// The name of the joint that moves body `i`, as Pinocchio names it: a multi-dof joint's
    /// own name (the free-flyer's `root_joint`, a spherical joint's), not its members'
    /// (`<name>_vx` ... `<name>_wz`, see [`FREE_FLYER`] and [`SPHERICAL`]).
    pub fn joint_name(&self, i: usize) -> &str {
        let Some(g) = self.group(i) else { return &self.joints[i].name };
        let first = &self.joints[g.start].name;
        let suffix = if self.is_free_flyer(g.start) { FREE_FLYER[0].0 } else { SPHERICAL[0].0 };
        first.strip_suffix(suffix).and_then(|n| n.strip_suffix('_')).unwrap_or(first)
    }

    /// The frame named `name`.
    pub fn frame(&self, name: &str) -> Option<usize> {
        self.frames.iter().position(|f| f.name == name)
    }

    /// The frames the frame kernels compute ([`Specialisation::frames`]).
    pub fn selected_frames(&self) -> impl Iterator<Item = &Frame> {
        self.specialisation.frames.iter().map(|&f| &self.frames[f])
    }

    /// Whether `a` is `i` or one of its ancestors.
    pub fn is_ancestor_or_self(&self, a: usize, i: usize) -> bool {
        a <= i && i < self.joints[a].subtree_end
    }

    /// Ancestors of `i` from the root down, `i` included.
    pub fn ancestors(&self, i: usize) -> Vec<usize> {
        let mut chain = vec![i];
        let mut j = i;
        while let Some(p) = self.joints[j].parent {
            chain.push(p);
            j = p;
        }
        chain.reverse();
        chain
    }

    /// Joint indices at each depth.
    pub fn levels(&self) -> Vec<Vec<usize>> {
        let depth = self.joints.iter().map(|j| j.level + 1).max().unwrap_or(0);
        let mut levels = vec![Vec::new(); depth];
        for (i, j) in self.joints.iter().enumerate() {
            levels[j.level].push(i);
        }
        levels
    }

    /// Nonzero pattern of ∂v_i/∂q_j (and ∂a_i/∂q_j): j an ancestor of i or i itself.
    pub fn motion_sparsity(&self) -> Count {
        let n = self.njoints();
        let nonzero = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .filter(|&(i, j)| self.is_ancestor_or_self(j, i))
            .count();
        Count { nonzero, total: n * n }
    }

    /// Nonzero pattern of ∂f_i/∂q_j and ∂c_i/∂q_j: i and j on one root-to-leaf path.
    pub fn force_sparsity(&self) -> Count {
        let n = self.njoints();
        let nonzero = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .filter(|&(i, j)| self.is_ancestor_or_self(j, i) || self.is_ancestor_or_self(i, j))
            .count();
        Count { nonzero, total: n * n }
    }
}

fn link_inertia(inertial: &urdf::Inertial, in_body: &Transform) -> Inertia {
    let m = inertial.mass;
    let [ixx, ixy, ixz, iyy, iyz, izz] = inertial.inertia;
    let ic = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
    let frame = in_body.compose(&Transform::from_pose(&inertial.origin));
    let r = frame.rot_matrix();
    let c = frame.pos_vector();
    let i_origin =
        r * ic * r.transpose() + (Matrix3::identity() * c.dot(&c) - c * c.transpose()) * m;
    Inertia {
        mass: m,
        h: (c * m).into(),
        i_origin: std::array::from_fn(|i| std::array::from_fn(|j| i_origin[(i, j)])),
    }
}

/// Warns about inertias no rigid body can have: not positive semi-definite, or breaking
/// the triangle inequality of principal moments (I1 + I2 ≥ I3).
fn check_inertia(link: &urdf::Link, diags: &mut Vec<Diagnostic>) {
    let Some(inertial) = &link.inertial else { return };
    if inertial.mass < 0.0 {
        diags.push(
            Diagnostic::error(
                format!("link `{}` has negative mass {}", link.name, inertial.mass),
                Some(inertial.mass_span.clone()),
                "mass must be zero or positive",
            )
            .with_help("correct <mass value=\"...\">"),
        );
        return;
    }
    let [ixx, ixy, ixz, iyy, iyz, izz] = inertial.inertia;
    let ic = Matrix3::new(ixx, ixy, ixz, ixy, iyy, iyz, ixz, iyz, izz);
    let mut e: Vec<f64> = SymmetricEigen::new(ic).eigenvalues.iter().copied().collect();
    e.sort_by(f64::total_cmp);
    // A relative tolerance: URDF inertias are printed with 4 to 17 digits.
    let tol = 1e-9 * e.iter().map(|x| x.abs()).sum::<f64>();
    if e[0] < -tol {
        diags.push(
            Diagnostic::warning(
                format!("link `{}` has an inertia that is not positive semi-definite (smallest principal moment {:.3e})", link.name, e[0]),
                Some(inertial.inertia_span.clone()),
                "physically implausible inertia",
            )
            .with_help("check the signs of the products of inertia; the dynamics use the values as written"),
        );
    } else if e[0] + e[1] < e[2] - tol {
        diags.push(
            Diagnostic::warning(
                format!("link `{}` breaks the triangle inequality of principal moments ({:.4e} + {:.4e} < {:.4e})", link.name, e[0], e[1], e[2]),
                Some(inertial.inertia_span.clone()),
                "physically implausible inertia",
            )
            .with_help("no rigid body has these moments; the dynamics use the values as written"),
        );
    }
}

/// The motion of URDF joint `j` at position `value`: a rotation about its (normalised)
/// axis, or a translation along it.
fn joint_motion(j: &urdf::Joint, value: f64) -> Transform {
    let a = Vector3::from(j.axis);
    let a = if a.norm() < 1e-12 { Vector3::z() } else { a.normalize() };
    match j.kind {
        JointKind::Prismatic => Transform::from_parts(Matrix3::identity(), a * value),
        _ => Transform::from_parts(axis_angle(&a, value), Vector3::zeros()),
    }
}

/// One step of the depth-first walk (an explicit stack: deep chains must not overflow).
enum Walk {
    /// Lump a link into `body` (None: the fixed root body) at pose `in_body`, then walk on.
    Visit { link: usize, body: Option<usize>, in_body: Transform },
    /// Create the model joint for URDF joint `joint`.
    Open { joint: usize, parent: Option<usize>, tree: Transform },
    /// Create the free-flyer `name` at `tree`, carrying `link` (see [`FREE_FLYER`]).
    Free { name: String, link: usize, tree: Transform },
    /// The subtree of model joint `body` is complete.
    Close { body: usize },
}

/// A scene resolved against one URDF: what the model builder does differently.
pub(crate) struct Edits {
    /// Per URDF joint: the position it is locked at.
    pub locked: Vec<Option<f64>>,
    /// Per URDF link: left out (with its subtree).
    pub dropped: Vec<bool>,
    /// Per URDF link: payloads, as inertials in the link frame.
    pub payload: Vec<Vec<urdf::Inertial>>,
}

impl Edits {
    pub fn none(urdf: &Urdf) -> Edits {
        Edits {
            locked: vec![None; urdf.joints.len()],
            dropped: vec![false; urdf.links.len()],
            payload: vec![Vec::new(); urdf.links.len()],
        }
    }
}

/// Builds the model from a checked URDF tree, with a free-flyer under the root link when
/// `floating_base`; also returns, for each model joint, the index of the URDF joint it
/// comes from (for located errors in later checks; `None` for `--floating-base`'s).
pub(crate) fn build(
    urdf: &Urdf,
    tree: &Tree,
    edits: &Edits,
    floating_base: bool,
    mimic_coupled: bool,
    diags: &mut Vec<Diagnostic>,
) -> Option<(Model, Vec<Option<usize>>)> {
    for link in &urdf.links {
        check_inertia(link, diags);
    }
    let mut joints: Vec<Joint> = Vec::new();
    // URDF joint index of each model joint, for located errors.
    let mut source: Vec<Option<usize>> = Vec::new();
    let mut floating = floating_base;
    let mut spherical = Vec::new();
    let mut frames = Vec::new();
    let mut stack = vec![match floating_base {
        true => Walk::Free {
            name: ROOT_JOINT.to_string(),
            link: tree.root,
            tree: Transform::identity(),
        },
        false => Walk::Visit { link: tree.root, body: None, in_body: Transform::identity() },
    }];
    while let Some(step) = stack.pop() {
        match step {
            Walk::Visit { link, body, in_body } => {
                frames.push(Frame {
                    name: urdf.links[link].name.clone(),
                    body,
                    placement: in_body,
                });
                // The root body is fixed: its inertia never enters the dynamics.
                if let Some(b) = body {
                    for inertial in urdf.links[link].inertial.iter().chain(&edits.payload[link]) {
                        if inertial.mass >= 0.0 {
                            let inertia = link_inertia(inertial, &in_body);
                            joints[b].inertia.add(&inertia);
                        }
                    }
                }
                // Pushed in reverse so that children are walked in document order, and a
                // floating joint last, so that the free-flyer is model joints 0 to 5.
                let floating_last = tree.child_joints[link]
                    .iter()
                    .rev()
                    .filter(|&&j| urdf.joints[j].kind != JointKind::Floating)
                    .chain(
                        tree.child_joints[link]
                            .iter()
                            .filter(|&&j| urdf.joints[j].kind == JointKind::Floating),
                    );
                for &j in floating_last {
                    let child = tree.joint_links[j].1;
                    if edits.dropped[child] {
                        continue;
                    }
                    let origin = in_body.compose(&Transform::from_pose(&urdf.joints[j].origin));
                    if urdf.joints[j].kind == JointKind::Floating {
                        let uj = &urdf.joints[j];
                        if link != tree.root || floating {
                            let why = if floating {
                                "a robot has at most one floating base"
                            } else {
                                "only the root link can carry a floating joint"
                            };
                            diags.push(Diagnostic::error(format!("floating joint `{}` is not supported here", uj.name), Some(uj.span.clone()), why).with_help(
                                "a floating joint must join the root link (e.g. `world`) to the base; with `--floating-base`, leave it out of the URDF",
                            ));
                            continue;
                        }
                        floating = true;
                        stack.push(Walk::Free { name: uj.name.clone(), link: child, tree: origin });
                        continue;
                    }
                    if urdf.joints[j].kind == JointKind::Fixed {
                        stack.push(Walk::Visit { link: child, body, in_body: origin });
                    } else if let Some(value) = edits.locked[j] {
                        // A locked joint is a fixed one at its locked position.
                        let motion = joint_motion(&urdf.joints[j], value);
                        stack.push(Walk::Visit {
                            link: child,
                            body,
                            in_body: origin.compose(&motion),
                        });
                    } else {
                        stack.push(Walk::Open { joint: j, parent: body, tree: origin });
                    }
                }
            }
            Walk::Open { joint: j, parent, tree: tree_transform }
                if urdf.joints[j].kind == JointKind::Spherical =>
            {
                let uj = &urdf.joints[j];
                if mimic_coupled && uj.mimic.is_some() {
                    diags.push(
                        Diagnostic::error(
                            format!("spherical joint `{}` has a <mimic>", uj.name),
                            uj.mimic.as_ref().map(|m| m.span.clone()),
                            "a spherical joint cannot be coupled",
                        )
                        .with_help("--mimic coupled couples one-dof joints; remove the <mimic>, or use --mimic independent"),
                    );
                }
                let first = joints.len();
                for (k, &(suffix, axis)) in SPHERICAL.iter().enumerate() {
                    let parent = if k == 0 { parent } else { Some(first + k - 1) };
                    joints.push(Joint {
                        name: format!("{}_{suffix}", uj.name),
                        joint_type: JointType::Continuous,
                        parent,
                        tree: if k == 0 { tree_transform } else { Transform::identity() },
                        axis,
                        inertia: Inertia::zero(),
                        level: parent.map_or(0, |p| joints[p].level + 1),
                        subtree_end: first + k + 1,
                        limit: None,
                        velocity_limit: uj.velocity,
                        damping: uj.damping,
                        friction: uj.friction,
                        mimic: None,
                    });
                    source.push(Some(j));
                    stack.push(Walk::Close { body: first + k });
                }
                spherical.push(JointIndex(first));
                stack.push(Walk::Visit {
                    link: tree.joint_links[j].1,
                    body: Some(first + SPHERICAL.len() - 1),
                    in_body: Transform::identity(),
                });
            }
            Walk::Open { joint: j, parent, tree: tree_transform } => {
                let uj = &urdf.joints[j];
                let norm = (uj.axis[0].powi(2) + uj.axis[1].powi(2) + uj.axis[2].powi(2)).sqrt();
                if norm < 1e-12 {
                    diags.push(
                        Diagnostic::error(
                            format!("joint `{}` has a zero axis", uj.name),
                            Some(uj.axis_span.clone()),
                            "the axis has no direction",
                        )
                        .with_help("give a nonzero <axis xyz=\"...\">; it is normalised"),
                    );
                }
                let index = joints.len();
                joints.push(Joint {
                    name: uj.name.clone(),
                    joint_type: match uj.kind {
                        JointKind::Revolute => JointType::Revolute,
                        JointKind::Continuous => JointType::Continuous,
                        _ => JointType::Prismatic,
                    },
                    parent,
                    tree: tree_transform,
                    axis: if norm < 1e-12 { [0.0, 0.0, 1.0] } else { uj.axis.map(|a| a / norm) },
                    inertia: Inertia::zero(),
                    level: parent.map_or(0, |p| joints[p].level + 1),
                    subtree_end: index + 1,
                    limit: uj.limit,
                    velocity_limit: uj.velocity,
                    damping: uj.damping,
                    friction: uj.friction,
                    mimic: uj.mimic.as_ref().map(|m| (m.joint.clone(), m.multiplier, m.offset)),
                });
                source.push(Some(j));
                stack.push(Walk::Close { body: index });
                stack.push(Walk::Visit {
                    link: tree.joint_links[j].1,
                    body: Some(index),
                    in_body: Transform::identity(),
                });
            }
            Walk::Free { name, link, tree: tree_transform } => {
                for (k, &(suffix, joint_type, axis)) in FREE_FLYER.iter().enumerate() {
                    joints.push(Joint {
                        name: format!("{name}_{suffix}"),
                        joint_type,
                        parent: k.checked_sub(1),
                        tree: if k == 0 { tree_transform } else { Transform::identity() },
                        axis,
                        inertia: Inertia::zero(),
                        level: k,
                        subtree_end: k + 1,
                        limit: None,
                        velocity_limit: None,
                        damping: 0.0,
                        friction: 0.0,
                        mimic: None,
                    });
                    source.push(None);
                }
                // Closed last-pushed-first: every free-flyer joint's subtree is the robot.
                for k in 0..FREE_FLYER.len() {
                    stack.push(Walk::Close { body: k });
                }
                stack.push(Walk::Visit {
                    link,
                    body: Some(FREE_FLYER.len() - 1),
                    in_body: Transform::identity(),
                });
            }
            Walk::Close { body } => joints[body].subtree_end = joints.len(),
        }
    }
    let mut coupling =
        if mimic_coupled { couple(urdf, &joints, &source, diags) } else { Vec::new() };
    if coupling.iter().all(Option::is_none) {
        coupling.clear();
    }
    let model = Model {
        name: urdf.name.clone(),
        source: String::new(),
        singular: None,
        root_link: urdf.links[tree.root].name.clone(),
        joints,
        floating,
        spherical,
        coupling,
        frames,
        specialisation: Specialisation::default(),
        rounded_angles: None,
    };
    Some((model, source))
}

/// `--mimic coupled`: each mimic joint follows the joint its `<mimic>` names, composed
/// through chains of mimics (`m₁ (m₂ q + o₂) + o₁`). A target that is not a movable joint
/// of the model (fixed, locked or left out by a scene), or a cycle, is an error at the
/// `<mimic>`; an unknown name was warned about while loading and stays independent.
fn couple(
    urdf: &Urdf,
    joints: &[Joint],
    source: &[Option<usize>],
    diags: &mut Vec<Diagnostic>,
) -> Vec<Option<Coupling>> {
    let index = |name: &str| joints.iter().position(|j| j.name == name);
    let span =
        |i: usize| source[i].and_then(|j| urdf.joints[j].mimic.as_ref()).map(|m| m.span.clone());
    // A mimic of a name the URDF lacks was warned about and stays independent.
    let mimics = |i: usize| {
        joints[i].mimic.as_ref().filter(|(t, ..)| urdf.joints.iter().any(|j| &j.name == t))
    };
    let mut coupling = vec![None; joints.len()];
    for (i, joint) in joints.iter().enumerate() {
        if mimics(i).is_none() {
            continue;
        }
        let (mut multiplier, mut offset) = (1.0, 0.0);
        let mut at = i;
        let mut seen = vec![i];
        let of = loop {
            let Some((target, m, o)) = mimics(at) else { break Some(at) };
            // Composing: the joint so far is `multiplier · q_at + offset`, q_at = m q + o.
            offset += multiplier * o;
            multiplier *= m;
            match index(target) {
                Some(t) if seen.contains(&t) => {
                    diags.push(
                        Diagnostic::error(format!("mimic joints form a cycle through `{}`", joint.name), span(i), "a mimic joint cannot follow itself")
                            .with_help("with --mimic coupled, every chain of <mimic> elements must end at a joint that mimics none"),
                    );
                    break None;
                }
                Some(t) => {
                    seen.push(t);
                    at = t;
                }
                None => {
                    let why = match urdf.joints.iter().find(|j| &j.name == target) {
                        Some(j) if j.kind == JointKind::Fixed => "a fixed joint",
                        Some(j) if j.kind == JointKind::Floating => "the floating base",
                        Some(j) if j.kind == JointKind::Spherical => "a spherical joint",
                        Some(_) => "locked or left out by the scene",
                        None => "not a joint of this robot",
                    };
                    diags.push(
                        Diagnostic::error(
                            format!("joint `{}` mimics `{target}`, which is {why}", joints[at].name),
                            span(at),
                            "the mimicked joint has no coordinate",
                        )
                        .with_help("--mimic coupled needs the mimicked joint movable; lock the mimic joint too, or use --mimic independent"),
                    );
                    break None;
                }
            }
        };
        if let Some(of) = of {
            coupling[i] = Some(Coupling { of, multiplier, offset });
        }
    }
    coupling
}
