//! RNEA, recorded: the joint torques c(q, q̇, q̈) (gravity and external forces
//! included), keeping the body quantities the gradients reuse.

use super::super::graph::{Id, Stage};
use super::super::spatial::{self as sp};
use super::{velocity_of, Dynamics, Rnea};

impl Dynamics<'_> {
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
}
