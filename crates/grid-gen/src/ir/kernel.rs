//! Kernels: one graph per public function (`rnea`, `rnea_grad`, `mass_matrix`, `minv`,
//! `fd`, `fd_grad`), with named outputs, dead nodes removed, and op counts.

use serde::Serialize;

use super::dynamics::Dynamics;
use super::graph::{Graph, Id, Input, Op};
use crate::model::Model;

/// A named result: a vector of `nv` or a row-major `nv x nv` matrix.
#[derive(Clone, Debug)]
pub struct Output {
    pub name: &'static str,
    pub matrix: bool,
    pub ids: Vec<Id>,
}

/// One function to emit.
pub struct Kernel {
    pub name: &'static str,
    pub inputs: Vec<Input>,
    pub outputs: Vec<Output>,
    pub graph: Graph,
    /// `live[id]`: the node contributes to an output.
    pub live: Vec<bool>,
}

/// The kernels every backend emits, in this order.
pub const KERNELS: [&str; 6] = ["rnea", "rnea_grad", "mass_matrix", "minv", "fd", "fd_grad"];

fn flat(m: Vec<Vec<Id>>) -> Vec<Id> {
    m.into_iter().flatten().collect()
}

/// Builds kernel `name` (one of [`KERNELS`]). With `specialise` off, records the
/// general dense algorithm instead (for op counts only).
pub fn build(model: &Model, gravity: [f64; 3], name: &'static str, specialise: bool) -> Kernel {
    use Input::*;
    let mut d = Dynamics::new(model, gravity, specialise);
    let (inputs, outputs) = match name {
        "rnea" => {
            let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
            let r = d.rnea(&qd, &qdd);
            (vec![Q, Qd, Qdd], vec![Output { name: "c", matrix: false, ids: r.c }])
        }
        "rnea_grad" => {
            let (qd, qdd) = (d.inputs(Qd), d.inputs(Qdd));
            let r = d.rnea(&qd, &qdd);
            let (dq, dqd) = d.rnea_grad(&r, &qd);
            (vec![Q, Qd, Qdd], vec![Output { name: "dc_dq", matrix: true, ids: flat(dq) }, Output { name: "dc_dqd", matrix: true, ids: flat(dqd) }])
        }
        "mass_matrix" => (vec![Q], vec![Output { name: "m", matrix: true, ids: flat(d.mass_matrix()) }]),
        "minv" => (vec![Q], vec![Output { name: "minv", matrix: true, ids: flat(d.minv()) }]),
        "fd" => {
            let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
            let (qdd, _) = d.fd(&qd, &tau);
            (vec![Q, Qd, Tau], vec![Output { name: "qdd", matrix: false, ids: qdd }])
        }
        "fd_grad" => {
            let (qd, tau) = (d.inputs(Qd), d.inputs(Tau));
            let (qdd, dq, dqd) = d.fd_grad(&qd, &tau);
            (
                vec![Q, Qd, Tau],
                vec![
                    Output { name: "qdd", matrix: false, ids: qdd },
                    Output { name: "dqdd_dq", matrix: true, ids: flat(dq) },
                    Output { name: "dqdd_dqd", matrix: true, ids: flat(dqd) },
                ],
            )
        }
        other => unreachable!("unknown kernel {other}"),
    };
    let graph = d.g;
    let live = liveness(&graph, &outputs);
    Kernel { name, inputs, outputs, graph, live }
}

/// Marks the nodes that reach an output (dead-code elimination).
fn liveness(g: &Graph, outputs: &[Output]) -> Vec<bool> {
    let mut live = vec![false; g.nodes.len()];
    for o in outputs {
        for id in &o.ids {
            live[id.0 as usize] = true;
        }
    }
    for i in (0..g.nodes.len()).rev() {
        if live[i] {
            for operand in g.nodes[i].op.operands() {
                live[operand.0 as usize] = true;
            }
        }
    }
    live
}

/// Arithmetic operations of a kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct OpCounts {
    /// Additions and subtractions.
    pub add: usize,
    pub mul: usize,
    pub div: usize,
    pub neg: usize,
    /// sin and cos.
    pub trig: usize,
    /// Longest chain of dependent operations.
    pub depth: usize,
}

impl OpCounts {
    pub fn total(&self) -> usize {
        self.add + self.mul + self.div + self.neg + self.trig
    }
}

impl Kernel {
    pub fn counts(&self) -> OpCounts {
        let mut c = OpCounts::default();
        let mut depth = vec![0usize; self.graph.nodes.len()];
        for (i, node) in self.graph.nodes.iter().enumerate() {
            if !self.live[i] {
                continue;
            }
            let below = node.op.operands().map(|o| depth[o.0 as usize]).max().unwrap_or(0);
            let is_op = !matches!(node.op, Op::Input(..) | Op::Const(_));
            depth[i] = below + usize::from(is_op);
            c.depth = c.depth.max(depth[i]);
            match node.op {
                Op::Add(..) | Op::Sub(..) => c.add += 1,
                Op::Mul(..) => c.mul += 1,
                Op::Div(..) => c.div += 1,
                Op::Neg(_) => c.neg += 1,
                Op::Sin(_) | Op::Cos(_) => c.trig += 1,
                Op::Input(..) | Op::Const(_) => {}
            }
        }
        c
    }
}

/// Op counts of every kernel, before (general dense algorithm) and after specialisation.
#[derive(Clone, Debug, Serialize)]
pub struct KernelStats {
    pub kernel: &'static str,
    pub before: OpCounts,
    pub after: OpCounts,
}

pub fn stats(model: &Model, gravity: [f64; 3]) -> Vec<KernelStats> {
    KERNELS
        .iter()
        .map(|&name| KernelStats { kernel: name, before: build(model, gravity, name, false).counts(), after: build(model, gravity, name, true).counts() })
        .collect()
}

impl Kernel {
    /// Interprets the graph in f64: `inputs` in the order of `self.inputs`, each of length
    /// nv. Returns each output's values (matrices row-major). Used to check the IR itself,
    /// before any backend prints it.
    pub fn eval(&self, inputs: &[&[f64]]) -> Vec<Vec<f64>> {
        let mut val = vec![0.0; self.graph.nodes.len()];
        for (i, node) in self.graph.nodes.iter().enumerate() {
            if !self.live[i] {
                continue;
            }
            let v = |id: Id| val[id.0 as usize];
            val[i] = match node.op {
                Op::Input(which, j) => {
                    let slot = self.inputs.iter().position(|&x| x == which).expect("kernel input");
                    inputs[slot][j as usize]
                }
                Op::Const(c) => c,
                Op::Add(a, b) => v(a) + v(b),
                Op::Sub(a, b) => v(a) - v(b),
                Op::Mul(a, b) => v(a) * v(b),
                Op::Div(a, b) => v(a) / v(b),
                Op::Neg(a) => -v(a),
                Op::Sin(a) => v(a).sin(),
                Op::Cos(a) => v(a).cos(),
            };
        }
        self.outputs.iter().map(|o| o.ids.iter().map(|id| val[id.0 as usize]).collect()).collect()
    }
}
