//! The measured error of a datapath the worst-case analysis cannot bound (`fd_grad`'s
//! chip partition, whose factorisation multiplies the analysed error bound by about
//! |M_ki M_kj| / D_k² per level): the software model against the same datapath in f64 on
//! seeded states, and the format chosen from it. The ranges stay proven; only the
//! fraction bits rest on the measurement.

use super::{analyse, port_values, quantize_ports, width_for, Analysis, Bounds, Datapath};
use super::{FixedError, Format, Rng, Rounding, MAX_WIDTH};
use crate::ir::{Function, Robot};

/// How many seeded states [`chip_states`] draws.
pub const MEASURED_STATES: usize = 128;
/// The most fraction bits the measured search tries (a measured format wider than 96
/// bits would be better served by the proven one).
const MEASURED_MAX_FRAC: u32 = 95;
/// How far below `--max-error` the measured error must be: two bits for states no sample
/// drew (the error grows where M is ill-conditioned, a region few states fall in). On the
/// tests' own states the worst error stayed below the sample's largest (at most 0.7 of it).
pub const MEASURED_MARGIN: f64 = 4.0;

/// What the measurement found for one format.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Measured {
    /// Largest |fixed − f64| over the outputs' entries and the states.
    pub error: f64,
    /// Largest |fixed − f64| over every node (what the width must leave room for).
    pub node_error: f64,
    pub states: usize,
}

/// One state of `fd_grad`'s chip partition: (q, q̇, τ).
pub type ChipState = (Vec<f64>, Vec<f64>, Vec<f64>);

/// Seeded states over the input box the ranges are proven for: every rotation at any
/// angle (every fourth state with all of them at one multiple of π/2, the aligned poses),
/// prismatic positions within their bounds, a floating base's pose and spherical joints'
/// rotations uniform; q̇ and q̈ within their bounds (uniform in every other state, at plus
/// or minus the bound in the rest: the errors are largest at the corners); and
/// τ = ID(q, q̇, q̈) from `rnea` (the IR's), zero where its bound is (a floating base's),
/// kept where |τ| is within its bound.
pub fn chip_states(
    rnea: &Function,
    robot: &Robot,
    bounds: &Bounds,
    count: usize,
) -> Vec<ChipState> {
    let mut rng = Rng(0x6368_6970);
    let mut out = Vec::new();
    let pi = std::f64::consts::PI;
    // A robot whose every state's τ leaves the bound stops after a fixed number of tries.
    for _ in 0..count * 16 {
        if out.len() == count {
            break;
        }
        let mut q = rng.configuration(robot);
        let aligned = (rng.uniform(-2.0, 2.0).floor() * pi / 2.0, out.len() % 4 == 3);
        for (k, c) in robot.q_coordinates.iter().enumerate() {
            if let Some(c) = *c {
                q[k] = match (robot.joint_types[c].is_rotation(), aligned) {
                    (true, (angle, true)) => angle,
                    (true, _) => rng.uniform(-pi, pi),
                    (false, _) => rng.uniform(bounds.q[k].0, bounds.q[k].1),
                };
            }
        }
        let corner = out.len() % 2 == 1;
        let mut draw = |b: f64| match (corner, rng.uniform(-1.0, 1.0)) {
            (true, s) => b.copysign(s),
            (false, s) => b * s,
        };
        let qd: Vec<f64> = bounds.qd.iter().map(|&b| draw(b)).collect();
        let qdd: Vec<f64> = bounds.qdd.iter().map(|&b| draw(b)).collect();
        let mut tau = rnea.eval(&[&q, &qd, &qdd]).swap_remove(0);
        // Where τ is not an input (a floating base), it is zero: q̈ is then FD's.
        for (t, b) in tau.iter_mut().zip(&bounds.tau) {
            if *b == 0.0 {
                *t = 0.0;
            }
        }
        if tau.iter().zip(&bounds.tau).all(|(t, b)| t.abs() <= *b) {
            out.push((q, qd, tau));
        }
    }
    out
}

/// The software model's largest errors against the f64 datapath on `states`.
pub fn measure(dp: &Datapath, format: &Format, states: &[ChipState]) -> Measured {
    let exact: Vec<Vec<f64>> = states.iter().map(|s| exact_values(dp, s)).collect();
    measure_against(dp, format, states, &exact)
}

/// Every node's value in f64 for one state (what the fixed-point one approximates).
fn exact_values(dp: &Datapath, (q, qd, tau): &ChipState) -> Vec<f64> {
    dp.values_f64(&port_values(dp, q, qd, &[], tau))
}

/// [`measure`] with each state's f64 values computed once (they do not depend on the format).
fn measure_against(
    dp: &Datapath,
    format: &Format,
    states: &[ChipState],
    exact: &[Vec<f64>],
) -> Measured {
    let (mut error, mut node_error) = (0.0f64, 0.0f64);
    let mut output = vec![false; dp.nodes.len()];
    for (_, _, id) in dp.nonzero_outputs() {
        output[id.0 as usize] = true;
    }
    for ((q, qd, tau), exact) in states.iter().zip(exact) {
        let (ports, _) = quantize_ports(dp, format, q, qd, &[], tau);
        let (fixed, _) = dp.run_nodes(format, &ports);
        for (i, (x, r)) in exact.iter().zip(&fixed).enumerate() {
            let e = (format.to_f64(*r) - x).abs();
            node_error = node_error.max(e);
            if output[i] {
                error = error.max(e);
            }
        }
    }
    Measured { error, node_error, states: states.len() }
}

/// A format for `dp` whose measured output error is at most `max_error` /
/// [`MEASURED_MARGIN`]: the fewest
/// fraction bits that meet it (searched by bisection: the error halves with each bit),
/// and the fewest integer bits that hold the proven range of every value plus twice its
/// measured error.
pub fn choose_format_measured(
    dp: &Datapath,
    bounds: &Bounds,
    rounding: Rounding,
    max_error: f64,
    states: &[ChipState],
) -> Result<(Format, Analysis, Measured), FixedError> {
    if !(max_error.is_finite() && max_error > 0.0) {
        return Err(FixedError::BadMaxError(max_error));
    }
    // Ranges do not depend on the fraction bits.
    let a = analyse(dp, bounds, 0, rounding);
    let needed = a.range();
    let exact: Vec<Vec<f64>> = states.iter().map(|s| exact_values(dp, s)).collect();
    let trial = |frac: u32| -> Option<(Format, Measured)> {
        let width = width_for(needed, frac)?;
        let f = Format { width, frac, rounding };
        let m = measure_against(dp, &f, states, &exact);
        let width = width_for(needed + 2.0 * m.node_error, frac)?;
        Some((Format { width, ..f }, m))
    };
    // The search's range is fixed (not MAX_WIDTH's): a bisection's path, and so the
    // format it lands on where the measured error is not monotone in FRAC, stays put.
    let (mut lo, mut hi) = (0u32, MEASURED_MAX_FRAC);
    let mut best = None;
    let mut found = None;
    while lo < hi {
        let mid = (lo + hi) / 2;
        match trial(mid) {
            Some((f, m)) if m.error * MEASURED_MARGIN <= max_error => {
                found = Some((f, m));
                hi = mid;
            }
            Some((f, m)) => {
                best = Some((m.error, f));
                lo = mid + 1;
            }
            None => hi = mid,
        }
    }
    match found {
        Some((f, m)) if f.frac == lo => Ok((f, analyse(dp, bounds, f.frac, rounding), m)),
        _ => match trial(lo) {
            Some((f, m)) if m.error * MEASURED_MARGIN <= max_error => {
                Ok((f, analyse(dp, bounds, f.frac, rounding), m))
            }
            _ => {
                let (best, f) =
                    best.unwrap_or((f64::INFINITY, Format { width: MAX_WIDTH, frac: 0, rounding }));
                Err(FixedError::Unreachable {
                    kernel: dp.kernel.to_string(),
                    max_error,
                    best,
                    width: f.width,
                    frac: f.frac,
                })
            }
        },
    }
}
