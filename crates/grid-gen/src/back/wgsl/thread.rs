//! The `thread` strategy: one invocation per state, straight-line code. Each kernel is
//! split into helper functions of at most `chunk` operations (the IR's [`Chunks`]),
//! because naga's WGSL front end (and so wgpu's `create_shader_module`) is quadratic in
//! the expressions of one function: 10k `let`s parse in about 1 s, the same as ten
//! functions of 1k in 0.16 s (measured, see DESIGN.md). Values that cross helpers go
//! through the per-state scratch storage buffer rather than a large per-invocation array,
//! which lavapipe compiles very slowly. The same scratch lets a kernel over
//! [`WgslOptions::stage`] operations run as several dispatches (stages) of consecutive
//! helpers, so a driver never compiles more than that in one pipeline.

use std::fmt::Write;

use super::WgslError;
use super::{block, output_stores, stages, EntryMeta, Strategy, WgslOptions};
use crate::ir::schedule::Chunks;
use crate::ir::{Function, Id};

pub(super) fn emit(
    out: &mut String,
    f: &Function,
    options: &WgslOptions,
    robot: &str,
) -> Result<EntryMeta, WgslError> {
    // A helper never spans two stages, so stages smaller than `chunk` shrink the helpers.
    let c = Chunks::new(
        f,
        if options.stage > 0 { options.chunk.min(options.stage) } else { options.chunk },
    );
    let name = Strategy::Thread.entry(f.kind.name());
    let (stores, inline, outputs) = output_stores(f);
    let mut statements = 0;
    let _ = writeln!(out, "// {} One invocation per state.", f.doc());
    for (ci, ids) in c.chunks.iter().enumerate() {
        let _ = writeln!(out, "fn {name}_part{ci}(s: u32, n: u32) {{");
        let here = |id: Id| c.chunk_of[id.0 as usize] == Some(ci as u32);
        let slot = |id: Id| c.slot[id.0 as usize].map(|k| format!("scratch[{k}u * n + s]"));
        let inline = if ci == 0 { &inline[..] } else { &[] };
        statements += block(out, f, options, robot, "    ", ids, inline, here, slot, &stores)?;
        let _ = writeln!(out, "}}\n");
    }
    let stages = stages(c.chunks.iter().map(Vec::len), options.stage);
    for (k, parts) in stages.iter().enumerate() {
        let entry = super::stage_entry(&name, k, stages.len());
        let _ = writeln!(out, "@compute @workgroup_size({})", options.workgroup_size);
        let _ = writeln!(out, "fn {entry}(@builtin(global_invocation_id) gid: vec3<u32>) {{");
        let _ = writeln!(out, "    let n = params.n;\n    let s = gid.x;\n    if (s >= n) {{\n        return;\n    }}");
        for ci in parts.clone() {
            let _ = writeln!(out, "    {name}_part{ci}(s, n);");
        }
        let _ = writeln!(out, "}}\n");
    }
    Ok(EntryMeta {
        entry: name,
        kernel: f.kind.name().to_string(),
        strategy: Strategy::Thread,
        outputs,
        scratch: c.slots,
        workgroup_size: options.workgroup_size,
        states_per_workgroup: options.workgroup_size,
        workgroup_bytes: 0,
        phases: 1,
        stages: stages.len(),
        statements,
        functions: c.chunks.len() + stages.len(),
    })
}
