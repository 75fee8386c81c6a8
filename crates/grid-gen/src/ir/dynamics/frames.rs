//! The frame kernels, recorded symbolically: world placements by forward kinematics over
//! the (E, r) transforms, Jacobian columns as the screws of the joints on a frame's path
//! (so a frame costs what its chain costs, and axis-aligned joints cost nothing to turn),
//! velocities and classical accelerations from RNEA's forward pass without gravity.
//! Conventions are Pinocchio's, as in `reference::frames`: 6-vectors [linear; angular].

use super::super::graph::{Graph, Id, Input, Stage};
use super::super::spatial::{self as sp, ang, k, lin, Sv, V3};
use super::Dynamics;
use crate::model::{CoordIndex, JointIndex, QIndex};
use crate::model::{Frame, ReferenceFrame};

/// A forward-mode direction: seeds on the kernel's inputs, and tangents given to nodes
/// (see [`Graph::tangent_at`](super::super::graph::Graph::tangent_at)).
type Tangents = (Vec<(Input, usize, Id)>, Vec<(Id, Id)>);

/// A rotation (columns: a frame's axes in world coordinates) and a position.
pub(super) type Pose = ([[Id; 3]; 3], V3);

/// `Rᵀ v`.
fn t_apply(g: &mut Graph, r: &[[Id; 3]; 3], v: &V3) -> V3 {
    sp::mat_t_vec(g, r, v)
}

/// A model transform's entries as constants (snapped when folding).
fn constant_pose(g: &mut Graph, frame: &Frame) -> Pose {
    let r = std::array::from_fn(|i| std::array::from_fn(|j| k(g, frame.placement.rot[i][j])));
    let p = std::array::from_fn(|i| k(g, frame.placement.pos[i]));
    (r, p)
}

/// A constant rotation's quaternion `[x, y, z, w]` (nalgebra's conversion, which picks the
/// largest of the four components to divide by).
fn constant_quaternion(g: &mut Graph, rot: [[f64; 3]; 3]) -> [Id; 4] {
    let m = nalgebra::Matrix3::from_fn(|r, c| rot[r][c]);
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(m),
    );
    let c = q.into_inner().coords;
    std::array::from_fn(|i| k(g, c[i]))
}

impl Dynamics<'_> {
    /// The world pose of every body: `R_i = R_λ E_iᵀ`, `p_i = p_λ + R_λ r_i`.
    pub(super) fn world_poses(&mut self) -> Vec<Pose> {
        self.poses(false)
    }

    /// Every body's pose as [`Self::world_poses`], or, `per_tree`, in its tree's root body:
    /// that body's own pose the identity.
    pub(super) fn poses(&mut self, per_tree: bool) -> Vec<Pose> {
        let g = &mut self.g;
        let (zero, one) = (g.constant(0.0), g.constant(1.0));
        let identity = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
        let mut poses: Vec<Pose> = Vec::with_capacity(self.model.njoints());
        for i in 0..self.model.njoints() {
            self.g.at(Some(i), Stage::Transform, self.model.joints[i].level);
            let parent = self.model.joints[i].parent;
            if per_tree && parent.is_none() {
                poses.push((identity, [zero; 3]));
                continue;
            }
            let (rp, pp) = parent.map_or((identity, [zero; 3]), |p| poses[p]);
            let x = &self.x[i];
            let g = &mut self.g;
            // R_λ Eᵀ: entry (a, b) = row a of R_λ · row b of E.
            let r = std::array::from_fn(|a| std::array::from_fn(|b| g.dot(&rp[a], &x.e[b])));
            let shift = sp::mat_vec(g, &rp, &x.r);
            let p = sp::add3(g, &pp, &shift);
            poses.push((r, p));
        }
        poses
    }

    /// A frame's world orientation as a quaternion `[x, y, z, w]` (Hamilton's product, q's
    /// convention): the product along its body's path of each joint's tree rotation and its
    /// own (`[a sin(θ/2), cos(θ/2)]` for a revolute joint, q's quaternion for a free-flyer or
    /// a spherical joint), then the frame's placement. It is the rotation of
    /// [`Self::frame_pose`] up to q's quaternions' norms, which only scale it; a wrench
    /// contact's Baumgarte error takes its logarithm, which needs no branch on a quaternion
    /// where a rotation matrix would need one near a half turn.
    pub(super) fn frame_quaternion(&mut self, frame: &Frame) -> [Id; 4] {
        let mut chain = Vec::new();
        let mut at = frame.body;
        while let Some(i) = at {
            chain.push(i);
            at = self.model.joints[i].parent;
        }
        let mut out =
            constant_quaternion(&mut self.g, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
        for &i in chain.iter().rev() {
            let tree = constant_quaternion(&mut self.g, self.model.joints[i].tree.rot);
            out = super::step::qmul(&mut self.g, out, tree);
            if let Some(own) = self.joint_quaternion(i) {
                out = super::step::qmul(&mut self.g, out, own);
            }
        }
        let placement = constant_quaternion(&mut self.g, frame.placement.rot);
        super::step::qmul(&mut self.g, out, placement)
    }

    /// Joint i's own rotation as a quaternion, `None` where it has none (a prismatic joint,
    /// a multi-dof joint's later members).
    fn joint_quaternion(&mut self, i: usize) -> Option<[Id; 4]> {
        let model = self.model;
        let g = &mut self.g;
        let config = self.config.as_ref();
        let q_at = |g: &mut Graph, e: usize| config.map_or_else(|| g.input(Input::Q, e), |q| q[e]);
        let joint = &model.joints[i];
        let Some((QIndex(qi), multiplier, offset)) = model.joint_q(JointIndex(i)) else {
            if model.group(i).is_none_or(|m| m.start != i) {
                return None;
            }
            let at = if model.is_free_flyer(i) { 3 } else { model.group_q(JointIndex(i)).0 };
            return Some(std::array::from_fn(|c| q_at(g, at + c)));
        };
        if !joint.joint_type.is_rotation() {
            return None;
        }
        // The half angle of `multiplier · q + offset` (a coupled mimic joint's angle).
        let q = q_at(g, qi);
        let (m, o) = (k(g, 0.5 * multiplier), k(g, 0.5 * offset));
        let half = g.mul(m, q);
        let half = g.add(half, o);
        let (s, c) = (g.sin(half), g.cos(half));
        let a = joint.axis;
        let [x, y, z] = a.map(|ar| {
            let ar = k(g, ar);
            g.mul(ar, s)
        });
        Some([x, y, z, c])
    }

    /// The world pose of a frame: its body's, composed with its constant placement.
    fn frame_pose(&mut self, poses: &[Pose], frame: &Frame) -> Pose {
        let (rl, pl) = constant_pose(&mut self.g, frame);
        let g = &mut self.g;
        match frame.body {
            None => (rl, pl),
            Some(b) => {
                let (rb, pb) = poses[b];
                let r = std::array::from_fn(|a| {
                    std::array::from_fn(|c| g.dot(&rb[a], &[rl[0][c], rl[1][c], rl[2][c]]))
                });
                let shift = sp::mat_vec(g, &rb, &pl);
                (r, sp::add3(g, &pb, &shift))
            }
        }
    }

    /// Frame work happens after the forward pass, at the frame's body.
    fn at_frame(&mut self, frame: &Frame) {
        let level = frame.body.map_or(0, |b| self.model.joints[b].level);
        self.g.at(frame.body, Stage::Forward, level);
    }

    fn selected(&self) -> Vec<Frame> {
        self.model.selected_frames().cloned().collect()
    }

    /// Per frame: world translation (3) and rotation (9, row-major).
    pub fn frame_placements(&mut self) -> (Vec<Id>, Vec<Id>) {
        let poses = self.world_poses();
        let (mut t, mut r) = (Vec::new(), Vec::new());
        for frame in self.selected() {
            self.at_frame(&frame);
            let (rf, pf) = self.frame_pose(&poses, &frame);
            t.extend(pf);
            r.extend(rf.into_iter().flatten());
        }
        (t, r)
    }

    /// Per frame: the 6 x nv Jacobian, row-major, rows [linear; angular], in the model's
    /// reference frame. Column of joint j (a screw of axis `w = R_j a_j` through `p_j`):
    /// `[w × (p_f − p_j); w]` at the frame (LOCAL_WORLD_ALIGNED), `[p_j × w; w]` at the world
    /// origin (WORLD), the former turned into the frame's axes (LOCAL); a prismatic joint's
    /// is `[R_j a_j; 0]`. A coupled mimic joint adds its multiple to its coordinate's column.
    pub fn frame_jacobians(&mut self) -> Vec<Id> {
        let rf = self.model.specialisation.reference;
        let poses = self.world_poses();
        let nv = self.model.nv();
        let zero = self.g.constant(0.0);
        let mut out = Vec::new();
        for frame in self.selected() {
            self.at_frame(&frame);
            let (r_f, p_f) = self.frame_pose(&poses, &frame);
            let mut cols = vec![[zero; 6]; nv];
            for j in frame.body.map(|b| self.model.ancestors(b)).unwrap_or_default() {
                let joint = &self.model.joints[j];
                let g = &mut self.g;
                let (r_j, p_j) = poses[j];
                let axis: V3 = std::array::from_fn(|i| k(g, joint.axis[i]));
                let w = sp::mat_vec(g, &r_j, &axis);
                let (l, a) = if joint.joint_type.is_rotation() {
                    let l = match rf {
                        ReferenceFrame::World => sp::cross(g, &p_j, &w),
                        _ => {
                            let d = sp::sub3(g, &p_f, &p_j);
                            sp::cross(g, &w, &d)
                        }
                    };
                    (l, w)
                } else {
                    (w, [zero; 3])
                };
                let (l, a) = match rf {
                    ReferenceFrame::Local => (t_apply(g, &r_f, &l), t_apply(g, &r_f, &a)),
                    _ => (l, a),
                };
                let c = self.model.coordinate_of(JointIndex(j)).0;
                let m = self.model.multiplier(j);
                let col = [l[0], l[1], l[2], a[0], a[1], a[2]];
                for (row, &x) in col.iter().enumerate() {
                    let x = if m == 1.0 {
                        x
                    } else {
                        let m = k(g, m);
                        g.mul(m, x)
                    };
                    cols[c][row] = g.add(cols[c][row], x);
                }
            }
            for row in 0..6 {
                out.extend(cols.iter().map(|c| c[row]));
            }
        }
        out
    }

    /// The bodies' velocities and accelerations without gravity (RNEA's forward pass at
    /// a₀ = 0), per model joint.
    pub(super) fn motion(&mut self, qd: &[Id], qdd: &[Id]) -> (Vec<Sv>, Vec<Sv>) {
        let gravity = std::mem::replace(&mut self.gravity, [0.0; 3]);
        let r = self.rnea(qd, qdd);
        self.gravity = gravity;
        (r.v, r.a)
    }

    /// A body's motion `m` ([angular; linear], body axes) at the point `at` (body axes):
    /// `(linear, angular)`, the linear part `m.lin + m.ang × at`.
    pub(super) fn at_point(g: &mut Graph, m: &Sv, at: &V3) -> (V3, V3) {
        let w = ang(m);
        let c = sp::cross(g, &w, at);
        (sp::add3(g, &lin(m), &c), w)
    }

    /// Per frame: the spatial velocity [linear; angular] in the model's reference frame.
    pub fn frame_velocities(&mut self, qd: &[Id]) -> Vec<Id> {
        let rf = self.model.specialisation.reference;
        let zeros: Vec<Id> = (0..qd.len()).map(|_| self.g.constant(0.0)).collect();
        let (v, _) = self.motion(qd, &zeros);
        let poses = self.world_poses();
        let zero = self.g.constant(0.0);
        let mut out = Vec::new();
        for frame in self.selected() {
            self.at_frame(&frame);
            let Some(b) = frame.body else {
                out.extend([zero; 6]);
                continue;
            };
            let (rl, pl) = constant_pose(&mut self.g, &frame);
            let (r_b, p_b) = poses[b];
            let g = &mut self.g;
            let (l, a) = match rf {
                ReferenceFrame::Local => {
                    let (l, a) = Self::at_point(g, &v[b], &pl);
                    (t_apply(g, &rl, &l), t_apply(g, &rl, &a))
                }
                ReferenceFrame::LocalWorldAligned => {
                    let (l, a) = Self::at_point(g, &v[b], &pl);
                    (sp::mat_vec(g, &r_b, &l), sp::mat_vec(g, &r_b, &a))
                }
                ReferenceFrame::World => {
                    let a = sp::mat_vec(g, &r_b, &ang(&v[b]));
                    let l = sp::mat_vec(g, &r_b, &lin(&v[b]));
                    let c = sp::cross(g, &p_b, &a);
                    (sp::add3(g, &l, &c), a)
                }
            };
            out.extend(l.into_iter().chain(a));
        }
        out
    }

    /// Per frame: the classical acceleration (3) in the model's reference frame: the
    /// spatial acceleration's linear part plus `ω × v`, at the frame's origin (LOCAL,
    /// LOCAL_WORLD_ALIGNED) or the world's (WORLD), as `getFrameClassicalAcceleration`.
    pub fn frame_accelerations(&mut self, qd: &[Id], qdd: &[Id]) -> Vec<Id> {
        let rf = self.model.specialisation.reference;
        let (v, a) = self.motion(qd, qdd);
        let poses = self.world_poses();
        let zero = self.g.constant(0.0);
        let mut out = Vec::new();
        for frame in self.selected() {
            self.at_frame(&frame);
            let Some(b) = frame.body else {
                out.extend([zero; 3]);
                continue;
            };
            let (rl, pl) = constant_pose(&mut self.g, &frame);
            let (r_b, p_b) = poses[b];
            let g = &mut self.g;
            let c = match rf {
                ReferenceFrame::Local | ReferenceFrame::LocalWorldAligned => {
                    let (vl, w) = Self::at_point(g, &v[b], &pl);
                    let (al, _) = Self::at_point(g, &a[b], &pl);
                    let wv = sp::cross(g, &w, &vl);
                    let c = sp::add3(g, &al, &wv);
                    match rf {
                        ReferenceFrame::Local => t_apply(g, &rl, &c),
                        _ => sp::mat_vec(g, &r_b, &c),
                    }
                }
                ReferenceFrame::World => {
                    let w = sp::mat_vec(g, &r_b, &ang(&v[b]));
                    let alpha = sp::mat_vec(g, &r_b, &ang(&a[b]));
                    let vl = sp::mat_vec(g, &r_b, &lin(&v[b]));
                    let al = sp::mat_vec(g, &r_b, &lin(&a[b]));
                    let pw = sp::cross(g, &p_b, &w);
                    let vo = sp::add3(g, &vl, &pw);
                    let pa = sp::cross(g, &p_b, &alpha);
                    let ao = sp::add3(g, &al, &pa);
                    let wv = sp::cross(g, &w, &vo);
                    sp::add3(g, &ao, &wv)
                }
            };
            out.extend(c);
        }
        out
    }

    /// The tangents of q's entries along coordinate `k`'s direction: 1 on its own entry, and
    /// for a multi-dof joint's coordinate the first-order change of the pose under
    /// `q ⊕ ε = q · exp(ε)` (Pinocchio's `integrate`): a free-flyer's linear coordinate moves
    /// the position by `R e_k`, an angular one turns the quaternion by `½ q ⊗ (e_k, 0)`.
    /// Entries name q's; the tangents are built from the configuration the transforms were
    /// (an RK4 stage's, see [`Self::stage_tangents`]).
    pub(super) fn q_seeds(&mut self, k: usize) -> Vec<(Input, usize, Id)> {
        self.config_seeds(Input::Q, k)
    }

    /// [`Self::q_seeds`] for the configuration `input` (q, or the Lie-group kernels' q1,
    /// which is never an RK4 stage's).
    pub(super) fn config_seeds(&mut self, input: Input, k: usize) -> Vec<(Input, usize, Id)> {
        if let Some(QIndex(i)) = self.model.q_index(CoordIndex(k)) {
            let one = self.g.constant(1.0);
            return vec![(input, i, one)];
        }
        let joint = self.model.coordinate_joints()[k].0;
        let group =
            self.model.group(joint).expect("a coordinate without a q entry is a multi-dof joint's");
        let member = joint - group.start;
        let free = self.model.is_free_flyer(group.start);
        let at = if free { 3 } else { self.model.group_q(JointIndex(group.start)).0 };
        let g = &mut self.g;
        let config = self.config.as_ref().filter(|_| input == Input::Q);
        let [x, y, z, w] =
            std::array::from_fn(|c| config.map_or_else(|| g.input(input, at + c), |q| q[at + c]));
        if free && member < 3 {
            // Column `member` of the rotation the kernels build (hash-consing shares its nodes).
            let r = sp::quaternion_rotation(g, [x, y, z, w]);
            let column = [r[0][member], r[1][member], r[2][member]];
            return (0..3).map(|r| (input, r, column[r])).collect();
        }
        let axis = if free { member - 3 } else { member };
        // ½ (w e_a + v × e_a, −v · e_a) with v = (x, y, z).
        let half = g.constant(0.5);
        let v = [x, y, z];
        let mut dv = [g.constant(0.0); 4];
        dv[axis] = g.mul(half, w);
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        // (v × e_a)_b = v_c, (v × e_a)_c = −v_b.
        dv[b] = g.mul(half, v[c]);
        let t = g.mul(half, v[b]);
        dv[c] = g.neg(t);
        let t = g.mul(half, v[axis]);
        dv[3] = g.neg(t);
        (0..4).map(|e| (input, at + e, dv[e])).collect()
    }

    /// The seeds and given node tangents for a forward-mode derivative along `seeds` (a
    /// direction in the kernel's q and q̇ inputs, as [`Self::q_seeds`] gives for q), with
    /// `held` fixed. At the kernel's inputs they are the seeds. At an RK4 stage the same
    /// tangents are given to the stage's configuration and velocity nodes `qd` instead, which
    /// stops the derivative there: the stage's dynamics are differentiated at the stage's
    /// state, not through it.
    pub(super) fn stage_tangents(
        &mut self,
        seeds: Vec<(Input, usize, Id)>,
        qd: &[Id],
        held: &[(Id, Id)],
    ) -> Tangents {
        let Some(config) = self.config.clone() else {
            return (seeds, held.to_vec());
        };
        let zero = self.g.constant(0.0);
        let seed = |input: Input, i: usize| {
            seeds.iter().find(|s| s.0 == input && s.1 == i).map_or(zero, |s| s.2)
        };
        let mut given = held.to_vec();
        given.extend(config.iter().enumerate().map(|(i, &n)| (n, seed(Input::Q, i))));
        given.extend(qd.iter().enumerate().map(|(i, &n)| (n, seed(Input::Qd, i))));
        (Vec::new(), given)
    }

    /// The derivatives of the frames' classical accelerations `acc` (3 per frame) with
    /// respect to q (in the tangent space), q̇ and q̈: each 3 × nv per frame, row-major,
    /// frame-major, by forward-mode differentiation of their graph.
    pub fn frame_acceleration_grads(&mut self, acc: &[Id]) -> (Vec<Id>, Vec<Id>, Vec<Id>) {
        let nv = self.model.nv();
        let nf = acc.len() / 3;
        let mut columns: [Vec<Vec<Id>>; 3] = Default::default();
        for k in 0..nv {
            if self.exhausted() {
                break;
            }
            let seeds = self.q_seeds(k);
            columns[0].push(self.g.tangent(acc, &seeds));
            let one = self.g.constant(1.0);
            columns[1].push(self.g.tangent(acc, &[(Input::Qd, k, one)]));
            columns[2].push(self.g.tangent(acc, &[(Input::Qdd, k, one)]));
        }
        if self.exhausted() {
            let z = self.g.constant(0.0);
            return (vec![z; 3 * nv * nf], vec![z; 3 * nv * nf], vec![z; 3 * nv * nf]);
        }
        let layout = |cols: &Vec<Vec<Id>>| -> Vec<Id> {
            (0..3 * nf).flat_map(|row| (0..nv).map(move |k| cols[k][row])).collect()
        };
        (layout(&columns[0]), layout(&columns[1]), layout(&columns[2]))
    }
}
