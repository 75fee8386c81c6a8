//! The kernel IR: the dynamics algorithms run symbolically over one robot, as scalar
//! dataflow graphs that every backend prints.

pub mod dynamics;
pub mod graph;
pub mod kernel;
pub mod spatial;

pub use graph::{Graph, Id, Input, Node, Op, Stage};
pub use kernel::{build, stats, Kernel, KernelStats, OpCounts, Output, KERNELS};
