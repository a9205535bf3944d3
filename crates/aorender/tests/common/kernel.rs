//! Test kernels: WGSL files in `tests/kernels/` that call the library's shader functions
//! once per invocation, composed with the library's shaders and run on the adapter.
//!
//! A kernel binds a uniform of four u32 at binding 0, its read-only storage inputs at
//! bindings 1..=n and its read-write output at n + 1, uses `@workgroup_size(64)`, and
//! takes its linear index as `gid.x + gid.y * num_workgroups.x * 64` (the host spreads
//! large dispatches over a 2-D grid of workgroups).

use aorender::gpu::context::GpuContext;
use wgpu::util::DeviceExt;

/// Invocations per workgroup of every test kernel.
const WORKGROUP: u32 = 64;

/// `source` (the text of `tests/kernels/{name}`) behind its `//#import`ed library shaders.
pub fn compose(name: &str, source: &str) -> String {
    let lookup = |n: &str| {
        if n == name {
            Some(source)
        } else {
            aorender::gpu::shaders::FILES.iter().find(|(f, _)| *f == n).map(|(_, t)| *t)
        }
    };
    aorender::gpu::shaders::compose_with(name, &lookup).expect("the kernel's imports resolve")
}

/// Parses and validates a composed kernel with naga, panicking with the diagnostic.
pub fn validate(name: &str, source: &str) -> naga::Module {
    let module =
        naga::front::wgsl::parse_str(source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(source)));
    module
}

/// A test kernel's pipelines on the default adapter.
pub struct TestKernel {
    name: &'static str,
    layout: wgpu::BindGroupLayout,
    pipelines: Vec<(&'static str, wgpu::ComputePipeline)>,
    /// Last: the device outlives what was made on it.
    ctx: GpuContext,
}

impl TestKernel {
    /// Builds `entries` of the kernel `name` (text `source`) with `inputs` storage inputs.
    pub fn new(name: &'static str, source: &str, entries: &[&'static str], inputs: u32) -> TestKernel {
        let ctx = GpuContext::new(None).expect("adapter opens");
        eprintln!("{name} on {} ({}, {})", ctx.description.name, ctx.description.backend, ctx.description.driver);
        let device = &ctx.device;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(name),
            source: wgpu::ShaderSource::Wgsl(compose(name, source).into()),
        });
        let entry = |binding: u32, ty: wgpu::BufferBindingType| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer { ty, has_dynamic_offset: false, min_binding_size: None },
            count: None,
        };
        let mut entries_layout = vec![entry(0, wgpu::BufferBindingType::Uniform)];
        entries_layout.extend((1..=inputs).map(|b| entry(b, wgpu::BufferBindingType::Storage { read_only: true })));
        entries_layout.push(entry(inputs + 1, wgpu::BufferBindingType::Storage { read_only: false }));
        let layout = device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor { label: Some(name), entries: &entries_layout });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(name),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipelines = entries
            .iter()
            .map(|&entry_point| {
                let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry_point),
                    layout: Some(&pipeline_layout),
                    module: &module,
                    entry_point: Some(entry_point),
                    compilation_options: Default::default(),
                    cache: None,
                });
                (entry_point, pipeline)
            })
            .collect();
        if let Some(e) = pollster::block_on(scope.pop()) {
            panic!("{name} does not build: {e}");
        }
        TestKernel { name, layout, pipelines, ctx }
    }

    /// Runs `entry` over `count` invocations with `params` and the storage `inputs`, and
    /// reads back `count × outputs_per_invocation` values of `T`.
    pub fn run<T: bytemuck::Pod>(
        &self,
        entry: &str,
        params: [u32; 4],
        inputs: &[&[u8]],
        count: u32,
        outputs_per_invocation: u32,
    ) -> Vec<T> {
        assert!(count > 0);
        let device = &self.ctx.device;
        let pipeline = &self.pipelines.iter().find(|(n, _)| *n == entry).expect("known entry point").1;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let init = |contents: &[u8], usage: wgpu::BufferUsages| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor { label: Some(self.name), contents, usage })
        };
        let params = init(bytemuck::cast_slice(&params), wgpu::BufferUsages::UNIFORM);
        let inputs: Vec<wgpu::Buffer> = inputs.iter().map(|b| init(b, wgpu::BufferUsages::STORAGE)).collect();
        let bytes = count as u64 * outputs_per_invocation as u64 * std::mem::size_of::<T>() as u64;
        let buffer = |usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.name),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        let output = buffer(wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
        let readback = buffer(wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        let mut entries = vec![wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() }];
        for (k, b) in inputs.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry { binding: k as u32 + 1, resource: b.as_entire_binding() });
        }
        entries.push(wgpu::BindGroupEntry { binding: inputs.len() as u32 + 1, resource: output.as_entire_binding() });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.name),
            layout: &self.layout,
            entries: &entries,
        });
        // A 2-D grid of workgroups keeps each dimension under the per-dimension limit.
        let groups = count.div_ceil(WORKGROUP);
        let groups_x = groups.min(device.limits().max_compute_workgroups_per_dimension);
        let groups_y = groups.div_ceil(groups_x);
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(self.name) });
        {
            let mut pass = encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(self.name), timestamp_writes: None });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(groups_x, groups_y, 1);
        }
        encoder.copy_buffer_to_buffer(&output, 0, &readback, 0, None);
        self.ctx.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        readback.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send(r);
        });
        device.poll(wgpu::PollType::wait_indefinitely()).expect("waiting for the GPU");
        if let Some(e) = pollster::block_on(scope.pop()) {
            panic!("{} entry point '{entry}' failed on the adapter: {e}", self.name);
        }
        rx.recv().expect("map callback").expect("readback maps");
        let data = {
            let view = readback.get_mapped_range(..).expect("mapped range");
            bytemuck::cast_slice::<u8, T>(&view).to_vec()
        };
        readback.unmap();
        data
    }
}
