//! Frames: the reference frame kinematics against Pinocchio 4.1 (placements, Jacobians in
//! the three reference frames, velocities, classical accelerations) on fixed and floating
//! robots, against central differences where Pinocchio has no fixture (spherical and
//! coupled mimic joints), and the bad-input errors.

use grid_gen::ir::KernelKind;
use grid_gen::model::ReferenceFrame;
use grid_gen::model::{CoordIndex, QIndex};
use grid_gen::{reference, Model, Scene};
use grid_gen_test_support::*;
use nalgebra::DMatrix;

/// Pinocchio and the reference evaluate the same formulas in another order: 1e-10 relative
/// (the project's bar for every quantity against Pinocchio) leaves five orders of magnitude
/// over the round-off of a 30-joint chain at angles of 1e3 rad.
const TOL: f64 = 1e-10;

/// `(fixture, robot file, floating)`.
const CASES: [(&str, &str, bool); 8] = [
    ("grid_iiwa.frames", "robots/grid_iiwa.urdf", false),
    ("grid_hyq.frames", "robots/grid_hyq.urdf", false),
    ("grid_hyq.floating.frames", "robots/grid_hyq.urdf", true),
    ("grid_atlas.frames", "robots/grid_atlas.urdf", false),
    ("grid_atlas.floating.frames", "robots/grid_atlas.urdf", true),
    ("ur5.frames", "robots/ur5.urdf", false),
    ("panda.frames", "robots/panda.urdf", false),
    ("go2.floating.frames", "tests/fixtures/go2.urdf", true),
];

fn rf_of(key: &str) -> ReferenceFrame {
    ReferenceFrame::parse(key).expect("a reference frame name")
}

#[test]
fn frame_kinematics_match_pinocchio() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for (name, path, floating) in CASES {
        let model = load_urdf(&repo().join(path), floating);
        let fx = fixture(&format!("{name}.pinocchio.json"));
        // perm[k]: our index of the fixture's k-th coordinate.
        let perm = fixture_perm(&model, &fx, name);
        let nv = model.nv();
        let ours = |v: &[f64]| {
            let mut o = vec![0.0; nv];
            for (k, &i) in perm.iter().enumerate() {
                o[i] = v[k];
            }
            o
        };
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            // The fixture's `q` lists the joints after the free-flyer.
            let angles = vec_of(&st["q"]);
            let per = if floating { [vec![0.0; 6], angles].concat() } else { angles };
            let base: [f64; 7] = if floating {
                vec_of(&st["base"]).try_into().unwrap()
            } else {
                [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
            };
            let q = model.q_from_joints(&ours(&per), base);
            let (qd, qdd) = (ours(&vec_of(&st["qd"])), ours(&vec_of(&st["qdd"])));
            for (frame_name, want) in st["frames"].as_object().unwrap() {
                let frame = &model.frames[model
                    .frame(frame_name)
                    .unwrap_or_else(|| panic!("{name}: no frame {frame_name}"))];
                let (r, p) = reference::frame_placement(&model, &q, frame);
                let mut results = vec![
                    (
                        "translation".to_string(),
                        col(p.as_slice()),
                        col(&vec_of(&want["translation"])),
                    ),
                    (
                        "rotation".to_string(),
                        DMatrix::from_fn(3, 3, |i, j| r[(i, j)]),
                        mat_of(&want["rotation"]),
                    ),
                ];
                for (key, j) in want["jacobian"].as_object().unwrap() {
                    let ours_j = reference::frame_jacobian(&model, &q, frame, rf_of(key));
                    let theirs = mat_of(j);
                    let theirs = DMatrix::from_fn(6, nv, |a, b| {
                        theirs[(a, perm.iter().position(|&i| i == b).unwrap())]
                    });
                    results.push((format!("jacobian {key}"), ours_j, theirs));
                }
                for (key, v) in want["velocity"].as_object().unwrap() {
                    results.push((
                        format!("velocity {key}"),
                        col(&reference::frame_velocity(&model, &q, &qd, frame, rf_of(key))),
                        col(&vec_of(v)),
                    ));
                }
                for (key, a) in want["classical_acceleration"].as_object().unwrap() {
                    let got = reference::frame_classical_acceleration(
                        &model,
                        &q,
                        &qd,
                        &qdd,
                        frame,
                        rf_of(key),
                    );
                    results.push((
                        format!("classical_acceleration {key}"),
                        col(&got),
                        col(&vec_of(a)),
                    ));
                }
                for (what, got, want) in results {
                    checked += 1;
                    let e = rel_err(&got, &want);
                    if e.is_nan() || e > TOL {
                        failures.push(format!(
                            "{name} state {s} ({}) {frame_name}: {what} relative error {e:.2e}",
                            st["kind"]
                        ));
                    }
                }
            }
        }
    }
    println!("{checked} frame quantities against Pinocchio, tolerance {TOL:e}");
    assert!(checked > 2000, "only {checked} comparisons");
    assert!(
        failures.is_empty(),
        "{} of {checked} above {TOL:e}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// q moved by `dq` in the tangent space: additively, and each quaternion by the rotation
/// `exp(dω)` on the right (Pinocchio's `integrate`: the local angular velocity; the
/// free-flyer's translation moves along the base's own axes).
fn integrate(model: &Model, q: &[f64], dq: &[f64]) -> Vec<f64> {
    let mut out = q.to_vec();
    for k in 0..model.nv() {
        if let Some(QIndex(i)) = model.q_index(CoordIndex(k)) {
            out[i] += dq[k];
        }
    }
    let rotate = |q: &mut [f64], at: usize, w: [f64; 3]| {
        let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        let (s, c) = if th == 0.0 { (0.5, 1.0) } else { ((th / 2.0).sin() / th, (th / 2.0).cos()) };
        let d = [w[0] * s, w[1] * s, w[2] * s, c];
        let [x, y, z, w0] = [q[at], q[at + 1], q[at + 2], q[at + 3]];
        // q ⊗ d, quaternions [x, y, z, w].
        q[at] = w0 * d[0] + x * d[3] + y * d[2] - z * d[1];
        q[at + 1] = w0 * d[1] - x * d[2] + y * d[3] + z * d[0];
        q[at + 2] = w0 * d[2] + x * d[1] - y * d[0] + z * d[3];
        q[at + 3] = w0 * d[3] - x * d[0] - y * d[1] - z * d[2];
    };
    if model.floating {
        let r = grid_gen::spatial::quaternion_matrix([q[3], q[4], q[5], q[6]]);
        let t = r * nalgebra::Vector3::new(dq[0], dq[1], dq[2]);
        for i in 0..3 {
            out[i] += t[i];
        }
        rotate(&mut out, 3, [dq[3], dq[4], dq[5]]);
    }
    for &s in &model.spherical {
        let k = model.coordinate_of(s).0;
        rotate(&mut out, model.group_q(s).0, [dq[k], dq[k + 1], dq[k + 2]]);
    }
    out
}

/// Where Pinocchio has no fixture (spherical joints, coupled mimic joints) and on a
/// floating base: the LOCAL_WORLD_ALIGNED Jacobian's linear rows are the central
/// difference of the frame's world position along each tangent direction, and its
/// angular rows that of the rotation (R(q + h e_k) Rᵀ ≈ I + h [ω_k]×); the velocity is
/// J q̇ in every reference frame.
#[test]
fn jacobians_are_derivatives_of_placements() {
    let fixtures = repo().join("tests/fixtures");
    let models = [
        ("ball_arm", load_urdf(&fixtures.join("ball_arm.urdf"), false)),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true)),
        ("mimic_arm coupled", load_coupled_urdf(&fixtures.join("mimic_arm.urdf"))),
        ("hyq floating", load_floating("grid_hyq")),
    ];
    let mut rng = Rng(29);
    let mut worst: f64 = 0.0;
    for (name, model) in &models {
        let nv = model.nv();
        for _ in 0..3 {
            let q = model.q_from_joints(&rng.vec(nv, -2.0, 2.0), rng.base_pose());
            let q = {
                // Random spherical rotations too (q_from_joints leaves them unrotated).
                let mut q = q;
                for &s in &model.spherical {
                    let at = model.group_q(s).0;
                    let r = rng.vec(4, -1.0, 1.0);
                    q[at..at + 4].copy_from_slice(&r);
                }
                q
            };
            let qd = rng.vec(nv, -2.0, 2.0);
            for frame in &model.frames {
                let j =
                    reference::frame_jacobian(model, &q, frame, ReferenceFrame::LocalWorldAligned);
                let (r0, _) = reference::frame_placement(model, &q, frame);
                // h = 1e-6: the central difference's truncation error (h²·|p'''| ~ 1e-12)
                // and round-off (ε/h ~ 1e-10) both stay under the 1e-8 bound.
                let h = 1e-6;
                let mut fd = DMatrix::zeros(6, nv);
                for k in 0..nv {
                    let mut e = vec![0.0; nv];
                    e[k] = h;
                    let (rp, pp) =
                        reference::frame_placement(model, &integrate(model, &q, &e), frame);
                    e[k] = -h;
                    let (rm, pm) =
                        reference::frame_placement(model, &integrate(model, &q, &e), frame);
                    let dp = (pp - pm) / (2.0 * h);
                    let dr = (rp - rm) / (2.0 * h) * r0.transpose();
                    let w = [dr[(2, 1)], dr[(0, 2)], dr[(1, 0)]];
                    for i in 0..3 {
                        fd[(i, k)] = dp[i];
                        fd[(i + 3, k)] = w[i];
                    }
                }
                let e = rel_err(&j, &fd);
                worst = worst.max(e);
                assert!(
                    e < 1e-8,
                    "{name} frame {}: Jacobian against central differences {e:.2e}",
                    frame.name
                );
                for rf in ReferenceFrame::ALL {
                    let jv = reference::frame_jacobian(model, &q, frame, rf)
                        * DMatrix::from_column_slice(nv, 1, &qd);
                    let v = col(&reference::frame_velocity(model, &q, &qd, frame, rf));
                    let e = rel_err(&jv, &v);
                    assert!(
                        e < 1e-13,
                        "{name} frame {} {}: J q̇ against the velocity {e:.2e}",
                        frame.name,
                        rf.name()
                    );
                }
            }
        }
    }
    println!("worst Jacobian against central differences: {worst:.2e} (bound 1e-8)");
}

fn load_error(robot: &str, scene: Scene) -> String {
    let path = repo().join("robots").join(format!("{robot}.urdf"));
    let text = std::fs::read_to_string(&path).unwrap();
    match Model::from_urdf_str_in_scene("robot.urdf", &text, false, &scene, "scene.toml") {
        Ok(_) => panic!("loaded"),
        Err(e) => e.render_plain(),
    }
}

#[test]
fn every_link_is_a_frame_and_a_scene_removes_them() {
    let ur5 = load("ur5");
    // Links merged by fixed joints are frames of the body that carries them.
    let tool = &ur5.frames[ur5.frame("tool0").unwrap()];
    let wrist = ur5.joints.iter().position(|j| j.name == "wrist_3_joint").unwrap();
    assert_eq!(tool.body, Some(wrist));
    assert_eq!(ur5.frames[ur5.frame("world").unwrap()].body, None);
    let urdf_links =
        std::fs::read_to_string(repo().join("robots/ur5.urdf")).unwrap().matches("<link ").count();
    assert_eq!(ur5.frames.len(), urdf_links);

    // A locked joint's child link becomes a frame of the parent body.
    let scene = Scene::parse("s.toml", "[lock]\niiwa_joint_7 = 0.5\n").unwrap();
    let (model, _) = Model::from_urdf_str_in_scene(
        "iiwa.urdf",
        &std::fs::read_to_string(repo().join("robots/grid_iiwa.urdf")).unwrap(),
        false,
        &scene,
        "s.toml",
    )
    .unwrap();
    let l7 = &model.frames[model.frame("iiwa_link_7").unwrap()];
    assert_eq!(model.joints[l7.body.unwrap()].name, "iiwa_joint_6");

    // Unknown, dropped and joint names are errors that say why and suggest frames.
    let scene = |names: &[&str], drop: &[&str]| {
        let mut s = Scene::default();
        s.frames.names = names.iter().map(|s| s.to_string()).collect();
        s.drop = drop.iter().map(|s| s.to_string()).collect();
        s
    };
    let e = load_error("grid_iiwa", scene(&["iiwa_link_8"], &[]));
    assert!(
        e.contains("`iiwa_link_8`, which is not a link of this robot")
            && e.contains("closest frames: iiwa_link_0"),
        "{e}"
    );
    let e = load_error("grid_iiwa", scene(&["iiwa_link_7"], &["iiwa_link_5"]));
    assert!(
        e.contains(
            "link `iiwa_link_7`, which the scene removes (by `drop = [..., \"iiwa_link_5\"]`)"
        ),
        "{e}"
    );
    let e = load_error("grid_iiwa", scene(&["iiwa_joint_7"], &[]));
    assert!(e.contains("a joint, not a link: frames are link names"), "{e}");
    let e = load_error("grid_iiwa", scene(&["iiwa_link_7", "iiwa_link_7"], &[]));
    assert!(e.contains("names frame `iiwa_link_7` twice"), "{e}");
}

/// The frame kernels' IR graphs against the reference: every reference frame, fixed and
/// floating bases, spherical and coupled mimic joints, a fixed frame on the root, a static
/// scene (q̇ ignored).
#[test]
fn frame_kernels_match_the_reference() {
    use grid_gen::ir::{self, LowerOptions};
    let fixtures = repo().join("tests/fixtures");
    let cases: Vec<(&str, Model, Vec<&str>)> = vec![
        ("iiwa", load("grid_iiwa"), vec!["iiwa_link_7", "iiwa_link_3", "base"]),
        (
            "hyq floating",
            load_floating("grid_hyq"),
            vec!["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg", "base_link_0"],
        ),
        ("ur5", load("ur5"), vec!["tool0", "world"]),
        (
            "ball_arm floating",
            load_urdf(&fixtures.join("ball_arm.urdf"), true),
            vec!["l4", "l6", "base"],
        ),
        (
            "mimic_arm coupled",
            load_coupled_urdf(&fixtures.join("mimic_arm.urdf")),
            vec!["l3", "l6", "l7"],
        ),
        ("go2 floating", load_urdf(&fixtures.join("go2.urdf"), true), vec!["FL_foot", "RR_foot"]),
    ];
    let mut rng = Rng(31);
    let mut worst: f64 = 0.0;
    for (name, model, frames) in &cases {
        for rf in ReferenceFrame::ALL {
            let m = with_frames(model, frames, rf);
            let module =
                ir::lower(&m, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
            let kinds: Vec<KernelKind> =
                module.functions.iter().map(|f| f.kind).filter(|k| k.is_frame()).collect();
            assert_eq!(kinds.len(), 5, "{name}: every frame kernel is generated");
            let nv = m.nv();
            for _ in 0..3 {
                let mut q = m.q_from_joints(&rng.vec(nv, -3.0, 3.0), rng.base_pose());
                for &s in &m.spherical {
                    let at = m.group_q(s).0;
                    q[at..at + 4].copy_from_slice(&rng.vec(4, -1.0, 1.0));
                }
                let (qd, qdd) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -2.0, 2.0));
                for f in module
                    .functions
                    .iter()
                    .filter(|f| f.kind.is_frame() && f.kind != KernelKind::FrameAccelerationGrad)
                {
                    let got = f.eval(&kernel_args(f.inputs(), &q, &qd, &qdd));
                    let want = reference_frames(f.kind, &m, &q, &qd, &qdd);
                    for ((o, got), want) in f.outputs.iter().zip(&got).zip(&want) {
                        let e = rel_err(&col(got), &col(want));
                        worst = worst.max(e);
                        // Both are f64 evaluations of the same kinematics in another order:
                        // 1e-13 is a few hundred ulps of the largest entry.
                        assert!(e < 1e-13, "{name} {} {} {}: {e:.2e}", rf.name(), f.kind, o.name);
                    }
                }
            }
        }
    }
    println!("worst frame kernel against the reference: {worst:.2e} (bound 1e-13)");
    // No frames asked, no frame kernels.
    let module =
        ir::lower(&load("grid_iiwa"), reference::DEFAULT_GRAVITY, &LowerOptions::default())
            .unwrap();
    assert!(module.functions.iter().all(|f| !f.kind.is_frame()));
}

/// A tool frame on a 7-joint arm costs what its chain costs: iiwa's flange Jacobian (in
/// LOCAL_WORLD_ALIGNED) in far fewer operations than one RNEA.
#[test]
fn a_frame_kernel_costs_its_chain() {
    use grid_gen::ir::{self, LowerOptions};
    let m = with_frames(&load("grid_iiwa"), &["iiwa_link_7"], ReferenceFrame::LocalWorldAligned);
    let module = ir::lower(&m, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
    let ops = |k: KernelKind| {
        module
            .function(k)
            .unwrap()
            .nodes
            .iter()
            .filter(|n| !matches!(n.op, ir::Op::Const(_) | ir::Op::Input(..)))
            .count()
    };
    let (jac, rnea) = (ops(KernelKind::FrameJacobian), ops(KernelKind::Rnea));
    println!(
        "iiwa flange: frame_jacobian {jac} operations, placement {}, rnea {rnea}",
        ops(KernelKind::FramePlacement)
    );
    assert!(jac < rnea, "frame_jacobian {jac} operations, rnea {rnea}");
}

/// `frame_acceleration_grad` (forward-mode derivative of the acceleration's graph) against
/// central differences of the reference's classical acceleration: along each coordinate on
/// the manifold (`integrate`), and along q̇ and q̈, in the three reference frames, on fixed,
/// floating, spherical and coupled-mimic models.
#[test]
fn frame_acceleration_derivatives_match_central_differences() {
    use grid_gen::ir::{self, LowerOptions};
    let fixtures = repo().join("tests/fixtures");
    let cases: Vec<(&str, Model, Vec<&str>)> = vec![
        ("iiwa", load("grid_iiwa"), vec!["iiwa_link_7"]),
        ("hyq floating", load_floating("grid_hyq"), vec!["lf_lowerleg", "rh_lowerleg"]),
        ("ball_arm floating", load_urdf(&fixtures.join("ball_arm.urdf"), true), vec!["l4", "l6"]),
        (
            "mimic_arm coupled",
            load_coupled_urdf(&fixtures.join("mimic_arm.urdf")),
            vec!["l3", "l7"],
        ),
    ];
    let mut rng = Rng(41);
    let mut worst: f64 = 0.0;
    for (name, model, frames) in &cases {
        for rf in ReferenceFrame::ALL {
            let m = with_frames(model, frames, rf);
            let kinds = vec![KernelKind::FrameAccelerationGrad];
            let module = ir::lower(
                &m,
                reference::DEFAULT_GRAVITY,
                &LowerOptions { kernels: kinds, ..LowerOptions::default() },
            )
            .unwrap();
            let f = module.function(KernelKind::FrameAccelerationGrad).unwrap();
            let nv = m.nv();
            let nf = frames.len();
            for _ in 0..2 {
                let mut q = m.q_from_joints(&rng.vec(nv, -2.0, 2.0), rng.base_pose());
                for &s in &m.spherical {
                    let at = m.group_q(s).0;
                    q[at..at + 4].copy_from_slice(&rng.unit_quaternion());
                }
                let (qd, qdd) = (rng.vec(nv, -2.0, 2.0), rng.vec(nv, -2.0, 2.0));
                let got = f.eval(&[&q, &qd, &qdd]);
                let acc = |q: &[f64], qd: &[f64], qdd: &[f64]| -> Vec<f64> {
                    m.selected_frames()
                        .flat_map(|fr| {
                            reference::frame_classical_acceleration(&m, q, qd, qdd, fr, rf)
                        })
                        .collect()
                };
                // h = 1e-6: the truncation (h² times the third derivative) and the round-off
                // (ε |a| / h) both stay far under the 1e-7 bound.
                let h = 1e-6;
                for (which, out) in got.iter().enumerate() {
                    let mut fd = vec![0.0; 3 * nf * nv];
                    for k in 0..nv {
                        let mut e = vec![0.0; nv];
                        e[k] = h;
                        let (plus, minus) = match which {
                            0 => {
                                let qp = integrate(&m, &q, &e);
                                e[k] = -h;
                                (acc(&qp, &qd, &qdd), acc(&integrate(&m, &q, &e), &qd, &qdd))
                            }
                            1 => {
                                let add = |s: f64| {
                                    qd.iter().zip(&e).map(|(a, b)| a + s * b).collect::<Vec<_>>()
                                };
                                (acc(&q, &add(1.0), &qdd), acc(&q, &add(-1.0), &qdd))
                            }
                            _ => {
                                let add = |s: f64| {
                                    qdd.iter().zip(&e).map(|(a, b)| a + s * b).collect::<Vec<_>>()
                                };
                                (acc(&q, &qd, &add(1.0)), acc(&q, &qd, &add(-1.0)))
                            }
                        };
                        for row in 0..3 * nf {
                            fd[row * nv + k] = (plus[row] - minus[row]) / (2.0 * h);
                        }
                    }
                    let e = rel_err(&col(out), &col(&fd));
                    worst = worst.max(e);
                    assert!(
                        e < 1e-7,
                        "{name} {} output {which}: {e:.2e} from central differences",
                        rf.name()
                    );
                }
            }
        }
    }
    println!("worst frame_acceleration_grad against central differences: {worst:.2e} (bound 1e-7)");
}

/// `frame_acceleration_grad` in LOCAL against Pinocchio: `getFrameAccelerationDerivatives`
/// composed into the classical acceleration's derivatives by `scripts/make_fixtures.py`, on
/// every frames fixture (fixed and floating bases, every state), at Pinocchio's 1e-10.
#[test]
fn frame_acceleration_derivatives_match_pinocchio() {
    use grid_gen::ir::{self, LowerOptions};
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for (name, path, floating) in CASES {
        let fx = fixture(&format!("{name}.pinocchio.json"));
        let frames: Vec<&str> =
            fx["frames"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        let model =
            with_frames(&load_urdf(&repo().join(path), floating), &frames, ReferenceFrame::Local);
        let lower = LowerOptions {
            kernels: vec![KernelKind::FrameAccelerationGrad],
            ..LowerOptions::default()
        };
        let module = ir::lower(&model, reference::DEFAULT_GRAVITY, &lower).unwrap();
        let f = module.function(KernelKind::FrameAccelerationGrad).unwrap();
        let names: Vec<&str> =
            fx["joint_names"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        let coordinates: Vec<&str> =
            model.coordinate_joints().into_iter().map(|i| model.joint(i).name.as_str()).collect();
        let perm: Vec<usize> =
            names.iter().map(|n| coordinates.iter().position(|c| c == n).unwrap()).collect();
        let nv = model.nv();
        let ours = |v: &[f64]| {
            let mut o = vec![0.0; nv];
            for (k, &i) in perm.iter().enumerate() {
                o[i] = v[k];
            }
            o
        };
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            let angles = vec_of(&st["q"]);
            let per = if floating { [vec![0.0; 6], angles].concat() } else { angles };
            let base: [f64; 7] = if floating {
                vec_of(&st["base"]).try_into().unwrap()
            } else {
                [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
            };
            let q = model.q_from_joints(&ours(&per), base);
            let got = f.eval(&[&q, &ours(&vec_of(&st["qd"])), &ours(&vec_of(&st["qdd"]))]);
            for (fi, frame) in frames.iter().enumerate() {
                let want = &st["frames"][*frame]["classical_acceleration_derivatives_local"];
                for (o, key) in ["dq", "dqd", "dqdd"].iter().enumerate() {
                    let theirs = mat_of(&want[*key]);
                    let theirs = DMatrix::from_fn(3, nv, |r, c| {
                        theirs[(r, perm.iter().position(|&i| i == c).unwrap())]
                    });
                    let mine =
                        DMatrix::from_row_slice(3, nv, &got[o][fi * 3 * nv..(fi + 1) * 3 * nv]);
                    let e = rel_err(&mine, &theirs);
                    worst = worst.max(e);
                    checked += 1;
                    assert!(
                        e <= TOL,
                        "{name} state {s} ({}) {frame}: {key} relative error {e:.2e}",
                        st["kind"]
                    );
                }
            }
        }
    }
    println!("{checked} acceleration derivatives against Pinocchio, worst {worst:.2e} (tolerance {TOL:e})");
    assert!(checked > 1000, "only {checked} comparisons");
}
