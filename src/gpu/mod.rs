//! The wgpu side: adapter and device, buffers, the AO pipeline, passes and readback.

mod layout;

pub use layout::{DispatchUniforms, FrameUniforms, GpuPlane, GpuProbePoint};

use crate::bvh::{BvhLayout, GpuBvh, GpuPrimitive};
use crate::error::{Error, Result};
use crate::film::Film;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::scene::Scene;
use crate::shaders::{GeometryChunks, GeometryStorage, ROW_TEXEL_MULTIPLE};
use std::cell::Cell;
use std::panic::AssertUnwindSafe;
use std::sync::{Arc, Mutex, MutexGuard};
use wgpu::util::DeviceExt;

/// Test hook: with this environment variable set to N, the renderer destroys its device
/// (`wgpu::Device::destroy`) before its pass N + 1, so that the real device-lost path runs.
pub const TEST_LOSE_DEVICE_ENV: &str = "AORENDER_TEST_LOSE_DEVICE_AFTER_PASSES";

thread_local! {
    /// Depth of [`catch_panic`] calls running on this thread.
    static CATCHING: Cell<u32> = const { Cell::new(0) };
}

/// True while [`catch_panic`] runs on this thread: a panic hook can stay quiet about a
/// panic that becomes an error.
pub fn catching_panics() -> bool {
    CATCHING.with(Cell::get) > 0
}

/// Runs `f`, turning a panic inside it (wgpu's own, or one of the callbacks it invokes,
/// such as buffer mapping and device-lost callbacks) into an error saying `what` failed.
pub fn catch_panic<T>(what: &str, f: impl FnOnce() -> T) -> Result<T> {
    CATCHING.with(|c| c.set(c.get() + 1));
    let result = std::panic::catch_unwind(AssertUnwindSafe(f));
    CATCHING.with(|c| c.set(c.get() - 1));
    result.map_err(|payload| {
        let text = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "no message".into());
        Error::Gpu(format!("wgpu panicked {what}: {}", text.lines().next().unwrap_or("")))
    })
}

/// A device error recorded by the callbacks, most serious first.
#[derive(Debug)]
enum Fault {
    Lost(String),
    OutOfMemory(String),
    Other(String),
}

/// The list of faults, whatever a panicking holder left in it.
fn lock(faults: &Mutex<Vec<Fault>>) -> MutexGuard<'_, Vec<Fault>> {
    faults.lock().unwrap_or_else(|e| e.into_inner())
}

/// Traversal loop iterations one invocation may spend on all its rays together. Mesa
/// 22.3's lavapipe silently ends a SIMD batch of invocations after 65,535 loop
/// iterations, counting every iteration that any of them runs; a traversal that would
/// pass the budget stops and voids its sample, and the pass is rendered again with fewer
/// samples per invocation or reports [`Error::TraversalBudget`].
pub const TRAVERSAL_BUDGET: u32 = 65_000;
/// Mesa 22.3 lavapipe's loop cap per SIMD batch (`LP_MAX_TGSI_LOOP_ITERATIONS`).
pub const LAVAPIPE_LOOP_CAP: u32 = 65_535;
/// The most invocations a CPU driver runs in one SIMD batch (32-bit lanes of a 512-bit
/// vector): where the kernel cannot count a batch's iterations together (no subgroup
/// operations), each invocation's budget is that share of the batch's.
const MAX_BATCH_LANES: u32 = 16;
/// Samples an invocation renders in turn where the BVH alone cannot promise that they
/// fit the loop cap. Each dispatch reads and writes the film and adds its counters once
/// per invocation; a pass that runs out of budget is rendered again with the safe count.
/// The bunny (512², 32 spp, cosine, lavapipe) renders about 10 % faster than with one.
pub const PREFERRED_SAMPLES_PER_INVOCATION: u32 = 16;
/// Loop iterations a sample may take outside the traversal loops: its turn of the
/// kernel's sample loop, the two turns of its ray loop (camera ray, AO ray), the
/// sampler's permutation walks, and the exits of bounded loops.
const SAMPLE_LOOP_OVERHEAD: u32 = crate::sampler::SAMPLER_LOOP_BOUND + 10;
/// Iterations of an invocation outside its samples.
const INVOCATION_LOOP_OVERHEAD: u32 = 8;
const _: () = assert!(TRAVERSAL_BUDGET + SAMPLE_LOOP_OVERHEAD + INVOCATION_LOOP_OVERHEAD <= LAVAPIPE_LOOP_CAP);

/// The traversal iterations a SIMD batch of invocations that each render `samples`
/// samples may run: what lavapipe's cap leaves after their other loops, and at most
/// [`TRAVERSAL_BUDGET`].
fn traversal_budget(samples: u32) -> u32 {
    let other = samples.saturating_mul(SAMPLE_LOOP_OVERHEAD).saturating_add(INVOCATION_LOOP_OVERHEAD);
    TRAVERSAL_BUDGET.min(LAVAPIPE_LOOP_CAP.saturating_sub(other))
}

/// The budget the kernel checks `steps` against in a dispatch of `samples` samples of
/// `rays` rays per invocation, a ray taking at most `ray_steps` iterations. Where that
/// worst case fits, nothing can run out: the batch's whole budget. Otherwise, with
/// `shared` steps (the kernel counts a batch's iterations together, src/shaders.rs
/// `batch_file`) also the batch's budget, and without, each invocation's share: a batch
/// runs each of its loops as long as its longest lane, so at most min(lanes, rays ×
/// samples) times the count of its busiest invocation.
fn dispatch_budget(samples: u32, rays: u32, ray_steps: u64, shared: bool) -> u32 {
    let batch = traversal_budget(samples);
    let worst = samples as u64 * rays as u64 * ray_steps;
    if shared || worst <= batch as u64 { batch } else { batch / MAX_BATCH_LANES.min(rays.saturating_mul(samples)) }
}

/// How many samples one invocation can render in turn without any chance of running out
/// of budget, given `ray_steps`, the most traversal loop iterations one ray can take
/// ([`GpuBvh::ray_steps`] plus the planes): one sample's rays take at most `rays` ×
/// `ray_steps`, and a batch's loops as many. At least 1: a sample that alone could exceed
/// the budget is rendered one per invocation, where running out is detected and reported.
pub fn safe_samples_per_invocation(rays: u32, ray_steps: u64) -> u32 {
    let steps = rays as u64 * ray_steps;
    let mut s = 1;
    while s < MAX_PASS_SAMPLES && (s as u64 + 1) * steps <= traversal_budget(s + 1) as u64 {
        s += 1;
    }
    s
}
/// Workgroup size of the AO kernel: an 8 × 8 tile of pixels (ao.wgsl `tile_pixel` lays
/// them out for that size).
pub const WORKGROUP_SIZE: [u32; 2] = [8, 8];
/// Workgroup size of the probe kernel (one dimension: point × lane slots).
pub const PROBE_WORKGROUP_SIZE: u32 = 64;
/// Invocations in a workgroup of either kernel: the columns of the CWBVH traversal's
/// stacks in workgroup memory.
pub const TRAVERSAL_LANES: u32 = 64;
const _: () = assert!(WORKGROUP_SIZE[0] == 8 && WORKGROUP_SIZE[1] == 8);
const _: () = assert!(WORKGROUP_SIZE[0] * WORKGROUP_SIZE[1] == TRAVERSAL_LANES);
const _: () = assert!(PROBE_WORKGROUP_SIZE == TRAVERSAL_LANES);
// The stacks (8-byte entries) and the workgroup counters fit the 16 KiB of workgroup
// memory that WebGPU's default limits promise.
const _: () = assert!(
    TRAVERSAL_LANES * crate::bvh::CWBVH_STACK_SIZE * 8 + COUNTER_COUNT * 4
        <= wgpu::Limits::downlevel_defaults().max_compute_workgroup_storage_size
);
/// Counter of AO rays traced in a pass.
pub const COUNTER_AO_RAYS: u32 = 0;
/// Counter of samples voided by the traversal budget in a pass.
pub const COUNTER_TRUNCATED: u32 = 1;
/// Number of counters.
pub const COUNTER_COUNT: u32 = 2;
/// Most samples (dispatches) in one pass.
pub const MAX_PASS_SAMPLES: u32 = 1024;
/// Offset of the pass timestamps in the counters' readback buffer.
const TIMESTAMPS_AT: u64 = 256;
/// Stride of the per-dispatch constants (the largest `min_storage_buffer_offset_alignment`).
const DISPATCH_STRIDE: u64 = 256;

/// What `aorender adapters` prints about an adapter.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AdapterDescription {
    /// Adapter name.
    pub name: String,
    /// Backend (Vulkan, Metal, …).
    pub backend: String,
    /// Discrete, integrated, CPU, ….
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
}

impl AdapterDescription {
    fn new(info: &wgpu::AdapterInfo) -> Self {
        AdapterDescription {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        }
    }
}

fn instance() -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends: wgpu::Backends::PRIMARY,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    })
}

/// Every adapter wgpu finds.
pub fn list_adapters() -> Vec<AdapterDescription> {
    let adapters = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::PRIMARY));
    adapters.iter().map(|a| AdapterDescription::new(&a.get_info())).collect()
}

/// An adapter, its device and queue, with device errors captured instead of panicking.
pub struct GpuContext {
    /// The adapter.
    pub adapter: wgpu::Adapter,
    /// The device, created with the adapter's own limits.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter's description.
    pub description: AdapterDescription,
    errors: Arc<Mutex<Vec<Fault>>>,
    /// Compiled pipelines by BVH layout and kernel: many renderers on one context (probe
    /// batches, the accuracy suite) compile each once.
    pipelines: Mutex<Vec<(PipelineKey, wgpu::BindGroupLayout, wgpu::ComputePipeline)>>,
    /// Largest chunk of nodes or primitives in one binding, in bytes.
    max_chunk_bytes: u64,
    /// Where the kernel reads the geometry from.
    geometry_storage: GeometryStorage,
    /// Largest width and height of a geometry texture (the adapter's limit, or less for tests).
    max_texture_size: [u32; 2],
    /// The kernel's `CPU_LANES`: the adapter is a CPU (or a test asks for its formulations).
    cpu_lanes: bool,
}

impl GpuContext {
    /// Opens the best adapter (discrete, then integrated, virtual, CPU), or the first
    /// whose name contains `name_filter` (case-insensitive).
    pub fn new(name_filter: Option<&str>) -> Result<GpuContext> {
        let adapters = pollster::block_on(instance().enumerate_adapters(wgpu::Backends::PRIMARY));
        let rank = |t: wgpu::DeviceType| match t {
            wgpu::DeviceType::DiscreteGpu => 0,
            wgpu::DeviceType::IntegratedGpu => 1,
            wgpu::DeviceType::VirtualGpu => 2,
            wgpu::DeviceType::Cpu => 3,
            wgpu::DeviceType::Other => 4,
        };
        let adapter = match name_filter {
            Some(f) => {
                let f = f.to_lowercase();
                adapters
                    .into_iter()
                    .find(|a| a.get_info().name.to_lowercase().contains(&f))
                    .ok_or_else(|| Error::Gpu(format!("no adapter's name contains '{f}' (see `aorender adapters`)")))?
            }
            None => adapters.into_iter().min_by_key(|a| rank(a.get_info().device_type)).ok_or_else(|| {
                Error::Gpu(
                    "no GPU adapter found: install a Vulkan driver (on Debian/Ubuntu, the \
                     mesa-vulkan-drivers package provides lavapipe), or use --device cpu"
                        .into(),
                )
            })?,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("aorender"),
            // Pass times from timestamp queries, and a traversal budget counted per
            // SIMD batch from subgroup operations, where the adapter has them.
            required_features: adapter.features() & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::SUBGROUP),
            // wgpu's defaults cap a storage binding at 128 MiB: ask for what the adapter has.
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| Error::Gpu(format!("cannot open a device on the adapter: {e}")))?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let text = e.to_string().lines().next().unwrap_or("").to_string();
            lock(&sink).push(match e {
                wgpu::Error::OutOfMemory { .. } => Fault::OutOfMemory(text),
                // Work on a lost device fails with wgpu-core's `DeviceError::Lost` ("Parent
                // device is lost") before the lost callback has run.
                _ if text.to_lowercase().contains("device is lost") => Fault::Lost(text),
                _ => Fault::Other(text),
            });
        }));
        let sink = errors.clone();
        device.set_device_lost_callback(move |reason, message| {
            let message = message.lines().next().unwrap_or("").trim().to_string();
            lock(&sink).push(Fault::Lost(if message.is_empty() {
                format!("{reason:?}")
            } else {
                format!("{message} ({reason:?})")
            }));
        });
        let description = AdapterDescription::new(&adapter.get_info());
        let limits = device.limits();
        let max_chunk_bytes = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let geometry_storage = GeometryStorage::preferred(adapter.get_info().device_type);
        let max_texture_size = [limits.max_texture_dimension_2d; 2];
        let cpu_lanes = adapter.get_info().device_type == wgpu::DeviceType::Cpu;
        Ok(GpuContext {
            adapter,
            device,
            queue,
            description,
            errors,
            pipelines: Mutex::new(Vec::new()),
            max_chunk_bytes,
            geometry_storage,
            max_texture_size,
            cpu_lanes,
        })
    }

    /// Where the kernel reads the BVH nodes and primitives from: by default textures on a
    /// CPU adapter (lavapipe), storage buffers elsewhere ([`GeometryStorage::preferred`]).
    pub fn geometry_storage(&self) -> GeometryStorage {
        self.geometry_storage
    }

    /// Reads the geometry from `storage` in renderers made from now on.
    pub fn set_geometry_storage(&mut self, storage: GeometryStorage) {
        self.geometry_storage = storage;
    }

    /// Compiles renderers made from now on with `CPU_LANES` = `cpu_lanes` (by default
    /// true where the adapter is a CPU): the traversal then takes the formulations that
    /// compile to fewer instructions on a CPU. Either choice runs on any adapter and
    /// renders the same film (tests compare the two).
    pub fn set_cpu_lanes(&mut self, cpu_lanes: bool) {
        self.cpu_lanes = cpu_lanes;
    }

    /// Caps the width and height of a geometry texture below the adapter's limit, so that
    /// small scenes are split into several textures as large ones are (for testing the
    /// split). The width is rounded down to a multiple of [`ROW_TEXEL_MULTIPLE`].
    pub fn limit_texture_size(&mut self, width: u32, height: u32) {
        self.max_texture_size = [self.max_texture_size[0].min(width), self.max_texture_size[1].min(height).max(1)];
    }

    /// Caps the bytes of nodes or primitives in one binding below the adapter's limit, so
    /// that small scenes are split into chunks as large ones are (for testing the split).
    pub fn limit_chunk_bytes(&mut self, bytes: u64) {
        self.max_chunk_bytes = self.max_chunk_bytes.min(bytes);
    }

    /// How `nodes` nodes and `primitives` primitives split into chunks of at most one
    /// binding each, or an error with the numbers when the adapter has too few bindings
    /// per shader stage for them.
    fn geometry_chunks(&self, layout: BvhLayout, nodes: usize, primitives: usize) -> Result<GeometryChunks> {
        let node_size = layout.node_size();
        let prim_size = std::mem::size_of::<GpuPrimitive>();
        let limits = self.device.limits();
        let storage = self.geometry_storage;
        // Texels in a texture row (0 for buffers), and the bytes one binding holds at most.
        let (row_texels, chunk_bytes) = match storage {
            GeometryStorage::Buffers => (0, self.max_chunk_bytes),
            GeometryStorage::Textures => {
                let [width, rows] = self.max_texture_size;
                let row = width / ROW_TEXEL_MULTIPLE * ROW_TEXEL_MULTIPLE;
                if row == 0 {
                    return Err(Error::Gpu(format!(
                        "textures of {width} texels are too narrow for the geometry: it needs {ROW_TEXEL_MULTIPLE}"
                    )));
                }
                (row, row as u64 * rows as u64 * 16)
            }
        };
        // An element is a whole number of texels and a row a whole number of elements, so
        // a texture holds exactly chunk_bytes / size of them.
        let per_chunk = |size: usize| (chunk_bytes / size as u64).clamp(1, u32::MAX as u64) as u32;
        let (nodes_per_chunk, primitives_per_chunk) = (per_chunk(node_size), per_chunk(prim_size));
        let chunks = GeometryChunks {
            storage,
            node_chunks: (nodes.div_ceil(nodes_per_chunk as usize) as u32).max(1),
            nodes_per_chunk,
            primitive_chunks: (primitives.div_ceil(primitives_per_chunk as usize) as u32).max(1),
            primitives_per_chunk,
            row_texels,
        };
        let (allowed, limit_name) = match storage {
            GeometryStorage::Buffers => (
                limits.max_storage_buffers_per_shader_stage.saturating_sub(OTHER_STORAGE_BINDINGS),
                "max_storage_buffers_per_shader_stage (less the kernel's other bindings) \
                 × max_storage_buffer_binding_size",
            ),
            GeometryStorage::Textures => (
                limits.max_storage_textures_per_shader_stage,
                "max_storage_textures_per_shader_stage × the texels of a texture (max_texture_dimension_2d²)",
            ),
        };
        if chunks.node_chunks + chunks.primitive_chunks > allowed {
            return Err(Error::TooLarge {
                what: "the BVH nodes and primitives",
                needed: (nodes * node_size + primitives * prim_size) as u64,
                limit: allowed as u64 * chunk_bytes,
                limit_name,
            });
        }
        Ok(chunks)
    }

    /// The bind group layout and pipeline of `kernel` over `layout`, compiled on first use.
    /// The bool is true when it was compiled just now.
    fn pipeline(&self, key: PipelineKey) -> Result<(wgpu::BindGroupLayout, wgpu::ComputePipeline, bool)> {
        let PipelineKey { layout, kernel, chunks, stack_size, .. } = key;
        let mut cache = self.pipelines.lock().expect("pipeline cache");
        if let Some((_, l, p)) = cache.iter().find(|(k, _, _)| *k == key) {
            return Ok((l.clone(), p.clone(), false));
        }
        let source =
            crate::shaders::compose("ao.wgsl", layout, chunks, stack_size, self.shared_steps()).map_err(Error::Gpu)?;
        let device = &self.device;
        let entry = |binding: u32, ty: wgpu::BufferBindingType, dynamic: bool| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: dynamic, min_binding_size: None },
            count: None,
        };
        let read_only = wgpu::BufferBindingType::Storage { read_only: true };
        let read_write = wgpu::BufferBindingType::Storage { read_only: false };
        let geometry = |binding: u32| match chunks.storage {
            GeometryStorage::Buffers => entry(binding, read_only, false),
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
        let mut entries = vec![
            entry(0, read_only, false),
            entry(1, read_only, true),
            entry(4, read_only, false),
            entry(5, read_write, false),
            entry(6, read_write, false),
            entry(7, read_only, false),
        ];
        entries.extend((0..chunks.node_chunks).map(|k| geometry(GeometryChunks::node_binding(k))));
        entries.extend((0..chunks.primitive_chunks).map(|k| geometry(GeometryChunks::primitive_binding(k))));
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
            entry_point: Some(match kernel {
                Kernel::Image => "render_sample",
                Kernel::Probe => "probe_sample",
            }),
            compilation_options: wgpu::PipelineCompilationOptions { constants: &key.constants(), ..Default::default() },
            cache: None,
        });
        cache.push((key, bind_group_layout.clone(), pipeline.clone()));
        Ok((bind_group_layout, pipeline, true))
    }

    /// Whether the kernel counts a SIMD batch's traversal iterations together (the device
    /// has subgroup operations): src/shaders.rs `batch_file`.
    fn shared_steps(&self) -> bool {
        self.device.features().contains(wgpu::Features::SUBGROUP)
    }

    /// The most serious device error since the last call, if any: a lost device, then
    /// running out of memory, then the first other error.
    fn take_error(&self) -> Result<()> {
        let faults = std::mem::take(&mut *lock(&self.errors));
        let adapter = self.description.name.clone();
        let lost = faults.iter().find_map(|f| if let Fault::Lost(m) = f { Some(m) } else { None });
        let oom = faults.iter().find_map(|f| if let Fault::OutOfMemory(m) = f { Some(m) } else { None });
        if let Some(message) = lost {
            return Err(Error::DeviceLost { adapter, message: message.clone() });
        }
        if let Some(message) = oom {
            return Err(Error::OutOfMemory { adapter, message: message.clone() });
        }
        match faults.first() {
            Some(Fault::Other(e)) => Err(Error::Gpu(format!("GPU error: {e}"))),
            _ => Ok(()),
        }
    }

    /// The recorded device error if there is one (a lost device explains most failures),
    /// else `fallback`.
    fn fault(&self, fallback: String) -> Error {
        self.take_error().err().unwrap_or(Error::Gpu(fallback))
    }

    /// Submits `commands`; a panic inside wgpu becomes an error.
    fn submit(&self, commands: impl IntoIterator<Item = wgpu::CommandBuffer>) -> Result<()> {
        catch_panic("submitting work", || {
            self.queue.submit(commands);
        })?;
        self.take_error()
    }

    /// Waits for the submitted work, running the callbacks it completes (buffer mappings,
    /// device loss); a panic inside wgpu or a callback becomes an error.
    pub fn wait(&self) -> Result<()> {
        let polled = catch_panic("while waiting for the GPU", || self.device.poll(wgpu::PollType::wait_indefinitely()));
        self.take_error()?;
        polled?.map_err(|e| self.fault(format!("waiting for the GPU failed: {e}")))?;
        Ok(())
    }

    fn check_size(&self, what: &'static str, bytes: u64) -> Result<()> {
        let limits = self.device.limits();
        let binding = limits.max_storage_buffer_binding_size;
        if bytes > binding {
            return Err(Error::TooLarge {
                what,
                needed: bytes,
                limit: binding,
                limit_name: "max_storage_buffer_binding_size",
            });
        }
        if bytes > limits.max_buffer_size {
            return Err(Error::TooLarge {
                what,
                needed: bytes,
                limit: limits.max_buffer_size,
                limit_name: "max_buffer_size",
            });
        }
        Ok(())
    }
}

/// What one pass did.
#[derive(Clone, Copy, Debug, Default)]
pub struct PassCounters {
    /// AO rays traced.
    pub ao_rays: u64,
    /// Seconds between the pass's first and last GPU timestamps, where the adapter has
    /// timestamp queries.
    pub gpu_seconds: Option<f64>,
}

/// What a compiled pipeline is specialised for. Besides the layout, kernel and geometry
/// split: what the scene holds, the sampler, the hemisphere mapping and whether to take
/// a CPU adapter's formulations, as the shaders' override constants, so that the compiler
/// drops every path the render cannot take (lavapipe runs a SIMD batch's lanes in
/// lockstep and pays for every branch that is not constant); and the traversal stack's
/// size, the BVH's depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PipelineKey {
    layout: BvhLayout,
    kernel: Kernel,
    chunks: GeometryChunks,
    /// `HAS_INSTANCES`: the BVH has instances.
    instances: bool,
    /// `HAS_SPHERES`: the scene has spheres.
    spheres: bool,
    /// `HAS_TRIANGLES`: the scene has triangles, placed once or instanced.
    triangles: bool,
    /// `HAS_PLANES`: the scene has planes.
    planes: bool,
    /// `SAMPLER`.
    sampler: Sampler,
    /// `HEMISPHERE`.
    hemisphere: Hemisphere,
    /// `STACK_SIZE`.
    stack_size: u32,
    /// `CPU_LANES`.
    cpu_lanes: bool,
}

impl PipelineKey {
    /// The key for rendering `scene` through `bvh` with `kernel`, its geometry split as
    /// `chunks`.
    fn new(scene: &Scene, bvh: &GpuBvh, kernel: Kernel, chunks: GeometryChunks, cpu_lanes: bool) -> PipelineKey {
        let s = &scene.settings;
        PipelineKey {
            layout: bvh.layout,
            kernel,
            chunks,
            // The BVH2 layout flattens instances.
            instances: bvh.layout == BvhLayout::Cwbvh && !scene.instances.is_empty(),
            spheres: !scene.spheres.is_empty(),
            triangles: !scene.triangles.is_empty() || !scene.instances.is_empty(),
            planes: !scene.planes.is_empty(),
            sampler: s.sampler,
            hemisphere: s.hemisphere,
            stack_size: bvh.stack_size(),
            cpu_lanes,
        }
    }

    /// The override constants' values.
    fn constants(&self) -> [(&'static str, f64); 7] {
        let flag = |b: bool| if b { 1.0 } else { 0.0 };
        [
            ("HAS_INSTANCES", flag(self.instances)),
            ("HAS_SPHERES", flag(self.spheres)),
            ("HAS_TRIANGLES", flag(self.triangles)),
            ("HAS_PLANES", flag(self.planes)),
            ("CPU_LANES", flag(self.cpu_lanes)),
            ("SAMPLER", self.sampler.shader_id() as f64),
            ("HEMISPHERE", self.hemisphere.shader_id() as f64),
        ]
    }
}

/// Storage bindings of the kernel besides the node and primitive chunks: frame,
/// dispatch, planes, film, counters, probe points.
pub const OTHER_STORAGE_BINDINGS: u32 = 6;

/// What the AO pipeline computes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Kernel {
    /// An image: one film slot per pixel, one sample per pixel per dispatch.
    Image,
    /// Probe points: `width` lanes for each of `height` points, one sample per lane per dispatch.
    Probe,
}

/// The AO pipeline bound to one scene and image size (or one set of probe points).
pub struct GpuRenderer<'a> {
    ctx: &'a GpuContext,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    film: wgpu::Buffer,
    film_readback: wgpu::Buffer,
    dispatch: wgpu::Buffer,
    counters: wgpu::Buffer,
    counters_readback: wgpu::Buffer,
    /// Start and end timestamps of a pass, resolved into `timestamps_resolved`, where
    /// the adapter has timestamp queries.
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    width: u32,
    height: u32,
    kernel: Kernel,
    /// Samples (or probe rounds) each invocation renders in turn.
    samples_per_invocation: u32,
    /// The most that cannot run out of traversal budget.
    safe_samples_per_invocation: u32,
    /// Rays of one sample (or probe round) of one invocation.
    rays_per_sample: u32,
    /// The most traversal iterations one ray can take.
    ray_steps: u64,
    /// Bytes of device memory the renderer allocated.
    pub device_bytes: u64,
    /// Bindings holding the BVH nodes and the primitives.
    pub geometry_bindings: u32,
    /// Whether those are storage buffers or textures.
    pub geometry_storage: GeometryStorage,
    /// The BVH layout the kernel traverses.
    pub layout: BvhLayout,
    /// Passes started.
    passes_run: u32,
    /// The test hook's pass count ([`TEST_LOSE_DEVICE_ENV`]).
    lose_device_after: Option<u32>,
}

/// `bytes` in chunks of `per_chunk` elements of `element` bytes; one empty chunk when
/// `bytes` is empty.
fn chunk_ranges(count: usize, per_chunk: u32) -> impl Iterator<Item = std::ops::Range<usize>> {
    let per_chunk = (per_chunk as usize).max(1);
    let chunks = count.div_ceil(per_chunk).max(1);
    (0..chunks).map(move |k| k * per_chunk..((k + 1) * per_chunk).min(count))
}

/// Bytes filled at a time when an upload is made piece by piece.
const UPLOAD_PIECE: usize = 1 << 20;

/// Makes bytes `0..len` a piece at a time: each piece, whole elements of about
/// [`UPLOAD_PIECE`] bytes, is filled by `fill(offset, piece)` and handed to `put(offset,
/// piece)`.
fn fill_pieces(len: usize, element: usize, fill: &mut dyn FnMut(usize, &mut [u8]), put: &mut dyn FnMut(usize, &[u8])) {
    let step = (UPLOAD_PIECE / element).max(1) * element;
    let mut piece = Vec::with_capacity(step.min(len));
    for at in (0..len).step_by(step) {
        piece.resize(step.min(len - at), 0);
        fill(at, &mut piece);
        put(at, &piece);
    }
}

/// A read-only storage buffer; `element` is the size of one array element in the shader.
fn storage(ctx: &GpuContext, label: &'static str, bytes: &[u8], element: usize) -> Result<wgpu::Buffer> {
    storage_filled(ctx, label, bytes.len(), element, &mut |at, out| out.copy_from_slice(&bytes[at..at + out.len()]))
}

/// A read-only storage buffer of `len` bytes written through its mapping by `fill(offset,
/// piece)`, so no copy of the whole is needed on the host.
fn storage_filled(
    ctx: &GpuContext,
    label: &'static str,
    len: usize,
    element: usize,
    fill: &mut dyn FnMut(usize, &mut [u8]),
) -> Result<wgpu::Buffer> {
    // A binding may not be empty: absent data is one zeroed element (wgpu zeroes buffers).
    let size = len.max(element) as u64;
    ctx.check_size(label, size)?;
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: true,
    });
    let mut mapped = Ok(());
    fill_pieces(len, element, fill, &mut |at, piece| {
        let range = at as u64..(at + piece.len()) as u64;
        match buffer.slice(range).get_mapped_range_mut() {
            Ok(mut view) => view.copy_from_slice(piece),
            Err(e) => mapped = Err(ctx.fault(format!("cannot write the mapped {label} buffer: {e}"))),
        }
    });
    mapped?;
    buffer.unmap();
    Ok(buffer)
}

/// One chunk of nodes or primitives on the device.
enum Geometry {
    Buffer(wgpu::Buffer),
    Texture(wgpu::TextureView, u64),
}

impl Geometry {
    /// Uploads `len` bytes, elements of `element` bytes, as `chunks` says; `fill(offset,
    /// piece)` writes them a piece at a time.
    fn upload(
        ctx: &GpuContext,
        label: &'static str,
        len: usize,
        element: usize,
        chunks: GeometryChunks,
        fill: &mut dyn FnMut(usize, &mut [u8]),
    ) -> Result<Geometry> {
        match chunks.storage {
            GeometryStorage::Buffers => storage_filled(ctx, label, len, element, fill).map(Geometry::Buffer),
            GeometryStorage::Textures => texels(ctx, label, len, element, chunks.row_texels, fill),
        }
    }

    fn resource(&self) -> wgpu::BindingResource<'_> {
        match self {
            Geometry::Buffer(b) => b.as_entire_binding(),
            Geometry::Texture(view, _) => wgpu::BindingResource::TextureView(view),
        }
    }

    fn bytes(&self) -> u64 {
        match self {
            Geometry::Buffer(b) => b.size(),
            Geometry::Texture(_, bytes) => *bytes,
        }
    }
}

/// An `Rgba32Uint` texture `row_texels` wide holding `len` bytes row after row (elements
/// of `element` bytes never straddle rows: `row_texels` is a multiple of their texels),
/// written by `fill(offset, piece)` a few rows at a time.
fn texels(
    ctx: &GpuContext,
    label: &'static str,
    len: usize,
    element: usize,
    row_texels: u32,
    fill: &mut dyn FnMut(usize, &mut [u8]),
) -> Result<Geometry> {
    const TEXEL: usize = 16;
    debug_assert_eq!(len % TEXEL, 0);
    let row_bytes = row_texels as usize * TEXEL;
    debug_assert_eq!(row_bytes % element, 0);
    let full_rows = (len / row_bytes) as u32;
    let rest = len % row_bytes;
    let rows = (full_rows + (rest > 0) as u32).max(1);
    let max = ctx.device.limits().max_texture_dimension_2d;
    if rows > max {
        return Err(Error::TooLarge {
            what: label,
            needed: len as u64,
            limit: max as u64 * row_bytes as u64,
            limit_name: "max_texture_dimension_2d² texels of 16 bytes",
        });
    }
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: row_texels, height: rows, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Uint,
        usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    let write = |y: u32, width: u32, height: u32, data: &[u8]| {
        ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: 0,
                origin: wgpu::Origin3d { x: 0, y, z: 0 },
                aspect: wgpu::TextureAspect::All,
            },
            data,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(width * TEXEL as u32),
                rows_per_image: Some(height),
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
    };
    // Pieces of whole rows, then the last, partial row on its own.
    let whole = full_rows as usize * row_bytes;
    fill_pieces(whole, row_bytes, fill, &mut |at, piece| {
        write((at / row_bytes) as u32, row_texels, (piece.len() / row_bytes) as u32, piece)
    });
    if rest > 0 {
        let mut piece = vec![0; rest];
        fill(whole, &mut piece);
        write(full_rows, (rest / TEXEL) as u32, 1, &piece);
    }
    // The writes wait in the queue's staging memory until a submission: send them now.
    ctx.queue.submit([]);
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    Ok(Geometry::Texture(view, rows as u64 * row_bytes as u64))
}

impl<'a> GpuRenderer<'a> {
    /// Uploads the scene and builds the image pipeline.
    pub fn new(ctx: &'a GpuContext, scene: &Scene, bvh: &GpuBvh) -> Result<GpuRenderer<'a>> {
        let s = &scene.settings;
        let frame = FrameUniforms::new(scene, bvh.node_count);
        GpuRenderer::build(ctx, scene, bvh, Kernel::Image, frame, &[], [s.width, s.height])
    }

    /// Uploads the scene and `points`, and builds the probe pipeline: `lanes` film slots
    /// per point share the point's `samples` sample indices (see [`GpuRenderer::render_pass`]).
    pub fn for_probes(
        ctx: &'a GpuContext,
        scene: &Scene,
        bvh: &GpuBvh,
        points: &[GpuProbePoint],
        lanes: u32,
        samples: u32,
    ) -> Result<GpuRenderer<'a>> {
        let slots = lanes as u64 * points.len() as u64;
        let max_slots = ctx.device.limits().max_compute_workgroups_per_dimension as u64 * PROBE_WORKGROUP_SIZE as u64;
        if slots > max_slots {
            return Err(Error::Gpu(format!(
                "{} probe points × {lanes} lanes need {slots} invocations per dispatch; the adapter allows {max_slots}",
                points.len()
            )));
        }
        let mut frame = FrameUniforms::new(scene, bvh.node_count);
        frame.width = lanes;
        frame.height = points.len() as u32;
        frame.probe_samples = samples;
        frame.strata = scene.settings.sampler.strata_per_axis(samples);
        GpuRenderer::build(ctx, scene, bvh, Kernel::Probe, frame, points, [lanes, points.len() as u32])
    }

    fn build(
        ctx: &'a GpuContext,
        scene: &Scene,
        bvh: &GpuBvh,
        kernel: Kernel,
        frame: FrameUniforms,
        points: &[GpuProbePoint],
        [width, height]: [u32; 2],
    ) -> Result<GpuRenderer<'a>> {
        if bvh.depth > bvh.layout.stack_size() {
            return Err(Error::Gpu(format!(
                "the {} BVH is {} levels deep; the shader's traversal stack holds {}",
                bvh.layout.name(),
                bvh.depth,
                bvh.layout.stack_size()
            )));
        }
        let device = &ctx.device;
        let frame = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("frame"),
            contents: bytemuck::bytes_of(&frame),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let dispatch = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("dispatch"),
            size: DISPATCH_STRIDE * MAX_PASS_SAMPLES as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let node_size = bvh.layout.node_size();
        let record_count = bvh.records.len();
        let chunks = ctx.geometry_chunks(bvh.layout, bvh.node_count as usize, record_count)?;
        let nodes: Vec<Geometry> = chunk_ranges(bvh.node_count as usize, chunks.nodes_per_chunk)
            .map(|r| {
                let bytes = &bvh.node_bytes[r.start * node_size..r.end * node_size];
                Geometry::upload(ctx, "BVH nodes", bytes.len(), node_size, chunks, &mut |at, out| {
                    out.copy_from_slice(&bytes[at..at + out.len()])
                })
            })
            .collect::<Result<_>>()?;
        let prim_size = std::mem::size_of::<GpuPrimitive>();
        // Records are made from the scene a piece at a time, straight into the upload.
        let mut piece: Vec<GpuPrimitive> = Vec::new();
        let primitives: Vec<Geometry> = chunk_ranges(record_count, chunks.primitives_per_chunk)
            .map(|r| {
                Geometry::upload(ctx, "primitives", r.len() * prim_size, prim_size, chunks, &mut |at, out| {
                    piece.resize(out.len() / prim_size, bytemuck::Zeroable::zeroed());
                    bvh.records.write(scene, r.start + at / prim_size, &mut piece);
                    out.copy_from_slice(bytemuck::cast_slice(&piece));
                })
            })
            .collect::<Result<_>>()?;
        let planes: Vec<GpuPlane> = scene.planes.iter().map(GpuPlane::from).collect();
        let planes = storage(ctx, "planes", bytemuck::cast_slice(&planes), std::mem::size_of::<GpuPlane>())?;
        let probe_points =
            storage(ctx, "probe points", bytemuck::cast_slice(points), std::mem::size_of::<GpuProbePoint>())?;
        let film_bytes = width as u64 * height as u64 * 16;
        ctx.check_size("film", film_bytes)?;
        let film = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("film"),
            size: film_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let film_readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("film readback"),
            size: film_bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let counter_bytes = 4 * COUNTER_COUNT as u64;
        let timestamps = ctx.device.features().contains(wgpu::Features::TIMESTAMP_QUERY).then(|| {
            let set = device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            });
            let resolved = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pass timestamps"),
                size: 2 * wgpu::QUERY_SIZE as u64,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (set, resolved)
        });
        let counters = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("counters"),
            size: counter_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        // The counters, then the timestamps at TIMESTAMPS_AT.
        let counters_readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("counters readback"),
            size: TIMESTAMPS_AT + 2 * wgpu::QUERY_SIZE as u64,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let (layout, pipeline, fresh) = ctx.pipeline(PipelineKey::new(scene, bvh, kernel, chunks, ctx.cpu_lanes))?;
        let dispatch_binding = wgpu::BufferBinding {
            buffer: &dispatch,
            offset: 0,
            size: wgpu::BufferSize::new(std::mem::size_of::<DispatchUniforms>() as u64),
        };
        let mut entries = vec![
            wgpu::BindGroupEntry { binding: 0, resource: frame.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::Buffer(dispatch_binding) },
            wgpu::BindGroupEntry { binding: 4, resource: planes.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 5, resource: film.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 6, resource: counters.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 7, resource: probe_points.as_entire_binding() },
        ];
        for (k, g) in nodes.iter().enumerate() {
            entries
                .push(wgpu::BindGroupEntry { binding: GeometryChunks::node_binding(k as u32), resource: g.resource() });
        }
        for (k, g) in primitives.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry {
                binding: GeometryChunks::primitive_binding(k as u32),
                resource: g.resource(),
            });
        }
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ao bindings"),
            layout: &layout,
            entries: &entries,
        });
        ctx.take_error()?;
        // Some drivers (lavapipe) compile the kernel at its first dispatch: run one
        // workgroup of a new pipeline now, so compilation counts as setup rather than
        // render time, then clear what it wrote.
        if fresh {
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("warm-up") });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("warm-up"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&pipeline);
                pass.set_bind_group(0, &bind_group, &[0]);
                pass.dispatch_workgroups(1, 1, 1);
            }
            encoder.clear_buffer(&film, 0, None);
            encoder.clear_buffer(&counters, 0, None);
            ctx.submit([encoder.finish()])?;
            ctx.wait()?;
        }
        ctx.take_error()?;
        let device_bytes =
            [&frame, &dispatch, &planes, &probe_points, &film, &film_readback, &counters, &counters_readback]
                .into_iter()
                .map(|b| b.size())
                .chain(nodes.iter().chain(&primitives).map(Geometry::bytes))
                .sum();
        let rays_per_sample = match kernel {
            Kernel::Image => 2,
            Kernel::Probe => 1,
        };
        let ray_steps = bvh.ray_steps(scene) + scene.planes.len() as u64;
        let safe_samples_per_invocation = safe_samples_per_invocation(rays_per_sample, ray_steps);
        Ok(GpuRenderer {
            ctx,
            pipeline,
            bind_group,
            film,
            film_readback,
            dispatch,
            counters,
            counters_readback,
            timestamps,
            width,
            height,
            kernel,
            samples_per_invocation: safe_samples_per_invocation.max(PREFERRED_SAMPLES_PER_INVOCATION),
            safe_samples_per_invocation,
            rays_per_sample,
            ray_steps,
            device_bytes,
            geometry_bindings: (nodes.len() + primitives.len()) as u32,
            geometry_storage: chunks.storage,
            layout: bvh.layout,
            passes_run: 0,
            lose_device_after: std::env::var(TEST_LOSE_DEVICE_ENV).ok().and_then(|v| v.trim().parse().ok()),
        })
    }

    /// Samples (or probe rounds) each invocation renders in turn.
    pub fn samples_per_invocation(&self) -> u32 {
        self.samples_per_invocation
    }

    /// Sets the samples each invocation renders in turn, at most [`MAX_PASS_SAMPLES`];
    /// returns the value set. The film is the same, bit for bit, whatever the setting:
    /// each invocation adds its samples in order, as one dispatch per sample would, and a
    /// pass that runs out of budget with more than [`safe_samples_per_invocation`] is
    /// rendered again with that many.
    pub fn set_samples_per_invocation(&mut self, samples: u32) -> u32 {
        self.samples_per_invocation = samples.clamp(1, MAX_PASS_SAMPLES);
        self.samples_per_invocation
    }

    /// Adds samples `first .. first + count` of every pixel to the film, in order, and
    /// waits for them. For probes, `first .. first + count` are rounds: round r gives lane
    /// l of every point the sample index r × lanes + l.
    ///
    /// With more samples per invocation than are safe, the film is copied aside first; if
    /// a ray runs out of budget, the copy is put back and the pass rendered again with the
    /// safe count, which the renderer keeps from then on.
    pub fn render_pass(&mut self, first: u32, count: u32) -> Result<PassCounters> {
        let per = self.samples_per_invocation;
        let guarded = per.min(count) > self.safe_samples_per_invocation;
        let (mut counters, mut truncated) = self.run_pass(first, count, guarded)?;
        if truncated > 0 && guarded {
            let words: Vec<[f32; 4]> = self.read(&self.film_readback)?;
            self.set_film_words(&words)?;
            self.samples_per_invocation = self.safe_samples_per_invocation;
            (counters, truncated) = self.run_pass(first, count, false)?;
        }
        if truncated == 0 {
            return Ok(counters);
        }
        let budget = self.dispatch_budget(self.samples_per_invocation.min(count));
        Err(Error::TraversalBudget { count: truncated, budget })
    }

    /// The traversal budget of a dispatch of `samples` samples per invocation.
    fn dispatch_budget(&self, samples: u32) -> u32 {
        dispatch_budget(samples, self.rays_per_sample, self.ray_steps, self.ctx.shared_steps())
    }

    /// One try at [`GpuRenderer::render_pass`], copying the film to the readback buffer
    /// first where `keep_film` is set; returns its counters and how many samples ran out
    /// of budget.
    fn run_pass(&mut self, first: u32, count: u32, keep_film: bool) -> Result<(PassCounters, u64)> {
        assert!((1..=MAX_PASS_SAMPLES).contains(&count), "pass of {count} samples");
        if self.lose_device_after == Some(self.passes_run) {
            self.ctx.device.destroy();
        }
        self.passes_run += 1;
        let per = self.samples_per_invocation;
        let dispatches = count.div_ceil(per);
        let mut uniforms = vec![0u8; (DISPATCH_STRIDE * dispatches as u64) as usize];
        for k in 0..dispatches {
            let n = per.min(count - k * per);
            let u = DispatchUniforms {
                first_sample: first.wrapping_add(k * per),
                sample_count: n,
                traversal_budget: self.dispatch_budget(n),
                _pad: 0,
            };
            let at = (DISPATCH_STRIDE * k as u64) as usize;
            uniforms[at..at + std::mem::size_of::<DispatchUniforms>()].copy_from_slice(bytemuck::bytes_of(&u));
        }
        self.ctx.queue.write_buffer(&self.dispatch, 0, &uniforms);
        let mut encoder =
            self.ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("pass") });
        encoder.clear_buffer(&self.counters, 0, None);
        if keep_film {
            encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, None);
        }
        {
            let timestamp_writes = self.timestamps.as_ref().map(|(set, _)| wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            });
            let mut pass =
                encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("ao"), timestamp_writes });
            pass.set_pipeline(&self.pipeline);
            let (groups_x, groups_y) = match self.kernel {
                Kernel::Image => (self.width.div_ceil(WORKGROUP_SIZE[0]), self.height.div_ceil(WORKGROUP_SIZE[1])),
                Kernel::Probe => ((self.width * self.height).div_ceil(PROBE_WORKGROUP_SIZE), 1),
            };
            for k in 0..dispatches {
                pass.set_bind_group(0, &self.bind_group, &[(DISPATCH_STRIDE * k as u64) as u32]);
                pass.dispatch_workgroups(groups_x, groups_y, 1);
            }
        }
        encoder.copy_buffer_to_buffer(&self.counters, 0, &self.counters_readback, 0, Some(4 * COUNTER_COUNT as u64));
        if let Some((set, resolved)) = &self.timestamps {
            encoder.resolve_query_set(set, 0..2, resolved, 0);
            encoder.copy_buffer_to_buffer(resolved, 0, &self.counters_readback, TIMESTAMPS_AT, None);
        }
        self.ctx.submit([encoder.finish()])?;
        let words: Vec<u32> = self.read(&self.counters_readback)?;
        let gpu_seconds = self.timestamps.as_ref().map(|_| {
            let at = (TIMESTAMPS_AT / 4) as usize;
            let tick = |k: usize| words[at + 2 * k] as u64 | (words[at + 2 * k + 1] as u64) << 32;
            tick(1).wrapping_sub(tick(0)) as f64 * self.ctx.queue.get_timestamp_period() as f64 * 1e-9
        });
        let truncated = words[COUNTER_TRUNCATED as usize] as u64;
        Ok((PassCounters { ao_rays: words[COUNTER_AO_RAYS as usize] as u64, gpu_seconds }, truncated))
    }

    /// Copies the film back: per-pixel compensated sums as f64.
    pub fn read_film(&self, samples: u64) -> Result<Film> {
        let mut encoder =
            self.ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("film readback") });
        encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, None);
        self.ctx.submit([encoder.finish()])?;
        let texels: Vec<[f32; 4]> = self.read(&self.film_readback)?;
        let mut film = Film::new(self.width, self.height);
        film.samples = samples;
        for (i, t) in texels.iter().enumerate() {
            film.sum[i] = t[0] as f64 + t[1] as f64;
            film.sum_sq[i] = t[2] as f64 + t[3] as f64;
        }
        Ok(film)
    }

    /// Maps a readback buffer after the last submission and copies it out.
    fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>> {
        let (tx, rx) = std::sync::mpsc::channel();
        catch_panic("mapping a readback buffer", || {
            buffer.map_async(wgpu::MapMode::Read, .., move |r| {
                let _ = tx.send(r);
            })
        })?;
        self.ctx.wait()?;
        let ctx = self.ctx;
        rx.recv()
            .map_err(|_| ctx.fault("buffer mapping was dropped".into()))?
            .map_err(|e| ctx.fault(format!("cannot map a readback buffer: {e}")))?;
        catch_panic("reading a readback buffer", || {
            let data = {
                let view =
                    buffer.get_mapped_range(..).map_err(|e| ctx.fault(format!("cannot read a mapped buffer: {e}")))?;
                bytemuck::cast_slice(&view).to_vec()
            };
            buffer.unmap();
            Ok(data)
        })?
    }

    /// The film's raw words, one `[Σv, compensation, Σv², compensation]` per slot, as
    /// the kernel left them: with [`GpuRenderer::set_film_words`], a render can stop and
    /// go on later from the same bits.
    pub fn film_words(&self) -> Result<Vec<[f32; 4]>> {
        let mut encoder =
            self.ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("film words") });
        encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, None);
        self.ctx.submit([encoder.finish()])?;
        self.read(&self.film_readback)
    }

    /// Replaces the film with `words` (as [`GpuRenderer::film_words`] returned them).
    pub fn set_film_words(&mut self, words: &[[f32; 4]]) -> Result<()> {
        let slots = self.width as usize * self.height as usize;
        if words.len() != slots {
            return Err(Error::Gpu(format!("{} film slots given for a film of {slots}", words.len())));
        }
        self.ctx.queue.write_buffer(&self.film, 0, bytemuck::cast_slice(words));
        self.ctx.submit([])?;
        self.ctx.wait()
    }

    /// Zeroes the film.
    pub fn clear_film(&mut self) -> Result<()> {
        let mut encoder =
            self.ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("clear film") });
        encoder.clear_buffer(&self.film, 0, None);
        self.ctx.submit([encoder.finish()])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The chosen count fits: its worst-case traversal within the budget, the budget and
    /// the other loops within lavapipe's cap; one more would not fit.
    #[test]
    fn safe_samples_per_invocation_fill_the_loop_cap() {
        for (rays, ray_steps) in [(2, 3), (2, 1), (2, 9), (1, 1762), (2, 1762), (2, 60_000)] {
            let steps = rays as u64 * ray_steps;
            let s = safe_samples_per_invocation(rays, ray_steps);
            let budget = traversal_budget(s);
            assert!(
                budget as u64 + (s * SAMPLE_LOOP_OVERHEAD + INVOCATION_LOOP_OVERHEAD) as u64
                    <= LAVAPIPE_LOOP_CAP as u64
            );
            if s > 1 {
                assert!(s as u64 * steps <= budget as u64, "{s} × {steps} steps > {budget}");
            }
            if s < MAX_PASS_SAMPLES {
                assert!((s as u64 + 1) * steps > traversal_budget(s + 1) as u64, "{} would fit too", s + 1);
            }
        }
        assert_eq!(safe_samples_per_invocation(2, 60_000), 1);
        assert_eq!(traversal_budget(1), TRAVERSAL_BUDGET);
    }

    /// A batch of invocations cannot pass lavapipe's cap. With its iterations counted
    /// together, or where the worst case fits, its budget is the whole of what the cap
    /// leaves. Counted per invocation otherwise, the batch runs at most min(lanes, rays ×
    /// samples) times its busiest invocation's count, so the budget is that share.
    #[test]
    fn dispatch_budgets_keep_a_batch_within_the_cap() {
        for (samples, rays, ray_steps) in
            [(1, 2, 40_000), (16, 2, 1000), (4, 1, 9), (16, 2, 3), (3, 2, 70_000), (64, 1, 2000)]
        {
            let batch = traversal_budget(samples);
            assert_eq!(dispatch_budget(samples, rays, ray_steps, true), batch);
            let own = dispatch_budget(samples, rays, ray_steps, false);
            if samples as u64 * rays as u64 * ray_steps <= batch as u64 {
                assert_eq!(own, batch);
            } else {
                let worst = own as u64 * MAX_BATCH_LANES.min(rays * samples) as u64;
                assert!(worst <= batch as u64, "{samples} × {rays}: {worst} > {batch}");
                assert!(own > 0);
            }
        }
        assert_eq!(dispatch_budget(1, 2, 40_000, false), TRAVERSAL_BUDGET / 2);
        assert_eq!(dispatch_budget(16, 2, 3, false), traversal_budget(16));
    }
}
