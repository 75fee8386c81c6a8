//! The command line end to end: exit codes, `info --json`'s documented fields, and `eval`
//! returning exactly what the library's reference computes.

use std::path::PathBuf;
use std::process::{Command, Output};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn grid_gen(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_grid-gen"))
        .current_dir(repo())
        .args(args)
        .env("NO_COLOR", "1")
        .output()
        .unwrap()
}

fn json(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stdout)))
}

#[test]
fn exit_codes() {
    assert_eq!(grid_gen(&["robots/grid_iiwa.urdf"]).status.code(), Some(0));
    assert_eq!(grid_gen(&["--help"]).status.code(), Some(0));
    assert_eq!(grid_gen(&["info", "--help"]).status.code(), Some(0));
    assert_eq!(grid_gen(&[]).status.code(), Some(2), "no URDF is a usage error");
    assert_eq!(grid_gen(&["info", "robots/grid_iiwa.urdf", "--bogus"]).status.code(), Some(2));
    assert_eq!(
        grid_gen(&["eval", "robots/grid_iiwa.urdf", "--states", "x.json", "--gravity", "1,2"])
            .status
            .code(),
        Some(2)
    );
    let missing = grid_gen(&["robots/no_such_robot.urdf"]);
    assert_eq!(missing.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&missing.stderr).contains("cannot read robots/no_such_robot.urdf")
    );
    assert_eq!(grid_gen(&["tests/diagnostics/cycle.urdf"]).status.code(), Some(1));
}

#[test]
fn summary_names_joints_levels_and_sparsity() {
    let out = grid_gen(&["robots/grid_hyq.urdf"]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.starts_with("robot `hyq`: 12 movable joints, root link `base_link_0`\n"),
        "{text}"
    );
    assert!(text.contains("    0  lf_haa_joint  (revolute, parent root)\n"), "{text}");
    assert!(text.contains("levels: [0, 3, 6, 9] [1, 4, 7, 10] [2, 5, 8, 11]\n"), "{text}");
    assert!(text.contains("sparsity: dv/dq 24 of 144 nonzero, dc/dq 36 of 144\n"), "{text}");
}

#[test]
fn info_json_has_the_documented_fields() {
    // GRiD's published counts of nonzero dv/dq columns (iiwa 28/49, HyQ 24/144, Atlas 150/900).
    for (robot, nv, nonzero) in
        [("grid_iiwa", 7, 28), ("grid_hyq", 12, 24), ("grid_atlas", 30, 150)]
    {
        let v = json(&grid_gen(&["info", &format!("robots/{robot}.urdf"), "--json"]));
        assert_eq!(v["nv"], nv);
        assert_eq!(v["joint_names"].as_array().unwrap().len(), nv);
        assert_eq!(v["joint_types"].as_array().unwrap().len(), nv);
        assert_eq!(v["parents"].as_array().unwrap().len(), nv);
        assert_eq!(v["sparsity"]["dv_dq"]["nonzero"], nonzero);
        assert_eq!(v["sparsity"]["dv_dq"]["total"], nv * nv);
        let levels: usize =
            v["levels"].as_array().unwrap().iter().map(|l| l.as_array().unwrap().len()).sum();
        assert_eq!(levels, nv);
        // Every kernel in both WGSL strategies, cooperative ones within WebGPU's 16 KiB of
        // workgroup memory, and the same figures the shader file's `// entry:` lines carry.
        let wgsl = v["wgsl"].as_array().unwrap();
        assert_eq!(
            wgsl.len(),
            20,
            "{robot}: six dynamics and four Lie-group kernels, two strategies"
        );
        assert!(v.get("wgsl_skipped").is_none());
        for e in wgsl {
            assert!(
                e["statements"].as_u64().unwrap() > 0 && e["functions"].as_u64().unwrap() > 0,
                "{e}"
            );
            assert!(e["workgroup_bytes"].as_u64().unwrap() <= 16384, "{e}");
            if e["strategy"] == "thread" {
                assert_eq!(e["workgroup_bytes"], 0);
            }
        }
        if robot != "grid_atlas" {
            let shader = std::fs::read_to_string(
                repo().join("generated").join(robot).join(if robot == "grid_iiwa" {
                    "iiwa14.wgsl"
                } else {
                    "hyq.wgsl"
                }),
            )
            .unwrap();
            for e in wgsl {
                let line = format!(
                    "// entry: {} kernel={} ",
                    e["entry"].as_str().unwrap(),
                    e["kernel"].as_str().unwrap()
                );
                let header = shader
                    .lines()
                    .find(|l| l.starts_with(&line))
                    .unwrap_or_else(|| panic!("{robot}: no `{line}` in the shader"));
                assert!(
                    header.contains(&format!(
                        " statements={} functions={}",
                        e["statements"], e["functions"]
                    )),
                    "{header} vs {e}"
                );
            }
        }
    }
    // The pipelined netlists at the stage depth asked for: one level between registers
    // leaves one cell on the slowest path, and more registers than four levels need.
    let pendulum = "robots/double_pendulum_continuous.urdf";
    let pipelined = |v: &serde_json::Value| -> Vec<serde_json::Value> {
        let all = v["verilog"].as_array().unwrap().iter();
        all.filter(|n| n["arch"] == "pipelined").cloned().collect()
    };
    let four = pipelined(&json(&grid_gen(&["info", pendulum, "--json"])));
    let one = pipelined(&json(&grid_gen(&["info", pendulum, "--json", "--stage-depth", "1"])));
    assert!(!one.is_empty() && one.len() == four.len());
    for (a, b) in four.iter().zip(&one) {
        assert_eq!((a["stage_depth"].as_u64(), b["stage_depth"].as_u64()), (Some(4), Some(1)));
        assert_eq!(b["stage_path"].as_array().unwrap().len(), 1, "{b}");
        assert!(b["registers"].as_u64() > a["registers"].as_u64(), "{a} vs {b}");
    }
    // In the format asked for, every netlist: a wider one takes more divider stages (what
    // scripts/fpga.py reads for a `--fixed` run).
    let all = |v: &serde_json::Value| v["verilog"].as_array().unwrap().clone();
    let wide = all(&json(&grid_gen(&["info", pendulum, "--json", "--fixed", "100.60"])));
    let auto = all(&json(&grid_gen(&["info", pendulum, "--json"])));
    assert!(!wide.is_empty() && wide.iter().all(|n| n["format"] == "100.60"), "{wide:?}");
    let chip = |v: &[serde_json::Value]| {
        let n = v.iter().find(|n| n["partition"] == "chip" && n["arch"] == "pipelined");
        n.expect("a pipelined chip partition")["divider_stages"].as_u64().unwrap()
    };
    assert!(chip(&wide) > chip(&auto), "{} vs {}", chip(&wide), chip(&auto));
    let bad = grid_gen(&["info", pendulum, "--fixed", "12.x"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--fixed: expected WIDTH.FRAC"));
    let zero = grid_gen(&["info", pendulum, "--stage-depth", "0"]);
    assert!(String::from_utf8_lossy(&zero.stdout).contains("--stage-depth must be at least 1"));
    let panda = json(&grid_gen(&["info", "robots/panda.urdf", "--json"]));
    assert_eq!(panda["mimic"][0]["joint"], "panda_finger_joint2");
    assert_eq!(panda["mimic"][0]["mimics"], "panda_finger_joint1");
    assert_eq!(panda["joint_types"][8], "prismatic");
}

#[test]
fn eval_prints_the_reference_and_omits_what_was_not_asked() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("states.json");
    std::fs::write(&states, r#"{"states": [{"q": [0.1, -0.4], "qd": [0.5, 2], "qdd": [1, -1]}, {"q": [0, 1], "qd": [0, 0], "tau": [0.1, 0.2]}]}"#).unwrap();
    let urdf = "robots/double_pendulum_continuous.urdf";
    let out =
        grid_gen(&["eval", urdf, "--states", states.to_str().unwrap(), "--gravity", "0,-9.81,0"]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let v = json(&out);
    assert_eq!(v["joint_names"], serde_json::json!(["joint1", "joint2"]));
    let s0 = &v["states"][0];
    let s1 = &v["states"][1];
    assert!(s0.get("rnea").is_some() && s0.get("drnea_dq").is_some() && s0.get("fd").is_none());
    assert!(s1.get("rnea").is_none() && s1.get("fd").is_some() && s1.get("dfd_dqd").is_some());

    let text = std::fs::read_to_string(repo().join(urdf)).unwrap();
    let (model, _) = grid_gen::Model::from_urdf_str(urdf, &text, false).unwrap();
    let g = [0.0, -9.81, 0.0];
    let rnea = grid_gen::reference::rnea(&model, &[0.1, -0.4], &[0.5, 2.0], &[1.0, -1.0], g);
    assert_eq!(s0["rnea"], serde_json::json!(rnea), "JSON round-trips f64 exactly");
    let (_, dq, _) = grid_gen::reference::forward_dynamics_derivatives(
        &model,
        &[0.0, 1.0],
        &[0.0, 0.0],
        &[0.1, 0.2],
        g,
    );
    assert_eq!(
        s1["dfd_dq"][0][1].as_f64().unwrap(),
        dq[(0, 1)],
        "row-major: [i][j] = d out_i / d in_j"
    );

    std::fs::write(
        &states,
        r#"{"states": [{"q": [0, 0], "qd": [0, 0]}, {"q": [0, 0, 0], "qd": [0, 0]}]}"#,
    )
    .unwrap();
    let bad = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&bad.stderr)
            .contains("state 1: `q` has 3 entries, the robot has 2 joints"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );

    // Python's json.dump writes NaN bare; the error still names the entry.
    std::fs::write(&states, r#"{"states": [{"q": [0, 0], "qd": [0, NaN]}]}"#).unwrap();
    let nan = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert_eq!(nan.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&nan.stderr).contains("state 0: `qd[1]` is not finite"),
        "{}",
        String::from_utf8_lossy(&nan.stderr)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn generate_writes_checks_and_reports_op_counts() {
    // The checked-in kernels are fresh by the CLI's own --check too.
    let fresh = grid_gen(&["robots/grid_iiwa.urdf", "-o", "generated/grid_iiwa", "--check"]);
    assert_eq!(fresh.status.code(), Some(0), "{}", String::from_utf8_lossy(&fresh.stderr));
    assert!(
        String::from_utf8_lossy(&fresh.stdout).contains("unchanged generated/grid_iiwa/iiwa14.rs")
    );

    let dir = std::env::temp_dir().join(format!("grid-gen-cli-gen-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().unwrap();
    let stale = grid_gen(&["robots/ur5.urdf", "-o", d, "--check"]);
    assert_eq!(stale.status.code(), Some(1));
    assert!(!dir.exists(), "--check writes nothing");
    let wrote = grid_gen(&["robots/ur5.urdf", "-o", d, "--emit", "rust"]);
    assert_eq!(wrote.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&wrote.stdout).starts_with("wrote "));
    assert_eq!(
        std::fs::read_to_string(dir.join("ur5.rs")).unwrap(),
        std::fs::read_to_string(repo().join("generated/ur5/ur5.rs")).unwrap()
    );
    assert_eq!(grid_gen(&["robots/ur5.urdf", "-o", d, "--check"]).status.code(), Some(0));
    // A different gravity is a different module.
    assert_eq!(
        grid_gen(&["robots/ur5.urdf", "-o", d, "--check", "--gravity", "0,0,-1.62"]).status.code(),
        Some(1)
    );
    assert_eq!(grid_gen(&["robots/ur5.urdf", "-o", d, "--emit", "cuda"]).status.code(), Some(2));
    // The checked-in UR5 takes auto's picks, `world` for rnea_grad and `idsva` for fd_grad
    // (`info`); forcing any one formulation is another file, and an unknown one is a usage
    // error.
    for form in ["idsva", "world", "columns"] {
        assert_eq!(
            grid_gen(&["robots/ur5.urdf", "-o", d, "--check", "--gradient", form]).status.code(),
            Some(1),
            "{form}"
        );
    }
    assert_eq!(
        grid_gen(&["robots/ur5.urdf", "-o", d, "--gradient", "rnea"]).status.code(),
        Some(2)
    );
    std::fs::remove_dir_all(&dir).unwrap();

    // Both backends in one run, each file as checked in.
    let wrote = grid_gen(&["robots/grid_iiwa.urdf", "-o", d, "--emit", "rust,wgsl"]);
    assert_eq!(wrote.status.code(), Some(0), "{}", String::from_utf8_lossy(&wrote.stderr));
    for file in ["iiwa14.rs", "iiwa14.wgsl"] {
        assert_eq!(
            std::fs::read_to_string(dir.join(file)).unwrap(),
            std::fs::read_to_string(repo().join("generated/grid_iiwa").join(file)).unwrap(),
            "{file}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();

    let v = json(&grid_gen(&["info", "robots/grid_iiwa.urdf", "--json"]));
    let kernels: Vec<&str> =
        v["ops"].as_array().unwrap().iter().map(|k| k["kernel"].as_str().unwrap()).collect();
    assert_eq!(
        kernels,
        [
            "rnea",
            "rnea_grad",
            "mass_matrix",
            "minv",
            "fd",
            "fd_grad",
            "integrate",
            "dintegrate",
            "difference",
            "ddifference"
        ]
    );
    for k in v["ops"].as_array().unwrap() {
        for field in ["add", "mul", "div", "neg", "trig", "depth"] {
            assert!(k["after"][field].is_u64() && k["before"][field].is_u64(), "{k}");
        }
        // The gradient kernels name their formulation; the others have none.
        let has_gradient = matches!(k["kernel"].as_str(), Some("rnea_grad" | "fd_grad"));
        assert_eq!(k["gradient"].as_str(), has_gradient.then_some("idsva"), "{k}");
    }
    // Every formulation's cost, the picked one the cheapest.
    let costs = v["gradient_costs"].as_array().unwrap();
    let names: Vec<&str> = costs.iter().map(|c| c["gradient"].as_str().unwrap()).collect();
    assert_eq!(names, ["columns", "idsva", "world"]);
    let cheapest = costs.iter().min_by_key(|c| c["ops"].as_u64().unwrap()).unwrap();
    assert_eq!(cheapest["gradient"], "idsva");
    let grad = v["ops"].as_array().unwrap().iter().find(|k| k["kernel"] == "rnea_grad").unwrap();
    let after: u64 = ["add", "mul", "div", "neg", "trig"]
        .iter()
        .map(|f| grad["after"][f].as_u64().unwrap())
        .sum();
    assert_eq!(cheapest["ops"].as_u64(), Some(after));
}

/// A serial chain of `n` revolute links with alternating axes, written to a temporary file.
fn chain_urdf(n: usize) -> PathBuf {
    let s = grid_gen_test_support::chain_urdf(n);
    let path = std::env::temp_dir().join(format!("grid-gen-chain{n}-{}.urdf", std::process::id()));
    std::fs::write(&path, s).unwrap();
    path
}

/// `info --json` on 400- and 1000-link chains with the address space limited to 2 GiB
/// (`ulimit -v`): it must finish, list the kernels it could count and say why it skipped
/// the others, never abort on an allocation. Generation on the 1000-link chain stops
/// with a clear error instead of exhausting memory.
#[test]
fn huge_chains_stay_within_two_gib() {
    for n in [400, 1000] {
        let path = chain_urdf(n);
        let start = std::time::Instant::now();
        let script = format!("ulimit -v 2097152 && exec \"$0\" info {} --json", path.display());
        let out = Command::new("sh")
            .arg("-c")
            .arg(script)
            .arg(env!("CARGO_BIN_EXE_grid-gen"))
            .output()
            .unwrap();
        let elapsed = start.elapsed();
        assert_eq!(
            out.status.code(),
            Some(0),
            "chain{n}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let info = json(&out);
        assert_eq!(info["nv"], n);
        let counted = info["ops"].as_array().unwrap().len();
        let skipped = info["ops_skipped"].as_array().unwrap();
        assert_eq!(counted + skipped.len(), 10, "chain{n}: every kernel is counted or skipped");
        assert!(
            skipped.iter().any(|s| s["kernel"] == "fd_grad"),
            "chain{n}: fd_grad is over the op-count limit"
        );
        assert!(skipped.iter().all(|s| !s["reason"].as_str().unwrap().is_empty()));
        eprintln!("chain{n}: info in {elapsed:.1?}, {counted} kernels counted");
        if n == 1000 {
            let dir =
                std::env::temp_dir().join(format!("grid-gen-chain-out-{}", std::process::id()));
            let script =
                format!("ulimit -v 2097152 && exec \"$0\" {} -o {}", path.display(), dir.display());
            let out = Command::new("sh")
                .arg("-c")
                .arg(script)
                .arg(env!("CARGO_BIN_EXE_grid-gen"))
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(1), "{err}");
            assert!(err.contains("needs more than 10000000 IR nodes"), "{err}");
            assert!(!dir.join("chain.rs").exists(), "nothing is written");
        }
        std::fs::remove_file(&path).unwrap();
    }
}

/// Whether a WebGPU adapter is there; with `CI` set its absence fails the test.
fn adapter_or_skip(out: &Output) -> bool {
    let err = String::from_utf8_lossy(&out.stderr);
    if out.status.code() == Some(1) && err.contains("no WebGPU adapter") {
        assert!(std::env::var_os("CI").is_none(), "{err}");
        eprintln!("SKIPPED: {err}");
        return false;
    }
    true
}

/// `eval --backend wgsl` prints the same keys, in the same order, as the reference, on a
/// robot the checked-in kernels do not include (a 3-joint chain written here), within
/// the f32 bounds of the WGSL tests (1e-5 direct, 1e-4 through M⁻¹; relative, max-abs).
/// The cooperative run also takes `--gradient idsva --solve ltdl`, which must reach the
/// generated kernels (stderr names the routes) and give the same numbers.
#[test]
fn eval_wgsl_matches_the_reference_on_an_unseen_robot() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-wgsl-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let urdf = chain_urdf(3);
    let states = dir.join("states.json");
    std::fs::write(
        &states,
        r#"{"states": [{"q": [0.3, -1.2, 2.0], "qd": [0.5, 1.5, -2.5], "qdd": [1.0, -0.5, 0.25], "tau": [2.0, -1.0, 0.5], "v": [0.2, -0.1, 0.4], "q1": [0.5, -1.0, 2.2]},
                      {"q": [-2.5, 0.1, 1.0], "qd": [-0.2, 0.0, 3.0]}]}"#,
    )
    .unwrap();
    let (u, s) = (urdf.to_str().unwrap(), states.to_str().unwrap());
    let reference = grid_gen(&["eval", u, "--states", s]);
    assert_eq!(reference.status.code(), Some(0), "{}", String::from_utf8_lossy(&reference.stderr));
    for (strategy, routes) in [
        ("thread", ["--gradient", "auto", "--solve", "auto"]),
        ("cooperative", ["--gradient", "idsva", "--solve", "ltdl"]),
    ] {
        let args = ["eval", u, "--states", s, "--backend", "wgsl", "--wgsl-strategy", strategy];
        let args: Vec<&str> = args.iter().chain(&routes).copied().collect();
        let out = grid_gen(&args);
        if !adapter_or_skip(&out) {
            return;
        }
        assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
        // stderr names the adapter, the number type and the strategy, and nothing from Mesa
        // about XDG_RUNTIME_DIR even where it is unset.
        let quiet = Command::new(env!("CARGO_BIN_EXE_grid-gen"))
            .current_dir(repo())
            .args(&args)
            .env_remove("XDG_RUNTIME_DIR")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&quiet.stderr);
        assert!(
            err.contains("eval: WGSL on `")
                && err.contains(&format!(
                    "f32, {strategy} strategy, gradient {}, solve {}",
                    routes[1], routes[3]
                ))
                && !err.contains("XDG_RUNTIME_DIR"),
            "{err}"
        );
        let (want, got) = (json(&reference), json(&out));
        assert_eq!(want["joint_names"], got["joint_names"]);
        for (ws, gs) in
            want["states"].as_array().unwrap().iter().zip(got["states"].as_array().unwrap())
        {
            let (wo, go) = (ws.as_object().unwrap(), gs.as_object().unwrap());
            assert_eq!(
                wo.keys().collect::<Vec<_>>(),
                go.keys().collect::<Vec<_>>(),
                "{strategy}: keys differ"
            );
            /// Every number of a value, in order (the Lie-group results are objects).
            fn flat(v: &serde_json::Value) -> Vec<f64> {
                match v {
                    serde_json::Value::Array(a) => a.iter().flat_map(flat).collect(),
                    serde_json::Value::Object(o) => o.values().flat_map(flat).collect(),
                    x => vec![x.as_f64().unwrap()],
                }
            }
            for (key, w) in wo {
                let (w, g) = (flat(w), flat(&go[key]));
                let scale = w.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(f64::MIN_POSITIVE);
                let err = w.iter().zip(&g).fold(0.0f64, |m, (a, b)| m.max((a - b).abs())) / scale;
                let tol = if ["Minv", "fd", "dfd_dq", "dfd_dqd"].contains(&key.as_str()) {
                    1e-4
                } else {
                    1e-5
                };
                assert!(err <= tol, "{strategy} {key}: relative error {err:.2e} > {tol:e}");
            }
        }
    }
}

#[test]
fn bench_prints_a_row_per_kernel_strategy_and_batch() {
    let out = grid_gen(&[
        "bench",
        "robots/double_pendulum_continuous.urdf",
        "--batch",
        "1,100",
        "--kernels",
        "rnea,mass_matrix",
        "--seconds",
        "0.01",
    ]);
    if !adapter_or_skip(&out) {
        return;
    }
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let floor = text
        .lines()
        .find_map(|l| l.split("empty submission and wait ").nth(1))
        .and_then(|t| t.trim_end_matches(" us").parse::<f64>().ok());
    assert!(floor.is_some_and(|t| t > 0.0 && t.is_finite()), "no submission floor:\n{text}");
    for kernel in ["rnea", "mass_matrix"] {
        for strategy in ["thread", "cooperative"] {
            for n in ["1", "100"] {
                let row = text.lines().find(|l| {
                    let w: Vec<&str> = l.split_whitespace().collect();
                    w.len() == 14 && w[0] == kernel && w[1] == strategy && w[2] == n
                });
                let row =
                    row.unwrap_or_else(|| panic!("no row for {kernel} {strategy} {n}:\n{text}"));
                // States per second, and the round trips on the uploaded batch and with
                // fresh buffers.
                for column in [6, 7, 8] {
                    let x: f64 = row.split_whitespace().nth(column).unwrap().parse().unwrap();
                    assert!(x > 0.0 && x.is_finite(), "{row}");
                }
                // The device's own time for the pass, or `-` without timestamp queries.
                let device = row.split_whitespace().nth(9).unwrap();
                assert!(
                    device == "-" || device.parse::<f64>().is_ok_and(|t| t >= 0.0 && t.is_finite()),
                    "{row}"
                );
                // The round trip's phases (states in, submission and wait, copy out,
                // conversion to f64): finite times, the submission never free.
                let phases: Vec<f64> = (10..14)
                    .map(|c| row.split_whitespace().nth(c).unwrap().parse().unwrap())
                    .collect();
                assert!(phases.iter().all(|t| *t >= 0.0 && t.is_finite()), "{row}");
                assert!(phases[1] > 0.0, "the submission and wait take time: {row}");
            }
        }
    }
    // A floating base: q has nq = nv + 1 entries per state (the base's quaternion). Forces:
    // `u` holds nv torques or accelerations and then fext and λ, per state.
    for scene in ["examples/scenes/hyq_floating.toml", "examples/scenes/hyq_contacts_floating.toml"]
    {
        let out = grid_gen(&[
            "bench",
            "robots/grid_hyq.urdf",
            "--scene",
            scene,
            "--batch",
            "2",
            "--kernels",
            "rnea",
            "--wgsl-strategy",
            "thread",
            "--seconds",
            "0.01",
        ]);
        assert_eq!(out.status.code(), Some(0), "{scene}: {}", stderr(&out));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.lines().any(|l| l.starts_with("rnea ") && l.contains(" thread ")),
            "{scene}: {text}"
        );
    }
    let bad = grid_gen(&["bench", "robots/double_pendulum_continuous.urdf", "--kernels", "nope"]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        stderr(&bad).contains("invalid value 'nope' for '--kernels")
            && stderr(&bad).contains("possible values: rnea, rnea_grad,"),
        "{}",
        stderr(&bad)
    );
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// What a new user tripped over on the command line.
#[test]
fn what_a_new_user_tripped_over() {
    // Global options work before the command too; `--strict` really is strict there (Atlas
    // has implausible inertias, a warning).
    assert_eq!(grid_gen(&["--strict", "info", "robots/grid_iiwa.urdf"]).status.code(), Some(0));
    assert_eq!(grid_gen(&["--strict", "info", "robots/grid_atlas.urdf"]).status.code(), Some(1));
    assert_eq!(grid_gen(&["--strict", "robots/grid_atlas.urdf"]).status.code(), Some(1));
    assert_eq!(grid_gen(&["info", "robots/grid_atlas.urdf"]).status.code(), Some(0));
    // `generate` is the default command and can be named.
    assert_eq!(
        grid_gen(&["generate", "robots/grid_iiwa.urdf"]).stdout,
        grid_gen(&["robots/grid_iiwa.urdf"]).stdout
    );
    // A mistyped command is named as one, with the suggestion.
    let typo = grid_gen(&["infoo", "robots/grid_iiwa.urdf"]);
    assert_eq!(typo.status.code(), Some(2));
    assert!(
        stderr(&typo).contains("unrecognized command 'infoo'")
            && stderr(&typo).contains("a similar command exists: 'info'"),
        "{}",
        stderr(&typo)
    );
    // A mistyped flag gets clap's suggestion, before or after the URDF.
    for args in [
        &["robots/grid_iiwa.urdf", "--gravty", "0,0,1"][..],
        &["--gravty", "0,0,1", "robots/grid_iiwa.urdf"],
    ] {
        let flag = grid_gen(args);
        assert_eq!(flag.status.code(), Some(2));
        assert!(
            stderr(&flag).contains("a similar argument exists: '--gravity'"),
            "{}",
            stderr(&flag)
        );
    }
    // The top-level usage shows the options.
    let bare = grid_gen(&[]);
    let text = String::from_utf8_lossy(&bare.stdout).into_owned() + &stderr(&bare);
    assert!(
        text.contains("Usage: grid-gen [OPTIONS] <ROBOT.urdf>")
            && text.contains("grid-gen [OPTIONS] <COMMAND>"),
        "{text}"
    );
    // The summary counts the operations of the code that --gravity would generate: zero
    // gravity folds the gravity terms away.
    let ops = |args: &[&str]| -> u64 {
        let v = json(&grid_gen(args));
        v["ops"]
            .as_array()
            .unwrap()
            .iter()
            .find(|k| k["kernel"] == "rnea")
            .map(|k| k["after"]["mul"].as_u64().unwrap())
            .unwrap()
    };
    let default = ops(&["info", "robots/grid_iiwa.urdf", "--json"]);
    let zero = ops(&["info", "robots/grid_iiwa.urdf", "--json", "--gravity", "0,0,0"]);
    assert!(zero < default, "zero gravity: {zero} multiplications, default {default}");
    let summary =
        String::from_utf8_lossy(&grid_gen(&["robots/grid_iiwa.urdf", "--gravity", "0,0,0"]).stdout)
            .into_owned();
    assert!(summary.contains("gravity: 0, 0, 0 m/s²"), "{summary}");

    let dir = std::env::temp_dir().join(format!("grid-gen-cli-newuser-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // One movable joint is singular.
    let single = dir.join("single.urdf");
    std::fs::write(
        &single,
        r#"<robot name="one"><link name="base"/><link name="arm"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>
<joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"#,
    )
    .unwrap();
    let one = String::from_utf8_lossy(&grid_gen(&[single.to_str().unwrap()]).stdout).into_owned();
    assert!(one.contains("robot `one`: 1 movable joint,"), "{one}");
    // -o naming an existing file says so.
    let file = dir.join("a_file");
    std::fs::write(&file, "x").unwrap();
    let out = grid_gen(&["robots/ur5.urdf", "-o", file.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("not a directory"), "{}", stderr(&out));
    // Two URDFs whose robots share a name do not overwrite each other in one folder.
    let ur5 = std::fs::read_to_string(repo().join("robots/ur5.urdf")).unwrap();
    let (a, b) = (dir.join("ur5_a.urdf"), dir.join("ur5_b.urdf"));
    std::fs::write(&a, &ur5).unwrap();
    std::fs::write(&b, &ur5).unwrap();
    let out_dir = dir.join("out");
    let o = out_dir.to_str().unwrap();
    assert_eq!(grid_gen(&[a.to_str().unwrap(), "-o", o]).status.code(), Some(0));
    let clash = grid_gen(&[b.to_str().unwrap(), "-o", o]);
    assert_eq!(clash.status.code(), Some(1));
    assert!(
        stderr(&clash).contains("generated from ur5_a.urdf, not ur5_b.urdf"),
        "{}",
        stderr(&clash)
    );
    assert!(
        std::fs::read_to_string(out_dir.join("ur5.rs")).unwrap().contains("// source: ur5_a.urdf"),
        "the first robot's file is kept"
    );
    assert_eq!(
        grid_gen(&[a.to_str().unwrap(), "-o", o]).status.code(),
        Some(0),
        "regenerating from the same file is fine"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// One word per choice across the commands, typed flags, and no flag accepted by a command
/// that would ignore it.
#[test]
fn every_command_takes_only_its_own_flags() {
    let iiwa = "robots/grid_iiwa.urdf";
    // A WGSL or Verilog setting means nothing to `info` (beyond its own --stage-depth and
    // --fixed): an error, not ignored.
    for flag in [["--wgsl-workers", "7"], ["--multipliers", "4"]] {
        let out = grid_gen(&["info", iiwa, flag[0], flag[1]]);
        assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
        assert!(stderr(&out).contains(&format!("unexpected argument '{}'", flag[0])));
    }
    // Nor do batch sizes to `bench --backend rust`, which times one state per call.
    let out = grid_gen(&["bench", iiwa, "--backend", "rust", "--batch", "16"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("apply to `--backend wgsl` only"), "{}", stderr(&out));
    // `eval` runs one strategy: `both` is refused, not silently read as `thread`.
    let states = std::env::temp_dir().join(format!("grid-gen-cli-own-{}.json", std::process::id()));
    std::fs::write(&states, r#"{"states": [{"q": [0,0,0,0,0,0,0], "qd": [0,0,0,0,0,0,0]}]}"#)
        .unwrap();
    let s = states.to_str().unwrap();
    let out =
        grid_gen(&["eval", iiwa, "--states", s, "--backend", "wgsl", "--wgsl-strategy", "both"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("runs one WGSL strategy"), "{}", stderr(&out));
    // Enumerated flags list their values and refuse others (no fallback to a default).
    let out = grid_gen(&["eval", iiwa, "--states", s, "--backend", "cuda"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("[possible values: reference, wgsl, verilog]"),
        "{}",
        stderr(&out)
    );
    let out = grid_gen(&["info", iiwa, "--gradient", "dense"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        stderr(&out).contains("[possible values: auto, columns, idsva, world]"),
        "{}",
        stderr(&out)
    );
    // `--solve` reaches the summary's counts, as it reaches the generated code.
    let summary =
        String::from_utf8_lossy(&grid_gen(&["info", iiwa, "--solve", "minv"]).stdout).into_owned();
    assert!(summary.contains("solve: minv"), "{summary}");
    // A flag replaces the scene's value, gravity as every other; the rest of the scene stays.
    let scene = std::env::temp_dir().join(format!("grid-gen-cli-own-{}.toml", std::process::id()));
    std::fs::write(&scene, "gravity = [0.0, 0.0, -3.0]\n[lock]\niiwa_joint_7 = 0.0\n").unwrap();
    let summary = |extra: &[&str]| {
        let mut args = vec!["--scene", scene.to_str().unwrap(), iiwa];
        args.extend(extra);
        String::from_utf8_lossy(&grid_gen(&args).stdout).into_owned()
    };
    let (scene_only, flagged) = (summary(&[]), summary(&["--gravity", "0,0,-1.62"]));
    assert!(scene_only.contains("gravity: 0, 0, -3 m/s²"), "{scene_only}");
    assert!(
        flagged.contains("gravity: 0, 0, -1.62 m/s²") && flagged.contains("6 movable joints"),
        "{flagged}"
    );
    std::fs::remove_file(&scene).unwrap();
    // `generate` names its backends with the word every command uses; `--emit` still works.
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-own-{}", std::process::id()));
    let d = dir.to_str().unwrap();
    let out = grid_gen(&[iiwa, "-o", d, "--backend", "rust,c"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(dir.join("iiwa14.h").exists() && dir.join("iiwa14_c.rs").exists());
    assert_eq!(grid_gen(&[iiwa, "-o", d, "--check", "--emit", "rust,c"]).status.code(), Some(0));
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_file(&states).unwrap();
}

/// `accuracy`: a row per kernel and format in text and JSON, the SVG written, the WGSL
/// kernels measured on the adapter next to the CPU formats, and bad arguments named.
#[test]
fn accuracy_measures_every_format_and_plots() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-accuracy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let plot = dir.join("trade.svg");
    let out = grid_gen(&[
        "accuracy",
        "robots/grid_iiwa.urdf",
        "--random",
        "5",
        "--json",
        "--plot",
        plot.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let report = json(&out);
    assert_eq!(report["states"], 5);
    let rows = report["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 6 * 3, "six kernels in f64, f32 and the --fixed format");
    for r in rows.iter().filter(|r| r["format"] == "f64") {
        assert!(r["error"]["max"].as_f64().unwrap() <= 1e-12, "{r}");
    }
    assert!(std::fs::read_to_string(&plot).unwrap().starts_with("<svg"));
    let text = grid_gen(&[
        "accuracy",
        "robots/grid_iiwa.urdf",
        "--random",
        "3",
        "--kernels",
        "rnea_grad",
        "--formats",
        "f64,fixed:32.16",
    ]);
    let text = String::from_utf8(text.stdout).unwrap();
    assert!(
        text.contains("cond(M): median") && text.contains("rnea_grad    fixed 32.16 half-up"),
        "{text}"
    );
    let bad = grid_gen(&["accuracy", "robots/grid_iiwa.urdf", "--formats", "f16"]);
    assert_eq!(bad.status.code(), Some(1));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("unknown number format `f16`") && err.matches("available").count() == 1,
        "one list of the formats: {err}"
    );
    // --plot creates its folder, as -o does.
    let plot_dir = std::env::temp_dir().join(format!("grid-gen-plot-{}", std::process::id()));
    let nested = plot_dir.join("plots/x.svg");
    let out = grid_gen(&[
        "accuracy",
        "robots/double_pendulum_continuous.urdf",
        "--random",
        "2",
        "--formats",
        "f64",
        "--plot",
        nested.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::read_to_string(&nested).unwrap().starts_with("<svg"));
    std::fs::remove_dir_all(&plot_dir).unwrap();
    let bad = grid_gen(&["accuracy", "robots/grid_iiwa.urdf", "--kernels", "aba"]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("invalid value 'aba' for '--kernels"));
    // WGSL is a backend, named as every command names one.
    let bad = grid_gen(&["accuracy", "robots/grid_iiwa.urdf", "--formats", "f32,wgsl"]);
    assert!(stderr(&bad).contains("pass --backend wgsl"), "{}", stderr(&bad));
    let gpu = grid_gen(&[
        "accuracy",
        "robots/double_pendulum_continuous.urdf",
        "--random",
        "4",
        "--formats",
        "f32",
        "--backend",
        "wgsl",
        "--json",
    ]);
    if adapter_or_skip(&gpu) {
        assert_eq!(gpu.status.code(), Some(0), "{}", String::from_utf8_lossy(&gpu.stderr));
        let report = json(&gpu);
        let wgsl: Vec<_> = report["rows"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|r| r["format"].as_str().unwrap().starts_with("wgsl f32 thread on "))
            .collect();
        assert_eq!(wgsl.len(), 6);
        for r in wgsl {
            // The WGSL tests' f32 bounds, from f64 states (1e-5 direct, 1e-4 through M⁻¹).
            let tol = if ["minv", "fd", "fd_grad"].contains(&r["kernel"].as_str().unwrap()) {
                1e-4
            } else {
                1e-5
            };
            assert!(r["error"]["max"].as_f64().unwrap() <= tol, "{r}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--scene` (before or after the command) reaches every command: the summary and `info`
/// see the reduced robot and the scene's gravity, `generate` writes only the scene's
/// kernels, `accuracy` measures only those; a bad scene is an error naming it.
#[test]
fn a_scene_reduces_every_command() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-scene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("scene.toml");
    std::fs::write(
        &scene,
        "outputs = [\"rnea_grad\"]\ngravity = [0.0, 0.0, -1.62]\n[lock]\niiwa_joint_7 = 0.3\n",
    )
    .unwrap();
    let s = scene.to_str().unwrap();
    // The text summary says what the scene changed.
    let text = grid_gen(&["--scene", s, "robots/grid_iiwa.urdf"]);
    assert!(String::from_utf8_lossy(&text.stdout)
        .contains("scene: locked (fixed at these positions): iiwa_joint_7 = 0.3\n"));
    let info = grid_gen(&["--scene", s, "info", "robots/grid_iiwa.urdf", "--json"]);
    assert_eq!(info.status.code(), Some(0), "{}", String::from_utf8_lossy(&info.stderr));
    let info = json(&info);
    assert_eq!(info["nv"], 6);
    assert_eq!(info["gravity"], serde_json::json!([0.0, 0.0, -1.62]));
    let out = dir.join("out");
    let gen = grid_gen(&["robots/grid_iiwa.urdf", "-o", out.to_str().unwrap(), "--scene", s]);
    assert_eq!(gen.status.code(), Some(0), "{}", String::from_utf8_lossy(&gen.stderr));
    let code = std::fs::read_to_string(out.join("iiwa14.rs")).unwrap();
    assert!(
        code.contains("pub fn rnea_grad<")
            && !code.contains("pub fn fd_grad<")
            && !code.contains("pub fn minv<")
    );
    assert!(code.contains("NV: usize = 6") && code.contains("-1.62"));
    let acc =
        grid_gen(&["accuracy", "robots/grid_iiwa.urdf", "--random", "3", "--scene", s, "--json"]);
    assert_eq!(acc.status.code(), Some(0), "{}", String::from_utf8_lossy(&acc.stderr));
    let rows = json(&acc)["rows"].as_array().unwrap().clone();
    assert!(!rows.is_empty() && rows.iter().all(|r| r["kernel"] == "rnea_grad"), "{rows:?}");
    std::fs::write(&scene, "[lock]\niiwa_joint_9 = 0.3\n").unwrap();
    let bad = grid_gen(&["info", "robots/grid_iiwa.urdf", "--scene", s]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr)
        .contains("[lock] names joint `iiwa_joint_9`, which robot `iiwa14` does not have"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `bench --backend rust` and `accuracy --time` compile the generated kernels of a robot
/// with rustc and time them: a row per kernel with positive times for the portable copy
/// and the dispatcher in f64 and f32 (returning its outputs, and `{kernel}_into`), and for
/// the `fma` copy exactly where the dispatcher
/// runs the `avx512` copy (the header says which); kernels with external and contact
/// forces too; and the times beside the f64 and f32 errors. (Times are not compared: that
/// is for benchmarks.)
#[test]
fn rust_kernels_are_compiled_and_timed() {
    let out = grid_gen(&[
        "bench",
        "robots/double_pendulum_continuous.urdf",
        "--backend",
        "rust",
        "--kernels",
        "rnea,fd_grad",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    let avx512 = text.lines().next().is_some_and(|l| l.contains("dispatch runs the avx512 copy"));
    for kernel in ["rnea", "fd_grad"] {
        let row = text
            .lines()
            .find(|l| l.starts_with(&format!("{kernel} ")))
            .unwrap_or_else(|| panic!("no {kernel} row in\n{text}"));
        let cells: Vec<&str> = row.split_whitespace().skip(1).collect();
        assert_eq!(cells.len(), 8, "{row}");
        for (i, cell) in cells.iter().enumerate() {
            // Columns: f64 portable, fma, dispatch; f32 portable, fma, dispatch; f64 and
            // f32 `{kernel}_into`.
            if i < 6 && i % 3 == 1 && !avx512 {
                assert_eq!(*cell, "-", "{row}");
            } else {
                assert!(cell.parse::<f64>().is_ok_and(|t| t > 0.0), "{row}");
            }
        }
    }
    // Kernels that take external and contact forces get them as arguments (a robot whose
    // last body moves in three directions, so that a point contact there is accepted).
    let forced = grid_gen(&[
        "bench",
        "tests/fixtures/ball_arm.urdf",
        "--backend",
        "rust",
        "--kernels",
        "rnea_grad,contact_fd",
        "--fext",
        "*",
        "--contact",
        "l6:point",
    ]);
    assert_eq!(forced.status.code(), Some(0), "{}", String::from_utf8_lossy(&forced.stderr));
    let text = String::from_utf8(forced.stdout).unwrap();
    for kernel in ["rnea_grad", "contact_fd"] {
        let row = text
            .lines()
            .find(|l| l.starts_with(&format!("{kernel} ")))
            .unwrap_or_else(|| panic!("no {kernel} row in\n{text}"));
        let dispatch = row.split_whitespace().nth(3).and_then(|c| c.parse::<f64>().ok());
        assert!(dispatch.is_some_and(|t| t > 0.0), "{row}");
    }
    let acc = grid_gen(&[
        "accuracy",
        "robots/double_pendulum_continuous.urdf",
        "--random",
        "4",
        "--formats",
        "f64,f32,fixed",
        "--time",
        "--json",
    ]);
    assert_eq!(acc.status.code(), Some(0), "{}", String::from_utf8_lossy(&acc.stderr));
    for r in json(&acc)["rows"].as_array().unwrap() {
        let float = r["format"] == "f64" || r["format"] == "f32";
        assert_eq!(r["time_ns"].as_f64().is_some_and(|t| t > 0.0), float, "{r}");
    }
}

/// `--floating-base`: `info --json` gives nq and the free-flyer's joints, the
/// summary says so, `eval` takes the long q and names a wrong one, and generation writes
/// `NQ` and `q: &[T; NQ]`.
#[test]
fn floating_base_from_the_command_line() {
    let urdf = "robots/grid_hyq.urdf";
    let v = json(&grid_gen(&["--floating-base", "info", urdf, "--json"]));
    assert_eq!(
        (v["nv"].as_u64(), v["nq"].as_u64(), v["floating_base"].as_bool()),
        (Some(18), Some(19), Some(true))
    );
    assert_eq!(v["joint_names"][0], "root_joint_vx");
    assert_eq!(v["joint_names"][5], "root_joint_wz");
    let fixed = json(&grid_gen(&["info", urdf, "--json"]));
    assert_eq!((fixed["nq"].as_u64(), fixed["floating_base"].as_bool()), (Some(12), Some(false)));
    let summary = grid_gen(&[urdf, "--floating-base"]);
    let text = String::from_utf8_lossy(&summary.stdout);
    assert!(text.contains("floating base: joints 0-5 are the free-flyer"), "{text}");
    // One joint as Pinocchio names it, with its six velocity coordinates.
    assert!(text.contains("  0-5  root_joint  (free-flyer, Pinocchio's JointModelFreeFlyer; velocity coordinates root_joint_vx,"), "{text}");
    assert!(!text.contains("    0  root_joint_vx"), "{text}");

    let dir = std::env::temp_dir().join(format!("grid-gen-cli-floating-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("states.json");
    let mut q = vec![0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0];
    q.extend([0.2; 12]);
    std::fs::write(
        &states,
        format!(r#"{{"states": [{{"q": {q:?}, "qd": {:?}, "qdd": {:?}}}]}}"#, [0.1; 18], [0.0; 18]),
    )
    .unwrap();
    let out = grid_gen(&["eval", urdf, "--floating-base", "--states", states.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(json(&out)["states"][0]["drnea_dq"].as_array().unwrap().len(), 18);
    // The fixed-base robot refuses the long q, and the floating one a short q.
    let out = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert!(
        stderr(&out).contains("`q` has 19 entries, the robot has 12 joints"),
        "{}",
        stderr(&out)
    );
    std::fs::write(
        &states,
        format!(r#"{{"states": [{{"q": {:?}, "qd": {:?}}}]}}"#, [0.0; 18], [0.0; 18]),
    )
    .unwrap();
    let out = grid_gen(&["eval", urdf, "--floating-base", "--states", states.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains(
            "`q` has 18 entries, expected 19: the floating base's position and quaternion"
        ),
        "{}",
        stderr(&out)
    );

    let out = grid_gen(&[urdf, "--floating-base", "-o", dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let code = std::fs::read_to_string(dir.join("hyq.rs")).unwrap();
    assert!(
        code.contains("pub const NQ: usize = 19;")
            && code.contains("q: &[T; NQ]")
            && code.contains("// Floating base (Pinocchio's free-flyer)")
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Spherical joints: `info --json` lists them with their quaternions' places
/// in q, `eval` takes the long q and names a non-unit quaternion's joint, and generation
/// writes `NQ`.
#[test]
fn spherical_joints_from_the_command_line() {
    let urdf = "tests/fixtures/ball_arm.urdf";
    let v = json(&grid_gen(&["info", urdf, "--json"]));
    assert_eq!((v["nv"].as_u64(), v["nq"].as_u64()), (Some(12), Some(15)));
    assert_eq!(v["spherical"][1]["joint"], "wrist");
    assert_eq!(v["spherical"][1]["q_index"].as_u64(), Some(5));
    assert_eq!(v["joint_names"][4], "wrist_wx");

    let dir = std::env::temp_dir().join(format!("grid-gen-cli-spherical-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("states.json");
    // shoulder's quaternion, elbow, wrist's, hand, slide, tip's: every rotation the identity.
    let mut q = vec![0.0, 0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 1.0, 0.2, 0.1, 0.0, 0.0, 0.0, 1.0];
    let write = |q: &[f64]| {
        std::fs::write(
            &states,
            format!(
                r#"{{"states": [{{"q": {q:?}, "qd": {:?}, "qdd": {:?}}}]}}"#,
                [0.1; 12], [0.0; 12]
            ),
        )
        .unwrap()
    };
    write(&q);
    let out = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert_eq!(json(&out)["states"][0]["drnea_dq"].as_array().unwrap().len(), 12);
    q[8] = 0.5;
    write(&q);
    let out = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("the quaternion of spherical joint `wrist`, `q[5..9]`, has norm 0.5"),
        "{}",
        stderr(&out)
    );
    write(&q[..12]);
    let out = grid_gen(&["eval", urdf, "--states", states.to_str().unwrap()]);
    assert!(
        stderr(&out).contains("`q` has 12 entries, expected 15: one per joint, with a quaternion"),
        "{}",
        stderr(&out)
    );

    let out = grid_gen(&[urdf, "-o", dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let code = std::fs::read_to_string(dir.join("ball_arm.rs")).unwrap();
    assert!(
        code.contains("pub const NQ: usize = 15;")
            && code.contains("q: &[T; NQ]")
            && code.contains("// Spherical joints (Pinocchio's JointModelSpherical)")
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--mimic coupled`: the Panda's second finger loses its coordinate in `info`,
/// `eval` and the generated module; an unknown mode is a usage error naming the modes.
#[test]
fn mimic_coupled_from_the_command_line() {
    let urdf = "robots/panda.urdf";
    let v = json(&grid_gen(&["--mimic", "coupled", "info", urdf, "--json"]));
    assert_eq!((v["nv"].as_u64(), v["mimic_coupled"].as_bool()), (Some(8), Some(true)));
    assert!(!v["joint_names"].as_array().unwrap().iter().any(|n| n == "panda_finger_joint2"));
    let independent = json(&grid_gen(&["info", urdf, "--json"]));
    assert_eq!(
        (independent["nv"].as_u64(), independent["mimic_coupled"].as_bool()),
        (Some(9), Some(false))
    );
    let summary = grid_gen(&[urdf, "--mimic", "coupled"]);
    assert!(String::from_utf8_lossy(&summary.stdout)
        .contains("coupled mimic joints (no coordinate of their own): panda_finger_joint2 = 1 * panda_finger_joint1 + 0"));

    let dir = std::env::temp_dir().join(format!("grid-gen-cli-mimic-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("states.json");
    std::fs::write(
        &states,
        format!(
            r#"{{"states": [{{"q": {:?}, "qd": {:?}, "qdd": {:?}, "tau": {:?}}}]}}"#,
            [0.1; 8], [0.2; 8], [0.3; 8], [0.4; 8]
        ),
    )
    .unwrap();
    let out = grid_gen(&["eval", urdf, "--mimic", "coupled", "--states", states.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let e = json(&out);
    assert_eq!(e["joint_names"].as_array().unwrap().len(), 8);
    assert_eq!(e["states"][0]["dfd_dq"].as_array().unwrap().len(), 8);
    let out = grid_gen(&[urdf, "--mimic", "coupled", "-o", dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let code = std::fs::read_to_string(dir.join("panda.rs")).unwrap();
    assert!(code.contains("pub const NV: usize = 8;") && code.contains("// Coupled mimic joints"));
    std::fs::remove_dir_all(&dir).unwrap();

    let bad = grid_gen(&["--mimic", "both", "info", urdf]);
    assert_eq!(bad.status.code(), Some(2));
    assert!(
        stderr(&bad).contains("invalid value 'both' for '--mimic <MODE>'")
            && stderr(&bad).contains("[possible values: independent, coupled]"),
        "{}",
        stderr(&bad)
    );
}

/// A legged-robot user's first call: `eval go2.urdf --floating-base --frames FL_foot,...` gives
/// each state the four feet's kinematics with the documented keys, equal to the library's reference
/// (which tests/frames.rs holds to Pinocchio); `info --json` lists every link as a frame with its
/// joint; a misspelt frame is an error that suggests the right name.
#[test]
fn eval_and_info_report_frames() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-frames-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("s.json");
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    std::fs::write(
        &states,
        format!(
            r#"{{"states": [{{"q": {q}, "qd": {qd}, "qdd": {qd}}}, {{"q": {q}, "qd": {qd}}}]}}"#
        ),
    )
    .unwrap();
    let feet = "FL_foot,FR_foot,RL_foot,RR_foot";
    let out = grid_gen(&[
        "eval",
        "tests/fixtures/go2.urdf",
        "--floating-base",
        "--frames",
        feet,
        "--states",
        states.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let v = json(&out);
    let text = std::fs::read_to_string(repo().join("tests/fixtures/go2.urdf")).unwrap();
    let scene = grid_gen::Scene { floating_base: true, ..Default::default() };
    let model =
        grid_gen::Model::from_urdf_str_in_scene("go2.urdf", &text, false, &scene, "").unwrap().0;
    let parse = |s: &str| -> Vec<f64> { serde_json::from_str(s).unwrap() };
    let (qv, qdv) = (parse(q), parse(qd));
    for name in feet.split(',') {
        let f = &v["states"][0]["frames"][name];
        let frame = &model.frames[model.frame(name).unwrap()];
        let (_, p) = grid_gen::reference::frame_placement(&model, &qv, frame);
        let nums = |x: &serde_json::Value| -> Vec<f64> {
            x.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
        };
        // serde_json reads floats back to within an ulp (no `float_roundtrip`).
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-15 * y.abs().max(1.0))
        };
        assert!(close(&nums(&f["translation"]), p.as_slice()), "{name}");
        let j = &f["jacobian"];
        for rf in ["local", "world", "local_world_aligned"] {
            assert_eq!(j[rf].as_array().unwrap().len(), 6);
            assert_eq!(j[rf][0].as_array().unwrap().len(), 18);
        }
        let lwa = grid_gen::reference::frame_classical_acceleration(
            &model,
            &qv,
            &qdv,
            &qdv,
            frame,
            grid_gen::model::ReferenceFrame::LocalWorldAligned,
        );
        assert!(close(&nums(&f["classical_acceleration"]["local_world_aligned"]), &lwa), "{name}");
        assert_eq!(f["velocity"]["local"].as_array().unwrap().len(), 6);
        // Without qdd, no acceleration.
        assert!(v["states"][1]["frames"][name].get("classical_acceleration").is_none());
    }
    let info = json(&grid_gen(&[
        "info",
        "tests/fixtures/go2.urdf",
        "--floating-base",
        "--json",
        "--frames",
        "FL_foot",
    ]));
    let frames = info["frames"].as_array().unwrap();
    let foot = frames.iter().find(|f| f["name"] == "FL_foot").unwrap();
    assert_eq!(foot["parent_joint"], "FL_calf_joint");
    assert_eq!(frames.iter().find(|f| f["name"] == "base").unwrap()["parent_joint"], "root_joint");
    assert_eq!(info["selected_frames"], serde_json::json!(["FL_foot"]));
    assert!(info["ops"].as_array().unwrap().iter().any(|k| k["kernel"] == "frame_jacobian"));
    let bad = grid_gen(&[
        "eval",
        "tests/fixtures/go2.urdf",
        "--floating-base",
        "--frames",
        "FL_fot",
        "--states",
        states.to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("--frames names `FL_fot`, which is not a link of this robot")
            && err.contains("closest frames: FL_foot"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--step` and `--dt`: `eval` adds each state's step (every scheme, the reference's values),
/// `info` says what the step kernels take, a τ on an unactuated joint is an error that
/// says why, and RK4 kernels generate.
#[test]
fn eval_and_info_report_the_step() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-step-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("s.json");
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    let tau = "[0,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]";
    std::fs::write(
        &states,
        format!(
            r#"{{"states": [{{"q": {q}, "qd": {qd}, "tau": {tau}}}, {{"q": {q}, "qd": {qd}}}]}}"#
        ),
    )
    .unwrap();
    let text = std::fs::read_to_string(repo().join("tests/fixtures/go2.urdf")).unwrap();
    let parse = |s: &str| -> Vec<f64> { serde_json::from_str(s).unwrap() };
    for scheme in grid_gen::model::Scheme::ALL {
        let out = grid_gen(&[
            "eval",
            "tests/fixtures/go2.urdf",
            "--floating-base",
            "--step",
            scheme.name(),
            "--dt",
            "0.02",
            "--states",
            states.to_str().unwrap(),
        ]);
        assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
        let v = json(&out);
        let step = &v["states"][0]["step"];
        assert_eq!(
            (step["A"].as_array().unwrap().len(), step["A"][0].as_array().unwrap().len()),
            (36, 36)
        );
        assert_eq!(
            (step["B"].as_array().unwrap().len(), step["B"][0].as_array().unwrap().len()),
            (36, 12),
            "one column per leg joint"
        );
        assert!(v["states"][1].get("step").is_none(), "no tau, no step");
        let scene = grid_gen::Scene { floating_base: true, ..Default::default() };
        let mut model =
            grid_gen::Model::from_urdf_str_in_scene("go2.urdf", &text, false, &scene, "")
                .unwrap()
                .0;
        model.specialisation.step = Some(grid_gen::model::StepSpec::folded(scheme, 0.02));
        let d = grid_gen::reference::step_derivatives(
            &model,
            &parse(q),
            &parse(qd),
            &parse(tau),
            grid_gen::model::DEFAULT_GRAVITY,
            grid_gen::model::Step { scheme, dt: 0.02 },
            &model.actuated(),
            &[],
        )
        .unwrap();
        let nums = |x: &serde_json::Value| -> Vec<f64> {
            x.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
        };
        let close = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-15 * y.abs().max(1.0))
        };
        assert!(close(&nums(&step["q_next"]), &d.q_next), "{}", scheme.name());
        assert!(
            close(&nums(&step["B"][30]), &d.b.row(30).iter().copied().collect::<Vec<_>>()),
            "{}",
            scheme.name()
        );
    }
    let bad = dir.join("bad.json");
    std::fs::write(&bad, format!(r#"{{"states": [{{"q": {q}, "qd": {qd}, "tau": [1,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]}}]}}"#)).unwrap();
    let out = grid_gen(&[
        "eval",
        "tests/fixtures/go2.urdf",
        "--floating-base",
        "--step",
        "explicit_euler",
        "--dt",
        "0.02",
        "--states",
        bad.to_str().unwrap(),
    ]);
    assert_ne!(out.status.code(), Some(0));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("not actuated"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = grid_gen(&[
        "robots/grid_iiwa.urdf",
        "--step",
        "rk4",
        "--dt",
        "0.01",
        "-o",
        dir.join("out").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let module = std::fs::read_to_string(dir.join("out/iiwa14.rs")).unwrap();
    assert!(
        module.contains("pub const STEP_SCHEME: &str = \"rk4\";")
            && module.contains("pub fn step_grad<")
    );
    let info = json(&grid_gen(&[
        "info",
        "robots/grid_iiwa.urdf",
        "--json",
        "--step",
        "semi_implicit_euler",
        "--dt",
        "0.01",
    ]));
    assert_eq!(info["step"], serde_json::json!({"scheme": "semi_implicit_euler", "dt": 0.01}));
    assert_eq!(info["actuated"].as_array().unwrap().len(), 7);
    std::fs::remove_dir_all(&dir).ok();
}

/// `--step` without `--dt`: the step kernels take dt at run time. `eval` reads each state's
/// `dt` and gives the folded step's values at it; a state without one, a bad one, or one
/// that contradicts a folded dt is an error that says what to give; `info` and the module
/// say dt is an input.
#[test]
fn a_step_without_dt_takes_it_at_run_time() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-dt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    let tau = "[0,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]";
    let write = |name: &str, states: &str| {
        let path = dir.join(name);
        std::fs::write(&path, format!(r#"{{"states": [{states}]}}"#)).unwrap();
        path
    };
    let eval = |states: &std::path::Path, dt: Option<&str>| {
        let mut args = vec!["eval", "tests/fixtures/go2.urdf", "--floating-base"];
        args.extend(["--step", "semi_implicit_euler"]);
        args.extend(dt.map(|d| ["--dt", d]).into_iter().flatten());
        args.extend(["--states", states.to_str().unwrap()]);
        grid_gen(&args)
    };
    let two = write(
        "two.json",
        &format!(
            r#"{{"q": {q}, "qd": {qd}, "tau": {tau}, "dt": 0.02}}, {{"q": {q}, "qd": {qd}, "tau": {tau}, "dt": 0.005}}"#
        ),
    );
    let runtime = eval(&two, None);
    assert_eq!(runtime.status.code(), Some(0), "{}", String::from_utf8_lossy(&runtime.stderr));
    let runtime = json(&runtime);
    for (k, dt) in [(0, "0.02"), (1, "0.005")] {
        let one = write(
            "one.json",
            &format!(
                r#"{{"q": {q}, "qd": {qd}, "tau": {tau}}}, {{"q": {q}, "qd": {qd}, "tau": {tau}}}"#
            ),
        );
        let folded = eval(&one, Some(dt));
        assert_eq!(folded.status.code(), Some(0), "{}", String::from_utf8_lossy(&folded.stderr));
        // The same reference at the same dt: the same numbers.
        assert_eq!(runtime["states"][k]["step"], json(&folded)["states"][k]["step"], "dt {dt}");
    }
    assert_ne!(
        runtime["states"][0]["step"]["q_next"], runtime["states"][1]["step"]["q_next"],
        "each state steps by its own dt"
    );
    let errors = [
        (
            format!(r#"{{"q": {q}, "qd": {qd}, "tau": {tau}}}"#),
            None,
            "give `dt` (seconds) beside `tau`",
        ),
        (
            format!(r#"{{"q": {q}, "qd": {qd}, "tau": {tau}, "dt": -1}}"#),
            None,
            "not a finite, positive",
        ),
        (
            format!(r#"{{"q": {q}, "qd": {qd}, "tau": {tau}, "dt": 0.5}}"#),
            Some("0.02"),
            "is folded into the kernels",
        ),
    ];
    for (state, dt, says) in errors {
        let out = eval(&write("bad.json", &state), dt);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("state 0") && err.contains(says), "{err}");
        assert!(out.stdout.is_empty(), "nothing on stdout");
    }
    let info = json(&grid_gen(&["info", "robots/grid_iiwa.urdf", "--json", "--step", "rk4"]));
    assert_eq!(info["step"], serde_json::json!({"scheme": "rk4", "dt": null}));
    let text = grid_gen(&["info", "robots/grid_iiwa.urdf", "--step", "rk4"]);
    assert!(String::from_utf8_lossy(&text.stdout).contains("dt given at run time"));
    let out = dir.join("out");
    let gen = grid_gen(&["robots/grid_iiwa.urdf", "--step", "rk4", "-o", out.to_str().unwrap()]);
    assert_eq!(gen.status.code(), Some(0), "{}", String::from_utf8_lossy(&gen.stderr));
    let module = std::fs::read_to_string(out.join("iiwa14.rs")).unwrap();
    assert!(module.contains("dt: &[T; 1]") && !module.contains("pub const DT"));
    std::fs::remove_dir_all(&dir).ok();
}

/// `--contact-mask`: `info` says the contact kernels take `active` and the module holds
/// NCONTACTS; without contacts it is an error that says what to declare.
#[test]
fn contact_mask_from_the_command_line() {
    let feet = "lf_lowerleg:point,rh_lowerleg:point";
    let base = ["robots/grid_hyq.urdf", "--floating-base", "--contact", feet, "--contact-mask"];
    let info = grid_gen(&[&["info"], &base[..]].concat());
    let text = String::from_utf8_lossy(&info.stdout);
    assert_eq!(info.status.code(), Some(0), "{}", String::from_utf8_lossy(&info.stderr));
    assert!(text.contains("take `active`, one 0 or 1 per contact"), "{text}");
    let summary = json(&grid_gen(&[&["info", "--json"], &base[..]].concat()));
    assert_eq!(summary["contact_mask"], serde_json::json!(true));
    let bad = grid_gen(&["info", "robots/grid_hyq.urdf", "--floating-base", "--contact-mask"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--contact-mask without contacts") && err.contains("--contact FRAME:point"),
        "{err}"
    );
    // eval: a state's `active` turns a contact off; its values are those of the model
    // holding just the other contact, its lambda rows 0.
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-mask-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    let tau = "[0,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]";
    let write = |name: &str, extra: &str| {
        let path = dir.join(name);
        let state = format!(r#"{{"q": {q}, "qd": {qd}, "tau": {tau}{extra}}}"#);
        std::fs::write(&path, format!(r#"{{"states": [{state}]}}"#)).unwrap();
        path
    };
    let off = write("off.json", r#", "active": {"rh_lowerleg": false}"#);
    let masked = grid_gen(&[&["eval"], &base[..], &["--states", off.to_str().unwrap()]].concat());
    assert_eq!(masked.status.code(), Some(0), "{}", String::from_utf8_lossy(&masked.stderr));
    let plain = write("plain.json", "");
    let one = grid_gen(&[
        "eval",
        "robots/grid_hyq.urdf",
        "--floating-base",
        "--contact",
        "lf_lowerleg:point",
        "--states",
        plain.to_str().unwrap(),
    ]);
    assert_eq!(one.status.code(), Some(0), "{}", String::from_utf8_lossy(&one.stderr));
    let (masked, one) = (json(&masked), json(&one));
    let (m, o) = (&masked["states"][0]["contact_fd"], &one["states"][0]["contact_fd"]);
    for key in ["qdd", "dqdd_dq", "dqdd_dtau"] {
        assert_eq!(m[key], o[key], "{key}: the model holding just lf_lowerleg");
    }
    assert_eq!(m["lambda"]["lf_lowerleg"], o["lambda"]["lf_lowerleg"]);
    assert_eq!(m["lambda"]["rh_lowerleg"], serde_json::json!([0.0, 0.0, 0.0]));
    assert_eq!(m["dlambda_dq"]["rh_lowerleg"][2], serde_json::json!(vec![0.0; 18]));
    let unknown = write("unknown.json", r#", "active": {"rf_lowerleg": false}"#);
    let errors = [
        (unknown, &base[..], "`active` names `rf_lowerleg`"),
        (off.clone(), &base[..4], "does not mask its contacts"),
    ];
    for (states, args, says) in errors {
        let out = grid_gen(&[&["eval"], args, &["--states", states.to_str().unwrap()]].concat());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(says), "{err}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// External and contact forces from the command line: `eval` with `fext` and
/// `contacts` gives the reference's values under them, with the derivatives keyed by joint
/// and frame; bad entries are errors naming the entry (nothing on stdout); `info` and the
/// generated module name the forces; `--contact` with an unknown frame is an error.
#[test]
fn eval_and_info_report_forces() {
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-forces-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let states = dir.join("s.json");
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    let u = "[0,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]";
    let forces = r#""fext": {"root_joint": [1, 2, 3, 0.1, 0.2, 0.3]}, "contacts": {"lf_lowerleg": [0, 0, 80], "rh_lowerleg": [5, -3, 70]}"#;
    std::fs::write(
        &states,
        format!(r#"{{"states": [{{"q": {q}, "qd": {qd}, "qdd": {u}, "tau": {u}, {forces}}}]}}"#),
    )
    .unwrap();
    let contacts = "lf_lowerleg:point,rf_lowerleg:point,lh_lowerleg:point,rh_lowerleg:point";
    let base =
        ["eval", "robots/grid_hyq.urdf", "--floating-base", "--contact", contacts, "--states"];
    let run = |file: &std::path::Path| grid_gen(&[&base[..], &[file.to_str().unwrap()]].concat());
    let out = run(&states);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let v = json(&out);
    let s = &v["states"][0];
    assert_eq!(s["drnea_dfext"]["root_joint"].as_array().unwrap().len(), 18, "nv rows");
    assert_eq!(s["drnea_dfext"]["root_joint"][0].as_array().unwrap().len(), 6);
    assert_eq!(
        s["dfd_dlambda"]["rh_lowerleg"][0].as_array().unwrap().len(),
        3,
        "a point contact's three columns"
    );
    assert_eq!(s["drnea_dlambda"].as_object().unwrap().len(), 4, "every declared contact");
    // The same numbers as the reference under the same forces.
    let text = std::fs::read_to_string(repo().join("robots/grid_hyq.urdf")).unwrap();
    let scene = grid_gen::Scene::parse(
        "s.toml",
        "floating_base = true\n[external_forces]\njoints = [\"root_joint\"]\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"rf_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"lh_lowerleg\"\ntype = \"point\"\n[[contact]]\nframe = \"rh_lowerleg\"\ntype = \"point\"\n",
    )
    .unwrap();
    let model =
        grid_gen::Model::from_urdf_str_in_scene("grid_hyq.urdf", &text, false, &scene, "s.toml")
            .unwrap()
            .0;
    let parse = |s: &str| -> Vec<f64> { serde_json::from_str(s).unwrap() };
    let lambda = [0.0, 0.0, 80.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0, -3.0, 70.0];
    let ext =
        grid_gen::reference::External { fext: &[1.0, 2.0, 3.0, 0.1, 0.2, 0.3], lambda: &lambda };
    let want = grid_gen::reference::rnea_with(
        &model,
        &parse(q),
        &parse(qd),
        &parse(u),
        grid_gen::model::DEFAULT_GRAVITY,
        ext,
    );
    let got: Vec<f64> = s["rnea"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    assert!(
        got.iter().zip(&want).all(|(a, b)| (a - b).abs() <= 1e-12 * b.abs().max(1.0)),
        "{got:?} against {want:?}"
    );
    // Rigid-contact dynamics: the reference's, under the state's fext, its λ and q̈
    // consistent with fd under those forces.
    let c = &s["contact_fd"];
    let floats = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
    };
    let fext = [1.0, 2.0, 3.0, 0.1, 0.2, 0.3];
    let (sol, _) = grid_gen::reference::contact_fd_derivatives(
        &model,
        &parse(q),
        &parse(qd),
        &parse(u),
        grid_gen::model::DEFAULT_GRAVITY,
        &fext,
    )
    .unwrap();
    // serde_json's default float parsing may round the last digit differently.
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len()
            && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-14 * y.abs().max(1.0))
    };
    assert!(close(&floats(&c["qdd"]), &sol.qdd), "contact_fd.qdd is the reference's");
    let lambda: Vec<f64> = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
        .iter()
        .flat_map(|f| floats(&c["lambda"][f]))
        .collect();
    assert!(close(&lambda, &sol.lambda), "contact_fd.lambda is the reference's");
    let ext = grid_gen::reference::External { fext: &fext, lambda: &lambda };
    let fd = grid_gen::reference::aba_with(
        &model,
        &parse(q),
        &parse(qd),
        &parse(u),
        grid_gen::model::DEFAULT_GRAVITY,
        ext,
    );
    assert!(
        fd.iter().zip(&sol.qdd).all(|(a, b)| (a - b).abs() <= 1e-9 * b.abs().max(1.0)),
        "fd under the solved forces is contact_fd's qdd"
    );
    assert_eq!(
        c["dlambda_dq"]["lf_lowerleg"].as_array().unwrap().len(),
        3,
        "a point contact's three rows"
    );
    assert_eq!(c["dlambda_dtau"]["lf_lowerleg"][0].as_array().unwrap().len(), 18, "nv columns");
    assert_eq!(c["dqdd_dtau"].as_array().unwrap().len(), 18);
    // With a step: the state's fext held over it, the contacts rigid (the state's λ does
    // not enter), as the reference's step.
    let out = grid_gen(
        &[&base[..5], &["--step", "rk4", "--dt", "0.01", "--states", states.to_str().unwrap()]]
            .concat(),
    );
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let step = &json(&out)["states"][0]["step"];
    let mut stepped = model.clone();
    let rk4 = grid_gen::model::Step { scheme: grid_gen::model::Scheme::Rk4, dt: 0.01 };
    stepped.specialisation.step = Some(grid_gen::model::StepSpec::folded(rk4.scheme, rk4.dt));
    let d = grid_gen::reference::step_derivatives(
        &stepped,
        &parse(q),
        &parse(qd),
        &parse(u),
        grid_gen::model::DEFAULT_GRAVITY,
        rk4,
        &stepped.actuated(),
        &fext,
    )
    .unwrap();
    assert!(
        close(&floats(&step["qd_next"]), &d.qd_next),
        "the step's qd_next is the reference's contact step"
    );
    assert!(
        close(&floats(&step["B"][20]), &d.b.row(20).iter().copied().collect::<Vec<_>>()),
        "and its B"
    );
    let bad_cases = [
        (r#""fext": {"lf_knee": [1, 2, 3, 0, 0, 0]}"#, "`fext` names `lf_knee`"),
        (r#""fext": {"root_joint": [1, 2, 3]}"#, "`fext.root_joint` has 3 values, expected 6"),
        (r#""fext": {"root_joint": [1, 2, NaN, 0, 0, 0]}"#, "`fext.root_joint[2]` is not finite"),
        (r#""contacts": {"lf_hipassembly": [0, 0, 1]}"#, "not a contact the scene declares"),
        (r#""contacts": {"lf_lowerleg": [0, 0, 1, 0, 0, 0]}"#, "has 6 values, expected 3"),
    ];
    for (entry, says) in bad_cases {
        let bad = dir.join("bad.json");
        std::fs::write(
            &bad,
            format!(r#"{{"states": [{{"q": {q}, "qd": {qd}, "qdd": {u}, {entry}}}]}}"#),
        )
        .unwrap();
        let out = run(&bad);
        assert_ne!(out.status.code(), Some(0), "{entry}");
        assert!(out.stdout.is_empty(), "{entry}: nothing written");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(says),
            "{entry}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let out = grid_gen(&["accuracy", "robots/grid_iiwa.urdf", "--fext", "iiwa_joint_7"]);
    assert_ne!(out.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&out.stderr)
        .contains("does not measure kernels that take external or contact forces yet"));
    let out = grid_gen(&[
        "info",
        "robots/grid_hyq.urdf",
        "--floating-base",
        "--contact",
        "lf_foot:point",
    ]);
    assert_ne!(out.status.code(), Some(0));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("closest frames"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info = json(&grid_gen(&[
        "info",
        "robots/grid_hyq.urdf",
        "--json",
        "--floating-base",
        "--fext",
        "*",
        "--contact",
        "lf_lowerleg:wrench",
    ]));
    assert_eq!(info["fext"].as_array().unwrap().len(), 13);
    assert_eq!(
        info["contacts"],
        serde_json::json!([{"frame": "lf_lowerleg", "type": "wrench", "entries": 6}])
    );
    let out = grid_gen(&[
        "robots/grid_iiwa.urdf",
        "--fext",
        "iiwa_joint_7",
        "-o",
        dir.join("out").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let module = std::fs::read_to_string(dir.join("out/iiwa14.rs")).unwrap();
    assert!(
        module.contains("pub const FEXT_JOINTS: [&str; NFEXT] = [\"iiwa_joint_7\"];")
            && module.contains("dc_dfext")
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The book's `info --json` example (`docs/reference/cli.md`) names every top-level field
/// the command prints (a new user once missed `spherical` there).
#[test]
fn the_books_info_json_example_names_every_field() {
    let out = grid_gen(&["info", "--json", "robots/grid_hyq.urdf"]);
    let page = std::fs::read_to_string(repo().join("docs/reference/cli.md")).unwrap();
    let example = page.split("```json\n").nth(1).unwrap().split("```").next().unwrap();
    let fields = json(&out);
    let missing: Vec<&String> = fields
        .as_object()
        .unwrap()
        .keys()
        .filter(|k| !example.contains(&format!("\"{k}\":")))
        .collect();
    assert!(missing.is_empty(), "docs/reference/cli.md's info --json example lacks {missing:?}");
}

/// `--round-angles`: HyQ's twelve truncated right angles are counted in the summary and in
/// `info --json`, the gradients lose operations, and a tolerance that would change the
/// robot is refused with exit code 1 (an input error) and the allowed range.
#[test]
fn round_angles_from_the_command_line() {
    let urdf = "robots/grid_hyq.urdf";
    let text =
        String::from_utf8_lossy(&grid_gen(&["--round-angles", "1e-11", urdf]).stdout).into_owned();
    assert!(
        text.contains("round_angles = 1e-11 read 12 <origin rpy> angles as multiples of pi/2 (largest change 4.90e-12 rad): the results move"),
        "{text}"
    );
    let ops = |v: &serde_json::Value| {
        let k = v["ops"].as_array().unwrap().iter().find(|k| k["kernel"] == "rnea_grad").unwrap();
        ["add", "mul", "div", "neg"].iter().map(|f| k["after"][f].as_u64().unwrap()).sum::<u64>()
    };
    let rounded = json(&grid_gen(&["--round-angles", "1e-11", "info", urdf, "--json"]));
    let literal = json(&grid_gen(&["info", urdf, "--json"]));
    assert_eq!(rounded["rounded_angles"]["count"], 12);
    assert!(literal.get("rounded_angles").is_none());
    // 3,212 against 4,264 (Speed, Right angles written short): under 80 %.
    assert!(ops(&rounded) * 10 < ops(&literal) * 8, "{} vs {}", ops(&rounded), ops(&literal));
    // The generated files say that their robot is not the file as written.
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-round-{}", std::process::id()));
    let out = grid_gen(&[
        "--round-angles",
        "1e-11",
        "generate",
        urdf,
        "-o",
        dir.to_str().unwrap(),
        "--emit",
        "rust,wgsl",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    for file in ["hyq.rs", "hyq.wgsl"] {
        let code = std::fs::read_to_string(dir.join(file)).unwrap();
        assert!(
            code.contains(
                "// Right angles: the scene's round_angles = 1e-11 read 12 <origin rpy> angles"
            ),
            "{file}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
    let bad = grid_gen(&["--round-angles", "0.1", "info", urdf]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        stderr(&bad)
            .contains("round_angles = 0.1 rad: give a tolerance above 0 and at most 1e-6 rad"),
        "{}",
        stderr(&bad)
    );
}

/// Baumgarte-stabilised contacts from the command line: `eval --baumgarte` takes a state's
/// `baumgarte` (kp, kd, ref per contact frame) and gives the reference's stabilised contact
/// dynamics and step (λ included), a wrench foot's reference a placement; `info` names the
/// inputs; bad correctors are errors naming the state and the contact.
#[test]
fn baumgarte_from_the_command_line() {
    let base = [
        "robots/grid_hyq.urdf",
        "--floating-base",
        "--contact",
        "lf_lowerleg:wrench,rh_lowerleg:point",
        "--baumgarte",
    ];
    let summary = json(&grid_gen(&[&["info", "--json"], &base[..]].concat()));
    assert_eq!(summary["baumgarte"], serde_json::json!(true));
    // Each counted kernel's generated Rust, in ops' order; a gradient outweighs its value.
    let sizes = summary["rust_size"].as_array().unwrap();
    let ops = summary["ops"].as_array().unwrap();
    assert_eq!(sizes.len(), ops.len());
    let bytes = |k: &str| {
        let row = sizes.iter().find(|r| r["kernel"] == k).unwrap_or_else(|| panic!("{k}"));
        assert!(row["lines"].as_u64().unwrap() > 0, "{k}");
        row["bytes"].as_u64().unwrap()
    };
    assert!(bytes("contact_fd_grad") > bytes("contact_fd") && bytes("rnea") > 0);
    // Lanes for the contact gradient (well under 150,000 operations), not for dIntegrate
    // (672 operations for 648 entries: lanes would cost more than they save).
    let lanes = |k: &str| sizes.iter().find(|r| r["kernel"] == k).unwrap()["batch_lanes"] == true;
    assert!(lanes("contact_fd_grad") && !lanes("dintegrate"));
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-baumgarte-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let q = "[0.1,0.2,0.3, 0,0,0.3826834323650898,0.9238795325112867, 0.1,0.7,-1.4, -0.1,0.7,-1.4, 0.1,0.9,-1.5, -0.1,0.9,-1.5]";
    let qd = "[0.1,0,0,0,0,0.2, 1,0,0,0,0,0,0,0,0,0,0,0.5]";
    let tau = "[0,0,0,0,0,0, 1,2,3,4,5,6,7,8,9,10,11,12]";
    let write = |name: &str, extra: &str| {
        let path = dir.join(name);
        let state = format!(r#"{{"q": {q}, "qd": {qd}, "tau": {tau}{extra}}}"#);
        std::fs::write(&path, format!(r#"{{"states": [{state}]}}"#)).unwrap();
        path
    };
    let corrected = write(
        "gains.json",
        r#", "baumgarte": {"lf_lowerleg": {"kp": 100, "kd": 20, "ref": [0.4, 0.3, -0.3, 0, 0, 0.3826834323650898, 0.9238795325112867]}, "rh_lowerleg": {"kp": 50, "kd": 5, "ref": [-0.4, -0.3, -0.35]}}"#,
    );
    let args = |extra: &[&str], states: &std::path::Path| -> Vec<String> {
        [&["eval"], &base[..], extra, &["--states", states.to_str().unwrap()]]
            .concat()
            .iter()
            .map(|s| s.to_string())
            .collect()
    };
    let run = |a: Vec<String>| grid_gen(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let out = run(args(&["--step", "semi_implicit_euler", "--dt", "0.01"], &corrected));
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let s = &json(&out)["states"][0];
    let text = std::fs::read_to_string(repo().join("robots/grid_hyq.urdf")).unwrap();
    let scene = grid_gen::Scene::parse(
        "s.toml",
        "floating_base = true\nbaumgarte = true\n[[contact]]\nframe = \"lf_lowerleg\"\ntype = \"wrench\"\n[[contact]]\nframe = \"rh_lowerleg\"\ntype = \"point\"\n",
    )
    .unwrap();
    let model =
        grid_gen::Model::from_urdf_str_in_scene("grid_hyq.urdf", &text, false, &scene, "s.toml")
            .unwrap()
            .0;
    let parse = |s: &str| -> Vec<f64> { serde_json::from_str(s).unwrap() };
    let gains = [100.0, 20.0, 50.0, 5.0];
    let refs =
        [0.4, 0.3, -0.3, 0.0, 0.0, 0.3826834323650898, 0.9238795325112867, -0.4, -0.3, -0.35];
    let corr = grid_gen::reference::Baumgarte { gains: &gains, refs: &refs };
    let g = grid_gen::model::DEFAULT_GRAVITY;
    let (x, v, u) = (parse(q), parse(qd), parse(tau));
    let (sol, _) =
        grid_gen::reference::contact_fd_derivatives_with(&model, &x, &v, &u, g, &[], corr).unwrap();
    let (rigid, _) =
        grid_gen::reference::contact_fd_derivatives(&model, &x, &v, &u, g, &[]).unwrap();
    let floats = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect()
    };
    // serde_json's float parsing may round the last digit of an input differently, which
    // moves the outputs by rounding relative to their largest entry (measured 2.6e-16 of it).
    let close = |a: &[f64], b: &[f64]| {
        let scale = b.iter().fold(1.0f64, |m, y| m.max(y.abs()));
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-14 * scale)
    };
    let got = floats(&s["contact_fd"]["qdd"]);
    assert!(close(&got, &sol.qdd), "contact_fd.qdd is the reference's with the corrector");
    assert!(!close(&got, &rigid.qdd), "and the corrector changes it");
    let lambda: Vec<f64> = ["lf_lowerleg", "rh_lowerleg"]
        .iter()
        .flat_map(|f| floats(&s["step"]["lambda"][f]))
        .collect();
    assert!(close(&lambda, &sol.lambda), "the step's lambda is contact_fd's, stabilised");
    let errors = [
        (
            write(
                "none.json",
                r#", "baumgarte": {"rf_lowerleg": {"kp": 1, "kd": 1, "ref": [0, 0, 0]}}"#,
            ),
            "`baumgarte` names `rf_lowerleg`",
        ),
        (
            write("noref.json", r#", "baumgarte": {"lf_lowerleg": {"kp": 1, "kd": 1}}"#),
            "kp pulls the contact towards `ref`",
        ),
        (
            write(
                "short.json",
                r#", "baumgarte": {"lf_lowerleg": {"kp": 1, "kd": 1, "ref": [0, 0, 0]}}"#,
            ),
            "`ref` of a wrench contact is a world placement, seven finite numbers",
        ),
        (
            write(
                "zero.json",
                r#", "baumgarte": {"lf_lowerleg": {"kp": 1, "kd": 1, "ref": [0, 0, 0, 0, 0, 0, 0]}}"#,
            ),
            "`ref`'s quaternion [qx, qy, qz, qw] must have norm 1",
        ),
        (
            write(
                "neg.json",
                r#", "baumgarte": {"lf_lowerleg": {"kp": -1, "kd": 1, "ref": [0, 0, 0]}}"#,
            ),
            "kp and kd are finite and >= 0",
        ),
    ];
    for (states, says) in errors {
        let out = run(args(&[], &states));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("state 0") && err.contains(says), "{err}");
    }
    let plain = grid_gen(&[
        "eval",
        "robots/grid_hyq.urdf",
        "--floating-base",
        "--contact",
        "lf_lowerleg:wrench,rh_lowerleg:point",
        "--states",
        corrected.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&plain.stderr);
    assert!(err.contains("does not stabilise its contacts"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A flag given beside a scene file is named as the flag when it is wrong, not blamed on the
/// file; the file's own values are named by the file and key.
#[test]
fn errors_name_the_flag_or_the_file_that_set_a_value() {
    let hyq = "robots/grid_hyq.urdf";
    let scene = "examples/scenes/hyq_step_floating.toml";
    for (args, said) in [
        (vec!["--scene", scene, "--dt=-1"], "--dt: dt = -1 is not a finite, positive number"),
        (vec!["--scene", scene, "--contact", "nothere:point"], "--contact names `nothere`"),
        (vec!["--scene", scene, "--actuated", "nothere"], "--actuated names `nothere`"),
        (vec!["--scene", scene, "--fext", "nothere"], "--fext names `nothere`"),
        (vec!["--scene", scene, "--frames", "nothere"], "--frames names `nothere`"),
        (vec!["--floating-base", "--step", "rk4", "--dt=0"], "--dt: dt = 0 is not"),
        (vec!["--contact-mask"], "--contact-mask without contacts"),
    ] {
        let out = grid_gen(&[&["info", hyq][..], &args].concat());
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let err = stderr(&out);
        assert!(err.contains(said) && !err.contains("scene `"), "{args:?}: {err}");
    }
    // The file's own bad value is the file's, at the line that sets it.
    let dir = std::env::temp_dir().join(format!("grid-gen-cli-whence-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad_dt.toml");
    std::fs::write(&bad, "floating_base = true\n[step]\ndt = -0.5\n").unwrap();
    let out = grid_gen(&["info", hyq, "--scene", bad.to_str().unwrap()]);
    let err = stderr(&out);
    assert!(err.contains("bad_dt.toml` line 3: [step] dt: dt = -0.5 is not"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
