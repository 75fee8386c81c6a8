//! The C++ example (`examples/cpp`, CMake, Eigen) links iiwa's static library and must
//! print the reference's forward dynamics and gradient. The library is built by a nested
//! cargo into its own target folder (the outer one is locked while tests run).

use std::process::{Command, Stdio};

use grid_gen::reference;
use grid_gen_test_support::*;

fn run(what: &str, cmd: &mut Command) -> String {
    let out = cmd.output().unwrap_or_else(|e| panic!("{what}: cannot start: {e}"));
    assert!(
        out.status.success(),
        "{what} failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_cpp_example_links_the_library_and_matches_the_reference() {
    let have = |tool: &str| {
        Command::new(tool)
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if !have("cmake") || !have("c++") {
        assert!(
            std::env::var_os("CI").is_none(),
            "cmake and a C++ compiler are required in CI (Debian: cmake g++ libeigen3-dev)"
        );
        eprintln!("SKIPPED: cmake or c++ is missing");
        return;
    }
    let root = repo();
    let build = root.join("target/cpp-example");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    run(
        "cargo build -p iiwa-c",
        Command::new(cargo)
            .current_dir(&root)
            .args(["build", "-q", "-p", "iiwa-c", "--target-dir"])
            .arg(build.join("cargo")),
    );
    let lib_dir = build.join("cargo/debug");
    assert!(lib_dir.join("libgrid_iiwa.a").exists());
    let cmake_dir = build.join("cmake");
    run(
        "cmake configure",
        Command::new("cmake")
            .arg("-S")
            .arg(root.join("examples/cpp"))
            .arg("-B")
            .arg(&cmake_dir)
            .arg(format!("-DGRID_IIWA_LIB_DIR={}", lib_dir.display())),
    );
    run("cmake build", Command::new("cmake").arg("--build").arg(&cmake_dir));

    let model = load("grid_iiwa");
    let mut rng = Rng(11);
    let n = 5;
    let states: Vec<[Vec<f64>; 3]> = (0..n)
        .map(|_| {
            [
                (0..7).map(|_| rng.uniform(-2.0, 2.0)).collect(),
                (0..7).map(|_| rng.uniform(-1.5, 1.5)).collect(),
                (0..7).map(|_| rng.uniform(-20.0, 20.0)).collect(),
            ]
        })
        .collect();
    let input: String = format!("{n}\n")
        + &states
            .iter()
            .map(|s| {
                s.iter().flatten().map(|x| format!("{x:e}")).collect::<Vec<_>>().join(" ") + "\n"
            })
            .collect::<String>();
    let mut child = Command::new(cmake_dir.join("iiwa_example"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::io::Write::write_all(child.stdin.as_mut().unwrap(), input.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "iiwa_example: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines[0].starts_with("joints iiwa_joint_1 "), "{text}");
    let numbers = |line: &str, label: &str| -> Vec<f64> {
        let mut words = line.split_whitespace();
        assert_eq!(words.next(), Some(label), "{line}");
        words.map(|w| w.parse().unwrap()).collect()
    };
    let mut worst = 0.0f64;
    for (i, [q, qd, tau]) in states.iter().enumerate() {
        let (qdd, dq, dqd) =
            reference::forward_dynamics_derivatives(&model, q, qd, tau, reference::DEFAULT_GRAVITY);
        let got = [
            numbers(lines[2 + 3 * i], "qdd"),
            numbers(lines[3 + 3 * i], "dqdd_dq"),
            numbers(lines[4 + 3 * i], "dqdd_dqd"),
        ];
        let want = [qdd, dq.transpose().as_slice().to_vec(), dqd.transpose().as_slice().to_vec()];
        for (g, w) in got.iter().zip(&want) {
            worst = worst.max(rel_err(&col(g), &col(w)));
        }
    }
    let back = numbers(lines[2 + 3 * n], "rnea_minus_tau");
    println!(
        "C++ example, {n} states: fd_grad {worst:.1e} from the reference (tolerance 1e-12); {}",
        lines[2 + 3 * n]
    );
    // f64 round-off through M^-1 (the C ABI test measures ~1e-14); printed with 17 digits.
    assert!(worst < 1e-12);
    // RNEA of the computed qdd gives tau back, within round-off.
    assert!(back[0] < 1e-12);
}
