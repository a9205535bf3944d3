//! The two devices behind one interface: a GPU adapter (WGSL compute shaders through
//! wgpu) or the CPU reference. [`Device`] is an opened one; preparing a scene on it
//! ([`Prepared`]: BVH build and upload) and making a request's film on that ([`Passes`])
//! is all the rest of the engine asks of a device.

use crate::bvh::ploc::cwbvh_depth;
use crate::bvh::{BuildQuality, BvhLayout, GpuBvh, build_cwbvh};
use crate::cpu::CpuTracer;
use crate::error::{Error, Result};
use crate::film::{BlockSums, ExactSums, INACTIVE_SLOT_BITS};
use crate::gpu::stats::{CheckQuery, CheckSums};
use crate::gpu::{
    AdapterInfo, FrameUniforms, GeometryStorage, GpuDevice, GpuProbePoint, GpuScene, GpuTarget, Traversal,
};
use crate::host_memory;
use crate::probe::Probe;
use crate::scene::{Camera, Scene, Settings};
use std::sync::Arc;
use std::time::Instant;

/// Which kind of device renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum DeviceKind {
    /// WGSL compute shaders on a wgpu adapter.
    #[default]
    Gpu,
    /// The multi-threaded CPU reference.
    Cpu,
}

impl DeviceKind {
    /// The name used on the command line: `gpu` or `cpu`.
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Gpu => "gpu",
            DeviceKind::Cpu => "cpu",
        }
    }
}

/// An opened device: an adapter with its device and compiled pipelines, or the CPU
/// reference. Cheap to clone; sessions on one device share its pipelines.
#[derive(Clone)]
pub struct Device(Opened);

#[derive(Clone)]
enum Opened {
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
    /// is built or made: [`Error::FilmBudget`] naming the scene's file, the bytes needed
    /// and the budget ([`host_memory::film_budget`]).
    pub fn check_image_budget(&self, scene: &Scene, settings: &Settings) -> Result<()> {
        let what = format!("a {}x{} image", settings.width, settings.height);
        let slots = settings.width as u64 * settings.height as u64;
        self.check_film_budget(&scene.source(), what, slots, settings.sampling.replicate_samples() >= 2, None)
    }

    /// Fails with [`Error::FilmBudget`] naming `scene` when a film of `slots` slots
    /// (`what`, in words) is past `budget` bytes (`None`: [`host_memory::film_budget`]).
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

/// How the scene is prepared on a device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BvhOptions {
    /// obvhs's build preset.
    pub quality: BuildQuality,
    /// The node layout the GPU traverses (the CPU reference always traverses obvhs's
    /// CWBVH).
    pub layout: BvhLayout,
    /// Where the GPU kernel reads the geometry from; `None` is the adapter's preference
    /// ([`GeometryStorage::preferred`]).
    pub geometry_storage: Option<GeometryStorage>,
    /// How the GPU kernel's lanes share the rays; `None` is the adapter's preference where
    /// the scene allows it.
    pub traversal: Option<Traversal>,
}

/// What preparing a scene on a device took and holds.
#[derive(Clone, Debug)]
pub struct Setup {
    /// The adapter.
    pub adapter: AdapterInfo,
    /// The BVH layout traversed.
    pub bvh_layout: BvhLayout,
    /// Seconds to build the BVH, its conversion to the GPU's layout included.
    pub bvh_build_seconds: f64,
    /// Of those, seconds to convert obvhs's CWBVH to the GPU's layout (0 for BVH2 and on
    /// the CPU).
    pub bvh_convert_seconds: f64,
    /// Nodes of the BVH as traversed.
    pub bvh_nodes: usize,
    /// Levels of the BVH as traversed: its deepest inner node's, the root 1 (with
    /// instances, the top level's and the deepest mesh's added).
    pub bvh_depth: u32,
    /// Primitives the BVH leaves out as copies of others (a triangle or sphere with the
    /// same bits and albedo, 16 times or more): rays meet them as they meet the first.
    pub bvh_duplicates: usize,
    /// Seconds to upload the geometry (GPU) or to lay out the tracer's records (CPU).
    pub upload_seconds: f64,
    /// Bytes of the BVH as traversed: nodes and primitive records, as uploaded (GPU) or
    /// held by the tracer (CPU).
    pub bvh_bytes: u64,
    /// Bytes of device memory the geometry takes (GPU; 0 on the CPU).
    pub device_bytes: u64,
    /// Bindings holding the BVH nodes and the primitives (GPU; 0 on the CPU).
    pub geometry_bindings: u32,
    /// `buffers` or `textures` on the GPU, empty on the CPU.
    pub geometry_storage: &'static str,
    /// `per-lane` or `cooperative` on the GPU, empty on the CPU.
    pub traversal: &'static str,
}

/// A scene prepared on a device: its BVH built and uploaded, ready for requests.
pub(crate) enum Prepared {
    /// The geometry on the adapter (dropped before the adapter's device, last).
    Gpu { scene: GpuScene, dev: Arc<GpuDevice> },
    /// The CPU tracer.
    Cpu(Arc<CpuTracer>),
}

impl Prepared {
    /// Builds the BVH of `scene` once and prepares it on each of `devices`: the GPU's
    /// layout converted from obvhs's CWBVH (or its BVH2 built) and uploaded, or the CPU
    /// tracer laid out. Each setup reports the shared build's time.
    pub(crate) fn new(devices: &[Device], scene: &Scene, options: &BvhOptions) -> Result<Vec<(Prepared, Setup)>> {
        // obvhs's CWBVH, built once for every device that traverses it: the CPU reference,
        // and a GPU in the CWBVH layout.
        let uses_cwbvh = |d: &Device| d.kind() == DeviceKind::Cpu || options.layout == BvhLayout::Cwbvh;
        #[cfg(feature = "testing")]
        crate::phase::enter("bvh");
        let build = Instant::now();
        let mut cwbvh = devices.iter().any(uses_cwbvh).then(|| build_cwbvh(scene, options.quality));
        let cwbvh_seconds = build.elapsed().as_secs_f64();
        let mut out = Vec::with_capacity(devices.len());
        for (i, device) in devices.iter().enumerate() {
            let adapter = device.info();
            match &device.0 {
                Opened::Gpu(dev) => {
                    // Build time includes the conversion to the GPU layout.
                    let convert = Instant::now();
                    let (bvh, bvh_build_seconds, bvh_convert_seconds) = match (options.layout, &cwbvh) {
                        (BvhLayout::Cwbvh, Some(cwbvh)) => {
                            let bvh = GpuBvh::from_cwbvh(scene, cwbvh);
                            let seconds = convert.elapsed().as_secs_f64();
                            (bvh, cwbvh_seconds + seconds, seconds)
                        }
                        (layout, _) => {
                            let bvh = GpuBvh::build(scene, layout, options.quality);
                            (bvh, convert.elapsed().as_secs_f64(), 0.0)
                        }
                    };
                    let upload = Instant::now();
                    let storage = options.geometry_storage.unwrap_or_else(|| dev.ctx.preferred_storage());
                    let gpu_scene = GpuScene::upload(&dev.ctx, scene, &bvh, storage, options.traversal)?;
                    let setup = Setup {
                        adapter,
                        bvh_layout: options.layout,
                        bvh_build_seconds,
                        bvh_convert_seconds,
                        bvh_nodes: bvh.node_count as usize,
                        bvh_depth: bvh.depth,
                        bvh_duplicates: bvh.duplicates,
                        upload_seconds: upload.elapsed().as_secs_f64(),
                        bvh_bytes: gpu_scene.bvh_bytes,
                        device_bytes: gpu_scene.device_bytes(),
                        geometry_bindings: gpu_scene.geometry_bindings(),
                        geometry_storage: storage.name(),
                        traversal: gpu_scene.traversal.name(),
                    };
                    out.push((Prepared::Gpu { scene: gpu_scene, dev: dev.clone() }, setup));
                }
                Opened::Cpu(_) => {
                    // The last device that needs the CWBVH takes it; the others copy it.
                    let last = !devices[i + 1..].iter().any(uses_cwbvh);
                    let cwbvh = if last { cwbvh.take() } else { cwbvh.clone() }.expect("built for the CPU");
                    let bvh_nodes = cwbvh.top.iter().chain(&cwbvh.meshes).map(|b| b.nodes.len()).sum();
                    let bvh_duplicates = cwbvh.duplicates;
                    let bvh_depth = cwbvh.top.as_ref().map_or(0, cwbvh_depth)
                        + cwbvh.meshes.iter().map(cwbvh_depth).max().unwrap_or(0);
                    let upload = Instant::now();
                    let tracer = CpuTracer::new(scene, cwbvh);
                    let setup = Setup {
                        adapter,
                        bvh_layout: BvhLayout::Cwbvh,
                        bvh_build_seconds: cwbvh_seconds,
                        bvh_convert_seconds: 0.0,
                        bvh_nodes,
                        bvh_depth,
                        bvh_duplicates,
                        upload_seconds: upload.elapsed().as_secs_f64(),
                        bvh_bytes: tracer.bytes(),
                        device_bytes: 0,
                        geometry_bindings: 0,
                        geometry_storage: "",
                        traversal: "",
                    };
                    out.push((Prepared::Cpu(Arc::new(tracer)), setup));
                }
            }
        }
        Ok(out)
    }

    /// The film of an image of `settings` seen by `camera`, whose samples are at most
    /// 2^`e` in magnitude ([`value_exponent`]).
    pub(crate) fn image(&self, camera: &Camera, settings: &Settings, e: i32) -> Result<Box<dyn Passes>> {
        match self {
            Prepared::Gpu { dev, scene } => {
                let frame = FrameUniforms::image(camera, settings, scene.node_count, scene.plane_count, e);
                let rows = crate::gpu::target::image_rows_per_target(dev, settings.width);
                if rows >= settings.height {
                    return Ok(Box::new(GpuTarget::image(
                        dev,
                        scene,
                        frame,
                        settings.sampling.sampler,
                        settings.sampling.hemisphere,
                    )?));
                }
                // Bands of rows, each a target with a film of one binding at most, read
                // through one shared buffer: driven as one film, in row order.
                let mut targets: Vec<(GpuTarget, usize)> = Vec::new();
                for first_row in (0..settings.height).step_by(rows as usize) {
                    let band = rows.min(settings.height - first_row);
                    let readback = targets.first().map(|(t, _)| t.readback());
                    let frame = FrameUniforms { first_row, ..frame };
                    let (sampler, hemisphere) = (settings.sampling.sampler, settings.sampling.hemisphere);
                    let target = GpuTarget::image_band(dev, scene, frame, band, sampler, hemisphere, readback)?;
                    targets.push((target, band as usize * settings.width as usize));
                }
                Ok(Box::new(GpuChunks { targets }))
            }
            Prepared::Cpu(tracer) => Ok(Box::new(CpuTarget {
                inactive: Vec::new(),
                work: CpuImage { tracer: tracer.clone(), camera: *camera, settings: settings.clone() },
                sums: BlockSums::new(settings.width as usize * settings.height as usize),
                e,
            })),
        }
    }

    /// The film of `probes`, `samples` samples each with the sampling of `settings`,
    /// spread over `lanes` slots a probe; or, with `bent_normals`, four slots a probe
    /// (`lanes` must be 4): the AO and the escaped directions' x, y, z. Probe k takes the
    /// sample sequence of point `first_point` + k. Its samples are at most 2^`e` in
    /// magnitude.
    // The request and where its points start: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn probes(
        &self,
        probes: &[Probe],
        first_point: u32,
        lanes: u32,
        samples: u32,
        settings: &Settings,
        bent_normals: bool,
        e: i32,
    ) -> Result<Box<dyn Passes>> {
        match self {
            Prepared::Gpu { dev, scene } => {
                let points: Vec<GpuProbePoint> = probes
                    .iter()
                    .map(|p| GpuProbePoint {
                        position: p.position.to_array(),
                        error: p.error,
                        normal: p.normal.to_array(),
                        _pad1: 0.0,
                        surface_normal: p.surface_normal.to_array(),
                        _pad2: 0.0,
                    })
                    .collect();
                let slots_per_point = if bent_normals { 4 } else { lanes };
                let per_target = crate::gpu::target::probe_points_per_target(dev, slots_per_point).max(1);
                let mut targets = Vec::new();
                for (k, chunk) in points.chunks(per_target).enumerate() {
                    let mut frame = FrameUniforms::probes(
                        settings,
                        lanes,
                        chunk.len() as u32,
                        samples,
                        scene.node_count,
                        scene.plane_count,
                        e,
                    );
                    frame.first_point = first_point + (k * per_target) as u32;
                    let target = GpuTarget::probes(
                        dev,
                        scene,
                        frame,
                        settings.sampling.sampler,
                        settings.sampling.hemisphere,
                        chunk,
                        bent_normals,
                    )?;
                    targets.push((target, chunk.len() * slots_per_point as usize));
                }
                match targets.len() {
                    1 => Ok(Box::new(targets.pop().expect("one target").0)),
                    _ => Ok(Box::new(GpuChunks { targets })),
                }
            }
            Prepared::Cpu(tracer) => Ok(Box::new(CpuTarget {
                inactive: Vec::new(),
                work: CpuProbes {
                    tracer: tracer.clone(),
                    settings: settings.clone(),
                    probes: probes.to_vec(),
                    first_point,
                    samples,
                    lanes,
                    bent_normals,
                },
                sums: BlockSums::new(lanes as usize * probes.len()),
                e,
            })),
        }
    }
}

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
    /// Stops sampling the slots marked in `inactive` (from the next pass on; an empty
    /// mask samples every slot). Their sums read back as empty. Called while the block
    /// holds no samples: right after a take, or before a checkpoint's block is loaded.
    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()>;
    /// Whether the device can keep the exact sums itself ([`Passes::fold`]): a GPU's
    /// image film. The CPU reference's exact sums are in host memory already.
    fn keeps_sums(&self) -> bool {
        false
    }
    /// Replaces the device's exact sums with `exact`'s.
    fn write_sums(&mut self, _exact: &ExactSums) -> Result<()> {
        Err(Error::settings("this device does not keep exact sums"))
    }
    /// Adds the block to the device's exact sums, leaving the block empty; `replicate`:
    /// the block is one whole replicate, whose square is added to the replicates' squares.
    fn fold(&mut self, _replicate: bool) -> Result<()> {
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

/// The slots `range` of `exact`: its sums (and replicates' squares, where it has them).
fn sums_part(exact: &ExactSums, range: std::ops::Range<usize>) -> ExactSums {
    ExactSums {
        sum: exact.sum[range.clone()].to_vec(),
        sum_sq: exact.sum_sq[range.clone()].to_vec(),
        replicate_sq: exact.replicate_sq.get(range).map_or_else(Vec::new, <[_]>::to_vec),
        pixel_samples: Vec::new(),
        pixel_replicates: Vec::new(),
        stopped: Vec::new(),
        ..*exact
    }
}

impl Passes for GpuTarget {
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let c = self.render_pass(first, count)?;
        Ok(PassReport { ao_rays: c.ao_rays, gpu_seconds: c.gpu_seconds })
    }

    fn read(&mut self) -> Result<BlockSums> {
        let mut words = self.film_words()?;
        for w in &mut words {
            if w[3] == INACTIVE_SLOT_BITS {
                *w = [0; 4];
            }
        }
        Ok(BlockSums::from_words(&words))
    }

    fn take(&mut self) -> Result<BlockSums> {
        let block = Passes::read(self)?;
        self.clear_film()?;
        self.mark_inactive(None)?;
        Ok(block)
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        let words = block.to_words();
        self.set_film_words(&words)?;
        self.mark_inactive(Some(&words))
    }

    fn device_bytes(&self) -> u64 {
        self.all_device_bytes()
    }

    fn keeps_sums(&self) -> bool {
        GpuTarget::keeps_sums(self)
    }

    fn write_sums(&mut self, exact: &ExactSums) -> Result<()> {
        GpuTarget::write_sums(self, exact)
    }

    fn fold(&mut self, replicate: bool) -> Result<()> {
        GpuTarget::fold(self, replicate)
    }

    fn check(&mut self, query: CheckQuery, exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        GpuTarget::check(self, query, exponents)
    }

    fn read_sums(&mut self, exact: &mut ExactSums, replicates: bool) -> Result<Option<u32>> {
        GpuTarget::read_sums(self, exact, replicates)
    }

    fn take_readback_bytes(&mut self) -> u64 {
        GpuTarget::take_readback_bytes(self)
    }

    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()> {
        self.inactive = inactive.to_vec();
        self.mark_inactive(None)
    }
}

/// A film past one target's storage bindings (lavapipe binds 128 MiB: an image of
/// 8,388,608 pixels, 2,796,202 probe points) over several targets, driven as one film:
/// slot order and sums are those of a single target. An image's targets are bands of
/// rows, a probe request's contiguous ranges of the points, each numbering its sample
/// sequences from its first point's index.
struct GpuChunks {
    /// Each target, and its film's slots.
    targets: Vec<(GpuTarget, usize)>,
}

impl GpuChunks {
    /// `words` (one entry per slot of the whole film) cut into the targets' parts.
    fn split<'a, T>(&self, words: &'a [T]) -> Vec<&'a [T]> {
        let mut start = 0;
        self.targets
            .iter()
            .map(|(_, slots)| {
                let part = &words[start.min(words.len())..(start + slots).min(words.len())];
                start += slots;
                part
            })
            .collect()
    }

    fn join(blocks: Vec<BlockSums>) -> BlockSums {
        let mut out = BlockSums::default();
        for block in blocks {
            out.sum.extend(block.sum);
            out.sum_sq.extend(block.sum_sq);
        }
        out
    }
}

impl Passes for GpuChunks {
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let mut report = PassReport { ao_rays: 0, gpu_seconds: Some(0.0) };
        for (target, _) in &mut self.targets {
            let r = Passes::pass(target, first, count)?;
            report.ao_rays += r.ao_rays;
            report.gpu_seconds = report.gpu_seconds.zip(r.gpu_seconds).map(|(a, b)| a + b);
        }
        Ok(report)
    }

    fn read(&mut self) -> Result<BlockSums> {
        let blocks = self.targets.iter_mut().map(|(t, _)| Passes::read(t)).collect::<Result<Vec<_>>>()?;
        Ok(GpuChunks::join(blocks))
    }

    fn take(&mut self) -> Result<BlockSums> {
        let blocks = self.targets.iter_mut().map(|(t, _)| Passes::take(t)).collect::<Result<Vec<_>>>()?;
        Ok(GpuChunks::join(blocks))
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        if block.len() != self.targets.iter().map(|(_, slots)| slots).sum::<usize>() {
            return Err(Error::settings("the checkpoint's block does not fit the film"));
        }
        let (sums, squares) = (self.split(&block.sum), self.split(&block.sum_sq));
        let parts: Vec<BlockSums> =
            sums.into_iter().zip(squares).map(|(s, q)| BlockSums { sum: s.to_vec(), sum_sq: q.to_vec() }).collect();
        for ((target, _), part) in self.targets.iter_mut().zip(parts) {
            Passes::load(target, &part)?;
        }
        Ok(())
    }

    fn device_bytes(&self) -> u64 {
        self.targets.iter().map(|(t, _)| t.all_device_bytes()).sum()
    }

    fn keeps_sums(&self) -> bool {
        self.targets.iter().all(|(t, _)| t.keeps_sums())
    }

    fn write_sums(&mut self, exact: &ExactSums) -> Result<()> {
        let mut start = 0;
        for (target, slots) in &mut self.targets {
            target.write_sums(&sums_part(exact, start..start + *slots))?;
            start += *slots;
        }
        Ok(())
    }

    fn fold(&mut self, replicate: bool) -> Result<()> {
        self.targets.iter_mut().try_for_each(|(t, _)| t.fold(replicate))
    }

    fn check(&mut self, query: CheckQuery, exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        let (mut total, mut bad, mut start) = (CheckSums::default(), None, 0u32);
        for (target, slots) in &mut self.targets {
            let (sums, b) = target.check(query, exponents)?;
            total = total + sums;
            bad = bad.or(b.map(|b| b + start));
            start += *slots as u32;
        }
        Ok((total, bad))
    }

    fn read_sums(&mut self, exact: &mut ExactSums, replicates: bool) -> Result<Option<u32>> {
        let (mut bad, mut start) = (None, 0usize);
        if replicates && exact.replicate_sq.len() != exact.sum.len() {
            exact.replicate_sq = vec![0; exact.sum.len()];
        }
        for (target, slots) in &mut self.targets {
            let range = start..start + *slots;
            let mut part = sums_part(exact, range.clone());
            let b = target.read_sums(&mut part, replicates)?;
            exact.sum[range.clone()].copy_from_slice(&part.sum);
            exact.sum_sq[range.clone()].copy_from_slice(&part.sum_sq);
            if replicates {
                exact.replicate_sq[range].copy_from_slice(&part.replicate_sq);
            }
            bad = bad.or(b.map(|b| b + start as u32));
            start += *slots;
        }
        Ok(bad)
    }

    fn take_readback_bytes(&mut self) -> u64 {
        self.targets.iter().map(|(t, _)| GpuTarget::take_readback_bytes(t)).sum()
    }

    fn set_inactive(&mut self, inactive: &[bool]) -> Result<()> {
        let parts: Vec<Vec<bool>> = if inactive.is_empty() {
            vec![Vec::new(); self.targets.len()]
        } else {
            self.split(inactive).into_iter().map(<[_]>::to_vec).collect()
        };
        for ((target, _), part) in self.targets.iter_mut().zip(parts) {
            Passes::set_inactive(target, &part)?;
        }
        Ok(())
    }
}

/// What the CPU reference traces into a film: an image, or probe points.
trait CpuWork {
    /// Adds samples (or probe rounds) `first .. first + count` to `sums`, in the quanta
    /// of samples of bound 2^`e`, leaving the slots marked in `inactive` (empty: none);
    /// returns the AO rays traced.
    fn pass(&self, sums: &mut BlockSums, e: i32, first: u32, count: u32, inactive: &[bool]) -> u64;
}

/// An image on the CPU reference.
struct CpuImage {
    tracer: Arc<CpuTracer>,
    camera: Camera,
    settings: Settings,
}

impl CpuWork for CpuImage {
    fn pass(&self, sums: &mut BlockSums, e: i32, first: u32, count: u32, inactive: &[bool]) -> u64 {
        self.tracer.render_pass(&self.camera, &self.settings, sums, e, first, count, inactive)
    }
}

/// Probe points on the CPU reference; the film's slots are lanes × probes, or four a
/// probe with bent normals.
struct CpuProbes {
    tracer: Arc<CpuTracer>,
    settings: Settings,
    probes: Vec<Probe>,
    /// The sample sequence of probe k is point `first_point` + k's.
    first_point: u32,
    samples: u32,
    lanes: u32,
    bent_normals: bool,
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
struct CpuTarget<W> {
    work: W,
    sums: BlockSums,
    /// The bound 2^e of the samples ([`value_exponent`]).
    e: i32,
    /// Slots not sampled (empty: none).
    inactive: Vec<bool>,
}

impl<W: CpuWork> Passes for CpuTarget<W> {
    fn pass(&mut self, first: u32, count: u32) -> Result<PassReport> {
        let rays = self.work.pass(&mut self.sums, self.e, first, count, &self.inactive);
        Ok(PassReport { ao_rays: rays, gpu_seconds: None })
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
