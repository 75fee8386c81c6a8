//! From a model to the files grid-gen writes: lower once into the IR module, run each
//! requested backend on it, and write files only when they change.

use std::path::{Path, PathBuf};

use crate::back::c::{self, COptions};
use crate::back::rust::{self, RustOptions};
use crate::back::verilog::{self, VerilogOptions};
use crate::back::wgsl::{self, WgslOptions};
pub use crate::back::{BackError, GeneratedFile, Target};
use crate::ir::{self, LowerError, LowerOptions};
use crate::model::{Model, DEFAULT_GRAVITY};

/// What to generate.
#[derive(Clone, Debug)]
pub struct Options {
    pub gravity: [f64; 3],
    pub targets: Vec<Target>,
    pub lower: LowerOptions,
    pub rust: RustOptions,
    pub wgsl: WgslOptions,
    pub verilog: VerilogOptions,
    pub c: COptions,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            gravity: DEFAULT_GRAVITY,
            targets: vec![Target::Rust],
            lower: LowerOptions::default(),
            rust: RustOptions::default(),
            wgsl: WgslOptions::default(),
            verilog: VerilogOptions::default(),
            c: COptions::default(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    #[error(transparent)]
    Lower(#[from] LowerError),
    #[error(transparent)]
    Back(#[from] BackError),
}

/// Each backend's error, as the generator's.
macro_rules! from_backend {
    ($($e:ty),*) => {$(
        impl From<$e> for GenerateError {
            fn from(e: $e) -> Self {
                GenerateError::Back(e.into())
            }
        }
    )*};
}
from_backend!(rust::RustError, wgsl::WgslError, verilog::VerilogError, c::CError);

/// Generates every requested file for `model`, in [`Target::ALL`] order. Deterministic:
/// same input, same bytes.
pub fn generate(model: &Model, options: &Options) -> Result<Vec<GeneratedFile>, GenerateError> {
    let module = ir::lower(model, options.gravity, &options.lower)?;
    emit(&module, options)
}

/// Runs the requested backends on a lowered module.
pub fn emit(module: &ir::Module, options: &Options) -> Result<Vec<GeneratedFile>, GenerateError> {
    let mut files = Vec::new();
    for target in Target::ALL.into_iter().filter(|t| options.targets.contains(t)) {
        match target {
            Target::Rust => files.push(rust::emit(module, &options.rust)?),
            Target::Wgsl => files.push(wgsl::emit(module, &options.wgsl)?),
            Target::Verilog => files.extend(verilog::emit(module, &options.verilog)?),
            Target::C => files.extend(c::emit(module, &options.c)?),
        }
    }
    Ok(files)
}

/// What happened to one file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileStatus {
    Unchanged,
    Written,
    /// `check` mode: the file is missing or differs.
    Stale,
}

/// Writes `files` into `dir` (created if needed), rewriting only files whose contents
/// change; with `check`, writes nothing and reports which would change. File names come
/// from the namer and never contain a path separator; a name that does is refused. A
/// file whose header names another source URDF (two robots with the same name sent to
/// one folder) is refused before anything is written.
pub fn write_files(
    dir: &Path,
    files: &[GeneratedFile],
    check: bool,
) -> std::io::Result<Vec<(PathBuf, FileStatus)>> {
    use std::io::{Error, ErrorKind};
    for f in files {
        if f.name.is_empty() || f.name.contains(['/', '\\']) || f.name.starts_with('.') {
            return Err(Error::new(
                ErrorKind::InvalidInput,
                format!("refusing to write `{}`: not a plain file name", f.name),
            ));
        }
    }
    if dir.exists() && !dir.is_dir() {
        return Err(Error::new(ErrorKind::NotADirectory, "it exists and is not a directory"));
    }
    // Each existing file is read once: for its source here, and below to skip rewriting it.
    let olds: Vec<Option<Vec<u8>>> =
        files.iter().map(|f| std::fs::read(dir.join(&f.name)).ok()).collect();
    for (f, old) in files.iter().zip(&olds) {
        let Some(old) = old.as_deref().and_then(|o| std::str::from_utf8(o).ok()) else { continue };
        if let (Some(was), Some(now)) =
            (crate::back::source_of(old), crate::back::source_of(&f.contents))
        {
            if was != now {
                return Err(Error::new(
                    ErrorKind::AlreadyExists,
                    format!(
                        "`{}` there was generated from {was}, not {now}: two robots with the same name would overwrite each other; \
                         choose another folder, or delete the file to replace it",
                        f.name
                    ),
                ));
            }
        }
    }
    if !check {
        std::fs::create_dir_all(dir)?;
    }
    let mut out = Vec::new();
    for (f, old) in files.iter().zip(olds) {
        let path = dir.join(&f.name);
        let same = old.is_some_and(|old| old == f.contents.as_bytes());
        let status = match (same, check) {
            (true, _) => FileStatus::Unchanged,
            (false, true) => FileStatus::Stale,
            (false, false) => {
                std::fs::write(&path, &f.contents)?;
                FileStatus::Written
            }
        };
        out.push((path, status));
    }
    Ok(out)
}
