//! Opening a device: which kind renders ([`DeviceKind`]), an opened GPU adapter or the
//! CPU reference ([`Device`]), one opening on a thread of its own while the caller loads
//! a scene ([`DeviceOpening`]), and the film budget a request on it is checked against.

use crate::error::{Error, Result};
use crate::gpu::{AdapterInfo, GpuDevice};
use crate::host_memory;
use crate::scene::{Scene, Settings};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

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

    /// Starts opening a device of `kind` on a thread of its own ([`DeviceOpening`]), so that
    /// the caller loads its scene and builds the BVH meanwhile: opening an adapter needs
    /// nothing of the scene, and neither do the statistics kernels that keep an image's
    /// exact sums on the device, which that thread also compiles, and runs once over no
    /// pixels, where `ready` says the device is for images. The CPU reference opens at
    /// once, on no thread.
    pub fn open_beside(kind: DeviceKind, adapter: Option<&str>, ready: Ready) -> DeviceOpening {
        let start = Instant::now();
        let state = match kind {
            DeviceKind::Cpu => Beside::Done(Ok(Device::cpu()), 0.0, 0.0),
            DeviceKind::Gpu => {
                let adapter = adapter.map(str::to_owned);
                let spawned = std::thread::Builder::new().name("aorender-device".into()).spawn(move || {
                    let device = Device::gpu(adapter.as_deref());
                    let opened = Instant::now();
                    let device = match (device, ready) {
                        (Ok(Device(Opened::Gpu(gpu))), Ready::Images { target, adaptive }) => {
                            gpu.warm_image_kernels(target, adaptive).map(|_| Device(Opened::Gpu(gpu)))
                        }
                        (other, _) => other,
                    };
                    (device, start.elapsed().as_secs_f64(), opened.elapsed().as_secs_f64())
                });
                match spawned {
                    Ok(handle) => Beside::Running(handle),
                    Err(e) => {
                        let error = Error::Gpu(format!("cannot start a thread to open the device: {e}"));
                        Beside::Done(Err(error), 0.0, 0.0)
                    }
                }
            }
        };
        DeviceOpening { kind, state: Some(state) }
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

    /// Times the host has waited for the device so far (submissions waited on and buffer
    /// mappings: its round trips), every session and request on it counted; 0 on the CPU.
    pub fn round_trips(&self) -> u64 {
        match &self.0 {
            Opened::Gpu(g) => g.ctx.round_trips(),
            Opened::Cpu(_) => 0,
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

/// What a device opened beside the scene ([`Device::open_beside`]) is readied for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ready {
    /// Points (probes and bakes): the adapter alone.
    Points,
    /// Images: the kernels that keep the exact sums on the device, with `target` those of
    /// an error target's checks and with `adaptive` those of adaptive decisions, compiled
    /// and run once.
    Images {
        /// The render has an error target.
        target: bool,
        /// The render samples adaptively.
        adaptive: bool,
    },
}

/// A device being opened on a thread of its own ([`Device::open_beside`]). Dropped before
/// [`DeviceOpening::wait`] (the caller failed first), it still waits for the thread and
/// closes the device there and then: no thread outlives it, and no device is made or
/// destroyed while the process exits (which NVIDIA's Vulkan driver does not survive,
/// gfx-rs/wgpu#8365).
pub struct DeviceOpening {
    kind: DeviceKind,
    /// `None` once waited for.
    state: Option<Beside>,
}

/// Where an opening stands.
enum Beside {
    /// On its thread, which returns the device, the seconds it took and, of those, the
    /// seconds compiling the statistics kernels.
    Running(JoinHandle<(Result<Device>, f64, f64)>),
    /// Opened (or failed) already, in these seconds, these compiling.
    Done(Result<Device>, f64, f64),
}

/// A device opened beside other work ([`DeviceOpening::wait`]), and what that took.
pub struct OpenedDevice {
    /// The device.
    pub device: Device,
    /// Seconds the opening took, from [`Device::open_beside`] to the device, its
    /// statistics kernels compiled.
    pub seconds: f64,
    /// Of `seconds`, those compiling the statistics kernels.
    pub compile_seconds: f64,
    /// Of `seconds`, those the caller waited for it: the rest ran beside its work.
    pub waited_seconds: f64,
}

impl DeviceOpening {
    /// The kind of device being opened.
    pub fn kind(&self) -> DeviceKind {
        self.kind
    }

    /// The device, where it has opened by now (without waiting): checks that need it
    /// can run early when it is there, and again once it is waited for when it was not.
    pub fn ready(&mut self) -> Option<&Device> {
        if let Some(Beside::Running(handle)) = &self.state
            && handle.is_finished()
            && let Some(state) = self.state.take()
        {
            let (device, seconds, compile) = finish(state);
            self.state = Some(Beside::Done(device, seconds, compile));
        }
        match &self.state {
            Some(Beside::Done(Ok(device), _, _)) => Some(device),
            _ => None,
        }
    }

    /// Waits for the device (at once where it is open already): the opening's error, if
    /// it failed, or the device and the seconds it took and was waited for.
    pub fn wait(mut self) -> Result<OpenedDevice> {
        let waiting = Instant::now();
        let (device, seconds, compile_seconds) =
            self.state.take().map_or_else(|| (Err(Error::Gpu("no device".into())), 0.0, 0.0), finish);
        let waited_seconds = waiting.elapsed().as_secs_f64().min(seconds);
        Ok(OpenedDevice { device: device?, seconds, compile_seconds, waited_seconds })
    }
}

impl Drop for DeviceOpening {
    fn drop(&mut self) {
        // The device, or its error, goes with the opening that nobody waited for.
        if let Some(state) = self.state.take() {
            drop(finish(state));
        }
    }
}

/// The opening's device (or error) and its seconds, its thread joined.
fn finish(state: Beside) -> (Result<Device>, f64, f64) {
    match state {
        Beside::Done(device, seconds, compile) => (device, seconds, compile),
        Beside::Running(handle) => handle
            .join()
            .unwrap_or_else(|_| (Err(Error::Gpu("opening the device failed: its thread panicked".into())), 0.0, 0.0)),
    }
}
