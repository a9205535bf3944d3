//! The CPU reference renderer: the same samples as the GPU kernel, traced with obvhs's
//! own traversal, to check the GPU against.

pub mod tracer;

pub use tracer::CpuTracer;
