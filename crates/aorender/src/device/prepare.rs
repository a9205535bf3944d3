//! Preparing a scene on devices: the BVH built once ([`BvhOptions`]), converted and
//! uploaded to each GPU or laid out for the CPU tracer ([`Prepared`], with what it took in
//! [`Setup`]), and a request's film made on it.

use super::cpu::{CpuImage, CpuProbes, CpuTarget};
use super::gpu::GpuChunks;
use super::open::{Device, DeviceKind, Opened};
use super::passes::Passes;
use crate::bvh::ploc::cwbvh_depth;
use crate::bvh::{BvhLayout, GpuBvh, SceneCwbvh, build_cwbvh};
use crate::cpu::CpuTracer;
use crate::error::Result;
use crate::film::BlockSums;
use crate::gpu::target::MadePoints;
use crate::gpu::{AdapterInfo, FrameUniforms, GpuDevice, GpuProbePoint, GpuScene, GpuTarget};
use crate::probe::Probe;
use crate::scene::{Camera, Scene, Settings};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// A probe as the scene's local frame has it.
pub(crate) type LocalProbe<'a> = dyn Fn(&Probe) -> Probe + Sync + 'a;

/// Probes a rayon task converts at least: enough to outweigh the task's cost.
const PROBE_CHUNK: usize = 1 << 13;

/// The device's record of `p` (made in pieces on rayon's threads as the buffer is
/// written, each record its probe's alone).
fn gpu_probe_point(p: &Probe) -> GpuProbePoint {
    GpuProbePoint {
        position: p.position.to_array(),
        error: p.error,
        normal: p.normal.to_array(),
        _pad1: 0.0,
        surface_normal: p.surface_normal.to_array(),
        _pad2: 0.0,
    }
}

// The options are described in `kinds`, where the accumulation reads them.
pub use crate::kinds::BvhOptions;

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
    /// What became of the driver's pipeline cache on disk (`CacheState::name`; empty on
    /// the CPU).
    pub pipeline_cache: &'static str,
    /// Seconds of the session's setup beside the BVH build and the upload (set by the
    /// session).
    pub scene_seconds: f64,
    /// Seconds opening the device took where the session opened it beside its BVH build
    /// ([`crate::Session::beside`]), else 0.
    pub adapter_seconds: f64,
    /// Seconds the opening's thread spent compiling the statistics kernels after the
    /// device opened (not in `adapter_seconds`).
    pub adapter_compile_seconds: f64,
    /// Of `adapter_seconds` and `adapter_compile_seconds`, those the session waited for
    /// the device once its BVH was built: the rest ran beside the caller's loading and
    /// the build.
    pub adapter_wait_seconds: f64,
}

/// A scene prepared on a device: its BVH built and uploaded, ready for requests.
pub(crate) enum Prepared {
    /// The geometry on the adapter (dropped before the adapter's device, last).
    Gpu { scene: GpuScene, dev: Arc<GpuDevice> },
    /// The CPU tracer.
    Cpu(Arc<CpuTracer>),
}

/// A scene's BVH built for devices of given kinds, before any of them is needed (a device
/// may still be opening, [`super::DeviceOpening`]): obvhs's CWBVH, and the GPU's layout of
/// it (or its BVH2) for the GPUs.
pub(crate) struct Built {
    /// The kinds of the devices it is built for, in order.
    kinds: Vec<DeviceKind>,
    /// obvhs's CWBVH, while a CPU device still needs it.
    cwbvh: Option<SceneCwbvh>,
    /// Seconds building the CWBVH took (0 where none was built).
    cwbvh_seconds: f64,
    /// The GPUs' BVH, with its build's seconds (the CWBVH's included) and its conversion's.
    gpu: Option<(GpuBvh, f64, f64)>,
}

impl Built {
    /// Builds the BVH of `scene` once for devices of `kinds`: obvhs's CWBVH where the CPU
    /// reference or a GPU in the CWBVH layout traverses it, and the GPU's layout where
    /// a GPU does.
    pub(crate) fn new(kinds: &[DeviceKind], scene: &Scene, options: &BvhOptions) -> Built {
        // obvhs's CWBVH, built once for every device that traverses it: the CPU reference,
        // and a GPU in the CWBVH layout.
        let uses_cwbvh = |k: &DeviceKind| *k == DeviceKind::Cpu || options.layout == BvhLayout::Cwbvh;
        #[cfg(feature = "testing")]
        crate::phase::enter("bvh");
        let build = Instant::now();
        let mut cwbvh = kinds.iter().any(uses_cwbvh).then(|| build_cwbvh(scene, options.quality));
        let cwbvh_seconds = build.elapsed().as_secs_f64();
        // Build time includes the conversion to the GPU layout.
        let gpu = kinds.contains(&DeviceKind::Gpu).then(|| {
            let convert = Instant::now();
            match (options.layout, &cwbvh) {
                (BvhLayout::Cwbvh, Some(cwbvh)) => {
                    let bvh = GpuBvh::from_cwbvh(scene, cwbvh);
                    let seconds = convert.elapsed().as_secs_f64();
                    (bvh, cwbvh_seconds + seconds, seconds)
                }
                (layout, _) => {
                    let bvh = GpuBvh::build(scene, layout, options.quality);
                    (bvh, convert.elapsed().as_secs_f64(), 0.0)
                }
            }
        });
        // The GPUs have their layout: the CWBVH stays only for the CPU reference.
        if !kinds.contains(&DeviceKind::Cpu) {
            cwbvh = None;
        }
        Built { kinds: kinds.to_vec(), cwbvh, cwbvh_seconds, gpu }
    }
}

impl Prepared {
    /// Builds the BVH of `scene` once and prepares it on each of `devices`: the GPU's
    /// layout converted from obvhs's CWBVH (or its BVH2 built) and uploaded, or the CPU
    /// tracer laid out. Each setup reports the shared build's time.
    pub(crate) fn new(devices: &[Device], scene: &Scene, options: &BvhOptions) -> Result<Vec<(Prepared, Setup)>> {
        let kinds: Vec<DeviceKind> = devices.iter().map(Device::kind).collect();
        Prepared::upload(Built::new(&kinds, scene, options), devices, scene, options)
    }

    /// Prepares `built` (the BVH of `scene`) on `devices`, of the kinds it was built for:
    /// uploaded to each GPU, laid out for the CPU tracer.
    pub(crate) fn upload(
        built: Built,
        devices: &[Device],
        scene: &Scene,
        options: &BvhOptions,
    ) -> Result<Vec<(Prepared, Setup)>> {
        let Built { kinds, mut cwbvh, cwbvh_seconds, gpu } = built;
        assert!(devices.iter().map(Device::kind).eq(kinds.iter().copied()), "devices of the kinds built for");
        let mut out = Vec::with_capacity(devices.len());
        for (i, device) in devices.iter().enumerate() {
            let adapter = device.info();
            match &device.0 {
                Opened::Gpu(dev) => {
                    let (bvh, bvh_build_seconds, bvh_convert_seconds) = gpu.as_ref().expect("built for the GPU");
                    let upload = Instant::now();
                    let storage = options.geometry_storage.unwrap_or_else(|| dev.ctx.preferred_storage());
                    let gpu_scene = GpuScene::upload(&dev.ctx, scene, bvh, storage, options.traversal)?;
                    let setup = Setup {
                        adapter,
                        bvh_layout: options.layout,
                        bvh_build_seconds: *bvh_build_seconds,
                        bvh_convert_seconds: *bvh_convert_seconds,
                        bvh_nodes: bvh.node_count as usize,
                        bvh_depth: bvh.depth,
                        bvh_duplicates: bvh.duplicates,
                        upload_seconds: upload.elapsed().as_secs_f64(),
                        bvh_bytes: gpu_scene.bvh_bytes,
                        device_bytes: gpu_scene.device_bytes(),
                        geometry_bindings: gpu_scene.geometry_bindings(),
                        geometry_storage: storage.name(),
                        traversal: gpu_scene.traversal.name(),
                        pipeline_cache: dev.pipelines.cache_state().name(),
                        scene_seconds: 0.0,
                        adapter_seconds: 0.0,
                        adapter_compile_seconds: 0.0,
                        adapter_wait_seconds: 0.0,
                    };
                    out.push((Prepared::Gpu { scene: gpu_scene, dev: dev.clone() }, setup));
                }
                Opened::Cpu(_) => {
                    // The last CPU device takes the CWBVH; the others copy it.
                    let last = !devices[i + 1..].iter().any(|d| d.kind() == DeviceKind::Cpu);
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
                        pipeline_cache: "",
                        scene_seconds: 0.0,
                        adapter_seconds: 0.0,
                        adapter_compile_seconds: 0.0,
                        adapter_wait_seconds: 0.0,
                    };
                    out.push((Prepared::Cpu(Arc::new(tracer)), setup));
                }
            }
        }
        Ok(out)
    }

    /// Seconds the adapter has spent compiling pipelines so far (0 on the CPU).
    pub(crate) fn compile_seconds(&self) -> f64 {
        match self {
            Prepared::Gpu { dev, .. } => dev.pipelines.compile_seconds(),
            Prepared::Cpu(_) => 0.0,
        }
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

    /// The film of `probes`, each as `local` puts it in the scene's local frame,
    /// `samples` samples each with the sampling of `settings`, spread over `lanes` slots
    /// a probe; or, with `bent_normals`, four slots a probe (`lanes` must be 4): the AO
    /// and the escaped directions' x, y, z. Probe k takes the sample sequence of point
    /// `first_point` + k. Its samples are at most 2^`e` in magnitude.
    // The request and where its points start: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn probes(
        &self,
        probes: &[Probe],
        local: &LocalProbe<'_>,
        first_point: u32,
        lanes: u32,
        samples: u32,
        settings: &Settings,
        bent_normals: bool,
        e: i32,
    ) -> Result<Box<dyn Passes>> {
        match self {
            Prepared::Gpu { dev, scene } => {
                let slots_per_point = if bent_normals { 4 } else { lanes };
                let per_target = crate::gpu::target::probe_points_per_target(dev, slots_per_point).max(1);
                let mut targets = Vec::new();
                // Each target's records are made in pieces straight into its buffer.
                for (k, chunk) in probes.chunks(per_target).enumerate() {
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
                    let fill = |first: usize, out: &mut [GpuProbePoint]| {
                        out.iter_mut().zip(&chunk[first..]).for_each(|(o, p)| *o = gpu_probe_point(&local(p)));
                    };
                    let target = GpuTarget::probes_made(
                        dev,
                        scene,
                        frame,
                        settings.sampling.sampler,
                        settings.sampling.hemisphere,
                        MadePoints { count: chunk.len(), fill: &fill },
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
                    probes: probes.par_iter().with_min_len(PROBE_CHUNK).map(local).collect(),
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

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// The device's record of a probe is the probe put in the local frame, field by field
    /// in the kernel's layout (the records are made a piece at a time as the buffer is
    /// written; the probe tests compare the GPU's values with the CPU reference's).
    #[test]
    fn a_probe_record_is_its_probe_in_the_local_frame() {
        let shift = Vec3::new(-3.5, 0.25, 1e3);
        let local = |p: &Probe| Probe { position: p.position + shift, error: p.error * 2.0, ..*p };
        for i in 0..100 {
            let f = i as f32;
            let surface_normal = if i % 3 == 0 { Vec3::ZERO } else { Vec3::new(0.6, 0.0, 0.8) };
            let normal = Vec3::new((0.1 * f).sin(), (0.1 * f).cos(), 0.0);
            let p =
                Probe { position: Vec3::new(f, -f * 0.5, 1.0 / (f + 1.0)), normal, surface_normal, error: 1e-6 * f };
            let q = local(&p);
            let (a, n, g) = (q.position, q.normal, q.surface_normal);
            let expected = [a.x, a.y, a.z, q.error, n.x, n.y, n.z, 0.0, g.x, g.y, g.z, 0.0].map(f32::to_bits);
            let record = gpu_probe_point(&local(&p));
            let got: &[u32; 12] = bytemuck::cast_ref(&record);
            assert_eq!(*got, expected, "probe {i}");
        }
    }
}
