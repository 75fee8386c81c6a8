//! grid-gen: robot-specific rigid-body dynamics and analytical gradients from a URDF.
//!
//! The pipeline is `URDF --parse+validate--> Model --> reference dynamics` (and, in later
//! stages, the kernel IR and its emitters). The library never prints and never exits;
//! every failure is a value carrying located [`Diagnostic`]s.

pub mod builder;
pub mod diagnostic;
pub mod emit;
pub mod eval;
pub mod generate;
pub mod info;
pub mod ir;
pub mod model;
pub mod reference;
pub mod spatial;
pub mod urdf;

pub use builder::{BuildError, Builder};
pub use diagnostic::{Diagnostic, LoadError, Severity};
pub use model::Model;
