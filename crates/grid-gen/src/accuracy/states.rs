//! Seeded random states for `accuracy --random N --seed S`, inside the bounds the
//! fixed-point analysis assumes, so every format is measured where it claims to work.

use crate::datapath::Bounds;
use crate::eval::{State, StatesFile};
use crate::ir::Robot;
use crate::model::Model;
use crate::reference;

pub use crate::datapath::Rng;

/// `n` states: a floating base's pose uniform ([`Rng::base_pose`]), q uniform within each joint's
/// limits (±π where a joint has none, or limits wider than 100, as Atlas's ±1e5), q̇ and q̈ uniform
/// within the fixed-point analysis's default bounds (the URDF's velocity limits, else its
/// defaults), and τ = RNEA(q, q̇, q̈′) for another such q̈′, so that forward dynamics answers a
/// plausible acceleration. `qd_max` / `qdd_max` override the bounds as in the Verilog backend.
pub fn random_states(
    model: &Model,
    gravity: [f64; 3],
    n: usize,
    seed: u64,
    qd_max: Option<f64>,
    qdd_max: Option<f64>,
) -> StatesFile {
    let bounds = Bounds::new(&Robot::of(model), qd_max, qdd_max);
    let mut rng = Rng(seed);
    let nv = model.nv();
    let states = (0..n)
        .map(|_| {
            let per_joint: Vec<f64> = model
                .coordinate_joints()
                .into_iter()
                .map(|i| model.joint(i))
                .map(|j| {
                    let (lo, hi) = j
                        .limit
                        .filter(|(lo, hi)| lo < hi && hi - lo <= 100.0)
                        .unwrap_or((-std::f64::consts::PI, std::f64::consts::PI));
                    rng.uniform(lo, hi)
                })
                .collect();
            // With a floating base, a random pose too (drawn only then: fixed-base states
            // stay what they were for a seed).
            let base = if model.floating { rng.base_pose() } else { [0.0; 7] };
            let mut q = model.q_from_joints(&per_joint, base);
            // Each spherical joint: a uniform rotation (drawn only for robots that have one).
            for &first in &model.spherical {
                let at = model.group_q(first).0;
                q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
            }
            let qd: Vec<f64> = bounds.qd.iter().map(|&b| rng.uniform(-b, b)).collect();
            let qdd: Vec<f64> = bounds.qdd.iter().map(|&b| rng.uniform(-b, b)).collect();
            let other: Vec<f64> = bounds.qdd.iter().map(|&b| rng.uniform(-b, b)).collect();
            let tau = (model.singular.is_none() && nv > 0)
                .then(|| reference::rnea(model, &q, &qd, &other, gravity));
            State {
                q,
                qd,
                qdd: Some(qdd),
                tau,
                v: None,
                q1: None,
                fext: Default::default(),
                contacts: Default::default(),
                // The accuracy study leaves the step kernels out.
                dt: None,
                active: Default::default(),
                baumgarte: Default::default(),
            }
        })
        .collect();
    StatesFile { states }
}
