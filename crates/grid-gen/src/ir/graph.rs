//! The graph builder of the kernel IR: a scalar dataflow graph in SSA form, under
//! construction. Nodes are created in topological order (operands always have smaller
//! ids). With folding on, every constructor folds constants and shares identical nodes
//! (hash-consing), so that constant folding and common-subexpression elimination happen
//! once, here, for every backend. Backends never see this type: `ir::lower` freezes it
//! into a [`crate::ir::Function`].

use rustc_hash::FxHashMap;

/// A node of the graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Id(pub u32);

/// The kernel inputs: q has nq entries, the actuated forces nu, the others one per
/// coordinate (nv).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Input {
    Q,
    Qd,
    Qdd,
    Tau,
    /// The step kernels' τ: the actuated coordinates' forces only (named `tau` too).
    TauActuated,
    /// External forces, 6 per body of [`crate::model::Specialisation::fext`].
    Fext,
    /// Contact forces, 3 or 6 per contact of [`crate::model::Specialisation::contacts`].
    Lambda,
    /// Which candidate contacts hold, one 0 or 1 per contact of
    /// [`crate::model::Specialisation::contacts`], when the scene masks them
    /// ([`crate::model::Specialisation::contact_mask`]).
    Active,
    /// Baumgarte gains `[Kp, Kd]` per contact, when the scene stabilises them
    /// ([`crate::model::Specialisation::baumgarte`]).
    Gains,
    /// Each contact's reference in the world, with [`Input::Gains`]: a point's position (3
    /// entries), a wrench's placement (position and quaternion, 7).
    ContactRef,
    /// The step kernels' time step, one value, when the scene leaves it to run time
    /// ([`crate::model::StepSpec::dt`]).
    Dt,
    /// A tangent vector, nv entries: `integrate`'s and `dintegrate`'s `v`.
    V,
    /// A second configuration, nq entries: `difference`'s and `ddifference`'s `q1`.
    Q1,
    /// A callee's output that a kernel's rest takes from its call ([`crate::ir::Call`]):
    /// entry `k` of [`CALLED`]. Only the Rust backend sees these inputs.
    Called(u8),
}

/// The callee outputs that a kernel's rest may take ([`Input::Called`]`(k)` is entry k):
/// the Rust name its rest and its call give it, the kernels that return it, and its
/// output's name there. The contact kernel that a step kernel calls returns the first
/// eight (`contact_fd` the first two); with `calls = all`, `fd_grad` reads `fd`'s q̈ and
/// `rnea_grad`'s two, and `contact_fd_grad` `contact_fd`'s two and `rnea_grad`'s.
pub const CALLED: [(&str, &[crate::ir::KernelKind], &str); 11] = {
    use crate::ir::KernelKind::{ContactFd, ContactFdGrad, Fd, RneaGrad};
    [
        ("called_qdd", &[ContactFd, ContactFdGrad], "qdd"),
        ("called_lambda", &[ContactFd, ContactFdGrad], "lambda"),
        ("called_dqdd_dq", &[ContactFdGrad], "dqdd_dq"),
        ("called_dqdd_dqd", &[ContactFdGrad], "dqdd_dqd"),
        ("called_dqdd_dtau", &[ContactFdGrad], "dqdd_dtau"),
        ("called_dlambda_dq", &[ContactFdGrad], "dlambda_dq"),
        ("called_dlambda_dqd", &[ContactFdGrad], "dlambda_dqd"),
        ("called_dlambda_dtau", &[ContactFdGrad], "dlambda_dtau"),
        ("fd_qdd", &[Fd], "qdd"),
        ("rnea_grad_dc_dq", &[RneaGrad], "dc_dq"),
        ("rnea_grad_dc_dqd", &[RneaGrad], "dc_dqd"),
    ]
};

/// Which of a WGSL kernel's three input buffers holds an input: `q`, `qd` (q̇, or the
/// Lie-group kernels' tangent `v`), or `u`, which packs every other input in argument order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Buffer {
    Q,
    Qd,
    U,
}

impl Input {
    pub fn name(self) -> &'static str {
        match self {
            Input::Q => "q",
            Input::Qd => "qd",
            Input::Qdd => "qdd",
            Input::Tau | Input::TauActuated => "tau",
            Input::Fext => "fext",
            Input::Lambda => "lambda",
            Input::Active => "active",
            Input::Gains => "gains",
            Input::ContactRef => "contact_ref",
            Input::Dt => "dt",
            Input::V => "v",
            Input::Q1 => "q1",
            Input::Called(k) => CALLED[usize::from(k) % CALLED.len()].0,
        }
    }

    /// The WGSL buffer that holds the input.
    pub fn buffer(self) -> Buffer {
        match self {
            Input::Q => Buffer::Q,
            Input::Qd | Input::V => Buffer::Qd,
            _ => Buffer::U,
        }
    }

    /// Whether the input is a configuration, whose quaternions are rotations (checked to be
    /// unit by the C ABI and Python).
    pub fn is_config(self) -> bool {
        matches!(self, Input::Q | Input::Q1)
    }

    /// Entries of the input for a robot of these sizes.
    pub fn len(self, dims: &crate::ir::Dims) -> usize {
        match self {
            Input::Q | Input::Q1 => dims.nq,
            Input::TauActuated => dims.nu,
            Input::Fext => 6 * dims.nfext,
            Input::Lambda => dims.nlambda,
            Input::Active => dims.ncontacts,
            Input::Gains => 2 * dims.nbaumgarte,
            Input::ContactRef => dims.ncontact_ref,
            Input::Dt => 1,
            Input::Qd | Input::Qdd | Input::Tau | Input::V => dims.nv,
            Input::Called(k) => Input::called_shape(k).len(dims),
        }
    }

    /// The shape of [`Input::Called`]`(k)`: its output's in the kernels that return it.
    pub fn called_shape(k: u8) -> crate::ir::Shape {
        let (_, kernels, output) = CALLED[usize::from(k) % CALLED.len()];
        let outputs = kernels[0].outputs();
        outputs.iter().find(|o| o.name == output).map_or(outputs[0].shape, |o| o.shape)
    }

    /// The [`Input::Called`] that carries output `output` of a call to `callee`, if a rest
    /// may take it.
    pub fn called(callee: crate::ir::KernelKind, output: &str) -> Option<Input> {
        CALLED
            .iter()
            .position(|(_, kernels, name)| *name == output && kernels.contains(&callee))
            .map(|k| Input::Called(k as u8))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Op {
    Input(Input, u16),
    Const(f64),
    Add(Id, Id),
    Sub(Id, Id),
    Mul(Id, Id),
    Div(Id, Id),
    Neg(Id),
    Sin(Id),
    Cos(Id),
    /// The square root (of a non-negative value: the Lie-group kernels' logarithm, whose
    /// arguments the IR keeps away from 0, see `dynamics/lie.rs`).
    Sqrt(Id),
}

impl Op {
    pub fn operands(&self) -> impl Iterator<Item = Id> {
        let (a, b) = match *self {
            Op::Input(..) | Op::Const(_) => (None, None),
            Op::Add(a, b) | Op::Sub(a, b) | Op::Mul(a, b) | Op::Div(a, b) => (Some(a), Some(b)),
            Op::Neg(a) | Op::Sin(a) | Op::Cos(a) | Op::Sqrt(a) => (Some(a), None),
        };
        a.into_iter().chain(b)
    }
}

/// Marks every operand, transitively, of the nodes marked in `marked`, except the operands
/// of a node for which `stop` holds (its value comes from elsewhere). One pass from the last
/// node suffices because every node comes after its operands.
pub(crate) fn mark_ancestors(nodes: &[Node], marked: &mut [bool], stop: impl Fn(usize) -> bool) {
    for i in (0..nodes.len()).rev() {
        if marked[i] && !stop(i) {
            for o in nodes[i].op.operands() {
                marked[o.0 as usize] = true;
            }
        }
    }
}

/// Which step of which algorithm a node belongs to, for scheduling and op counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stage {
    /// sin/cos and joint transforms: independent of the serial chain.
    Transform,
    /// Forward (root to leaves) passes.
    Forward,
    /// Backward (leaves to root) passes.
    Backward,
    /// Dense products after the passes (M⁻¹ τ, −M⁻¹ ∂c/∂u).
    Combine,
}

/// A node and where it comes from: the joint (link) it was computed for, if any, the
/// stage, and that joint's tree level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    pub op: Op,
    pub link: Option<u16>,
    pub stage: Stage,
    pub level: u16,
}

#[derive(Clone, Copy, PartialEq, Eq, Hash)]
enum Key {
    Input(Input, u16),
    Const(u64),
    Bin(u8, Id, Id),
    Un(u8, Id),
}

/// The graph under construction. With `fold` off it records the algorithm as a
/// general-purpose implementation would run it (no folding, no sharing), which gives the
/// "before specialisation" op counts.
///
/// The graph holds at most `limit` nodes. Past that it stops recording (every constructor
/// returns node 0) and [`Graph::exhausted`] turns true; the algorithms check it at their
/// per-body loops and stop, and lowering reports the kernel as too large instead of
/// running out of memory.
pub(crate) struct Graph {
    pub nodes: Vec<Node>,
    /// Fx hashing: the keys are a few small integers and this map is the generator's
    /// hottest (a third of a humanoid's generation time with std's SipHash).
    shared: FxHashMap<Key, Id>,
    fold: bool,
    here: (Option<u16>, Stage, u16),
    limit: usize,
    exhausted: bool,
}

impl Graph {
    pub fn new(fold: bool, limit: usize) -> Self {
        // Node 0 always exists, so the placeholder id handed out when exhausted is valid.
        let mut g = Graph {
            nodes: Vec::new(),
            shared: FxHashMap::default(),
            fold,
            here: (None, Stage::Transform, 0),
            limit: limit.max(1),
            exhausted: false,
        };
        g.constant(0.0);
        g
    }

    pub fn folding(&self) -> bool {
        self.fold
    }

    /// Whether the node limit was reached (the graph is then incomplete).
    pub fn exhausted(&self) -> bool {
        self.exhausted
    }

    /// Tags the nodes created from now on.
    pub fn at(&mut self, link: Option<usize>, stage: Stage, level: usize) {
        self.here = (link.map(|l| l as u16), stage, level as u16);
    }

    pub fn op(&self, id: Id) -> Op {
        self.nodes[id.0 as usize].op
    }

    fn push(&mut self, op: Op, key: Option<Key>) -> Id {
        if let Some(k) = key {
            if let Some(&id) = self.shared.get(&k) {
                return id;
            }
        }
        if self.nodes.len() >= self.limit {
            self.exhausted = true;
            return Id(0);
        }
        let id = Id(self.nodes.len() as u32);
        let (link, stage, level) = self.here;
        self.nodes.push(Node { op, link, stage, level });
        if let Some(k) = key {
            self.shared.insert(k, id);
        }
        id
    }

    fn key(&self, k: Key) -> Option<Key> {
        self.fold.then_some(k)
    }

    pub fn input(&mut self, input: Input, joint: usize) -> Id {
        // Inputs are shared even when not specialising: they are loads, not operations.
        self.push(Op::Input(input, joint as u16), Some(Key::Input(input, joint as u16)))
    }

    pub fn constant(&mut self, c: f64) -> Id {
        let c = if c == 0.0 { 0.0 } else { c }; // one zero: -0.0 and 0.0 fold alike
        let key = self.key(Key::Const(c.to_bits()));
        self.push(Op::Const(c), key)
    }

    pub fn value(&self, id: Id) -> Option<f64> {
        match self.op(id) {
            Op::Const(c) if self.fold => Some(c),
            _ => None,
        }
    }

    fn is(&self, id: Id, c: f64) -> bool {
        self.value(id) == Some(c)
    }

    /// A folded constant, unless folding would leave f64's range (then the op stays).
    fn folded(&mut self, c: f64) -> Option<Id> {
        c.is_finite().then(|| self.constant(c))
    }

    pub fn add(&mut self, a: Id, b: Id) -> Id {
        if self.fold {
            if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
                if let Some(id) = self.folded(x + y) {
                    return id;
                }
            }
            if self.is(a, 0.0) {
                return b;
            }
            if self.is(b, 0.0) {
                return a;
            }
            if let Op::Neg(nb) = self.op(b) {
                return self.sub(a, nb);
            }
            if let Op::Neg(na) = self.op(a) {
                return self.sub(b, na);
            }
        }
        let (x, y) = if a <= b { (a, b) } else { (b, a) };
        let key = self.key(Key::Bin(0, x, y));
        self.push(Op::Add(x, y), key)
    }

    pub fn sub(&mut self, a: Id, b: Id) -> Id {
        if self.fold {
            if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
                if let Some(id) = self.folded(x - y) {
                    return id;
                }
            }
            if self.is(b, 0.0) {
                return a;
            }
            if self.is(a, 0.0) {
                return self.neg(b);
            }
            if a == b {
                return self.constant(0.0);
            }
            if let Op::Neg(nb) = self.op(b) {
                return self.add(a, nb);
            }
        }
        let key = self.key(Key::Bin(1, a, b));
        self.push(Op::Sub(a, b), key)
    }

    pub fn mul(&mut self, a: Id, b: Id) -> Id {
        if self.fold {
            if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
                if let Some(id) = self.folded(x * y) {
                    return id;
                }
            }
            if self.is(a, 0.0) || self.is(b, 0.0) {
                return self.constant(0.0);
            }
            if self.is(a, 1.0) {
                return b;
            }
            if self.is(b, 1.0) {
                return a;
            }
            if self.is(a, -1.0) {
                return self.neg(b);
            }
            if self.is(b, -1.0) {
                return self.neg(a);
            }
            // Signs move outwards so that x·(−y) and −(x·y) are shared.
            if let Op::Neg(na) = self.op(a) {
                let m = self.mul(na, b);
                return self.neg(m);
            }
            if let Op::Neg(nb) = self.op(b) {
                let m = self.mul(a, nb);
                return self.neg(m);
            }
        }
        let (x, y) = if a <= b { (a, b) } else { (b, a) };
        let key = self.key(Key::Bin(2, x, y));
        self.push(Op::Mul(x, y), key)
    }

    pub fn div(&mut self, a: Id, b: Id) -> Id {
        if self.fold {
            if let (Some(x), Some(y)) = (self.value(a), self.value(b)) {
                if y != 0.0 {
                    if let Some(id) = self.folded(x / y) {
                        return id;
                    }
                }
            }
            if self.is(b, 1.0) {
                return a;
            }
        }
        let key = self.key(Key::Bin(3, a, b));
        self.push(Op::Div(a, b), key)
    }

    pub fn neg(&mut self, a: Id) -> Id {
        if self.fold {
            if let Some(x) = self.value(a) {
                return self.constant(-x);
            }
            if let Op::Neg(x) = self.op(a) {
                return x;
            }
        }
        let key = self.key(Key::Un(0, a));
        self.push(Op::Neg(a), key)
    }

    pub fn sin(&mut self, a: Id) -> Id {
        let key = self.key(Key::Un(1, a));
        self.push(Op::Sin(a), key)
    }

    pub fn cos(&mut self, a: Id) -> Id {
        let key = self.key(Key::Un(2, a));
        self.push(Op::Cos(a), key)
    }

    pub fn sqrt(&mut self, a: Id) -> Id {
        if self.fold {
            if let Some(x) = self.value(a) {
                if x >= 0.0 {
                    if let Some(id) = self.folded(x.sqrt()) {
                        return id;
                    }
                }
            }
        }
        let key = self.key(Key::Un(3, a));
        self.push(Op::Sqrt(a), key)
    }

    /// Σ aᵢ bᵢ, skipping structural zeros.
    pub fn dot(&mut self, a: &[Id], b: &[Id]) -> Id {
        let mut acc: Option<Id> = None;
        for (&x, &y) in a.iter().zip(b) {
            let p = self.mul(x, y);
            acc = Some(match acc {
                Some(s) => self.add(s, p),
                None => p,
            });
        }
        acc.unwrap_or_else(|| self.constant(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn folding() -> (Graph, Id, Id) {
        let mut g = Graph::new(true, 1000);
        let (x, y) = (g.input(Input::Q, 0), g.input(Input::Qd, 0));
        (g, x, y)
    }

    #[test]
    fn constants_fold_and_identities_vanish() {
        let (mut g, x, _) = folding();
        let (two, three) = (g.constant(2.0), g.constant(3.0));
        let five = g.add(two, three);
        assert_eq!(g.value(five), Some(5.0));
        let (zero, one, minus_one) = (g.constant(0.0), g.constant(1.0), g.constant(-1.0));
        assert_eq!(g.add(x, zero), x);
        assert_eq!(g.sub(x, zero), x);
        assert_eq!(g.mul(x, one), x);
        assert_eq!(g.div(x, one), x);
        let m = g.mul(x, zero);
        assert_eq!(g.value(m), Some(0.0));
        let nx = g.mul(x, minus_one);
        assert_eq!(g.op(nx), Op::Neg(x));
        assert_eq!(g.neg(nx), x, "double negation folds");
        let d = g.sub(x, x);
        assert_eq!(g.value(d), Some(0.0));
        assert_eq!(g.constant(-0.0), g.constant(0.0), "one zero");
    }

    #[test]
    fn identical_nodes_are_shared_and_signs_move_out() {
        let (mut g, x, y) = folding();
        let a = g.mul(x, y);
        assert_eq!(g.mul(y, x), a, "commutative operands are ordered");
        let ny = g.neg(y);
        let b = g.mul(x, ny);
        assert_eq!(g.op(b), Op::Neg(a), "x·(−y) is −(x·y)");
        let s = g.add(x, ny);
        assert_eq!(g.op(s), Op::Sub(x, y), "x + (−y) is x − y");
        let c = g.sin(x);
        assert_eq!(g.sin(x), c);
    }

    #[test]
    fn folding_never_produces_an_infinite_constant() {
        let (mut g, _, _) = folding();
        let big = g.constant(1e300);
        let p = g.mul(big, big);
        assert!(matches!(g.op(p), Op::Mul(..)), "the overflowing product stays an operation");
    }

    #[test]
    fn without_folding_nothing_is_shared() {
        let mut g = Graph::new(false, 1000);
        let x = g.input(Input::Q, 0);
        let zero = g.constant(0.0);
        assert_ne!(g.add(x, zero), x);
        let (p, q) = (g.mul(x, x), g.mul(x, x));
        assert_ne!(p, q);
    }

    #[test]
    fn the_node_limit_stops_recording() {
        let mut g = Graph::new(true, 4);
        let x = g.input(Input::Q, 0);
        let y = g.input(Input::Qd, 0);
        let a = g.mul(x, y);
        assert!(!g.exhausted());
        let b = g.add(a, x);
        assert!(g.exhausted());
        assert_eq!(b, Id(0));
        assert_eq!(g.nodes.len(), 4);
    }
}
