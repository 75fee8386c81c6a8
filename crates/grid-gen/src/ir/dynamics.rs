//! The recorder the algorithms share: [`Dynamics`] holds the graph, the joint transforms,
//! motion subspaces and inertias, and each algorithm is one file below it (`rnea`,
//! `rnea_grad`, `rnea_grad_world`, `crba`, `minv`, `aba`, `fd_grad`, `frames`, `forces`, `contact`, `step`,
//! `coupled`) that records into the [`Graph`]. The same recursions as `reference`, written
//! over (E, r) transforms and structural sparsity: a gradient column is only built where the
//! model says it can be nonzero (`sparse` off turns that off, for the "before
//! specialisation" counts).
//!
//! Every per-body loop stops once the graph is exhausted (see [`Graph`]), so that a robot
//! too large for the node limit costs at most one body's work past the limit.

use super::graph::{Graph, Id, Input, Stage};
use super::kernel::{Gradient, Solve};
use super::spatial::{self as sp, joint_xform, subspace, Sv, SymInertia, Xform};
use crate::model::Model;

mod aba;
mod contact;
mod coupled;
mod crba;
mod fd_grad;
mod forces;
mod frames;
mod lie;
mod minv;
mod rnea;
mod rnea_grad;
mod rnea_grad_world;
mod step;

pub(crate) use forces::{transpose, Forces, LambdaSource};

/// Row-major n x n matrix of nodes.
pub type Mat = Vec<Vec<Id>>;

/// A factor the algorithms scale by (the step's dt and its multiples `c dt`): a constant
/// folded at generation time, or `coef` times a node read at run time. A folded `c dt` stays
/// the one constant it was (`c * dt` rounded once), so a folded step's graph does not change
/// when a run-time one is possible.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Scalar {
    Const(f64),
    Node { coef: f64, id: Id },
}

impl Scalar {
    pub const ONE: Scalar = Scalar::Const(1.0);

    /// A node's value.
    pub fn node(id: Id) -> Scalar {
        Scalar::Node { coef: 1.0, id }
    }

    /// `c · self`.
    pub fn times(self, c: f64) -> Scalar {
        match self {
            Scalar::Const(x) => Scalar::Const(c * x),
            Scalar::Node { coef, id } => Scalar::Node { coef: c * coef, id },
        }
    }

    /// `self / c`.
    pub fn over(self, c: f64) -> Scalar {
        match self {
            Scalar::Const(x) => Scalar::Const(x / c),
            Scalar::Node { coef, id } => Scalar::Node { coef: coef / c, id },
        }
    }

    /// Whether it is the constant 1 (scaling by it is the identity).
    pub fn is_one(self) -> bool {
        self == Scalar::ONE
    }

    /// Its node: a constant (snapped as every model constant), or `coef · node`.
    pub fn id(self, g: &mut Graph) -> Id {
        match self {
            Scalar::Const(x) => sp::k(g, x),
            Scalar::Node { coef: 1.0, id } => id,
            Scalar::Node { coef, id } => {
                let c = sp::k(g, coef);
                g.mul(c, id)
            }
        }
    }
}

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
    /// Set by [`Self::contact_fd_grad`]: its combination as a per-column program.
    pub program: Option<super::module::ColumnProgram>,
    /// Set by [`Self::fd_grad`] when it solves through M's factorisation: its solves as
    /// steps on the right-hand sides, which [`Self::contact_fd_grad`] runs in its program.
    fd_solves: Option<fd_grad::FdSolves>,
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
    /// The sign nodes of the logarithms [`Self::contact_accelerations`] took (a wrench
    /// contact's Baumgarte error), whose tangents the derivatives hold at 0.
    log_signs: Vec<Id>,
    /// Whether the kernel takes its callees' outputs as inputs ([`Input::Called`]) instead
    /// of recording their work: a kernel's rest ([`crate::ir::Call`]). The step kernels take
    /// the contact kernel's, `fd_grad` `fd`'s q̈ and `rnea_grad`'s ∂c/∂u.
    pub called: bool,
    /// The q̈ that the next [`Self::fd_grad`] takes instead of ABA's: `contact_fd_grad`'s
    /// solved q̈ (its own, or in a rest the one its callee `contact_fd` gave), at which
    /// Pinocchio's `computeConstraintDynamicsDerivatives` differentiates too.
    given_qdd: Option<Vec<Id>>,
    /// In a rest, whether q̈ and λ are the kernel's own (its callee is `rnea_grad` alone,
    /// [`crate::ir::Calls::RneaGrad`]) rather than a callee's.
    pub own_qdd: bool,
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
            program: None,
            fd_solves: None,
            solve: Solve::Minv,
            forces: Forces::default(),
            called: false,
            given_qdd: None,
            own_qdd: false,
            config: None,
            log_signs: Vec::new(),
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
}

/// Of the picked coordinates `cols`, the one before position `at` that is `row`: where M⁻¹ (or
/// the contacts' symmetric ∂q̈/∂τ) has both, entry (row, `cols[at]`) is that column's entry in
/// row `cols[at]`, already formed.
fn mirrored_column(cols: &[usize], row: usize, at: usize) -> Option<usize> {
    cols[..at].iter().position(|&c| c == row)
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
