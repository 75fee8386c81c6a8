//! The two arithmetic cells every netlist instantiates, specialised to its format: a
//! saturating multiplier that drops FRAC bits with the chosen rounding, and a saturating
//! adder/subtractor. Their semantics are the software model's (`datapath::model`)
//! exactly; the simulation tests compare the two bit for bit.

use std::fmt::Write;

use crate::datapath::{Format, Rounding};

/// A `W'sh…` literal of a raw value (two's complement bits, so the most negative value
/// needs no special case).
pub fn literal(raw: i128, width: u32) -> String {
    let mask = if width == 128 { u128::MAX } else { (1u128 << width) - 1 };
    format!("{width}'sh{:x}", raw as u128 & mask)
}

/// Clock stages of a pipelined divider in a `width`-bit format: its `width - 1` restoring
/// steps, `3 * stage_depth` per stage. A step is a subtraction and a select, about an
/// adder, so a stage of them weighs what `stage_depth` multipliers do (a multiplier
/// weighs three adders: `pipelined::Stages::slowest_path`).
pub fn divider_stages(width: u32, stage_depth: u32) -> u32 {
    width.saturating_sub(1).div_ceil(3 * stage_depth).max(1)
}

/// Data registers (of WIDTH bits, about) inside `dividers` dividers of `stages` stages:
/// the remainder, the divisor and the partial quotient at each inner boundary.
pub fn divider_registers(dividers: usize, stages: u32) -> usize {
    dividers * 3 * (stages as usize).saturating_sub(1)
}

/// How a netlist divides (`<top>_recip`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Divider {
    /// No reciprocal.
    None,
    /// One combinational divider: no netlist uses it; it is the reference the pipelined
    /// one is simulated against.
    Combinational,
    /// A divider pipelined over this many clock stages (every netlist that divides).
    Pipelined(u32),
}

/// The cell modules `<top>_mul` and `<top>_add`, and `<top>_recip` as `divider` says.
pub fn cells(top: &str, f: &Format, divider: Divider) -> String {
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
        recip = match divider {
            Divider::None => String::new(),
            Divider::Combinational => recip_cell(top, f),
            Divider::Pipelined(stages) => pipelined_recip(top, f, stages),
        },
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

/// `<top>_recip` over `stages` clock stages: the combinational cell's quotient and flag,
/// by restoring division. Where the quotient fits (below 2^(WIDTH-1)), its bits above
/// WIDTH-2 are zero, so the remainder entering bit WIDTH-2 is the dividend's bits above it,
/// the constant `r0 = 2^(2 FRAC) >> (WIDTH-1)`: WIDTH-1 steps of one subtraction and one
/// select then give the quotient, split evenly over the stages with the remainder, the
/// divisor, the quotient's bits so far and the flag registered between them. Where it does
/// not fit (divisor ≤ r0, or not positive), the flag is set from the input alone and the
/// steps' bits are not used. The latency is `stages - 1` clocks inside the cell; its output
/// is combinational from the last stage's registers, like every other cell's.
fn pipelined_recip(top: &str, f: &Format, stages: u32) -> String {
    let w = f.width;
    let steps = w - 1;
    // Step k computes quotient bit j = WIDTH-2-k, shifting in the dividend's bit j.
    let r0: u128 = if 2 * f.frac >= steps { 1u128 << (2 * f.frac - steps) } else { 0 };
    let max = literal(f.max_raw(), w);
    let head = format!(
        "// y = 1 / a in {label}: 2^{two_frac} / a rounded toward zero, saturated, by restoring division over {stages} clock stages; a <= 0 gives the largest value and sets ovf.
module {top}_recip (
    input  wire clk,
    input  wire signed [{wm}:0] a,
    output wire signed [{wm}:0] y,
    output wire ovf
);
    wire [{w}:0] d_0 = {{2'b00, a[{wm2}:0]}};
    // The quotient overflows where the divisor is at most r0 (or not positive).
    wire [{w}:0] r_init = {w1}'h{r0:x};
    wire big_0 = a[{wm}] || (a == {zero}) || (d_0 <= r_init);
",
        label = f.label(),
        two_frac = 2 * f.frac,
        wm = w - 1,
        wm2 = w - 2,
        w1 = w + 1,
        zero = literal(0, w),
    );
    let mut v = String::new();
    let mut regs = String::new();
    let mut clocked = String::new();
    // The remainder before the next step, and the quotient bits so far (most significant
    // first), as expressions.
    let mut r_prev = "r_init".to_string();
    let mut q_bits: Vec<String> = Vec::new();
    for g in 0..stages {
        let (from, to) = (g * steps / stages, (g + 1) * steps / stages);
        let _ = writeln!(
            v,
            "    // stage {g}: quotient bits {} down to {}",
            steps - 1 - from,
            steps - to
        );
        for k in from..to {
            let j = steps - 1 - k;
            let bit = u32::from(j == 2 * f.frac);
            let _ = writeln!(
                v,
                "    wire [{w}:0] t_{k} = {{{r_prev}[{rm}:0], 1'b{bit}}};\n    wire g_{k} = t_{k} >= d_{g};\n    wire [{w}:0] r_{k} = g_{k} ? t_{k} - d_{g} : t_{k};",
                rm = w - 1,
            );
            r_prev = format!("r_{k}");
            q_bits.push(format!("g_{k}"));
        }
        if g + 1 < stages {
            let n = g + 1;
            // The quotient's bits so far.
            let qw = to;
            let _ = writeln!(
                regs,
                "    reg [{w}:0] r_s{n}, d_{n};\n    reg [{qm}:0] q_s{n};\n    reg big_{n};",
                qm = qw - 1
            );
            let _ = writeln!(
                clocked,
                "        r_s{n} <= {r_prev};\n        d_{n} <= d_{g};\n        q_s{n} <= {{{}}};\n        big_{n} <= big_{g};",
                q_bits.join(", ")
            );
            r_prev = format!("r_s{n}");
            q_bits = vec![format!("q_s{n}")];
        }
    }
    // Registers are declared before the stages that read them.
    let mut v = format!("{head}{regs}{v}");
    if !clocked.is_empty() {
        let _ = writeln!(v, "    always @(posedge clk) begin\n{clocked}    end");
    }
    let last = stages - 1;
    let _ = writeln!(
        v,
        "    assign ovf = big_{last};\n    assign y = ovf ? {max} : {{1'b0, {}}};\nendmodule\n",
        q_bits.join(", ")
    );
    v
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
