//! The `cooperative` strategy (GRiD's scheme, on the IR's list scheduler [`Phases`]): one
//! workgroup per state; the kernel's operations are spread over the workgroup's
//! invocations in barrier-separated phases. A value read in a later phase lives in a
//! `var<workgroup>` slot while the slots fit WebGPU's default 16 KiB of workgroup storage
//! ([`WORKGROUP_STORAGE_LIMIT`]; naga and wgpu do not check it), and in the storage
//! scratch buffer past that (with a `storageBarrier` between phases). Each phase's
//! worker lists are grouped into helper functions of at most `chunk` operations (naga's
//! parser is quadratic in one function's size).

use std::fmt::Write;

use super::{expression, leaf, output_stores, EntryStats, Strategy, WgslOptions, WORKGROUP_STORAGE_LIMIT};
use crate::back::BackError;
use crate::ir::schedule::Phases;
use crate::ir::{Function, Id};

pub(super) fn emit(out: &mut String, f: &Function, nv: usize, options: &WgslOptions, robot: &str) -> Result<EntryStats, BackError> {
    let p = Phases::new(f, options.workers as usize, usize::MAX).map_err(|e| BackError::WgslOption(e.to_string()))?;
    let name = Strategy::Cooperative.entry(f.kind.name());
    let budget = WORKGROUP_STORAGE_LIMIT / options.precision.bytes();
    let in_workgroup = p.slots.min(budget);
    let spilled = p.slots - in_workgroup;
    let wg = format!("{name}_wg");
    let (stores, inline, outputs) = output_stores(f, nv);
    let slot_ref = |slot: u32| -> String {
        let slot = slot as usize;
        if slot < budget {
            format!("{wg}[{slot}u]")
        } else {
            format!("scratch[{}u * n + s]", slot - budget)
        }
    };
    let operand = |phase: u32, worker: u32, id: Id| -> Result<String, BackError> {
        Ok(match leaf(f, id, options.precision, robot)? {
            Some(s) => s,
            None => {
                let at = p.place[id.0 as usize].expect("every operation is placed");
                if at.phase == phase && at.worker == worker {
                    format!("t{}", id.0)
                } else {
                    slot_ref(p.slot[id.0 as usize].expect("values read in a later phase have a slot"))
                }
            }
        })
    };
    let _ = writeln!(out, "// {} One workgroup of {} invocations per state, {} phases.", f.kind.doc(), options.workers, p.phases.len());
    if in_workgroup > 0 {
        let _ = writeln!(out, "var<workgroup> {wg}: array<real, {in_workgroup}>;");
    }
    let mut statements = 0;
    let mut functions = 1;
    // calls[phase]: the helper functions of that phase.
    let mut calls: Vec<Vec<String>> = Vec::new();
    for (pi, lists) in p.phases.iter().enumerate() {
        // Group consecutive workers' lists into functions of at most `chunk` operations.
        let mut groups: Vec<Vec<usize>> = vec![Vec::new()];
        let mut size = 0;
        for (w, list) in lists.iter().enumerate() {
            if list.is_empty() && !(pi == 0 && w == 0 && !inline.is_empty()) {
                continue;
            }
            if size > 0 && size + list.len() > options.chunk {
                groups.push(Vec::new());
                size = 0;
            }
            size += list.len();
            if let Some(g) = groups.last_mut() {
                g.push(w);
            }
        }
        let mut names = Vec::new();
        for (gi, workers) in groups.iter().enumerate().filter(|(_, g)| !g.is_empty()) {
            let fname = format!("{name}_p{pi}_{gi}");
            let _ = writeln!(out, "fn {fname}(w: u32, s: u32, n: u32) {{\n    switch w {{");
            for &w in workers {
                let _ = writeln!(out, "        case {w}u: {{");
                if pi == 0 && w == 0 {
                    for (k, id) in &inline {
                        let _ = writeln!(out, "            out[{k}u * n + s] = {};", operand(0, 0, *id)?);
                        statements += 1;
                    }
                }
                for &id in &lists[w] {
                    let e = expression(f, id, options.trig, |x| operand(pi as u32, w as u32, x))?;
                    let _ = writeln!(out, "            let t{} = {e};", id.0);
                    statements += 1;
                    if let Some(slot) = p.slot[id.0 as usize] {
                        let _ = writeln!(out, "            {} = t{};", slot_ref(slot), id.0);
                        statements += 1;
                    }
                    for k in &stores[id.0 as usize] {
                        let _ = writeln!(out, "            out[{k}u * n + s] = t{};", id.0);
                        statements += 1;
                    }
                }
                let _ = writeln!(out, "        }}");
            }
            let _ = writeln!(out, "        default: {{}}\n    }}\n}}\n");
            functions += 1;
            names.push(fname);
        }
        calls.push(names);
    }
    let _ = writeln!(out, "@compute @workgroup_size({})", options.workers);
    let _ = writeln!(out, "fn {name}(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) w: u32) {{");
    // s and n are workgroup-uniform, so the early return keeps the barriers in uniform
    // control flow.
    let _ = writeln!(out, "    let n = params.n;\n    let s = wid.x;\n    if (s >= n) {{\n        return;\n    }}");
    let barrier = if spilled > 0 { "    workgroupBarrier();\n    storageBarrier();" } else { "    workgroupBarrier();" };
    for (pi, names) in calls.iter().enumerate() {
        if pi > 0 {
            let _ = writeln!(out, "{barrier}");
        }
        for fname in names {
            let _ = writeln!(out, "    {fname}(w, s, n);");
        }
    }
    let _ = writeln!(out, "}}\n");
    Ok(EntryStats {
        entry: name,
        kernel: f.kind.name(),
        strategy: Strategy::Cooperative,
        outputs,
        scratch: spilled,
        workgroup_size: options.workers,
        states_per_workgroup: 1,
        workgroup_bytes: in_workgroup * options.precision.bytes(),
        phases: p.phases.len(),
        statements,
        functions,
    })
}
