//! Seeded configurations for the datapath's input contracts: a generator that gives the
//! same numbers on every machine, and the bound on M⁻¹'s diagonal that `fd_grad`'s host
//! partition assumes of its M⁻¹ input.

use crate::ir::{Function, Robot};

/// A small deterministic generator (SplitMix64, Steele, Lea & Flood 2014), so that a seed
/// gives the same states on every machine without an RNG crate.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    pub fn vec(&mut self, n: usize, lo: f64, hi: f64) -> Vec<f64> {
        (0..n).map(|_| self.uniform(lo, hi)).collect()
    }

    /// A uniformly distributed unit quaternion `[x, y, z, w]` (Shoemake, "Uniform random
    /// rotations", Graphics Gems III, 1992).
    pub fn unit_quaternion(&mut self) -> [f64; 4] {
        let (u1, u2, u3) = (self.uniform(0.0, 1.0), self.uniform(0.0, 1.0), self.uniform(0.0, 1.0));
        let tau = std::f64::consts::TAU;
        let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
        [a * (tau * u2).sin(), a * (tau * u2).cos(), b * (tau * u3).sin(), b * (tau * u3).cos()]
    }

    /// A floating base's pose: position uniform in [-1, 1) m per axis, a uniform rotation.
    pub fn base_pose(&mut self) -> [f64; 7] {
        let [x, y, z] = [self.uniform(-1.0, 1.0), self.uniform(-1.0, 1.0), self.uniform(-1.0, 1.0)];
        let [qx, qy, qz, qw] = self.unit_quaternion();
        [x, y, z, qx, qy, qz, qw]
    }

    /// A configuration: each coordinate uniform within its joint's limits (±π where it
    /// has none, or limits wider than 100, as Atlas's ±1e5), a floating base's pose and
    /// each spherical joint's quaternion uniform.
    pub fn configuration(&mut self, robot: &Robot) -> Vec<f64> {
        let mut q = vec![0.0; robot.nq()];
        for (k, c) in robot.q_coordinates.iter().enumerate() {
            if let Some(c) = *c {
                let (lo, hi) = robot.limits[c]
                    .filter(|(lo, hi)| lo < hi && hi - lo <= 100.0)
                    .unwrap_or((-std::f64::consts::PI, std::f64::consts::PI));
                q[k] = self.uniform(lo, hi);
            }
        }
        if robot.floating {
            q[..7].copy_from_slice(&self.base_pose());
        }
        for s in &robot.spherical {
            q[s.q_start..s.q_start + 4].copy_from_slice(&self.unit_quaternion());
        }
        q
    }
}

/// Configurations [`minv_diagonal`] samples, and the margin it leaves above the largest
/// value it saw: M⁻¹ is smooth in q, so a few hundred configurations find its diagonal's
/// largest values to within a few percent on the bundled robots, and the margin covers
/// the rest.
pub const MINV_SAMPLES: usize = 256;
pub const MINV_MARGIN: f64 = 2.0;

/// Each joint's bound on M⁻¹'s diagonal entry: [`MINV_MARGIN`] times its largest value
/// over [`MINV_SAMPLES`] seeded configurations, from `minv` (the IR's `minv` kernel,
/// whose input is q). An estimate, not a proof: the host, which computes M⁻¹, checks its
/// diagonal against it. The off-diagonal entries follow rigorously,
/// |M⁻¹ᵢₖ| ≤ √(M⁻¹ᵢᵢ M⁻¹ₖₖ), because M⁻¹ is positive definite.
pub fn minv_diagonal(minv: &Function, robot: &Robot) -> Vec<f64> {
    let nv = robot.nv();
    let mut rng = Rng(0x6d69_6e76);
    let mut most = vec![0.0f64; nv];
    for _ in 0..MINV_SAMPLES {
        let q = rng.configuration(robot);
        let out = minv.eval(&[&q]);
        for (j, m) in most.iter_mut().enumerate() {
            *m = m.max(out[0][j * nv + j].abs());
        }
    }
    most.into_iter().map(|m| MINV_MARGIN * m).collect()
}

/// The bound of every entry of M⁻¹, row-major, from its diagonal's (Cauchy–Schwarz).
pub fn minv_entries(diagonal: &[f64]) -> Vec<f64> {
    diagonal.iter().flat_map(|a| diagonal.iter().map(move |b| (a * b).sqrt())).collect()
}
