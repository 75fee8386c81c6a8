//! Numerics over the IR, beside it rather than in it: double-double numbers for the
//! high-precision reference value of a graph, and the mixed-precision plan (which nodes
//! run in f64 so that the others can run in f32).

pub mod precise;
pub mod precision;

pub use precise::Dd;
