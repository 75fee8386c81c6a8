//! Target-neutral scheduling of a frozen function: [`Chunks`] splits straight-line code
//! into functions of bounded size with scratch slots for the values that cross them (Rust
//! and WGSL's thread strategy), and [`Phases`] places the operations on P parallel
//! workers in barrier-separated phases, with shared slots for the values that cross
//! workers or phases, under a slot budget. (WGSL's cooperative strategy was built on
//! `Phases` and now schedules by graph levels of its own, which measured far shorter on
//! the robots' gradients; `Phases` has no caller in the backends today.)

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::graph::Id;
use super::module::Function;

/// Straight-line code split into chunks of at most `size` operations, in node order.
/// Constants and inputs belong to no chunk (backends print them inline).
#[derive(Clone, Debug, PartialEq)]
pub struct Chunks {
    pub chunks: Vec<Vec<Id>>,
    /// Chunk that computes each node.
    pub chunk_of: Vec<Option<u32>>,
    /// Scratch slot of each node read by a later chunk; a slot is reused once the last
    /// chunk reading its value has run.
    pub slot: Vec<Option<u32>>,
    pub slots: usize,
    /// Per node, where it is a value the kernel's callee computed and keeps
    /// ([`crate::ir::Call::shared`]): the callee's slot that holds it. Empty until a backend
    /// sets it.
    pub provided: Vec<Option<u32>>,
}

impl Chunks {
    pub fn new(f: &Function, size: usize) -> Chunks {
        Chunks::split(f, size, &[]).0
    }

    /// Chunks of which the first ones hold exactly the nodes marked `ahead` (closed under
    /// operands, as [`crate::ir::Call::ahead`]), so that a call can run between them and
    /// the others; returns the number of those first chunks. No marks: [`Chunks::new`].
    pub fn split(f: &Function, size: usize, ahead: &[bool]) -> (Chunks, usize) {
        Chunks::split_keeping(f, size, ahead, &[])
    }

    /// [`Chunks::split`], with a slot of its own, never reused, for each node marked `keep`
    /// (the values a caller reads after the chunks have run, [`crate::ir::Call::shared`]).
    pub fn split_keeping(
        f: &Function,
        size: usize,
        ahead: &[bool],
        keep: &[bool],
    ) -> (Chunks, usize) {
        let size = size.max(1);
        let mut chunks: Vec<Vec<Id>> = vec![Vec::new()];
        let mut chunk_of = vec![None; f.nodes.len()];
        let mut first = 0;
        let groups: &[Option<bool>] =
            if ahead.is_empty() { &[None] } else { &[Some(true), Some(false)] };
        for &group in groups {
            if group == Some(false) {
                // The other nodes start a chunk of their own.
                if chunks.last().is_some_and(|c| !c.is_empty()) {
                    chunks.push(Vec::new());
                }
                first = chunks.len() - 1;
            }
            for i in 0..f.nodes.len() {
                let id = Id(i as u32);
                if !f.is_operation(id) || group.is_some_and(|g| ahead[i] != g) {
                    continue;
                }
                if chunks.last().is_some_and(|c| c.len() >= size) {
                    chunks.push(Vec::new());
                }
                if let Some(c) = chunks.last_mut() {
                    c.push(id);
                }
                chunk_of[i] = Some((chunks.len() - 1) as u32);
            }
        }
        let (slot, slots) = assign_slots(f, &chunk_of, &chunks, keep);
        (Chunks { chunks, chunk_of, slot, slots, provided: Vec::new() }, first)
    }
}

/// Slots for the values read in a later step than the one that computes them, given each
/// node's step (`None`: constants and inputs) and the nodes of each step in order. A slot
/// is reused only by a value written in a step after the last step that reads its
/// previous value, so no step both reads and overwrites a slot; free slots are taken
/// lowest first, for stable, compact numbering. A node marked in `keep` holds its slot to
/// the end. Returns each node's slot and the count.
fn assign_slots(
    f: &Function,
    step_of: &[Option<u32>],
    steps: &[Vec<Id>],
    keep: &[bool],
) -> (Vec<Option<u32>>, usize) {
    let mut last_read: Vec<Option<u32>> = vec![None; f.nodes.len()];
    for (i, _) in keep.iter().enumerate().filter(|(_, &k)| k) {
        last_read[i] = Some(u32::MAX);
    }
    for (i, node) in f.nodes.iter().enumerate() {
        let Some(si) = step_of[i] else { continue };
        for o in node.op.operands() {
            if step_of[o.0 as usize].is_some_and(|so| so < si) {
                let r = &mut last_read[o.0 as usize];
                *r = Some(r.map_or(si, |x| x.max(si)));
            }
        }
    }
    let mut slot = vec![None; f.nodes.len()];
    let mut slots = 0u32;
    let mut free: Vec<u32> = Vec::new();
    let mut busy: Vec<(u32, u32)> = Vec::new();
    for (step, ids) in steps.iter().enumerate() {
        let step = step as u32;
        busy.retain(|&(s, until)| {
            let keep = until >= step;
            if !keep {
                free.push(s);
            }
            keep
        });
        free.sort_unstable_by(|a, b| b.cmp(a));
        for id in ids {
            if let Some(until) = last_read[id.0 as usize] {
                let s = free.pop().unwrap_or_else(|| {
                    slots += 1;
                    slots - 1
                });
                slot[id.0 as usize] = Some(s);
                busy.push((s, until));
            }
        }
    }
    (slot, slots as usize)
}

/// Where one operation runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Place {
    pub phase: u32,
    pub worker: u32,
}

/// A function's operations on `workers` parallel workers: within a phase each worker runs
/// its list in order; a barrier separates phases. An operation reads values computed
/// earlier in its own list directly, and every other value from a shared slot.
#[derive(Clone, Debug, PartialEq)]
pub struct Phases {
    pub workers: usize,
    /// `phases[p][w]`: the operations worker w runs in phase p, in order.
    pub phases: Vec<Vec<Vec<Id>>>,
    pub place: Vec<Option<Place>>,
    /// Shared slot of each operation read in a later phase. A slot is reused only by a
    /// value written in a phase after the last phase that reads its previous value, so
    /// no phase both reads and overwrites a slot.
    pub slot: Vec<Option<u32>>,
    pub slots: usize,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ScheduleError {
    #[error("{kernel}: the schedule needs {needed} shared slots, over the budget of {budget}")]
    OverBudget { kernel: &'static str, needed: usize, budget: usize },
    #[error("a schedule needs at least one worker")]
    NoWorkers,
}

impl Phases {
    /// List scheduling in node order: a phase takes every operation whose operands are
    /// done, the lowest id first (the algorithm's own order, which keeps few values live),
    /// on the least-loaded worker; an operation whose operands from this phase all come
    /// from one worker joins that worker's list in the same phase. Fails if the shared
    /// values live at once need more than `max_slots` slots.
    pub fn new(f: &Function, workers: usize, max_slots: usize) -> Result<Phases, ScheduleError> {
        if workers == 0 {
            return Err(ScheduleError::NoWorkers);
        }
        let n = f.nodes.len();
        let is_op: Vec<bool> = (0..n).map(|i| f.is_operation(Id(i as u32))).collect();
        // Users of each operation (CSR), and how many operation operands each waits for.
        let mut pending = vec![0u32; n];
        let mut user_count = vec![0u32; n + 1];
        for (i, node) in f.nodes.iter().enumerate() {
            for o in node.op.operands() {
                if is_op[o.0 as usize] {
                    pending[i] += 1;
                    user_count[o.0 as usize + 1] += 1;
                }
            }
        }
        for i in 0..n {
            user_count[i + 1] += user_count[i];
        }
        let mut users = vec![0u32; user_count[n] as usize];
        let mut fill = user_count.clone();
        for (i, node) in f.nodes.iter().enumerate() {
            for o in node.op.operands() {
                if is_op[o.0 as usize] {
                    users[fill[o.0 as usize] as usize] = i as u32;
                    fill[o.0 as usize] += 1;
                }
            }
        }

        const MANY: u32 = u32::MAX;
        let mut place: Vec<Option<Place>> = vec![None; n];
        // For waiting operations: the worker that supplied operands in the current phase
        // (MANY if several did), stamped with the phase.
        let mut from: Vec<(u32, u32)> = vec![(u32::MAX, 0); n];
        let mut ready: BinaryHeap<Reverse<u32>> =
            (0..n).filter(|&i| is_op[i] && pending[i] == 0).map(|i| Reverse(i as u32)).collect();
        let mut phases: Vec<Vec<Vec<Id>>> = Vec::new();
        let mut done = 0usize;
        let total = is_op.iter().filter(|&&x| x).count();
        while done < total {
            let p = phases.len() as u32;
            let mut lists: Vec<Vec<Id>> = vec![Vec::new(); workers];
            // Operations ready within this phase on one worker: (id, worker).
            let mut local: BinaryHeap<Reverse<(u32, u32)>> = BinaryHeap::new();
            let mut next_phase: Vec<u32> = Vec::new();
            loop {
                let take_local = match (local.peek(), ready.peek()) {
                    (Some(Reverse((l, _))), Some(Reverse(g))) => l < g,
                    (Some(_), None) => true,
                    (None, Some(_)) => false,
                    (None, None) => break,
                };
                let (id, w) = if take_local {
                    let Reverse((id, w)) = local.pop().unwrap_or_default();
                    (id, w)
                } else {
                    let Reverse(id) = ready.pop().unwrap_or_default();
                    let w = (0..workers).min_by_key(|&w| (lists[w].len(), w)).unwrap_or(0) as u32;
                    (id, w)
                };
                lists[w as usize].push(Id(id));
                place[id as usize] = Some(Place { phase: p, worker: w });
                done += 1;
                for &u in
                    &users[user_count[id as usize] as usize..user_count[id as usize + 1] as usize]
                {
                    let u = u as usize;
                    let (stamp, who) = from[u];
                    from[u] = if stamp == p && who != w { (p, MANY) } else { (p, w) };
                    pending[u] -= 1;
                    if pending[u] == 0 {
                        match from[u].1 {
                            MANY => next_phase.push(u as u32),
                            only => local.push(Reverse((u as u32, only))),
                        }
                    }
                }
            }
            ready.extend(next_phase.into_iter().map(Reverse));
            phases.push(lists);
        }

        let phase_of: Vec<Option<u32>> = place.iter().map(|p| p.map(|p| p.phase)).collect();
        let in_phase: Vec<Vec<Id>> =
            phases.iter().map(|lists| lists.iter().flatten().copied().collect()).collect();
        let (slot, slots) = assign_slots(f, &phase_of, &in_phase, &[]);
        if slots > max_slots {
            return Err(ScheduleError::OverBudget {
                kernel: f.kind.name(),
                needed: slots,
                budget: max_slots,
            });
        }
        Ok(Phases { workers, phases, place, slot, slots })
    }

    /// The longest list of each phase, summed: the schedule's length in operations.
    pub fn span(&self) -> usize {
        self.phases.iter().map(|p| p.iter().map(Vec::len).max().unwrap_or(0)).sum()
    }
}
