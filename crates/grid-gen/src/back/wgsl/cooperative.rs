//! The `cooperative` strategy (GRiD's scheme): one workgroup per state; the kernel's
//! operations are spread over the workgroup's invocations in barrier-separated phases,
//! one phase per level of the dataflow graph. The operations are not unrolled into WGSL:
//! they are a table (binding 6, `prog`) that a short interpreter loop in the entry point
//! walks, each invocation its share of each phase, with the constants in binding 7
//! (`konst`). Unrolled per-invocation code (a `switch` over 64 invocations per phase, as
//! this strategy was first built) took lavapipe's LLVM 4 to 12 ms per statement to compile
//! (coroutine frames across every barrier, each case run under masks): minutes per
//! gradient, hours for Atlas. The interpreter is the same few dozen statements for every
//! robot, so every pipeline compiles in milliseconds, and neighbouring invocations run
//! the same loop (and mostly the same operation) rather than different `switch` cases.
//!
//! Every value lives in a slot from the phase that writes it to the last phase that reads
//! it (a slot is reused only after that phase, so no phase both reads and overwrites one):
//! `var<workgroup>` memory while the slots fit WebGPU's default 16 KiB of workgroup storage
//! ([`WORKGROUP_STORAGE_LIMIT`]; naga and wgpu do not check it), the storage scratch
//! buffer past that (with a `storageBarrier` between phases).

use std::collections::{BTreeSet, HashMap};
use std::fmt::Write;

use super::WgslError;
use super::{
    output_stores, EntryMeta, Precision, Strategy, Tables, Trig, WgslOptions,
    WORKGROUP_STORAGE_LIMIT,
};
use crate::ir::{Buffer, Function, Id, Op};

/// Operation codes of the table (bits 24..32 of an instruction's first word).
const ADD: u32 = 0;
const SUB: u32 = 1;
const MUL: u32 = 2;
const DIV: u32 = 3;
const NEG: u32 = 4;
const SIN: u32 = 5;
const COS: u32 = 6;
const COPY: u32 = 7;
/// Does nothing: pads an invocation's list to its phase's longest.
const NOP: u32 = 8;
const SQRT: u32 = 9;

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

fn address(tag: u32, index: usize, robot: &str) -> Result<u32, WgslError> {
    if index >= 1 << INDEX_BITS {
        return Err(WgslError::Option(format!("robot \"{robot}\": a cooperative table index {index} does not fit in {INDEX_BITS} bits")));
    }
    Ok(tag << INDEX_BITS | index as u32)
}

pub(super) fn emit(
    out: &mut String,
    f: &Function,
    options: &WgslOptions,
    robot: &str,
    tables: &mut Tables,
) -> Result<EntryMeta, WgslError> {
    let workers = options.workers as usize;
    let name = Strategy::Cooperative.entry(f.kind.name());
    let (stores, inline, outputs) = output_stores(f);
    let nodes = f.nodes.len();

    // Level scheduling: an operation runs in the phase one past its latest operand's
    // (inputs and constants are ready at phase 0), and an output copy in the phase after
    // its value's; each phase's instructions are spread over the invocations in turn.
    // The phases are the graph's depth, each as many steps as its width needs. (The IR's
    // list scheduler, `Phases`, which keeps a chain of dependent operations on one
    // invocation to save barriers, was this strategy's first schedule: iiwa's fd_grad took
    // 14 phases but 2464 steps, 1563 of them one invocation's chain in the last phase;
    // by levels it is 138 phases of 169 steps.)
    let mut phase = vec![usize::MAX; nodes];
    for (i, node) in f.nodes.iter().enumerate() {
        if node.op.operands().any(|o| o.0 as usize >= i) {
            return Err(WgslError::Option(format!(
                "{}: node {i} reads a later node (the IR is built in dependence order)",
                f.kind.name()
            )));
        }
        if f.is_operation(Id(i as u32)) {
            phase[i] = node
                .op
                .operands()
                .filter(|o| phase[o.0 as usize] != usize::MAX)
                .map(|o| phase[o.0 as usize] + 1)
                .max()
                .unwrap_or(0);
        }
    }
    let copies_after = |i: usize| if stores[i].is_empty() { 0 } else { 1 };
    let phases = (0..nodes)
        .filter(|&i| phase[i] != usize::MAX)
        .map(|i| phase[i] + 1 + copies_after(i))
        .max()
        .unwrap_or(0)
        .max(1);

    // Each operation's slot: from its phase to the last phase that reads it (its copies
    // included). A slot is reused only by a value written in a later phase than that, so
    // no phase both reads and overwrites one.
    let mut last = vec![0usize; nodes];
    let mut by_phase: Vec<Vec<usize>> = vec![Vec::new(); phases];
    for (i, node) in f.nodes.iter().enumerate() {
        if phase[i] != usize::MAX {
            last[i] = last[i].max(phase[i] + copies_after(i));
            for o in node.op.operands() {
                last[o.0 as usize] = last[o.0 as usize].max(phase[i]);
            }
            by_phase[phase[i]].push(i);
        }
    }
    let mut slot = vec![u32::MAX; nodes];
    let mut free: BTreeSet<u32> = BTreeSet::new();
    // (last phase, slot) of the slots in use; the lowest free slot first keeps the most
    // used slots in workgroup memory.
    let mut busy: BTreeSet<(usize, u32)> = BTreeSet::new();
    let mut slots = 0u32;
    for (p, ids) in by_phase.iter().enumerate() {
        while let Some(&(end, s)) = busy.first() {
            if end >= p {
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
        return Err(WgslError::Option(format!(
            "robot \"{robot}\": {} needs {slots} slots, more than the table's 2^24",
            f.kind.name()
        )));
    }

    let operand = |id: Id, tables: &mut Tables| -> Result<u32, WgslError> {
        match f.op(id) {
            Op::Const(c) => address(KONST, tables.konst.get(c, options.precision, robot)?, robot),
            Op::Input(which, j) => {
                let tag = match which.buffer() {
                    Buffer::Q => Q,
                    Buffer::Qd => QD,
                    Buffer::U => U,
                };
                address(tag, f.packed_u(which, j as usize), robot)
            }
            _ => match slot[id.0 as usize] as usize {
                k if k < in_workgroup => address(WORKGROUP, k, robot),
                k => address(SCRATCH, k - in_workgroup, robot),
            },
        }
    };
    // Each phase's instructions.
    let mut lists: Vec<Vec<[u32; WORDS]>> = vec![Vec::new(); phases];
    for (i, &p) in phase.iter().enumerate() {
        if p == usize::MAX {
            continue;
        }
        let id = Id(i as u32);
        let (code, a, b) = match f.op(id) {
            Op::Add(a, b) => (ADD, a, b),
            Op::Sub(a, b) => (SUB, a, b),
            Op::Mul(a, b) => (MUL, a, b),
            Op::Div(a, b) => (DIV, a, b),
            Op::Neg(a) => (NEG, a, a),
            Op::Sin(a) => (SIN, a, a),
            Op::Cos(a) => (COS, a, a),
            Op::Sqrt(a) => (SQRT, a, a),
            Op::Const(_) | Op::Input(..) => unreachable!("only operations have a phase"),
        };
        let (a, b) = (operand(a, tables)?, operand(b, tables)?);
        lists[p].push([code << 24 | slot[i], a, b]);
        let me = operand(id, tables)?;
        for &k in &stores[i] {
            lists[p + 1].push([COPY << 24 | k as u32, me, me]);
        }
    }
    // Outputs that are constants or inputs: in phase 0.
    for &(k, id) in &inline {
        let a = operand(id, tables)?;
        lists[0].push([COPY << 24 | k as u32, a, a]);
    }
    // Neighbouring invocations run the same operation where they can (one branch of the
    // interpreter's switch per warp instead of several).
    for list in &mut lists {
        list.sort_by_key(|ins| ins[0] >> 24);
    }

    // The table: for each phase its block's offset (an absolute word index into `prog`)
    // and its steps, then the blocks. Block p holds its instructions in turn over the
    // invocations (instruction j of the phase goes to invocation j % workers, at step
    // j / workers), so neighbouring invocations fetch neighbouring words, padded with NOP
    // to whole steps.
    let base = tables.prog.len();
    let mut at = base + 2 * phases;
    let mut head = Vec::with_capacity(2 * phases);
    for list in &lists {
        let steps = list.len().div_ceil(workers);
        head.extend([at as u32, steps as u32]);
        at += steps * workers * WORDS;
    }
    if at > u32::MAX as usize {
        return Err(WgslError::Option(format!(
            "robot \"{robot}\": the cooperative tables exceed 2^32 words"
        )));
    }
    tables.prog.extend(head);
    let mut instructions = 0;
    for list in &lists {
        instructions += list.len();
        let padded = list.len().div_ceil(workers) * workers;
        tables.prog.extend(list.iter().flatten());
        tables.prog.extend(std::iter::repeat_n([NOP << 24, 0, 0], padded - list.len()).flatten());
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
         operations are a table at prog[{base}..{at}] (phase p's block starts at prog[{base} + 2 * p] \
         and has prog[{base} + 2 * p + 1] steps of {workers} instructions of 3 words, invocation w's \
         at (step * {workers} + w) * 3).",
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
         case {COS}u: {{ v = {cos}(x); }}\n        case {SQRT}u: {{ v = sqrt(x); }}\n        case {COPY}u: {{\n            out[d * n + s] = x;\n            return;\n        }}\n        default: {{ return; }}\n    }}\n    \
         if (d < {in_workgroup}u) {{\n        {wg}[d] = v;\n    }} else {{\n        scratch[(d - {in_workgroup}u) * n + s] = v;\n    }}\n}}\n"
    );
    let barrier = if spilled > 0 {
        "        workgroupBarrier();\n        storageBarrier();"
    } else {
        "        workgroupBarrier();"
    };
    let _ = writeln!(out, "@compute @workgroup_size({workers})");
    let _ = writeln!(out, "fn {name}(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) w: u32) {{");
    // s and n are workgroup-uniform, so the early return keeps the barriers in uniform
    // control flow.
    let _ = writeln!(
        out,
        "    let n = params.n;\n    let s = wid.x;\n    if (s >= n) {{\n        return;\n    }}\n    \
         for (var p = 0u; p < {phases}u; p++) {{\n        let at = prog[{base}u + 2u * p] + 3u * w;\n        \
         let steps = prog[{base}u + 2u * p + 1u];\n        for (var k = 0u; k < steps; k++) {{\n            {name}_step(at + k * {stride}u, s, n);\n        }}\n{barrier}\n    }}\n}}\n",
        stride = workers * WORDS
    );
    Ok(EntryMeta {
        entry: name,
        kernel: f.kind.name().to_string(),
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
    pub fn get(&mut self, c: f64, precision: Precision, robot: &str) -> Result<usize, WgslError> {
        let c = super::rounded(c, precision, robot)?;
        let next = self.values.len();
        let k = *self.index.entry(c.to_bits()).or_insert(next);
        if k == next {
            self.values.push(c);
        }
        Ok(k)
    }
}
