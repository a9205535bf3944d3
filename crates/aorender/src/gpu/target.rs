//! One request on the device: its film (per pixel, or per probe lane), the constants of
//! the frame and of each dispatch, the pass counters, and the pipeline specialised for
//! it, bound to the session's geometry. A pass adds a range of samples to the film.

use super::budget::{PREFERRED_SAMPLES_PER_INVOCATION, dispatch_budget, safe_samples_per_invocation};
use super::compact::LivePixels;
use super::layout::{
    COUNTER_AO_RAYS, COUNTER_COUNT, COUNTER_TRUNCATED, COUNTERS, DISPATCH, DISPATCH_STRIDE, DispatchUniforms, FILM,
    FRAME, FrameUniforms, GpuProbePoint, MAX_PASS_SAMPLES, PLANES, PROBE_POINTS, PROBE_WORKGROUP_SIZE, TRAVERSAL_LANES,
    WORKGROUP_SIZE,
};
use super::pipeline::{GpuDevice, Kernel, PipelineKey};
use super::stats::{AdaptQuery, AdaptSums, CheckQuery, CheckSums, DeviceSums, Stop};
use super::upload::{GeometryBindings, GpuScene, fill_records, storage_filled};
use crate::error::{Error, Result};
use crate::film::{ExactSums, INACTIVE_SLOT_BITS};
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use wgpu::util::DeviceExt;

/// Test hook: with this environment variable set to N, a target destroys its device
/// (`wgpu::Device::destroy`) before its pass N + 1, so that the real device-lost path runs.
#[cfg(feature = "testing")]
pub const TEST_LOSE_DEVICE_ENV: &str = "AORENDER_TEST_LOSE_DEVICE_AFTER_PASSES";

/// Offset of the pass timestamps in the counters' readback buffer.
const TIMESTAMPS_AT: u64 = 256;

/// An image's live pixels on the device, and the kernel's bindings with them.
struct Listed {
    pixels: LivePixels,
    bind_group: wgpu::BindGroup,
}

/// The bindings of an image's kernel other than the film, the counters and the constants
/// of each dispatch (which the target holds): to bind its live pixels' list.
struct Rebind {
    layout: wgpu::BindGroupLayout,
    frame: wgpu::Buffer,
    planes: wgpu::Buffer,
    probe_points: wgpu::Buffer,
    geometry: GeometryBindings,
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

/// The AO pipeline bound to the session's geometry and one image (or one set of probe
/// points), with its film.
pub struct GpuTarget {
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    film: wgpu::Buffer,
    /// Where the film is copied to be read, or kept during a guarded pass: shared by the
    /// bands of an image split over several targets (they use it one after another), at
    /// least as large as this target's film.
    film_readback: Arc<wgpu::Buffer>,
    dispatch: wgpu::Buffer,
    counters: wgpu::Buffer,
    counters_readback: wgpu::Buffer,
    /// Start and end timestamps of a pass, resolved into a buffer, where the adapter has
    /// timestamp queries.
    timestamps: Option<(wgpu::QuerySet, wgpu::Buffer)>,
    /// Film slots per row: image width, or probe lanes.
    width: u32,
    /// Film rows: the image rows of this target's band, or probe points.
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
    /// Bytes of device memory the target allocated (the session's geometry aside).
    pub device_bytes: u64,
    /// Passes started.
    passes_run: u32,
    /// Bytes mapped from the readback buffers since [`GpuTarget::take_readback_bytes`]
    /// (atomic: the film is read through `&self`).
    readback_bytes: AtomicU64,
    /// The test hook's pass count.
    lose_device_after: Option<u32>,
    /// Pixels an adaptive render no longer samples (empty: none).
    pub(crate) inactive: Vec<bool>,
    /// The bound 2^e of the samples, which sets the film's quanta (for `read_film`).
    #[cfg(feature = "testing")]
    value_exponent: i32,
    /// The film's exact sums on the device, made when a render first folds a block into
    /// them.
    sums: Option<DeviceSums>,
    /// An image's passes once some of its pixels have stopped: the live pixels listed
    /// ([`LivePixels`], made on first use) after the counters of a listed pass, bound in
    /// place of the target's counters.
    listed: Option<Listed>,
    /// What an image binds besides its list, to bind the list later.
    rebind: Option<Rebind>,
    /// Pixels the list holds, when passes dispatch it (`None`: every tile).
    live: Option<u32>,
    /// The scene's file, for messages.
    source: std::path::PathBuf,
    /// The adapter: last, so that its device outlives the resources above.
    dev: Arc<GpuDevice>,
}

/// A target's probe points, made where they are uploaded: `fill(first, out)` writes
/// points `first..first + out.len()` of `count`.
#[derive(Clone, Copy)]
pub(crate) struct MadePoints<'a> {
    pub count: usize,
    pub fill: &'a (dyn Fn(usize, &mut [GpuProbePoint]) + Sync),
}

impl MadePoints<'_> {
    /// No points: an image's target.
    const NONE: MadePoints<'static> = MadePoints { count: 0, fill: &|_, _| {} };
}

impl GpuTarget {
    /// A target rendering an image with `frame`'s constants, sampled by `sampler` with
    /// directions from `hemisphere`.
    pub fn image(
        dev: &Arc<GpuDevice>,
        scene: &GpuScene,
        frame: FrameUniforms,
        sampler: Sampler,
        hemisphere: Hemisphere,
    ) -> Result<GpuTarget> {
        let rows = frame.height;
        GpuTarget::build(dev, scene, Kernel::Image, frame, rows, sampler, hemisphere, MadePoints::NONE, None)
    }

    /// A target rendering the band of `rows` image rows from `frame.first_row` (a
    /// multiple of the workgroup's height, so that its workgroups are those of the whole
    /// image), its film read through `readback` (at least as large, and shared with the
    /// image's other bands: `None` makes one).
    // A target's constants and the band's: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn image_band(
        dev: &Arc<GpuDevice>,
        scene: &GpuScene,
        frame: FrameUniforms,
        rows: u32,
        sampler: Sampler,
        hemisphere: Hemisphere,
        readback: Option<Arc<wgpu::Buffer>>,
    ) -> Result<GpuTarget> {
        assert!(frame.first_row.is_multiple_of(WORKGROUP_SIZE[1]) && frame.first_row + rows <= frame.height);
        GpuTarget::build(dev, scene, Kernel::Image, frame, rows, sampler, hemisphere, MadePoints::NONE, readback)
    }

    /// The buffer this target reads its film through, to share with other bands.
    pub(crate) fn readback(&self) -> Arc<wgpu::Buffer> {
        self.film_readback.clone()
    }

    /// A target estimating AO at `points`: `frame.width` film slots (lanes) per point
    /// share the point's `frame.probe_samples` sample indices (see
    /// [`GpuTarget::render_pass`]).
    #[cfg(feature = "testing")]
    pub fn probes(
        dev: &Arc<GpuDevice>,
        scene: &GpuScene,
        frame: FrameUniforms,
        sampler: Sampler,
        hemisphere: Hemisphere,
        points: &[GpuProbePoint],
        bent_normals: bool,
    ) -> Result<GpuTarget> {
        let fill = |first: usize, out: &mut [GpuProbePoint]| out.copy_from_slice(&points[first..first + out.len()]);
        let points = MadePoints { count: points.len(), fill: &fill };
        GpuTarget::probes_made(dev, scene, frame, sampler, hemisphere, points, bent_normals)
    }

    /// [`GpuTarget::probes`] with the points made straight into the device's buffer, a
    /// piece at a time, rather than from a copy of them all.
    pub(crate) fn probes_made(
        dev: &Arc<GpuDevice>,
        scene: &GpuScene,
        frame: FrameUniforms,
        sampler: Sampler,
        hemisphere: Hemisphere,
        points: MadePoints<'_>,
        bent_normals: bool,
    ) -> Result<GpuTarget> {
        let lanes = frame.width;
        // With bent normals, one invocation fills a point's four slots.
        let slots = if bent_normals { points.count as u64 } else { lanes as u64 * points.count as u64 };
        // Workgroups in x and y (rows of x): the slot index must fit a u32.
        let per_dimension = u64::from(dev.ctx.device.limits().max_compute_workgroups_per_dimension);
        let max_slots = (per_dimension * per_dimension * u64::from(PROBE_WORKGROUP_SIZE)).min(u64::from(u32::MAX));
        if slots > max_slots {
            return Err(Error::Gpu(format!(
                "{} probe points × {lanes} lanes need {slots} invocations per dispatch; the adapter allows {max_slots}",
                points.count
            )));
        }
        let kernel = if bent_normals { Kernel::BentProbe } else { Kernel::Probe };
        let rows = frame.height;
        GpuTarget::build(dev, scene, kernel, frame, rows, sampler, hemisphere, points, None)
    }

    /// The target of `kernel` whose film has `frame.width` slots in each of `rows` rows,
    /// read through `readback` (a new buffer for `None`).
    // The pieces of a target: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    fn build(
        dev: &Arc<GpuDevice>,
        scene: &GpuScene,
        kernel: Kernel,
        frame: FrameUniforms,
        rows: u32,
        sampler: Sampler,
        hemisphere: Hemisphere,
        points: MadePoints<'_>,
        readback: Option<Arc<wgpu::Buffer>>,
    ) -> Result<GpuTarget> {
        let ctx = &dev.ctx;
        let device = &ctx.device;
        let (width, height, sky) = (frame.width, rows, frame.sky);
        #[cfg(feature = "testing")]
        let value_exponent = frame.value_exponent;
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
        let size = std::mem::size_of::<GpuProbePoint>();
        let probe_points = storage_filled(ctx, "probe points", points.count * size, size, &|at, out| {
            fill_records(out, |records: &mut [GpuProbePoint]| (points.fill)(at / size, records))
        })?;
        let film_bytes = width as u64 * height as u64 * 16;
        ctx.check_size("film", film_bytes)?;
        let film = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("film"),
            size: film_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let owns_readback = readback.is_none();
        let film_readback = match readback {
            Some(shared) if shared.size() >= film_bytes => shared,
            Some(_) => return Err(Error::Gpu("a band's film is larger than the readback it shares".into())),
            None => Arc::new(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("film readback"),
                size: film_bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })),
        };
        let timestamps = ctx.has_timestamps().then(|| {
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
            size: 4 * COUNTER_COUNT as u64,
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

        let key = PipelineKey {
            layout: scene.layout,
            traversal: scene.traversal,
            kernel,
            chunks: scene.chunks,
            instances: scene.has_instances,
            spheres: scene.has_spheres,
            triangles: scene.has_triangles,
            planes: scene.has_planes,
            sampler,
            hemisphere,
            sky,
            stack_size: scene.stack_size,
            cpu_lanes: ctx.cpu_lanes(),
        };
        let pipeline = dev.pipelines.get(ctx, key)?;
        let dispatch_binding = wgpu::BufferBinding {
            buffer: &dispatch,
            offset: 0,
            size: wgpu::BufferSize::new(std::mem::size_of::<DispatchUniforms>() as u64),
        };
        let mut entries = vec![
            wgpu::BindGroupEntry { binding: FRAME.index, resource: frame.as_entire_binding() },
            wgpu::BindGroupEntry { binding: DISPATCH.index, resource: wgpu::BindingResource::Buffer(dispatch_binding) },
            wgpu::BindGroupEntry { binding: PLANES.index, resource: scene.planes.as_entire_binding() },
            wgpu::BindGroupEntry { binding: FILM.index, resource: film.as_entire_binding() },
            wgpu::BindGroupEntry { binding: COUNTERS.index, resource: counters.as_entire_binding() },
            wgpu::BindGroupEntry { binding: PROBE_POINTS.index, resource: probe_points.as_entire_binding() },
        ];
        entries.extend(scene.bind_group_entries());
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ao bindings"),
            layout: &pipeline.bind_group_layout,
            entries: &entries,
        });
        ctx.take_error()?;
        let rebind = (kernel == Kernel::Image).then(|| Rebind {
            layout: pipeline.bind_group_layout.clone(),
            frame: frame.clone(),
            planes: scene.planes.clone(),
            probe_points: probe_points.clone(),
            geometry: scene.bindings(),
        });
        // Some drivers (lavapipe) compile the kernel at its first dispatch: run one
        // workgroup of a new pipeline now, then clear what it wrote. Not waited for: the
        // driver compiles while the host makes the request, and the next wait (the exact
        // sums written, or the first pass) takes what is left, a round trip fewer.
        if pipeline.fresh {
            let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("warm-up") });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("warm-up"),
                    timestamp_writes: None,
                });
                pass.set_pipeline(&pipeline.pipeline);
                pass.set_bind_group(0, &bind_group, &[0]);
                pass.dispatch_workgroups(1, 1, 1);
            }
            encoder.clear_buffer(&film, 0, None);
            encoder.clear_buffer(&counters, 0, None);
            ctx.submit([encoder.finish()])?;
        }
        ctx.take_error()?;
        // A shared readback counts once, with the band that made it.
        let readback_bytes = if owns_readback { film_readback.size() } else { 0 };
        let device_bytes = [&frame, &dispatch, &probe_points, &film, &counters, &counters_readback]
            .into_iter()
            .map(|b| b.size())
            .sum::<u64>()
            + readback_bytes;
        // A cooperative traversal traces the rays of its group's lanes in turn, each a
        // step of the loop over them more: for the loop cap, an invocation's samples have
        // that many rays, each a step longer.
        let lanes_per_ray = scene.traversal.lanes_per_ray();
        let rays_per_sample = lanes_per_ray
            * match kernel {
                Kernel::Image => 2,
                Kernel::Probe | Kernel::BentProbe => 1,
            };
        let ray_steps = scene.ray_steps + u64::from(lanes_per_ray > 1);
        let safe_samples_per_invocation = safe_samples_per_invocation(rays_per_sample, ray_steps);
        #[cfg(feature = "testing")]
        let lose_device_after = std::env::var(TEST_LOSE_DEVICE_ENV).ok().and_then(|v| v.trim().parse().ok());
        #[cfg(not(feature = "testing"))]
        let lose_device_after = None;
        Ok(GpuTarget {
            pipeline: pipeline.pipeline,
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
            passes_run: 0,
            readback_bytes: AtomicU64::new(0),
            lose_device_after,
            inactive: Vec::new(),
            #[cfg(feature = "testing")]
            value_exponent,
            sums: None,
            listed: None,
            rebind,
            live: None,
            source: scene.source.clone(),
            dev: dev.clone(),
        })
    }

    /// Film slots: pixels, or probe points × lanes.
    pub fn slots(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Sets the samples each invocation renders in turn, at most [`MAX_PASS_SAMPLES`];
    /// returns the value set. The film is the same, bit for bit, whatever the setting:
    /// each invocation adds its samples in order, as one dispatch per sample would, and a
    /// pass that runs out of budget with more than `safe_samples_per_invocation` is
    /// rendered again with that many.
    #[cfg(feature = "testing")]
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
    /// safe count, which the target keeps from then on.
    pub fn render_pass(&mut self, first: u32, count: u32) -> Result<PassCounters> {
        let per = self.samples_per_invocation;
        let guarded = per.min(count) > self.safe_samples_per_invocation;
        let (mut counters, mut truncated) = self.run_pass(first, count, guarded)?;
        if truncated > 0 && guarded {
            let words = self.read_film_readback()?;
            self.set_film_words(&words)?;
            self.samples_per_invocation = self.safe_samples_per_invocation;
            (counters, truncated) = self.run_pass(first, count, false)?;
        }
        if truncated == 0 {
            return Ok(counters);
        }
        let budget = self.dispatch_budget(self.samples_per_invocation.min(count));
        Err(Error::TraversalBudget { path: self.source.clone(), count: truncated, budget })
    }

    /// The traversal budget of a dispatch of `samples` samples per invocation.
    fn dispatch_budget(&self, samples: u32) -> u32 {
        dispatch_budget(samples, self.rays_per_sample, self.ray_steps, self.dev.ctx.shared_steps())
    }

    /// One try at [`GpuTarget::render_pass`], copying the film to the readback buffer
    /// first where `keep_film` is set; returns its counters and how many samples ran out
    /// of budget.
    fn run_pass(&mut self, first: u32, count: u32, keep_film: bool) -> Result<(PassCounters, u64)> {
        assert!((1..=MAX_PASS_SAMPLES).contains(&count), "pass of {count} samples");
        let ctx = &self.dev.ctx;
        if self.lose_device_after == Some(self.passes_run) {
            ctx.device.destroy();
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
                listed: self.live.unwrap_or(0),
            };
            let at = (DISPATCH_STRIDE * k as u64) as usize;
            uniforms[at..at + std::mem::size_of::<DispatchUniforms>()].copy_from_slice(bytemuck::bytes_of(&u));
        }
        ctx.queue.write_buffer(&self.dispatch, 0, &uniforms);
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("pass") });
        // A listed pass counts in its list's buffer, ahead of the list.
        let counters = match (&self.listed, self.live) {
            (Some(listed), Some(_)) => listed.pixels.list().clone(),
            _ => self.counters.clone(),
        };
        encoder.clear_buffer(&counters, 0, Some(4 * COUNTER_COUNT as u64));
        if keep_film {
            encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, self.film.size());
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
            let (groups_x, groups_y) = match (self.kernel, self.live) {
                (Kernel::Image, Some(live)) => rows_of_groups(&self.dev, live.div_ceil(TRAVERSAL_LANES), 0),
                (Kernel::Image, None) => {
                    (self.width.div_ceil(WORKGROUP_SIZE[0]), self.height.div_ceil(WORKGROUP_SIZE[1]))
                }
                (Kernel::Probe, _) => probe_groups(&self.dev, self.width * self.height),
                (Kernel::BentProbe, _) => probe_groups(&self.dev, self.height),
            };
            let bind_group = match (&self.listed, self.live) {
                (Some(listed), Some(_)) => &listed.bind_group,
                _ => &self.bind_group,
            };
            // With every pixel stopped there is nothing to dispatch.
            if groups_x > 0 {
                for k in 0..dispatches {
                    pass.set_bind_group(0, bind_group, &[(DISPATCH_STRIDE * k as u64) as u32]);
                    pass.dispatch_workgroups(groups_x, groups_y, 1);
                }
            }
        }
        encoder.copy_buffer_to_buffer(&counters, 0, &self.counters_readback, 0, Some(4 * COUNTER_COUNT as u64));
        if let Some((set, resolved)) = &self.timestamps {
            encoder.resolve_query_set(set, 0..2, resolved, 0);
            encoder.copy_buffer_to_buffer(resolved, 0, &self.counters_readback, TIMESTAMPS_AT, None);
        }
        ctx.submit([encoder.finish()])?;
        let words: Vec<u32> = ctx.read(&self.counters_readback)?;
        self.readback_bytes.fetch_add(self.counters_readback.size(), Ordering::Relaxed);
        let gpu_seconds = self.timestamps.as_ref().map(|_| {
            let at = (TIMESTAMPS_AT / 4) as usize;
            let tick = |k: usize| words[at + 2 * k] as u64 | (words[at + 2 * k + 1] as u64) << 32;
            tick(1).wrapping_sub(tick(0)) as f64 * ctx.queue.get_timestamp_period() as f64 * 1e-9
        });
        let truncated = words[COUNTER_TRUNCATED as usize] as u64;
        Ok((PassCounters { ao_rays: words[COUNTER_AO_RAYS as usize] as u64, gpu_seconds }, truncated))
    }

    /// The film as per-slot f64 sums (its integers scaled by their quanta), labelled as
    /// holding `samples` samples.
    #[cfg(feature = "testing")]
    pub fn read_film(&self, samples: u64) -> Result<crate::film::Film> {
        let mut film = crate::film::Film::new(self.width, self.height);
        film.samples = samples;
        let block = crate::film::BlockSums::from_words(&self.film_words()?);
        for i in 0..block.len() {
            (film.sum[i], film.sum_sq[i]) = block.slot(i, self.value_exponent);
        }
        Ok(film)
    }

    /// The film's raw words, one `[Σv low, Σv high, Σv² low, Σv² high]` per slot
    /// ([`crate::film::BlockSums::from_words`]), as the kernel left them: with
    /// [`GpuTarget::set_film_words`], a render can stop and go on later from the same bits.
    #[cfg(feature = "testing")]
    pub fn film_words(&self) -> Result<Vec<[u32; 4]>> {
        let ctx = &self.dev.ctx;
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("film words") });
        encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, self.film.size());
        ctx.submit([encoder.finish()])?;
        self.read_film_readback()
    }

    /// The film's sums as the kernel left them, a stopped slot's read as nothing
    /// ([`crate::film::BlockSums::from_marked_words`]): converted where the words are
    /// mapped, on rayon's threads, rather than from a copy of them.
    pub fn film_block(&self) -> Result<crate::film::BlockSums> {
        let ctx = &self.dev.ctx;
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("film words") });
        encoder.copy_buffer_to_buffer(&self.film, 0, &self.film_readback, 0, self.film.size());
        ctx.submit([encoder.finish()])?;
        let slots = self.slots();
        let block = ctx.read_mapped(&[&self.film_readback], |views| {
            crate::film::BlockSums::from_marked_words(&bytemuck::cast_slice(views[0])[..slots])
        })?;
        self.readback_bytes.fetch_add(self.film_readback.size(), Ordering::Relaxed);
        Ok(block)
    }

    /// This target's film as last copied to the readback buffer (which may be larger).
    fn read_film_readback(&self) -> Result<Vec<[u32; 4]>> {
        let mut words: Vec<[u32; 4]> = self.dev.ctx.read(&self.film_readback)?;
        self.readback_bytes.fetch_add(self.film_readback.size(), Ordering::Relaxed);
        words.truncate(self.slots());
        Ok(words)
    }

    /// Replaces the film with `words` (as the kernel leaves them:
    /// [`crate::film::BlockSums::to_words`]).
    pub fn set_film_words(&mut self, words: &[[u32; 4]]) -> Result<()> {
        let slots = self.slots();
        if words.len() != slots {
            return Err(Error::Gpu(format!("{} film slots given for a film of {slots}", words.len())));
        }
        let ctx = &self.dev.ctx;
        ctx.queue.write_buffer(&self.film, 0, bytemuck::cast_slice(words));
        ctx.submit([])?;
        ctx.wait()
    }

    /// Marks the slots of the inactive pixels in the film (`words`: its current words, or
    /// `None` for a cleared film), so that the kernel skips them; nothing to do when every
    /// pixel is active.
    pub fn mark_inactive(&mut self, words: Option<&[[u32; 4]]>) -> Result<()> {
        if let Some(sums) = self.sums.as_mut() {
            sums.forget();
        }
        if !self.inactive.iter().any(|&x| x) {
            self.live = None;
            return Ok(());
        }
        let mut marked = words.map_or_else(|| vec![[0u32; 4]; self.slots()], <[_]>::to_vec);
        for (w, &off) in marked.iter_mut().zip(&self.inactive) {
            if off {
                *w = [0, 0, 0, INACTIVE_SLOT_BITS];
            }
        }
        self.set_film_words(&marked)?;
        let stopped = self.inactive.iter().take(self.slots()).filter(|&&off| off).count();
        self.list_live((self.slots() - stopped) as u32)
    }

    /// Stops sampling the pixels marked in `inactive` from the next pass on, marking them
    /// in an emptied film (the block must hold no samples). An empty mask leaves the film
    /// as it is: [`GpuTarget::clear_film`] then samples every pixel again.
    pub fn stop_pixels(&mut self, inactive: &[bool]) -> Result<()> {
        self.inactive = inactive.to_vec();
        self.mark_inactive(None)
    }

    /// Lists the film's live pixels on the device (`live` of them, as the host counts
    /// them), so that the next passes dispatch those alone: submitted, not waited for.
    /// Every tile is dispatched instead for probes, and where the context says so.
    fn list_live(&mut self, live: u32) -> Result<()> {
        let Some(rebind) = self.rebind.as_ref().filter(|_| self.dev.ctx.lists_live_pixels()) else {
            self.live = None;
            return Ok(());
        };
        let ctx = &self.dev.ctx;
        if self.listed.is_none() {
            let pixels = LivePixels::new(ctx, self.dev.compact_pipelines()?, &self.film, self.width, self.height)?;
            let dispatch_binding = wgpu::BufferBinding {
                buffer: &self.dispatch,
                offset: 0,
                size: wgpu::BufferSize::new(std::mem::size_of::<DispatchUniforms>() as u64),
            };
            let mut entries = vec![
                wgpu::BindGroupEntry { binding: FRAME.index, resource: rebind.frame.as_entire_binding() },
                wgpu::BindGroupEntry {
                    binding: DISPATCH.index,
                    resource: wgpu::BindingResource::Buffer(dispatch_binding),
                },
                wgpu::BindGroupEntry { binding: PLANES.index, resource: rebind.planes.as_entire_binding() },
                wgpu::BindGroupEntry { binding: FILM.index, resource: self.film.as_entire_binding() },
                wgpu::BindGroupEntry { binding: COUNTERS.index, resource: pixels.list().as_entire_binding() },
                wgpu::BindGroupEntry { binding: PROBE_POINTS.index, resource: rebind.probe_points.as_entire_binding() },
            ];
            entries.extend(rebind.geometry.entries());
            let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("ao bindings, live pixels"),
                layout: &rebind.layout,
                entries: &entries,
            });
            ctx.take_error()?;
            self.listed = Some(Listed { pixels, bind_group });
        }
        let listed = self.listed.as_ref().expect("made above");
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("live") });
        listed.pixels.record(&mut encoder);
        ctx.submit([encoder.finish()])?;
        self.live = Some(live);
        Ok(())
    }

    /// The live pixels the passes dispatch, as the device listed them, and the count the
    /// listing found (`None`: the passes dispatch every tile).
    #[cfg(feature = "testing")]
    pub fn live_pixels(&self) -> Result<Option<(Vec<u32>, u32)>> {
        let (Some(listed), Some(live)) = (&self.listed, self.live) else {
            return Ok(None);
        };
        let ctx = &self.dev.ctx;
        let (total, at) = listed.pixels.total();
        let bytes = live as u64 * 4;
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("live pixels readback"),
            size: bytes + 4,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("live") });
        if bytes > 0 {
            encoder.copy_buffer_to_buffer(
                listed.pixels.list(),
                super::layout::LIVE_LIST as u64 * 4,
                &staging,
                0,
                Some(bytes),
            );
        }
        encoder.copy_buffer_to_buffer(total, at, &staging, bytes, Some(4));
        ctx.submit([encoder.finish()])?;
        let mut words: Vec<u32> = ctx.read(&staging)?;
        let found = words.pop().expect("the total is read");
        Ok(Some((words, found)))
    }

    /// Bytes mapped from the device's readback buffers (films and pass counters) since the
    /// last call.
    pub fn take_readback_bytes(&self) -> u64 {
        self.readback_bytes.swap(0, Ordering::Relaxed)
    }

    /// Times the host has waited for this target's device so far (every request on it).
    pub fn round_trips(&self) -> u64 {
        self.dev.ctx.round_trips()
    }

    /// Whether the device can keep this target's exact sums (an image's film).
    pub fn keeps_sums(&self) -> bool {
        self.kernel == Kernel::Image
    }

    /// The exact sums on the device, made (zero) on first use.
    fn device_sums(&mut self) -> Result<&DeviceSums> {
        if self.sums.is_none() {
            let pipelines = self.dev.stats_pipelines()?;
            let sums = DeviceSums::new(&self.dev.ctx, pipelines, &self.film, self.slots() as u32)?;
            self.sums = Some(sums);
        }
        Ok(self.sums.as_ref().expect("made above"))
    }

    /// Bytes of device memory of the target with its exact sums and its live pixels' list.
    pub fn all_device_bytes(&self) -> u64 {
        self.device_bytes
            + self.sums.as_ref().map_or(0, |s| s.device_bytes)
            + self.listed.as_ref().map_or(0, |l| l.pixels.device_bytes)
    }

    /// Replaces the device's exact sums and counts with `exact`'s (`samples` a pixel
    /// where it does not count them per pixel).
    pub fn write_sums(&mut self, exact: &ExactSums, samples: u32) -> Result<()> {
        self.device_sums()?;
        self.sums.as_mut().expect("made above").write(&self.dev.ctx, exact, samples)
    }

    /// Folds the film's block of `taken` samples into the device's exact sums and empties
    /// the film (`replicate`: the block is one whole replicate, whose square is added).
    pub fn fold(&mut self, replicate: bool, taken: u32) -> Result<()> {
        self.device_sums()?;
        self.sums.as_ref().expect("made above").fold(&self.dev.ctx, replicate, taken)
    }

    /// The image-level sums of an adaptive render's decisions ([`DeviceSums::adapt_check`]).
    pub fn adapt_check(&mut self, query: AdaptQuery, exponents: (i32, i32)) -> Result<(AdaptSums, Option<u32>)> {
        self.device_sums()?;
        let sums = self.sums.as_mut().expect("made above");
        sums.adapt_check(&self.dev.ctx, query, exponents, &self.readback_bytes)
    }

    /// Counts the pixels that have their share and stops them as `stop` says
    /// ([`DeviceSums::allocate`]).
    pub fn allocate(
        &mut self,
        query: AdaptQuery,
        exponents: (i32, i32),
        per_sigma: f32,
        stop: Stop,
    ) -> Result<(u32, u32)> {
        self.device_sums()?;
        let sums = self.sums.as_ref().expect("made above");
        let (stops, going) = sums.allocate(&self.dev.ctx, query, exponents, per_sigma, stop, &self.readback_bytes)?;
        // The pixels still sampled are those that go on: the next passes take them alone.
        if stops > 0 && stop.applies(going) {
            self.list_live(going)?;
        }
        Ok((stops, going))
    }

    /// Has the next [`GpuTarget::adapt_check`] evaluate every pixel and sum every
    /// workgroup again, keeping nothing from the last, for tests that hold what a check
    /// keeps against a check that keeps nothing.
    #[cfg(feature = "testing")]
    pub fn forget_kept(&mut self) {
        if let Some(sums) = self.sums.as_mut() {
            sums.forget();
        }
    }

    /// Each pixel's samples, replicates and whether it is stopped, as the device keeps
    /// them; the stopped pixels become the target's inactive ones, so that a later
    /// [`GpuTarget::mark_inactive`] keeps them.
    pub fn read_counts(&mut self) -> Result<Vec<(u32, u32, bool)>> {
        self.device_sums()?;
        let sums = self.sums.as_ref().expect("made above");
        let counts = sums.read_counts(&self.dev.ctx, &self.film_readback, &self.readback_bytes)?;
        if counts.iter().any(|c| c.2) || !self.inactive.is_empty() {
            self.inactive = counts.iter().map(|c| c.2).collect();
        }
        Ok(counts)
    }

    /// The image-level sums of the stopping rule over the device's exact sums, and the
    /// first slot that received a sample out of range.
    pub fn check(&mut self, query: CheckQuery, exponents: (i32, i32)) -> Result<(CheckSums, Option<u32>)> {
        self.device_sums()?;
        let sums = self.sums.as_mut().expect("made above");
        sums.check(&self.dev.ctx, query, exponents, &self.readback_bytes)
    }

    /// Reads the device's exact sums into `exact` ([`DeviceSums::read`]).
    pub fn read_sums(&mut self, exact: &mut ExactSums, replicates: bool) -> Result<Option<u32>> {
        self.device_sums()?;
        let sums = self.sums.as_ref().expect("made above");
        sums.read(&self.dev.ctx, &self.film_readback, exact, replicates, &self.readback_bytes)
    }

    /// Zeroes the film.
    pub fn clear_film(&mut self) -> Result<()> {
        let ctx = &self.dev.ctx;
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("clear film") });
        encoder.clear_buffer(&self.film, 0, None);
        // The film has no stopped pixels now: every tile again.
        self.live = None;
        if let Some(sums) = self.sums.as_mut() {
            sums.forget();
        }
        ctx.submit([encoder.finish()])
    }
}

/// Overrides the adapter's limit on probe workgroups per dimension in the dispatch's
/// shape when not zero (a smaller one: tests cross into the second dimension with few
/// points); the largest dispatch allowed stays the adapter's.
static PROBE_GROUPS_PER_DIMENSION: AtomicU32 = AtomicU32::new(0);

/// Caps the probe dispatch at `n` workgroups per dimension (0: the adapter's limit), for
/// tests of the 2-D dispatch; results do not change.
#[cfg(feature = "testing")]
pub fn limit_probe_groups_per_dimension(n: u32) {
    PROBE_GROUPS_PER_DIMENSION.store(n, Ordering::Relaxed);
}

/// Probe workgroups a dispatch may have per dimension.
fn probe_groups_per_dimension(dev: &GpuDevice) -> u32 {
    let adapter = dev.ctx.device.limits().max_compute_workgroups_per_dimension;
    match PROBE_GROUPS_PER_DIMENSION.load(Ordering::Relaxed) {
        0 => adapter,
        n => n.min(adapter),
    }
}

/// The probe dispatch of `slots` invocations: rows of at most the per-dimension limit of
/// workgroups (the kernels number slots row by row).
fn probe_groups(dev: &GpuDevice, slots: u32) -> (u32, u32) {
    rows_of_groups(dev, slots.div_ceil(PROBE_WORKGROUP_SIZE).max(1), probe_groups_per_dimension(dev))
}

/// A dispatch of `groups` workgroups in rows of at most `per_row` (0: the adapter's
/// limit per dimension); (0, 0) for none.
fn rows_of_groups(dev: &GpuDevice, groups: u32, per_row: u32) -> (u32, u32) {
    let limit = dev.ctx.device.limits().max_compute_workgroups_per_dimension;
    let x = groups.min(if per_row == 0 { limit } else { per_row.min(limit) });
    if x == 0 { (0, 0) } else { (x, groups.div_ceil(x)) }
}

/// Overrides how many probe points one target takes when not zero (fewer: tests split a
/// request over several targets with few points).
static PROBE_POINTS_PER_TARGET: AtomicU32 = AtomicU32::new(0);

/// Caps the probe points of one target at `n` (0: as many as its storage bindings
/// take), for tests of requests split over several targets; results do not change.
#[cfg(feature = "testing")]
pub fn limit_probe_points_per_target(n: u32) {
    PROBE_POINTS_PER_TARGET.store(n, Ordering::Relaxed);
}

/// The most probe points one target binds with `slots_per_point` film slots each: its
/// points' and its film's storage buffers must each fit one binding.
pub(crate) fn probe_points_per_target(dev: &GpuDevice, slots_per_point: u32) -> usize {
    let limits = dev.ctx.device.limits();
    let binding = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
    let point_bytes = std::mem::size_of::<GpuProbePoint>() as u64;
    // A film slot is four u32 words: the sum and the sum of squares, 64 bits each.
    let slot_bytes = 16 * u64::from(slots_per_point.max(1));
    let n = (binding / point_bytes).min(binding / slot_bytes).min(u64::from(u32::MAX)) as usize;
    match PROBE_POINTS_PER_TARGET.load(Ordering::Relaxed) {
        0 => n,
        k => n.min(k as usize),
    }
}

/// Image rows one target's film holds: as many as fit one storage binding (or a test's
/// smaller cap), in whole workgroup rows, so that every band's workgroups are those of the
/// unsplit image and render its pixels bit for bit.
pub fn image_rows_per_target(dev: &GpuDevice, width: u32) -> u32 {
    // A film slot is four u32 words: the sum and the sum of squares, 64 bits each.
    let row_bytes = 16 * u64::from(width.max(1));
    let rows = dev.ctx.max_film_bytes() / row_bytes;
    let rows = rows / u64::from(WORKGROUP_SIZE[1]) * u64::from(WORKGROUP_SIZE[1]);
    rows.clamp(u64::from(WORKGROUP_SIZE[1]), u64::from(u32::MAX)) as u32
}
