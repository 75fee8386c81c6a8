//! The rounding-error bound of `fd_grad`'s chip partition through M's factorisation and
//! the solves, by backward error analysis (Higham, *Accuracy and Stability of Numerical
//! Algorithms*, 2nd ed., §10.1 for the factorisation, §8.1 for the triangular solves),
//! where forward propagation multiplies the error by about |M_ki M_kj| / D_k² per level.
//!
//! In fixed point every product rounds by at most ρ (absolute) and sums are exact. The
//! computed L̂ and D̂ are then the exact factors of M' = M̂ + Δ_f, with, for j = i or an
//! ancestor of i,
//! `Δ_f,ij = [i ≠ j] η_ij + Σ_{k below i} (L̂_ki η_kj − ρ_kij)`, where `η_kj = D̂_k L̂_kj −
//! M̃_kj` is what the rounded reciprocal and product leave (|η_kj| ≤ D̂_k (|M̃_kj| u + ρ),
//! u the ulp: the reciprocal rounds toward zero by less than one). With M̂ = M + δM from
//! the mass-matrix datapath's own analysis, ‖M' − M‖₂ ≤ ε, the Frobenius norm of the
//! entrywise bounds. Positive definiteness gives λ_min(M) ≥ λ = 1 / Σ_k M⁻¹_kk (the
//! model's bounds on M⁻¹'s diagonal), so θ = ε / λ ≤ ½ makes M' ≥ (1 − θ) M: M' is
//! positive definite, its pivots are at least (1 − θ) times the floors, its inverse's
//! diagonal at most 1 / (1 − θ) times M⁻¹'s bounds, and every value the factorisation
//! computes is one of M''s Schur complements, bounded as [`super::Clamp`] says for M with
//! M_ii + ε for M_ii. The argument runs by induction over the eliminations, each step's
//! values bounded by the previous steps' partial Δ, which the full bound covers; the
//! bounds below assume twice the exact ones, which θ ≤ ½ and ε ≤ min M_ii / 4 confirm.
//!
//! A solve of −M⁻¹ b̂ computes y (Lᵀ y = b̂ + r₁), z = −D̂⁻¹ y (D̂ z = −y + r₂) and x
//! (L x = z + r₃), so −M' x = b̂ + R with R = r₁ + P r₂ + P D̂ r₃ (P the unit factor), and
//! x − x* = −M'⁻¹ (b̂ − b + R + (M' − M) x*) for the exact x* = −M⁻¹ b. Each entry of
//! M'⁻¹ v is at most √(M'⁻¹_ii) Σ_j √(M'⁻¹_jj) |v_j| (positive definiteness), which gives
//! every solution entry's error.

use super::{Datapath, Format, HwId};

/// The factorisation's bounds, once M's entries are analysed.
pub(super) struct Backward {
    /// Whether the argument holds (θ ≤ ½, ε ≤ min M_ii / 4): else no bound.
    pub valid: bool,
    /// ‖M' − M‖₂ ≤ ε.
    eps: f64,
    /// ε / λ_min(M)'s lower bound.
    theta: f64,
    /// |(M' − M)_ij| ≤ delta[i · n + j].
    delta: Vec<f64>,
    /// max M_ii.
    diag: Vec<f64>,
    /// Bounds on M'⁻¹'s diagonal: M⁻¹'s over 1 − θ.
    minv: Vec<f64>,
    /// Each coordinate's strict descendants, and its number of ancestors.
    below: Vec<Vec<usize>>,
    depth: Vec<usize>,
    ulp: f64,
    rho: f64,
}

/// One solve's bounds on computed values: |ŷ_k| ≤ lower[k], |ẑ_k| ≤ scaled[k], and
/// |x̂_k − x*_k| ≤ error[k].
pub(super) struct SolveBounds {
    pub lower: Vec<f64>,
    pub scaled: Vec<f64>,
    pub error: Vec<f64>,
}

impl Backward {
    /// `maxabs` gives a node's exact range, `err` its error bound (M's entries').
    pub fn new(dp: &Datapath, format: &Format, maxabs: impl Fn(HwId) -> f64, err: &[f64]) -> Self {
        let f = &dp.factor;
        let n = f.diagonal.len();
        let (ulp, rho) = (format.ulp(), format.product_error());
        let diag: Vec<f64> = f.diagonal.iter().map(|&d| maxabs(d)).collect();
        let mut below = vec![Vec::new(); n];
        let mut depth = vec![0; n];
        for k in 0..n {
            let mut a = f.parents[k];
            while let Some(p) = a {
                below[p as usize].push(k);
                depth[k] += 1;
                a = f.parents[p as usize];
            }
        }
        // Under the assumed bounds (twice the exact ones): |η_kj| and |L̂_ki|.
        let eta =
            |k: usize, j: usize| 2.0 * diag[k] * (2.0 * (diag[k] * diag[j]).sqrt() * ulp + rho);
        let l = |k: usize, i: usize| 2.0 * (diag[i] / f.floor[k]).sqrt();
        let mut delta = vec![0.0; n * n];
        for &(i, j, id) in &f.entries {
            let (i, j) = (i as usize, j as usize);
            let own = if i == j { 0.0 } else { eta(i, j) };
            let updates: f64 = below[i].iter().map(|&k| l(k, i) * eta(k, j) + rho).sum();
            let b = err[id.0 as usize] + own + updates;
            delta[i * n + j] = b;
            delta[j * n + i] = b;
        }
        let eps = delta.iter().map(|d| d * d).sum::<f64>().sqrt();
        let theta = eps * f.minv.iter().sum::<f64>();
        let smallest = diag.iter().copied().fold(f64::INFINITY, f64::min);
        let valid = eps.is_finite() && theta <= 0.5 && eps <= smallest / 4.0;
        let minv = f.minv.iter().map(|m| m / (1.0 - theta.min(0.5))).collect();
        Backward { valid, eps, theta, delta, diag, minv, below, depth, ulp, rho }
    }

    /// A computed pivot (or partially eliminated diagonal entry) lies within `err` of the
    /// exact one's range [floor, max M_ii].
    pub fn pivot_excess(&self, floor: f64) -> f64 {
        self.theta * floor + 2.0 * self.eps
    }

    /// A computed Schur-complement entry or update product, against the exact bound
    /// √(M_aa M_bb).
    pub fn schur_excess(&self, ma: f64, mb: f64) -> f64 {
        ((ma + self.eps) * (mb + self.eps)).sqrt() + self.eps - (ma * mb).sqrt()
    }

    /// A computed multiplier, against √(M_ii / floor).
    pub fn multiplier_excess(&self, mi: f64, floor: f64) -> f64 {
        ((mi + self.eps) / (floor * (1.0 - self.theta))).sqrt() - (mi / floor).sqrt()
    }

    /// Solve `s`: its right-hand side's exact magnitudes and errors from `maxabs` and `err`.
    pub fn solve(
        &self,
        dp: &Datapath,
        s: usize,
        maxabs: impl Fn(HwId) -> f64,
        err: &[f64],
    ) -> SolveBounds {
        let f = &dp.factor;
        let n = self.diag.len();
        let (mut b, mut e) = (vec![0.0; n], vec![0.0; n]);
        for &(k, id) in &f.rhs[s] {
            b[k as usize] = maxabs(id);
            e[k as usize] = err[id.0 as usize];
        }
        let exact: f64 = (0..n).map(|k| f.minv[k].sqrt() * b[k]).sum();
        let beta = exact * exact;
        // r₁: one rounding per product subtracted from each entry.
        let r1: Vec<f64> = (0..n).map(|k| self.below[k].len() as f64 * self.rho).collect();
        let perturbed: f64 = (0..n).map(|k| self.minv[k].sqrt() * (b[k] + e[k] + r1[k])).sum();
        let beta_p = perturbed * perturbed;
        let pivot_max: Vec<f64> = self.diag.iter().map(|d| d + self.eps).collect();
        let lower: Vec<f64> = (0..n).map(|k| (beta_p * pivot_max[k]).sqrt()).collect();
        let scaled: Vec<f64> = (0..n)
            .map(|k| {
                (beta_p / (f.floor[k] * (1.0 - self.theta))).sqrt() + lower[k] * self.ulp + self.rho
            })
            .collect();
        let r2: Vec<f64> =
            (0..n).map(|k| pivot_max[k] * (lower[k] * self.ulp + self.rho)).collect();
        let r3: Vec<f64> = (0..n).map(|k| self.depth[k] as f64 * self.rho).collect();
        let x_exact: Vec<f64> = (0..n).map(|k| (f.minv[k] * beta).sqrt()).collect();
        let sum: f64 = (0..n)
            .map(|j| {
                let unit = |k: usize| {
                    if k == j {
                        1.0
                    } else {
                        (pivot_max[j] / (f.floor[k] * (1.0 - self.theta))).sqrt()
                    }
                };
                let residual = r1[j]
                    + std::iter::once(j)
                        .chain(self.below[j].iter().copied())
                        .map(|k| unit(k) * (r2[k] + pivot_max[k] * r3[k]))
                        .sum::<f64>();
                let perturbation: f64 =
                    (0..n).map(|l| self.delta[j * n + l] * x_exact[l]).sum::<f64>();
                self.minv[j].sqrt() * (e[j] + residual + perturbation)
            })
            .sum();
        let error = (0..n).map(|k| self.minv[k].sqrt() * sum).collect();
        SolveBounds { lower, scaled, error }
    }
}
