//! The WGSL backend, `thread` strategy: one compute invocation per state, straight-line
//! f32 code, every kernel an entry point over a batch of N states. Each kernel is split
//! into helper functions of at most `chunk` operations (the IR's [`Chunks`]), because
//! naga's WGSL front end (and so wgpu's `create_shader_module`) is quadratic in the
//! expressions of one function: 10k `let`s parse in about 1 s, the same as ten functions
//! of 1k in 0.16 s (measured, see DESIGN.md). Values that cross helpers go through a
//! per-state scratch storage buffer rather than a large per-invocation array, which
//! lavapipe compiles very slowly.

use std::fmt::Write;

use super::names::{comment_text, identifier};
use super::{BackError, GeneratedFile, Target};
use crate::ir::schedule::Chunks;
use crate::ir::{Function, Id, Input, Module, Op};

/// Options of the WGSL backend.
#[derive(Clone, Debug)]
pub struct WgslOptions {
    /// Most operations in one WGSL function.
    pub chunk: usize,
    /// Invocations per workgroup (WebGPU's default limit is 256).
    pub workgroup_size: u32,
}

impl Default for WgslOptions {
    fn default() -> Self {
        WgslOptions { chunk: 1000, workgroup_size: 64 }
    }
}

/// The buffer layout, described once for the file header and the README.
pub const LAYOUT_DOC: &str = "\
Every entry point shares one bind group (group 0), so one pipeline layout serves all:
  binding 0  uniform  Params { n: u32 }            number of states N in the batch
  binding 1  storage, read        q:   array<f32>  q[j * N + s] is joint j of state s
  binding 2  storage, read        qd:  array<f32>  same layout (unused by mass_matrix, minv)
  binding 3  storage, read        u:   array<f32>  qdd (rnea, rnea_grad) or tau (fd, fd_grad)
  binding 4  storage, read_write  out: array<f32>  out[k * N + s]: value k of state s, the
             kernel's outputs concatenated in order, matrices row-major ([i][j] = d out_i / d in_j)
  binding 5  storage, read_write  scratch: array<f32>  scratch[k * N + s], <KERNEL>_SCRATCH values
             per state (at least one word: bind a 4-byte buffer when it is 0)
Structure-of-arrays, so neighbouring invocations touch neighbouring words. Dispatch
ceil(N / WORKGROUP_SIZE) workgroups in x; an invocation past N does nothing. Every output
value is written, structural zeros included. Arithmetic is f32; sin and cos are WGSL's
built-ins, whose accuracy the WebGPU spec leaves to the implementation (absolute error
2^-11 on [-pi, pi] is allowed).";

/// WGSL's f32 literal for a constant, or an error if f32 cannot hold it.
fn literal(c: f64, robot: &str) -> Result<String, BackError> {
    let x = c as f32;
    if !x.is_finite() {
        return Err(BackError::WgslRange { robot: robot.to_string(), value: c });
    }
    // `{:?}` prints the shortest text that reads back as the same f32.
    let s = format!("{x:?}");
    Ok(if x < 0.0 { format!("({s}f)") } else { format!("{s}f") })
}

fn input_buffer(input: Input) -> &'static str {
    match input {
        Input::Q => "q",
        Input::Qd => "qd",
        Input::Qdd | Input::Tau => "u",
    }
}

fn operand(f: &Function, c: &Chunks, here: u32, id: Id, robot: &str) -> Result<String, BackError> {
    Ok(match f.op(id) {
        Op::Const(k) => literal(k, robot)?,
        Op::Input(which, j) => format!("{}[{j}u * n + s]", input_buffer(which)),
        _ if c.chunk_of[id.0 as usize] == Some(here) => format!("t{}", id.0),
        _ => format!("scratch[{}u * n + s]", c.slot[id.0 as usize].expect("values read by a later chunk have a slot")),
    })
}

fn emit_function(out: &mut String, f: &Function, nv: usize, options: &WgslOptions, robot: &str) -> Result<(), BackError> {
    let c = Chunks::new(f, options.chunk);
    let name = f.kind.name();
    // Output index of every value: stores after the node that computes it.
    let mut stores: Vec<Vec<usize>> = vec![Vec::new(); f.nodes.len()];
    let mut inline = Vec::new();
    let mut base = 0;
    for o in &f.outputs {
        for (k, &id) in o.ids.iter().enumerate() {
            if f.is_operation(id) {
                stores[id.0 as usize].push(base + k);
            } else {
                inline.push((base + k, id));
            }
        }
        base += o.shape.len(nv);
    }
    let _ = writeln!(out, "// {}\nconst {}_SCRATCH: u32 = {}u;\n", f.kind.doc(), name.to_uppercase(), c.slots);
    for (ci, ids) in c.chunks.iter().enumerate() {
        let _ = writeln!(out, "fn {name}_part{ci}(s: u32, n: u32) {{");
        if ci == 0 {
            for (k, id) in &inline {
                let _ = writeln!(out, "    out[{k}u * n + s] = {};", operand(f, &c, 0, *id, robot)?);
            }
        }
        for &id in ids {
            let o = |x: Id| operand(f, &c, ci as u32, x, robot);
            let e = match f.op(id) {
                Op::Add(a, b) => format!("{} + {}", o(a)?, o(b)?),
                Op::Sub(a, b) => format!("{} - {}", o(a)?, o(b)?),
                Op::Mul(a, b) => format!("{} * {}", o(a)?, o(b)?),
                Op::Div(a, b) => format!("{} / {}", o(a)?, o(b)?),
                Op::Neg(a) => format!("-({})", o(a)?),
                Op::Sin(a) => format!("sin({})", o(a)?),
                Op::Cos(a) => format!("cos({})", o(a)?),
                Op::Const(_) | Op::Input(..) => unreachable!("chunks hold operations only"),
            };
            let _ = writeln!(out, "    let t{} = {e};", id.0);
            if let Some(slot) = c.slot[id.0 as usize] {
                let _ = writeln!(out, "    scratch[{slot}u * n + s] = t{};", id.0);
            }
            for k in &stores[id.0 as usize] {
                let _ = writeln!(out, "    out[{k}u * n + s] = t{};", id.0);
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
    Ok(())
}

/// The WGSL file for `module`: `<stem>.wgsl`, every kernel an entry point.
pub fn emit(module: &Module, options: &WgslOptions) -> Result<GeneratedFile, BackError> {
    let robot = &module.robot;
    let nv = robot.nv();
    let stem = identifier(&robot.name);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "// @generated by grid-gen {} from the URDF of robot \"{}\" ({nv} joints). Do not edit:\n\
         // regenerate with `grid-gen ROBOT.urdf -o DIR --emit wgsl`.\n//",
        env!("CARGO_PKG_VERSION"),
        comment_text(&robot.name),
    );
    for line in LAYOUT_DOC.lines() {
        let _ = writeln!(out, "// {line}");
    }
    let _ = writeln!(out, "//\n// Joints (model order), gravity [{}, {}, {}] m/s^2 compiled in:", module.gravity[0], module.gravity[1], module.gravity[2]);
    for (j, name) in robot.joint_names.iter().enumerate() {
        let _ = writeln!(out, "//   {j:>3}  {}", comment_text(name));
    }
    let _ = writeln!(out, "//\n// Entry points and output values per state:");
    for f in &module.functions {
        let parts: Vec<String> = f.outputs.iter().map(|o| format!("{} ({})", o.name, o.shape.len(nv))).collect();
        let _ = writeln!(out, "//   {}: {}", f.kind.signature(), parts.join(", "));
    }
    let _ = writeln!(
        out,
        "\nstruct Params {{\n    n: u32,\n}}\n\n\
         const NV: u32 = {nv}u;\nconst WORKGROUP_SIZE: u32 = {}u;\n\n\
         @group(0) @binding(0) var<uniform> params: Params;\n\
         @group(0) @binding(1) var<storage, read> q: array<f32>;\n\
         @group(0) @binding(2) var<storage, read> qd: array<f32>;\n\
         @group(0) @binding(3) var<storage, read> u: array<f32>;\n\
         @group(0) @binding(4) var<storage, read_write> out: array<f32>;\n\
         @group(0) @binding(5) var<storage, read_write> scratch: array<f32>;\n",
        options.workgroup_size
    );
    for f in &module.functions {
        emit_function(&mut out, f, nv, options, &robot.name)?;
    }
    Ok(GeneratedFile { name: Target::Wgsl.file_name(&stem), contents: out })
}
