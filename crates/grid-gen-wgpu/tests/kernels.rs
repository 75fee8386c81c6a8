//! The WGSL backend and this runtime: every robot's shader validated by naga, and the
//! kernels run through wgpu (lavapipe, Mesa's software Vulkan driver, when there is no
//! GPU) on random and extreme states, both strategies, against the reference dynamics.
//!
//! Tolerances (‖Δ‖max / ‖ref‖max per output; the reference runs in f64 at the
//! f32-rounded state, so only the shader's arithmetic is measured), the bounds of the Rust
//! backend's f32 tests, which run the same graphs:
//! - f32, RNEA, its gradient and M: ≤ 1e-5 (ε = 6e-8 times O(10·depth) rounded products,
//!   and about two digits of cancellation in the Coriolis terms at speeds of 1e3);
//! - f32, through M⁻¹: ≤ 1e-4 (the error grows with cond(M), 1e2 to 1e4 for these robots);
//! - f64: ≤ 1e-12 (ε = 1.1e-16 times the same growth, as the Rust f64 kernels).
//!
//! With `CI` set, a machine without a Vulkan adapter fails these tests (scripts/test.sh
//! installs lavapipe); elsewhere they say so and check only the naga validation.
//!
//! The runs cover every kernel of every bundled robot in f32 in both strategies (Atlas's
//! `fd_grad` too: with one invocation per state as dispatches of at most 1000
//! operations, which lavapipe compiles in linear time), HyQ also in f64 in both
//! strategies, a floating base, coupled mimics and spherical joints in f64, and WGSL's
//! built-in trig on the double pendulum. lavapipe compiles a pipeline at its first
//! dispatch: about 0.5 ms per statement with one invocation per state; the cooperative
//! entries are a table walked by the same short loop for every kernel, a few ms each.

use grid_gen::back::wgsl::{Precision, Strategy, Trig, WgslOptions};
use grid_gen::generate::{generate, Options, Target};
use grid_gen::ir::KernelKind;
use grid_gen::{reference, Model};
use grid_gen_test_support::*;
use grid_gen_wgpu::{Gpu, GpuError};

const DIRECT: f64 = 1e-5;
const THROUGH_MINV: f64 = 1e-4;
const F64_TOL: f64 = 1e-12;
/// The condition number up to which [`F64_TOL`] holds a solve: the floating robots' M
/// (floating HyQ's is 4e3 to 8e3 on the tests' states).
const COND_AT_F64_TOL: f64 = 1e4;

fn wgsl(model: &Model, wgsl: WgslOptions) -> String {
    let options = Options { targets: vec![Target::Wgsl], wgsl, ..Options::default() };
    generate(model, &options).unwrap().remove(0).contents
}

/// One state's f64 outputs from a run (`got` from the state's first value, outputs one after
/// another) against the reference's `want` and the IR interpreter's values, each within
/// F64_TOL, as every f64 kernel is held; `what` names the state in a failure. Returns the
/// worst relative error from the reference.
fn check_f64_state(
    what: &str,
    f: &grid_gen::ir::Function,
    nv: usize,
    got: &[f64],
    want: &[nalgebra::DMatrix<f64>],
    interpreted: &[Vec<f64>],
) -> f64 {
    check_f64_state_within(what, f, nv, got, want, interpreted, F64_TOL)
}

/// [`check_f64_state`] within `tol` (a state whose solve is worse conditioned than the
/// states F64_TOL was set for: [`contact_step_matches_the_reference`]).
fn check_f64_state_within(
    what: &str,
    f: &grid_gen::ir::Function,
    nv: usize,
    got: &[f64],
    want: &[nalgebra::DMatrix<f64>],
    interpreted: &[Vec<f64>],
    tol: f64,
) -> f64 {
    let (mut worst, mut base) = (0.0f64, 0);
    assert_eq!(f.outputs.len(), want.len(), "{what}: the reference's outputs");
    for ((o, want), ir_vals) in f.outputs.iter().zip(want).zip(interpreted) {
        let got = output_matrix(o.shape, nv, &got[base..base + o.ids.len()]);
        let e = rel_err(&got, want);
        assert!(e <= tol, "{what} {}: {e:.2e} > {tol:.1e}", o.name);
        let e_ir = rel_err(&got, &output_matrix(o.shape, nv, ir_vals));
        assert!(e_ir <= tol, "{what} {}: {e_ir:.2e} from the IR > {tol:.1e}", o.name);
        worst = worst.max(e);
        base += o.ids.len();
    }
    worst
}

fn naga_validate(name: &str, source: &str) -> std::time::Duration {
    let start = std::time::Instant::now();
    let module = naga::front::wgsl::parse_str(source)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::FLOAT64,
    )
    .validate(&module)
    .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    start.elapsed()
}

#[test]
fn every_robot_validates_with_naga() {
    for robot in robots() {
        let model = load(&robot);
        let source = wgsl(&model, WgslOptions::default());
        let t = naga_validate(&robot, &source);
        eprintln!("{robot}: {} lines, naga parse + validate {t:.2?}", source.lines().count());
    }
    // A floating base (both strategies, f32 and f64).
    for robot in ["grid_hyq", "grid_atlas"] {
        let model = load_floating(robot);
        for precision in [Precision::F32, Precision::F64] {
            let source = wgsl(
                &model,
                WgslOptions { precision, trig: Trig::Accurate, ..WgslOptions::default() },
            );
            assert!(
                source.contains(&format!("// nq: {}\n", model.nq())),
                "{robot}: the header gives nq"
            );
            let t = naga_validate(robot, &source);
            eprintln!("{robot} floating {}: naga parse + validate {t:.2?}", precision.name());
        }
    }
    // Coupled mimic joints (the Panda's fingers; mimic_arm's multipliers and offsets).
    for (name, path) in [
        ("panda coupled", repo().join("robots/panda.urdf")),
        ("mimic_arm coupled", repo().join("tests/fixtures/mimic_arm.urdf")),
    ] {
        let source = wgsl(&load_coupled_urdf(&path), WgslOptions::default());
        let t = naga_validate(name, &source);
        eprintln!("{name}: naga parse + validate {t:.2?}");
    }
    // Spherical joints (ball_arm: three, on a fixed base and a floating one).
    for floating in [false, true] {
        let model = load_urdf(&repo().join("tests/fixtures/ball_arm.urdf"), floating);
        let source = wgsl(&model, WgslOptions::default());
        assert!(
            source.contains(&format!("// nq: {}\n", model.nq())),
            "ball_arm: the header gives nq"
        );
        let t = naga_validate("ball_arm", &source);
        eprintln!("ball_arm (floating: {floating}): naga parse + validate {t:.2?}");
    }
    // The other precision and trigonometry, on a chain and a tree.
    for robot in ["grid_iiwa", "grid_hyq"] {
        let model = load(robot);
        for (precision, trig) in [(Precision::F64, Trig::Accurate), (Precision::F32, Trig::Builtin)]
        {
            let source = wgsl(&model, WgslOptions { precision, trig, ..WgslOptions::default() });
            let t = naga_validate(robot, &source);
            eprintln!(
                "{robot} {} {}: naga parse + validate {t:.2?}",
                precision.name(),
                trig.name()
            );
        }
    }
}

/// One GPU test at a time: two lavapipe devices in one process, each with its own worker
/// threads, made a 36-second test take 15 minutes on the 2-core CI machine (measured:
/// the f64 test alone 36 s; beside the f32 test, most of the test command's 32 minutes).
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// The adapter, or `None` (with a note) where there is none and `CI` is not set; with the
/// guard that keeps the other GPU tests waiting.
fn gpu() -> Option<(std::sync::MutexGuard<'static, ()>, Gpu)> {
    // A test that failed while holding the guard poisons it; the others still run.
    let serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    match Gpu::new() {
        Ok(g) => {
            eprintln!("adapter: {}", g.adapter());
            Some((serial, g))
        }
        Err(e) => {
            assert!(std::env::var_os("CI").is_none(), "{e}");
            eprintln!("SKIPPED running the WGSL kernels: {e}");
            None
        }
    }
}

/// [`gpu`], when the adapter runs f64 shaders; with `CI` set, one that does not fails.
fn gpu_f64() -> Option<(std::sync::MutexGuard<'static, ()>, Gpu)> {
    let (serial, gpu) = gpu()?;
    if !gpu.has_f64() {
        assert!(
            std::env::var_os("CI").is_none(),
            "the adapter {} has no SHADER_F64 (lavapipe has it)",
            gpu.adapter()
        );
        eprintln!("SKIPPED f64: the adapter {} has no SHADER_F64", gpu.adapter());
        return None;
    }
    Some((serial, gpu))
}

/// Random states and extremes: zero, both joint limits, speeds 1e-8 and 1e3; rounded to
/// f32 so both precisions see the same inputs.
fn states(model: &Model, rng: &mut Rng) -> Vec<[Vec<f64>; 3]> {
    let n = model.nv();
    let round = |v: Vec<f64>| v.into_iter().map(|x| x as f32 as f64).collect::<Vec<_>>();
    let limit = |lo: bool| {
        let coordinates = model.coordinate_joints().into_iter().map(|i| model.joint(i));
        coordinates
            .map(|j| {
                j.limit
                    .map_or(if lo { -3.1 } else { 3.1 }, |(l, h)| if lo { l } else { h })
                    .clamp(-1e3, 1e3)
            })
            .collect::<Vec<_>>()
    };
    let mut out: Vec<[Vec<f64>; 3]> = (0..32)
        .map(|_| [rng.vec(n, -3.1, 3.1), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0)])
        .collect();
    out.push([vec![0.0; n], vec![0.0; n], vec![0.0; n]]);
    out.push([limit(true), rng.vec(n, -1.0, 1.0), rng.vec(n, -1.0, 1.0)]);
    out.push([limit(false), rng.vec(n, -1.0, 1.0), rng.vec(n, -1.0, 1.0)]);
    for s in [1e-8, 1e3] {
        out.push([rng.vec(n, -3.1, 3.1), rng.vec(n, -s, s), rng.vec(n, -s, s)]);
    }
    // A floating base gets a random pose (the zero state: at the origin, unrotated); its
    // quaternion rounded to f32 is not quite unit, which kernels and reference both absorb.
    let zero = out.len() - 5;
    out.into_iter()
        .enumerate()
        .map(|(k, [q, qd, u])| {
            let base = if !model.floating || k == zero {
                [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
            } else {
                rng.base_pose()
            };
            let mut q = model.q_from_joints(&q, base);
            // Spherical joints likewise (drawn only for robots that have them).
            for &first in &model.spherical {
                let at = model.group_q(first).0;
                if k != zero {
                    q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
                }
            }
            [round(q), round(qd), round(u)]
        })
        .collect()
}

/// Runs every kernel of `robot` under each strategy and checks each state's outputs
/// against the reference and the IR interpreter.
fn check_robot(
    gpu: &Gpu,
    robot: &str,
    options: WgslOptions,
    strategies: &[Strategy],
    rng: &mut Rng,
) {
    check_model(gpu, robot, &load(robot), &KernelKind::ALL, options, strategies, rng)
}

/// [`check_robot`] on a model, for the `kernels` only.
fn check_model(
    gpu: &Gpu,
    robot: &str,
    model: &Model,
    kernels: &[KernelKind],
    options: WgslOptions,
    strategies: &[Strategy],
    rng: &mut Rng,
) {
    check_model_within(gpu, robot, model, kernels, options, strategies, rng, F64_TOL)
}

/// [`check_model`], f64 outputs held to the reference within `f64_reference` (and to the
/// IR interpreter, which runs the same graph, within [`F64_TOL`] still).
#[allow(clippy::too_many_arguments)]
fn check_model_within(
    gpu: &Gpu,
    robot: &str,
    model: &Model,
    kernels: &[KernelKind],
    options: WgslOptions,
    strategies: &[Strategy],
    rng: &mut Rng,
    f64_reference: f64,
) {
    let nv = model.nv();
    let f64 = options.precision == Precision::F64;
    let source = wgsl(model, WgslOptions { strategies: strategies.to_vec(), ..options.clone() });
    let shader = gpu.load(&source).unwrap_or_else(|e| panic!("{robot}: {e}"));
    let lowered =
        grid_gen::ir::lower(model, reference::DEFAULT_GRAVITY, &Default::default()).unwrap();
    let states = states(model, rng);
    let n = states.len(); // 37: not a multiple of the workgroup size
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd, u) = (flat(0), flat(1), flat(2));
    // The step kernels take the actuated joints' τ: each state's first nu entries of u.
    let nu = model.nu();
    let u_step: Vec<f64> = states.iter().flat_map(|s| s[2][..nu].iter().copied()).collect();
    // `difference` takes a second configuration in u: each state's q moved by its q̇ (whose
    // rotations reach 3 rad and more, the logarithm's far range), so that it returns q̇.
    let q1s: Vec<Vec<f64>> =
        states.iter().map(|[q, qd, _]| reference::integrate(model, q, qd)).collect();
    // `integrate` takes a step's tangent, dt q̇ with dt = 0.01 (a base spinning at 1e3 rad/s
    // turns by 10 rad): past 1e3 rad the exponential's own conditioning, ε θ, is 1e-13.
    let qd_lie: Vec<f64> = qd.iter().map(|x| 0.01 * x).collect();
    let u_q1: Vec<f64> = q1s.concat();
    for f in lowered.functions.iter().filter(|f| kernels.contains(&f.kind)) {
        let takes_q1 = f.inputs().contains(&grid_gen::ir::Input::Q1);
        let none = Vec::new();
        let u = if f.kind.is_step() {
            &u_step
        } else if takes_q1 {
            &u_q1
        } else if f.packed_u_len() == 0 {
            // `integrate` and `dintegrate`: q and v (in q̇'s buffer) only.
            &none
        } else {
            &u
        };
        for &strategy in strategies {
            let kernel = gpu.kernel(&shader, &strategy.entry(f.kind.name())).unwrap();
            let t0 = std::time::Instant::now();
            let qd = if f.kind.is_lie() { &qd_lie } else { &qd };
            let got = gpu.run(&kernel, &q, qd, u).unwrap();
            let ran = t0.elapsed();
            let total = kernel.entry.outputs;
            assert_eq!(got.len(), n * total);
            let (tol, ir_tol) = match (f64, f.kind) {
                (true, _) => (f64_reference, F64_TOL),
                (
                    false,
                    KernelKind::Minv
                    | KernelKind::Fd
                    | KernelKind::FdGrad
                    | KernelKind::Step
                    | KernelKind::StepGrad,
                ) => (THROUGH_MINV, THROUGH_MINV),
                _ => (DIRECT, DIRECT),
            };
            let what = format!(
                "{robot} {} {} {}",
                kernel.entry.entry,
                options.precision.name(),
                options.trig.name()
            );
            let (mut worst, mut worst_ir, mut graph) = (0.0f64, 0.0f64, 0.0f64);
            for (s, [q, qd, u]) in states.iter().enumerate() {
                let u = if f.kind.is_step() {
                    &u[..nu]
                } else if takes_q1 {
                    &q1s[s][..]
                } else {
                    &u[..]
                };
                let lie_v: Vec<f64> = qd.iter().map(|x| 0.01 * x).collect();
                let qd = if f.kind.is_lie() { &lie_v } else { qd };
                let want = reference_outputs(f.kind, model, q, qd, u, reference::DEFAULT_GRAVITY);
                // The IR interpreter on the same graph: the backend prints it faithfully.
                let interpreted = f.eval(&kernel_args(f.inputs(), q, qd, u));
                let mut base = s * total;
                for ((o, want), ir_vals) in f.outputs.iter().zip(&want).zip(&interpreted) {
                    let vals = &got[base..base + o.ids.len()];
                    assert!(
                        vals.iter().all(|v| v.is_finite()),
                        "{what}.{} state {s}: a value was not written",
                        o.name
                    );
                    let got = output_matrix(o.shape, nv, vals);
                    // `difference` of nearby configurations cancels: its absolute error is
                    // the configurations' rounding, ε (|q| + |q1|), so it is measured against
                    // their scale where that is larger than its own.
                    let floor = |want: &nalgebra::DMatrix<f64>| {
                        let inputs = q.iter().chain(u).fold(0.0f64, |m, x| m.max(x.abs()));
                        if f.kind == KernelKind::Difference {
                            want.amax().max(inputs)
                        } else {
                            0.0
                        }
                    };
                    let e = rel_err(&got, want).min((&got - want).amax() / floor(want));
                    assert!(
                        e <= tol,
                        "{what}.{} state {s}: relative error {e:.2e} > {tol:e}",
                        o.name
                    );
                    let ir = output_matrix(o.shape, nv, ir_vals);
                    let e_ir = rel_err(&got, &ir).min((&got - &ir).amax() / floor(&ir));
                    assert!(
                        e_ir <= ir_tol,
                        "{what}.{} state {s}: {e_ir:.2e} from the IR interpreter",
                        o.name
                    );
                    worst = worst.max(e);
                    worst_ir = worst_ir.max(e_ir);
                    let e_graph = rel_err(&output_matrix(o.shape, nv, ir_vals), want);
                    graph = graph.max(e_graph);
                    base += o.ids.len();
                }
            }
            eprintln!(
                "{what}: worst relative error {worst:.2e} over {n} states ({worst_ir:.2e} from the IR interpreter, whose own is {graph:.2e}); pipeline {:.1?}, run {ran:.1?}",
                kernel.build_time
            );
        }
    }
}

#[test]
fn kernels_run_through_wgpu_and_match_the_reference() {
    let Some((_serial, gpu)) = gpu() else { return };
    let mut rng = Rng(41);
    check_robot(
        &gpu,
        "double_pendulum_continuous",
        WgslOptions::default(),
        &Strategy::ALL,
        &mut rng,
    );
    check_robot(&gpu, "grid_iiwa", WgslOptions::default(), &Strategy::ALL, &mut rng);
    // WGSL's built-in sin/cos instead of the accurate ones.
    check_robot(
        &gpu,
        "double_pendulum_continuous",
        WgslOptions { trig: Trig::Builtin, ..WgslOptions::default() },
        &Strategy::ALL,
        &mut rng,
    );
}

/// Every bundled robot in f64, every kernel, both strategies but Atlas's thread entries
/// (lavapipe compiles straight-line f64 code at about 1 ms per statement, a few minutes
/// for Atlas's 150k; its f32 thread entries run below, its f64 cooperative ones here).
#[test]
fn f64_kernels_match_the_reference_to_1e_12() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(43);
    let f64 = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    for robot in robots() {
        let strategies: &[Strategy] =
            if robot == "grid_atlas" { &[Strategy::Cooperative] } else { &Strategy::ALL };
        check_robot(&gpu, &robot, f64.clone(), strategies, &mut rng);
    }
}

/// Every bundled robot, every kernel, one invocation per state, f32 (the runs above
/// cover the double pendulum and iiwa in both strategies): Atlas's `fd_grad`, 85k
/// statements in 66 dispatches, included (about 90 s of lavapipe compile).
#[test]
fn every_bundled_robot_runs_with_one_invocation_per_state() {
    let Some((_serial, gpu)) = gpu() else { return };
    let mut rng = Rng(71);
    for robot in robots()
        .iter()
        .filter(|r| !["double_pendulum_continuous", "grid_iiwa"].contains(&r.as_str()))
    {
        check_robot(&gpu, robot, WgslOptions::default(), &[Strategy::Thread], &mut rng);
    }
}

/// Every bundled robot in the cooperative strategy, f32, every kernel (the double
/// pendulum and iiwa run above), Atlas's too: the table-driven kernels compile in
/// milliseconds on lavapipe, where the unrolled ones took 4 to 12 ms per statement.
#[test]
fn every_bundled_robot_runs_cooperatively() {
    let Some((_serial, gpu)) = gpu() else { return };
    let mut rng = Rng(79);
    for robot in robots()
        .iter()
        .filter(|r| !["double_pendulum_continuous", "grid_iiwa"].contains(&r.as_str()))
    {
        check_model(
            &gpu,
            robot,
            &load(robot),
            &KernelKind::ALL,
            WgslOptions::default(),
            &[Strategy::Cooperative],
            &mut rng,
        );
    }
}

/// A kernel split into dispatches (stages) computes what it computes in one dispatch:
/// the same operations in the same order, values crossing stages through the scratch
/// buffer, stages small enough that values cross several of them. One invocation per
/// state only: a cooperative entry is always one dispatch. Not bit for bit: SPIR-V from naga
/// lets the driver fuse `a * b + c` into one FMA, which it cannot do across a value that
/// went through memory, so where the stage (and helper) boundaries fall changes some
/// roundings (measured on lavapipe: thread `rnea_grad` in 12 stages differs in the last
/// bits). So each state's outputs agree within the f32 bounds above, relative to the
/// state's largest output.
#[test]
fn stages_compute_what_one_dispatch_computes() {
    let Some((_serial, gpu)) = gpu() else { return };
    // The double pendulum in stages of 25 operations: many stages for little lavapipe
    // time.
    let model = load("double_pendulum_continuous");
    let nv = model.nv();
    let mut rng = Rng(73);
    let states = states(&model, &mut rng);
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd, u) = (flat(0), flat(1), flat(2));
    let strategy = Strategy::Thread;
    {
        for kind in [KernelKind::RneaGrad, KernelKind::FdGrad] {
            let lower = grid_gen::ir::LowerOptions { kernels: vec![kind], ..Default::default() };
            let module = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
            let run = |stage: usize| {
                let options =
                    WgslOptions { stage, strategies: vec![strategy], ..WgslOptions::default() };
                let (file, stats) =
                    grid_gen::back::wgsl::emit_with_stats(&module, &options).unwrap();
                let shader = gpu.load(&file.contents).unwrap();
                let kernel = gpu.kernel(&shader, &strategy.entry(kind.name())).unwrap();
                (stats[0].clone(), gpu.run(&kernel, &q, &qd, &u).unwrap())
            };
            let (one, whole) = run(0);
            let (split, staged) = run(25);
            assert_eq!(one.stages, 1);
            assert!(split.stages >= 4, "{kind:?} {strategy:?}: {} stages", split.stages);
            assert_eq!(whole.len(), states.len() * one.outputs);
            assert!(whole.iter().all(|x| x.is_finite()), "{kind:?} {strategy:?}");
            let tol = if kind == KernelKind::FdGrad { THROUGH_MINV } else { DIRECT };
            let mut worst = 0.0f64;
            for (a, b) in whole.chunks(one.outputs).zip(staged.chunks(one.outputs)) {
                let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
                let diff = a.iter().zip(b).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
                worst = worst.max(diff / scale);
            }
            assert!(worst <= tol, "{kind:?} {strategy:?}: {} stages differ from one dispatch by {worst:.2e} > {tol:e}", split.stages);
            eprintln!(
                "double pendulum {} {}: {} stages against 1 dispatch: {worst:.2e} relative ({} states, nv {nv})",
                kind.name(),
                strategy.name(),
                split.stages,
                states.len()
            );
        }
    }
}

/// A floating base: q has nq = nv + 1 entries per state, the runtime reads
/// `// nq:` from the header. HyQ on a free-flyer, one invocation per state, in f64,
/// against the reference (which tests/pinocchio.rs holds to Pinocchio's free-flyer) at
/// the fixed-base tolerance: every kernel cooperatively, and every kernel but `fd_grad`
/// with one invocation per state, whose straight-line pipeline (37,860 statements)
/// lavapipe had not built after 6 minutes (measured 2026-11-23; the others build in 0.2
/// to 6.6 s and run 37 states in 7 to 21 ms); the table-driven cooperative `fd_grad` runs
/// the same graph.
#[test]
fn floating_base_kernels_match_the_reference() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(53);
    let options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    let kernels = [
        KernelKind::Rnea,
        KernelKind::RneaGrad,
        KernelKind::MassMatrix,
        KernelKind::Minv,
        KernelKind::Fd,
    ];
    let hyq = load_floating("grid_hyq");
    check_model(
        &gpu,
        "grid_hyq floating",
        &hyq,
        &kernels,
        options.clone(),
        &[Strategy::Thread],
        &mut rng,
    );
    check_model(
        &gpu,
        "grid_hyq floating",
        &hyq,
        &KernelKind::ALL,
        options.clone(),
        &[Strategy::Cooperative],
        &mut rng,
    );
    // Atlas on a free-flyer: its base block (150 kg) beside the hands' links makes M far
    // worse conditioned than the fixed-base robots' (cond ≤ 2e3, tests/accuracy.rs), and
    // its f64 fd_grad graph itself is 9.9e-13 from the reference here (measured), so the reference
    // bound is the 1e-10 that tests/pinocchio.rs holds floating robots to; the kernels are
    // still held to the graph they run at 1e-12.
    let atlas = load_floating("grid_atlas");
    check_model_within(
        &gpu,
        "grid_atlas floating",
        &atlas,
        &KernelKind::ALL,
        options,
        &[Strategy::Cooperative],
        &mut rng,
        1e-10,
    );
}

/// The step kernels (floating HyQ, semi-implicit Euler, 10 ms; iiwa, explicit Euler and
/// RK4) in f64 against the reference step and `[A | B]`: cooperative entries for HyQ (its
/// step_grad is 45k statements straight-line, minutes for lavapipe's f64 compiler), both
/// strategies for iiwa, and f32 thread entries for HyQ's `step`.
#[test]
fn step_kernels_match_the_reference() {
    use grid_gen::model::Scheme;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(61);
    let options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    let steps = [KernelKind::Step, KernelKind::StepGrad];
    let hyq = with_step(&load_floating("grid_hyq"), Scheme::SemiImplicitEuler, 0.01);
    check_model(
        &gpu,
        "grid_hyq floating step",
        &hyq,
        &steps,
        options.clone(),
        &[Strategy::Cooperative],
        &mut rng,
    );
    let iiwa = with_step(&load("grid_iiwa"), Scheme::ExplicitEuler, 0.005);
    check_model(&gpu, "grid_iiwa step", &iiwa, &steps, options, &Strategy::ALL, &mut rng);
    check_model(
        &gpu,
        "grid_hyq floating step",
        &hyq,
        &[KernelKind::Step],
        WgslOptions::default(),
        &[Strategy::Thread],
        &mut rng,
    );
    // RK4 on iiwa, cooperative, over 0.1 ms: the states include 1e3 rad/s, where a 10 ms RK4
    // step is far outside the scheme's stability and each stage would multiply rounding by
    // dt ∂q̈/∂q̇ ~ 1e2 (grid-gen's tests/step.rs); at 0.1 ms it stays stable there.
    let rk4 = with_step(&load("grid_iiwa"), Scheme::Rk4, 1e-4);
    let f64_options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    check_model(
        &gpu,
        "grid_iiwa rk4",
        &rk4,
        &steps,
        f64_options,
        &[Strategy::Cooperative],
        &mut rng,
    );
}

/// The step under contacts: floating HyQ on its four feet as rigid point contacts,
/// semi-implicit Euler over 10 ms, f64, cooperative, against the reference step (which
/// grid-gen's tests/step.rs holds to Pinocchio) and the IR interpreter. Its graph takes
/// `contact_fd`'s route (M's factorisation here), as its Rust code does by calling
/// `contact_fd`.
///
/// The random configurations put legs anywhere within ±3.1 rad, and some of them nearly
/// straight, where the contact Jacobian J loses rank and K = J M⁻¹ Jᵀ's condition number
/// reaches 4e5 (state 9 of this seed; the others stay under 4e4, most under 1e3). A
/// solve's forward error grows with its matrix's condition number (Higham, *Accuracy and
/// Stability of Numerical Algorithms*, 2nd ed., §7.1), so a state is held to
/// [`F64_TOL`] times cond(K) / [`COND_AT_F64_TOL`] where that is larger: F64_TOL
/// everywhere K is conditioned as M is on the floating robots it was set for. A state
/// whose J is singular (the zero state's straight legs: λ is not unique) is skipped, as in
/// `masked_contacts_match_the_reference`.
#[test]
fn contact_step_matches_the_reference() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(67);
    let model = hyq_standing_step();
    let options = WgslOptions {
        precision: Precision::F64,
        strategies: vec![Strategy::Cooperative],
        ..WgslOptions::default()
    };
    let shader = gpu.load(&wgsl(&model, options)).unwrap();
    let kind = KernelKind::Step;
    let kernels = vec![kind, KernelKind::ContactFd];
    let lower = grid_gen::ir::LowerOptions { kernels, ..Default::default() };
    let g = reference::DEFAULT_GRAVITY;
    let lowered = grid_gen::ir::lower(&model, g, &lower).unwrap();
    let f = lowered.function(kind).unwrap();
    let contact = lowered.function(KernelKind::ContactFd).unwrap();
    assert_eq!(f.solve, contact.solve, "the step's graph takes contact_fd's route");
    let (nv, nu) = (model.nv(), model.nu());
    let states = states(&model, &mut rng);
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd) = (flat(0), flat(1));
    let u: Vec<f64> = states.iter().flat_map(|s| s[2][..nu].iter().copied()).collect();
    let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
    assert_eq!(kernel.nu, f.packed_u_len(), "{kind}: u's width");
    let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
    let total = kernel.entry.outputs;
    let (mut worst, mut singular, mut scaled) = (0.0f64, 0, 0);
    for (s, [q, qd, u]) in states.iter().enumerate() {
        let j = reference::contact_jacobian(&model, &model.specialisation.contacts, q);
        let sj = j.singular_values();
        if sj.min() < 1e-8 * sj.max() {
            singular += 1;
            continue;
        }
        let k = &j * reference::minv(&model, q) * j.transpose();
        let sk = k.singular_values();
        let cond = sk.max() / sk.min();
        let tol = F64_TOL * (cond / COND_AT_F64_TOL).max(1.0);
        scaled += usize::from(cond > COND_AT_F64_TOL);
        let u = &u[..nu];
        let want = reference_outputs(kind, &model, q, qd, u, g);
        let interpreted = f.eval(&kernel_args(f.inputs(), q, qd, u));
        let what = format!("{kind} state {s} (cond(K) {cond:.1e})");
        let e = check_f64_state_within(&what, f, nv, &got[s * total..], &want, &interpreted, tol);
        worst = worst.max(e);
    }
    assert!(singular <= 2, "{singular} singular states");
    assert!(
        scaled <= 3,
        "{scaled} states past cond(K) {COND_AT_F64_TOL:e}: the seed's states changed"
    );
    eprintln!(
        "grid_hyq standing step, f64 cooperative: worst relative error {worst:.2e} over {} states ({singular} singular skipped, {scaled} held to a bound scaled by cond(K))",
        states.len() - singular
    );
}

/// Coupled mimic joints: mimic_arm (`tests/fixtures/mimic_arm.urdf`, three
/// mimics with multipliers −0.7, 1.5 and 2 and offsets) in f64, every kernel, one
/// invocation per state, against the reference (which tests/pinocchio.rs holds to
/// Pinocchio's mimic model) at the fixed-base tolerance: the kernels take 4 coordinates for
/// 7 joints. Both strategies.
#[test]
fn coupled_mimic_kernels_match_the_reference() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(59);
    let model = load_coupled_urdf(&repo().join("tests/fixtures/mimic_arm.urdf"));
    assert_eq!((model.nv(), model.njoints()), (4, 7));
    let options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    check_model(
        &gpu,
        "mimic_arm coupled",
        &model,
        &KernelKind::ALL,
        options,
        &Strategy::ALL,
        &mut rng,
    );
}

/// Spherical joints: an arm with one on the root and one between moving
/// bodies (the layout and algorithms of `tests/fixtures/ball_arm.urdf`, which
/// tests/pinocchio.rs holds to Pinocchio's `JointModelSpherical`, on 7 coordinates instead
/// of 12), in f64, every kernel, one invocation per state, against the reference at the
/// fixed-base tolerance; random rotations of every quaternion, rounded to f32 (not quite
/// unit: kernels and reference both normalise). Both strategies; naga checks ball_arm
/// above.
#[test]
fn spherical_kernels_match_the_reference() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(61);
    let inertial = |m: f64, z: f64| {
        format!(
            r#"<inertial><origin xyz="0.01 0.02 {z}" rpy="0.1 -0.2 0.3"/><mass value="{m}"/><inertia ixx="0.02" iyy="0.03" izz="0.025" ixy="0.001" ixz="-0.002" iyz="0.0015"/></inertial>"#
        )
    };
    let urdf = format!(
        r#"<robot name="ball_chain"><link name="base"/>
  <joint name="shoulder" type="spherical"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/></joint>
  <link name="l1">{}</link>
  <joint name="elbow" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.05 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="5"/></joint>
  <link name="l2">{}</link>
  <joint name="wrist" type="spherical"><parent link="l2"/><child link="l3"/><origin xyz="0.3 0 0" rpy="0 0.3 0"/></joint>
  <link name="l3">{}</link>
</robot>"#,
        inertial(1.2, 0.1),
        inertial(0.9, 0.02),
        inertial(0.6, 0.0)
    );
    let model = Model::from_urdf_str("ball_chain.urdf", &urdf, false)
        .map_err(|e| e.render_plain())
        .unwrap()
        .0;
    assert_eq!((model.nv(), model.nq()), (7, 9));
    let options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    check_model(&gpu, "ball_chain", &model, &KernelKind::ALL, options, &Strategy::ALL, &mut rng);
}

/// The cooperative schedule deals each phase's operations to however many invocations
/// there are; each operation is the same rounded arithmetic on the same operands wherever
/// it runs, so 1, 7 (not a power of two) and 256 (WebGPU's most) invocations per state
/// give the 64-invocation results bit for bit, on iiwa's gradients (and a one-joint chain,
/// whose phases are narrower than any workgroup, matches the reference).
#[test]
fn cooperative_results_do_not_depend_on_the_workgroup_size() {
    let Some((_serial, gpu)) = gpu() else { return };
    let model = load("grid_iiwa");
    let mut rng = Rng(83);
    let states = states(&model, &mut rng);
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd, u) = (flat(0), flat(1), flat(2));
    for kind in [KernelKind::RneaGrad, KernelKind::FdGrad] {
        let lower = grid_gen::ir::LowerOptions { kernels: vec![kind], ..Default::default() };
        let module = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
        let run = |workers: u32| {
            let options = WgslOptions {
                workers,
                strategies: vec![Strategy::Cooperative],
                ..WgslOptions::default()
            };
            let (file, stats) = grid_gen::back::wgsl::emit_with_stats(&module, &options).unwrap();
            let shader = gpu.load(&file.contents).unwrap();
            let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
            (stats[0].clone(), gpu.run(&kernel, &q, &qd, &u).unwrap())
        };
        let (base, want) = run(64);
        assert!(want.iter().all(|x| x.is_finite()), "{kind:?}");
        for workers in [1, 7, 256] {
            let (stats, got) = run(workers);
            assert_eq!(
                stats.phases, base.phases,
                "{kind:?}: the levels do not depend on the workers"
            );
            assert!(got == want, "{kind:?}: {workers} invocations per state differ from 64");
            eprintln!(
                "iiwa {}: {workers} invocations per state = 64, bit for bit ({} phases)",
                kind.name(),
                stats.phases
            );
        }
    }
    let one = Model::from_urdf_str("chain1.urdf", &chain_urdf(1), false)
        .map_err(|e| e.render_plain())
        .unwrap()
        .0;
    check_model(
        &gpu,
        "one-joint chain",
        &one,
        &KernelKind::ALL,
        WgslOptions::default(),
        &[Strategy::Cooperative],
        &mut rng,
    );
}

#[test]
fn batch_sizes_nan_and_dispatch_splitting() {
    let Some((_serial, gpu)) = gpu() else { return };
    let model = load("double_pendulum_continuous");
    let nv = model.nv();
    let shader = gpu.load(&wgsl(&model, WgslOptions::default())).unwrap();
    let mut rng = Rng(47);
    for strategy in Strategy::ALL {
        let kernel = gpu.kernel(&shader, &strategy.entry("rnea")).unwrap();
        // N = 0: a no-op that returns nothing.
        assert!(gpu.run(&kernel, &[], &[], &[]).unwrap().is_empty());
        // Wrong lengths: an error naming the field.
        let e = gpu.run(&kernel, &[0.0; 4], &[0.0; 3], &[0.0; 4]).unwrap_err();
        assert!(matches!(e, GpuError::Length { field: "qd", .. }), "{e}");
        // One state, and a NaN in state 1 of 3 that leaves states 0 and 2 exact.
        let q = rng.vec(3 * nv, -3.0, 3.0);
        let qd = rng.vec(3 * nv, -3.0, 3.0);
        let u = rng.vec(3 * nv, -3.0, 3.0);
        let one = gpu.run(&kernel, &q[..nv], &qd[..nv], &u[..nv]).unwrap();
        let mut poisoned = q.clone();
        poisoned[nv] = f64::NAN;
        let three = gpu.run(&kernel, &poisoned, &qd, &u).unwrap();
        assert_eq!(&three[..nv], &one[..], "{strategy:?}: state 0 changed");
        assert!(
            three[nv..2 * nv].iter().all(|x| x.is_nan()),
            "{strategy:?}: NaN did not reach state 1's result"
        );
        let last = gpu.run(&kernel, &q[2 * nv..], &qd[2 * nv..], &u[2 * nv..]).unwrap();
        assert_eq!(&three[2 * nv..], &last[..], "{strategy:?}: state 2 changed");
    }
    // Past 65,535 workgroups: the cooperative strategy takes one workgroup per state, so
    // 70,000 states need two dispatches; states on both sides of the split are checked.
    let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry("mass_matrix")).unwrap();
    let n = 70_000;
    let q = rng.vec(n * nv, -3.0, 3.0);
    let batch = gpu.upload(&kernel, &q, &[], &[]).unwrap();
    assert_eq!(batch.dispatches(), 2);
    gpu.dispatch(&batch).unwrap();
    let got = gpu.read(&batch).unwrap();
    let mut worst = 0.0f64;
    for s in (0..n).step_by(97).chain([65_534, 65_535, 65_536, n - 1]) {
        let qs: Vec<f64> = q[s * nv..(s + 1) * nv].iter().map(|&x| x as f32 as f64).collect();
        let want = reference::crba(&model, &qs);
        let e = rel_err(
            &output_matrix(grid_gen::ir::Shape::Matrix, nv, &got[s * nv * nv..(s + 1) * nv * nv]),
            &want,
        );
        assert!(e <= DIRECT, "state {s}: {e:.2e}");
        worst = worst.max(e);
    }
    eprintln!(
        "70,000 states in {} dispatches: worst relative error {worst:.2e}",
        batch.dispatches()
    );
    // New states written into the same batch (`run_on`: no allocation, one submission)
    // give what a fresh upload of them gives, on both sides of the split, bit for bit.
    let q2 = rng.vec(n * nv, -3.0, 3.0);
    let mut again = vec![f64::NAN; got.len()];
    gpu.run_on(&batch, &q2, &[], &[], &mut again).unwrap();
    let fresh = gpu.run(&kernel, &q2, &[], &[]).unwrap();
    assert_eq!(again.len(), fresh.len());
    assert!(again.iter().zip(&fresh).all(|(a, b)| a.to_bits() == b.to_bits()));
    assert_ne!(again, got, "the batch still holds the first states");
    for s in [0, 65_535, n - 1] {
        let qs: Vec<f64> = q2[s * nv..(s + 1) * nv].iter().map(|&x| x as f32 as f64).collect();
        let e = rel_err(
            &output_matrix(grid_gen::ir::Shape::Matrix, nv, &again[s * nv * nv..(s + 1) * nv * nv]),
            &reference::crba(&model, &qs),
        );
        assert!(e <= DIRECT, "run_on, state {s}: {e:.2e}");
    }
    // Another count of states, or an input the batch was uploaded without: errors.
    let e = gpu.run_on(&batch, &q2[nv..], &[], &[], &mut again).unwrap_err();
    assert!(matches!(e, GpuError::Length { field: "q", .. }), "{e}");
    let e = gpu.run_on(&batch, &q2, &[], &[], &mut again[1..]).unwrap_err();
    assert!(matches!(e, GpuError::Length { field: "out", .. }), "{e}");
    let e = gpu.run_on(&batch, &q2, &q2, &[], &mut again).unwrap_err();
    assert!(matches!(e, GpuError::NotUploaded("qd")), "{e}");
    // The failed call left the staging buffer unmapped; the next one maps it again.
    gpu.run_on(&batch, &q, &[], &[], &mut again).unwrap();
    assert!(again.iter().zip(&got).all(|(a, b)| a.to_bits() == b.to_bits()));
}

/// The layouts change on the device for chunks of [`grid_gen_wgpu::DEVICE_TRANSPOSES`]
/// values or more and on the host below: the same states give the same bits either way,
/// in f32 and f64, through `run` and `run_on`, for a kernel with all three inputs (iiwa's
/// `fd_grad`: 21 inputs and 105 outputs a state, so 200 states take the device's path and
/// 8 the host's).
#[test]
fn device_and_host_transposes_agree() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let model = load("grid_iiwa");
    let nv = model.nv();
    let mut rng = Rng(89);
    let n = 200;
    let q = rng.vec(n * nv, -3.0, 3.0);
    let qd = rng.vec(n * nv, -3.0, 3.0);
    let tau = rng.vec(n * nv, -3.0, 3.0);
    for precision in [Precision::F32, Precision::F64] {
        let options = WgslOptions {
            precision,
            strategies: vec![Strategy::Cooperative],
            ..WgslOptions::default()
        };
        let shader = gpu.load(&wgsl(&model, options)).unwrap();
        let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry("fd_grad")).unwrap();
        let per = kernel.entry.outputs;
        assert!(n * (3 * nv + per) >= grid_gen_wgpu::DEVICE_TRANSPOSES);
        assert!(8 * (3 * nv + per) < grid_gen_wgpu::DEVICE_TRANSPOSES);
        let whole = gpu.run(&kernel, &q, &qd, &tau).unwrap();
        assert!(whole.iter().all(|x| x.is_finite()), "{precision:?}");
        // The same states run again through the uploaded batch, in reverse order.
        let rev = |x: &[f64]| -> Vec<f64> { x.chunks(nv).rev().flatten().copied().collect() };
        let batch = gpu.upload(&kernel, &q, &qd, &tau).unwrap();
        let mut again = vec![f64::NAN; whole.len()];
        gpu.run_on(&batch, &rev(&q), &rev(&qd), &rev(&tau), &mut again).unwrap();
        for s in 0..n {
            let (a, b) = (&whole[s * per..(s + 1) * per], &again[(n - 1 - s) * per..][..per]);
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()), "state {s}");
        }
        for start in (0..n).step_by(8) {
            let part = |x: &[f64]| x[start * nv..(start + 8) * nv].to_vec();
            let small = gpu.run(&kernel, &part(&q), &part(&qd), &part(&tau)).unwrap();
            let want = &whole[start * per..(start + 8) * per];
            assert!(
                small.iter().zip(want).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{precision:?}: states {start}..{} differ between the two paths",
                start + 8
            );
        }
        eprintln!("iiwa fd_grad {precision:?}: {n} states, device and host transposes agree");
    }
}

/// The frame kernels (placement, Jacobian, velocity, classical acceleration) in every
/// reference frame, both strategies, f32 and f64, against the reference (held to Pinocchio
/// by grid-gen's tests/frames.rs): iiwa's flange and a fixed root frame, and floating
/// HyQ's four lower legs. Frames add no M⁻¹, so f32 is held to the direct tolerance.
#[test]
fn frame_kernels_match_the_reference() {
    use grid_gen::model::ReferenceFrame;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(61);
    let frames: Vec<KernelKind> = KernelKind::ALL
        .into_iter()
        .filter(|k| k.is_frame() && *k != KernelKind::FrameAccelerationGrad)
        .collect();
    let iiwa = load("grid_iiwa");
    let hyq = load_floating("grid_hyq");
    for rf in ReferenceFrame::ALL {
        for precision in [Precision::F32, Precision::F64] {
            let options = WgslOptions { precision, ..WgslOptions::default() };
            let model = with_frames(&iiwa, &["iiwa_link_7", "base"], rf);
            check_model(
                &gpu,
                &format!("iiwa frames {}", rf.name()),
                &model,
                &frames,
                options.clone(),
                &Strategy::ALL,
                &mut rng,
            );
            let model = with_frames(
                &hyq,
                &["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"],
                rf,
            );
            check_model(
                &gpu,
                &format!("hyq floating frames {}", rf.name()),
                &model,
                &frames,
                options,
                &Strategy::ALL,
                &mut rng,
            );
        }
    }
}

/// `frame_acceleration_grad` on lavapipe, both strategies, f64: against the IR interpreter
/// of the same graph (held to central differences of the reference by grid-gen's
/// tests/frames.rs) at the f64 tolerance, floating HyQ's four lower legs.
#[test]
fn frame_acceleration_grad_matches_its_graph() {
    use grid_gen::model::ReferenceFrame;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(67);
    let model = with_frames(
        &load_floating("grid_hyq"),
        &["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"],
        ReferenceFrame::LocalWorldAligned,
    );
    let options = WgslOptions { precision: Precision::F64, ..WgslOptions::default() };
    let shader = gpu.load(&wgsl(&model, options)).unwrap();
    let lowered =
        grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &Default::default()).unwrap();
    let f = lowered.function(KernelKind::FrameAccelerationGrad).unwrap();
    let states = states(&model, &mut rng);
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    for strategy in Strategy::ALL {
        let kernel = gpu.kernel(&shader, &strategy.entry(f.kind.name())).unwrap();
        let got = gpu.run(&kernel, &flat(0), &flat(1), &flat(2)).unwrap();
        let per = kernel.entry.outputs;
        let mut worst: f64 = 0.0;
        for (s, [q, qd, qdd]) in states.iter().enumerate() {
            let want: Vec<f64> = f.eval(&[q, qd, qdd]).concat();
            let e = rel_err(&col(&got[s * per..(s + 1) * per]), &col(&want));
            worst = worst.max(e);
            assert!(e <= F64_TOL, "{} state {s}: {e:.2e}", kernel.entry.entry);
        }
        println!(
            "{}: worst {worst:.2e} from the IR interpreter over {} states",
            kernel.entry.entry,
            states.len()
        );
    }
}

/// External and contact forces: floating HyQ with fext on its base and a knee,
/// and its four lower legs as point contacts (λ in world axes), in f64, rnea, rnea_grad,
/// fd and fd_grad, both strategies, 37 states with random forces packed after q̈ or τ in
/// `u`, against the reference (which tests/forces.rs holds to Pinocchio) and the IR
/// interpreter; and iiwa in f32 with a tool wrench, at the f32 tolerances.
#[test]
fn force_kernels_match_the_reference() {
    use grid_gen::model::ContactKind;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(67);
    let legs: Vec<String> =
        ["lf", "rf", "lh", "rh"].iter().map(|l| format!("{l}_lowerleg")).collect();
    let contacts: Vec<(&str, ContactKind)> =
        legs.iter().map(|l| (l.as_str(), ContactKind::Point)).collect();
    let hyq = with_forces(&load_floating("grid_hyq"), &["root_joint", "lf_kfe_joint"], &contacts);
    let iiwa =
        with_forces(&load("grid_iiwa"), &["iiwa_joint_4"], &[("iiwa_link_7", ContactKind::Wrench)]);
    let kernels = [KernelKind::Rnea, KernelKind::RneaGrad, KernelKind::Fd, KernelKind::FdGrad];
    // Rigid-contact dynamics on iiwa's tool wrench (HyQ's are in grid-gen-kernels: its
    // contact_fd_grad would double this shader's size on lavapipe).
    let contact = [KernelKind::ContactFd, KernelKind::ContactFdGrad];
    for (robot, model, precision, strategies) in [
        ("grid_hyq floating, forces", &hyq, Precision::F64, &Strategy::ALL[..]),
        ("grid_iiwa, forces", &iiwa, Precision::F32, &[Strategy::Cooperative][..]),
    ] {
        let nv = model.nv();
        let options =
            WgslOptions { precision, strategies: strategies.to_vec(), ..WgslOptions::default() };
        let source = wgsl(model, options);
        assert!(
            source.contains(&format!("// forces: {}\n", 6 * model.nfext() + model.nlambda())),
            "{robot}: the header counts the forces"
        );
        let shader = gpu.load(&source).unwrap_or_else(|e| panic!("{robot}: {e}"));
        let lowered =
            grid_gen::ir::lower(model, reference::DEFAULT_GRAVITY, &Default::default()).unwrap();
        let states = states(model, &mut rng);
        let forces: Vec<(Vec<f64>, Vec<f64>)> = states
            .iter()
            .map(|_| {
                (rng.vec(6 * model.nfext(), -20.0, 20.0), rng.vec(model.nlambda(), -100.0, 100.0))
            })
            .collect();
        let flat =
            |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
        let (q, qd) = (flat(0), flat(1));
        for f in lowered
            .functions
            .iter()
            .filter(|f| kernels.contains(&f.kind) || (contact.contains(&f.kind) && model.nv() < 10))
        {
            // The contact kernels solve for λ: it is no input of theirs.
            let u: Vec<f64> = states
                .iter()
                .zip(&forces)
                .flat_map(|(s, (f_ext, l))| {
                    s[2].iter()
                        .chain(f_ext)
                        .chain(if f.kind.is_contact() { &[][..] } else { &l[..] })
                        .copied()
                        .collect::<Vec<_>>()
                })
                .collect();
            for &strategy in strategies {
                let kernel = gpu.kernel(&shader, &strategy.entry(f.kind.name())).unwrap();
                assert_eq!(kernel.nu, f.packed_u_len(), "{robot} {}: u's width", f.kind);
                let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
                let total = kernel.entry.outputs;
                let tol = match (precision, f.kind) {
                    // The contacts' Schur complement J M⁻¹ Jᵀ squares J's conditioning:
                    // grid-gen-kernels' CONTACT_F32 (measured here: see the eprintln).
                    (Precision::F32, KernelKind::ContactFd | KernelKind::ContactFdGrad) => 2e-3,
                    (Precision::F64, _) => F64_TOL,
                    (_, KernelKind::Fd | KernelKind::FdGrad) => THROUGH_MINV,
                    _ => DIRECT,
                };
                let mut worst: f64 = 0.0;
                let mut singular = Vec::new();
                for (s, ([q, qd, u], (fext, lambda))) in states.iter().zip(&forces).enumerate() {
                    let ext = reference::External { fext, lambda };
                    let j = reference::contact_jacobian(model, &model.specialisation.contacts, q);
                    let sv = j.singular_values();
                    if f.kind.is_contact() && sv.min() < 1e-8 * sv.max() {
                        // The arm stretched straight (the zero state): λ is not unique.
                        singular.push(s);
                        continue;
                    }
                    let want = reference_outputs_with(
                        f.kind,
                        model,
                        q,
                        qd,
                        u,
                        reference::DEFAULT_GRAVITY,
                        ext,
                    );
                    let interpreted = f.eval(&kernel_args_with(f.inputs(), q, qd, u, ext));
                    assert_eq!(want.len(), f.outputs.len(), "{robot} {}: outputs", f.kind);
                    let mut base = s * total;
                    for ((o, want), ir_vals) in f.outputs.iter().zip(&want).zip(&interpreted) {
                        let vals = &got[base..base + o.ids.len()];
                        let got = output_matrix(o.shape, nv, vals);
                        let e = rel_err(&got, want);
                        assert!(
                            e <= tol,
                            "{robot} {} {}.{} state {s}: {e:.2e} > {tol:e}",
                            strategy.entry(""),
                            f.kind,
                            o.name
                        );
                        let e_ir = rel_err(&got, &output_matrix(o.shape, nv, ir_vals));
                        assert!(
                            e_ir <= tol,
                            "{robot} {}.{} state {s}: {e_ir:.2e} from the IR interpreter",
                            f.kind,
                            o.name
                        );
                        worst = worst.max(e);
                        base += o.ids.len();
                    }
                }
                assert!(
                    singular.len() <= 1,
                    "{robot} {}: singular contact states {singular:?}",
                    f.kind
                );
                eprintln!(
                    "{robot} {} {}: worst relative error {worst:.2e} over {} states",
                    f.kind,
                    precision.name(),
                    states.len() - singular.len()
                );
            }
        }
    }
}

/// A step under forces: iiwa holding its tool by a rigid wrench contact, with fext on its
/// fourth link, semi-implicit Euler, f64 cooperative entries; `u` packs the actuated τ and
/// then fext (no λ: the step solves for it), against the reference step and the IR.
#[test]
fn forced_step_kernels_match_the_reference() {
    use grid_gen::model::ContactKind;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(71);
    let iiwa =
        with_forces(&load("grid_iiwa"), &["iiwa_joint_4"], &[("iiwa_link_7", ContactKind::Wrench)]);
    let model = with_step(&iiwa, grid_gen::model::Scheme::SemiImplicitEuler, 0.01);
    let options = WgslOptions {
        precision: Precision::F64,
        strategies: vec![Strategy::Cooperative],
        ..WgslOptions::default()
    };
    let shader = gpu.load(&wgsl(&model, options)).unwrap();
    let lowered =
        grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &Default::default()).unwrap();
    let (nv, nu) = (model.nv(), model.nu());
    let states = states(&model, &mut rng);
    let fext: Vec<Vec<f64>> = states.iter().map(|_| rng.vec(6, -20.0, 20.0)).collect();
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd) = (flat(0), flat(1));
    let u: Vec<f64> = states
        .iter()
        .zip(&fext)
        .flat_map(|(s, f)| s[2][..nu].iter().chain(f).copied().collect::<Vec<_>>())
        .collect();
    for kind in [KernelKind::Step, KernelKind::StepGrad] {
        let f = lowered.function(kind).unwrap();
        let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
        assert_eq!(kernel.nu, nu + 6, "{kind}: u holds the actuated τ and fext");
        assert_eq!(kernel.nu, f.packed_u_len(), "{kind}: u's width");
        let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
        let total = kernel.entry.outputs;
        let mut worst: f64 = 0.0;
        let mut singular = 0;
        for (s, ([q, qd, u], fext)) in states.iter().zip(&fext).enumerate() {
            let j = reference::contact_jacobian(&model, &model.specialisation.contacts, q);
            let sv = j.singular_values();
            if sv.min() < 1e-8 * sv.max() {
                // The arm stretched straight (the zero state): λ is not unique.
                singular += 1;
                continue;
            }
            let ext = reference::External { fext, lambda: &[] };
            let want = reference_outputs_with(
                kind,
                &model,
                q,
                qd,
                &u[..nu],
                reference::DEFAULT_GRAVITY,
                ext,
            );
            let interpreted = f.eval(&kernel_args_with(f.inputs(), q, qd, &u[..nu], ext));
            // Measured 2.3e-13: these states' contact Schur complements are well conditioned.
            let what = format!("{kind} state {s}");
            let e = check_f64_state(&what, f, nv, &got[s * total..], &want, &interpreted);
            worst = worst.max(e);
        }
        assert!(singular <= 1, "{kind}: {singular} singular states");
        eprintln!(
            "grid_iiwa contact step {kind} f64: worst relative error {worst:.2e} over {} states",
            states.len() - singular
        );
    }
}

/// Step kernels that take dt at run time, f64 cooperative entries, each state its own dt:
/// floating HyQ's `step` with fext on its base (`u` packs the twelve actuated τ, fext, then
/// dt: nu < nv, so fext and dt sit after nu entries, not nv) and iiwa's `step_grad`, against
/// the reference at each state's dt and the IR.
#[test]
fn runtime_dt_step_kernels_match_the_reference() {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(73);
    let hyq = with_forces(&load_floating("grid_hyq"), &["root_joint"], &[]);
    let cases = [
        (
            "grid_hyq floating",
            with_runtime_step(&hyq, grid_gen::model::Scheme::SemiImplicitEuler),
            KernelKind::Step,
            1e-2,
        ),
        (
            "grid_iiwa",
            with_runtime_step(&load("grid_iiwa"), grid_gen::model::Scheme::Rk4),
            KernelKind::StepGrad,
            1e-4,
        ),
    ];
    for (robot, model, kind, longest) in cases {
        let options = WgslOptions {
            precision: Precision::F64,
            strategies: vec![Strategy::Cooperative],
            ..WgslOptions::default()
        };
        let shader = gpu.load(&wgsl(&model, options)).unwrap();
        assert!(shader.info.runtime_dt, "{robot}: the header says dt is an input");
        let lower = grid_gen::ir::LowerOptions { kernels: vec![kind], ..Default::default() };
        let lowered = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
        let f = lowered.function(kind).unwrap();
        let (nv, nu, nf) = (model.nv(), model.nu(), 6 * model.nfext());
        let states = states(&model, &mut rng);
        let fext: Vec<Vec<f64>> = states.iter().map(|_| rng.vec(nf, -20.0, 20.0)).collect();
        // A twentieth of the longest to the longest: HyQ's Euler step up to 10 ms, iiwa's
        // RK4 up to 0.1 ms, where it stays within its stability at these states' speeds (as
        // step_kernels_match_the_reference).
        let dt: Vec<f64> =
            (0..states.len()).map(|s| longest * (0.05 + 0.95 * (s % 7) as f64 / 6.0)).collect();
        let flat =
            |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
        let (q, qd) = (flat(0), flat(1));
        let u: Vec<f64> = states
            .iter()
            .zip(&fext)
            .zip(&dt)
            .flat_map(|((s, f), dt)| {
                s[2][..nu].iter().chain(f).chain([dt]).copied().collect::<Vec<_>>()
            })
            .collect();
        let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
        assert_eq!(kernel.nu, nu + nf + 1, "{robot} {kind}: u holds τ, fext and dt");
        assert_eq!(kernel.nu, f.packed_u_len(), "{robot} {kind}: u's width");
        let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
        let total = kernel.entry.outputs;
        let mut worst: f64 = 0.0;
        for (s, (([q, qd, u], fext), dt)) in states.iter().zip(&fext).zip(&dt).enumerate() {
            let g = reference::DEFAULT_GRAVITY;
            let want = reference_step_outputs(kind, &model, q, qd, &u[..nu], g, fext, *dt);
            let ext = reference::External { fext, lambda: &[] };
            let args = kernel_args_dt(f.inputs(), q, qd, &u[..nu], ext, std::slice::from_ref(dt));
            let interpreted = f.eval(&args);
            let what = format!("{robot} {kind} state {s}");
            let e = check_f64_state(&what, f, nv, &got[s * total..], &want, &interpreted);
            worst = worst.max(e);
        }
        eprintln!(
            "{robot} {kind} with a run-time dt, f64: worst relative error {worst:.2e} over {} states",
            states.len()
        );
    }
}

/// A masked contact set on the GPU: floating HyQ's four feet as candidates, f64 cooperative
/// `contact_fd`, every state in another of the sixteen modes (`u` packs τ, then the mask),
/// against the reference holding just the active contacts and the IR.
#[test]
fn masked_contacts_match_the_reference() {
    use grid_gen::model::ContactKind;
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(79);
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    let mut model = with_forces(&load_floating("grid_hyq"), &[], &legs);
    model.specialisation.contact_mask = true;
    let options = WgslOptions {
        precision: Precision::F64,
        strategies: vec![Strategy::Cooperative],
        ..WgslOptions::default()
    };
    let shader = gpu.load(&wgsl(&model, options)).unwrap();
    assert_eq!(shader.info.active, 4, "the header counts the mask");
    let kind = KernelKind::ContactFd;
    let lower = grid_gen::ir::LowerOptions { kernels: vec![kind], ..Default::default() };
    let lowered = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
    let f = lowered.function(kind).unwrap();
    let nv = model.nv();
    let states = states(&model, &mut rng);
    let modes: Vec<[bool; 4]> =
        (0..states.len()).map(|s| std::array::from_fn(|c| (s % 16) >> c & 1 == 1)).collect();
    let mask = |m: &[bool; 4]| m.map(|a| f64::from(u8::from(a)));
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd) = (flat(0), flat(1));
    let u: Vec<f64> = states
        .iter()
        .zip(&modes)
        .flat_map(|(s, m)| s[2].iter().copied().chain(mask(m)).collect::<Vec<_>>())
        .collect();
    let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
    assert_eq!(kernel.nu, nv + 4, "{kind}: u holds τ and the mask");
    assert_eq!(kernel.nu, f.packed_u_len(), "{kind}: u's width");
    let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
    let total = kernel.entry.outputs;
    let (mut worst, mut singular): (f64, usize) = (0.0, 0);
    for (s, ([q, qd, u], m)) in states.iter().zip(&modes).enumerate() {
        let held = model.holding_contacts(m);
        let j = reference::contact_jacobian(&held, &held.specialisation.contacts, q);
        if j.nrows() > 0 && j.singular_values().min() < 1e-8 * j.singular_values().max() {
            // A leg stretched straight: λ is not unique there.
            singular += 1;
            continue;
        }
        let g = reference::DEFAULT_GRAVITY;
        let want = reference_masked_outputs(kind, &model, q, qd, u, g, &[], 0.0, m);
        let values = mask(m);
        let ext = reference::External { fext: &[], lambda: &[] };
        let interpreted = f.eval(&kernel_args_masked(f.inputs(), q, qd, u, ext, &[], &values));
        let what = format!("{kind} state {s} mode {m:?}");
        let e = check_f64_state(&what, f, nv, &got[s * total..], &want, &interpreted);
        worst = worst.max(e);
    }
    assert!(singular <= 2, "{singular} singular states");
    eprintln!(
        "grid_hyq floating {kind}, sixteen contact modes, f64: worst relative error {worst:.2e} over {} states",
        states.len() - singular
    );
}

/// Baumgarte-stabilised contacts on the GPU: floating HyQ's four feet, f64 cooperative
/// `contact_fd_grad`, each state its own gains and references (`u` packs τ, then the gains,
/// then the references), against the reference's stabilised contact dynamics and the IR.
#[test]
fn stabilised_contacts_match_the_reference() {
    use grid_gen::model::ContactKind;
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    check_stabilised(&legs, 107);
}

/// A stabilised wrench foot (its error SE(3)'s logarithm, its reference 7 entries of `u`)
/// beside a point foot, as [`stabilised_contacts_match_the_reference`].
#[test]
fn stabilised_wrench_contacts_match_the_reference() {
    use grid_gen::model::ContactKind;
    check_stabilised(
        &[("lf_lowerleg", ContactKind::Wrench), ("rh_lowerleg", ContactKind::Point)],
        109,
    );
}

fn check_stabilised(legs: &[(&str, grid_gen::model::ContactKind)], seed: u64) {
    let Some((_serial, gpu)) = gpu_f64() else { return };
    let mut rng = Rng(seed);
    let mut model = with_forces(&load_floating("grid_hyq"), &[], legs);
    model.specialisation.baumgarte = true;
    let nc = legs.len();
    let nref = model.specialisation.contact_ref_len();
    let options = WgslOptions {
        precision: Precision::F64,
        strategies: vec![Strategy::Cooperative],
        ..WgslOptions::default()
    };
    let shader = gpu.load(&wgsl(&model, options)).unwrap();
    assert_eq!(shader.info.baumgarte, nc, "the header counts the stabilised contacts");
    let kind = KernelKind::ContactFdGrad;
    let lower = grid_gen::ir::LowerOptions { kernels: vec![kind], ..Default::default() };
    let lowered = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
    let f = lowered.function(kind).unwrap();
    let nv = model.nv();
    let states = states(&model, &mut rng);
    let corr: Vec<(Vec<f64>, Vec<f64>)> = states
        .iter()
        .map(|_| {
            let gains: Vec<f64> = (0..nc)
                .flat_map(|_| [rng.vec(1, 0.0, 200.0)[0], rng.vec(1, 0.0, 30.0)[0]])
                .collect();
            // Positions within 0.6 m of the origin; a wrench's quaternion any unit one.
            let refs = legs.iter().flat_map(|(_, kind)| {
                let mut r = rng.vec(3, -0.6, 0.6);
                if *kind == grid_gen::model::ContactKind::Wrench {
                    let quat = rng.vec(4, -1.0, 1.0);
                    let norm = quat.iter().map(|x| x * x).sum::<f64>().sqrt();
                    r.extend(quat.iter().map(|x| x / norm));
                }
                r
            });
            (gains, refs.collect())
        })
        .collect();
    let flat =
        |k: usize| -> Vec<f64> { states.iter().flat_map(|s| s[k].iter().copied()).collect() };
    let (q, qd) = (flat(0), flat(1));
    let u: Vec<f64> = states
        .iter()
        .zip(&corr)
        .flat_map(|(s, (g, r))| s[2].iter().chain(g).chain(r).copied().collect::<Vec<_>>())
        .collect();
    let kernel = gpu.kernel(&shader, &Strategy::Cooperative.entry(kind.name())).unwrap();
    assert_eq!(kernel.nu, nv + 2 * nc + nref, "{kind}: u holds τ, the gains and the references");
    assert_eq!(kernel.nu, f.packed_u_len(), "{kind}: u's width");
    let got = gpu.run(&kernel, &q, &qd, &u).unwrap();
    let total = kernel.entry.outputs;
    let (mut worst, mut singular): (f64, usize) = (0.0, 0);
    for (s, ([q, qd, u], (gains, refs))) in states.iter().zip(&corr).enumerate() {
        let j = reference::contact_jacobian(&model, &model.specialisation.contacts, q);
        if j.singular_values().min() < 1e-8 * j.singular_values().max() {
            // A leg stretched straight: λ is not unique there.
            singular += 1;
            continue;
        }
        let g = reference::DEFAULT_GRAVITY;
        let c = reference::Baumgarte { gains, refs };
        let (sol, d) = reference::contact_fd_derivatives_with(&model, q, qd, u, g, &[], c).unwrap();
        let col = |v: &[f64]| nalgebra::DMatrix::from_column_slice(v.len(), 1, v);
        let want = vec![
            col(&sol.qdd),
            col(&sol.lambda),
            d.dqdd_dq,
            d.dqdd_dqd,
            d.dqdd_dtau,
            d.dlambda_dq,
            d.dlambda_dqd,
            d.dlambda_dtau,
        ];
        let ext = reference::External { fext: &[], lambda: &[] };
        let args = kernel_args_corrected(f.inputs(), q, qd, u, ext, &[], &[], c);
        let interpreted = f.eval(&args);
        let what = format!("{kind} state {s}");
        let e = check_f64_state(&what, f, nv, &got[s * total..], &want, &interpreted);
        worst = worst.max(e);
    }
    assert!(singular <= 2, "{singular} singular states");
    eprintln!(
        "grid_hyq floating stabilised {kind} ({}) f64: worst relative error {worst:.2e} over {} states",
        legs.iter().map(|(l, k)| format!("{l} {}", k.name())).collect::<Vec<_>>().join(", "),
        states.len() - singular
    );
}
