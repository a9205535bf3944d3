//! The commands other than the benchmark, one module each.

pub mod accuracy;
pub mod bake;
pub mod compare;
pub mod merge;
pub mod probe;
pub mod render;
