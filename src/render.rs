//! The progressive driver: builds the BVH, runs passes of a few samples per pixel on the
//! GPU or the CPU reference until the sample range is done, the time limit is reached or
//! a stop is asked for, and reports progress through a callback.
//!
//! Samples are summed in blocks of [`BLOCK_SAMPLES`] sample indices: the device sums a
//! block in its own arithmetic, then the block is added to exact fixed-point sums. The
//! accumulation ([`Accumulation`]) can be saved at any pass and continued from the same
//! bits, and accumulations of disjoint sample ranges merge exactly.

use crate::bvh::{self, BuildQuality, BvhLayout, GpuBvh};
use crate::checkpoint::Accumulation;
use crate::cpu::CpuTracer;
use crate::error::{Error, Result};
use crate::film::{BLOCK_SAMPLES, BlockSums, Film};
use crate::gpu::{GpuContext, GpuRenderer, MAX_PASS_SAMPLES};
use crate::scene::Scene;
use crate::shaders::GeometryStorage;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Where to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Device {
    /// WGSL compute shaders on a wgpu adapter.
    #[default]
    Gpu,
    /// The multi-threaded CPU reference.
    Cpu,
}

/// How to render (what to render is in the scene's settings).
#[derive(Clone, Debug, Default)]
pub struct RenderOptions {
    /// GPU or CPU.
    pub device: Device,
    /// Substring of the adapter's name to pick (GPU only).
    pub adapter: Option<String>,
    /// Stop after the pass that crosses this many seconds.
    pub time_limit: Option<f64>,
    /// BVH build preset.
    pub bvh_quality: BuildQuality,
    /// BVH layout the GPU traverses (the CPU reference always uses obvhs's CWBVH).
    pub bvh_layout: BvhLayout,
    /// Where the GPU kernel reads the geometry from; `None` is the adapter's preference
    /// ([`GeometryStorage::preferred`]).
    pub geometry_storage: Option<GeometryStorage>,
    /// Sample indices to render, `start..end` with `end` at most the samples per pixel;
    /// `None` is all of them, `0..spp`. The cell samplers still place their cells for
    /// `spp` samples, so disjoint ranges are parts of one render.
    pub sample_range: Option<Range<u32>>,
    /// Set from another thread (a signal handler) to stop the render after its current
    /// pass; the render then returns the samples done, with [`RenderStats::interrupted`].
    pub stop: Option<Arc<AtomicBool>>,
}

/// Progress after each pass.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Samples per pixel done.
    pub samples_done: u32,
    /// Samples per pixel asked for.
    pub samples_total: u32,
    /// Camera and AO rays so far.
    pub rays: u64,
    /// Seconds since the first pass began.
    pub elapsed: f64,
}

/// Figures of a finished render (serialised by `--stats`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct RenderStats {
    /// Scene name.
    pub scene: String,
    /// Samples per pixel in the accumulation (fewer than asked when the time limit or a
    /// stop ended the render early), including those of a checkpoint it continued.
    pub samples_per_pixel: u32,
    /// Samples per pixel asked for: the length of the sample range.
    pub samples_requested: u32,
    /// First sample index of the range.
    pub first_sample: u32,
    /// Samples per pixel taken from the checkpoint the render continued (0 for none).
    pub samples_resumed: u32,
    /// True when a stop request ended the render before its range was done.
    pub interrupted: bool,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays plus AO rays (including those of a checkpoint the render continued).
    pub rays_traced: u64,
    /// Camera rays.
    pub camera_rays: u64,
    /// AO rays (one per camera ray that hit something).
    pub ao_rays: u64,
    /// Seconds spent in passes and checkpoints (BVH build and upload excluded), including
    /// those of a checkpoint the render continued.
    pub render_seconds: f64,
    /// Seconds to build the BVH.
    pub bvh_build_seconds: f64,
    /// Seconds to upload buffers and create the pipeline (GPU only).
    pub setup_seconds: f64,
    /// rays_traced / render_seconds.
    pub rays_per_second: f64,
    /// Triangles in the scene.
    pub triangles: usize,
    /// Placements of meshes placed more than once (their triangles are in `triangles`).
    pub instances: usize,
    /// Spheres in the scene.
    pub spheres: usize,
    /// Planes in the scene.
    pub planes: usize,
    /// Adapter name ("cpu" for the reference).
    pub adapter: String,
    /// wgpu backend, or "cpu".
    pub backend: String,
    /// Adapter device type, or "cpu".
    pub device_type: String,
    /// Driver.
    pub driver: String,
    /// Hemisphere distribution.
    pub hemisphere: String,
    /// 2-D point sampler of the hemisphere and pixel numbers.
    pub sampler: String,
    /// Random seed.
    pub seed: u32,
    /// BVH layout traversed.
    pub bvh_layout: String,
    /// Bytes of device memory allocated (GPU only).
    pub device_bytes: u64,
    /// Storage bindings the BVH nodes and primitives were split into (GPU only; 2 when
    /// each fits one binding).
    pub geometry_bindings: u32,
    /// What holds them on the device: `buffers` or `textures` (empty on the CPU).
    pub geometry_storage: String,
    /// Bytes of the scene's geometry on the host: its triangles, spheres and planes.
    pub scene_bytes: u64,
    /// Bytes of the BVH as traversed: its nodes and primitive records, as uploaded to the
    /// device (GPU) or held by the tracer (CPU).
    pub bvh_bytes: u64,
    /// Peak resident memory of the process so far, in bytes (Linux; 0 elsewhere).
    pub host_peak_bytes: u64,
    /// The most bytes aorender's own heap held at once so far: the loaded scene, the BVH
    /// build's workspace, the bytes prepared for upload; not the driver's. `None` when the
    /// program did not install `memory::CountingAlloc`.
    pub heap_peak_bytes: Option<u64>,
    /// Seconds to read and parse the scene and its meshes: set by the caller that loaded
    /// it (`aorender render` does), 0 for a scene made in memory.
    pub load_seconds: f64,
    /// Passes run (including those of a checkpoint the render continued).
    pub passes: u32,
    /// Mean of the image.
    pub image_mean: f64,
}

/// A finished render.
pub struct RenderOutput {
    /// The accumulation as per-pixel sums.
    pub film: Film,
    /// Its figures.
    pub stats: RenderStats,
    /// The raw accumulation, as a checkpoint stores it.
    pub accumulation: Accumulation,
}

/// Receives an accumulation to save.
pub type SaveFn<'a> = &'a mut dyn FnMut(&Accumulation) -> Result<()>;

/// Saving and continuing a render.
#[derive(Default)]
pub struct Checkpointing<'a> {
    /// An accumulation to continue (from [`Accumulation::read`]): of the same scene and
    /// sample settings, device, BVH options and first sample. The render adds the samples
    /// from where it stopped to the end of the range, and the result has the same bits as
    /// a render that never stopped, on the same adapter.
    pub resume: Option<Accumulation>,
    /// Seconds between two saves, at least; stretched so that saving takes at most a tenth
    /// of the render's time. Zero or less saves after every pass, however long saving takes.
    pub interval: f64,
    /// Receives the accumulation every `interval` seconds and when the render ends
    /// (finished, out of time or stopped), not after an error: the last saved one stays.
    pub save: Option<SaveFn<'a>>,
}

/// Seconds a pass aims for: long enough to amortise the round trip, short enough for
/// progress, time limits and GPU watchdogs.
const PASS_TARGET_SECONDS: f64 = 0.25;

/// A device summing samples one block at a time.
trait BlockDevice {
    /// Adds samples `first .. first + count` of every pixel to the block; returns the AO
    /// rays traced.
    fn pass(&mut self, first: u32, count: u32) -> Result<u64>;
    /// The block's sums so far.
    fn read(&mut self) -> Result<BlockSums>;
    /// The block's sums, leaving the block empty.
    fn take(&mut self) -> Result<BlockSums>;
    /// Replaces the block's sums (from a checkpoint).
    fn load(&mut self, block: &BlockSums) -> Result<()>;
}

struct GpuBlocks<'r, 'c> {
    renderer: &'r mut GpuRenderer<'c>,
}

impl BlockDevice for GpuBlocks<'_, '_> {
    fn pass(&mut self, first: u32, count: u32) -> Result<u64> {
        Ok(self.renderer.render_pass(first, count)?.ao_rays)
    }

    fn read(&mut self) -> Result<BlockSums> {
        Ok(BlockSums::Gpu(self.renderer.film_words()?))
    }

    fn take(&mut self) -> Result<BlockSums> {
        let block = self.read()?;
        self.renderer.clear_film()?;
        Ok(block)
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        match block {
            BlockSums::Gpu(words) => self.renderer.set_film_words(words),
            BlockSums::Cpu { .. } => Err(Error::Gpu("the CPU reference's sums cannot continue on the GPU".into())),
        }
    }
}

struct CpuBlocks<'s> {
    tracer: CpuTracer,
    scene: &'s Scene,
    film: Film,
}

impl BlockDevice for CpuBlocks<'_> {
    fn pass(&mut self, first: u32, count: u32) -> Result<u64> {
        Ok(self.tracer.render_pass(self.scene, &mut self.film, first, count))
    }

    fn read(&mut self) -> Result<BlockSums> {
        Ok(BlockSums::Cpu { sum: self.film.sum.clone(), sum_sq: self.film.sum_sq.clone() })
    }

    fn take(&mut self) -> Result<BlockSums> {
        let empty = Film::new(self.film.width, self.film.height);
        let film = std::mem::replace(&mut self.film, empty);
        Ok(BlockSums::Cpu { sum: film.sum, sum_sq: film.sum_sq })
    }

    fn load(&mut self, block: &BlockSums) -> Result<()> {
        match block {
            BlockSums::Cpu { sum, sum_sq } if sum.len() == self.film.sum.len() && sum_sq.len() == sum.len() => {
                self.film.sum.clone_from(sum);
                self.film.sum_sq.clone_from(sum_sq);
                Ok(())
            }
            _ => Err(Error::scene(&self.scene.name, "the checkpoint's block does not fit the CPU reference's film")),
        }
    }
}

/// How a run of passes ended.
struct Run {
    /// A stop request ended it early.
    interrupted: bool,
}

/// Runs passes over `acc.next .. acc.end`, in blocks, until done, out of time or stopped;
/// saves the accumulation through `save` every `interval` seconds and at the end.
fn accumulate(
    scene: &Scene,
    options: &RenderOptions,
    acc: &mut Accumulation,
    device: &mut dyn BlockDevice,
    save: &mut Option<SaveFn<'_>>,
    interval: f64,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Run> {
    let pixels = scene.settings.width as u64 * scene.settings.height as u64;
    let start = Instant::now();
    let seconds_before = acc.render_seconds;
    let total = acc.end - acc.first;
    let (mut passes, mut count, mut interrupted) = (0u32, 1u32, false);
    let (mut last_save, mut save_seconds) = (Instant::now(), 0.0f64);
    while acc.next < acc.end {
        if options.stop.as_ref().is_some_and(|s| s.load(Ordering::SeqCst)) {
            interrupted = true;
            break;
        }
        if let Some(limit) = options.time_limit
            && start.elapsed().as_secs_f64() >= limit
            && passes > 0
        {
            break;
        }
        // A pass stays within one block.
        let block_end = ((acc.next / BLOCK_SAMPLES) as u64 + 1) * BLOCK_SAMPLES as u64;
        let block_end = block_end.min(acc.end as u64) as u32;
        let count_now = count.min(block_end - acc.next);
        let pass_start = Instant::now();
        acc.ao_rays += device.pass(acc.next, count_now)?;
        let seconds = pass_start.elapsed().as_secs_f64().max(1e-6);
        acc.next += count_now;
        acc.partial_samples += count_now;
        acc.passes += 1;
        passes += 1;
        if acc.next == block_end {
            let block = device.take()?;
            acc.exact.add_block(&block).map_err(|m| Error::scene(&scene.name, m))?;
            acc.partial_samples = 0;
        }
        // Size the next pass to the target time and to what is left of the limit, growing at
        // most eightfold (the first passes' times include warm-up): a fast adapter reaches
        // full-size passes within three round trips.
        let mut target = PASS_TARGET_SECONDS;
        if let Some(limit) = options.time_limit {
            target = target.min((limit - start.elapsed().as_secs_f64()).max(0.0));
        }
        let per_sample = seconds / count_now as f64;
        count = ((target / per_sample) as u32).clamp(1, (8 * count).min(MAX_PASS_SAMPLES));
        acc.render_seconds = seconds_before + start.elapsed().as_secs_f64();
        progress(&Progress {
            samples_done: acc.samples(),
            samples_total: total,
            rays: acc.samples() as u64 * pixels + acc.ao_rays,
            elapsed: acc.render_seconds,
        });
        if let Some(save) = save.as_mut()
            && acc.next < acc.end
            && (interval <= 0.0 || last_save.elapsed().as_secs_f64() >= interval.max(10.0 * save_seconds))
        {
            let t = Instant::now();
            acc.partial = if acc.partial_samples > 0 { Some(device.read()?) } else { None };
            save(acc)?;
            acc.partial = None;
            save_seconds = t.elapsed().as_secs_f64();
            last_save = Instant::now();
        }
    }
    acc.partial = if acc.partial_samples > 0 { Some(device.read()?) } else { None };
    acc.render_seconds = seconds_before + start.elapsed().as_secs_f64();
    // Without a pass the last checkpoint is already this accumulation.
    if passes > 0
        && let Some(save) = save.as_mut()
    {
        save(acc)?;
    }
    Ok(Run { interrupted })
}

/// Renders `scene` with its settings.
pub fn render(scene: &Scene, options: &RenderOptions, progress: &mut dyn FnMut(&Progress)) -> Result<RenderOutput> {
    render_resumable(scene, options, Checkpointing::default(), progress)
}

/// Renders `scene` with its settings, continuing `checkpointing.resume` when given and
/// handing the accumulation to `checkpointing.save` as it goes.
pub fn render_resumable(
    scene: &Scene,
    options: &RenderOptions,
    checkpointing: Checkpointing,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RenderOutput> {
    let s = &scene.settings;
    s.validate().map_err(|m| Error::scene(&scene.name, m))?;
    let range = options.sample_range.clone().unwrap_or(0..s.spp);
    if range.start >= range.end || range.end > s.spp {
        return Err(Error::scene(
            &scene.name,
            format!(
                "sample range {}..{} must be non-empty and end at most at the {} samples per pixel",
                range.start, range.end, s.spp
            ),
        ));
    }
    // The CPU reference always traverses obvhs's CWBVH.
    let layout = match options.device {
        Device::Gpu => options.bvh_layout,
        Device::Cpu => BvhLayout::Cwbvh,
    };
    let Checkpointing { resume, interval, mut save } = checkpointing;
    let mut acc = match resume {
        Some(mut acc) => {
            acc.check_resume(scene, options.device, layout, options.bvh_quality, range.start, range.end)
                .map_err(|m| Error::scene(acc.source.clone().unwrap_or_else(|| "checkpoint".into()), m))?;
            if acc.end != range.end {
                // A last block cut short by the old end was summed as a block of its own.
                if acc.next == acc.end && acc.end % BLOCK_SAMPLES != 0 {
                    acc.on_grid = false;
                }
                acc.end = range.end;
            }
            acc
        }
        None => Accumulation::new(scene, options.device, layout, options.bvh_quality, range.start, range.end),
    };
    let resumed = acc.samples();
    let partial = acc.partial.take();
    let (run, build_seconds, setup_seconds, device_info, on_device, bvh_bytes) = match options.device {
        Device::Gpu => {
            let mut ctx = GpuContext::new(options.adapter.as_deref())?;
            if let Some(storage) = options.geometry_storage {
                ctx.set_geometry_storage(storage);
            }
            // Build time includes the conversion to the GPU layout.
            let build = Instant::now();
            let gpu_bvh = GpuBvh::build(scene, options.bvh_layout, options.bvh_quality);
            let build_seconds = build.elapsed().as_secs_f64();
            let setup = Instant::now();
            let mut renderer = GpuRenderer::new(&ctx, scene, &gpu_bvh)?;
            let bvh_bytes = gpu_bvh.bytes();
            drop(gpu_bvh);
            let setup_seconds = setup.elapsed().as_secs_f64();
            acc.adapter = ctx.description.name.clone();
            let mut device = GpuBlocks { renderer: &mut renderer };
            if let Some(block) = &partial {
                device.load(block)?;
            }
            let run = accumulate(scene, options, &mut acc, &mut device, &mut save, interval, progress)?;
            let bytes = (renderer.device_bytes, renderer.geometry_bindings, renderer.geometry_storage.name());
            (run, build_seconds, setup_seconds, ctx.description.clone(), bytes, bvh_bytes)
        }
        Device::Cpu => {
            let build = Instant::now();
            let cwbvh = bvh::build_cwbvh(scene, options.bvh_quality);
            let build_seconds = build.elapsed().as_secs_f64();
            let d = crate::gpu::AdapterDescription {
                name: "cpu".into(),
                backend: "cpu".into(),
                device_type: "Cpu".into(),
                driver: format!("obvhs cwbvh, {} threads", rayon::current_num_threads()),
            };
            acc.adapter = d.name.clone();
            let tracer = CpuTracer::new(scene, cwbvh);
            let bvh_bytes = tracer.bytes();
            let mut device = CpuBlocks { tracer, scene, film: Film::new(s.width, s.height) };
            if let Some(block) = &partial {
                device.load(block)?;
            }
            let run = accumulate(scene, options, &mut acc, &mut device, &mut save, interval, progress)?;
            (run, build_seconds, 0.0, d, (0, 0, ""), bvh_bytes)
        }
    };
    let film = acc.film().map_err(|m| Error::scene(&scene.name, m))?;
    let done = acc.samples();
    let camera_rays = done as u64 * s.width as u64 * s.height as u64;
    let rays = camera_rays + acc.ao_rays;
    let (device_bytes, geometry_bindings, geometry_storage) = on_device;
    let stats = RenderStats {
        scene: scene.name.clone(),
        samples_per_pixel: done,
        samples_requested: range.end - range.start,
        first_sample: range.start,
        samples_resumed: resumed,
        interrupted: run.interrupted,
        width: s.width,
        height: s.height,
        rays_traced: rays,
        camera_rays,
        ao_rays: acc.ao_rays,
        render_seconds: acc.render_seconds,
        bvh_build_seconds: build_seconds,
        setup_seconds,
        rays_per_second: rays as f64 / acc.render_seconds.max(1e-9),
        triangles: scene.world_triangle_count(),
        instances: scene.instances.len(),
        spheres: scene.spheres.len(),
        planes: scene.planes.len(),
        adapter: device_info.name,
        backend: device_info.backend,
        device_type: device_info.device_type,
        driver: device_info.driver,
        hemisphere: s.hemisphere.name().into(),
        sampler: s.sampler.name().into(),
        seed: s.seed,
        bvh_layout: layout.name().into(),
        device_bytes,
        geometry_bindings,
        geometry_storage: geometry_storage.into(),
        scene_bytes: scene.geometry_bytes(),
        bvh_bytes,
        host_peak_bytes: crate::memory::peak_rss_bytes().unwrap_or(0),
        heap_peak_bytes: crate::memory::heap_peak_bytes(),
        load_seconds: 0.0,
        passes: acc.passes,
        image_mean: film.image_mean(),
    };
    Ok(RenderOutput { film, stats, accumulation: acc })
}
