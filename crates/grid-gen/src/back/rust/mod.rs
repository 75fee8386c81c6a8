//! The Rust backend: straight-line, sparsity-specialised code, generic over f32 and f64,
//! split into functions of at most `chunk` statements (rustc's time grows faster than
//! linearly in the size of one function; the split is the IR's [`Chunks`]).

mod format;
mod mixed;
mod split;

use std::collections::HashMap;
use std::fmt::Write;

pub use mixed::emit_mixed_kernel;

use super::names::{identifier, string_literal};
use super::{GeneratedFile, Target};
use crate::ir::schedule::Chunks;
use crate::ir::{
    ColumnProgram, ColumnStep, ColumnStore, DenseProduct, Function, Id, Module, Op, Operand, Shape,
    Stage,
};

/// The public API of a module with `kernels`, for the file's header.
fn api_doc<'a>(kernels: impl Iterator<Item = &'a Function>) -> String {
    let mut s = String::from(
        "Everything in this module is specialised to one robot. Vectors are `[T; NV]` in the order of\n\
         `JOINT_NAMES`; matrices are `[[T; NV]; NV]`, row-major, `m[i][j] = d out_i / d in_j`. `T` is `f64`\n\
         or `f32` (see [`Real`]), or several states per call: `F64x4` and `F32x8` (one AVX register, on x86-64 with AVX2\n\
         and FMA; the fastest per state) or the portable `Lanes<N>` (`Lanes<N, f32>`). Gravity is fixed at generation\n\
         time (`GRAVITY`).\n\n",
    );
    for k in kernels {
        let _ = writeln!(s, "- `{}`: {}", k.signature(), k.summary());
    }
    s
}

/// Options of the Rust backend.
#[derive(Clone, Debug)]
pub struct RustOptions {
    /// Most statements in one generated function.
    pub chunk: usize,
    /// Also emit the `avx512` copy (the `fma` copy's operations compiled for AVX-512 F and
    /// VL, dispatched first where the CPU has them). Off by default: it adds half again to
    /// the module's size and release compile time (Atlas: 32 s -> 47 s) for 5-12% on the
    /// gradients of an AVX-512 CPU (the book, Speed).
    pub avx512: bool,
    /// Which copies of the kernels the module holds.
    pub copies: Copies,
    /// Gate each kernel's items behind a Cargo feature of its name (`#[cfg(feature =
    /// "fd_grad")]`), so that a loader can compile a large robot's kernels in several
    /// crates at once, one per core: rustc's front end runs on one thread per crate
    /// (`grid_gen.load`; the book, Compile time). Off by default: a module included as it
    /// is holds every kernel.
    pub kernel_features: bool,
}

impl Default for RustOptions {
    fn default() -> Self {
        RustOptions { chunk: 2500, avx512: false, copies: Copies::Dispatch, kernel_features: false }
    }
}

/// Which machine-code copies of the kernels a module holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Copies {
    /// `portable` and `fma` (and `avx512` with [`RustOptions::avx512`]), chosen per call by
    /// the CPU's features: a library that runs on any CPU, at several times the compile
    /// time of one copy.
    #[default]
    Dispatch,
    /// Only `portable`: separate multiplies and adds, for any target.
    Portable,
    /// Only `fma`, for x86-64 with AVX2 and FMA; elsewhere every kernel panics. Its results
    /// are `Dispatch`'s on such a CPU, bit for bit, and it compiles about 4x faster than
    /// `Dispatch` (a floating tree's stabilised step: 85 s and 2.0 GB against 21 s and
    /// 0.9 GB, docs/guide/compile-time.md): what `grid_gen.load` builds on a machine that
    /// has them, since its library runs where it was compiled.
    Fma,
}

impl Copies {
    /// The one copy this machine runs: `Fma` on x86-64 with AVX2 and FMA, else `Portable`.
    pub fn host() -> Copies {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
            return Copies::Fma;
        }
        Copies::Portable
    }

    pub fn name(self) -> &'static str {
        match self {
            Copies::Dispatch => "dispatch",
            Copies::Portable => "portable",
            Copies::Fma => "fma",
        }
    }

    /// `dispatch`, `portable`, `fma`, or `host` (this machine's one copy, [`Copies::host`]).
    pub fn parse(name: &str) -> Option<Copies> {
        match name {
            "host" => Some(Copies::host()),
            _ => [Copies::Dispatch, Copies::Portable, Copies::Fma]
                .into_iter()
                .find(|c| c.name() == name),
        }
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

fn operand(k: &Function, names: &Chunks, here: usize, id: Id) -> String {
    match k.op(id) {
        Op::Const(c) => format!("lit::<T>({})", literal(c)),
        Op::Input(which, j) => input_place(k, which, j),
        // A value the callee keeps in its slots (`ir::Call::shared`).
        _ if names.provided.get(id.0 as usize).is_some_and(Option::is_some) => {
            format!("sc.{}", names.provided[id.0 as usize].unwrap_or_default())
        }
        _ if names.chunk_of[id.0 as usize] == Some(here as u32) => format!("t{}", id.0),
        _ => format!(
            "s.{}",
            names.slot[id.0 as usize].expect("values read by a later chunk have a slot")
        ),
    }
}

/// Entry `j` of an input: `q[3]`; a rest's callee outputs in their own shapes
/// (`called_dqdd_dq[2][5]`).
fn input_place(k: &Function, which: crate::ir::Input, j: u16) -> String {
    let index: String = input_index(k, which, j).iter().map(|i| format!("[{i}]")).collect();
    format!("{}{index}", which.name())
}

/// The indices of entry `j` of an input in its own shape.
fn input_index(k: &Function, which: crate::ir::Input, j: u16) -> Vec<usize> {
    match which {
        crate::ir::Input::Called(c) => crate::ir::Input::called_shape(c).index(j.into(), &k.dims),
        _ => vec![j.into()],
    }
}

/// Where consecutive entries lie in one innermost row of an array: the place of the row
/// (`a[3]`) and the first entry's index in it, if `index` gives each entry's indices.
fn row_run(name: &str, n: usize, index: impl Fn(usize) -> Vec<usize>) -> Option<(String, usize)> {
    let (first, last) = (index(0), index(n.checked_sub(1)?));
    let (prefix, start) = first.split_last().map(|(s, p)| (p, *s))?;
    let consecutive = (0..n).all(|i| {
        let at = index(i);
        at.split_last().is_some_and(|(s, p)| p == prefix && *s == start + i)
    });
    (consecutive && last.len() == first.len()).then(|| {
        (format!("{name}{}", prefix.iter().map(|i| format!("[{i}]")).collect::<String>()), start)
    })
}

/// A program's init row that copies consecutive entries of one input (the callee's
/// outputs in a step's rest), as one loop instead of a statement per column.
fn init_row_copy(k: &Function, ops: &[Operand], place: &str, at: usize) -> Option<String> {
    let input = |o: &Operand| match *o {
        Operand::Node(id) | Operand::Neg(id) => match k.op(id) {
            Op::Input(which, j) => Some((which, j, matches!(o, Operand::Neg(_)))),
            _ => None,
        },
        Operand::Const(_) => None,
    };
    let (which, j0, neg) = input(ops.first()?)?;
    let same = ops.iter().enumerate().all(|(c, o)| {
        input(o).is_some_and(|(w, j, n)| {
            w == which && usize::from(j) == usize::from(j0) + c && n == neg
        })
    });
    if !same {
        return None;
    }
    let (row, start) =
        row_run(which.name(), ops.len(), |c| input_index(k, which, j0.saturating_add(c as u16)))?;
    let sign = if neg { "-" } else { "" };
    Some(format!("for c in 0..{} {{ {place}[{at} + c] = {sign}{row}[{start} + c]; }}", ops.len()))
}

/// The machine-code copy a function is emitted for.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Copy {
    /// Any target: separate multiplies and adds, the default x86-64 instruction set.
    Portable,
    /// x86-64 with AVX2 and FMA: three-operand instructions, ymm registers for
    /// `Lanes<4>`, and `mul_add` where a product is used once, by an addition.
    Fma,
    /// The `Fma` copy's operations, compiled for AVX-512 (F and VL): 32 vector registers
    /// instead of 16, so fewer spills in large kernels, and zmm for `Lanes<8>`. The same
    /// operations in the same order, so its results are bit-identical to the `fma` copy's.
    Avx512,
}

impl Copy {
    /// The attribute every function of the copy carries.
    fn attribute(self) -> &'static str {
        match self {
            Copy::Portable => "",
            Copy::Fma => "#[target_feature(enable = \"avx2,fma\")]\n",
            Copy::Avx512 => "#[target_feature(enable = \"avx512f,avx512vl,avx2,fma\")]\n",
        }
    }
}

/// Products that the FMA copy fuses into the one addition or subtraction that reads
/// them: used once, not an output, and in the same chunk as that use.
fn fusable(k: &Function, names: &Chunks) -> Vec<bool> {
    let mut uses = vec![0u32; k.nodes.len()];
    for node in &k.nodes {
        for o in node.op.operands() {
            uses[o.0 as usize] += 1;
        }
    }
    for o in &k.outputs {
        for id in &o.ids {
            uses[id.0 as usize] += 2;
        }
    }
    (0..k.nodes.len())
        .map(|i| matches!(k.nodes[i].op, Op::Mul(..)) && uses[i] == 1 && names.slot[i].is_none())
        .collect()
}

/// `a * b + c` as one rounding: `T::mul_add(a, b, c)`.
fn fused(k: &Function, names: &Chunks, here: usize, op: Op, fuse: &[bool]) -> Option<String> {
    let o = |id| operand(k, names, here, id);
    let product = |id: Id| match k.op(id) {
        Op::Mul(x, y) if fuse[id.0 as usize] => Some((x, y)),
        _ => None,
    };
    match op {
        Op::Add(a, b) => {
            if let Some((x, y)) = product(a) {
                Some(format!("T::mul_add({}, {}, {})", o(x), o(y), o(b)))
            } else {
                product(b).map(|(x, y)| format!("T::mul_add({}, {}, {})", o(x), o(y), o(a)))
            }
        }
        // a - x y = (-x) y + a (negation is exact); x y - b = x y + (-b).
        Op::Sub(a, b) => {
            if let Some((x, y)) = product(b) {
                Some(format!("T::mul_add(-{}, {}, {})", o(x), o(y), o(a)))
            } else {
                product(a).map(|(x, y)| format!("T::mul_add({}, {}, -{})", o(x), o(y), o(b)))
            }
        }
        _ => None,
    }
}

fn expression(k: &Function, names: &Chunks, here: usize, op: Op) -> String {
    let o = |id| operand(k, names, here, id);
    match op {
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
}

/// An output's array type with elements `t`: `[t; NV]`, `[[t; NV]; NV]`, and per frame
/// `[[t; K]; NF]` or `[[[t; NV]; 6]; NF]`.
pub(super) fn array_of(shape: Shape, t: &str) -> String {
    match shape {
        Shape::Vector => format!("[{t}; NV]"),
        Shape::Matrix => format!("[[{t}; NV]; NV]"),
        Shape::PerFrame(k) => format!("[[{t}; {k}]; NF]"),
        Shape::FrameMatrix(r) => format!("[[[{t}; NV]; {r}]; NF]"),
        Shape::Config => format!("[{t}; NQ]"),
        Shape::StateMatrix => format!("[[{t}; NX]; NX]"),
        Shape::StateInput => format!("[[{t}; NU]; NX]"),
        Shape::ByFext => format!("[[{t}; 6 * NFEXT]; NV]"),
        Shape::ByLambda => format!("[[{t}; NLAMBDA]; NV]"),
        Shape::Lambda => format!("[{t}; NLAMBDA]"),
        Shape::LambdaBy => format!("[[{t}; NV]; NLAMBDA]"),
        Shape::LambdaByState => format!("[[{t}; NX]; NLAMBDA]"),
        Shape::LambdaByInput => format!("[[{t}; NU]; NLAMBDA]"),
    }
}

fn output_type(shape: Shape) -> String {
    array_of(shape, "T")
}

fn output_place(k: &Function, out: usize, flat: usize, dims: &crate::ir::Dims) -> String {
    let o = &k.outputs[out];
    let index: String = o.shape.index(flat, dims).iter().map(|i| format!("[{i}]")).collect();
    format!("{}{index}", o.name)
}

/// The function's return expression: its output, or the tuple of its outputs.
fn return_value(k: &Function) -> String {
    if k.outputs.len() == 1 {
        k.outputs[0].name.to_string()
    } else {
        format!("({})", k.outputs.iter().map(|o| o.name).collect::<Vec<_>>().join(", "))
    }
}

/// Output places written once from a constant or an input, and per computed node the places
/// that take its value.
type OutputStores = (Vec<(String, Id)>, HashMap<Id, Vec<String>>);

/// Where output values are stored: output places that take a constant or an input
/// (written once, up front), and for each computed node the places that take its value.
/// Outputs start at zero, so structural zeros need no store.
fn output_stores(k: &Function) -> OutputStores {
    let dims = &k.dims;
    let mut sinks: HashMap<Id, Vec<String>> = HashMap::new();
    let mut inline_outputs = Vec::new();
    for (oi, o) in k.outputs.iter().enumerate() {
        for (flat, &id) in o.ids.iter().enumerate() {
            let place = output_place(k, oi, flat, dims);
            match k.op(id) {
                Op::Const(0.0) => {}
                Op::Const(_) | Op::Input(..) => inline_outputs.push((place, id)),
                _ => sinks.entry(id).or_default().push(place),
            }
        }
    }
    (inline_outputs, sinks)
}

/// The dense product the `fma` and `avx512` copies run as a loop instead of the graph's
/// straight-line dot products: `fd_grad`'s `−M⁻¹ ∂c/∂u` where ∂c/∂u has at least 3/4 of its
/// entries non-zero (iiwa: all of them; HyQ's block structure and Atlas's branches leave
/// 1/8 to 1/7 of the dense operations, which the straight-line code already skips). A
/// prototype measured the loop at 80-90 ns against 170-200 ns straight-line in iiwa's
/// `fd_grad` (docs/bench/product-loop-prototype/). The portable copy keeps the graph's
/// order, so it stays bit-identical to the IR.
fn looped_product(k: &Function, nv: usize, copy: Copy) -> Option<&DenseProduct> {
    let p = k.product.as_ref().filter(|_| copy != Copy::Portable && nv > 0)?;
    let nonzero = p
        .dc
        .iter()
        .flatten()
        .filter(|o| match **o {
            Operand::Const(c) => c != 0.0,
            Operand::Node(id) | Operand::Neg(id) => !matches!(k.op(id), Op::Const(c) if c == 0.0),
        })
        .count();
    // The loop replaces the `Combine` nodes, so nothing else may read them (with coupled
    // mimic joints, for one, the graph goes on after the product).
    let combine = |id: Id| k.nodes[id.0 as usize].stage == Stage::Combine;
    let read_elsewhere =
        k.nodes.iter().any(|n| n.stage != Stage::Combine && n.op.operands().any(combine))
            || k.outputs
                .iter()
                .any(|out| !p.outputs.contains(&out.name) && out.ids.iter().any(|&id| combine(id)));
    (!read_elsewhere && 4 * nonzero >= 3 * p.dc.len() * nv * nv).then_some(p)
}

/// Names of the local matrices that hold a looped product's operands: M⁻¹, then each ∂c/∂u.
fn operand_names(p: &DenseProduct) -> Vec<String> {
    std::iter::once("pm".to_string()).chain((0..p.dc.len()).map(|i| format!("pd{i}"))).collect()
}

/// The fewest operations of `fd_grad`'s straight-line solves for which this backend runs
/// them as their per-column program instead ([`ColumnProgram::replaces`]), where the program
/// does at most 1.5 times their operations (it cannot skip the steps a column's zeros make
/// empty).
/// Measured with `grid-gen bench --backend rust`, the `fma` copy, side by side with the
/// straight-line solves (2026-11-27, AMD EPYC, 32 KiB instruction cache): floating Atlas's
/// solves, 81,054 operations straight and 87,912 as a program, went from 19.2 to 14.3 µs;
/// floating HyQ's, 11,556 and 12,960, from 2.7 to 2.9 µs; fixed Atlas's, 16,854 and 32,400,
/// from 5.5 to 7.5 µs. Straight-line code that fits the instruction caches, or nearly, runs
/// faster than loops that load and store every row at every step; floating Atlas's streams
/// from L2 on every call (`scripts/cache_stats.py`: every line of Atlas's kernels misses
/// the L1 instruction cache on every call). A CPU with another instruction cache may want
/// another threshold: it is this backend's, not the IR's.
const PROGRAM_MIN_OPS: usize = 32_000;

/// The column program a copy of `k` runs instead of the graph's statements for its
/// outputs, if any: every program that is cheaper everywhere, and one that replaces
/// straight-line code where that code is large ([`PROGRAM_MIN_OPS`]).
fn runs_program(k: &Function) -> Option<&ColumnProgram> {
    k.program.as_ref().filter(|p| match p.replaces {
        None => true,
        Some(straight) => {
            let looped: usize = p.blocks.iter().map(|b| 2 * b.steps.len() * b.columns()).sum();
            straight >= PROGRAM_MIN_OPS && 2 * looped <= 3 * straight
        }
    })
}

/// The operations a copy of `k` holds as statements: its graph's, less those its column
/// program computes in loops instead. What rustc compiles for it, by which a loader
/// balances the crates it builds ([`RustOptions::kernel_features`]).
pub fn statements(k: &Function) -> usize {
    let skip = runs_program(k).map(|p| program_skip(k, p));
    k.nodes
        .iter()
        .enumerate()
        .filter(|(i, n)| {
            !matches!(n.op, Op::Input(..) | Op::Const(_))
                && !skip.as_ref().is_some_and(|skip| skip[*i])
        })
        .count()
}

/// The position of output `name` of `k`, which a program or a product stores into
/// (`ir::validate` checks that `k` has it).
fn out_index(k: &Function, name: &str) -> usize {
    k.output_index(name).expect("a validated kernel's program and product store into its outputs")
}

/// A kernel whose rest computes its callees' arguments ([`crate::ir::Call::ahead`]): the
/// kernel, its call, its robot, and its callee where the rest reads values the callee keeps
/// ([`crate::ir::Call::shared`]).
type Within<'a> =
    (&'a Function, &'a crate::ir::Call, &'a crate::ir::Robot, Option<&'a split::SplitCallee<'a>>);

/// Writes one copy of kernel `k` as the function `name`. With `within`, `k` is that kernel's
/// rest, written as the kernel itself: its parts before the call, the call, the others.
/// `own`: `k` as its callers run it, where their rests read values it keeps.
#[allow(clippy::too_many_arguments)]
fn emit_kernel(
    out: &mut String,
    k: &Function,
    name: &str,
    nv: usize,
    q_len: &str,
    options: &RustOptions,
    copy: Copy,
    within: Option<Within>,
    own: Option<&split::SplitCallee>,
) {
    let (mut names, first_after) = match within {
        Some((_, call, _, _)) => Chunks::split(k, options.chunk, &call.ahead),
        None => match own {
            Some(own) => (own.names.clone(), own.first),
            None => (Chunks::new(k, options.chunk), 0),
        },
    };
    let callee = within.and_then(|w| w.3);
    if let (Some((_, call, _, _)), Some(callee)) = (within, callee) {
        names.provided = callee.provided(call);
    }
    let provided: Vec<bool> = names.provided.iter().map(Option::is_some).collect();
    let looped = looped_product(k, nv, copy);
    // Every copy runs a program as loops: the portable one too, since on a target without
    // the SIMD copies (aarch64, or x86-64 without FMA) its straight-line form is the
    // instruction-cache-bound code the program replaces (side by side, portable copy on
    // x86-64: floating HyQ's `contact_fd_grad` 20 -> 13 us, floating Atlas's `fd_grad` 33 ->
    // 23 us; docs/bench/portable-loops-2026-11-27.md).
    let program = runs_program(k).filter(|_| looped.is_none());
    let coefs = program.map(|p| ProgramCoefs::of(k, p));
    // With a looped product, the graph's product nodes are not emitted; with a program, the
    // nodes only its outputs read.
    let mut skip: Vec<bool> =
        k.nodes.iter().map(|n| looped.is_some() && n.stage == Stage::Combine).collect();
    if let Some(p) = program {
        skip = program_skip(k, p);
    }
    // What the callee provides is read, not computed, and so is what only it reads.
    if !provided.is_empty() {
        let live = crate::ir::live_through(k, &provided);
        for (i, s) in skip.iter_mut().enumerate() {
            *s |= !live[i] || provided[i];
        }
    }
    let mut fuse =
        if copy != Copy::Portable { fusable(k, &names) } else { vec![false; k.nodes.len()] };
    for (f, _) in fuse.iter_mut().zip(&provided).filter(|(_, &p)| p) {
        *f = false;
    }
    // The operands are stored into the loops' matrices, so they must exist.
    let product_operands =
        looped.into_iter().flat_map(|p| p.minv.iter().chain(p.dc.iter().flatten()).copied());
    for o in product_operands.chain(program.into_iter().flat_map(|p| p.operands())) {
        if let Operand::Node(id) | Operand::Neg(id) = o {
            fuse[id.0 as usize] = false;
        }
    }
    // A product is dropped only where its one user fuses it.
    let mut dropped = vec![false; k.nodes.len()];
    for (i, node) in k.nodes.iter().enumerate() {
        if skip[i] {
            continue;
        }
        if let Op::Add(a, b) | Op::Sub(a, b) = node.op {
            if fuse[a.0 as usize] {
                dropped[a.0 as usize] = true;
            } else if fuse[b.0 as usize] {
                dropped[b.0 as usize] = true;
            }
        }
    }
    let chunks = &names.chunks;
    let Signature { args, arg_names, .. } = Signature::of(k, q_len);
    let ret_value = return_value(k);
    let (mut inline_outputs, mut sinks) = output_stores(k);
    let operand_mats = looped.map(operand_names).unwrap_or_default();
    // Local arrays the operands are stored into, with their types.
    let mut locals: Vec<(String, String)> =
        operand_mats.iter().map(|m| (m.clone(), "[[T; NV]; NV]".to_string())).collect();
    let layouts: Vec<BlockLayout> = program
        .map(|p| p.blocks.iter().map(|b| BlockLayout::of(k, b, p.rows)).collect())
        .unwrap_or_default();
    if let (Some(p), Some(c)) = (program, &coefs) {
        // One slot more than the coefficients: a zero, for a step that scales by zero.
        locals.push(("pc".to_string(), format!("[T; {}]", c.slots.len() + 1)));
        for (b, block) in p.blocks.iter().enumerate() {
            if layouts[b].scratch > 0 {
                locals.push((
                    format!("pb{b}"),
                    format!("[[T; {}]; {}]", block.columns(), layouts[b].scratch),
                ));
            }
        }
    }
    // Each array a part writes by constant index, as a `repr(C)` tuple struct of its
    // entries (`a.185` for `a[2][41]`): like the slots, a field type-checks several times
    // faster than an index (the humanoid's type checking: 25 -> 8 s without these writes).
    let mut arrays: Vec<(String, String, usize)> =
        k.outputs.iter().map(|o| (o.name.to_string(), output_type(o.shape), o.ids.len())).collect();
    let mut field_of: HashMap<String, String> = HashMap::new();
    for (oi, o) in k.outputs.iter().enumerate() {
        for flat in 0..o.ids.len() {
            field_of.insert(output_place(k, oi, flat, &k.dims), format!("{}.{flat}", o.name));
        }
    }
    for (m, ty) in &locals {
        // `[T; n]` or `[[T; c]; r]` with numbers or NV.
        let dim = |d: &str| if d == "NV" { nv } else { d.parse::<usize>().unwrap_or(0) };
        let parts: Vec<&str> = ty
            .trim_start_matches('[')
            .split(';')
            .skip(1)
            .map(|d| d.trim_end_matches(']').trim())
            .collect();
        let (rows, cols) = match parts.as_slice() {
            [n] => (1, dim(n)),
            [c, r] => (dim(r), dim(c)),
            _ => (0, 0),
        };
        for r in 0..rows {
            for c in 0..cols {
                let place =
                    if parts.len() == 1 { format!("{m}[{c}]") } else { format!("{m}[{r}][{c}]") };
                field_of.insert(place, format!("{m}.{}", r * cols + c));
            }
        }
        arrays.push((m.clone(), ty.clone(), rows * cols));
    }
    let field = |place: &str| field_of.get(place).cloned().unwrap_or_else(|| place.to_string());
    // The operands reach their matrices as outputs do; negations and constants the graph
    // no longer holds are written just before the loop (`fixups`).
    let mut fixups = Vec::new();
    // A program's init rows that copy an input's row, as loops run before the program.
    let mut row_copies = Vec::new();
    if let Some(p) = looped {
        for (m, ids) in operand_mats.iter().zip(std::iter::once(&p.minv).chain(&p.dc)) {
            for (flat, &o) in ids.iter().enumerate() {
                let place = format!("{m}[{}][{}]", flat / nv, flat % nv);
                place_operand(k, place, o, &mut fixups, &mut inline_outputs, &mut sinks);
            }
        }
    }
    if let (Some(p), Some(c)) = (program, &coefs) {
        let places = c.slots.iter().enumerate().map(|(i, &o)| (format!("pc[{i}]"), o));
        for (place, o) in places {
            place_operand(k, place, o, &mut fixups, &mut inline_outputs, &mut sinks);
        }
        // The program writes its stored entries: the graph's own stores of them go (their
        // nodes are not emitted, but a constant or an input's would be).
        let stored: std::collections::HashSet<String> = p
            .blocks
            .iter()
            .flat_map(|b| b.stores.iter())
            .flat_map(|st| {
                st.flat.iter().map(|&f| output_place(k, out_index(k, st.output), f, &k.dims))
            })
            .collect();
        inline_outputs.retain(|(place, _)| !stored.contains(place));
        for places in sinks.values_mut() {
            places.retain(|place| !stored.contains(place));
        }
        for (b, block) in p.blocks.iter().enumerate() {
            for (row, ops) in block.init.iter().enumerate() {
                let (dst, start) = match &layouts[b].homes[row] {
                    RowHome::Output { row: prefix, start, .. } => (prefix.clone(), *start),
                    RowHome::Scratch(i) => (format!("pb{b}[{i}]"), 0),
                    RowHome::Unused => continue,
                };
                if let Some(copy) = init_row_copy(k, ops, &dst, start) {
                    row_copies.push(copy);
                    continue;
                }
                for (col, &o) in ops.iter().enumerate() {
                    let place = layouts[b].place(k, b, block, row, col);
                    place_operand(k, place, o, &mut fixups, &mut inline_outputs, &mut sinks);
                }
            }
        }
    }
    // In a part, the arrays are views with one field per entry (see `arrays`).
    let parted = chunks.len() > 1 || within.is_some() || own.is_some();
    // A part before the call takes no callee's output.
    let takes = |c: usize, i: usize| {
        within.is_none()
            || c >= first_after
            || !matches!(k.inputs()[i], crate::ir::Input::Called(_))
    };
    let at = |place: &str| if parted { field(place) } else { place.to_string() };
    let body = |c: usize, ids: &[Id]| -> String {
        let mut b = String::new();
        // Within a kernel, the entries that copy a callee's outputs wait for the call.
        let called = |id: Id| matches!(k.op(id), Op::Input(crate::ir::Input::Called(_), _));
        // A callee that runs its first parts before its caller has set q̈ and λ writes the
        // entries that copy an input after them ([`split::chunks`]).
        let input = |id: Id| matches!(k.op(id), Op::Input(..));
        for (place, id) in &inline_outputs {
            let waits = (within.is_some() && called(*id)) || (own.is_some() && input(*id));
            let due = if waits { first_after } else { 0 };
            if c == due {
                let _ = writeln!(b, "{} = {};", at(place), operand(k, &names, c, *id));
            }
        }
        for &id in ids {
            if provided.get(id.0 as usize).is_some_and(|&p| p) {
                for place in sinks.get(&id).into_iter().flatten() {
                    let _ = writeln!(b, "{} = {};", at(place), operand(k, &names, c, id));
                }
                continue;
            }
            if dropped[id.0 as usize] || skip[id.0 as usize] {
                continue;
            }
            let expr = fused(k, &names, c, k.op(id), &dropped)
                .unwrap_or_else(|| expression(k, &names, c, k.op(id)));
            let _ = writeln!(b, "let t{} = {expr};", id.0);
            if let Some(s) = names.slot[id.0 as usize] {
                let _ = writeln!(b, "s.{s} = t{};", id.0);
            }
            for place in sinks.get(&id).into_iter().flatten() {
                let _ = writeln!(b, "{} = t{};", at(place), id.0);
            }
        }
        b
    };

    let attr = copy.attribute();
    let doc = if let Some((_, call, _, _)) = within {
        let calls: Vec<String> = call.callees.iter().map(|c| format!("[`{c}`]")).collect();
        format!(
            "{}\n///\n/// Computes its q̈ (and λ), runs {} there, then the rest of its work.",
            k.doc(),
            calls.join(", ")
        )
    } else if name == k.kind.name() {
        k.doc()
    } else {
        format!(
            "The part of [`{}`] after the kernel it calls (see [`{}`]).",
            k.kind.name(),
            k.kind.name()
        )
    };
    let into = open_function(out, within.map_or(k, |w| w.0), name, &doc, q_len, copy);
    if !into {
        emit_output_init(out, k);
    }
    for (m, ty) in &locals {
        let _ = writeln!(out, "let mut {m} = {};", ty.replace("T;", "lit::<T>(0.0);"));
    }
    if !parted {
        out.push_str(&body(0, &chunks[0]));
    } else {
        let _ = writeln!(
            out,
            "let mut s = [lit::<T>(0.0); {n}];\n\
             // SAFETY: `{name}_slots` is `repr(C)` with {n} fields of type T: the array's layout.\n\
             let s = unsafe {{ &mut *(&mut s as *mut [T; {n}] as *mut {name}_slots<T>) }};",
            n = names.slots
        );
        // In `{name}_into` the outputs are references already.
        let outs: Vec<String> = k
            .outputs
            .iter()
            .map(|o| if into { o.name.to_string() } else { format!("&mut {}", o.name) })
            .chain(locals.iter().map(|(m, _)| format!("&mut {m}")))
            .collect();
        // The callee's parts that compute what the rest reads of it run first.
        let sc = match (within, callee) {
            (Some((outer, ..)), Some(callee)) => Some(open_split_callee(out, outer, callee, into)),
            _ => None,
        };
        for c in 0..chunks.len() {
            if let Some((outer, call, robot, _)) = within.filter(|_| c == first_after) {
                match (&sc, callee) {
                    (Some(parts), Some(callee)) => {
                        for part in callee.first..callee.names.chunks.len() {
                            let _ = writeln!(out, "{}", parts.call(part));
                        }
                    }
                    _ => write_callee_calls(out, outer, &call.callees, robot, into, true),
                }
            }
            // Within a kernel, the callees' outputs are its locals.
            let passed: Vec<String> = (0..arg_names.len())
                .filter(|&i| takes(c, i))
                .map(|i| match k.inputs()[i] {
                    crate::ir::Input::Called(_) if within.is_some() => format!("&{}", arg_names[i]),
                    _ => arg_names[i].to_string(),
                })
                .collect();
            let sc_arg = if callee.is_some() { "sc, " } else { "" };
            let _ = writeln!(
                out,
                "{name}_part{c}({}, s, {sc_arg}{});",
                passed.join(", "),
                outs.join(", ")
            );
        }
    }
    if let Some(p) = looped {
        emit_product_loop(out, k, p, &operand_mats, &fixups, nv);
    }
    if let Some(p) = program {
        for f in row_copies.iter().chain(&fixups) {
            let _ = writeln!(out, "{f}");
        }
        for (b, block) in p.blocks.iter().enumerate() {
            // A block of no columns stores nothing (each store has one entry per column).
            let cols = block.columns();
            if cols == 0 {
                continue;
            }
            // The block's rows as pointers into the outputs and its scratch rows, each from
            // one raw pointer per array so that none invalidates another.
            let layout = &layouts[b];
            let _ = writeln!(out, "{{");
            let mut bases: Vec<&str> =
                layout.homes.iter().filter_map(|h| h.output().map(|o| k.outputs[o].name)).collect();
            bases.sort_unstable();
            bases.dedup();
            for n in &bases {
                let ty = &arrays.iter().find(|(m, _, _)| m == n).expect("an output").1;
                let from = if into { n.to_string() } else { format!("&mut {n}") };
                let _ = writeln!(out, "let p_{n} = {from} as *mut {ty} as *mut T;");
            }
            if layout.scratch > 0 {
                let _ = writeln!(
                    out,
                    "let p_pb = &mut pb{b} as *mut [[T; {cols}]; {}] as *mut T;",
                    layout.scratch
                );
            }
            let rows: Vec<String> = layout
                .homes
                .iter()
                .map(|h| match h {
                    RowHome::Output { output, first, .. } => {
                        format!("p_{}.add({first}) as *mut [T; {cols}]", k.outputs[*output].name)
                    }
                    RowHome::Scratch(i) => format!("p_pb.add({}) as *mut [T; {cols}]", i * cols),
                    RowHome::Unused => "core::ptr::null_mut()".to_string(),
                })
                .collect();
            let _ = writeln!(
                out,
                "// SAFETY: each row is {cols} entries of one array, and no two rows overlap.
                 let rows: [*mut [T; {cols}]; {}] = unsafe {{ [{}] }};
                 {name}_cols{b}(&rows, &pc);
}}",
                rows.len(),
                rows.join(", ")
            );
            let stores: Vec<&ColumnStore> = block
                .stores
                .iter()
                .filter(|st| !matches!(layout.homes[st.row], RowHome::Output { .. }))
                .collect();
            if stores.is_empty() {
                continue;
            }
            // The stores read and write views, in a scope of their own so that the views'
            // borrows end before anything else touches the arrays.
            let view = |n: &str, owned: bool, mutable: bool| {
                let (ty, len) = arrays
                    .iter()
                    .find(|(m, _, _)| m == n)
                    .map(|(_, ty, len)| (ty.clone(), *len))
                    .expect("every stored array is an output or a local");
                let (r, p) = if mutable { ("&mut ", "*mut") } else { ("&", "*const") };
                let from = if owned { format!("{r}{n}") } else { format!("{r}*{n}") };
                format!("let {n} = unsafe {{ {r}*({from} as {p} {ty} as {p} {name}_f{len}<T>) }};")
            };
            // A store into consecutive entries of one row of its output is one loop; the
            // others, one statement per column through the views.
            let mut scattered = Vec::new();
            for st in stores {
                let RowHome::Scratch(i) = layout.homes[st.row] else { continue };
                let o = &k.outputs[out_index(k, st.output)];
                let run = row_run(o.name, cols, |c| o.shape.index(st.flat[c], &k.dims));
                match run {
                    Some((place, start)) => {
                        let sign = if st.negate { "-" } else { "" };
                        let _ = writeln!(
                            out,
                            "for c in 0..{cols} {{ {place}[{start} + c] = {sign}pb{b}[{i}][c]; }}"
                        );
                    }
                    None => scattered.push((st, i)),
                }
            }
            if scattered.is_empty() {
                continue;
            }
            let _ = writeln!(out, "{{\n{}", view(&format!("pb{b}"), true, false));
            let mut written: Vec<usize> =
                scattered.iter().map(|(st, _)| out_index(k, st.output)).collect();
            written.sort_unstable();
            written.dedup();
            for o in written {
                let _ = writeln!(out, "{}", view(k.outputs[o].name, !into, true));
            }
            for (st, i) in scattered {
                let sign = if st.negate { "-" } else { "" };
                for (col, &flat) in st.flat.iter().enumerate() {
                    let place = field(&output_place(k, out_index(k, st.output), flat, &k.dims));
                    let _ = writeln!(out, "{place} = {sign}pb{b}.{};", i * cols + col);
                }
            }
            let _ = writeln!(out, "}}");
        }
    }
    if into {
        let _ = writeln!(out, "}}\n");
    } else {
        let _ = writeln!(out, "{ret_value}\n}}\n");
    }
    if parted {
        // The values one part passes to a later one, as fields rather than an array's
        // entries: rustc type-checks `s.584` on a generic `T` several times faster than
        // `s[584]` (an `Index` obligation per access). Floating HyQ's gait library: the
        // front end 10.9 -> 5.4 s, its whole build 36 -> 30 s (the book, Compile time).
        let _ = writeln!(
            out,
            "/// The values `{name}`'s parts pass on: one field per slot.\n\
             #[repr(C)]\n#[allow(non_camel_case_types, dead_code)]\n\
             struct {name}_slots<T>({});\n",
            vec!["T"; names.slots].join(", ")
        );
    }
    if parted || program.is_some() {
        let mut lens: Vec<usize> = arrays.iter().map(|a| a.2).filter(|&n| n > 0).collect();
        lens.sort_unstable();
        lens.dedup();
        for len in lens {
            let _ = writeln!(
                out,
                "/// An array of {len} entries of `{name}`'s, one field per entry.\n\
                 #[repr(C)]\n#[allow(non_camel_case_types, dead_code)]\n\
                 struct {name}_f{len}<T>({});\n",
                vec!["T"; len].join(", ")
            );
        }
    }
    if parted {
        let outs: Vec<String> = k
            .outputs
            .iter()
            .map(|o| format!("{}: &mut {}", o.name, output_type(o.shape)))
            .chain(locals.iter().map(|(m, ty)| format!("{m}: &mut {ty}")))
            .collect();
        // Each part in a module of its own: rustc makes a codegen unit of each module, so the
        // parts compile on every core where one copy's module was one unit on one core
        // (floating HyQ's gait library: 23 -> 14 s on two cores; the book, Compile time).
        for (c, ids) in chunks.iter().enumerate() {
            let _ = writeln!(
                out,
                "mod {name}_part{c} {{\nuse super::*;\n\
                 #[inline(never)]\n{attr}#[allow(clippy::all, unused_variables, unused_mut)]"
            );
            let sc = callee
                .map(|callee| format!("sc: &{}_slots<T>, ", callee.f.kind.name()))
                .unwrap_or_default();
            let _ = writeln!(
                out,
                "pub(super) fn {name}_part{c}<T: Real>({}, s: &mut {name}_slots<T>, {sc}{}) {{",
                (0..args.len())
                    .filter(|&i| takes(c, i))
                    .map(|i| args[i].as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                outs.join(", ")
            );
            for (m, ty, len) in arrays.iter().filter(|a| a.2 > 0) {
                let _ = writeln!(
                    out,
                    "let {m} = unsafe {{ &mut *({m} as *mut {ty} as *mut {name}_f{len}<T>) }};"
                );
            }
            out.push_str(&body(c, ids));
            let _ = writeln!(out, "}}\n}}\nuse {name}_part{c}::{name}_part{c};\n");
        }
    }
    if let (Some(p), Some(c)) = (program, &coefs) {
        for (b, block) in p.blocks.iter().enumerate().filter(|(_, b)| b.columns() > 0) {
            emit_program_block(out, k, block, p.rows, c, &format!("{name}_cols{b}"), copy);
        }
    }
}

/// Writes the calls to `callees` ([`crate::ir::Call`]) into `body`, each output bound under
/// its `CALLED` name where a rest may read it. A callee takes the kernel's inputs of the
/// same name, a step's actuated τ spread over the coordinates (0 elsewhere), and what the
/// kernel does not take (`qdd`, `lambda`) from an earlier callee, or, with `own`, from the
/// kernel's outputs of that name, which its parts before the call have set.
fn write_callee_calls(
    body: &mut String,
    k: &Function,
    callees: &[crate::ir::KernelKind],
    robot: &crate::ir::Robot,
    into: bool,
    own: bool,
) {
    use crate::ir::Input;
    let spec = &robot.specialisation;
    let spread = k.inputs().contains(&Input::TauActuated);
    if spread {
        let _ = writeln!(body, "let mut called_tau = [lit::<T>(0.0); NV];");
        for (i, &c) in robot.actuated.iter().enumerate() {
            let _ = writeln!(body, "called_tau[{c}] = tau[{i}];");
        }
    }
    for (at, callee) in callees.iter().enumerate() {
        let args: Vec<String> = callee
            .inputs_for(spec)
            .iter()
            .map(|&i| callee_arg(k, i, &callees[..at], spread, into, own))
            .collect();
        // Each output under its `CALLED` name where the rest may read it.
        let bound: Vec<(String, crate::ir::Shape)> = callee
            .outputs_for(spec)
            .iter()
            .enumerate()
            .map(|(j, o)| {
                let name = match Input::called(*callee, o.name) {
                    Some(c) => c.name().to_string(),
                    None if into => format!("unread_{at}_{j}"),
                    None => "_".to_string(),
                };
                (name, o.shape)
            })
            .collect();
        let callee_name = callee.name();
        if into {
            for (c, shape) in &bound {
                let _ = writeln!(body, "let mut {c} = {};", array_of(*shape, "lit::<T>(0.0)"));
            }
            let refs: Vec<String> = bound.iter().map(|(c, _)| format!("&mut {c}")).collect();
            let _ = writeln!(body, "{callee_name}_into({}, {});", args.join(", "), refs.join(", "));
        } else {
            let names: Vec<&str> = bound.iter().map(|(c, _)| c.as_str()).collect();
            let pattern = if names.len() == 1 {
                names[0].to_string()
            } else {
                format!("({})", names.join(", "))
            };
            let _ = writeln!(body, "let {pattern} = {callee_name}({});", args.join(", "));
        }
    }
}

/// What a callee takes for its input `i` in kernel `k`: the kernel's input of the same name,
/// a step's actuated τ spread over the coordinates (`spread`), and what the kernel does not
/// take (`qdd`, `lambda`) from an earlier callee, or, with `own`, from the kernel's outputs of
/// that name, which its parts before the call have set (references already in `_into`).
fn callee_arg(
    k: &Function,
    i: crate::ir::Input,
    earlier: &[crate::ir::KernelKind],
    spread: bool,
    into: bool,
    own: bool,
) -> String {
    use crate::ir::Input;
    match i {
        Input::Tau if spread => "&called_tau".to_string(),
        _ if k.inputs().contains(&i) => i.name().to_string(),
        _ if own => {
            let o = k.outputs.iter().find(|o| o.name == i.name());
            let o = o.expect("a kernel that computes its callees' arguments outputs them");
            if into {
                format!("&*{}", o.name)
            } else {
                format!("&{}", o.name)
            }
        }
        _ => {
            let from = earlier
                .iter()
                .find_map(|c| Input::called(*c, i.name()))
                .expect("an earlier callee gives what the kernel does not take");
            format!("&{}", from.name())
        }
    }
}

/// A callee run as its parts within a kernel ([`split::SplitCallee`]): the calls to its parts.
struct SplitParts {
    name: &'static str,
    args: String,
}

impl SplitParts {
    /// The statement that runs the callee's part `part`.
    fn call(&self, part: usize) -> String {
        format!("{}_part{part}({});", self.name, self.args)
    }
}

/// Opens `callee` within kernel `k` (whose rest reads values it keeps): its outputs and its
/// slots (`sc`) as locals, and its first parts, which compute those values. Its outputs are
/// named as [`write_callee_calls`] names them, for the rest's parts after the call.
fn open_split_callee(
    out: &mut String,
    k: &Function,
    callee: &split::SplitCallee,
    into: bool,
) -> SplitParts {
    use crate::ir::Input;
    let f = callee.f;
    let name = f.kind.name();
    let spread = k.inputs().contains(&Input::TauActuated);
    let mut args: Vec<String> =
        f.inputs().iter().map(|&i| callee_arg(k, i, &[], spread, into, true)).collect();
    args.push("sc".to_string());
    for (j, o) in f.outputs.iter().enumerate() {
        let local = match Input::called(f.kind, o.name) {
            Some(c) => c.name().to_string(),
            None => format!("unread_{j}"),
        };
        let _ = writeln!(out, "let mut {local} = {};", array_of(o.shape, "lit::<T>(0.0)"));
        args.push(format!("&mut {local}"));
    }
    let _ = writeln!(
        out,
        "let mut sc = [lit::<T>(0.0); {n}];\n\
         // SAFETY: `{name}_slots` is `repr(C)` with {n} fields of type T: the array's layout.\n\
         let sc = unsafe {{ &mut *(&mut sc as *mut [T; {n}] as *mut {name}_slots<T>) }};",
        n = callee.names.slots
    );
    let parts = SplitParts { name, args: args.join(", ") };
    for part in 0..callee.first {
        let _ = writeln!(out, "{}", parts.call(part));
    }
    parts
}

/// A kernel that runs its callees and then its rest ([`crate::ir::Call`]): the callees'
/// outputs that the rest reads are its last inputs. A callee takes the kernel's inputs of
/// the same name, a step's actuated τ spread over the coordinates (0 elsewhere), and what
/// the kernel does not take (`qdd`, `lambda`) from an earlier callee. A SIMD copy's `{name}_into` passes its outputs on to
/// the rest's.
fn emit_call(
    out: &mut String,
    k: &Function,
    call: &crate::ir::Call,
    robot: &crate::ir::Robot,
    copy: Copy,
) {
    use crate::ir::Input;
    let name = k.kind.name();
    let into = copy != Copy::Portable;
    let rest_args: Vec<String> = call
        .rest
        .inputs()
        .iter()
        .map(|i| {
            if matches!(i, Input::Called(_)) {
                format!("&{}", i.name())
            } else {
                i.name().to_string()
            }
        })
        .collect();
    let mut body = String::new();
    write_callee_calls(&mut body, k, &call.callees, robot, into, false);
    if into {
        let outs: Vec<&str> = k.outputs.iter().map(|o| o.name).collect();
        let _ = writeln!(body, "{name}_rest_into({}, {});", rest_args.join(", "), outs.join(", "));
    } else {
        let _ = writeln!(body, "{name}_rest({})", rest_args.join(", "));
    }
    let calls: Vec<String> = call.callees.iter().map(|c| format!("[`{c}`]")).collect();
    let their = if calls.len() == 1 { "its" } else { "their" };
    let doc = format!(
        "{}\n///\n/// Runs {}, then [`{name}_rest`] on {their} outputs.",
        k.doc(),
        calls.join(", ")
    );
    open_function(out, k, name, &doc, q_len(robot), copy);
    let _ = writeln!(out, "{body}}}\n");
}

/// Opens a copy's public function `name` (its doc, attributes and signature). In a SIMD copy
/// it also writes the whole of it, which sets the outputs by the checked `T::k` and hands
/// them to `{name}_into`, and opens `{name}_into`: a SIMD copy's body writes into its
/// caller's outputs, which the dispatcher passes as its own (see `emit_dispatcher`). The
/// caller writes the body next; returns whether that is `{name}_into`'s.
fn open_function(
    out: &mut String,
    k: &Function,
    name: &str,
    doc: &str,
    q_len: &str,
    copy: Copy,
) -> bool {
    let Signature { args, arg_names, ret_type } = Signature::of(k, q_len);
    let attr = copy.attribute();
    let _ = writeln!(out, "/// {doc}");
    let _ = writeln!(
        out,
        "#[inline]\n{attr}#[allow(clippy::all, unused_variables, unused_mut, dead_code)]"
    );
    let _ = writeln!(out, "pub fn {name}<T: Real>({}) -> {ret_type} {{", args.join(", "));
    let into = copy != Copy::Portable;
    if into {
        emit_output_init(out, k);
        let _ = writeln!(
            out,
            "{name}_into({}, {});\n{}\n}}\n",
            arg_names.join(", "),
            output_refs(k),
            return_value(k)
        );
        let params: Vec<String> = k
            .outputs
            .iter()
            .map(|o| format!("{}: &mut {}", o.name, output_type(o.shape)))
            .collect();
        let _ = writeln!(
            out,
            "/// [`{name}`] into outputs that start at zero, set by `T::k(0.0)` (which has run the\n\
             /// CPU check that makes `lit` sound for the SIMD types).\n\
             #[inline]\n{attr}#[allow(clippy::all, unused_variables, unused_mut, dead_code)]\n\
             pub(super) fn {name}_into<T: Real>({}, {}) {{",
            args.join(", "),
            params.join(", ")
        );
    }
    into
}

/// Writes a loop operand into `place` (a local matrix, which starts at zero): a node's
/// value when it is computed (`sinks`), an input or constant up front (`inline_outputs`), a
/// constant or a negation just before the loops (`fixups`).
fn place_operand(
    k: &Function,
    place: String,
    o: Operand,
    fixups: &mut Vec<String>,
    inline_outputs: &mut Vec<(String, Id)>,
    sinks: &mut HashMap<Id, Vec<String>>,
) {
    match o {
        Operand::Const(0.0) => {}
        Operand::Const(c) => fixups.push(format!("{place} = lit::<T>({});", literal(c))),
        Operand::Node(id) | Operand::Neg(id) => {
            if matches!(o, Operand::Neg(_)) && k.op(id) != Op::Const(0.0) {
                fixups.push(format!("{place} = -{place};"));
            }
            match k.op(id) {
                Op::Const(0.0) => {}
                Op::Const(_) | Op::Input(..) => inline_outputs.push((place, id)),
                _ => sinks.entry(id).or_default().push(place),
            }
        }
    }
}

/// Where a [`ColumnProgram`]'s coefficients are stored: one slot of `pc` per distinct
/// node, negated node or nonzero constant (zero coefficients have none: their terms are
/// dropped).
struct ProgramCoefs {
    slots: Vec<Operand>,
    index: HashMap<(u8, u64), usize>,
}

impl ProgramCoefs {
    fn of(k: &Function, p: &ColumnProgram) -> Self {
        let mut c = ProgramCoefs { slots: Vec::new(), index: HashMap::new() };
        for block in &p.blocks {
            for step in &block.steps {
                let (ColumnStep::Sub { coef, .. } | ColumnStep::Mul { coef, .. }) = *step;
                let Some(key) = Self::key(k, coef) else { continue };
                let next = c.slots.len();
                if *c.index.entry(key).or_insert(next) == next {
                    c.slots.push(match key {
                        (2, bits) => Operand::Const(f64::from_bits(bits)),
                        _ => coef,
                    });
                }
            }
        }
        c
    }

    /// A coefficient's identity: a node (0), a negated node (1) or a constant's value (2);
    /// `None` where it is zero.
    fn key(k: &Function, coef: Operand) -> Option<(u8, u64)> {
        let constant = |c: f64| (c != 0.0).then_some((2, c.to_bits()));
        match coef {
            Operand::Const(c) => constant(c),
            Operand::Node(id) | Operand::Neg(id) => match k.op(id) {
                Op::Const(c) => constant(if matches!(coef, Operand::Neg(_)) { -c } else { c }),
                _ => Some((u8::from(matches!(coef, Operand::Neg(_))), u64::from(id.0))),
            },
        }
    }

    /// The coefficient's slot, `None` where it is zero.
    fn slot(&self, k: &Function, coef: Operand) -> Option<usize> {
        Self::key(k, coef).map(|key| self.index[&key])
    }
}

/// Where a program block's row lives while the block runs.
enum RowHome {
    /// In the one output row it is stored to, unnegated: entries `first..` of `output` (flat),
    /// `row[start..]` as a place.
    Output { output: usize, first: usize, row: String, start: usize },
    /// Row `i` of the block's scratch array `pb{b}`.
    Scratch(usize),
    /// Neither read, written nor stored by the block.
    Unused,
}

impl RowHome {
    fn output(&self) -> Option<usize> {
        match self {
            RowHome::Output { output, .. } => Some(*output),
            _ => None,
        }
    }
}

/// A program block's rows: a row stored once, unnegated, into consecutive entries of one
/// output row runs there, so that the block writes its results where they are returned
/// instead of into a scratch array that is zeroed, filled and copied out on every call (on
/// a humanoid's step those arrays were 88 kB); the others are scratch rows.
struct BlockLayout {
    homes: Vec<RowHome>,
    scratch: usize,
}

impl BlockLayout {
    fn of(k: &Function, block: &crate::ir::ColumnBlock, rows: usize) -> Self {
        let mut used = vec![false; rows];
        let mut stores = vec![0usize; rows];
        for step in &block.steps {
            match *step {
                ColumnStep::Sub { dst, src, .. } => {
                    used[dst] = true;
                    used[src] = true;
                }
                ColumnStep::Mul { dst, .. } => used[dst] = true,
            }
        }
        for st in &block.stores {
            stores[st.row] += 1;
        }
        let cols = block.columns();
        let mut scratch = 0;
        let homes = (0..rows)
            .map(|r| {
                let store = block.stores.iter().find(|st| st.row == r);
                let run = store.filter(|st| stores[r] == 1 && !st.negate).and_then(|st| {
                    let o = &k.outputs[out_index(k, st.output)];
                    row_run(o.name, cols, |c| o.shape.index(st.flat[c], &k.dims))
                        .map(|(row, start)| (st, row, start))
                });
                match run {
                    Some((st, row, start)) => RowHome::Output {
                        output: out_index(k, st.output),
                        first: st.flat[0],
                        row,
                        start,
                    },
                    None if used[r] || stores[r] > 0 => {
                        scratch += 1;
                        RowHome::Scratch(scratch - 1)
                    }
                    None => RowHome::Unused,
                }
            })
            .collect();
        BlockLayout { homes, scratch }
    }

    /// The place of entry `col` of row `row` in block `b`.
    fn place(
        &self,
        k: &Function,
        b: usize,
        block: &crate::ir::ColumnBlock,
        row: usize,
        col: usize,
    ) -> String {
        match &self.homes[row] {
            RowHome::Output { output, .. } => {
                let st = block.stores.iter().find(|st| st.row == row).expect("stored");
                output_place(k, *output, st.flat[col], &k.dims)
            }
            RowHome::Scratch(i) => format!("pb{b}[{i}][{col}]"),
            RowHome::Unused => unreachable!("unused rows have no places"),
        }
    }
}

/// The nodes that only a [`ColumnProgram`]'s stored outputs read, which its loops compute
/// instead: everything else (the other outputs, the program's operands and what they read)
/// is still emitted.
fn program_skip(k: &Function, p: &ColumnProgram) -> Vec<bool> {
    let stored: std::collections::HashSet<(usize, usize)> = p
        .blocks
        .iter()
        .flat_map(|b| b.stores.iter())
        .flat_map(|st| st.flat.iter().map(move |&f| (out_index(k, st.output), f)))
        .collect();
    let mut live = vec![false; k.nodes.len()];
    for (oi, o) in k.outputs.iter().enumerate() {
        for (flat, id) in o.ids.iter().enumerate() {
            if !stored.contains(&(oi, flat)) {
                live[id.0 as usize] = true;
            }
        }
    }
    for o in p.operands() {
        if let Operand::Node(id) | Operand::Neg(id) = o {
            live[id.0 as usize] = true;
        }
    }
    crate::ir::mark_ancestors(&k.nodes, &mut live, |_| false);
    live.into_iter().map(|l| !l).collect()
}

/// One block of a [`ColumnProgram`] as a function of its rows that hands its steps, as
/// tables, to the copy's runner ([`emit_column_runner`]): code whose size does not grow
/// with the program's (the tables do, as data). Consecutive subtractions into one row (a solve's
/// row, a dot product) form one group, whose accumulator the runner keeps for every column
/// while it subtracts the group's terms in order; a group of no terms scales its row by the
/// slot in its second field. Each term's rounding is the unrolled loops' it replaces, so
/// the values are theirs to the bit (the graph's where the graph is these steps, fd_grad's
/// solves, to the sign of a zero; to rounding where it sums a dot product first).
fn emit_program_block(
    out: &mut String,
    k: &Function,
    block: &crate::ir::ColumnBlock,
    rows: usize,
    coefs: &ProgramCoefs,
    fn_name: &str,
    copy: Copy,
) {
    let cols = block.columns();
    // Groups `(row, first term, terms)` and terms `(slot, source row)`.
    let mut groups: Vec<(usize, usize, usize)> = Vec::new();
    let mut terms: Vec<(usize, usize)> = Vec::new();
    let mut steps = block.steps.iter().peekable();
    while let Some(step) = steps.next() {
        match *step {
            ColumnStep::Sub { dst, coef, src } => {
                let first = terms.len();
                terms.extend(coefs.slot(k, coef).map(|c| (c, src)));
                while let Some(&&ColumnStep::Sub { dst: d, coef, src }) = steps.peek() {
                    if d != dst || src == dst {
                        break;
                    }
                    steps.next();
                    terms.extend(coefs.slot(k, coef).map(|c| (c, src)));
                }
                if terms.len() > first {
                    groups.push((dst, first, terms.len() - first));
                }
            }
            ColumnStep::Mul { dst, coef } => match coefs.slot(k, coef) {
                Some(c) => groups.push((dst, c, 0)),
                // A zero factor: the row becomes zero, as `x * 0` leaves it for finite x.
                None => groups.push((dst, coefs.slots.len(), 0)),
            },
        }
    }
    let list = |items: Vec<String>| items.join(", ");
    let _ = writeln!(
        out,
        "#[inline(never)]\n{}#[allow(clippy::all, unused_variables)]\n\
         fn {fn_name}<T: Real>(x: &[*mut [T; {cols}]; {rows}], pc: &[T; {}]) {{\n\
         static GROUPS: [(u32, u32, u32); {}] = [{}];\n\
         static TERMS: [(u32, u32); {}] = [{}];\n\
         run_columns(x, pc, &GROUPS, &TERMS);\n}}\n",
        copy.attribute(),
        coefs.slots.len() + 1,
        groups.len(),
        list(groups.iter().map(|(d, f, n)| format!("({d}, {f}, {n})")).collect()),
        terms.len(),
        list(terms.iter().map(|(c, s)| format!("({c}, {s})")).collect()),
    );
}

/// The copy's runner of [`emit_program_block`]'s tables, once per copy that has a program:
/// each step a loop over the columns (innermost, so that the compiler vectorises it; `C`
/// is the block's column count). In the SIMD copies a term `a −= k x` is one `mul_add`; in
/// the portable copy a multiplication and a subtraction.
fn emit_column_runner(out: &mut String, copy: Copy) {
    let term = match copy {
        Copy::Portable => "let k = pc[slot as usize]; for c in 0..C { a[c] = a[c] - k * s[c]; }",
        _ => "let k = -pc[slot as usize]; for c in 0..C { a[c] = T::mul_add(k, s[c], a[c]); }",
    };
    let _ = writeln!(
        out,
        "/// Runs one block of a column program from its tables: per group `(row, first, n)` the\n\
         /// row less its `n` terms `(slot, source row)` from `first` on, or with `n = 0` the row\n\
         /// times slot `first`. The rows are pointers (into the outputs, or scratch rows): every\n\
         /// one the tables name is valid for `C` entries, and no two overlap.\n\
         #[inline(never)]\n{}#[allow(clippy::all, dead_code)]\n\
         fn run_columns<T: Real, const C: usize>(x: &[*mut [T; C]], pc: &[T], groups: &[(u32, u32, u32)], terms: &[(u32, u32)]) {{\n\
         for &(dst, first, n) in groups {{\n\
         let d = x[dst as usize];\n\
         // SAFETY: as above; each row is read or written while no reference to it lives.\n\
         if n == 0 {{ let k = pc[first as usize]; let r = unsafe {{ &mut *d }}; for c in 0..C {{ r[c] = r[c] * k; }} continue; }}\n\
         let mut a = unsafe {{ *d }};\n\
         for &(slot, src) in &terms[first as usize..(first + n) as usize] {{\n\
         let s = unsafe {{ &*x[src as usize] }};\n\
         {term}\n\
         }}\n\
         unsafe {{ *d = a; }}\n\
         }}\n\
         }}\n",
        copy.attribute()
    );
}

/// The operand matrices' `fixups`, then `out_k = −M⁻¹ · dc_k` over rows of M⁻¹, the
/// column index innermost so that the compiler vectorises it; each entry sums its terms in the graph's order (j = 0, 1, ...), with
/// `mul_add`. Entries the graph holds as constants (structural zeros) are written back
/// after the loop.
fn emit_product_loop(
    out: &mut String,
    k: &Function,
    p: &DenseProduct,
    mats: &[String],
    fixups: &[String],
    nv: usize,
) {
    for f in fixups {
        let _ = writeln!(out, "{f}");
    }
    let accs: Vec<String> = (0..p.dc.len()).map(|i| format!("r{i}")).collect();
    let _ = writeln!(out, "for i in 0..NV {{");
    for a in &accs {
        let _ = writeln!(out, "let mut {a} = [lit::<T>(0.0); NV];");
    }
    let _ = writeln!(out, "for j in 0..NV {{\nlet m = {}[i][j];\nfor c in 0..NV {{", mats[0]);
    for (a, d) in accs.iter().zip(&mats[1..]) {
        let _ = writeln!(out, "{a}[c] = T::mul_add(m, {d}[j][c], {a}[c]);");
    }
    let _ = writeln!(out, "}}\n}}\nfor c in 0..NV {{");
    for (a, o) in accs.iter().zip(&p.outputs) {
        let _ = writeln!(out, "{o}[i][c] = -{a}[c];");
    }
    let _ = writeln!(out, "}}\n}}");
    for o in p.outputs.iter().map(|o| out_index(k, o)) {
        for (flat, &id) in k.outputs[o].ids.iter().enumerate() {
            if let Op::Const(c) = k.op(id) {
                let _ = writeln!(
                    out,
                    "{}[{}][{}] = lit::<T>({});",
                    k.outputs[o].name,
                    flat / nv,
                    flat % nv,
                    literal(c)
                );
            }
        }
    }
}

const DISPATCH_DOC: &str = r#"
/// Whether this CPU runs the [`fma`] copy (x86-64 with AVX2 and FMA, detected once and
/// cached by std).
#[inline]
#[allow(dead_code)]
pub fn has_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

"#;

/// A kernel's parameters and return type, shared by both copies and the dispatcher.
struct Signature {
    /// `q: &[T; NV]`, ...
    args: Vec<String>,
    arg_names: Vec<&'static str>,
    ret_type: String,
}

impl Signature {
    /// `q_len`: the length constant of q, `NV`, or `NQ` with a floating base.
    fn of(k: &Function, q_len: &str) -> Self {
        let ret: Vec<String> = k.outputs.iter().map(|o| output_type(o.shape)).collect();
        Signature {
            args: k
                .inputs()
                .iter()
                .map(|i| match *i {
                    crate::ir::Input::Called(c) => {
                        format!("{}: &{}", i.name(), output_type(crate::ir::Input::called_shape(c)))
                    }
                    _ => format!("{}: &[T; {}]", i.name(), input_len(*i, q_len)),
                })
                .collect(),
            arg_names: k.inputs().iter().map(|i| i.name()).collect(),
            ret_type: if ret.len() == 1 { ret[0].clone() } else { format!("({})", ret.join(", ")) },
        }
    }
}

/// The length constant of an input: q's is `q_len` (`NQ` with a floating base), the
/// step's τ `NU`.
pub(super) fn input_len(input: crate::ir::Input, q_len: &str) -> &str {
    match input {
        crate::ir::Input::Q | crate::ir::Input::Q1 => q_len,
        crate::ir::Input::TauActuated => "NU",
        crate::ir::Input::Fext => "6 * NFEXT",
        crate::ir::Input::Lambda => "NLAMBDA",
        crate::ir::Input::Dt => "1",
        crate::ir::Input::Active => "NCONTACTS",
        crate::ir::Input::Gains => "2 * NBAUMGARTE",
        crate::ir::Input::ContactRef => "NCONTACT_REF",
        crate::ir::Input::Qd
        | crate::ir::Input::Qdd
        | crate::ir::Input::Tau
        | crate::ir::Input::V => "NV",
        // In their shapes (see `Signature::of`); flat, these lengths.
        crate::ir::Input::Called(c) => match crate::ir::Input::called_shape(c) {
            Shape::Lambda => "NLAMBDA",
            Shape::Matrix => "NV * NV",
            Shape::LambdaBy => "NLAMBDA * NV",
            _ => "NV",
        },
    }
}

/// The length constant of q in a module for `robot`.
pub(super) fn q_len(robot: &crate::ir::Robot) -> &'static str {
    if robot.nq() != robot.nv() {
        "NQ"
    } else {
        "NV"
    }
}

/// The public kernel: the AVX-512 copy (when emitted) or the FMA copy where the CPU has
/// it, else the portable one.
fn emit_dispatcher(out: &mut String, k: &Function, q_len: &str, avx512: bool, copies: Copies) {
    let name = k.kind.name();
    let Signature { args, arg_names, ret_type } = Signature::of(k, q_len);
    let call = arg_names.join(", ");
    let runs = match (copies, avx512) {
        (Copies::Portable, _) => format!("Runs [`portable::{name}`] (this module holds no other copy)."),
        (Copies::Fma, _) => format!("Runs [`fma::{name}`] where [`has_fma`] (this module holds no other copy), and panics\n/// elsewhere."),
        (Copies::Dispatch, true) => format!("Runs [`avx512::{name}`] where [`has_avx512`], else [`fma::{name}`] where [`has_fma`] (the same\n/// results, bit for bit), else [`portable::{name}`]."),
        (Copies::Dispatch, false) => format!("Runs [`fma::{name}`] where [`has_fma`], else [`portable::{name}`]."),
    };
    let _ = writeln!(out, "/// {}\n///\n/// {runs}", k.doc());
    let _ = writeln!(
        out,
        "#[inline]\n#[allow(dead_code, {}clippy::type_complexity)]\npub fn {name}<T: Real>({}) -> {ret_type} {{",
        // Off x86-64 an fma-only dispatcher only panics.
        if copies == Copies::Fma { "unused_variables, " } else { "" },
        args.join(", ")
    );
    if copies == Copies::Portable {
        let _ = writeln!(out, "portable::{name}({call})\n}}\n");
        return;
    }
    // The SIMD copies write into this function's own outputs, which it returns: returned
    // by a `#[target_feature]` function (which cannot be inlined here) they were copied once
    // more, up to 14 KB per call (floating HyQ's `step_grad`), and that copy's speed moved
    // with the stack's layout (0.6 µs of its 4.4 µs in one build, docs/guide/speed.md).
    let _ = writeln!(out, "#[cfg(target_arch = \"x86_64\")]\nif has_fma() {{");
    emit_output_init(out, k);
    let into_call = format!("{call}, {}", output_refs(k));
    if avx512 {
        let _ = writeln!(
            out,
            "if has_avx512() {{\n// SAFETY: the CPU has AVX-512 F and VL, AVX2 and FMA (checked just above).\nunsafe {{ avx512::{name}_into({into_call}) }};\n}} else {{"
        );
    }
    let _ = writeln!(
        out,
        "// SAFETY: the CPU has AVX2 and FMA (checked just above).\nunsafe {{ fma::{name}_into({into_call}) }};"
    );
    if avx512 {
        let _ = writeln!(out, "}}");
    }
    let _ = writeln!(out, "return {};\n}}", return_value(k));
    if copies == Copies::Fma {
        let _ = writeln!(
            out,
            "panic!(\"this module holds only the kernels for x86-64 with AVX2 and FMA (generated with copies = fma), and this CPU lacks them\")\n}}\n"
        );
    } else {
        let _ = writeln!(out, "portable::{name}({call})\n}}\n");
    }
}

/// The public kernel into its caller's outputs (`{name}_into`): what a caller that keeps
/// its outputs from call to call (an MPC's knots, the C ABI's batches) runs, as Pinocchio
/// writes into its `Data`. The by-value kernel returns its outputs, a copy of every one
/// (42 kB for a humanoid's `contact_fd_grad`, 6 % of its time in `perf`); here the SIMD
/// copies write into the caller's, set to zero first (a kernel stores only the entries
/// that are not structurally zero).
fn emit_into_dispatcher(out: &mut String, k: &Function, q_len: &str, avx512: bool, copies: Copies) {
    let name = k.kind.name();
    let Signature { args, arg_names, .. } = Signature::of(k, q_len);
    let call = arg_names.join(", ");
    let params: Vec<String> =
        k.outputs.iter().map(|o| format!("{}: &mut {}", o.name, output_type(o.shape))).collect();
    let _ = writeln!(
        out,
        "/// [`{name}`] into the caller's outputs, every entry of which it overwrites (the SIMD\n\
         /// copies write there directly: no output is returned by value, then copied).\n\
         #[inline]\n#[allow(dead_code, {}clippy::type_complexity, clippy::too_many_arguments)]\n\
         pub fn {name}_into<T: Real>({}, {}) {{",
        if copies == Copies::Fma { "unused_variables, " } else { "" },
        args.join(", "),
        params.join(", ")
    );
    if copies != Copies::Portable {
        let _ = writeln!(out, "#[cfg(target_arch = \"x86_64\")]\nif has_fma() {{");
        // `T::k` first, as in the by-value kernel: the CPU check for the SIMD types.
        for o in &k.outputs {
            let _ = writeln!(out, "*{} = {};", o.name, array_of(o.shape, "T::k(0.0)"));
        }
        let refs: Vec<&str> = k.outputs.iter().map(|o| o.name).collect();
        let into_call = format!("{call}, {}", refs.join(", "));
        if avx512 {
            let _ = writeln!(
                out,
                "if has_avx512() {{\n// SAFETY: the CPU has AVX-512 F and VL, AVX2 and FMA (checked just above).\nunsafe {{ avx512::{name}_into({into_call}) }};\nreturn;\n}}"
            );
        }
        let _ = writeln!(
            out,
            "// SAFETY: the CPU has AVX2 and FMA (checked just above).\nunsafe {{ fma::{name}_into({into_call}) }};\nreturn;\n}}"
        );
    }
    if copies == Copies::Fma {
        let _ = writeln!(
            out,
            "panic!(\"this module holds only the kernels for x86-64 with AVX2 and FMA (generated with copies = fma), and this CPU lacks them\")\n}}\n"
        );
        return;
    }
    let results: Vec<String> = (0..k.outputs.len()).map(|j| format!("r{j}")).collect();
    let pattern = match results.len() {
        1 => results[0].clone(),
        _ => format!("({})", results.join(", ")),
    };
    let writes: String =
        k.outputs.iter().enumerate().map(|(j, o)| format!("*{} = r{j};\n", o.name)).collect();
    let _ = writeln!(out, "let {pattern} = portable::{name}({call});\n{writes}}}\n");
}

/// `&mut out1, &mut out2, ...`: the outputs passed to a copy's `{name}_into`.
fn output_refs(k: &Function) -> String {
    k.outputs.iter().map(|o| format!("&mut {}", o.name)).collect::<Vec<_>>().join(", ")
}

/// The outputs, from the checked `T::k` before anything else runs: for the SIMD types that
/// is the CPU check which makes every later `lit` sound (see the prelude).
fn emit_output_init(out: &mut String, k: &Function) {
    for o in &k.outputs {
        let init = array_of(o.shape, "T::k(0.0)");
        let _ = writeln!(out, "let mut {} = {init};", o.name);
    }
}

const HAS_AVX512: &str = r#"
/// Whether this CPU runs the [`avx512`] copy (x86-64 with AVX-512 F and VL, AVX2 and FMA).
#[inline]
#[allow(dead_code)]
pub fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        has_fma() && std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vl")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
"#;

const PRELUDE: &str = r#"
/// The scalar types the kernels run in: `f64` (exact to round-off) and `f32`.
#[allow(dead_code)]
pub trait Real: Copy + core::ops::Add<Output = Self> + core::ops::Sub<Output = Self> + core::ops::Mul<Output = Self> + core::ops::Div<Output = Self> + core::ops::Neg<Output = Self> {
    /// A constant of the robot, rounded to this type (for the SIMD types, it checks that this
    /// CPU runs them, and panics where it does not).
    fn k(x: f64) -> Self;
    /// `k` without its check of the CPU, for the kernels' constants.
    ///
    /// # Safety
    /// This CPU runs `Self`'s operations (for `f64`, `f32` and `Lanes`, always).
    #[inline(always)]
    unsafe fn lit(x: f64) -> Self { Self::k(x) }
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    /// Correctly rounded (IEEE 754), so every type's lanes agree bit for bit.
    fn sqrt(self) -> Self;
    /// `self * a + b` rounded once; only the FMA copy calls it (without the FMA
    /// instruction it would be a slow library call).
    fn mul_add(self, a: Self, b: Self) -> Self;
    /// Whether `Self` is `f64`, and `f32`: constants, so that the batch functions (`_c.rs`)
    /// pick their SIMD type at compile time and an f64 batch never compiles the f32 kernels
    /// (their `TypeId` check is what makes the choice sound).
    const IS_F64: bool = false;
    const IS_F32: bool = false;
}

impl Real for f64 {
    const IS_F64: bool = true;
    #[inline(always)]
    fn k(x: f64) -> Self { x }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self { f64::mul_add(self, a, b) }
    #[inline(always)]
    fn sin(self) -> Self { f64::sin(self) }
    #[inline(always)]
    fn cos(self) -> Self { f64::cos(self) }
    #[inline(always)]
    fn sqrt(self) -> Self { f64::sqrt(self) }
}

impl Real for f32 {
    const IS_F32: bool = true;
    #[inline(always)]
    fn k(x: f64) -> Self { x as f32 }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self { f32::mul_add(self, a, b) }
    #[inline(always)]
    fn sin(self) -> Self { f32::sin(self) }
    #[inline(always)]
    fn cos(self) -> Self { f32::cos(self) }
    #[inline(always)]
    fn sqrt(self) -> Self { f32::sqrt(self) }
}

/// A constant in the kernels: `Real::lit`, sound here because every kernel first fills its
/// outputs with the checked `T::k`, so this runs only where the CPU runs `T`'s operations.
#[inline(always)]
#[allow(dead_code)]
fn lit<T: Real>(x: f64) -> T {
    // SAFETY: see above; only this module's kernels call it, after that check.
    unsafe { T::lit(x) }
}

/// `N` states evaluated by one call, one per lane (`q[j].0[l]` is joint j of state l), for
/// sweeping many knot points: every lane runs exactly the operations of a scalar call in its
/// scalar type `S` (of the same copy, `portable` or `fma`), so results are bit-identical, and
/// the compiler can put the lanes in SIMD registers, which it does only in part (it spills
/// the rest): on x86-64 with AVX2 and FMA, `F64x4` and `F32x8` compute the same bits with
/// one vector instruction per operation, two to three times faster per state. `Lanes` runs
/// on any target and at any width.
#[derive(Clone, Copy, Debug, PartialEq)]
#[allow(dead_code)]
pub struct Lanes<const N: usize, S = f64>(pub [S; N]);

impl<const N: usize, S: Real> core::ops::Add for Lanes<N, S> {
    type Output = Self;
    #[inline(always)]
    fn add(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] + b.0[l]))
    }
}

impl<const N: usize, S: Real> core::ops::Sub for Lanes<N, S> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] - b.0[l]))
    }
}

impl<const N: usize, S: Real> core::ops::Mul for Lanes<N, S> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] * b.0[l]))
    }
}

impl<const N: usize, S: Real> core::ops::Div for Lanes<N, S> {
    type Output = Self;
    #[inline(always)]
    fn div(self, b: Self) -> Self {
        Lanes(core::array::from_fn(|l| self.0[l] / b.0[l]))
    }
}

impl<const N: usize, S: Real> core::ops::Neg for Lanes<N, S> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self { Lanes(self.0.map(|x| -x)) }
}

impl<const N: usize, S: Real> Real for Lanes<N, S> {
    #[inline(always)]
    fn k(x: f64) -> Self { Lanes([S::k(x); N]) }
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self { Lanes(core::array::from_fn(|l| self.0[l].mul_add(a.0[l], b.0[l]))) }
    #[inline(always)]
    fn sin(self) -> Self { Lanes(self.0.map(S::sin)) }
    #[inline(always)]
    fn cos(self) -> Self { Lanes(self.0.map(S::cos)) }
    #[inline(always)]
    fn sqrt(self) -> Self { Lanes(self.0.map(S::sqrt)) }
}
"#;

/// The SIMD types, each a scalar type and a register width: with `avx512`, also the 512-bit
/// ones (only such a module has a copy that compiles their operations inline).
fn simd_types(avx512: bool) -> String {
    let widths: &[u32] = if avx512 { &[256, 512] } else { &[256] };
    let mut out = String::new();
    for (scalar, bits) in widths.iter().flat_map(|&b| [("f64", b), ("f32", b)]) {
        let lanes = bits / if scalar == "f64" { 64 } else { 32 };
        let name = format!("F{}x{lanes}", &scalar[1..]);
        let (check, needs) = match bits {
            256 => ("has_fma", "AVX2 and FMA"),
            _ => ("has_avx512", "AVX-512 F and VL, AVX2 and FMA"),
        };
        let (suffix, reg) = match scalar {
            "f64" => ("pd", format!("__m{bits}d")),
            _ => ("ps", format!("__m{bits}")),
        };
        let op = |o: &str| format!("core::arch::x86_64::_mm{bits}_{o}_{suffix}");
        let bin = |tr: &str, f: &str, o: &str| {
            format!(
                "#[cfg(target_arch = \"x86_64\")]\nimpl core::ops::{tr} for {name} {{\ntype Output = Self;\n#[inline(always)]\n\
                 fn {f}(self, b: Self) -> Self {{\n// SAFETY: a {name} exists only where the CPU runs it (every constructor checks).\n\
                 {name}(unsafe {{ {}(self.0, b.0) }})\n}}\n}}\n",
                op(o)
            )
        };
        let _ = write!(
            out,
            "
/// {lanes} {scalar} states per call in one {bits}-bit register (`{reg}`): what `Lanes<{lanes}{ty}>` computes,
/// bit for bit, but each operation is one vector instruction, where `Lanes` leaves the
/// vectorising to the compiler (which does part of it, and spills the rest). Runs where
/// the CPU has {needs} ([`{check}`]): every way to make one checks, so a value of this type
/// is proof of that. Through the dispatching functions it runs in the copy that compiles
/// its operations inline; elsewhere each operation is a call (correct, slow).
#[cfg(target_arch = \"x86_64\")]
#[derive(Clone, Copy)]
#[repr(transparent)]
#[allow(dead_code)]
pub struct {name}(core::arch::x86_64::{reg});

#[cfg(target_arch = \"x86_64\")]
#[allow(dead_code)]
impl {name} {{
    /// States in one value.
    pub const LANES: usize = {lanes};
    /// Whether this CPU runs `{name}`: x86-64 with {needs}.
    #[inline]
    pub fn supported() -> bool {{
        {check}()
    }}
    /// The lanes as one value, or `None` where this CPU does not run `{name}`.
    #[inline]
    pub fn new(lanes: [{scalar}; {lanes}]) -> Option<Self> {{
        if Self::supported() {{ Some(Self::unchecked(lanes)) }} else {{ None }}
    }}
    #[inline(always)]
    fn unchecked(lanes: [{scalar}; {lanes}]) -> Self {{
        // SAFETY: the same size, and every bit pattern is a valid value of both.
        {name}(unsafe {{ core::mem::transmute::<[{scalar}; {lanes}], core::arch::x86_64::{reg}>(lanes) }})
    }}
    /// The lanes.
    #[inline(always)]
    pub fn to_array(self) -> [{scalar}; {lanes}] {{
        // SAFETY: as in `unchecked`.
        unsafe {{ core::mem::transmute::<core::arch::x86_64::{reg}, [{scalar}; {lanes}]>(self.0) }}
    }}
}}

#[cfg(target_arch = \"x86_64\")]
impl core::fmt::Debug for {name} {{
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {{
        f.debug_tuple(\"{name}\").field(&self.to_array()).finish()
    }}
}}

#[cfg(target_arch = \"x86_64\")]
impl PartialEq for {name} {{
    fn eq(&self, b: &Self) -> bool {{
        self.to_array() == b.to_array()
    }}
}}
{}{}{}{}
/// Negation is `-0 - x`: exact, and the same bits as the scalar `-x` for every number.
#[cfg(target_arch = \"x86_64\")]
impl core::ops::Neg for {name} {{
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {{
        // SAFETY: as for the other operations.
        {name}(unsafe {{ {}({}(-0.0), self.0) }})
    }}
}}

#[cfg(target_arch = \"x86_64\")]
impl Real for {name} {{
    #[inline]
    fn k(x: f64) -> Self {{
        {name}::new([x{cast}; {lanes}]).expect(\"{name} needs a CPU with {needs} ({name}::supported)\")
    }}
    #[inline(always)]
    unsafe fn lit(x: f64) -> Self {{
        // One broadcast, where the array's transmute left LLVM a store and a load to fold
        // per constant: the gait library's F64x4 kernels built in 23 s instead of 27 s (the
        // book, Compile time).
        // SAFETY: `lit`'s contract, this CPU runs {name}.
        {name}(unsafe {{ {}(x{cast}) }})
    }}
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {{
        // SAFETY: as for the other operations.
        {name}(unsafe {{ {}(self.0, a.0, b.0) }})
    }}
    #[inline(always)]
    fn sin(self) -> Self {{
        {name}::unchecked(self.to_array().map({scalar}::sin))
    }}
    #[inline(always)]
    fn cos(self) -> Self {{
        {name}::unchecked(self.to_array().map({scalar}::cos))
    }}
    #[inline(always)]
    fn sqrt(self) -> Self {{
        // SAFETY: as for the other operations.
        {name}(unsafe {{ {}(self.0) }})
    }}
}}
",
            bin("Add", "add", "add"),
            bin("Sub", "sub", "sub"),
            bin("Mul", "mul", "mul"),
            bin("Div", "div", "div"),
            op("sub"),
            op("set1"),
            op("set1"),
            op("fmadd"),
            op("sqrt"),
            ty = if scalar == "f64" { "" } else { ", f32" },
            cast = if scalar == "f64" { "" } else { " as f32" },
        );
    }
    out
}

/// The Rust file for `module`: `<stem>.rs`, formatted, with its header.
/// Why the Rust backend could not print a module.
#[derive(Debug, thiserror::Error)]
pub enum RustError {
    #[error("internal error: the Rust backend produced code that does not parse: {0}")]
    Unparsable(String),
}

pub fn emit(module: &Module, options: &RustOptions) -> Result<GeneratedFile, RustError> {
    let robot = &module.robot;
    let nv = robot.nv();
    let gravity = module.gravity;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "/// The robot's name in its URDF.\n#[allow(dead_code)]\npub const ROBOT: &str = {};",
        string_literal(&robot.name)
    );
    let _ = writeln!(out, "/// Number of movable joints (and of entries in every vector).\n#[allow(dead_code)]\npub const NV: usize = {nv};");
    let nq_doc = match (robot.floating, robot.spherical.is_empty()) {
        (true, true) => {
            "Entries of q: the floating base's position and quaternion `[x, y, z, qx, qy, qz, qw]`, then the\n\
                 /// joints after the base's six velocity coordinates (Pinocchio's free-flyer layout)."
        }
        (false, true) => "Entries of q: `NV` (a fixed base).",
        (_, false) => {
            "Entries of q: one per coordinate, but four (a quaternion `[qx, qy, qz, qw]`) for each spherical\n\
                 /// joint's three and seven for a floating base's six (Pinocchio's layout; see the file header)."
        }
    };
    let _ =
        writeln!(out, "/// {nq_doc}\n#[allow(dead_code)]\npub const NQ: usize = {};", robot.nq());
    let names: Vec<String> = robot.joint_names.iter().map(|n| string_literal(n)).collect();
    let _ = writeln!(out, "/// Movable joints in model order: depth-first from the root, children in document order.\n#[allow(dead_code)]\npub const JOINT_NAMES: [&str; NV] = [{}];", names.join(", "));
    let parents: Vec<String> =
        robot.parents.iter().map(|p| p.map_or("None".into(), |p| format!("Some({p})"))).collect();
    let _ = writeln!(
        out,
        "/// Parent joint of each joint (`None`: the fixed root).\n#[allow(dead_code)]\npub const PARENTS: [Option<usize>; NV] = [{}];",
        parents.join(", ")
    );
    if !robot.frames.is_empty() {
        let frames: Vec<String> = robot.frames.iter().map(|n| string_literal(n)).collect();
        let _ = writeln!(
            out,
            "/// Number of frames the frame kernels compute.\n#[allow(dead_code)]\npub const NF: usize = {};\n\
             /// The frames (URDF link names), in the order of the frame kernels' outputs.\n#[allow(dead_code)]\npub const FRAME_NAMES: [&str; NF] = [{}];\n\
             /// The reference frame of the Jacobian, velocity and acceleration (Pinocchio's `ReferenceFrame`).\n#[allow(dead_code)]\npub const REFERENCE_FRAME: &str = {};",
            frames.len(),
            frames.join(", "),
            string_literal(robot.reference.name())
        );
    }
    if let Some(step) = robot.specialisation.step {
        let actuated: Vec<String> =
            robot.actuated.iter().map(|&c| string_literal(&robot.joint_names[c])).collect();
        let _ = writeln!(
            out,
            "/// Entries of the step kernels' `tau`: the actuated joints.\n#[allow(dead_code)]\npub const NU: usize = {};\n\
             /// The actuated joints, in the order of the step kernels' `tau` and B's columns.\n#[allow(dead_code)]\npub const ACTUATED: [&str; NU] = [{}];\n\
             /// Rows and columns of the step's A: the state's tangent `[dq; dqd]`.\n#[allow(dead_code)]\npub const NX: usize = 2 * NV;\n\
             {}\
             /// The step kernels' integration scheme (Crocoddyl's integrated action models).\n#[allow(dead_code)]\npub const STEP_SCHEME: &str = {};",
            actuated.len(),
            actuated.join(", "),
            match step.dt {
                Some(dt) => format!("/// The step kernels' time step, s, fixed at generation time.\n#[allow(dead_code)]\npub const DT: f64 = {};\n", literal(dt)),
                // No DT: a caller who reads it learns at compile time that the module has none.
                None => "/// The step kernels take their time step, s, at run time: their last argument `dt`, one value per state.\n".to_string(),
            },
            string_literal(step.scheme.name())
        );
    }
    if !robot.fext.is_empty() {
        let names: Vec<String> = robot.fext.iter().map(|n| string_literal(n)).collect();
        let _ = writeln!(
            out,
            "/// Bodies that take an external force: `fext` has 6 entries per body, `[fx, fy, fz, tx, ty, tz]` in the frame of\n\
             /// the joint that moves it (Pinocchio's `fext`, subtracted in RNEA).\n#[allow(dead_code)]\npub const NFEXT: usize = {};\n\
             /// The joints (Pinocchio's names) whose bodies take `fext`, in its order.\n#[allow(dead_code)]\npub const FEXT_JOINTS: [&str; NFEXT] = [{}];",
            names.len(),
            names.join(", ")
        );
    }
    if !robot.contacts.is_empty() {
        let frames: Vec<String> = robot.contacts.iter().map(|c| string_literal(&c.frame)).collect();
        let kinds: Vec<String> =
            robot.contacts.iter().map(|c| string_literal(c.kind.name())).collect();
        let _ = writeln!(
            out,
            "/// Entries of the contact forces `lambda`: 3 per point contact, 6 per wrench (`[f; tau]`), in world axes at the\n\
             /// contact frame's origin (`LOCAL_WORLD_ALIGNED`), the force on the robot.\n#[allow(dead_code)]\npub const NLAMBDA: usize = {};\n\
             /// The contact frames, in `lambda`'s order, and their kinds (`point` or `wrench`).\n#[allow(dead_code)]\npub const CONTACTS: [(&str, &str); {}] = [{}];",
            robot.nlambda(),
            frames.len(),
            frames.iter().zip(&kinds).map(|(f, k)| format!("({f}, {k})")).collect::<Vec<_>>().join(", ")
        );
        if robot.specialisation.baumgarte {
            let _ = writeln!(
                out,
                "/// Contacts stabilised as Pinocchio's Baumgarte corrector: `contact_fd`, `contact_fd_grad`, `step` and `step_grad` take\n\
                 /// `gains` (`[Kp, Kd]` per contact of `CONTACTS`) and `contact_ref` (each contact's reference in the world: a point's\n\
                 /// position, 3 entries; a wrench's placement `[x, y, z, qx, qy, qz, qw]`, 7), and drive each contact's acceleration\n\
                 /// to `-Kd v - Kp e`, e the error to the reference (a point's `p - p_ref`, a wrench's `-log6`; gains 0: the rigid\n\
                 /// contact).\n#[allow(dead_code)]\npub const NBAUMGARTE: usize = {};\n/// Entries of `contact_ref`.\n#[allow(dead_code)]\npub const NCONTACT_REF: usize = {};",
                frames.len(),
                robot.dims().ncontact_ref
            );
        }
        if robot.specialisation.contact_mask {
            let _ = writeln!(
                out,
                "/// Entries of the contact mask `active` that `contact_fd`, `contact_fd_grad`, `step` and `step_grad` take: one per\n\
                 /// contact of `CONTACTS`, 1 where it holds and 0 where it does not (its lambda and their rows are then 0).\n#[allow(dead_code)]\npub const NCONTACTS: usize = {};",
                frames.len()
            );
        }
    }
    let _ = writeln!(
        out,
        "/// Gravity in the root frame, m/s^2, fixed at generation time.\n#[allow(dead_code)]\npub const GRAVITY: [f64; 3] = [{}, {}, {}];",
        literal(gravity[0]),
        literal(gravity[1]),
        literal(gravity[2])
    );
    out.push_str(PRELUDE);
    out.push_str(DISPATCH_DOC);
    if options.avx512 {
        out.push_str(HAS_AVX512);
    }
    out.push_str(&simd_types(options.avx512));
    // The avx512 copy rides with the dispatched pair only.
    let avx512 = options.avx512 && options.copies == Copies::Dispatch;
    for k in &module.functions {
        if options.kernel_features {
            out.push_str(&super::feature_gate(k.kind.name()));
        }
        emit_dispatcher(&mut out, k, q_len(robot), avx512, options.copies);
        if options.kernel_features {
            out.push_str(&super::feature_gate(k.kind.name()));
        }
        emit_into_dispatcher(&mut out, k, q_len(robot), avx512, options.copies);
    }
    let copies = [
        (
            options.copies != Copies::Fma,
            Copy::Portable,
            "/// The kernels for any target: separate multiplies and adds.\npub mod portable {\nuse super::*;\n",
        ),
        (
            options.copies != Copies::Portable,
            Copy::Fma,
            "/// The kernels for x86-64 with AVX2 and FMA (`mul_add` where a product feeds one addition).\n\
             /// Calling them on a CPU without those features is undefined behaviour; the functions\n\
             /// at the top of the module check first.\n#[cfg(target_arch = \"x86_64\")]\npub mod fma {\nuse super::*;\n",
        ),
        (
            avx512,
            Copy::Avx512,
            "/// The `fma` copy's kernels compiled for AVX-512 (F and VL): the same operations, so the same\n\
         /// results bit for bit, with 32 vector registers (fewer spills) and zmm for `Lanes<8>`.\n\
         /// Calling them on a CPU without those features is undefined behaviour.\n#[cfg(target_arch = \"x86_64\")]\npub mod avx512 {\nuse super::*;\n",
        ),
    ];
    let has_program = module.functions.iter().any(|f| {
        runs_program(f).is_some()
            || f.call.as_ref().is_some_and(|c| runs_program(&c.rest).is_some())
    });
    // Every piece of the file, each emitted and formatted on its own (on every core, in
    // order): the top-level items, then per copy its header, its kernels and its runner.
    enum Piece<'a> {
        Head,
        Start(&'a str),
        Kernel(&'a Function, Copy),
        Runner(Copy),
    }
    let splits = split::split_callees(module, options.chunk);
    let mut pieces = vec![Piece::Head];
    for (wanted, copy, header) in copies {
        if wanted {
            pieces.push(Piece::Start(header));
            pieces.extend(module.functions.iter().map(|k| Piece::Kernel(k, copy)));
            if has_program {
                pieces.push(Piece::Runner(copy));
            }
        }
    }
    let formatted = crate::parallel::in_parallel(&pieces, |piece| match *piece {
        Piece::Head => format::items(&out),
        Piece::Start(header) => format::module_start(header),
        Piece::Kernel(k, copy) => {
            let mut item = String::new();
            match &k.call {
                Some(call) if !call.ahead.is_empty() => {
                    let callee = split::SplitCallee::of(&splits, call);
                    let within = Some((k, &**call, robot, callee));
                    let name = k.kind.name();
                    emit_kernel(
                        &mut item,
                        &call.rest,
                        name,
                        nv,
                        q_len(robot),
                        options,
                        copy,
                        within,
                        None,
                    );
                }
                Some(call) => {
                    let rest = format!("{}_rest", k.kind.name());
                    emit_kernel(
                        &mut item,
                        &call.rest,
                        &rest,
                        nv,
                        q_len(robot),
                        options,
                        copy,
                        None,
                        None,
                    );
                    emit_call(&mut item, k, call, robot, copy);
                }
                None => {
                    let name = k.kind.name();
                    let own = splits.iter().find(|s| s.f.kind == k.kind);
                    emit_kernel(&mut item, k, name, nv, q_len(robot), options, copy, None, own)
                }
            }
            let feature = options.kernel_features.then(|| k.kind.name());
            format::module_items(&item, feature).map(format::compact_slots)
        }
        Piece::Runner(copy) => {
            let mut item = String::new();
            emit_column_runner(&mut item, copy);
            format::module_items(&item, None)
        }
    });
    let mut code = String::new();
    for (i, text) in formatted.into_iter().enumerate() {
        // A module ends where the next one starts, and at the end of the file.
        if i > 1 && matches!(pieces[i], Piece::Start(_)) {
            code.push_str("}\n");
        }
        code.push_str(&text.map_err(RustError::Unparsable)?);
    }
    if pieces.len() > 1 {
        code.push_str("}\n");
    }
    let stem = identifier(&robot.name);
    let api: String = api_doc(module.functions.iter())
        .lines()
        .map(|l| if l.is_empty() { "//\n".to_string() } else { format!("// {l}\n") })
        .collect();
    let header = format!(
        "// @generated by grid-gen {} from the URDF of robot {} ({} joints). Do not edit:\n\
         // regenerate with `grid-gen ROBOT.urdf -o DIR` or grid_gen::Builder in build.rs.\n\
         // Use it with `mod {stem} {{ include!(\"{stem}.rs\"); }}`.\n\
         {}//\n{api}\n",
        env!("CARGO_PKG_VERSION"),
        string_literal(&robot.name),
        nv,
        crate::back::source_line(&robot.source) + &crate::back::specialisation_lines(robot),
    );
    Ok(GeneratedFile { name: Target::Rust.file_name(&stem), contents: header + &code })
}
