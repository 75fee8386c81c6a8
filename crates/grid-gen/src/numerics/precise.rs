//! Double-double numbers (about 106 bits), so that the IR can be evaluated as a
//! high-precision reference and every format's error measured against the true value
//! rather than against f64.
//!
//! A value is the unevaluated sum `hi + lo` of two f64 with `|lo| <= ulp(hi) / 2`.
//! Arithmetic: Knuth's TwoSum and the FMA product, and the double-word algorithms of
//! Joldes, Muller & Popescu, "Tight and rigorous error bounds for basic building blocks of
//! double-word arithmetic", ACM TOMS 44(2), 2017: Algorithm 6 (sum, relative error below
//! 3u², u = 2⁻⁵³), 12 (product, 5u²), 9 (by a double, 2u²) and 18 (quotient, 10u²).
//! sin and cos reduce by π/2 held in three doubles (the constants of Hida, Li & Bailey's
//! QD library) and sum the Taylor series to below 1e-33 on [-π/4, π/4].

use core::ops::{Add, Div, Mul, Neg, Sub};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dd {
    pub hi: f64,
    pub lo: f64,
}

fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// Requires `|a| >= |b|` (or `a == 0`).
fn fast_two_sum(a: f64, b: f64) -> Dd {
    let s = a + b;
    Dd { hi: s, lo: b - (s - a) }
}

fn two_prod(a: f64, b: f64) -> Dd {
    let p = a * b;
    Dd { hi: p, lo: a.mul_add(b, -p) }
}

/// π/2 as the sum of three doubles (QD library, `qd_real::_pi` halved).
const HALF_PI: [f64; 3] =
    [std::f64::consts::FRAC_PI_2, 6.123_233_995_736_766e-17, -1.497_384_904_859_169_8e-33];

impl Dd {
    pub const fn new(x: f64) -> Dd {
        Dd { hi: x, lo: 0.0 }
    }

    /// The nearest f64 (`hi`, since `|lo| <= ulp(hi) / 2`).
    pub fn to_f64(self) -> f64 {
        self.hi
    }

    fn mul_f64(self, y: f64) -> Dd {
        let c = two_prod(self.hi, y);
        fast_two_sum(c.hi, self.lo.mul_add(y, c.lo))
    }

    /// The square root: f64's, then one Newton step in double-double
    /// (`s + (x − s²) / 2s`, Karp & Markstein's form), which doubles its 53 bits.
    pub fn sqrt(self) -> Dd {
        if self.hi <= 0.0 {
            return Dd::new(self.hi.sqrt());
        }
        let s = Dd::new(self.hi.sqrt());
        s + (self - s * s) / Dd::new(2.0 * s.hi)
    }

    /// sin and cos together, after reduction by π/2.
    pub fn sin_cos(self) -> (Dd, Dd) {
        let k = (self.hi / HALF_PI[0]).round();
        // k·(π/2) exactly enough for |k| up to about 2^20 (|x| < 1.6e6 rad): each product
        // by the three parts is exact or below 1e-40.
        let r = self - two_prod(k, HALF_PI[0]) - two_prod(k, HALF_PI[1]) - Dd::new(k * HALF_PI[2]);
        let r2 = r * r;
        // Taylor series; |r| <= π/4, so the 16th terms are below 1e-37.
        let (mut sin, mut cos) = (Dd::new(0.0), Dd::new(0.0));
        let (mut s_term, mut c_term) = (r, Dd::new(1.0));
        for n in 0..16 {
            sin = sin + s_term;
            cos = cos + c_term;
            let (a, b) = (2.0 * n as f64 + 2.0, 2.0 * n as f64 + 3.0);
            s_term = -(s_term * r2) / Dd::new(a * b);
            c_term = -(c_term * r2) / Dd::new((a - 1.0) * a);
        }
        match (k as i64).rem_euclid(4) {
            0 => (sin, cos),
            1 => (cos, -sin),
            2 => (-sin, -cos),
            _ => (-cos, sin),
        }
    }
}

impl Add for Dd {
    type Output = Dd;
    fn add(self, y: Dd) -> Dd {
        let (sh, sl) = two_sum(self.hi, y.hi);
        let (th, tl) = two_sum(self.lo, y.lo);
        let v = fast_two_sum(sh, sl + th);
        fast_two_sum(v.hi, tl + v.lo)
    }
}

impl Sub for Dd {
    type Output = Dd;
    fn sub(self, y: Dd) -> Dd {
        self + -y
    }
}

impl Neg for Dd {
    type Output = Dd;
    fn neg(self) -> Dd {
        Dd { hi: -self.hi, lo: -self.lo }
    }
}

impl Mul for Dd {
    type Output = Dd;
    fn mul(self, y: Dd) -> Dd {
        let c = two_prod(self.hi, y.hi);
        let tl = self.hi.mul_add(y.lo, self.lo * y.hi);
        fast_two_sum(c.hi, c.lo + tl)
    }
}

impl Div for Dd {
    type Output = Dd;
    fn div(self, y: Dd) -> Dd {
        let th = self.hi / y.hi;
        let r = y.mul_f64(th);
        let d = (self.hi - r.hi) + (self.lo - r.lo);
        fast_two_sum(th, d / y.hi)
    }
}

/// The IR's interpreter runs in double-double ([`crate::ir::Function::eval_as`]).
impl crate::ir::EvalNumber for Dd {
    fn from_f64(x: f64) -> Self {
        Dd::new(x)
    }
    fn sin(self) -> Self {
        self.sin_cos().0
    }
    fn cos(self) -> Self {
        self.sin_cos().1
    }
    fn sqrt(self) -> Self {
        self.sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error of `x` from the value `want_hi + want_lo` known to more than 106 bits.
    fn err(x: Dd, want_hi: f64, want_lo: f64) -> f64 {
        ((x.hi - want_hi) + (x.lo - want_lo)).abs()
    }

    #[test]
    fn arithmetic_keeps_106_bits() {
        let third = Dd::new(1.0) / Dd::new(3.0);
        assert!(err(third * Dd::new(3.0), 1.0, 0.0) < 1e-31);
        // (1 + 2⁻⁶⁰)² = 1 + 2⁻⁵⁹ + 2⁻¹²⁰: f64 loses all but the 1.
        let a = Dd::new(1.0) + Dd::new(2f64.powi(-60));
        let sq = a * a;
        assert_eq!((sq.hi, sq.lo), (1.0, 2f64.powi(-59) + 2f64.powi(-120)));
        assert!(err((a - Dd::new(1.0)) / Dd::new(2f64.powi(-60)), 1.0, 0.0) == 0.0);
    }

    #[test]
    fn sqrt_keeps_106_bits() {
        for x in [2.0, 0.5, 3.0, 1e-30, 7.25e12] {
            let r = Dd::new(x).sqrt();
            let back = r * r;
            assert!(err(back, x, 0.0) < 1e-30 * x, "x = {x}: {back:?}");
        }
        assert_eq!(Dd::new(0.0).sqrt(), Dd::new(0.0));
    }

    #[test]
    fn sin_and_cos_keep_about_106_bits_up_to_1e3_rad() {
        // π/6 from QD's π: sin = 1/2 exactly.
        let pi = Dd { hi: std::f64::consts::PI, lo: 1.224_646_799_147_353_2e-16 };
        let (s, c) = (pi / Dd::new(6.0)).sin_cos();
        assert!(err(s, 0.5, 0.0) < 1e-31, "{s:?}");
        // cos(π/6)² = 3/4.
        assert!(err(c * c, 0.75, 0.0) < 1e-31);
        let mut x = -1000.0f64;
        while x < 1000.0 {
            let (s, c) = Dd::new(x).sin_cos();
            assert!(err(s * s + c * c, 1.0, 0.0) < 1e-30, "x = {x}");
            // libm's sin and cos are within an ulp or so of the truth.
            assert!(
                (s.to_f64() - x.sin()).abs() <= 2.0 * f64::EPSILON * x.sin().abs().max(1e-300),
                "x = {x}"
            );
            assert!(
                (c.to_f64() - x.cos()).abs() <= 2.0 * f64::EPSILON * x.cos().abs().max(1e-300),
                "x = {x}"
            );
            x += 0.731;
        }
    }
}
