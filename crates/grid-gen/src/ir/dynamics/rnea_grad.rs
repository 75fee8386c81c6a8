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
    /// The paper's composite `B^C` is kept as `D^C + (H^C)×̄` (its symmetric part is the
    /// rate of the composite inertia, inertia-shaped; the rest is the composite momentum
    /// H^C, so `B^C s = D^C s + s ×* H^C` and `B^Cᵀ s = D^C s − s ×* H^C`). Each joint
    /// computes its four force vectors t1..t4 once, in its own frame; they are carried
    /// up to every ancestor with one Xᵀ each, where six dot products give the pair's
    /// four entries. Dot products pair a motion with a force, so any common frame gives
    /// the paper's world-frame values.
    pub fn rnea_grad_idsva(&mut self, r: &Rnea) -> (Mat, Mat) {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let (mut dc_q, mut dc_qd) = (vec![vec![zero; n]; n], vec![vec![zero; n]; n]);
        // Ψ̇ = v_λ × S, Ψ̈ = a_λ × S + v_λ × Ψ̇ (a_λ carries gravity); the paper's
        // Ṡ + Ψ̇ term for q̇ is 2Ψ̇ for one-dof joints (S × S = 0).
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
        // Composites of the subtree, in the body's frame: inertia, its rate, momentum.
        let mut ic: Vec<SymInertia> = self.inertia.clone();
        let mut dc: Vec<SymInertia> = Vec::with_capacity(n);
        for i in 0..n {
            self.at(i, Stage::Forward);
            dc.push(self.inertia[i].rate(&mut self.g, &r.v[i]));
        }
        let mut hc: Vec<Sv> = r.iv.clone();
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
            let g = &mut self.g;
            let s = &self.s[i];
            let is = ic[i].apply(g, s);
            let isd = ic[i].apply(g, &sd[i]);
            let isdd = ic[i].apply(g, &sdd[i]);
            let ds = dc[i].apply(g, s);
            let dsd = dc[i].apply(g, &sd[i]);
            let sh = sp::crf(g, s, &hc[i]);
            let sdh = sp::crf(g, &sd[i], &hc[i]);
            // A multi-dof joint is one joint (`Model::group`): Ṡ + Ψ̇ is v_J × S + Ψ̇ (not
            // 2Ψ̇: S_k × S_m ≠ 0), with v_J the last member's velocity; Ψ̇ = 0 at the root;
            // and no S ×* f term between members.
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
            let t3 = sp::add(g, &t3, &isdd);
            t3_inner[i] = t3;
            let t3 = match root_group {
                true => t3,
                false => {
                    let sf = sp::crf(g, s, &r.f[i]);
                    sp::add(g, &t3, &sf)
                }
            };
            let t4 = sp::sub(g, &ds, &sh);
            t[i] = [is, t2, t3, t4];
            for j in i..end {
                let [t1, t2, t3, t4] = t[j];
                if j != i {
                    let inner = group.as_ref().is_some_and(|m| m.contains(&j));
                    dc_q[i][j] = sp::dot(g, s, if inner { &t3_inner[j] } else { &t3 });
                    dc_qd[i][j] = sp::dot(g, s, &t2);
                }
                let a = sp::dot(g, &t1, &sdd[i]);
                let b = sp::dot(g, &t4, &sd[i]);
                dc_q[j][i] = g.add(a, b);
                let a2 = match free {
                    Some(sdot) => sp::dot(g, &t1, &sdot),
                    None => {
                        let a = sp::dot(g, &t1, &sd[i]);
                        g.add(a, a)
                    }
                };
                let b = sp::dot(g, &t4, s);
                dc_qd[j][i] = g.add(a2, b);
            }
            if let Some(p) = self.model.joints[i].parent {
                for tj in &mut t[i..end] {
                    *tj = tj.map(|v| self.x[i].apply_t(g, &v));
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
