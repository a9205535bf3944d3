//! The AO kernel's compute pipelines, each specialised for what a render needs, compiled
//! once per adapter and kept: many sessions and requests on one adapter (the accuracy
//! suite's thousands of probe runs, a comparison grid's cells) compile each variant once.
//! An opened adapter with the pipelines compiled on it ([`GpuDevice`]) is what every
//! session on the adapter shares. Where the backend keeps a driver pipeline cache
//! (Vulkan), it is kept on disk between processes ([`DiskCache`]), so that a later
//! process on the same adapter and driver skips the driver's compilation.

use super::compact::CompactPipelines;
use super::context::GpuContext;
use super::layout::{Access, BINDINGS, node_binding, primitive_binding};
use super::shaders::{GeometryChunks, GeometryStorage, Traversal, compose};
use super::stats::StatsPipelines;
use crate::bvh::BvhLayout;
use crate::error::Result;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// The environment variable that places the pipeline cache: `off` (or `0`) keeps none on
/// disk; a directory keeps it there. Unset: `$XDG_CACHE_HOME/aorender`, else
/// `~/.cache/aorender`.
pub const PIPELINE_CACHE_ENV: &str = "AORENDER_PIPELINE_CACHE";

/// What the AO pipeline computes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// An image: one film slot per pixel, one sample per pixel per dispatch.
    Image,
    /// Probe points: `width` lanes for each of `height` points, one sample per lane per dispatch.
    Probe,
    /// Probe points with their bent normals: four slots for each of `height` points (AO,
    /// then the unoccluded directions' x, y, z), one sample per point per dispatch.
    BentProbe,
}

impl Kernel {
    /// The WGSL entry point.
    fn entry_point(self) -> &'static str {
        match self {
            Kernel::Image => "render_sample",
            Kernel::Probe => "probe_sample",
            Kernel::BentProbe => "probe_bent_sample",
        }
    }
}

/// What a compiled pipeline is specialised for. Besides the layout, kernel and geometry
/// split: what the scene holds, the sampler, the hemisphere mapping and whether to take
/// a CPU adapter's formulations, as the shaders' override constants, so that the compiler
/// drops every path the render cannot take (lavapipe runs a SIMD batch's lanes in
/// lockstep and pays for every branch that is not constant); and the traversal stack's
/// size, the BVH's depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineKey {
    /// The BVH layout traversed.
    pub layout: BvhLayout,
    /// A ray per lane or per group of lanes.
    pub traversal: Traversal,
    /// Image or probes.
    pub kernel: Kernel,
    /// How the geometry is split into bindings.
    pub chunks: GeometryChunks,
    /// `HAS_INSTANCES`: the BVH has instances.
    pub instances: bool,
    /// `HAS_SPHERES`: the scene has spheres.
    pub spheres: bool,
    /// `HAS_TRIANGLES`: the scene has triangles, placed once or instanced.
    pub triangles: bool,
    /// `HAS_PLANES`: the scene has planes.
    pub planes: bool,
    /// `SAMPLER`.
    pub sampler: Sampler,
    /// `HEMISPHERE`.
    pub hemisphere: Hemisphere,
    /// `SKY` (`Sky::shader_id`).
    pub sky: u32,
    /// `STACK_SIZE`.
    pub stack_size: u32,
    /// `CPU_LANES`.
    pub cpu_lanes: bool,
}

impl PipelineKey {
    /// The override constants' values.
    fn constants(&self) -> [(&'static str, f64); 8] {
        let flag = |b: bool| if b { 1.0 } else { 0.0 };
        [
            ("HAS_INSTANCES", flag(self.instances)),
            ("HAS_SPHERES", flag(self.spheres)),
            ("HAS_TRIANGLES", flag(self.triangles)),
            ("HAS_PLANES", flag(self.planes)),
            ("CPU_LANES", flag(self.cpu_lanes)),
            ("SAMPLER", self.sampler.shader_id() as f64),
            ("HEMISPHERE", self.hemisphere.shader_id() as f64),
            ("SKY", self.sky as f64),
        ]
    }
}

/// A compiled pipeline and its bind group layout.
#[derive(Clone, Debug)]
pub struct Pipeline {
    /// The bind group layout: the fixed bindings, then the geometry's.
    pub bind_group_layout: wgpu::BindGroupLayout,
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// True when it was compiled for this request (some drivers compile at the first
    /// dispatch: the caller warms it up).
    pub fresh: bool,
}

/// The pipelines compiled on one adapter, by key, and the driver's cache they are
/// compiled through.
#[derive(Debug, Default)]
pub struct Pipelines {
    /// The pipelines compiled so far.
    compiled: Mutex<Vec<(PipelineKey, wgpu::BindGroupLayout, wgpu::ComputePipeline)>>,
    /// The driver's pipeline cache, kept on disk (`None` where there is none).
    disk: Option<DiskCache>,
    /// What became of the cache on disk when the adapter was opened.
    state: CacheState,
    /// Nanoseconds spent compiling pipelines so far.
    compile_nanos: AtomicU64,
}

impl Pipelines {
    /// No pipelines yet, compiled through the cache on disk of `ctx`'s adapter where the
    /// backend has one and [`PIPELINE_CACHE_ENV`] does not turn it off.
    pub fn new(ctx: &GpuContext) -> Pipelines {
        let (disk, state) = DiskCache::open(ctx, cache_dir().as_deref());
        Pipelines { disk, state, ..Pipelines::default() }
    }

    /// What became of the cache on disk when the adapter was opened.
    pub fn cache_state(&self) -> CacheState {
        self.state
    }

    /// Seconds spent compiling pipelines on this adapter so far.
    pub fn compile_seconds(&self) -> f64 {
        self.compile_nanos.load(Ordering::Relaxed) as f64 * 1e-9
    }

    /// The pipeline of `key`, compiled on first use.
    pub fn get(&self, ctx: &GpuContext, key: PipelineKey) -> Result<Pipeline> {
        let mut cache = self.compiled.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, l, p)) = cache.iter().find(|(k, _, _)| *k == key) {
            return Ok(Pipeline { bind_group_layout: l.clone(), pipeline: p.clone(), fresh: false });
        }
        let start = Instant::now();
        let compiled = self.compile(ctx, key);
        self.compile_nanos.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        let (bind_group_layout, pipeline) = compiled?;
        if let Some(disk) = &self.disk {
            disk.save();
        }
        cache.push((key, bind_group_layout.clone(), pipeline.clone()));
        Ok(Pipeline { bind_group_layout, pipeline, fresh: true })
    }

    /// Compiles the pipeline of `key` (through the driver's cache, where there is one).
    fn compile(&self, ctx: &GpuContext, key: PipelineKey) -> Result<(wgpu::BindGroupLayout, wgpu::ComputePipeline)> {
        let PipelineKey { layout, traversal, kernel, chunks, stack_size, .. } = key;
        let source = compose("ao.wgsl", layout, traversal, chunks, stack_size, ctx.shared_steps())?;
        let device = &ctx.device;
        let buffer = |binding: u32, read_only: bool, dynamic: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only },
                has_dynamic_offset: dynamic,
                min_binding_size: None,
            },
            count: None,
        };
        let geometry = |binding: u32| match chunks.storage {
            GeometryStorage::Buffers => buffer(binding, true, false),
            GeometryStorage::Textures => wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::StorageTexture {
                    access: wgpu::StorageTextureAccess::ReadOnly,
                    format: wgpu::TextureFormat::Rgba32Uint,
                    view_dimension: wgpu::TextureViewDimension::D2,
                },
                count: None,
            },
        };
        let mut entries: Vec<wgpu::BindGroupLayoutEntry> =
            BINDINGS.iter().map(|b| buffer(b.index, b.access == Access::Read, b.dynamic_offset)).collect();
        entries.extend((0..chunks.node_chunks).map(|k| geometry(node_binding(k))));
        entries.extend((0..chunks.primitive_chunks).map(|k| geometry(primitive_binding(k))));
        let bind_group_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("ao bindings"),
            entries: &entries,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("ao.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("ao"),
            bind_group_layouts: &[Some(&bind_group_layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("ao"),
            layout: Some(&pipeline_layout),
            module: &module,
            entry_point: Some(kernel.entry_point()),
            compilation_options: wgpu::PipelineCompilationOptions { constants: &key.constants(), ..Default::default() },
            cache: self.disk.as_ref().map(|d| &d.cache),
        });
        Ok((bind_group_layout, pipeline))
    }
}

/// What became of the pipeline cache on disk when an adapter was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CacheState {
    /// No cache on disk: [`PIPELINE_CACHE_ENV`] turned it off, or no cache directory.
    #[default]
    Off,
    /// The backend keeps no pipeline cache (only Vulkan does, in wgpu).
    Unsupported,
    /// No cache file yet: this process's pipelines start one.
    Miss,
    /// The cache file was read and the driver took it.
    Hit,
    /// The cache file was damaged, or made by another adapter, driver or wgpu: ignored,
    /// and replaced by this process's.
    Rejected,
}

impl CacheState {
    /// The state in one word, as the statistics give it.
    pub fn name(self) -> &'static str {
        match self {
            CacheState::Off => "off",
            CacheState::Unsupported => "unsupported",
            CacheState::Miss => "miss",
            CacheState::Hit => "hit",
            CacheState::Rejected => "rejected",
        }
    }
}

/// The directory of the pipeline cache ([`PIPELINE_CACHE_ENV`]); `None` when turned off
/// or when there is no home.
fn cache_dir() -> Option<PathBuf> {
    let nonempty = |v: std::ffi::OsString| (!v.is_empty()).then(|| PathBuf::from(v));
    match std::env::var_os(PIPELINE_CACHE_ENV) {
        Some(v) if v == "off" || v == "0" => None,
        Some(v) if !v.is_empty() => Some(PathBuf::from(v)),
        _ => std::env::var_os("XDG_CACHE_HOME")
            .and_then(nonempty)
            .or_else(|| std::env::var_os("HOME").and_then(nonempty).map(|h| h.join(".cache")))
            .map(|d| d.join("aorender")),
    }
}

/// The file's first bytes: what it is and its layout's version.
const CACHE_MAGIC: &[u8; 8] = b"AOPLC001";
/// The magic, the payload's length (u64, little-endian) and its BLAKE3 hash.
const CACHE_HEADER: usize = 8 + 8 + 32;

/// A driver pipeline cache kept in a file: wgpu's data (which carries its own header
/// naming the backend, adapter, driver and wgpu's format, checked when it is loaded),
/// behind a header with a hash of it, so that a damaged file is never handed to the
/// driver.
#[derive(Debug)]
pub struct DiskCache {
    /// The cache the pipelines are compiled through.
    cache: wgpu::PipelineCache,
    /// Its file.
    path: PathBuf,
    /// The hash of the data as last read or written (nothing to write while it is the same).
    saved: Mutex<Option<[u8; 32]>>,
}

impl DiskCache {
    /// The cache of `ctx`'s adapter in `dir` (none without a directory or where the backend
    /// has no pipeline cache), and what became of its file.
    fn open(ctx: &GpuContext, dir: Option<&Path>) -> (Option<DiskCache>, CacheState) {
        let device = &ctx.device;
        let key = wgpu::util::pipeline_cache_key(&ctx.adapter.get_info());
        let (Some(dir), Some(key)) = (dir, key) else {
            return (None, if dir.is_none() { CacheState::Off } else { CacheState::Unsupported });
        };
        if !device.features().contains(wgpu::Features::PIPELINE_CACHE) {
            return (None, CacheState::Unsupported);
        }
        let path = dir.join(format!("{key}.bin"));
        let create = |data: Option<&[u8]>| {
            // Refused data (another adapter, driver or wgpu) is a validation error: caught
            // here, and the cache made empty instead.
            let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
            // SAFETY: the data is what `PipelineCache::get_data` gave a process of this
            // program, as its hash in the file's header shows; wgpu checks its own header
            // (backend, adapter, driver, format) before the driver sees it.
            let cache = unsafe {
                device.create_pipeline_cache(&wgpu::PipelineCacheDescriptor {
                    label: Some("aorender pipelines"),
                    data,
                    fallback: false,
                })
            };
            (cache, pollster::block_on(scope.pop()).is_none())
        };
        let (data, mut state) = match std::fs::read(&path) {
            Ok(bytes) => match unwrap_cache_file(&bytes) {
                Some(data) => (Some(data.to_vec()), CacheState::Hit),
                None => (None, CacheState::Rejected),
            },
            Err(_) => (None, CacheState::Miss),
        };
        let (mut cache, mut taken) = create(data.as_deref());
        if !taken && data.is_some() {
            state = CacheState::Rejected;
            (cache, taken) = create(None);
        }
        if !taken {
            return (None, CacheState::Unsupported);
        }
        let saved = match state {
            CacheState::Hit => data.as_deref().map(|d| *blake3::hash(d).as_bytes()),
            _ => None,
        };
        (Some(DiskCache { cache, path, saved: Mutex::new(saved) }), state)
    }

    /// Writes the cache's data to its file where it changed: whole or not at all (a
    /// temporary file renamed over it). A cache that cannot be written is left as it is:
    /// it only saves time.
    fn save(&self) {
        let Some(data) = self.cache.get_data() else { return };
        let hash = *blake3::hash(&data).as_bytes();
        let mut saved = self.saved.lock().unwrap_or_else(|e| e.into_inner());
        if *saved == Some(hash) {
            return;
        }
        if write_cache_file(&self.path, &data, &hash).is_ok() {
            *saved = Some(hash);
        }
    }
}

/// The payload of a cache file whose header and hash hold (`None` for any other file).
fn unwrap_cache_file(bytes: &[u8]) -> Option<&[u8]> {
    let (header, data) = (bytes.get(..CACHE_HEADER)?, &bytes[CACHE_HEADER..]);
    let len = u64::from_le_bytes(header[8..16].try_into().ok()?);
    let ok = &header[..8] == CACHE_MAGIC && len == data.len() as u64 && header[16..] == *blake3::hash(data).as_bytes();
    ok.then_some(data)
}

/// Writes `data` (of hash `hash`) to `path` with its header, atomically: to a temporary
/// file beside it (named for the process and the write, as adapters of several processes
/// and threads may save at once), renamed over it.
fn write_cache_file(path: &Path, data: &[u8], hash: &[u8; 32]) -> std::io::Result<()> {
    use std::io::Write;
    static WRITES: AtomicU64 = AtomicU64::new(0);
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let n = WRITES.fetch_add(1, Ordering::Relaxed);
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
    let result = (|| {
        let mut file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        file.write_all(CACHE_MAGIC)?;
        file.write_all(&(data.len() as u64).to_le_bytes())?;
        file.write_all(hash)?;
        file.write_all(data)?;
        file.into_inner().map_err(|e| e.into_error())?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// An adapter's context and its compiled pipelines (dropped before the context, whose
/// device they were made on).
pub struct GpuDevice {
    /// Pipelines compiled on it so far.
    pub pipelines: Pipelines,
    /// The statistics kernels, compiled when a render first keeps its sums on the device.
    stats: std::sync::Mutex<Option<StatsPipelines>>,
    /// The kernels that list an adaptive image's live pixels, compiled on first use.
    compact: std::sync::Mutex<Option<CompactPipelines>>,
    /// The adapter, device and queue.
    pub ctx: GpuContext,
}

impl GpuDevice {
    /// Wraps an opened context (after any test limits were set on it).
    pub fn new(ctx: GpuContext) -> GpuDevice {
        GpuDevice { pipelines: Pipelines::new(&ctx), ctx, stats: Default::default(), compact: Default::default() }
    }

    /// The statistics kernels (`stats.wgsl`), compiled on first use.
    pub fn stats_pipelines(&self) -> Result<StatsPipelines> {
        let mut cached = self.stats.lock().unwrap_or_else(|e| e.into_inner());
        if cached.is_none() {
            *cached = Some(StatsPipelines::new(&self.ctx)?);
        }
        Ok(cached.clone().expect("compiled above"))
    }

    /// The kernels that list an adaptive image's live pixels (`compact.wgsl`), compiled
    /// on first use.
    pub fn compact_pipelines(&self) -> Result<CompactPipelines> {
        let mut cached = self.compact.lock().unwrap_or_else(|e| e.into_inner());
        if cached.is_none() {
            *cached = Some(CompactPipelines::new(&self.ctx)?);
        }
        Ok(cached.clone().expect("compiled above"))
    }

    /// Compiles the statistics kernels an image render dispatches and runs each once over
    /// no pixels (with `target` a check's, with `adaptive` the decisions' and the listing
    /// of the live pixels): on an adapter that compiles a kernel at its first dispatch
    /// (lavapipe), a render's first checks then cost what later ones do.
    pub fn warm_image_kernels(&self, target: bool, adaptive: bool) -> Result<()> {
        // A film of one slot's bytes that holds no pixel.
        let film = self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("warm-up film"),
            size: 16,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        self.stats_pipelines()?.warm(&self.ctx, &film, target, adaptive)?;
        if adaptive {
            self.compact_pipelines()?.warm(&self.ctx, &film)?;
        }
        Ok(())
    }

    /// Opens the best adapter, or the first whose name contains `name_filter`
    /// (case-insensitive): [`GpuContext::new`].
    pub fn open(name_filter: Option<&str>) -> Result<GpuDevice> {
        Ok(GpuDevice::new(GpuContext::new(name_filter)?))
    }
}
