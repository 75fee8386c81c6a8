//! Values a kernel's rest takes from the `rnea_grad` it calls instead of computing them
//! again ([`crate::ir::Call::shared`]): the transforms, velocities and composite inertias
//! that both compute before q̈ enters.

use rustc_hash::FxHashMap;

use super::graph::{Id, Input, Op};
use super::kernel::KernelKind;
use super::module::{Function, Operand};

/// A node's operations and inputs, whatever its id: equal keys, equal values (up to the
/// rounding of a fused multiply-add). Additions and products are keyed with their operands
/// in order of key, as either graph may hold them in either order.
#[derive(Clone, Copy, Hash, PartialEq, Eq)]
enum Key {
    Input(Input, u16),
    Const(u64),
    Binary(u8, u32, u32),
    Unary(u8, u32),
}

/// Interns [`Key`]s over several functions, so that one number names one value in all.
#[derive(Default)]
struct Keys(FxHashMap<Key, u32>);

impl Keys {
    /// Each node's key number.
    fn of(&mut self, f: &Function) -> Vec<u32> {
        let mut out: Vec<u32> = Vec::with_capacity(f.nodes.len());
        for node in &f.nodes {
            let k = |id: Id| out[id.0 as usize];
            let sorted = |a: Id, b: Id| (k(a).min(k(b)), k(a).max(k(b)));
            let key = match node.op {
                Op::Input(input, j) => Key::Input(input, j),
                Op::Const(c) => Key::Const(c.to_bits()),
                Op::Add(a, b) => {
                    let (x, y) = sorted(a, b);
                    Key::Binary(0, x, y)
                }
                Op::Mul(a, b) => {
                    let (x, y) = sorted(a, b);
                    Key::Binary(1, x, y)
                }
                Op::Sub(a, b) => Key::Binary(2, k(a), k(b)),
                Op::Div(a, b) => Key::Binary(3, k(a), k(b)),
                Op::Neg(a) => Key::Unary(0, k(a)),
                Op::Sin(a) => Key::Unary(1, k(a)),
                Op::Cos(a) => Key::Unary(2, k(a)),
                Op::Sqrt(a) => Key::Unary(3, k(a)),
            };
            let next = self.0.len() as u32;
            out.push(*self.0.entry(key).or_insert(next));
        }
        out
    }
}

/// The nodes of `f` that its outputs, its column program and its product read, through
/// nodes that are not `provided` (a provided node is live, its operands only where another
/// live node reads them).
pub(crate) fn live_through(f: &Function, provided: &[bool]) -> Vec<bool> {
    let mut live = vec![false; f.nodes.len()];
    for id in f.outputs.iter().flat_map(|o| o.ids.iter()) {
        live[id.0 as usize] = true;
    }
    let program = f.program.iter().flat_map(|p| p.operands());
    let product = f.product.iter().flat_map(|p| p.minv.iter().chain(p.dc.iter().flatten()));
    for o in program.chain(product.copied()) {
        if let Operand::Node(id) | Operand::Neg(id) = o {
            live[id.0 as usize] = true;
        }
    }
    crate::ir::mark_ancestors(&f.nodes, &mut live, |i| provided.get(i).copied().unwrap_or(false));
    live
}

/// Sets [`crate::ir::Call::shared`] of every kernel whose rest calls `rnea_grad` between
/// its parts ([`crate::ir::Call::ahead`]): each operation of the rest that `rnea_grad`
/// computes too without reading an argument that a caller computes itself (q̈, and λ where
/// `contact_fd_grad` calls), and that the rest reads where it does not compute it
/// again, paired with `rnea_grad`'s node. The rest's graph keeps those nodes, so every
/// other reader of it (`eval`, the tests) sees the same function.
pub(crate) fn share_callee_values(functions: &mut [Function]) {
    let Some(callee) = functions.iter().find(|f| f.kind == KernelKind::RneaGrad) else {
        return;
    };
    // The callee runs as its parts: it must hold nothing else to run (a program's or a
    // product's arrays) and call nothing itself.
    if callee.call.is_some() || callee.program.is_some() || callee.product.is_some() {
        return;
    }
    let splits = |f: &Function| {
        f.call
            .as_deref()
            .is_some_and(|c| !c.ahead.is_empty() && c.callees == [KernelKind::RneaGrad])
    };
    // The callee's arguments that some caller computes itself (q̈; λ, which `fd_grad` takes
    // and `contact_fd_grad` computes): the callee's first parts run before them, and one
    // copy of those parts serves every caller.
    let own: Vec<Input> = functions
        .iter()
        .filter(|f| splits(f))
        .flat_map(|f| callee.inputs().iter().filter(|i| !f.inputs().contains(i)))
        .copied()
        .collect();
    let mut keys = Keys::default();
    let callee_keys = keys.of(callee);
    // The callee's values that do not read those, by key (the first node of each key).
    let mut free = vec![true; callee.nodes.len()];
    let mut by_key: FxHashMap<u32, Id> = FxHashMap::default();
    for (i, node) in callee.nodes.iter().enumerate() {
        free[i] = match node.op {
            Op::Input(input, _) => !own.contains(&input),
            _ => node.op.operands().all(|o| free[o.0 as usize]),
        };
        if free[i] && callee.is_operation(Id(i as u32)) {
            by_key.entry(callee_keys[i]).or_insert(Id(i as u32));
        }
    }
    for f in functions.iter_mut().filter(|f| splits(f)) {
        let Some(call) = f.call.as_mut() else { continue };
        let rest = &call.rest;
        let rest_keys = keys.of(rest);
        let matched: Vec<Option<Id>> = (0..rest.nodes.len())
            .map(|i| {
                let operation = rest.is_operation(Id(i as u32));
                operation.then(|| by_key.get(&rest_keys[i]).copied()).flatten()
            })
            .collect();
        let provided: Vec<bool> = matched.iter().map(Option::is_some).collect();
        let live = live_through(rest, &provided);
        call.shared = matched
            .iter()
            .enumerate()
            .filter_map(|(i, m)| m.filter(|_| live[i]).map(|c| (Id(i as u32), c)))
            .collect();
    }
}
