//! IDSVA with every pair in one frame per tree: each joint's motion and force vectors are
//! turned once into the frame of its tree's root body, so a (joint, ancestor) pair costs
//! dot products and no transform (Singh, Russell & Wensing, RA-L 2022, Algorithm 1, which
//! works in world coordinates, as Pinocchio's `computeRNEADerivatives` does).

use super::super::graph::{Graph, Id, Stage};
use super::super::spatial::{self as sp, Sv, SymInertia};
use super::frames::Pose;
use super::{Dynamics, Mat, Rnea};

fn ang(v: &Sv) -> [Id; 3] {
    [v[0], v[1], v[2]]
}

fn lin(v: &Sv) -> [Id; 3] {
    [v[3], v[4], v[5]]
}

/// A body-frame motion vector `[ω; v]` in the pose's frame: `[R ω; R v + p × R ω]`.
fn motion_out(g: &mut Graph, (r, p): &Pose, m: &Sv) -> Sv {
    let w = sp::mat_vec(g, r, &ang(m));
    let v = sp::mat_vec(g, r, &lin(m));
    let pw = sp::cross(g, p, &w);
    let v = sp::add3(g, &v, &pw);
    [w[0], w[1], w[2], v[0], v[1], v[2]]
}

/// A body-frame force vector `[n; f]` in the pose's frame: `[R n + p × R f; R f]`.
fn force_out(g: &mut Graph, (r, p): &Pose, f: &Sv) -> Sv {
    let n = sp::mat_vec(g, r, &ang(f));
    let f = sp::mat_vec(g, r, &lin(f));
    let pf = sp::cross(g, p, &f);
    let n = sp::add3(g, &n, &pf);
    [n[0], n[1], n[2], f[0], f[1], f[2]]
}

impl Dynamics<'_> {
    /// Every body's pose in its tree's root body: `R_i = R_λ E_iᵀ`, `p_i = p_λ + R_λ r_i`, the
    /// root body's own pose the identity (so its vectors cost nothing to turn, and its
    /// children's only what their joint transform costs).
    fn tree_poses(&mut self) -> Vec<Pose> {
        let (zero, one) = (self.g.constant(0.0), self.g.constant(1.0));
        let identity = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
        let mut poses: Vec<Pose> = Vec::with_capacity(self.n());
        for i in 0..self.n() {
            self.at(i, Stage::Transform);
            let pose = match self.model.joints[i].parent {
                None => (identity, [zero; 3]),
                Some(p) => {
                    let (rp, pp) = poses[p];
                    let x = &self.x[i];
                    let g = &mut self.g;
                    let r =
                        std::array::from_fn(|a| std::array::from_fn(|b| g.dot(&rp[a], &x.e[b])));
                    let shift = sp::mat_vec(g, &rp, &x.r);
                    (r, sp::add3(g, &pp, &shift))
                }
            };
            poses.push(pose);
        }
        poses
    }

    /// `(∂c/∂q, ∂c/∂q̇)` by IDSVA with the pairs in the tree's frame: the same per-joint
    /// vectors as [`Self::rnea_grad_idsva`] (see there for the composites and multi-dof
    /// joints), each turned once into the tree's frame where a descendant or an ancestor
    /// needs it, instead of four force vectors carried up one level at a time per pair.
    pub fn rnea_grad_world(&mut self, r: &Rnea) -> (Mat, Mat) {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let (mut dc_q, mut dc_qd) = (vec![vec![zero; n]; n], vec![vec![zero; n]; n]);
        let poses = self.tree_poses();
        let has_descendants = |i: usize| self.model.joints[i].subtree_end > i + 1;
        let mut sd = Vec::with_capacity(n);
        let mut sdd = Vec::with_capacity(n);
        for i in 0..n {
            if self.exhausted() {
                return (dc_q, dc_qd);
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            let d = sp::crm(g, &r.xv[i], &self.s[i]);
            let t1 = sp::crm(g, &r.xa[i], &self.s[i]);
            let t2 = sp::crm(g, &r.xv[i], &d);
            sdd.push(sp::add(g, &t1, &t2));
            sd.push(d);
        }
        let mut ic: Vec<SymInertia> = self.inertia.clone();
        let mut dc: Vec<SymInertia> = Vec::with_capacity(n);
        for i in 0..n {
            self.at(i, Stage::Forward);
            dc.push(self.inertia[i].rate(&mut self.g, &r.v[i]));
        }
        let mut hc: Vec<Sv> = r.iv.clone();
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
            let below = has_descendants(i);
            let g = &mut self.g;
            let s = &self.s[i];
            let is = ic[i].apply(g, s);
            let isd = ic[i].apply(g, &sd[i]);
            let isdd = ic[i].apply(g, &sdd[i]);
            let ds = dc[i].apply(g, s);
            let dsd = dc[i].apply(g, &sd[i]);
            let sh = sp::crf(g, s, &hc[i]);
            let sdh = sp::crf(g, &sd[i], &hc[i]);
            let group = self.model.group(i);
            let root_group = self.model.in_root_group(i);
            let free = group.clone().map(|m| {
                let sdot = sp::crm(g, &r.v[m.end - 1], s);
                if root_group {
                    sdot
                } else {
                    sp::add(g, &sd[i], &sdot)
                }
            });
            let isd2 = match free {
                Some(sdot) => ic[i].apply(g, &sdot),
                None => sp::add(g, &isd, &isd),
            };
            let t2 = sp::add(g, &ds, &sh);
            let t2 = sp::add(g, &t2, &isd2);
            let t3 = sp::add(g, &dsd, &sdh);
            let t3i = sp::add(g, &t3, &isdd);
            let t3 = match root_group {
                true => t3i,
                false => {
                    let sf = sp::crf(g, s, &r.f[i]);
                    sp::add(g, &t3i, &sf)
                }
            };
            let t4 = sp::sub(g, &ds, &sh);
            // The diagonal pair in the body's own frame, where S is sparsest.
            let entries = |g: &mut Graph, [t1, _, _, t4]: &[Sv; 4], sd: &Sv, sdd: &Sv, free| {
                let a = sp::dot(g, t1, sdd);
                let b = sp::dot(g, t4, sd);
                let q = g.add(a, b);
                let a2 = match free {
                    Some(sdot) => sp::dot(g, t1, &sdot),
                    None => {
                        let a = sp::dot(g, t1, sd);
                        g.add(a, a)
                    }
                };
                let b = sp::dot(g, t4, s);
                (q, g.add(a2, b))
            };
            let own = [is, t2, t3, t4];
            (dc_q[i][i], dc_qd[i][i]) = entries(g, &own, &sd[i], &sdd[i], free);
            if below {
                let pose = &poses[i];
                let sw = motion_out(g, pose, s);
                let sdw = motion_out(g, pose, &sd[i]);
                let sddw = motion_out(g, pose, &sdd[i]);
                let freew = free.map(|f| motion_out(g, pose, &f));
                for j in i + 1..end {
                    let inner = group.as_ref().is_some_and(|m| m.contains(&j));
                    dc_q[i][j] = sp::dot(g, &sw, if inner { &t3_inner[j] } else { &t[j][2] });
                    dc_qd[i][j] = sp::dot(g, &sw, &t[j][1]);
                    let a = sp::dot(g, &t[j][0], &sddw);
                    let b = sp::dot(g, &t[j][3], &sdw);
                    dc_q[j][i] = g.add(a, b);
                    let a2 = match freew {
                        Some(sdot) => sp::dot(g, &t[j][0], &sdot),
                        None => {
                            let a = sp::dot(g, &t[j][0], &sdw);
                            g.add(a, a)
                        }
                    };
                    let b = sp::dot(g, &t[j][3], &sw);
                    dc_qd[j][i] = g.add(a2, b);
                }
            }
            if let Some(p) = parent {
                let pose = &poses[i];
                t[i] = own.map(|v| force_out(g, pose, &v));
                if group.is_some() {
                    t3_inner[i] = force_out(g, pose, &t3i);
                }
                let up = ic[i].to_parent(g, &self.x[i]);
                ic[p] = ic[p].add(g, &up);
                let up = dc[i].to_parent(g, &self.x[i]);
                dc[p] = dc[p].add(g, &up);
                let up = self.x[i].apply_t(g, &hc[i]);
                hc[p] = sp::add(g, &hc[p], &up);
            }
        }
        (dc_q, dc_qd)
    }
}
