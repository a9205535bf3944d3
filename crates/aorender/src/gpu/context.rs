//! An adapter, its device and queue: opened with the adapter's own limits and features,
//! with the device's errors captured (`fault`) rather than panicking, and the waits,
//! submissions and read-backs every pass uses.

use super::fault::{Fault, Faults, catch_panic};
use super::layout::{GROUP_LANES, OTHER_STORAGE_BINDINGS};
use super::shaders::{FILES, GeometryStorage, Traversal, compose_with};
use crate::bvh::BvhLayout;
use crate::error::{Error, Result};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

/// Test hook: with this environment variable set to N, the kernel's traversal stack is
/// taken to hold N entries, so that a small scene's BVH is refused as too deep.
#[cfg(feature = "testing")]
pub const TEST_STACK_ENTRIES_ENV: &str = "AORENDER_TEST_STACK_ENTRIES";

/// An adapter's name, backend, type and driver (the CPU reference has one too).
#[derive(Clone, Debug, serde::Serialize)]
pub struct AdapterInfo {
    /// Adapter name.
    pub name: String,
    /// Backend (Vulkan, Metal, …).
    pub backend: String,
    /// Discrete, integrated, CPU, ….
    pub device_type: String,
    /// Driver name and version.
    pub driver: String,
}

impl AdapterInfo {
    fn new(info: &wgpu::AdapterInfo) -> Self {
        AdapterInfo {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        }
    }
}

/// The process's one wgpu instance, made on first use and never destroyed. NVIDIA's
/// Vulkan driver on Linux races with itself when instances (and devices) are created or
/// destroyed on several threads at once: heap corruption ("corrupted size vs. prev_size")
/// or a segfault inside the driver (gfx-rs/wgpu#5930, labelled a driver bug; kvark/blade#336
/// for devices). One instance, and the [`lifecycle`] lock around every device's creation
/// and destruction, keep those calls on one thread at a time.
fn instance() -> &'static wgpu::Instance {
    static INSTANCE: OnceLock<wgpu::Instance> = OnceLock::new();
    INSTANCE.get_or_init(|| {
        let _held = lifecycle();
        wgpu::Instance::new(wgpu::InstanceDescriptor {
            backends: wgpu::Backends::PRIMARY,
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        })
    })
}

/// Held while the driver creates or destroys an instance or a device, or enumerates the
/// adapters ([`instance`]); whatever a panicking holder left behind, the lock is taken.
fn lifecycle() -> MutexGuard<'static, ()> {
    static LIFECYCLE: Mutex<()> = Mutex::new(());
    LIFECYCLE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Every adapter wgpu finds.
pub fn list_adapters() -> Vec<AdapterInfo> {
    let instance = instance();
    let _held = lifecycle();
    let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
    adapters.iter().map(|a| AdapterInfo::new(&a.get_info())).collect()
}

/// An adapter, its device and queue, with device errors captured instead of panicking.
/// Opened and dropped under a process-wide lock ([`instance`]): several threads may open,
/// use and drop contexts at once. Whatever holds a resource made on its device holds the
/// context too and drops it last, so that the device is destroyed when the context is.
pub struct GpuContext {
    /// The adapter.
    pub adapter: ManuallyDrop<wgpu::Adapter>,
    /// The device, created with the adapter's own limits.
    pub device: ManuallyDrop<wgpu::Device>,
    /// Its queue.
    pub queue: ManuallyDrop<wgpu::Queue>,
    /// The adapter's description.
    pub description: AdapterInfo,
    /// What the device's callbacks reported since the last check.
    faults: Arc<Faults>,
    /// Times the host has waited for the device ([`GpuContext::wait`], a read-back's
    /// mapping included): its round trips.
    round_trips: AtomicU64,
    /// Largest chunk of nodes or primitives in one binding, in bytes.
    max_chunk_bytes: u64,
    /// Largest film of one target, in bytes: one binding, or less for tests.
    max_film_bytes: u64,
    /// Largest width and height of a geometry texture (the adapter's limit, or less for tests).
    max_texture_size: [u32; 2],
    /// The kernel's `CPU_LANES`: the adapter is a CPU (or a test asks for its formulations).
    cpu_lanes: bool,
    /// The traversal a scene gets where none is asked for and it can run cooperatively.
    preferred_traversal: Traversal,
    /// Fewer traversal stack entries than the kernel has, for tests of a BVH too deep.
    stack_limit: Option<u32>,
    /// Fewer bindings for the geometry than the adapter allows, for tests of a scene that
    /// needs too many.
    geometry_binding_limit: Option<u32>,
    /// Whether an adaptive image's passes, once pixels have stopped, dispatch its live
    /// pixels only (`gpu/compact.rs`); else every tile, for tests of the same bits.
    list_live_pixels: bool,
}

impl Drop for GpuContext {
    fn drop(&mut self) {
        let _held = lifecycle();
        // SAFETY: each field is dropped once, here, and never used again.
        unsafe {
            ManuallyDrop::drop(&mut self.queue);
            ManuallyDrop::drop(&mut self.device);
            ManuallyDrop::drop(&mut self.adapter);
        }
    }
}

impl GpuContext {
    /// Opens the best adapter (discrete, then integrated, virtual, CPU), or the first
    /// whose name contains `name_filter` (case-insensitive).
    pub fn new(name_filter: Option<&str>) -> Result<GpuContext> {
        let instance = instance();
        let _held = lifecycle();
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
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
            // SIMD batch from subgroup operations, and a driver pipeline cache kept on disk,
            // where the adapter has them.
            required_features: adapter.features()
                & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::SUBGROUP | wgpu::Features::PIPELINE_CACHE),
            // wgpu's defaults cap a storage binding at 128 MiB: ask for what the adapter has.
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| Error::Gpu(format!("cannot open a device on the adapter: {e}")))?;
        let faults = Arc::new(Faults::default());
        let sink = faults.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let text = e.to_string().lines().next().unwrap_or("").to_string();
            sink.push(match e {
                wgpu::Error::OutOfMemory { .. } => Fault::OutOfMemory(text),
                // Work on a lost device fails with wgpu-core's `DeviceError::Lost` ("Parent
                // device is lost") before the lost callback has run.
                _ if text.to_lowercase().contains("device is lost") => Fault::Lost(text),
                _ => Fault::Other(text),
            });
        }));
        let sink = faults.clone();
        device.set_device_lost_callback(move |reason, message| {
            let message = message.lines().next().unwrap_or("").trim().to_string();
            sink.push(Fault::Lost(if message.is_empty() {
                format!("{reason:?}")
            } else {
                format!("{message} ({reason:?})")
            }));
        });
        let description = AdapterInfo::new(&adapter.get_info());
        let limits = device.limits();
        let max_chunk_bytes = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let max_texture_size = [limits.max_texture_dimension_2d; 2];
        let cpu_lanes = adapter.get_info().device_type == wgpu::DeviceType::Cpu;
        Ok(GpuContext {
            adapter: ManuallyDrop::new(adapter),
            device: ManuallyDrop::new(device),
            queue: ManuallyDrop::new(queue),
            description,
            faults,
            round_trips: AtomicU64::new(0),
            max_chunk_bytes,
            max_film_bytes: max_chunk_bytes,
            max_texture_size,
            cpu_lanes,
            // Per lane on every adapter: it measured faster on lavapipe (docs/performance.md,
            // "Eight lanes per ray"), and no GPU has measured the cooperative one yet.
            preferred_traversal: Traversal::PerLane,
            #[cfg(feature = "testing")]
            stack_limit: std::env::var(TEST_STACK_ENTRIES_ENV).ok().and_then(|v| v.trim().parse().ok()),
            #[cfg(not(feature = "testing"))]
            stack_limit: None,
            geometry_binding_limit: None,
            list_live_pixels: true,
        })
    }

    /// The deepest BVH in `layout` the kernel traverses: its stack's entries.
    pub(crate) fn stack_entries(&self, layout: BvhLayout) -> u32 {
        self.stack_limit.map_or(layout.stack_size(), |n| n.min(layout.stack_size()))
    }

    /// Takes the kernel's traversal stack as holding at most `entries` entries, so that
    /// a small scene is refused as one too deep for the stack is (for testing the
    /// refusal).
    #[cfg(feature = "testing")]
    pub fn limit_stack_entries(&mut self, entries: u32) {
        self.stack_limit = Some(entries);
    }

    /// Where the kernel should read the BVH nodes and primitives from on this adapter:
    /// textures on a CPU (lavapipe), storage buffers elsewhere
    /// ([`GeometryStorage::preferred`]).
    pub fn preferred_storage(&self) -> GeometryStorage {
        GeometryStorage::preferred(self.adapter.get_info().device_type)
    }

    /// Whether the adapter can run the cooperative traversal: subgroup operations, with
    /// subgroups of a multiple of its group's eight lanes.
    pub fn cooperative_traversal(&self) -> bool {
        let info = self.adapter.get_info();
        self.shared_steps() && info.subgroup_min_size >= GROUP_LANES && info.subgroup_min_size.is_power_of_two()
    }

    /// The traversal a scene that allows either gets where none is asked for.
    pub fn preferred_traversal(&self) -> Traversal {
        self.preferred_traversal
    }

    /// Makes `traversal` the preferred one (where the adapter can run it), so that tests
    /// run every scene that allows it cooperatively.
    #[cfg(feature = "testing")]
    pub fn prefer_traversal(&mut self, traversal: Traversal) {
        if traversal == Traversal::PerLane || self.cooperative_traversal() {
            self.preferred_traversal = traversal;
        }
    }

    /// The kernel's `CPU_LANES`: true where the adapter is a CPU, unless a test chose.
    pub(crate) fn cpu_lanes(&self) -> bool {
        self.cpu_lanes
    }

    /// Largest bytes of nodes or primitives in one binding.
    pub(crate) fn max_chunk_bytes(&self) -> u64 {
        self.max_chunk_bytes
    }

    /// Largest film of one target, in bytes.
    pub(crate) fn max_film_bytes(&self) -> u64 {
        self.max_film_bytes
    }

    /// Caps the bytes of one target's film below a binding, so that small images are
    /// rendered in bands of rows as large ones are (for testing the split; the image
    /// does not change).
    #[cfg(feature = "testing")]
    pub fn limit_film_bytes(&mut self, bytes: u64) {
        self.max_film_bytes = self.max_film_bytes.min(bytes);
    }

    /// Whether an adaptive image's passes dispatch its live pixels only.
    pub(crate) fn lists_live_pixels(&self) -> bool {
        self.list_live_pixels
    }

    /// Dispatches every tile of an adaptive image's film in every pass, as a render that
    /// lists no live pixels (`false`; by default `true`), for tests that the film's bits
    /// do not depend on it.
    #[cfg(feature = "testing")]
    pub fn set_list_live_pixels(&mut self, list: bool) {
        self.list_live_pixels = list;
    }

    /// Largest width and height of a geometry texture.
    pub(crate) fn max_texture_size(&self) -> [u32; 2] {
        self.max_texture_size
    }

    /// Compiles kernels with `CPU_LANES` = `cpu_lanes` from now on (by default true where
    /// the adapter is a CPU): the traversal then takes the formulations that compile to
    /// fewer instructions on a CPU. Either choice runs on any adapter and renders the same
    /// film (tests compare the two).
    #[cfg(feature = "testing")]
    pub fn set_cpu_lanes(&mut self, cpu_lanes: bool) {
        self.cpu_lanes = cpu_lanes;
    }

    /// Caps the width and height of a geometry texture below the adapter's limit, so that
    /// small scenes are split into several textures as large ones are (for testing the
    /// split). The width is rounded down to a multiple of `ROW_TEXEL_MULTIPLE`.
    #[cfg(feature = "testing")]
    pub fn limit_texture_size(&mut self, width: u32, height: u32) {
        self.max_texture_size = [self.max_texture_size[0].min(width), self.max_texture_size[1].min(height).max(1)];
    }

    /// How many bindings the BVH nodes and the primitives may take together in `storage`,
    /// from the adapter's limits (the storage buffers a shader stage may bind, less the
    /// kernel's other buffers; or the storage textures), and the limit's name for
    /// messages.
    pub fn geometry_bindings(&self, storage: GeometryStorage) -> (u32, &'static str) {
        let limits = self.device.limits();
        let (per_stage, name) = match storage {
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
        (per_stage.min(self.geometry_binding_limit.unwrap_or(u32::MAX)), name)
    }

    /// How many chunks of the nodes, and as many of the primitives, the binding numbers
    /// of a bind group leave room for: k chunks of each end at binding 2k + 5
    /// (`layout::node_binding`, `layout::primitive_binding`), below the adapter's
    /// `max_bindings_per_bind_group`.
    pub fn geometry_chunks_per_kind(&self) -> u32 {
        self.device.limits().max_bindings_per_bind_group.saturating_sub(6) / 2
    }

    /// Caps the bindings the geometry may take below the adapter's limits, so that a
    /// small scene split into small chunks needs more than are allowed on any adapter (for
    /// testing the refusal).
    #[cfg(feature = "testing")]
    pub fn limit_geometry_bindings(&mut self, bindings: u32) {
        self.geometry_binding_limit = Some(bindings);
    }

    /// Caps the bytes of nodes or primitives in one binding below the adapter's limit, so
    /// that small scenes are split into chunks as large ones are (for testing the split).
    #[cfg(feature = "testing")]
    pub fn limit_chunk_bytes(&mut self, bytes: u64) {
        self.max_chunk_bytes = self.max_chunk_bytes.min(bytes);
    }

    /// Whether the kernel counts a SIMD batch's traversal iterations together (the device
    /// has subgroup operations): `shaders::batch_file`.
    pub(crate) fn shared_steps(&self) -> bool {
        self.device.features().contains(wgpu::Features::SUBGROUP)
    }

    /// Whether passes can be timed by timestamp queries.
    pub(crate) fn has_timestamps(&self) -> bool {
        self.device.features().contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// The most serious device error since the last call, if any: a lost device, then
    /// running out of memory, then the first other error.
    pub(crate) fn take_error(&self) -> Result<()> {
        self.faults.take(&self.description.name)
    }

    /// The recorded device error if there is one (a lost device explains most failures),
    /// else `fallback`.
    pub(crate) fn fault(&self, fallback: String) -> Error {
        self.take_error().err().unwrap_or(Error::Gpu(fallback))
    }

    /// Times the host has waited for the device so far: submissions waited on and buffer
    /// mappings, each a round trip.
    pub fn round_trips(&self) -> u64 {
        self.round_trips.load(Ordering::Relaxed)
    }

    /// Submits `commands`; a panic inside wgpu becomes an error.
    pub(crate) fn submit(&self, commands: impl IntoIterator<Item = wgpu::CommandBuffer>) -> Result<()> {
        catch_panic("submitting work", || {
            self.queue.submit(commands);
        })?;
        self.take_error()
    }

    /// Waits for the submitted work, running the callbacks it completes (buffer mappings,
    /// device loss); a panic inside wgpu or a callback becomes an error.
    pub fn wait(&self) -> Result<()> {
        self.round_trips.fetch_add(1, Ordering::Relaxed);
        let polled = catch_panic("while waiting for the GPU", || self.device.poll(wgpu::PollType::wait_indefinitely()));
        self.take_error()?;
        polled?.map_err(|e| self.fault(format!("waiting for the GPU failed: {e}")))?;
        Ok(())
    }

    /// Maps a readback buffer after the last submission and copies it out.
    pub(crate) fn read<T: bytemuck::Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>> {
        self.read_mapped(&[buffer], |views| bytemuck::cast_slice(views[0]).to_vec())
    }

    /// Maps readback buffers after the last submission, all in one round trip, and hands
    /// their bytes to `read`, which converts them where they lie rather than from a copy.
    pub(crate) fn read_mapped<R>(&self, buffers: &[&wgpu::Buffer], read: impl FnOnce(&[&[u8]]) -> R) -> Result<R> {
        let (tx, rx) = std::sync::mpsc::channel();
        for buffer in buffers {
            let tx = tx.clone();
            catch_panic("mapping a readback buffer", || {
                buffer.map_async(wgpu::MapMode::Read, .., move |r| {
                    let _ = tx.send(r);
                })
            })?;
        }
        drop(tx);
        self.wait()?;
        for _ in buffers {
            rx.recv()
                .map_err(|_| self.fault("buffer mapping was dropped".into()))?
                .map_err(|e| self.fault(format!("cannot map a readback buffer: {e}")))?;
        }
        catch_panic("reading a readback buffer", || {
            let data = {
                let views = buffers
                    .iter()
                    .map(|b| b.get_mapped_range(..))
                    .collect::<std::result::Result<Vec<_>, _>>()
                    .map_err(|e| self.fault(format!("cannot read a mapped buffer: {e}")))?;
                let bytes: Vec<&[u8]> = views.iter().map(|v| &v[..]).collect();
                read(&bytes)
            };
            buffers.iter().for_each(|b| b.unmap());
            Ok(data)
        })?
    }

    /// Maps `buffer` for writing once the work submitted so far is done with it (one round
    /// trip), for the host to fill it again.
    pub(crate) fn map_for_write(&self, buffer: &wgpu::Buffer) -> Result<()> {
        let (tx, rx) = std::sync::mpsc::channel();
        catch_panic("mapping a staging buffer", || {
            buffer.map_async(wgpu::MapMode::Write, .., move |r| {
                let _ = tx.send(r);
            })
        })?;
        self.wait()?;
        rx.recv()
            .map_err(|_| self.fault("buffer mapping was dropped".into()))?
            .map_err(|e| self.fault(format!("cannot map a staging buffer: {e}")))
    }

    /// Fails with [`Error::TooLarge`] when a buffer of `bytes` exceeds a binding or a buffer.
    pub(crate) fn check_size(&self, what: &'static str, bytes: u64) -> Result<()> {
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

/// The compute kernels of one WGSL file over one bind group of storage buffers: its
/// bind group layout, and a pipeline for each entry point asked for.
pub(crate) struct StorageKernels {
    /// The bind group layout every kernel of the file takes.
    pub layout: wgpu::BindGroupLayout,
    module: wgpu::ShaderModule,
    pipeline_layout: wgpu::PipelineLayout,
}

impl StorageKernels {
    /// Compiles `file` (its imports composed from the shader files) for a bind group whose
    /// binding i is a storage buffer, read-only where `read_only[i]`.
    pub(crate) fn new(ctx: &GpuContext, file: &str, read_only: &[bool]) -> Result<StorageKernels> {
        let lookup = |n: &str| FILES.iter().find(|(f, _)| *f == n).map(|(_, t)| *t);
        let source = compose_with(file, &lookup)?;
        let label = file.trim_end_matches(".wgsl");
        let entries: Vec<wgpu::BindGroupLayoutEntry> = (0u32..)
            .zip(read_only)
            .map(|(binding, &read_only)| wgpu::BindGroupLayoutEntry {
                binding,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            })
            .collect();
        let device = &ctx.device;
        let layout =
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(label), entries: &entries });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(file),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(label),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        Ok(StorageKernels { layout, module, pipeline_layout })
    }

    /// The pipeline of the entry point `name`.
    pub(crate) fn pipeline(&self, ctx: &GpuContext, name: &str) -> wgpu::ComputePipeline {
        ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(name),
            layout: Some(&self.pipeline_layout),
            module: &self.module,
            entry_point: Some(name),
            compilation_options: Default::default(),
            cache: None,
        })
    }
}
