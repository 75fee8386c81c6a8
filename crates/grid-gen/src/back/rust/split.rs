//! A callee whose parts run around its caller's ([`crate::ir::Call::shared`]): the callee's
//! first parts compute what the caller's rest reads of it and keep it in their slots, the
//! rest's parts before the call read those slots, the callee's other parts follow.

use crate::ir::mark_ancestors;
use crate::ir::schedule::Chunks;
use crate::ir::{Function, Id, KernelKind, Module};

/// A callee's chunks as its callers run them: the first `first` compute its exported values
/// (and what they read), each in a slot of its own.
pub(super) struct SplitCallee<'a> {
    pub f: &'a Function,
    pub names: Chunks,
    pub first: usize,
}

/// The nodes of `callee` that some rest of `module` reads ([`crate::ir::Call::shared`]), in
/// order.
fn exports(module: &Module, callee: KernelKind) -> Vec<Id> {
    let mut ids: Vec<Id> = module
        .functions
        .iter()
        .filter_map(|f| f.call.as_deref())
        .filter(|c| c.callees.contains(&callee))
        .flat_map(|c| c.shared.iter().map(|&(_, at)| at))
        .collect();
    ids.sort_unstable();
    ids.dedup();
    ids
}

/// `f`'s chunks: the exported values and what they read first, each export in a slot that
/// is never reused.
fn chunks(f: &Function, size: usize, exports: &[Id]) -> (Chunks, usize) {
    let mut keep = vec![false; f.nodes.len()];
    for id in exports {
        keep[id.0 as usize] = true;
    }
    let mut head = keep.clone();
    mark_ancestors(&f.nodes, &mut head, |_| false);
    Chunks::split_keeping(f, size, &head, &keep)
}

/// Every kernel of `module` whose values some rest reads, as it runs: computed once, so that
/// the kernel's own code and its callers' agree on its slots.
pub(super) fn split_callees(module: &Module, size: usize) -> Vec<SplitCallee<'_>> {
    module
        .functions
        .iter()
        .filter(|f| f.call.is_none())
        .filter_map(|f| {
            let exports = exports(module, f.kind);
            (!exports.is_empty()).then(|| {
                let (names, first) = chunks(f, size, &exports);
                SplitCallee { f, names, first }
            })
        })
        .collect()
}

impl<'a> SplitCallee<'a> {
    /// The callee of `call` among `splits`, where the rest shares values with it.
    pub(super) fn of<'s>(
        splits: &'s [SplitCallee<'a>],
        call: &crate::ir::Call,
    ) -> Option<&'s SplitCallee<'a>> {
        let &[callee] = call.callees.as_slice() else { return None };
        if call.shared.is_empty() {
            return None;
        }
        splits.iter().find(|s| s.f.kind == callee)
    }

    /// The rest's node → the callee's slot that holds its value.
    pub(super) fn provided(&self, call: &crate::ir::Call) -> Vec<Option<u32>> {
        let mut provided = vec![None; call.rest.nodes.len()];
        for &(at, from) in &call.shared {
            provided[at.0 as usize] = self.names.slot[from.0 as usize];
        }
        provided
    }
}
