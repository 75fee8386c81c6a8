//! `build.rs` integration in the style of prost-build: configure a [`Builder`], then one
//! terminal call generates the module into `OUT_DIR`.
//!
//! ```no_run
//! // build.rs
//! fn main() -> Result<(), grid_gen::BuildError> {
//!     grid_gen::Builder::new()
//!         .urdf("robots/grid_iiwa.urdf")
//!         .file_name("robot.rs")
//!         .compile()?;
//!     Ok(())
//! }
//! ```
//!
//! ```ignore
//! // src/main.rs
//! mod robot {
//!     include!(concat!(env!("OUT_DIR"), "/robot.rs"));
//! }
//! let (qdd, dqdd_dq, dqdd_dqd) = robot::fd_grad(&q, &qd, &tau);
//! ```

use std::fmt;
use std::path::{Path, PathBuf};

use crate::config::{Config, ConfigError};
use crate::generate::{write_files, Target};
use crate::scene::ContactEntry;

/// Why a build script could not generate the kernels. `Debug` prints the same text as
/// `Display`, so `fn main() -> Result<(), BuildError>` shows cargo a readable message.
pub enum BuildError {
    NoUrdf,
    NoOutDir,
    /// Reading the URDF or scene, the robot description's errors, or generation.
    Config(ConfigError),
    Write(PathBuf, std::io::Error),
    BadFileName(String),
    NoTargets,
}

impl fmt::Display for BuildError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BuildError::NoUrdf => write!(f, "grid-gen: no URDF given; call Builder::urdf(\"path/to/robot.urdf\")"),
            BuildError::NoOutDir => write!(f, "grid-gen: OUT_DIR is not set (not running under cargo); call Builder::out_dir(...)"),
            BuildError::Config(ConfigError::Load(e)) => write!(f, "grid-gen: {} is not a usable robot description:\n{}", e.path, e.render_plain()),
            BuildError::Config(e) => write!(f, "grid-gen: {e}"),
            BuildError::Write(p, e) => write!(f, "grid-gen: cannot write {}: {e}", p.display()),
            BuildError::BadFileName(n) => write!(f, "grid-gen: file name `{n}` must be a plain `*.rs` name without folders"),
            BuildError::NoTargets => write!(f, "grid-gen: no targets selected; call Builder::emit(&[Target::Rust])"),
        }
    }
}

impl fmt::Debug for BuildError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl std::error::Error for BuildError {}

/// Generates robot kernels from a build script: the setters fill a [`Config`], the
/// description the CLI and the Python package build too.
#[derive(Clone, Debug, Default)]
pub struct Builder {
    config: Config,
    out_dir: Option<PathBuf>,
    file_name: Option<String>,
    quiet: bool,
}

impl Builder {
    pub fn new() -> Self {
        Builder::default()
    }

    /// The robot description (relative paths are relative to the crate, as in build.rs).
    /// Cargo is told to rerun the build script when it changes.
    pub fn urdf(&mut self, path: impl AsRef<Path>) -> &mut Self {
        self.config.urdf = path.as_ref().to_path_buf();
        self
    }

    /// Where to write; default `$OUT_DIR`.
    pub fn out_dir(&mut self, dir: impl AsRef<Path>) -> &mut Self {
        self.out_dir = Some(dir.as_ref().to_path_buf());
        self
    }

    /// Which backends to run (default: Rust only); each writes its own file.
    ///
    /// ```no_run
    /// # fn main() -> Result<(), grid_gen::BuildError> {
    /// use grid_gen::generate::Target;
    /// grid_gen::Builder::new().urdf("robots/grid_iiwa.urdf").emit(&[Target::Rust]).compile()?;
    /// # Ok(()) }
    /// ```
    pub fn emit(&mut self, targets: &[Target]) -> &mut Self {
        self.config.options.targets = targets.to_vec();
        self
    }

    /// Name of the generated Rust file; default `<robot>.rs` from the URDF's robot name
    /// made an identifier. Must be a plain `*.rs` name.
    pub fn file_name(&mut self, name: impl Into<String>) -> &mut Self {
        self.file_name = Some(name.into());
        self
    }

    /// Gravity in the root frame, m/s², compiled in; default (0, 0, -9.81).
    pub fn gravity(&mut self, gravity: [f64; 3]) -> &mut Self {
        self.config.overrides.gravity = Some(gravity);
        self
    }

    /// The RNEA gradient's formulation (default [`crate::ir::Gradient::Auto`]: the one with fewer
    /// operations for this robot).
    pub fn gradient(&mut self, gradient: crate::ir::Gradient) -> &mut Self {
        self.config.options.lower.gradient = gradient;
        self
    }

    /// How `fd_grad` applies M⁻¹ (default [`crate::ir::Solve::Auto`]: the route with fewer
    /// operations; `info` says which).
    pub fn solve(&mut self, solve: crate::ir::Solve) -> &mut Self {
        self.config.options.lower.solve = solve;
        self
    }

    /// Which kernels call other kernels of their module ([`crate::ir::Calls`]).
    pub fn calls(&mut self, calls: crate::ir::Calls) -> &mut Self {
        self.config.options.lower.calls = calls;
        self
    }

    /// A scene file (TOML; see [`crate::scene`]): locked joints, kept or dropped subtrees,
    /// payloads, gravity (which [`Builder::gravity`] replaces) and the kernels to
    /// generate. Cargo is told to rerun the build script when it changes.
    pub fn scene(&mut self, path: impl AsRef<Path>) -> &mut Self {
        self.config.scene = Some(path.as_ref().to_path_buf());
        self
    }

    /// Put a free-flyer between the world and the URDF's root link (a floating base, as
    /// Pinocchio's `JointModelFreeFlyer`): q becomes `[x, y, z, qx, qy, qz, qw, joints…]`
    /// and the kernels' first six velocity coordinates are the base's linear and angular
    /// velocity in its own frame. Same as `floating_base = true` in a scene.
    pub fn floating_base(&mut self, floating: bool) -> &mut Self {
        self.config.overrides.floating_base = Some(floating);
        self
    }

    /// How `<mimic>` joints are modelled (default: independent, or the scene's `mimic`):
    /// coupled mimic joints follow their joint and have no coordinate of their own.
    pub fn mimic(&mut self, mode: crate::MimicMode) -> &mut Self {
        self.config.overrides.mimic = Some(mode);
        self
    }

    /// Frames (URDF link names) the frame kernels compute: `frame_placement`,
    /// `frame_jacobian`, `frame_velocity`, `frame_acceleration` (replaces the scene's
    /// `[frames] names`; none: no frame kernels). An unknown name fails the build with the
    /// closest link names.
    pub fn frames<S: AsRef<str>>(&mut self, names: &[S]) -> &mut Self {
        self.config.overrides.frames = Some(names.iter().map(|n| n.as_ref().to_string()).collect());
        self
    }

    /// The frame kernels' reference frame (default `LocalWorldAligned`, or the scene's).
    pub fn reference_frame(&mut self, rf: crate::model::ReferenceFrame) -> &mut Self {
        self.config.overrides.reference_frame = Some(rf);
        self
    }

    /// Generate the step kernels `step` and `step_grad` for this scheme and time step
    /// (replaces the scene's `[step]`).
    pub fn step(&mut self, scheme: crate::model::Scheme, dt: f64) -> &mut Self {
        self.config.overrides.scheme = Some(scheme);
        self.config.overrides.dt = Some(dt);
        self
    }

    /// Generate the step kernels for this scheme with the time step left to run time: `step`
    /// and `step_grad` take `dt` as their last argument, one value per state (replaces the
    /// scene's `[step]`, its dt included).
    ///
    /// ```no_run
    /// // build.rs
    /// grid_gen::Builder::new()
    ///     .urdf("robots/grid_hyq.urdf")
    ///     .floating_base(true)
    ///     .step_at_run_time(grid_gen::model::Scheme::SemiImplicitEuler)
    ///     .compile()?;
    /// # Ok::<(), grid_gen::BuildError>(())
    /// ```
    pub fn step_at_run_time(&mut self, scheme: crate::model::Scheme) -> &mut Self {
        self.config.overrides.scheme = Some(scheme);
        self.config.overrides.dt = None;
        self.config.overrides.runtime_dt = true;
        self
    }

    /// The actuated joints, the step's τ and B's columns (replaces the scene's
    /// `[actuation] joints`; default every joint but a floating base).
    pub fn actuated<S: AsRef<str>>(&mut self, joints: &[S]) -> &mut Self {
        self.config.overrides.actuated =
            Some(joints.iter().map(|n| n.as_ref().to_string()).collect());
        self
    }

    /// `fd_grad` also returns `dqdd_dtau = M⁻¹` (as the scene's `[fd_grad] minv = true`).
    pub fn fd_grad_minv(&mut self, on: bool) -> &mut Self {
        self.config.overrides.fd_grad_minv = Some(on);
        self
    }

    /// Reads every `<origin rpy>` angle within `tolerance` rad (at most 1e-6) of a multiple
    /// of π/2 as that multiple (the scene's `round_angles`; off by default).
    pub fn round_angles(&mut self, tolerance: f64) -> &mut Self {
        self.config.overrides.round_angles = Some(tolerance);
        self
    }

    /// The bodies that take an external force `fext`, by the name of the joint that moves
    /// them (Pinocchio's names; `"*"` for every body). Replaces `[external_forces] joints`.
    pub fn external_forces<S: AsRef<str>>(&mut self, joints: &[S]) -> &mut Self {
        self.config.overrides.fext = Some(joints.iter().map(|n| n.as_ref().to_string()).collect());
        self
    }

    /// Whether `rnea_grad` and `fd_grad` return `∂/∂fext` (default true; the scene's
    /// `[external_forces] derivatives`).
    pub fn external_force_derivatives(&mut self, on: bool) -> &mut Self {
        self.config.overrides.fext_derivatives = Some(on);
        self
    }

    /// Whether the contacts are candidates chosen per state (the scene's `contact_mask`):
    /// `contact_fd`, `contact_fd_grad`, `step` and `step_grad` then take `active`, one 0 or
    /// 1 per contact, and one library serves every contact mode of a gait.
    ///
    /// ```no_run
    /// // build.rs: HyQ's four feet, any of them on the ground.
    /// let feet = ["lf_lowerleg", "rf_lowerleg", "lh_lowerleg", "rh_lowerleg"]
    ///     .map(|f| (f, grid_gen::model::ContactKind::Point));
    /// grid_gen::Builder::new()
    ///     .urdf("robots/grid_hyq.urdf")
    ///     .floating_base(true)
    ///     .contacts(&feet)
    ///     .contact_mask(true)
    ///     .compile()?;
    /// # Ok::<(), grid_gen::BuildError>(())
    /// ```
    pub fn contact_mask(&mut self, mask: bool) -> &mut Self {
        self.config.overrides.contact_mask = Some(mask);
        self
    }

    /// Names the caller's settings in errors (`load` for the Python package), and makes a
    /// setting given here that the scene file also sets an error naming both, rather than
    /// this value replacing the file's ([`crate::Config::exclusive`]).
    pub fn exclusive_of_scene(&mut self, caller: impl Into<String>) -> &mut Self {
        self.config.exclusive = Some(caller.into());
        self
    }

    /// The step's time step alone, for the scene's `[step]` scheme (its dt must be unset
    /// there; with [`Self::exclusive_of_scene`], a scene without a step is an error).
    pub fn dt(&mut self, dt: f64) -> &mut Self {
        self.config.overrides.dt = Some(dt);
        self
    }

    /// Whether the contacts are stabilised as Pinocchio's Baumgarte corrector (the scene's
    /// `baumgarte`): `contact_fd`, `contact_fd_grad`, `step` and `step_grad` then take
    /// `gains` (Kp, Kd per contact) and `contact_ref` (a world position per contact), and
    /// drive each contact's acceleration to `−Kd v − Kp (p − p_ref)`. Point contacts only.
    pub fn baumgarte(&mut self, on: bool) -> &mut Self {
        self.config.overrides.baumgarte = Some(on);
        self
    }

    /// Contacts at frames (link names), each a point or a wrench; the kernels take their
    /// forces λ in `LOCAL_WORLD_ALIGNED` axes. Replaces the scene's `[[contact]]`.
    pub fn contacts<S: AsRef<str>>(
        &mut self,
        contacts: &[(S, crate::model::ContactKind)],
    ) -> &mut Self {
        self.config.overrides.contacts = Some(
            contacts
                .iter()
                .map(|(f, k)| ContactEntry { frame: f.as_ref().to_string(), kind: *k })
                .collect(),
        );
        self
    }

    /// Which kernels to generate (replaces the scene's `kernels`; default every kernel the
    /// robot has: frame, force, contact and step kernels where those are declared).
    pub fn kernels(&mut self, kernels: &[crate::ir::KernelKind]) -> &mut Self {
        self.config.kernels = Some(kernels.to_vec());
        self
    }

    /// The scalar types of the C target's entry points (default both; a loader that needs
    /// one halves the library's compile time).
    pub fn c_precision(&mut self, f64: bool, f32: bool) -> &mut Self {
        self.config.options.c.f64 = f64;
        self.config.options.c.f32 = f32;
        self
    }

    /// Which kernels' batch entry points run several states per call in SIMD lanes
    /// (default [`BatchLanes::Auto`](crate::back::c::BatchLanes::Auto): where lanes were
    /// measured to pay). Each kernel with lanes is compiled twice.
    pub fn batch_lanes(&mut self, lanes: crate::back::c::BatchLanes) -> &mut Self {
        self.config.options.c.lanes = lanes;
        self
    }

    /// Gate each kernel's items in the Rust module and its C ABI behind a Cargo feature of
    /// the kernel's name (shared entry points behind `common`) and write
    /// `<robot>_features.json` (each kernel's feature, the kernels it calls, its weight), so
    /// that a loader can compile a large robot's kernels in several crates at once (default
    /// off; `grid_gen.load` turns it on).
    pub fn kernel_features(&mut self, on: bool) -> &mut Self {
        self.config.options.rust.kernel_features = on;
        self.config.options.c.kernel_features = on;
        self
    }

    /// Refuse URDFs with warnings (such as physically implausible inertias, or a `<mimic>`
    /// naming an unknown joint): the build fails with every diagnostic. Default `false`:
    /// warnings are printed as `cargo:warning=` lines and generation goes on.
    pub fn strict(&mut self, strict: bool) -> &mut Self {
        self.config.strict = strict;
        self
    }

    /// Most statements per generated function (default 2500): lower compiles faster per
    /// function, higher gives the optimiser more room.
    pub fn chunk_size(&mut self, statements: usize) -> &mut Self {
        self.config.options.rust.chunk = statements.max(1);
        self
    }

    /// Also emit the Rust module's `avx512` copy, dispatched first on CPUs with AVX-512 F and
    /// VL (default off: half again the module's size and compile time for 5-12% on the
    /// gradients of an AVX-512 CPU; results bit-identical to the `fma` copy).
    pub fn avx512(&mut self, avx512: bool) -> &mut Self {
        self.config.options.rust.avx512 = avx512;
        self
    }

    /// Which machine-code copies the Rust module holds (default [`Copies::Dispatch`]: a
    /// portable one and an AVX2+FMA one, chosen per call). A library compiled for the
    /// machine it runs on needs one: [`Copies::host`] compiles about 4x faster.
    ///
    /// [`Copies::Dispatch`]: crate::back::rust::Copies::Dispatch
    /// [`Copies::host`]: crate::back::rust::Copies::host
    pub fn copies(&mut self, copies: crate::back::rust::Copies) -> &mut Self {
        self.config.options.rust.copies = copies;
        self
    }

    /// Do not print `cargo:` directives (`rerun-if-changed`, and `warning` for each URDF
    /// warning), for use outside build scripts.
    pub fn quiet(&mut self, quiet: bool) -> &mut Self {
        self.quiet = quiet;
        self
    }

    /// Reads the URDF, generates the selected targets' files, writes each if its contents
    /// changed, and returns their paths in [`Target::ALL`] order. In a build script this
    /// prints `cargo:rerun-if-changed=<urdf>` and a `cargo:warning=` line per line of each
    /// URDF warning (cargo's protocol, the only output of the library) unless
    /// [`Builder::quiet`].
    pub fn compile(&self) -> Result<Vec<PathBuf>, BuildError> {
        if self.config.options.targets.is_empty() {
            return Err(BuildError::NoTargets);
        }
        if self.config.urdf.as_os_str().is_empty() {
            return Err(BuildError::NoUrdf);
        }
        let out_dir = match &self.out_dir {
            Some(d) => d.clone(),
            None => std::env::var_os("OUT_DIR").map(PathBuf::from).ok_or(BuildError::NoOutDir)?,
        };
        if let Some(name) = &self.file_name {
            if name.contains(['/', '\\']) || name.starts_with('.') || !name.ends_with(".rs") {
                return Err(BuildError::BadFileName(name.clone()));
            }
        }
        let mut cargo = vec![format!("cargo:rerun-if-changed={}", self.config.urdf.display())];
        if let Some(scene) = &self.config.scene {
            cargo.push(format!("cargo:rerun-if-changed={}", scene.display()));
        }
        let generated = self.config.generate();
        if let Ok((loaded, _)) = &generated {
            cargo.extend(cargo_warnings(&loaded.urdf_path, &loaded.urdf_text, &loaded.warnings));
        }
        if !self.quiet {
            // Cargo's build-script protocol: the only place the library prints.
            for line in cargo {
                println!("{line}");
            }
        }
        let (_, mut files) = generated.map_err(BuildError::Config)?;
        if let (Some(name), Some(rust)) =
            (&self.file_name, files.iter_mut().find(|f| f.name.ends_with(".rs")))
        {
            rust.name = name.clone();
        }
        let written = write_files(&out_dir, &files, false)
            .map_err(|e| BuildError::Write(out_dir.clone(), e))?;
        Ok(written.into_iter().map(|(path, _)| path).collect())
    }
}

/// The URDF's warnings as `cargo:warning=` lines, which cargo shows to the user (one line
/// each); without them a build script would hide what `grid-gen info` reports.
fn cargo_warnings(path: &str, text: &str, warnings: &[crate::Diagnostic]) -> Vec<String> {
    warnings
        .iter()
        .flat_map(|w| {
            w.render_plain(path, text)
                .lines()
                .map(|l| format!("cargo:warning={l}"))
                .collect::<Vec<_>>()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_scene_reaches_the_generated_module() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
        let out =
            std::env::temp_dir().join(format!("grid-gen-builder-scene-{}", std::process::id()));
        let written = crate::Builder::new()
            .urdf(format!("{root}/robots/grid_iiwa.urdf"))
            .scene(format!("{root}/examples/scenes/iiwa_wrist_locked.toml"))
            .out_dir(&out)
            .quiet(true)
            .compile()
            .unwrap();
        let code = std::fs::read_to_string(&written[0]).unwrap();
        assert!(
            code.contains("NV: usize = 4")
                && code.contains("pub fn fd_grad<")
                && !code.contains("pub fn minv<")
        );
        assert!(code.contains("// source: grid_iiwa.urdf in scene iiwa_wrist_locked.toml"));
        let bad = crate::Builder::new()
            .urdf(format!("{root}/robots/grid_iiwa.urdf"))
            .scene("/nonexistent.toml")
            .out_dir(&out)
            .quiet(true)
            .compile();
        assert!(bad.unwrap_err().to_string().contains("cannot read /nonexistent.toml"));
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn floating_base_reaches_the_generated_module() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
        let out =
            std::env::temp_dir().join(format!("grid-gen-builder-floating-{}", std::process::id()));
        let written = crate::Builder::new()
            .urdf(format!("{root}/robots/grid_hyq.urdf"))
            .floating_base(true)
            .out_dir(&out)
            .quiet(true)
            .compile()
            .unwrap();
        let code = std::fs::read_to_string(&written[0]).unwrap();
        assert!(
            code.contains("NV: usize = 18")
                && code.contains("NQ: usize = 19")
                && code.contains("q: &[T; NQ]")
                && code.contains("qd: &[T; NV]")
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// `step_at_run_time` leaves dt to the caller even over a scene that folds one; `step`
    /// folds it.
    #[test]
    fn a_run_time_dt_reaches_the_generated_module() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
        let out = std::env::temp_dir().join(format!("grid-gen-builder-dt-{}", std::process::id()));
        let compile = |runtime: bool| {
            let mut b = crate::Builder::new();
            b.urdf(format!("{root}/robots/grid_hyq.urdf"))
                .scene(format!("{root}/examples/scenes/hyq_step_floating.toml"))
                .out_dir(&out)
                .quiet(true);
            if runtime {
                b.step_at_run_time(crate::model::Scheme::ExplicitEuler);
            }
            let written = b.compile().unwrap();
            std::fs::read_to_string(&written[0]).unwrap()
        };
        let (folded, runtime) = (compile(false), compile(true));
        assert!(folded.contains("pub const DT: f64 = 0.01;"), "the scene's dt folds");
        assert!(!runtime.contains("pub const DT") && runtime.contains("dt: &[T; 1]"));
        assert!(runtime.contains("pub const STEP_SCHEME: &str = \"explicit_euler\";"));
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn forces_reach_the_generated_module() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
        let out =
            std::env::temp_dir().join(format!("grid-gen-builder-forces-{}", std::process::id()));
        let urdf = format!("{root}/robots/grid_iiwa.urdf");
        let compile = |derivatives: bool| {
            let written = crate::Builder::new()
                .urdf(&urdf)
                .external_forces(&["iiwa_joint_7"])
                .external_force_derivatives(derivatives)
                .contacts(&[("iiwa_link_7", crate::model::ContactKind::Wrench)])
                .out_dir(&out)
                .quiet(true)
                .compile()
                .unwrap();
            std::fs::read_to_string(&written[0]).unwrap()
        };
        let code = compile(true);
        assert!(
            code.contains("pub const NLAMBDA: usize = 6;")
                && code.contains("[(\"iiwa_link_7\", \"wrench\")]")
        );
        assert!(
            code.contains("fext: &[T; 6 * NFEXT],")
                && code.contains("lambda: &[T; NLAMBDA]")
                && code.contains("dqdd_dfext")
                && code.contains("dqdd_dlambda")
        );
        let code = compile(false);
        assert!(
            !code.contains("dqdd_dfext") && code.contains("dqdd_dlambda"),
            "no fext derivatives when asked"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn frames_reach_the_generated_module() {
        let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../..");
        let out =
            std::env::temp_dir().join(format!("grid-gen-builder-frames-{}", std::process::id()));
        let urdf = format!("{root}/robots/ur5.urdf");
        let written = crate::Builder::new()
            .urdf(&urdf)
            .frames(&["tool0"])
            .reference_frame(crate::model::ReferenceFrame::Local)
            .out_dir(&out)
            .quiet(true)
            .compile()
            .unwrap();
        let code = std::fs::read_to_string(&written[0]).unwrap();
        assert!(
            code.contains("pub const FRAME_NAMES: [&str; NF] = [\"tool0\"]")
                && code.contains("REFERENCE_FRAME: &str = \"local\"")
        );
        assert!(code.contains("pub fn frame_jacobian<T: Real>(q: &[T; NV]) -> [[[T; NV]; 6]; NF]"));
        let bad = crate::Builder::new()
            .urdf(&urdf)
            .frames(&["tool1"])
            .out_dir(&out)
            .quiet(true)
            .compile()
            .unwrap_err()
            .to_string();
        assert!(
            bad.contains("`tool1`, which is not a link of this robot")
                && bad.contains("closest frames: tool0"),
            "{bad}"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    #[test]
    fn urdf_warnings_become_cargo_warning_lines() {
        let path =
            concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/diagnostics/mimic_unknown.urdf");
        let text = std::fs::read_to_string(path).unwrap();
        let (_, warnings) =
            crate::Model::from_urdf_str("mimic_unknown.urdf", &text, false).unwrap();
        let lines = super::cargo_warnings("mimic_unknown.urdf", &text, &warnings);
        assert!(
            lines[0].starts_with("cargo:warning=mimic_unknown.urdf:4:")
                && lines[0].ends_with("warning: joint `j1` mimics unknown joint `j0`"),
            "{lines:?}"
        );
        assert!(
            lines.len() > 1
                && lines.iter().all(|l| l.starts_with("cargo:warning=") && !l.contains('\n')),
            "{lines:?}"
        );
    }
}
