//! The Rust backend: straight-line, sparsity-specialised code, generic over f32 and f64,
//! split into functions of at most `chunk` statements (rustc's time grows faster than
//! linearly in the size of one function).

use std::collections::HashMap;
use std::fmt::Write;

use super::names::string_literal;
use crate::ir::{Id, Kernel, Op};
use crate::model::Model;

/// The public API, described once for the file's doc comments and the README.
pub const API_DOC: &str = "\
/// Everything in this module is specialised to one robot. Vectors are `[T; NV]` in the order of
/// `JOINT_NAMES`; matrices are `[[T; NV]; NV]`, row-major, `m[i][j] = d out_i / d in_j`. `T` is `f64`
/// or `f32` (see [`Real`]), or `Lanes<N>` for N states per call. Gravity is fixed at generation
/// time (`GRAVITY`).
///
/// - `rnea(q, qd, qdd) -> c`: inverse dynamics `c = M(q) qdd + C(q, qd) qd + g(q)`.
/// - `rnea_grad(q, qd, qdd) -> (dc_dq, dc_dqd)`: its analytical gradient.
/// - `mass_matrix(q) -> m`: the joint-space inertia matrix M(q).
/// - `minv(q) -> minv`: M(q)^-1, by the direct O(nv^2) recursion (M is never inverted).
/// - `fd(q, qd, tau) -> qdd`: forward dynamics `qdd = M^-1 (tau - c(q, qd, 0))`.
/// - `fd_grad(q, qd, tau) -> (qdd, dqdd_dq, dqdd_dqd)`: forward dynamics and its gradient
///   `-M^-1 dc/du` at the computed qdd, sharing M^-1 and the RNEA pass.";

/// Options of the Rust backend.
#[derive(Clone, Debug)]
pub struct RustOptions {
    /// Most statements in one generated function.
    pub chunk: usize,
}

impl Default for RustOptions {
    fn default() -> Self {
        RustOptions { chunk: 2500 }
    }
}

fn literal(c: f64) -> String {
    debug_assert!(c.is_finite());
    // `{:?}` prints the shortest representation that reads back to the same f64.
    let s = format!("{c:?}");
    if s.contains(['.', 'e']) {
        s
    } else {
        format!("{s}.0")
    }
}

/// What one kernel's code refers to for each live node.
struct Names {
    /// Chunk that defines each node (None: constant or input, printed inline).
    chunk: Vec<Option<usize>>,
    /// Scratch slot of nodes used outside their chunk.
    slot: HashMap<Id, usize>,
    slots: usize,
}

fn plan(k: &Kernel, chunk_size: usize) -> (Vec<Vec<Id>>, Names) {
    let mut chunks: Vec<Vec<Id>> = vec![Vec::new()];
    let mut chunk = vec![None; k.graph.nodes.len()];
    for (i, node) in k.graph.nodes.iter().enumerate() {
        if !k.live[i] || matches!(node.op, Op::Const(_) | Op::Input(..)) {
            continue;
        }
        if chunks.last().unwrap().len() >= chunk_size {
            chunks.push(Vec::new());
        }
        chunks.last_mut().unwrap().push(Id(i as u32));
        chunk[i] = Some(chunks.len() - 1);
    }
    // Last chunk that reads each node.
    let mut last_use: HashMap<Id, usize> = HashMap::new();
    for (c, ids) in chunks.iter().enumerate() {
        for id in ids {
            for o in k.graph.nodes[id.0 as usize].op.operands() {
                if chunk[o.0 as usize].is_some_and(|d| d < c) {
                    last_use.insert(o, c);
                }
            }
        }
    }
    // Scratch slots, reused once a value's last reader has run.
    let mut free: Vec<usize> = Vec::new();
    let mut slots = 0;
    let mut slot = HashMap::new();
    let mut live_until: Vec<(usize, usize)> = Vec::new();
    for (c, ids) in chunks.iter().enumerate() {
        live_until.retain(|&(s, until)| {
            let keep = until >= c;
            if !keep {
                free.push(s);
            }
            keep
        });
        free.sort_unstable_by(|a, b| b.cmp(a));
        for id in ids {
            if let Some(&until) = last_use.get(id) {
                let s = free.pop().unwrap_or_else(|| {
                    slots += 1;
                    slots - 1
                });
                slot.insert(*id, s);
                live_until.push((s, until));
            }
        }
    }
    (chunks, Names { chunk, slot, slots })
}

fn operand(k: &Kernel, names: &Names, here: usize, id: Id) -> String {
    match k.graph.op(id) {
        Op::Const(c) => format!("T::k({})", literal(c)),
        Op::Input(which, j) => format!("{}[{j}]", which.name()),
        _ if names.chunk[id.0 as usize] == Some(here) => format!("t{}", id.0),
        _ => format!("s[{}]", names.slot[&id]),
    }
}

fn expression(k: &Kernel, names: &Names, here: usize, op: Op) -> String {
    let o = |id| operand(k, names, here, id);
    match op {
        Op::Add(a, b) => format!("{} + {}", o(a), o(b)),
        Op::Sub(a, b) => format!("{} - {}", o(a), o(b)),
        Op::Mul(a, b) => format!("{} * {}", o(a), o(b)),
        Op::Div(a, b) => format!("{} / {}", o(a), o(b)),
        Op::Neg(a) => format!("-{}", o(a)),
        Op::Sin(a) => format!("{}.sin()", o(a)),
        Op::Cos(a) => format!("{}.cos()", o(a)),
        Op::Const(_) | Op::Input(..) => unreachable!("printed inline"),
    }
}

fn output_type(matrix: bool) -> &'static str {
    if matrix {
        "[[T; NV]; NV]"
    } else {
        "[T; NV]"
    }
}

fn output_place(k: &Kernel, out: usize, flat: usize, nv: usize) -> String {
    let o = &k.outputs[out];
    if o.matrix {
        format!("{}[{}][{}]", o.name, flat / nv, flat % nv)
    } else {
        format!("{}[{flat}]", o.name)
    }
}

/// Doc comment of each kernel.
fn kernel_doc(name: &str) -> &'static str {
    match name {
        "rnea" => "Inverse dynamics (RNEA): joint forces `c = M(q) qdd + C(q, qd) qd + g(q)`.",
        "rnea_grad" => "Analytical gradient of RNEA: `(dc/dq, dc/dqd)`, row-major `[i][j] = dc_i/du_j`.",
        "mass_matrix" => "The joint-space inertia matrix M(q) (CRBA).",
        "minv" => "M(q)^-1 by the direct O(nv^2) recursion; M is never formed or inverted.",
        "fd" => "Forward dynamics: `qdd = M^-1 (tau - c(q, qd, 0))`.",
        "fd_grad" => "Forward dynamics and its gradient: `(qdd, dqdd/dq, dqdd/dqd)` with `dqdd/du = -M^-1 dc/du` at that qdd.",
        _ => "",
    }
}

fn emit_kernel(out: &mut String, k: &Kernel, nv: usize, options: &RustOptions) {
    let (chunks, names) = plan(k, options.chunk.max(1));
    let args: Vec<String> = k.inputs.iter().map(|i| format!("{}: &[T; NV]", i.name())).collect();
    let arg_names: Vec<&str> = k.inputs.iter().map(|i| i.name()).collect();
    let ret: Vec<&str> = k.outputs.iter().map(|o| output_type(o.matrix)).collect();
    let ret_type = if ret.len() == 1 { ret[0].to_string() } else { format!("({})", ret.join(", ")) };
    let ret_value =
        if k.outputs.len() == 1 { k.outputs[0].name.to_string() } else { format!("({})", k.outputs.iter().map(|o| o.name).collect::<Vec<_>>().join(", ")) };

    // Where each node's value must be stored as an output.
    let mut sinks: HashMap<Id, Vec<String>> = HashMap::new();
    let mut inline_outputs = Vec::new();
    for (oi, o) in k.outputs.iter().enumerate() {
        for (flat, &id) in o.ids.iter().enumerate() {
            let place = output_place(k, oi, flat, nv);
            match k.graph.op(id) {
                // Outputs start at zero; structural zeros need no store.
                Op::Const(c) if c == 0.0 => {}
                Op::Const(_) | Op::Input(..) => inline_outputs.push((place, id)),
                _ => sinks.entry(id).or_default().push(place),
            }
        }
    }
    let body = |c: usize, ids: &[Id]| -> String {
        let mut b = String::new();
        if c == 0 {
            for (place, id) in &inline_outputs {
                let _ = writeln!(b, "{place} = {};", operand(k, &names, 0, *id));
            }
        }
        for &id in ids {
            let _ = writeln!(b, "let t{} = {};", id.0, expression(k, &names, c, k.graph.op(id)));
            if let Some(s) = names.slot.get(&id) {
                let _ = writeln!(b, "s[{s}] = t{};", id.0);
            }
            for place in sinks.get(&id).into_iter().flatten() {
                let _ = writeln!(b, "{place} = t{};", id.0);
            }
        }
        b
    };

    let _ = writeln!(out, "/// {}", kernel_doc(k.name));
    let _ = writeln!(out, "#[inline]\n#[allow(clippy::all, unused_variables, dead_code)]");
    let _ = writeln!(out, "pub fn {}<T: Real>({}) -> {ret_type} {{", k.name, args.join(", "));
    for o in &k.outputs {
        let init = if o.matrix { "[[T::k(0.0); NV]; NV]" } else { "[T::k(0.0); NV]" };
        let _ = writeln!(out, "let mut {} = {init};", o.name);
    }
    if chunks.len() == 1 {
        out.push_str(&body(0, &chunks[0]));
    } else {
        let _ = writeln!(out, "let mut s = [T::k(0.0); {}];", names.slots);
        let outs: Vec<String> = k.outputs.iter().map(|o| format!("&mut {}", o.name)).collect();
        for c in 0..chunks.len() {
            let _ = writeln!(out, "{}_part{c}({}, &mut s, {});", k.name, arg_names.join(", "), outs.join(", "));
        }
    }
    let _ = writeln!(out, "{ret_value}\n}}\n");
    if chunks.len() > 1 {
        let outs: Vec<String> = k.outputs.iter().map(|o| format!("{}: &mut {}", o.name, output_type(o.matrix))).collect();
        for (c, ids) in chunks.iter().enumerate() {
            let _ = writeln!(out, "#[inline(never)]\n#[allow(clippy::all, unused_variables)]");
            let _ = writeln!(out, "fn {}_part{c}<T: Real>({}, s: &mut [T; {}], {}) {{", k.name, args.join(", "), names.slots, outs.join(", "));
            out.push_str(&body(c, ids));
            out.push_str("}\n\n");
        }
    }
}

const PRELUDE: &str = r#"
/// The scalar types the kernels run in: `f64` (exact to round-off) and `f32`.
pub trait Real: Copy + core::ops::Add<Output = Self> + core::ops::Sub<Output = Self> + core::ops::Mul<Output = Self> + core::ops::Div<Output = Self> + core::ops::Neg<Output = Self> {
    /// A constant of the robot, rounded to this type.
    fn k(x: f64) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
}

impl Real for f64 {
    #[inline(always)]
    fn k(x: f64) -> Self { x }
    #[inline(always)]
    fn sin(self) -> Self { f64::sin(self) }
    #[inline(always)]
    fn cos(self) -> Self { f64::cos(self) }
}

impl Real for f32 {
    #[inline(always)]
    fn k(x: f64) -> Self { x as f32 }
    #[inline(always)]
    fn sin(self) -> Self { f32::sin(self) }
    #[inline(always)]
    fn cos(self) -> Self { f32::cos(self) }
}

/// `N` states evaluated by one call, one per lane (`q[j].0[l]` is joint j of state l), for
/// sweeping many knot points: every lane runs exactly the f64 operations of a scalar call,
/// so results are bit-identical, and the compiler can put the lanes in SIMD registers.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(dead_code)]
pub struct Lanes<const N: usize>(pub [f64; N]);

impl<const N: usize> core::ops::Add for Lanes<N> {
    type Output = Self;
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] + b.0[l]))
    }
}

impl<const N: usize> core::ops::Sub for Lanes<N> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] - b.0[l]))
    }
}

impl<const N: usize> core::ops::Mul for Lanes<N> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] * b.0[l]))
    }
}

impl<const N: usize> core::ops::Div for Lanes<N> {
    type Output = Self;
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] / b.0[l]))
    }
}

impl<const N: usize> core::ops::Neg for Lanes<N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self { Lanes(self.0.map(|x| -x)) }
}

impl<const N: usize> Real for Lanes<N> {
    #[inline(always)]
    fn k(x: f64) -> Self { Lanes([x; N]) }
    #[inline(always)]
    fn sin(self) -> Self { Lanes(self.0.map(f64::sin)) }
    #[inline(always)]
    fn cos(self) -> Self { Lanes(self.0.map(f64::cos)) }
}
"#;

/// The whole module for one robot, formatted. `kernels` in [`crate::ir::KERNELS`] order.
pub fn emit(model: &Model, kernels: &[Kernel], gravity: [f64; 3], options: &RustOptions) -> Result<String, syn::Error> {
    let nv = model.nv();
    let mut out = String::new();
    let _ = writeln!(out, "/// The robot's name in its URDF.\n#[allow(dead_code)]\npub const ROBOT: &str = {};", string_literal(&model.name));
    let _ = writeln!(out, "/// Number of movable joints (and of entries in every vector).\n#[allow(dead_code)]\npub const NV: usize = {nv};");
    let names: Vec<String> = model.joints.iter().map(|j| string_literal(&j.name)).collect();
    let _ = writeln!(out, "/// Movable joints in model order: depth-first from the root, children in document order.\n#[allow(dead_code)]\npub const JOINT_NAMES: [&str; NV] = [{}];", names.join(", "));
    let parents: Vec<String> = model.joints.iter().map(|j| j.parent.map_or("None".into(), |p| format!("Some({p})"))).collect();
    let _ = writeln!(
        out,
        "/// Parent joint of each joint (`None`: the fixed root).\n#[allow(dead_code)]\npub const PARENTS: [Option<usize>; NV] = [{}];",
        parents.join(", ")
    );
    let _ = writeln!(
        out,
        "/// Gravity in the root frame, m/s^2, fixed at generation time.\n#[allow(dead_code)]\npub const GRAVITY: [f64; 3] = [{}, {}, {}];",
        literal(gravity[0]),
        literal(gravity[1]),
        literal(gravity[2])
    );
    out.push_str(PRELUDE);
    for k in kernels {
        emit_kernel(&mut out, k, nv, options);
    }
    let file = syn::parse_file(&out)?;
    Ok(prettyplease::unparse(&file))
}
