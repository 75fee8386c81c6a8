//! The algorithms run symbolically over the model: RNEA, ∇RNEA, CRBA, the direct M⁻¹,
//! forward dynamics and ∇FD, recorded into a [`Graph`]. The same recursions as
//! `reference`, written over (E, r) transforms and structural sparsity: a gradient column
//! is only built where the model says it can be nonzero (`sparse` off turns that off, for
//! the "before specialisation" counts).
//!
//! Every per-body loop stops once the graph is exhausted (see [`Graph`]), so that a robot
//! too large for the node limit costs at most one body's work past the limit.

use super::graph::{Graph, Id, Input, Stage};
use super::kernel::{Gradient, Solve};
use super::spatial::{self as sp, joint_xform, subspace, Sv, SymInertia, Xform};
use crate::model::Model;

mod contact;
mod coupled;
mod forces;
mod frames;
mod step;

pub(crate) use forces::{transpose, Forces, LambdaSource};

/// Row-major n x n matrix of nodes.
pub type Mat = Vec<Vec<Id>>;

pub(crate) struct Dynamics<'a> {
    pub g: Graph,
    /// Which formulation [`Self::rnea_grad`] records (never `Auto` here).
    pub gradient: Gradient,
    sparse: bool,
    model: &'a Model,
    gravity: [f64; 3],
    x: Vec<Xform>,
    s: Vec<Sv>,
    inertia: Vec<SymInertia>,
    /// Set by [`Self::fd_grad`]: the operands of its dense product.
    pub product: Option<super::module::DenseProduct>,
    /// How [`Self::fd_grad`] gets q̈ and applies M⁻¹ to ∂c/∂u (`Auto` runs `Minv`); after
    /// recording, the solve it took.
    pub solve: Solve,
    /// The external and contact forces on the bodies, once [`Self::load_forces`] has read
    /// the kernel's force inputs: RNEA subtracts them, ABA adds them to its bias forces.
    forces: Forces,
    /// The configuration's nodes when the joint transforms were built from nodes other than
    /// the kernel's q input (an RK4 stage's `q ⊕ dq`), so that derivatives with respect to
    /// "q" there seed those nodes.
    config: Option<Vec<Id>>,
}

/// The RNEA quantities the gradient needs.
pub(crate) struct Rnea {
    pub c: Vec<Id>,
    v: Vec<Sv>,
    xv: Vec<Sv>,
    xa: Vec<Sv>,
    /// Body accelerations (gravity's a₀ included).
    a: Vec<Sv>,
    iv: Vec<Sv>,
    /// Body forces after the backward pass (children included).
    f: Vec<Sv>,
}

impl<'a> Dynamics<'a> {
    /// Records the joint transforms (sin/cos, E, r) for every joint.
    pub fn new(
        model: &'a Model,
        gravity: [f64; 3],
        fold: bool,
        sparse: bool,
        limit: usize,
    ) -> Self {
        let mut g = Graph::new(fold, limit);
        let mut x = Vec::new();
        let mut s = Vec::new();
        let mut inertia = Vec::new();
        for i in 0..model.njoints() {
            g.at(Some(i), Stage::Transform, model.joints[i].level);
            x.push(joint_xform(&mut g, model, i));
            s.push(subspace(&mut g, &model.joints[i]));
            inertia.push(SymInertia::new(&mut g, &model.joints[i].inertia));
        }
        Dynamics {
            g,
            gradient: Gradient::Columns,
            sparse,
            model,
            gravity,
            x,
            s,
            inertia,
            product: None,
            solve: Solve::Minv,
            forces: Forces::default(),
            config: None,
        }
    }

    /// Model joints (bodies): what the recursions loop over. The kernels' inputs and
    /// outputs have one entry per coordinate instead (fewer with coupled mimic joints).
    fn n(&self) -> usize {
        self.model.njoints()
    }

    fn dense(&self) -> bool {
        !self.sparse
    }

    fn exhausted(&self) -> bool {
        self.g.exhausted()
    }

    /// One node per coordinate of a velocity-sized input.
    pub fn inputs(&mut self, input: Input) -> Vec<Id> {
        let nv = self.model.nv();
        if input == Input::Qd && self.model.specialisation.static_velocity {
            // A static scene: q̇ = 0 is a constant, and folding removes every velocity term.
            return (0..nv).map(|_| self.g.constant(0.0)).collect();
        }
        (0..nv).map(|i| self.g.input(input, i)).collect()
    }

    /// The root's spatial acceleration that stands in for gravity: a₀ = −g (Featherstone
    /// 2008, §5.3), shared by RNEA and ABA.
    fn root_acceleration(&mut self) -> Sv {
        let z = sp::zero(&mut self.g);
        let g = &mut self.g;
        [
            z[0],
            z[1],
            z[2],
            g.constant(-self.gravity[0]),
            g.constant(-self.gravity[1]),
            g.constant(-self.gravity[2]),
        ]
    }

    fn at(&mut self, i: usize, stage: Stage) {
        self.g.at(Some(i), stage, self.model.joints[i].level);
    }

    /// Gradient columns of v_i, a_i that can be nonzero: ancestors of i and i.
    fn motion_cols(&self, i: usize) -> Vec<usize> {
        if self.dense() {
            (0..self.n()).collect()
        } else {
            self.model.ancestors(i)
        }
    }

    /// Gradient columns of f_i that can be nonzero: ancestors, i, and its subtree.
    fn force_cols(&self, i: usize) -> Vec<usize> {
        if self.dense() {
            (0..self.n()).collect()
        } else {
            let mut cols = self.model.ancestors(i);
            cols.extend(i + 1..self.model.joints[i].subtree_end);
            cols
        }
    }

    /// RNEA (Featherstone table 5.1) at symbolic q̇, q̈.
    pub fn rnea(&mut self, qd: &[Id], qdd: &[Id]) -> Rnea {
        let n = self.n();
        let z = sp::zero(&mut self.g);
        let a0 = self.root_acceleration();
        let (mut v, mut xv, mut xa, mut a, mut f, mut iv) =
            (vec![z; n], vec![z; n], vec![z; n], vec![z; n], vec![z; n], vec![z; n]);
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.g.at(Some(i), Stage::Forward, self.model.joints[i].level);
            let g = &mut self.g;
            let (vp, ap) = match self.model.joints[i].parent {
                Some(p) => (v[p], a[p]),
                None => (z, a0),
            };
            xv[i] = self.x[i].apply(g, &vp);
            xa[i] = self.x[i].apply(g, &ap);
            let vj = sp::scale(g, &self.s[i], qd[i]);
            v[i] = sp::add(g, &xv[i], &vj);
            let sa = sp::scale(g, &self.s[i], qdd[i]);
            if let Some(group) = self.model.group(i) {
                // One multi-dof joint (`Model::group`): the gradients see its parent's
                // velocity and acceleration at every member, and its velocity product
                // u × v_J is at the last member (none at the root, where u = 0).
                a[i] = sp::add(g, &xa[i], &sa);
                if self.model.in_root_group(i) {
                    xv[i] = z;
                } else {
                    xv[i] = xv[group.start];
                    if i + 1 == group.end {
                        let vjs = velocity_of(g, &self.s, qd, group.clone());
                        let cv = sp::crm(g, &xv[i], &vjs);
                        a[i] = sp::add(g, &a[i], &cv);
                    }
                }
                xa[i] = xa[group.start];
            } else {
                let cv = sp::crm(g, &v[i], &vj);
                let t = sp::add(g, &xa[i], &sa);
                a[i] = sp::add(g, &t, &cv);
            }
            iv[i] = self.inertia[i].apply(g, &v[i]);
            let ia = self.inertia[i].apply(g, &a[i]);
            let vf = sp::crf(g, &v[i], &iv[i]);
            f[i] = sp::add(g, &ia, &vf);
            if let Some(fe) = self.forces.on(i) {
                f[i] = sp::sub(g, &f[i], &fe);
            }
        }
        let mut c = vec![z[0]; n];
        for i in (0..n).rev() {
            self.at(i, Stage::Backward);
            let g = &mut self.g;
            c[i] = sp::dot(g, &self.s[i], &f[i]);
            if let Some(p) = self.model.joints[i].parent {
                let fp = self.x[i].apply_t(g, &f[i]);
                f[p] = sp::add(g, &f[p], &fp);
            }
        }
        Rnea { c, v, xv, xa, a, iv, f }
    }

    /// `(∂c/∂q, ∂c/∂q̇)` in the chosen formulation.
    pub fn rnea_grad(&mut self, r: &Rnea, qd: &[Id]) -> (Mat, Mat) {
        let (mut dq, dqd) = match self.gradient {
            Gradient::Idsva => self.rnea_grad_idsva(r),
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

    fn composite_start(&mut self) -> Vec<[[Id; 6]; 6]> {
        (0..self.n()).map(|i| self.inertia[i].to_matrix(&mut self.g)).collect()
    }

    /// CRBA (Featherstone table 6.2), composites kept inertia-shaped.
    pub fn mass_matrix(&mut self) -> Mat {
        let n = self.n();
        let mut ic = self.inertia.clone();
        for i in (0..n).rev() {
            self.at(i, Stage::Backward);
            if let Some(p) = self.model.joints[i].parent {
                let up = ic[i].to_parent(&mut self.g, &self.x[i]);
                ic[p] = ic[p].add(&mut self.g, &up);
            }
        }
        let zero = self.g.constant(0.0);
        let mut m = vec![vec![zero; n]; n];
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            let mut f = ic[i].apply(g, &self.s[i]);
            m[i][i] = sp::dot(g, &self.s[i], &f);
            let mut j = i;
            while let Some(p) = self.model.joints[j].parent {
                f = self.x[j].apply_t(g, &f);
                j = p;
                m[i][j] = sp::dot(g, &f, &self.s[j]);
                m[j][i] = m[i][j];
            }
        }
        m
    }

    /// The direct O(n²) M⁻¹ of `reference::minv`.
    pub fn minv(&mut self) -> Mat {
        let n = self.n();
        let mut ia = self.composite_start();
        let z = sp::zero(&mut self.g);
        let zero = z[0];
        let mut f: Vec<Vec<Option<Sv>>> = vec![vec![None; n]; n];
        let mut u = vec![z; n];
        let mut dinv = vec![zero; n];
        let mut minv: Vec<Vec<Option<Id>>> = vec![vec![None; n]; n];
        for i in (0..n).rev() {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Backward);
            let end = self.model.joints[i].subtree_end;
            let g = &mut self.g;
            (u[i], dinv[i]) = pivot(g, &ia[i], &self.s[i]);
            minv[i][i] = Some(dinv[i]);
            for j in i + 1..end {
                if let Some(col) = f[i][j] {
                    let sf = sp::dot(g, &self.s[i], &col);
                    let t = g.mul(dinv[i], sf);
                    minv[i][j] = Some(g.neg(t));
                }
            }
            if let Some(p) = self.model.joints[i].parent {
                for j in i..end {
                    let um = sp::scale(g, &u[i], minv[i][j].unwrap_or(zero));
                    let col = match f[i][j] {
                        Some(c) => sp::add(g, &c, &um),
                        None => um,
                    };
                    let moved = self.x[i].apply_t(g, &col);
                    f[p][j] = Some(match f[p][j] {
                        Some(old) => sp::add(g, &old, &moved),
                        None => moved,
                    });
                }
                let ia_a = articulated(g, &ia[i], &u[i], dinv[i]);
                let add = sp::congruence(g, &self.x[i], &ia_a);
                ia[p] = add6(g, &ia[p], &add);
            }
        }
        let mut pacc: Vec<Vec<Option<Sv>>> = vec![vec![None; n]; n];
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            for j in i..n {
                let xp = match self.model.joints[i].parent.and_then(|p| pacc[p][j]) {
                    Some(col) => {
                        let xp = self.x[i].apply(g, &col);
                        let ux = sp::dot(g, &u[i], &xp);
                        let t = g.mul(dinv[i], ux);
                        let old = minv[i][j].unwrap_or(zero);
                        minv[i][j] = Some(g.sub(old, t));
                        xp
                    }
                    None => z,
                };
                let sm = sp::scale(g, &self.s[i], minv[i][j].unwrap_or(zero));
                pacc[i][j] = Some(sp::add(g, &xp, &sm));
            }
        }
        (0..n).map(|i| (0..n).map(|j| minv[i.min(j)][i.max(j)].unwrap_or(zero)).collect()).collect()
    }

    /// M⁻¹ per coordinate: [`Self::minv`], projected onto the mimic constraints when
    /// some joint is coupled.
    pub fn minv_coordinates(&mut self) -> Mat {
        let mi = self.minv();
        if !self.coupled() {
            return mi;
        }
        self.g.at(None, Stage::Combine, 0);
        let k = self.constraints(&mi);
        self.project_minv(&mi, &k)
    }

    /// Forward dynamics per coordinate: [`Self::aba`], or with coupled mimic joints the
    /// unconstrained ABA under `τ_joints = Pᵀ τ` projected onto the constraints.
    pub fn fd(&mut self, qd: &[Id], tau: &[Id]) -> Vec<Id> {
        if !self.coupled() {
            return self.aba(qd, tau);
        }
        self.fd_minv(qd, tau).0
    }

    /// q̈ and M⁻¹ per coordinate, sharing the constraint terms.
    fn fd_minv(&mut self, qd: &[Id], tau: &[Id]) -> (Vec<Id>, Mat) {
        if !self.coupled() {
            let qdd = self.aba(qd, tau);
            return (qdd, self.minv());
        }
        let (qd, tau) = (self.expand(qd), self.place(tau));
        let a = self.aba(&qd, &tau);
        let mi = self.minv();
        self.g.at(None, Stage::Combine, 0);
        let k = self.constraints(&mi);
        let qdd = self.project_acceleration(&a, &k);
        (qdd, self.project_minv(&mi, &k))
    }

    /// Forward dynamics by the articulated-body algorithm (Featherstone 2008, table 7.1),
    /// O(n). Its articulated inertias, U and D⁻¹ are recorded exactly as [`Self::minv`]
    /// records them, so `fd_grad` shares them. Why not `M⁻¹ (τ − c)`: with cond(M) = 1e5
    /// (a 100-link chain) that product loses 40x more to rounding than ABA, and ∂q̈/∂q,
    /// evaluated at q̈, amplifies the difference to 1e-9 against ABA's 1e-12 (Pinocchio's
    /// `computeABADerivatives` takes q̈ from ABA for the same reason).
    pub fn aba(&mut self, qd: &[Id], tau: &[Id]) -> Vec<Id> {
        let n = self.n();
        let z = sp::zero(&mut self.g);
        let (mut v, mut c, mut pa, mut xv) = (vec![z; n], vec![z; n], vec![z; n], vec![z; n]);
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            let vp = self.model.joints[i].parent.map_or(z, |p| v[p]);
            // The same nodes as `rnea`'s velocity pass, so fd_grad shares them.
            xv[i] = self.x[i].apply(g, &vp);
            let vj = sp::scale(g, &self.s[i], qd[i]);
            v[i] = sp::add(g, &xv[i], &vj);
            c[i] = match self.model.group(i) {
                None => sp::crm(g, &v[i], &vj),
                Some(m) if i + 1 == m.end && !self.model.in_root_group(i) => {
                    let vjs = velocity_of(g, &self.s, qd, m.clone());
                    sp::crm(g, &xv[m.start], &vjs)
                }
                Some(_) => z,
            };
            let iv = self.inertia[i].apply(g, &v[i]);
            pa[i] = sp::crf(g, &v[i], &iv);
            if let Some(fe) = self.forces.on(i) {
                pa[i] = sp::sub(g, &pa[i], &fe);
            }
        }
        let mut ia = self.composite_start();
        let (mut u, mut dinv, mut uu) = (vec![z; n], vec![z[0]; n], vec![z[0]; n]);
        for i in (0..n).rev() {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Backward);
            let g = &mut self.g;
            (u[i], dinv[i]) = pivot(g, &ia[i], &self.s[i]);
            let sp_a = sp::dot(g, &self.s[i], &pa[i]);
            uu[i] = g.sub(tau[i], sp_a);
            if let Some(p) = self.model.joints[i].parent {
                let ia_a = articulated(g, &ia[i], &u[i], dinv[i]);
                let ia_c = sp::mat6_vec(g, &ia_a, &c[i]);
                let du = g.mul(dinv[i], uu[i]);
                let ud = sp::scale(g, &u[i], du);
                let t = sp::add(g, &pa[i], &ia_c);
                let pa_a = sp::add(g, &t, &ud);
                let moved = self.x[i].apply_t(g, &pa_a);
                pa[p] = sp::add(g, &pa[p], &moved);
                let add = sp::congruence(g, &self.x[i], &ia_a);
                ia[p] = add6(g, &ia[p], &add);
            }
        }
        let a0 = self.root_acceleration();
        let mut a = vec![z; n];
        let mut qdd = vec![z[0]; n];
        for i in 0..n {
            if self.exhausted() {
                break;
            }
            self.at(i, Stage::Forward);
            let g = &mut self.g;
            let ap = self.model.joints[i].parent.map_or(a0, |p| a[p]);
            let xa = self.x[i].apply(g, &ap);
            let a_bias = sp::add(g, &xa, &c[i]);
            let ua = sp::dot(g, &u[i], &a_bias);
            let r = g.sub(uu[i], ua);
            qdd[i] = g.mul(dinv[i], r);
            let sq = sp::scale(g, &self.s[i], qdd[i]);
            a[i] = sp::add(g, &a_bias, &sq);
        }
        qdd
    }

    /// `∂q̈/∂u = −M⁻¹ ∂c/∂u` at the q̈ of [`Self::aba`] (Carpentier & Mansard 2018, eq. 9;
    /// Pinocchio's `computeABADerivatives`), sharing through hash-consing ABA's
    /// articulated inertias with M⁻¹ and its velocities with the RNEA pass.
    /// Per-coordinate inputs and outputs: with coupled mimic joints q̈ and M⁻¹ are the
    /// constrained ones and the gradient `−M⁻¹ Gᵀ (∂c/∂u) G`.
    /// Also `∂q̈/∂τ` for the coordinates `columns` (those columns of M⁻¹),
    /// and `−M⁻¹ b` for each per-coordinate vector b of `rhs`, both from the route that
    /// formed `∂q̈/∂u` (M⁻¹ itself, or its factorisation's solves).
    pub fn fd_grad(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        columns: &[usize],
        rhs: &[Vec<Id>],
    ) -> (Vec<Id>, Mat, Mat, Mat, Mat) {
        if matches!(self.solve, Solve::Ltdl | Solve::Crba) && !self.coupled() {
            return self.fd_grad_ltdl(qd, tau, columns, rhs);
        }
        // The constrained M⁻¹ of coupled mimic joints comes from the direct route.
        self.solve = Solve::Minv;
        let n = self.model.nv();
        let (qdd, mi) = self.fd_minv(qd, tau);
        let (qd, qdd_joints) = (self.expand(qd), self.expand(&qdd));
        let r = self.rnea(&qd, &qdd_joints);
        let (dc_q, dc_qd) = self.rnea_grad(&r, &qd);
        let (dc_q, dc_qd) = (self.reduce_matrix(dc_q), self.reduce_matrix(dc_qd));
        self.g.at(None, Stage::Combine, 0);
        let product = |dc: &Mat, g: &mut Graph| -> Mat {
            (0..n)
                .map(|i| {
                    if g.exhausted() {
                        return vec![Id(0); n];
                    }
                    (0..n)
                        .map(|k| {
                            let col: Vec<Id> = (0..n).map(|j| dc[j][k]).collect();
                            let d = g.dot(&mi[i], &col);
                            g.neg(d)
                        })
                        .collect()
                })
                .collect()
        };
        let dq = product(&dc_q, &mut self.g);
        let dqd = product(&dc_qd, &mut self.g);
        let flat = |m: &Mat| {
            m.iter().flatten().map(|&id| super::module::Operand::Node(id)).collect::<Vec<_>>()
        };
        self.product = Some(super::module::DenseProduct {
            minv: flat(&mi),
            dc: vec![flat(&dc_q), flat(&dc_qd)],
            outputs: vec![1, 2],
        });
        let picked = mi.iter().map(|row| columns.iter().map(|&c| row[c]).collect()).collect();
        let solved = rhs
            .iter()
            .map(|b| {
                (0..n)
                    .map(|i| {
                        let d = self.g.dot(&mi[i], b);
                        self.g.neg(d)
                    })
                    .collect()
            })
            .collect();
        (qdd, dq, dqd, picked, solved)
    }
}

impl Dynamics<'_> {
    /// [`Self::fd_grad`] by [`Solve::Ltdl`] (q̈ by ABA) or [`Solve::Crba`] (q̈ from the
    /// factorisation, `−M⁻¹ (c(q, q̇, 0) − τ)`): ∂c/∂u at q̈, M by CRBA (whose
    /// composites, `IC S` vectors and their moves to the ancestors are the IDSVA
    /// gradient's own nodes, shared by hash-consing), then `−M⁻¹ ∂c/∂u` by the
    /// factorisation. Zero entries of ∂c/∂u (joints on different branches) fold away, so
    /// each column's solves touch only the joints it can reach.
    fn fd_grad_ltdl(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        columns: &[usize],
        rhs: &[Vec<Id>],
    ) -> (Vec<Id>, Mat, Mat, Mat, Mat) {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let m = self.mass_matrix();
        // q̈ by ABA, or the bias forces c(q, q̇, 0) that the factorisation turns into q̈.
        let by_aba = (self.solve == Solve::Ltdl).then(|| self.aba(qd, tau));
        let bias = if by_aba.is_none() { self.rnea(qd, &vec![zero; n]).c } else { Vec::new() };
        let empty = |columns: usize| vec![vec![zero; columns]; n];
        if self.exhausted() {
            return (
                vec![zero; n],
                empty(n),
                empty(n),
                empty(columns.len()),
                vec![vec![zero; n]; rhs.len()],
            );
        }
        let f = self.ltdl(m);
        let qdd = by_aba.unwrap_or_else(|| {
            let b: Vec<Id> = (0..n).map(|i| self.g.sub(bias[i], tau[i])).collect();
            f.solve(&mut self.g, self.model, b)
        });
        let r = self.rnea(qd, &qdd);
        let (dc_q, dc_qd) = self.rnea_grad(&r, qd);
        if self.exhausted() {
            return (qdd, dc_q, dc_qd, empty(columns.len()), vec![vec![zero; n]; rhs.len()]);
        }
        self.g.at(None, Stage::Combine, 0);
        let g = &mut self.g;
        let mut solve = |dc: &Mat| -> Mat {
            let mut out = vec![vec![Id(0); n]; n];
            for c in 0..n {
                let x = f.solve(g, self.model, (0..n).map(|row| dc[row][c]).collect());
                for (row, x) in x.into_iter().enumerate() {
                    out[row][c] = x;
                }
            }
            out
        };
        let dq = solve(&dc_q);
        let dqd = solve(&dc_qd);
        // M⁻¹ e_c = −(−M⁻¹ e_c).
        let mut picked = vec![vec![zero; columns.len()]; n];
        for (at, &c) in columns.iter().enumerate() {
            let one = self.g.constant(1.0);
            let mut e = vec![zero; n];
            e[c] = one;
            for (row, x) in f.solve(&mut self.g, self.model, e).into_iter().enumerate() {
                picked[row][at] = self.g.neg(x);
            }
        }
        let solved = rhs.iter().map(|b| f.solve(&mut self.g, self.model, b.clone())).collect();
        (qdd, dq, dqd, picked, solved)
    }

    /// LTDL (Featherstone 2005, table 2): M's lower triangle becomes L (unit diagonal
    /// implied) and its diagonal D, rows visited leaves first. One division per joint,
    /// −1/D_k: the solves' diagonal step takes it as it is (the minus sign of −M⁻¹), and
    /// L's entries are −(M_ki · −1/D_k), whose negations the graph moves into the
    /// subtractions that read them (no node is left for them).
    fn ltdl(&mut self, mut m: Mat) -> Ltdl {
        let n = self.n();
        self.g.at(None, Stage::Combine, 0);
        let g = &mut self.g;
        let minus_one = g.constant(-1.0);
        let mut neg_dinv = vec![minus_one; n];
        for k in (0..n).rev() {
            neg_dinv[k] = g.div(minus_one, m[k][k]);
            let up = strict_ancestors(self.model, k);
            for (at, &i) in up.iter().enumerate() {
                let p = g.mul(m[k][i], neg_dinv[k]);
                let a = g.neg(p);
                for &j in &up[at..] {
                    let t = g.mul(a, m[k][j]);
                    m[i][j] = g.sub(m[i][j], t);
                }
                m[k][i] = a;
            }
        }
        Ltdl { l: m, neg_dinv }
    }
}

/// M = Lᵀ D L, as [`Dynamics::ltdl`] leaves it: L below the diagonal (row k, the
/// ancestors of k), and −1/D.
struct Ltdl {
    l: Mat,
    neg_dinv: Vec<Id>,
}

impl Ltdl {
    /// −M⁻¹ b: `Lᵀ y = b` leaves first, `z = −D⁻¹ y`, `L x = z` root first. Zero entries
    /// of b fold away, so a column touches only the joints it can reach.
    fn solve(&self, g: &mut Graph, model: &Model, mut b: Vec<Id>) -> Vec<Id> {
        let n = b.len();
        for k in (0..n).rev() {
            for j in strict_ancestors(model, k) {
                let t = g.mul(self.l[k][j], b[k]);
                b[j] = g.sub(b[j], t);
            }
        }
        for k in 0..n {
            b[k] = g.mul(b[k], self.neg_dinv[k]);
        }
        for k in 0..n {
            for j in strict_ancestors(model, k) {
                let t = g.mul(self.l[k][j], b[j]);
                b[k] = g.sub(b[k], t);
            }
        }
        b
    }
}

/// The ancestors of joint k, nearest first, k excluded: the order the factorisation and
/// the solves visit them.
fn strict_ancestors(model: &Model, k: usize) -> Vec<usize> {
    let mut up = model.ancestors(k);
    up.pop();
    up.reverse();
    up
}

/// `Σ S_m q̇_m` over joints `members`: one joint's `S q̇`, or a multi-dof joint's v_J.
fn velocity_of(g: &mut Graph, s: &[Sv], qd: &[Id], members: std::ops::Range<usize>) -> Sv {
    let mut out: Option<Sv> = None;
    for m in members {
        let vj = sp::scale(g, &s[m], qd[m]);
        out = Some(match out {
            Some(o) => sp::add(g, &o, &vj),
            None => vj,
        });
    }
    out.expect("a joint has at least one member")
}

/// ABA's pivot at one body: `U = IA S` and `D⁻¹ = 1 / (Sᵀ U)`.
fn pivot(g: &mut Graph, ia: &[[Id; 6]; 6], s: &Sv) -> (Sv, Id) {
    let u = sp::mat6_vec(g, ia, s);
    let d = sp::dot(g, s, &u);
    let one = g.constant(1.0);
    (u, g.div(one, d))
}

/// The articulated inertia a body hands its parent (before transforming):
/// `IA − U D⁻¹ Uᵀ`, symmetric, built once per upper-triangle entry.
fn articulated(g: &mut Graph, ia: &[[Id; 6]; 6], u: &Sv, dinv: Id) -> [[Id; 6]; 6] {
    let mut out = *ia;
    for r in 0..6 {
        for c in r..6 {
            let ud = g.mul(u[r], dinv);
            let t = g.mul(ud, u[c]);
            out[r][c] = g.sub(ia[r][c], t);
            out[c][r] = out[r][c];
        }
    }
    out
}

/// Sum of two symmetric 6x6 matrices, built once per upper-triangle entry.
fn add6(g: &mut Graph, a: &[[Id; 6]; 6], b: &[[Id; 6]; 6]) -> [[Id; 6]; 6] {
    let mut out = *a;
    for r in 0..6 {
        for c in r..6 {
            out[r][c] = g.add(a[r][c], b[r][c]);
            out[c][r] = out[r][c];
        }
    }
    out
}
