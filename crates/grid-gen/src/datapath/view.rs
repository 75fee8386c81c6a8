//! The datapath view of a kernel: the IR function with sin q and cos q turned into input
//! ports (the host computes them, as in robomorphic computing), and only +, −, ×, negation
//! and constants left. The software model, the analysis and the Verilog backend read this.

use super::FixedError;
use crate::ir::{Function, Id, Input, Op, Shape};

/// A node of the datapath.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct HwId(pub u32);

/// What an input port carries, for joint `j`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Port {
    Sin(u16),
    Cos(u16),
    /// `q`, `qd`, `qdd` or `tau` itself (prismatic positions, speeds, accelerations, a
    /// floating base's quaternion entries).
    Value(Input, u16),
    /// A quaternion's scale `2 / |q[k..k + 4]|²` (the floating base's, k = 3, or a
    /// spherical joint's), which normalises it: like sin and cos, a division the host
    /// computes (the datapath has no divider).
    QuatScale(u16),
    /// Entry (row, column) of M⁻¹, row ≤ column (M⁻¹ is symmetric): an input of `fd_grad`'s
    /// host partition, which the host computes as robomorphic computing's does.
    Minv(u16, u16),
}

impl Port {
    /// The entry of its input it reads: a q index for `Sin`, `Cos` and `Value(Q, _)`
    /// (nq entries with a floating base), a joint for the others; the quaternion's first
    /// q index for `QuatScale`.
    pub fn joint(self) -> usize {
        match self {
            Port::Sin(j) | Port::Cos(j) | Port::Value(_, j) | Port::QuatScale(j) => j as usize,
            Port::Minv(i, _) => i as usize,
        }
    }

    /// `sin_q`, `cos_q`, `qd`, …: the port's name before the joint.
    pub fn prefix(self) -> &'static str {
        match self {
            Port::Sin(_) => "sin_q",
            Port::Cos(_) => "cos_q",
            Port::Value(i, _) => i.name(),
            Port::QuatScale(_) => "quat_scale",
            Port::Minv(..) => "minv",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HwOp {
    /// Input port number `n` of [`Datapath::ports`].
    Port(u32),
    Const(f64),
    Add(HwId, HwId),
    Sub(HwId, HwId),
    Mul(HwId, HwId),
    Neg(HwId),
    /// `1 / x` for a positive `x` (`fd_grad`'s chip partition: one per pivot of M's
    /// factorisation), rounded toward zero; a non-positive or too small `x` saturates and
    /// sets the overflow flag.
    Recip(HwId),
}

/// A proven bound on a node's exact value that interval arithmetic cannot see (the
/// factorisation of a positive definite matrix), which the analysis intersects with the
/// node's interval. Bounds that name other nodes read those nodes' analysed ranges.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Clamp {
    /// An entry (i, j) of a Schur complement of M: |x| ≤ √(max M_ii · max M_jj), where
    /// the two nodes are M's original diagonal entries (a Schur complement of a positive
    /// definite matrix is positive definite and its diagonal only shrinks).
    Schur(HwId, HwId),
    /// A diagonal entry of a Schur complement, or a pivot: `floor ≤ x ≤ max M_ii`.
    Pivot { floor: f64, diagonal: HwId },
    /// An entry of L, M_ki / D_k: |x| ≤ √(max M_ii / floor_k) (|M_ki| ≤ √(M_ii D_k)).
    Multiplier { diagonal: HwId, floor: f64 },
    /// A value of solve number `solve` of [`Datapath::factor`] at coordinate `k`, bounded
    /// through β ≥ bᵀ M⁻¹ b = Σ w_k² / D_k, with β = (Σ_k √(M⁻¹_kk) |b_k|)² (positive
    /// definiteness: |M⁻¹_ik| ≤ √(M⁻¹_ii M⁻¹_kk)).
    Solve { solve: u32, k: u16, stage: SolveStage },
}

/// Which value of a solve `−M⁻¹ b` a [`Clamp::Solve`] bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolveStage {
    /// w = L⁻ᵀ b: |w_k| ≤ √(β max D_k) ≤ √(β max M_kk).
    Lower,
    /// z = −D⁻¹ w: |z_k| ≤ √(β / D_k).
    Scaled,
    /// x = −M⁻¹ b: |x_k| ≤ √(M⁻¹_kk β).
    Solution,
}

/// What the bounds of a factorisation's values read: M's diagonal entries (nodes), each
/// pivot's floor, each M⁻¹_kk's bound, and every solve's right-hand side (nodes).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Factor {
    pub diagonal: Vec<HwId>,
    pub floor: Vec<f64>,
    pub minv: Vec<f64>,
    /// Each solve's non-zero right-hand-side entries: (coordinate, node).
    pub rhs: Vec<Vec<(u16, HwId)>>,
    /// The coordinates' tree (each one's parent), which the factorisation follows.
    pub parents: Vec<Option<u16>>,
    /// M's entries before the factorisation, `(i, j, node)` for j = i or an ancestor of i
    /// (the others are structurally zero): what its rounding-error analysis starts from.
    pub entries: Vec<(u16, u16, HwId)>,
}

impl Clamp {
    /// The nodes whose ranges the bound reads (`factor`: the datapath's).
    pub fn reads(&self, factor: &Factor) -> Vec<HwId> {
        match *self {
            Clamp::Schur(a, b) => vec![a, b],
            Clamp::Pivot { diagonal, .. } | Clamp::Multiplier { diagonal, .. } => vec![diagonal],
            Clamp::Solve { solve, k, .. } => {
                let mut v: Vec<HwId> = factor.rhs[solve as usize].iter().map(|r| r.1).collect();
                v.push(factor.diagonal[k as usize]);
                v
            }
        }
    }
}

impl HwOp {
    pub fn operands(&self) -> impl Iterator<Item = HwId> {
        let (a, b) = match *self {
            HwOp::Port(_) | HwOp::Const(_) => (None, None),
            HwOp::Add(a, b) | HwOp::Sub(a, b) | HwOp::Mul(a, b) => (Some(a), Some(b)),
            HwOp::Neg(a) | HwOp::Recip(a) => (Some(a), None),
        };
        a.into_iter().chain(b)
    }

    /// Whether the node is an arithmetic unit (not a port or constant).
    pub fn is_operation(&self) -> bool {
        !matches!(self, HwOp::Port(_) | HwOp::Const(_))
    }

    /// Whether a multiplier computes it (the others need an adder or, for `Recip`, the
    /// divider).
    pub fn is_mul(&self) -> bool {
        matches!(self, HwOp::Mul(..))
    }

    /// Whether it is an addition, subtraction or negation.
    pub fn is_add(&self) -> bool {
        matches!(self, HwOp::Add(..) | HwOp::Sub(..) | HwOp::Neg(_))
    }
}

/// One output of the kernel, with all its entries (structural zeros included: they are
/// the constant 0 node).
#[derive(Clone, Debug, PartialEq)]
pub struct DatapathOutput {
    pub name: &'static str,
    pub shape: Shape,
    pub ids: Vec<HwId>,
}

/// A kernel as a fixed-point datapath: nodes in topological order, every node live.
#[derive(Clone, Debug, PartialEq)]
pub struct Datapath {
    pub kernel: &'static str,
    pub nv: usize,
    /// The robot's sizes, which the outputs are indexed in.
    pub dims: crate::ir::Dims,
    pub ports: Vec<Port>,
    pub nodes: Vec<HwOp>,
    /// The joint each node was computed for, where the IR knew one (what a refusal names).
    pub links: Vec<Option<u16>>,
    /// Proven bounds of nodes (see [`Clamp`]), per node.
    pub clamps: Vec<Option<Clamp>>,
    /// What [`Clamp::Solve`] and the factorisation's bounds read (`fd_grad`'s chip
    /// partition; empty otherwise).
    pub factor: Factor,
    pub outputs: Vec<DatapathOutput>,
}

impl Datapath {
    /// A one-joint datapath of `nodes` (ports 0 and 1 are sin q₀ and cos q₀) whose one
    /// output is `output`: what the backends' unit tests schedule.
    #[cfg(test)]
    pub(crate) fn for_test(nodes: Vec<HwOp>, output: HwId) -> Datapath {
        Datapath {
            kernel: "test",
            nv: 1,
            dims: crate::ir::Dims { nq: 1, nv: 1, ..Default::default() },
            ports: vec![Port::Sin(0), Port::Cos(0)],
            links: vec![None; nodes.len()],
            clamps: vec![None; nodes.len()],
            factor: Default::default(),
            nodes,
            outputs: vec![DatapathOutput { name: "c", shape: Shape::Vector, ids: vec![output] }],
        }
    }

    /// Converts a frozen IR function; fails on division and on sin/cos of anything but
    /// an input position.
    pub fn new(f: &Function, nv: usize) -> Result<Datapath, FixedError> {
        let unsupported = || FixedError::Unsupported { kernel: f.kind.name().to_string() };
        // Which nodes a datapath computes: those reachable from an output, where sin/cos
        // of q stop the walk (they become ports).
        let mut live = vec![false; f.nodes.len()];
        for o in &f.outputs {
            for id in &o.ids {
                live[id.0 as usize] = true;
            }
        }
        for i in (0..f.nodes.len()).rev() {
            if !live[i] {
                continue;
            }
            match f.nodes[i].op {
                Op::Sin(a) | Op::Cos(a) => {
                    if !matches!(f.op(a), Op::Input(Input::Q, _)) {
                        return Err(unsupported());
                    }
                }
                Op::Div(a, b) if quat_scale(f, a, b).is_some() => {}
                Op::Div(..) | Op::Sqrt(_) => return Err(unsupported()),
                op => op.operands().for_each(|o| live[o.0 as usize] = true),
            }
        }
        let mut ports = Vec::new();
        let mut nodes = Vec::new();
        let mut links = Vec::new();
        let mut new_id = vec![HwId(u32::MAX); f.nodes.len()];
        for (i, node) in f.nodes.iter().enumerate() {
            if !live[i] {
                continue;
            }
            let m = |id: Id| new_id[id.0 as usize];
            let mut port = |p: Port| {
                ports.push(p);
                HwOp::Port(ports.len() as u32 - 1)
            };
            let op = match node.op {
                Op::Input(input, j) => port(Port::Value(input, j)),
                Op::Sin(a) | Op::Cos(a) => {
                    let Op::Input(_, j) = f.op(a) else { unreachable!("checked above") };
                    port(if matches!(node.op, Op::Sin(_)) { Port::Sin(j) } else { Port::Cos(j) })
                }
                Op::Const(c) => HwOp::Const(c),
                Op::Add(a, b) => HwOp::Add(m(a), m(b)),
                Op::Sub(a, b) => HwOp::Sub(m(a), m(b)),
                Op::Mul(a, b) => HwOp::Mul(m(a), m(b)),
                Op::Neg(a) => HwOp::Neg(m(a)),
                Op::Div(a, b) => port(Port::QuatScale(quat_scale(f, a, b).expect("checked above"))),
                Op::Sqrt(_) => unreachable!("refused above"),
            };
            new_id[i] = HwId(nodes.len() as u32);
            nodes.push(op);
            links.push(node.link);
        }
        let outputs = f
            .outputs
            .iter()
            .map(|o| DatapathOutput {
                name: o.name,
                shape: o.shape,
                ids: o.ids.iter().map(|id| new_id[id.0 as usize]).collect(),
            })
            .collect();
        let clamps = vec![None; nodes.len()];
        Ok(Datapath {
            kernel: f.kind.name(),
            nv,
            dims: f.dims,
            ports,
            nodes,
            links,
            clamps,
            factor: Factor::default(),
            outputs,
        })
    }

    /// `fd_grad`'s host partition, robomorphic computing's: from the datapath of `rnea_grad`'s
    /// first two outputs, ∂c/∂q and ∂c/∂q̇ at the q̈ the host supplies (every node of it
    /// live, so the result's are too), ∂q̈/∂u = −M⁻¹ ∂c/∂u with M⁻¹'s
    /// entries as input ports (Featherstone's ∇Dynamics, the seeds' Algorithm 3). `coupled(i,
    /// k)` says whether M⁻¹'s entry (i, k) can be non-zero (joints under different children
    /// of a fixed root never couple); no port is made for the others. Each entry is a
    /// balanced sum of its products, negated.
    pub fn fd_grad_host(rnea_grad: &Datapath, coupled: impl Fn(usize, usize) -> bool) -> Datapath {
        let nv = rnea_grad.nv;
        let mut ports = rnea_grad.ports.clone();
        let mut nodes = rnea_grad.nodes.clone();
        // The product's nodes belong to no joint.
        let push = |nodes: &mut Vec<HwOp>, op: HwOp| {
            nodes.push(op);
            HwId(nodes.len() as u32 - 1)
        };
        // The entries some product reads, each one port (a row of ∂c that is structurally
        // zero leaves M⁻¹'s column unread).
        let nonzero = |d: HwId| rnea_grad.op(d) != HwOp::Const(0.0);
        let read = |i: usize, k: usize| {
            coupled(i.min(k), i.max(k))
                && rnea_grad.outputs.iter().any(|dc| (0..nv).any(|c| nonzero(dc.ids[k * nv + c])))
        };
        let mut minv = vec![None; nv * nv];
        for i in 0..nv {
            for k in i..nv {
                if read(i, k) || read(k, i) {
                    ports.push(Port::Minv(i as u16, k as u16));
                    let id = push(&mut nodes, HwOp::Port(ports.len() as u32 - 1));
                    minv[i * nv + k] = Some(id);
                    minv[k * nv + i] = Some(id);
                }
            }
        }
        // An entry with no product is the constant 0 (made only if some entry needs it).
        let mut zero =
            rnea_grad.nodes.iter().position(|&o| o == HwOp::Const(0.0)).map(|z| HwId(z as u32));
        let outputs = rnea_grad
            .outputs
            .iter()
            .zip(["dqdd_dq", "dqdd_dqd"])
            .map(|(dc, name)| {
                let ids = (0..nv * nv)
                    .map(|e| {
                        let (i, c) = (e / nv, e % nv);
                        let mut terms: Vec<HwId> = (0..nv)
                            .filter_map(|k| {
                                let d = dc.ids[k * nv + c];
                                let m = minv[i * nv + k]?;
                                nonzero(d).then_some((m, d))
                            })
                            .map(|(m, d)| push(&mut nodes, HwOp::Mul(m, d)))
                            .collect();
                        if terms.is_empty() {
                            return *zero.get_or_insert_with(|| push(&mut nodes, HwOp::Const(0.0)));
                        }
                        while terms.len() > 1 {
                            terms = terms
                                .chunks(2)
                                .map(|p| match *p {
                                    [a, b] => push(&mut nodes, HwOp::Add(a, b)),
                                    _ => p[0],
                                })
                                .collect();
                        }
                        push(&mut nodes, HwOp::Neg(terms[0]))
                    })
                    .collect();
                DatapathOutput { name, shape: dc.shape, ids }
            })
            .collect();
        let mut links = rnea_grad.links.clone();
        links.resize(nodes.len(), None);
        let mut clamps = rnea_grad.clamps.clone();
        clamps.resize(nodes.len(), None);
        Datapath {
            kernel: "fd_grad",
            nv,
            dims: rnea_grad.dims,
            ports,
            nodes,
            links,
            clamps,
            factor: rnea_grad.factor.clone(),
            outputs,
        }
    }

    pub fn op(&self, id: HwId) -> HwOp {
        self.nodes[id.0 as usize]
    }

    /// Whether an output entry is structurally zero (no port is emitted for it).
    pub fn is_zero(&self, id: HwId) -> bool {
        self.op(id) == HwOp::Const(0.0)
    }

    /// Every output entry that is not structurally zero: (output index, entry index, node).
    pub fn nonzero_outputs(&self) -> Vec<(usize, usize, HwId)> {
        let mut out = Vec::new();
        for (k, o) in self.outputs.iter().enumerate() {
            for (e, &id) in o.ids.iter().enumerate() {
                if !self.is_zero(id) {
                    out.push((k, e, id));
                }
            }
        }
        out
    }

    /// (multiplications, additions/subtractions/negations).
    pub fn op_counts(&self) -> (usize, usize) {
        let muls = self.nodes.iter().filter(|o| o.is_mul()).count();
        let adds = self.nodes.iter().filter(|o| o.is_add()).count();
        (muls, adds)
    }

    /// Reciprocals (the divider's operations).
    pub fn reciprocals(&self) -> usize {
        self.nodes.iter().filter(|o| matches!(o, HwOp::Recip(_))).count()
    }

    /// Multiplications with a constant operand (cheaper in hardware: shift-and-add).
    pub fn constant_muls(&self) -> usize {
        self.nodes
            .iter()
            .filter(|o| match o {
                HwOp::Mul(a, b) => {
                    matches!(self.op(*a), HwOp::Const(_)) || matches!(self.op(*b), HwOp::Const(_))
                }
                _ => false,
            })
            .count()
    }
}

/// Whether `a / b` is a quaternion's scale `2 / (qx² + qy² + qz² + qw²)` (see
/// `ir::spatial::group_xform`): 2 over a sum of products of the four entries q[k..k + 4];
/// returns k, the least q index read.
fn quat_scale(f: &Function, a: Id, b: Id) -> Option<u16> {
    fn q_inputs(f: &Function, id: Id, out: &mut Vec<u16>) -> bool {
        match f.op(id) {
            Op::Input(Input::Q, j) => {
                out.push(j);
                true
            }
            Op::Add(x, y) | Op::Mul(x, y) => q_inputs(f, x, out) && q_inputs(f, y, out),
            _ => false,
        }
    }
    let mut read = Vec::new();
    if !matches!(f.op(a), Op::Const(c) if c == 2.0) || !q_inputs(f, b, &mut read) {
        return None;
    }
    read.sort_unstable();
    read.dedup();
    (read.len() == 4 && read[3] == read[0] + 3).then_some(read[0])
}
