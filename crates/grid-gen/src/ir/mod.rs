//! The kernel IR: the dynamics algorithms run symbolically over one robot into scalar
//! dataflow graphs, lowered once into a [`Module`] that every backend reads.
//!
//! `graph` (the hash-consing builder), `spatial` and `dynamics` (the algorithms) are
//! private to lowering; backends see [`Module`], [`Function`], the node types, and the
//! target-neutral [`schedule`].

mod dynamics;
mod graph;
mod kernel;
mod module;
pub mod schedule;
mod share;
mod spatial;
mod stats;
mod tangent;
mod validate;

pub(crate) use graph::mark_ancestors;
pub use graph::{Buffer, Id, Input, Node, Op, Stage};
pub use kernel::{Dims, Gradient, KernelKind, OutputSpec, Shape, Solve, UPacking};
pub use module::{
    lower, lower_function, Call, Calls, ColumnBlock, ColumnProgram, ColumnStep, ColumnStore,
    Contact, CoupledJoint, DenseProduct, EvalNumber, Function, LowerError, LowerOptions, Module,
    Operand, Output, Robot, SphericalJoint, CALLS_RNEA_GRAD_MIN_OPS, DEFAULT_MAX_NODES,
    LTDL_MAX_DEPTH,
};
pub(crate) use share::live_through;
pub use spatial::SNAP;
pub use stats::{stats, KernelStats, OpCounts, Skipped, Stats, STATS_MAX_NODES};
pub use validate::{validate, ValidationError};
