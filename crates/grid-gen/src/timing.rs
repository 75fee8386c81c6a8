//! Times the generated Rust kernels of any robot: the module is generated, compiled with
//! `rustc -C opt-level=3` beside a small timing program (generated files need no crate),
//! run, and its medians read back. `grid-gen bench --backend rust` and
//! `grid-gen accuracy --time` use it, so the speed of a format sits beside its accuracy.
//!
//! Protocol, as the criterion benchmarks (`crates/grid-gen-kernels/benches`): 64 fixed
//! pseudo-random states cycled, one state per call; each sample runs enough calls to
//! take 2 ms; the median of 15 samples is reported. One thread. Absolute times on a
//! shared machine are noise: compare within one run.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::generate::{generate, GenerateError, Options, Target};
use crate::ir::{KernelKind, LowerOptions};
use crate::model::Model;

/// One kernel's time per call.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct KernelTime {
    pub kernel: KernelKind,
    /// `f64`, `f32`, or a mixed-precision plan's label (`mixed ≤1e-12`).
    pub scalar: String,
    /// `portable` (no FMA; what `accuracy` measures bit for bit), `dispatch` (the public
    /// function: the `avx512` copy where the CPU has AVX-512, else the `fma` copy where it
    /// has AVX2 and FMA), `into` (the public `{kernel}_into`: the same copy, into outputs
    /// kept from call to call), or `fma` (timed only where `dispatch` is the `avx512` copy).
    pub copy: &'static str,
    pub ns_per_call: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum TimingError {
    #[error(transparent)]
    Generate(#[from] GenerateError),
    #[error("cannot write the timing program into {0}: {1}")]
    Io(PathBuf, std::io::Error),
    #[error(transparent)]
    Rustc(#[from] crate::tools::rustc::RustcError),
    #[error("the timing program wrote an unexpected line: `{0}`")]
    Output(String),
}

/// A mixed-precision kernel to time beside the generic ones: the function and which of
/// its nodes run in f64 ([`crate::numerics::precision::Plan::wide`]), under `label`.
pub struct MixedKernel<'a> {
    pub label: String,
    pub function: &'a crate::ir::Function,
    pub wide: &'a [bool],
}

/// The module of mixed-precision kernels, `mixed{i}::NAME` for the i-th of `mixed`.
fn mixed_module(nv: usize, nq: usize, mixed: &[MixedKernel]) -> String {
    let mut out = String::new();
    for (i, m) in mixed.iter().enumerate() {
        let _ = writeln!(
            out,
            "pub mod mixed{i} {{
const NV: usize = {nv};
#[allow(dead_code)]
const NQ: usize = {nq};"
        );
        crate::back::rust::emit_mixed_kernel(
            &mut out,
            m.function,
            "NQ",
            &crate::back::rust::RustOptions::default(),
            m.wide,
        );
        out.push_str(
            "}
",
        );
    }
    out
}

/// A call's arguments from a state `x = (q, [q̇, u], fext, λ, dt, active, gains, contact_ref)`: each input in the kernel's
/// order, u as q̈ or τ, the step kernels' τ the first NU entries of u.
fn call_args(inputs: &[crate::ir::Input]) -> String {
    use crate::ir::Input;
    let args: Vec<&str> = inputs
        .iter()
        .map(|i| match i {
            // `difference(q, q)`: the kernels have no branches, so any pair times the same.
            Input::Q | Input::Q1 => "&x.0",
            Input::Qd | Input::V => "&x.1[0]",
            Input::Qdd | Input::Tau => "&x.1[1]",
            Input::TauActuated => "x.1[1].first_chunk::<{ robot::NU }>().unwrap()",
            Input::Fext => "&x.2",
            Input::Lambda => "&x.3",
            Input::Dt => "&x.4",
            Input::Active => "&x.5",
            Input::Gains => "&x.6",
            Input::ContactRef => "&x.7",
            // Only a step kernel's rest takes these, and only the kernels are timed.
            Input::Called(_) => "unreachable!()",
        })
        .collect();
    args.join(", ")
}

/// The timing program for `kernels` of a module whose file is `robot.rs`, and the
/// mixed kernels of `mixed.rs`.
fn program(kernels: &[KernelKind], mixed: &[MixedKernel], model: &Model) -> String {
    let (nq, nf, nl) = (model.nq(), 6 * model.nfext(), model.nlambda());
    let nc = model.specialisation.active_len();
    let nb = model.specialisation.baumgarte_len();
    let nr = model.specialisation.contact_ref_len();
    let mut calls = String::new();
    for (i, m) in mixed.iter().enumerate() {
        let name = m.function.kind.name();
        let args = call_args(m.function.inputs());
        let _ = writeln!(calls, "    println!(\"{name} {i} mixed {{}}\", time(|j| {{ let x = &s64[j]; black_box(mixed::mixed{i}::{name}({args})); }}));");
    }
    for k in kernels {
        let name = k.name();
        let args = call_args(&k.inputs_for(&model.specialisation));
        for (scalar, states) in [("f64", "s64"), ("f32", "s32")] {
            for (copy, path) in [("portable", "robot::portable::"), ("dispatch", "robot::")] {
                let _ =
                    writeln!(calls, "    println!(\"{name} {scalar} {copy} {{}}\", time(|j| {{ let x = &{states}[j]; black_box({path}{name}({args})); }}));");
            }
            // The public `{name}_into`, into outputs the program keeps from call to call (as
            // Pinocchio's benchmark keeps its `Data`): the first call's outputs, by value.
            let n_out = k.outputs_for(&model.specialisation).len();
            let outs: Vec<String> = match n_out {
                1 => vec!["&mut o".to_string()],
                n => (0..n).map(|i| format!("&mut o.{i}")).collect(),
            };
            let _ = writeln!(
                calls,
                "    {{ let x = &{states}[0]; let mut o = robot::{name}({args}); println!(\"{name} {scalar} into {{}}\", time(|j| {{ let x = &{states}[j]; robot::{name}_into({args}, {}); black_box(&mut o); }})); }}",
                outs.join(", ")
            );
            // Where the dispatcher picks the avx512 copy, the fma copy beside it shows what
            // AVX-512 buys.
            let _ = writeln!(
                calls,
                "    #[cfg(target_arch = \"x86_64\")]\n    if robot::has_avx512() {{ println!(\"{name} {scalar} fma {{}}\", time(|j| {{ let x = &{states}[j]; black_box(unsafe {{ robot::fma::{name}({args}) }}); }})); }}"
            );
        }
    }
    format!(
        r#"#![allow(dead_code, clippy::all)]
mod robot {{
    include!("robot.rs");
}}
mod mixed {{
    include!("mixed.rs");
}}
use std::hint::black_box;
use std::time::Instant;

const STATES: usize = 64;

fn state(k: usize, i: usize, salt: usize) -> f64 {{
    (((k * 7919 + i * 104_729 + salt * 15_485_863) % 2001) as f64 / 1000.0) - 1.0
}}

fn time<F: FnMut(usize)>(mut f: F) -> f64 {{
    let mut reps = 1usize;
    loop {{
        let t = Instant::now();
        for r in 0..reps {{
            f(r % STATES);
        }}
        if t.elapsed().as_secs_f64() > 2e-3 || reps > 1 << 30 {{
            break;
        }}
        reps *= 2;
    }}
    let mut samples: Vec<f64> = (0..15)
        .map(|_| {{
            let t = Instant::now();
            for r in 0..reps {{
                f(r % STATES);
            }}
            t.elapsed().as_secs_f64() * 1e9 / reps as f64
        }})
        .collect();
    samples.sort_by(f64::total_cmp);
    samples[7]
}}

fn main() {{
    const N: usize = robot::NV;
    // q (nq entries: a floating base's quaternion is normalised by the kernels), then q̇, and
    // q̈ or τ; external forces (6 per body) and contact forces, in newtons and newton-metres.
    const NQ: usize = {nq};
    const NF: usize = {nf};
    const NL: usize = {nl};
    // A run-time time step between 5 and 15 ms, for step kernels that take one.
    // Every candidate contact active, for kernels that take a contact mask.
    const NC: usize = {nc};
    // Baumgarte gains (Kp 100, Kd 20) and references (positions within a metre of the
    // origin; a wrench's quaternion is normalised by the kernels).
    const NB: usize = {nb};
    const NR: usize = {nr};
    let s64: Vec<([f64; NQ], [[f64; N]; 2], [f64; NF], [f64; NL], [f64; 1], [f64; NC], [f64; 2 * NB], [f64; NR])> = (0..STATES)
        .map(|j| (std::array::from_fn(|i| state(j, i, 0)), std::array::from_fn(|salt| std::array::from_fn(|i| state(j, i, salt + 1))), std::array::from_fn(|i| 20.0 * state(j, i, 3)), std::array::from_fn(|i| 100.0 * state(j, i, 4)), [0.01 + 0.005 * state(j, 0, 5)], [1.0; NC], std::array::from_fn(|i| if i % 2 == 0 {{ 100.0 }} else {{ 20.0 }}), std::array::from_fn(|i| state(j, i, 6))))
        .collect();
    let s32: Vec<([f32; NQ], [[f32; N]; 2], [f32; NF], [f32; NL], [f32; 1], [f32; NC], [f32; 2 * NB], [f32; NR])> = s64.iter().map(|x| (x.0.map(|y| y as f32), x.1.map(|v| v.map(|y| y as f32)), x.2.map(|y| y as f32), x.3.map(|y| y as f32), x.4.map(|y| y as f32), x.5.map(|y| y as f32), x.6.map(|y| y as f32), x.7.map(|y| y as f32))).collect();
{calls}}}
"#
    )
}

/// Generates `model`'s Rust kernels (`kernels`, with `gravity`, and the gradient
/// formulation and solve of `routes`, whose kernel list is not read), compiles
/// them with `rustc` in `work` (a folder this call may fill and leaves behind), and times
/// each in f64 and f32, portable and dispatching copies.
pub fn time_rust_kernels(
    model: &Model,
    gravity: [f64; 3],
    routes: &LowerOptions,
    kernels: &[KernelKind],
    rustc: &str,
    work: &Path,
) -> Result<Vec<KernelTime>, TimingError> {
    time_rust_kernels_with_mixed(model, gravity, routes, kernels, &[], rustc, work)
}

/// [`time_rust_kernels`], and the `mixed` kernels (one state per call, f64 in and out;
/// their `copy` is `portable`: they are not FMA-dispatched).
pub fn time_rust_kernels_with_mixed(
    model: &Model,
    gravity: [f64; 3],
    routes: &LowerOptions,
    kernels: &[KernelKind],
    mixed: &[MixedKernel],
    rustc: &str,
    work: &Path,
) -> Result<Vec<KernelTime>, TimingError> {
    let options = Options {
        gravity,
        targets: vec![Target::Rust],
        // With the avx512 copy, so that on an AVX-512 CPU `dispatch` is the fastest copy
        // and `fma` is timed beside it.
        rust: crate::back::rust::RustOptions { avx512: true, ..Default::default() },
        lower: LowerOptions { kernels: kernels.to_vec(), ..routes.clone() },
        ..Options::default()
    };
    let files = generate(model, &options)?;
    let module = files
        .into_iter()
        .find(|f| f.name.ends_with(".rs"))
        .expect("the Rust target writes a .rs file");
    // Kernels the model cannot have (M singular) are not in the module.
    let present: Vec<KernelKind> = kernels
        .iter()
        .copied()
        .filter(|k| module.contents.contains(&format!("pub fn {}<", k.name())))
        .collect();
    let io = |e| TimingError::Io(work.to_path_buf(), e);
    std::fs::create_dir_all(work).map_err(io)?;
    std::fs::write(work.join("robot.rs"), &module.contents).map_err(io)?;
    std::fs::write(work.join("mixed.rs"), mixed_module(model.nv(), model.nq(), mixed))
        .map_err(io)?;
    std::fs::write(work.join("main.rs"), program(&present, mixed, model)).map_err(io)?;
    let exe = work.join(if cfg!(windows) { "time_kernels.exe" } else { "time_kernels" });
    let text = crate::tools::rustc::build_and_run(rustc, &work.join("main.rs"), &exe)?;
    let mut times = Vec::new();
    for line in text.lines() {
        let parts: Vec<&str> = line.split_whitespace().collect();
        let parsed = match parts.as_slice() {
            [k, i, "mixed", ns] => {
                let m = i.parse::<usize>().ok().and_then(|i| mixed.get(i));
                KernelKind::parse(k).zip(m).zip(ns.parse::<f64>().ok()).map(|((kernel, m), ns)| {
                    KernelTime {
                        kernel,
                        scalar: m.label.clone(),
                        copy: "portable",
                        ns_per_call: ns,
                    }
                })
            }
            [k, s, c, ns] => {
                KernelKind::parse(k).zip(ns.parse::<f64>().ok()).map(|(kernel, ns)| KernelTime {
                    kernel,
                    scalar: if *s == "f32" { "f32" } else { "f64" }.to_string(),
                    copy: match *c {
                        "portable" => "portable",
                        "fma" => "fma",
                        "into" => "into",
                        _ => "dispatch",
                    },
                    ns_per_call: ns,
                })
            }
            _ => None,
        };
        times.push(parsed.ok_or_else(|| TimingError::Output(line.to_string()))?);
    }
    Ok(times)
}

/// `grid-gen bench --backend rust`'s table: one row per kernel of `kinds`, ns per call for
/// each scalar type and machine-code copy in `times` ("-" where one was not timed).
pub fn table(times: &[KernelTime], kinds: &[KernelKind]) -> String {
    let mut out = format!(
        "{:<12} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}   (ns per call, one state, median of 15; dispatch runs the {} copy here, returning its outputs; into is `{{kernel}}_into`, the same copy into kept outputs)\n",
        "kernel",
        "f64 portable",
        "f64 fma",
        "f64 dispatch",
        "f32 portable",
        "f32 fma",
        "f32 dispatch",
        "f64 into",
        "f32 into",
        dispatched_copy()
    );
    for &kind in kinds {
        let cell = |scalar: &str, copy: &str| {
            times
                .iter()
                .find(|t| t.kernel == kind && t.scalar == scalar && t.copy == copy)
                .map_or("-".to_string(), |t| format!("{:.0}", t.ns_per_call))
        };
        let _ = writeln!(
            out,
            "{:<12} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14} {:>14}",
            kind.name(),
            cell("f64", "portable"),
            cell("f64", "fma"),
            cell("f64", "dispatch"),
            cell("f32", "portable"),
            cell("f32", "fma"),
            cell("f32", "dispatch"),
            cell("f64", "into"),
            cell("f32", "into")
        );
    }
    out
}

/// The machine-code copy the generated dispatchers pick on this CPU (the same test as
/// their `has_avx512` and `has_fma`).
pub fn dispatched_copy() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        let fma = std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        if fma
            && std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512vl")
        {
            return "avx512";
        }
        if fma {
            return "fma";
        }
    }
    "portable"
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_missing_compiler_is_named_with_what_to_install() {
        let model = crate::Model::from_urdf_str(
            "one.urdf",
            r#"<robot name="one"><link name="a"/><link name="b"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
               <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>"#,
            false,
        )
        .unwrap()
        .0;
        let work =
            std::env::temp_dir().join(format!("grid-gen-timing-test-{}", std::process::id()));
        let err = super::time_rust_kernels(
            &model,
            [0.0, 0.0, -9.81],
            &crate::ir::LowerOptions::default(),
            &[crate::ir::KernelKind::Rnea],
            "/nonexistent/rustc",
            &work,
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.starts_with("cannot run `/nonexistent/rustc`") && err.contains("https://rustup.rs"),
            "{err}"
        );
        // The program it would have compiled is there, for a user to build by hand.
        assert!(std::fs::read_to_string(work.join("main.rs"))
            .unwrap()
            .contains("println!(\"rnea f64 portable {}\""));
        std::fs::remove_dir_all(&work).unwrap();
    }
}
