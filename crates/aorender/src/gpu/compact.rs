//! The live pixels of an adaptive image, listed on the device (`shaders/compact.wgsl`)
//! after each decision that stops some, so that the next passes dispatch one invocation
//! a live pixel rather than every tile of the film: a tile whose pixels have partly
//! stopped would otherwise cost its SIMD batches as much as a live one (8 lanes in
//! lockstep on lavapipe, 32 on NVIDIA), and a stopped tile a workgroup.
//!
//! The list is in the film's tile order, each tile's pixels in `tile_pixel`'s order:
//! per-tile counts, a prefix sum over the tiles and a scatter, so the same marks give
//! the same list on every adapter (an atomic append's order would change from run to
//! run) and the rays of a batch stay as close together as a tile's. A pixel keeps its
//! samples and is rendered by one invocation: the film's bits do not change.

use super::context::{GpuContext, StorageKernels};
use super::layout::{LIVE_LIST, WORKGROUP_SIZE};
use crate::error::Result;
use wgpu::util::DeviceExt;

/// Tiles of a workgroup of `count_live` and `list_live`, and of a block of the scan.
const BLOCK: u32 = 256;

/// The kernels of `compact.wgsl`, compiled once an adapter.
#[derive(Clone, Debug)]
pub struct CompactPipelines {
    layout: wgpu::BindGroupLayout,
    count: wgpu::ComputePipeline,
    scan: wgpu::ComputePipeline,
    list: wgpu::ComputePipeline,
}

impl CompactPipelines {
    /// Compiles `compact.wgsl`'s entry points.
    pub fn new(ctx: &GpuContext) -> Result<CompactPipelines> {
        let kernels = StorageKernels::new(ctx, "compact.wgsl", &[true, true, false, false, false])?;
        let pipeline = |name: &str| kernels.pipeline(ctx, name);
        let pipelines = CompactPipelines {
            count: pipeline("count_live"),
            scan: pipeline("scan_blocks"),
            list: pipeline("list_live"),
            layout: kernels.layout,
        };
        ctx.take_error()?;
        Ok(pipelines)
    }

    /// Lists the live pixels of `film`, taken as empty, once and waits: an adapter that compiles a
    /// kernel at its first dispatch (lavapipe) compiles these here
    /// ([`super::stats::StatsPipelines::warm`]).
    pub fn warm(&self, ctx: &GpuContext, film: &wgpu::Buffer) -> Result<()> {
        let live = LivePixels::new(ctx, self.clone(), film, 0, 0)?;
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("warm-up") });
        live.record(&mut encoder);
        ctx.submit([encoder.finish()])?;
        ctx.wait()
    }
}

/// The parameters of `compact.wgsl` (`CompactParams`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct CompactParams {
    width: u32,
    rows: u32,
    tiles_x: u32,
    tiles: u32,
    blocks: u32,
    row_groups: u32,
    _pad: [u32; 2],
}

/// The list of a film's live pixels on the device, with the buffers that make it.
pub struct LivePixels {
    pipelines: CompactPipelines,
    bind_group: wgpu::BindGroup,
    /// The counters of a listed pass, then from word [`LIVE_LIST`] the live pixels' film
    /// slots, in order (one word a slot): bound as the kernel's counters.
    list: wgpu::Buffer,
    /// Per block of tiles, the live pixels before it; then the total (read by tests).
    #[cfg(feature = "testing")]
    blocks: wgpu::Buffer,
    /// Workgroups over the tiles, and in one row of the dispatch.
    groups: u32,
    row_groups: u32,
    /// Bytes allocated.
    pub device_bytes: u64,
}

impl LivePixels {
    /// The buffers that list the live pixels of `film`, `width` slots in each of `rows`
    /// rows (an image, or one band of it).
    pub fn new(
        ctx: &GpuContext,
        pipelines: CompactPipelines,
        film: &wgpu::Buffer,
        width: u32,
        rows: u32,
    ) -> Result<LivePixels> {
        let device = &ctx.device;
        let slots = width as u64 * rows as u64;
        let tiles_x = width.div_ceil(WORKGROUP_SIZE[0]);
        let tiles = tiles_x * rows.div_ceil(WORKGROUP_SIZE[1]);
        let groups = tiles.div_ceil(BLOCK).max(1);
        let row_groups = groups.min(device.limits().max_compute_workgroups_per_dimension);
        let params = CompactParams { width, rows, tiles_x, tiles, blocks: groups, row_groups, _pad: [0; 2] };
        let list_bytes = (LIVE_LIST as u64 + slots) * 4;
        ctx.check_size("live pixels", list_bytes)?;
        let buffer = |label: &str, size: u64| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let list = buffer("live pixels", list_bytes);
        let tile_info = buffer("live tiles", tiles as u64 * 16);
        let blocks = buffer("live blocks", (groups as u64 + 1) * 4);
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("compact params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::STORAGE,
        });
        fn bind(binding: u32, b: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() }
        }
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("compact"),
            layout: &pipelines.layout,
            entries: &[bind(0, film), bind(1, &params), bind(2, &tile_info), bind(3, &blocks), bind(4, &list)],
        });
        ctx.take_error()?;
        let device_bytes = [&list, &tile_info, &blocks, &params].into_iter().map(|b| b.size()).sum();
        Ok(LivePixels {
            pipelines,
            bind_group,
            list,
            #[cfg(feature = "testing")]
            blocks,
            groups,
            row_groups,
            device_bytes,
        })
    }

    /// A listed pass's counters, then from word [`LIVE_LIST`] the live pixels' film slots.
    pub fn list(&self) -> &wgpu::Buffer {
        &self.list
    }

    /// The word that holds the count of live pixels the last listing found.
    #[cfg(feature = "testing")]
    pub fn total(&self) -> (&wgpu::Buffer, u64) {
        (&self.blocks, self.groups as u64 * 4)
    }

    /// Records the listing of the film's live pixels (as its slots' marks are when the
    /// encoder runs).
    pub fn record(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("live pixels"), timestamp_writes: None });
        pass.set_bind_group(0, &self.bind_group, &[]);
        let rows = self.groups.div_ceil(self.row_groups);
        pass.set_pipeline(&self.pipelines.count);
        pass.dispatch_workgroups(self.row_groups, rows, 1);
        pass.set_pipeline(&self.pipelines.scan);
        pass.dispatch_workgroups(1, 1, 1);
        pass.set_pipeline(&self.pipelines.list);
        pass.dispatch_workgroups(self.row_groups, rows, 1);
    }
}
