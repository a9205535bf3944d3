//! Opening a device: which kind renders ([`DeviceKind`]), an opened GPU adapter or the
//! CPU reference ([`Device`]), and the film budget a request on it is checked against.

use crate::error::Result;
use crate::gpu::{AdapterInfo, GpuDevice};
use crate::host_memory;
use crate::scene::{Scene, Settings};
use std::sync::Arc;

// The kind is named in `kinds`, below the checkpoint format that records it.
pub use crate::kinds::DeviceKind;

/// An opened device: an adapter with its device and compiled pipelines, or the CPU
/// reference. Cheap to clone; sessions on one device share its pipelines.
#[derive(Clone)]
pub struct Device(pub(super) Opened);

/// What an opened [`Device`] holds.
#[derive(Clone)]
pub(super) enum Opened {
    Gpu(Arc<GpuDevice>),
    Cpu(AdapterInfo),
}

impl Device {
    /// Opens the best GPU adapter (discrete, then integrated, virtual, CPU such as
    /// lavapipe), or the first whose name contains `adapter` (case-insensitive).
    pub fn gpu(adapter: Option<&str>) -> Result<Device> {
        Ok(Device(Opened::Gpu(Arc::new(GpuDevice::open(adapter)?))))
    }

    /// The CPU reference, on rayon's threads.
    pub fn cpu() -> Device {
        Device(Opened::Cpu(AdapterInfo {
            name: "cpu".into(),
            backend: "cpu".into(),
            device_type: "Cpu".into(),
            driver: format!("obvhs cwbvh, {} threads", rayon::current_num_threads()),
        }))
    }

    /// Opens a device of `kind` (`adapter` names the GPU adapter, as in [`Device::gpu`]).
    pub fn open(kind: DeviceKind, adapter: Option<&str>) -> Result<Device> {
        match kind {
            DeviceKind::Gpu => Device::gpu(adapter),
            DeviceKind::Cpu => Ok(Device::cpu()),
        }
    }

    /// A device on an opened GPU adapter (tests set limits on its context first).
    #[cfg(feature = "testing")]
    pub fn from_gpu(gpu: GpuDevice) -> Device {
        Device(Opened::Gpu(Arc::new(gpu)))
    }

    /// GPU or CPU.
    pub fn kind(&self) -> DeviceKind {
        match &self.0 {
            Opened::Gpu(_) => DeviceKind::Gpu,
            Opened::Cpu(_) => DeviceKind::Cpu,
        }
    }

    /// The adapter's name, backend, type and driver (`cpu` for the reference).
    pub fn info(&self) -> AdapterInfo {
        match &self.0 {
            Opened::Gpu(g) => g.ctx.description.clone(),
            Opened::Cpu(info) => info.clone(),
        }
    }

    /// Whether passes are timed on the adapter by timestamp queries (false on the CPU and
    /// on adapters without them).
    pub fn has_timestamps(&self) -> bool {
        match &self.0 {
            Opened::Gpu(g) => g.ctx.has_timestamps(),
            Opened::Cpu(_) => false,
        }
    }

    /// Host bytes a film of `slots` slots (pixels, or probe lanes) takes at a render's
    /// peak on this device, with samples in replicates or not ([`host_memory::film_bytes`]).
    pub fn film_bytes(&self, slots: u64, replicated: bool) -> u64 {
        // A GPU on a CPU adapter (lavapipe) keeps its device memory on the host.
        let cpu_adapter = self.kind() == DeviceKind::Gpu && self.info().device_type == "Cpu";
        host_memory::film_bytes(slots, replicated, cpu_adapter)
    }

    /// Checks an image of `settings` of `scene` against the film budget before anything
    /// is built or made: [`Error::FilmBudget`](crate::Error::FilmBudget) naming the scene's
    /// file, the bytes needed and the budget ([`host_memory::film_budget`]).
    pub fn check_image_budget(&self, scene: &Scene, settings: &Settings) -> Result<()> {
        let what = format!("a {}x{} image", settings.width, settings.height);
        let slots = settings.width as u64 * settings.height as u64;
        self.check_film_budget(&scene.source(), what, slots, settings.sampling.replicate_samples() >= 2, None)
    }

    /// Fails with [`Error::FilmBudget`](crate::Error::FilmBudget) naming `scene` when a film
    /// of `slots` slots (`what`, in words) is past `budget` bytes (`None`:
    /// [`host_memory::film_budget`]).
    pub(crate) fn check_film_budget(
        &self,
        scene: &std::path::Path,
        what: String,
        slots: u64,
        replicated: bool,
        budget: Option<u64>,
    ) -> Result<()> {
        let budget = match budget {
            Some(bytes) => host_memory::FilmBudget { bytes, basis: "set for the session".into() },
            None => host_memory::film_budget()?,
        };
        host_memory::check_film(scene, what, self.film_bytes(slots, replicated), &budget)
    }

    /// The GPU adapter, if this is one.
    #[cfg(feature = "testing")]
    pub fn as_gpu(&self) -> Option<&Arc<GpuDevice>> {
        match &self.0 {
            Opened::Gpu(g) => Some(g),
            Opened::Cpu(_) => None,
        }
    }
}
