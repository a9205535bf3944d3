//! A film's exact sums kept on the device (`shaders/stats.wgsl`): each finished block of
//! samples is folded into them there, a replicate's square with it, and a check of an
//! error target reduces the image-level sums of the stopping rule on the device and reads
//! back 32 bytes rather than the film. The sums are read (`DeviceSums::read`) at
//! checkpoints and at the end, into the host's [`ExactSums`], bit for bit the integers
//! the host would have added.
//!
//! An adaptive render keeps each pixel's counts of samples and replicates on the device
//! as well, and takes its decisions there: a decision reduces the image-level sums of
//! the allocation (`DeviceSums::adapt_check`, 32 bytes back), then counts and stops the
//! pixels that have their share of σ in one submission (`DeviceSums::allocate`, 32
//! bytes back); the counts and the stopped pixels (8 bytes a pixel) are read with the
//! sums. A check evaluates the rule only for the pixels folded or stopped since the last
//! and sums again only the workgroups beside one of them: the device keeps each pixel's
//! evaluation and each workgroup's sums (12 bytes a pixel), so that a decision costs in
//! proportion to the pixels still sampled, as the passes do.

use super::context::{GpuContext, StorageKernels};
use crate::error::{Error, Result};
use crate::film::{ExactSums, REPLICATE_SQ_SHIFT, SampleRange};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Invocations of a workgroup of the statistics kernels (`stats.wgsl`), and slots of a
/// workgroup's partial sums.
const STATS_WORKGROUP: u32 = 256;
/// Invocations of a workgroup of `group_sums` (one a workgroup of slots) and of the
/// kernels that walk runs of [`RUN_SLOTS`] slots.
const SMALL_WORKGROUP: u32 = 64;
/// Consecutive slots an invocation of the kernels that walk runs looks after
/// (`stats.wgsl`'s `RUN_SLOTS`).
const RUN_SLOTS: u32 = 8;

/// What a statistics kernel's dispatch covers.
#[derive(Clone, Copy, Debug)]
enum Shape {
    /// One invocation a slot.
    Slots,
    /// One invocation a workgroup of slots.
    Groups,
    /// One invocation each [`RUN_SLOTS`] slots.
    Runs,
    /// One workgroup.
    One,
}

/// Bytes of the parameters (`StatsParams`).
const PARAMS_BYTES: u64 = 80;
/// Bytes a check reads back: the total (Σv, Σv², Σ mean, 0) and the status word.
const CHECK_BYTES: u64 = 32;
/// Values kept per pixel by an adaptive render's checks (`stats.wgsl`'s `KEPT_*`).
const KEPT_REGIONS: u64 = 3;

/// The statistics kernels of one adapter, compiled once.
#[derive(Clone, Debug)]
pub struct StatsPipelines {
    layout: wgpu::BindGroupLayout,
    fold: wgpu::ComputePipeline,
    evaluate: wgpu::ComputePipeline,
    group_sums: wgpu::ComputePipeline,
    group_sums_shared: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    reduce_groups: wgpu::ComputePipeline,
    allocate: wgpu::ComputePipeline,
    stop_allocated: wgpu::ComputePipeline,
    mark: wgpu::ComputePipeline,
}

impl StatsPipelines {
    /// Compiles `stats.wgsl`'s entry points.
    pub fn new(ctx: &GpuContext) -> Result<StatsPipelines> {
        let kernels = StorageKernels::new(ctx, "stats.wgsl", &[false, false, false, false, true, false, false, false])?;
        let pipeline = |name: &str| kernels.pipeline(ctx, name);
        let pipelines = StatsPipelines {
            fold: pipeline("fold"),
            evaluate: pipeline("evaluate"),
            group_sums: pipeline("group_sums"),
            group_sums_shared: pipeline("group_sums_shared"),
            reduce: pipeline("reduce"),
            reduce_groups: pipeline("reduce_groups"),
            allocate: pipeline("allocate"),
            stop_allocated: pipeline("stop_allocated"),
            mark: pipeline("mark"),
            layout: kernels.layout,
        };
        ctx.take_error()?;
        Ok(pipelines)
    }

    /// Runs once, over no slots, the kernels a render dispatches (the fold; with `target`
    /// a check's; with `adaptive` the decisions') and waits for them. An adapter that
    /// compiles a kernel at its first dispatch rather than with its pipeline (lavapipe
    /// does) compiles them here, where the device opens beside the scene's loading, rather
    /// than within the render's first checks.
    /// `film` is an empty film of one slot's bytes.
    pub fn warm(&self, ctx: &GpuContext, film: &wgpu::Buffer, target: bool, adaptive: bool) -> Result<()> {
        let sums = DeviceSums::new(ctx, self.clone(), film, 0)?;
        let mut kernels = vec![&self.fold];
        if target || adaptive {
            kernels.extend([&self.reduce, &self.reduce_groups]);
        }
        if adaptive {
            let group_sums = if ctx.cpu_lanes() { &self.group_sums } else { &self.group_sums_shared };
            kernels.extend([&self.evaluate, group_sums, &self.allocate, &self.stop_allocated]);
        }
        // No slots and no workgroups of them: every invocation returns at once.
        let mut encoder = sums.encoder(ctx, StatsParams::default());
        for kernel in kernels {
            sums.pass(&mut encoder, kernel, Shape::One);
        }
        ctx.submit([encoder.finish()])?;
        ctx.wait()
    }
}

/// The parameters of `stats.wgsl` (`StatsParams`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct StatsParams {
    slots: u32,
    groups: u32,
    replicate: u32,
    row_groups: u32,
    n: f32,
    k: f32,
    b: f32,
    /// 0: `exact.wgsl`'s opaque zero, which keeps products out of fused sums.
    zero: u32,
    sum_exponent: i32,
    square_exponent: i32,
    replicate_exponent: i32,
    /// 1: the partial sums have room for the kept evaluations.
    kept: u32,
    taken: u32,
    range: u32,
    max_value: f32,
    met: u32,
    per_sigma: f32,
    width: u32,
    _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<StatsParams>() as u64 == PARAMS_BYTES);

/// How a check estimates each pixel's variance of the mean.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CheckQuery {
    /// Samples per pixel.
    pub samples: u64,
    /// `Some((b, k))`: from `k` complete replicates of `b` samples; `None`: from the
    /// spread of independent samples.
    pub replicates: Option<(u32, u64)>,
}

/// The image-level sums of the stopping rule, over every pixel: Σv, Σv² and Σ mean, v a
/// pixel's variance of the mean (`film::standard_error` squared), each pixel's in f32 and
/// summed in f32 in a fixed tree, so the same on the same adapter for the same sums.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CheckSums {
    /// Σv.
    pub variance: f64,
    /// Σv².
    pub variance_sq: f64,
    /// Σ of the pixels' means.
    pub mean: f64,
    /// Pixels summed.
    pub pixels: u64,
}

impl std::ops::Add for CheckSums {
    type Output = CheckSums;

    /// The sums of `self` and `other` (bands of one image).
    fn add(self, other: CheckSums) -> CheckSums {
        CheckSums {
            variance: self.variance + other.variance,
            variance_sq: self.variance_sq + other.variance_sq,
            mean: self.mean + other.mean,
            pixels: self.pixels + other.pixels,
        }
    }
}

/// What an adaptive render's decisions need besides the sums: the samples per replicate
/// and what a sample can be.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptQuery {
    /// Samples per replicate.
    pub replicate: u32,
    /// What one sample can be.
    pub range: SampleRange,
    /// Pixels in a row of the image, whose neighbours decide a pixel's share.
    pub width: u32,
}

impl AdaptQuery {
    /// The range's kind as `stats.wgsl` takes it (0 binary, 1 bounded, 2 signed), and
    /// its bound in f32.
    pub fn range_code(&self) -> (u32, f32) {
        match self.range {
            SampleRange::Binary(m) => (0, m as f32),
            SampleRange::Bounded(m) => (1, m as f32),
            SampleRange::Signed(m) => (2, m as f32),
        }
    }

    /// The largest standard deviation a replicate's mean can have, half the samples'
    /// range, in f32 (`stats.wgsl`'s `sigma_bound`).
    pub fn sigma_bound(&self) -> f32 {
        match self.range_code() {
            (2, m) => m,
            (_, m) => 0.5 * m,
        }
    }
}

/// The image-level sums of an adaptive render's decisions, each pixel's terms
/// (`accumulation::pixel_sigma`) summed in f32 in a fixed tree (`accumulation::adapt_sums`
/// on the host is the same tree): the same bits for the same sums and counts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdaptSums {
    /// Σv, v a pixel's variance of the mean.
    pub variance: f32,
    /// Σv².
    pub variance_sq: f32,
    /// Σ of the pixels' means.
    pub mean: f32,
    /// Σ σ² / σ̃, σ the standard deviation of a pixel's replicate means the allocation
    /// takes and σ̃ its neighbours' (`accumulation::share_sigma`).
    pub sigma: f32,
    /// The fewest complete replicates of a pixel whose value is not exact (`None`: none).
    pub fewest: Option<u32>,
    /// The most complete replicates of any pixel.
    pub most: u32,
    /// Pixels summed.
    pub pixels: u64,
}

/// What [`DeviceSums::allocate`] does with the pixels still sampled that have their share.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stop {
    /// Counts them.
    Count,
    /// Stops them.
    Always,
    /// Stops them when some pixel goes on, in the same submission as the count: the
    /// rule's bound is not met yet, so stopping every pixel would end the render short
    /// of it.
    IfAnyGoesOn,
}

impl Stop {
    /// Whether the pixels that have their share are stopped, `going` pixels going on.
    pub fn applies(self, going: u32) -> bool {
        match self {
            Stop::Count => false,
            Stop::Always => true,
            Stop::IfAnyGoesOn => going > 0,
        }
    }
}

/// A film's exact sums on the device, with the buffers its checks reduce into.
pub struct DeviceSums {
    pipelines: StatsPipelines,
    bind_group: wgpu::BindGroup,
    /// Σv, Σv² and the replicates' Σ (Σv)², 128-bit words a slot.
    sums: [wgpu::Buffer; 3],
    params: wgpu::Buffer,
    partial: wgpu::Buffer,
    status: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Each pixel's samples and complete replicates (bit 31: stopped).
    counts: wgpu::Buffer,
    slots: u32,
    /// The film the kernels bind (for a bind group made again with room for kept values).
    film: wgpu::Buffer,
    /// The query and exponents the pixels' kept evaluations are of (`None`: none kept).
    kept: Option<(AdaptQuery, (i32, i32))>,
    /// Workgroups of a dispatch over the slots, and of one row of it.
    groups: u32,
    row_groups: u32,
    /// Bytes allocated.
    pub device_bytes: u64,
}

impl DeviceSums {
    /// Zero sums for the `slots` slots of `film`.
    pub fn new(ctx: &GpuContext, pipelines: StatsPipelines, film: &wgpu::Buffer, slots: u32) -> Result<DeviceSums> {
        let device = &ctx.device;
        let bytes = slots as u64 * 16;
        ctx.check_size("exact sums", bytes)?;
        let buffer = |label: &str, size: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor { label: Some(label), size, usage, mapped_at_creation: false })
        };
        let copy = wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let sums = ["sums", "squares", "replicate squares"]
            .map(|l| buffer(l, bytes.max(16), wgpu::BufferUsages::STORAGE | copy));
        let groups = slots.div_ceil(STATS_WORKGROUP).max(1);
        let row_groups = groups.min(device.limits().max_compute_workgroups_per_dimension);
        let params = buffer("stats params", PARAMS_BYTES, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST);
        // The workgroups' sums and their total; an adaptive check's kept values follow them
        // once one is made (`DeviceSums::keep_room`).
        let partial = buffer("stats partial sums", (groups as u64 + 1) * 16, wgpu::BufferUsages::STORAGE | copy);
        // The status, then a flag a workgroup for the adaptive checks.
        let status = buffer("stats status", 16 + groups as u64 * 4, wgpu::BufferUsages::STORAGE | copy);
        let readback =
            buffer("stats readback", CHECK_BYTES, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        let counts = buffer("stats counts", (slots as u64 * 8).max(16), wgpu::BufferUsages::STORAGE | copy);
        let bind_group = bind_stats(
            ctx,
            &pipelines.layout,
            [film, &sums[0], &sums[1], &sums[2], &params, &partial, &status, &counts],
        );
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("stats") });
        for b in sums.iter().chain([&status, &counts]) {
            encoder.clear_buffer(b, 0, None);
        }
        ctx.submit([encoder.finish()])?;
        let device_bytes = [&sums[0], &sums[1], &sums[2], &params, &partial, &status, &readback, &counts]
            .into_iter()
            .map(|b| b.size())
            .sum();
        Ok(DeviceSums {
            pipelines,
            bind_group,
            film: film.clone(),
            sums,
            params,
            partial,
            status,
            readback,
            counts,
            slots,
            kept: None,
            groups,
            row_groups,
            device_bytes,
        })
    }

    /// An encoder over the slots with `params`, which every pass it records reads.
    fn encoder(&self, ctx: &GpuContext, params: StatsParams) -> wgpu::CommandEncoder {
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("stats") })
    }

    /// Bytes of the partial sums with an adaptive check's kept values: the workgroups'
    /// sums and their total, each pixel's kept σ, v and mean, and each workgroup's record
    /// (`stats.wgsl`'s `stats_partial`).
    fn kept_partial_bytes(&self) -> u64 {
        (self.groups as u64 + 1) * 16 + KEPT_REGIONS * self.slots as u64 * 4 + self.groups as u64 * 8
    }

    /// Whether the partial sums have room for an adaptive check's kept values.
    fn has_kept_room(&self) -> bool {
        self.partial.size() >= self.kept_partial_bytes()
    }

    /// Makes room for an adaptive check's kept values (12 bytes a pixel), the first time
    /// one is made: renders that are not adaptive never hold them. The new buffer is
    /// zero, every pixel stale.
    fn keep_room(&mut self, ctx: &GpuContext) -> Result<()> {
        if self.has_kept_room() {
            return Ok(());
        }
        let bytes = self.kept_partial_bytes();
        ctx.check_size("stats partial sums", bytes)?;
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let partial = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("stats partial sums"),
            size: bytes,
            usage,
            mapped_at_creation: false,
        });
        let [s0, s1, s2] = &self.sums;
        let buffers = [&self.film, s0, s1, s2, &self.params, &partial, &self.status, &self.counts];
        self.bind_group = bind_stats(ctx, &self.pipelines.layout, buffers);
        self.device_bytes += bytes - self.partial.size();
        self.partial = partial;
        self.kept = None;
        ctx.take_error()
    }

    /// Marks every pixel's kept evaluation stale, on `encoder`.
    fn forget_kept(&self, encoder: &mut wgpu::CommandEncoder) {
        // The kept means, whose zero words mark stale pixels.
        let start = (self.groups as u64 + 1) * 16 + 2 * self.slots as u64 * 4;
        encoder.clear_buffer(&self.partial, start, Some(self.slots as u64 * 4));
    }

    /// Has the next [`DeviceSums::adapt_check`] evaluate every pixel again: the pixels'
    /// stopped marks were written from the host.
    pub fn forget(&mut self) {
        self.kept = None;
    }

    /// Records `pipeline` over `shape`.
    fn pass(&self, encoder: &mut wgpu::CommandEncoder, pipeline: &wgpu::ComputePipeline, shape: Shape) {
        let mut pass =
            encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("stats"), timestamp_writes: None });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        match shape {
            Shape::Slots => pass.dispatch_workgroups(self.row_groups, self.groups.div_ceil(self.row_groups), 1),
            Shape::Groups | Shape::Runs => {
                let invocations = match shape {
                    Shape::Groups => self.groups,
                    _ => self.slots.div_ceil(RUN_SLOTS),
                };
                let workgroups = invocations.div_ceil(SMALL_WORKGROUP).max(1);
                let row = workgroups.min(self.row_groups);
                pass.dispatch_workgroups(row, workgroups.div_ceil(row), 1)
            }
            Shape::One => pass.dispatch_workgroups(1, 1, 1),
        }
    }

    /// An encoder that runs `pipeline` over the slots with `params`.
    fn dispatch(
        &self,
        ctx: &GpuContext,
        pipeline: &wgpu::ComputePipeline,
        params: StatsParams,
    ) -> wgpu::CommandEncoder {
        let mut encoder = self.encoder(ctx, params);
        self.pass(&mut encoder, pipeline, Shape::Slots);
        encoder
    }

    fn params(&self) -> StatsParams {
        StatsParams {
            slots: self.slots,
            groups: self.groups,
            row_groups: self.row_groups,
            kept: self.has_kept_room() as u32,
            ..Default::default()
        }
    }

    /// The parameters of the stopping rule over the sums held, whose quanta have the
    /// exponents `exponents` (Σv's and Σv²'s, [`ExactSums`]'s), for an adaptive render's
    /// per-pixel counts (`adapt`) or for `check`'s uniform ones (set by the caller).
    fn rule_params(&self, exponents: (i32, i32), adapt: Option<AdaptQuery>) -> StatsParams {
        let base = StatsParams {
            sum_exponent: exponents.0,
            square_exponent: exponents.1,
            replicate_exponent: exponents.1 + REPLICATE_SQ_SHIFT,
            ..self.params()
        };
        match adapt {
            Some(query) => {
                let (range, max_value) = query.range_code();
                let (b, width) = (query.replicate as f32, query.width);
                StatsParams { b, range, max_value, width, ..base }
            }
            None => base,
        }
    }

    /// Adds the film's block of `taken` samples to the sums and counts and empties the
    /// film; with `replicate`, the block is one whole replicate and its square is added
    /// to the replicates' squares.
    pub fn fold(&self, ctx: &GpuContext, replicate: bool, taken: u32) -> Result<()> {
        let params = StatsParams { replicate: replicate as u32, taken, ..self.params() };
        let encoder = self.dispatch(ctx, &self.pipelines.fold, params);
        ctx.submit([encoder.finish()])
    }

    /// The image-level sums of the stopping rule for the sums held (`exponents`: those
    /// of the quanta of Σv and Σv², [`ExactSums`]'s); reads back [`CHECK_BYTES`].
    pub fn check(
        &mut self,
        ctx: &GpuContext,
        query: CheckQuery,
        exponents: (i32, i32),
        readback_bytes: &AtomicU64,
    ) -> Result<(CheckSums, Option<u32>)> {
        let (b, k) = query.replicates.unwrap_or((1, 0));
        let params = StatsParams {
            replicate: query.replicates.is_some() as u32,
            n: query.samples as f32,
            k: k as f32,
            b: b as f32,
            ..self.rule_params(exponents, None)
        };
        let p = &self.pipelines;
        let passes = [(&p.reduce, Shape::Slots), (&p.reduce_groups, Shape::One)];
        let words = self.reduce_and_read(ctx, params, false, &passes, readback_bytes)?;
        // Its workgroups' sums replace those an adaptive check keeps.
        self.kept = None;
        let f = |i: usize| f32::from_bits(words[i]) as f64;
        let sums = CheckSums { variance: f(0), variance_sq: f(1), mean: f(2), pixels: self.slots as u64 };
        Ok((sums, bad_slot(words[4])))
    }

    /// The image-level sums of an adaptive render's decisions over the sums and counts
    /// held, keeping each pixel's σ on the device for [`DeviceSums::allocate`] and the
    /// next checks (the rule is evaluated again only for the pixels folded since, and
    /// for all of them when `query` or `exponents` change); reads back [`CHECK_BYTES`].
    /// Also the first slot whose block held a sample out of range.
    pub fn adapt_check(
        &mut self,
        ctx: &GpuContext,
        query: AdaptQuery,
        exponents: (i32, i32),
        readback_bytes: &AtomicU64,
    ) -> Result<(AdaptSums, Option<u32>)> {
        self.keep_room(ctx)?;
        let params = self.rule_params(exponents, Some(query));
        let p = &self.pipelines;
        // Lanes in lockstep (a CPU's) sum a workgroup in one invocation, with no barrier;
        // a GPU's workgroup sums its slots in shared memory. The same tree either way.
        let group_sums = match ctx.cpu_lanes() {
            true => (&p.group_sums, Shape::Groups),
            false => (&p.group_sums_shared, Shape::Slots),
        };
        let passes = [(&p.evaluate, Shape::Runs), group_sums, (&p.reduce_groups, Shape::One)];
        let forget = self.kept != Some((query, exponents));
        let words = self.reduce_and_read(ctx, params, forget, &passes, readback_bytes)?;
        self.kept = Some((query, exponents));
        let f = |i: usize| f32::from_bits(words[i]);
        let sums = AdaptSums {
            variance: f(0),
            variance_sq: f(1),
            mean: f(2),
            sigma: f(3),
            fewest: (words[6] != 0).then(|| u32::MAX - words[6]),
            most: words[7],
            pixels: self.slots as u64,
        };
        Ok((sums, bad_slot(words[4])))
    }

    /// Counts the pixels still sampled whose replicates k reach σ̃ × `per_sigma`
    /// ([`AdaptSums`]'s σ), σ̃ from the σ the last [`DeviceSums::adapt_check`] of the same
    /// `query` and `exponents` kept (no block folded since), and stops them as `stop`
    /// says, in one submission; returns how many have their share and how many go on.
    /// Reads back [`CHECK_BYTES`].
    pub fn allocate(
        &self,
        ctx: &GpuContext,
        query: AdaptQuery,
        exponents: (i32, i32),
        per_sigma: f32,
        stop: Stop,
        readback_bytes: &AtomicU64,
    ) -> Result<(u32, u32)> {
        if self.kept != Some((query, exponents)) {
            return Err(Error::Gpu("an allocation without the check of its sums".into()));
        }
        let met = (stop == Stop::Always) as u32;
        let params = StatsParams { met, per_sigma, ..self.rule_params(exponents, Some(query)) };
        let p = &self.pipelines;
        let passes: &[_] = match stop {
            Stop::Count => &[(&p.allocate, Shape::Runs)],
            Stop::Always | Stop::IfAnyGoesOn => &[(&p.allocate, Shape::Runs), (&p.stop_allocated, Shape::Runs)],
        };
        let words = self.reduce_and_read(ctx, params, false, passes, readback_bytes)?;
        Ok((words[5], words[6]))
    }

    /// Clears the status words past the first and the workgroups' flags (and the pixels'
    /// kept evaluations, with `forget`), runs `passes` in turn and reads back the total
    /// and the status: one submission.
    fn reduce_and_read(
        &self,
        ctx: &GpuContext,
        params: StatsParams,
        forget: bool,
        passes: &[(&wgpu::ComputePipeline, Shape)],
        readback_bytes: &AtomicU64,
    ) -> Result<Vec<u32>> {
        let mut encoder = self.encoder(ctx, params);
        encoder.clear_buffer(&self.status, 4, None);
        if forget {
            self.forget_kept(&mut encoder);
        }
        for &(pipeline, shape) in passes {
            self.pass(&mut encoder, pipeline, shape);
        }
        encoder.copy_buffer_to_buffer(&self.partial, self.groups as u64 * 16, &self.readback, 0, Some(16));
        encoder.copy_buffer_to_buffer(&self.status, 0, &self.readback, 16, Some(16));
        ctx.submit([encoder.finish()])?;
        let words: Vec<u32> = ctx.read(&self.readback)?;
        readback_bytes.fetch_add(CHECK_BYTES, Ordering::Relaxed);
        Ok(words)
    }

    /// Each pixel's samples, complete replicates and whether it is stopped, read through
    /// `staging` (a readback buffer of at least 8 bytes a slot).
    pub fn read_counts(
        &self,
        ctx: &GpuContext,
        staging: &wgpu::Buffer,
        readback_bytes: &AtomicU64,
    ) -> Result<Vec<(u32, u32, bool)>> {
        let mut encoder = self.dispatch(ctx, &self.pipelines.mark, self.params());
        encoder.copy_buffer_to_buffer(&self.counts, 0, staging, 0, Some(self.slots as u64 * 8));
        ctx.submit([encoder.finish()])?;
        let words: Vec<[u32; 2]> = ctx.read(staging)?;
        readback_bytes.fetch_add(staging.size(), Ordering::Relaxed);
        Ok(words[..self.slots as usize].iter().map(|w| (w[0], w[1] & 0x7fff_ffff, w[1] >> 31 == 1)).collect())
    }

    /// Replaces `exact`'s Σv, Σv² and (where `replicates`) the replicates' squares with
    /// the device's, read through `staging` (a readback buffer of at least 16 bytes a
    /// slot: the film's); returns the first slot whose block held a sample out of range.
    /// One round trip a kind of sum: the status word comes back with the last of them.
    pub fn read(
        &self,
        ctx: &GpuContext,
        staging: &wgpu::Buffer,
        exact: &mut ExactSums,
        replicates: bool,
        readback_bytes: &AtomicU64,
    ) -> Result<Option<u32>> {
        let n = self.slots as usize;
        if exact.sum.len() != n {
            return Err(Error::Gpu(format!("{} device sums read into sums of {} pixels", n, exact.sum.len())));
        }
        let bytes = self.slots as u64 * 16;
        if replicates && exact.replicate_sq.len() != n {
            exact.replicate_sq = vec![0; n];
        }
        let targets: Vec<&mut Vec<i128>> = match replicates {
            true => vec![&mut exact.sum, &mut exact.sum_sq, &mut exact.replicate_sq],
            false => vec![&mut exact.sum, &mut exact.sum_sq],
        };
        // A staging buffer the size of all the sums would save a round trip or two at the
        // cost of up to three times the film's readback memory: each kind of sum comes
        // through the film's in turn.
        let last = targets.len() - 1;
        let mut bad = None;
        for (k, (source, dst)) in self.sums.iter().zip(targets).enumerate() {
            let mut encoder =
                ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("sums") });
            encoder.copy_buffer_to_buffer(source, 0, staging, 0, Some(bytes));
            if k == last {
                encoder.copy_buffer_to_buffer(&self.status, 0, &self.readback, 16, Some(16));
            }
            ctx.submit([encoder.finish()])?;
            let buffers: &[&wgpu::Buffer] = if k == last { &[staging, &self.readback] } else { &[staging] };
            ctx.read_mapped(buffers, |views| {
                wide_sums(&bytemuck::cast_slice::<u8, [u32; 4]>(views[0])[..n], dst);
                if k == last {
                    bad = bad_slot(bytemuck::cast_slice::<u8, u32>(views[1])[4]);
                }
            })?;
            readback_bytes.fetch_add(staging.size(), Ordering::Relaxed);
        }
        readback_bytes.fetch_add(CHECK_BYTES, Ordering::Relaxed);
        Ok(bad)
    }

    /// Replaces the device's sums with `exact`'s (the replicates' squares zero where it
    /// has none), and its counts with `exact`'s per-pixel ones, or `samples` and its
    /// replicates for every pixel.
    pub fn write(&mut self, ctx: &GpuContext, exact: &ExactSums, samples: u32) -> Result<()> {
        let n = self.slots as usize;
        if exact.sum.len() != n {
            return Err(Error::Gpu(format!("sums of {} pixels written to device sums of {n}", exact.sum.len())));
        }
        let words = |v: &[i128]| -> Vec<[u32; 4]> {
            let mut out: Vec<[u32; 4]> = v
                .iter()
                .map(|&x| x as u128)
                .map(|x| [x as u32, (x >> 32) as u32, (x >> 64) as u32, (x >> 96) as u32])
                .collect();
            out.resize(n, [0; 4]);
            out
        };
        // Sums that are all zero (a render's start) are cleared on the device rather than
        // sent: at 1080p that is 100 MB the host need not build and upload.
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("status") });
        for (buffer, sums) in self.sums.iter().zip([&exact.sum, &exact.sum_sq, &exact.replicate_sq]) {
            match sums.iter().all(|&x| x == 0) {
                true => encoder.clear_buffer(buffer, 0, None),
                false => ctx.queue.write_buffer(buffer, 0, bytemuck::cast_slice(&words(sums))),
            }
        }
        let uniform = exact.pixel_samples.is_empty();
        if uniform && samples == 0 && exact.replicates == 0 {
            encoder.clear_buffer(&self.counts, 0, None);
        } else {
            let counts: Vec<[u32; 2]> = match uniform {
                true => vec![[samples, exact.replicates as u32]; n],
                false => exact.pixel_samples.iter().zip(&exact.pixel_replicates).map(|(&s, &k)| [s, k]).collect(),
            };
            ctx.queue.write_buffer(&self.counts, 0, bytemuck::cast_slice(&counts));
        }
        encoder.clear_buffer(&self.status, 0, None);
        if self.has_kept_room() {
            self.forget_kept(&mut encoder);
        }
        self.kept = None;
        ctx.submit([encoder.finish()])?;
        ctx.wait()
    }
}

/// The statistics kernels' bind group over `buffers`, in binding order: the film, Σv, Σv²,
/// the replicates' squares, the parameters, the partial sums, the status and the counts.
fn bind_stats(ctx: &GpuContext, layout: &wgpu::BindGroupLayout, buffers: [&wgpu::Buffer; 8]) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = (0u32..)
        .zip(buffers)
        .map(|(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() })
        .collect();
    ctx.device.create_bind_group(&wgpu::BindGroupDescriptor { label: Some("stats"), layout, entries: &entries })
}

/// Device words of 128-bit sums (little-endian 32-bit words, lowest first) as `dst`'s
/// integers, in chunks on rayon's threads: each integer is its own words', so the same
/// bits on any number of threads.
pub(crate) fn wide_sums(words: &[[u32; 4]], dst: &mut [i128]) {
    let wide =
        |w: &[u32; 4]| (w[0] as u128 | (w[1] as u128) << 32 | (w[2] as u128) << 64 | (w[3] as u128) << 96) as i128;
    dst.par_chunks_mut(WIDE_CHUNK)
        .zip(words.par_chunks(WIDE_CHUNK))
        .for_each(|(d, w)| d.iter_mut().zip(w).for_each(|(d, w)| *d = wide(w)));
}

/// Sums a rayon task converts at a time: enough to outweigh the task's cost.
const WIDE_CHUNK: usize = 1 << 14;

/// The slot a status word names (`stats.wgsl`'s `stats_status`), if any.
fn bad_slot(word: u32) -> Option<u32> {
    (word != 0).then(|| u32::MAX - word)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `count` words of pseudo-random bits, with the sign bit set in some.
    fn words(count: usize) -> Vec<[u32; 4]> {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u32
        };
        (0..count).map(|_| [next(), next(), next(), next()]).collect()
    }

    /// The words of 128-bit sums become the same integers on 1, 2, 3 and 8 threads, at
    /// sizes around the chunks the threads take, as each word's bytes read as one
    /// little-endian integer on one thread.
    #[test]
    fn wide_sums_are_the_same_on_any_number_of_threads() {
        for count in [0, 1, WIDE_CHUNK - 1, WIDE_CHUNK, WIDE_CHUNK + 1, 3 * WIDE_CHUNK + 7] {
            let words = words(count);
            let expected: Vec<i128> =
                words.iter().map(|w| i128::from_le_bytes(bytemuck::cast::<[u32; 4], [u8; 16]>(*w))).collect();
            assert!(count < 2 || expected.iter().any(|&x| x < 0) && expected.iter().any(|&x| x > 0), "{count}");
            for threads in [1, 2, 3, 8] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let mut got = vec![7i128; count];
                pool.install(|| wide_sums(&words, &mut got));
                assert!(got == expected, "{count} sums on {threads} threads");
            }
        }
    }
}
