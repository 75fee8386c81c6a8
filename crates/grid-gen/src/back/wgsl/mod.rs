//! The WGSL backend: every kernel a compute entry point over a batch of N states, in two
//! strategies (one invocation per state, or one workgroup per state), f32 or f64, with
//! WGSL's built-in sin/cos or an accurate in-kernel reduction and polynomial.

mod cooperative;
mod thread;
mod trig;

use std::fmt::Write;

use serde::Serialize;

use super::names::{comment_text, identifier};
use super::{GeneratedFile, Target};
use crate::ir::{Buffer, Function, Id, Input, Module, Op};

/// Invocation layout of the entry points.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Strategy {
    /// One invocation per state, straight-line code: throughput at large N.
    Thread,
    /// One workgroup per state, the graph spread over its invocations in
    /// barrier-separated phases (GRiD's scheme): latency at small N.
    Cooperative,
}

impl Strategy {
    pub const ALL: [Strategy; 2] = [Strategy::Thread, Strategy::Cooperative];

    pub fn name(self) -> &'static str {
        match self {
            Strategy::Thread => "thread",
            Strategy::Cooperative => "cooperative",
        }
    }

    pub fn parse(s: &str) -> Option<Strategy> {
        Strategy::ALL.into_iter().find(|x| x.name() == s)
    }

    /// The entry point of kernel `name` under this strategy.
    pub fn entry(self, name: &str) -> String {
        match self {
            Strategy::Thread => name.to_string(),
            Strategy::Cooperative => format!("{name}_coop"),
        }
    }
}

/// Floating-point type of the kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Precision {
    /// WebGPU's only universal float.
    F32,
    /// Needs the adapter feature `SHADER_F64` (wgpu's name; not in core WebGPU).
    F64,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    pub fn parse(s: &str) -> Option<Precision> {
        [Precision::F32, Precision::F64].into_iter().find(|x| x.name() == s)
    }

    pub fn bytes(self) -> usize {
        match self {
            Precision::F32 => 4,
            Precision::F64 => 8,
        }
    }
}

/// How sin and cos of q are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Trig {
    /// WGSL's `sin`/`cos`: fast, but the WebGPU spec allows an absolute error of 2^-11 on
    /// [-π, π] and says nothing outside it. f32 only (Vulkan's GLSL.std.450 has no f64
    /// sine).
    Builtin,
    /// Cody–Waite reduction by π/2 and minimax polynomials on [-π/4, π/4] (see `trig.rs`):
    /// about 1 ulp, the same on every adapter.
    Accurate,
}

impl Trig {
    pub fn name(self) -> &'static str {
        match self {
            Trig::Builtin => "builtin",
            Trig::Accurate => "accurate",
        }
    }

    pub fn parse(s: &str) -> Option<Trig> {
        [Trig::Builtin, Trig::Accurate].into_iter().find(|x| x.name() == s)
    }
}

/// WebGPU's default `maxComputeWorkgroupStorageSize` (bytes). naga and wgpu do not check
/// it, so the cooperative strategy keeps its `var<workgroup>` arrays under it and spills
/// the rest to the storage scratch buffer.
pub const WORKGROUP_STORAGE_LIMIT: usize = 16384;
/// WebGPU's default `maxComputeInvocationsPerWorkgroup`.
pub const MAX_INVOCATIONS: u32 = 256;

/// Default most operations per dispatch ([`WgslOptions::stage`]).
/// lavapipe compiled UR5's thread `fd_grad` (5.8k statements) in 6.5 s as one dispatch,
/// 5.2 s in stages of 4000 operations, 3.5 s of 2000, 2.6 s of 1000 and 3.5 s of 500
/// (the helpers shrink with the stage, and the dispatches multiply); measured 2026-11-24,
/// Mesa 22.3 on 2 cores, shader cache off. On a GPU each extra dispatch costs a few µs
/// of launch: `--wgsl-stage 0` keeps every kernel in one.
pub const DEFAULT_STAGE: usize = 1000;

/// Options of the WGSL backend.
#[derive(Clone, Debug)]
pub struct WgslOptions {
    /// Most operations in one WGSL function (naga's parser is quadratic in one function).
    pub chunk: usize,
    /// Thread strategy: most operations in one dispatch. A kernel over it becomes several
    /// entry points (stages) run in order on one bind group, values crossing them in the
    /// scratch buffer, because drivers compile a pipeline as one function after inlining
    /// and lavapipe's compiler is superlinear in its size (see `stages` in
    /// [`LAYOUT_DOC`]). 0: every kernel in one dispatch.
    pub stage: usize,
    /// Thread strategy: invocations (= states) per workgroup.
    pub workgroup_size: u32,
    /// Cooperative strategy: invocations sharing one state.
    pub workers: u32,
    pub strategies: Vec<Strategy>,
    pub precision: Precision,
    pub trig: Trig,
}

impl Default for WgslOptions {
    fn default() -> Self {
        WgslOptions {
            chunk: 1000,
            stage: DEFAULT_STAGE,
            workgroup_size: 64,
            workers: 64,
            strategies: Strategy::ALL.to_vec(),
            precision: Precision::F32,
            trig: Trig::Accurate,
        }
    }
}

/// One entry point's metadata: what it costs (for `info --json`) and what the runtime needs
/// to dispatch it. The emitter writes it as a `// entry:` header line
/// ([`EntryMeta::header_line`]) and the runtime reads it back ([`EntryMeta::parse`]): one
/// type on both sides of the file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EntryMeta {
    pub entry: String,
    pub kernel: String,
    pub strategy: Strategy,
    /// Output values per state (structural zeros included).
    pub outputs: usize,
    /// Words of the storage scratch buffer per state.
    pub scratch: usize,
    pub workgroup_size: u32,
    pub states_per_workgroup: u32,
    pub workgroup_bytes: usize,
    /// Barrier-separated phases (cooperative) or 1.
    pub phases: usize,
    /// Dispatches, one entry point each (`<entry>_stage<k>` when more than one).
    pub stages: usize,
    /// `let`s and stores (thread); operations and output copies in the table
    /// (cooperative, whose WGSL is the same few dozen statements for every kernel).
    pub statements: usize,
    pub functions: usize,
}

impl EntryMeta {
    /// The machine-readable header line the runtime parses.
    pub fn header_line(&self) -> String {
        format!(
            "// entry: {} kernel={} strategy={} outputs={} scratch={} workgroup_size={} states_per_workgroup={} workgroup_bytes={} phases={} stages={} statements={} functions={}",
            self.entry,
            self.kernel,
            self.strategy.name(),
            self.outputs,
            self.scratch,
            self.workgroup_size,
            self.states_per_workgroup,
            self.workgroup_bytes,
            self.phases,
            self.stages,
            self.statements,
            self.functions
        )
    }

    /// Reads what follows `// entry: ` on a header line; the error says what is wrong.
    /// `stages`, `statements` and `functions` may be absent (shaders written before they
    /// existed: one dispatch, counts unknown).
    pub fn parse(text: &str) -> Result<EntryMeta, String> {
        let mut words = text.split_whitespace();
        let entry = words.next().ok_or("no name")?.to_string();
        let mut field = std::collections::HashMap::new();
        for w in words {
            let (k, v) = w.split_once('=').ok_or("expected key=value")?;
            field.insert(k, v);
        }
        let get = |k: &str| field.get(k).copied().ok_or(format!("no `{k}`"));
        let num = |k: &str| get(k)?.parse::<usize>().map_err(|_| format!("`{k}` is not a count"));
        let optional = |k: &str, absent: usize| {
            if field.contains_key(k) {
                num(k)
            } else {
                Ok(absent)
            }
        };
        let small =
            |k: &str| u32::try_from(num(k)?).map_err(|_| format!("`{k}` is too large for a u32"));
        Ok(EntryMeta {
            kernel: get("kernel")?.to_string(),
            strategy: Strategy::parse(get("strategy")?).ok_or("unknown strategy")?,
            outputs: num("outputs")?,
            scratch: num("scratch")?,
            workgroup_size: small("workgroup_size")?,
            states_per_workgroup: small("states_per_workgroup")?.max(1),
            workgroup_bytes: num("workgroup_bytes")?,
            phases: num("phases")?,
            stages: optional("stages", 1)?.max(1),
            statements: optional("statements", 0)?,
            functions: optional("functions", 0)?,
            entry,
        })
    }
}

/// Why the WGSL backend could not print a module.
#[derive(Debug, thiserror::Error)]
pub enum WgslError {
    #[error("robot `{robot}`: the constant {value} is out of f32's range, so the WGSL f32 kernels cannot hold it (try --precision f64)")]
    Range { robot: String, value: f64 },
    /// Options the backend cannot honour, or a kernel too large for the cooperative tables.
    #[error("WGSL: {0}")]
    Option(String),
}

/// The buffer layout, described once for the file header and the book.
pub const LAYOUT_DOC: &str = "\
Every entry point shares one bind group (group 0), so one pipeline layout serves all:
  binding 0  uniform  Params { n: u32 }             number of states N in this dispatch
  binding 1  storage, read        q:   array<real>  q[j * N + s] is joint j of state s
  binding 2  storage, read        qd:  array<real>  same layout (unused by mass_matrix, minv)
  binding 3  storage, read        u:   array<real>  qdd (rnea, rnea_grad) or tau (fd, fd_grad)
  binding 4  storage, read_write  out: array<real>  out[k * N + s]: value k of state s, the
             kernel's outputs concatenated in order, matrices row-major ([i][j] = d out_i / d in_j)
  binding 5  storage, read_write  scratch: array<real>  scratch[k * N + s], `scratch` words per
             state (see the entry lines; bind at least one word when it is 0)
  binding 6  storage, read        prog:  array<u32>   the cooperative entry points' operation
             tables: the words of the `// prog:` lines at the end of this file, in order
  binding 7  storage, read        konst: array<real>  their constants: the `// konst:` lines
             (bind at least one word each when the `// tables:` line gives 0)
Structure-of-arrays, so neighbouring invocations touch neighbouring words. `real` is the
precision below. Thread entry points (`<kernel>`): dispatch ceil(N / workgroup_size)
workgroups in x. Cooperative entry points (`<kernel>_coop`): dispatch N workgroups in x,
one state each. An entry with stages=K > 1 is K entry points `<entry>_stage0` .. `_stage<K-1>`,
dispatched in that order on the same bind group and workgroup count (values cross stages in
scratch); K = 1 is the entry point `<entry>` itself (every cooperative entry). At most 65535 workgroups per dispatch: split larger batches into
dispatches of their own buffers. A state past N does nothing. Every output value is
written, structural zeros included.";

/// WGSL's literal for a constant in `precision`, or an error if it cannot hold it.
fn literal(c: f64, precision: Precision, robot: &str) -> Result<String, WgslError> {
    // `{:?}` prints the shortest text that reads back as the same value.
    let x = rounded(c, precision, robot)?;
    let s = match precision {
        Precision::F32 => format!("{:?}f", x as f32),
        Precision::F64 => format!("{x:?}lf"),
    };
    Ok(if x < 0.0 { format!("({s})") } else { s })
}

/// Constant `c` as `precision` holds it, or an error if it cannot (an f32 overflow).
fn rounded(c: f64, precision: Precision, robot: &str) -> Result<f64, WgslError> {
    match precision {
        Precision::F32 if !(c as f32).is_finite() => {
            Err(WgslError::Range { robot: robot.to_string(), value: c })
        }
        Precision::F32 => Ok(c as f32 as f64),
        Precision::F64 => Ok(c),
    }
}

fn input_buffer(input: Input) -> &'static str {
    match input.buffer() {
        Buffer::Q => "q",
        Buffer::Qd => "qd",
        Buffer::U => "u",
    }
}

/// The expression of operation `id`, given how to name each operand.
fn expression(
    f: &Function,
    id: Id,
    trig: Trig,
    mut o: impl FnMut(Id) -> Result<String, WgslError>,
) -> Result<String, WgslError> {
    let (sin, cos) = match trig {
        Trig::Builtin => ("sin", "cos"),
        Trig::Accurate => ("gg_sin", "gg_cos"),
    };
    Ok(match f.op(id) {
        Op::Add(a, b) => format!("{} + {}", o(a)?, o(b)?),
        Op::Sub(a, b) => format!("{} - {}", o(a)?, o(b)?),
        Op::Mul(a, b) => format!("{} * {}", o(a)?, o(b)?),
        Op::Div(a, b) => format!("{} / {}", o(a)?, o(b)?),
        Op::Neg(a) => format!("-({})", o(a)?),
        Op::Sin(a) => format!("{sin}({})", o(a)?),
        Op::Cos(a) => format!("{cos}({})", o(a)?),
        Op::Sqrt(a) => format!("sqrt({})", o(a)?),
        Op::Const(_) | Op::Input(..) => unreachable!("schedules hold operations only"),
    })
}

/// Constants and inputs printed inline; `None` for operations.
fn leaf(
    f: &Function,
    id: Id,
    precision: Precision,
    robot: &str,
) -> Result<Option<String>, WgslError> {
    Ok(match f.op(id) {
        Op::Const(k) => Some(literal(k, precision, robot)?),
        Op::Input(which, j) => {
            Some(format!("{}[{}u * n + s]", input_buffer(which), f.packed_u(which, j as usize)))
        }
        _ => None,
    })
}

/// One straight-line block of operations (a thread helper, or one worker's list in a
/// cooperative phase), printed loads first and stores last, so no load follows a store:
/// a driver's compiler then never has to prove a load independent of the stores before
/// it. With them interleaved, lavapipe's LLVM took seconds per thousand operations
/// (UR5's thread `rnea_grad`, 210 scratch stores among 655 loads: 4.0 s to compile, then
/// 1.3 s in this order; `fd_grad` 9.3 s, then 2.6 s; measured 2026-11-24). The order is
/// free because a block never reads a slot it writes (the schedules' slot rule).
/// `local(id)`: the value is computed in this block; `slot(id)`: the memory that holds a
/// value read by a later block; `outputs`: output stores of each node; `inline`: output
/// values that are inputs or constants, written by this block. Returns the statements.
#[allow(clippy::too_many_arguments)]
fn block(
    out: &mut String,
    f: &Function,
    options: &WgslOptions,
    robot: &str,
    indent: &str,
    ids: &[Id],
    inline: &[(usize, Id)],
    local: impl Fn(Id) -> bool,
    slot: impl Fn(Id) -> Option<String>,
    outputs: &[Vec<usize>],
) -> Result<usize, WgslError> {
    let operand = |id: Id| -> Result<String, WgslError> {
        Ok(match f.op(id) {
            Op::Const(_) => leaf(f, id, options.precision, robot)?.unwrap_or_default(),
            _ => format!("t{}", id.0),
        })
    };
    let mut statements = 0;
    let mut loaded = std::collections::BTreeSet::new();
    let reads =
        ids.iter().flat_map(|&id| f.op(id).operands()).chain(inline.iter().map(|&(_, id)| id));
    for x in reads {
        let load = match f.op(x) {
            Op::Const(_) => None,
            Op::Input(..) => leaf(f, x, options.precision, robot)?,
            _ if local(x) => None,
            _ => Some(slot(x).expect("values read by a later block have a slot")),
        };
        if let Some(load) = load {
            if loaded.insert(x.0) {
                let _ = writeln!(out, "{indent}let t{} = {load};", x.0);
                statements += 1;
            }
        }
    }
    let mut tail = Vec::new();
    for (k, id) in inline {
        tail.push(format!("{indent}out[{k}u * n + s] = {};", operand(*id)?));
    }
    for &id in ids {
        let e = expression(f, id, options.trig, operand)?;
        let _ = writeln!(out, "{indent}let t{} = {e};", id.0);
        statements += 1;
        if let Some(place) = slot(id) {
            tail.push(format!("{indent}{place} = t{};", id.0));
        }
        for k in &outputs[id.0 as usize] {
            tail.push(format!("{indent}out[{k}u * n + s] = t{};", id.0));
        }
    }
    statements += tail.len();
    for line in tail {
        let _ = writeln!(out, "{line}");
    }
    Ok(statements)
}

/// The entry point of stage `k` of an entry split into `stages` dispatches: the entry's own
/// name when it is one dispatch, else `<entry>_stage<k>`. The emitters and the runtime
/// (which reads `stages=` from the header) both name stages with this.
pub fn stage_entry(entry: &str, k: usize, stages: usize) -> String {
    if stages == 1 {
        entry.to_string()
    } else {
        format!("{entry}_stage{k}")
    }
}

/// Consecutive steps (thread helpers or cooperative phases) of the given operation counts
/// grouped into stages of at most `limit` operations, at least one step each (0: one
/// stage), as ranges of step indices.
fn stages(sizes: impl Iterator<Item = usize>, limit: usize) -> Vec<std::ops::Range<usize>> {
    let mut stages: Vec<std::ops::Range<usize>> = std::iter::once(0..0).collect();
    let mut size = 0;
    for (k, ops) in sizes.enumerate() {
        let last = stages.len() - 1;
        if limit > 0 && size > 0 && size + ops > limit {
            stages.push(k..k + 1);
            size = 0;
        } else {
            stages[last].end = k + 1;
        }
        size += ops;
    }
    stages
}

/// Output index of every operation's value (stores follow the node), and the outputs that
/// are constants or inputs.
fn output_stores(f: &Function) -> (Vec<Vec<usize>>, Vec<(usize, Id)>, usize) {
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
        base += o.ids.len();
    }
    (stores, inline, base)
}

/// The WGSL file for `module`: `<stem>.wgsl`, every kernel an entry point per strategy.
pub fn emit(module: &Module, options: &WgslOptions) -> Result<GeneratedFile, WgslError> {
    emit_with_stats(module, options).map(|(file, _)| file)
}

/// [`emit`], and what each entry point costs.
pub fn emit_with_stats(
    module: &Module,
    options: &WgslOptions,
) -> Result<(GeneratedFile, Vec<EntryMeta>), WgslError> {
    let robot = &module.robot;
    let nv = robot.nv();
    let stem = identifier(&robot.name);
    check_options(options)?;
    if options.precision == Precision::F64 && options.trig == Trig::Builtin {
        return Err(WgslError::Option(
            "f64 kernels need --wgsl-trig accurate (Vulkan has no f64 sine)".into(),
        ));
    }
    let mut body = String::new();
    let mut stats = Vec::new();
    let mut tables = Tables::default();
    for f in &module.functions {
        for &strategy in &options.strategies {
            let s = match strategy {
                Strategy::Thread => thread::emit(&mut body, f, options, &robot.name)?,
                Strategy::Cooperative => {
                    cooperative::emit(&mut body, f, options, &robot.name, &mut tables)?
                }
            };
            stats.push(s);
        }
    }
    let mut out = String::new();
    let _ = writeln!(
        out,
        "// @generated by grid-gen {} from the URDF of robot \"{}\" ({nv} joints). Do not edit:\n\
         // regenerate with `grid-gen ROBOT.urdf -o DIR --backend wgsl`.\n{}//",
        env!("CARGO_PKG_VERSION"),
        comment_text(&robot.name),
        crate::back::source_line(&robot.source) + &crate::back::specialisation_lines(robot),
    );
    for line in LAYOUT_DOC.lines() {
        let _ = writeln!(out, "// {line}");
    }
    let _ = writeln!(
        out,
        "//\n// Joints (model order), gravity [{}, {}, {}] m/s^2 compiled in:",
        module.gravity[0], module.gravity[1], module.gravity[2]
    );
    for (j, name) in robot.joint_names.iter().enumerate() {
        let _ = writeln!(out, "//   {j:>3}  {}", comment_text(name));
    }
    let _ = writeln!(out, "//\n// Kernels and output values per state:");
    for f in &module.functions {
        let parts: Vec<String> =
            f.outputs.iter().map(|o| format!("{} ({})", o.name, o.ids.len())).collect();
        let _ = writeln!(out, "//   {}: {}", f.signature(), parts.join(", "));
    }
    if robot.floating {
        let _ = writeln!(
            out,
            "//\n// Floating base: q has nq = nv + 1 entries per state, the base's position and quaternion\n\
             // [x, y, z, qx, qy, qz, qw] (q[0..7]), then the joints after the free-flyer's six velocity\n\
             // coordinates (joint j >= 6 at q[j + 1]); qd, u and the outputs have nv per state."
        );
    }
    let _ = writeln!(
        out,
        "//\n// Read by grid-gen's runtime (crates/grid-gen-wgpu):\n// nv: {nv}\n{}{}{}{}{}{}{}// precision: {}\n// trig: {}",
        if robot.nq() != robot.nv() { format!("// nq: {}\n", robot.nq()) } else { String::new() },
        // The step kernels' `u` is the actuated joints' τ.
        if robot.specialisation.step.is_some() { format!("// nu: {}\n", robot.nu()) } else { String::new() },
        // rnea, rnea_grad, fd and fd_grad read their forces after q̈ or τ in `u`.
        match 6 * robot.fext.len() + robot.nlambda() {
            0 => String::new(),
            n => format!("// forces: {n}\n"),
        },
        // Of which λ, which the contact kernels solve for instead of reading.
        match robot.nlambda() {
            0 => String::new(),
            n => format!("// lambda: {n}\n"),
        },
        // The contact-solving kernels read the contact mask in `u`.
        match robot.dims().ncontacts {
            0 => String::new(),
            n => format!("// active: {n}\n"),
        },
        // With Baumgarte gains, then gains (2 per contact) and contact_ref (3 per point
        // contact, 7 per wrench contact: the second count).
        match robot.dims().nbaumgarte {
            0 => String::new(),
            n => format!("// baumgarte: {n}\n// contact_ref: {}\n", robot.dims().ncontact_ref),
        },
        // The step kernels read a run-time dt last in `u`.
        match robot.specialisation.step.is_some_and(|s| s.runtime_dt()) {
            true => "// dt: input\n",
            false => "",
        },
        options.precision.name(),
        options.trig.name()
    );
    let _ =
        writeln!(out, "// tables: prog={} konst={}", tables.prog.len(), tables.konst.values.len());
    for s in &stats {
        let _ = writeln!(out, "{}", s.header_line());
    }
    let _ = writeln!(
        out,
        "\nalias real = {};\n\nstruct Params {{\n    n: u32,\n}}\n\n\
         @group(0) @binding(0) var<uniform> params: Params;\n\
         @group(0) @binding(1) var<storage, read> q: array<real>;\n\
         @group(0) @binding(2) var<storage, read> qd: array<real>;\n\
         @group(0) @binding(3) var<storage, read> u: array<real>;\n\
         @group(0) @binding(4) var<storage, read_write> out: array<real>;\n\
         @group(0) @binding(5) var<storage, read_write> scratch: array<real>;\n\
         @group(0) @binding(6) var<storage, read> prog: array<u32>;\n\
         @group(0) @binding(7) var<storage, read> konst: array<real>;\n",
        options.precision.name()
    );
    if options.trig == Trig::Accurate {
        out.push_str(&trig::source(options.precision));
        out.push('\n');
    }
    out.push_str(&body);
    tables.write(&mut out, options.precision);
    Ok((GeneratedFile { name: Target::Wgsl.file_name(&stem), contents: out }, stats))
}

/// The cooperative entry points' operation tables and constants (bindings 6 and 7),
/// shared by the whole shader.
#[derive(Default)]
struct Tables {
    prog: Vec<u32>,
    konst: cooperative::Constants,
}

impl Tables {
    /// The `// prog:` and `// konst:` lines at the end of the file, which the runtime (or
    /// any host) uploads as they are.
    fn write(&self, out: &mut String, precision: Precision) {
        if self.prog.is_empty() {
            return;
        }
        let _ = writeln!(out, "// The cooperative entry points' tables: binding 6 (prog, u32 in hex) and binding 7 (konst).");
        for words in self.prog.chunks(16) {
            let words: Vec<String> = words.iter().map(|w| format!("{w:x}")).collect();
            let _ = writeln!(out, "// prog: {}", words.join(" "));
        }
        for values in self.konst.values.chunks(8) {
            let values: Vec<String> = values
                .iter()
                .map(|&c| match precision {
                    Precision::F32 => format!("{:?}", c as f32),
                    Precision::F64 => format!("{c:?}"),
                })
                .collect();
            let _ = writeln!(out, "// konst: {}", values.join(" "));
        }
    }
}

fn check_options(options: &WgslOptions) -> Result<(), WgslError> {
    let bad = |what: String| Err(WgslError::Option(what));
    if options.strategies.is_empty() {
        return bad("no strategy selected (available: thread, cooperative)".into());
    }
    for (name, v) in
        [("workgroup size", options.workgroup_size), ("cooperative workers", options.workers)]
    {
        if v == 0 || v > MAX_INVOCATIONS {
            return bad(format!("{name} {v} is outside 1..={MAX_INVOCATIONS} (WebGPU's default maxComputeInvocationsPerWorkgroup)"));
        }
    }
    Ok(())
}
