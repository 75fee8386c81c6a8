//! Every program the library starts: `rustc` and the timing program it builds, Icarus
//! Verilog's `iverilog` and `vvp`. The front end, the IR and the backends only return text;
//! running something on it happens here, outside the core, where a missing tool becomes
//! an error that says what to install.

pub mod icarus;
pub mod rustc;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Why a program did not run to a successful exit.
#[derive(Debug)]
pub(crate) enum RunError {
    /// The program is not on PATH (the name it was started by).
    NotFound(String),
    /// Starting it failed for another reason.
    Io(std::io::Error),
    /// It ran and exited with a failure status.
    Failed { stdout: String, stderr: String },
}

/// Runs `cmd` to completion and returns its standard output.
pub(crate) fn run(cmd: &mut Command) -> Result<String, RunError> {
    let out = cmd.output().map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            RunError::NotFound(cmd.get_program().to_string_lossy().into_owned())
        } else {
            RunError::Io(e)
        }
    })?;
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        return Err(RunError::Failed { stdout, stderr });
    }
    Ok(stdout)
}

/// A fresh folder under the system's temporary folder, removed when dropped (also on an
/// error path), named by the process and a counter so that parallel tests never share one.
pub(crate) struct Scratch(PathBuf);

impl Scratch {
    pub(crate) fn new(what: &str) -> std::io::Result<Self> {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let dir = std::env::temp_dir().join(format!(
            "grid-gen-{what}-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&dir)?;
        Ok(Self(dir))
    }

    pub(crate) fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
