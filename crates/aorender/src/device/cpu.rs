//! The CPU reference's films: an image or probe points traced by [`CpuTracer`] into the
//! integers the GPU keeps, in the same quanta ([`CpuTarget`]).

use super::passes::{PassReport, Passes};
use crate::cpu::CpuTracer;
use crate::error::{Error, Result};
use crate::film::BlockSums;
use crate::probe::Probe;
use crate::scene::{Camera, Settings};
use std::sync::Arc;

/// The most samples a pass of the CPU reference takes: the GPU's cap
/// (`gpu::MAX_PASS_SAMPLES`), so that a fixed pass size cuts a render into the same passes
/// on both devices and their statistics compare pass for pass.
pub(super) const CPU_MAX_PASS_SAMPLES: u32 = 1024;

/// What the CPU reference traces into a film: an image, or probe points.
pub(super) trait CpuWork {
    /// Adds samples (or probe rounds) `first .. first + count` to `sums`, in the quanta
    /// of samples of bound 2^`e`, leaving the slots marked in `inactive` (empty: none);
    /// returns the AO rays traced.
    fn pass(&self, sums: &mut BlockSums, e: i32, first: u32, count: u32, inactive: &[bool]) -> u64;
}

/// An image on the CPU reference.
pub(super) struct CpuImage {
    pub(super) tracer: Arc<CpuTracer>,
    pub(super) camera: Camera,
    pub(super) settings: Settings,
}

impl CpuWork for CpuImage {
    fn pass(&self, sums: &mut BlockSums, e: i32, first: u32, count: u32, inactive: &[bool]) -> u64 {
        self.tracer.render_pass(&self.camera, &self.settings, sums, e, first, count, inactive)
    }
}

/// Probe points on the CPU reference; the film's slots are lanes × probes, or four a
/// probe with bent normals.
pub(super) struct CpuProbes {
    pub(super) tracer: Arc<CpuTracer>,
    pub(super) settings: Settings,
    pub(super) probes: Vec<Probe>,
    /// The sample sequence of probe k is point `first_point` + k's.
    pub(super) first_point: u32,
    pub(super) samples: u32,
    pub(super) lanes: u32,
    pub(super) bent_normals: bool,
}

impl CpuWork for CpuProbes {
    // Probe requests are not adaptive: every point is sampled.
    fn pass(&self, sums: &mut BlockSums, e: i32, first: u32, count: u32, _inactive: &[bool]) -> u64 {
        let (t, s, p, k) = (&self.tracer, &self.settings.sampling, &self.probes, self.first_point);
        if self.bent_normals {
            t.probe_bent_pass(s, p, k, self.samples, sums, e, first, count)
        } else {
            t.probe_pass(s, p, k, self.samples, self.lanes, sums, e, first, count)
        }
    }
}

/// A request on the CPU reference and its block's sums: the integers the GPU keeps, in
/// the same quanta.
pub(super) struct CpuTarget<W> {
    pub(super) work: W,
    pub(super) sums: BlockSums,
    /// The bound 2^e of the samples ([`value_exponent`](crate::film::value_exponent)).
    pub(super) e: i32,
    /// Slots not sampled (empty: none).
    pub(super) inactive: Vec<bool>,
}

impl<W: CpuWork> Passes for CpuTarget<W> {
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let rays = self.work.pass(&mut self.sums, self.e, first, count, &self.inactive);
        Ok(PassReport { ao_rays: rays, gpu_seconds: None })
    }

    fn max_pass_samples(&self) -> u32 {
        CPU_MAX_PASS_SAMPLES
    }

    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()> {
        self.inactive = inactive.to_vec();
        Ok(())
    }

    fn read(&mut self) -> Result<BlockSums> {
        Ok(self.sums.clone())
    }

    fn take(&mut self) -> Result<BlockSums> {
        let empty = BlockSums::new(self.sums.len());
        Ok(std::mem::replace(&mut self.sums, empty))
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        if block.len() != self.sums.len() || block.sum_sq.len() != block.sum.len() {
            return Err(Error::settings("the checkpoint's block does not fit the CPU reference's film"));
        }
        self.sums.clone_from(block);
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        0
    }

    fn take_readback_bytes(&mut self) -> u64 {
        0
    }
}
