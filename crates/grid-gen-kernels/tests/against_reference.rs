//! Every checked-in kernel, compiled and run, against the reference dynamics, in f64 and
//! f32, on random and extreme states (zero, both joint limits, speeds 1e-8 and 1e3): both
//! machine-code copies, `portable` and `fma` (fused multiply-adds round once where the
//! portable copy rounds twice; the same tolerances hold for both).
//!
//! Norm: ‖generated − reference‖max / ‖reference‖max per output matrix or vector.
//! - f64: ≤ 1e-12. The generated code reorders sums, folds constants and snaps model
//!   constants within 1e-15 of 0 or ±1; nothing else differs.
//! - f32: the reference runs in f64 at the same (f32-rounded) inputs, so only the
//!   kernel's f32 arithmetic is measured. RNEA, its gradient and M: ≤ F32_DIRECT; anything
//!   through M⁻¹: ≤ F32_MINV (see the constants for why).

use grid_gen::{reference, Model};
use grid_gen_test_support::{load, rel_err as rel, Rng};
use nalgebra::DMatrix;

const F64_TOL: f64 = 1e-12;
/// f32 has ε = 6e-8; the recursions sum O(10·depth) rounded products, and at speeds of
/// 1e3 the Coriolis terms cancel by about two digits (measured worst: 4.9e-6 on UR5,
/// typically 3e-7; Pinocchio in f32 reaches about 1e-7 on these outputs).
const F32_DIRECT: f64 = 1e-5;
/// Through M⁻¹ the error grows with cond(M), 1e2 to 1e4 for these robots (measured worst
/// 1.6e-5 on the rbd-benchmarks iiwa; Pinocchio in f32 reaches 1e-5 to 1e-4 here).
const F32_MINV: f64 = 1e-4;

/// (label, q, qd, u) where u is q̈ for RNEA and τ for FD.
type State = (String, Vec<f64>, Vec<f64>, Vec<f64>);

fn states(model: &Model, rng: &mut Rng) -> Vec<State> {
    let n = model.nv();
    let mut out: Vec<_> = (0..6)
        .map(|i| {
            (
                format!("random {i}"),
                rng.vec(n, -3.1, 3.1),
                rng.vec(n, -3.0, 3.0),
                rng.vec(n, -3.0, 3.0),
            )
        })
        .collect();
    let limit = |lo: bool| {
        model
            .coordinate_joints()
            .into_iter()
            .map(|i| model.joint(i))
            .map(|j| {
                j.limit
                    .map_or(if lo { -3.1 } else { 3.1 }, |(l, h)| if lo { l } else { h })
                    .clamp(-1e3, 1e3)
            })
            .collect::<Vec<_>>()
    };
    out.push(("zero".into(), vec![0.0; n], vec![0.0; n], vec![0.0; n]));
    out.push(("lower limits".into(), limit(true), rng.vec(n, -1.0, 1.0), rng.vec(n, -1.0, 1.0)));
    out.push(("upper limits".into(), limit(false), rng.vec(n, -1.0, 1.0), rng.vec(n, -1.0, 1.0)));
    for s in [1e-8, 1e3] {
        out.push((
            format!("speed {s:e}"),
            rng.vec(n, -3.1, 3.1),
            rng.vec(n, -s, s),
            rng.vec(n, -s, s),
        ));
    }
    out
}

/// Reference outputs in kernel order: rnea, dc_dq, dc_dqd, M, Minv, fd, qdd, dqdd_dq, dqdd_dqd.
fn reference_outputs(m: &Model, q: &[f64], qd: &[f64], u: &[f64]) -> Vec<DMatrix<f64>> {
    let g = reference::DEFAULT_GRAVITY;
    let col = |v: Vec<f64>| DMatrix::from_column_slice(v.len(), 1, &v);
    let (dq, dqd) = reference::rnea_derivatives(m, q, qd, u, g);
    let (qdd, fq, fqd) = reference::forward_dynamics_derivatives(m, q, qd, u, g);
    vec![
        col(reference::rnea(m, q, qd, u, g)),
        dq,
        dqd,
        reference::crba(m, q),
        reference::minv(m, q),
        col(reference::forward_dynamics(m, q, qd, u, g)),
        col(qdd),
        fq,
        fqd,
    ]
}

/// Each copy's outputs against `want` at `(direct, through M⁻¹)` tolerances, raising `worst`.
fn check_copies<G: AsRef<[DMatrix<f64>]>>(
    at: &str,
    copies: Vec<(&str, G)>,
    want: &[DMatrix<f64>],
    (tol_direct, tol_minv): (f64, f64),
    worst: &mut f64,
) {
    for (copy, got) in copies {
        for (i, g) in got.as_ref().iter().enumerate() {
            let tol = if THROUGH_MINV[i] { tol_minv } else { tol_direct };
            let e = rel(g, &want[i]);
            *worst = worst.max(e);
            assert!(e <= tol, "{at} ({copy}): {} relative error {e:.2e} > {tol:e}", NAMES[i]);
        }
    }
}

const NAMES: [&str; 9] = [
    "rnea",
    "rnea_grad.dc_dq",
    "rnea_grad.dc_dqd",
    "mass_matrix",
    "minv",
    "fd",
    "fd_grad.qdd",
    "fd_grad.dqdd_dq",
    "fd_grad.dqdd_dqd",
];
/// Outputs computed through M⁻¹.
const THROUGH_MINV: [bool; 9] = [false, false, false, false, true, true, true, true, true];

/// Whether the `fma` copies run here. Without AVX2 and FMA they cannot; with `CI` set that
/// fails the run rather than leaving half the generated code untested.
fn fma_runs() -> bool {
    let has = grid_gen_kernels::grid_iiwa::has_fma();
    if !has {
        assert!(std::env::var_os("CI").is_none(), "this CPU has no AVX2+FMA, so the generated `fma` copies cannot be tested; CI needs an x86-64-v3 machine");
        eprintln!("note: this CPU has no AVX2+FMA; only the portable copies were tested");
    }
    has
}

/// Every kernel of the checked-in module `$m`, both copies, f64 and f32 (the f32 run's
/// reference at the f32-rounded state), on `$states` (label, q, qd, u) against the
/// reference on `$model` at the fixed-base tolerances; prints the worst errors under `$name`.
macro_rules! check_module {
    ($($m:ident)::+, $model:expr, $name:expr, $states:expr) => {{
        let mut worst = [0.0f64; 2];
        for (label, q, qd, u) in $states {
            for (f32, tol_direct, tol_minv) in [(false, F64_TOL, F64_TOL), (true, F32_DIRECT, F32_MINV)] {
                let r = |v: &[f64]| -> Vec<f64> { v.iter().map(|&x| if f32 { x as f32 as f64 } else { x }).collect() };
                let (q, qd, u) = (r(&q), r(&qd), r(&u));
                let want = reference_outputs($model, &q, &qd, &u);
                let mut copies = vec![(
                    "portable",
                    if f32 { run_kernels!($($m)::+, portable, f32, &q, &qd, &u) } else { run_kernels!($($m)::+, portable, f64, &q, &qd, &u) },
                )];
                if fma_runs() {
                    copies.push(("fma", if f32 { run_kernels!($($m)::+, fma, f32, &q, &qd, &u) } else { run_kernels!($($m)::+, fma, f64, &q, &qd, &u) }));
                }
                check_copies(
                    &format!("{} {}, {label}", $name, if f32 { "f32" } else { "f64" }),
                    copies,
                    &want,
                    (tol_direct, tol_minv),
                    &mut worst[usize::from(f32)],
                );
            }
        }
        println!("{}: worst relative error f64 {:.2e}, f32 {:.2e}", $name, worst[0], worst[1]);
    }};
}

/// `$t` and returns the outputs as f64.
macro_rules! run_kernels {
    ($($m:ident)::+, $copy:ident, $t:ty, $q:expr, $qd:expr, $u:expr) => {{
        use grid_gen_kernels::$($m)::+ as k;
        use k::$copy as c;
        let arr = |v: &[f64]| -> [$t; k::NV] { std::array::from_fn(|i| v[i] as $t) };
        // q has NQ entries (NV + 1 per quaternion: a floating base, spherical joints).
        let q: [$t; k::NQ] = std::array::from_fn(|i| $q[i] as $t);
        let (qd, u) = (arr($qd), arr($u));
        let v = |x: [$t; k::NV]| DMatrix::from_iterator(k::NV, 1, x.iter().map(|&y| y as f64));
        let m = |x: [[$t; k::NV]; k::NV]| DMatrix::from_fn(k::NV, k::NV, |i, j| x[i][j] as f64);
        // SAFETY: the fma copy is only called after `fma_runs()` (the portable one needs none).
        #[allow(unused_unsafe)]
        unsafe {
            let (dq, dqd) = c::rnea_grad(&q, &qd, &u);
            let (qdd, fq, fqd) = c::fd_grad(&q, &qd, &u);
            vec![v(c::rnea(&q, &qd, &u)), m(dq), m(dqd), m(c::mass_matrix(&q)), m(c::minv(&q)), v(c::fd(&q, &qd, &u)), v(qdd), m(fq), m(fqd)]
        }
    }};
}

/// `$lanes` seeded states of robot `$m` in one call of `$t` (built from an array of
/// `$lanes` values of `$s` by `$wrap`, read back by `$get`) against `$lanes` scalar calls
/// in `$s` (inputs converted by `$to`), `rnea_grad` and `fd_grad`, through the dispatcher and
/// the portable copy: every output of every lane equal bit for bit.
macro_rules! lanes_match_scalar_calls {
    ($m:ident, $stem:literal, $t:ty, $lanes:literal, $s:ty, $seed:literal, $to:expr, $wrap:expr, $get:expr) => {{
        use grid_gen_kernels::$m as k;
        let (to, wrap, get) = ($to, $wrap, $get);
        let model = load($stem);
        let mut rng = Rng($seed);
        let st: Vec<_> = states(&model, &mut rng).into_iter().take($lanes).collect();
        assert_eq!(st.len(), $lanes);
        let lane =
            |f: &dyn Fn(&(String, Vec<f64>, Vec<f64>, Vec<f64>)) -> &Vec<f64>| -> [$t; k::NV] {
                std::array::from_fn(|j| wrap(std::array::from_fn(|l| to(f(&st[l])[j]))))
            };
        let (q, qd, u) = (lane(&|s| &s.1), lane(&|s| &s.2), lane(&|s| &s.3));
        macro_rules! check {
            ($c:path) => {{
                use $c as c;
                let (lq, lqd) = c::rnea_grad(&q, &qd, &u);
                let (lqdd, lfq, lfqd) = c::fd_grad(&q, &qd, &u);
                for (l, s) in st.iter().enumerate() {
                    let arr = |v: &Vec<f64>| -> [$s; k::NV] { std::array::from_fn(|i| to(v[i])) };
                    let (dq, dqd) = c::rnea_grad(&arr(&s.1), &arr(&s.2), &arr(&s.3));
                    let (qdd, fq, fqd) = c::fd_grad(&arr(&s.1), &arr(&s.2), &arr(&s.3));
                    for i in 0..k::NV {
                        assert_eq!(get(lqdd[i], l).to_bits(), qdd[i].to_bits());
                        for j in 0..k::NV {
                            assert_eq!(get(lq[i][j], l).to_bits(), dq[i][j].to_bits());
                            assert_eq!(get(lqd[i][j], l).to_bits(), dqd[i][j].to_bits());
                            assert_eq!(get(lfq[i][j], l).to_bits(), fq[i][j].to_bits());
                            assert_eq!(get(lfqd[i][j], l).to_bits(), fqd[i][j].to_bits());
                        }
                    }
                }
            }};
        }
        check!(k);
        check!(k::portable);
    }};
}

/// `$body` for the robots whose modules are small (the `Lanes` tests); nothing for the large.
macro_rules! array_lanes_on_small_robots {
    (grid_atlas, $($body:tt)*) => {};
    (panda, $($body:tt)*) => {};
    (rbd_benchmarks_iiwa, $($body:tt)*) => {};
    ($m:ident, $($body:tt)*) => { $($body)* };
}

macro_rules! robot_test {
    ($m:ident, $stem:literal) => {
        mod $m {
            use super::*;

            // The array lanes (`Lanes`) are generic code that the batches do not run (they run
            // `F64x4` and `F32x8`, checked on every robot below); checked on the smaller robots
            // only, where their debug build is short.
            array_lanes_on_small_robots! { $m,
            /// Four states in one `Lanes<4>` call give bit-identical results to four scalar
            /// calls of the same copy (the dispatcher's, and the portable one).
            #[test]
            fn lanes_are_bit_identical_to_scalar_calls() {
                lanes_match_scalar_calls!($m, $stem, k::Lanes<4>, 4, f64, 9, |x: f64| x, k::Lanes, |v: k::Lanes<4>, l: usize| v.0[l]);
            }

            /// Eight f32 states in one `Lanes<8, f32>` call give bit-identical results to eight
            /// scalar f32 calls of the same copy: a lane runs the scalar call's f32 operations.
            #[test]
            fn f32_lanes_are_bit_identical_to_scalar_f32_calls() {
                lanes_match_scalar_calls!($m, $stem, k::Lanes<8, f32>, 8, f32, 11, |x: f64| x as f32, k::Lanes, |v: k::Lanes<8, f32>, l: usize| v.0[l]);
            }
            }

            /// Four f64 states in one `F64x4` (one AVX register) give bit-identical results to
            /// four scalar calls of the same copy. The portable copy runs it too (each
            /// operation a call): a CPU without AVX2 and FMA cannot make an `F64x4`.
            #[test]
            fn f64x4_is_bit_identical_to_scalar_calls() {
                use grid_gen_kernels::$m as k;
                if !fma_runs() {
                    assert!(k::F64x4::new([0.0; 4]).is_none() && !k::F64x4::supported());
                    return;
                }
                lanes_match_scalar_calls!($m, $stem, k::F64x4, 4, f64, 13, |x: f64| x, |a: [f64; 4]| k::F64x4::new(a).unwrap(), |v: k::F64x4, l: usize| v.to_array()[l]);
            }

            /// Eight f32 states in one `F32x8` give bit-identical results to eight scalar f32
            /// calls of the same copy.
            #[test]
            fn f32x8_is_bit_identical_to_scalar_f32_calls() {
                use grid_gen_kernels::$m as k;
                if !fma_runs() {
                    assert!(k::F32x8::new([0.0; 8]).is_none());
                    return;
                }
                lanes_match_scalar_calls!($m, $stem, k::F32x8, 8, f32, 15, |x: f64| x as f32, |a: [f32; 8]| k::F32x8::new(a).unwrap(), |v: k::F32x8, l: usize| v.to_array()[l]);
            }

            /// The portable copy computes exactly the IR's graph: bit for bit in f64 and in
            /// f32 (inputs and constants rounded to f32), so what `grid-gen accuracy`
            /// measures by interpreting the graph is what this code returns.
            #[test]
            fn the_portable_copy_is_the_ir_bit_for_bit() {
                let model = load($stem);
                let n = model.nv();
                let module = grid_gen::ir::lower(&model, reference::DEFAULT_GRAVITY, &grid_gen::ir::LowerOptions::default()).unwrap();
                let mut rng = Rng(17);
                for (label, q, qd, u) in states(&model, &mut rng).into_iter().take(3) {
                    let mut want64 = Vec::new();
                    let mut want32 = Vec::new();
                    for f in &module.functions {
                        let args = grid_gen_test_support::kernel_args(f.inputs(), &q, &qd, &u);
                        for (o, v) in f.outputs.iter().zip(f.eval(&args)) {
                            want64.push(grid_gen_test_support::output_matrix(o.shape, n, &v));
                        }
                        for (o, v) in f.outputs.iter().zip(f.eval_f32(&args)) {
                            want32.push(grid_gen_test_support::output_matrix(o.shape, n, &v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>()));
                        }
                    }
                    for (t, got, want) in
                        [("f64", run_kernels!($m, portable, f64, &q, &qd, &u), want64), ("f32", run_kernels!($m, portable, f32, &q, &qd, &u), want32)]
                    {
                        for ((name, g), w) in NAMES.iter().zip(&got).zip(&want) {
                            let same = g.iter().zip(w.iter()).all(|(a, b)| a.to_bits() == b.to_bits());
                            assert!(same, "{} {t} {label}: {name} differs from the IR's value", $stem);
                        }
                    }
                }
            }

            #[test]
            fn f64_and_f32_match_the_reference() {
                let model = load($stem);
                assert_eq!(grid_gen_kernels::$m::NV, model.nv());
                let names: Vec<&str> = model.joints.iter().map(|j| j.name.as_str()).collect();
                assert_eq!(grid_gen_kernels::$m::JOINT_NAMES.to_vec(), names);
                let fma = fma_runs();
                for copy in ["portable", "fma"] {
                    if copy == "fma" && !fma {
                        continue;
                    }
                    let run = |t32: bool, q: &[f64], qd: &[f64], u: &[f64]| match (copy, t32) {
                        ("portable", false) => run_kernels!($m, portable, f64, q, qd, u),
                        ("portable", true) => run_kernels!($m, portable, f32, q, qd, u),
                        (_, false) => run_kernels!($m, fma, f64, q, qd, u),
                        (_, true) => run_kernels!($m, fma, f32, q, qd, u),
                    };
                    let mut rng = Rng(7);
                    let mut worst = [0.0f64; 2];
                    let mut worst64 = 0.0f64;
                    for (label, q, qd, u) in states(&model, &mut rng) {
                        let want = reference_outputs(&model, &q, &qd, &u);
                        let got64 = run(false, &q, &qd, &u);
                        for ((name, got), want) in NAMES.iter().zip(&got64).zip(&want) {
                            let e = rel(got, want);
                            assert!(e <= F64_TOL, "{} {copy} f64 {label}: {name} relative error {e:.2e}", $stem);
                            worst64 = worst64.max(e);
                        }
                        // f32: the reference at the f32-rounded state.
                        let r = |v: &Vec<f64>| v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>();
                        let (q, qd, u) = (r(&q), r(&qd), r(&u));
                        let want = reference_outputs(&model, &q, &qd, &u);
                        let got32 = run(true, &q, &qd, &u);
                        for (i, ((name, got), want)) in NAMES.iter().zip(&got32).zip(&want).enumerate() {
                            let e = rel(got, want);
                            let tol = if THROUGH_MINV[i] { F32_MINV } else { F32_DIRECT };
                            worst[usize::from(THROUGH_MINV[i])] = worst[usize::from(THROUGH_MINV[i])].max(e);
                            assert!(e <= tol, "{} {copy} f32 {label}: {name} relative error {e:.2e} > {tol:e}", $stem);
                        }
                    }
                    eprintln!("{} {copy}: worst f64 error {worst64:.2e}; worst f32 error {:.2e} direct, {:.2e} through Minv", $stem, worst[0], worst[1]);
                }
            }
        }
    };
}

grid_gen_kernels::for_each_robot!(robot_test);

/// The checked-in scene kernels (`generated/scenes/`) against the reference on the scene's
/// model, f64, at F64_TOL: the scene reaches the generated code, not only the model.
#[test]
fn scene_kernels_match_the_reference_on_the_scene_model() {
    macro_rules! check {
        ($m:ident, $robot:literal, $scene:literal) => {{
            use grid_gen_kernels::scenes::$m as k;
            let (model, _) = grid_gen_test_support::load_in_scene($robot, $scene);
            assert_eq!(k::NV, model.nv());
            let mut rng = Rng(23);
            for (label, q, qd, u) in states(&model, &mut rng) {
                let arr = |v: &[f64]| -> [f64; k::NV] { std::array::from_fn(|i| v[i]) };
                let m = |x: [[f64; k::NV]; k::NV]| DMatrix::from_fn(k::NV, k::NV, |i, j| x[i][j]);
                // A static scene's kernels answer for q̇ = 0 whatever `qd` holds, and a
                // `[gradient]` selection writes 0 outside it: the reference, so told.
                let spec = &model.specialisation;
                let qd_ref = if spec.static_velocity { vec![0.0; k::NV] } else { qd.clone() };
                let mut want = reference_outputs(&model, &q, &qd_ref, &u);
                for i in [1, 2, 7, 8] {
                    want[i] = DMatrix::from_fn(k::NV, k::NV, |r, c| {
                        if spec.keeps(r, c) {
                            want[i][(r, c)]
                        } else {
                            0.0
                        }
                    });
                }
                let (dq, dqd) = k::rnea_grad(&arr(&q), &arr(&qd), &arr(&u));
                let (qdd, fq, fqd) = k::fd_grad(&arr(&q), &arr(&qd), &arr(&u));
                let got = [
                    (1, m(dq)),
                    (2, m(dqd)),
                    (6, DMatrix::from_column_slice(k::NV, 1, &qdd)),
                    (7, m(fq)),
                    (8, m(fqd)),
                ];
                for (i, g) in got {
                    let e = rel(&g, &want[i]);
                    assert!(
                        e <= F64_TOL,
                        "{} in {}, {label}: {} relative error {e:.2e}",
                        $robot,
                        $scene,
                        NAMES[i]
                    );
                }
            }
        }};
    }
    check!(grid_iiwa_wrist_locked, "grid_iiwa", "iiwa_wrist_locked");
    check!(grid_hyq_front_legs, "grid_hyq", "hyq_front_legs");
    check!(grid_iiwa_static, "grid_iiwa", "iiwa_static");
    check!(grid_hyq_lf_columns, "grid_hyq", "hyq_lf_columns");
}

/// HyQ on a floating base (`generated/scenes/grid_hyq.hyq_floating/`): every kernel, both
/// copies, f64 and f32, against the reference (held to Pinocchio's free-flyer by
/// grid-gen's tests/pinocchio.rs) at the fixed-base tolerances, on the usual states each
/// with a random base pose (the zero state unrotated at the origin).
#[test]
fn floating_base_kernels_match_the_reference() {
    use grid_gen_kernels::scenes::grid_hyq_floating as k;
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_floating");
    assert!(model.floating && k::NV == model.nv() && k::NQ == model.nq());
    let mut rng = Rng(29);
    let states: Vec<_> = states(&model, &mut rng)
        .into_iter()
        .map(|(label, per_joint, qd, u)| {
            let base =
                if label == "zero" { [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] } else { rng.base_pose() };
            (label, model.q_from_joints(&per_joint, base), qd, u)
        })
        .collect();
    check_module!(scenes::grid_hyq_floating, &model, "HyQ floating", states);
}

/// Spherical joints (`generated/fixtures/ball_arm/`): ball_arm's three
/// (on the root, between moving bodies, at a leaf), every kernel, both copies, f64 and f32,
/// uniform random rotations, against the reference (held to Pinocchio's
/// `JointModelSpherical` by grid-gen's tests/pinocchio.rs) at the fixed-base tolerances.
#[test]
fn spherical_kernels_match_the_reference() {
    use grid_gen_kernels::fixtures::ball_arm as k;
    let model = grid_gen_test_support::load_urdf(
        &grid_gen_test_support::repo().join("tests/fixtures/ball_arm.urdf"),
        false,
    );
    assert!(model.spherical.len() == 3 && k::NV == model.nv() && k::NQ == model.nq());
    let mut rng = Rng(31);
    let states: Vec<_> = states(&model, &mut rng)
        .into_iter()
        .map(|(label, per_joint, qd, u)| {
            let mut q = model.q_from_joints(&per_joint, [0.0; 7]);
            if label != "zero" {
                for &first in &model.spherical {
                    let at = model.group_q(first).0;
                    q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
                }
            }
            (label, q, qd, u)
        })
        .collect();
    check_module!(fixtures::ball_arm, &model, "ball_arm", states);
}

/// The Panda with coupled fingers (`generated/scenes/panda.panda_mimic/`):
/// every kernel, both copies, f64 and f32, against the reference (held to Pinocchio's mimic
/// model by grid-gen's tests/pinocchio.rs) at the fixed-base tolerances.
#[test]
fn coupled_mimic_kernels_match_the_reference() {
    use grid_gen_kernels::scenes::panda_mimic as k;
    let (model, _) = grid_gen_test_support::load_in_scene("panda", "panda_mimic");
    assert!(k::NV == model.nv() && model.njoints() == k::NV + 1);
    let mut rng = Rng(31);
    check_module!(scenes::panda_mimic, &model, "Panda coupled", states(&model, &mut rng));
}

/// The frame kernels of `$m` (`portable` or `fma` copy `$copy`, scalar `$t`) as flat f64
/// vectors in the reference's layout: translation, rotation, Jacobian, velocity, acceleration.
macro_rules! run_frames {
    ($m:ident, $copy:ident, $t:ty, $q:expr, $qd:expr, $u:expr) => {{
        use grid_gen_kernels::scenes::$m as k;
        use k::$copy as c;
        let q: [$t; k::NQ] = std::array::from_fn(|i| $q[i] as $t);
        let qd: [$t; k::NV] = std::array::from_fn(|i| $qd[i] as $t);
        let u: [$t; k::NV] = std::array::from_fn(|i| $u[i] as $t);
        // The `fma` copy's functions are `unsafe` (they need the CPU features checked above).
        #[allow(unused_unsafe)]
        let ((t, r), j, v, a) = unsafe {
            (
                c::frame_placement(&q),
                c::frame_jacobian(&q),
                c::frame_velocity(&q, &qd),
                c::frame_acceleration(&q, &qd, &u),
            )
        };
        let f = |x: &[$t]| x.iter().map(|&y| y as f64).collect::<Vec<f64>>();
        vec![
            f(t.as_flattened()),
            f(r.as_flattened()),
            f(j.as_flattened().as_flattened()),
            f(v.as_flattened()),
            f(a.as_flattened()),
        ]
    }};
}

/// The checked-in frame kernels (`generated/scenes/grid_iiwa.iiwa_tool_frame/`, floating
/// `grid_hyq.hyq_feet_floating/`), both copies, f64 and f32, against the reference frame
/// kinematics (held to Pinocchio by grid-gen's tests/frames.rs) on the usual states, each
/// floating one with a random base pose. Tolerances: f64 1e-12 as every kernel; f32 1e-5
/// (F32_DIRECT: forward kinematics sums a chain of rounded rotations, no M⁻¹).
#[test]
fn frame_kernels_match_the_reference() {
    use grid_gen::ir::KernelKind::*;
    use grid_gen_test_support::{col, reference_frames};
    macro_rules! check {
        ($m:ident, $robot:literal, $scene:literal) => {{
            let (model, _) = grid_gen_test_support::load_in_scene($robot, $scene);
            let k_nf = grid_gen_kernels::scenes::$m::NF;
            assert_eq!(k_nf, model.specialisation.frames.len());
            let mut rng = Rng(37);
            let mut worst = [0.0f64; 2];
            for (label, per_joint, qd, u) in states(&model, &mut rng) {
                let base = if label == "zero" { [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] } else { rng.base_pose() };
                let q = model.q_from_joints(&per_joint, base);
                for (f32, tol) in [(false, F64_TOL), (true, F32_DIRECT)] {
                    let r = |v: &[f64]| -> Vec<f64> { v.iter().map(|&x| if f32 { x as f32 as f64 } else { x }).collect() };
                    let (q, qd, u) = (r(&q), r(&qd), r(&u));
                    let want: Vec<Vec<f64>> = [FramePlacement, FrameJacobian, FrameVelocity, FrameAcceleration]
                        .into_iter()
                        .flat_map(|kind| reference_frames(kind, &model, &q, &qd, &u))
                        .collect();
                    let mut copies = vec![("portable", if f32 { run_frames!($m, portable, f32, q, qd, u) } else { run_frames!($m, portable, f64, q, qd, u) })];
                    if fma_runs() {
                        copies.push(("fma", if f32 { run_frames!($m, fma, f32, q, qd, u) } else { run_frames!($m, fma, f64, q, qd, u) }));
                    }
                    for (copy, got) in copies {
                        for (i, name) in ["translation", "rotation", "jacobian", "velocity", "acceleration"].iter().enumerate() {
                            let e = rel(&col(&got[i]), &col(&want[i]));
                            worst[usize::from(f32)] = worst[usize::from(f32)].max(e);
                            assert!(e <= tol, "{} {label} ({copy}, f32 {f32}): {name} relative error {e:.2e} > {tol:e}", $scene);
                        }
                    }
                }
            }
            println!("{}: worst relative error f64 {:.2e}, f32 {:.2e}", $scene, worst[0], worst[1]);
        }};
    }
    check!(grid_iiwa_tool_frame, "grid_iiwa", "iiwa_tool_frame");
    check!(grid_hyq_feet_floating, "grid_hyq", "hyq_feet_floating");
}

/// `frame_acceleration_grad` of the frame scenes, both copies, f64: against the IR
/// interpreter of the same graph (itself held to central differences of the reference by
/// grid-gen's tests/frames.rs): the portable copy bit for bit, the `fma` copy within 1e-12
/// (fused multiply-adds round once where the graph rounds twice).
#[test]
fn frame_acceleration_grad_matches_its_graph() {
    use grid_gen::ir::{self, KernelKind, LowerOptions};
    macro_rules! check {
        ($m:ident, $robot:literal, $scene:literal) => {{
            use grid_gen_kernels::scenes::$m as k;
            let (model, _) = grid_gen_test_support::load_in_scene($robot, $scene);
            let lower = LowerOptions {
                kernels: vec![KernelKind::FrameAccelerationGrad],
                ..LowerOptions::default()
            };
            let module = ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
            let f = module.function(KernelKind::FrameAccelerationGrad).unwrap();
            let mut rng = Rng(43);
            for (label, per_joint, qd, u) in states(&model, &mut rng) {
                let q = model.q_from_joints(&per_joint, rng.base_pose());
                let want = f.eval(&[&q, &qd, &u]);
                let qa: [f64; k::NQ] = std::array::from_fn(|i| q[i]);
                let qda: [f64; k::NV] = std::array::from_fn(|i| qd[i]);
                let ua: [f64; k::NV] = std::array::from_fn(|i| u[i]);
                let flat = |x: (
                    [[[f64; k::NV]; 3]; k::NF],
                    [[[f64; k::NV]; 3]; k::NF],
                    [[[f64; k::NV]; 3]; k::NF],
                )| {
                    [
                        x.0.as_flattened().as_flattened().to_vec(),
                        x.1.as_flattened().as_flattened().to_vec(),
                        x.2.as_flattened().as_flattened().to_vec(),
                    ]
                };
                let portable = flat(k::portable::frame_acceleration_grad(&qa, &qda, &ua));
                assert_eq!(
                    portable.to_vec(),
                    want,
                    "{} {label}: the portable copy is the graph",
                    $scene
                );
                if fma_runs() {
                    let fma = flat(unsafe { k::fma::frame_acceleration_grad(&qa, &qda, &ua) });
                    for (o, (g, w)) in fma.iter().zip(&want).enumerate() {
                        let e = rel(&grid_gen_test_support::col(g), &grid_gen_test_support::col(w));
                        assert!(e <= F64_TOL, "{} {label} output {o} (fma): {e:.2e}", $scene);
                    }
                }
            }
        }};
    }
    check!(grid_iiwa_tool_frame, "grid_iiwa", "iiwa_tool_frame");
    check!(grid_hyq_feet_floating, "grid_hyq", "hyq_feet_floating");
}

/// Four states in one `Lanes<4>` call of floating HyQ's frame kernels give bit-identical
/// results to four scalar calls (the dispatcher's copy and the portable one).
#[test]
fn frame_kernel_lanes_are_bit_identical_to_scalar_calls() {
    use grid_gen_kernels::scenes::grid_hyq_feet_floating as k;
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_feet_floating");
    let mut rng = Rng(47);
    let st: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> = states(&model, &mut rng)
        .into_iter()
        .take(4)
        .map(|(_, per, qd, u)| (model.q_from_joints(&per, rng.base_pose()), qd, u))
        .collect();
    let q: [k::Lanes<4>; k::NQ] =
        std::array::from_fn(|j| k::Lanes(std::array::from_fn(|l| st[l].0[j])));
    let qd: [k::Lanes<4>; k::NV] =
        std::array::from_fn(|j| k::Lanes(std::array::from_fn(|l| st[l].1[j])));
    let u: [k::Lanes<4>; k::NV] =
        std::array::from_fn(|j| k::Lanes(std::array::from_fn(|l| st[l].2[j])));
    macro_rules! check {
        ($c:path) => {{
            use $c as c;
            let lj = c::frame_jacobian(&q);
            let la = c::frame_acceleration(&q, &qd, &u);
            for (l, s) in st.iter().enumerate() {
                let sq: [f64; k::NQ] = std::array::from_fn(|i| s.0[i]);
                let sqd: [f64; k::NV] = std::array::from_fn(|i| s.1[i]);
                let su: [f64; k::NV] = std::array::from_fn(|i| s.2[i]);
                let (j, a) = (c::frame_jacobian(&sq), c::frame_acceleration(&sq, &sqd, &su));
                let lanes_j: Vec<u64> =
                    lj.as_flattened().as_flattened().iter().map(|x| x.0[l].to_bits()).collect();
                let lanes_a: Vec<u64> =
                    la.as_flattened().iter().map(|x| x.0[l].to_bits()).collect();
                assert_eq!(
                    lanes_j,
                    j.as_flattened().as_flattened().iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    "lane {l}: jacobian"
                );
                assert_eq!(
                    lanes_a,
                    a.as_flattened().iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                    "lane {l}: acceleration"
                );
            }
        }};
    }
    check!(k);
    check!(k::portable);
}

/// The checked-in step kernels (`generated/scenes/grid_hyq.hyq_step_floating/`: floating
/// HyQ, semi-implicit Euler, 10 ms), both copies, f64 and f32, against the reference step
/// and `[A | B]` (held to Pinocchio's compositions by grid-gen's tests/step.rs), each state
/// with a random base pose and the twelve leg torques. Tolerances: f64 1e-12 as every
/// kernel; f32 F32_MINV (B is dt M⁻¹ and A holds dt ∂q̈/∂x, through M⁻¹ as `fd_grad`).
#[test]
fn step_kernels_match_the_reference() {
    use grid_gen::ir::KernelKind::*;
    use grid_gen_kernels::scenes::grid_hyq_step_floating as k;
    use grid_gen_test_support::{col, reference_outputs};
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_step_floating");
    assert_eq!((k::NU, k::DT, k::STEP_SCHEME), (model.nu(), 0.01, "semi_implicit_euler"));
    let mut rng = Rng(59);
    let mut worst = [0.0f64; 2];
    macro_rules! run {
        ($c:path, $t:ty, $q:expr, $qd:expr, $u:expr) => {{
            use $c as c;
            let q: [$t; k::NQ] = std::array::from_fn(|i| $q[i] as $t);
            let qd: [$t; k::NV] = std::array::from_fn(|i| $qd[i] as $t);
            let u: [$t; k::NU] = std::array::from_fn(|i| $u[i] as $t);
            #[allow(unused_unsafe)]
            let ((q1, v1), (q2, v2, a, b)) =
                unsafe { (c::step(&q, &qd, &u), c::step_grad(&q, &qd, &u)) };
            let f = |x: &[$t]| x.iter().map(|&y| y as f64).collect::<Vec<f64>>();
            // step's q̈ is ABA's; step_grad's may come from M's factorisation (its `solve`).
            vec![f(&q2), f(&v2), f(a.as_flattened()), f(b.as_flattened()), f(&q1), f(&v1)]
        }};
    }
    for (label, per_joint, qd, _) in states(&model, &mut rng) {
        let q = model.q_from_joints(&per_joint, rng.base_pose());
        let u = rng.vec(k::NU, -20.0, 20.0);
        for (f32, tol) in [(false, F64_TOL), (true, F32_MINV)] {
            let r = |v: &[f64]| -> Vec<f64> {
                v.iter().map(|&x| if f32 { x as f32 as f64 } else { x }).collect()
            };
            let (q, qd, u) = (r(&q), r(&qd), r(&u));
            let want = reference_outputs(StepGrad, &model, &q, &qd, &u, model_gravity());
            let mut copies = vec![(
                "portable",
                if f32 {
                    run!(k::portable, f32, q, qd, u)
                } else {
                    run!(k::portable, f64, q, qd, u)
                },
            )];
            if fma_runs() {
                copies.push((
                    "fma",
                    if f32 { run!(k::fma, f32, q, qd, u) } else { run!(k::fma, f64, q, qd, u) },
                ));
            }
            for (copy, got) in copies {
                for (i, name) in ["q_next", "qd_next", "A", "B", "step q_next", "step qd_next"]
                    .iter()
                    .enumerate()
                {
                    let want = col(want[i % 4].transpose().as_slice());
                    let e = rel(&col(&got[i]), &want);
                    worst[usize::from(f32)] = worst[usize::from(f32)].max(e);
                    assert!(
                        e <= tol,
                        "{label} ({copy}, f32 {f32}): {name} relative error {e:.2e} > {tol:e}"
                    );
                }
            }
        }
    }
    println!("hyq_step_floating: worst relative error f64 {:.2e}, f32 {:.2e}", worst[0], worst[1]);
}

fn model_gravity() -> [f64; 3] {
    reference::DEFAULT_GRAVITY
}

/// The checked-in force kernels (`generated/scenes/grid_hyq.hyq_contacts_floating/`:
/// floating HyQ, fext on all thirteen bodies, four point contacts), both copies, f64 and
/// f32, against the reference under the same forces (held to Pinocchio by grid-gen's
/// tests/forces.rs): rnea, rnea_grad with d/dfext and d/dlambda, fd, fd_grad likewise.
/// Tolerances: f64 1e-12; f32 F32_DIRECT for the RNEA pair, F32_MINV through M⁻¹.
#[test]
fn force_kernels_match_the_reference() {
    use grid_gen::ir::KernelKind::*;
    use grid_gen_kernels::scenes::grid_hyq_contacts_floating as k;
    use grid_gen_test_support::{col, reference_outputs_with};
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_contacts_floating");
    assert_eq!((k::NFEXT, k::NLAMBDA), (13, 12));
    assert_eq!(k::CONTACTS[0], ("lf_lowerleg", "point"));
    let mut rng = Rng(71);
    let mut worst = [0.0f64; 2];
    macro_rules! run {
        ($c:path, $t:ty, $q:expr, $qd:expr, $u:expr, $f:expr, $l:expr) => {{
            use $c as c;
            let q: [$t; k::NQ] = std::array::from_fn(|i| $q[i] as $t);
            let qd: [$t; k::NV] = std::array::from_fn(|i| $qd[i] as $t);
            let u: [$t; k::NV] = std::array::from_fn(|i| $u[i] as $t);
            let f: [$t; 6 * k::NFEXT] = std::array::from_fn(|i| $f[i] as $t);
            let l: [$t; k::NLAMBDA] = std::array::from_fn(|i| $l[i] as $t);
            #[allow(unused_unsafe)]
            let (c0, (dq, dqd, df, dl), a, (a0, aq, aqd, af, al)) = unsafe {
                (
                    c::rnea(&q, &qd, &u, &f, &l),
                    c::rnea_grad(&q, &qd, &u, &f, &l),
                    c::fd(&q, &qd, &u, &f, &l),
                    c::fd_grad(&q, &qd, &u, &f, &l),
                )
            };
            let g = |x: &[$t]| x.iter().map(|&y| y as f64).collect::<Vec<f64>>();
            vec![
                vec![g(&c0)],
                vec![
                    g(dq.as_flattened()),
                    g(dqd.as_flattened()),
                    g(df.as_flattened()),
                    g(dl.as_flattened()),
                ],
                vec![g(&a)],
                vec![
                    g(&a0),
                    g(aq.as_flattened()),
                    g(aqd.as_flattened()),
                    g(af.as_flattened()),
                    g(al.as_flattened()),
                ],
            ]
        }};
    }
    for (label, per_joint, qd, qdd) in states(&model, &mut rng) {
        let q = model.q_from_joints(&per_joint, rng.base_pose());
        let (fext, lambda) =
            (rng.vec(6 * k::NFEXT, -20.0, 20.0), rng.vec(k::NLAMBDA, -100.0, 100.0));
        for (f32, direct, through) in [(false, F64_TOL, F64_TOL), (true, F32_DIRECT, F32_MINV)] {
            let r = |v: &[f64]| -> Vec<f64> {
                v.iter().map(|&x| if f32 { x as f32 as f64 } else { x }).collect()
            };
            let (q, qd, qdd, fext, lambda) = (r(&q), r(&qd), r(&qdd), r(&fext), r(&lambda));
            let ext = reference::External { fext: &fext, lambda: &lambda };
            let want: Vec<Vec<nalgebra::DMatrix<f64>>> = [Rnea, RneaGrad, Fd, FdGrad]
                .iter()
                .map(|&kind| {
                    reference_outputs_with(kind, &model, &q, &qd, &qdd, model_gravity(), ext)
                })
                .collect();
            let mut copies = vec![(
                "portable",
                if f32 {
                    run!(k::portable, f32, q, qd, qdd, fext, lambda)
                } else {
                    run!(k::portable, f64, q, qd, qdd, fext, lambda)
                },
            )];
            if fma_runs() {
                copies.push((
                    "fma",
                    if f32 {
                        run!(k::fma, f32, q, qd, qdd, fext, lambda)
                    } else {
                        run!(k::fma, f64, q, qd, qdd, fext, lambda)
                    },
                ));
            }
            for (copy, got) in copies {
                for (kernel, (got, want)) in got.iter().zip(&want).enumerate() {
                    let tol = if kernel < 2 { direct } else { through };
                    assert_eq!(got.len(), want.len());
                    for (o, (got, want)) in got.iter().zip(want).enumerate() {
                        let e = rel(&col(got), &col(want.transpose().as_slice()));
                        worst[usize::from(f32)] = worst[usize::from(f32)].max(e);
                        assert!(e <= tol, "{label} ({copy}, f32 {f32}): kernel {kernel} output {o} relative error {e:.2e} > {tol:e}");
                    }
                }
            }
        }
    }
    println!(
        "hyq_contacts_floating: worst relative error f64 {:.2e}, f32 {:.2e}",
        worst[0], worst[1]
    );
}

/// The checked-in contact kernels (`generated/scenes/grid_hyq.hyq_standing_floating/`:
/// floating HyQ on its four lower legs as rigid point contacts), both copies, f64 and f32,
/// against the reference's full KKT solution (held to Pinocchio's `constraintDynamics` and
/// `computeConstraintDynamicsDerivatives` by grid-gen's tests/forces.rs).
/// Tolerances: f64 CONTACT_F64 and f32 CONTACT_F32 (see there).
#[test]
fn contact_kernels_match_the_reference() {
    use grid_gen::ir::KernelKind::*;
    use grid_gen_kernels::scenes::grid_hyq_standing_floating as k;
    use grid_gen_test_support::{col, reference_outputs_with};
    // Through K = J M⁻¹ Jᵀ as well as M⁻¹: the contacts' conditioning (J's smallest
    // singular value down to 6e-3 of its largest on these states, squared in K) costs
    // digits over fd_grad's bounds. Measured: f64 1.3e-12, f32 4.9e-4.
    const CONTACT_F64: f64 = 5e-12;
    const CONTACT_F32: f64 = 2e-3;
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_standing_floating");
    assert_eq!(k::NLAMBDA, 12);
    assert_eq!(k::CONTACTS[3], ("rh_lowerleg", "point"));
    let mut rng = Rng(72);
    let mut worst = [0.0f64; 2];
    macro_rules! run {
        ($c:path, $t:ty, $q:expr, $qd:expr, $u:expr) => {{
            use $c as c;
            let q: [$t; k::NQ] = std::array::from_fn(|i| $q[i] as $t);
            let qd: [$t; k::NV] = std::array::from_fn(|i| $qd[i] as $t);
            let u: [$t; k::NV] = std::array::from_fn(|i| $u[i] as $t);
            #[allow(unused_unsafe)]
            let ((a, l), (a1, l1, aq, aqd, at, lq, lqd, lt)) =
                unsafe { (c::contact_fd(&q, &qd, &u), c::contact_fd_grad(&q, &qd, &u)) };
            let g = |x: &[$t]| x.iter().map(|&y| y as f64).collect::<Vec<f64>>();
            vec![
                vec![g(&a), g(&l)],
                vec![
                    g(&a1),
                    g(&l1),
                    g(aq.as_flattened()),
                    g(aqd.as_flattened()),
                    g(at.as_flattened()),
                    g(lq.as_flattened()),
                    g(lqd.as_flattened()),
                    g(lt.as_flattened()),
                ],
            ]
        }};
    }
    let mut singular = Vec::new();
    for (label, per_joint, qd, tau) in states(&model, &mut rng) {
        let q = model.q_from_joints(&per_joint, rng.base_pose());
        let tau: Vec<f64> = tau.iter().map(|t| 10.0 * t).collect();
        // Where the contacts' Jacobian loses rank (legs straight at the zero state), λ has
        // no unique value: such states are counted, not compared.
        let sv = reference::contact_jacobian(&model, &model.specialisation.contacts, &q)
            .singular_values();
        if sv.min() < 1e-8 * sv.max() {
            singular.push(label);
            continue;
        }
        for (f32, tol) in [(false, CONTACT_F64), (true, CONTACT_F32)] {
            let r = |v: &[f64]| -> Vec<f64> {
                v.iter().map(|&x| if f32 { x as f32 as f64 } else { x }).collect()
            };
            let (q, qd, tau) = (r(&q), r(&qd), r(&tau));
            let want: Vec<Vec<nalgebra::DMatrix<f64>>> = [ContactFd, ContactFdGrad]
                .iter()
                .map(|&kind| {
                    reference_outputs_with(
                        kind,
                        &model,
                        &q,
                        &qd,
                        &tau,
                        model_gravity(),
                        reference::External::NONE,
                    )
                })
                .collect();
            let mut copies = vec![(
                "portable",
                if f32 {
                    run!(k::portable, f32, q, qd, tau)
                } else {
                    run!(k::portable, f64, q, qd, tau)
                },
            )];
            if fma_runs() {
                copies.push((
                    "fma",
                    if f32 { run!(k::fma, f32, q, qd, tau) } else { run!(k::fma, f64, q, qd, tau) },
                ));
            }
            for (copy, got) in copies {
                for (kernel, (got, want)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(got.len(), want.len());
                    for (o, (got, want)) in got.iter().zip(want).enumerate() {
                        let e = rel(&col(got), &col(want.transpose().as_slice()));
                        worst[usize::from(f32)] = worst[usize::from(f32)].max(e);
                        assert!(e <= tol, "{label} ({copy}, f32 {f32}): kernel {kernel} output {o} relative error {e:.2e} > {tol:e}");
                    }
                }
            }
        }
    }
    assert_eq!(singular, ["zero"], "only the zero state is singular");
    println!(
        "hyq_standing_floating: worst relative error f64 {:.2e}, f32 {:.2e}",
        worst[0], worst[1]
    );
}

/// The portable copy of the checked-in contact kernels runs `contact_fd_grad`'s
/// combination as loops over the columns (the IR's `ColumnProgram`) where the graph has it
/// straight-line: the same products, but each row's terms subtracted one by one where the
/// graph sums a dot product first, so the two round differently, and K⁻¹ (the contacts'
/// conditioning) carries that into λ and q̈. Held to the graph (what `grid-gen accuracy`
/// interprets) at 1e-13 in f64 and 5e-5 in f32, about 17 times the differences measured
/// (6e-15, 3e-6: tens of ε), far inside the kernels' bounds against the reference.
#[test]
fn the_portable_contact_loops_round_as_the_graph_does() {
    use grid_gen::ir::KernelKind::*;
    use grid_gen_kernels::scenes::grid_hyq_standing_floating as k;
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_standing_floating");
    let module = grid_gen::ir::lower(
        &model,
        model_gravity(),
        &grid_gen::ir::LowerOptions { kernels: vec![ContactFdGrad], ..Default::default() },
    )
    .unwrap();
    let f = &module.functions[0];
    assert!(f.program.is_some(), "the combination is a column program");
    let mut rng = Rng(73);
    let mut compared = 0;
    let mut worst = [0.0f64; 2];
    // The first state is the zero state, where these contacts are singular.
    for (label, per_joint, qd, tau) in states(&model, &mut rng).into_iter().skip(1).take(3) {
        let q = model.q_from_joints(&per_joint, rng.base_pose());
        let args = grid_gen_test_support::kernel_args(f.inputs(), &q, &qd, &tau);
        let want64: Vec<f64> = f.eval(&args).concat();
        let want32: Vec<f64> = f.eval_f32(&args).concat().into_iter().map(f64::from).collect();
        macro_rules! got {
            ($t:ty) => {{
                let q: [$t; k::NQ] = std::array::from_fn(|i| q[i] as $t);
                let qd: [$t; k::NV] = std::array::from_fn(|i| qd[i] as $t);
                let u: [$t; k::NV] = std::array::from_fn(|i| tau[i] as $t);
                let (a, l, aq, aqd, at, lq, lqd, lt) = k::portable::contact_fd_grad(&q, &qd, &u);
                [
                    &a[..],
                    &l,
                    aq.as_flattened(),
                    aqd.as_flattened(),
                    at.as_flattened(),
                    lq.as_flattened(),
                    lqd.as_flattened(),
                    lt.as_flattened(),
                ]
                .concat()
                .into_iter()
                .map(f64::from)
                .collect::<Vec<f64>>()
            }};
        }
        for (at, (t, got, want, bound)) in
            [("f64", got!(f64), want64, 1e-13), ("f32", got!(f32), want32, 5e-5)]
                .into_iter()
                .enumerate()
        {
            assert_eq!(got.len(), want.len(), "{label} {t}: values");
            let e = rel(&grid_gen_test_support::col(&got), &grid_gen_test_support::col(&want));
            assert!(e <= bound, "{label} {t}: {e:.2e} from the graph (bound {bound:e})");
            worst[at] = worst[at].max(e);
            compared += got.len();
        }
    }
    assert!(compared > 0);
    println!(
        "portable contact loops against the graph: f64 {:.2e}, f32 {:.2e}",
        worst[0], worst[1]
    );
}

/// HyQ with `round_angles = 1e-11` (`generated/scenes/grid_hyq.hyq_round_angles/` and its
/// floating twin): rnea_grad and fd_grad against the reference on the rounded model at
/// F64_TOL, and how far the rounding moves them from the literal file's reference. The
/// twelve angles move by at most 4.9e-12 rad, so the outputs move by that times how
/// sensitive they are to the geometry (measured at most 2.1e-11, 4.4 times the angle, on
/// these states). ROUNDED_TOL is the agreement with Pinocchio the project promises
/// (1e-10 relative): the rounded kernels must still keep it against the literal file.
/// At least one output must differ by more than F64_TOL (the rounding reached the
/// kernels).
#[test]
fn rounded_angle_kernels_match_the_rounded_reference_and_stay_near_the_literal() {
    const ROUNDED_TOL: f64 = 1e-10;
    macro_rules! check {
        ($m:ident, $scene:literal, $literal:literal) => {{
            use grid_gen_kernels::scenes::$m as k;
            let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", $scene);
            let literal = match $literal {
                "" => load("grid_hyq"),
                s => grid_gen_test_support::load_in_scene("grid_hyq", s).0,
            };
            let r = model.rounded_angles.expect("the scene rounds");
            assert_eq!((r.count, literal.rounded_angles), (12, None));
            assert!(k::NV == model.nv() && k::NQ == model.nq());
            let mut rng = Rng(31);
            let (mut moved, mut worst) = (0.0f64, 0.0f64);
            for (label, per_joint, qd, u) in states(&model, &mut rng) {
                let q = match model.floating {
                    true => model.q_from_joints(&per_joint, rng.base_pose()),
                    false => per_joint,
                };
                let nq = |v: &[f64]| -> [f64; k::NQ] { std::array::from_fn(|i| v[i]) };
                let nv = |v: &[f64]| -> [f64; k::NV] { std::array::from_fn(|i| v[i]) };
                let m = |x: [[f64; k::NV]; k::NV]| DMatrix::from_fn(k::NV, k::NV, |i, j| x[i][j]);
                let (dq, dqd) = k::rnea_grad(&nq(&q), &nv(&qd), &nv(&u));
                let (qdd, fq, fqd) = k::fd_grad(&nq(&q), &nv(&qd), &nv(&u));
                let got = [
                    (1, m(dq)),
                    (2, m(dqd)),
                    (6, DMatrix::from_column_slice(k::NV, 1, &qdd)),
                    (7, m(fq)),
                    (8, m(fqd)),
                ];
                let want = reference_outputs(&model, &q, &qd, &u);
                let far = reference_outputs(&literal, &q, &qd, &u);
                for (i, g) in got {
                    let (e, d) = (rel(&g, &want[i]), rel(&g, &far[i]));
                    assert!(
                        e <= F64_TOL,
                        "{} {label}: {} relative error {e:.2e}",
                        $scene,
                        NAMES[i]
                    );
                    assert!(
                        d <= ROUNDED_TOL,
                        "{} {label}: {} {d:.2e} from the literal file's",
                        $scene,
                        NAMES[i]
                    );
                    (moved, worst) = (moved.max(d), worst.max(d));
                }
            }
            assert!(moved > F64_TOL, "{}: the rounding changed nothing ({moved:.2e})", $scene);
            eprintln!("{}: at most {worst:.2e} relative from the literal file's reference", $scene);
        }};
    }
    check!(grid_hyq_round_angles, "hyq_round_angles", "");
    check!(grid_hyq_floating_round_angles, "hyq_floating_round_angles", "hyq_floating");
}

/// `{kernel}_into` overwrites every entry of its outputs: filled with NaN beforehand, they
/// hold bit for bit what the returning kernel gives (the dispatcher's copy, so the `avx512`
/// or `fma` copy where the CPU runs it, else the portable one). iiwa's kernels in f64 and
/// f32, and floating HyQ standing on its feet's contact kernels, whose outputs have
/// structural zeros that the kernels never store.
#[test]
fn into_kernels_overwrite_their_outputs_as_the_returning_ones_give_them() {
    fn same<T: Copy + Into<f64>>(label: &str, into: &[T], returned: &[T]) {
        assert_eq!(into.len(), returned.len());
        for (i, (&a, &b)) in into.iter().zip(returned).enumerate() {
            let (a, b): (f64, f64) = (a.into(), b.into());
            assert_eq!(a.to_bits(), b.to_bits(), "{label}: entry {i}, into {a}, returned {b}");
        }
    }
    let mut rng = Rng(91);
    let model = load("grid_iiwa");
    macro_rules! iiwa {
        ($t:ty) => {{
            use grid_gen_kernels::grid_iiwa as k;
            for (_, q, qd, u) in states(&model, &mut rng).into_iter().take(4) {
                let a = |v: &[f64]| -> [$t; k::NV] { std::array::from_fn(|i| v[i] as $t) };
                let (q, qd, u) = (a(&q), a(&qd), a(&u));
                let nan = <$t>::NAN;
                let (mut v, mut m1, mut m2) =
                    ([nan; k::NV], [[nan; k::NV]; k::NV], [[nan; k::NV]; k::NV]);
                k::rnea_into(&q, &qd, &u, &mut v);
                same("rnea", &v, &k::rnea(&q, &qd, &u));
                k::rnea_grad_into(&q, &qd, &u, &mut m1, &mut m2);
                let (dq, dqd) = k::rnea_grad(&q, &qd, &u);
                same("rnea_grad dq", m1.as_flattened(), dq.as_flattened());
                same("rnea_grad dqd", m2.as_flattened(), dqd.as_flattened());
                (m1, m2, v) = ([[nan; k::NV]; k::NV], [[nan; k::NV]; k::NV], [nan; k::NV]);
                k::mass_matrix_into(&q, &mut m1);
                same("mass_matrix", m1.as_flattened(), k::mass_matrix(&q).as_flattened());
                k::minv_into(&q, &mut m2);
                same("minv", m2.as_flattened(), k::minv(&q).as_flattened());
                k::fd_into(&q, &qd, &u, &mut v);
                same("fd", &v, &k::fd(&q, &qd, &u));
                (m1, m2, v) = ([[nan; k::NV]; k::NV], [[nan; k::NV]; k::NV], [nan; k::NV]);
                k::fd_grad_into(&q, &qd, &u, &mut v, &mut m1, &mut m2);
                let (qdd, fq, fqd) = k::fd_grad(&q, &qd, &u);
                same("fd_grad qdd", &v, &qdd);
                same("fd_grad dq", m1.as_flattened(), fq.as_flattened());
                same("fd_grad dqd", m2.as_flattened(), fqd.as_flattened());
            }
        }};
    }
    iiwa!(f64);
    iiwa!(f32);
    use grid_gen_kernels::scenes::grid_hyq_standing_floating as k;
    let (model, _) = grid_gen_test_support::load_in_scene("grid_hyq", "hyq_standing_floating");
    let mut stood = 0;
    for (_, per_joint, qd, tau) in states(&model, &mut rng) {
        let q = model.q_from_joints(&per_joint, rng.base_pose());
        let q: [f64; k::NQ] = std::array::from_fn(|i| q[i]);
        let qd: [f64; k::NV] = std::array::from_fn(|i| qd[i]);
        let u: [f64; k::NV] = std::array::from_fn(|i| 10.0 * tau[i]);
        let n = f64::NAN;
        let (mut a, mut l) = ([n; k::NV], [n; k::NLAMBDA]);
        k::contact_fd_into(&q, &qd, &u, &mut a, &mut l);
        let (ra, rl) = k::contact_fd(&q, &qd, &u);
        same("contact_fd qdd", &a, &ra);
        same("contact_fd lambda", &l, &rl);
        let (mut a, mut l) = ([n; k::NV], [n; k::NLAMBDA]);
        let (mut aq, mut aqd, mut at) =
            ([[n; k::NV]; k::NV], [[n; k::NV]; k::NV], [[n; k::NV]; k::NV]);
        let (mut lq, mut lqd, mut lt) =
            ([[n; k::NV]; k::NLAMBDA], [[n; k::NV]; k::NLAMBDA], [[n; k::NV]; k::NLAMBDA]);
        k::contact_fd_grad_into(
            &q, &qd, &u, &mut a, &mut l, &mut aq, &mut aqd, &mut at, &mut lq, &mut lqd, &mut lt,
        );
        let r = k::contact_fd_grad(&q, &qd, &u);
        same("contact_fd_grad qdd", &a, &r.0);
        same("contact_fd_grad lambda", &l, &r.1);
        for (name, into, returned) in [
            ("dqdd_dq", aq.as_flattened(), r.2.as_flattened()),
            ("dqdd_dqd", aqd.as_flattened(), r.3.as_flattened()),
            ("dqdd_dtau", at.as_flattened(), r.4.as_flattened()),
            ("dlambda_dq", lq.as_flattened(), r.5.as_flattened()),
            ("dlambda_dqd", lqd.as_flattened(), r.6.as_flattened()),
            ("dlambda_dtau", lt.as_flattened(), r.7.as_flattened()),
        ] {
            same(&format!("contact_fd_grad {name}"), into, returned);
        }
        stood += 1;
    }
    assert!(stood >= 4, "{stood} states");
}
