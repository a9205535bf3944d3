//! An opened adapter with the pipelines compiled on it: what every session on the
//! adapter shares.

use super::context::GpuContext;
use super::pipeline::Pipelines;
use super::stats::StatsPipelines;
use crate::error::Result;

/// An adapter's context and its compiled pipelines (dropped before the context, whose
/// device they were made on).
pub struct GpuDevice {
    /// Pipelines compiled on it so far.
    pub pipelines: Pipelines,
    /// The statistics kernels, compiled when a render first keeps its sums on the device.
    stats: std::sync::Mutex<Option<StatsPipelines>>,
    /// The adapter, device and queue.
    pub ctx: GpuContext,
}

impl GpuDevice {
    /// Wraps an opened context (after any test limits were set on it).
    pub fn new(ctx: GpuContext) -> GpuDevice {
        GpuDevice { pipelines: Pipelines::default(), ctx, stats: Default::default() }
    }

    /// The statistics kernels (`stats.wgsl`), compiled on first use.
    pub fn stats_pipelines(&self) -> Result<StatsPipelines> {
        let mut cached = self.stats.lock().unwrap_or_else(|e| e.into_inner());
        if cached.is_none() {
            *cached = Some(StatsPipelines::new(&self.ctx)?);
        }
        Ok(cached.clone().expect("compiled above"))
    }

    /// Opens the best adapter, or the first whose name contains `name_filter`
    /// (case-insensitive): [`GpuContext::new`].
    pub fn open(name_filter: Option<&str>) -> Result<GpuDevice> {
        Ok(GpuDevice::new(GpuContext::new(name_filter)?))
    }
}
