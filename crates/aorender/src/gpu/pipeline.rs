//! The AO kernel's compute pipelines, each specialised for what a render needs, compiled
//! once per adapter and kept: many sessions and requests on one adapter (the accuracy
//! suite's thousands of probe runs, a comparison grid's cells) compile each variant once.
//! An opened adapter with the pipelines compiled on it ([`GpuDevice`]) is what every
//! session on the adapter shares.

use super::context::GpuContext;
use super::layout::{Access, BINDINGS, node_binding, primitive_binding};
use super::shaders::{GeometryChunks, GeometryStorage, Traversal, compose};
use super::stats::StatsPipelines;
use crate::bvh::BvhLayout;
use crate::error::Result;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use std::sync::Mutex;

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

/// The pipelines compiled on one adapter, by key.
#[derive(Debug, Default)]
pub struct Pipelines(Mutex<Vec<(PipelineKey, wgpu::BindGroupLayout, wgpu::ComputePipeline)>>);

impl Pipelines {
    /// The pipeline of `key`, compiled on first use.
    pub fn get(&self, ctx: &GpuContext, key: PipelineKey) -> Result<Pipeline> {
        let mut cache = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, l, p)) = cache.iter().find(|(k, _, _)| *k == key) {
            return Ok(Pipeline { bind_group_layout: l.clone(), pipeline: p.clone(), fresh: false });
        }
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
            cache: None,
        });
        cache.push((key, bind_group_layout.clone(), pipeline.clone()));
        Ok(Pipeline { bind_group_layout, pipeline, fresh: true })
    }
}

/// An adapter's context and its compiled pipelines (dropped before the context, whose
/// device they were made on).
pub struct GpuDevice {
    /// Pipelines compiled on it so far.
    pub pipelines: Pipelines,
    /// The statistics kernels, compiled when a render first keeps its sums on the device.
    stats: std::sync::Mutex<Option<StatsPipelines>>,
    /// The adapter, device and queue.
    pub ctx: GpuContext,
}

impl GpuDevice {
    /// Wraps an opened context (after any test limits were set on it).
    pub fn new(ctx: GpuContext) -> GpuDevice {
        GpuDevice { pipelines: Pipelines::default(), ctx, stats: Default::default() }
    }

    /// The statistics kernels (`stats.wgsl`), compiled on first use.
    pub fn stats_pipelines(&self) -> Result<StatsPipelines> {
        let mut cached = self.stats.lock().unwrap_or_else(|e| e.into_inner());
        if cached.is_none() {
            *cached = Some(StatsPipelines::new(&self.ctx)?);
        }
        Ok(cached.clone().expect("compiled above"))
    }

    /// Opens the best adapter, or the first whose name contains `name_filter`
    /// (case-insensitive): [`GpuContext::new`].
    pub fn open(name_filter: Option<&str>) -> Result<GpuDevice> {
        Ok(GpuDevice::new(GpuContext::new(name_filter)?))
    }
}
