//! Timing of one kernel on a batch, for `grid-gen bench`: the median over repetitions of
//! the dispatch alone (inputs already on the device, waiting for completion) and of the
//! whole round trip (upload, dispatch, read back), so both throughput and the latency a
//! host sees are reported; and, where the adapter has timestamp queries, the device's own
//! time for the compute pass, which a one-state latency is about; the round trip's phases;
//! and the floor under every dispatch, an empty submission and its wait.

use std::time::{Duration, Instant};

use crate::{Gpu, GpuError, Kernel, Maps, Phases};

#[derive(Clone, Copy, Debug)]
pub struct Timing {
    pub states: usize,
    /// Median time of one dispatch of the whole batch, submission to completion as the
    /// host sees it.
    pub dispatch: Duration,
    /// Median time the device spent in the compute pass by its own clock (timestamp
    /// queries), where the adapter has them.
    pub device: Option<Duration>,
    /// Median time of writing new states into the uploaded batch, dispatching and reading
    /// back, in one submission ([`Gpu::run_on`]): what an MPC loop pays per iteration.
    pub round_trip: Duration,
    /// Median time of the same with the batch's buffers and bind groups allocated anew on
    /// each call ([`Gpu::run`]).
    pub fresh_round_trip: Duration,
    /// Medians of the round trip's phases, each over the same repetitions.
    pub phases: Phases,
    pub repetitions: usize,
    /// Dispatches the batch takes.
    pub dispatches: usize,
}

/// Median of `f`'s time over repetitions: at least `min_reps`, and until `budget` is
/// spent (at most 1000).
fn median(
    min_reps: usize,
    budget: Duration,
    mut f: impl FnMut() -> Result<(), GpuError>,
) -> Result<(Duration, usize), GpuError> {
    let mut times = Vec::new();
    let start = Instant::now();
    while times.len() < min_reps || (start.elapsed() < budget && times.len() < 1000) {
        let t = Instant::now();
        f()?;
        times.push(t.elapsed());
    }
    times.sort();
    Ok((times[times.len() / 2], times.len()))
}

/// Times `kernel` on the state-major batch `q`, `qd`, `u` (see [`Gpu::upload`]), after
/// one warm-up run.
pub fn time(
    gpu: &Gpu,
    kernel: &Kernel,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
    budget: Duration,
) -> Result<Timing, GpuError> {
    let batch = gpu.upload(kernel, q, qd, u)?;
    // Warm-up for as long as one measurement: a GPU at its idle clock (an H200 idles at
    // 345 MHz) runs the first dispatches after a pause several times slower.
    median(1, budget, || gpu.dispatch(&batch))?;
    let (dispatch, repetitions) = median(5, budget, || gpu.dispatch(&batch))?;
    let mut device = Vec::new();
    for _ in 0..repetitions.min(100) {
        match gpu.dispatch_timed(&batch)? {
            Some(t) => device.push(t),
            None => break,
        }
    }
    device.sort();
    let device = device.get(device.len() / 2).copied();
    let mut out = vec![0.0; batch.len() * kernel.entry.outputs];
    let mut each = Vec::new();
    let (round_trip, _) = median(5, budget, || {
        each.push(gpu.run_on_timed(&batch, q, qd, u, &mut out)?);
        Ok(())
    })?;
    let mid = |f: fn(&Phases) -> Duration| {
        let mut t: Vec<Duration> = each.iter().map(f).collect();
        t.sort();
        t[t.len() / 2]
    };
    let phases = Phases {
        stage_in: mid(|p| p.stage_in),
        submit_wait: mid(|p| p.submit_wait),
        copy_out: mid(|p| p.copy_out),
        convert_out: mid(|p| p.convert_out),
    };
    let (fresh_round_trip, _) = median(5, budget, || gpu.run(kernel, q, qd, u).map(|_| ()))?;
    Ok(Timing {
        states: batch.len(),
        dispatch,
        device,
        round_trip,
        fresh_round_trip,
        phases,
        repetitions,
        dispatches: batch.dispatches(),
    })
}

/// The median time of an empty submission and the wait for it, after a warm-up: the
/// floor under every dispatch as the host sees it (the API's and the driver's submission,
/// the fence, the poll), whatever the kernel.
pub fn submission_floor(gpu: &Gpu, budget: Duration) -> Result<Duration, GpuError> {
    let mut submit = || {
        gpu.queue.submit([gpu.device.create_command_encoder(&Default::default()).finish()]);
        gpu.wait(&Maps::default())
    };
    median(1, budget, &mut submit)?;
    Ok(median(5, budget, submit)?.0)
}

/// Why `grid-gen bench` could not time the WGSL kernels.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Emit(#[from] grid_gen::back::wgsl::WgslError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("the time per measurement must be a positive number of seconds, got {0}")]
    Seconds(f64),
}

/// `grid-gen bench`: emits `module`'s WGSL with `options`, times every kernel under each
/// strategy on batches of `batch` states (seeded pseudo-random inputs, so every run times
/// the same work), spending about `seconds` per measurement, and returns the table.
pub fn table(
    gpu: &Gpu,
    module: &grid_gen::ir::Module,
    options: &grid_gen::back::wgsl::WgslOptions,
    batch: &[usize],
    seconds: f64,
) -> Result<String, BenchError> {
    use std::fmt::Write as _;
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(BenchError::Seconds(seconds));
    }
    let source = grid_gen::back::wgsl::emit(module, options)?.contents;
    let t = Instant::now();
    let shader = gpu.load(&source)?;
    let budget = Duration::from_secs_f64(seconds);
    let floor = submission_floor(gpu, budget)?;
    let mut report = format!(
        "adapter: {}; empty submission and wait {:.1} us\nrobot: {} ({} joints), {}, trig {}; \
         shader module {:.2?}\n",
        gpu.adapter(),
        floor.as_secs_f64() * 1e6,
        module.robot.name,
        module.robot.nv(),
        options.precision.name(),
        options.trig.name(),
        t.elapsed()
    );
    let _ = writeln!(
        report,
        "{:<12} {:<12} {:>7} {:>4} {:>14} {:>12} {:>14} {:>16} {:>14} {:>14} {:>9} {:>9} {:>9} {:>9}",
        "kernel",
        "strategy",
        "N",
        "disp",
        "us/batch",
        "us/state",
        "states/s",
        "round-trip us",
        "fresh rt us",
        "device us",
        "in us",
        "wait us",
        "copy us",
        "f64 us"
    );
    // q has nq entries per state (a floating base's or spherical joint's quaternion, which
    // the kernels scale by 1/|q|²), velocities and torques nv.
    let (nq, nv) = (module.robot.nq(), module.robot.nv());
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    let mut uniform = move |lo: f64, hi: f64| {
        // xorshift64 (Marsaglia 2003): the same inputs on every run and machine.
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        lo + (hi - lo) * ((rng >> 11) as f64 / (1u64 << 53) as f64)
    };
    let largest = batch.iter().copied().max().unwrap_or(0);
    let q: Vec<f64> = (0..largest * nq).map(|_| uniform(-3.1, 3.1)).collect();
    let qd: Vec<f64> = (0..largest * nv).map(|_| uniform(-3.0, 3.0)).collect();
    // `u` per kernel: nv torques or accelerations, the actuated joints' count for the step,
    // nv plus the forces where the robot declares them (`Kernel::nu` per state).
    let mut u: Vec<f64> = Vec::new();
    for f in &module.functions {
        for &strategy in &options.strategies {
            let kernel = gpu.kernel(&shader, &strategy.entry(f.kind.name()))?;
            if u.len() < largest * kernel.nu {
                u.extend((u.len()..largest * kernel.nu).map(|_| uniform(-3.0, 3.0)));
            }
            let _ = writeln!(
                report,
                "{} {}: pipeline built in {:.2?}",
                kernel.entry.entry,
                strategy.name(),
                kernel.build_time
            );
            for &n in batch {
                let m = n * nv;
                let t = time(gpu, &kernel, &q[..n * nq], &qd[..m], &u[..n * kernel.nu], budget)?;
                let us = t.dispatch.as_secs_f64() * 1e6;
                let device =
                    t.device.map_or("-".to_string(), |d| format!("{:.1}", d.as_secs_f64() * 1e6));
                let _ = writeln!(
                    report,
                    "{:<12} {:<12} {:>7} {:>4} {:>14.1} {:>12.4} {:>14.3e} {:>16.1} {:>14.1} {:>14} \
                     {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
                    f.kind.name(),
                    strategy.name(),
                    n,
                    t.dispatches,
                    us,
                    us / n.max(1) as f64,
                    n as f64 / t.dispatch.as_secs_f64(),
                    t.round_trip.as_secs_f64() * 1e6,
                    t.fresh_round_trip.as_secs_f64() * 1e6,
                    device,
                    t.phases.stage_in.as_secs_f64() * 1e6,
                    t.phases.submit_wait.as_secs_f64() * 1e6,
                    t.phases.copy_out.as_secs_f64() * 1e6,
                    t.phases.convert_out.as_secs_f64() * 1e6,
                );
            }
        }
    }
    Ok(report)
}
