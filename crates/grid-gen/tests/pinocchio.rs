//! The reference dynamics against Pinocchio fixtures (tests/fixtures/*.pinocchio.json,
//! written by scripts/make_fixtures.py) on every bundled robot.
//!
//! Tolerance: ‖ours − pin‖_max / ‖pin‖_max ≤ 1e-10 per output and state (DESIGN.md).
//! Both are f64 implementations of the same recursions in different frames (Pinocchio
//! works in the world frame), so they differ by round-off amplified by the condition of
//! M for the outputs through M⁻¹.

use grid_gen::reference;
use grid_gen_test_support::*;
use nalgebra::DMatrix;

const TOL: f64 = 1e-10;

#[test]
fn reference_matches_pinocchio_on_every_robot() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for robot in robots() {
        checked += compare(
            &robot,
            &load(&robot),
            &fixture(&format!("{robot}.pinocchio.json")),
            &mut failures,
        );
    }
    assert!(checked > 500, "only {checked} comparisons");
    assert!(
        failures.is_empty(),
        "{} of {checked} comparisons above {TOL:e}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// Scenes against Pinocchio's own reduction: `[lock]` is
/// `buildReducedModel` at the locked positions, a payload is added to the inertia of the
/// joint carrying the link's frame (scripts/make_fixtures.py, `scene_model`). Same
/// tolerance: the reduced model is an ordinary model for both.
#[test]
fn scenes_match_pinocchio_reduced_models() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for (robot, scene) in [("grid_iiwa", "iiwa_wrist_locked"), ("grid_hyq", "hyq_knees_locked")] {
        let (model, _) = load_in_scene(robot, scene);
        checked += compare(
            &format!("{robot} in {scene}"),
            &model,
            &fixture(&format!("{robot}.{scene}.pinocchio.json")),
            &mut failures,
        );
    }
    assert!(checked > 100, "only {checked} comparisons");
    assert!(
        failures.is_empty(),
        "{} of {checked} comparisons above {TOL:e}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// Every state of one fixture against the reference on `model`; returns the number of
/// comparisons, pushing each one above TOL onto `failures`.
fn compare(
    robot: &str,
    model: &grid_gen::Model,
    fx: &serde_json::Value,
    failures: &mut Vec<String>,
) -> usize {
    let mut checked = 0;
    {
        let names: Vec<&str> =
            fx["joint_names"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        assert_eq!(names.len(), model.nv(), "{robot}: joint count");
        // perm[k] = our index of Pinocchio's k-th joint.
        let perm: Vec<usize> = names
            .iter()
            .map(|n| {
                model
                    .joints
                    .iter()
                    .position(|j| j.name == *n)
                    .unwrap_or_else(|| panic!("{robot}: no joint {n}"))
            })
            .collect();
        let ours = |v: &[f64]| {
            let mut out = vec![0.0; v.len()];
            for (k, &i) in perm.iter().enumerate() {
                out[i] = v[k];
            }
            out
        };
        let back_v = |v: &[f64]| col(&perm.iter().map(|&i| v[i]).collect::<Vec<_>>());
        let back_m =
            |m: &DMatrix<f64>| DMatrix::from_fn(m.nrows(), m.ncols(), |a, b| m[(perm[a], perm[b])]);
        let g = [0.0, 0.0, -9.81];
        assert_eq!(vec_of(&fx["gravity"]), g.to_vec());
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            let (q, qd, qdd, tau) = (
                ours(&vec_of(&st["q"])),
                ours(&vec_of(&st["qd"])),
                ours(&vec_of(&st["qdd"])),
                ours(&vec_of(&st["tau"])),
            );
            let (dq, dqd) = reference::rnea_derivatives(model, &q, &qd, &qdd, g);
            let (fd, dfd_dq, dfd_dqd) =
                reference::forward_dynamics_derivatives(model, &q, &qd, &tau, g);
            let results = [
                (
                    "rnea",
                    back_v(&reference::rnea(model, &q, &qd, &qdd, g)),
                    col(&vec_of(&st["rnea"])),
                ),
                ("drnea_dq", back_m(&dq), mat_of(&st["drnea_dq"])),
                ("drnea_dqd", back_m(&dqd), mat_of(&st["drnea_dqd"])),
                ("M", back_m(&reference::crba(model, &q)), mat_of(&st["M"])),
                ("Minv", back_m(&reference::minv(model, &q)), mat_of(&st["Minv"])),
                ("fd", back_v(&fd), col(&vec_of(&st["fd"]))),
                (
                    "fd alone",
                    back_v(&reference::forward_dynamics(model, &q, &qd, &tau, g)),
                    col(&vec_of(&st["fd"])),
                ),
                ("dfd_dq", back_m(&dfd_dq), mat_of(&st["dfd_dq"])),
                ("dfd_dqd", back_m(&dfd_dqd), mat_of(&st["dfd_dqd"])),
            ];
            for (what, got, want) in results {
                checked += 1;
                let e = rel_err(&got, &want);
                if e.is_nan() || e > TOL {
                    failures.push(format!(
                        "{robot} state {s} ({}): {what} relative error {e:.2e}",
                        st["kind"]
                    ));
                }
            }
        }
    }
    checked
}

/// A fixture's listing order (Pinocchio's, by name) against the model's joint order.
struct Order {
    /// `perm[k]`: our index of the fixture's k-th coordinate.
    perm: Vec<usize>,
    /// `inv[i]`: the fixture's index of our coordinate i.
    inv: Vec<usize>,
}

impl Order {
    fn new(robot: &str, model: &grid_gen::Model, fx: &serde_json::Value) -> Order {
        let names: Vec<&str> =
            fx["joint_names"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        assert_eq!(names.len(), model.nv(), "{robot}: joint count");
        // Coordinates: the joints that are not coupled mimics (all of them by default).
        let coordinates: Vec<&str> =
            model.coordinate_joints().into_iter().map(|i| model.joint(i).name.as_str()).collect();
        let perm: Vec<usize> = names
            .iter()
            .map(|name| {
                coordinates
                    .iter()
                    .position(|j| j == name)
                    .unwrap_or_else(|| panic!("{robot}: no coordinate {name}"))
            })
            .collect();
        let mut inv = vec![0; perm.len()];
        for (k, &i) in perm.iter().enumerate() {
            inv[i] = k;
        }
        Order { perm, inv }
    }

    /// A fixture vector in our order.
    fn ours(&self, v: &[f64]) -> Vec<f64> {
        self.inv.iter().map(|&k| v[k]).collect()
    }

    /// Fixture entry `key` of state `st` in our order.
    fn theirs(
        &self,
        st: &serde_json::Value,
        key: &str,
        shape: grid_gen::ir::Shape,
    ) -> DMatrix<f64> {
        match shape {
            grid_gen::ir::Shape::Vector => col(&self.ours(&vec_of(&st[key]))),
            grid_gen::ir::Shape::Matrix => {
                let m = mat_of(&st[key]);
                DMatrix::from_fn(m.nrows(), m.ncols(), |a, b| m[(self.inv[a], self.inv[b])])
            }
            other => panic!("no dynamics fixture has {other:?} outputs (frames: tests/frames.rs)"),
        }
    }
}

/// The fixture keys of a kernel's outputs, in output order.
fn fixture_keys(kind: grid_gen::ir::KernelKind) -> &'static [&'static str] {
    use grid_gen::ir::KernelKind;
    match kind {
        KernelKind::Rnea => &["rnea"],
        KernelKind::RneaGrad => &["drnea_dq", "drnea_dqd"],
        KernelKind::MassMatrix => &["M"],
        KernelKind::Minv => &["Minv"],
        KernelKind::Fd => &["fd"],
        KernelKind::FdGrad => &["fd", "dfd_dq", "dfd_dqd"],
        frame => panic!("{frame}: the frame kernels are checked in tests/frames.rs"),
    }
}

/// The scenes that change the kernels rather than the model (`static`, `[gradient]`),
/// their generated graphs (not the reference, which knows nothing of them) against
/// Pinocchio: `iiwa_static` against Pinocchio at v = 0 (fixture written with q̇ = 0)
/// while the kernels are handed a random nonzero q̇, which they must ignore;
/// `hyq_lf_columns` against Pinocchio's full HyQ, the entries outside the columns 0.
#[test]
fn static_and_gradient_scenes_match_pinocchio() {
    use grid_gen::ir::{self, Input, LowerOptions};
    let mut failures = Vec::new();
    let mut checked = 0;
    for (robot, scene, fixture_name) in [
        ("grid_iiwa", "iiwa_static", "grid_iiwa.iiwa_static.pinocchio.json"),
        ("grid_hyq", "hyq_lf_columns", "grid_hyq.pinocchio.json"),
    ] {
        let (model, _) = load_in_scene(robot, scene);
        let spec = model.specialisation.clone();
        let module =
            ir::lower(&model, reference::DEFAULT_GRAVITY, &LowerOptions::default()).unwrap();
        let fx = fixture(fixture_name);
        let n = model.nv();
        let order = Order::new(robot, &model, &fx);
        let ours = |v: &[f64]| order.ours(v);
        // Pinocchio's answer in our joint order, the entries the scene does not read 0.
        let theirs = |st: &serde_json::Value, key: &str, shape: ir::Shape| -> DMatrix<f64> {
            let m = order.theirs(st, key, shape);
            match shape {
                ir::Shape::Matrix if key.starts_with('d') => {
                    DMatrix::from_fn(n, n, |a, b| if spec.keeps(a, b) { m[(a, b)] } else { 0.0 })
                }
                _ => m,
            }
        };
        let mut rng = Rng(17);
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            let q = ours(&vec_of(&st["q"]));
            let qd = if spec.static_velocity {
                assert!(
                    vec_of(&st["qd"]).iter().all(|&x| x == 0.0),
                    "the static fixture is at rest"
                );
                rng.vec(n, -1.0, 1.0)
            } else {
                ours(&vec_of(&st["qd"]))
            };
            // The Lie-group kernels are held to Pinocchio in tests/lie.rs and python/tests.
            for f in module.functions.iter().filter(|f| !f.kind.is_lie()) {
                let u = match f.inputs().get(2) {
                    Some(Input::Qdd) => ours(&vec_of(&st["qdd"])),
                    Some(Input::Tau) => ours(&vec_of(&st["tau"])),
                    _ => Vec::new(),
                };
                let keys = fixture_keys(f.kind);
                let got = f.eval(&kernel_args(f.inputs(), &q, &qd, &u));
                for ((o, got), key) in f.outputs.iter().zip(&got).zip(keys) {
                    checked += 1;
                    let e = rel_err(&output_matrix(o.shape, n, got), &theirs(st, key, o.shape));
                    if e.is_nan() || e > TOL {
                        failures.push(format!(
                            "{robot} in {scene} state {s} ({}): {} {key} relative error {e:.2e}",
                            st["kind"], f.kind
                        ));
                    }
                }
            }
        }
    }
    assert!(checked > 200, "only {checked} comparisons");
    assert!(
        failures.is_empty(),
        "{} of {checked} comparisons above {TOL:e}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// Floating base: `--floating-base` against Pinocchio's
/// `JointModelFreeFlyer` (scripts/make_fixtures.py, `floating_fixture`) on HyQ, Atlas, the
/// iiwa, the UR5 and two legged robots the project does not bundle (example-robot-data's
/// Solo-12 and Go2, kept under tests/fixtures): random base poses, an upside-down base,
/// base speeds of 1e3. Both the
/// reference and every kernel's graph in both gradient formulations (evaluated in f64),
/// at the same 1e-10 as the fixed-base robots: the free-flyer adds no ill-conditioning of
/// its own (its block of M is the robot's total mass and inertia).
#[test]
fn floating_base_matches_pinocchio_free_flyer() {
    use grid_gen::ir::{self, Gradient, LowerOptions};
    let mut tally = Tally::default();
    for robot in ["grid_hyq", "grid_atlas", "grid_iiwa", "ur5", "solo12", "go2"] {
        // Solo-12 and Go2 are test-only robots (tests/fixtures/LICENSE.example-robot-data).
        let model = match robot {
            "solo12" | "go2" => {
                load_floating_urdf(&repo().join("tests/fixtures").join(format!("{robot}.urdf")))
            }
            _ => load_floating(robot),
        };
        assert!(model.floating && model.nq() == model.nv() + 1);
        let fx = fixture(&format!("{robot}.floating.pinocchio.json"));
        let order = Order::new(robot, &model, &fx);
        assert_eq!(order.perm[..6], [0, 1, 2, 3, 4, 5], "{robot}: the free-flyer comes first");
        let modules: Vec<_> = [Gradient::Columns, Gradient::Idsva, Gradient::World]
            .into_iter()
            .map(|gradient| {
                ir::lower(
                    &model,
                    reference::DEFAULT_GRAVITY,
                    &LowerOptions { gradient, ..LowerOptions::default() },
                )
                .unwrap()
            })
            .collect();
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            // q: the base's seven entries, then each joint after the free-flyer at its model
            // index + 1.
            let mut q = vec_of(&st["base"]);
            q.resize(model.nq(), 0.0);
            for (k, &a) in vec_of(&st["q"]).iter().enumerate() {
                q[order.perm[6 + k] + 1] = a;
            }
            tally.add(
                &format!("{robot} floating state {s} ({})", st["kind"]),
                everything(&model, &modules, &order, st, &q),
            );
        }
    }
    tally.finish("floating base: comparisons with Pinocchio's free-flyer", 1800);
}

/// Coupled mimic joints: `--mimic coupled` against Pinocchio's mimic
/// model (`buildModelFromUrdf(..., mimic=True)`; scripts/make_fixtures.py,
/// `mimic_fixture`) on the Panda (finger_joint2 = finger_joint1) and mimic_arm (revolute
/// and prismatic mimics with multipliers -0.7, 1.5, 2 and nonzero offsets, one below
/// another joint's mimic). The reference (whose M⁻¹ and q̈ project the joint-level ones
/// onto the mimic constraints) and every kernel's graph in both gradient formulations
/// (whose projection runs through a symbolic LDLᵀ), at the fixed-base robots' 1e-10:
/// the constraint adds no ill-conditioning beyond M's own (S = K M⁻¹ Kᵀ is as well
/// conditioned as the mimic joints' block of M⁻¹).
#[test]
fn coupled_mimic_matches_pinocchio_mimic() {
    use grid_gen::ir::{self, Gradient, LowerOptions};
    let mut tally = Tally::default();
    for (robot, path, coupled) in [
        ("panda", repo().join("robots/panda.urdf"), 1),
        ("mimic_arm", repo().join("tests/fixtures/mimic_arm.urdf"), 3),
    ] {
        let model = load_coupled_urdf(&path);
        assert_eq!(model.njoints() - model.nv(), coupled, "{robot}: coupled mimic joints");
        let fx = fixture(&format!("{robot}.mimic.pinocchio.json"));
        let order = Order::new(robot, &model, &fx);
        let modules: Vec<_> = [Gradient::Columns, Gradient::Idsva, Gradient::World]
            .into_iter()
            .map(|gradient| {
                ir::lower(
                    &model,
                    reference::DEFAULT_GRAVITY,
                    &LowerOptions { gradient, ..LowerOptions::default() },
                )
                .unwrap()
            })
            .collect();
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            tally.add(
                &format!("{robot} coupled state {s} ({})", st["kind"]),
                everything(&model, &modules, &order, st, &order.ours(&vec_of(&st["q"]))),
            );
        }
    }
    tally.finish("coupled mimic joints: comparisons with Pinocchio's mimic model", 700);
}

/// Spherical joints (`type="spherical"`, a grid-gen extension of URDF)
/// against Pinocchio's `JointModelSpherical` (scripts/make_fixtures.py, `ball_fixture`) on
/// ball_arm: one on the root, one between moving bodies, one at a leaf, on a fixed base and
/// on a free-flyer; random rotations, unrotated, half turns (w = 0) and speeds of 1e3. The
/// reference and every kernel's graph in both gradient formulations, at the fixed-base
/// robots' 1e-10: a spherical joint adds no conditioning of its own.
#[test]
fn spherical_joints_match_pinocchio_spherical() {
    use grid_gen::ir::{self, Gradient, LowerOptions};
    let mut tally = Tally::default();
    for floating in [false, true] {
        let robot = if floating { "ball_arm.floating" } else { "ball_arm" };
        let model = load_urdf(&repo().join("tests/fixtures/ball_arm.urdf"), floating);
        assert_eq!(
            (model.spherical.len(), model.nq()),
            (3, model.nv() + 3 + usize::from(floating)),
            "{robot}: q's size"
        );
        let fx = fixture(&format!("{robot}.pinocchio.json"));
        let order = Order::new(robot, &model, &fx);
        // q is Pinocchio's whole q, which is in grid-gen's layout when the orders agree.
        assert!(
            order.perm.iter().enumerate().all(|(k, &p)| k == p),
            "{robot}: Pinocchio's model is built in grid-gen's order"
        );
        let modules: Vec<_> = [Gradient::Columns, Gradient::Idsva, Gradient::World]
            .into_iter()
            .map(|gradient| {
                ir::lower(
                    &model,
                    reference::DEFAULT_GRAVITY,
                    &LowerOptions { gradient, ..LowerOptions::default() },
                )
                .unwrap()
            })
            .collect();
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            tally.add(
                &format!("{robot} state {s} ({})", st["kind"]),
                everything(&model, &modules, &order, st, &vec_of(&st["q"])),
            );
        }
    }
    tally.finish("spherical joints: comparisons with Pinocchio's JointModelSpherical", 600);
}

/// Every output of the reference and of each module's kernel graphs at fixture state `st`
/// (q given in our layout), beside the fixture's: `(what, ours, Pinocchio's)`.
fn everything(
    model: &grid_gen::Model,
    modules: &[grid_gen::ir::Module],
    order: &Order,
    st: &serde_json::Value,
    q: &[f64],
) -> Vec<(String, DMatrix<f64>, DMatrix<f64>)> {
    use grid_gen::ir::{Input, Shape};
    let g = reference::DEFAULT_GRAVITY;
    let (qd, qdd, tau) = (
        order.ours(&vec_of(&st["qd"])),
        order.ours(&vec_of(&st["qdd"])),
        order.ours(&vec_of(&st["tau"])),
    );
    let theirs = |key: &str, shape| order.theirs(st, key, shape);
    let (dq, dqd) = reference::rnea_derivatives(model, q, &qd, &qdd, g);
    let (fd, dfd_dq, dfd_dqd) = reference::forward_dynamics_derivatives(model, q, &qd, &tau, g);
    let mut results = vec![
        (
            "reference rnea".to_string(),
            col(&reference::rnea(model, q, &qd, &qdd, g)),
            theirs("rnea", Shape::Vector),
        ),
        ("reference drnea_dq".into(), dq, theirs("drnea_dq", Shape::Matrix)),
        ("reference drnea_dqd".into(), dqd, theirs("drnea_dqd", Shape::Matrix)),
        ("reference M".into(), reference::crba(model, q), theirs("M", Shape::Matrix)),
        ("reference Minv".into(), reference::minv(model, q), theirs("Minv", Shape::Matrix)),
        ("reference fd".into(), col(&fd), theirs("fd", Shape::Vector)),
        (
            "reference aba".into(),
            col(&reference::aba(model, q, &qd, &tau, g)),
            theirs("fd", Shape::Vector),
        ),
        ("reference dfd_dq".into(), dfd_dq, theirs("dfd_dq", Shape::Matrix)),
        ("reference dfd_dqd".into(), dfd_dqd, theirs("dfd_dqd", Shape::Matrix)),
    ];
    for module in modules {
        for f in module.functions.iter().filter(|f| !f.kind.is_lie()) {
            let u = match f.inputs().get(2) {
                Some(Input::Qdd) => qdd.clone(),
                Some(Input::Tau) => tau.clone(),
                _ => Vec::new(),
            };
            let got = f.eval(&kernel_args(f.inputs(), q, &qd, &u));
            for ((o, got), key) in f.outputs.iter().zip(&got).zip(fixture_keys(f.kind)) {
                let form = f.gradient.map_or(String::new(), |g| format!(" ({})", g.name()));
                results.push((
                    format!("{}{form} {key}", f.kind.name()),
                    output_matrix(o.shape, model.nv(), got),
                    theirs(key, o.shape),
                ));
            }
        }
    }
    results
}

/// Comparisons against a fixture at [`TOL`]: how many, the worst, and each one above.
#[derive(Default)]
struct Tally {
    checked: usize,
    worst: f64,
    failures: Vec<String>,
}

impl Tally {
    fn add(&mut self, at: &str, results: Vec<(String, DMatrix<f64>, DMatrix<f64>)>) {
        for (what, got, want) in results {
            self.checked += 1;
            let e = rel_err(&got, &want);
            self.worst = self.worst.max(e);
            if e.is_nan() || e > TOL {
                self.failures.push(format!("{at}: {what} relative error {e:.2e}"));
            }
        }
    }

    /// Prints the count and worst error, and fails on any above TOL or fewer than `min`.
    fn finish(self, what: &str, min: usize) {
        let Tally { checked, worst, failures } = self;
        println!("{what}: {checked}, worst relative error {worst:.2e}");
        assert!(checked > min, "only {checked} comparisons");
        assert!(
            failures.is_empty(),
            "{} of {checked} comparisons above {TOL:e}:\n{}",
            failures.len(),
            failures.join("\n")
        );
    }
}
