//! The native half of the `grid_gen` Python package: grid-gen's generator (URDF to the
//! Rust kernels and their C ABI), and the runtime crate's source, which `grid_gen.load`
//! writes beside each robot it compiles. The kernels themselves are not here: each robot
//! becomes its own shared library, loaded through its C ABI.

use pyo3::exceptions::{PyFileNotFoundError, PyValueError};
use pyo3::prelude::*;

/// Generates the Rust module and its C ABI for one robot into `out_dir`; returns the
/// written files' names. Raises ValueError with grid-gen's diagnostics (located in the
/// URDF) for a robot it cannot use.
#[pyfunction]
#[pyo3(signature = (urdf, out_dir, floating_base=false, scene=None, frames=None, kernels=None, precision="f64"))]
fn generate(
    urdf: &str,
    out_dir: &str,
    floating_base: bool,
    scene: Option<&str>,
    frames: Option<Vec<String>>,
    kernels: Option<Vec<String>>,
    precision: &str,
) -> PyResult<Vec<String>> {
    use grid_gen::generate::Target;
    if !std::path::Path::new(urdf).is_file() {
        return Err(PyFileNotFoundError::new_err(format!("no URDF at {urdf}")));
    }
    let (f64, f32) = match precision {
        "f64" => (true, false),
        "f32" => (false, true),
        "both" => (true, true),
        other => {
            return Err(PyValueError::new_err(format!(
                "precision must be \"f64\", \"f32\" or \"both\", not {other:?}"
            )))
        }
    };
    let mut b = grid_gen::Builder::new();
    b.urdf(urdf)
        .out_dir(out_dir)
        .emit(&[Target::Rust, Target::C])
        .c_precision(f64, f32)
        .quiet(true);
    // False is the default, not a request to take away a scene's floating base.
    if floating_base {
        b.floating_base(true);
    }
    if let Some(scene) = scene {
        b.scene(scene);
    }
    if let Some(frames) = &frames {
        b.frames(frames);
    }
    if let Some(names) = &kernels {
        let mut kinds = Vec::new();
        for name in names {
            let kind = grid_gen::ir::KernelKind::parse(name).ok_or_else(|| {
                let known: Vec<&str> =
                    grid_gen::ir::KernelKind::ALL.iter().map(|k| k.name()).collect();
                PyValueError::new_err(format!(
                    "unknown kernel {name:?}; kernels: {}",
                    known.join(", ")
                ))
            })?;
            kinds.push(kind);
        }
        b.kernels(&kinds);
    }
    let written = b.compile().map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(written
        .iter()
        .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .collect())
}

/// The source of the `grid-gen-runtime` crate (one file), which every robot's library
/// links.
#[pyfunction]
fn runtime_source() -> &'static str {
    include_str!("../../crates/grid-gen-runtime/src/lib.rs")
}

/// grid-gen's version; part of the cache key of every compiled robot.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(runtime_source, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
