//! Range and rounding-error analysis of a datapath. Interval arithmetic from the input
//! bounds gives every node's range (so the integer bits are shown sufficient), and a
//! forward worst-case error bound per node: for `x̂ = x + ex`, `ŷ = y + ey`,
//! `|x̂ŷ − xy| ≤ |x||ey| + |y||ex| + |ex||ey|`, plus the product's rounding; sums add
//! their operands' bounds. Both are rigorous (no overflow occurs inside the bounds, and
//! the fixed-point result is within the bound of the exact one) but conservative.
//! Intervals do not know that sin² + cos² = 1: a joint's rotation `c·x ± s·y` is bounded
//! by √(X² + Y²) where that pattern is explicit in the graph (one joint's sin and cos
//! times two nodes), but sums of several joints' terms still take |a| + |b|, so ranges grow
//! along the chain faster than the true values. First-order affine arithmetic (one noise symbol per port) was tried and bounded no
//! node of the bundled robots tighter: the dynamics are multilinear in the joints'
//! sin/cos, so every product of two joints' terms falls into the nonlinear remainder. The book
//! reports the bound beside the measured error.

use super::backward::{Backward, SolveBounds};
use super::MAX_WIDTH;
use super::{Clamp, Datapath, FixedError, Format, HwId, HwOp, Port, Rounding, SolveStage};
use crate::ir::{Input, Robot};

/// Joint speed bound when the URDF gives no `<limit velocity>` (rad/s or m/s); a fast
/// industrial arm's joints stay under it (the iiwa's limits are 1.5 to 3.1 rad/s; GRiD's
/// URDFs write 10 or 12).
pub const DEFAULT_QD_MAX: f64 = 10.0;
/// Joint acceleration bound (rad/s² or m/s²); no URDF field gives one. Ten times what
/// industrial arms are rated for (the iiwa: about 10 rad/s²), to leave room for MPC
/// iterates far from feasible.
pub const DEFAULT_QDD_MAX: f64 = 100.0;
/// Bound on every entry of the external and contact forces (N and N m) when none is given:
/// ten times a 100 kg robot's weight on one contact, as an MPC iterate may ask.
pub const DEFAULT_FORCE_MAX: f64 = 1e4;
/// Joint torque (or force) bound for `fd_grad`'s chip partition, whose input τ is: a
/// large humanoid's hip or knee is rated at a few hundred newton-metres (Atlas's URDF
/// writes efforts up to 890 N m for the legs' hydraulic joints), and MPC iterates may ask
/// for more.
pub const DEFAULT_TAU_MAX: f64 = 1000.0;
/// Prismatic position bound (m) when the joint has no `<limit>`.
pub const DEFAULT_Q_MAX: f64 = 2.0;

/// The inputs' declared ranges, per joint (symmetric magnitudes, except positions).
#[derive(Clone, Debug, PartialEq)]
pub struct Bounds {
    pub q: Vec<(f64, f64)>,
    pub qd: Vec<f64>,
    pub qdd: Vec<f64>,
    /// |τ| per coordinate (`fd_grad`'s chip partition); 0 for a floating base's six,
    /// which are unactuated (the chip takes no τ for them).
    pub tau: Vec<f64>,
    /// Every entry of `fext` and λ (the kernels that take forces).
    pub force: f64,
    /// |M⁻¹|'s entries, row-major (`fd_grad`'s host partition; empty: unbounded, which
    /// fails the check of any datapath that reads M⁻¹).
    pub minv: Vec<f64>,
}

impl Bounds {
    /// From the URDF's limits, overridden for every joint by `qd_max` / `qdd_max` when
    /// given; the defaults above otherwise.
    pub fn new(robot: &Robot, qd_max: Option<f64>, qdd_max: Option<f64>) -> Bounds {
        let nv = robot.nv();
        let joint_q = |j: usize| {
            robot.limits[j].filter(|(lo, hi)| lo < hi).unwrap_or((-DEFAULT_Q_MAX, DEFAULT_Q_MAX))
        };
        // With a floating base, q's entries: position (read by no datapath: gravity does
        // not depend on it), the quaternion (within `eval`'s tolerance of unit), then the
        // joints after the free-flyer.
        // Spherical joints' quaternions likewise.
        let unit = 1.0 + crate::model::QUATERNION_TOLERANCE;
        let q = (0..robot.nq())
            .map(|k| match robot.q_coordinates[k] {
                Some(c) => joint_q(c),
                None if robot.floating && k < 3 => (-DEFAULT_Q_MAX, DEFAULT_Q_MAX),
                None => (-unit, unit),
            })
            .collect();
        Bounds {
            q,
            // A static scene holds q̇ at 0 (its kernels never read it).
            qd: (0..nv)
                .map(|j| {
                    if robot.specialisation.static_velocity {
                        0.0
                    } else {
                        qd_max.or(robot.velocity_limits[j]).unwrap_or(DEFAULT_QD_MAX)
                    }
                })
                .collect(),
            qdd: vec![qdd_max.unwrap_or(DEFAULT_QDD_MAX); nv],
            tau: (0..nv)
                .map(|j| if robot.floating && j < 6 { 0.0 } else { DEFAULT_TAU_MAX })
                .collect(),
            force: DEFAULT_FORCE_MAX,
            minv: Vec::new(),
        }
    }

    /// Whether a state lies inside the bounds (positions are only bounded where a
    /// datapath uses them directly, for prismatic joints).
    pub fn contains(&self, qd: &[f64], qdd: &[f64]) -> bool {
        qd.iter().zip(&self.qd).all(|(v, b)| v.abs() <= *b)
            && qdd.iter().zip(&self.qdd).all(|(v, b)| v.abs() <= *b)
    }

    fn port(&self, p: Port) -> (f64, f64) {
        match p {
            Port::Sin(_) | Port::Cos(_) => (-1.0, 1.0),
            Port::QuatScale(_) => {
                let t = crate::model::QUATERNION_TOLERANCE;
                (2.0 / (1.0 + t).powi(2), 2.0 / (1.0 - t).powi(2))
            }
            Port::Value(Input::Q, j) => self.q[j as usize],
            Port::Value(Input::Qd, j) => (-self.qd[j as usize], self.qd[j as usize]),
            Port::Value(Input::Qdd, j) => (-self.qdd[j as usize], self.qdd[j as usize]),
            Port::Value(Input::Tau, j) => (-self.tau[j as usize], self.tau[j as usize]),
            // No datapath kernel takes a step; unbounded makes any that did fail the check.
            Port::Value(
                Input::TauActuated
                | Input::Active
                | Input::Gains
                | Input::ContactRef
                | Input::Dt
                | Input::V
                | Input::Q1
                | Input::Called(_),
                _,
            ) => (f64::NEG_INFINITY, f64::INFINITY),
            Port::Value(Input::Fext | Input::Lambda, _) => (-self.force, self.force),
            Port::Minv(i, k) => match self.minv.get(i as usize * self.qd.len() + k as usize) {
                Some(&b) => (-b, b),
                None => (f64::NEG_INFINITY, f64::INFINITY),
            },
        }
    }
}

/// What the analysis found for one format.
#[derive(Clone, Debug, PartialEq)]
pub struct Analysis {
    /// Range of each node's exact value.
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
    /// Bound on |fixed − exact| of each node.
    pub err: Vec<f64>,
    /// Largest magnitude any node's fixed-point value can reach (range plus error).
    pub needed: f64,
    /// Largest error bound over the outputs' non-zero entries.
    pub output_error: f64,
}

/// How far a value computed in f64 may be from the exact one: widening each bound by it
/// keeps the f64 rounding of the analysis itself from making a bound too tight.
fn slack(x: f64) -> f64 {
    x.abs() * 8.0 * f64::EPSILON + f64::MIN_POSITIVE
}

/// Analyses `dp` for inputs within `bounds`, with `frac` fraction bits and `rounding`
/// (the width does not change either result, as long as nothing saturates).
pub fn analyse(dp: &Datapath, bounds: &Bounds, frac: u32, rounding: Rounding) -> Analysis {
    let format = Format { width: MAX_WIDTH, frac, rounding };
    let ulp = format.ulp();
    let n = dp.nodes.len();
    let (mut lo, mut hi, mut err) = (vec![0.0f64; n], vec![0.0f64; n], vec![0.0f64; n]);
    // β of each solve, once its right-hand side is analysed.
    let mut beta: Vec<Option<f64>> = vec![None; dp.factor.rhs.len()];
    // The factorisation's and solves' error bounds (`fd_grad`'s chip partition), once M's
    // entries are analysed: nodes after them that carry a bound take it from there.
    let last_entry = dp.factor.entries.iter().map(|e| e.2 .0 as usize).max();
    let mut backward: Option<Backward> = None;
    let mut solves: Vec<Option<SolveBounds>> = (0..dp.factor.rhs.len()).map(|_| None).collect();
    let trig = trig_products(dp);
    for (i, op) in dp.nodes.iter().enumerate() {
        // The largest magnitude of an analysed node's exact value.
        let range = |x: HwId| lo[x.0 as usize].abs().max(hi[x.0 as usize].abs());
        let (l, h, e) = match *op {
            HwOp::Port(p) => {
                let (l, h) = bounds.port(dp.ports[p as usize]);
                (l, h, ulp / 2.0)
            }
            HwOp::Const(c) => (c, c, (c - format.to_f64(format.quantize(c).0)).abs()),
            HwOp::Add(a, b) => (
                lo[a.0 as usize] + lo[b.0 as usize],
                hi[a.0 as usize] + hi[b.0 as usize],
                err[a.0 as usize] + err[b.0 as usize],
            ),
            HwOp::Sub(a, b) => (
                lo[a.0 as usize] - hi[b.0 as usize],
                hi[a.0 as usize] - lo[b.0 as usize],
                err[a.0 as usize] + err[b.0 as usize],
            ),
            HwOp::Neg(a) => (-hi[a.0 as usize], -lo[a.0 as usize], err[a.0 as usize]),
            HwOp::Mul(a, b) => {
                let (al, ah, bl, bh) =
                    (lo[a.0 as usize], hi[a.0 as usize], lo[b.0 as usize], hi[b.0 as usize]);
                let p = [al * bl, al * bh, ah * bl, ah * bh];
                let l = p.iter().copied().fold(f64::INFINITY, f64::min);
                let h = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                // 0 · ∞ from an unbounded port: the product is unbounded.
                let (l, h) = if l.is_nan() || h.is_nan() {
                    (f64::NEG_INFINITY, f64::INFINITY)
                } else {
                    (l, h)
                };
                let (ea, eb) = (err[a.0 as usize], err[b.0 as usize]);
                let (ma, mb) = (al.abs().max(ah.abs()), bl.abs().max(bh.abs()));
                (l, h, ma * eb + mb * ea + ea * eb + format.product_error())
            }
            HwOp::Recip(a) => {
                let (al, ah, ea) = (lo[a.0 as usize], hi[a.0 as usize], err[a.0 as usize]);
                // The exact divisor lies in [al, ah]: a positive one bounds the exact
                // reciprocal. |1/(x + δ) − 1/x| = |δ| / (x (x + δ)) for x ≥ al > |δ|; the
                // divider's quotient rounds toward zero, less than one ulp.
                let (l, h) = if al > 0.0 && ah.is_finite() {
                    (ah.recip(), al.recip())
                } else {
                    (f64::NEG_INFINITY, f64::INFINITY)
                };
                let e = if al > ea { ea / (al * (al - ea)) + ulp } else { f64::INFINITY };
                (l, h, e)
            }
        };
        // A joint's rotation: |±cos θ · x ± sin θ · y| ≤ √(x² + y²) (Cauchy–Schwarz, as
        // cos² θ + sin² θ = 1), where intervals alone give |x| + |y|. Its error likewise:
        // the computed value is ĉx̂ ± ŝŷ plus two roundings, and ĉx̂ − cx = c(x̂ − x) +
        // (ĉ − c)x̂, so the errors of x and y enter as √(ex² + ey²).
        let (l, h, e) = match *op {
            HwOp::Add(a, b) | HwOp::Sub(a, b) => match (trig[a.0 as usize], trig[b.0 as usize]) {
                (Some(ta), Some(tb)) if ta.joint == tb.joint && ta.cos != tb.cos => {
                    let (xa, xb) = (range(ta.other), range(tb.other));
                    let r = xa.hypot(xb);
                    let (ea, eb) = (err[ta.other.0 as usize], err[tb.other.0 as usize]);
                    let rotated = ea.hypot(eb)
                        + err[ta.port.0 as usize] * (xa + ea)
                        + err[tb.port.0 as usize] * (xb + eb)
                        + 2.0 * format.product_error();
                    (l.max(-r), h.min(r), e.min(rotated))
                }
                _ => (l, h, e),
            },
            _ => (l, h, e),
        };
        // A pivot's bound may name the node itself (an entry of M no update reached).
        let maxabs = |x: HwId| if x.0 as usize == i { l.abs().max(h.abs()) } else { range(x) };
        // The backward analysis's bounds apply to the values the factorisation computes
        // (M's entries keep their own).
        let after = last_entry.is_some_and(|last| i > last) && dp.clamps[i].is_some();
        if after && backward.is_none() {
            backward = Some(Backward::new(dp, &format, range, &err));
        }
        let proof = backward.as_ref().filter(|b| after && b.valid);
        let (l, h, e) = match dp.clamps[i] {
            None => (l, h, e),
            Some(Clamp::Schur(a, b)) => {
                let m = (maxabs(a) * maxabs(b)).sqrt();
                let e = proof.map_or(e, |p| e.min(p.schur_excess(maxabs(a), maxabs(b))));
                (l.max(-m), h.min(m), e)
            }
            Some(Clamp::Pivot { floor, diagonal }) => {
                let e = proof.map_or(e, |p| e.min(p.pivot_excess(floor)));
                (l.max(floor), h.min(maxabs(diagonal)), e)
            }
            Some(Clamp::Multiplier { diagonal, floor }) => {
                let m = (maxabs(diagonal) / floor).sqrt();
                let e = proof.map_or(e, |p| e.min(p.multiplier_excess(maxabs(diagonal), floor)));
                (l.max(-m), h.min(m), e)
            }
            Some(Clamp::Solve { solve, k, stage }) => {
                let f = &dp.factor;
                let b = *beta[solve as usize].get_or_insert_with(|| {
                    let s: f64 = f.rhs[solve as usize]
                        .iter()
                        .map(|&(k, x)| f.minv[k as usize].sqrt() * maxabs(x))
                        .sum();
                    s * s
                });
                let k = k as usize;
                let m = match stage {
                    SolveStage::Lower => (b * maxabs(f.diagonal[k])).sqrt(),
                    SolveStage::Scaled => (b / f.floor[k]).sqrt(),
                    SolveStage::Solution => (f.minv[k] * b).sqrt(),
                };
                let e = match proof {
                    None => e,
                    Some(p) => {
                        let s = solves[solve as usize]
                            .get_or_insert_with(|| p.solve(dp, solve as usize, maxabs, &err));
                        // Lower and scaled values: how far the computed value's bound
                        // exceeds the exact one's. A solution's: its error.
                        match stage {
                            SolveStage::Lower => e.min((s.lower[k] - m).max(0.0)),
                            SolveStage::Scaled => e.min((s.scaled[k] - m).max(0.0)),
                            SolveStage::Solution => s.error[k],
                        }
                    }
                };
                (l.max(-m), h.min(m), e)
            }
        };
        // Exact zeros (structural zeros) stay exact.
        lo[i] = if l == 0.0 { 0.0 } else { l - slack(l) };
        hi[i] = if h == 0.0 { 0.0 } else { h + slack(h) };
        err[i] = e + slack(e);
    }
    let needed = (0..n).map(|i| lo[i].abs().max(hi[i].abs()) + err[i]).fold(0.0, f64::max);
    let output_error =
        dp.nonzero_outputs().iter().map(|&(_, _, id)| err[id.0 as usize]).fold(0.0, f64::max);
    Analysis { lo, hi, err, needed, output_error }
}

/// A node that is ± sin θⱼ or cos θⱼ of one joint times another node.
#[derive(Clone, Copy)]
struct Trig {
    joint: u16,
    cos: bool,
    /// The `Sin` or `Cos` port's node.
    port: HwId,
    other: HwId,
}

/// Each node's [`Trig`] form, where it has one: a product with a `Sin` or `Cos` port, or
/// the negation of one.
fn trig_products(dp: &Datapath) -> Vec<Option<Trig>> {
    let port = |x: HwId| match dp.nodes[x.0 as usize] {
        HwOp::Port(p) => match dp.ports[p as usize] {
            Port::Sin(j) => Some((j, false)),
            Port::Cos(j) => Some((j, true)),
            _ => None,
        },
        _ => None,
    };
    let mut trig: Vec<Option<Trig>> = Vec::with_capacity(dp.nodes.len());
    for op in &dp.nodes {
        let t = match *op {
            HwOp::Mul(a, b) => match (port(a), port(b)) {
                (Some((joint, cos)), _) => Some(Trig { joint, cos, port: a, other: b }),
                (None, Some((joint, cos))) => Some(Trig { joint, cos, port: b, other: a }),
                (None, None) => None,
            },
            HwOp::Neg(a) => trig[a.0 as usize],
            _ => None,
        };
        trig.push(t);
    }
    trig
}

impl Analysis {
    /// The largest proven magnitude of any node's exact value (its error not included).
    pub fn range(&self) -> f64 {
        self.lo.iter().zip(&self.hi).map(|(l, h)| l.abs().max(h.abs())).fold(0.0, f64::max)
    }

    /// Error unless every value fits `format` (then no node can saturate for inputs
    /// within the bounds).
    pub fn check(&self, dp: &Datapath, format: &Format) -> Result<(), FixedError> {
        if self.needed.is_finite() && self.needed <= format.max_value() {
            Ok(())
        } else {
            Err(FixedError::Range {
                kernel: dp.kernel.to_string(),
                width: format.width,
                frac: format.frac,
                needed: self.needed,
                max: format.max_value(),
            })
        }
    }
}

/// The narrowest width that holds `needed` with `frac` fraction bits, if any ≤ 64.
pub fn width_for(needed: f64, frac: u32) -> Option<u32> {
    (frac + 1..=MAX_WIDTH)
        .find(|&w| Format { width: w, frac, rounding: Rounding::Truncate }.max_value() >= needed)
}

/// The narrowest format whose analysed output error is at most `max_error`: the fewest
/// fraction bits that meet it, then the fewest integer bits that hold every value.
pub fn choose_format(
    dp: &Datapath,
    bounds: &Bounds,
    rounding: Rounding,
    max_error: f64,
) -> Result<(Format, Analysis), FixedError> {
    if !(max_error.is_finite() && max_error > 0.0) {
        return Err(FixedError::BadMaxError(max_error));
    }
    let mut best = None;
    for frac in 0..MAX_WIDTH - 1 {
        let a = analyse(dp, bounds, frac, rounding);
        let Some(width) = width_for(a.needed, frac) else {
            // More fraction bits only need more width: nothing further fits, unless the
            // ranges are bounded and only an error is not (the factorisation's error
            // analysis failing at few fraction bits, which more bits cure).
            if a.needed.is_finite() || !a.range().is_finite() {
                break;
            }
            continue;
        };
        if a.output_error <= max_error {
            return Ok((Format { width, frac, rounding }, a));
        }
        best = Some((a.output_error, width, frac));
    }
    let (best, width, frac) = best.unwrap_or((f64::INFINITY, MAX_WIDTH, 0));
    Err(FixedError::Unreachable { kernel: dp.kernel.to_string(), max_error, best, width, frac })
}

/// The format of width `width` with as many fraction bits as the analysed range allows.
pub fn format_for_width(
    dp: &Datapath,
    bounds: &Bounds,
    rounding: Rounding,
    width: u32,
) -> Option<(Format, Analysis)> {
    (0..width).rev().find_map(|frac| {
        let a = analyse(dp, bounds, frac, rounding);
        let f = Format { width, frac, rounding };
        (a.needed <= f.max_value()).then_some((f, a))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::datapath::{DatapathOutput, Factor};
    use crate::ir::{Dims, Shape};

    /// `cos θ · x − sin θ · y` and `−(sin θ · x) + cos θ · y` with |x|, |y| ≤ 3 and 4: the
    /// rotation bound gives 5 where intervals give 7, and only for one joint's sin and cos.
    #[test]
    fn a_rotation_is_bounded_by_the_norm_of_what_it_rotates() {
        let ports = vec![
            Port::Sin(0),
            Port::Cos(0),
            Port::Value(Input::Qd, 0),
            Port::Value(Input::Qd, 1),
            Port::Cos(1),
        ];
        let id = HwId;
        let nodes = vec![
            HwOp::Port(0),
            HwOp::Port(1),
            HwOp::Port(2),
            HwOp::Port(3),
            HwOp::Port(4),
            HwOp::Mul(id(1), id(2)),  // 5: cos θ₀ · x
            HwOp::Mul(id(3), id(0)),  // 6: y · sin θ₀
            HwOp::Sub(id(5), id(6)),  // 7
            HwOp::Mul(id(0), id(2)),  // 8: sin θ₀ · x
            HwOp::Neg(id(8)),         // 9
            HwOp::Mul(id(1), id(3)),  // 10: cos θ₀ · y
            HwOp::Add(id(9), id(10)), // 11
            HwOp::Mul(id(4), id(3)),  // 12: cos θ₁ · y, another joint
            HwOp::Add(id(8), id(12)), // 13
            HwOp::Add(id(5), id(10)), // 14: two cosines
        ];
        let n = nodes.len();
        let dp = Datapath {
            kernel: "test",
            nv: 2,
            dims: Dims { nq: 2, nv: 2, nu: 2, ..Dims::default() },
            ports,
            links: vec![None; n],
            clamps: vec![None; n],
            factor: Factor::default(),
            outputs: vec![DatapathOutput {
                name: "out",
                shape: Shape::Vector,
                ids: vec![id(7), id(11)],
            }],
            nodes,
        };
        let bounds = Bounds {
            q: vec![(-3.2, 3.2); 2],
            qd: vec![3.0, 4.0],
            qdd: vec![1.0; 2],
            tau: vec![1.0; 2],
            force: 1.0,
            minv: Vec::new(),
        };
        let a = analyse(&dp, &bounds, 20, Rounding::HalfUp);
        let close = |x: f64, y: f64| (x - y).abs() < 1e-9;
        for i in [7, 11] {
            assert!(close(a.hi[i], 5.0) && close(a.lo[i], -5.0), "node {i}: {a:?}");
        }
        for i in [13, 14] {
            assert!(close(a.hi[i], 7.0) && close(a.lo[i], -7.0), "node {i}: {a:?}");
        }
    }
}
