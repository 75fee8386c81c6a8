//! Operation counts of lowered functions, and the bounded "before and after
//! specialisation" comparison behind `grid-gen info`.

use serde::Serialize;

use super::graph::Op;
use super::kernel::{Gradient, KernelKind, Solve};
use super::module::{lower_function, Calls, Function, LowerError, LowerOptions};
use crate::model::Model;

/// Arithmetic operations of a kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct OpCounts {
    /// Additions and subtractions.
    pub add: usize,
    pub mul: usize,
    /// Divisions and square roots (the Lie-group kernels' logarithm).
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

impl Function {
    pub fn counts(&self) -> OpCounts {
        let mut c = OpCounts::default();
        let mut depth = vec![0usize; self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            let below = node.op.operands().map(|o| depth[o.0 as usize]).max().unwrap_or(0);
            let is_op = !matches!(node.op, Op::Input(..) | Op::Const(_));
            depth[i] = below + usize::from(is_op);
            c.depth = c.depth.max(depth[i]);
            match node.op {
                Op::Add(..) | Op::Sub(..) => c.add += 1,
                Op::Mul(..) => c.mul += 1,
                Op::Neg(_) => c.neg += 1,
                Op::Sin(_) | Op::Cos(_) => c.trig += 1,
                // A square root costs what a division does (both about 15-20 cycles' latency).
                Op::Div(..) | Op::Sqrt(_) => c.div += 1,
                Op::Input(..) | Op::Const(_) => {}
            }
        }
        c
    }
}

/// Op counts of one kernel, before (general dense algorithm) and after specialisation.
#[derive(Clone, Debug, Serialize)]
pub struct KernelStats {
    pub kernel: KernelKind,
    /// `None` where the general graph is over the node limit (a humanoid's contact step:
    /// its specialised graph is counted all the same).
    pub before: Option<OpCounts>,
    pub after: OpCounts,
    /// The RNEA gradient's formulation in the specialised kernel, where it has one (the
    /// general algorithm is always `columns`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gradient: Option<Gradient>,
    /// How the specialised `fd_grad` applies M⁻¹ (picked by operation count).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub solve: Option<Solve>,
}

/// A kernel left out of [`Stats`] because one of its graphs exceeds the node limit.
#[derive(Clone, Debug, Serialize)]
pub struct Skipped {
    pub kernel: KernelKind,
    pub reason: String,
}

#[derive(Clone, Debug, Serialize)]
pub struct Stats {
    pub ops: Vec<KernelStats>,
    pub skipped: Vec<Skipped>,
}

/// Node limit of each graph that [`stats`] builds by default: a few seconds and a few
/// hundred MB at most (Atlas's largest, the dense `fd_grad`, has about 1.1 million).
pub const STATS_MAX_NODES: usize = 2_000_000;

/// Counts every kernel specialised and as the general algorithm, each graph built under
/// `max_nodes`. A kernel whose graph would be larger is listed as skipped, and so is
/// every kernel that contains it, without building them: time and memory stay bounded
/// whatever the robot. `gradient` picks the specialised graphs' RNEA-gradient formulation
/// (the general count is always the column formulation, as a library runs it), and `calls`
/// the routes that `solve`'s `auto` may pick (as generation's `--calls`).
pub fn stats(
    model: &Model,
    gravity: [f64; 3],
    gradient: Gradient,
    solve: Solve,
    calls: Calls,
    max_nodes: usize,
) -> Stats {
    let mut out = Stats { ops: Vec::new(), skipped: Vec::new() };
    let mut too_large: Vec<(KernelKind, KernelKind)> = Vec::new();
    let mut kinds = KernelKind::for_model(model);
    super::module::lowering_order(&mut kinds);
    for kind in kinds {
        if let Some((_, inner)) = too_large.iter().find(|(k, _)| *k == kind) {
            out.skipped.push(Skipped {
                kernel: kind,
                reason: format!("contains `{inner}`, which is over the node limit"),
            });
            continue;
        }
        // The specialised graph first: a kernel over the limit there is skipped (and so is
        // every kernel that holds it); the general graph over the limit only leaves its
        // "before" count out.
        let specialised =
            LowerOptions { gradient, solve, calls, max_nodes, ..LowerOptions::default() };
        let routes =
            |c: KernelKind| out.ops.iter().find(|k| k.kernel == c).map(|k| (k.gradient, k.solve));
        let pinned = super::module::options_after_callee(model, kind, &specialised, routes);
        let f = match lower_function(model, gravity, kind, pinned.as_ref().unwrap_or(&specialised))
        {
            Ok(f) => f,
            Err(e) => {
                let reason = match e {
                    LowerError::TooLarge { limit, .. } => {
                        too_large.extend(kind.contained_in().iter().map(|&k| (k, kind)));
                        format!("over {limit} IR nodes, the limit for op counts")
                    }
                    other => other.to_string(),
                };
                out.skipped.push(Skipped { kernel: kind, reason });
                continue;
            }
        };
        let general = LowerOptions { max_nodes, ..LowerOptions::general() };
        let before = match lower_function(model, gravity, kind, &general) {
            Ok(g) => Some(g.counts()),
            Err(LowerError::TooLarge { .. }) => None,
            Err(e) => {
                out.skipped.push(Skipped { kernel: kind, reason: e.to_string() });
                continue;
            }
        };
        out.ops.push(KernelStats {
            kernel: kind,
            after: f.counts(),
            before,
            gradient: f.gradient,
            solve: f.solve,
        });
    }
    out.ops.sort_by_key(|k| k.kernel.position());
    out.skipped.sort_by_key(|k| k.kernel.position());
    out
}
