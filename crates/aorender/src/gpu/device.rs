//! An opened adapter with the pipelines compiled on it: what every session on the
//! adapter shares.

use super::context::GpuContext;
use super::pipeline::Pipelines;
use crate::error::Result;

/// An adapter's context and its compiled pipelines (dropped before the context, whose
/// device they were made on).
pub struct GpuDevice {
    /// Pipelines compiled on it so far.
    pub pipelines: Pipelines,
    /// The adapter, device and queue.
    pub ctx: GpuContext,
}

impl GpuDevice {
    /// Wraps an opened context (after any test limits were set on it).
    pub fn new(ctx: GpuContext) -> GpuDevice {
        GpuDevice { pipelines: Pipelines::default(), ctx }
    }

    /// Opens the best adapter, or the first whose name contains `name_filter`
    /// (case-insensitive): [`GpuContext::new`].
    pub fn open(name_filter: Option<&str>) -> Result<GpuDevice> {
        Ok(GpuDevice::new(GpuContext::new(name_filter)?))
    }
}
