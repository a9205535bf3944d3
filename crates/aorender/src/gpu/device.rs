//! An opened adapter with the pipelines compiled on it: what every session on the
//! adapter shares.

use super::context::GpuContext;
use super::pipeline::Pipelines;
use crate::error::Result;

/// An adapter's context and its compiled pipelines.
pub struct GpuDevice {
    /// The adapter, device and queue.
    pub ctx: GpuContext,
    /// Pipelines compiled on it so far.
    pub pipelines: Pipelines,
}

impl GpuDevice {
    /// Wraps an opened context (after any test limits were set on it).
    pub fn new(ctx: GpuContext) -> GpuDevice {
        GpuDevice { ctx, pipelines: Pipelines::default() }
    }

    /// Opens the best adapter, or the first whose name contains `name_filter`
    /// (case-insensitive): [`GpuContext::new`].
    pub fn open(name_filter: Option<&str>) -> Result<GpuDevice> {
        Ok(GpuDevice::new(GpuContext::new(name_filter)?))
    }
}
