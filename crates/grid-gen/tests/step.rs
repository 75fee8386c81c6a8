//! The discrete step and its linearisation `[A | B]`: the reference against Pinocchio 4.1
//! compositions (`aba`, `computeABADerivatives`, `integrate`, `dIntegrate`, Crocoddyl's
//! schemes) on fixed, floating and spherical robots, against central differences on the
//! manifold for every scheme, the step kernels' IR against the reference, and the
//! scene's bad inputs.

use grid_gen::ir::{self, KernelKind, LowerOptions};
use grid_gen::model::{ContactKind, Scheme, Step, StepSpec};
use grid_gen::{reference, Model, Scene};
use grid_gen_test_support::*;
use nalgebra::DMatrix;

/// Pinocchio and the reference compose the same quantities by other routes (Pinocchio's
/// closed-form Jexp6 against a summed series): 1e-10 relative, the project's bar against
/// Pinocchio.
const TOL: f64 = 1e-10;

/// Five-point central differences at h = 1e-4 against the analytical A and B (see
/// `step_derivatives_match_central_differences`): the x⁺ rounding, ~1e-16 on entries of
/// order 1, over h leaves ~1e-12 (measured 1.5e-11 worst).
const TOL_STENCIL: f64 = 1e-10;
/// The same with rigid contacts: the same ~1e-12 absolute, relative to a B that the
/// contacts' projection `M⁻¹ − G K⁻¹ Gᵀ` shrinks (iiwa's tool wrench leaves it one free
/// direction), is up to 1e-8 (measured 9.2e-9).
const TOL_STENCIL_CONTACT: f64 = 5e-8;

/// The fixture's model, with the fext bodies and contacts the fixture declares.
fn fixture_model(name: &str, fx: &serde_json::Value) -> (Model, bool) {
    let fixtures = repo().join("tests/fixtures");
    let (model, floating) = match name.split('.').next().unwrap() {
        "grid_iiwa" => (load("grid_iiwa"), false),
        "grid_hyq" => (load_floating("grid_hyq"), true),
        "grid_atlas" => (load_floating("grid_atlas"), true),
        "ball_arm" => (load_urdf(&fixtures.join("ball_arm.urdf"), true), true),
        _ => unreachable!(),
    };
    let names = |key: &str| -> Vec<String> {
        fx[key]
            .as_array()
            .map_or(Vec::new(), |a| a.iter().map(|n| n.as_str().unwrap().to_string()).collect())
    };
    let fext = names("fext");
    let contacts: Vec<(String, ContactKind)> = fx["contacts"].as_array().map_or(Vec::new(), |a| {
        a.iter()
            .map(|c| {
                (
                    c["frame"].as_str().unwrap().to_string(),
                    ContactKind::parse(c["type"].as_str().unwrap()).unwrap(),
                )
            })
            .collect()
    });
    let fext: Vec<&str> = fext.iter().map(String::as_str).collect();
    let contacts: Vec<(&str, ContactKind)> =
        contacts.iter().map(|(f, k)| (f.as_str(), *k)).collect();
    (with_forces(&model, &fext, &contacts), floating)
}

/// Plain steps on fixed, floating and spherical robots; iiwa with fext on three bodies held
/// over the step; floating HyQ on four rigid point contacts, iiwa with its tool held by a
/// rigid wrench contact, and floating Atlas (a 30-joint humanoid) standing on both feet as
/// rigid 6-D contacts (`constraintDynamics` at every stage; Atlas's fixture holds the
/// semi-implicit step alone, on four states, to stay small).
#[test]
fn reference_step_matches_pinocchio() {
    let mut checked = 0;
    let mut humanoid = 0;
    let mut worst: f64 = 0.0;
    let names = [
        "grid_iiwa",
        "grid_hyq.floating",
        "ball_arm.floating",
        "grid_iiwa.fext",
        "grid_hyq.floating.contact",
        "grid_iiwa.contact",
        "grid_atlas.floating.contact",
    ];
    for name in names {
        let fx = fixture(&format!("{name}.step.pinocchio.json"));
        let (model, floating) = fixture_model(name, &fx);
        let perm = fixture_perm(&model, &fx, name);
        let coordinates: Vec<&str> =
            model.coordinate_joints().into_iter().map(|i| model.joint(i).name.as_str()).collect();
        let nv = model.nv();
        let ours = |v: &[f64]| {
            let mut o = vec![0.0; nv];
            for (k, &i) in perm.iter().enumerate() {
                o[i] = v[k];
            }
            o
        };
        let spherical = !model.spherical.is_empty();
        // The fixture's q: the base's seven, then the listed joints' angles; ball_arm's is
        // Pinocchio's (and grid-gen's) whole q.
        let q_of = |v: &[f64]| {
            if spherical {
                return v.to_vec();
            }
            let (base, angles) = if floating {
                (v[..7].try_into().unwrap(), &v[7..])
            } else {
                ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], v)
            };
            let per =
                if floating { [vec![0.0; 6], angles.to_vec()].concat() } else { angles.to_vec() };
            model.q_from_joints(&ours(&per), base)
        };
        let actuated: Vec<usize> = fx["actuated"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| coordinates.iter().position(|c| *c == n.as_str().unwrap()).unwrap())
            .collect();
        assert_eq!(
            actuated.iter().copied().collect::<std::collections::BTreeSet<_>>(),
            model.actuated().into_iter().collect(),
            "{name}: the default actuation"
        );
        let state_perm: Vec<usize> =
            perm.iter().copied().chain(perm.iter().map(|&p| nv + p)).collect();
        let dt = fx["dt"].as_f64().unwrap();
        let g: [f64; 3] = vec_of(&fx["gravity"]).try_into().unwrap();
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            let (q, qd, tau) =
                (q_of(&vec_of(&st["q"])), ours(&vec_of(&st["qd"])), ours(&vec_of(&st["tau"])));
            let fext = if st["fext"].is_null() { Vec::new() } else { vec_of(&st["fext"]) };
            for scheme in Scheme::ALL {
                let want = &st[scheme.name()];
                if want.is_null() && name.starts_with("grid_atlas") {
                    continue;
                }
                let step = Step { scheme, dt };
                let d = reference::step_derivatives(
                    &model,
                    &q,
                    &qd,
                    &tau,
                    g,
                    step,
                    &model.actuated(),
                    &fext,
                )
                .unwrap();
                let (q1, v1) = reference::step(&model, &q, &qd, &tau, g, step, &fext).unwrap();
                let theirs_a = mat_of(&want["A"]);
                let theirs_a = DMatrix::from_fn(2 * nv, 2 * nv, |r, c| {
                    theirs_a[(
                        state_perm.iter().position(|&p| p == r).unwrap(),
                        state_perm.iter().position(|&p| p == c).unwrap(),
                    )]
                });
                // B's columns: the fixture's actuated order, mapped to ours (model order).
                let theirs_b = mat_of(&want["B"]);
                let order: Vec<usize> = model
                    .actuated()
                    .iter()
                    .map(|c| actuated.iter().position(|a| a == c).unwrap())
                    .collect();
                let theirs_b = DMatrix::from_fn(2 * nv, order.len(), |r, c| {
                    theirs_b[(state_perm.iter().position(|&p| p == r).unwrap(), order[c])]
                });
                let results = [
                    ("q_next", col(&d.q_next), col(&q_of(&vec_of(&want["q_next"])))),
                    ("q_next (step)", col(&q1), col(&q_of(&vec_of(&want["q_next"])))),
                    ("qd_next", col(&d.qd_next), col(&ours(&vec_of(&want["qd_next"])))),
                    ("qd_next (step)", col(&v1), col(&ours(&vec_of(&want["qd_next"])))),
                    ("A", d.a, theirs_a),
                    ("B", d.b, theirs_b),
                ];
                for (what, got, want) in results {
                    let e = rel_err(&got, &want);
                    worst = worst.max(e);
                    checked += 1;
                    humanoid += usize::from(name.starts_with("grid_atlas"));
                    assert!(
                        e < TOL,
                        "{name} state {s} ({}) {}: {what} {e:.2e}",
                        st["kind"],
                        scheme.name()
                    );
                }
            }
        }
    }
    println!("{checked} step quantities against Pinocchio, worst {worst:.2e} (bound {TOL:.0e})");
    assert!(checked > 800);
    // Four states of the humanoid, six quantities each, the semi-implicit step.
    assert_eq!(humanoid, 24, "the humanoid's step quantities");
}

/// Robots with forces for the step tests: floating HyQ on four rigid point contacts with a
/// force on its base, iiwa holding its tool by a rigid wrench contact with a force on its
/// third link, the floating spherical arm with its tip held by a wrench contact.
fn forced_cases() -> Vec<(&'static str, Model)> {
    let legs = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .map(|l| (l, ContactKind::Point));
    let ball = load_urdf(&repo().join("tests/fixtures/ball_arm.urdf"), true);
    let tip = ball.frames.iter().rev().find(|f| f.body.is_some()).unwrap().name.clone();
    vec![
        (
            "hyq floating, four point contacts, fext",
            with_forces(&load_floating("grid_hyq"), &["root_joint"], &legs),
        ),
        (
            "iiwa, tool wrench contact, fext",
            with_forces(
                &load("grid_iiwa"),
                &["iiwa_joint_3"],
                &[("iiwa_link_7", ContactKind::Wrench)],
            ),
        ),
        (
            "ball_arm floating, tip wrench contact",
            with_forces(&ball, &[], &[(tip.as_str(), ContactKind::Wrench)]),
        ),
    ]
}

/// A and B against central differences of the step on the manifold, every scheme: the
/// state moved by `x ⊕ ε e_k`, the results compared by `⊖`; plain robots, and robots with
/// fext held over the step and rigid contacts.
#[test]
fn step_derivatives_match_central_differences() {
    let fixtures = repo().join("tests/fixtures");
    let mut cases: Vec<(&str, Model)> = vec![
        ("iiwa", load("grid_iiwa")),
        ("hyq floating", load_floating("grid_hyq")),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true)),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
    ];
    cases.extend(forced_cases());
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(47);
    let mut worst: f64 = 0.0;
    for (name, model) in &cases {
        let fext = rng.vec(6 * model.nfext(), -20.0, 20.0);
        let fext = fext.as_slice();
        let nv = model.nv();
        let actuated = model.actuated();
        let mut q = model.q_from_joints(&rng.vec(nv, -2.0, 2.0), rng.base_pose());
        for &s in &model.spherical {
            let at = model.group_q(s).0;
            let x = rng.vec(4, -1.0, 1.0);
            let n = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            q[at..at + 4].copy_from_slice(&x.iter().map(|v| v / n).collect::<Vec<_>>());
        }
        let qd = rng.vec(nv, -3.0, 3.0);
        let tau = actuated_tau(model, &rng.vec(actuated.len(), -5.0, 5.0));
        for scheme in Scheme::ALL {
            let step = Step { scheme, dt: 0.05 };
            let d = reference::step_derivatives(model, &q, &qd, &tau, g, step, &actuated, fext)
                .unwrap();
            let (q1, v1) = reference::step(model, &q, &qd, &tau, g, step, fext).unwrap();
            // The five-point stencil, `(−f(2h) + 8 f(h) − 8 f(−h) + f(−2h)) / 12h`, errs by
            // about h⁴ |f⁽⁵⁾| / 30 + 1e-16 |f| / h: at h = 1e-4, 1e-12 from rounding. The
            // three-point one at its best h (~1e-6) leaves ~1e-7 here, because a rigid
            // wrench contact that leaves iiwa one free direction makes the step's
            // higher derivatives large.
            let eps = 1e-4;
            // The step moved by `h` along one direction, as a tangent at q1: `[q ⊖ q1; q̇]`.
            let derivative = |at: &dyn Fn(f64) -> (Vec<f64>, Vec<f64>)| -> nalgebra::DVector<f64> {
                let tangent = |h: f64| {
                    let (qa, va) = at(h);
                    let mut t = reference::difference(model, &q1, &qa);
                    t.extend(va);
                    nalgebra::DVector::from_vec(t)
                };
                (tangent(-2.0 * eps) - tangent(2.0 * eps) + (tangent(eps) - tangent(-eps)) * 8.0)
                    / (12.0 * eps)
            };
            let mut num_a = DMatrix::zeros(2 * nv, 2 * nv);
            for k in 0..2 * nv {
                let moved = |h: f64| {
                    let mut e = vec![0.0; nv];
                    let mut qd_e = qd.clone();
                    if k < nv {
                        e[k] = h;
                    } else {
                        qd_e[k - nv] += h;
                    }
                    reference::step(
                        model,
                        &reference::integrate(model, &q, &e),
                        &qd_e,
                        &tau,
                        g,
                        step,
                        fext,
                    )
                    .unwrap()
                };
                num_a.set_column(k, &derivative(&moved));
            }
            let mut num_b = DMatrix::zeros(2 * nv, actuated.len());
            for (c, &k) in actuated.iter().enumerate() {
                let moved = |h: f64| {
                    let mut t = tau.clone();
                    t[k] += h;
                    reference::step(model, &q, &qd, &t, g, step, fext).unwrap()
                };
                num_b.set_column(c, &derivative(&moved));
            }
            assert!(
                rel_err(&col(&q1), &col(&d.q_next)) < 1e-14
                    && rel_err(&col(&v1), &col(&d.qd_next)) < 1e-14,
                "{name}: step and step_derivatives agree"
            );
            for (what, got, want) in [("A", &d.a, &num_a), ("B", &d.b, &num_b)] {
                let e = rel_err(got, want);
                worst = worst.max(e);
                let bound = if model.nlambda() > 0 { TOL_STENCIL_CONTACT } else { TOL_STENCIL };
                assert!(e < bound, "{name} {}: {what} {e:.2e}", scheme.name());
            }
        }
    }
    println!("worst step derivative against central differences: {worst:.2e} (bounds {TOL_STENCIL:.0e}, {TOL_STENCIL_CONTACT:.0e} with contacts)");
}

/// The step kernels' IR graphs against the reference, both Euler schemes, fixed, floating,
/// spherical and coupled mimic robots, with the default and a chosen actuation, and every
/// fd_grad solve (their M⁻¹ columns come from different routes).
#[test]
fn step_kernels_match_the_reference() {
    let fixtures = repo().join("tests/fixtures");
    let mut hyq_partial = load_floating("grid_hyq");
    hyq_partial.specialisation.actuated = Some(vec![6, 7, 9, 13]);
    let cases: Vec<(&str, Model)> = vec![
        ("iiwa", load("grid_iiwa")),
        ("hyq floating", load_floating("grid_hyq")),
        ("hyq floating, four motors", hyq_partial),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true)),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
    ];
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(53);
    let mut worst: f64 = 0.0;
    for (name, model) in &cases {
        for scheme in Scheme::ALL {
            for solve in [ir::Solve::Minv, ir::Solve::Ltdl] {
                let m = with_step(model, scheme, 0.01);
                let options = LowerOptions {
                    kernels: vec![KernelKind::Step, KernelKind::StepGrad],
                    solve,
                    ..LowerOptions::default()
                };
                let module = ir::lower(&m, g, &options).unwrap();
                assert_eq!(module.functions.len(), 2, "{name}: both step kernels");
                let nv = m.nv();
                for state in 0..3 {
                    // The last state spins at 1e3 rad/s: the base turns by 10 rad and more in a
                    // step. RK4's at 30 rad/s: at 1e3 its 10 ms step is far outside the scheme's
                    // stability (dt |∂f/∂x| ≫ 2.8), each stage multiplies the previous one's
                    // rounding by dt ∂q̈/∂q̇ ~ 1e2, and two f64 evaluations drift 1e-10 apart.
                    let fast = if scheme == Scheme::Rk4 { 30.0 } else { 1e3 };
                    let speed = if state == 2 { fast } else { 2.0 };
                    let mut q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
                    for &s in &m.spherical {
                        let at = m.group_q(s).0;
                        let x = rng.vec(4, -1.0, 1.0);
                        let n = x.iter().map(|v| v * v).sum::<f64>().sqrt();
                        q[at..at + 4].copy_from_slice(&x.iter().map(|v| v / n).collect::<Vec<_>>());
                    }
                    let qd = rng.vec(nv, -speed, speed);
                    let u = rng.vec(m.nu(), -10.0, 10.0);
                    for f in &module.functions {
                        let got = f.eval(&kernel_args(f.inputs(), &q, &qd, &u));
                        let want = reference_outputs(f.kind, &m, &q, &qd, &u, g);
                        for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                            let e = rel_err(&output_matrix(o.shape, nv, got), want);
                            worst = worst.max(e);
                            // The same f64 dynamics by other routes (scaling and squaring
                            // against nalgebra's exponential, AD against a summed series).
                            assert!(
                                e < 1e-12,
                                "{name} {} {solve:?} state {state} {} {}: {e:.2e}",
                                scheme.name(),
                                f.kind,
                                o.name
                            );
                        }
                    }
                }
            }
        }
    }
    println!("worst step kernel against the reference: {worst:.2e} (bound 1e-12)");
}

/// The step kernels of robots with forces against the reference: fext an input held over
/// the step, the contacts rigid (no λ input), every scheme, and every solve with the Euler
/// schemes (RK4 runs the same dynamics at each stage, so one solve there).
#[test]
fn forced_step_kernels_match_the_reference() {
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(59);
    let mut worst: f64 = 0.0;
    for (name, model) in forced_cases() {
        for scheme in Scheme::ALL {
            let solves: &[ir::Solve] = if scheme == Scheme::Rk4 {
                &[ir::Solve::Ltdl]
            } else {
                &[ir::Solve::Minv, ir::Solve::Ltdl, ir::Solve::Crba]
            };
            for &solve in solves {
                let m = with_step(&model, scheme, 0.01);
                let options = LowerOptions {
                    kernels: vec![KernelKind::Step, KernelKind::StepGrad],
                    solve,
                    ..LowerOptions::default()
                };
                let module = ir::lower(&m, g, &options).unwrap();
                let nv = m.nv();
                let mut q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
                for &s in &m.spherical {
                    let at = m.group_q(s).0;
                    q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
                }
                let (qd, u, fext) = (
                    rng.vec(nv, -2.0, 2.0),
                    rng.vec(m.nu(), -10.0, 10.0),
                    rng.vec(6 * m.nfext(), -20.0, 20.0),
                );
                let ext = reference::External { fext: &fext, lambda: &[] };
                for f in &module.functions {
                    assert_eq!(
                        f.inputs().contains(&ir::Input::Fext),
                        m.nfext() > 0,
                        "{name} {}: takes fext",
                        f.kind
                    );
                    assert!(
                        !f.inputs().contains(&ir::Input::Lambda),
                        "{name} {}: solves for λ",
                        f.kind
                    );
                    let got = f.eval(&kernel_args_with(f.inputs(), &q, &qd, &u, ext));
                    let want = reference_outputs_with(f.kind, &m, &q, &qd, &u, g, ext);
                    assert_eq!(got.len(), want.len(), "{name} {}: outputs", f.kind);
                    for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                        let e = rel_err(&output_matrix(o.shape, nv, got), want);
                        worst = worst.max(e);
                        // As `contact_kernels_match_the_reference` (the Schur complement
                        // against the reference's KKT LU, a digit lost to K's conditioning),
                        // then integrated.
                        assert!(
                            e < 5e-11,
                            "{name} {} {solve:?} {} {}: {e:.2e}",
                            scheme.name(),
                            f.kind,
                            o.name
                        );
                    }
                }
            }
        }
    }
    println!("worst forced step kernel against the reference: {worst:.2e} (bound 5e-11)");
}

/// Issue 56's humanoid: floating Atlas (30 joints) on both feet as rigid 6-D contacts, the
/// semi-implicit step's kernels (the default solve) against the reference, which
/// `reference_step_matches_pinocchio` holds to Pinocchio on the same scene. The bound is
/// `forced_step_kernels_match_the_reference`'s.
#[test]
fn humanoid_contact_step_kernels_match_the_reference() {
    let g = reference::DEFAULT_GRAVITY;
    let feet = [("l_foot", ContactKind::Wrench), ("r_foot", ContactKind::Wrench)];
    let m = with_step(
        &with_forces(&load_floating("grid_atlas"), &[], &feet),
        Scheme::SemiImplicitEuler,
        0.01,
    );
    let options = LowerOptions {
        kernels: vec![KernelKind::Step, KernelKind::StepGrad],
        ..Default::default()
    };
    let module = ir::lower(&m, g, &options).unwrap();
    assert_eq!(module.functions.len(), 2, "step and step_grad");
    let mut rng = Rng(61);
    let nv = m.nv();
    let mut worst: f64 = 0.0;
    for _ in 0..2 {
        let q = m.q_from_joints(&rng.vec(nv, -1.0, 1.0), rng.base_pose());
        let (qd, u) = (rng.vec(nv, -2.0, 2.0), rng.vec(m.nu(), -10.0, 10.0));
        let ext = reference::External { fext: &[], lambda: &[] };
        for f in &module.functions {
            let got = f.eval(&kernel_args_with(f.inputs(), &q, &qd, &u, ext));
            let want = reference_outputs_with(f.kind, &m, &q, &qd, &u, g, ext);
            assert_eq!(got.len(), want.len(), "{}: outputs", f.kind);
            for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                let e = rel_err(&output_matrix(o.shape, nv, got), want);
                worst = worst.max(e);
                assert!(e < 5e-11, "humanoid {} {}: {e:.2e}", f.kind, o.name);
            }
        }
    }
    println!(
        "humanoid contact step kernels against the reference: worst {worst:.2e} (bound 5e-11)"
    );
}

/// Under `calls = auto`, a module whose `contact_fd_grad` has at least
/// `CALLS_RNEA_GRAD_MIN_OPS` operations (the humanoid on its feet) does what
/// `calls = rnea_grad` does: `fd_grad` and `contact_fd_grad` call `rnea_grad`, with the same
/// rests and the same values read from it; below it (the standing HyQ) they keep their
/// work whole. The called kernels' values are `fd_grad_calls_fd_and_rnea_grad_when_asked`'s
/// and `contact_fd_grad_calls_contact_fd_and_rnea_grad_when_asked`'s to check (floating.rs).
#[test]
fn auto_calls_rnea_grad_where_the_contact_gradient_is_large() {
    let g = reference::DEFAULT_GRAVITY;
    let feet = [("l_foot", ContactKind::Wrench), ("r_foot", ContactKind::Wrench)];
    let humanoid = with_forces(&load_floating("grid_atlas"), &[], &feet);
    let kernels = vec![KernelKind::RneaGrad, KernelKind::FdGrad, KernelKind::ContactFdGrad];
    let lower = |m: &Model, calls: ir::Calls| {
        let options = LowerOptions { kernels: kernels.clone(), calls, ..Default::default() };
        ir::lower(m, g, &options).unwrap()
    };
    let ops =
        |module: &ir::Module| module.function(KernelKind::ContactFdGrad).unwrap().counts().total();
    let calls = |module: &ir::Module, kind: KernelKind| {
        module
            .function(kind)
            .unwrap()
            .call
            .as_ref()
            .map(|c| (c.callees.clone(), c.rest.nodes.len(), c.shared.len()))
    };
    let auto = lower(&humanoid, ir::Calls::Auto);
    let asked = lower(&humanoid, ir::Calls::RneaGrad);
    assert!(
        ops(&auto) >= ir::CALLS_RNEA_GRAD_MIN_OPS,
        "the humanoid's contact_fd_grad: {}",
        ops(&auto)
    );
    for kind in [KernelKind::FdGrad, KernelKind::ContactFdGrad] {
        let call = calls(&auto, kind);
        assert_eq!(
            call.as_ref().map(|c| c.0.clone()),
            Some(vec![KernelKind::RneaGrad]),
            "{kind:?}"
        );
        assert!(call.as_ref().is_some_and(|c| c.2 > 0), "{kind:?} reads rnea_grad's first values");
        assert_eq!(call, calls(&asked, kind), "{kind:?}: auto against calls = rnea_grad");
    }
    let standing = hyq_standing_step();
    let hyq = lower(&standing, ir::Calls::Auto);
    assert!(
        ops(&hyq) < ir::CALLS_RNEA_GRAD_MIN_OPS,
        "the standing HyQ's contact_fd_grad: {}",
        ops(&hyq)
    );
    for kind in [KernelKind::FdGrad, KernelKind::ContactFdGrad] {
        assert_eq!(calls(&hyq, kind), None, "{kind:?} on the standing HyQ");
    }
    println!(
        "contact_fd_grad operations: humanoid {}, standing HyQ {}; the bound {}",
        ops(&auto),
        ops(&hyq),
        ir::CALLS_RNEA_GRAD_MIN_OPS
    );
}

/// A step under contacts records its contact kernel's routes: `step` `contact_fd`'s solve,
/// `step_grad` `contact_fd_grad`'s gradient formulation and solve. Their Rust code calls
/// those kernels, and their whole graphs, which WGSL, `eval` and `info` read, hold the
/// same routes (the humanoid's step took the direct M⁻¹ before: 49,445 operations, 23,500
/// now, with `contact_fd` at 23,095). A step without contacts has no solve.
#[test]
fn a_contact_step_takes_its_contact_kernels_routes() {
    let g = reference::DEFAULT_GRAVITY;
    let standing = hyq_standing_step();
    let order =
        [KernelKind::Step, KernelKind::StepGrad, KernelKind::ContactFd, KernelKind::ContactFdGrad];
    let kernels = order.to_vec();
    let module = ir::lower(&standing, g, &LowerOptions { kernels, ..Default::default() }).unwrap();
    let kinds: Vec<KernelKind> = module.functions.iter().map(|f| f.kind).collect();
    assert_eq!(kinds, order, "the module keeps its order");
    let (step, contact) = (
        module.function(KernelKind::Step).unwrap(),
        module.function(KernelKind::ContactFd).unwrap(),
    );
    assert_eq!(step.solve, Some(ir::Solve::Crba), "floating HyQ is 4 joints deep");
    assert_eq!(step.solve, contact.solve);
    let (step_grad, contact_grad) = (
        module.function(KernelKind::StepGrad).unwrap(),
        module.function(KernelKind::ContactFdGrad).unwrap(),
    );
    assert!(contact_grad.gradient.is_some() && contact_grad.solve.is_some());
    let routes = |f: &ir::Function| (f.gradient, f.solve);
    assert_eq!(routes(step_grad), routes(contact_grad));
    assert!(step_grad.call.is_some(), "step_grad calls contact_fd_grad");
    let minv = LowerOptions {
        kernels: vec![KernelKind::Step],
        solve: ir::Solve::Minv,
        ..Default::default()
    };
    let by_minv = ir::lower(&standing, g, &minv).unwrap();
    let by_minv = by_minv.function(KernelKind::Step).unwrap();
    assert!(
        step.nodes.len() < by_minv.nodes.len(),
        "the factorisation's step has fewer nodes ({} against {})",
        step.nodes.len(),
        by_minv.nodes.len()
    );
    let free = with_step(&load_floating("grid_hyq"), Scheme::SemiImplicitEuler, 0.01);
    let kernels = vec![KernelKind::Step];
    let module = ir::lower(&free, g, &LowerOptions { kernels, ..Default::default() }).unwrap();
    assert_eq!(module.function(KernelKind::Step).unwrap().solve, None, "no contacts, no solve");
}

/// `info`'s counts skip a step kernel whose contact kernel is over the node limit without
/// building it: the step's graph holds its contact kernel's. The limit is found by
/// raising it until `contact_fd` fits, keeping the last one at which `fd` fit and
/// `contact_fd` did not.
#[test]
fn info_skips_a_step_whose_contact_kernel_is_too_large() {
    let g = reference::DEFAULT_GRAVITY;
    let standing = hyq_standing_step();
    let stats = |limit| {
        ir::stats(&standing, g, ir::Gradient::Auto, ir::Solve::Auto, ir::Calls::Auto, limit)
    };
    let counted = |s: &ir::Stats, k| s.ops.iter().any(|o| o.kernel == k);
    let mut limit = 1_000usize;
    let mut found = None;
    loop {
        let s = stats(limit);
        if counted(&s, KernelKind::ContactFd) {
            break;
        }
        if counted(&s, KernelKind::Fd) {
            found = Some(s);
        }
        limit += limit / 4;
    }
    let s = found.expect("a limit between fd's graph and contact_fd's");
    let reason = |k| s.skipped.iter().find(|x| x.kernel == k).map(|x| x.reason.clone());
    assert!(reason(KernelKind::ContactFd).unwrap().contains("over"), "{:?}", s.skipped);
    assert_eq!(
        reason(KernelKind::Step).as_deref(),
        Some("contains `contact_fd`, which is over the node limit")
    );
    assert!(reason(KernelKind::StepGrad).unwrap().starts_with("contains `"), "{:?}", s.skipped);
}

/// A scene's `[step]` and `[actuation]` mistakes are errors that say what is wrong.
#[test]
fn bad_steps_are_errors() {
    let load = |scene: &str| load_scene_text("grid_hyq", scene);
    let cases = [
        ("[step]\ndt = -0.01\n", "not a finite, positive"),
        ("[step]\ndt = 0.0\n", "not a finite, positive"),
        ("static = true\n[step]\ndt = 0.01\n", "with `static = true`"),
        ("[step]\ndt = 0.01\n[actuation]\njoints = [\"lf_haa\"]\n", "closest joints: lf_haa_joint"),
        (
            "[step]\ndt = 0.01\n[actuation]\njoints = [\"lf_haa_joint\", \"lf_haa_joint\"]\n",
            "twice",
        ),
    ];
    for (scene, says) in cases {
        let err = load(scene).err().unwrap_or_else(|| panic!("{scene:?} loads"));
        assert!(err.contains(says), "{scene:?}: {err}");
    }
    assert!(
        Scene::parse("s.toml", "[step]\nscheme = \"leapfrog\"\ndt = 0.01\n").is_err(),
        "an unknown scheme"
    );
    let m = load("floating_base = true\n[step]\ndt = 0.01\n[actuation]\njoints = [\"lf_kfe_joint\", \"root_joint\"]\n").unwrap();
    assert_eq!(m.actuated().len(), 7, "root_joint stands for its six coordinates");
    assert_eq!(m.specialisation.step, Some(StepSpec::folded(Scheme::SemiImplicitEuler, 0.01)));
    // A [step] without dt leaves it to run time: the step kernels take it last.
    let m = load("floating_base = true\n[step]\nscheme = \"rk4\"\n").unwrap();
    assert_eq!(m.specialisation.step, Some(StepSpec::at_run_time(Scheme::Rk4)));
    for kind in [KernelKind::Step, KernelKind::StepGrad] {
        assert_eq!(kind.inputs_for(&m.specialisation).last(), Some(&ir::Input::Dt), "{kind}");
    }
}

/// RK4's generated Rust, compiled with rustc and run: iiwa's `step_grad` (both copies) on
/// four states against the reference (the checked-in step scene covers the Euler scheme).
#[test]
fn rk4_step_grad_compiles_and_matches_the_reference() {
    use grid_gen::generate::{generate, Options, Target};
    let model = with_step(&load("grid_iiwa"), Scheme::Rk4, 0.01);
    let lower = LowerOptions { kernels: vec![KernelKind::StepGrad], ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    let said = compile_and_run(
        "rk4",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn main() {
    for k in 0..4 {
        let x: [[f64; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s)));
        let (q, v, a, b) = if has_fma() { unsafe { fma::step_grad(&x[0], &x[1], &x[2]) } } else { portable::step_grad(&x[0], &x[1], &x[2]) };
        let all: Vec<String> = q.iter().chain(&v).chain(a.as_flattened()).chain(b.as_flattened()).map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#,
        ]
        .concat(),
    );
    let nv = model.nv();
    // f64 kernels are held to 1e-12 of the reference, as everywhere.
    let worst = worst_line_error(&said, 4, 0, 1e-12, |k, _| {
        let x: Vec<Vec<f64>> =
            (0..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        let g = reference::DEFAULT_GRAVITY;
        let want = reference_outputs(KernelKind::StepGrad, &model, &x[0], &x[1], &x[2], g);
        want.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect()
    });
    println!("iiwa RK4 step_grad, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// A forced step's generated Rust, compiled with rustc and run: iiwa holding its tool by a
/// rigid wrench contact, with fext on its third link, `step_grad` by both Euler schemes
/// (whose programs store different rows of A and B) on four states against the reference,
/// the contact's force λ and its derivatives included.
#[test]
fn forced_step_grad_compiles_and_matches_the_reference() {
    let iiwa =
        with_forces(&load("grid_iiwa"), &["iiwa_joint_3"], &[("iiwa_link_7", ContactKind::Wrench)]);
    for scheme in [Scheme::SemiImplicitEuler, Scheme::ExplicitEuler] {
        forced_step_grad_compiles(&iiwa, scheme);
    }
}

fn forced_step_grad_compiles(iiwa: &Model, scheme: Scheme) {
    use grid_gen::generate::{generate, Options, Target};
    let model = with_step(iiwa, scheme, 0.01);
    let lower = LowerOptions { kernels: vec![KernelKind::StepGrad], ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    assert!(
        file.contents.contains(
            "`step_grad(q, qd, tau, fext) -> (q_next, qd_next, a, b, lambda, dlambda_dx, dlambda_du)`"
        ),
        "the API summary names fext, no lambda input, and the step's lambda outputs"
    );
    let said = compile_and_run(
        "forcedstep",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn main() {
    for k in 0..4 {
        let x: [[f64; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s)));
        let fext: [f64; 6 * NFEXT] = std::array::from_fn(|i| 10.0 * state(k, i, 3));
        let (q, v, a, b, lam, dlx, dlu) = step_grad(&x[0], &x[1], &x[2], &fext);
        let all: Vec<String> = q.iter().chain(&v).chain(a.as_flattened()).chain(b.as_flattened())
            .chain(&lam).chain(dlx.as_flattened()).chain(dlu.as_flattened()).map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#,
        ]
        .concat(),
    );
    let nv = model.nv();
    // f64 kernels are held to 1e-12 of the reference, as everywhere (measured 3.7e-15
    // on these states, whose contact Schur complement is well conditioned).
    let worst = worst_line_error(&said, 4, 0, 1e-12, |k, _| {
        let x: Vec<Vec<f64>> =
            (0..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        let fext: Vec<f64> = (0..6).map(|i| 10.0 * seeded_state(k, i, 3)).collect();
        let ext = reference::External { fext: &fext, lambda: &[] };
        let g = reference::DEFAULT_GRAVITY;
        let want =
            reference_outputs_with(KernelKind::StepGrad, &model, &x[0], &x[1], &x[2], g, ext);
        want.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect()
    });
    println!(
        "iiwa contact step_grad ({scheme:?}), compiled: worst {worst:.2e} from the reference (bound 1e-12)"
    );
}

/// `fd_grad` with `dqdd_dtau` (`[fd_grad] minv = true`): M⁻¹ from the route `fd_grad` took,
/// both solves, fixed, floating and coupled robots, against the reference's M⁻¹; the other
/// outputs unchanged; and the generated Rust returns it (compiled by rustc, run).
#[test]
fn fd_grad_can_return_minv() {
    let fixtures = repo().join("tests/fixtures");
    let cases: Vec<(&str, Model)> = vec![
        ("iiwa", load("grid_iiwa")),
        ("hyq floating", load_floating("grid_hyq")),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
    ];
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(67);
    for (name, model) in &cases {
        let mut m = model.clone();
        m.specialisation.fd_grad_minv = true;
        for solve in [ir::Solve::Minv, ir::Solve::Ltdl] {
            let options = LowerOptions {
                kernels: vec![KernelKind::FdGrad],
                solve,
                ..LowerOptions::default()
            };
            let with = ir::lower(&m, g, &options).unwrap();
            let without = ir::lower(model, g, &options).unwrap();
            let f = with.function(KernelKind::FdGrad).unwrap();
            assert_eq!(
                f.outputs.iter().map(|o| o.name).collect::<Vec<_>>(),
                ["qdd", "dqdd_dq", "dqdd_dqd", "dqdd_dtau"]
            );
            let nv = m.nv();
            let q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
            let (qd, tau) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -5.0, 5.0));
            let got = f.eval(&[&q, &qd, &tau]);
            let plain = without.function(KernelKind::FdGrad).unwrap().eval(&[&q, &qd, &tau]);
            assert_eq!(&got[..3], &plain[..], "{name}: the other outputs are the same graph's");
            let e = rel_err(&DMatrix::from_row_slice(nv, nv, &got[3]), &reference::minv(&m, &q));
            assert!(e < 1e-12, "{name} {solve:?}: dqdd_dtau {e:.2e}");
        }
    }
    let mut m = load("grid_iiwa");
    m.specialisation.fd_grad_minv = true;
    let options = grid_gen::generate::Options {
        targets: vec![grid_gen::generate::Target::Rust],
        lower: LowerOptions { kernels: vec![KernelKind::FdGrad], ..LowerOptions::default() },
        ..grid_gen::generate::Options::default()
    };
    let file = grid_gen::generate::generate(&m, &options).unwrap().remove(0);
    assert!(
        file.contents.contains("`fd_grad(q, qd, tau) -> (qdd, dqdd_dq, dqdd_dqd, dqdd_dtau)`"),
        "the API summary names it"
    );
    let said = compile_and_run(
        "fdminv",
        &file.contents,
        r#"mod robot { include!("robot.rs"); }
fn main() {
    let q = [0.1, -0.4, 0.3, 1.2, -0.5, 0.6, 0.2];
    let (_, _, _, minv) = robot::fd_grad(&q, &[0.0; 7], &[0.0; 7]);
    let all: Vec<String> = minv.as_flattened().iter().map(|x| format!("{x:?}")).collect();
    println!("{}", all.join(" "));
}
"#,
    );
    let got: Vec<f64> = said.split_whitespace().map(|x| x.parse().unwrap()).collect();
    let want = reference::minv(&m, &[0.1, -0.4, 0.3, 1.2, -0.5, 0.6, 0.2]);
    assert!(rel_err(&DMatrix::from_row_slice(7, 7, &got), &want) < 1e-12);
}

/// A step whose time step is an input (`[step]` without dt) gives, at each dt, the values of
/// the step with that dt folded in: every scheme, fixed, floating, spherical and coupled
/// robots and robots with fext and rigid contacts, two time steps a state (one library
/// for a horizon whose knots differ in dt). Both graphs are the same operations but for
/// where `c dt` is rounded (RK4's `dt / 6` weights once at generation time, or `(1/6) dt`
/// at run time), so they agree to a few ulps; each is also held to the reference at its dt.
#[test]
fn runtime_dt_steps_match_folded_ones() {
    let fixtures = repo().join("tests/fixtures");
    let mut cases: Vec<(&str, Model)> = vec![
        ("iiwa", load("grid_iiwa")),
        ("hyq floating", load_floating("grid_hyq")),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true)),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
    ];
    cases.extend(forced_cases());
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(61);
    let (mut worst_folded, mut worst_reference): (f64, f64) = (0.0, 0.0);
    let kernels = vec![KernelKind::Step, KernelKind::StepGrad];
    let options = LowerOptions { kernels, ..LowerOptions::default() };
    for (name, model) in &cases {
        // RK4's floating HyQ graphs take a minute each to lower; RK4's run-time dt is the
        // Euler schemes' multipliers, four times, and the smaller robots check it.
        let schemes: &[Scheme] = match name.starts_with("hyq") {
            true => &[Scheme::SemiImplicitEuler, Scheme::ExplicitEuler],
            false => &Scheme::ALL,
        };
        for &scheme in schemes {
            let runtime = ir::lower(&with_runtime_step(model, scheme), g, &options).unwrap();
            let nv = model.nv();
            let mut q = model.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
            for &s in &model.spherical {
                let at = model.group_q(s).0;
                q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
            }
            let (qd, u, fext) = (
                rng.vec(nv, -2.0, 2.0),
                rng.vec(model.nu(), -10.0, 10.0),
                rng.vec(6 * model.nfext(), -20.0, 20.0),
            );
            let ext = reference::External { fext: &fext, lambda: &[] };
            // One dt on floating HyQ, whose contact step_grad takes seconds to lower.
            let dts: &[f64] = if name.starts_with("hyq") { &[0.03] } else { &[1e-3, 0.03] };
            for &dt in dts {
                let folded_model = with_step(model, scheme, dt);
                let folded = ir::lower(&folded_model, g, &options).unwrap();
                for (f, fixed) in runtime.functions.iter().zip(&folded.functions) {
                    assert_eq!(f.inputs().last(), Some(&ir::Input::Dt), "{name} {}", f.kind);
                    assert!(!fixed.inputs().contains(&ir::Input::Dt), "{name} {}", f.kind);
                    let got = f.eval(&kernel_args_dt(f.inputs(), &q, &qd, &u, ext, &[dt]));
                    let want = fixed.eval(&kernel_args_with(fixed.inputs(), &q, &qd, &u, ext));
                    let reference =
                        reference_step_outputs(f.kind, &folded_model, &q, &qd, &u, g, &fext, dt);
                    for (((o, got), want), reference) in
                        f.outputs.iter().zip(&got).zip(&want).zip(&reference)
                    {
                        let got = output_matrix(o.shape, nv, got);
                        let e = rel_err(&got, &output_matrix(o.shape, nv, want));
                        worst_folded = worst_folded.max(e);
                        let what =
                            format!("{name} {} dt {dt} {} {}", scheme.name(), f.kind, o.name);
                        // An ulp of a multiplier, carried through the step (measured 4.1e-16).
                        assert!(e < 1e-14, "{what}: {e:.2e} from the folded step");
                        let e = rel_err(&got, reference);
                        worst_reference = worst_reference.max(e);
                        // As forced_step_kernels_match_the_reference (the contacts' Schur
                        // complement against the reference's KKT LU).
                        assert!(e < 5e-11, "{what}: {e:.2e} from the reference");
                    }
                }
            }
        }
    }
    println!(
        "run-time dt: worst {worst_folded:.2e} from the folded step (bound 1e-14), {worst_reference:.2e} from the reference (bound 5e-11)"
    );
}

/// A run-time dt costs a multiplication where the folded step has a constant: the graphs
/// have the same operations but for a handful (floating HyQ with the Euler schemes, iiwa
/// with RK4), so the one library that serves every dt is as fast as the folded ones.
#[test]
fn runtime_dt_costs_a_few_operations() {
    let g = reference::DEFAULT_GRAVITY;
    let options = LowerOptions {
        kernels: vec![KernelKind::Step, KernelKind::StepGrad],
        ..LowerOptions::default()
    };
    let cases = [
        ("floating HyQ", Scheme::SemiImplicitEuler),
        ("floating HyQ", Scheme::ExplicitEuler),
        ("iiwa", Scheme::Rk4),
    ];
    for (name, scheme) in cases {
        let model = if name == "iiwa" { load("grid_iiwa") } else { load_floating("grid_hyq") };
        let runtime = ir::lower(&with_runtime_step(&model, scheme), g, &options).unwrap();
        let folded = ir::lower(&with_step(&model, scheme, 0.01), g, &options).unwrap();
        for (f, fixed) in runtime.functions.iter().zip(&folded.functions) {
            let ops = |f: &ir::Function| {
                (0..f.nodes.len()).filter(|&i| f.is_operation(ir::Id(i as u32))).count()
            };
            let (a, b) = (ops(f), ops(fixed));
            let what = format!("{name} {} {}", scheme.name(), f.kind);
            println!("{what}: {a} operations with a run-time dt, {b} folded");
            // Each distinct `c dt` the folded step reads as a constant is one multiplication
            // at run time: none or one for the Euler schemes (dt itself is an input), three
            // for RK4 (dt / 2, dt / 6, dt / 3). Measured on floating HyQ: 0, 1 and 3.
            assert!(a <= b + 3, "{what}: {a} against {b}");
        }
    }
}

/// A run-time dt through the generated Rust, compiled with rustc and run: iiwa with fext on
/// its third link (so `dt` follows `fext`), semi-implicit `step_grad` on four states, each
/// with its own dt, called one state at a time in both copies and as one `Lanes<4>` call
/// (each lane its own dt), against the reference at each state's dt.
#[test]
fn runtime_dt_step_grad_compiles_and_matches_the_reference() {
    use grid_gen::generate::{generate, Options, Target};
    let iiwa = with_forces(&load("grid_iiwa"), &["iiwa_joint_3"], &[]);
    let model = with_runtime_step(&iiwa, Scheme::SemiImplicitEuler);
    let lower = LowerOptions { kernels: vec![KernelKind::StepGrad], ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    assert!(
        file.contents.contains("`step_grad(q, qd, tau, fext, dt) -> (q_next, qd_next, a, b)`"),
        "the API summary names dt last"
    );
    assert!(!file.contents.contains("pub const DT"), "no folded DT");
    let said = compile_and_run(
        "runtimedt",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn dt(k: usize) -> f64 { 0.002 + 0.01 * k as f64 }
fn args(k: usize) -> ([[f64; NV]; 3], [f64; 6 * NFEXT]) {
    (std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s))), std::array::from_fn(|i| 10.0 * state(k, i, 3)))
}
fn main() {
    let flat = |q: &[f64], v: &[f64], a: &[[f64; NX]], b: &[[f64; NU]]| -> Vec<f64> { q.iter().chain(v).chain(a.as_flattened()).chain(b.as_flattened()).copied().collect() };
    let lane = |x: &[Lanes<4>], l: usize| -> Vec<f64> { x.iter().map(|v| v.0[l]).collect() };
    let st: Vec<_> = (0..4).map(args).collect();
    let x: [[Lanes<4>; NV]; 3] = std::array::from_fn(|s| std::array::from_fn(|i| Lanes(std::array::from_fn(|l| st[l].0[s][i]))));
    let fext: [Lanes<4>; 6 * NFEXT] = std::array::from_fn(|i| Lanes(std::array::from_fn(|l| st[l].1[i])));
    let (lq, lv, la, lb) = portable::step_grad(&x[0], &x[1], &x[2], &fext, &[Lanes(std::array::from_fn(dt))]);
    for k in 0..4 {
        let (x, fext) = &st[k];
        let (q, v, a, b) = step_grad(&x[0], &x[1], &x[2], fext, &[dt(k)]);
        let (pq, pv, pa, pb) = portable::step_grad(&x[0], &x[1], &x[2], fext, &[dt(k)]);
        let one = flat(&q, &v, &a, &b);
        assert_eq!(flat(&pq, &pv, &pa, &pb).len(), one.len());
        let lanes: Vec<f64> = lane(&lq, k).into_iter().chain(lane(&lv, k)).chain(lane(la.as_flattened(), k)).chain(lane(lb.as_flattened(), k)).collect();
        let portable = flat(&pq, &pv, &pa, &pb);
        assert!(lanes.iter().zip(&portable).all(|(a, b)| a.to_bits() == b.to_bits()), "state {k}: Lanes<4> differs from a portable call");
        let all: Vec<String> = one.iter().chain(&portable).map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#,
        ]
        .concat(),
    );
    let nv = model.nv();
    // f64 kernels are held to 1e-12 of the reference, as everywhere; the dispatched copy
    // and the portable one are printed one after the other and both checked.
    let worst = worst_line_error(&said, 4, 0, 1e-12, |k, _| {
        let x: Vec<Vec<f64>> =
            (0..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        let fext: Vec<f64> = (0..6).map(|i| 10.0 * seeded_state(k, i, 3)).collect();
        let g = reference::DEFAULT_GRAVITY;
        let dt = 0.002 + 0.01 * k as f64;
        let want =
            reference_step_outputs(KernelKind::StepGrad, &model, &x[0], &x[1], &x[2], g, &fext, dt);
        let one: Vec<f64> = want.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect();
        one.iter().chain(&one).copied().collect()
    });
    println!("iiwa step_grad with a run-time dt, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}
