//! CRBA, recorded: the joint-space mass matrix M(q) from composite inertias.

use super::super::graph::{Id, Stage};
use super::super::spatial::{self as sp};
use super::{Dynamics, Mat};

impl Dynamics<'_> {
    pub(super) fn composite_start(&mut self) -> Vec<[[Id; 6]; 6]> {
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
}
