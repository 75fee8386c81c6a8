//! grid-gen: robot-specific rigid-body dynamics and analytical gradients from a URDF.
//!
//! The pipeline is `URDF --parse+validate--> Model --ir::lower--> ir::Module --> back/*`,
//! with the reference dynamics (`reference`) beside it as the oracle. The library never
//! prints and never exits; every failure is a value carrying located [`Diagnostic`]s.

pub mod accuracy;
pub mod back;
pub mod builder;
pub mod config;
pub mod datapath;
pub mod diagnostic;
pub mod eval;
pub mod generate;
pub mod info;
pub mod ir;
mod load;
pub mod model;
pub mod numerics;
mod parallel;
pub mod reference;
pub mod scene;
pub mod settings;
pub mod spatial;
pub mod timing;
pub mod tools;
pub mod urdf;

pub use builder::{BuildError, Builder};
pub use config::{Config, ConfigError, Loaded};
pub use diagnostic::{Diagnostic, LoadError, Severity};
pub use model::Model;
pub use scene::{ContactEntry, MimicMode, Scene, SceneOverrides};
