//! The shared architecture's top module: M multiplier and A adder cells whose operands a
//! cycle counter selects (one `case` per cycle), a register file written from the cells'
//! results, and a controller: idle → load the inputs on `in_valid` → run the schedule's
//! cycles → raise `out_valid` for one clock. The overflow flag is sticky over a state.

use std::fmt::Write;

use super::cells::literal;
use super::schedule::{SharedSchedule, Unit};
use super::Netlist;
use crate::datapath::{HwId, HwOp};

fn unit_name(u: Unit) -> String {
    match u {
        Unit::Mul(k) => format!("m{k}"),
        Unit::Add(k) => format!("a{k}"),
        Unit::Div(k) => format!("d{k}"),
    }
}

/// The top module.
pub fn top(n: &Netlist, s: &SharedSchedule) -> String {
    let dp = &n.datapath;
    let w = n.format.width;
    let (muls, adds) = (s.multipliers, s.adders);
    let counter_bits = usize::BITS - s.cycles.leading_zeros();
    let read = |x: HwId| -> String {
        match dp.op(x) {
            HwOp::Const(c) => literal(n.format.quantize(c).0, w),
            _ => format!("r{}", s.reg[x.0 as usize].expect("allocated")),
        }
    };
    let zero = literal(0, w);

    let mut v = String::new();
    v.push_str(&n.module_ports());
    let _ = writeln!(v, "    reg busy, done, ovf;\n    reg [{}:0] cyc;", counter_bits - 1);
    for r in 0..s.registers {
        let _ = writeln!(v, "    reg signed [{}:0] r{r};", w - 1);
    }
    let units: Vec<Unit> = (0..muls)
        .map(Unit::Mul)
        .chain((0..adds).map(Unit::Add))
        .chain((0..s.dividers).map(Unit::Div))
        .collect();
    for &u in &units {
        let m = unit_name(u);
        let _ = writeln!(v, "    reg signed [{wm}:0] {m}_a, {m}_b;\n    wire signed [{wm}:0] {m}_y;\n    wire {m}_o;", wm = w - 1);
        match u {
            Unit::Mul(_) => {
                let _ = writeln!(
                    v,
                    "    {}_mul u{m} (.a({m}_a), .b({m}_b), .y({m}_y), .ovf({m}_o));",
                    n.top
                );
            }
            Unit::Add(_) => {
                let _ = writeln!(v, "    reg {m}_s;\n    {}_add u{m} (.a({m}_a), .b({m}_b), .sub({m}_s), .y({m}_y), .ovf({m}_o));", n.top);
            }
            Unit::Div(_) => {
                let _ = writeln!(
                    v,
                    "    {}_recip u{m} (.clk(clk), .a({m}_a), .y({m}_y), .ovf({m}_o));",
                    n.top
                );
            }
        }
    }

    // Operations by the cycle they take their operands, and by the cycle they write.
    let mut by_cycle: Vec<Vec<(usize, Unit)>> = vec![Vec::new(); s.cycles];
    let mut writes: Vec<Vec<(usize, Unit)>> = vec![Vec::new(); s.cycles];
    for (i, slot) in s.slot.iter().enumerate() {
        if let Some((c, u)) = slot {
            by_cycle[*c].push((i, *u));
            writes[s.done(dp, i).expect("scheduled")].push((i, *u));
        }
    }

    let _ = writeln!(v, "\n    // Operand selection.\n    always @(*) begin");
    // An idle divider divides one by one (zero would raise the overflow flag).
    let one = literal(n.format.quantize(1.0).0, w);
    for &u in &units {
        let m = unit_name(u);
        let idle = if matches!(u, Unit::Div(_)) { &one } else { &zero };
        let _ = write!(v, "        {m}_a = {idle}; {m}_b = {zero};");
        if matches!(u, Unit::Add(_)) {
            let _ = write!(v, " {m}_s = 1'b0;");
        }
        v.push('\n');
    }
    let _ = writeln!(v, "        case (cyc)");
    for (c, ops) in by_cycle.iter().enumerate() {
        let _ = write!(v, "            {counter_bits}'d{c}: begin");
        for &(i, u) in ops {
            let m = unit_name(u);
            let (a, b, sub) = match dp.nodes[i] {
                HwOp::Add(a, b) => (read(a), read(b), Some(false)),
                HwOp::Sub(a, b) => (read(a), read(b), Some(true)),
                HwOp::Neg(a) => (zero.clone(), read(a), Some(true)),
                HwOp::Mul(a, b) => (read(a), read(b), None),
                // The divider has no second operand; its `_b` is driven and unread.
                HwOp::Recip(a) => (read(a), zero.clone(), None),
                HwOp::Port(_) | HwOp::Const(_) => unreachable!("operations only"),
            };
            let _ = write!(v, " {m}_a = {a}; {m}_b = {b};");
            if sub == Some(true) {
                let _ = write!(v, " {m}_s = 1'b1;");
            }
        }
        let _ = writeln!(v, " end");
    }
    let _ = writeln!(v, "            default: ;\n        endcase\n    end");

    let _ = writeln!(v, "\n    // Controller and register file.\n    always @(posedge clk) begin");
    let _ = writeln!(v, "        if (rst) begin\n            busy <= 1'b0; done <= 1'b0; ovf <= 1'b0; cyc <= {counter_bits}'d0;\n        end else begin");
    let _ = writeln!(v, "            done <= 1'b0;\n            if (!busy) begin\n                if (in_valid) begin");
    let _ = writeln!(v, "                    busy <= 1'b1; cyc <= {counter_bits}'d0; ovf <= 1'b0;");
    for (i, op) in dp.nodes.iter().enumerate() {
        if let HwOp::Port(p) = op {
            let _ = writeln!(
                v,
                "                    r{} <= {};",
                s.reg[i].expect("allocated"),
                n.names.inputs[*p as usize]
            );
        }
    }
    let _ = writeln!(v, "                end\n            end else begin");
    // Idle multipliers and adders see zeros, so their flags count every cycle; the
    // divider's pipeline holds other cycles' operands, so its flag counts only with the
    // result it belongs to.
    let flags: Vec<String> = units
        .iter()
        .filter(|u| !matches!(u, Unit::Div(_)))
        .map(|&u| format!("{}_o", unit_name(u)))
        .collect();
    let _ = writeln!(v, "                ovf <= ovf | {};", flags.join(" | "));
    let _ = writeln!(v, "                case (cyc)");
    for (c, ops) in writes.iter().enumerate() {
        let _ = write!(v, "                    {counter_bits}'d{c}: begin");
        for &(i, u) in ops {
            let m = unit_name(u);
            let _ = write!(v, " r{} <= {m}_y;", s.reg[i].expect("allocated"));
            if matches!(u, Unit::Div(_)) {
                let _ = write!(v, " if ({m}_o) ovf <= 1'b1;");
            }
        }
        let _ = writeln!(v, " end");
    }
    let _ = writeln!(v, "                    default: ;\n                endcase");
    let _ = writeln!(
        v,
        "                if (cyc == {counter_bits}'d{}) begin busy <= 1'b0; done <= 1'b1; end",
        s.cycles - 1
    );
    let _ =
        writeln!(v, "                cyc <= cyc + 1'b1;\n            end\n        end\n    end");

    let _ = writeln!(
        v,
        "\n    assign in_ready = !busy;\n    assign out_valid = done;\n    assign overflow = ovf;"
    );
    for (name, id) in &n.names.outputs {
        let _ = writeln!(v, "    assign {name} = {};", read(*id));
    }
    let _ = writeln!(v, "endmodule");
    v
}
