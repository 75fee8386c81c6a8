//! M⁻¹, recorded: the direct recursion (no M, no factorisation: articulated inertias and
//! one backward and one forward sweep, per joint and per coordinate), or M's sparse
//! factorisation's solves (on a floating base, as a program over the columns).

use super::super::graph::{Id, Stage};
use super::super::kernel::Solve;
use super::super::module::{ColumnBlock, ColumnProgram, ColumnStore, Operand};
use super::super::spatial::{self as sp, Sv};
use super::fd_grad::{run_steps, Ltdl};
use super::{add6, articulated, pivot, Dynamics, Mat};

impl Dynamics<'_> {
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
    /// some joint is coupled; or, with [`Solve::Ltdl`] and no coupled joint, CRBA's M
    /// factorised (`M = Lᵀ D L`, [`Self::ltdl`]) and solved for each column of the
    /// identity, whose work follows each joint's depth where the direct recursion's
    /// follows the pairs of joints on one path; on a floating base, the solves as one
    /// program over the columns ([`Self::minv_program`]).
    pub fn minv_coordinates(&mut self) -> Mat {
        if self.solve == Solve::Ltdl && !self.coupled() {
            let m = self.mass_matrix();
            let f = self.ltdl(m);
            if self.model.floating {
                return self.minv_program(&f);
            }
            let all: Vec<usize> = (0..self.n()).collect();
            return self.minv_columns(&f, &all);
        }
        // The constrained M⁻¹ of coupled mimic joints comes from the direct route.
        self.solve = Solve::Minv;
        let mi = self.minv();
        if !self.coupled() {
            return mi;
        }
        self.g.at(None, Stage::Combine, 0);
        let k = self.constraints(&mi);
        self.project_minv(&mi, &k)
    }
}

impl Dynamics<'_> {
    /// M⁻¹ from its factorisation `f`, each column solved whole (no entry taken from
    /// another column, as [`Self::minv_columns`] takes the mirrored ones), and the solves'
    /// last pass as a program over the columns. On a floating base the free-flyer is an
    /// ancestor of every joint, so that pass (`L x = z`, root first) fills every row of
    /// every column: the program does no work the straight-line solves would skip, and the
    /// Rust backend runs it with the columns innermost, four or eight per instruction. The
    /// passes before it touch only a column's joint and its ancestors, and stay
    /// straight-line (the program's initial rows). M⁻¹ is then symmetric to round-off, not
    /// entry for entry.
    fn minv_program(&mut self, f: &Ltdl) -> Mat {
        let n = self.n();
        let zero = self.g.constant(0.0);
        let minus_one = self.g.constant(-1.0);
        let (head, tail) = f.split_steps(self.model);
        let mut init = vec![Vec::with_capacity(n); n];
        let mut out = vec![vec![zero; n]; n];
        for c in 0..n {
            let mut e = vec![zero; n];
            e[c] = minus_one;
            let z = run_steps(&mut self.g, &head, e);
            for (row, &x) in z.iter().enumerate() {
                init[row].push(Operand::Node(x));
            }
            for (row, x) in run_steps(&mut self.g, &tail, z).into_iter().enumerate() {
                out[row][c] = x;
            }
        }
        let stores = (0..n)
            .map(|row| ColumnStore {
                row,
                output: "minv",
                flat: (0..n).map(|c| row * n + c).collect(),
                negate: false,
            })
            .collect();
        let block = ColumnBlock { init, steps: tail, stores };
        self.program = Some(ColumnProgram { rows: n, blocks: vec![block], replaces: None });
        out
    }
}
