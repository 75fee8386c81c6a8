//! External forces and contact forces: the reference against Pinocchio 4.1
//! (`rnea`, `aba`, `computeRNEADerivatives`, `computeABADerivatives` with `fext`, the
//! contacts' λ-fixed-in-world terms, `getJointJacobian`, `getFrameJacobian`) on fixed and
//! floating robots with point and wrench contacts; the λ-fixed q-derivatives against
//! central differences on the manifold; the kernels' IR against the reference for every
//! gradient formulation and solve; and the scenes' bad inputs.

use grid_gen::ir::{self, Gradient, KernelKind, LowerOptions, Solve};
use grid_gen::model::ContactKind;
use grid_gen::reference::External;
use grid_gen::{reference, Model, Scene};
use grid_gen_test_support::*;
use nalgebra::DMatrix;

/// The project's bar against Pinocchio: the same f64 dynamics by other routes.
const TOL: f64 = 1e-10;

/// A fixture's robot with its forces declared: fext by Pinocchio's joint names (`*`:
/// every body), contacts by frame.
fn fixture_model(name: &str, fx: &serde_json::Value) -> Model {
    let fixtures = repo().join("tests/fixtures");
    let model = match name {
        "grid_iiwa" => load("grid_iiwa"),
        "grid_hyq.floating" => load_floating("grid_hyq"),
        "go2.floating" => load_floating_urdf(&fixtures.join("go2.urdf")),
        "grid_atlas.floating" => load_floating("grid_atlas"),
        _ => unreachable!(),
    };
    let fext: Vec<&str> = fx["fext"]
        .as_array()
        .map_or(Vec::new(), |a| a.iter().map(|n| n.as_str().unwrap()).collect());
    let contacts: Vec<(&str, ContactKind)> = fx["contacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (c["frame"].as_str().unwrap(), ContactKind::parse(c["type"].as_str().unwrap()).unwrap())
        })
        .collect();
    with_forces(&model, &fext, &contacts)
}

const FIXTURES: [&str; 4] =
    ["grid_iiwa", "grid_hyq.floating", "go2.floating", "grid_atlas.floating"];

/// One fixture state in grid-gen's order: (q, q̇, q̈, τ, fext, λ) and the fixture's
/// permutation to reorder its matrices' rows and columns.
struct State {
    q: Vec<f64>,
    qd: Vec<f64>,
    qdd: Vec<f64>,
    tau: Vec<f64>,
    fext: Vec<f64>,
    lambda: Vec<f64>,
}

fn states(model: &Model, fx: &serde_json::Value, name: &str) -> (Vec<State>, Vec<usize>) {
    let perm = fixture_perm(model, fx, name);
    let nv = model.nv();
    let ours = |v: &[f64]| {
        let mut o = vec![0.0; nv];
        for (k, &i) in perm.iter().enumerate() {
            o[i] = v[k];
        }
        o
    };
    let q_of = |v: &[f64]| {
        let (base, angles) = if model.floating {
            (v[..7].try_into().unwrap(), &v[7..])
        } else {
            ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], v)
        };
        let per =
            if model.floating { [vec![0.0; 6], angles.to_vec()].concat() } else { angles.to_vec() };
        model.q_from_joints(&ours(&per), base)
    };
    let states = fx["states"]
        .as_array()
        .unwrap()
        .iter()
        .map(|st| State {
            q: q_of(&vec_of(&st["q"])),
            qd: ours(&vec_of(&st["qd"])),
            qdd: ours(&vec_of(&st["qdd"])),
            tau: ours(&vec_of(&st["tau"])),
            fext: if st["fext"].is_null() { Vec::new() } else { vec_of(&st["fext"]) },
            lambda: vec_of(&st["lambda"]),
        })
        .collect();
    (states, perm)
}

/// A fixture matrix with its rows (and, for `square`, columns) in grid-gen's order.
fn reorder(m: &DMatrix<f64>, perm: &[usize], square: bool) -> DMatrix<f64> {
    let at = |i: usize| perm.iter().position(|&p| p == i).unwrap();
    DMatrix::from_fn(m.nrows(), m.ncols(), |r, c| m[(at(r), if square { at(c) } else { c })])
}

#[test]
fn reference_forces_match_pinocchio() {
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for name in FIXTURES {
        let fx = fixture(&format!("{name}.forces.pinocchio.json"));
        let model = fixture_model(name, &fx);
        let g: [f64; 3] = vec_of(&fx["gravity"]).try_into().unwrap();
        let (states, perm) = states(&model, &fx, name);
        for (s, (st, want)) in states.iter().zip(fx["states"].as_array().unwrap()).enumerate() {
            let ext = External { fext: &st.fext, lambda: &st.lambda };
            let rnea = reference::rnea_with(&model, &st.q, &st.qd, &st.qdd, g, ext);
            let (dq, dqd) =
                reference::rnea_derivatives_with(&model, &st.q, &st.qd, &st.qdd, g, ext);
            let (fd, fdq, fdqd) = reference::forward_dynamics_derivatives_with(
                &model, &st.q, &st.qd, &st.tau, g, ext,
            );
            let d = reference::force_derivatives(&model, &st.q);
            let theirs = |key: &str, square: bool| reorder(&mat_of(&want[key]), &perm, square);
            let pairs: Vec<(&str, DMatrix<f64>, DMatrix<f64>)> = vec![
                ("rnea", col(&rnea), reorder(&col(&vec_of(&want["rnea"])), &perm, false)),
                ("drnea_dq", dq, theirs("drnea_dq", true)),
                ("drnea_dqd", dqd, theirs("drnea_dqd", true)),
                ("drnea_dfext", d.dc_dfext, theirs("drnea_dfext", false)),
                ("drnea_dlambda", d.dc_dlambda, theirs("drnea_dlambda", false)),
                ("fd", col(&fd), reorder(&col(&vec_of(&want["fd"])), &perm, false)),
                ("dfd_dq", fdq, theirs("dfd_dq", true)),
                ("dfd_dqd", fdqd, theirs("dfd_dqd", true)),
                ("dfd_dfext", d.dqdd_dfext, theirs("dfd_dfext", false)),
                ("dfd_dlambda", d.dqdd_dlambda, theirs("dfd_dlambda", false)),
            ];
            for (what, ours, theirs) in pairs {
                assert_eq!(ours.shape(), theirs.shape(), "{name} state {s} {what}");
                let e = rel_err(&ours, &theirs);
                worst = worst.max(e);
                assert!(e < TOL, "{name} state {s} {what}: {e:.2e}");
                checked += 1;
            }
        }
    }
    assert!(checked >= 4 * 8 * 10, "every fixture state checked ({checked})");
    println!("worst reference force quantity against Pinocchio: {worst:.2e} over {checked} (bound {TOL:e})");
}

/// ∂c/∂q with λ fixed in world axes (the `J_bᵀ (m ×* f)` terms) and fext fixed in the
/// bodies' frames, against central differences of the reference's c on the manifold
/// (Pinocchio's `integrate`), and ∂c/∂λ, ∂c/∂fext against differences in the forces.
#[test]
fn force_derivatives_match_central_differences() {
    let g = reference::DEFAULT_GRAVITY;
    let mut worst: f64 = 0.0;
    for name in FIXTURES {
        let fx = fixture(&format!("{name}.forces.pinocchio.json"));
        let model = fixture_model(name, &fx);
        let (states, _) = states(&model, &fx, name);
        let st = &states[0];
        let nv = model.nv();
        let c = |q: &[f64], fext: &[f64], lambda: &[f64]| {
            reference::rnea_with(&model, q, &st.qd, &st.qdd, g, External { fext, lambda })
        };
        let (dq, _) = reference::rnea_derivatives_with(
            &model,
            &st.q,
            &st.qd,
            &st.qdd,
            g,
            External { fext: &st.fext, lambda: &st.lambda },
        );
        // h = 1e-6 balances the O(h²) truncation against rounding of c (~1e3 here).
        let h = 1e-6;
        let mut num = DMatrix::zeros(nv, nv);
        for u in 0..nv {
            let mut e = vec![0.0; nv];
            e[u] = h;
            let plus = c(&reference::integrate(&model, &st.q, &e), &st.fext, &st.lambda);
            e[u] = -h;
            let minus = c(&reference::integrate(&model, &st.q, &e), &st.fext, &st.lambda);
            for i in 0..nv {
                num[(i, u)] = (plus[i] - minus[i]) / (2.0 * h);
            }
        }
        let e = rel_err(&dq, &num);
        worst = worst.max(e);
        assert!(e < 1e-7, "{name}: dc/dq against central differences {e:.2e}");
        // c is affine in the forces: one-sided differences of size 1 are exact to rounding.
        let d = reference::force_derivatives(&model, &st.q);
        for (what, analytic, len) in
            [("fext", &d.dc_dfext, st.fext.len()), ("lambda", &d.dc_dlambda, st.lambda.len())]
        {
            let base = c(&st.q, &st.fext, &st.lambda);
            let mut num = DMatrix::zeros(nv, len);
            for k in 0..len {
                let (mut f, mut l) = (st.fext.clone(), st.lambda.clone());
                if what == "fext" {
                    f[k] += 1.0;
                } else {
                    l[k] += 1.0;
                }
                let moved = c(&st.q, &f, &l);
                for i in 0..nv {
                    num[(i, k)] = moved[i] - base[i];
                }
            }
            let e = rel_err(analytic, &num);
            worst = worst.max(e);
            assert!(e < 1e-9, "{name}: dc/d{what} {e:.2e}");
        }
    }
    println!("worst force derivative against differences: {worst:.2e}");
}

/// A random configuration: coordinates in ±3, a random base pose, unit quaternions for
/// spherical joints.
fn random_config(m: &Model, rng: &mut Rng) -> Vec<f64> {
    let mut q = m.q_from_joints(&rng.vec(m.nv(), -3.0, 3.0), rng.base_pose());
    for &s in &m.spherical {
        let at = m.group_q(s).0;
        q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
    }
    q
}

/// Random forces for a model: N(0, 10)-sized fext and N(0, 50)-sized λ, uniformly drawn.
fn random_forces(model: &Model, rng: &mut Rng) -> (Vec<f64>, Vec<f64>) {
    (rng.vec(6 * model.nfext(), -20.0, 20.0), rng.vec(model.nlambda(), -100.0, 100.0))
}

/// The dynamics kernels' IR with forces against the reference: every fixture robot, a
/// coupled mimic arm and a floating spherical arm with fext on their bodies, every
/// gradient formulation and every fd_grad solve.
#[test]
fn force_kernels_match_the_reference() {
    let fixtures = repo().join("tests/fixtures");
    let mut cases: Vec<(String, Model)> = FIXTURES
        .iter()
        .map(|name| {
            let fx = fixture(&format!("{name}.forces.pinocchio.json"));
            (name.to_string(), fixture_model(name, &fx))
        })
        .collect();
    let mimic = load_coupled_urdf(&fixtures.join("mimic_arm.urdf"));
    let all: Vec<String> = mimic.body_joint_names().iter().map(|s| s.to_string()).collect();
    let all: Vec<&str> = all.iter().map(String::as_str).collect();
    cases.push(("mimic_arm coupled".into(), with_forces(&mimic, &all, &[])));
    let ball = load_urdf(&fixtures.join("ball_arm.urdf"), true);
    let ball_frames: Vec<String> =
        ball.frames.iter().filter(|f| f.body.is_some()).map(|f| f.name.clone()).collect();
    let ball_joints: Vec<String> = ball.body_joint_names().iter().map(|s| s.to_string()).collect();
    let ball_joints: Vec<&str> = ball_joints.iter().map(String::as_str).collect();
    let last = ball_frames.last().unwrap().as_str();
    cases.push((
        "ball_arm floating".into(),
        with_forces(&ball, &ball_joints, &[(last, ContactKind::Wrench)]),
    ));
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(30);
    let mut worst: f64 = 0.0;
    let kernels = vec![KernelKind::Rnea, KernelKind::RneaGrad, KernelKind::Fd, KernelKind::FdGrad];
    for (name, m) in &cases {
        for (gradient, solve) in [
            (Gradient::Columns, Solve::Minv),
            (Gradient::Idsva, Solve::Ltdl),
            (Gradient::Columns, Solve::Crba),
            (Gradient::World, Solve::Minv),
        ] {
            let options = LowerOptions {
                kernels: kernels.clone(),
                gradient,
                solve,
                ..LowerOptions::default()
            };
            let module = ir::lower(m, g, &options).unwrap();
            let nv = m.nv();
            for state in 0..2 {
                let q = random_config(m, &mut rng);
                let (qd, u) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -10.0, 10.0));
                let (fext, lambda) = random_forces(m, &mut rng);
                let ext = External { fext: &fext, lambda: &lambda };
                for f in &module.functions {
                    assert!(
                        f.inputs().contains(&ir::Input::Fext) == (m.nfext() > 0),
                        "{name} {}: takes fext",
                        f.kind
                    );
                    let got = f.eval(&kernel_args_with(f.inputs(), &q, &qd, &u, ext));
                    let want = reference_outputs_with(f.kind, m, &q, &qd, &u, g, ext);
                    assert_eq!(got.len(), want.len(), "{name} {}: outputs", f.kind);
                    for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                        let got = DMatrix::from_row_slice(want.nrows(), want.ncols(), got);
                        let e = rel_err(&got, want);
                        worst = worst.max(e);
                        // The same f64 dynamics by other routes; Crba's q̈ solves with M
                        // (cond(M) ~ 1e3 on these robots, see `ir::CRBA_MAX_DEPTH`).
                        assert!(
                            e < 1e-11,
                            "{name} {gradient:?} {solve:?} state {state} {} {}: {e:.2e}",
                            f.kind,
                            o.name
                        );
                    }
                }
            }
        }
    }
    println!("worst force kernel against the reference: {worst:.2e} (bound 1e-11)");
}

/// Kernels of a model without forces take no force inputs and have no force outputs.
#[test]
fn kernels_without_forces_are_unchanged() {
    let m = load("grid_iiwa");
    let module = ir::lower(&m, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
    for f in &module.functions {
        assert_eq!(f.inputs(), f.kind.inputs(), "{}", f.kind);
        assert!(
            f.outputs.iter().all(|o| !o.name.contains("fext") && !o.name.contains("lambda")),
            "{}",
            f.kind
        );
    }
}

/// A scene's `[external_forces]` and `[[contact]]` mistakes are errors that name the entry.
#[test]
fn bad_forces_are_errors() {
    let load = |scene: &str| load_scene_text("grid_hyq", scene);
    let cases = [
        ("[external_forces]\njoints = [\"lf_kfe\"]\n", "closest joints: lf_kfe_joint"),
        ("[external_forces]\njoints = [\"lf_kfe_joint\", \"lf_kfe_joint\"]\n", "twice"),
        ("[external_forces]\njoints = [\"*\", \"lf_kfe_joint\"]\n", "`*` names every body"),
        ("[[contact]]\nframe = \"lf_foot\"\ntype = \"point\"\n", "closest frames"),
        ("[[contact]]\nframe = \"base_link_0\"\ntype = \"point\"\n", "fixed to the world"),
        ("[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"wrench\"\n", "twice"),
        ("drop = [\"lf_lowerleg\"]\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"point\"\n", "which the scene removes"),
    ];
    for (scene, says) in cases {
        let err = load(scene).err().unwrap_or_else(|| panic!("{scene:?} loads"));
        assert!(err.contains(says), "{scene:?}: {err}");
    }
    assert!(
        Scene::parse("s.toml", "[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"line\"\n").is_err(),
        "an unknown contact type"
    );
    let m = load("floating_base = true\n[external_forces]\njoints = [\"*\"]\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"point\"\n").unwrap();
    assert_eq!(m.nfext(), 13, "`*`: the base and twelve leg bodies");
    assert_eq!(m.nlambda(), 3);
}

/// The generated Rust with forces, compiled by rustc and run: floating HyQ with fext on
/// every body and its four lower legs as point contacts, `rnea_grad` and `fd_grad` (both
/// copies) on four states against the reference; the module's force constants.
#[test]
fn force_kernels_compile_and_match_the_reference() {
    use grid_gen::generate::{generate, Options, Target};
    let legs: Vec<String> =
        ["lf", "rf", "lh", "rh"].iter().map(|l| format!("{l}_lowerleg")).collect();
    let contacts: Vec<(&str, ContactKind)> =
        legs.iter().map(|l| (l.as_str(), ContactKind::Point)).collect();
    let hyq = load_floating("grid_hyq");
    let all: Vec<String> = hyq.body_joint_names().iter().map(|s| s.to_string()).collect();
    let all: Vec<&str> = all.iter().map(String::as_str).collect();
    let model = with_forces(&hyq, &all, &contacts);
    let lower = LowerOptions {
        kernels: vec![KernelKind::RneaGrad, KernelKind::FdGrad],
        ..LowerOptions::default()
    };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    for needle in [
        "pub const NFEXT: usize = 13;",
        "pub const NLAMBDA: usize = 12;",
        "(\"lf_lowerleg\", \"point\")",
        "fext: &[T; 6 * NFEXT]",
    ] {
        assert!(file.contents.contains(needle), "the module has {needle}");
    }
    let said = compile_and_run(
        "forces",
        &file.contents,
        &[
            "mod robot { include!(\"robot.rs\"); }\nuse robot::*;\n",
            SEEDED_STATE_RS,
            r#"fn main() {
    for k in 0..4 {
        let mut q: [f64; NQ] = std::array::from_fn(|i| state(k, i, 0));
        let n = q[3..7].iter().map(|x| x * x).sum::<f64>().sqrt();
        for x in &mut q[3..7] { *x /= n; }
        let x: [[f64; NV]; 2] = std::array::from_fn(|s| std::array::from_fn(|i| state(k, i, s + 1)));
        let f: [f64; 6 * NFEXT] = std::array::from_fn(|i| 10.0 * state(k, i, 3));
        let l: [f64; NLAMBDA] = std::array::from_fn(|i| 50.0 * state(k, i, 4));
        let (dq, dv, df, dl) = if has_fma() { unsafe { fma::rnea_grad(&q, &x[0], &x[1], &f, &l) } } else { portable::rnea_grad(&q, &x[0], &x[1], &f, &l) };
        let (a, aq, av, af, al) = portable::fd_grad(&q, &x[0], &x[1], &f, &l);
        let all: Vec<String> = q.iter().chain(dq.as_flattened()).chain(dv.as_flattened()).chain(df.as_flattened()).chain(dl.as_flattened())
            .chain(&a).chain(aq.as_flattened()).chain(av.as_flattened()).chain(af.as_flattened()).chain(al.as_flattened()).map(|x| format!("{x:?}")).collect();
        println!("{}", all.join(" "));
    }
}
"#,
        ]
        .concat(),
    );
    let (nv, nq) = (model.nv(), model.nq());
    let g = reference::DEFAULT_GRAVITY;
    // f64 kernels are held to 1e-12 of the reference, as everywhere; each line starts with
    // the normalised q the program ran on.
    let worst = worst_line_error(&said, 4, nq, 1e-12, |k, q| {
        let x: Vec<Vec<f64>> =
            (1..3).map(|s| (0..nv).map(|i| seeded_state(k, i, s)).collect()).collect();
        let fext: Vec<f64> = (0..6 * model.nfext()).map(|i| 10.0 * seeded_state(k, i, 3)).collect();
        let lambda: Vec<f64> = (0..model.nlambda()).map(|i| 50.0 * seeded_state(k, i, 4)).collect();
        let ext = External { fext: &fext, lambda: &lambda };
        let mut want =
            reference_outputs_with(KernelKind::RneaGrad, &model, q, &x[0], &x[1], g, ext);
        want.extend(reference_outputs_with(KernelKind::FdGrad, &model, q, &x[0], &x[1], g, ext));
        want.iter().flat_map(|m| m.transpose().as_slice().to_vec()).collect()
    });
    println!("HyQ with forces, compiled: worst {worst:.2e} from the reference (bound 1e-12)");
}

/// Rigid-contact forward dynamics (`constraintDynamics`) and its derivatives
/// (`computeConstraintDynamicsDerivatives`) of the reference against Pinocchio: HyQ and
/// go2 on four point contacts, Atlas on two foot wrenches, iiwa with its tool held.
#[test]
fn reference_contact_dynamics_matches_pinocchio() {
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    for name in FIXTURES {
        let fx = fixture(&format!("{name}.contact.pinocchio.json"));
        let model = fixture_model(name, &fx);
        let g: [f64; 3] = vec_of(&fx["gravity"]).try_into().unwrap();
        let (states, perm) = states(&model, &fx, name);
        for (s, (st, want)) in states.iter().zip(fx["states"].as_array().unwrap()).enumerate() {
            let (sol, d) =
                reference::contact_fd_derivatives(&model, &st.q, &st.qd, &st.tau, g, &[])
                    .expect("independent contacts");
            let square = |key: &str| reorder(&mat_of(&want[key]), &perm, true);
            // λ's rows are the contacts', in both; only its columns are coordinates.
            let by_coordinate =
                |key: &str| reorder(&mat_of(&want[key]).transpose(), &perm, false).transpose();
            let pairs: Vec<(&str, DMatrix<f64>, DMatrix<f64>)> = vec![
                ("qdd", col(&sol.qdd), reorder(&col(&vec_of(&want["qdd"])), &perm, false)),
                ("lambda", col(&sol.lambda), col(&vec_of(&want["lambda"]))),
                ("dqdd_dq", d.dqdd_dq, square("dqdd_dq")),
                ("dqdd_dqd", d.dqdd_dqd, square("dqdd_dqd")),
                ("dqdd_dtau", d.dqdd_dtau, square("dqdd_dtau")),
                ("dlambda_dq", d.dlambda_dq, by_coordinate("dlambda_dq")),
                ("dlambda_dqd", d.dlambda_dqd, by_coordinate("dlambda_dqd")),
                ("dlambda_dtau", d.dlambda_dtau, by_coordinate("dlambda_dtau")),
            ];
            for (what, ours, theirs) in pairs {
                assert_eq!(ours.shape(), theirs.shape(), "{name} state {s} {what}");
                let e = rel_err(&ours, &theirs);
                worst = worst.max(e);
                assert!(e < TOL, "{name} state {s} {what}: {e:.2e}");
                checked += 1;
            }
        }
    }
    assert!(checked >= 4 * 8 * 8, "every fixture state checked ({checked})");
    println!("worst reference contact dynamics against Pinocchio: {worst:.2e} over {checked} (bound {TOL:e})");
}

/// The contacts' acceleration derivatives at fixed q̈ (world screws) against central
/// differences of the acceleration on the manifold, and the acceleration itself against
/// the frame kernels' reference (`frame_classical_acceleration` in LOCAL_WORLD_ALIGNED);
/// on the fixture robots and a coupled mimic arm and a floating spherical arm.
#[test]
fn contact_accelerations_match_frames_and_central_differences() {
    use grid_gen::model::ReferenceFrame;
    let fixtures = repo().join("tests/fixtures");
    let mut cases: Vec<(String, Model)> = FIXTURES
        .iter()
        .map(|name| {
            (
                name.to_string(),
                fixture_model(name, &fixture(&format!("{name}.contact.pinocchio.json"))),
            )
        })
        .collect();
    let mimic = load_coupled_urdf(&fixtures.join("mimic_arm.urdf"));
    let tip = mimic.frames.iter().rev().find(|f| f.body.is_some()).unwrap().name.clone();
    cases.push((
        "mimic_arm coupled".into(),
        with_forces(&mimic, &[], &[(tip.as_str(), ContactKind::Point)]),
    ));
    let ball = load_urdf(&fixtures.join("ball_arm.urdf"), true);
    let tip = ball.frames.iter().rev().find(|f| f.body.is_some()).unwrap().name.clone();
    cases.push((
        "ball_arm floating".into(),
        with_forces(&ball, &[], &[(tip.as_str(), ContactKind::Wrench)]),
    ));
    let mut rng = Rng(31);
    let (mut worst, mut worst_frame): (f64, f64) = (0.0, 0.0);
    for (name, m) in &cases {
        let contacts = &m.specialisation.contacts;
        let nv = m.nv();
        let q = random_config(m, &mut rng);
        let (qd, qdd) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -5.0, 5.0));
        let acc =
            |q: &[f64], qd: &[f64]| reference::contact_accelerations(m, contacts, q, qd, &qdd);
        let here = acc(&q, &qd);
        let mut at = 0;
        for c in contacts {
            if c.kind == ContactKind::Point {
                let frame = &m.frames[c.frame];
                let want = reference::frame_classical_acceleration(
                    m,
                    &q,
                    &qd,
                    &qdd,
                    frame,
                    ReferenceFrame::LocalWorldAligned,
                );
                let e = rel_err(&col(&here[at..at + 3]), &col(&want));
                worst_frame = worst_frame.max(e);
                assert!(
                    e < 1e-12,
                    "{name}: a point contact's acceleration is its frame's classical one ({e:.2e})"
                );
            }
            at += c.kind.dim();
        }
        let (dq, dqd) = reference::contact_acceleration_derivatives(m, contacts, &q, &qd, &qdd);
        // h = 1e-6: O(h²) truncation ~1e-12 against rounding ~1e-16·|acc|/h ~ 1e-8 relative
        // at worst; q̇'s dependence is quadratic, so its central difference is exact.
        let h = 1e-6;
        let (mut num_q, mut num_qd) =
            (DMatrix::zeros(here.len(), nv), DMatrix::zeros(here.len(), nv));
        for u in 0..nv {
            let mut e = vec![0.0; nv];
            e[u] = h;
            let plus = acc(&reference::integrate(m, &q, &e), &qd);
            e[u] = -h;
            let minus = acc(&reference::integrate(m, &q, &e), &qd);
            let (mut vp, mut vm) = (qd.clone(), qd.clone());
            vp[u] += 1.0;
            vm[u] -= 1.0;
            let (ap, am) = (acc(&q, &vp), acc(&q, &vm));
            for r in 0..here.len() {
                num_q[(r, u)] = (plus[r] - minus[r]) / (2.0 * h);
                num_qd[(r, u)] = (ap[r] - am[r]) / 2.0;
            }
        }
        for (what, ours, num, bound) in [("dq", &dq, &num_q, 1e-7), ("dqd", &dqd, &num_qd, 1e-12)] {
            let e = rel_err(ours, num);
            worst = worst.max(e);
            assert!(
                e < bound,
                "{name}: dacc/{what} against central differences {e:.2e} (bound {bound:e})"
            );
        }
    }
    println!("contact accelerations: {worst_frame:.2e} from the frame reference; derivatives {worst:.2e} from central differences");
}

/// Contacts whose Jacobian loses rank are an error naming them; a quadruped's feet, a
/// humanoid's foot wrenches and an arm's tool are not.
#[test]
fn dependent_contacts_are_errors() {
    let cases = [
        ("grid_hyq", "[[contact]]\nframe = \"lf_upperleg\"\ntype = \"wrench\"\n", Some("`lf_upperleg`")),
        ("grid_hyq", "floating_base = true\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"wrench\"\n[[contact]]\nframe = \"rf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"lf_upperleg\"\ntype = \"wrench\"\n", Some("`lf_lowerleg`, `lf_upperleg`")),
        ("grid_hyq", "floating_base = true\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"rf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"lh_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"rh_lowerleg\"\ntype = \"point\"\n", None),
        ("grid_iiwa", "[[contact]]\nframe = \"iiwa_link_7\"\ntype = \"wrench\"\n", None),
    ];
    for (robot, scene, says) in cases {
        match (load_scene_text(robot, scene), says) {
            (Err(err), Some(says)) => {
                assert!(err.contains(says) && err.contains("rank"), "{robot} {scene:?}: {err}")
            }
            (Ok(_), None) => {}
            (got, _) => panic!("{robot} {scene:?}: {:?}", got.err()),
        }
    }
    // Atlas (whose URDF's inertias the scene loader rejects as implausible): its feet hold,
    // a foot and the ankle link one joint above it do not.
    let atlas = load_floating("grid_atlas");
    let feet = with_forces(
        &atlas,
        &[],
        &[("l_foot", ContactKind::Wrench), ("r_foot", ContactKind::Wrench)],
    );
    assert_eq!(reference::check_contact_rank(&feet, &feet.specialisation.contacts), Ok(()));
    let three = with_forces(
        &atlas,
        &[],
        &[
            ("l_foot", ContactKind::Wrench),
            ("r_foot", ContactKind::Wrench),
            ("l_talus", ContactKind::Wrench),
        ],
    );
    assert_eq!(
        reference::check_contact_rank(&three, &three.specialisation.contacts),
        Err(vec![0, 2])
    );
}

/// The contact kernels' IR against the reference: the fixture robots' contact sets, a
/// Panda's tool point (its fingers coupled) and a floating spherical arm's tool wrench, with fext
/// where the model declares it, every gradient formulation and every solve.
#[test]
fn contact_kernels_match_the_reference() {
    let fixtures = repo().join("tests/fixtures");
    let mut cases: Vec<(String, Model)> = FIXTURES
        .iter()
        .map(|name| {
            (
                name.to_string(),
                fixture_model(name, &fixture(&format!("{name}.contact.pinocchio.json"))),
            )
        })
        .collect();
    // Panda with its fingers coupled: the tool point and a force on the left finger.
    let panda = load_coupled_urdf(&repo().join("robots/panda.urdf"));
    cases.push((
        "panda coupled".into(),
        with_forces(&panda, &["panda_finger_joint1"], &[("panda_hand_tcp", ContactKind::Point)]),
    ));
    let ball = load_urdf(&fixtures.join("ball_arm.urdf"), true);
    let tip = ball.frames.iter().rev().find(|f| f.body.is_some()).unwrap().name.clone();
    cases.push((
        "ball_arm floating".into(),
        with_forces(&ball, &["root_joint"], &[(tip.as_str(), ContactKind::Wrench)]),
    ));
    let g = reference::DEFAULT_GRAVITY;
    let mut rng = Rng(32);
    let mut worst: f64 = 0.0;
    let kernels = vec![KernelKind::ContactFd, KernelKind::ContactFdGrad];
    for (name, m) in &cases {
        for (gradient, solve) in [
            (Gradient::Columns, Solve::Minv),
            (Gradient::Idsva, Solve::Ltdl),
            (Gradient::Columns, Solve::Crba),
            (Gradient::World, Solve::Minv),
        ] {
            let options = LowerOptions {
                kernels: kernels.clone(),
                gradient,
                solve,
                ..LowerOptions::default()
            };
            let module = ir::lower(m, g, &options).unwrap();
            assert_eq!(module.functions.len(), 2, "{name}: both contact kernels");
            let nv = m.nv();
            for state in 0..2 {
                let q = random_config(m, &mut rng);
                let (qd, u) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -10.0, 10.0));
                let (fext, _) = random_forces(m, &mut rng);
                let ext = External { fext: &fext, lambda: &[] };
                for f in &module.functions {
                    assert!(
                        !f.inputs().contains(&ir::Input::Lambda),
                        "{name} {}: solves for λ",
                        f.kind
                    );
                    let got = f.eval(&kernel_args_with(f.inputs(), &q, &qd, &u, ext));
                    let want = reference_outputs_with(f.kind, m, &q, &qd, &u, g, ext);
                    assert_eq!(got.len(), want.len(), "{name} {}: outputs", f.kind);
                    for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                        let got = DMatrix::from_row_slice(want.nrows(), want.ncols(), got);
                        let e = rel_err(&got, want);
                        worst = worst.max(e);
                        // The same f64 dynamics by other routes (the Schur complement
                        // against the reference's full KKT LU); K's conditioning on
                        // random states costs a digit (measured 6.3e-12).
                        assert!(
                            e < 5e-11,
                            "{name} {gradient:?} {solve:?} state {state} {} {}: {e:.2e}",
                            f.kind,
                            o.name
                        );
                    }
                }
            }
        }
    }
    println!("worst contact kernel against the reference: {worst:.2e} (bound 5e-11)");
}

/// `contact_fd_grad`'s combination reaches the Rust backend as a per-column program, which
/// every copy (portable, `fma`, and `avx512`'s with `--avx512`) runs as loops over the
/// columns (`against_reference.rs` checks both copies' values against the reference); a
/// step under contacts runs the combination and its own composition as one program.
#[test]
fn the_contact_combination_is_looped_in_every_copy() {
    use grid_gen::generate::{generate, Options, Target};
    let legs: Vec<String> =
        ["lf", "rf", "lh", "rh"].iter().map(|l| format!("{l}_lowerleg")).collect();
    let contacts: Vec<(&str, ContactKind)> =
        legs.iter().map(|l| (l.as_str(), ContactKind::Point)).collect();
    let model = with_forces(&load_floating("grid_hyq"), &[], &contacts);
    let lowered = ir::lower(
        &model,
        reference::DEFAULT_GRAVITY,
        &LowerOptions { kernels: vec![KernelKind::ContactFdGrad], ..LowerOptions::default() },
    )
    .unwrap();
    let program = lowered.functions[0].program.as_ref().expect("the program survives freezing");
    // q's, τ's, and q̇'s in two: the twelve leg and three linear base columns through M's
    // factorisation, the three angular base ones known without a solve.
    assert_eq!((program.rows, program.blocks.len()), (18 + 12, 4));
    let widths: Vec<usize> = program.blocks.iter().map(|b| b.columns()).collect();
    assert_eq!(widths, [18, 15, 3, 18]);
    let lower =
        LowerOptions { kernels: vec![KernelKind::ContactFdGrad], ..LowerOptions::default() };
    let file =
        generate(&model, &Options { targets: vec![Target::Rust], lower, ..Options::default() })
            .unwrap()
            .remove(0);
    let text = &file.contents;
    assert_program_looped(text, "contact_fd_grad", 4);
    let mut stepping = model.clone();
    stepping.specialisation.step =
        Some(grid_gen::model::StepSpec::folded(grid_gen::model::Scheme::SemiImplicitEuler, 0.01));
    let lowered = ir::lower(
        &stepping,
        reference::DEFAULT_GRAVITY,
        &LowerOptions { kernels: vec![KernelKind::StepGrad], ..LowerOptions::default() },
    )
    .unwrap();
    let program = lowered.functions[0].program.as_ref().expect("the step extends the program");
    // The combination's rows, then the q rows of A and B and q̇'s identity.
    assert_eq!((program.rows, program.blocks.len()), (18 + 12 + 2 * 18, 4));
    let file = generate(
        &stepping,
        &Options {
            targets: vec![Target::Rust],
            lower: LowerOptions { kernels: vec![KernelKind::StepGrad], ..LowerOptions::default() },
            ..Options::default()
        },
    )
    .unwrap()
    .remove(0);
    assert_program_looped(&file.contents, "step_grad", 4);
}
