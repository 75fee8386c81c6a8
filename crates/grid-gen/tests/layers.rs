//! The library's layering invariants (`docs/dev/architecture.md`), checked on the source: each
//! layer names only the modules below it, and the library prints in one place. A `use` or a
//! path that breaks one fails here with the file and the module it reached for.

use std::path::{Path, PathBuf};

/// The library's top-level modules.
const MODULES: [&str; 20] = [
    "accuracy",
    "back",
    "builder",
    "config",
    "datapath",
    "diagnostic",
    "eval",
    "generate",
    "info",
    "ir",
    "load",
    "model",
    "numerics",
    "reference",
    "scene",
    "spatial",
    "timing",
    "tools",
    "urdf",
    "lib",
];

/// (module, what it may name besides itself): the URDF front end and the model know nothing
/// of the IR, the reference knows only the model, the IR knows only the model, the numerics
/// and the datapath model read the IR from beside it, and the backends read only the IR and
/// those analyses of it.
const LAYERS: [(&str, &[&str]); 8] = [
    ("diagnostic", &[]),
    ("spatial", &[]),
    ("urdf", &["diagnostic"]),
    ("model", &["diagnostic", "spatial", "urdf"]),
    ("reference", &["model", "spatial"]),
    ("ir", &["model"]),
    ("numerics", &["ir"]),
    ("datapath", &["ir", "model"]),
];

/// Backends read only `ir` and its analyses (and share nothing else of the library).
const BACKENDS: (&str, &[&str]) = ("back", &["ir", "numerics", "datapath"]);

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The `.rs` files of module `name` (its file, or every file under its folder).
fn files_of(name: &str) -> Vec<PathBuf> {
    let file = src().join(format!("{name}.rs"));
    let mut out = Vec::new();
    if file.exists() {
        out.push(file);
    }
    let mut dirs = vec![src().join(name)];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    assert!(!out.is_empty(), "no source for module `{name}`");
    out.sort();
    out
}

/// The top-level modules a file names as `crate::m`.
fn crate_paths(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (i, _) in text.match_indices("crate::") {
        let before = text[..i].chars().next_back();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let name: String =
            text[i + 7..].chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        if MODULES.contains(&name.as_str()) {
            out.push(name);
        }
    }
    out
}

fn check(module: &str, allowed: &[&str], broken: &mut Vec<String>) {
    for file in files_of(module) {
        let text = std::fs::read_to_string(&file).unwrap();
        for m in crate_paths(&text) {
            if m != module && !allowed.contains(&m.as_str()) {
                broken.push(format!(
                    "{}: `{module}` names `crate::{m}` (it may name only {allowed:?})",
                    file.strip_prefix(src()).unwrap().display()
                ));
            }
        }
    }
}

#[test]
fn each_layer_names_only_the_layers_below_it() {
    let mut broken = Vec::new();
    for (module, allowed) in LAYERS.iter().chain([&BACKENDS]) {
        check(module, allowed, &mut broken);
    }
    assert!(broken.is_empty(), "layering broken:\n{}", broken.join("\n"));
}

/// The library prints only cargo's build-script lines, from one place in `builder`: every
/// other result is returned (warnings as values, errors as types).
#[test]
fn the_library_prints_in_one_place() {
    let mut printing = Vec::new();
    for module in MODULES {
        for file in files_of(module) {
            let text = std::fs::read_to_string(&file).unwrap();
            for (n, line) in text.lines().enumerate() {
                let t = line.trim_start();
                let prints = ["println!(", "eprintln!(", "print!(", "eprint!(", "dbg!("]
                    .iter()
                    .any(|p| t.starts_with(p));
                if prints {
                    printing.push(format!(
                        "{}:{}",
                        file.strip_prefix(src()).unwrap().display(),
                        n + 1
                    ));
                }
            }
        }
    }
    assert_eq!(printing.len(), 1, "the library prints at {printing:?}");
    assert!(printing[0].starts_with("builder.rs:"), "{printing:?}");
}

/// One way in: the CLI, `Builder` and the Python package describe a job as a `Config`, and
/// only `config.rs` reads a scene, merges the caller's settings into it and builds the model
/// from both, so that a setting added there reaches every caller alike.
#[test]
fn every_way_in_loads_through_config() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let callers =
        ["crates/grid-gen/src/builder.rs", "crates/grid-gen-cli/src/main.rs", "python/src/lib.rs"];
    let merging = ["Scene::parse", "from_urdf_str", ".apply(", "Scene::default()"];
    let mut found = Vec::new();
    for caller in callers {
        let text = std::fs::read_to_string(root.join(caller)).unwrap();
        // Unit tests may build models directly.
        let text = text.split("#[cfg(test)]").next().unwrap();
        for m in merging.iter().filter(|m| text.contains(*m)) {
            found.push(format!("{caller} calls `{m}`"));
        }
    }
    for module in MODULES.iter().filter(|m| !["config", "scene", "load"].contains(m)) {
        for file in files_of(module) {
            let text = std::fs::read_to_string(&file).unwrap();
            if text.contains("from_urdf_str_in_scene(") || text.contains(".apply(&") {
                found.push(format!("{} loads a robot in a scene", file.display()));
            }
        }
    }
    assert!(found.is_empty(), "loading outside `Config::load`:\n{}", found.join("\n"));
}

/// Programs (rustc, iverilog, vvp) are started only from `tools`, outside the core: the
/// front end, the IR and the backends return text (and, by the layers above, never name
/// `tools`).
#[test]
fn only_tools_starts_programs() {
    let mut found = Vec::new();
    for module in MODULES.iter().filter(|m| **m != "tools") {
        for file in files_of(module) {
            let text = std::fs::read_to_string(&file).unwrap();
            if text.contains("Command::new") || text.contains("process::Command") {
                found.push(format!(
                    "{} starts a program",
                    file.strip_prefix(src()).unwrap().display()
                ));
            }
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// The check itself: it sees an import that breaks a layer.
#[test]
fn the_check_sees_a_broken_layer() {
    assert_eq!(crate_paths("use crate::eval::X;\nlet y = crate::ir::lower;"), ["eval", "ir"]);
    assert!(crate_paths("grid_gen_crate::ir // mycrate::eval").is_empty());
}
