//! Runs independent pieces of the generator (the kernels to emit and format) on every
//! core, with results in the pieces' order so that the output never depends on timing.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// `f` of each of `items`, in order, computed on up to every core (the next free thread
/// takes the next item, so one large item does not hold back the rest).
pub(crate) fn in_parallel<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let slots: Vec<Option<R>> = items.iter().map(|_| None).collect();
    let slots = fold_in_parallel(items, cores(), slots, f, |slots, i, r| slots[i] = Some(r));
    // Every index was taken by a thread, and a thread that panicked has re-raised its
    // panic at the end of the scope, so every slot holds its result.
    slots.into_iter().map(|r| r.expect("every item ran")).collect()
}

/// Folds `f` of each of `items` into `acc` on up to `threads` threads (the next free thread
/// takes the next item), `merge(acc, index, result)` under a lock as each finishes. The
/// order of the merges depends on timing, so `merge` must give the same `acc` in any
/// order (keep the best by a key and the item's index, say); only `threads` results are
/// alive at once besides what `acc` keeps.
pub(crate) fn fold_in_parallel<T: Sync, R: Send, A: Send>(
    items: &[T],
    threads: usize,
    acc: A,
    f: impl Fn(&T) -> R + Sync,
    merge: impl Fn(&mut A, usize, R) + Sync,
) -> A {
    let threads = threads.min(items.len());
    let acc = Mutex::new(acc);
    if threads <= 1 {
        for (i, item) in items.iter().enumerate() {
            merge(&mut acc.lock().unwrap_or_else(|e| e.into_inner()), i, f(item));
        }
    } else {
        let next = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for _ in 0..threads {
                s.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(item) = items.get(i) else { break };
                    let r = f(item);
                    merge(&mut acc.lock().unwrap_or_else(|e| e.into_inner()), i, r);
                });
            }
        });
    }
    acc.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// The cores this process may use (1 where that is unknown).
pub(crate) fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
