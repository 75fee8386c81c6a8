//! Scenes, beside the Pinocchio comparison in `pinocchio.rs`: each
//! reduction equals the robot written without it (a dropped subtree is the URDF without
//! those elements, a lock is a fixed joint at that position, a payload is a fixed child
//! link carrying it), every name is checked, and the kernels of a scene model agree with
//! the reference as on any robot.

use grid_gen::ir::{self, KernelKind, LowerOptions};
use grid_gen::{reference, Model, Scene};
use grid_gen_test_support::*;

/// A base with two branches: a1 → a2 (revolute about z, then y) and b1 → b2.
/// `with_b` writes branch b; `extra` is appended inside <robot>.
fn tree_urdf(with_b: bool, a2_joint: &str, extra: &str) -> String {
    let link = |name: &str, m: f64| {
        format!("<link name=\"{name}\"><inertial><origin xyz=\"0.01 0.02 0.05\" rpy=\"0.1 0 0\"/><mass value=\"{m}\"/><inertia ixx=\"0.02\" ixy=\"0.001\" ixz=\"0\" iyy=\"0.03\" iyz=\"0\" izz=\"0.01\"/></inertial></link>")
    };
    let joint = |name: &str, parent: &str, child: &str, axis: &str| {
        format!("<joint name=\"{name}\" type=\"revolute\"><parent link=\"{parent}\"/><child link=\"{child}\"/><origin xyz=\"0 0.1 0.2\" rpy=\"0 0 0\"/><axis xyz=\"{axis}\"/><limit lower=\"-2\" upper=\"2\" effort=\"1\" velocity=\"1\"/></joint>")
    };
    let mut s = String::from("<robot name=\"tree\"><link name=\"base\"/>");
    s += &link("a1", 2.0);
    s += &joint("ja1", "base", "a1", "0 0 1");
    s += &link("a2", 1.0);
    s += a2_joint;
    if with_b {
        s += &link("b1", 1.5);
        s += &joint("jb1", "base", "b1", "1 0 0");
        s += &link("b2", 0.5);
        s += &joint("jb2", "b1", "b2", "0 1 0");
    }
    s += extra;
    s + "</robot>"
}

const A2_REVOLUTE: &str = "<joint name=\"ja2\" type=\"revolute\"><parent link=\"a1\"/><child link=\"a2\"/><origin xyz=\"0 0.1 0.2\"/><axis xyz=\"0 0 1\"/><limit lower=\"-2\" upper=\"2\" effort=\"1\" velocity=\"1\"/></joint>";

fn in_scene(urdf: &str, scene: &str) -> Result<(Model, Vec<grid_gen::Diagnostic>), String> {
    let scene = Scene::parse("scene.toml", scene).map_err(|e| e.to_string())?;
    Model::from_urdf_str_in_scene("tree.urdf", urdf, false, &scene, "scene.toml")
        .map_err(|e| e.render_plain())
}

fn plain(urdf: &str) -> Model {
    Model::from_urdf_str("tree.urdf", urdf, false).map_err(|e| e.render_plain()).unwrap().0
}

/// Same joints, and the same dynamics at a few states to 1e-14 (the payload and lock
/// paths compose transforms in another order than the URDF's fixed joints).
fn assert_same(a: &Model, b: &Model, what: &str) {
    let names = |m: &Model| m.joints.iter().map(|j| j.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(a), names(b), "{what}: joints");
    let n = a.nv();
    let mut rng = Rng(3);
    for _ in 0..3 {
        let (q, qd, qdd) = (rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0));
        let g = reference::DEFAULT_GRAVITY;
        let pairs = [
            (
                col(&reference::rnea(a, &q, &qd, &qdd, g)),
                col(&reference::rnea(b, &q, &qd, &qdd, g)),
            ),
            (reference::crba(a, &q), reference::crba(b, &q)),
            (
                reference::rnea_derivatives(a, &q, &qd, &qdd, g).0,
                reference::rnea_derivatives(b, &q, &qd, &qdd, g).0,
            ),
        ];
        for (x, y) in pairs {
            assert!(rel_err(&x, &y) <= 1e-14, "{what}: {:.2e}", rel_err(&x, &y));
        }
    }
}

#[test]
fn dropping_a_subtree_is_the_urdf_without_it() {
    let (dropped, _) = in_scene(&tree_urdf(true, A2_REVOLUTE, ""), "drop = [\"b1\"]").unwrap();
    assert_same(&dropped, &plain(&tree_urdf(false, A2_REVOLUTE, "")), "drop b1");
    let (only_b2, _) =
        in_scene(&tree_urdf(true, A2_REVOLUTE, ""), "drop = [\"b2\", \"a1\"]").unwrap();
    assert_eq!(only_b2.joints.iter().map(|j| j.name.as_str()).collect::<Vec<_>>(), ["jb1"]);
}

#[test]
fn keep_models_the_path_to_a_link_and_its_subtree() {
    let (kept, _) = in_scene(&tree_urdf(true, A2_REVOLUTE, ""), "keep = [\"a2\"]").unwrap();
    assert_same(&kept, &plain(&tree_urdf(false, A2_REVOLUTE, "")), "keep a2");
    let (both, _) = in_scene(&tree_urdf(true, A2_REVOLUTE, ""), "keep = [\"a1\", \"b2\"]").unwrap();
    assert_eq!(both.nv(), 4, "both paths and subtrees");
}

#[test]
fn a_lock_is_a_fixed_joint_at_that_position() {
    // ja2 rotates about z: locked at 0.7, it is a fixed joint whose origin turns by 0.7 rad.
    let (locked, _) = in_scene(&tree_urdf(true, A2_REVOLUTE, ""), "[lock]\nja2 = 0.7").unwrap();
    let fixed = "<joint name=\"ja2\" type=\"fixed\"><parent link=\"a1\"/><child link=\"a2\"/><origin xyz=\"0 0.1 0.2\" rpy=\"0 0 0.7\"/></joint>";
    assert_same(&locked, &plain(&tree_urdf(true, fixed, "")), "lock ja2");
}

#[test]
fn a_payload_is_a_fixed_child_carrying_it() {
    let scene = "[[payload]]\nlink = \"a2\"\nmass = 0.8\ncom = [0.05, -0.02, 0.1]\ninertia = [0.004, 0.0005, 0.0, 0.003, 0.0, 0.002]\n";
    let (loaded, _) = in_scene(&tree_urdf(true, A2_REVOLUTE, ""), scene).unwrap();
    let tool = "<link name=\"tool\"><inertial><origin xyz=\"0.05 -0.02 0.1\"/><mass value=\"0.8\"/><inertia ixx=\"0.004\" ixy=\"0.0005\" ixz=\"0\" iyy=\"0.003\" iyz=\"0\" izz=\"0.002\"/></inertial></link>\
                <joint name=\"tool_mount\" type=\"fixed\"><parent link=\"a2\"/><child link=\"tool\"/></joint>";
    assert_same(&loaded, &plain(&tree_urdf(true, A2_REVOLUTE, tool)), "payload on a2");
}

#[test]
fn every_name_is_checked_and_bad_scenes_are_named() {
    let urdf = tree_urdf(true, A2_REVOLUTE, "");
    for (scene, expected) in [
        (
            "[lock]\nnope = 1.0",
            "scene `scene.toml`: [lock] names joint `nope`, which robot `tree` does not have",
        ),
        (
            "drop = [\"nope\"]",
            "scene `scene.toml`: drop names link `nope`, which robot `tree` does not have",
        ),
        (
            "keep = [\"nope\"]",
            "scene `scene.toml`: keep names link `nope`, which robot `tree` does not have",
        ),
        ("drop = [\"base\"]", "drop names the root link `base`, which would leave no robot"),
        ("[payload]\nlink = \"nope\"\nmass = 1.0", "payload names link `nope`"),
        ("lokc = 1", "unknown field `lokc`"),
        ("outputs = [\"aba\"]", "outputs: unknown kernel `aba`; available: rnea, rnea_grad"),
        ("[payload]\nlink = \"a2\"\nmass = -1.0", "must be finite and the mass not negative"),
        ("gravity = [0.0, 0.0]", "gravity"),
    ] {
        let err = in_scene(&urdf, scene).unwrap_err();
        assert!(err.contains(expected), "{scene:?}: {err}");
    }
    // Warnings: outside the limits, already fixed; --strict refuses them.
    let (_, warnings) = in_scene(&urdf, "[lock]\nja2 = 3.0").unwrap();
    assert!(
        warnings.iter().any(|w| w.message.contains("holds `ja2` at 3, outside its limits [-2, 2]")),
        "{warnings:?}"
    );
    let scene = Scene::parse("scene.toml", "[lock]\nja2 = 3.0").unwrap();
    assert!(Model::from_urdf_str_in_scene("tree.urdf", &urdf, true, &scene, "scene.toml").is_err());
}

#[test]
fn kernels_of_a_scene_model_match_the_reference() {
    let (model, scene) = load_in_scene("grid_iiwa", "iiwa_wrist_locked");
    assert_eq!(scene.kernels().unwrap(), Some(vec![KernelKind::RneaGrad, KernelKind::FdGrad]));
    assert_eq!(model.nv(), 4);
    let g = scene.gravity.unwrap_or(reference::DEFAULT_GRAVITY);
    let module = ir::lower(
        &model,
        g,
        &LowerOptions { kernels: scene.kernels().unwrap().unwrap(), ..LowerOptions::default() },
    )
    .unwrap();
    assert_eq!(
        module.functions.iter().map(|f| f.kind).collect::<Vec<_>>(),
        [KernelKind::RneaGrad, KernelKind::FdGrad]
    );
    let mut rng = Rng(8);
    let (q, qd, u) = (rng.vec(4, -2.0, 2.0), rng.vec(4, -2.0, 2.0), rng.vec(4, -2.0, 2.0));
    for f in &module.functions {
        let got = f.eval(&kernel_args(f.inputs(), &q, &qd, &u));
        for ((o, got), want) in
            f.outputs.iter().zip(&got).zip(reference_outputs(f.kind, &model, &q, &qd, &u, g))
        {
            let e = rel_err(&output_matrix(o.shape, 4, got), &want);
            assert!(e <= 1e-12, "{} {}: {e:.2e}", f.kind, o.name);
        }
    }
}

/// Operations (not constants or inputs) in a kernel's graph.
fn ops(f: &ir::Function) -> usize {
    (0..f.nodes.len()).filter(|&i| f.is_operation(ir::Id(i as u32))).count()
}

#[test]
fn a_static_scene_compiles_the_velocity_terms_out() {
    let (fixed, scene) = load_in_scene("grid_iiwa", "iiwa_static");
    assert!(scene.static_velocity && fixed.specialisation.static_velocity);
    let moving = load("grid_iiwa");
    let g = reference::DEFAULT_GRAVITY;
    let (a, b) = (
        ir::lower(&fixed, g, &LowerOptions::default()).unwrap(),
        ir::lower(&moving, g, &LowerOptions::default()).unwrap(),
    );
    let n = fixed.nv();
    let zero = vec![0.0; n];
    let mut rng = Rng(21);
    // The Lie-group kernels take no velocity (their `v` is a tangent, not q̇).
    let dynamics = |m: &ir::Module| {
        m.functions.iter().filter(|f| !f.kind.is_lie()).cloned().collect::<Vec<_>>()
    };
    for (fa, fb) in dynamics(&a).iter().zip(&dynamics(&b)) {
        // No kernel reads q̇ any more, and the q̇-gradients are constant zeros.
        assert!(
            !fa.nodes.iter().any(|node| matches!(node.op, ir::Op::Input(ir::Input::Qd, _))),
            "{}: reads qd",
            fa.kind
        );
        for o in fa.outputs.iter().filter(|o| o.name.ends_with("_dqd")) {
            assert!(
                o.ids.iter().all(|&id| fa.op(id) == ir::Op::Const(0.0)),
                "{} {}",
                fa.kind,
                o.name
            );
        }
        let velocity = fa.inputs().contains(&ir::Input::Qd);
        assert!(
            if velocity { ops(fa) < ops(fb) } else { ops(fa) == ops(fb) },
            "{}: {} vs {} ops",
            fa.kind,
            ops(fa),
            ops(fb)
        );
        for _ in 0..3 {
            let (q, qd, u) = (rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0));
            // Whatever qd is passed, the answer is the full robot's at q̇ = 0; dropping
            // terms that are exactly 0 (x·0, x + 0) changes no rounding, so to the bit.
            let got = fa.eval(&kernel_args(fa.inputs(), &q, &qd, &u));
            let want = fb.eval(&kernel_args(fb.inputs(), &q, &zero, &u));
            assert_eq!(got, want, "{}", fa.kind);
            for ((o, got), want) in fa
                .outputs
                .iter()
                .zip(&got)
                .zip(reference_outputs(fa.kind, &fixed, &q, &zero, &u, g))
            {
                let e = rel_err(&output_matrix(o.shape, n, got), &want);
                assert!(e <= 1e-12, "{} {}: {e:.2e}", fa.kind, o.name);
            }
        }
    }
    // eval refuses a moving state rather than answer for a still one.
    let states = grid_gen::eval::parse_states(&format!(
        r#"{{"states": [{{"q": {zero:?}, "qd": [0, 0, 0.5, 0, 0, 0, 0]}}]}}"#
    ))
    .unwrap();
    let err = grid_gen::eval::evaluate(&fixed, &states, g).unwrap_err().to_string();
    assert!(err.contains("state 0: `qd[2]` is 0.5, and the scene is static"), "{err}");
}

#[test]
fn gradient_entries_the_scene_does_not_read_are_not_computed() {
    let (chosen, _) = load_in_scene("grid_hyq", "hyq_lf_columns");
    let columns = [0, 1, 2];
    assert_eq!(chosen.specialisation.columns.as_deref(), Some(&columns[..]));
    let all = load("grid_hyq");
    let g = reference::DEFAULT_GRAVITY;
    let n = all.nv();
    let mut rng = Rng(5);
    let (q, qd, u) = (rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0), rng.vec(n, -2.0, 2.0));
    for gradient in [ir::Gradient::Columns, ir::Gradient::Idsva, ir::Gradient::World] {
        for kind in [KernelKind::RneaGrad, KernelKind::FdGrad] {
            let options = LowerOptions { kernels: vec![kind], gradient, ..LowerOptions::default() };
            let (a, b) =
                (ir::lower(&chosen, g, &options).unwrap(), ir::lower(&all, g, &options).unwrap());
            let (fa, fb) = (&a.functions[0], &b.functions[0]);
            // One leg of four: a quarter of rnea_grad (measured 1298/5222 columns, 1060/4264
            // IDSVA); fd_grad keeps ABA's q̈ for every joint, about half (4089/8042, 3853/7092).
            let most = if kind == KernelKind::RneaGrad { 0.3 } else { 0.6 };
            assert!(
                (ops(fa) as f64) < most * ops(fb) as f64,
                "{kind} {gradient:?}: {} vs {} ops",
                ops(fa),
                ops(fb)
            );
            // The entries kept are the full kernel's to the bit (the same graph, less the
            // work that fed only the others); the rest are 0.
            let (got, want) = (
                fa.eval(&kernel_args(fa.inputs(), &q, &qd, &u)),
                fb.eval(&kernel_args(fb.inputs(), &q, &qd, &u)),
            );
            for ((o, got), want) in fa.outputs.iter().zip(&got).zip(&want) {
                for (k, (x, y)) in got.iter().zip(want).enumerate() {
                    let kept = o.shape == ir::Shape::Vector || columns.contains(&(k % n));
                    assert_eq!(*x, if kept { *y } else { 0.0 }, "{kind} {} entry {k}", o.name);
                }
            }
        }
    }
    // The reference in `eval` answers the same way.
    let states = grid_gen::eval::parse_states(&format!(
        r#"{{"states": [{{"q": {q:?}, "qd": {qd:?}, "qdd": {u:?}}}]}}"#
    ))
    .unwrap();
    let out = grid_gen::eval::evaluate(&chosen, &states, g).unwrap();
    let dq = out.states[0].drnea_dq.as_ref().unwrap();
    assert!(
        dq.iter().all(|row| row[3..].iter().all(|&x| x == 0.0))
            && dq[0][..3].iter().any(|&x| x != 0.0)
    );
}

#[test]
fn gradient_rows_and_columns_name_movable_joints() {
    let urdf = tree_urdf(true, A2_REVOLUTE, "");
    for (scene, expected) in [
        (
            "[lock]\nja2 = 0.5\n[gradient]\ncolumns = [\"ja2\"]",
            "[gradient] columns names `ja2`, which is locked by the scene's [lock]",
        ),
        (
            "drop = [\"b1\"]\n[gradient]\nrows = [\"jb2\"]",
            "[gradient] rows names `jb2`, which is left out by the scene's keep or drop",
        ),
        (
            "[gradient]\nrows = [\"nope\"]",
            "[gradient] rows names `nope`, which is not a joint of robot `tree`",
        ),
        ("[gradient]\nrow = [\"ja1\"]", "unknown field `row`"),
        ("static = 1", "static"),
    ] {
        let err = in_scene(&urdf, scene).unwrap_err();
        assert!(err.contains(expected), "{scene:?}: {err}");
    }
    let (m, _) = in_scene(&urdf, "[gradient]\nrows = [\"jb2\", \"ja1\", \"jb2\"]").unwrap();
    let jb2 = m.joints.iter().position(|j| j.name == "jb2").unwrap();
    assert_eq!(m.specialisation.rows, Some(vec![0, jb2]), "model order, once each");
}

/// The book's scene example (every key at once, `docs/guide/scenes.md`) parses, and its
/// keys land where the comments say (a new user's copy of it once failed: `static`
/// written after `[lock]` was read as a joint to lock).
#[test]
fn the_books_scene_example_parses() {
    let page = std::fs::read_to_string(repo().join("docs/guide/scenes.md")).unwrap();
    let block = page.split("```toml\n").nth(1).unwrap().split("```").next().unwrap();
    let scene = Scene::parse("scenes.md", block).unwrap();
    assert!(
        scene.static_velocity
            && scene.floating_base
            && scene.lock.len() == 1
            && scene.payload.len() == 1
    );
    assert_eq!(
        scene.outputs.as_deref(),
        Some(&["rnea_grad".to_string(), "fd_grad".to_string()][..])
    );
    // Written after the table, `static` is a joint of `[lock]`, and the error says what went wrong.
    let misplaced = block
        .replace("static = true ", "")
        .replace("iiwa_joint_7 = 0.0\n", "iiwa_joint_7 = 0.0\nstatic = true\n");
    let err = Scene::parse("scenes.md", &misplaced).unwrap_err().to_string();
    assert!(err.contains("static"), "{err}");
}

/// `round_angles`: an angle written to 11 digits becomes the right angle it stands for
/// (the model equals the URDF written with π/2 in full), an angle that is no multiple of
/// π/2 stays, and a tolerance that would change the robot rather than its round-off is
/// an error, from a scene file and from the caller's override alike.
#[test]
#[allow(clippy::approx_constant)] // the truncated π/2 is the point
fn round_angles_reads_truncated_right_angles_and_refuses_large_tolerances() {
    let ja2 = |rpy: &str| {
        A2_REVOLUTE.replace(
            "<origin xyz=\"0 0.1 0.2\"/>",
            &format!("<origin xyz=\"0 0.1 0.2\" rpy=\"{rpy}\"/>"),
        )
    };
    let truncated = tree_urdf(true, &ja2("1.57079632679 0.3 0"), "");
    let (m, _) = in_scene(&truncated, "round_angles = 1e-11").unwrap();
    let r = m.rounded_angles.unwrap();
    assert_eq!((r.count, r.largest), (1, std::f64::consts::FRAC_PI_2 - 1.57079632679));
    let exact = tree_urdf(true, &ja2(&format!("{} 0.3 0", std::f64::consts::FRAC_PI_2)), "");
    assert_same(&m, &plain(&exact), "rounded");
    assert_eq!(plain(&truncated).rounded_angles, None);
    for bad in ["0.0", "-1e-12", "1e-3", "nan", "inf"] {
        let e = in_scene(&truncated, &format!("round_angles = {bad}")).unwrap_err();
        assert!(e.contains("round_angles") && e.contains("at most 1e-6"), "{bad}: {e}");
    }
    let dir = std::env::temp_dir().join(format!("grid-gen-round-angles-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("tree.urdf");
    std::fs::write(&path, &truncated).unwrap();
    let mut config = grid_gen::Config::new(&path);
    config.overrides.round_angles = Some(0.01);
    let e = config.load().unwrap_err().to_string();
    assert!(e.contains("round_angles = 0.01"), "{e}");
    config.overrides.round_angles = Some(1e-11);
    assert_eq!(config.load().unwrap().model.rounded_angles.map(|r| r.count), Some(1));
    std::fs::remove_dir_all(&dir).unwrap();
}
