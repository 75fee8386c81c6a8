//! The checked-in kernels under `generated/<robot>/` are exactly what grid-gen generates
//! now, for every robot in `robots/`, and generating twice gives the same bytes.
//!
//! Refresh after an intended change: `GRID_GEN_BLESS=1 cargo test -p grid-gen --test generated_fresh`
//! (or `grid-gen robots/<robot>.urdf -o generated/<robot>` per robot), then review the diff.

mod common;

use common::*;
use grid_gen::generate::{generate, write_files, FileStatus, Options};

#[test]
fn checked_in_kernels_are_fresh() {
    let bless = std::env::var_os("GRID_GEN_BLESS").is_some();
    let mut stale = Vec::new();
    let mut dirs: Vec<String> = std::fs::read_dir(repo().join("generated"))
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    dirs.sort();
    assert_eq!(dirs, robots(), "generated/ holds one folder per robot in robots/");
    for robot in robots() {
        let model = load(&robot);
        let files = generate(&model, &Options::default()).unwrap();
        let again = generate(&model, &Options::default()).unwrap();
        assert_eq!(files, again, "{robot}: generation is deterministic");
        let dir = repo().join("generated").join(&robot);
        for (path, status) in write_files(&dir, &files, !bless).unwrap() {
            if status == FileStatus::Stale {
                stale.push(path.display().to_string());
            }
        }
        let expected: Vec<String> = files.iter().map(|f| f.name.clone()).collect();
        let mut present: Vec<String> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        present.sort();
        assert_eq!(present, expected, "{robot}: no stray files in generated/{robot}");
    }
    assert!(stale.is_empty(), "stale generated files (GRID_GEN_BLESS=1 cargo test -p grid-gen --test generated_fresh to refresh):\n{}", stale.join("\n"));
}
