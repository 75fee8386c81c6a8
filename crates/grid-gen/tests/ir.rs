//! The kernel IR, interpreted in f64, against the reference dynamics on every bundled
//! robot: this checks the symbolic algorithms and the folding/sharing before any backend
//! prints them. Tolerance: ‖Δ‖max / ‖ref‖max ≤ 1e-12 (the IR reorders sums and snaps
//! model constants within 1e-15 of 0 or ±1; see `ir::spatial::SNAP`). The unspecialised
//! (dense) graphs are checked too, at the same tolerance.

use grid_gen::ir::{self, Gradient, KernelKind, LowerOptions};
use grid_gen::{reference, Model};
use grid_gen_test_support::*;

const TOL: f64 = 1e-12;

/// Every kernel output next to what the reference says it should be.
fn compare(
    model: &Model,
    g: [f64; 3],
    options: &LowerOptions,
    q: &[f64],
    qd: &[f64],
    u: &[f64],
) -> Vec<(String, f64)> {
    let n = model.nv();
    let module = ir::lower(model, g, options).expect("bundled robots lower");
    let mut errs = Vec::new();
    for f in &module.functions {
        let out = f.eval(&kernel_args(f.inputs(), q, qd, u));
        let want = reference_outputs(f.kind, model, q, qd, u, g);
        for ((o, got), want) in f.outputs.iter().zip(&out).zip(&want) {
            let got = output_matrix(o.shape, n, got);
            errs.push((format!("{}.{}", f.kind, o.name), rel_err(&got, want)));
        }
    }
    errs
}

#[test]
fn specialised_ir_matches_the_reference() {
    let mut rng = Rng(11);
    let mut worst = 0.0f64;
    for robot in robots() {
        let model = load(&robot);
        let n = model.nv();
        for g in [reference::DEFAULT_GRAVITY, [0.3, 1.0, -9.0]] {
            for _ in 0..3 {
                let (q, qd, u) =
                    (rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0));
                for (what, e) in compare(&model, g, &LowerOptions::default(), &q, &qd, &u) {
                    assert!(e <= TOL, "{robot}: {what} relative error {e:.2e}");
                    worst = worst.max(e);
                }
            }
        }
    }
    eprintln!("specialised IR: worst relative error {worst:.2e}");
}

#[test]
fn every_gradient_formulation_matches_the_reference() {
    let mut rng = Rng(13);
    for robot in robots() {
        let model = load(&robot);
        let n = model.nv();
        for gradient in [Gradient::Columns, Gradient::Idsva, Gradient::World] {
            let options = LowerOptions {
                kernels: vec![KernelKind::RneaGrad, KernelKind::FdGrad],
                gradient,
                ..LowerOptions::default()
            };
            let (q, qd, u) = (rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0));
            for (what, e) in compare(&model, [0.3, 1.0, -9.0], &options, &q, &qd, &u) {
                assert!(e <= TOL, "{robot} {gradient:?}: {what} relative error {e:.2e}");
            }
        }
    }
}

#[test]
fn dense_ir_matches_the_reference() {
    let mut rng = Rng(12);
    for robot in ["grid_iiwa", "rbd_benchmarks_iiwa", "panda", "double_pendulum_continuous"] {
        let model = load(robot);
        let n = model.nv();
        let (q, qd, u) = (rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0));
        // Each option on its own, and both off (the general dense algorithm).
        let partial = [
            LowerOptions { fold: false, ..LowerOptions::default() },
            LowerOptions { sparse: false, ..LowerOptions::default() },
            LowerOptions::general(),
        ];
        for options in &partial {
            for (what, e) in compare(&model, reference::DEFAULT_GRAVITY, options, &q, &qd, &u) {
                assert!(e <= TOL, "{robot} {options:?}: {what} relative error {e:.2e}");
            }
        }
    }
}

#[test]
fn specialisation_removes_work_and_keeps_depth_bounded() {
    let model = load("grid_atlas");
    let stats = ir::stats(
        &model,
        reference::DEFAULT_GRAVITY,
        ir::Gradient::Auto,
        ir::Solve::Auto,
        ir::Calls::Auto,
        ir::STATS_MAX_NODES,
    );
    assert!(stats.skipped.is_empty(), "Atlas fits the op-count limit: {:?}", stats.skipped);
    assert_eq!(
        stats.ops.len(),
        KernelKind::DYNAMICS.len() + 4,
        "no frames asked, no frame kernels: the dynamics and the four Lie-group kernels"
    );
    // The Lie-group kernels of a fixed robot are additions and constants: nothing to remove.
    for s in stats.ops.into_iter().filter(|s| !s.kernel.is_lie()) {
        let before = s.before.expect("Atlas's general graphs fit the limit");
        assert!(s.after.total() < before.total(), "{}: {:?} vs {:?}", s.kernel, s.after, s.before);
    }
}

/// A joint that moves only massless links makes M singular. Loading
/// warns; RNEA, its gradient and M are still lowered (and right), the kernels that need
/// M⁻¹ are left out everywhere: the module, `info`, the generated Rust and `eval`.
#[test]
fn a_singular_mass_matrix_blocks_only_the_kernels_that_need_its_inverse() {
    let path = repo().join("tests/diagnostics/massless_subtree.urdf");
    let text = std::fs::read_to_string(&path).unwrap();
    let (model, warnings) = Model::from_urdf_str("massless_subtree.urdf", &text, false)
        .expect("a singular M is a warning");
    assert!(
        warnings.iter().any(|w| w.message.contains("joint `j2` moves only massless links")),
        "{warnings:?}"
    );
    assert!(
        Model::from_urdf_str("massless_subtree.urdf", &text, true).is_err(),
        "--strict refuses it"
    );
    assert_eq!(model.singular.as_deref(), Some("j2"));
    let module = ir::lower(&model, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
    let kinds: Vec<KernelKind> = module.functions.iter().map(|f| f.kind).collect();
    let lie = [
        KernelKind::Integrate,
        KernelKind::DIntegrate,
        KernelKind::Difference,
        KernelKind::DDifference,
    ];
    assert_eq!(
        kinds,
        [&[KernelKind::Rnea, KernelKind::RneaGrad, KernelKind::MassMatrix][..], &lie].concat()
    );
    let mut rng = Rng(17);
    let n = model.nv();
    for _ in 0..3 {
        let (q, qd, u) = (rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0));
        for (what, e) in
            compare(&model, reference::DEFAULT_GRAVITY, &LowerOptions::default(), &q, &qd, &u)
        {
            assert!(e <= TOL, "{what} relative error {e:.2e}");
        }
    }
    let err = ir::lower_function(
        &model,
        reference::DEFAULT_GRAVITY,
        KernelKind::FdGrad,
        &LowerOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("needs M⁻¹, and M is singular (joint `j2`"), "{err}");
    let info = grid_gen::info::Info::new(&model);
    let skipped: Vec<&str> = info.ops_skipped.iter().map(|s| s.kernel.name()).collect();
    assert_eq!(skipped, ["minv", "fd", "fd_grad"]);
    let rust = grid_gen::generate::generate(&model, &grid_gen::generate::Options::default())
        .unwrap()
        .remove(0)
        .contents;
    assert!(
        rust.contains("pub fn mass_matrix<")
            && !rust.contains("pub fn minv<")
            && !rust.contains("pub fn fd<")
    );
    let states = grid_gen::eval::parse_states(
        r#"{"states": [{"q": [0.1, 0.2], "qd": [0.3, 0.4], "qdd": [1, 2]}]}"#,
    )
    .unwrap();
    let out = serde_json::to_value(
        grid_gen::eval::evaluate(&model, &states, reference::DEFAULT_GRAVITY).unwrap(),
    )
    .unwrap();
    assert!(
        out["states"][0]["M"].is_array()
            && out["states"][0]["drnea_dq"].is_array()
            && out["states"][0].get("Minv").is_none(),
        "{out}"
    );
    let with_tau =
        grid_gen::eval::parse_states(r#"{"states": [{"q": [0, 0], "qd": [0, 0], "tau": [1, 2]}]}"#)
            .unwrap();
    let err = grid_gen::eval::evaluate(&model, &with_tau, reference::DEFAULT_GRAVITY)
        .unwrap_err()
        .to_string();
    assert!(err.contains("state 0: `tau` asks for forward dynamics, which needs M⁻¹, and M is singular (joint `j2`"), "{err}");
}

fn chain(n: usize) -> Model {
    Model::from_urdf_str("chain.urdf", &chain_urdf(n), false).unwrap().0
}

/// The IR evaluated in double-double (about 106 bits) as the
/// reference. The graph is lowered without constant folding, so every model constant
/// enters as the f64 the model holds and the double-double result is the true dynamics of
/// the f64 model (to about 1e-30 relative, times the growth of its graph). Against it:
/// the specialised f64 graph (what the generated kernels compute, up to their own
/// operation order) and the reference algorithms in f64. Checked: the double-double
/// value agrees with both to the f64 tolerance of this file's other tests, at random
/// and extreme states, on two bundled robots and a 30-link chain (cond(M) ~ 1e4); the
/// 100-link chain is measured against Pinocchio in the next test.
#[test]
fn f64_against_the_double_double_reference() {
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(29);
    let unfolded = LowerOptions {
        fold: false,
        kernels: vec![KernelKind::Fd, KernelKind::FdGrad],
        ..LowerOptions::default()
    };
    let folded = LowerOptions {
        kernels: vec![KernelKind::Fd, KernelKind::FdGrad],
        ..LowerOptions::default()
    };
    for (name, model) in
        [("grid_iiwa", load("grid_iiwa")), ("grid_hyq", load("grid_hyq")), ("chain30", chain(30))]
    {
        let n = model.nv();
        let exact = ir::lower(&model, g, &unfolded).unwrap();
        let fast = ir::lower(&model, g, &folded).unwrap();
        let (mut kernel_worst, mut reference_worst) = (0.0f64, 0.0f64);
        for _ in 0..3 {
            let (q, qd, tau) =
                (rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0), rng.vec(n, -3.0, 3.0));
            let f = exact.function(KernelKind::FdGrad).unwrap();
            let args = kernel_args(f.inputs(), &q, &qd, &tau);
            let truth: Vec<Vec<f64>> = f
                .eval_as::<grid_gen::numerics::Dd>(&args)
                .into_iter()
                .map(|o| o.into_iter().map(|x| x.to_f64()).collect())
                .collect();
            let got = fast.function(KernelKind::FdGrad).unwrap().eval(&args);
            let (qdd, dq, dqd) = reference::forward_dynamics_derivatives(&model, &q, &qd, &tau, g);
            let reference_outputs = [col(&qdd), dq, dqd];
            for (k, o) in f.outputs.iter().enumerate() {
                let want = output_matrix(o.shape, n, &truth[k]);
                let e = rel_err(&output_matrix(o.shape, n, &got[k]), &want);
                let r = rel_err(&reference_outputs[k], &want);
                kernel_worst = kernel_worst.max(e);
                reference_worst = reference_worst.max(r);
                assert!(
                    e <= TOL && r <= TOL,
                    "{name} {}: kernel {e:.1e}, reference {r:.1e}",
                    o.name
                );
            }
        }
        let m = reference::crba(&model, &vec![0.3; n]);
        let eig = m.symmetric_eigenvalues();
        let cond = eig.max() / eig.min();
        eprintln!("{name}: fd_grad in f64 against double-double: generated graph {kernel_worst:.1e}, reference algorithms {reference_worst:.1e} (cond(M) at q = 0.3: {cond:.1e})");
        // Extremes: angles up to ±1e3 rad, speeds 1e3 and 1e-8.
        let mut extreme_worst = 0.0f64;
        for (qs, vs) in [(1e3, 1e3), (1e3, 1e-8), (3.0, 1e3)] {
            let (q, qd, tau) = (rng.vec(n, -qs, qs), rng.vec(n, -vs, vs), rng.vec(n, -3.0, 3.0));
            let f = exact.function(KernelKind::FdGrad).unwrap();
            let args = kernel_args(f.inputs(), &q, &qd, &tau);
            let truth = f.eval_as::<grid_gen::numerics::Dd>(&args);
            let got = fast.function(KernelKind::FdGrad).unwrap().eval(&args);
            for (k, o) in f.outputs.iter().enumerate() {
                let want = output_matrix(
                    o.shape,
                    n,
                    &truth[k].iter().map(|x| x.to_f64()).collect::<Vec<_>>(),
                );
                let e = rel_err(&output_matrix(o.shape, n, &got[k]), &want);
                assert!(e <= TOL, "{name} {} at extreme angles or speeds: {e:.1e}", o.name);
                extreme_worst = extreme_worst.max(e);
            }
        }
        eprintln!(
            "{name}: the same at angles up to ±1e3 rad and speeds 1e3 or 1e-8: {extreme_worst:.1e}"
        );
    }
}

/// The accuracy goal: forward dynamics and its gradient in f64 no less accurate than
/// Pinocchio's `aba` and `computeABADerivatives`, on a 100-link chain (cond(M) ~ 1e5, where
/// q̈ = M⁻¹ (τ − c) made ∂q̈/∂q 1000x worse than Pinocchio). Both are measured against the
/// double-double value of the unfolded graph at the fixture's states; the assertion is
/// that grid-gen's error is at most Pinocchio's, per output and state.
#[test]
fn forward_dynamics_as_accurate_as_pinocchio_on_a_100_link_chain() {
    let n = 100;
    let path = repo().join("tests/fixtures/chain100.urdf");
    let text = std::fs::read_to_string(&path)
        .expect("tests/fixtures/chain100.urdf (run scripts/make_fixtures.py)");
    assert_eq!(
        text.trim_end(),
        chain_urdf(n),
        "{} is not chain_urdf(100): rerun scripts/make_fixtures.py",
        path.display()
    );
    let model = chain(n);
    let fx = fixture("chain100.pinocchio.json");
    let names: Vec<&str> =
        fx["joint_names"].as_array().unwrap().iter().map(|x| x.as_str().unwrap()).collect();
    assert_eq!(
        names,
        model.joints.iter().map(|j| j.name.as_str()).collect::<Vec<_>>(),
        "Pinocchio's joint order is grid-gen's on a chain"
    );
    let g = reference::DEFAULT_GRAVITY;
    assert_eq!(vec_of(&fx["gravity"]), g.to_vec());
    let kinds = vec![KernelKind::FdGrad];
    let exact = ir::lower(
        &model,
        g,
        &LowerOptions { fold: false, kernels: kinds.clone(), ..LowerOptions::default() },
    )
    .unwrap();
    let fast =
        ir::lower(&model, g, &LowerOptions { kernels: kinds, ..LowerOptions::default() }).unwrap();
    let (exact, fast) =
        (exact.function(KernelKind::FdGrad).unwrap(), fast.function(KernelKind::FdGrad).unwrap());
    for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
        let (q, qd, tau) = (vec_of(&st["q"]), vec_of(&st["qd"]), vec_of(&st["tau"]));
        let args = kernel_args(exact.inputs(), &q, &qd, &tau);
        let truth: Vec<Vec<f64>> = exact
            .eval_as::<grid_gen::numerics::Dd>(&args)
            .into_iter()
            .map(|o| o.into_iter().map(|x| x.to_f64()).collect())
            .collect();
        let got = fast.eval(&args);
        let (qdd, dq, dqd) = reference::forward_dynamics_derivatives(&model, &q, &qd, &tau, g);
        let pinocchio = [col(&vec_of(&st["fd"])), mat_of(&st["dfd_dq"]), mat_of(&st["dfd_dqd"])];
        let reference_outputs = [col(&qdd), dq, dqd];
        for (k, o) in exact.outputs.iter().enumerate() {
            let want = output_matrix(o.shape, n, &truth[k]);
            let e = rel_err(&output_matrix(o.shape, n, &got[k]), &want);
            let r = rel_err(&reference_outputs[k], &want);
            let p = rel_err(&pinocchio[k], &want);
            eprintln!("chain100 state {s} {}: against double-double, generated graph {e:.1e}, reference algorithms {r:.1e}, Pinocchio {p:.1e}", o.name);
            assert!(e <= p, "chain100 state {s} {}: generated {e:.1e}, Pinocchio {p:.1e}", o.name);
            // The reference is every other test's oracle at TOL; it must stay within it.
            assert!(r <= TOL, "chain100 state {s} {}: reference algorithms {r:.1e}", o.name);
        }
    }
}
