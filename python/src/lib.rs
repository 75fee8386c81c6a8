//! The native half of the `grid_gen` Python package: grid-gen's generator (URDF to the
//! Rust kernels and their C ABI), and the runtime crate's source, which `grid_gen.load`
//! writes beside each robot it compiles. The kernels themselves are not here: each robot
//! becomes its own shared library, loaded through its C ABI; [`Caller`] is the fast path
//! that calls one of its batch entry points on NumPy arrays.

use numpy::{Element, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

/// What `grid_gen.load`'s scene keywords set, each the scene key of the same name; `None`
/// leaves it to the scene file (or the default). `dt` without `step` times the scene's
/// `[step]`.
#[derive(Default, FromPyObject)]
#[pyo3(from_item_all)]
struct SceneKeywords {
    contacts: Option<Vec<(String, String)>>,
    step: Option<String>,
    dt: Option<f64>,
    actuated: Option<Vec<String>>,
    external_forces: Option<Vec<String>>,
    contact_mask: Option<bool>,
    baumgarte: Option<bool>,
    gravity: Option<[f64; 3]>,
    round_angles: Option<f64>,
}

impl SceneKeywords {
    /// Sets what the keywords give on `b`, which is exclusive of the scene file: a keyword
    /// that the file also sets is an error naming both (`grid_gen::Config::exclusive`).
    fn set_on(&self, b: &mut grid_gen::Builder) -> PyResult<()> {
        use grid_gen::model::{ContactKind, Scheme};
        b.exclusive_of_scene("load");
        if let Some(contacts) = &self.contacts {
            let mut entries = Vec::with_capacity(contacts.len());
            for (frame, kind) in contacts {
                let kind = ContactKind::parse(kind).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "load(contacts=...): contact `{frame}` has type {kind:?}; a contact is \"point\" (a 3-D force) or \"wrench\" (6-D)"
                    ))
                })?;
                entries.push((frame.clone(), kind));
            }
            b.contacts(&entries);
        }
        if let Some(dt) = self.dt {
            if !(dt.is_finite() && dt > 0.0) {
                return Err(PyValueError::new_err(format!(
                    "load(dt={dt}): a time step is a finite, positive number of seconds (or None: given at run time)"
                )));
            }
        }
        match (&self.step, self.dt) {
            (Some(name), dt) => {
                let scheme = Scheme::parse(name).ok_or_else(|| {
                    let known: Vec<&str> = Scheme::ALL.iter().map(|s| s.name()).collect();
                    PyValueError::new_err(format!(
                        "load(step={name:?}): no such scheme; schemes: {}",
                        known.join(", ")
                    ))
                })?;
                match dt {
                    Some(dt) => b.step(scheme, dt),
                    None => b.step_at_run_time(scheme),
                };
            }
            // The scene's [step], timed here (an error without one).
            (None, Some(dt)) => {
                b.dt(dt);
            }
            (None, None) => {}
        }
        if let Some(joints) = &self.actuated {
            b.actuated(joints);
        }
        if let Some(joints) = &self.external_forces {
            b.external_forces(joints);
        }
        if let Some(mask) = self.contact_mask {
            b.contact_mask(mask);
        }
        if let Some(on) = self.baumgarte {
            b.baumgarte(on);
        }
        if let Some(g) = self.gravity {
            b.gravity(g);
        }
        if let Some(tol) = self.round_angles {
            grid_gen::scene::check_round_angles(tol)
                .map_err(|why| PyValueError::new_err(format!("load(round_angles=...): {why}")))?;
            b.round_angles(tol);
        }
        Ok(())
    }
}

/// Generates the Rust module and its C ABI for one robot into `out_dir`; returns the
/// written files' names. Raises ValueError with grid-gen's diagnostics (located in the
/// URDF) for a robot it cannot use. `keywords`: `grid_gen.load`'s scene keywords, a dict
/// (see [`SceneKeywords`]).
#[pyfunction]
#[pyo3(signature = (urdf, out_dir, floating_base=false, scene=None, frames=None, kernels=None, precision="f64", keywords=None, batch_lanes="auto", calls="auto", kernel_features=false))]
#[allow(clippy::too_many_arguments)]
fn generate(
    urdf: &str,
    out_dir: &str,
    floating_base: bool,
    scene: Option<&str>,
    frames: Option<Vec<String>>,
    kernels: Option<Vec<String>>,
    precision: &str,
    keywords: Option<SceneKeywords>,
    batch_lanes: &str,
    calls: &str,
    kernel_features: bool,
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
    let lanes = match batch_lanes {
        "auto" => grid_gen::back::c::BatchLanes::Auto,
        "all" => grid_gen::back::c::BatchLanes::All,
        "none" => grid_gen::back::c::BatchLanes::None,
        other => {
            return Err(PyValueError::new_err(format!(
                "batch_lanes must be \"auto\", \"all\" or \"none\", not {other:?}"
            )))
        }
    };
    let calls = grid_gen::ir::Calls::parse(calls).ok_or_else(|| {
        PyValueError::new_err(format!(
            "calls must be \"auto\", \"rnea_grad\" or \"all\", not {calls:?}"
        ))
    })?;
    let mut b = grid_gen::Builder::new();
    // One copy of the kernels, this machine's: the library runs where it is compiled (the
    // cache key holds `host_copies()`), and one copy compiles about 4x faster than the
    // dispatched pair.
    b.urdf(urdf)
        .out_dir(out_dir)
        .emit(&[Target::Rust, Target::C])
        .c_precision(f64, f32)
        .batch_lanes(lanes)
        .calls(calls)
        .kernel_features(kernel_features)
        .copies(grid_gen::back::rust::Copies::host())
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
    keywords.unwrap_or_default().set_on(&mut b)?;
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

/// The settings table (`grid_gen::settings::SETTINGS`): each setting's load keyword, scene
/// key, CLI flag and Builder method, which the tests hold `load`'s signature to.
#[pyfunction]
fn settings() -> Vec<(&'static str, &'static str, &'static str, &'static str)> {
    grid_gen::settings::SETTINGS.iter().map(|s| (s.key, s.toml, s.flag, s.builder)).collect()
}

/// The one copy of the kernels `generate` compiles on this machine (`fma` on x86-64 with
/// AVX2 and FMA, else `portable`); part of the cache key, so that a cache shared between
/// machines never hands one a library its CPU cannot run.
#[pyfunction]
fn host_copies() -> &'static str {
    grid_gen::back::rust::Copies::host().name()
}

/// grid-gen's version; part of the cache key of every compiled robot.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

/// The most pointers one entry point takes (inputs and outputs): contact_fd_grad with fext
/// has 4 inputs and 8 outputs.
const MAX_POINTERS: usize = 16;

/// Calls the C ABI batch entry point at `addr`, `int32_t f(size_t n, T* p0, T* p1, ...)`,
/// with `p.len()` pointers.
///
/// # Safety
/// `addr` is such an entry point taking exactly `p.len()` pointers, each holding `n`
/// states' arrays of the entry point's sizes.
unsafe fn call_entry(addr: usize, n: usize, p: &[usize]) -> i32 {
    macro_rules! arity {
        ($($i:literal)*) => {{
            type F = unsafe extern "C" fn(usize, $(arity!(@ptr $i)),*) -> i32;
            // SAFETY: the caller's contract: addr is an entry point of this arity.
            let f: F = unsafe { std::mem::transmute::<usize, F>(addr) };
            // SAFETY: the caller's contract on the pointers.
            unsafe { f(n, $(p[$i] as *mut std::ffi::c_void),*) }
        }};
        (@ptr $i:literal) => { *mut std::ffi::c_void };
    }
    match p.len() {
        2 => arity!(0 1),
        3 => arity!(0 1 2),
        4 => arity!(0 1 2 3),
        5 => arity!(0 1 2 3 4),
        6 => arity!(0 1 2 3 4 5),
        7 => arity!(0 1 2 3 4 5 6),
        8 => arity!(0 1 2 3 4 5 6 7),
        9 => arity!(0 1 2 3 4 5 6 7 8),
        10 => arity!(0 1 2 3 4 5 6 7 8 9),
        11 => arity!(0 1 2 3 4 5 6 7 8 9 10),
        12 => arity!(0 1 2 3 4 5 6 7 8 9 10 11),
        13 => arity!(0 1 2 3 4 5 6 7 8 9 10 11 12),
        14 => arity!(0 1 2 3 4 5 6 7 8 9 10 11 12 13),
        15 => arity!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14),
        16 => arity!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15),
        _ => unreachable!("Caller::new admits 2 to {MAX_POINTERS} pointers"),
    }
}

/// One kernel's batch entry point, called on NumPy arrays without leaving native code: the
/// fast path of `grid_gen`'s kernel methods. It takes the common case only (every input an
/// array of exactly the kernel's dtype, C-contiguous, shaped `(len,)` or `(B, len)` alike,
/// every value finite) and returns None for anything else, so that the Python path, which
/// converts, copies and names what is wrong, handles it: the two give the same results.
#[pyclass(frozen)]
struct Caller {
    addr: usize,
    f64: bool,
    in_lens: Vec<usize>,
    out_dims: Vec<Vec<usize>>,
    /// Where each unit quaternion starts in a configuration (q, and `difference`'s q1): a
    /// state whose norm is off by more than 1e-6 goes to the Python path, which names it.
    quats: Vec<usize>,
    /// Which inputs are configurations (the first, q, unless told).
    configs: Vec<usize>,
}

#[pymethods]
impl Caller {
    /// `addr`: the entry point's address (from ctypes), which must stay loaded as long as
    /// this object lives; `f64`: its scalar (else f32); the per-state input lengths and
    /// output shapes, in the entry point's order; where q's quaternions start.
    #[new]
    #[pyo3(signature = (addr, f64, in_lens, out_dims, quats=Vec::new(), configs=vec![0]))]
    fn new(
        addr: usize,
        f64: bool,
        in_lens: Vec<usize>,
        out_dims: Vec<Vec<usize>>,
        quats: Vec<usize>,
        configs: Vec<usize>,
    ) -> PyResult<Self> {
        let count = in_lens.len() + out_dims.len();
        if addr == 0 || in_lens.is_empty() || out_dims.is_empty() || count > MAX_POINTERS {
            return Err(PyValueError::new_err(format!(
                "Caller: a non-null entry point with 1 to {MAX_POINTERS} arrays, not {count}"
            )));
        }
        if configs.iter().any(|&c| c >= in_lens.len())
            || configs.iter().any(|&c| quats.iter().any(|&at| at + 4 > in_lens[c]))
        {
            return Err(PyValueError::new_err("Caller: a quaternion past the end of q"));
        }
        Ok(Caller { addr, f64, in_lens, out_dims, quats, configs })
    }

    /// The kernel's outputs for these inputs (one array, or a tuple), or None where the
    /// fast path does not apply.
    #[pyo3(signature = (*args))]
    fn __call__(&self, py: Python<'_>, args: &Bound<'_, PyTuple>) -> PyResult<Option<Py<PyAny>>> {
        if self.f64 {
            self.run::<f64>(py, args)
        } else {
            self.run::<f32>(py, args)
        }
    }
}

impl Caller {
    fn run<T: Element + Copy + Into<f64>>(
        &self,
        py: Python<'_>,
        args: &Bound<'_, PyTuple>,
    ) -> PyResult<Option<Py<PyAny>>> {
        if args.len() != self.in_lens.len() {
            return Ok(None);
        }
        let mut pointers = [0usize; MAX_POINTERS];
        let mut count = 0;
        let mut batch: Option<Option<usize>> = None;
        // The inputs stay borrowed (read-only) until the call returns.
        let mut borrowed = Vec::with_capacity(self.in_lens.len());
        for (arg, &len) in args.iter().zip(&self.in_lens) {
            let Ok(array) = arg.cast::<PyArrayDyn<T>>() else { return Ok(None) };
            let Ok(view) = array.try_readonly() else { return Ok(None) };
            let b = match *view.shape() {
                [l] if l == len => None,
                [b, l] if l == len => Some(b),
                _ => return Ok(None),
            };
            match batch {
                None => batch = Some(b),
                Some(first) if first != b => return Ok(None),
                Some(_) => {}
            }
            // as_slice takes Fortran order too, which the entry point would misread.
            if !view.is_c_contiguous() {
                return Ok(None);
            }
            let Ok(values) = view.as_slice() else { return Ok(None) };
            if !values.iter().all(|&x| x.into().is_finite()) {
                return Ok(None);
            }
            if self.configs.contains(&count) && !self.quats.is_empty() {
                let unit = |state: &[T]| {
                    self.quats.iter().all(|&at| {
                        let n2: f64 = state[at..at + 4].iter().map(|&x| x.into() * x.into()).sum();
                        (n2.sqrt() - 1.0).abs() <= 1e-6
                    })
                };
                if !values.chunks_exact(len).all(unit) {
                    return Ok(None);
                }
            }
            pointers[count] = values.as_ptr() as usize;
            count += 1;
            borrowed.push(view);
        }
        let lead = batch.flatten();
        let n = lead.unwrap_or(1);
        let mut outputs = Vec::with_capacity(self.out_dims.len());
        for dims in &self.out_dims {
            let shape: Vec<usize> = lead.into_iter().chain(dims.iter().copied()).collect();
            // SAFETY: the entry point writes every element before anyone reads it (and on
            // an error status the array is dropped unread).
            let array = unsafe { PyArrayDyn::<T>::new(py, shape, false) };
            pointers[count] = array.data() as usize;
            count += 1;
            outputs.push(array);
        }
        let addr = self.addr;
        let p = &pointers[..count];
        // SAFETY: addr is the entry point Caller::new was given, of this arity; each input
        // pointer holds n states of its length (shapes checked above) and stays borrowed,
        // each output was just allocated with n states of its shape.
        let status = py.detach(|| unsafe { call_entry(addr, n, p) });
        drop(borrowed);
        if status != 0 {
            return Err(PyRuntimeError::new_err(format!(
                "the kernel library returned status {status}"
            )));
        }
        if outputs.len() == 1 {
            Ok(Some(outputs.pop().expect("one output").into_any().unbind()))
        } else {
            Ok(Some(PyTuple::new(py, outputs)?.into_any().unbind()))
        }
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Caller>()?;
    m.add_function(wrap_pyfunction!(generate, m)?)?;
    m.add_function(wrap_pyfunction!(runtime_source, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    m.add_function(wrap_pyfunction!(settings, m)?)?;
    m.add_function(wrap_pyfunction!(host_copies, m)?)?;
    Ok(())
}
