//! The one piece of run-time code that generated batch entry points share: running a
//! kernel over `n` states on a rayon pool of a chosen size. The generated `<robot>_c.rs`
//! files call [`for_each`]; a C or Python user sets the size with [`set_threads`].
//!
//! This file is also embedded in the Python package, which builds each robot's library
//! itself, so it depends on nothing but rayon and std.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// Threads a batch runs on; 0 means every core (rayon's default).
static THREADS: AtomicUsize = AtomicUsize::new(0);

/// Sets how many threads later batches run on: 0 for every core (the default), 1 to run
/// on the calling thread alone.
pub fn set_threads(n: usize) {
    THREADS.store(n, Ordering::Relaxed);
}

/// The threads a batch runs on now: the count set by [`set_threads`], or every core.
pub fn threads() -> usize {
    match THREADS.load(Ordering::Relaxed) {
        0 => rayon::current_num_threads().max(1),
        n => n,
    }
}

/// One pool per thread count asked for, built once; rayon's global pool serves 0.
fn pool(n: usize) -> Option<Arc<rayon::ThreadPool>> {
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<rayon::ThreadPool>>>> = OnceLock::new();
    let mut pools = POOLS.get_or_init(Default::default).lock().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = pools.get(&n) {
        return Some(p.clone());
    }
    let p = Arc::new(rayon::ThreadPoolBuilder::new().num_threads(n).build().ok()?);
    pools.insert(n, p.clone());
    Some(p)
}

/// Calls `f` on disjoint ranges that cover `0..n`, in parallel on [`threads`] threads;
/// with one thread, or one state, on the calling thread. Each range is a block of states
/// (several per thread, so that a slow core does not hold the others up), and every
/// state is visited exactly once.
pub fn for_each(n: usize, f: impl Fn(Range<usize>) + Sync + Send) {
    let threads = threads();
    if threads <= 1 || n <= 1 {
        f(0..n);
        return;
    }
    // Four blocks per thread: enough to balance, few enough that each block's call
    // overhead is nothing next to its kernels.
    let block = n.div_ceil(4 * threads).max(1);
    let blocks = n.div_ceil(block);
    let run = || {
        use rayon::prelude::*;
        (0..blocks).into_par_iter().for_each(|b| f(b * block..((b + 1) * block).min(n)));
    };
    match THREADS.load(Ordering::Relaxed) {
        0 => run(),
        t => match pool(t) {
            Some(p) => p.install(run),
            None => run(),
        },
    }
}

/// A pointer to a batch's outputs that blocks on several threads write through, each
/// into its own states: [`for_each`]'s ranges are disjoint, so no two writes meet.
#[derive(Clone, Copy)]
pub struct Out<T>(pub *mut T);

// SAFETY: `Out` is only dereferenced at the indices of one `for_each` range, and the
// ranges are disjoint; `T` itself is sent, so it must be `Send`.
unsafe impl<T: Send> Send for Out<T> {}
unsafe impl<T: Send> Sync for Out<T> {}

impl<T> Out<T> {
    /// Writes state `i`'s value.
    ///
    /// # Safety
    /// `i` is in bounds of the slice the pointer came from, and no other thread writes
    /// state `i` at the same time.
    #[inline(always)]
    pub unsafe fn write(self, i: usize, value: T) {
        // SAFETY: the caller's contract.
        unsafe { self.0.add(i).write(value) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU32;

    #[test]
    fn every_state_is_visited_once_on_every_thread_count() {
        for threads in [0, 1, 2, 3] {
            set_threads(threads);
            for n in [0, 1, 2, 7, 64, 1000] {
                let seen: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
                for_each(n, |r| {
                    for i in r {
                        seen[i].fetch_add(1, Ordering::Relaxed);
                    }
                });
                assert!(
                    seen.iter().all(|s| s.load(Ordering::Relaxed) == 1),
                    "threads {threads}, n {n}"
                );
            }
        }
        set_threads(0);
    }

    #[test]
    fn outputs_written_from_blocks_land_in_place() {
        let mut out = vec![0usize; 777];
        let p = Out(out.as_mut_ptr());
        for_each(out.len(), |r| {
            for i in r {
                // SAFETY: i < 777 and the ranges are disjoint.
                unsafe { p.write(i, 3 * i) }
            }
        });
        assert!(out.iter().enumerate().all(|(i, &v)| v == 3 * i));
    }
}
