//! What an iLQR or DDP iteration asks of the dynamics, on a floating HyQ: roll out 64 knots
//! with `step` (semi-implicit Euler, 10 ms), linearise every knot with `step_grad`, and run
//! the backward pass's value-gradient recursion `p_k = A_kᵀ p_(k+1) + l_x` over them.
//! The kernels are the checked-in `generated/scenes/grid_hyq.hyq_step_floating/`.
//! HyQ has no contacts yet (the model has none), so it falls while its legs hold a PD pose.
//!
//! Run it with `cargo run --release -p grid-gen-kernels --example hyq_rollout`.

use std::time::Instant;

use grid_gen_kernels::scenes::grid_hyq_step_floating as hyq;
use hyq::{NQ, NU, NV, NX};

const KNOTS: usize = 64;

/// A PD law about a crouched pose: the twelve leg torques (the actuated joints, in
/// `hyq::ACTUATED` order, which follows q's joint entries after the base).
fn control(q: &[f64; NQ], qd: &[f64; NV]) -> [f64; NU] {
    // Hip abduction 0, hip flexion ±0.6, knee ∓1.2 rad (front legs bend one way, hind the other).
    let pose = [0.0, 0.6, -1.2, 0.0, 0.6, -1.2, 0.0, -0.6, 1.2, 0.0, -0.6, 1.2];
    std::array::from_fn(|j| -20.0 * (q[7 + j] - pose[j]) - 0.5 * qd[6 + j])
}

fn main() {
    assert_eq!(hyq::STEP_SCHEME, "semi_implicit_euler");
    let mut q = [0.0; NQ];
    q[2] = 0.6; // the base 0.6 m up, level: quaternion [0, 0, 0, 1]
    q[6] = 1.0;
    let mut qd = [0.0; NV];
    let mut states = Vec::with_capacity(KNOTS + 1);
    let mut controls = Vec::with_capacity(KNOTS);
    let start = Instant::now();
    for _ in 0..KNOTS {
        let u = control(&q, &qd);
        states.push((q, qd));
        controls.push(u);
        (q, qd) = hyq::step(&q, &qd, &u);
    }
    let rollout = start.elapsed();
    states.push((q, qd));

    // A and B into buffers a solver keeps from one iteration to the next.
    type Linear = ([[f64; NX]; NX], [[f64; NU]; NX]);
    let mut linear: Vec<Linear> = vec![([[0.0; NX]; NX], [[0.0; NU]; NX]); KNOTS];
    let linearise_all = |linear: &mut Vec<Linear>| {
        for (k, out) in linear.iter_mut().enumerate() {
            let (x, u) = (&states[k], &controls[k]);
            let (_, _, a, b) = hyq::step_grad(&x.0, &x.1, u);
            *out = (a, b);
        }
    };
    // The first pass pays for loading the kernel's code and touching the buffers; an iLQR
    // iteration is a later pass.
    let first = Instant::now();
    linearise_all(&mut linear);
    let cold = first.elapsed();
    let start = Instant::now();
    linearise_all(&mut linear);
    let linearise = start.elapsed();

    // The backward pass's gradient recursion for the cost Σ |qd_k|² / 2 (l_x = [0; qd_k]),
    // and the control gradients B_kᵀ p_(k+1) a solver would step along.
    let start = Instant::now();
    let last = states[KNOTS].1;
    let mut p: [f64; NX] = std::array::from_fn(|i| if i < NV { 0.0 } else { last[i - NV] });
    let mut gradient_norm = 0.0f64;
    for k in (0..KNOTS).rev() {
        let (a, b) = &linear[k];
        let g_u: [f64; NU] = std::array::from_fn(|c| (0..NX).map(|r| b[r][c] * p[r]).sum());
        gradient_norm = gradient_norm.max(g_u.iter().map(|x| x * x).sum::<f64>().sqrt());
        let qd_k = states[k].1;
        p = std::array::from_fn(|c| {
            (0..NX).map(|r| a[r][c] * p[r]).sum::<f64>() + if c < NV { 0.0 } else { qd_k[c - NV] }
        });
    }
    let backward = start.elapsed();

    let (q, _) = states[KNOTS];
    println!(
        "{KNOTS} knots of {} s: base height {:.4} m -> {:.4} m",
        hyq::DT,
        states[0].0[2],
        q[2]
    );
    println!(
        "largest |B_k^T p_(k+1)| = {gradient_norm:.6e}; |p_0| = {:.6e}",
        p.iter().map(|x| x * x).sum::<f64>().sqrt()
    );
    let per = |t: std::time::Duration| t.as_secs_f64() * 1e9 / KNOTS as f64;
    println!(
        "per knot: step {:.0} ns (first pass), step_grad {:.0} ns ({:.0} ns on the first pass), backward recursion {:.0} ns (one thread; use --release)",
        per(rollout),
        per(linearise),
        per(cold),
        per(backward)
    );
    assert!(q.iter().chain(&p).all(|x| x.is_finite()), "a finite rollout");
}
