//! How a batch scales with cores: iiwa's `fd_grad` through its C ABI batch entry point
//! (`iiwa14_fd_grad_batch_f64`, what C, C++ and Python call), on one thread against every
//! core, at B = 64 and 1024 states, called back to back and called with a pause between
//! calls (a solver's own work between knot-point batches, during which the pool's workers go
//! to sleep and must be woken).
//!
//! `cargo bench -p iiwa-c --bench scaling` prints the table; run as a test (`cargo test`,
//! no `--bench`) it checks once that every thread count gives bit-identical outputs.
//! Protocol: the two thread counts alternate round by round in one process, each round
//! long enough for 20 ms of calls; medians over 15 rounds. Ratios only: absolute times on
//! a shared machine are noise.

use std::time::{Duration, Instant};

use grid_gen_test_support::Rng;
use grid_iiwa::iiwa14::{NQ, NV};
use grid_iiwa::iiwa14_batch::{iiwa14_fd_grad_batch_f64, iiwa14_set_threads, GRID_GEN_OK};

struct Batch {
    n: usize,
    q: Vec<f64>,
    qd: Vec<f64>,
    tau: Vec<f64>,
    out: [Vec<f64>; 3],
}

impl Batch {
    fn new(n: usize) -> Self {
        // The library's seeded generator, as the C ABI tests draw iiwa's states.
        let mut rng = Rng(7);
        let mut draw = |len: usize, scale: f64| -> Vec<f64> {
            (0..len).map(|_| rng.uniform(-scale, scale)).collect()
        };
        let (q, qd, tau) = (draw(n * NQ, 2.0), draw(n * NV, 1.5), draw(n * NV, 20.0));
        Batch {
            n,
            q,
            qd,
            tau,
            out: [vec![0.0; n * NV], vec![0.0; n * NV * NV], vec![0.0; n * NV * NV]],
        }
    }

    fn run(&mut self) {
        let [qdd, dq, dqd] = &mut self.out;
        // SAFETY: every array holds `n` states, and the outputs are distinct vectors.
        let status = unsafe {
            iiwa14_fd_grad_batch_f64(
                self.n,
                self.q.as_ptr(),
                self.qd.as_ptr(),
                self.tau.as_ptr(),
                qdd.as_mut_ptr(),
                dq.as_mut_ptr(),
                dqd.as_mut_ptr(),
            )
        };
        assert_eq!(status, GRID_GEN_OK);
    }
}

/// Busy-waits `d`: the caller's own work between batches (a sleep would hand the core to
/// the pool's workers, which a solver busy with its own work does not).
fn spin(d: Duration) {
    let t = Instant::now();
    while t.elapsed() < d {
        std::hint::spin_loop();
    }
}

/// Seconds per batch call on `threads` threads, over one round of `calls` calls, each
/// followed by `pause` (not counted).
fn round(b: &mut Batch, threads: usize, calls: usize, pause: Duration) -> f64 {
    iiwa14_set_threads(threads);
    b.run();
    let mut total = Duration::ZERO;
    for _ in 0..calls {
        spin(pause);
        let t = Instant::now();
        b.run();
        total += t.elapsed();
    }
    total.as_secs_f64() / calls as f64
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let benching = std::env::args().any(|a| a == "--bench");
    if !benching {
        // As a test: one thread and every core give the same bits.
        let mut b = Batch::new(64);
        iiwa14_set_threads(1);
        b.run();
        let one = b.out.clone();
        iiwa14_set_threads(0);
        b.run();
        assert!(one == b.out, "a batch on every core differs from one thread");
        return;
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("iiwa fd_grad through iiwa14_fd_grad_batch_f64, {cores} cores, median of 15 rounds\n");
    println!("| B | calls | 1 thread, per state | {cores} threads, per state | speed-up |");
    println!("|---|---|---|---|---|");
    for n in [64, 1024] {
        for (label, pause) in
            [("back to back", Duration::ZERO), ("200 µs apart", Duration::from_micros(200))]
        {
            let mut b = Batch::new(n);
            let once = round(&mut b, 1, 3, Duration::ZERO);
            let calls = ((0.02 / once) as usize).clamp(3, 100_000);
            let (mut one, mut all) = (Vec::new(), Vec::new());
            for _ in 0..15 {
                one.push(round(&mut b, 1, calls, pause));
                all.push(round(&mut b, 0, calls, pause));
            }
            let (one, all) = (median(one), median(all));
            println!(
                "| {n} | {label} | {:.0} ns | {:.0} ns | {:.2}x |",
                one / n as f64 * 1e9,
                all / n as f64 * 1e9,
                one / all
            );
        }
    }
}
