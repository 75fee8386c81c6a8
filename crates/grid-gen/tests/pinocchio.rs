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
        checked += compare(&robot, &load(&robot), &fixture(&format!("{robot}.pinocchio.json")), &mut failures);
    }
    assert!(checked > 500, "only {checked} comparisons");
    assert!(failures.is_empty(), "{} of {checked} comparisons above {TOL:e}:\n{}", failures.len(), failures.join("\n"));
}

/// Scenes (issue 10, item 6) against Pinocchio's own reduction: `[lock]` is
/// `buildReducedModel` at the locked positions, a payload is added to the inertia of the
/// joint carrying the link's frame (scripts/make_fixtures.py, `scene_model`). Same
/// tolerance: the reduced model is an ordinary model for both.
#[test]
fn scenes_match_pinocchio_reduced_models() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for (robot, scene) in [("grid_iiwa", "iiwa_wrist_locked"), ("grid_hyq", "hyq_knees_locked")] {
        let (model, _) = load_in_scene(robot, scene);
        checked += compare(&format!("{robot} in {scene}"), &model, &fixture(&format!("{robot}.{scene}.pinocchio.json")), &mut failures);
    }
    assert!(checked > 100, "only {checked} comparisons");
    assert!(failures.is_empty(), "{} of {checked} comparisons above {TOL:e}:\n{}", failures.len(), failures.join("\n"));
}

/// Every state of one fixture against the reference on `model`; returns the number of
/// comparisons, pushing each one above TOL onto `failures`.
fn compare(robot: &str, model: &grid_gen::Model, fx: &serde_json::Value, failures: &mut Vec<String>) -> usize {
    let mut checked = 0;
    {
        let names: Vec<&str> = fx["joint_names"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect();
        assert_eq!(names.len(), model.nv(), "{robot}: joint count");
        // perm[k] = our index of Pinocchio's k-th joint.
        let perm: Vec<usize> =
            names.iter().map(|n| model.joints.iter().position(|j| j.name == *n).unwrap_or_else(|| panic!("{robot}: no joint {n}"))).collect();
        let ours = |v: &[f64]| {
            let mut out = vec![0.0; v.len()];
            for (k, &i) in perm.iter().enumerate() {
                out[i] = v[k];
            }
            out
        };
        let back_v = |v: &[f64]| col(&perm.iter().map(|&i| v[i]).collect::<Vec<_>>());
        let back_m = |m: &DMatrix<f64>| DMatrix::from_fn(m.nrows(), m.ncols(), |a, b| m[(perm[a], perm[b])]);
        let g = [0.0, 0.0, -9.81];
        assert_eq!(vec_of(&fx["gravity"]), g.to_vec());
        for (s, st) in fx["states"].as_array().unwrap().iter().enumerate() {
            let (q, qd, qdd, tau) = (ours(&vec_of(&st["q"])), ours(&vec_of(&st["qd"])), ours(&vec_of(&st["qdd"])), ours(&vec_of(&st["tau"])));
            let (dq, dqd) = reference::rnea_derivatives(&model, &q, &qd, &qdd, g);
            let (fd, dfd_dq, dfd_dqd) = reference::forward_dynamics_derivatives(&model, &q, &qd, &tau, g);
            let results = [
                ("rnea", back_v(&reference::rnea(&model, &q, &qd, &qdd, g)), col(&vec_of(&st["rnea"]))),
                ("drnea_dq", back_m(&dq), mat_of(&st["drnea_dq"])),
                ("drnea_dqd", back_m(&dqd), mat_of(&st["drnea_dqd"])),
                ("M", back_m(&reference::crba(&model, &q)), mat_of(&st["M"])),
                ("Minv", back_m(&reference::minv(&model, &q)), mat_of(&st["Minv"])),
                ("fd", back_v(&fd), col(&vec_of(&st["fd"]))),
                ("fd alone", back_v(&reference::forward_dynamics(&model, &q, &qd, &tau, g)), col(&vec_of(&st["fd"]))),
                ("dfd_dq", back_m(&dfd_dq), mat_of(&st["dfd_dq"])),
                ("dfd_dqd", back_m(&dfd_dqd), mat_of(&st["dfd_dqd"])),
            ];
            for (what, got, want) in results {
                checked += 1;
                let e = rel_err(&got, &want);
                if !(e <= TOL) {
                    failures.push(format!("{robot} state {s} ({}): {what} relative error {e:.2e}", st["kind"]));
                }
            }
        }
    }
    checked
}
