//! Forward dynamics, recorded: ABA's q̈ and, with coupled mimic joints, the constrained
//! q̈ and M⁻¹ that `fd` and `fd_grad` share.

use super::super::graph::{Id, Stage};
use super::super::spatial::{self as sp};
use super::{add6, articulated, pivot, velocity_of, Dynamics, Mat};

impl Dynamics<'_> {
    /// Forward dynamics per coordinate: [`Self::aba`], or with coupled mimic joints the
    /// unconstrained ABA under `τ_joints = Pᵀ τ` projected onto the constraints.
    pub fn fd(&mut self, qd: &[Id], tau: &[Id]) -> Vec<Id> {
        if !self.coupled() {
            return self.aba(qd, tau);
        }
        self.fd_minv(qd, tau).0
    }

    /// q̈ and M⁻¹ per coordinate, sharing the constraint terms.
    pub(super) fn fd_minv(&mut self, qd: &[Id], tau: &[Id]) -> (Vec<Id>, Mat) {
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
}
