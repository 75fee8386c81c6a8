//! Compiles a single-file Rust program with `rustc -C opt-level=3` (generated modules need
//! no crate) and runs it: how `grid-gen bench --backend rust` and `accuracy --time` time the
//! generated kernels.

use std::path::Path;
use std::process::Command;

use super::{run, RunError};

#[derive(Debug, thiserror::Error)]
pub enum RustcError {
    #[error("cannot run `{0}`; timing the Rust kernels needs a Rust compiler: install one from https://rustup.rs, or set RUSTC")]
    NotFound(String),
    #[error("cannot start `{0}`: {1}")]
    Io(String, std::io::Error),
    #[error("rustc could not compile the generated kernels:\n{0}")]
    Compile(String),
    #[error("the compiled program failed: {0}")]
    Run(String),
}

/// The compiler to use: `$RUSTC` (as cargo sets it for build scripts), else `rustc`.
pub fn rustc() -> String {
    std::env::var("RUSTC").unwrap_or_else(|_| "rustc".to_string())
}

/// Compiles `main` (a crate root; its `mod` files sit beside it) into the executable `exe`
/// with `rustc`, optimised, then runs it with no arguments and returns its standard output.
pub fn build_and_run(rustc: &str, main: &Path, exe: &Path) -> Result<String, RustcError> {
    let mut compile = Command::new(rustc);
    compile
        .args(["--edition", "2021", "-C", "opt-level=3", "-C", "debuginfo=0"])
        .args(["--crate-name", "time_kernels", "-o"])
        .arg(exe)
        .arg(main);
    run(&mut compile).map_err(|e| match e {
        RunError::NotFound(p) => RustcError::NotFound(p),
        RunError::Io(e) => RustcError::Io(rustc.to_string(), e),
        RunError::Failed { stderr, .. } => {
            // rustc's last lines carry the error; the whole text can be thousands of lines.
            let tail: Vec<&str> = stderr.lines().rev().take(30).collect();
            RustcError::Compile(tail.into_iter().rev().collect::<Vec<_>>().join("\n"))
        }
    })?;
    run(&mut Command::new(exe)).map_err(|e| match e {
        RunError::NotFound(p) => RustcError::Run(format!("{p} was not built")),
        RunError::Io(e) => RustcError::Run(e.to_string()),
        RunError::Failed { stderr, .. } => RustcError::Run(stderr),
    })
}
