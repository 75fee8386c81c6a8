//! Floating base, beyond the Pinocchio comparison in tests/pinocchio.rs:
//! the three ways to ask for one agree, what cannot be a floating base is a located error,
//! `eval` checks q's length and the quaternion, a slightly non-unit quaternion is
//! normalised, and the base's position does not enter the dynamics.

use grid_gen::eval::{evaluate, parse_states, EvalError};
use grid_gen::{reference, Model, Scene};
use grid_gen_test_support::*;

fn hyq_text() -> String {
    std::fs::read_to_string(repo().join("robots/grid_hyq.urdf")).unwrap()
}

/// HyQ's URDF with a `world` link and a floating joint `float` to its root link.
fn hyq_with_floating_joint(origin: &str) -> String {
    hyq_text().replacen(
        "<link name=\"base_link_0\">",
        &format!("<link name=\"world\"/><joint name=\"float\" type=\"floating\"><parent link=\"world\"/><child link=\"base_link_0\"/>{origin}</joint><link name=\"base_link_0\">"),
        1,
    )
}

fn errors(text: &str, scene: &Scene) -> String {
    match Model::from_urdf_str_in_scene("robot.urdf", text, false, scene, "scene.toml") {
        Ok(_) => panic!("loaded"),
        Err(e) => e.render_plain(),
    }
}

#[test]
fn a_urdf_floating_joint_is_the_floating_base_flag() {
    let flag = load_floating("grid_hyq");
    let (joint, _) = Model::from_urdf_str("hyq.urdf", &hyq_with_floating_joint(""), false).unwrap();
    assert!(joint.floating && joint.nv() == flag.nv() && joint.nq() == 19);
    assert_eq!(flag.joints[0].name, "root_joint_vx");
    assert_eq!(joint.joints[5].name, "float_wz");
    let mut rng = Rng(5);
    let g = reference::DEFAULT_GRAVITY;
    for _ in 0..5 {
        let q = flag.q_from_joints(&rng.vec(18, -3.0, 3.0), rng.base_pose());
        let (qd, qdd) = (rng.vec(18, -2.0, 2.0), rng.vec(18, -2.0, 2.0));
        // The same computation on the same model: identical to the bit.
        assert_eq!(
            reference::rnea_derivatives(&flag, &q, &qd, &qdd, g),
            reference::rnea_derivatives(&joint, &q, &qd, &qdd, g)
        );
        assert_eq!(reference::crba(&flag, &q), reference::crba(&joint, &q));
    }
    // A joint origin places the free-flyer's reference frame: the base pose q is then
    // relative to it, so with the origin rotated by 90° about x, gravity in the base frame
    // is that of the base rotated by the same amount under the plain flag.
    let (rotated, _) = Model::from_urdf_str(
        "hyq.urdf",
        &hyq_with_floating_joint(r#"<origin xyz="1 2 3" rpy="1.5707963267948966 0 0"/>"#),
        false,
    )
    .unwrap();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let (ident, turned) = ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, s, 0.0, 0.0, s]);
    let joints = rng.vec(18, -3.0, 3.0);
    let zero = vec![0.0; 18];
    let a = reference::rnea(&rotated, &rotated.q_from_joints(&joints, ident), &zero, &zero, g);
    let b = reference::rnea(&flag, &flag.q_from_joints(&joints, turned), &zero, &zero, g);
    assert!(rel_err(&col(&a), &col(&b)) < 1e-14, "{a:?} vs {b:?}");
}

#[test]
fn what_cannot_be_a_floating_base_is_a_located_error() {
    let none = Scene::default();
    // Below the root link.
    let deep = hyq_text().replacen(
        "<link name=\"lf_hipassembly\">",
        "<link name=\"extra\"/><joint name=\"deep\" type=\"floating\"><parent link=\"lf_hipassembly\"/><child link=\"extra\"/></joint><link name=\"lf_hipassembly\">",
        1,
    );
    let e = errors(&deep, &none);
    assert!(
        e.contains("floating joint `deep` is not supported here")
            && e.contains("only the root link can carry a floating joint"),
        "{e}"
    );
    // A floating joint and --floating-base.
    let both = Scene { floating_base: true, ..Scene::default() };
    let e = errors(&hyq_with_floating_joint(""), &both);
    assert!(e.contains("floating joint `float`") && e.contains("at most one floating base"), "{e}");
    // Locking one.
    let lock =
        Scene { lock: [("float".to_string(), 0.0)].into_iter().collect(), ..Scene::default() };
    let e = errors(&hyq_with_floating_joint(""), &lock);
    assert!(e.contains("[lock] names floating joint `float`"), "{e}");
}

#[test]
fn eval_checks_the_length_and_the_quaternion() {
    let model = load_floating("grid_hyq");
    let g = reference::DEFAULT_GRAVITY;
    let state = |q: &[f64]| {
        format!(
            r#"{{"states": [{{"q": {q:?}, "qd": {:?}, "qdd": {:?}}}]}}"#,
            vec![0.5; 18],
            vec![0.1; 18]
        )
    };
    let mut q = model.q_from_joints(&[0.3; 18], [0.1, 0.2, 0.3, 0.5, 0.5, 0.5, 0.5]);
    let out = evaluate(&model, &parse_states(&state(&q)).unwrap(), g).unwrap();
    assert_eq!(
        out.states[0].rnea.as_ref().unwrap(),
        &reference::rnea(&model, &q, &[0.5; 18], &[0.1; 18], g)
    );
    // nv entries instead of nq.
    let e = evaluate(&model, &parse_states(&state(&q[..18])).unwrap(), g).unwrap_err();
    assert!(
        matches!(e, EvalError::FloatingLength { index: 0, field: "q", found: 18, expected: 19 }),
        "{e}"
    );
    assert!(e.to_string().contains("[x, y, z, qx, qy, qz, qw]"), "{e}");
    // A quaternion far from unit (here: all zero, a missing orientation) is refused...
    let mut zero = q.clone();
    zero[3..7].copy_from_slice(&[0.0; 4]);
    let e = evaluate(&model, &parse_states(&state(&zero)).unwrap(), g).unwrap_err();
    assert!(matches!(e, EvalError::Quaternion { index: 0, .. }), "{e}");
    // ... a slightly non-unit one (within 1e-3) is used normalised: the same dynamics as
    // the unit quaternion, to rounding.
    let unit = reference::rnea(&model, &q, &[0.5; 18], &[0.1; 18], g);
    for x in &mut q[3..7] {
        *x *= 1.0 + 9e-4;
    }
    let out = evaluate(&model, &parse_states(&state(&q)).unwrap(), g).unwrap();
    let scaled = out.states[0].rnea.as_ref().unwrap();
    assert!(rel_err(&col(scaled), &col(&unit)) < 1e-14, "{scaled:?} vs {unit:?}");
}

/// Gravity is uniform: moving the base changes nothing, and no kernel reads x, y, z.
#[test]
fn the_base_position_does_not_enter() {
    use grid_gen::ir::{self, Input, LowerOptions, Op};
    let model = load_floating("grid_iiwa");
    let mut rng = Rng(9);
    let joints = rng.vec(model.nv(), -3.0, 3.0);
    let [_, _, _, qx, qy, qz, qw] = rng.base_pose();
    let g = reference::DEFAULT_GRAVITY;
    let (qd, qdd) = (rng.vec(model.nv(), -1.0, 1.0), rng.vec(model.nv(), -1.0, 1.0));
    let here = reference::rnea_derivatives(
        &model,
        &model.q_from_joints(&joints, [0.0, 0.0, 0.0, qx, qy, qz, qw]),
        &qd,
        &qdd,
        g,
    );
    let there = reference::rnea_derivatives(
        &model,
        &model.q_from_joints(&joints, [5.0, -7.0, 100.0, qx, qy, qz, qw]),
        &qd,
        &qdd,
        g,
    );
    assert_eq!(here, there);
    let module = ir::lower(&model, g, &LowerOptions::default()).unwrap();
    // The Lie-group kernels move the position; they are not dynamics.
    for f in module.functions.iter().filter(|f| !f.kind.is_lie()) {
        assert!(
            f.nodes.iter().all(|n| !matches!(n.op, Op::Input(Input::Q, 0..=2))),
            "{} reads the base position",
            f.kind.name()
        );
    }
}

/// A floating base large enough (floating Atlas) has `fd_grad`'s per-column LTDL solves run
/// as loops over the columns, in every copy of the Rust module (`PROGRAM_MIN_OPS` in
/// `back/rust`: the IR records the program, the backend chooses); floating HyQ's, which
/// fit the instruction cache, stay straight-line. Both copies (the `fma` one where the CPU has AVX2 and FMA), compiled by
/// rustc and run on three states, against the reference at 1e-12 (the f64 kernels' bound
/// everywhere), and the portable copy against the IR's graph, value for value.
#[test]
fn large_floating_fd_grad_solves_run_as_column_loops() {
    use grid_gen::generate::{generate, Options, Target};
    use grid_gen::ir::{self, KernelKind, LowerOptions};
    let lower = LowerOptions { kernels: vec![KernelKind::FdGrad], ..LowerOptions::default() };
    let g = reference::DEFAULT_GRAVITY;
    let hyq = load_floating("grid_hyq");
    let options =
        Options { targets: vec![Target::Rust], lower: lower.clone(), ..Options::default() };
    let hyq_text = generate(&hyq, &options).unwrap().remove(0).contents;
    let program = ir::lower(&hyq, g, &lower).unwrap().functions[0].program.clone();
    let replaces = program.expect("the IR records the solves' program").replaces;
    assert!(replaces.is_some_and(|n| n < 32_000), "floating HyQ's solves are few: {replaces:?}");
    assert!(!hyq_text.contains("fd_grad_cols0"), "floating HyQ's solves stay straight-line");
    let model = load_floating("grid_atlas");
    let lowered = ir::lower(&model, g, &lower).unwrap();
    let program = lowered.functions[0].program.as_ref().expect("floating Atlas's solves loop");
    // ∂q̈/∂q and ∂q̈/∂q̇, each without the three columns the free-flyer's invariances give.
    let columns: Vec<usize> = program.blocks.iter().map(|b| b.columns()).collect();
    assert_eq!((program.rows, columns), (36, vec![33, 33]));
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    let text = &file.contents;
    assert_program_looped(text, "fd_grad", 2);
    // Three lines from the portable copy, then three from the fma copy where it runs.
    let said = run_fd_grad_copies("floating_atlas_loops", text);
    let (nv, nq) = (model.nv(), model.nq());
    // State k's q̇ and τ, as the program drew them.
    let inputs = |k: usize| -> Vec<Vec<f64>> {
        (1..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect()
    };
    let worst = worst_per_copy(&said, nq, 1e-12, fd_grad_reference(&model, g));
    for (name, worst) in &worst {
        println!("floating Atlas fd_grad, looped solves, {name} copy: worst {worst:.2e} from the reference (bound 1e-12)");
    }
    let lines: Vec<&str> = said.lines().collect();
    if worst.len() == 1 {
        println!("no AVX2 and FMA here: the fma copy's loops are not run");
    }
    // The portable copy's loops are the graph's operations in the graph's order (the
    // solve's steps, one multiplication and one subtraction each): its values are the IR's,
    // equal as numbers (a zero's sign may differ: the graph folds `a − c·0` to `a`).
    let f = &lowered.functions[0];
    for (k, line) in lines[..3].iter().enumerate() {
        let got: Vec<f64> = line.split(' ').map(|x| x.parse().unwrap()).collect();
        let x = inputs(k);
        let want = f.eval(&kernel_args(f.inputs(), &got[..nq], &x[0], &x[1])).concat();
        assert_eq!(got.len() - nq, want.len(), "state {k}: values");
        for (i, (g, w)) in got[nq..].iter().zip(&want).enumerate() {
            assert!(g == w, "state {k}: portable value {i} is {g:e}, the graph's {w:e}");
        }
    }
}

/// The calls and solves [`fd_grad_calls_fd_and_rnea_grad_when_asked`] and
/// [`contact_fd_grad_calls_contact_fd_and_rnea_grad_when_asked`] run: each call under M's
/// factorisation with q̈ by ABA (`ltdl`) and with q̈ from the factorisation (`crba`, a
/// floating humanoid's route since 2026-11-30).
const ROUTES: [(grid_gen::ir::Calls, grid_gen::ir::Solve); 4] = {
    use grid_gen::ir::{Calls, Solve};
    [
        (Calls::All, Solve::Ltdl),
        (Calls::RneaGrad, Solve::Ltdl),
        (Calls::All, Solve::Crba),
        (Calls::RneaGrad, Solve::Crba),
    ]
};

/// With `calls = all`, an `fd_grad` that factorises M calls `fd` and `rnea_grad` and
/// keeps the rest ([`grid_gen::ir::Call`]); with `calls = rnea_grad` it computes q̈
/// itself and calls `rnea_grad` there, between its parts: a floating 14-link chain with
/// each solve of [`ROUTES`]. The rest fed the callees' values gives the whole graph's
/// (two roundings of the same operations, 1e-12 as every f64 bound); the module, compiled
/// by rustc and run on three states in both copies, gives the reference's at 1e-12; the
/// default (`auto`) keeps `fd_grad` whole.
#[test]
fn fd_grad_calls_fd_and_rnea_grad_when_asked() {
    use grid_gen::generate::{generate, Options, Target};
    use grid_gen::ir::{self, Calls, KernelKind, LowerOptions};
    let model = floating_chain14();
    let g = reference::DEFAULT_GRAVITY;
    let kernels = vec![KernelKind::RneaGrad, KernelKind::Fd, KernelKind::FdGrad];
    let (nv, nq) = (model.nv(), model.nq());
    for (calls, solve) in ROUTES {
        let whole = LowerOptions { kernels: kernels.clone(), solve, ..LowerOptions::default() };
        let by_default = ir::lower(&model, g, &whole).unwrap();
        assert!(by_default.functions.iter().all(|f| f.call.is_none()), "auto keeps it whole");
        let lower = LowerOptions { calls, ..whole.clone() };
        let lowered = ir::lower(&model, g, &lower).unwrap();
        let f = lowered.function(KernelKind::FdGrad).unwrap();
        let call = f.call.as_ref().expect("fd_grad calls");
        let own = calls == Calls::RneaGrad;
        let callees = if own {
            vec![KernelKind::RneaGrad]
        } else {
            vec![KernelKind::Fd, KernelKind::RneaGrad]
        };
        assert_eq!(call.callees, callees);
        assert_eq!(call.ahead.is_empty(), !own, "only a kernel that computes q̈ splits");
        let mut worst: f64 = 0.0;
        for k in 0..3 {
            let joints: Vec<f64> = (0..nv - 6).map(|i| 2.0 * seeded_state(k, i, 0)).collect();
            let q = model.q_from_joints(&joints, [0.1, -0.2, 0.3, 0.5, -0.5, 0.5, 0.5]);
            let x: Vec<Vec<f64>> =
                (1..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
            let args = kernel_args(f.inputs(), &q, &x[0], &x[1]);
            let all = f.eval(&args);
            // q̈ from `fd`, or the kernel's own (its first output).
            let fd = lowered.function(KernelKind::Fd).unwrap();
            let qdd = if own {
                all[0].clone()
            } else {
                fd.eval(&kernel_args(fd.inputs(), &q, &x[0], &x[1])).remove(0)
            };
            let rg = lowered.function(KernelKind::RneaGrad).unwrap();
            let dc = rg.eval(&kernel_args(rg.inputs(), &q, &x[0], &qdd));
            let mut rest_args = args.clone();
            if !own {
                rest_args.push(&qdd);
            }
            rest_args.extend(dc.iter().map(Vec::as_slice));
            assert_eq!(rest_args.len(), call.rest.inputs().len());
            for (a, b) in all.iter().zip(&call.rest.eval(&rest_args)) {
                worst = worst.max(rel_err(&col(a), &col(b)));
            }
        }
        let name = format!("{}_{}", calls.name(), solve.name());
        assert!(worst < 1e-12, "{name}: rest after its callees: {worst:.2e} from the whole graph");
        println!("calls={name}: fd_grad's rest with its callees' values: worst {worst:.2e} from the whole graph (bound 1e-12)");
        let file =
            generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
                .unwrap()
                .remove(0);
        let text = &file.contents;
        assert_eq!(text.contains("fn fd_grad_rest<"), !own, "a rest of its own unless split");
        if own {
            // It runs rnea_grad's parts around its own, and reads the transforms, velocities
            // and composite inertias that rnea_grad's first parts keep.
            assert!(!call.shared.is_empty(), "the rest reads what rnea_grad computes before q̈");
            assert!(text.contains("rnea_grad_part0(q, qd, &qdd, sc,"), "fd_grad calls rnea_grad");
            assert!(text.contains("sc: &rnea_grad_slots<T>"), "its parts read rnea_grad's slots");
        }
        let said = run_fd_grad_copies(&format!("fd_grad_calls_{name}"), text);
        for (copy_name, worst) in worst_per_copy(&said, nq, 1e-12, fd_grad_reference(&model, g)) {
            println!("calls={name}: floating 14-link chain fd_grad, {copy_name} copy: worst {worst:.2e} from the reference (bound 1e-12)");
        }
    }
}

/// `said` (three states per copy, as [`run_fd_grad_copies`] prints them) split by copy:
/// each copy's name and its worst error against `want` ([`worst_line_error`], q first on
/// each line, every entry within `bound`).
fn worst_per_copy(
    said: &str,
    nq: usize,
    bound: f64,
    mut want: impl FnMut(usize, &[f64]) -> Vec<f64>,
) -> Vec<(&'static str, f64)> {
    let lines: Vec<&str> = said.lines().collect();
    let copies = lines.len() / 3;
    assert!(copies >= 1 && lines.len() == 3 * copies, "three states per copy: {said}");
    ["portable", "fma"]
        .into_iter()
        .take(copies)
        .enumerate()
        .map(|(copy, name)| {
            let mine = lines[3 * copy..3 * copy + 3].join("\n");
            (name, worst_line_error(&mine, 3, nq, bound, &mut want))
        })
        .collect()
}

/// The reference's `fd_grad` of `model` at seeded state k's q̇ and τ and the q a compiled
/// program printed, row-major: what [`run_fd_grad_copies`]' lines hold after q.
fn fd_grad_reference(model: &Model, g: [f64; 3]) -> impl FnMut(usize, &[f64]) -> Vec<f64> + '_ {
    let nv = model.nv();
    move |k, q| {
        let x: Vec<Vec<f64>> =
            (1..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        reference_outputs(grid_gen::ir::KernelKind::FdGrad, model, q, &x[0], &x[1], g)
            .iter()
            .flat_map(|m| m.transpose().as_slice().to_vec())
            .collect()
    }
}

/// Compiles `text` (a floating robot's module) and runs its `fd_grad` on the first three
/// seeded states, normalised quaternion, in the portable copy and in the `fma` copy where
/// the CPU runs it: one line per state and copy, q then the outputs, row-major.
fn run_fd_grad_copies(name: &str, text: &str) -> String {
    compile_and_run(
        name,
        text,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn main() {
    let copies = if has_fma() { 2 } else { 1 };
    for copy in 0..copies {
        for k in 0..3 {
            let mut q: [f64; NQ] = std::array::from_fn(|i| state(k, i, 0));
            let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
            for x in &mut q[3..7] { *x /= n; }
            let x: [[f64; NV]; 2] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s + 1)));
            let (a, aq, av) = if copy == 1 { unsafe { fma::fd_grad(&q, &x[0], &x[1]) } } else { portable::fd_grad(&q, &x[0], &x[1]) };
            let all: Vec<String> = q.iter().chain(&a).chain(aq.as_flattened()).chain(av.as_flattened()).map(|x| format!("{x:?}")).collect();
            println!("{}", all.join(" "));
        }
    }
}
"#,
        ]
        .concat(),
    )
}

/// `CRBA_MAX_DEPTH` (12) counts a free-flyer as one joint: a floating 9-link chain is 10
/// deep, and `fd_grad` and `contact_fd` take q̈ from M's factorisation when it has fewer
/// operations (it does here), as a fixed chain of 10 would, with `calls` set or not (until
/// 2026-12-01 the six coordinates counted under `calls`, whose calls applied only with
/// ABA's q̈); a floating 14-link chain (15 deep) keeps ABA's q̈.
#[test]
fn the_crba_solve_counts_a_free_flyer_as_one_joint() {
    use grid_gen::ir::{self, Calls, KernelKind, LowerOptions, Solve};
    use grid_gen::model::ContactKind;
    let path = std::env::temp_dir().join(format!("grid-gen-chain9-{}.urdf", std::process::id()));
    let body = "<link name=\"l0\"><inertial><mass value=\"2\"/><inertia ixx=\"0.02\" ixy=\"0\" ixz=\"0\" iyy=\"0.02\" iyz=\"0\" izz=\"0.02\"/></inertial></link>";
    std::fs::write(&path, chain_urdf(9).replacen("<link name=\"l0\"/>", body, 1)).unwrap();
    let chain9 = with_forces(&load_urdf(&path, true), &[], &[("l9", ContactKind::Point)]);
    let _ = std::fs::remove_file(&path);
    let chain14 = with_forces(&floating_chain14(), &[], &[("l14", ContactKind::Point)]);
    let g = reference::DEFAULT_GRAVITY;
    let solve = |model: &Model, kind: KernelKind, calls: Calls| {
        let options = LowerOptions { kernels: vec![kind], calls, ..LowerOptions::default() };
        ir::lower_function(model, g, kind, &options).unwrap().solve
    };
    for kind in [KernelKind::FdGrad, KernelKind::ContactFd] {
        assert_eq!(solve(&chain9, kind, Calls::Auto), Some(Solve::Crba), "{kind:?}");
        assert_eq!(solve(&chain9, kind, Calls::RneaGrad), Some(Solve::Crba), "{kind:?}");
        assert_eq!(solve(&chain14, kind, Calls::Auto), Some(Solve::Ltdl), "{kind:?}");
    }
}

/// A 14-link chain on a floating base, deeper than `CRBA_MAX_DEPTH`. The base link carries
/// a body: a free-flyer under the chain's massless l0 would turn it about j1's axis as j1
/// does (a singular M).
fn floating_chain14() -> Model {
    let path = std::env::temp_dir().join(format!("grid-gen-chain14-{}.urdf", std::process::id()));
    let body = "<link name=\"l0\"><inertial><mass value=\"2\"/><inertia ixx=\"0.02\" ixy=\"0\" ixz=\"0\" iyy=\"0.02\" iyz=\"0\" izz=\"0.02\"/></inertial></link>";
    std::fs::write(&path, chain_urdf(14).replacen("<link name=\"l0\"/>", body, 1)).unwrap();
    let model = load_urdf(&path, true);
    let _ = std::fs::remove_file(&path);
    model
}

/// With `calls = all`, `contact_fd_grad` calls `contact_fd` and `rnea_grad` (at its q̈ and
/// λ) and keeps J, K and the columns; with `calls = rnea_grad` it computes q̈ and λ and
/// calls `rnea_grad` there, between its parts: the floating 14-link chain holding its tip (6-D) and
/// its seventh link (a point), each solve of [`ROUTES`]. The rest fed the callees' values gives the
/// whole graph's, and so does the module, compiled and run on three states in both copies
/// (1e-12, two roundings of the same operations; the whole graph is held to Pinocchio by
/// the contact suites).
#[test]
fn contact_fd_grad_calls_contact_fd_and_rnea_grad_when_asked() {
    use grid_gen::generate::{generate, Options, Target};
    use grid_gen::ir::{self, Calls, KernelKind, LowerOptions};
    use grid_gen::model::ContactKind;
    let plain = with_forces(
        &floating_chain14(),
        &[],
        &[("l14", ContactKind::Wrench), ("l7", ContactKind::Point)],
    );
    let g = reference::DEFAULT_GRAVITY;
    // `fd_grad` calls `rnea_grad` too, taking λ as its input where `contact_fd_grad` computes
    // it: what both read of `rnea_grad` must not depend on λ.
    let kernels = vec![
        KernelKind::RneaGrad,
        KernelKind::FdGrad,
        KernelKind::ContactFd,
        KernelKind::ContactFdGrad,
    ];
    let (nv, nq) = (plain.nv(), plain.nq());
    let state = |k: usize| -> (Vec<f64>, Vec<Vec<f64>>) {
        let mut q: Vec<f64> = (0..nq).map(|i| seeded_state(k, i, 0)).collect();
        let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
        q[3..7].iter_mut().for_each(|x| *x /= n);
        (q, (1..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect())
    };
    // The rest fed its callees' values, plain and with the contacts masked (the point
    // inactive) and stabilised (gains, and references: the wrench's placement with a unit
    // quaternion, the point's position), which the callee takes too.
    let mut masked = plain.clone();
    masked.specialisation.contact_mask = true;
    masked.specialisation.baumgarte = true;
    let (gains, refs) =
        ([20.0, 5.0, 30.0, 8.0], [0.1, 0.2, 1.3, 0.5, -0.5, 0.5, 0.5, -0.1, 0.3, 0.7]);
    for (calls, solve) in ROUTES {
        let whole = LowerOptions { kernels: kernels.clone(), solve, ..LowerOptions::default() };
        let lower = LowerOptions { calls, ..whole.clone() };
        let own = calls == Calls::RneaGrad;
        let name = format!("{}_{}", calls.name(), solve.name());
        let mut worst: f64 = 0.0;
        for model in [&plain, &masked] {
            let by_default = ir::lower(model, g, &whole).unwrap();
            let f = by_default.function(KernelKind::ContactFdGrad).unwrap();
            assert!(f.call.is_none(), "auto keeps contact_fd_grad whole");
            let lowered = ir::lower(model, g, &lower).unwrap();
            let call =
                lowered.function(KernelKind::ContactFdGrad).unwrap().call.as_ref().expect("calls");
            let callees = if own {
                vec![KernelKind::RneaGrad]
            } else {
                vec![KernelKind::ContactFd, KernelKind::RneaGrad]
            };
            assert_eq!(call.callees, callees);
            assert_eq!(!call.shared.is_empty(), own, "a split rest reads rnea_grad's first values");
            let corr = reference::Baumgarte { gains: &gains, refs: &refs };
            for k in 0..3 {
                let (q, x) = state(k);
                let active = [1.0, (k % 2) as f64];
                let none = reference::External::NONE;
                let args =
                    kernel_args_corrected(f.inputs(), &q, &x[0], &x[1], none, &[], &active, corr);
                let all = f.eval(&args);
                let cfd = lowered.function(KernelKind::ContactFd).unwrap();
                // q̈ and λ from `contact_fd`, or the kernel's own (its first outputs).
                let sol = if own {
                    all[..2].to_vec()
                } else {
                    cfd.eval(&kernel_args_corrected(
                        cfd.inputs(),
                        &q,
                        &x[0],
                        &x[1],
                        none,
                        &[],
                        &active,
                        corr,
                    ))
                };
                let rg = lowered.function(KernelKind::RneaGrad).unwrap();
                let ext = reference::External { fext: &[], lambda: &sol[1] };
                let dc = rg.eval(&kernel_args_with(rg.inputs(), &q, &x[0], &sol[0], ext));
                let mut rest_args = args.clone();
                if !own {
                    rest_args.extend(sol.iter().map(Vec::as_slice));
                }
                rest_args.extend(dc.iter().take(2).map(Vec::as_slice));
                assert_eq!(rest_args.len(), call.rest.inputs().len());
                for (a, b) in all.iter().zip(&call.rest.eval(&rest_args)) {
                    worst = worst.max(rel_err(&col(a), &col(b)));
                }
                // Each value the rest reads from `rnea_grad`'s first parts is the value the
                // rest would compute (the same operations: equal to the bit).
                let callee_args = kernel_args_with(rg.inputs(), &q, &x[0], &sol[0], ext);
                let (mine, theirs) =
                    (call.rest.eval_nodes(&rest_args), rg.eval_nodes(&callee_args));
                for &(at, from) in &call.shared {
                    assert_eq!(mine[at.0 as usize], theirs[from.0 as usize], "{name}: {at:?}");
                }
            }
        }
        let model = &plain;
        let f = ir::lower(model, g, &whole)
            .unwrap()
            .functions
            .into_iter()
            .find(|f| f.kind == KernelKind::ContactFdGrad)
            .unwrap();
        assert!(worst < 1e-12, "{name}: rest after its callees: {worst:.2e} from the whole graph");
        println!("calls={name}: contact_fd_grad's rest with its callees' values, plain, masked and stabilised: worst {worst:.2e} from the whole graph (bound 1e-12)");
        let file =
            generate(model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
                .unwrap()
                .remove(0);
        let split = !file.contents.contains("fn contact_fd_grad_rest<");
        assert_eq!(split, own, "a rest of its own unless split");
        let said = compile_and_run(
            &format!("contact_fd_grad_calls_{name}"),
            &file.contents,
            &[
                "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
                SEEDED_STATE_RS,
                r#"fn main() {
        let copies = if has_fma() { 2 } else { 1 };
        for copy in 0..copies {
            for k in 0..3 {
                let mut q: [f64; NQ] = std::array::from_fn(|i| state(k, i, 0));
                let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
                for x in &mut q[3..7] { *x /= n; }
                let x: [[f64; NV]; 2] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s + 1)));
                let o = if copy == 1 { unsafe { fma::contact_fd_grad(&q, &x[0], &x[1]) } } else { portable::contact_fd_grad(&q, &x[0], &x[1]) };
                let all: Vec<String> = q.iter().chain(&o.0).chain(&o.1).chain(o.2.as_flattened()).chain(o.3.as_flattened()).chain(o.4.as_flattened()).chain(o.5.as_flattened()).chain(o.6.as_flattened()).chain(o.7.as_flattened()).map(|x| format!("{x:?}")).collect();
                println!("{}", all.join(" "));
            }
        }
    }
    "#,
            ]
            .concat(),
        );
        let whole = |k: usize, _: &[f64]| {
            let (q, x) = state(k);
            f.eval(&kernel_args(f.inputs(), &q, &x[0], &x[1])).concat()
        };
        for (copy_name, worst) in worst_per_copy(&said, nq, 1e-12, whole) {
            println!("calls={name}: floating chain contact_fd_grad, {copy_name} copy: worst {worst:.2e} from the whole graph (bound 1e-12)");
        }
    }
}
