//! Backends: each prints the kernel IR for one target and reads nothing but the IR and the
//! model's names.

pub mod names;
pub mod rust;
