//! The one piece of run-time code that generated batch entry points share: running a
//! kernel over `n` states on a rayon pool of a chosen size. The generated `<robot>_c.rs`
//! files call [`for_each`]; a C or Python user sets the size with [`set_threads`].
//!
//! This file is also embedded in the Python package, which builds each robot's library
//! itself, so it depends on nothing but rayon and std.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
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

thread_local! {
    /// The state that made this thread's last call return `GRID_GEN_BAD_VALUE`, -1 before
    /// any. Here rather than in each `<robot>_c.rs`, so that a library built from several
    /// crates (`grid_gen.load` splits a large robot's kernels over a crate per core) has one.
    static BAD_STATE: std::cell::Cell<i64> = const { std::cell::Cell::new(-1) };
}

/// Records the state that made this thread's call return `GRID_GEN_BAD_VALUE`.
pub fn set_bad_state(state: i64) {
    BAD_STATE.with(|b| b.set(state));
}

/// The state (from 0) that made this thread's last call return `GRID_GEN_BAD_VALUE`; -1
/// before any.
pub fn bad_state() -> i64 {
    BAD_STATE.with(|b| b.get())
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

/// How long a helper stays awake after its last block, in microseconds, waiting for the
/// next batch; `u64::MAX` until first read (then `GRID_GEN_BATCH_SPIN_US`, or 1000).
static SPIN_US: AtomicU64 = AtomicU64::new(u64::MAX);

/// Sets how long, in microseconds, the pool's helpers keep spinning after a batch for the
/// next one (default 1000, or `GRID_GEN_BATCH_SPIN_US`): a solver that calls batches with
/// its own serial work between them finds them awake instead of waking them through the
/// OS (tens of microseconds on a virtual machine). The price is a core kept busy that long
/// after the last batch; 0 lets them sleep at once, as an OpenMP runtime's
/// `OMP_WAIT_POLICY=passive` does.
pub fn set_spin_us(us: u64) {
    SPIN_US.store(us.min(u64::MAX - 1), Ordering::Relaxed);
}

fn spin_time() -> std::time::Duration {
    let mut us = SPIN_US.load(Ordering::Relaxed);
    if us == u64::MAX {
        us = std::env::var("GRID_GEN_BATCH_SPIN_US")
            .ok()
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(1000)
            .min(u64::MAX - 1);
        SPIN_US.store(us, Ordering::Relaxed);
    }
    std::time::Duration::from_micros(us)
}

/// Calls `f` on disjoint ranges that cover `0..n`, in parallel on [`threads`] threads;
/// with one thread, or one state, on the calling thread. Every state is visited exactly
/// once; a panic in `f` reaches the caller after every thread has left `f`.
///
/// The calling thread works too: it publishes the batch, asks the pool for as many helpers
/// as are missing (`threads - 1`, less those still awake from the last batch), and claims
/// blocks of states (guided: large first, one group last) from a shared counter like
/// them, so a batch never waits for a sleeping worker to wake before it starts. When the blocks run out, it waits (spinning: a block
/// takes microseconds) only for the helpers that are inside `f`; a helper that arrives
/// later finds the batch closed and leaves without touching it. Waiting on rayon's own
/// scope instead would put the caller to sleep and wake it through the OS at the end of
/// every batch, tens of microseconds on a virtual machine, a third of a 64-state batch of
/// iiwa. A helper then stays awake for [`set_spin_us`] to join the next batch.
pub fn for_each(n: usize, f: impl Fn(Range<usize>) + Sync + Send) {
    for_each_lanes(n, 1, f)
}

/// [`for_each`] with every range but the last a multiple of `lanes` states long, so that
/// a kernel that evaluates `lanes` states per call (the generated `F64x4` and `F32x8`
/// paths) leaves at most one partial group per batch, not one per range.
pub fn for_each_lanes(n: usize, lanes: usize, f: impl Fn(Range<usize>) + Sync + Send) {
    let threads = threads();
    if threads <= 1 || n <= 1 {
        f(0..n);
        return;
    }
    let lanes = lanes.max(1);
    let next = AtomicUsize::new(0);
    // Guided self-scheduling (OpenMP's `schedule(guided)`): each claim takes half a
    // thread's share of what is left, in whole groups of `lanes`, so the first blocks are
    // large (few claims: each is an atomic on a line both cores write, about 0.1 µs) and the
    // last ones one group long (the threads finish within a group of each other). A
    // 64-state batch on two threads is 8 claims instead of 16 equal blocks of 4.
    let work = || {
        let mut start = next.load(Ordering::Relaxed);
        loop {
            if start >= n {
                return;
            }
            let size = ((n - start) / (2 * threads)).next_multiple_of(lanes).max(lanes);
            match next.compare_exchange_weak(
                start,
                start + size,
                Ordering::Relaxed,
                Ordering::Relaxed,
            ) {
                Ok(_) => {
                    f(start..(start + size).min(n));
                    start = next.load(Ordering::Relaxed);
                }
                Err(now) => start = now,
            }
        }
    };
    let helpers = threads.min(n.div_ceil(lanes)) - 1;
    let erased: &(dyn Fn() + Sync) = &work;
    // SAFETY: helpers call through this pointer only between entering and leaving the
    // batch (`Shared::run`), and this function returns only after closing it with no
    // helper inside, so `work` (and the `f` and counter it borrows) outlives every call.
    let erased: &'static (dyn Fn() + Sync) = unsafe { std::mem::transmute(erased) };
    let batch = Arc::new(Shared {
        state: AtomicUsize::new(0),
        panic: Mutex::new(None),
        work: Erased(erased),
        generation: PUBLISHED.next.fetch_add(1, Ordering::Relaxed) + 1,
    });
    PUBLISHED.publish(&batch);
    let awake = AWAKE.load(Ordering::Acquire);
    let pool = match THREADS.load(Ordering::Relaxed) {
        0 => None,
        t => pool(t),
    };
    for _ in awake.min(helpers)..helpers {
        let batch = batch.clone();
        match &pool {
            Some(p) => p.spawn(move || help(batch)),
            None => rayon::spawn(move || help(batch)),
        }
    }
    let mine = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
    batch.close_and_wait();
    PUBLISHED.clear(&batch);
    if let Err(p) = mine {
        std::panic::resume_unwind(p);
    }
    let theirs = batch.panic.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some(p) = theirs {
        std::panic::resume_unwind(p);
    }
}

/// A helper on the pool: runs `first` (unless it is already closed, then it leaves at
/// once), then stays awake for [`spin_time`] and joins each newer batch published meanwhile.
fn help(first: Arc<Shared>) {
    if !first.run() {
        return;
    }
    let mut last = first;
    loop {
        AWAKE.fetch_add(1, Ordering::AcqRel);
        let next = PUBLISHED.newer_than(last.generation, spin_time());
        AWAKE.fetch_sub(1, Ordering::AcqRel);
        match next {
            Some(batch) => {
                batch.run();
                last = batch;
            }
            None => return,
        }
    }
}

/// Helpers spinning between batches, which a new batch need not ask the pool for.
static AWAKE: AtomicUsize = AtomicUsize::new(0);

/// The batch running now, for helpers that are awake to find.
static PUBLISHED: Published =
    Published { next: AtomicU64::new(0), generation: AtomicU64::new(0), batch: Mutex::new(None) };

struct Published {
    /// The last generation handed to a batch.
    next: AtomicU64,
    /// The generation of the batch last published, stored after the batch is in `batch`,
    /// so that a helper who sees it change finds the batch there (or already gone).
    generation: AtomicU64,
    batch: Mutex<Option<Arc<Shared>>>,
}

impl Published {
    fn publish(&self, batch: &Arc<Shared>) {
        *self.batch.lock().unwrap_or_else(|e| e.into_inner()) = Some(batch.clone());
        self.generation.store(batch.generation, Ordering::Release);
    }

    /// Takes `batch` down if it is still the one published.
    fn clear(&self, batch: &Arc<Shared>) {
        let mut slot = self.batch.lock().unwrap_or_else(|e| e.into_inner());
        if slot.as_ref().is_some_and(|b| Arc::ptr_eq(b, batch)) {
            *slot = None;
        }
    }

    /// Spins up to `wait` for a batch newer than generation `last` to be published.
    fn newer_than(&self, last: u64, wait: std::time::Duration) -> Option<Arc<Shared>> {
        let start = std::time::Instant::now();
        let mut seen = last;
        let mut spins = 0u32;
        loop {
            let now = self.generation.load(Ordering::Acquire);
            if now != seen {
                seen = now;
                let slot = self.batch.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(b) = slot.as_ref().filter(|b| b.generation > last) {
                    return Some(b.clone());
                }
            }
            spins = spins.wrapping_add(1);
            if spins & 63 == 0 && start.elapsed() >= wait {
                return None;
            }
            std::hint::spin_loop();
        }
    }
}

/// A batch's work as its helpers see it, lifetime erased (see [`for_each`]'s SAFETY).
#[derive(Clone, Copy)]
struct Erased(&'static (dyn Fn() + Sync));

// SAFETY: the closure behind it is `Sync`, so calling it from another thread is sound.
unsafe impl Send for Erased {}
unsafe impl Sync for Erased {}

/// One batch, as its caller and helpers share it.
struct Shared {
    /// [`CLOSED`] once the caller has finished its blocks; below it, the helpers inside.
    state: AtomicUsize,
    /// The first panic a helper caught, for the caller to resume.
    panic: Mutex<Option<Box<dyn std::any::Any + Send>>>,
    /// Claims and runs blocks until none is left; valid only while the batch is open.
    work: Erased,
    /// Its place in the order batches were published.
    generation: u64,
}

const CLOSED: usize = 1 << (usize::BITS - 1);

impl Shared {
    /// Runs the batch's blocks as a helper, unless it is closed; whether it was open.
    fn run(&self) -> bool {
        if !self.enter() {
            return false;
        }
        let work = self.work.0;
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
        if let Err(p) = r {
            *self.panic.lock().unwrap_or_else(|e| e.into_inner()) = Some(p);
        }
        self.state.fetch_sub(1, Ordering::Release);
        true
    }

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

    /// With lanes, every range starts at a multiple of `lanes` and only a range that ends
    /// the batch is shorter than a whole number of groups; every state is still visited once.
    #[test]
    fn ranges_come_in_whole_groups_of_lanes() {
        let _one_at_a_time = serial();
        for threads in [1, 2, 3] {
            set_threads(threads);
            for lanes in [1, 4, 8] {
                for n in [0, 1, 3, 4, 9, 37, 64, 203, 1024] {
                    let seen: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
                    let ranges = Mutex::new(Vec::new());
                    for_each_lanes(n, lanes, |r| {
                        ranges.lock().unwrap().push(r.clone());
                        for i in r {
                            seen[i].fetch_add(1, Ordering::Relaxed);
                        }
                    });
                    let what = format!("threads {threads}, lanes {lanes}, n {n}");
                    assert!(seen.iter().all(|s| s.load(Ordering::Relaxed) == 1), "{what}");
                    for r in ranges.into_inner().unwrap() {
                        assert!(r.start % lanes == 0, "{what}: {r:?}");
                        assert!(r.end == n || r.len() % lanes == 0, "{what}: {r:?}");
                    }
                }
            }
        }
        set_threads(0);
    }

    #[test]
    fn outputs_written_from_blocks_land_in_place() {
        // One batch at a time, as the other tests: a batch published beside
        // `a_panic_on_a_helper_reaches_the_caller`'s took the helper that test counted on
        // (CI, 2026-11-30: its caller ran all 64 states and the panic never came).
        let _one_at_a_time = serial();
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
