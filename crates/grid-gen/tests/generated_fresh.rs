//! The checked-in kernels under `generated/<robot>/` are exactly what grid-gen generates
//! now, for every robot in `robots/`, and generating twice gives the same bytes. Every
//! robot has its Rust module; the robots in [`WGSL_ROBOTS`] also have their WGSL shader
//! (the others' shaders add size, not information, to a review), and the robots in
//! [`VERILOG_ROBOTS`] their default Verilog netlists and testbenches (a fully pipelined
//! iiwa gradient is 1.4 MB of instances: readable in a simulator, not in a review).
//!
//! Refresh after an intended change: `GRID_GEN_BLESS=1 cargo test -p grid-gen --test
//! generated_fresh` (or `grid-gen robots/<robot>.urdf -o generated/<robot>` per robot), then review
//! the diff.

use grid_gen::generate::{generate, write_files, FileStatus, Options, Target};
use grid_gen_test_support::*;

/// Robots whose WGSL is checked in: a 7-joint chain and a 12-joint, four-branch tree.
const WGSL_ROBOTS: [&str; 2] = ["grid_iiwa", "grid_hyq"];

/// Robots whose Verilog is checked in (default options: pipelined, `--fixed auto`).
const VERILOG_ROBOTS: [&str; 1] = ["double_pendulum_continuous"];

/// Robots whose C ABI (`<robot>_c.rs` and `<robot>.h`) is checked in: iiwa's, which
/// `examples/iiwa-c` builds into a library and `examples/cpp` links.
const C_ROBOTS: [&str; 1] = ["grid_iiwa"];

/// Robots in a scene of `examples/scenes/`, whose Rust modules are checked in under
/// `generated/scenes/<robot>.<scene>/` (benchmarked against the full robots').
pub const SCENES: [(&str, &str); 13] = [
    ("grid_iiwa", "iiwa_wrist_locked"),
    ("grid_hyq", "hyq_front_legs"),
    ("grid_iiwa", "iiwa_static"),
    ("grid_hyq", "hyq_lf_columns"),
    ("grid_hyq", "hyq_floating"),
    ("panda", "panda_mimic"),
    ("grid_iiwa", "iiwa_tool_frame"),
    ("grid_hyq", "hyq_feet_floating"),
    ("grid_hyq", "hyq_step_floating"),
    ("grid_hyq", "hyq_contacts_floating"),
    ("grid_hyq", "hyq_standing_floating"),
    ("grid_hyq", "hyq_round_angles"),
    ("grid_hyq", "hyq_floating_round_angles"),
];

/// Test robots (not bundled: they use grid-gen's extensions of URDF) whose Rust modules
/// are checked in under `generated/fixtures/<robot>/`, so that grid-gen-kernels compiles
/// and runs them: ball_arm's spherical joints.
pub const FIXTURE_ROBOTS: [&str; 1] = ["ball_arm"];

#[test]
fn checked_in_kernels_are_fresh() {
    let bless = std::env::var_os("GRID_GEN_BLESS").is_some();
    let mut stale = Vec::new();
    let mut dirs: Vec<String> = std::fs::read_dir(repo().join("generated"))
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir() && e.file_name() != "scenes" && e.file_name() != "fixtures")
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    dirs.sort();
    assert_eq!(dirs, robots(), "generated/ holds one folder per robot in robots/");
    for robot in robots() {
        let model = load(&robot);
        let mut targets = vec![Target::Rust];
        if WGSL_ROBOTS.contains(&robot.as_str()) {
            targets.push(Target::Wgsl);
        }
        if VERILOG_ROBOTS.contains(&robot.as_str()) {
            targets.push(Target::Verilog);
        }
        if C_ROBOTS.contains(&robot.as_str()) {
            targets.push(Target::C);
        }
        let options = Options { targets, ..Options::default() };
        let files = generate(&model, &options).unwrap();
        let again = generate(&model, &options).unwrap();
        assert_eq!(files, again, "{robot}: generation is deterministic");
        let dir = repo().join("generated").join(&robot);
        for (path, status) in write_files(&dir, &files, !bless).unwrap() {
            if status == FileStatus::Stale {
                stale.push(path.display().to_string());
            }
        }
        let mut expected: Vec<String> = files.iter().map(|f| f.name.clone()).collect();
        expected.sort();
        let mut present: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        present.sort();
        assert_eq!(present, expected, "{robot}: no stray files in generated/{robot}");
    }
    for (robot, scene) in SCENES {
        let (model, parsed) = load_in_scene(robot, scene);
        let mut options = Options::default();
        if let Some(k) = parsed.kernels().unwrap() {
            options.lower.kernels = k;
        }
        if let Some(g) = parsed.gravity {
            options.gravity = g;
        }
        let files = generate(&model, &options).unwrap();
        let dir = repo().join("generated/scenes").join(format!("{robot}.{scene}"));
        for (path, status) in write_files(&dir, &files, !bless).unwrap() {
            if status == FileStatus::Stale {
                stale.push(path.display().to_string());
            }
        }
    }
    for robot in FIXTURE_ROBOTS {
        let model = load_urdf(&repo().join("tests/fixtures").join(format!("{robot}.urdf")), false);
        let files = generate(&model, &Options::default()).unwrap();
        for (path, status) in
            write_files(&repo().join("generated/fixtures").join(robot), &files, !bless).unwrap()
        {
            if status == FileStatus::Stale {
                stale.push(path.display().to_string());
            }
        }
    }
    assert!(stale.is_empty(), "stale generated files (GRID_GEN_BLESS=1 cargo test -p grid-gen --test generated_fresh to refresh):\n{}", stale.join("\n"));
}
