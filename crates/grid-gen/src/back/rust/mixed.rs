//! Mixed-precision Rust: each kernel as one non-generic function whose
//! every value is f32 or f64 as a [`crate::numerics::precision::Plan`] says, taking and
//! returning f64. It computes what [`Function::eval_mixed`] computes, bit for bit: a node
//! runs in its own precision on operands converted to it, and a constant or input is
//! rounded to its node's precision first.

use std::fmt::Write;

use super::{literal, output_stores, output_type, return_value, RustOptions};
use crate::ir::schedule::Chunks;
use crate::ir::{Function, Id, Op};

/// One kernel's mixed function: `pub fn NAME(q: &[f64; NV], ...) -> outputs` (f64), with
/// its `_part` functions where the kernel is split. `wide[i]`: node i is f64. The caller
/// provides `NV` in scope.
pub fn emit_mixed_kernel(
    out: &mut String,
    k: &Function,
    q_len: &str,
    options: &RustOptions,
    wide: &[bool],
) {
    let names = Chunks::new(k, options.chunk);
    let ty = |id: Id| if wide[id.0 as usize] { "f64" } else { "f32" };
    // A constant or input as written: the f64 the model or the caller holds.
    let raw = |id: Id| match k.op(id) {
        Op::Const(c) => Some(format!("{}f64", literal(c))),
        Op::Input(which, j) => Some(format!("{}[{j}]", which.name())),
        _ => None,
    };
    // The node's value as an f64 expression (exact: an f32 value widens exactly).
    let as_f64 = |here: usize, id: Id| -> String {
        let i = id.0 as usize;
        match raw(id) {
            Some(r) if wide[i] => r,
            Some(r) => format!("(({r} as f32) as f64)"),
            None if names.chunk_of[i] == Some(here as u32) => {
                if wide[i] {
                    format!("t{i}")
                } else {
                    format!("(t{i} as f64)")
                }
            }
            None => {
                format!("s[{}]", names.slot[i].expect("values read by a later chunk have a slot"))
            }
        }
    };
    // The operand as a consumer of precision `to_wide` reads it.
    let operand = |here: usize, id: Id, to_wide: bool| -> String {
        let i = id.0 as usize;
        if names.chunk_of[i] == Some(here as u32) && wide[i] == to_wide {
            return format!("t{i}");
        }
        match raw(id) {
            // Rounded to f32 once, whatever the node's own precision.
            Some(r) if !to_wide => format!("({r} as f32)"),
            _ if to_wide => as_f64(here, id),
            _ => format!("({} as f32)", as_f64(here, id)),
        }
    };
    let expression = |here: usize, id: Id| -> String {
        let w = wide[id.0 as usize];
        let o = |x: Id| operand(here, x, w);
        match k.op(id) {
            Op::Add(a, b) => format!("{} + {}", o(a), o(b)),
            Op::Sub(a, b) => format!("{} - {}", o(a), o(b)),
            Op::Mul(a, b) => format!("{} * {}", o(a), o(b)),
            Op::Div(a, b) => format!("{} / {}", o(a), o(b)),
            Op::Neg(a) => format!("-{}", o(a)),
            Op::Sin(a) => format!("{}.sin()", o(a)),
            Op::Cos(a) => format!("{}.cos()", o(a)),
            Op::Sqrt(a) => format!("{}.sqrt()", o(a)),
            Op::Const(_) | Op::Input(..) => unreachable!("printed inline"),
        }
    };
    let name = k.kind.name();
    let args: Vec<String> = k
        .inputs()
        .iter()
        .map(|i| format!("{}: &[f64; {}]", i.name(), super::input_len(*i, q_len)))
        .collect();
    let arg_names: Vec<&str> = k.inputs().iter().map(|i| i.name()).collect();
    let types: Vec<String> =
        k.outputs.iter().map(|o| output_type(o.shape).replace('T', "f64")).collect();
    let ret_type =
        if types.len() == 1 { types[0].clone() } else { format!("({})", types.join(", ")) };
    let ret_value = return_value(k);
    let (inline_outputs, sinks) = output_stores(k);
    let body = |c: usize, ids: &[Id]| -> String {
        let mut b = String::new();
        if c == 0 {
            for (place, id) in &inline_outputs {
                let _ = writeln!(b, "{place} = {};", as_f64(0, *id));
            }
        }
        for &id in ids {
            let i = id.0 as usize;
            let _ = writeln!(b, "let t{i}: {} = {};", ty(id), expression(c, id));
            let widened = if wide[i] { format!("t{i}") } else { format!("t{i} as f64") };
            if let Some(s) = names.slot[i] {
                let _ = writeln!(b, "s[{s}] = {widened};");
            }
            for place in sinks.get(&id).into_iter().flatten() {
                let _ = writeln!(b, "{place} = {widened};");
            }
        }
        b
    };
    let _ = writeln!(out, "/// {} Mixed precision.", k.doc());
    let _ = writeln!(
        out,
        "#[allow(clippy::all, unused_variables, unused_mut, unused_parens, dead_code)]"
    );
    let _ = writeln!(out, "pub fn {name}({}) -> {ret_type} {{", args.join(", "));
    for o in &k.outputs {
        let init = super::array_of(o.shape, "0.0f64");
        let _ = writeln!(out, "let mut {} = {init};", o.name);
    }
    let chunks = &names.chunks;
    if chunks.len() == 1 {
        out.push_str(&body(0, &chunks[0]));
    } else {
        let _ = writeln!(out, "let mut s = [0.0f64; {}];", names.slots);
        let outs: Vec<String> = k.outputs.iter().map(|o| format!("&mut {}", o.name)).collect();
        for c in 0..chunks.len() {
            let _ = writeln!(
                out,
                "{name}_part{c}({}, &mut s, {});",
                arg_names.join(", "),
                outs.join(", ")
            );
        }
    }
    let _ = writeln!(out, "{ret_value}\n}}\n");
    if chunks.len() > 1 {
        let outs: Vec<String> =
            k.outputs.iter().zip(&types).map(|(o, t)| format!("{}: &mut {t}", o.name)).collect();
        for (c, ids) in chunks.iter().enumerate() {
            let _ = writeln!(out, "#[inline(never)]\n#[allow(clippy::all, unused_variables, unused_mut, unused_parens)]");
            let _ = writeln!(
                out,
                "fn {name}_part{c}({}, s: &mut [f64; {}], {}) {{",
                args.join(", "),
                names.slots,
                outs.join(", ")
            );
            out.push_str(&body(c, ids));
            out.push_str("}\n\n");
        }
    }
}
