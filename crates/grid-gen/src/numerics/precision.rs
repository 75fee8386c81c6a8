//! Mixed precision: which nodes of a kernel to compute in f64 so that
//! the others can run in f32, chosen by a first-order rounding-error analysis of the
//! graph at sample states, and the interpreter that runs a kernel so split (the oracle of
//! the mixed Rust the backend emits).
//!
//! The model (Higham, "Accuracy and Stability of Numerical Algorithms", 2nd ed., §3.1,
//! first-order error propagation through a computational graph): a node j computed in
//! f32 rounds its result and each operand taken from an f64 node, relative error at most
//! u = 2⁻²⁴ each, so it perturbs output o by at most
//! `u · |∂o/∂v_j| · (|v_j| + Σ_k |∂v_j/∂v_k| |v_k|)` over its operands k. Counting every
//! operand as rounded overcounts operands that are f32 already, so the sum over the f32
//! nodes is an upper bound (to first order) on each output's error. Its weight is that
//! term without u, relative to the largest entry of the output, the largest over the
//! outputs' entries and the sample states.

use crate::ir::{Function, Id, Op};

/// f32's unit roundoff, 2⁻²⁴ (round to nearest).
pub const F32_UNIT_ROUNDOFF: f64 = 1.0 / 16_777_216.0;

/// Which nodes run in f64, and the analysis behind the choice.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// Per node: computed (and stored) in f64.
    pub wide: Vec<bool>,
    /// The first-order bound on each output's relative error that the f32 nodes leave,
    /// at the sample states.
    pub bound: f64,
    /// The same bound with every node in f32.
    pub all_f32_bound: f64,
}

impl Plan {
    /// Nodes computed in f64, of the operations (constants and inputs not counted).
    pub fn wide_operations(&self, f: &Function) -> (usize, usize) {
        let ops: Vec<usize> =
            (0..f.nodes.len()).filter(|&i| f.is_operation(Id(i as u32))).collect();
        (ops.iter().filter(|&&i| self.wide[i]).count(), ops.len())
    }
}

/// The weight of each node (see the module documentation), the largest over `states`
/// (each the kernel's inputs, as [`Function::eval`] takes them).
pub fn weights(f: &Function, states: &[Vec<Vec<f64>>]) -> Vec<f64> {
    let n = f.nodes.len();
    let mut weight = vec![0.0f64; n];
    let mut adjoint = vec![0.0f64; n];
    for inputs in states {
        let refs: Vec<&[f64]> = inputs.iter().map(|v| v.as_slice()).collect();
        let val = f.eval_nodes(&refs);
        // Local rounding exposure of each node run in f32: its result and its operands.
        let exposure: Vec<f64> = (0..n)
            .map(|j| {
                let v = |id: Id| val[id.0 as usize];
                val[j].abs()
                    + match f.nodes[j].op {
                        Op::Input(..) | Op::Const(_) => 0.0,
                        Op::Add(a, b) | Op::Sub(a, b) => v(a).abs() + v(b).abs(),
                        Op::Mul(..) => 2.0 * val[j].abs(),
                        Op::Div(..) => 2.0 * val[j].abs(),
                        // √x rounds once, and halves its operand's relative error.
                        Op::Sqrt(_) => 1.5 * val[j].abs(),
                        Op::Neg(_) => val[j].abs(),
                        Op::Sin(a) => (v(a).cos() * v(a)).abs(),
                        Op::Cos(a) => (v(a).sin() * v(a)).abs(),
                    }
            })
            .collect();
        for out in &f.outputs {
            let scale = out.ids.iter().map(|id| val[id.0 as usize].abs()).fold(0.0, f64::max);
            if scale == 0.0 {
                continue;
            }
            for &seed in &out.ids {
                if !f.is_operation(seed) && !matches!(f.op(seed), Op::Input(..)) {
                    continue;
                }
                // Reverse sweep from this output entry: adjoint[k] = ∂entry/∂v_k.
                let top = seed.0 as usize;
                adjoint[..=top].iter_mut().for_each(|a| *a = 0.0);
                adjoint[top] = 1.0;
                for j in (0..=top).rev() {
                    let a = adjoint[j];
                    if a == 0.0 {
                        continue;
                    }
                    weight[j] = weight[j].max((a * exposure[j]).abs() / scale);
                    let v = |id: Id| val[id.0 as usize];
                    let mut push = |id: Id, d: f64| adjoint[id.0 as usize] += a * d;
                    match f.nodes[j].op {
                        Op::Input(..) | Op::Const(_) => {}
                        Op::Add(x, y) => {
                            push(x, 1.0);
                            push(y, 1.0);
                        }
                        Op::Sub(x, y) => {
                            push(x, 1.0);
                            push(y, -1.0);
                        }
                        Op::Mul(x, y) => {
                            push(x, v(y));
                            push(y, v(x));
                        }
                        Op::Div(x, y) => {
                            push(x, 1.0 / v(y));
                            push(y, -v(x) / (v(y) * v(y)));
                        }
                        Op::Neg(x) => push(x, -1.0),
                        Op::Sin(x) => push(x, v(x).cos()),
                        Op::Cos(x) => push(x, -v(x).sin()),
                        Op::Sqrt(x) => push(x, 0.5 / val[j]),
                    }
                }
            }
        }
    }
    weight
}

/// The fewest f64 nodes whose first-order bound (module documentation) meets `target`,
/// by weight, heaviest first: every node left in f32 is lighter than every node moved.
pub fn plan(f: &Function, states: &[Vec<Vec<f64>>], target: f64) -> Plan {
    let weight = weights(f, states);
    let all_f32_bound = F32_UNIT_ROUNDOFF * weight.iter().sum::<f64>();
    let mut order: Vec<usize> = (0..weight.len()).collect();
    order.sort_by(|&a, &b| weight[b].total_cmp(&weight[a]).then(a.cmp(&b)));
    let mut wide = vec![false; weight.len()];
    let mut bound = all_f32_bound;
    for &k in &order {
        if bound <= target {
            break;
        }
        wide[k] = true;
        bound -= F32_UNIT_ROUNDOFF * weight[k];
    }
    // An f32 operation between f64 neighbours only would cost two conversions and save
    // nothing: it joins them (the bound can only fall). Repeated to a fixed point.
    let mut users: Vec<Vec<usize>> = vec![Vec::new(); f.nodes.len()];
    for (i, node) in f.nodes.iter().enumerate() {
        for o in node.op.operands() {
            users[o.0 as usize].push(i);
        }
    }
    let is_op = |i: usize| f.is_operation(Id(i as u32));
    loop {
        let mut changed = false;
        for i in 0..f.nodes.len() {
            if !is_op(i) || wide[i] {
                continue;
            }
            let operands_wide = f.nodes[i]
                .op
                .operands()
                .filter(|o| is_op(o.0 as usize))
                .all(|o| wide[o.0 as usize]);
            if operands_wide && !users[i].is_empty() && users[i].iter().all(|&u| wide[u]) {
                wide[i] = true;
                bound -= F32_UNIT_ROUNDOFF * weight[i];
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    Plan { wide, bound: bound.max(0.0), all_f32_bound }
}

impl Function {
    /// The kernel run as `plan` splits it: f64 nodes in f64; f32 nodes in f32 arithmetic
    /// on their operands rounded to f32 (inputs and constants rounded where they are f32).
    /// What the mixed Rust the backend emits computes, bit for bit.
    pub fn eval_mixed(&self, inputs: &[&[f64]], wide: &[bool]) -> Vec<Vec<f64>> {
        let mut val = vec![0.0f64; self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            let w = |id: Id| val[id.0 as usize];
            let n = |id: Id| val[id.0 as usize] as f32;
            val[i] = if wide[i] {
                match node.op {
                    Op::Input(which, j) => inputs[self.input_slot(which)][j as usize],
                    Op::Const(c) => c,
                    Op::Add(a, b) => w(a) + w(b),
                    Op::Sub(a, b) => w(a) - w(b),
                    Op::Mul(a, b) => w(a) * w(b),
                    Op::Div(a, b) => w(a) / w(b),
                    Op::Neg(a) => -w(a),
                    Op::Sin(a) => w(a).sin(),
                    Op::Cos(a) => w(a).cos(),
                    Op::Sqrt(a) => w(a).sqrt(),
                }
            } else {
                f64::from(match node.op {
                    Op::Input(which, j) => inputs[self.input_slot(which)][j as usize] as f32,
                    Op::Const(c) => c as f32,
                    Op::Add(a, b) => n(a) + n(b),
                    Op::Sub(a, b) => n(a) - n(b),
                    Op::Mul(a, b) => n(a) * n(b),
                    Op::Div(a, b) => n(a) / n(b),
                    Op::Neg(a) => -n(a),
                    Op::Sin(a) => n(a).sin(),
                    Op::Cos(a) => n(a).cos(),
                    Op::Sqrt(a) => n(a).sqrt(),
                })
            };
        }
        self.outputs.iter().map(|o| o.ids.iter().map(|id| val[id.0 as usize]).collect()).collect()
    }
}
