//! The shared architecture's schedule: a cycle-by-cycle list schedule of the datapath on
//! M multipliers and A adders, and one divider where the datapath has reciprocals (every
//! operation one cycle but a reciprocal, which the pipelined divider returns
//! `divider_stages` cycles after it takes its operand; results registered), priority
//! to the longest path to an output, then register allocation by live interval so that
//! a register is reused once its value's last reader has run.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::datapath::{Datapath, HwOp};

/// Which unit runs an operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Unit {
    Mul(usize),
    Add(usize),
    /// The divider (reciprocals).
    Div(usize),
}

/// Where and when every operation runs, and where every value lives.
#[derive(Clone, Debug, PartialEq)]
pub struct SharedSchedule {
    /// The units it was scheduled on.
    pub multipliers: usize,
    pub adders: usize,
    /// 1 where the datapath has reciprocals, else 0.
    pub dividers: usize,
    /// Cycles from a reciprocal's operand to its result's register: the divider's stages
    /// at one multiplier's delay each ([`super::cells::divider_stages`] at depth 1), as
    /// the clock is one multiplication behind the operand multiplexers.
    pub divider_stages: u32,
    /// Cycles of computation per state (the load cycle excluded).
    pub cycles: usize,
    /// (cycle, unit) of each operation, the cycle it takes its operands; `None` for ports
    /// and constants. Its result is written at the end of that cycle, or of
    /// [`SharedSchedule::done`]'s for a reciprocal.
    pub slot: Vec<Option<(usize, Unit)>>,
    /// Register of each port and operation; `None` for constants.
    pub reg: Vec<Option<usize>>,
    /// Data registers of the register file (the divider's own are inside its cell).
    pub registers: usize,
}

impl SharedSchedule {
    /// The schedule of `dp` in a `width`-bit format (which sets the divider's stages).
    pub fn new(dp: &Datapath, multipliers: usize, adders: usize, width: u32) -> SharedSchedule {
        let n = dp.nodes.len();
        let divider_stages = super::cells::divider_stages(width, 1);
        let latency = |i: usize| latency(&dp.nodes[i], divider_stages);
        let mut users: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut waiting = vec![0usize; n];
        for (i, op) in dp.nodes.iter().enumerate() {
            for a in op.operands() {
                if dp.op(a).is_operation() {
                    users[a.0 as usize].push(i);
                    waiting[i] += 1;
                }
            }
        }
        // Longest path (in cycles) from each node to the end.
        let mut height = vec![0usize; n];
        for i in (0..n).rev() {
            if dp.nodes[i].is_operation() {
                height[i] = latency(i) + users[i].iter().map(|&u| height[u]).max().unwrap_or(0);
            }
        }
        let mut ready: [BinaryHeap<(usize, Reverse<usize>)>; 3] =
            [BinaryHeap::new(), BinaryHeap::new(), BinaryHeap::new()];
        let kind = |i: usize| match dp.nodes[i] {
            HwOp::Mul(..) => 0,
            HwOp::Recip(_) => 2,
            _ => 1,
        };
        let dividers = usize::from(dp.reciprocals() > 0);
        for i in 0..n {
            if dp.nodes[i].is_operation() && waiting[i] == 0 {
                ready[kind(i)].push((height[i], Reverse(i)));
            }
        }
        let mut slot = vec![None; n];
        // The first cycle each operation's operands are all in registers, and the
        // operations whose operands are scheduled but not yet all written.
        let mut earliest = vec![0usize; n];
        let mut pending: Vec<usize> = Vec::new();
        let mut left = dp.nodes.iter().filter(|o| o.is_operation()).count();
        let mut cycle = 0;
        let units = [multipliers, adders, dividers];
        while left > 0 {
            pending.retain(|&s| {
                let now = earliest[s] <= cycle;
                if now {
                    ready[kind(s)].push((height[s], Reverse(s)));
                }
                !now
            });
            for (k, heap) in ready.iter_mut().enumerate() {
                for u in 0..units[k] {
                    let Some((_, Reverse(i))) = heap.pop() else { break };
                    let unit = [Unit::Mul, Unit::Add, Unit::Div][k](u);
                    slot[i] = Some((cycle, unit));
                    left -= 1;
                    for &s in &users[i] {
                        earliest[s] = earliest[s].max(cycle + latency(i));
                        waiting[s] -= 1;
                        if waiting[s] == 0 {
                            pending.push(s);
                        }
                    }
                }
            }
            cycle += 1;
        }
        // The cycle after the last result is written.
        let cycles =
            (0..n).filter_map(|i| slot[i].map(|(c, _)| c + latency(i))).max().unwrap_or(0).max(1);

        // Live intervals: defined at the end of its cycle (ports: on the load edge, -1),
        // last read in the cycle of its last user; outputs are held to the end.
        let mut last_use: Vec<isize> = vec![-1; n];
        for (i, op) in dp.nodes.iter().enumerate() {
            if let Some((c, _)) = slot[i] {
                for a in op.operands() {
                    last_use[a.0 as usize] = last_use[a.0 as usize].max(c as isize);
                }
            }
        }
        for (_, _, id) in dp.nonzero_outputs() {
            last_use[id.0 as usize] = cycles as isize;
        }
        let def = |i: usize| -> isize {
            match (dp.nodes[i], slot[i]) {
                (HwOp::Port(_), _) => -1,
                (_, Some((c, _))) => (c + latency(i) - 1) as isize,
                _ => unreachable!("constants are not allocated"),
            }
        };
        let mut order: Vec<usize> =
            (0..n).filter(|&i| !matches!(dp.nodes[i], HwOp::Const(_))).collect();
        order.sort_by_key(|&i| (def(i), i));
        let mut free: BinaryHeap<Reverse<(isize, usize)>> = BinaryHeap::new();
        let mut reg = vec![None; n];
        let mut registers = 0;
        for i in order {
            let d = def(i);
            let r = match free.peek() {
                Some(&Reverse((from, r))) if from <= d => {
                    free.pop();
                    r
                }
                _ => {
                    registers += 1;
                    registers - 1
                }
            };
            reg[i] = Some(r);
            // A value nobody reads (a port only sin/cos would have used) frees at once.
            free.push(Reverse((last_use[i].max(d), r)));
        }
        SharedSchedule {
            multipliers,
            adders,
            dividers,
            divider_stages,
            cycles,
            slot,
            reg,
            registers,
        }
    }

    /// The cycle at whose end operation `i` (scheduled) writes its result.
    pub fn done(&self, dp: &Datapath, i: usize) -> Option<usize> {
        let (c, _) = self.slot[i]?;
        Some(c + latency(&dp.nodes[i], self.divider_stages) - 1)
    }
}

/// Cycles from an operation's operands to its result's register.
fn latency(op: &HwOp, divider_stages: u32) -> usize {
    match op {
        HwOp::Recip(_) => divider_stages as usize,
        _ => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::datapath::HwId;

    /// A small graph: (p0 * p1) + (p0 * 3), then negated.
    fn graph() -> Datapath {
        use HwOp::*;
        let nodes = vec![
            Port(0),
            Port(1),
            Const(3.0),
            Mul(HwId(0), HwId(1)),
            Mul(HwId(0), HwId(2)),
            Add(HwId(3), HwId(4)),
            Neg(HwId(5)),
        ];
        Datapath::for_test(nodes, HwId(6))
    }

    #[test]
    fn one_multiplier_serialises_the_products() {
        let s = SharedSchedule::new(&graph(), 1, 1, 16);
        assert_eq!(s.cycles, 4);
        let c = |i: usize| s.slot[i].unwrap().0;
        assert_ne!(c(3), c(4));
        assert!(c(5) > c(3).max(c(4)) && c(6) > c(5));
    }

    #[test]
    fn registers_are_reused_after_the_last_read() {
        let s = SharedSchedule::new(&graph(), 2, 1, 16);
        assert_eq!(s.cycles, 3);
        // Ports (2 registers) die in cycle 0 when both products read them, so the
        // products reuse them; the sum and the negation reuse again.
        assert_eq!(s.registers, 2);
        assert!(s.reg[2].is_none());
    }

    #[test]
    fn a_reciprocals_readers_wait_for_the_divider() {
        use HwOp::*;
        let nodes = vec![
            Port(0),
            Port(1),
            Add(HwId(0), HwId(1)),
            Recip(HwId(2)),
            Mul(HwId(3), HwId(1)),
            Mul(HwId(0), HwId(1)),
            Add(HwId(4), HwId(5)),
        ];
        let dp = Datapath::for_test(nodes, HwId(6));
        // 15 restoring steps at three per stage.
        let s = SharedSchedule::new(&dp, 1, 1, 16);
        assert_eq!(s.divider_stages, 5);
        let c = |i: usize| s.slot[i].unwrap().0;
        assert_eq!((c(2), c(3)), (0, 1));
        // Written at the end of cycle 5, read from cycle 6; the other product fills cycle 0.
        assert_eq!(s.done(&dp, 3), Some(5));
        assert_eq!((c(4), c(5), c(6)), (6, 0, 7));
        assert_eq!(s.cycles, 8);
    }
}
