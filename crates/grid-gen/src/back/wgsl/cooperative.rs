//! The `cooperative` strategy (GRiD's scheme, on the IR's list scheduler [`Phases`]): one
//! workgroup per state; the kernel's operations are spread over the workgroup's
//! invocations in barrier-separated phases. A value read in a later phase lives in a
//! `var<workgroup>` slot while the slots fit WebGPU's default 16 KiB of workgroup storage
//! ([`WORKGROUP_STORAGE_LIMIT`]; naga and wgpu do not check it), and in the storage
//! scratch buffer past that (with a `storageBarrier` between phases). Each phase's
//! worker lists are grouped into helper functions of at most `chunk` operations (naga's
//! parser is quadratic in one function's size). A kernel over [`WgslOptions::coop_stage`]
//! operations runs as several dispatches (stages) of consecutive phases; a slot whose
//! value crosses a stage lives in the scratch buffer.

use std::fmt::Write;

use super::{block, output_stores, stages, EntryStats, Strategy, WgslOptions, WORKGROUP_STORAGE_LIMIT};
use crate::back::BackError;
use crate::ir::schedule::Phases;
use crate::ir::{Function, Id};

pub(super) fn emit(out: &mut String, f: &Function, nv: usize, options: &WgslOptions, robot: &str) -> Result<EntryStats, BackError> {
    let p = Phases::new(f, options.workers as usize, usize::MAX).map_err(|e| BackError::WgslOption(e.to_string()))?;
    let name = Strategy::Cooperative.entry(f.kind.name());
    let budget = WORKGROUP_STORAGE_LIMIT / options.precision.bytes();
    let stages = stages(p.phases.iter().map(|lists| lists.iter().map(Vec::len).sum()), options.coop_stage);
    let (home, in_workgroup, spilled) = slot_homes(f, &p, &stages, budget);
    let wg = format!("{name}_wg");
    let (stores, inline, outputs) = output_stores(f, nv);
    let slot_ref = |slot: u32| -> String {
        match home[slot as usize] {
            Home::Workgroup(k) => format!("{wg}[{k}u]"),
            Home::Scratch(k) => format!("scratch[{k}u * n + s]"),
        }
    };
    let _ = writeln!(out, "// {} One workgroup of {} invocations per state, {} phases.", f.doc(), options.workers, p.phases.len());
    if in_workgroup > 0 {
        let _ = writeln!(out, "var<workgroup> {wg}: array<real, {in_workgroup}>;");
    }
    let mut statements = 0;
    let mut functions = stages.len();
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
                let here = |id: Id| p.place[id.0 as usize].is_some_and(|at| at.phase == pi as u32 && at.worker == w as u32);
                let slot = |id: Id| p.slot[id.0 as usize].map(slot_ref);
                let inline = if pi == 0 && w == 0 { &inline[..] } else { &[] };
                statements += block(out, f, options, robot, "            ", &lists[w], inline, here, slot, &stores)?;
                let _ = writeln!(out, "        }}");
            }
            let _ = writeln!(out, "        default: {{}}\n    }}\n}}\n");
            functions += 1;
            names.push(fname);
        }
        calls.push(names);
    }
    let barrier = if spilled > 0 { "    workgroupBarrier();\n    storageBarrier();" } else { "    workgroupBarrier();" };
    for (k, phases) in stages.iter().enumerate() {
        let entry = super::stage_entry(&name, k, stages.len());
        let _ = writeln!(out, "@compute @workgroup_size({})", options.workers);
        let _ = writeln!(out, "fn {entry}(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) w: u32) {{");
        // s and n are workgroup-uniform, so the early return keeps the barriers in uniform
        // control flow.
        let _ = writeln!(out, "    let n = params.n;\n    let s = wid.x;\n    if (s >= n) {{\n        return;\n    }}");
        for pi in phases.clone() {
            if pi > phases.start {
                let _ = writeln!(out, "{barrier}");
            }
            for fname in &calls[pi] {
                let _ = writeln!(out, "    {fname}(w, s, n);");
            }
        }
        let _ = writeln!(out, "}}\n");
    }
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
        stages: stages.len(),
        statements,
        functions,
    })
}

/// Where a shared slot lives.
#[derive(Clone, Copy)]
enum Home {
    Workgroup(usize),
    Scratch(usize),
}

/// Each slot's home: workgroup memory, lowest slots first, up to `budget` words, unless
/// a value in it is read in a later stage than the one that writes it (workgroup memory
/// does not outlive a dispatch); the rest in the scratch buffer. Returns the homes and
/// the words of each kind.
fn slot_homes(f: &Function, p: &Phases, stages: &[std::ops::Range<usize>], budget: usize) -> (Vec<Home>, usize, usize) {
    let mut stage_of_phase = vec![0; p.phases.len()];
    for (k, r) in stages.iter().enumerate() {
        for pi in r.clone() {
            stage_of_phase[pi] = k;
        }
    }
    let mut crosses = vec![false; p.slots];
    for (i, node) in f.nodes.iter().enumerate() {
        let Some(at) = p.place[i] else { continue };
        for o in node.op.operands() {
            if let (Some(from), Some(slot)) = (p.place[o.0 as usize], p.slot[o.0 as usize]) {
                if stage_of_phase[from.phase as usize] != stage_of_phase[at.phase as usize] {
                    crosses[slot as usize] = true;
                }
            }
        }
    }
    let (mut workgroup, mut scratch) = (0, 0);
    let homes = crosses
        .iter()
        .map(|&crossing| {
            if !crossing && workgroup < budget {
                workgroup += 1;
                Home::Workgroup(workgroup - 1)
            } else {
                scratch += 1;
                Home::Scratch(scratch - 1)
            }
        })
        .collect();
    (homes, workgroup, scratch)
}
