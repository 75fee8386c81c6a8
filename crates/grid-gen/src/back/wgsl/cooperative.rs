//! The `cooperative` strategy (GRiD's scheme, on the IR's list scheduler [`Phases`]): one
//! workgroup per state; the kernel's operations are spread over the workgroup's
//! invocations in barrier-separated phases. The operations are not unrolled into WGSL:
//! they are a table (binding 6, `prog`) that a short interpreter loop in the entry point
//! walks, each invocation its own list per phase, with the constants in binding 7
//! (`konst`). Unrolled per-invocation code (a `switch` over 64 invocations per phase, as
//! this strategy was first built) took lavapipe's LLVM 4 to 12 ms per statement to compile
//! (coroutine frames across every barrier, each case run under masks): minutes per
//! gradient, hours for Atlas. The interpreter is the same few dozen statements for every
//! robot, so every pipeline compiles in well under a second, and neighbouring invocations
//! run the same loop rather than different `switch` cases.
//!
//! Every value lives in a slot from the phase that writes it to the last phase that reads
//! it (a slot is reused only after that phase, so no phase both reads and overwrites one):
//! `var<workgroup>` memory while the slots fit WebGPU's default 16 KiB of workgroup storage
//! ([`WORKGROUP_STORAGE_LIMIT`]; naga and wgpu do not check it), the storage scratch
//! buffer past that (with a `storageBarrier` between phases).

use std::collections::{BTreeSet, HashMap};
use std::fmt::Write;

use super::{output_stores, EntryStats, Precision, Strategy, Tables, Trig, WgslOptions, WORKGROUP_STORAGE_LIMIT};
use crate::back::BackError;
use crate::ir::schedule::Phases;
use crate::ir::{Function, Id, Input, Op};

/// Operation codes of the table (bits 24..32 of an instruction's first word).
const ADD: u32 = 0;
const SUB: u32 = 1;
const MUL: u32 = 2;
const DIV: u32 = 3;
const NEG: u32 = 4;
const SIN: u32 = 5;
const COS: u32 = 6;
const COPY: u32 = 7;

/// Address tags (bits 28..32 of an address; the index is the low 28 bits).
const WORKGROUP: u32 = 0;
const SCRATCH: u32 = 1;
const KONST: u32 = 2;
const Q: u32 = 3;
const QD: u32 = 4;
const U: u32 = 5;
const INDEX_BITS: u32 = 28;

/// Words per instruction: `op << 24 | destination slot`, then the two operand addresses.
/// A destination is a slot (below 2^24; its home is decided from the slot number) or,
/// for `COPY`, an output index.
const WORDS: usize = 3;

fn address(tag: u32, index: usize, robot: &str) -> Result<u32, BackError> {
    if index >= 1 << INDEX_BITS {
        return Err(BackError::WgslOption(format!("robot \"{robot}\": a cooperative table index {index} does not fit in {INDEX_BITS} bits")));
    }
    Ok(tag << INDEX_BITS | index as u32)
}

pub(super) fn emit(out: &mut String, f: &Function, nv: usize, options: &WgslOptions, robot: &str, tables: &mut Tables) -> Result<EntryStats, BackError> {
    let workers = options.workers as usize;
    let p = Phases::new(f, workers, usize::MAX).map_err(|e| BackError::WgslOption(e.to_string()))?;
    let name = Strategy::Cooperative.entry(f.kind.name());
    let (stores, inline, outputs) = output_stores(f, nv);
    // Phase 0 exists even for a kernel with no operations, for the inline stores.
    let phases = p.phases.len().max(1);

    // Each operation's slot: from its phase to the last phase that reads it.
    let mut last = vec![0usize; f.nodes.len()];
    for (i, node) in f.nodes.iter().enumerate() {
        if let Some(at) = p.place[i] {
            last[i] = last[i].max(at.phase as usize);
            for o in node.op.operands() {
                last[o.0 as usize] = last[o.0 as usize].max(at.phase as usize);
            }
        }
    }
    let mut by_phase: Vec<Vec<usize>> = vec![Vec::new(); phases];
    for (i, at) in p.place.iter().enumerate() {
        if let Some(at) = at {
            by_phase[at.phase as usize].push(i);
        }
    }
    let mut slot = vec![u32::MAX; f.nodes.len()];
    let mut free: BTreeSet<u32> = BTreeSet::new();
    // (last phase, slot) of the slots in use; the lowest free slot first keeps the most
    // used slots in workgroup memory.
    let mut busy: BTreeSet<(usize, u32)> = BTreeSet::new();
    let mut slots = 0u32;
    for (phase, ids) in by_phase.iter().enumerate() {
        while let Some(&(end, s)) = busy.first() {
            if end >= phase {
                break;
            }
            busy.pop_first();
            free.insert(s);
        }
        for &i in ids {
            let s = free.pop_first().unwrap_or_else(|| {
                slots += 1;
                slots - 1
            });
            slot[i] = s;
            busy.insert((last[i], s));
        }
    }
    let budget = (WORKGROUP_STORAGE_LIMIT / options.precision.bytes()) as u32;
    let in_workgroup = slots.min(budget) as usize;
    let spilled = slots.saturating_sub(budget) as usize;
    if slots >= 1 << 24 {
        return Err(BackError::WgslOption(format!("robot \"{robot}\": {} needs {slots} slots, more than the table's 2^24", f.kind.name())));
    }

    let operand = |id: Id, tables: &mut Tables| -> Result<u32, BackError> {
        match f.op(id) {
            Op::Const(c) => address(KONST, tables.konst.get(c, options.precision, robot)?, robot),
            Op::Input(which, j) => {
                let tag = match which {
                    Input::Q => Q,
                    Input::Qd => QD,
                    Input::Qdd | Input::Tau => U,
                };
                address(tag, j as usize, robot)
            }
            _ => match slot[id.0 as usize] as usize {
                k if k < in_workgroup => address(WORKGROUP, k, robot),
                k => address(SCRATCH, k - in_workgroup, robot),
            },
        }
    };
    // The instruction lists, phase by phase, worker by worker.
    let mut lists: Vec<Vec<Vec<[u32; WORDS]>>> = vec![vec![Vec::new(); workers]; phases];
    for (pi, phase) in p.phases.iter().enumerate() {
        for (w, ids) in phase.iter().enumerate() {
            for &id in ids {
                let (code, a, b) = match f.op(id) {
                    Op::Add(a, b) => (ADD, a, b),
                    Op::Sub(a, b) => (SUB, a, b),
                    Op::Mul(a, b) => (MUL, a, b),
                    Op::Div(a, b) => (DIV, a, b),
                    Op::Neg(a) => (NEG, a, a),
                    Op::Sin(a) => (SIN, a, a),
                    Op::Cos(a) => (COS, a, a),
                    Op::Const(_) | Op::Input(..) => unreachable!("schedules hold operations only"),
                };
                let (a, b) = (operand(a, tables)?, operand(b, tables)?);
                lists[pi][w].push([code << 24 | slot[id.0 as usize], a, b]);
                let me = operand(id, tables)?;
                for &k in &stores[id.0 as usize] {
                    lists[pi][w].push([COPY << 24 | k as u32, me, me]);
                }
            }
        }
    }
    // Outputs that are constants or inputs: spread over phase 0's workers.
    for (n, &(k, id)) in inline.iter().enumerate() {
        let a = operand(id, tables)?;
        lists[0][n % workers].push([COPY << 24 | k as u32, a, a]);
    }

    // The table: phases * workers + 1 start offsets (absolute word indices into `prog`),
    // then the instructions.
    let base = tables.prog.len();
    let mut at = base + phases * workers + 1;
    let mut starts = Vec::with_capacity(phases * workers + 1);
    for phase in &lists {
        for list in phase {
            starts.push(at as u32);
            at += list.len() * WORDS;
        }
    }
    starts.push(at as u32);
    if at > u32::MAX as usize {
        return Err(BackError::WgslOption(format!("robot \"{robot}\": the cooperative tables exceed 2^32 words")));
    }
    tables.prog.extend(starts);
    let mut instructions = 0;
    for phase in &lists {
        for list in phase {
            instructions += list.len();
            tables.prog.extend(list.iter().flatten());
        }
    }

    let wg = format!("{name}_wg");
    let (sin, cos) = match options.trig {
        Trig::Builtin => ("sin", "cos"),
        Trig::Accurate => ("gg_sin", "gg_cos"),
    };
    let zero = match options.precision {
        Precision::F32 => "0.0f",
        Precision::F64 => "0.0lf",
    };
    let _ = writeln!(
        out,
        "// {} One workgroup of {workers} invocations per state, {phases} phases; its {instructions} \
         operations are a table at prog[{base}..{at}] (phase p's list for invocation w starts at \
         prog[{base} + p * {workers} + w] and ends where the next begins; 3 words each).",
        f.doc()
    );
    let _ = writeln!(out, "var<workgroup> {wg}: array<real, {}>;\n", in_workgroup.max(1));
    // The operand read and result write, by the address's tag.
    let _ = writeln!(
        out,
        "fn {name}_read(a: u32, s: u32, n: u32) -> real {{\n    let i = a & {mask}u;\n    switch (a >> {INDEX_BITS}u) {{\n        \
         case {WORKGROUP}u: {{ return {wg}[i]; }}\n        case {SCRATCH}u: {{ return scratch[i * n + s]; }}\n        \
         case {KONST}u: {{ return konst[i]; }}\n        case {Q}u: {{ return q[i * n + s]; }}\n        \
         case {QD}u: {{ return qd[i * n + s]; }}\n        default: {{ return u[i * n + s]; }}\n    }}\n}}\n",
        mask = (1u32 << INDEX_BITS) - 1
    );
    let _ = writeln!(
        out,
        "fn {name}_step(k: u32, s: u32, n: u32) {{\n    let w0 = prog[k];\n    \
         let x = {name}_read(prog[k + 1u], s, n);\n    let y = {name}_read(prog[k + 2u], s, n);\n    \
         let d = w0 & 16777215u;\n    var v = {zero};\n    switch (w0 >> 24u) {{\n        \
         case {ADD}u: {{ v = x + y; }}\n        case {SUB}u: {{ v = x - y; }}\n        case {MUL}u: {{ v = x * y; }}\n        \
         case {DIV}u: {{ v = x / y; }}\n        case {NEG}u: {{ v = -x; }}\n        case {SIN}u: {{ v = {sin}(x); }}\n        \
         case {COS}u: {{ v = {cos}(x); }}\n        default: {{\n            out[d * n + s] = x;\n            return;\n        }}\n    }}\n    \
         if (d < {in_workgroup}u) {{\n        {wg}[d] = v;\n    }} else {{\n        scratch[(d - {in_workgroup}u) * n + s] = v;\n    }}\n}}\n"
    );
    let barrier = if spilled > 0 { "        workgroupBarrier();\n        storageBarrier();" } else { "        workgroupBarrier();" };
    let _ = writeln!(out, "@compute @workgroup_size({workers})");
    let _ = writeln!(out, "fn {name}(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) w: u32) {{");
    // s and n are workgroup-uniform, so the early return keeps the barriers in uniform
    // control flow.
    let _ = writeln!(
        out,
        "    let n = params.n;\n    let s = wid.x;\n    if (s >= n) {{\n        return;\n    }}\n    \
         for (var p = 0u; p < {phases}u; p++) {{\n        let r = {base}u + p * {workers}u + w;\n        \
         let end = prog[r + 1u];\n        for (var k = prog[r]; k < end; k += 3u) {{\n            {name}_step(k, s, n);\n        }}\n{barrier}\n    }}\n}}\n"
    );
    Ok(EntryStats {
        entry: name,
        kernel: f.kind.name(),
        strategy: Strategy::Cooperative,
        outputs,
        scratch: spilled,
        workgroup_size: options.workers,
        states_per_workgroup: 1,
        workgroup_bytes: in_workgroup.max(1) * options.precision.bytes(),
        phases,
        stages: 1,
        statements: instructions,
        functions: 3,
    })
}

/// The constants of every cooperative entry of one shader, deduplicated by their bits in
/// the shader's precision.
#[derive(Default)]
pub(super) struct Constants {
    pub values: Vec<f64>,
    index: HashMap<u64, usize>,
}

impl Constants {
    pub fn get(&mut self, c: f64, precision: Precision, robot: &str) -> Result<usize, BackError> {
        let c = match precision {
            Precision::F32 => {
                let x = c as f32;
                if !x.is_finite() {
                    return Err(BackError::WgslRange { robot: robot.to_string(), value: c });
                }
                x as f64
            }
            Precision::F64 => c,
        };
        let next = self.values.len();
        let k = *self.index.entry(c.to_bits()).or_insert(next);
        if k == next {
            self.values.push(c);
        }
        Ok(k)
    }
}
