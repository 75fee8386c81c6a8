//! The pipelined architecture: every datapath node its own operator, pipeline registers
//! after every `stage_depth` levels of dependence depth, one state accepted per clock.
//! A value computed in stage t and read in stage s > t travels through registers
//! `p<t>_n<id>` … `p<s-1>_n<id>`; inputs are registered on entry (stage 0) and outputs
//! leave from the last stage's registers. The overflow flag travels with the data.
//! A reciprocal is a divider pipelined over [`Stages::divider_stages`] stages of its own
//! (`cells::pipelined_recip`): it reads its operand's register and its consumers read its
//! result's, so no stage holds a divider in series with other cells.

use std::fmt::Write;

use super::cells::{divider_registers, divider_stages, literal};
use super::Netlist;
use crate::datapath::{Datapath, HwId, HwOp};

/// Which stage computes each node, and the last stage that needs its value.
#[derive(Clone, Debug, PartialEq)]
pub struct Stages {
    /// Levels of dependence depth per stage.
    pub stage_depth: u32,
    /// Stages one reciprocal spans ([`super::cells::divider_stages`]).
    pub divider_stages: u32,
    /// The most restoring steps in one of them (the format's WIDTH - 1 split evenly).
    pub divider_steps: u32,
    /// 0 for ports and constants; a reciprocal's last stage.
    pub stage: Vec<u32>,
    /// Stages after the input registers (at least 1).
    pub count: u32,
    /// For ports and operations: one past the last stage whose registers hold the value
    /// (the value is registered at the end of stages `stage..last`).
    pub last: Vec<u32>,
}

impl Stages {
    /// Stages for `dp` in a format `width` bits wide (which sets the divider's steps).
    pub fn new(dp: &Datapath, stage_depth: u32, width: u32) -> Stages {
        let divider_stages = divider_stages(width, stage_depth);
        // Levels of dependence depth, a reciprocal's ending its last stage.
        let mut level = vec![0u32; dp.nodes.len()];
        let mut stage = vec![0u32; dp.nodes.len()];
        for (i, op) in dp.nodes.iter().enumerate() {
            match op {
                HwOp::Port(_) | HwOp::Const(_) => {}
                HwOp::Recip(a) => {
                    stage[i] = stage[a.0 as usize] + divider_stages;
                    level[i] = stage[i] * stage_depth;
                }
                _ => {
                    level[i] = 1 + op.operands().map(|a| level[a.0 as usize]).max().unwrap_or(0);
                    stage[i] = level[i].div_ceil(stage_depth);
                }
            }
        }
        let count = stage.iter().copied().max().unwrap_or(0).max(1);
        let mut last = stage.clone();
        for (i, op) in dp.nodes.iter().enumerate() {
            for a in op.operands() {
                let a = a.0 as usize;
                let read = Self::read_stage(op, stage[i], stage[a]);
                if read > stage[a] {
                    last[a] = last[a].max(read);
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
        let divider_steps = width.saturating_sub(1).div_ceil(divider_stages);
        Stages { stage_depth, divider_stages, divider_steps, stage, count, last }
    }

    /// The stage in which `op`, computed in stage `at`, reads an operand computed in stage
    /// `from`: a reciprocal reads its operand's register in its first stage.
    fn read_stage(op: &HwOp, at: u32, from: u32) -> u32 {
        match op {
            HwOp::Recip(_) => from + 1,
            _ => at,
        }
    }

    /// Data registers: one per value per stage boundary it crosses, and a divider's
    /// remainder, divisor and partial quotient at each of its inner boundaries.
    pub fn registers(&self, dp: &Datapath) -> usize {
        let values: usize =
            self.stage.iter().zip(&self.last).map(|(s, l)| l.saturating_sub(*s) as usize).sum();
        values + divider_registers(dp.reciprocals(), self.divider_stages)
    }

    /// The cells along the slowest chain of operations between two register boundaries, in
    /// dependence order (`"recip"`, `"mul"`, `"add"`; `add` also subtracts and negates):
    /// what sets the clock, for a timing tool to place alone (`scripts/fpga.py`). Which
    /// chain is slowest is judged by a multiplier weighing three adders and a divider's
    /// stage as many adders as it has restoring steps: on ECP5, nextpnr-ecp5 put one 49-bit
    /// multiplier between registers at 18.8 ns, one adder at 5.4 ns and four adders in
    /// series at 21.1 ns; at 78 bits, four multipliers in series at 153 ns and a divider of
    /// 11 steps a stage at 114 ns. A divider is alone between its stages' registers, so `"recip"`
    /// stands for the whole pipelined divider, whose slowest stage is its first.
    pub fn slowest_path(&self, dp: &Datapath) -> Vec<&'static str> {
        let cell = |op: &HwOp| match op {
            HwOp::Recip(_) => "recip",
            HwOp::Mul(..) => "mul",
            _ => "add",
        };
        let weight = |op: &HwOp| match op {
            // Its slowest stage's restoring steps, an adder each.
            HwOp::Recip(_) => u64::from(self.divider_steps),
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
        // At equal weight a chain of operations goes first: four 78-bit multipliers placed
        // slower than a divider's stage of twelve steps' weight.
        let Some(end) = (0..dp.nodes.len()).max_by_key(|&i| {
            (best[i], !matches!(dp.nodes[i], HwOp::Recip(_)), std::cmp::Reverse(i))
        }) else {
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
                HwOp::Recip(a) => {
                    let from = st.stage[a.0 as usize];
                    ("recip", operand(n, st, a, from + 1), String::new(), None)
                }
                HwOp::Port(_) | HwOp::Const(_) => unreachable!("operations only"),
            };
            let sub = match (op, sub) {
                (HwOp::Recip(_), _) => ", .clk(clk)".to_string(),
                (_, Some(s)) => format!(", .sub({s})"),
                (_, None) => String::new(),
            };
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
        assert_eq!(Stages::new(&dp, 4, 25).slowest_path(&dp), ["mul", "add", "mul", "add"]);
        // Two levels per stage: the chain is cut by a register after the first add.
        assert_eq!(Stages::new(&dp, 2, 25).slowest_path(&dp), ["mul", "add"]);
        assert_eq!(Stages::new(&dp, 1, 25).slowest_path(&dp), ["mul"]);
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
        assert_eq!(Stages::new(&dp, 4, 25).slowest_path(&dp), ["add", "add", "add", "add"]);
        // Two levels: the lone product outweighs two adders in series.
        assert_eq!(Stages::new(&dp, 2, 25).slowest_path(&dp), ["mul"]);
    }

    #[test]
    fn a_divider_has_stages_of_its_own() {
        use HwOp::*;
        let dp = datapath(vec![
            Mul(HwId(0), HwId(1)),
            Mul(HwId(2), HwId(1)),
            Mul(HwId(3), HwId(1)),
            Add(HwId(0), HwId(1)),
            Recip(HwId(5)),
            Add(HwId(4), HwId(6)),
        ]);
        // 24 restoring steps (a 25-bit format), 12 per stage at four levels: two stages,
        // after its operand's; the sum reading it starts the next.
        let st = Stages::new(&dp, 4, 25);
        assert_eq!((st.divider_stages, st.divider_steps), (2, 12));
        assert_eq!(st.stage, [0, 0, 1, 1, 1, 1, 3, 4]);
        // The divisor is registered once (read in stage 2); the quotient once.
        assert_eq!((st.last[5], st.last[6]), (2, 4));
        // Values: the two ports once; node 4 at the ends of stages 1 to 3; nodes 5, 6 and 7
        // (the output) once; the divider's remainder, divisor and quotient once.
        assert_eq!(st.registers(&dp), 1 + 1 + 3 + 1 + 1 + 1 + 3);
        // The divider's stage (12 steps) outweighs three products (nine adders).
        assert_eq!(st.slowest_path(&dp), ["recip"]);
        // One level per stage: three steps each, eight stages; a product weighs as much and
        // goes first.
        let st = Stages::new(&dp, 1, 25);
        assert_eq!((st.divider_stages, st.stage[6], st.count), (8, 9, 10));
        assert_eq!(st.slowest_path(&dp), ["mul"]);
    }

    #[test]
    fn at_equal_weight_the_path_is_the_operations() {
        use HwOp::*;
        // A divider of three steps a stage (a 10-bit format at one level) before a product.
        let dp = datapath(vec![Recip(HwId(0)), Mul(HwId(0), HwId(1)), Add(HwId(2), HwId(3))]);
        let st = Stages::new(&dp, 1, 10);
        assert_eq!((st.divider_stages, st.divider_steps), (3, 3));
        assert_eq!(st.slowest_path(&dp), ["mul"]);
    }
}
