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
/// with one thread, or one state, on the calling thread. Every state is visited exactly
/// once; a panic in `f` reaches the caller after every thread has left `f`.
///
/// The calling thread works too: it asks the pool for `threads - 1` helpers and claims
/// blocks of states from a shared counter like them, so a batch never waits for a sleeping
/// worker to wake before it starts. When the blocks run out, it waits (spinning: a block
/// takes microseconds) only for the helpers that are inside `f`; a helper that wakes later
/// finds the batch closed and leaves without touching it. Waiting on rayon's own scope
/// instead would put the caller to sleep and wake it through the OS at the end of every
/// batch, tens of microseconds on a virtual machine, a third of a 64-state batch of iiwa.
pub fn for_each(n: usize, f: impl Fn(Range<usize>) + Sync + Send) {
    let threads = threads();
    if threads <= 1 || n <= 1 {
        f(0..n);
        return;
    }
    // Eight blocks per thread: small enough that the threads finish together, large
    // enough that claiming one (an atomic add) is nothing next to its kernels.
    let block = n.div_ceil(8 * threads).max(1);
    let next = AtomicUsize::new(0);
    let work = || loop {
        let start = next.fetch_add(block, Ordering::Relaxed);
        if start >= n {
            break;
        }
        f(start..(start + block).min(n));
    };
    let helpers = threads.min(n.div_ceil(block)) - 1;
    let pool = match THREADS.load(Ordering::Relaxed) {
        0 => None,
        t => pool(t),
    };
    let shared = Arc::new(Shared { state: AtomicUsize::new(0), panic: Mutex::new(None) });
    let erased: &(dyn Fn() + Sync) = &work;
    // SAFETY: helpers call through this pointer only between entering and leaving
    // `shared`, and this function returns only after closing it with no helper inside, so
    // `work` (and the `f` and counter it borrows) outlives every call.
    let erased: &'static (dyn Fn() + Sync) = unsafe { std::mem::transmute(erased) };
    for _ in 0..helpers {
        let (shared, work) = (shared.clone(), Erased(erased));
        let job = move || {
            if shared.enter() {
                // Taken whole, so the closure captures `Erased` (which is `Send`), not
                // its field.
                let work = work;
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (work.0)()));
                if let Err(p) = r {
                    *shared.panic.lock().unwrap_or_else(|e| e.into_inner()) = Some(p);
                }
                shared.state.fetch_sub(1, Ordering::Release);
            }
        };
        match &pool {
            Some(p) => p.spawn(job),
            None => rayon::spawn(job),
        }
    }
    let mine = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
    shared.close_and_wait();
    if let Err(p) = mine {
        std::panic::resume_unwind(p);
    }
    let theirs = shared.panic.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some(p) = theirs {
        std::panic::resume_unwind(p);
    }
}

/// A batch's work as its helpers see it, lifetime erased (see [`for_each`]'s SAFETY).
#[derive(Clone, Copy)]
struct Erased(&'static (dyn Fn() + Sync));

// SAFETY: the closure behind it is `Sync`, so calling it from another thread is sound.
unsafe impl Send for Erased {}

/// What a batch's caller and helpers share.
struct Shared {
    /// [`CLOSED`] once the caller has finished its blocks; below it, the helpers inside.
    state: AtomicUsize,
    /// The first panic a helper caught, for the caller to resume.
    panic: Mutex<Option<Box<dyn std::any::Any + Send>>>,
}

const CLOSED: usize = 1 << (usize::BITS - 1);

impl Shared {
    /// Counts a helper in, unless the batch is closed (then the helper must not run).
    fn enter(&self) -> bool {
        let mut s = self.state.load(Ordering::Acquire);
        loop {
            if s & CLOSED != 0 {
                return false;
            }
            match self.state.compare_exchange_weak(s, s + 1, Ordering::AcqRel, Ordering::Acquire) {
                Ok(_) => return true,
                Err(now) => s = now,
            }
        }
    }

    /// Closes the batch to helpers not yet in, then waits for those inside to leave (their
    /// `Release` on leaving makes their outputs visible here).
    fn close_and_wait(&self) {
        self.state.fetch_or(CLOSED, Ordering::AcqRel);
        let mut spins = 0u32;
        while self.state.load(Ordering::Acquire) != CLOSED {
            if spins < 10_000 {
                std::hint::spin_loop();
                spins += 1;
            } else {
                std::thread::yield_now();
            }
        }
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

    /// The thread count is global: tests that set it take turns.
    fn serial() -> std::sync::MutexGuard<'static, ()> {
        static SERIAL: Mutex<()> = Mutex::new(());
        SERIAL.lock().unwrap_or_else(|e| e.into_inner())
    }

    #[test]
    fn every_state_is_visited_once_on_every_thread_count() {
        let _one_at_a_time = serial();
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

    /// A panic in a helper's block reaches the caller, after the caller's own blocks.
    #[test]
    fn a_panic_on_a_helper_reaches_the_caller() {
        let _one_at_a_time = serial();
        let caller = std::thread::current().id();
        let helper_in = std::sync::atomic::AtomicBool::new(false);
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            set_threads(2);
            for_each(64, |_| {
                if std::thread::current().id() != caller {
                    helper_in.store(true, Ordering::Relaxed);
                    panic!("a helper's block");
                }
                // The caller holds its first block until a helper is in (or 10 s pass),
                // so that the blocks cannot all run here.
                let t = std::time::Instant::now();
                while !helper_in.load(Ordering::Relaxed) && t.elapsed().as_secs() < 10 {
                    std::thread::yield_now();
                }
            });
        }));
        set_threads(0);
        let message = r.expect_err("the helper's panic was lost");
        assert_eq!(message.downcast_ref::<&str>(), Some(&"a helper's block"));
    }
}
