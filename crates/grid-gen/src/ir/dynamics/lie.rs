//! The configuration space's Lie-group kernels, recorded symbolically: `integrate`
//! (`q ⊕ v`), `difference` (`q1 ⊖ q`, the tangent `v` with `q ⊕ v = q1`) and their
//! Jacobians in the tangent space, as Pinocchio's `integrate`, `difference`,
//! `dIntegrate` and `dDifference` (`ARG0`, `ARG1`) compute them for a free-flyer (SE(3)),
//! a spherical joint (SO(3), a unit quaternion) and a scalar coordinate (revolute,
//! prismatic, continuous held as one angle: `q1 − q`).
//!
//! `integrate` is the step's exponential (`step.rs`). `difference` needs the logarithm,
//! which has `atan2(|v|, w)` and `(θ/2) cot(θ/2)` at its heart: no branch-free closed form
//! at θ = 0, and the IR has no `atan2`. It is computed instead by halving the angle: the
//! relative quaternion `r` (normalised, and negated where `w < 0`, so that θ ≤ π as
//! Pinocchio's `quaternion::log3` picks) is square-rooted [`HALVINGS`] times
//! (`cos(φ/2) = √((1 + cos φ)/2)`, whose argument stays in [1/2, 1]); at the small angle
//! left, `atan(t)/t` and `x cot x` are short series, and the cotangent is doubled back
//! (`2x cot 2x = x cot x − x² / (x cot x)`). Each step is exact to rounding, so `v` is
//! too, at every angle up to π, with no division by a vanishing value. The Jacobians are
//! the forward-mode derivatives of that graph along each coordinate's tangent direction
//! (Pinocchio's right perturbation `q ⊕ δ`), the sign taken as fixed.

use super::super::graph::{Graph, Id, Input};
use super::super::spatial::{self as sp, k, V3};
use super::step::qmul;
use super::{Dynamics, Mat};
use crate::model::LieBlock;

/// Square roots that halve the angle: after six, φ ≤ π/2 is at most π/128 and `t² =
/// tan² φ` at most 6.1e-4.
const HALVINGS: usize = 6;
/// Terms of `atan(t)/t = Σ (−t²)^n / (2n + 1)`: the first left out is below
/// (6.1e-4)^6 / 13 ≈ 4e-21.
const ATAN_TERMS: usize = 6;
/// `x cot x = 1 − Σ_{n≥1} c_n x^2n`, `c_n = 2^2n |B_2n| / (2n)!` (B the Bernoulli numbers):
/// 1/3, 1/45, 2/945, 1/4725, 2/93555. With x² ≤ 6.1e-4 the first left out, c_6 x^12 =
/// 1382/638512875 x^12, is about 1e-25.
const COT: [f64; 5] = [1.0 / 3.0, 1.0 / 45.0, 2.0 / 945.0, 1.0 / 4725.0, 2.0 / 93555.0];
/// Added to `w` before its sign is taken, so that `w = 0` (a half turn, where either sign
/// is a logarithm) reads as positive, as Pinocchio's `w >= 0`; its square is a normal
/// number in f32 too.
const SIGN_SHIFT: f64 = 1e-18;

/// A quaternion's logarithm as [`quaternion_log`] records it: the rotation vector ω
/// (θ = |ω| ≤ π), `α = (θ/2) cot(θ/2)` and `β = (1 − α)/θ²` (a free-flyer's translation
/// needs them), and the node of `w`'s sign, whose tangent the Jacobians hold at 0.
pub(super) struct Log {
    pub omega: V3,
    pub alpha: Id,
    pub beta: Id,
    pub sign: Id,
}

/// `Σ c_n y^n` by Horner's rule.
fn polynomial(g: &mut Graph, y: Id, c: &[f64]) -> Id {
    let (last, rest) = c.split_last().expect("coefficients");
    let mut acc = k(g, *last);
    for &x in rest.iter().rev() {
        let t = g.mul(acc, y);
        let x = k(g, x);
        acc = g.add(x, t);
    }
    acc
}

/// The logarithm of the rotation of the quaternion `r = [x, y, z, w]` (Pinocchio's
/// `quaternion::log3`, as the module documentation computes it).
pub(super) fn quaternion_log(g: &mut Graph, r: [Id; 4]) -> Log {
    let norm = g.dot(&r, &r);
    let norm = g.sqrt(norm);
    let shift = k(g, SIGN_SHIFT);
    let shifted = g.add(r[3], shift);
    let square = g.mul(shifted, shifted);
    let size = g.sqrt(square);
    let sign = g.div(shifted, size);
    // r / |r| with w ≥ 0.
    let scale = g.div(sign, norm);
    let mut v: V3 = [r[0], r[1], r[2]].map(|x| g.mul(scale, x));
    let mut c = g.mul(scale, r[3]);
    let (one, half) = (k(g, 1.0), k(g, 0.5));
    for _ in 0..HALVINGS {
        let s = g.add(one, c);
        let s = g.mul(half, s);
        c = g.sqrt(s);
        // One division per halving: v / 2c as v · (½ / c).
        let inv = g.div(half, c);
        v = v.map(|x| g.mul(x, inv));
    }
    // t = tan φ_K; φ_K / sin φ_K = (atan t / t) / cos φ_K.
    let vv = g.dot(&v, &v);
    let cc = g.mul(c, c);
    let t2 = g.div(vv, cc);
    let signs: Vec<f64> =
        (0..ATAN_TERMS).map(|n| if n % 2 == 0 { 1.0 } else { -1.0 } / (2 * n + 1) as f64).collect();
    let atanc = polynomial(g, t2, &signs);
    let factor = k(g, 2f64.powi(HALVINGS as i32 + 1));
    let f = g.div(atanc, c);
    let f = g.mul(factor, f);
    let omega = v.map(|x| g.mul(f, x));
    // x = φ_K: x² = t² (atan t / t)²; a = x cot x and b = (1 − a)/x², doubled back to φ.
    let aa = g.mul(atanc, atanc);
    let mut x2 = g.mul(t2, aa);
    let mut b = polynomial(g, x2, &COT);
    let bx = g.mul(b, x2);
    let mut a = g.sub(one, bx);
    let (four, quarter) = (k(g, 4.0), k(g, 0.25));
    for _ in 0..HALVINGS {
        // 2x cot 2x = a − x²/a; (1 − 2x cot 2x)/(2x)² = (b + 1/a)/4.
        let inv = g.div(one, a);
        let xa = g.mul(x2, inv);
        let bi = g.add(b, inv);
        b = g.mul(quarter, bi);
        a = g.sub(a, xa);
        x2 = g.mul(four, x2);
    }
    // With θ = 2φ: α = φ cot φ, β = (1 − α)/(4φ²).
    let beta = g.mul(quarter, b);
    Log { omega, alpha: a, beta, sign }
}

/// The conjugate of `a` times `b`: `a⁻¹ b` for unit quaternions.
fn conjugate_times(g: &mut Graph, a: [Id; 4], b: [Id; 4]) -> [Id; 4] {
    let conj = [g.neg(a[0]), g.neg(a[1]), g.neg(a[2]), a[3]];
    qmul(g, conj, b)
}

impl Dynamics<'_> {
    /// The kernel's q ⊕ v: `integrate(q, v)`.
    pub fn lie_integrate(&mut self) -> Vec<Id> {
        let v = self.inputs(Input::V);
        self.integrate_recorded(&v).0
    }

    /// `(∂(q ⊕ v)/∂q, ∂(q ⊕ v)/∂v)`: `dintegrate(q, v)`.
    pub fn lie_d_integrate(&mut self) -> (Mat, Mat) {
        let v = self.inputs(Input::V);
        let (_, exps) = self.integrate_recorded(&v);
        self.d_integrate(&exps)
    }

    /// `q1 ⊖ q` and the nodes of the signs its logarithms took.
    fn difference_recorded(&mut self) -> (Vec<Id>, Vec<Id>) {
        let g = &mut self.g;
        let q0: Vec<Id> = (0..self.model.nq()).map(|i| g.input(Input::Q, i)).collect();
        let q1: Vec<Id> = (0..self.model.nq()).map(|i| g.input(Input::Q1, i)).collect();
        let quat = |q: &[Id], at: usize| [q[at], q[at + 1], q[at + 2], q[at + 3]];
        let zero = g.constant(0.0);
        let mut out = vec![zero; self.model.nv()];
        let mut signs = Vec::new();
        for block in self.model.lie_blocks() {
            match block {
                LieBlock::Scalar { v, q } => out[v] = g.sub(q1[q], q0[q]),
                LieBlock::Spherical { v, q } => {
                    let r = conjugate_times(g, quat(&q0, q), quat(&q1, q));
                    let log = quaternion_log(g, r);
                    out[v..v + 3].copy_from_slice(&log.omega);
                    signs.push(log.sign);
                }
                LieBlock::FreeFlyer => {
                    // log6(M0⁻¹ M1): ω from R0ᵀ R1, p = R0ᵀ (p1 − p0), and the translation
                    // V(ω)⁻¹ p = α p − ½ ω × p + β (ω · p) ω (Pinocchio's `log6`).
                    let r = conjugate_times(g, quat(&q0, 3), quat(&q1, 3));
                    let log = quaternion_log(g, r);
                    let rot = sp::quaternion_rotation(g, quat(&q0, 3));
                    let dp = sp::sub3(g, &[q1[0], q1[1], q1[2]], &[q0[0], q0[1], q0[2]]);
                    let p = sp::mat_t_vec(g, &rot, &dp);
                    let w = log.omega;
                    let wp = sp::cross(g, &w, &p);
                    let dot = g.dot(&w, &p);
                    let bd = g.mul(log.beta, dot);
                    let half = k(g, 0.5);
                    for i in 0..3 {
                        let x = g.mul(log.alpha, p[i]);
                        let y = g.mul(half, wp[i]);
                        let z = g.mul(bd, w[i]);
                        let s = g.sub(x, y);
                        out[i] = g.add(s, z);
                    }
                    out[3..6].copy_from_slice(&w);
                    signs.push(log.sign);
                }
            }
        }
        (out, signs)
    }

    /// `difference(q, q1)`: the tangent v with `q ⊕ v = q1`.
    pub fn difference(&mut self) -> Vec<Id> {
        self.difference_recorded().0
    }

    /// `(∂(q1 ⊖ q)/∂q, ∂(q1 ⊖ q)/∂q1)` in the tangent space (`dDifference`, `ARG0` and
    /// `ARG1`), nv × nv each, by forward mode along each coordinate's direction of q and of
    /// q1, the logarithms' signs held.
    pub fn d_difference(&mut self) -> (Mat, Mat) {
        let (v, signs) = self.difference_recorded();
        let nv = self.model.nv();
        let zero = self.g.constant(0.0);
        let held: Vec<(Id, Id)> = signs.iter().map(|&s| (s, zero)).collect();
        let mut by = [vec![vec![zero; nv]; nv], vec![vec![zero; nv]; nv]];
        for (m, input) in [Input::Q, Input::Q1].into_iter().enumerate() {
            for c in 0..nv {
                let seeds = self.config_seeds(input, c);
                let column = self.g.tangent_at(&v, &seeds, &held);
                for (r, x) in column.into_iter().enumerate() {
                    by[m][r][c] = x;
                }
            }
        }
        let [dq, dq1] = by;
        (dq, dq1)
    }
}
