//! The `thread` strategy: one invocation per state, straight-line code. Each kernel is
//! split into helper functions of at most `chunk` operations (the IR's [`Chunks`]),
//! because naga's WGSL front end (and so wgpu's `create_shader_module`) is quadratic in
//! the expressions of one function: 10k `let`s parse in about 1 s, the same as ten
//! functions of 1k in 0.16 s (measured, see DESIGN.md). Values that cross helpers go
//! through the per-state scratch storage buffer rather than a large per-invocation array,
//! which lavapipe compiles very slowly.

use std::fmt::Write;

use super::{expression, leaf, output_stores, EntryStats, Strategy, WgslOptions};
use crate::back::BackError;
use crate::ir::schedule::Chunks;
use crate::ir::{Function, Id};

pub(super) fn emit(out: &mut String, f: &Function, nv: usize, options: &WgslOptions, robot: &str) -> Result<EntryStats, BackError> {
    let c = Chunks::new(f, options.chunk);
    let name = Strategy::Thread.entry(f.kind.name());
    let (stores, inline, outputs) = output_stores(f, nv);
    let operand = |here: u32, id: Id| -> Result<String, BackError> {
        Ok(match leaf(f, id, options.precision, robot)? {
            Some(s) => s,
            None if c.chunk_of[id.0 as usize] == Some(here) => format!("t{}", id.0),
            None => format!("scratch[{}u * n + s]", c.slot[id.0 as usize].expect("values read by a later chunk have a slot")),
        })
    };
    let mut statements = 0;
    let _ = writeln!(out, "// {} One invocation per state.", f.kind.doc());
    for (ci, ids) in c.chunks.iter().enumerate() {
        let _ = writeln!(out, "fn {name}_part{ci}(s: u32, n: u32) {{");
        if ci == 0 {
            for (k, id) in &inline {
                let _ = writeln!(out, "    out[{k}u * n + s] = {};", operand(0, *id)?);
                statements += 1;
            }
        }
        for &id in ids {
            let e = expression(f, id, options.trig, |x| operand(ci as u32, x))?;
            let _ = writeln!(out, "    let t{} = {e};", id.0);
            statements += 1;
            if let Some(slot) = c.slot[id.0 as usize] {
                let _ = writeln!(out, "    scratch[{slot}u * n + s] = t{};", id.0);
                statements += 1;
            }
            for k in &stores[id.0 as usize] {
                let _ = writeln!(out, "    out[{k}u * n + s] = t{};", id.0);
                statements += 1;
            }
        }
        let _ = writeln!(out, "}}\n");
    }
    let _ = writeln!(out, "@compute @workgroup_size({})", options.workgroup_size);
    let _ = writeln!(out, "fn {name}(@builtin(global_invocation_id) gid: vec3<u32>) {{");
    let _ = writeln!(out, "    let n = params.n;\n    let s = gid.x;\n    if (s >= n) {{\n        return;\n    }}");
    for ci in 0..c.chunks.len() {
        let _ = writeln!(out, "    {name}_part{ci}(s, n);");
    }
    let _ = writeln!(out, "}}\n");
    Ok(EntryStats {
        entry: name,
        kernel: f.kind.name(),
        strategy: Strategy::Thread,
        outputs,
        scratch: c.slots,
        workgroup_size: options.workgroup_size,
        states_per_workgroup: options.workgroup_size,
        workgroup_bytes: 0,
        phases: 1,
        statements,
        functions: c.chunks.len() + 1,
    })
}
