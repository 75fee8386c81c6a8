//! ∂c/∂q and ∂c/∂q̇ of RNEA, recorded in one of three formulations: per-column forward
//! derivatives (Carpentier & Mansard 2018), or IDSVA's per-pair form (Singh, Russell &
//! Wensing 2022) in body frames here or in one frame per tree (`rnea_grad_world.rs`),
//! picked per robot by operation count.

use super::super::graph::{Graph, Id, Stage};
use super::super::kernel::Gradient;
use super::super::spatial::{self as sp, Sv, SymInertia};
use super::{velocity_of, Dynamics, Mat, Rnea};

impl Dynamics<'_> {
    /// `(∂c/∂q, ∂c/∂q̇)` in the chosen formulation.
    pub fn rnea_grad(&mut self, r: &Rnea, qd: &[Id]) -> (Mat, Mat) {
        let (mut dq, dqd) = match self.gradient {
            Gradient::Idsva => self.rnea_grad_idsva(r),
            Gradient::World => self.rnea_grad_world(r),
            Gradient::Columns | Gradient::Auto => self.rnea_grad_columns(r, qd),
        };
        self.add_contact_q_terms(&mut dq);
        (dq, dqd)
    }

    /// `(∂c/∂q, ∂c/∂q̇)` (Carpentier & Mansard 2018, as in `reference::rnea_derivatives`),
    /// column u of body i built only where it can be nonzero.
    fn rnea_grad_columns(&mut self, r: &Rnea, qd: &[Id]) -> (Mat, Mat) {
        let n = self.n();
        let z = sp::zero(&mut self.g);
        let none = || vec![None::<Sv>; n];
        let (mut dv_q, mut dv_qd, mut da_q, mut da_qd) =
            (vec![none(); n], vec![none(); n], vec![none(); n], vec![none(); n]);
        let (mut df_q, mut df_qd) = (vec![none(); n], vec![none(); n]);
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Forward);
            let parent = self.model.joints[i].parent;
            let group = self.model.group(i);
            // The velocity product's joint velocity: S_i q̇_i, a multi-dof joint's v_J at its
            // last member (with a moving parent), none at its other members.
            let product =
                group.as_ref().is_none_or(|m| i + 1 == m.end && !self.model.in_root_group(i));
            let members = group.clone().unwrap_or(i..i + 1);
            let cols = self.motion_cols(i);
            let g = &mut self.g;
            let vj = velocity_of(g, &self.s, qd, members.clone());
            for u in cols {
                let from =
                    |m: &Vec<Vec<Option<Sv>>>, g: &mut Graph| match parent.and_then(|p| m[p][u]) {
                        Some(col) => self.x[i].apply(g, &col),
                        None => z,
                    };
                let mut dvq = from(&dv_q, g);
                let mut dvqd = from(&dv_qd, g);
                let mut daq = from(&da_q, g);
                let mut daqd = from(&da_qd, g);
                if u == i {
                    let t = sp::crm(g, &r.xv[i], &self.s[i]);
                    dvq = sp::add(g, &dvq, &t);
                    dvqd = sp::add(g, &dvqd, &self.s[i]);
                    let t = sp::crm(g, &r.xa[i], &self.s[i]);
                    daq = sp::add(g, &daq, &t);
                }
                if product && members.contains(&u) {
                    let t = sp::crm(g, &r.v[i], &self.s[u]);
                    daqd = sp::add(g, &daqd, &t);
                }
                if product {
                    let t = sp::crm(g, &dvq, &vj);
                    daq = sp::add(g, &daq, &t);
                    let t = sp::crm(g, &dvqd, &vj);
                    daqd = sp::add(g, &daqd, &t);
                }
                for (dv, da, df) in [(dvq, daq, &mut df_q[i][u]), (dvqd, daqd, &mut df_qd[i][u])] {
                    let ida = self.inertia[i].apply(g, &da);
                    let idv = self.inertia[i].apply(g, &dv);
                    let t1 = sp::crf(g, &dv, &r.iv[i]);
                    let t2 = sp::crf(g, &r.v[i], &idv);
                    let t = sp::add(g, &ida, &t1);
                    *df = Some(sp::add(g, &t, &t2));
                }
                dv_q[i][u] = Some(dvq);
                dv_qd[i][u] = Some(dvqd);
                da_q[i][u] = Some(daq);
                da_qd[i][u] = Some(daqd);
            }
        }
        let zero = self.g.constant(0.0);
        let (mut dc_q, mut dc_qd) = (vec![vec![zero; n]; n], vec![vec![zero; n]; n]);
        for i in (0..n).rev() {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Backward);
            let cols = self.force_cols(i);
            let g = &mut self.g;
            for &u in &cols {
                for (df, dc) in [(&df_q, &mut dc_q), (&df_qd, &mut dc_qd)] {
                    if let Some(col) = df[i][u] {
                        dc[i][u] = sp::dot(g, &self.s[i], &col);
                    }
                }
            }
            if let Some(p) = self.model.joints[i].parent {
                for &u in &cols {
                    for df in [&mut df_q, &mut df_qd] {
                        if let Some(col) = df[i][u] {
                            let moved = self.x[i].apply_t(g, &col);
                            df[p][u] = Some(match df[p][u] {
                                Some(old) => sp::add(g, &old, &moved),
                                None => moved,
                            });
                        }
                    }
                }
                // iXλᵀ (S_i ×* f_i) in the q_i column; for a multi-dof joint at its first
                // member in every member's column (between members: none).
                let members = match self.model.group(i) {
                    None => i..i + 1,
                    Some(m) if m.start == i => m,
                    Some(_) => i..i,
                };
                for m in members {
                    let sf = sp::crf(g, &self.s[m], &r.f[i]);
                    let moved = self.x[i].apply_t(g, &sf);
                    let old = df_q[p][m].unwrap_or(z);
                    df_q[p][m] = Some(sp::add(g, &old, &moved));
                }
            }
        }
        (dc_q, dc_qd)
    }

    /// `(∂c/∂q, ∂c/∂q̇)` by IDSVA (Singh, Russell & Wensing, "Efficient Analytical
    /// Derivatives of Rigid-Body Dynamics using Spatial Vector Algebra", RA-L 2022,
    /// Algorithm 1; `ID_derivatives.m` of spatial_v2_extended), in body coordinates.
    ///
    /// Each joint computes its four force vectors t1..t4 once, in its own frame
    /// ([`Self::idsva_joint`]); they are carried up to every ancestor with one Xᵀ each,
    /// where six dot products give the pair's four entries. Dot products pair a motion
    /// with a force, so any common frame gives the paper's world-frame values.
    pub fn rnea_grad_idsva(&mut self, r: &Rnea) -> (Mat, Mat) {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let (mut dc_q, mut dc_qd) = (vec![vec![zero; n]; n], vec![vec![zero; n]; n]);
        let Some(mut st) = self.idsva_start(r) else { return (dc_q, dc_qd) };
        // t1..t4 of every joint, in the frame of the last ancestor reached.
        let mut t: Vec<[Sv; 4]> = vec![[[zero; 6]; 4]; n];
        // A multi-dof joint's members: t3 without S ×* f, for the pairs between members
        // (in their common frame).
        let mut t3_inner: Vec<Sv> = vec![[zero; 6]; n];
        for i in (0..n).rev() {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Backward);
            let end = self.model.joints[i].subtree_end;
            let group = self.model.group(i);
            let joint = self.idsva_joint(&st, r, i);
            t[i] = joint.t;
            t3_inner[i] = joint.t3_inner;
            let g = &mut self.g;
            let s = &self.s[i];
            for j in i..end {
                if j != i {
                    let inner = group.as_ref().is_some_and(|m| m.contains(&j));
                    dc_q[i][j] = sp::dot(g, s, if inner { &t3_inner[j] } else { &t[j][2] });
                    dc_qd[i][j] = sp::dot(g, s, &t[j][1]);
                }
                (dc_q[j][i], dc_qd[j][i]) =
                    pair_entries(g, &t[j], [s, &st.sd[i], &st.sdd[i]], joint.free.as_ref());
            }
            if let Some(p) = self.model.joints[i].parent {
                for tj in &mut t[i..end] {
                    *tj = tj.map(|v| self.x[i].apply_t(g, &v));
                }
                self.idsva_up(&mut st, i, p);
            }
        }
        (dc_q, dc_qd)
    }

    /// What IDSVA needs before its backward pass: Ψ̇ = v_λ × S and Ψ̈ = a_λ × S + v_λ × Ψ̇
    /// (a_λ carries gravity; the paper's Ṡ + Ψ̇ term for q̇ is 2Ψ̇ for one-dof joints, as
    /// S × S = 0), and the composites seeded with each body's own inertia, its rate and
    /// momentum. `None` once the graph is exhausted.
    pub(super) fn idsva_start(&mut self, r: &Rnea) -> Option<IdsvaState> {
        let n = self.n();
        let mut sd = Vec::with_capacity(n);
        let mut sdd = Vec::with_capacity(n);
        for i in 0..n {
            if self.exhausted() {
                return None;
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            let d = sp::crm(g, &r.xv[i], &self.s[i]);
            let t1 = sp::crm(g, &r.xa[i], &self.s[i]);
            let t2 = sp::crm(g, &r.xv[i], &d);
            sdd.push(sp::add(g, &t1, &t2));
            sd.push(d);
        }
        let mut dc: Vec<SymInertia> = Vec::with_capacity(n);
        for i in 0..n {
            self.at(i, Stage::Forward);
            dc.push(self.inertia[i].rate(&mut self.g, &r.v[i]));
        }
        Some(IdsvaState { sd, sdd, ic: self.inertia.clone(), dc, hc: r.iv.clone() })
    }

    /// Joint i's force vectors, in its own frame, from its subtree's composites (which
    /// must hold the whole subtree: call after [`Self::idsva_up`] of every child).
    ///
    /// The paper's composite `B^C` is kept as `D^C + (H^C)×̄` (its symmetric part is the
    /// rate of the composite inertia, inertia-shaped; the rest is the composite momentum
    /// H^C, so `B^C s = D^C s + s ×* H^C` and `B^Cᵀ s = D^C s − s ×* H^C`). A multi-dof
    /// joint is one joint (`Model::group`): Ṡ + Ψ̇ is v_J × S + Ψ̇ (not 2Ψ̇: S_k × S_m ≠
    /// 0), with v_J the last member's velocity; Ψ̇ = 0 at the root; and no S ×* f term
    /// between members.
    pub(super) fn idsva_joint(&mut self, st: &IdsvaState, r: &Rnea, i: usize) -> IdsvaJoint {
        let g = &mut self.g;
        let s = &self.s[i];
        let (ic, dc, hc, sd, sdd) = (&st.ic[i], &st.dc[i], &st.hc[i], &st.sd[i], &st.sdd[i]);
        let is = ic.apply(g, s);
        let isd = ic.apply(g, sd);
        let isdd = ic.apply(g, sdd);
        let ds = dc.apply(g, s);
        let dsd = dc.apply(g, sd);
        let sh = sp::crf(g, s, hc);
        let sdh = sp::crf(g, sd, hc);
        let root_group = self.model.in_root_group(i);
        let free = self.model.group(i).map(|m| {
            let sdot = sp::crm(g, &r.v[m.end - 1], s);
            if root_group {
                sdot
            } else {
                sp::add(g, sd, &sdot)
            }
        });
        let isd2 = match free {
            Some(sdot) => ic.apply(g, &sdot),
            None => sp::add(g, &isd, &isd),
        };
        let t2 = sp::add(g, &ds, &sh);
        let t2 = sp::add(g, &t2, &isd2);
        let t3 = sp::add(g, &dsd, &sdh);
        let t3_inner = sp::add(g, &t3, &isdd);
        let t3 = match root_group {
            true => t3_inner,
            false => {
                let sf = sp::crf(g, s, &r.f[i]);
                sp::add(g, &t3_inner, &sf)
            }
        };
        let t4 = sp::sub(g, &ds, &sh);
        IdsvaJoint { t: [is, t2, t3, t4], t3_inner, free }
    }

    /// Adds body i's composites to its parent's.
    pub(super) fn idsva_up(&mut self, st: &mut IdsvaState, i: usize, p: usize) {
        let g = &mut self.g;
        let up = st.ic[i].to_parent(g, &self.x[i]);
        st.ic[p] = st.ic[p].add(g, &up);
        let up = st.dc[i].to_parent(g, &self.x[i]);
        st.dc[p] = st.dc[p].add(g, &up);
        let up = self.x[i].apply_t(g, &st.hc[i]);
        st.hc[p] = sp::add(g, &st.hc[p], &up);
    }
}

/// IDSVA's per-joint motion terms and the subtree composites, in body frames.
pub(super) struct IdsvaState {
    /// Ψ̇ and Ψ̈ of every joint.
    pub sd: Vec<Sv>,
    pub sdd: Vec<Sv>,
    /// Composite inertia, its rate, and momentum of each subtree reached so far.
    ic: Vec<SymInertia>,
    dc: Vec<SymInertia>,
    hc: Vec<Sv>,
}

/// One joint's IDSVA force vectors, in its frame.
pub(super) struct IdsvaJoint {
    /// t1..t4 (t1 = I^C S; t3 with S ×* f below the root group).
    pub t: [Sv; 4],
    /// t3 without S ×* f, for the pairs between a multi-dof joint's members.
    pub t3_inner: Sv,
    /// A multi-dof joint's Ṡ + Ψ̇ (see [`Dynamics::idsva_joint`]); `None`: 2Ψ̇.
    pub free: Option<Sv>,
}

/// `(∂c_j/∂q_i, ∂c_j/∂q̇_i)` of joint j at or below joint i, from j's t1..t4 and i's
/// `[S, Ψ̇, Ψ̈]` in one frame, and i's multi-dof `Ṡ + Ψ̇`.
pub(super) fn pair_entries(
    g: &mut Graph,
    [t1, _, _, t4]: &[Sv; 4],
    [s, sd, sdd]: [&Sv; 3],
    free: Option<&Sv>,
) -> (Id, Id) {
    let a = sp::dot(g, t1, sdd);
    let b = sp::dot(g, t4, sd);
    let q = g.add(a, b);
    let a2 = match free {
        Some(sdot) => sp::dot(g, t1, sdot),
        None => {
            let a = sp::dot(g, t1, sd);
            g.add(a, a)
        }
    };
    let b = sp::dot(g, t4, s);
    (q, g.add(a2, b))
}
