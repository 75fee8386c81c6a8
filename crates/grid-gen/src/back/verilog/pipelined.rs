//! The pipelined architecture: every datapath node its own operator, pipeline registers
//! after every `stage_depth` levels of dependence depth, one state accepted per clock.
//! A value computed in stage t and read in stage s > t travels through registers
//! `p<t>_n<id>` … `p<s-1>_n<id>`; inputs are registered on entry (stage 0) and outputs
//! leave from the last stage's registers. The overflow flag travels with the data.

use std::fmt::Write;

use super::cells::literal;
use super::Netlist;
use crate::datapath::{Datapath, HwId, HwOp};

/// Which stage computes each node, and the last stage that needs its value.
#[derive(Clone, Debug, PartialEq)]
pub struct Stages {
    /// Levels of dependence depth per stage.
    pub stage_depth: u32,
    /// 0 for ports and constants.
    pub stage: Vec<u32>,
    /// Stages after the input registers (at least 1).
    pub count: u32,
    /// For ports and operations: one past the last stage whose registers hold the value
    /// (the value is registered at the end of stages `stage..last`).
    pub last: Vec<u32>,
}

impl Stages {
    pub fn new(dp: &Datapath, stage_depth: u32) -> Stages {
        let stage: Vec<u32> = dp.depths().iter().map(|d| d.div_ceil(stage_depth)).collect();
        let count = stage.iter().copied().max().unwrap_or(0).max(1);
        let mut last = stage.clone();
        for (i, op) in dp.nodes.iter().enumerate() {
            for a in op.operands() {
                let a = a.0 as usize;
                if stage[i] > stage[a] {
                    last[a] = last[a].max(stage[i]);
                }
            }
        }
        for (_, _, id) in dp.nonzero_outputs() {
            last[id.0 as usize] = count + 1;
        }
        for (i, op) in dp.nodes.iter().enumerate() {
            if matches!(op, HwOp::Const(_)) {
                last[i] = stage[i];
            }
        }
        Stages { stage_depth, stage, count, last }
    }

    /// Data registers: one per value per stage boundary it crosses.
    pub fn registers(&self) -> usize {
        self.stage.iter().zip(&self.last).map(|(s, l)| l.saturating_sub(*s) as usize).sum()
    }

    /// The cells along the slowest chain of operations between two register boundaries, in
    /// dependence order (`"recip"`, `"mul"`, `"add"`; `add` also subtracts and negates):
    /// what sets the clock, for a timing tool to place alone (`scripts/fpga.py`). Which
    /// chain is slowest is judged by a multiplier weighing three adders and a divider more
    /// than any chain without one: on ECP5, nextpnr-ecp5 put one 49-bit multiplier between
    /// registers at 18.8 ns, one adder at 5.4 ns and four adders in series at 21.1 ns.
    pub fn slowest_path(&self, dp: &Datapath) -> Vec<&'static str> {
        let cell = |op: &HwOp| match op {
            HwOp::Recip(_) => "recip",
            HwOp::Mul(..) => "mul",
            _ => "add",
        };
        // A stage holds at most `stage_depth` operations on one chain, so a divider weighing
        // 3 * stage_depth + 1 outweighs every chain without one.
        let weight = |op: &HwOp| match op {
            HwOp::Recip(_) => 3 * u64::from(self.stage_depth) + 1,
            HwOp::Mul(..) => 3,
            _ => 1,
        };
        // Per operation: the slowest chain ending at it within its stage, and the operand
        // it continues.
        let mut best = vec![0u64; dp.nodes.len()];
        let mut from: Vec<Option<usize>> = vec![None; dp.nodes.len()];
        for (i, op) in dp.nodes.iter().enumerate() {
            if !op.is_operation() {
                continue;
            }
            let mut before = 0;
            for a in op.operands() {
                let a = a.0 as usize;
                if self.stage[a] == self.stage[i] && dp.nodes[a].is_operation() && best[a] > before
                {
                    before = best[a];
                    from[i] = Some(a);
                }
            }
            best[i] = before + weight(op);
        }
        let Some(end) = (0..dp.nodes.len()).max_by_key(|&i| (best[i], std::cmp::Reverse(i))) else {
            return Vec::new();
        };
        if best[end] == 0 {
            return Vec::new();
        }
        let mut path = vec![cell(&dp.nodes[end])];
        let mut at = end;
        while let Some(a) = from[at] {
            path.push(cell(&dp.nodes[a]));
            at = a;
        }
        path.reverse();
        path
    }
}

/// How a node is read in stage `s`.
fn operand(n: &Netlist, st: &Stages, x: HwId, s: u32) -> String {
    let i = x.0 as usize;
    match n.datapath.op(x) {
        HwOp::Const(c) => literal(n.format.quantize(c).0, n.format.width),
        _ if st.stage[i] == s => format!("n{i}"),
        _ => format!("p{}_n{i}", s - 1),
    }
}

/// The top module.
pub fn top(n: &Netlist, st: &Stages) -> String {
    let dp = &n.datapath;
    let w = n.format.width;
    let s_max = st.count;
    let mut v = String::new();
    v.push_str(&n.module_ports());
    let _ = writeln!(v, "    assign in_ready = 1'b1;");
    let _ = writeln!(v, "    reg [{s_max}:0] valid;");
    let _ = writeln!(
        v,
        "    always @(posedge clk) valid <= rst ? {}'d0 : {{valid[{}:0], in_valid}};",
        s_max + 1,
        s_max - 1
    );
    let _ = writeln!(v, "    wire ovf0 = 1'b0;");

    // Registers, declared once; filled in one clocked block per stage below.
    let mut regs = String::new();
    for (i, (&s, &l)) in st.stage.iter().zip(&st.last).enumerate() {
        for t in s..l {
            let _ = writeln!(regs, "    reg signed [{}:0] p{t}_n{i};", w - 1);
        }
    }
    v.push_str(&regs);

    let register_from = |v: &mut String, t: u32| {
        // Registers at the end of stage t.
        let _ = writeln!(v, "    always @(posedge clk) begin");
        for (i, (&s, &l)) in st.stage.iter().zip(&st.last).enumerate() {
            if t < s || t >= l {
                continue;
            }
            let src = match (t == s, dp.nodes[i]) {
                (true, HwOp::Port(p)) => n.names.inputs[p as usize].clone(),
                (true, _) => format!("n{i}"),
                (false, _) => format!("p{}_n{i}", t - 1),
            };
            let _ = writeln!(v, "        p{t}_n{i} <= {src};");
        }
        let _ = writeln!(v, "    end");
    };
    let _ = writeln!(v, "\n    // stage 0: input registers");
    register_from(&mut v, 0);

    for s in 1..=s_max {
        let _ = writeln!(v, "\n    // stage {s}");
        let mut flags = Vec::new();
        for (i, op) in dp.nodes.iter().enumerate() {
            if st.stage[i] != s || !op.is_operation() {
                continue;
            }
            let _ = writeln!(v, "    wire signed [{}:0] n{i};\n    wire o{i};", w - 1);
            let (cell, a, b, sub) = match *op {
                HwOp::Add(a, b) => {
                    ("add", operand(n, st, a, s), operand(n, st, b, s), Some("1'b0"))
                }
                HwOp::Sub(a, b) => {
                    ("add", operand(n, st, a, s), operand(n, st, b, s), Some("1'b1"))
                }
                HwOp::Neg(a) => ("add", literal(0, w), operand(n, st, a, s), Some("1'b1")),
                HwOp::Mul(a, b) => ("mul", operand(n, st, a, s), operand(n, st, b, s), None),
                HwOp::Recip(a) => ("recip", operand(n, st, a, s), String::new(), None),
                HwOp::Port(_) | HwOp::Const(_) => unreachable!("operations only"),
            };
            let sub = sub.map_or(String::new(), |s| format!(", .sub({s})"));
            let b = if b.is_empty() { b } else { format!(", .b({b})") };
            let _ =
                writeln!(v, "    {}_{cell} u{i} (.a({a}){b}{sub}, .y(n{i}), .ovf(o{i}));", n.top);
            flags.push(format!("o{i}"));
        }
        let _ = writeln!(v, "    reg ovf{s};");
        let any = if flags.is_empty() {
            "1'b0".to_string()
        } else {
            format!("(|{{{}}})", flags.join(", "))
        };
        let _ = writeln!(v, "    always @(posedge clk) ovf{s} <= ovf{} | {any};", s - 1);
        register_from(&mut v, s);
    }

    let _ =
        writeln!(v, "\n    assign out_valid = valid[{s_max}];\n    assign overflow = ovf{s_max};");
    for (name, id) in &n.names.outputs {
        let src = match dp.op(*id) {
            HwOp::Const(c) => literal(n.format.quantize(c).0, w),
            _ => format!("p{s_max}_n{}", id.0),
        };
        let _ = writeln!(v, "    assign {name} = {src};");
    }
    let _ = writeln!(v, "endmodule");
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A datapath of two ports and `ops` (node 2 on), whose last node is the output.
    fn datapath(ops: Vec<HwOp>) -> Datapath {
        let mut nodes = vec![HwOp::Port(0), HwOp::Port(1)];
        nodes.extend(ops);
        let last = HwId(nodes.len() as u32 - 1);
        Datapath::for_test(nodes, last)
    }

    #[test]
    fn the_slowest_path_stays_within_a_stage() {
        use HwOp::*;
        // mul, add, mul, negate in a chain, and an adder beside it.
        let dp = datapath(vec![
            Mul(HwId(0), HwId(1)),
            Add(HwId(2), HwId(0)),
            Add(HwId(0), HwId(1)),
            Mul(HwId(3), HwId(4)),
            Neg(HwId(5)),
        ]);
        assert_eq!(Stages::new(&dp, 4).slowest_path(&dp), ["mul", "add", "mul", "add"]);
        // Two levels per stage: the chain is cut by a register after the first add.
        assert_eq!(Stages::new(&dp, 2).slowest_path(&dp), ["mul", "add"]);
        assert_eq!(Stages::new(&dp, 1).slowest_path(&dp), ["mul"]);
    }

    #[test]
    fn four_adders_outweigh_one_multiplier() {
        use HwOp::*;
        // A lone product beside four additions in series.
        let dp = datapath(vec![
            Mul(HwId(0), HwId(1)),
            Add(HwId(0), HwId(1)),
            Add(HwId(3), HwId(1)),
            Add(HwId(4), HwId(1)),
            Sub(HwId(5), HwId(2)),
        ]);
        assert_eq!(Stages::new(&dp, 4).slowest_path(&dp), ["add", "add", "add", "add"]);
        // Two levels: the lone product outweighs two adders in series.
        assert_eq!(Stages::new(&dp, 2).slowest_path(&dp), ["mul"]);
    }

    #[test]
    fn a_divider_outweighs_a_chain_of_multipliers() {
        use HwOp::*;
        let dp = datapath(vec![
            Mul(HwId(0), HwId(1)),
            Mul(HwId(2), HwId(1)),
            Mul(HwId(3), HwId(1)),
            Add(HwId(0), HwId(1)),
            Recip(HwId(5)),
            Add(HwId(4), HwId(6)),
        ]);
        // Stage one holds the three products and add-then-divide; the final add is level 4.
        assert_eq!(Stages::new(&dp, 4).slowest_path(&dp), ["add", "recip", "add"]);
        // Three levels: the final add is cut off, and the divider still outweighs the three
        // products; one level: the divider alone.
        assert_eq!(Stages::new(&dp, 3).slowest_path(&dp), ["add", "recip"]);
        assert_eq!(Stages::new(&dp, 1).slowest_path(&dp), ["recip"]);
    }
}
