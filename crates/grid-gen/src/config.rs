//! One description of a generation job, which the CLI, `Builder` and the Python package all
//! build: the robot, its scene and the caller's changes to it, and every backend's
//! settings. Loading it is the one place where a scene file and the caller's settings meet.

use std::path::{Path, PathBuf};

use crate::diagnostic::{Diagnostic, LoadError};
use crate::generate::{self, GenerateError, GeneratedFile, Options};
use crate::ir::KernelKind;
use crate::model::{Model, DEFAULT_GRAVITY};
use crate::scene::{Scene, SceneError, SceneOverrides};

/// What to generate, and from what.
#[derive(Clone, Debug, Default)]
pub struct Config {
    /// The robot description.
    pub urdf: PathBuf,
    /// A scene file (TOML; see [`crate::scene`]).
    pub scene: Option<PathBuf>,
    /// The caller's changes to the scene; each replaces the scene file's value.
    pub overrides: SceneOverrides,
    /// The kernels to generate, replacing the scene's `outputs` (default: every kernel the
    /// robot has).
    pub kernels: Option<Vec<KernelKind>>,
    /// Refuse URDFs with warnings.
    pub strict: bool,
    /// The caller's name for its settings (`load` for the Python package): when set, a
    /// setting in [`Self::overrides`] that the scene file also sets is an error naming both
    /// (the keyword and the file), rather than the caller's value replacing the file's.
    pub exclusive: Option<String>,
    /// The lowering's and the backends' settings. Its `gravity` and `lower.kernels` are
    /// not read: [`Loaded::options`] sets them from the merged scene.
    pub options: Options,
}

/// A robot loaded by a [`Config`], with what the caller needs to report on it.
#[derive(Clone, Debug)]
pub struct Loaded {
    pub model: Model,
    /// The scene file's contents with the caller's changes applied.
    pub scene: Scene,
    /// The kernels to generate: the caller's, else the scene's, else `None` (all).
    pub kernels: Option<Vec<KernelKind>>,
    /// The URDF's warnings (rendered against `urdf_text`).
    pub warnings: Vec<Diagnostic>,
    /// The URDF's path as diagnostics show it.
    pub urdf_path: String,
    pub urdf_text: String,
    /// The files read (URDF, then scene), for `cargo:rerun-if-changed`.
    pub inputs: Vec<PathBuf>,
}

/// Why a [`Config`] could not be loaded or generated.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {1}", path = .0.display())]
    Read(PathBuf, std::io::Error),
    #[error("{}: the file is not UTF-8 text", .0.display())]
    NotUtf8(PathBuf),
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// The robot description has errors, each located in the URDF.
    #[error(transparent)]
    Load(Box<LoadError>),
    #[error(transparent)]
    Generate(#[from] GenerateError),
    #[error(
        "{caller}({key}=...) and the scene file `{scene}` both set {what}; give it in one place"
    )]
    Clash { caller: String, key: &'static str, what: &'static str, scene: String },
    #[error("{caller}(dt=...) times a step, and none is asked for: give step= too (\"semi_implicit_euler\", \"explicit_euler\" or \"rk4\")")]
    DtWithoutStep { caller: String },
    /// A setting the caller gave that no scene could hold, named as the caller gave it.
    #[error("{0}")]
    Setting(String),
}

fn read(path: &Path) -> Result<String, ConfigError> {
    let bytes = std::fs::read(path).map_err(|e| ConfigError::Read(path.to_path_buf(), e))?;
    String::from_utf8(bytes).map_err(|_| ConfigError::NotUtf8(path.to_path_buf()))
}

impl Config {
    pub fn new(urdf: impl AsRef<Path>) -> Self {
        Config { urdf: urdf.as_ref().to_path_buf(), ..Config::default() }
    }

    /// Reads the URDF and the scene, applies the overrides, and builds the model.
    pub fn load(&self) -> Result<Loaded, ConfigError> {
        let mut inputs = vec![self.urdf.clone()];
        let (mut scene, scene_path) = match &self.scene {
            None => (Scene::default(), String::new()),
            Some(p) => {
                inputs.push(p.clone());
                let shown = p.display().to_string();
                (Scene::parse(&shown, &read(p)?)?, shown)
            }
        };
        // Who gives the overrides: a caller that named itself gives keywords.
        let mut overrides = self.overrides.clone();
        if let Some(caller) = &self.exclusive {
            overrides.source = crate::settings::Source::Keywords(caller.clone());
        }
        if let Some(g) = overrides.gravity {
            if g.iter().any(|x| !x.is_finite()) {
                let whence = overrides.source.name("gravity");
                return Err(ConfigError::Setting(format!("{whence}: gravity {g:?} is not finite")));
            }
        }
        if let Some(tol) = overrides.round_angles {
            let whence = overrides.source.name("round_angles");
            crate::scene::check_round_angles(tol)
                .map_err(|message| ConfigError::Setting(format!("{whence}: {message}")))?;
        }
        if let Some(caller) = &self.exclusive {
            if let Some((key, what)) = scene.clash(&self.overrides) {
                let (caller, scene) = (caller.clone(), scene_path.clone());
                return Err(ConfigError::Clash { caller, key, what, scene });
            }
            let o = &self.overrides;
            if o.dt.is_some() && o.scheme.is_none() && scene.step.is_none() {
                return Err(ConfigError::DtWithoutStep { caller: caller.clone() });
            }
        }
        scene.apply(&overrides);
        let kernels = match &self.kernels {
            Some(k) => Some(KernelKind::ALL.into_iter().filter(|x| k.contains(x)).collect()),
            None => scene
                .kernels()
                .map_err(|message| SceneError { path: scene_path.clone(), message })?,
        };
        let urdf_text = read(&self.urdf)?;
        let urdf_path = self.urdf.display().to_string();
        let (model, warnings) =
            Model::from_urdf_str_in_scene(&urdf_path, &urdf_text, self.strict, &scene, &scene_path)
                .map_err(|e| ConfigError::Load(Box::new(e)))?;
        Ok(Loaded { model, scene, kernels, warnings, urdf_path, urdf_text, inputs })
    }

    /// Loads the robot and generates every requested file (nothing is written).
    pub fn generate(&self) -> Result<(Loaded, Vec<GeneratedFile>), ConfigError> {
        let loaded = self.load()?;
        let files = generate::generate(&loaded.model, &loaded.options(&self.options))?;
        Ok((loaded, files))
    }
}

impl Loaded {
    /// Gravity in the root frame: the caller's, else the scene's, else (0, 0, −9.81).
    pub fn gravity(&self) -> [f64; 3] {
        self.scene.gravity.unwrap_or(DEFAULT_GRAVITY)
    }

    /// `base` with this robot's gravity and kernels.
    pub fn options(&self, base: &Options) -> Options {
        let mut options = base.clone();
        options.gravity = self.gravity();
        if let Some(k) = &self.kernels {
            options.lower.kernels = k.clone();
        }
        options
    }
}
