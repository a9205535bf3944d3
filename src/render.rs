//! The progressive driver: builds the BVH, runs passes of a few samples per pixel on the
//! GPU or the CPU reference until the sample count or the time limit is reached, and
//! reports progress through a callback.

use crate::bvh::{self, BuildQuality, BvhLayout, GpuBvh};
use crate::cpu::CpuTracer;
use crate::error::Result;
use crate::film::Film;
use crate::gpu::{GpuContext, GpuRenderer, MAX_PASS_SAMPLES};
use crate::scene::Scene;
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
    /// Samples per pixel rendered (fewer than asked when the time limit hit).
    pub samples_per_pixel: u32,
    /// Samples per pixel asked for.
    pub samples_requested: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Camera rays plus AO rays.
    pub rays_traced: u64,
    /// Camera rays.
    pub camera_rays: u64,
    /// AO rays (one per camera ray that hit something).
    pub ao_rays: u64,
    /// Seconds spent in passes (BVH build and upload excluded).
    pub render_seconds: f64,
    /// Seconds to build the BVH.
    pub bvh_build_seconds: f64,
    /// Seconds to upload buffers and create the pipeline (GPU only).
    pub setup_seconds: f64,
    /// rays_traced / render_seconds.
    pub rays_per_second: f64,
    /// Triangles in the scene.
    pub triangles: usize,
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
    /// Passes run.
    pub passes: u32,
    /// Mean of the image.
    pub image_mean: f64,
}

/// A finished render.
pub struct RenderOutput {
    /// The accumulation.
    pub film: Film,
    /// Its figures.
    pub stats: RenderStats,
}

/// Seconds a pass aims for: long enough to amortise the round trip, short enough for
/// progress, time limits and GPU watchdogs.
const PASS_TARGET_SECONDS: f64 = 0.25;

/// Runs passes until `total` samples or the time limit; `run_pass(first, count)` renders
/// one pass and returns its AO rays.
fn progressive(
    scene: &Scene,
    options: &RenderOptions,
    progress: &mut dyn FnMut(&Progress),
    mut run_pass: impl FnMut(u32, u32) -> Result<u64>,
) -> Result<(u32, u64, f64, u32)> {
    let s = &scene.settings;
    let pixels = s.width as u64 * s.height as u64;
    let start = Instant::now();
    let (mut done, mut ao_rays, mut passes, mut count) = (0u32, 0u64, 0u32, 1u32);
    while done < s.spp {
        let elapsed = start.elapsed().as_secs_f64();
        if let Some(limit) = options.time_limit
            && elapsed >= limit
            && done > 0
        {
            break;
        }
        let count_now = count.min(s.spp - done);
        let pass_start = Instant::now();
        ao_rays += run_pass(done, count_now)?;
        let seconds = pass_start.elapsed().as_secs_f64().max(1e-6);
        done += count_now;
        passes += 1;
        // Size the next pass to the target time (at most doubling), and to what is left of the limit.
        let mut target = PASS_TARGET_SECONDS;
        if let Some(limit) = options.time_limit {
            target = target.min((limit - start.elapsed().as_secs_f64()).max(0.0));
        }
        let per_sample = seconds / count_now as f64;
        count = ((target / per_sample) as u32).clamp(1, (2 * count_now).min(MAX_PASS_SAMPLES));
        progress(&Progress {
            samples_done: done,
            samples_total: s.spp,
            rays: done as u64 * pixels + ao_rays,
            elapsed: start.elapsed().as_secs_f64(),
        });
    }
    Ok((done, ao_rays, start.elapsed().as_secs_f64(), passes))
}

/// Renders `scene` with its settings.
pub fn render(scene: &Scene, options: &RenderOptions, progress: &mut dyn FnMut(&Progress)) -> Result<RenderOutput> {
    let s = &scene.settings;
    s.validate().map_err(|m| crate::Error::scene(&scene.name, m))?;
    let (film, done, ao_rays, render_seconds, passes, build_seconds, setup_seconds, device_info, device_bytes, layout) =
        match options.device {
            Device::Gpu => {
                let ctx = GpuContext::new(options.adapter.as_deref())?;
                // Build time includes the conversion to the GPU layout.
                let build = Instant::now();
                let gpu_bvh = GpuBvh::build(scene, options.bvh_layout, options.bvh_quality);
                let build_seconds = build.elapsed().as_secs_f64();
                let setup = Instant::now();
                let mut renderer = GpuRenderer::new(&ctx, scene, &gpu_bvh)?;
                drop(gpu_bvh);
                let setup_seconds = setup.elapsed().as_secs_f64();
                let (done, ao, secs, passes) = progressive(scene, options, progress, |first, count| {
                    Ok(renderer.render_pass(first, count)?.ao_rays)
                })?;
                let film = renderer.read_film(done as u64)?;
                let d = ctx.description.clone();
                (
                    film,
                    done,
                    ao,
                    secs,
                    passes,
                    build_seconds,
                    setup_seconds,
                    d,
                    renderer.device_bytes,
                    renderer.layout.name(),
                )
            }
            Device::Cpu => {
                let build = Instant::now();
                let cwbvh = bvh::build_cwbvh(scene, options.bvh_quality);
                let build_seconds = build.elapsed().as_secs_f64();
                let tracer = CpuTracer::new(scene, cwbvh);
                let mut film = Film::new(s.width, s.height);
                let (done, ao, secs, passes) = progressive(scene, options, progress, |first, count| {
                    Ok(tracer.render_pass(scene, &mut film, first, count))
                })?;
                let d = crate::gpu::AdapterDescription {
                    name: "cpu".into(),
                    backend: "cpu".into(),
                    device_type: "Cpu".into(),
                    driver: format!("obvhs cwbvh, {} threads", rayon::current_num_threads()),
                };
                (film, done, ao, secs, passes, build_seconds, 0.0, d, 0, "cwbvh")
            }
        };
    let camera_rays = done as u64 * s.width as u64 * s.height as u64;
    let rays = camera_rays + ao_rays;
    let stats = RenderStats {
        scene: scene.name.clone(),
        samples_per_pixel: done,
        samples_requested: s.spp,
        width: s.width,
        height: s.height,
        rays_traced: rays,
        camera_rays,
        ao_rays,
        render_seconds,
        bvh_build_seconds: build_seconds,
        setup_seconds,
        rays_per_second: rays as f64 / render_seconds.max(1e-9),
        triangles: scene.triangles.len(),
        spheres: scene.spheres.len(),
        planes: scene.planes.len(),
        adapter: device_info.name,
        backend: device_info.backend,
        device_type: device_info.device_type,
        driver: device_info.driver,
        hemisphere: s.hemisphere.name().into(),
        sampler: s.sampler.name().into(),
        seed: s.seed,
        bvh_layout: layout.into(),
        device_bytes,
        passes,
        image_mean: film.image_mean(),
    };
    Ok(RenderOutput { film, stats })
}
