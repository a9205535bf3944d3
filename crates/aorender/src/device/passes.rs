//! The one interface the pass loop drives, whatever the device: a request's film, one
//! block of samples at a time ([`Passes`]), and what a pass did ([`PassReport`]).

use crate::error::{Error, Result};
use crate::film::{BlockSums, ExactSums};
use crate::gpu::stats::{AdaptQuery, AdaptSums, CheckQuery, CheckSums, Stop};

/// What a pass did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PassReport {
    /// AO rays traced.
    pub ao_rays: u64,
    /// The pass's time on the adapter by timestamp queries, where it has them.
    pub gpu_seconds: Option<f64>,
}

/// A request's film on a device, one block of samples at a time: the one interface the
/// pass loop drives, whatever the device.
pub(crate) trait Passes {
    /// Adds samples (or probe rounds) `first .. first + count` of every slot to the
    /// block.
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport>;
    /// The most samples (or probe rounds) one pass may take on this device: the pass
    /// loop sizes no pass above it.
    fn max_pass_samples(&self) -> u32;
    /// The block's sums so far.
    fn read(&mut self) -> Result<BlockSums>;
    /// The block's sums, leaving the block empty.
    fn take(&mut self) -> Result<BlockSums>;
    /// Replaces the block's sums (from a checkpoint).
    fn load(&mut self, block: &BlockSums) -> Result<()>;
    /// Bytes of device memory the film and its buffers take (0 on the CPU).
    fn device_bytes(&self) -> u64;
    /// Bytes read back from the device since the last call (0 on the CPU).
    fn take_readback_bytes(&mut self) -> u64;
    /// Times the host has waited for the device so far, every request on it counted (0 on
    /// the CPU): [`crate::gpu::context::GpuContext::round_trips`].
    fn round_trips(&self) -> u64 {
        0
    }
    /// Stops sampling the slots marked in `inactive` (from the next pass on; an empty
    /// mask samples every slot). Their sums read back as empty. Called while the block
    /// holds no samples: right after a take, or before a checkpoint's block is loaded.
    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()>;
    /// Whether the device can keep the exact sums itself ([`Passes::fold`]): a GPU's
    /// image film. The CPU reference's exact sums are in host memory already.
    fn keeps_sums(&self) -> bool {
        false
    }
    /// Replaces the device's exact sums and counts with `exact`'s (`samples` a pixel
    /// where it does not count them per pixel).
    fn write_sums(&mut self, _exact: &ExactSums, _samples: u32) -> Result<()> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// Adds the block of `taken` samples to the device's exact sums and the counts of
    /// the pixels it holds, leaving the block empty; `replicate`: the block is one whole
    /// replicate, whose square is added to the replicates' squares.
    fn fold(&mut self, _replicate: bool, _taken: u32) -> Result<()> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// The image-level sums of an adaptive render's decisions over the device's sums and
    /// counts, and the first slot that received a sample out of range.
    fn adapt_check(&mut self, _query: AdaptQuery, _exponents: (i32, i32)) -> Result<(AdaptSums, Option<u32>)> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// Counts the pixels still sampled whose replicates reach σ̃ × `per_sigma` and stops
    /// them as `stop` says (over the whole film: [`Stop::IfAnyGoesOn`] looks at every
    /// pixel); how many have their share, and how many go on.
    fn allocate(
        &mut self,
        _query: AdaptQuery,
        _exponents: (i32, i32),
        _per_sigma: f32,
        _stop: Stop,
    ) -> Result<(u32, u32)> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// Each pixel's samples, complete replicates and whether it is stopped, as the device
    /// counts them.
    fn read_counts(&mut self) -> Result<Vec<(u32, u32, bool)>> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// The image-level sums of the stopping rule over the device's exact sums, and the
    /// first slot that received a sample out of range.
    fn check(&mut self, _query: CheckQuery, _exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// Reads the device's exact sums into `exact` (the replicates' squares too where
    /// `replicates`); returns the first slot that received a sample out of range.
    fn read_sums(&mut self, _exact: &mut ExactSums, _replicates: bool) -> Result<Option<u32>> {
        Err(Error::settings("this device does not keep exact sums"))
    }
}
