//! Signed fixed-point arithmetic on the IR, for the Verilog datapath: the number format,
//! the datapath view of a function (host-computed sin/cos as inputs), the bit-exact
//! software model of the generated hardware, and the range and rounding-error analysis
//! that shows a format safe, and the seeded configurations behind the M⁻¹ input's bound.

mod analysis;
mod backward;
mod chip;
mod measure;
mod model;
mod sample;
mod view;

pub use analysis::{
    analyse, choose_format, format_for_width, width_for, Analysis, Bounds, DEFAULT_FORCE_MAX,
    DEFAULT_QDD_MAX, DEFAULT_QD_MAX, DEFAULT_Q_MAX, DEFAULT_TAU_MAX,
};
pub use chip::fd_grad_chip;
pub use measure::{
    chip_states, choose_format_measured, measure, ChipState, Measured, MEASURED_MARGIN,
    MEASURED_STATES,
};
pub use model::{port_values, quantize_ports, Run};
pub use sample::{minv_diagonal, minv_entries, Rng, MINV_MARGIN, MINV_SAMPLES};
pub use view::{Clamp, Datapath, DatapathOutput, Factor, HwId, HwOp, Port, SolveStage};

/// How a multiplier drops the low `frac` bits of its double-width product.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Rounding {
    /// Keep the high bits (an arithmetic shift: rounds toward −∞), as the robomorphic RTL
    /// does (it keeps bits [47:16] of a 64-bit product). Error in [0, 1 ulp).
    Truncate,
    /// Add half an ulp, then shift: round to nearest, ties toward +∞. Error ≤ ½ ulp, for
    /// one adder per multiplier.
    HalfUp,
}

impl Rounding {
    pub const ALL: [Rounding; 2] = [Rounding::Truncate, Rounding::HalfUp];

    pub fn name(self) -> &'static str {
        match self {
            Rounding::Truncate => "truncate",
            Rounding::HalfUp => "half-up",
        }
    }

    pub fn parse(s: &str) -> Option<Rounding> {
        Rounding::ALL.into_iter().find(|r| r.name() == s)
    }
}

/// A signed two's-complement format: `width` bits, of which `frac` are after the binary
/// point. Values are `raw · 2^-frac` with `raw` in `[-2^(width-1), 2^(width-1) - 1]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
pub struct Format {
    pub width: u32,
    pub frac: u32,
    pub rounding: Rounding,
}

/// Widest format. Raw values are `i128` in the software model and products are formed
/// in 256 bits (`ethnum::I256`): 120 bits leave every sum of two raw values in `i128`, a
/// product (240 bits) and a reciprocal's dividend 2^(2·FRAC) in 256, and cover what the
/// error analyses prove for a 7-joint arm's whole gradient on chip (the iiwa's needs 118
/// bits) and a floating humanoid's `rnea_grad` (Atlas's, 100).
pub const MAX_WIDTH: u32 = 120;

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum FixedError {
    #[error("fixed-point format {width}.{frac}: need 2 <= WIDTH <= {MAX_WIDTH} and FRAC < WIDTH")]
    BadFormat { width: u32, frac: u32 },
    #[error("kernel `{kernel}` divides (or takes sin/cos of a computed value, as a coupled mimic joint with a multiplier or offset does); the fixed-point datapath supports +, −, × only. Verilog is emitted for rnea, rnea_grad and mass_matrix")]
    Unsupported { kernel: String },
    #[error(
        "format {width}.{frac} cannot hold kernel `{kernel}`: the analysis bounds a value by {needed:.4e}, above the largest representable {max:.4e}; \
         use more integer bits (a wider WIDTH or a smaller FRAC), tighter input bounds, or --fixed auto"
    )]
    Range { kernel: String, width: u32, frac: u32, needed: f64, max: f64 },
    #[error("no format of at most {MAX_WIDTH} bits meets --max-error {max_error:e} for kernel `{kernel}` (best bound {best:.3e} at {width}.{frac})")]
    Unreachable { kernel: String, max_error: f64, best: f64, width: u32, frac: u32 },
    #[error("--max-error must be a positive finite number, got {0}")]
    BadMaxError(f64),
}

impl Format {
    pub fn new(width: u32, frac: u32, rounding: Rounding) -> Result<Format, FixedError> {
        if !(2..=MAX_WIDTH).contains(&width) || frac >= width {
            return Err(FixedError::BadFormat { width, frac });
        }
        Ok(Format { width, frac, rounding })
    }

    /// Parses `WIDTH.FRAC`, e.g. `32.16`.
    pub fn parse(s: &str, rounding: Rounding) -> Option<Result<Format, FixedError>> {
        let (w, f) = s.split_once('.')?;
        Some(Format::new(w.parse().ok()?, f.parse().ok()?, rounding))
    }

    pub fn max_raw(&self) -> i128 {
        (1i128 << (self.width - 1)) - 1
    }

    pub fn min_raw(&self) -> i128 {
        -(1i128 << (self.width - 1))
    }

    /// One unit in the last place, 2^-frac.
    pub fn ulp(&self) -> f64 {
        (-(self.frac as f64)).exp2()
    }

    /// The largest representable value.
    pub fn max_value(&self) -> f64 {
        self.max_raw() as f64 * self.ulp()
    }

    /// The rounding error one multiplication can add.
    pub fn product_error(&self) -> f64 {
        match self.rounding {
            Rounding::Truncate => self.ulp(),
            Rounding::HalfUp => self.ulp() / 2.0,
        }
    }

    /// `x` rounded to the nearest representable value (ties away from zero), saturated;
    /// the flag says it saturated (or was not finite).
    pub fn quantize(&self, x: f64) -> (i128, bool) {
        let scaled = (x * self.ulp().recip()).round();
        if !scaled.is_finite() {
            return (if scaled > 0.0 { self.max_raw() } else { self.min_raw() }, true);
        }
        // `as` saturates at i128's range, far beyond any format's.
        self.saturate(scaled as i128)
    }

    pub fn to_f64(&self, raw: i128) -> f64 {
        raw as f64 * self.ulp()
    }

    /// Clamps a wide result into the format; the flag says it had to.
    pub fn saturate(&self, x: i128) -> (i128, bool) {
        if x > self.max_raw() {
            (self.max_raw(), true)
        } else if x < self.min_raw() {
            (self.min_raw(), true)
        } else {
            (x, false)
        }
    }

    /// [`Format::saturate`] of a product's 256 bits.
    pub fn saturate_wide(&self, x: ethnum::I256) -> (i128, bool) {
        if x > ethnum::I256::from(self.max_raw()) {
            (self.max_raw(), true)
        } else if x < ethnum::I256::from(self.min_raw()) {
            (self.min_raw(), true)
        } else {
            (x.as_i128(), false)
        }
    }

    /// `WIDTH.FRAC`.
    pub fn label(&self) -> String {
        format!("{}.{}", self.width, self.frac)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_to_nearest_and_saturates() {
        let f = Format::new(8, 4, Rounding::Truncate).unwrap();
        assert_eq!(f.quantize(1.0), (16, false));
        assert_eq!(f.quantize(0.03125), (1, false)); // half an ulp rounds away from zero
        assert_eq!(f.quantize(-0.03125), (-1, false));
        assert_eq!(f.quantize(7.9375), (127, false));
        assert_eq!(f.quantize(8.0), (127, true));
        assert_eq!(f.quantize(-8.0), (-128, false));
        assert_eq!(f.quantize(-9.0), (-128, true));
        assert!(f.quantize(f64::NAN).1);
    }

    #[test]
    fn formats_are_checked() {
        assert!(Format::new(64, 63, Rounding::HalfUp).is_ok());
        assert!(Format::new(120, 40, Rounding::HalfUp).is_ok());
        assert!(Format::new(121, 16, Rounding::HalfUp).is_err());
        assert!(Format::new(16, 16, Rounding::HalfUp).is_err());
        assert!(Format::new(1, 0, Rounding::HalfUp).is_err());
        assert_eq!(
            Format::parse("32.16", Rounding::HalfUp),
            Some(Ok(Format { width: 32, frac: 16, rounding: Rounding::HalfUp }))
        );
        assert_eq!(Format::parse("32", Rounding::HalfUp), None);
        let f = Format::new(64, 10, Rounding::Truncate).unwrap();
        assert_eq!((f.max_raw(), f.min_raw()), (i64::MAX as i128, i64::MIN as i128));
    }
}
