//! ∂q̈/∂(q, q̇) = −M⁻¹ ∂c/∂(q, q̇), recorded by either solve: the dense product with the
//! direct M⁻¹, or CRBA's M factorised as Lᵀ D L (LTDL) and solved per column; on a
//! floating base, six columns come from the free-flyer's invariances without a solve.

use super::super::graph::{Graph, Id, Stage};
use super::super::kernel::{KernelKind, Solve};
use super::super::module::{ColumnBlock, ColumnProgram, ColumnStep, ColumnStore, Operand};
use super::{strict_ancestors, Dynamics, Mat, Rnea, Scalar};
use crate::model::Model;

impl Dynamics<'_> {
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
        self.fd_grad_scaled(qd, tau, columns, rhs, Scalar::ONE)
    }

    /// [`Self::fd_grad`] with `∂q̈/∂u` and the columns of M⁻¹ multiplied by `s` (a step's
    /// dt, whose `A` and `B` read `dt ∂q̈/∂u` and `dt M⁻¹`). Through the factorisation,
    /// `s` rides on −D⁻¹: one multiplication per coordinate instead of one per entry.
    pub fn fd_grad_scaled(
        &mut self,
        qd: &[Id],
        tau: &[Id],
        columns: &[usize],
        rhs: &[Vec<Id>],
        s: Scalar,
    ) -> (Vec<Id>, Mat, Mat, Mat, Mat) {
        if matches!(self.solve, Solve::Ltdl | Solve::Crba) && !self.coupled() {
            return self.fd_grad_ltdl(qd, tau, columns, rhs, s);
        }
        // The constrained M⁻¹ of coupled mimic joints comes from the direct route.
        self.solve = Solve::Minv;
        let n = self.model.nv();
        let (mut qdd, mi) = self.fd_minv(qd, tau);
        if let Some(given) = self.given_qdd.take() {
            qdd = given;
        }
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
        let mut dq = product(&dc_q, &mut self.g);
        let mut dqd = product(&dc_qd, &mut self.g);
        let (known_q, known_qd) = match self.coupled() {
            true => (Vec::new(), Vec::new()),
            false => self.free_flyer_columns(&r, &qd, Scalar::ONE),
        };
        for (m, known) in [(&mut dq, &known_q), (&mut dqd, &known_qd)] {
            for (c, col) in known.iter().enumerate() {
                for (row, &x) in col.iter().flatten().enumerate() {
                    m[row][c] = x;
                }
            }
        }
        let flat = |m: &Mat| {
            m.iter()
                .flatten()
                .map(|&id| super::super::module::Operand::Node(id))
                .collect::<Vec<_>>()
        };
        self.product = Some(super::super::module::DenseProduct {
            minv: flat(&mi),
            dc: vec![flat(&dc_q), flat(&dc_qd)],
            outputs: vec!["dqdd_dq", "dqdd_dqd"],
        });
        let mut picked: Mat =
            mi.iter().map(|row| columns.iter().map(|&c| row[c]).collect()).collect();
        if !s.is_one() {
            // The product loop would write the unscaled entries.
            self.product = None;
            let h = s.id(&mut self.g);
            for x in dq.iter_mut().chain(&mut dqd).chain(&mut picked).flatten() {
                *x = self.g.mul(h, *x);
            }
        }
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
        s: Scalar,
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
        let mut qdd = by_aba.unwrap_or_else(|| {
            let b: Vec<Id> = (0..n).map(|i| self.g.sub(bias[i], tau[i])).collect();
            f.solve(&mut self.g, self.model, b)
        });
        // A given q̈ (`contact_fd_grad`'s), or in a rest whose first callee is `fd`, its q̈;
        // ABA's nodes then drop out when the graph is frozen.
        if let Some(given) = self.given_qdd.take() {
            qdd = given;
        } else if self.called && !self.own_qdd {
            qdd = self.called_inputs(crate::ir::Input::called(KernelKind::Fd, "qdd"));
        }
        let r = self.rnea(qd, &qdd);
        let (mut dc_q, mut dc_qd) = self.rnea_grad(&r, qd);
        if self.called {
            // A rest: ∂c/∂u from the call to `rnea_grad`, except where the graph above folded
            // an entry to a constant (joints on different branches), which the solves keep
            // folding. The recorded nodes left unread are dropped when the graph is frozen.
            for (dc, output) in [(&mut dc_q, "dc_dq"), (&mut dc_qd, "dc_dqd")] {
                let flat =
                    self.called_inputs(crate::ir::Input::called(KernelKind::RneaGrad, output));
                for (row, entries) in dc.iter_mut().enumerate() {
                    for (c, x) in entries.iter_mut().enumerate() {
                        if !matches!(self.g.nodes[x.0 as usize].op, crate::ir::Op::Const(_)) {
                            *x = flat[row * n + c];
                        }
                    }
                }
            }
        }
        if self.exhausted() {
            return (qdd, dc_q, dc_qd, empty(columns.len()), vec![vec![zero; n]; rhs.len()]);
        }
        self.g.at(None, Stage::Combine, 0);
        let (known_q, known_qd) = self.free_flyer_columns(&r, qd, s);
        let fs = f.scaled(&mut self.g, s);
        let before = self.g.nodes.len();
        let g = &mut self.g;
        let mut solve = |dc: &Mat, known: &[Option<Vec<Id>>]| -> Mat {
            let mut out = vec![vec![Id(0); n]; n];
            for c in 0..n {
                let x = match &known[c] {
                    Some(col) => col.clone(),
                    None => fs.solve(g, self.model, (0..n).map(|row| dc[row][c]).collect()),
                };
                for (row, x) in x.into_iter().enumerate() {
                    out[row][c] = x;
                }
            }
            out
        };
        let dq = solve(&dc_q, &known_q);
        let dqd = solve(&dc_qd, &known_qd);
        self.fd_solves = Some(FdSolves {
            steps: fs.program_steps(self.model),
            dc: [dc_q.clone(), dc_qd.clone()],
            known: [known_q.clone(), known_qd.clone()],
        });
        let straight = self.g.nodes.len() - before;
        if s.is_one() {
            // The Rust backend runs it where the straight-line solves are many
            // (`back::rust::runs_program`).
            let blocks = [(&dc_q, &known_q, "dqdd_dq"), (&dc_qd, &known_qd, "dqdd_dqd")]
                .map(|(dc, known, output)| solve_block(&fs, self.model, dc, known, output));
            let blocks = blocks.into();
            self.program = Some(ColumnProgram { rows: n, blocks, replaces: Some(straight) });
        }
        let picked = self.minv_columns(&fs, columns);
        let solved = rhs.iter().map(|b| f.solve(&mut self.g, self.model, b.clone())).collect();
        (qdd, dq, dqd, picked, solved)
    }

    /// Columns `columns` of `s M⁻¹` from its factorisation scaled by `s` (`fs`, see
    /// [`Ltdl::scaled`]), one solve per column; rows of a later column that are also an
    /// earlier column are that column's entries (M⁻¹ is symmetric).
    pub(super) fn minv_columns(&mut self, fs: &Ltdl, columns: &[usize]) -> Mat {
        let n = self.n();
        let zero = self.g.constant(0.0);
        // M⁻¹ e_c = −M⁻¹ (−e_c): no negation is left to store.
        let mut picked = vec![vec![zero; columns.len()]; n];
        for (at, &c) in columns.iter().enumerate() {
            let minus_one = self.g.constant(-1.0);
            let mut e = vec![zero; n];
            e[c] = minus_one;
            for (row, x) in fs.solve(&mut self.g, self.model, e).into_iter().enumerate() {
                picked[row][at] = x;
            }
        }
        // M⁻¹ is symmetric: where a row is also an earlier picked column, the entry is
        // that column's, and the solve's last pass drops the rows no other row reads (a
        // floating quadruped's B: the other legs' rows of half its columns).
        for (at, &c) in columns.iter().enumerate() {
            for row in 0..n {
                if let Some(at_r) = super::mirrored_column(columns, row, at) {
                    picked[row][at] = picked[c][at_r];
                }
            }
        }
        picked
    }

    /// LTDL (Featherstone 2005, table 2): M's lower triangle becomes L (unit diagonal
    /// implied) and its diagonal D, rows visited leaves first. One division per joint,
    /// −1/D_k: the solves' diagonal step takes it as it is (the minus sign of −M⁻¹), and
    /// L's entries are −(M_ki · −1/D_k), whose negations the graph moves into the
    /// subtractions that read them (no node is left for them).
    pub(super) fn ltdl(&mut self, mut m: Mat) -> Ltdl {
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
#[derive(Clone)]
pub(super) struct Ltdl {
    l: Mat,
    neg_dinv: Vec<Id>,
}

impl Ltdl {
    /// The factorisation whose solves give `−s M⁻¹ b`: −D⁻¹ multiplied by `s`.
    pub(super) fn scaled(&self, g: &mut Graph, s: Scalar) -> Ltdl {
        let h = s.id(g);
        Ltdl { l: self.l.clone(), neg_dinv: self.neg_dinv.iter().map(|&d| g.mul(h, d)).collect() }
    }

    /// −M⁻¹ b: [`Self::steps`] on b's nodes. Zero entries of b fold away, so a column
    /// touches only the joints it can reach.
    pub(super) fn solve(&self, g: &mut Graph, model: &Model, b: Vec<Id>) -> Vec<Id> {
        run_steps(g, &self.steps(model), b)
    }

    /// [`Self::steps`] as the passes before the last (`Lᵀ y = b`, `z = −D⁻¹ y`) and the
    /// last (`L x = z`, root first), which on a floating base fills every row.
    pub(super) fn split_steps(&self, model: &Model) -> (Vec<ColumnStep>, Vec<ColumnStep>) {
        let mut head = self.steps(model);
        let last =
            head.iter().rposition(|s| matches!(s, ColumnStep::Mul { .. })).map_or(0, |i| i + 1);
        let tail = head.split_off(last);
        (head, tail)
    }

    /// [`Self::solve`] up to its last pass, in two halves: `y = L⁻ᵀ b` and `z = −D⁻¹ y`.
    /// Both touch only b's joints and their ancestors, and `bᵀ M⁻¹ b′ = −yᵀ z′` needs no
    /// more (`contact_fd`'s K, without each column's last pass).
    pub(super) fn first_passes(
        &self,
        g: &mut Graph,
        model: &Model,
        b: Vec<Id>,
    ) -> (Vec<Id>, Vec<Id>) {
        let (head, _) = self.split_steps(model);
        let (diagonal, first): (Vec<ColumnStep>, Vec<ColumnStep>) =
            head.into_iter().partition(|s| matches!(s, ColumnStep::Mul { .. }));
        let y = run_steps(g, &first, b);
        let z = run_steps(g, &diagonal, y.clone());
        (y, z)
    }

    /// The last pass of [`Self::solve`] on the z of [`Self::first_passes`]: `−M⁻¹ b`.
    pub(super) fn last_pass(&self, g: &mut Graph, model: &Model, z: Vec<Id>) -> Vec<Id> {
        run_steps(g, &self.split_steps(model).1, z)
    }

    /// [`Self::steps`] with the first pass gathered: row j of `Lᵀ y = b` takes every term
    /// from its descendants k in one run (k descending, the order in which the scattered
    /// pass subtracts them), so each row's value is the same to the bit. A program runs
    /// a run of terms into one row in registers, where the scattered pass loads and stores
    /// the row once per term (the base's rows once per joint on a floating base).
    pub(super) fn program_steps(&self, model: &Model) -> Vec<ColumnStep> {
        self.passes(model, true)
    }

    /// The solve `−M⁻¹ b` as steps on b's rows: `Lᵀ y = b` leaves first, `z = −D⁻¹ y`,
    /// `L x = z` root first. [`Self::solve`] runs them on graph nodes, [`solve_block`] on
    /// many columns at once (as [`Self::program_steps`]).
    fn steps(&self, model: &Model) -> Vec<ColumnStep> {
        self.passes(model, false)
    }

    /// [`Self::steps`], with the first pass scattered (each row k, once final, subtracted
    /// from its ancestors) or `gathered` ([`Self::program_steps`]).
    fn passes(&self, model: &Model, gathered: bool) -> Vec<ColumnStep> {
        let n = self.neg_dinv.len();
        let l = |k: usize, j: usize| Operand::Node(self.l[k][j]);
        let mut first: Vec<(usize, usize)> = (0..n)
            .rev()
            .flat_map(|k| strict_ancestors(model, k).into_iter().map(move |j| (k, j)))
            .collect();
        if gathered {
            // Stable: each row keeps its terms in the scattered order, k descending.
            first.sort_by_key(|&(_, j)| std::cmp::Reverse(j));
        }
        let mut steps: Vec<ColumnStep> = first
            .into_iter()
            .map(|(k, j)| ColumnStep::Sub { dst: j, coef: l(k, j), src: k })
            .collect();
        steps.extend(
            (0..n).map(|k| ColumnStep::Mul { dst: k, coef: Operand::Node(self.neg_dinv[k]) }),
        );
        for k in 0..n {
            for j in strict_ancestors(model, k) {
                steps.push(ColumnStep::Sub { dst: k, coef: l(k, j), src: j });
            }
        }
        steps
    }
}

/// `steps` (of [`Ltdl::steps`]) run on b's nodes.
pub(super) fn run_steps(g: &mut Graph, steps: &[ColumnStep], mut b: Vec<Id>) -> Vec<Id> {
    let node = |o: Operand| match o {
        Operand::Node(id) => id,
        _ => unreachable!("Ltdl::steps reads nodes"),
    };
    for &step in steps {
        match step {
            ColumnStep::Sub { dst, coef, src } => {
                let t = g.mul(node(coef), b[src]);
                b[dst] = g.sub(b[dst], t);
            }
            ColumnStep::Mul { dst, coef } => b[dst] = g.mul(b[dst], node(coef)),
        }
    }
    b
}

/// The solves of [`Dynamics::fd_grad_ltdl`] for the columns of `dc` that are not `known`,
/// as a per-column program that stores `−M⁻¹ dc` into output `output` (`dqdd_dq` or
/// `dqdd_dqd`): [`Ltdl::solve`]'s steps for every column, where the
/// graph's straight-line solves drop the steps a column's zeros make empty. On a floating
/// base every column reaches every joint (the base is an ancestor of all), so the
/// straight-line solves are as long as the program's, and the Rust backend runs the
/// program with the columns innermost, four or eight of them per instruction.
fn solve_block(
    f: &Ltdl,
    model: &Model,
    dc: &Mat,
    known: &[Option<Vec<Id>>],
    output: &'static str,
) -> ColumnBlock {
    let n = dc.len();
    let cols: Vec<usize> = (0..n).filter(|&c| known[c].is_none()).collect();
    let init =
        (0..n).map(|row| cols.iter().map(|&c| Operand::Node(dc[row][c])).collect()).collect();
    let steps = f.program_steps(model);
    let stores = (0..n)
        .map(|row| ColumnStore {
            row,
            output,
            flat: cols.iter().map(|&c| row * n + c).collect(),
            negate: false,
        })
        .collect();
    ColumnBlock { init, steps, stores }
}

/// Per column, the column itself where it is known without a solve.
pub(super) type KnownColumns = Vec<Option<Vec<Id>>>;

/// [`Dynamics::fd_grad_ltdl`]'s solves, for a program that runs them over the columns:
/// `−s M⁻¹ b` is `steps` on b's rows; ∂q̈/∂q and ∂q̈/∂q̇ solve the columns of `dc` that are
/// not `known`.
pub(super) struct FdSolves {
    pub steps: Vec<ColumnStep>,
    pub dc: [Mat; 2],
    pub known: [KnownColumns; 2],
}

impl FdSolves {
    /// `steps` as the passes before the last (`Lᵀ y = b`, then `z = −D⁻¹ y`) and the last
    /// (`L x = z`, root first, row by row).
    pub fn split(&self) -> (&[ColumnStep], &[ColumnStep]) {
        let last = self
            .steps
            .iter()
            .rposition(|s| matches!(s, ColumnStep::Mul { .. }))
            .map_or(0, |i| i + 1);
        self.steps.split_at(last)
    }
}

impl Dynamics<'_> {
    /// Columns of ∂q̈/∂q and ∂q̈/∂q̇ that a free-flyer base's invariances give without a
    /// solve (`None` for the others, and for every column without a floating base).
    ///
    /// With no force held in world axes (fext is held in the bodies' frames; contact forces
    /// λ are held in world axes), the dynamics in the base frame see the base's orientation
    /// only through gravity, and every body's classical acceleration shifts by g with it:
    /// the joints' q̈ and the base's angular acceleration do not change, and the base's
    /// spatial linear acceleration `a = Rᵀ p̈ − ω × v` moves with `Rᵀ g`. Along
    /// Pinocchio's tangent `R ↦ R exp(δθ)`, `∂(Rᵀ g)/∂δθ = [Rᵀ g]×`.
    /// Galilean invariance (every force here is independent of a uniform velocity, λ
    /// included): adding a uniform velocity leaves every p̈ and q̈ of the joints unchanged,
    /// so along the base's linear velocity only `a = Rᵀ p̈ − ω × v` moves, by `−[ω]×`.
    /// These are the columns Pinocchio's `computeABADerivatives` returns there; the tests
    /// compare them with it through the reference.
    /// Multiplied by `s`, as [`Dynamics::fd_grad_scaled`]'s.
    fn free_flyer_columns(
        &mut self,
        r: &Rnea,
        qd: &[Id],
        s: Scalar,
    ) -> (KnownColumns, KnownColumns) {
        let n = self.n();
        let (mut dq, mut dqd) = (vec![None; n], vec![None; n]);
        if !self.model.floating || self.config.is_some() {
            return (dq, dqd);
        }
        let g = &mut self.g;
        let zero = g.constant(0.0);
        let h = s.id(g);
        // Column c of −[x]×: −(x × e_c) = e_c × x, −x_b at row a and x_a at row b (a, b the
        // axes after c).
        let neg_skew_col = |g: &mut Graph, x: [Id; 3], c: usize| -> Vec<Id> {
            let mut col = vec![zero; n];
            let (a, b) = ((c + 1) % 3, (c + 2) % 3);
            col[a] = g.neg(x[b]);
            col[b] = x[a];
            col
        };
        if !self.forces.any_in_world_axes() {
            // r.xa[0] is the base's a₀ = −g moved into its frame: [0; −Rᵀ g].
            let neg_gb = [r.xa[0][3], r.xa[0][4], r.xa[0][5]].map(|x| g.mul(h, x));
            for c in 0..3 {
                dq[3 + c] = Some(neg_skew_col(g, neg_gb, c));
            }
        }
        let omega = [qd[3], qd[4], qd[5]].map(|x| g.mul(h, x));
        for c in 0..3 {
            dqd[c] = Some(neg_skew_col(g, omega, c));
        }
        (dq, dqd)
    }
}
