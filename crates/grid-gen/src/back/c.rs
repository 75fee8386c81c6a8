//! The C target: batch entry points over slices of states, the `extern "C"` functions
//! that expose them (f64 and f32, one state or n), and the C header that declares them.
//!
//! It writes two files beside the Rust module `<robot>.rs`:
//! - `<robot>_c.rs`, a module `<robot>_batch` to `include!` in the same Rust module as
//!   `mod <robot> { include!("<robot>.rs"); }`, in a crate with `crate-type = ["staticlib",
//!   "cdylib"]` that depends on `grid-gen-runtime` (the rayon pool);
//! - `<robot>.h`, the header: sizes as macros, names as arrays, one documented prototype
//!   per kernel, precision and batch.
//!
//! Arrays are contiguous, row-major and state-major: state `i`'s `q` starts at
//! `q + i * NQ`, its `dqdd_dq` at `dqdd_dq + i * NV * NV` — the layout of the Rust arrays
//! `[[f64; NQ]]` and `[[[f64; NV]; NV]]`, so the C functions pass the caller's memory to
//! the Rust kernels without copying.

use std::fmt::Write;

use super::names::{comment_text, identifier};
use super::rust::{array_of, input_len, q_len};
use super::GeneratedFile;
use crate::ir::{Function, Input, Module, Shape};

/// Options of the C target.
#[derive(Clone, Debug)]
pub struct COptions {
    /// Emit the f64 entry points.
    pub f64: bool,
    /// Emit the f32 entry points.
    pub f32: bool,
    /// Which kernels' batches run several states per call in SIMD lanes.
    pub lanes: BatchLanes,
    /// Gate each kernel's items behind a Cargo feature of its name (and the shared entry
    /// points behind `common`), and write `<robot>_features.json`, so that a loader can
    /// compile the kernels in several crates at once ([`RustOptions::kernel_features`]).
    ///
    /// [`RustOptions::kernel_features`]: super::rust::RustOptions::kernel_features
    pub kernel_features: bool,
}

impl Default for COptions {
    fn default() -> Self {
        COptions { f64: true, f32: true, lanes: BatchLanes::Auto, kernel_features: false }
    }
}

/// Which batch entry points evaluate four f64 (`F64x4`) or eight f32 (`F32x8`) states per
/// kernel call where the CPU has AVX2 and FMA. Each such kernel is compiled a second time
/// for its lane type: on a humanoid with contacts, half of the library's compile time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum BatchLanes {
    /// The kernels where lanes were measured to pay ([`lanes_pay`]); one state per call
    /// for the others.
    #[default]
    Auto,
    /// Every kernel: the most throughput for mid-sized kernels, the longest compile.
    All,
    /// No kernel: one state per call, the shortest compile.
    None,
}

/// At most this many operations (after specialisation) for lanes to pay: measured per
/// kernel on this project's 2-core machine (an Intel Xeon, 2 MiB of L2 per core; the book,
/// Compile time, "Lanes where they pay"), one core, batches of 64. Lanes gain 1.3x to 3.2x
/// per state up to floating Atlas's `fd_grad` (124,000 operations: 1.43x) and HyQ's
/// `contact_fd_grad` (81,000: 1.68x), and 0.9x to 1.2x above (Atlas's `contact_fd_grad`,
/// 280,000, and `step_grad`, 285,000): four states' intermediates no longer fit the
/// caches. Their second compilation (with `mass_matrix`'s) was 9 s of the humanoid's 51.
pub const LANES_MAX_OPS: usize = 150_000;

/// At least this many operations per output entry for lanes to pay: taking the lanes
/// apart costs per entry. Atlas's `mass_matrix` (6,163 operations, 1,296 entries: 4.8)
/// runs at 0.7x in lanes, iiwa's (380, 49: 7.8) at 1.3x; `integrate` (1 per entry) at 0.8x.
pub const LANES_MIN_OPS_PER_ENTRY: usize = 6;

/// Whether a kernel's batches evaluate states in SIMD lanes under `lanes`.
pub fn lanes_pay(k: &Function, lanes: BatchLanes) -> bool {
    match lanes {
        BatchLanes::All => true,
        BatchLanes::None => false,
        BatchLanes::Auto => {
            let ops = k.counts().total();
            let entries: usize = k.outputs.iter().map(|o| o.ids.len()).sum();
            ops <= LANES_MAX_OPS && ops >= LANES_MIN_OPS_PER_ENTRY * entries
        }
    }
}

/// The scalar types emitted: Rust name, C name, suffix.
fn precisions(options: &COptions) -> Vec<(&'static str, &'static str)> {
    let mut out = Vec::new();
    if options.f64 {
        out.push(("f64", "double"));
    }
    if options.f32 {
        out.push(("f32", "float"));
    }
    out
}

/// A C string literal for any text: printable ASCII as is, but for `"`, `\` and `?`
/// (trigraphs), and every other byte as a three-digit octal escape (a hex escape would
/// swallow the digits after it).
pub fn c_string_literal(text: &str) -> String {
    let mut out = String::from("\"");
    for b in text.bytes() {
        match b {
            b'"' | b'\\' | b'?' => {
                out.push('\\');
                out.push(b as char);
            }
            b' '..=b'~' => out.push(b as char),
            _ => {
                let _ = write!(out, "\\{b:03o}");
            }
        }
    }
    out.push('"');
    out
}

/// The manifest the library returns from `<robot>_manifest()`: what a loader (the Python
/// package) needs to call every entry point without reading the header.
fn manifest(module: &Module, options: &COptions) -> String {
    let robot = &module.robot;
    let dims = module.functions.first().map(|k| k.dims).unwrap_or_default();
    let kernels: Vec<serde_json::Value> = module
        .functions
        .iter()
        .map(|k| {
            serde_json::json!({
                "name": k.kind.name(),
                "doc": k.doc(),
                "inputs": k.inputs().iter().map(|i| serde_json::json!({"name": i.name(), "len": i.len(&k.dims)})).collect::<Vec<_>>(),
                "outputs": k.outputs.iter().map(|o| serde_json::json!({"name": o.name, "dims": o.shape.dims(&k.dims)})).collect::<Vec<_>>(),
            })
        })
        .collect();
    let manifest = serde_json::json!({
        "robot": robot.name,
        "prefix": c_prefix(&identifier(&robot.name)),
        "grid_gen": env!("CARGO_PKG_VERSION"),
        "nq": dims.nq,
        "nv": dims.nv,
        "nu": dims.nu,
        "nlambda": dims.nlambda,
        "nfext": dims.nfext,
        "floating_base": robot.floating,
        "joint_names": robot.joint_names,
        // Where each unit quaternion `[qx, qy, qz, qw]` sits in q, and its joint: a loader
        // checks their norms.
        "quaternions": robot.floating.then(|| serde_json::json!({"joint": "root_joint", "q": 3})).into_iter()
            .chain(robot.spherical.iter().map(|s| serde_json::json!({"joint": s.name, "q": s.q_start})))
            .collect::<Vec<_>>(),
        "frames": robot.frames,
        "reference_frame": robot.reference.name(),
        "contacts": robot.contacts.iter().map(|c| serde_json::json!([c.frame, c.kind.name()])).collect::<Vec<_>>(),
        "gravity": module.gravity,
        "precisions": precisions(options).iter().map(|p| p.0).collect::<Vec<_>>(),
        "kernels": kernels,
    });
    manifest.to_string()
}

/// `<robot>_features.json` ([`COptions::kernel_features`]): each kernel's Cargo feature,
/// the kernels it calls (whose features it needs, in the same crate), and its weight, the
/// statements that crate compiles for it (its own, or its rest's, less what its column
/// program loops over; once per precision and once more with lanes), by which a loader
/// balances its crates.
fn features(module: &Module, options: &COptions) -> String {
    let per_copy = precisions(options).len();
    let kernels: Vec<serde_json::Value> = module
        .functions
        .iter()
        .map(|k| {
            let (calls, own) = match &k.call {
                Some(call) => (
                    call.callees.iter().map(|c| c.name()).collect(),
                    super::rust::statements(&call.rest),
                ),
                None => (Vec::new(), super::rust::statements(k)),
            };
            let copies = per_copy * if lanes_pay(k, options.lanes) { 2 } else { 1 };
            serde_json::json!({"name": k.kind.name(), "calls": calls, "weight": own * copies})
        })
        .collect();
    let features = serde_json::json!({"common": "common", "kernels": kernels});
    serde_json::to_string_pretty(&features).unwrap_or_default() + "\n"
}

/// The largest per-state array of a kernel, in scalars: a batch longer than
/// `isize::MAX / (this * size)` bytes cannot exist, and is a bad length.
fn largest(k: &Function) -> usize {
    let inputs = k.inputs().iter().map(|i| i.len(&k.dims));
    let outputs = k.outputs.iter().map(|o| o.shape.len(&k.dims));
    inputs.chain(outputs).max().unwrap_or(1).max(1)
}

/// What the batch functions' SIMD paths share: moving `L` states in and out of `L`-lane
/// values (`F64x4`, `F32x8`: `repr(transparent)` over `L` scalars, lane l in memory slot l).
const LANE_HELPERS: &str = "\
/// States `i..i + L` of a batch slice as one `L`-lane value per entry (lane l: state i + l).
///
/// # Safety
/// `S` is `T`, `V` is `L` lanes of `S` laid out as `[S; L]`, and `i + L <= s.len()`.
#[cfg(target_arch = \"x86_64\")]
#[inline(always)]
unsafe fn gather<T: Copy, S: Copy + Default, V, const N: usize, const L: usize>(s: &[[T; N]], i: usize) -> [V; N] {
let mut lanes = [[S::default(); L]; N];
for l in 0..L {
let state = &s[i + l];
for k in 0..N {
// SAFETY: S is T (the caller's contract).
lanes[k][l] = unsafe { core::mem::transmute_copy::<T, S>(&state[k]) };
}
}
// SAFETY: [V; N] is [[S; L]; N] (the caller's contract); transmute_copy reads unaligned.
unsafe { core::mem::transmute_copy::<[[S; L]; N], [V; N]>(&lanes) }
}

/// Lane `l` of an `L`-lane kernel output `r` (an array of any depth of `L`-lane values), as
/// the output `X` of that one state.
///
/// # Safety
/// `X` is `r`'s shape over the scalar `S`, each lane value is `[S; L]` in memory, `l < L`.
#[cfg(target_arch = \"x86_64\")]
#[inline(always)]
unsafe fn lane<R, X, S: Copy, const L: usize>(r: &R, l: usize) -> X {
let count = core::mem::size_of::<X>() / core::mem::size_of::<S>();
let src = (r as *const R).cast::<S>();
let mut out = core::mem::MaybeUninit::<X>::uninit();
let dst = out.as_mut_ptr().cast::<S>();
for k in 0..count {
// SAFETY: entry k of X is lane l of r's value k (the caller's contract).
unsafe { dst.add(k).write(src.add(k * L + l).read()) };
}
// SAFETY: every one of X's count scalars was written.
unsafe { out.assume_init() }
}

";

fn emit_rust(module: &Module, options: &COptions, stem: &str) -> String {
    let robot = &module.robot;
    let p = c_prefix(stem);
    let ql = q_len(robot);
    let gate = |feature: &str| {
        if options.kernel_features {
            super::feature_gate(feature)
        } else {
            String::new()
        }
    };
    let common = gate("common");
    let mut out = String::new();
    let _ = writeln!(
        out,
        "/// Batches of states over slices, on every core ([`grid_gen_runtime::for_each`]), and the C ABI\n\
         /// (`extern \"C\"`, declared in `{stem}.h`).\n\
         #[allow(dead_code, clippy::all)]\npub mod {stem}_batch {{\nuse super::{stem}::*;\nuse grid_gen_runtime::Out;\n"
    );
    out.push_str(LANE_HELPERS);
    let _ = writeln!(
        out,
        "/// Success.\npub const GRID_GEN_OK: i32 = 0;\n/// A pointer the call needs is null.\npub const GRID_GEN_NULL_POINTER: i32 = 1;\n\
         /// The batch is longer than any array in memory can be.\npub const GRID_GEN_BAD_LENGTH: i32 = 2;\n\
         /// q holds a quaternion whose norm is more than 1e-6 from 1 (`{p}_bad_state` says which state).\n\
         pub const GRID_GEN_BAD_VALUE: i32 = 3;\n\
         const MANIFEST: &str = {};\n",
        super::names::string_literal(&(manifest(module, options) + "\0"))
    );
    let quats: Vec<String> = robot
        .floating
        .then_some(3)
        .into_iter()
        .chain(robot.spherical.iter().map(|s| s.q_start))
        .map(|at| at.to_string())
        .collect();
    let _ = writeln!(
        out,
        "/// Where each unit quaternion `[qx, qy, qz, qw]` starts in q.\nconst QUATERNIONS: [usize; {}] = [{}];\n\
         /// The first state of q whose quaternion at `QUATERNIONS` has a norm more than 1e-6 from 1 (NaN\n\
         /// included): the kernels read them as rotations without normalising. Four values a quaternion and\n\
         /// state, read on the calling thread before the batch runs.\n\
         fn first_bad<S: Copy + Into<f64>, const N: usize>(q: &[[S; N]]) -> Option<usize> {{\n\
         q.iter().position(|s| {{\nQUATERNIONS.iter().any(|&at| {{\nlet n2: f64 = s[at..at + 4].iter().map(|&v| v.into() * v.into()).sum();\n!((n2.sqrt() - 1.0).abs() <= 1e-6)\n}})\n}})\n}}\n\
         /// The state (from 0) that made this thread's last call return GRID_GEN_BAD_VALUE; -1 before any.\n\
         {common}#[unsafe(no_mangle)]\npub extern \"C\" fn {p}_bad_state() -> i64 {{\ngrid_gen_runtime::bad_state()\n}}\n",
        quats.len(),
        quats.join(", ")
    );
    // A stabilised wrench contact's reference quaternion is read as a rotation too (its
    // logarithm normalises it, but a zero one is NaN): checked as q's are.
    let ref_quats: Vec<String> =
        robot.reference_quaternions().into_iter().map(|at| at.to_string()).collect();
    if !ref_quats.is_empty() {
        let _ = writeln!(
            out,
            "/// Where each wrench contact's reference quaternion `[qx, qy, qz, qw]` starts in contact_ref.
             const REF_QUATERNIONS: [usize; {}] = [{}];
             /// The first state of contact_ref whose quaternion at `REF_QUATERNIONS` has a norm more than 1e-6
             /// from 1 (NaN included), as [`first_bad`] for q.
             fn first_bad_ref<S: Copy + Into<f64>, const N: usize>(r: &[[S; N]]) -> Option<usize> {{
             r.iter().position(|s| {{
REF_QUATERNIONS.iter().any(|&at| {{
let n2: f64 = s[at..at + 4].iter().map(|&v| v.into() * v.into()).sum();
!((n2.sqrt() - 1.0).abs() <= 1e-6)
}})
}})
}}",
            ref_quats.len(),
            ref_quats.join(", ")
        );
    }
    let _ = writeln!(
        out,
        "/// Sets the threads a batch runs on (0: every core, the default; 1: the calling thread).\n\
         {common}#[unsafe(no_mangle)]\npub extern \"C\" fn {p}_set_threads(n: usize) {{\ngrid_gen_runtime::set_threads(n);\n}}\n\n\
         /// The threads a batch runs on now.\n{common}#[unsafe(no_mangle)]\npub extern \"C\" fn {p}_threads() -> usize {{\ngrid_gen_runtime::threads()\n}}\n\n\
         /// What this library holds, as JSON (sizes, names, and each kernel's inputs and outputs); static, NUL-terminated.\n\
         {common}#[unsafe(no_mangle)]\npub extern \"C\" fn {p}_manifest() -> *const core::ffi::c_char {{\nMANIFEST.as_ptr().cast()\n}}\n"
    );
    for k in &module.functions {
        let name = k.kind.name();
        let inputs = k.inputs();
        // The safe batch function.
        let args: Vec<String> =
            inputs.iter().map(|i| format!("{}: &[[T; {}]]", i.name(), input_len(*i, ql))).collect();
        let outs: Vec<String> = k
            .outputs
            .iter()
            .map(|o| format!("{}: &mut [{}]", o.name, array_of(o.shape, "T")))
            .collect();
        let first = inputs[0].name();
        let lens: Vec<String> = inputs
            .iter()
            .skip(1)
            .map(|i| i.name())
            .chain(k.outputs.iter().map(|o| o.name))
            .map(|n| format!("{n}.len() == n"))
            .collect();
        let lanes = lanes_pay(k, options.lanes);
        let per_call = if lanes {
            "in f64 and\n/// f32, four or eight states per call (`F64x4`, `F32x8`) where the CPU has AVX2 and FMA,\n\
             /// bit-identical to one call per state."
        } else {
            "one state per\n/// kernel call: SIMD lanes do not pay for this kernel, or were turned off (`BatchLanes`)."
        };
        let _ = writeln!(
            out,
            "/// `{}` for each state: entry `i` of every slice is state `i`. On every core; {per_call}\n///\n/// # Panics\n/// If the slices' lengths differ.\n\
             {}pub fn {name}<T: Real + Send + Sync + 'static>({}) {{\nlet n = {first}.len();\nassert!({}, \"{name}: every slice holds one entry per state\");",
            k.signature(),
            gate(name),
            args.iter().chain(&outs).cloned().collect::<Vec<_>>().join(", "),
            if lens.is_empty() { "true".to_string() } else { lens.join(" && ") },
        );
        for (j, o) in k.outputs.iter().enumerate() {
            let _ = writeln!(out, "let o{j} = Out({}.as_mut_ptr());", o.name);
        }
        let results: Vec<String> = (0..k.outputs.len()).map(|j| format!("r{j}")).collect();
        let pattern = if results.len() == 1 {
            results[0].clone()
        } else {
            format!("({})", results.join(", "))
        };
        let call: Vec<String> = inputs.iter().map(|i| format!("&{}[i]", i.name())).collect();
        // One state at a time, the kernel writes into state i's outputs in place
        // (`{name}_into`): no output is returned by value, then copied. `{ o }` copies the
        // whole `Out`, so that the closure captures it (which is `Sync`), not its pointer.
        let in_place: Vec<String> =
            (0..k.outputs.len()).map(|j| format!("&mut *{{ o{j} }}.0.add(i)")).collect();
        // Groups of states in one SIMD value where T is f64 or f32 and the CPU runs it: the
        // same operations lane by lane (bit-identical to one call per state), two to three
        // times fewer instructions per state (Speed). The constant `T::IS_F64` comes first:
        // rustc does not compile the code under an `if` on a constant that is false for this
        // `T` (rust-lang/rust#121421), so an f64 batch holds no f32 kernels and back, a third
        // less to compile; the `TypeId` check after it is what makes the transmutes sound.
        let simd = |v: &str, s: &str, l: usize, c: &str| {
            let gathered: Vec<String> = inputs
                .iter()
                .map(|i| {
                    // A const argument that is an expression (`6 * NFEXT`) needs braces.
                    let len = input_len(*i, ql);
                    let len = if len.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
                        len.to_string()
                    } else {
                        format!("{{ {len} }}")
                    };
                    format!("&gather::<T, {s}, {v}, {len}, {l}>({}, i)", i.name())
                })
                .collect();
            let lane_writes: String = (0..k.outputs.len())
                .map(|j| format!("o{j}.write(i + l, lane::<_, _, {s}, {l}>(&r{j}, l));"))
                .collect();
            format!(
                "if T::{c} && core::any::TypeId::of::<T>() == core::any::TypeId::of::<{s}>() && {v}::supported() {{\n\
                 while i + {l} <= range.end {{\n\
                 // SAFETY: T is {s} (its TypeId), {v} is {l} lanes of it and runs on this CPU (both\n\
                 // checked above), states i..i + {l} are in this range, and no two ranges meet.\n\
                 unsafe {{\nlet {pattern} = super::{stem}::{name}({});\nfor l in 0..{l} {{\n{lane_writes}\n}}\n}}\ni += {l};\n}}\n}}",
                gathered.join(", ")
            )
        };
        // Without lanes the kernel is instantiated for T alone, and the states are claimed one
        // at a time.
        let (group, simd_code) = if lanes {
            (
                "if core::any::TypeId::of::<T>() == core::any::TypeId::of::<f32>() { 8 } else { 4 }",
                format!(
                    "#[cfg(target_arch = \"x86_64\")]\n{{\n{}\n{}\n}}\n",
                    simd("F64x4", "f64", 4, "IS_F64"),
                    simd("F32x8", "f32", 8, "IS_F32")
                ),
            )
        } else {
            ("1", String::new())
        };
        let _ = writeln!(
            out,
            "let lanes = {group};\n\
             grid_gen_runtime::for_each_lanes(n, lanes, |range| {{\n#[allow(unused_mut)]\nlet mut i = range.start;\n\
             {simd_code}\
             for i in i..range.end {{\n\
             // SAFETY: i < n, every output's length, and no two ranges meet.\nunsafe {{ super::{stem}::{name}_into({}, {}) }};\n}}\n}});\n}}\n",
            call.join(", "),
            in_place.join(", ")
        );
        // The C entry points.
        for (rt, _) in precisions(options) {
            let ptr_args: Vec<String> = inputs
                .iter()
                .map(|i| format!("{}: *const {rt}", i.name()))
                .chain(k.outputs.iter().map(|o| format!("{}: *mut {rt}", o.name)))
                .collect();
            let all: Vec<&str> =
                inputs.iter().map(|i| i.name()).chain(k.outputs.iter().map(|o| o.name)).collect();
            let _ = writeln!(
                out,
                "/// `{name}` in {rt} for one state (`{stem}.h`).\n///\n/// # Safety\n/// Each pointer holds one state's array, aligned, and outputs overlap nothing.\n\
                 {}#[unsafe(no_mangle)]\npub unsafe extern \"C\" fn {p}_{name}_{rt}({}) -> i32 {{\n// SAFETY: the caller's contract, for n = 1.\nunsafe {{ {p}_{name}_batch_{rt}(1, {}) }}\n}}\n",
                gate(name),
                ptr_args.join(", "),
                all.join(", ")
            );
            let nulls: Vec<String> = all.iter().map(|n| format!("{n}.is_null()")).collect();
            let _ = writeln!(
                out,
                "/// `{name}` in {rt} for `n` states, on every core (`{stem}.h`).\n///\n/// # Safety\n/// Each pointer holds `n` states' arrays, aligned, and outputs overlap nothing.\n\
                 {}#[unsafe(no_mangle)]\npub unsafe extern \"C\" fn {p}_{name}_batch_{rt}(n: usize, {}) -> i32 {{\nif n == 0 {{\nreturn GRID_GEN_OK;\n}}\n\
                 if {} {{\nreturn GRID_GEN_NULL_POINTER;\n}}\nif n > isize::MAX as usize / ({} * core::mem::size_of::<{rt}>()) {{\nreturn GRID_GEN_BAD_LENGTH;\n}}",
                gate(name),
                ptr_args.join(", "),
                nulls.join(" || "),
                largest(k)
            );
            let _ = writeln!(out, "// SAFETY: the caller's contract: each pointer holds n states, which fit in memory (checked above).\nunsafe {{");
            for i in inputs {
                let _ = writeln!(
                    out,
                    "let {0} = core::slice::from_raw_parts({0}.cast::<[{rt}; {1}]>(), n);",
                    i.name(),
                    input_len(*i, ql)
                );
            }
            for o in &k.outputs {
                let _ = writeln!(
                    out,
                    "let {0} = core::slice::from_raw_parts_mut({0}.cast::<{1}>(), n);",
                    o.name,
                    array_of(o.shape, rt)
                );
            }
            // q's quaternions checked before anything runs (a robot with none pays nothing):
            // a bad one turns every output into NaN, silently. Other values are not checked,
            // so that the batch's cost stays the kernel's on every core (NaN in, NaN out).
            for config in inputs.iter().filter(|i| !quats.is_empty() && i.is_config()) {
                let _ = writeln!(
                    out,
                    "if let Some(bad) = first_bad({}) {{\ngrid_gen_runtime::set_bad_state(bad as i64);\nreturn GRID_GEN_BAD_VALUE;\n}}",
                    config.name()
                );
            }
            if !ref_quats.is_empty() && inputs.contains(&Input::ContactRef) {
                let _ = writeln!(
                    out,
                    "if let Some(bad) = first_bad_ref(contact_ref) {{\ngrid_gen_runtime::set_bad_state(bad as i64);\nreturn GRID_GEN_BAD_VALUE;\n}}"
                );
            }
            let _ =
                writeln!(out, "self::{name}::<{rt}>({});\n}}\nGRID_GEN_OK\n}}\n", all.join(", "));
        }
    }
    out.push_str("}\n");
    out
}

fn emit_header(module: &Module, options: &COptions, stem: &str) -> String {
    let robot = &module.robot;
    let dims = module.functions.first().map(|k| k.dims).unwrap_or_default();
    let p = c_prefix(stem);
    let mac = p.to_uppercase();
    let mut h = String::new();
    let _ = writeln!(
        h,
        "// @generated by grid-gen {} from the URDF of robot {}. Do not edit:\n// regenerate with `grid-gen ROBOT.urdf --backend rust,c -o DIR`.\n{}//\n\
         // The C ABI of the kernels in {stem}.rs, built from {stem}_c.rs (see the book, \"From C, C++ and Python\").\n\
         // Arrays are contiguous, row-major and state-major: state i's q starts at q + i * {mac}_NQ, its\n\
         // dqdd_dq at dqdd_dq + i * {mac}_NV * {mac}_NV; matrices are [i][j] = d out_i / d in_j. Vectors are in\n\
         // the order of {mac}_JOINT_NAMES. Pointers must be aligned to their scalar; outputs must not overlap\n\
         // inputs or each other. Every function returns GRID_GEN_OK (0), GRID_GEN_NULL_POINTER when a pointer\n\
         // is null (nothing is written), GRID_GEN_BAD_LENGTH when n states cannot fit in memory, or\n\
         // GRID_GEN_BAD_VALUE when q (or difference's q1) holds a quaternion whose norm is more than 1e-6 from 1 (nothing is\n\
         // written; {p}_bad_state() gives the first such state). n = 0 does nothing. Other values are not\n\
         // checked: a NaN in gives NaN out. Batches run on every core (a rayon pool); {p}_set_threads(1)\n\
         // keeps them on the caller's.\n",
        env!("CARGO_PKG_VERSION"),
        comment_text(&robot.name),
        crate::back::source_line(&robot.source),
    );
    let guard = format!("GRID_GEN_{mac}_H");
    let _ = writeln!(
        h,
        "#ifndef {guard}\n#define {guard}\n\n#include <stddef.h>\n#include <stdint.h>\n\n#ifdef __cplusplus\nextern \"C\" {{\n#endif\n\n\
         #ifndef GRID_GEN_OK\n#define GRID_GEN_OK 0\n#define GRID_GEN_NULL_POINTER 1\n#define GRID_GEN_BAD_LENGTH 2\n#endif\n\
         #ifndef GRID_GEN_BAD_VALUE\n#define GRID_GEN_BAD_VALUE 3\n#endif\n"
    );
    let _ = writeln!(h, "/* Entries of q (Pinocchio's layout: a floating base's [x, y, z, qx, qy, qz, qw] first). */\n#define {mac}_NQ {}", dims.nq);
    let _ = writeln!(h, "/* Velocity coordinates: entries of qd, qdd and tau, rows and columns of the matrices. */\n#define {mac}_NV {}", dims.nv);
    // C has no empty arrays: a robot without movable joints has no name array.
    if dims.nv > 0 {
        let joints: Vec<String> = robot.joint_names.iter().map(|n| c_string_literal(n)).collect();
        let _ =
            writeln!(h, "/* The coordinates' joints, in model order. */\nstatic const char *const {mac}_JOINT_NAMES[{mac}_NV] = {{{}}};", joints.join(", "));
    }
    if dims.nframes > 0 {
        let frames: Vec<String> = robot.frames.iter().map(|n| c_string_literal(n)).collect();
        let _ = writeln!(
            h,
            "/* Frames the frame kernels compute, in their outputs' order ({} axes). */\n#define {mac}_NF {}\nstatic const char *const {mac}_FRAME_NAMES[{mac}_NF] = {{{}}};",
            robot.reference.name().to_uppercase(),
            dims.nframes,
            frames.join(", ")
        );
    }
    if robot.specialisation.step.is_some() {
        let _ = writeln!(h, "/* Entries of the step kernels' tau: the actuated joints. */\n#define {mac}_NU {}\n#define {mac}_NX (2 * {mac}_NV)", dims.nu);
        if robot.specialisation.step.is_some_and(|s| s.runtime_dt()) {
            let _ = writeln!(h, "/* The step kernels take their time step (s) at run time: their last input, dt, one value per state. */");
        }
    }
    if dims.nfext > 0 {
        let _ = writeln!(
            h,
            "/* Bodies that take an external force: fext has 6 entries per body, [f; tau] in its joint's frame. */\n#define {mac}_NFEXT {}",
            dims.nfext
        );
    }
    if dims.nlambda > 0 {
        let frames: Vec<String> =
            robot.contacts.iter().map(|c| c_string_literal(&c.frame)).collect();
        let _ = writeln!(
            h,
            "/* Entries of the contact forces lambda (3 per point, 6 per wrench; LOCAL_WORLD_ALIGNED). */\n#define {mac}_NLAMBDA {}\n\
             #define {mac}_NCONTACTS {}\nstatic const char *const {mac}_CONTACT_FRAMES[{mac}_NCONTACTS] = {{{}}};",
            dims.nlambda,
            frames.len(),
            frames.join(", ")
        );
        if dims.nbaumgarte > 0 {
            let _ = writeln!(h, "/* The contact kernels and the step take gains (Kp, Kd per contact: 2 * {mac}_NCONTACTS values per state) and contact_ref ({mac}_NCONTACT_REF values per state: a point contact's reference position in the world, 3 values; a wrench contact's reference placement, position and quaternion x, y, z, qx, qy, qz, qw, 7, the quaternion checked as q's: GRID_GEN_BAD_VALUE), Pinocchio's Baumgarte corrector. */\n#define {mac}_NCONTACT_REF {}", dims.ncontact_ref);
        }
        if dims.ncontacts > 0 {
            let _ = writeln!(h, "/* The contact kernels and the step take active: {mac}_NCONTACTS values per state, 1 where a contact holds, 0 where it does not. */");
        }
    }
    let _ = writeln!(
        h,
        "\n/* Sets the threads a batch runs on: 0 for every core (the default), 1 for the calling thread. */\nvoid {p}_set_threads(size_t n);\n\
         /* The threads a batch runs on now. */\nsize_t {p}_threads(void);\n\
         /* The state (from 0) that made this thread's last call return GRID_GEN_BAD_VALUE; -1 before any. */\nint64_t {p}_bad_state(void);\n\
         /* What the library holds, as JSON: sizes, names, and each kernel's inputs and outputs. Static. */\nconst char *{p}_manifest(void);\n"
    );
    let size = |n: &str| format!("{mac}_{n}");
    let c_len = |len: &str| -> String {
        // `6 * NFEXT` and the like, in the header's macros.
        len.split(' ')
            .map(
                |t| if t.chars().all(|c| c.is_ascii_uppercase()) { size(t) } else { t.to_string() },
            )
            .collect::<Vec<_>>()
            .join(" ")
    };
    for k in &module.functions {
        let name = k.kind.name();
        let ins: Vec<String> = k
            .inputs()
            .iter()
            .map(|i| format!("{}[{}]", i.name(), c_len(input_len(*i, q_len(robot)))))
            .collect();
        let outs: Vec<String> = k
            .outputs
            .iter()
            .map(|o| {
                let dims: Vec<String> = shape_macros(o.shape).iter().map(|d| c_len(d)).collect();
                format!("{}[{}]", o.name, dims.join("]["))
            })
            .collect();
        // The docs are grid-gen's own text, but a `*/` in one must still not end the comment.
        let doc = k.doc().replace("*/", "*\\/");
        let _ = writeln!(
            h,
            "/* {name}: {doc}\n * Per state, in: {}.\n * Per state, out: {}. */",
            ins.join(", "),
            outs.join(", ")
        );
        for (rt, ct) in precisions(options) {
            let params: Vec<String> = k
                .inputs()
                .iter()
                .map(|i| format!("const {ct} *{}", i.name()))
                .chain(k.outputs.iter().map(|o| format!("{ct} *{}", o.name)))
                .collect();
            let _ = writeln!(h, "int32_t {p}_{name}_{rt}({});", params.join(", "));
            let _ = writeln!(h, "int32_t {p}_{name}_batch_{rt}(size_t n, {});", params.join(", "));
        }
        h.push('\n');
    }
    let _ = writeln!(h, "#ifdef __cplusplus\n}}\n#endif\n\n#endif");
    h
}

/// An output's per-state dimensions as the header's size macros (without the prefix).
fn shape_macros(shape: Shape) -> Vec<String> {
    let v = |d: &[&str]| d.iter().map(|s| s.to_string()).collect();
    match shape {
        Shape::Vector => v(&["NV"]),
        Shape::Matrix => v(&["NV", "NV"]),
        Shape::PerFrame(k) => vec!["NF".into(), k.to_string()],
        Shape::FrameMatrix(r) => vec!["NF".into(), r.to_string(), "NV".into()],
        Shape::Config => v(&["NQ"]),
        Shape::StateMatrix => v(&["NX", "NX"]),
        Shape::StateInput => v(&["NX", "NU"]),
        Shape::ByFext => v(&["NV", "6 * NFEXT"]),
        Shape::ByLambda => v(&["NV", "NLAMBDA"]),
        Shape::Lambda => v(&["NLAMBDA"]),
        Shape::LambdaBy => v(&["NLAMBDA", "NV"]),
        Shape::LambdaByState => v(&["NLAMBDA", "NX"]),
        Shape::LambdaByInput => v(&["NLAMBDA", "NU"]),
    }
}

/// The prefix of the C names: the file stem, or `robot` and the stem where the stem starts
/// with `_` (C reserves names that start with `__` or `_` and a capital letter).
pub fn c_prefix(stem: &str) -> String {
    if stem.starts_with('_') {
        format!("robot{stem}")
    } else {
        stem.to_string()
    }
}

/// The C target's two files for `module`: `<stem>_c.rs` and `<stem>.h`.
/// Why the C target could not print a module.
#[derive(Debug, thiserror::Error)]
pub enum CError {
    #[error("the C target needs at least one precision (f64 or f32)")]
    NoPrecision,
    #[error("internal error: the C target produced Rust that does not parse: {0}")]
    Unparsable(String),
}

pub fn emit(module: &Module, options: &COptions) -> Result<Vec<GeneratedFile>, CError> {
    if !options.f64 && !options.f32 {
        return Err(CError::NoPrecision);
    }
    let stem = identifier(&module.robot.name);
    let code = emit_rust(module, options, &stem);
    let file = syn::parse_file(&code).map_err(|e| CError::Unparsable(e.to_string()))?;
    let header = format!(
        "// @generated by grid-gen {} from the URDF of robot {}. Do not edit.\n{}// The batch entry points and C ABI of {stem}.rs: `include!` this file beside\n\
         // `mod {stem} {{ include!(\"{stem}.rs\"); }}` in a crate that depends on grid-gen-runtime;\n\
         // crate-type = [\"staticlib\", \"cdylib\"] makes the library that {stem}.h declares.\n\n",
        env!("CARGO_PKG_VERSION"),
        comment_text(&module.robot.name),
        crate::back::source_line(&module.robot.source),
    );
    let mut files = vec![
        GeneratedFile {
            name: format!("{stem}_c.rs"),
            contents: header + &prettyplease::unparse(&file),
        },
        GeneratedFile { name: format!("{stem}.h"), contents: emit_header(module, options, &stem) },
    ];
    if options.kernel_features {
        files.push(GeneratedFile {
            name: format!("{stem}_features.json"),
            contents: features(module, options),
        });
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `auto`'s size bound: a kernel of `LANES_MAX_OPS` operations keeps its lanes and one
    /// more loses them (iiwa's `fd` padded with additions; no bundled robot's test module
    /// is that large, the humanoid's `contact_fd_grad` is).
    #[test]
    fn lanes_stop_above_the_measured_size() {
        use crate::ir::{lower_function, Id, KernelKind, LowerOptions, Node, Op};
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../robots/grid_iiwa.urdf");
        let text = std::fs::read_to_string(path).unwrap();
        let (model, _) = crate::Model::from_urdf_str(path, &text, false).unwrap();
        let mut f =
            lower_function(&model, [0.0, 0.0, -9.81], KernelKind::Fd, &LowerOptions::default())
                .unwrap();
        assert!(lanes_pay(&f, BatchLanes::Auto));
        let pad = Node { op: Op::Add(Id(0), Id(0)), ..f.nodes[0] };
        let ops = f.counts().total();
        f.nodes.extend(std::iter::repeat_n(pad, LANES_MAX_OPS - ops));
        assert!(lanes_pay(&f, BatchLanes::Auto));
        f.nodes.push(pad);
        assert!(!lanes_pay(&f, BatchLanes::Auto));
        assert!(lanes_pay(&f, BatchLanes::All));
    }

    #[test]
    fn c_strings_escape_everything_that_could_end_or_bend_them() {
        assert_eq!(c_string_literal("a\"b\\c??=d"), "\"a\\\"b\\\\c\\?\\?=d\"");
        assert_eq!(c_string_literal("é\n"), "\"\\303\\251\\012\"");
        // An octal escape never takes more than three digits, so a digit after it stays a digit.
        assert_eq!(c_string_literal("\u{1}7"), "\"\\0017\"");
    }
}
