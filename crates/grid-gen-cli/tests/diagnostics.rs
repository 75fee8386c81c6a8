//! Data-driven diagnostic tests: each `tests/diagnostics/<case>.urdf` is run through
//! `grid-gen info` and its exit code and rendered stderr are compared with
//! `<case>.stderr`. A case whose name ends in `_strict` runs with `--strict`, one ending in
//! `_coupled` with `--mimic coupled`.
//!
//! After an intended change of wording, refresh the expectations with
//! `GRID_GEN_BLESS=1 cargo test -p grid-gen-cli --test diagnostics` and review the diff.

use std::path::PathBuf;
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn rendered_diagnostics_match_expectations() {
    let dir = repo().join("tests/diagnostics");
    let bless = std::env::var_os("GRID_GEN_BLESS").is_some();
    let mut cases: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "urdf"))
        .collect();
    cases.sort();
    assert!(cases.len() >= 20, "expected the full set of diagnostic cases");
    let mut mismatches = Vec::new();
    for case in cases {
        let stem = case.file_stem().unwrap().to_string_lossy().into_owned();
        let rel = format!("tests/diagnostics/{stem}.urdf");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_grid-gen"));
        cmd.current_dir(repo()).arg("info").arg(&rel).env("NO_COLOR", "1");
        if stem.ends_with("_strict") {
            cmd.arg("--strict");
        }
        if stem.ends_with("_coupled") {
            cmd.args(["--mimic", "coupled"]);
        }
        let out = cmd.output().unwrap();
        let got = format!(
            "exit: {}\n{}",
            out.status.code().unwrap_or(-1),
            String::from_utf8_lossy(&out.stderr)
        );
        let expected_path = dir.join(format!("{stem}.stderr"));
        if bless {
            std::fs::write(&expected_path, &got).unwrap();
            continue;
        }
        let want = std::fs::read_to_string(&expected_path).unwrap_or_default();
        if got != want {
            mismatches.push(format!("--- {stem}: expected\n{want}\n--- got\n{got}"));
        }
    }
    assert!(
        mismatches.is_empty(),
        "{} case(s) differ (GRID_GEN_BLESS=1 to refresh):\n{}",
        mismatches.len(),
        mismatches.join("\n")
    );
}
