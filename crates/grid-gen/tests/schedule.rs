//! The IR's target-neutral schedulers on real kernels: every operation placed exactly once,
//! after its operands, values crossing chunks or phases given slots that are never
//! overwritten while still to be read, and the slot budget honoured.

use grid_gen::ir::schedule::{Chunks, Phases, ScheduleError};
use grid_gen::ir::{self, Function, Id, LowerOptions};
use grid_gen_test_support::*;

fn functions(robot: &str) -> Vec<Function> {
    let model = load(robot);
    ir::lower(&model, grid_gen::reference::DEFAULT_GRAVITY, &LowerOptions::default())
        .unwrap()
        .functions
}

#[test]
fn chunks_cover_every_operation_once_with_safe_slots() {
    for robot in ["grid_iiwa", "grid_hyq"] {
        for f in functions(robot) {
            let c = Chunks::new(&f, 300);
            let mut seen = vec![0; f.nodes.len()];
            for (ci, ids) in c.chunks.iter().enumerate() {
                assert!(ids.len() <= 300);
                for id in ids {
                    seen[id.0 as usize] += 1;
                    assert_eq!(c.chunk_of[id.0 as usize], Some(ci as u32));
                }
            }
            // A slot holds one value from its write to its last read.
            let mut holder: Vec<Option<Id>> = vec![None; c.slots];
            for (ci, ids) in c.chunks.iter().enumerate() {
                for id in ids {
                    for o in f.op(*id).operands() {
                        if let Some(d) = c.chunk_of[o.0 as usize] {
                            assert!(d as usize <= ci, "operand computed before use");
                            if (d as usize) < ci {
                                let s = c.slot[o.0 as usize].expect("crossing value has a slot");
                                assert_eq!(
                                    holder[s as usize],
                                    Some(o),
                                    "{robot} {}: slot {s} overwritten before its last read",
                                    f.kind
                                );
                            }
                        }
                    }
                }
                for id in ids {
                    if let Some(s) = c.slot[id.0 as usize] {
                        holder[s as usize] = Some(*id);
                    }
                }
            }
            for (i, n) in seen.iter().enumerate() {
                assert_eq!(
                    *n,
                    usize::from(f.is_operation(Id(i as u32))),
                    "{robot} {}: node {i}",
                    f.kind
                );
            }
        }
    }
}

/// Checks a phase schedule: placement, order, and that each shared slot, between a
/// value's write and its last read, is written by no other value.
fn check(f: &Function, p: &Phases, budget: usize) {
    assert!(p.slots <= budget);
    let mut seen = vec![0; f.nodes.len()];
    let mut holder: Vec<Option<Id>> = vec![None; p.slots];
    let mut pos = vec![usize::MAX; f.nodes.len()];
    for list in p.phases.iter().flatten() {
        for (k, id) in list.iter().enumerate() {
            pos[id.0 as usize] = k;
        }
    }
    for (pi, phase) in p.phases.iter().enumerate() {
        assert_eq!(phase.len(), p.workers);
        for (w, list) in phase.iter().enumerate() {
            for (k, id) in list.iter().enumerate() {
                seen[id.0 as usize] += 1;
                for o in f.op(*id).operands() {
                    let Some(po) = p.place[o.0 as usize] else { continue };
                    if po.phase as usize == pi {
                        assert_eq!(po.worker as usize, w, "same-phase operand on another worker");
                        assert!(
                            pos[o.0 as usize] < k,
                            "same-phase operand computed earlier in the list"
                        );
                    } else {
                        assert!((po.phase as usize) < pi, "operand from a later phase");
                        let s =
                            p.slot[o.0 as usize].expect("value read in a later phase has a slot");
                        assert_eq!(
                            holder[s as usize],
                            Some(o),
                            "{}: slot {s} overwritten before its last read",
                            f.kind
                        );
                    }
                }
            }
        }
        for id in phase.iter().flatten() {
            if let Some(s) = p.slot[id.0 as usize] {
                holder[s as usize] = Some(*id);
            }
        }
    }
    for (i, n) in seen.iter().enumerate() {
        assert_eq!(
            *n,
            usize::from(f.is_operation(Id(i as u32))),
            "{}: node {i} placed once",
            f.kind
        );
    }
}

#[test]
fn phases_place_every_operation_once_after_its_operands() {
    for robot in ["grid_iiwa", "grid_hyq", "double_pendulum_continuous"] {
        for f in functions(robot) {
            for workers in [1, 7, 64] {
                let p = Phases::new(&f, workers, usize::MAX).unwrap();
                check(&f, &p, usize::MAX);
                let ops = (0..f.nodes.len()).filter(|&i| f.is_operation(Id(i as u32))).count();
                assert!(p.span() >= ops.div_ceil(workers), "no schedule beats perfect balance");
                if workers == 1 {
                    // (A fixed robot's `dintegrate` is constants: no operation, no phase.)
                    assert_eq!(p.phases.len(), usize::from(ops > 0), "one worker needs no barrier");
                } else if ops > 1 {
                    assert!(
                        p.span() < ops,
                        "{robot} {}: {workers} workers shorten the schedule ({} of {ops})",
                        f.kind,
                        p.span()
                    );
                }
            }
        }
    }
}

#[test]
fn phases_respect_the_slot_budget() {
    let f =
        functions("grid_iiwa").into_iter().find(|f| f.kind == ir::KernelKind::RneaGrad).unwrap();
    let free = Phases::new(&f, 32, usize::MAX).unwrap();
    assert!(free.slots > 10);
    check(&f, &free, free.slots);
    let err = Phases::new(&f, 32, free.slots - 1).unwrap_err();
    assert_eq!(
        err,
        ScheduleError::OverBudget {
            kernel: "rnea_grad",
            needed: free.slots,
            budget: free.slots - 1
        }
    );
    assert_eq!(Phases::new(&f, 0, 10).unwrap_err(), ScheduleError::NoWorkers);
}

#[test]
fn lowering_over_the_node_limit_is_an_error_not_an_abort() {
    let model = load("grid_atlas");
    let options = LowerOptions { max_nodes: 5_000, ..LowerOptions::default() };
    let err =
        ir::lower(&model, grid_gen::reference::DEFAULT_GRAVITY, &options).unwrap_err().to_string();
    assert!(err.contains("needs more than 5000 IR nodes"), "{err}");
}
