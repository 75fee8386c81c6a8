//! Timing of one kernel on a batch, for `grid-gen bench`: the median over repetitions of
//! the dispatch alone (inputs already on the device, waiting for completion) and of the
//! whole round trip (upload, dispatch, read back), so both throughput and the latency a
//! host sees are reported; and, where the adapter has timestamp queries, the device's own
//! time for the compute pass, which a one-state latency is about.

use std::time::{Duration, Instant};

use crate::{Gpu, GpuError, Kernel};

#[derive(Clone, Copy, Debug)]
pub struct Timing {
    pub states: usize,
    /// Median time of one dispatch of the whole batch, submission to completion as the
    /// host sees it.
    pub dispatch: Duration,
    /// Median time the device spent in the compute pass by its own clock (timestamp
    /// queries), where the adapter has them.
    pub device: Option<Duration>,
    /// Median time of upload + dispatch + read back.
    pub round_trip: Duration,
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
    gpu.dispatch(&batch)?;
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
    let (round_trip, _) = median(5, budget, || gpu.run(kernel, q, qd, u).map(|_| ()))?;
    Ok(Timing {
        states: batch.len(),
        dispatch,
        device,
        round_trip,
        repetitions,
        dispatches: batch.dispatches(),
    })
}
