//! IDSVA with every pair in one frame per tree: each joint's motion and force vectors are
//! turned once into the frame of its tree's root body, so a (joint, ancestor) pair costs
//! dot products and no transform (Singh, Russell & Wensing, RA-L 2022, Algorithm 1, which
//! works in world coordinates, as Pinocchio's `computeRNEADerivatives` does).

use super::super::graph::{Graph, Stage};
use super::super::spatial::{self as sp, ang, join, lin, Sv};
use super::frames::Pose;
use super::rnea_grad::pair_entries;
use super::{Dynamics, Mat, Rnea};

/// A body-frame motion vector `[ω; v]` in the pose's frame: `[R ω; R v + p × R ω]`.
fn motion_out(g: &mut Graph, (r, p): &Pose, m: &Sv) -> Sv {
    let w = sp::mat_vec(g, r, &ang(m));
    let v = sp::mat_vec(g, r, &lin(m));
    let pw = sp::cross(g, p, &w);
    join(w, sp::add3(g, &v, &pw))
}

/// A body-frame force vector `[n; f]` in the pose's frame: `[R n + p × R f; R f]`.
fn force_out(g: &mut Graph, (r, p): &Pose, f: &Sv) -> Sv {
    let n = sp::mat_vec(g, r, &ang(f));
    let f = sp::mat_vec(g, r, &lin(f));
    let pf = sp::cross(g, p, &f);
    join(sp::add3(g, &n, &pf), f)
}

impl Dynamics<'_> {
    /// `(∂c/∂q, ∂c/∂q̇)` by IDSVA with the pairs in the tree's frame: the same per-joint
    /// vectors as [`Self::rnea_grad_idsva`] ([`Self::idsva_joint`]), each turned once into
    /// the frame of its tree's root body (so the root's vectors cost nothing to turn, and its
    /// children's only what their joint transform costs) where a descendant or an ancestor
    /// needs it, instead of four force vectors carried up one level at a time per pair.
    pub fn rnea_grad_world(&mut self, r: &Rnea) -> (Mat, Mat) {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let (mut dc_q, mut dc_qd) = (vec![vec![zero; n]; n], vec![vec![zero; n]; n]);
        let poses = self.poses(true);
        let Some(mut st) = self.idsva_start(r) else { return (dc_q, dc_qd) };
        // t1..t4 of every joint with an ancestor, and a multi-dof member's t3 without
        // S ×* f, in the tree's frame.
        let mut t: Vec<[Sv; 4]> = vec![[[zero; 6]; 4]; n];
        let mut t3_inner: Vec<Sv> = vec![[zero; 6]; n];
        for i in (0..n).rev() {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Backward);
            let end = self.model.joints[i].subtree_end;
            let parent = self.model.joints[i].parent;
            let group = self.model.group(i);
            let joint = self.idsva_joint(&st, r, i);
            let g = &mut self.g;
            let s = &self.s[i];
            let (sd, sdd) = (&st.sd[i], &st.sdd[i]);
            // The diagonal pair in the body's own frame, where S is sparsest.
            (dc_q[i][i], dc_qd[i][i]) =
                pair_entries(g, &joint.t, [s, sd, sdd], joint.free.as_ref());
            if end > i + 1 {
                let pose = &poses[i];
                let sw = motion_out(g, pose, s);
                let sdw = motion_out(g, pose, sd);
                let sddw = motion_out(g, pose, sdd);
                let freew = joint.free.map(|f| motion_out(g, pose, &f));
                for j in i + 1..end {
                    let inner = group.as_ref().is_some_and(|m| m.contains(&j));
                    dc_q[i][j] = sp::dot(g, &sw, if inner { &t3_inner[j] } else { &t[j][2] });
                    dc_qd[i][j] = sp::dot(g, &sw, &t[j][1]);
                    (dc_q[j][i], dc_qd[j][i]) =
                        pair_entries(g, &t[j], [&sw, &sdw, &sddw], freew.as_ref());
                }
            }
            if let Some(p) = parent {
                let pose = &poses[i];
                t[i] = joint.t.map(|v| force_out(g, pose, &v));
                if group.is_some() {
                    t3_inner[i] = force_out(g, pose, &joint.t3_inner);
                }
                self.idsva_up(&mut st, i, p);
            }
        }
        (dc_q, dc_qd)
    }
}
