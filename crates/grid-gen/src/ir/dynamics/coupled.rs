//! Coupled mimic joints in the graph (`--mimic coupled`): the maps between coordinates
//! and joints, and M⁻¹ and q̈ under the mimic constraints, by the same formulas as
//! `reference::coupled` (whose comment derives them). Without a coupled joint every map
//! is the identity and records no node, so those graphs are unchanged.

use super::{Dynamics, Mat};
use crate::ir::graph::{Graph, Id};
use crate::model::JointIndex;

/// The mimic constraints `K q̈_joints = 0` against a joint-level M⁻¹: `W = M⁻¹ Kᵀ`
/// (joints × constraints) and `Y = W S⁻¹` with `S = K W` (symmetric positive definite).
pub(crate) struct Constraints {
    /// `(mimic joint, joint it follows, multiplier)`: row r of K is `e_m − multiplier · e_of`.
    rows: Vec<(usize, usize, f64)>,
    w: Mat,
    y: Mat,
}

impl Dynamics<'_> {
    /// Whether some joint is a coupled mimic (inputs and outputs are smaller than the tree).
    pub fn coupled(&self) -> bool {
        self.model.has_coupled()
    }

    /// Per-joint q̇ or q̈ from per-coordinate values, `G x` (see `reference::coupled`):
    /// the same nodes when no joint is coupled.
    pub fn expand(&mut self, x: &[Id]) -> Vec<Id> {
        (0..self.n())
            .map(|i| {
                let xi = x[self.model.coordinate_of(JointIndex(i)).0];
                match self.model.multiplier(i) {
                    1.0 => xi,
                    m => {
                        let m = self.g.constant(m);
                        self.g.mul(m, xi)
                    }
                }
            })
            .collect()
    }

    /// Per-joint τ from per-coordinate τ, `Pᵀ τ`: a coupled joint's is 0.
    pub fn place(&mut self, tau: &[Id]) -> Vec<Id> {
        (0..self.n())
            .map(|i| {
                if self.model.coupling(i).is_some() {
                    self.g.constant(0.0)
                } else {
                    tau[self.model.coordinate_of(JointIndex(i)).0]
                }
            })
            .collect()
    }

    /// Per-coordinate forces from per-joint ones, `Gᵀ c`.
    pub fn reduce(&mut self, c: &[Id]) -> Vec<Id> {
        let mut out: Vec<Option<Id>> = vec![None; self.model.nv()];
        for (i, &ci) in c.iter().enumerate() {
            let k = self.model.coordinate_of(JointIndex(i)).0;
            let term = match self.model.multiplier(i) {
                1.0 => ci,
                m => {
                    let m = self.g.constant(m);
                    self.g.mul(m, ci)
                }
            };
            out[k] = Some(match out[k] {
                Some(sum) => self.g.add(sum, term),
                None => term,
            });
        }
        out.into_iter().map(|x| x.expect("every coordinate has its own joint")).collect()
    }

    /// `Gᵀ D G` for a joint-level matrix (the same matrix when no joint is coupled).
    pub fn reduce_matrix(&mut self, d: Mat) -> Mat {
        if !self.coupled() {
            return d;
        }
        let columns: Mat = d.iter().map(|row| self.reduce(row)).collect();
        let nv = self.model.nv();
        let mut out = vec![Vec::with_capacity(nv); nv];
        for k in 0..nv {
            let col: Vec<Id> = columns.iter().map(|row| row[k]).collect();
            for (a, x) in self.reduce(&col).into_iter().enumerate() {
                out[a].push(x);
            }
        }
        out
    }

    /// `K x` for a per-joint vector.
    fn constrain(&mut self, rows: &[(usize, usize, f64)], x: &[Id]) -> Vec<Id> {
        rows.iter()
            .map(|&(m, of, multiplier)| {
                let k = self.g.constant(multiplier);
                let t = self.g.mul(k, x[of]);
                self.g.sub(x[m], t)
            })
            .collect()
    }

    /// W, S and Y from the joint-level M⁻¹ (symmetric, so `M⁻¹ Kᵀ` has rows `K M⁻¹[a]`).
    pub fn constraints(&mut self, minv: &Mat) -> Constraints {
        let rows: Vec<(usize, usize, f64)> = (0..self.n())
            .filter_map(|i| self.model.coupling(i).map(|c| (i, c.of, c.multiplier)))
            .collect();
        let w: Mat = minv.iter().map(|row| self.constrain(&rows, row)).collect();
        // S = K W: column s of S is K applied to column s of W.
        let columns: Vec<Vec<Id>> = (0..rows.len())
            .map(|s| self.constrain(&rows, &w.iter().map(|row| row[s]).collect::<Vec<_>>()))
            .collect();
        let s: Mat = (0..rows.len()).map(|r| columns.iter().map(|col| col[r]).collect()).collect();
        let (l, d) = ldl(&mut self.g, &s);
        let y = w.iter().map(|row| ldl_solve(&mut self.g, &l, &d, row)).collect();
        Constraints { rows, w, y }
    }

    /// The coordinates' M⁻¹: `P (M⁻¹ − Y Wᵀ) Pᵀ`, each symmetric pair built once.
    pub fn project_minv(&mut self, minv: &Mat, k: &Constraints) -> Mat {
        let joints = self.model.coordinate_joints();
        let nv = joints.len();
        let mut out = vec![vec![Id(0); nv]; nv];
        for a in 0..nv {
            for b in a..nv {
                let (ja, jb) = (joints[a].0, joints[b].0);
                let t = self.g.dot(&k.y[ja], &k.w[jb]);
                out[a][b] = self.g.sub(minv[ja][jb], t);
                out[b][a] = out[a][b];
            }
        }
        out
    }

    /// The coordinates' q̈ from the unconstrained joint-level `a`: `P (a − Y K a)`.
    pub fn project_acceleration(&mut self, a: &[Id], k: &Constraints) -> Vec<Id> {
        let ka = self.constrain(&k.rows, a);
        self.model
            .coordinate_joints()
            .into_iter()
            .map(|JointIndex(j)| {
                let t = self.g.dot(&k.y[j], &ka);
                self.g.sub(a[j], t)
            })
            .collect()
    }
}

/// `S = L D Lᵀ` with L unit lower triangular (Golub & Van Loan, *Matrix Computations*,
/// 4th ed., alg. 4.1.1): no square roots, and S is positive definite so no pivoting.
fn ldl(g: &mut Graph, s: &Mat) -> (Mat, Vec<Id>) {
    let c = s.len();
    let zero = g.constant(0.0);
    let mut l = vec![vec![zero; c]; c];
    let mut d: Vec<Id> = Vec::with_capacity(c);
    for j in 0..c {
        let mut dj = s[j][j];
        for k in 0..j {
            let t = g.mul(l[j][k], l[j][k]);
            let t = g.mul(t, d[k]);
            dj = g.sub(dj, t);
        }
        d.push(dj);
        for i in j + 1..c {
            let mut x = s[i][j];
            for k in 0..j {
                let t = g.mul(l[i][k], l[j][k]);
                let t = g.mul(t, d[k]);
                x = g.sub(x, t);
            }
            l[i][j] = g.div(x, dj);
        }
    }
    (l, d)
}

/// `y` with `L D Lᵀ y = b`.
fn ldl_solve(g: &mut Graph, l: &Mat, d: &[Id], b: &[Id]) -> Vec<Id> {
    let c = b.len();
    let mut z = b.to_vec();
    for i in 0..c {
        for k in 0..i {
            let t = g.mul(l[i][k], z[k]);
            z[i] = g.sub(z[i], t);
        }
    }
    for i in 0..c {
        z[i] = g.div(z[i], d[i]);
    }
    for i in (0..c).rev() {
        for k in i + 1..c {
            let t = g.mul(l[k][i], z[k]);
            z[i] = g.sub(z[i], t);
        }
    }
    z
}
