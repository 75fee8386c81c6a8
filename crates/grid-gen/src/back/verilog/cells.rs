//! The two arithmetic cells every netlist instantiates, specialised to its format: a
//! saturating multiplier that drops FRAC bits with the chosen rounding, and a saturating
//! adder/subtractor. Their semantics are the software model's (`datapath::model`)
//! exactly; the simulation tests compare the two bit for bit.

use crate::datapath::{Format, Rounding};

/// A `W'sh…` literal of a raw value (two's complement bits, so the most negative value
/// needs no special case).
pub fn literal(raw: i128, width: u32) -> String {
    let mask = if width == 128 { u128::MAX } else { (1u128 << width) - 1 };
    format!("{width}'sh{:x}", raw as u128 & mask)
}

/// The cell modules `<top>_mul` and `<top>_add`, and `<top>_recip` where `recip`.
pub fn cells(top: &str, f: &Format, recip: bool) -> String {
    let w = f.width;
    let w2 = 2 * w;
    let (max, min) = (literal(f.max_raw(), w), literal(f.min_raw(), w));
    let rounded = match (f.rounding, f.frac) {
        (_, 0) => "p".to_string(),
        (Rounding::Truncate, frac) => format!("p >>> {frac}"),
        (Rounding::HalfUp, frac) => format!("(p + ({w2}'sd1 <<< {})) >>> {frac}", frac - 1),
    };
    let how = match f.rounding {
        Rounding::Truncate => "drops the low FRAC bits (rounds toward -inf)",
        Rounding::HalfUp => {
            "adds half an ulp and drops the low FRAC bits (rounds to nearest, ties up)"
        }
    };
    format!(
        "// y = a * b in {label}: the {w2}-bit product {how}, then saturates.
module {top}_mul (
    input  wire signed [{wm}:0] a,
    input  wire signed [{wm}:0] b,
    output wire signed [{wm}:0] y,
    output wire ovf
);
    wire signed [{w2m}:0] p = a * b;
    wire signed [{w2m}:0] r = {rounded};
    // r fits in {w} bits when its top {top_bits} bits are all equal.
    assign ovf = !((&r[{w2m}:{wm}]) || !(|r[{w2m}:{wm}]));
    assign y = ovf ? (r[{w2m}] ? {min} : {max}) : r[{wm}:0];
endmodule

// y = a + b (sub = 0) or a - b (sub = 1), saturated.
module {top}_add (
    input  wire signed [{wm}:0] a,
    input  wire signed [{wm}:0] b,
    input  wire sub,
    output wire signed [{wm}:0] y,
    output wire ovf
);
    wire signed [{w}:0] s = sub ? a - b : a + b;
    assign ovf = s[{w}] != s[{wm}];
    assign y = ovf ? (s[{w}] ? {min} : {max}) : s[{wm}:0];
endmodule

{recip}",
        label = f.label(),
        wm = w - 1,
        w2m = w2 - 1,
        top_bits = w + 1,
        recip = if recip { recip_cell(top, f) } else { String::new() },
    )
}

/// `<top>_recip`: y = 1 / a as the quotient 2^(2 FRAC) / a, rounded toward zero (a
/// combinational divider; synthesis builds it from subtractors, one per quotient bit).
fn recip_cell(top: &str, f: &Format) -> String {
    let w = f.width;
    // The dividend 2^(2 FRAC) and every divisor fit in n bits.
    let n = (2 * f.frac + 2).max(w + 1);
    let max = literal(f.max_raw(), w);
    format!(
        "// y = 1 / a in {label}: 2^{two_frac} / a rounded toward zero, saturated; a <= 0 gives the largest value and sets ovf.
module {top}_recip (
    input  wire signed [{wm}:0] a,
    output wire signed [{wm}:0] y,
    output wire ovf
);
    wire [{nm}:0] one = {n}'d1 << {two_frac};
    wire [{nm}:0] d = {{{{{pad}{{1'b0}}}}, a}};
    wire bad = a[{wm}] || (a == {zero});
    wire [{nm}:0] q = bad ? {n}'d0 : one / d;
    // q fits when its bits from {wm} up are all zero (it is never negative).
    assign ovf = bad || (|q[{nm}:{wm}]);
    assign y = ovf ? {max} : q[{wm}:0];
endmodule

",
        label = f.label(),
        two_frac = 2 * f.frac,
        wm = w - 1,
        nm = n - 1,
        pad = n - w,
        zero = literal(0, w),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literals_are_twos_complement() {
        assert_eq!(literal(5, 16), "16'sh5");
        assert_eq!(literal(-1, 16), "16'shffff");
        assert_eq!(literal(i64::MIN as i128, 64), "64'sh8000000000000000");
        assert_eq!(literal(-1, 96), "96'shffffffffffffffffffffffff");
    }
}
