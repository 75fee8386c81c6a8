//! The bit-exact software model of the generated fixed-point hardware: the datapath
//! interpreted on integers with the same rounding and saturation as the Verilog cells, so
//! numbers can be checked without a simulator and the simulator is checked against it.

use super::{Datapath, Format, HwOp, Port, Rounding};
use crate::ir::Input;
use ethnum::I256;

/// One evaluation: every output entry (structural zeros included) and the overflow flag.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Run {
    pub outputs: Vec<Vec<i128>>,
    pub overflow: bool,
}

/// The exact value of each port for one state, as the host computes it in f64: sin and
/// cos of q, a floating base's quaternion scale, the inputs themselves. `rest` holds what
/// follows q̈: τ for a kernel that takes it (no datapath does), else the forces, `fext`
/// then λ (empty: none), then, for `fd_grad`'s host partition, M⁻¹ row-major.
pub fn port_values(dp: &Datapath, q: &[f64], qd: &[f64], qdd: &[f64], rest: &[f64]) -> Vec<f64> {
    let lambda_at = 6 * dp.dims.nfext;
    let minv_at = lambda_at + dp.dims.nlambda;
    dp.ports
        .iter()
        .map(|&p| match p {
            Port::Sin(j) => q[j as usize].sin(),
            Port::Cos(j) => q[j as usize].cos(),
            Port::QuatScale(k) => {
                2.0 / q[k as usize..k as usize + 4].iter().map(|x| x * x).sum::<f64>()
            }
            Port::Minv(i, k) => rest[minv_at + i as usize * dp.nv + k as usize],
            Port::Value(input, j) => {
                let (v, at) = match input {
                    Input::Q => (q, 0),
                    Input::Qd => (qd, 0),
                    Input::Qdd => (qdd, 0),
                    Input::Tau
                    | Input::TauActuated
                    | Input::Fext
                    | Input::Active
                    | Input::Gains
                    | Input::ContactRef
                    | Input::Dt
                    | Input::V
                    | Input::Q1
                    | Input::Called(_) => (rest, 0),
                    Input::Lambda => (rest, lambda_at),
                };
                v[at + j as usize]
            }
        })
        .collect()
}

/// The raw value of each port for one state ([`port_values`] rounded to nearest). The
/// flag says a value did not fit.
pub fn quantize_ports(
    dp: &Datapath,
    format: &Format,
    q: &[f64],
    qd: &[f64],
    qdd: &[f64],
    rest: &[f64],
) -> (Vec<i128>, bool) {
    let mut overflow = false;
    let raw = port_values(dp, q, qd, qdd, rest)
        .into_iter()
        .map(|x| {
            let (r, o) = format.quantize(x);
            overflow |= o;
            r
        })
        .collect();
    (raw, overflow)
}

/// The product of two raw values with the format's rounding, before saturation, in 256
/// bits (the netlist's product is 2·WIDTH bits; an arithmetic shift drops FRAC of them).
pub(crate) fn product(format: &Format, a: i128, b: i128) -> I256 {
    // Operands within 63 bits (most values at the formats chosen) multiply in i128.
    if let (Ok(x), Ok(y)) = (i64::try_from(a), i64::try_from(b)) {
        let p = x as i128 * y as i128;
        return I256::from(match format.rounding {
            Rounding::Truncate => p >> format.frac,
            Rounding::HalfUp if format.frac == 0 => p,
            Rounding::HalfUp => (p + (1i128 << (format.frac - 1))) >> format.frac,
        });
    }
    let p = I256::from(a) * I256::from(b);
    match format.rounding {
        Rounding::Truncate => p >> format.frac,
        Rounding::HalfUp if format.frac == 0 => p,
        Rounding::HalfUp => (p + (I256::ONE << (format.frac - 1))) >> format.frac,
    }
}

/// `1 / x` of a raw value: `2^(2·FRAC) / x` rounded toward zero (the divider's
/// quotient), saturated; a non-positive `x` saturates to the largest value and sets the
/// flag (the analysis shows the divisor positive for inputs within the bounds).
pub(crate) fn reciprocal(format: &Format, x: i128) -> (i128, bool) {
    if x <= 0 {
        return (format.max_raw(), true);
    }
    format.saturate_wide((I256::ONE << (2 * format.frac)) / I256::from(x))
}

impl Datapath {
    /// Every node's value in f64 for port values `ports` (not quantized): the exact
    /// computation the fixed-point one approximates.
    pub fn values_f64(&self, ports: &[f64]) -> Vec<f64> {
        let mut val = vec![0.0; self.nodes.len()];
        for (i, op) in self.nodes.iter().enumerate() {
            let v = |id: super::HwId| val[id.0 as usize];
            val[i] = match *op {
                HwOp::Port(n) => ports[n as usize],
                HwOp::Const(c) => c,
                HwOp::Add(a, b) => v(a) + v(b),
                HwOp::Sub(a, b) => v(a) - v(b),
                HwOp::Neg(a) => -v(a),
                HwOp::Mul(a, b) => v(a) * v(b),
                HwOp::Recip(a) => v(a).recip(),
            };
        }
        val
    }

    /// Runs the datapath on raw port values (from [`quantize_ports`]).
    pub fn run(&self, format: &Format, ports: &[i128]) -> Run {
        let (val, overflow) = self.run_nodes(format, ports);
        Run {
            outputs: self
                .outputs
                .iter()
                .map(|o| o.ids.iter().map(|id| val[id.0 as usize]).collect())
                .collect(),
            overflow,
        }
    }

    /// Every node's raw value, and whether any saturated.
    pub fn run_nodes(&self, format: &Format, ports: &[i128]) -> (Vec<i128>, bool) {
        let mut val = vec![0i128; self.nodes.len()];
        let mut overflow = false;
        for (i, op) in self.nodes.iter().enumerate() {
            let v = |id: super::HwId| val[id.0 as usize];
            let (x, o) = match *op {
                HwOp::Port(n) => (ports[n as usize], false),
                HwOp::Const(c) => format.quantize(c),
                // Raw values have at most 120 bits: sums stay in i128.
                HwOp::Add(a, b) => format.saturate(v(a) + v(b)),
                HwOp::Sub(a, b) => format.saturate(v(a) - v(b)),
                HwOp::Neg(a) => format.saturate(-v(a)),
                HwOp::Mul(a, b) => format.saturate_wide(product(format, v(a), v(b))),
                HwOp::Recip(a) => reciprocal(format, v(a)),
            };
            overflow |= o;
            val[i] = x;
        }
        (val, overflow)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_round_as_documented() {
        let t = Format::new(16, 4, Rounding::Truncate).unwrap();
        let h = Format::new(16, 4, Rounding::HalfUp).unwrap();
        // 1.5 * 0.0625 = 0.09375 = 1.5 ulp: truncation keeps 1 ulp, half-up gives 2.
        let p = |f: &Format, a: i128, b: i128| product(f, a, b).as_i128();
        assert_eq!(p(&t, 24, 1), 1);
        assert_eq!(p(&h, 24, 1), 2);
        // −1.5 ulp: truncation rounds toward −∞ (−2), half-up ties toward +∞ (−1).
        assert_eq!(p(&t, -24, 1), -2);
        assert_eq!(p(&h, -24, 1), -1);
        assert_eq!(p(&h, -25, 1), -2);
        // 96 bits: the product needs more than i128; it saturates.
        let w = Format::new(96, 10, Rounding::HalfUp).unwrap();
        let big = w.max_raw();
        // (2^95 − 1)² / 2^10 lies in [2^179, 2^180): beyond i128, exact in 256 bits.
        assert_eq!(product(&w, big, big) >> 179u32, I256::ONE);
        assert_eq!(w.saturate_wide(product(&w, big, big)), (big, true));
        assert_eq!(w.saturate_wide(product(&w, big, -big)), (w.min_raw(), true));
    }

    #[test]
    fn reciprocals_round_toward_zero_and_refuse_non_positive_divisors() {
        let f = Format::new(16, 4, Rounding::HalfUp).unwrap();
        // 1 / 3 = 0.333… = 5.33 ulp: 5. 1 / 0.0625 = 16 = 256 ulp.
        assert_eq!(reciprocal(&f, 48), (5, false));
        assert_eq!(reciprocal(&f, 1), (256, false));
        assert_eq!(reciprocal(&f, 0), (f.max_raw(), true));
        assert_eq!(reciprocal(&f, -16), (f.max_raw(), true));
        // 1 / 2^-8 does not fit 8.4.
        let small = Format::new(8, 4, Rounding::HalfUp).unwrap();
        assert_eq!(reciprocal(&small, 1), (127, true));
    }
}
