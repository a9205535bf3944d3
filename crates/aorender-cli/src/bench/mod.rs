//! `aorender bench`: how fast each hemisphere × point sampler converges on real scenes,
//! on this machine's adapter and on the CPU reference, and where the time goes.
//!
//! For every scene of a [`Plan`] and every configuration (hemisphere distribution ×
//! point sampler) one progressive render reads its film at 1, 2, 4, …, N samples per
//! pixel and measures its error against a converged reference image: the same scene and
//! view rendered with a different seed at many more samples, with independent samples
//! (whose per-pixel variance is then known), cached on disk by a hash of the scene and
//! settings (see `cache`). The reference's own variance is taken out of each error
//! ([`metrics::ErrorMetrics`]). The same run measures the CPU reference renderer on the
//! cosine / independent configuration, the BVH build presets (build time against the
//! trace speed they give), and how the cost per ray scales with triangles, resolution and
//! samples per pass.
//!
//! Under the overcast sky (`--sky overcast`, or a scene's own) the sky's samplings are
//! measured against each other: horizon-clipped sampling and its control variate once per
//! point sampler, weighted sampling with every hemisphere; each run also reports its
//! variance per sample and that variance times the seconds a sample takes.
//!
//! Timings are reported, never asserted: on the GPU a pass's time is the span between its
//! first and last timestamp queries where the adapter has them, else the wall clock
//! around the pass; the CPU reference is timed by the wall clock. Each scene's BVH is
//! built once per preset and prepared on the GPU and the CPU reference (a session each);
//! every configuration, resolution and the reference are requests on those sessions.

mod cache;
mod cli;
pub mod metrics;
mod plot;
mod report;

pub use cli::{BenchArgs, command};

use anyhow::{Result, anyhow};
use aorender::{
    AdapterInfo, BuildQuality, BvhOptions, Control, Device, ErrorEstimator, Film, Hemisphere, ImageRequest, PassSizing,
    Sampler, Scene, Session, SkyModel, SkyNormalise, SkySampling,
};
use metrics::{ErrorMetrics, Reference};
use std::path::PathBuf;
use std::time::Instant;

/// Most samples in one pass: keeps passes short enough for progress and watchdogs.
const PASS_SAMPLES: u32 = 64;

/// One scene of a run and how much to render of it.
#[derive(Clone, Debug)]
pub struct ScenePlan {
    /// Name in the tables and plots.
    pub label: String,
    /// Scene file or mesh; `None` is the built-in aobench scene.
    pub path: Option<PathBuf>,
    /// Already loaded (scenes named on the command line are loaded before the run, so a
    /// bad one fails at once).
    pub loaded: Option<Scene>,
    /// The image's longer side; the scene's aspect ratio gives the other.
    pub size: u32,
    /// Samples per pixel of the progressive renders, N (a power of two).
    pub max_spp: u32,
    /// Samples per pixel of the reference.
    pub reference_spp: u32,
    /// Also time every BVH preset on this scene.
    pub presets: bool,
    /// Also time a series of image sizes on this scene.
    pub resolutions: bool,
}

/// A whole run.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The scenes, in order.
    pub scenes: Vec<ScenePlan>,
    /// Hemisphere distributions to measure.
    pub hemispheres: Vec<Hemisphere>,
    /// Point samplers to measure.
    pub samplers: Vec<Sampler>,
    /// Seed of the measured renders (the reference uses another).
    pub seed: u32,
    /// The sky options.
    pub sky: SkyPlan,
    /// Substring of the adapter's name.
    pub adapter: Option<String>,
    /// Measure the CPU reference renderer too.
    pub cpu: bool,
    /// Directory of cached references.
    pub cache_dir: PathBuf,
    /// Samples per pixel of the preset and resolution measurements.
    pub scaling_spp: u32,
    /// Square image sizes of the resolution series.
    pub resolutions: Vec<u32>,
    /// The command line that made the plan, for the results.
    pub command: String,
    /// True for `--quick`.
    pub quick: bool,
}

/// The sky options of a run, applied to every scene as `render`'s are.
#[derive(Clone, Debug, Default)]
pub struct SkyPlan {
    /// `--sky`.
    pub model: Option<SkyModel>,
    /// `--up`.
    pub up: Option<glam::Vec3>,
    /// `--ground-albedo`.
    pub ground_albedo: Option<f32>,
    /// `--sky-normalise`.
    pub normalise: Option<SkyNormalise>,
    /// The sky samplings to measure under the overcast sky; empty for every one the sky's
    /// normalisation allows.
    pub samplings: Vec<SkySampling>,
}

impl SkyPlan {
    /// Applies the options to `scene`'s sky (refusing an overcast sky's option with the
    /// uniform sky, in `render`'s words) and returns the sky samplings to measure: none
    /// under the uniform sky.
    pub fn apply(&self, scene: &mut Scene) -> Result<Vec<SkySampling>> {
        let args = crate::args::SkyArgs {
            sky: self.model,
            up: self.up,
            ground_albedo: self.ground_albedo,
            sky_sampling: self.samplings.first().copied(),
            sky_normalise: self.normalise,
        };
        args.apply(scene)?;
        if scene.settings.sampling.sky.is_uniform() {
            return Ok(Vec::new());
        }
        let with = |m: SkySampling| aorender::Sky { sampling: m, ..scene.settings.sampling.sky };
        if self.samplings.is_empty() {
            // Every sampling the sky allows (weighted has no surface normalisation).
            return Ok(SkySampling::ALL.into_iter().filter(|&m| with(m).validate().is_ok()).collect());
        }
        for &m in &self.samplings {
            with(m).validate().map_err(|e| anyhow!("invalid option: {e}"))?;
        }
        Ok(self.samplings.clone())
    }
}

/// One measured configuration: hemisphere, point sampler and, under the overcast sky, the
/// sky's sampling.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Config {
    hemisphere: Hemisphere,
    sampler: Sampler,
    sky: Option<SkySampling>,
}

/// The configurations of a scene: every hemisphere × sampler under the uniform sky; under
/// the overcast sky, for each of `samplings`, every sampler (horizon and control-variate,
/// whose directions are cos θ-distributed above the horizon whatever the hemisphere, are
/// listed as cosine) or every hemisphere × sampler (weighted). The first is the baseline.
fn configs(plan: &Plan, samplings: &[SkySampling]) -> Vec<Config> {
    let mut out = Vec::new();
    let mut add = |sky: Option<SkySampling>, hemispheres: &[Hemisphere]| {
        for &hemisphere in hemispheres {
            for &sampler in &plan.samplers {
                out.push(Config { hemisphere, sampler, sky });
            }
        }
    };
    if samplings.is_empty() {
        add(None, &plan.hemispheres);
    }
    for &m in samplings {
        match m {
            SkySampling::Weighted => add(Some(m), &plan.hemispheres),
            _ => add(Some(m), &[Hemisphere::Cosine]),
        }
    }
    out
}

/// The configuration the CPU reference, the reference image and the scaling series use:
/// cosine / independent, with the first sky sampling measured.
fn baseline(samplings: &[SkySampling]) -> Config {
    Config { hemisphere: Hemisphere::Cosine, sampler: Sampler::Independent, sky: samplings.first().copied() }
}

/// The reference's seed for a benchmark seed: any other value would do.
pub fn reference_seed(seed: u32) -> u32 {
    seed ^ 0x5EED_AB1E
}

/// Progress of a run: a stage and work units done out of the expected total (camera
/// rays, i.e. pixels × samples).
#[derive(Clone, Debug)]
pub struct Progress {
    /// What is running.
    pub stage: String,
    /// Units done.
    pub done: u64,
    /// Units expected in all.
    pub total: u64,
}

/// What one checkpoint of a progressive render measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Checkpoint {
    /// Samples per pixel so far.
    pub spp: u32,
    /// Seconds of rendering so far: GPU timestamps where the adapter has them, else the
    /// wall clock (see [`Run::time_source`]).
    pub seconds: f64,
    /// Wall-clock seconds of the passes so far (submission and waiting included; film
    /// read-backs excluded).
    pub wall_seconds: f64,
    /// Camera plus AO rays so far.
    pub rays: u64,
    /// rays / seconds.
    pub rays_per_second: f64,
    /// Mean squared error against the reference, its variance taken out.
    pub mse: f64,
    /// Standard error of `mse` (from the spread over pixels).
    pub mse_std_error: f64,
    /// √max(mse, 0).
    pub rmse: f64,
    /// Relative MSE, ε = [`metrics::REL_MSE_EPSILON`].
    pub rel_mse: f64,
    /// 1 / (mse × seconds); `None` when the error is below the reference's floor.
    pub efficiency: Option<f64>,
    /// Mean of the image.
    pub image_mean: f64,
}

/// One progressive render.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Run {
    /// "gpu" or "cpu".
    pub device: String,
    /// Hemisphere distribution.
    pub hemisphere: String,
    /// Point sampler.
    pub sampler: String,
    /// The overcast sky's sampling (`None` under the uniform sky).
    pub sky_sampling: Option<String>,
    /// Whether this is the scene's baseline configuration (cosine / independent, with the
    /// first sky sampling measured), which the CPU run and the scaling series share.
    pub baseline: bool,
    /// Whether the sampler is unbiased (the grid is not: its error stops falling).
    pub unbiased: bool,
    /// Variance of one sample at N, the mean over pixels: from the film's own spread for
    /// independent samples, else MSE × N against the reference (the variance an
    /// independent sampler of the same error would have).
    pub variance_per_sample: f64,
    /// `variance_per_sample` times the seconds one sample of one pixel took: the variance
    /// of a pixel after one second of rendering spent on it (less is better).
    pub variance_seconds: f64,
    /// "gpu-timestamps" or "wall-clock".
    pub time_source: String,
    /// Seconds to upload the scene and create the pipeline (GPU) or to prepare the
    /// tracer (CPU).
    pub setup_seconds: f64,
    /// Bytes of device memory (GPU; 0 on the CPU).
    pub device_bytes: u64,
    /// Least-squares slope of ln RMSE against ln spp over the checkpoints.
    pub slope: Option<f64>,
    /// The checkpoints, 1, 2, 4, …, N.
    pub checkpoints: Vec<Checkpoint>,
}

impl Run {
    /// The last checkpoint.
    pub fn last(&self) -> &Checkpoint {
        self.checkpoints.last().expect("a run has checkpoints")
    }

    /// How its AO directions are drawn, for tables and plots: the hemisphere, or the
    /// overcast sky's sampling ("weighted" with its hemisphere).
    pub fn distribution(&self) -> String {
        match self.sky_sampling.as_deref() {
            None => self.hemisphere.clone(),
            Some("weighted") => format!("weighted {}", self.hemisphere),
            Some(m) => m.to_string(),
        }
    }
}

/// The reference of a scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReferenceInfo {
    /// Samples per pixel.
    pub samples: u64,
    /// Seed.
    pub seed: u32,
    /// Where it was rendered.
    pub device: String,
    /// Seconds it took when it was rendered.
    pub seconds: f64,
    /// Whether it came from the cache.
    pub cached: bool,
    /// Cache file.
    pub file: String,
    /// The reference's own RMSE, √mean(SE²): errors near it cannot be resolved.
    pub rmse_floor: f64,
    /// Its relative MSE floor.
    pub rel_mse_floor: f64,
}

/// GPU against CPU on the same configuration and samples.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GpuCpu {
    /// GPU rays/s (by the run's time source).
    pub gpu_rays_per_second: f64,
    /// GPU rays/s by the wall clock.
    pub gpu_wall_rays_per_second: f64,
    /// CPU rays/s.
    pub cpu_rays_per_second: f64,
    /// gpu_rays_per_second / cpu_rays_per_second.
    pub ratio: f64,
    /// The same by the GPU's wall clock.
    pub wall_ratio: f64,
    /// Largest difference between the two images, which trace the same samples.
    pub max_abs_difference: f64,
    /// Fraction of pixels whose values agree within 1e-4 (a pixel may differ where a ray
    /// grazes an edge and the two traversals round differently).
    pub matching_pixels: f64,
}

/// The configuration with the highest efficiency at N samples.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Best {
    /// Hemisphere, or the overcast sky's sampling ([`Run::distribution`]).
    pub hemisphere: String,
    /// Sampler.
    pub sampler: String,
    /// 1 / (MSE × seconds).
    pub efficiency: f64,
    /// Its efficiency over cosine / independent's.
    pub over_default: Option<f64>,
}

/// Everything measured on one scene.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SceneResult {
    /// Name.
    pub name: String,
    /// The file, or "built-in".
    pub source: String,
    /// Triangles.
    pub triangles: usize,
    /// Spheres.
    pub spheres: usize,
    /// Planes.
    pub planes: usize,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// N.
    pub max_spp: u32,
    /// The sky, as the statistics describe it (with the baseline's sampling).
    pub sky: String,
    /// Seconds to load the scene.
    pub load_seconds: f64,
    /// Seconds to build the CWBVH (medium preset), shared by the GPU and the CPU.
    pub bvh_build_seconds: f64,
    /// Seconds to convert it to the GPU's buffers.
    pub bvh_convert_seconds: f64,
    /// CWBVH nodes.
    pub bvh_nodes: usize,
    /// The process's peak resident memory after this scene, where the OS reports it.
    pub peak_rss_bytes: Option<u64>,
    /// The reference.
    pub reference: ReferenceInfo,
    /// GPU runs (every configuration), then the CPU run.
    pub runs: Vec<Run>,
    /// GPU against CPU on cosine / independent.
    pub gpu_cpu: Option<GpuCpu>,
    /// The most efficient unbiased GPU configuration at N.
    pub best: Option<Best>,
}

/// A BVH preset's build and trace times.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PresetResult {
    /// Scene.
    pub scene: String,
    /// Triangles.
    pub triangles: usize,
    /// Preset name.
    pub preset: String,
    /// Seconds to build the CWBVH.
    pub build_seconds: f64,
    /// Seconds to convert it for the GPU.
    pub convert_seconds: f64,
    /// Nodes.
    pub nodes: usize,
    /// GPU rays/s, cosine / independent.
    pub gpu_rays_per_second: f64,
    /// CPU rays/s (`None` without the CPU).
    pub cpu_rays_per_second: Option<f64>,
    /// Rays the GPU must trace before this preset's build time is repaid against the
    /// fastest preset's (`None` when it traces no faster or builds no slower).
    pub gpu_break_even_rays: Option<f64>,
}

/// A point of a scaling series.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ScalingPoint {
    /// Scene.
    pub scene: String,
    /// "gpu" or "cpu".
    pub device: String,
    /// What varies: "triangles", "resolution" or "spp".
    pub series: String,
    /// Its value: primitives in the BVH, pixels, or samples per pixel at the checkpoint.
    pub x: f64,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel measured.
    pub spp: u32,
    /// Rays traced.
    pub rays: u64,
    /// Seconds.
    pub seconds: f64,
    /// Seconds per million rays.
    pub seconds_per_mray: f64,
}

/// The machine.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Machine {
    /// CPU model (Linux: /proc/cpuinfo), or "unknown".
    pub cpu: String,
    /// Threads the CPU reference uses.
    pub threads: usize,
    /// Memory in bytes, where the OS reports it.
    pub memory_bytes: Option<u64>,
    /// OS and architecture.
    pub os: String,
}

/// A scene that could not be measured, and why.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Failure {
    /// Scene.
    pub scene: String,
    /// The error, one line.
    pub error: String,
}

/// The results of a run (results.json).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Results {
    /// The command line.
    pub command: String,
    /// `--quick`.
    pub quick: bool,
    /// The machine.
    pub machine: Machine,
    /// The adapter.
    pub adapter: AdapterInfo,
    /// How GPU time is measured: "gpu-timestamps" or "wall-clock".
    pub gpu_time_source: String,
    /// ε of the relative MSE.
    pub rel_mse_epsilon: f64,
    /// Seed of the measured renders.
    pub seed: u32,
    /// Seconds the whole run took.
    pub total_seconds: f64,
    /// Per scene.
    pub scenes: Vec<SceneResult>,
    /// BVH presets.
    pub bvh_presets: Vec<PresetResult>,
    /// Scaling series.
    pub scaling: Vec<ScalingPoint>,
    /// Scenes that failed.
    pub failures: Vec<Failure>,
}

/// The samples per pixel at which a run of N is measured: 1, 2, 4, …, N.
pub fn checkpoints(max_spp: u32) -> Vec<u32> {
    std::iter::successors(Some(1u32), |&k| (k < max_spp).then_some(k * 2)).collect()
}

/// Calls the progress callback as work is done.
struct Tracker<'a> {
    done: u64,
    total: u64,
    stage: String,
    callback: &'a mut dyn FnMut(&Progress),
}

impl Tracker<'_> {
    fn stage(&mut self, stage: String) {
        self.stage = stage;
        self.report();
    }

    fn advance(&mut self, units: u64) {
        self.done += units;
        self.total = self.total.max(self.done);
        self.report();
    }

    /// Takes back work that will not be done (a cached reference).
    fn skip(&mut self, units: u64) {
        self.total = self.total.saturating_sub(units).max(self.done);
        self.report();
    }

    fn report(&mut self) {
        let p = Progress { stage: self.stage.clone(), done: self.done, total: self.total };
        (self.callback)(&p);
    }
}

/// A render's passes: timings and the image at each checkpoint.
struct RawRun {
    setup_seconds: f64,
    device_bytes: u64,
    timestamps: bool,
    checkpoints: Vec<RawCheckpoint>,
    /// The film at the last checkpoint.
    film: Film,
}

struct RawCheckpoint {
    spp: u32,
    gpu_seconds: f64,
    wall_seconds: f64,
    rays: u64,
    image: Vec<f64>,
}

impl RawCheckpoint {
    /// Seconds by the run's time source.
    fn seconds(&self, timestamps: bool) -> f64 {
        if timestamps { self.gpu_seconds } else { self.wall_seconds }
    }
}

/// A progressive render of `request` on `session`, after one untimed warm-up sample:
/// passes of at most [`PASS_SAMPLES`] up to each of `targets` samples per pixel, timing
/// the passes only, keeping the image at each target.
fn measure(session: &Session, request: &ImageRequest, targets: &[u32], tracker: &mut Tracker) -> Result<RawRun> {
    let mut render = session.render(request)?;
    render.run_to(1, &mut Control::default())?;
    render.restart()?;
    let setup_seconds = session.setup().upload_seconds + render.setup_seconds();
    let pixels = request.settings.width as u64 * request.settings.height as u64;
    let mut checkpoints = Vec::with_capacity(targets.len());
    let mut film = None;
    let mut reported = 0;
    for &target in targets {
        let mut on_progress = |p: &aorender::Progress| {
            tracker.advance((p.samples_done - reported) as u64 * pixels);
            reported = p.samples_done;
        };
        let mut control =
            Control { progress: Some(&mut on_progress), sizing: PassSizing::Fixed(PASS_SAMPLES), ..Control::default() };
        render.run_to(target, &mut control)?;
        let f = render.film()?;
        let times = render.times();
        checkpoints.push(RawCheckpoint {
            spp: render.samples(),
            gpu_seconds: times.gpu_seconds.unwrap_or(0.0),
            wall_seconds: times.wall_seconds,
            rays: render.samples() as u64 * pixels + times.ao_rays,
            image: f.mean(),
        });
        film = Some(f);
    }
    let film = film.ok_or_else(|| anyhow!("a run without checkpoints"))?;
    let timestamps = render.times().gpu_seconds.is_some();
    Ok(RawRun {
        setup_seconds,
        device_bytes: session.setup().device_bytes + render.device_bytes(),
        timestamps,
        checkpoints,
        film,
    })
}

/// The variance of one sample, the mean over pixels, of independent samples from `film`'s
/// spread; `None` for other samplers.
fn film_variance(film: &Film) -> Option<f64> {
    if film.error_estimator() != ErrorEstimator::Samples {
        return None;
    }
    let se = film.std_error();
    let sum: f64 = se.iter().enumerate().map(|(i, e)| e * e * film.samples_of(i) as f64).sum();
    Some(sum / se.len().max(1) as f64)
}

/// `run` measured against `reference`.
fn measured(raw: &RawRun, device: &str, request: &ImageRequest, baseline: bool, reference: &Reference) -> Run {
    let checkpoints: Vec<Checkpoint> = raw
        .checkpoints
        .iter()
        .map(|c| {
            let m = ErrorMetrics::measure(&c.image, reference);
            let seconds = c.seconds(raw.timestamps);
            Checkpoint {
                spp: c.spp,
                seconds,
                wall_seconds: c.wall_seconds,
                rays: c.rays,
                rays_per_second: c.rays as f64 / seconds.max(1e-12),
                mse: m.mse,
                mse_std_error: m.mse_std_error,
                rmse: m.rmse,
                rel_mse: m.rel_mse,
                efficiency: metrics::efficiency(m.mse, seconds),
                image_mean: c.image.iter().sum::<f64>() / c.image.len().max(1) as f64,
            }
        })
        .collect();
    let points: Vec<(f64, f64)> = checkpoints.iter().map(|c| (c.spp as f64, c.rmse)).collect();
    let s = &request.settings;
    let last = checkpoints.last().expect("a run has checkpoints");
    let variance_per_sample = film_variance(&raw.film).unwrap_or(last.mse * last.spp as f64);
    let pixel_samples = last.spp as f64 * s.width as f64 * s.height as f64;
    Run {
        device: device.into(),
        hemisphere: s.sampling.hemisphere.name().into(),
        sampler: s.sampling.sampler.name().into(),
        sky_sampling: (!s.sampling.sky.is_uniform()).then(|| s.sampling.sky.sampling.name().into()),
        baseline,
        unbiased: s.sampling.sampler.is_unbiased(),
        variance_per_sample,
        variance_seconds: variance_per_sample * last.seconds / pixel_samples.max(1.0),
        time_source: if raw.timestamps { "gpu-timestamps" } else { "wall-clock" }.into(),
        setup_seconds: raw.setup_seconds,
        device_bytes: raw.device_bytes,
        slope: metrics::log_log_slope(&points),
        checkpoints,
    }
}

/// The session's own view with a configuration's settings.
fn configured(session: &Session, config: Config, spp: u32, seed: u32) -> ImageRequest {
    let mut r = session.default_request();
    let s = &mut r.settings;
    (s.sampling.hemisphere, s.sampling.sampler, s.spp, s.sampling.seed) =
        (config.hemisphere, config.sampler, spp, seed);
    if let Some(m) = config.sky {
        s.sampling.sky.sampling = m;
    }
    r
}

/// The machine's CPU model, threads, memory and OS.
pub fn machine() -> Machine {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let cpu = cpuinfo
        .lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let memory_bytes = meminfo
        .lines()
        .find(|l| l.starts_with("MemTotal:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<u64>().ok())
        .map(|kb| kb * 1024);
    Machine {
        cpu,
        threads: rayon::current_num_threads(),
        memory_bytes,
        os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
    }
}

/// Expected work of a scene, in camera rays, for the progress bar.
fn planned_units(plan: &Plan, sp: &ScenePlan) -> u64 {
    let px = sp.size as u64 * sp.size as u64;
    let samplings = match plan.sky.model {
        Some(SkyModel::Overcast) if plan.sky.samplings.is_empty() => SkySampling::ALL.to_vec(),
        Some(SkyModel::Overcast) => plan.sky.samplings.clone(),
        _ => Vec::new(),
    };
    let configs = configs(plan, &samplings).len() as u64;
    let devices = if plan.cpu { 2 } else { 1 };
    let mut units = configs * sp.max_spp as u64 * px + sp.reference_spp as u64 * px;
    if plan.cpu {
        units += sp.max_spp as u64 * px;
    }
    if sp.presets {
        units += BuildQuality::ALL.len() as u64 * devices * plan.scaling_spp as u64 * px;
    }
    if sp.resolutions {
        units += devices * plan.scaling_spp as u64 * plan.resolutions.iter().map(|&r| r as u64 * r as u64).sum::<u64>();
    }
    units
}

/// Runs the plan. Scenes that fail are listed in [`Results::failures`]; the others are
/// measured. Errors only when the adapter cannot be opened.
pub fn run(plan: &Plan, progress: &mut dyn FnMut(&Progress)) -> Result<Results> {
    let start = Instant::now();
    let gpu = Device::gpu(plan.adapter.as_deref())?;
    let timestamps = gpu.has_timestamps();
    let total = plan.scenes.iter().map(|sp| planned_units(plan, sp)).sum();
    let mut tracker = Tracker { done: 0, total, stage: String::new(), callback: progress };
    let mut results = Results {
        command: plan.command.clone(),
        quick: plan.quick,
        machine: machine(),
        adapter: gpu.info(),
        gpu_time_source: if timestamps { "gpu-timestamps" } else { "wall-clock" }.into(),
        rel_mse_epsilon: metrics::REL_MSE_EPSILON,
        seed: plan.seed,
        total_seconds: 0.0,
        scenes: Vec::new(),
        bvh_presets: Vec::new(),
        scaling: Vec::new(),
        failures: Vec::new(),
    };
    for (i, sp) in plan.scenes.iter().enumerate() {
        let prefix = format!("[{}/{}] {}", i + 1, plan.scenes.len(), sp.label);
        let before = tracker.done;
        match bench_scene(&gpu, plan, sp, &prefix, &mut tracker, &mut results) {
            Ok(r) => results.scenes.push(r),
            Err(e) => {
                let planned = planned_units(plan, sp);
                tracker.skip(planned.saturating_sub(tracker.done - before));
                results.failures.push(Failure { scene: sp.label.clone(), error: e.to_string() });
            }
        }
    }
    results.scaling.extend(triangle_scaling(&results.scenes));
    results.total_seconds = start.elapsed().as_secs_f64();
    Ok(results)
}

/// Seconds per million rays against primitives, from each scene's cosine / independent runs.
fn triangle_scaling(scenes: &[SceneResult]) -> Vec<ScalingPoint> {
    let mut out = Vec::new();
    for s in scenes {
        for r in s.runs.iter().filter(|r| r.baseline) {
            let c = r.last();
            out.push(ScalingPoint {
                scene: s.name.clone(),
                device: r.device.clone(),
                series: "triangles".into(),
                x: (s.triangles + s.spheres).max(1) as f64,
                width: s.width,
                height: s.height,
                spp: c.spp,
                rays: c.rays,
                seconds: c.seconds,
                seconds_per_mray: c.seconds / (c.rays as f64 / 1e6),
            });
        }
    }
    out
}

/// Seconds per million rays of the samples between consecutive checkpoints, at the
/// checkpoint's spp (the samples from spp/2 to spp, in passes of up to [`PASS_SAMPLES`]).
fn spp_scaling(scene: &str, width: u32, height: u32, run: &Run) -> Vec<ScalingPoint> {
    let mut out = Vec::new();
    let mut prev: Option<&Checkpoint> = None;
    for c in &run.checkpoints {
        let (spp0, s0, r0) = prev.map_or((0, 0.0, 0), |p| (p.spp, p.seconds, p.rays));
        let (rays, seconds) = (c.rays - r0, c.seconds - s0);
        out.push(ScalingPoint {
            scene: scene.into(),
            device: run.device.clone(),
            series: "spp".into(),
            x: c.spp as f64,
            width,
            height,
            spp: c.spp - spp0,
            rays,
            seconds,
            seconds_per_mray: seconds / (rays as f64 / 1e6).max(1e-12),
        });
        prev = Some(c);
    }
    out
}

/// A `width × height` image's size with its longer side `long`.
pub fn fit(long: u32, width: u32, height: u32) -> (u32, u32) {
    let (w, h) = (width.max(1) as f64, height.max(1) as f64);
    if w >= h {
        (long, ((long as f64 * h / w).round() as u32).max(1))
    } else {
        (((long as f64 * w / h).round() as u32).max(1), long)
    }
}

fn load_scene(sp: &ScenePlan) -> Result<Scene> {
    Ok(match (&sp.loaded, &sp.path) {
        (Some(s), _) => s.clone(),
        (None, Some(p)) => Scene::load(p)?,
        (None, None) => Scene::default_scene(),
    })
}

/// A scene's measurement under way: the plans it follows and its label in progress lines.
struct SceneBench<'a> {
    plan: &'a Plan,
    sp: &'a ScenePlan,
    prefix: &'a str,
}

/// A GPU configuration's request, its measurement, and whether it is the baseline.
type GpuRun = (ImageRequest, RawRun, bool);

/// The reference image of a scene and where it came from.
struct ReferenceRun {
    stored: cache::Stored,
    /// Whether it was read from the cache.
    cached: bool,
    file: PathBuf,
    seed: u32,
}

/// Measures one scene; BVH presets and scaling series go into `results`.
fn bench_scene(
    gpu: &Device,
    plan: &Plan,
    sp: &ScenePlan,
    prefix: &str,
    tracker: &mut Tracker,
    results: &mut Results,
) -> Result<SceneResult> {
    let bench = SceneBench { plan, sp, prefix };
    tracker.stage(format!("{prefix}: loading"));
    let t = Instant::now();
    let mut scene = load_scene(sp)?;
    let load_seconds = t.elapsed().as_secs_f64();
    let samplings = plan.sky.apply(&mut scene)?;
    let base = baseline(&samplings);
    let (width, height) = fit(sp.size, scene.settings.width, scene.settings.height);
    scene.settings.width = width;
    scene.settings.height = height;
    scene.settings.validate()?;
    let name = sp.label.clone();
    let targets = checkpoints(sp.max_spp);

    tracker.stage(format!("{prefix}: building the BVH ({} triangles)", scene.world_triangle_count()));
    // The GPU's session, and the CPU reference's over the same BVH build.
    let devices: Vec<Device> = std::iter::once(gpu.clone()).chain(plan.cpu.then(Device::cpu)).collect();
    let mut sessions = Session::on_devices(&devices, scene, &BvhOptions::default())?.into_iter();
    let session = sessions.next().expect("the GPU's session");
    let cpu_session = sessions.next();
    let setup = session.setup().clone();

    let raw_runs = bench.gpu_runs(&session, &samplings, base, &targets, tracker)?;
    let default_config = configured(&session, base, sp.max_spp, plan.seed);
    let mut scaling = Vec::new();
    if sp.resolutions {
        scaling.extend(bench.resolution_series(&session, "gpu", base, tracker)?);
    }

    let mut cpu_raw = None;
    if let Some(cpu) = &cpu_session {
        tracker.stage(format!("{prefix}: CPU cosine/independent to {} spp", sp.max_spp));
        cpu_raw = Some(measure(cpu, &default_config, &targets, tracker)?);
        if sp.resolutions {
            scaling.extend(bench.resolution_series(cpu, "cpu", base, tracker)?);
        }
    }

    let cpu = cpu_session.as_ref().zip(cpu_raw.as_ref());
    let ReferenceRun { stored, cached, file, seed: ref_seed } =
        bench.reference(&session, cpu, base, &raw_runs, tracker)?;
    let reference = &stored.reference;

    let mut runs: Vec<Run> = raw_runs.iter().map(|(r, raw, b)| measured(raw, "gpu", r, *b, reference)).collect();
    let gpu_default = runs.iter().position(|r| r.baseline);
    let mut gpu_cpu = None;
    if let Some(raw) = &cpu_raw {
        let cpu = measured(raw, "cpu", &default_config, true, reference);
        if let Some(g) = gpu_default {
            gpu_cpu = Some(compare_gpu_cpu(&runs[g], &raw_runs[g].1, &cpu, raw));
        }
        runs.push(cpu);
    }
    for r in runs.iter().filter(|r| r.baseline) {
        scaling.extend(spp_scaling(&name, width, height, r));
    }
    let best = best_run(&runs, gpu_default);

    let scene = session.scene();
    let sky = default_config.settings.sampling.sky.describe();
    let (triangles, spheres, planes) = (scene.world_triangle_count(), scene.spheres.len(), scene.planes.len());
    if sp.presets {
        let mut preset_scene = scene.clone();
        preset_scene.settings = default_config.settings.clone();
        drop(session);
        drop(cpu_session);
        results.bvh_presets.extend(bvh_presets(gpu, plan, &name, preset_scene, prefix, tracker)?);
    }
    results.scaling.extend(scaling);
    Ok(SceneResult {
        name,
        source: sp.path.as_ref().map_or_else(|| "built-in".into(), |p| p.display().to_string()),
        triangles,
        spheres,
        planes,
        width,
        height,
        max_spp: sp.max_spp,
        sky,
        load_seconds,
        bvh_build_seconds: setup.bvh_build_seconds - setup.bvh_convert_seconds,
        bvh_convert_seconds: setup.bvh_convert_seconds,
        bvh_nodes: setup.bvh_nodes,
        peak_rss_bytes: aorender::peak_rss_bytes(),
        reference: ReferenceInfo {
            samples: reference.samples,
            seed: ref_seed,
            device: stored.device.clone(),
            seconds: stored.seconds,
            cached,
            file: file.display().to_string(),
            rmse_floor: reference.mse_floor().sqrt(),
            rel_mse_floor: reference.rel_mse_floor(),
        },
        runs,
        gpu_cpu,
        best,
    })
}

impl SceneBench<'_> {
    /// Measures every configuration on the GPU to the scene's most samples.
    fn gpu_runs(
        &self,
        session: &Session,
        samplings: &[SkySampling],
        base: Config,
        targets: &[u32],
        tracker: &mut Tracker,
    ) -> Result<Vec<GpuRun>> {
        let (plan, sp, prefix) = (self.plan, self.sp, self.prefix);
        let mut raw_runs = Vec::new();
        for config in configs(plan, samplings) {
            let (h, s) = (config.hemisphere.name(), config.sampler.name());
            let sky = config.sky.map_or(String::new(), |m| format!(", {} sky sampling", m.name()));
            tracker.stage(format!("{prefix}: GPU {h}/{s}{sky} to {} spp", sp.max_spp));
            let request = configured(session, config, sp.max_spp, plan.seed);
            let raw = measure(session, &request, targets, tracker)?;
            raw_runs.push((request, raw, config == base));
        }
        Ok(raw_runs)
    }

    /// Measures the baseline at every square resolution of the plan on `session`, whose
    /// device is named `device` ("gpu", "cpu").
    fn resolution_series(
        &self,
        session: &Session,
        device: &str,
        base: Config,
        tracker: &mut Tracker,
    ) -> Result<Vec<ScalingPoint>> {
        let plan = self.plan;
        let mut scaling = Vec::new();
        for &r in &plan.resolutions {
            tracker.stage(format!("{}: {} at {r}x{r}", self.prefix, device.to_uppercase()));
            let mut request = configured(session, base, plan.scaling_spp, plan.seed);
            request.settings.width = r;
            request.settings.height = r;
            let raw = measure(session, &request, &[plan.scaling_spp], tracker)?;
            scaling.push(resolution_point(&self.sp.label, device, &request, &raw));
        }
        Ok(scaling)
    }

    /// The reference image: cached, or rendered on whichever device traced faster (the
    /// CPU's session and its measurement, with one).
    fn reference(
        &self,
        session: &Session,
        cpu: Option<(&Session, &RawRun)>,
        base: Config,
        raw_runs: &[GpuRun],
        tracker: &mut Tracker,
    ) -> Result<ReferenceRun> {
        let (plan, sp, prefix) = (self.plan, self.sp, self.prefix);
        let ref_seed = reference_seed(plan.seed);
        let ref_request = configured(session, base, sp.reference_spp, ref_seed);
        let (width, height) = (ref_request.settings.width, ref_request.settings.height);
        let px = width as u64 * height as u64;
        let sampling = cache::ReferenceSampling { samples: sp.reference_spp, seed: ref_seed };
        let mut ref_scene = session.scene().clone();
        ref_scene.settings = ref_request.settings.clone();
        let key = cache::key(&ref_scene, sampling);
        let file = cache::path(&plan.cache_dir, &ref_scene, &key);
        drop(ref_scene);
        let (stored, cached) = match cache::load(&file, width, height, sp.reference_spp) {
            Ok(Some(stored)) => {
                tracker.skip(sp.reference_spp as u64 * px);
                (stored, true)
            }
            found => {
                if let Err(why) = found {
                    tracker.stage(format!("{prefix}: {}: {why}; rendering it again", file.display()));
                }
                let gpu_default = raw_runs.iter().find(|(_, _, baseline)| *baseline).map(|(_, r, _)| r);
                let speed = |r: &RawRun| {
                    let c = r.checkpoints.last().expect("checkpoints");
                    c.rays as f64 / c.wall_seconds.max(1e-12)
                };
                let on_cpu = match (cpu, gpu_default) {
                    (Some((_, c)), Some(g)) => speed(c) > speed(g),
                    (Some(_), None) => true,
                    _ => false,
                };
                tracker.stage(format!(
                    "{prefix}: reference, {} spp on the {}",
                    sp.reference_spp,
                    if on_cpu { "CPU" } else { "GPU" }
                ));
                let t = Instant::now();
                let (film, device) = match (cpu, on_cpu) {
                    (Some((cpu, _)), true) => {
                        (measure(cpu, &ref_request, &[sp.reference_spp], tracker)?.film, "cpu".into())
                    }
                    _ => (
                        measure(session, &ref_request, &[sp.reference_spp], tracker)?.film,
                        format!("gpu: {}", session.setup().adapter.name),
                    ),
                };
                let reference = Reference {
                    width,
                    height,
                    samples: film.samples,
                    mean: film.mean(),
                    variance: film.std_error().iter().map(|e| e * e).collect(),
                };
                let stored = cache::Stored { reference, seconds: t.elapsed().as_secs_f64(), device };
                cache::save(&file, &stored)?;
                (stored, false)
            }
        };
        Ok(ReferenceRun { stored, cached, file, seed: ref_seed })
    }
}

/// The GPU's baseline against the CPU reference's: speeds and how closely the images agree.
fn compare_gpu_cpu(gpu: &Run, gpu_raw: &RawRun, cpu: &Run, cpu_raw: &RawRun) -> GpuCpu {
    let (g_last, cr) = (gpu.last(), cpu.last());
    let (gi, ci) = (&gpu_raw.film.mean(), &cpu_raw.film.mean());
    let differences: Vec<f64> = gi.iter().zip(ci).map(|(a, b)| (a - b).abs()).collect();
    let max_abs_difference = differences.iter().copied().fold(0.0, f64::max);
    let matching_pixels = differences.iter().filter(|&&d| d <= 1e-4).count() as f64 / differences.len().max(1) as f64;
    let wall_rps = g_last.rays as f64 / g_last.wall_seconds.max(1e-12);
    GpuCpu {
        gpu_rays_per_second: g_last.rays_per_second,
        gpu_wall_rays_per_second: wall_rps,
        cpu_rays_per_second: cr.rays_per_second,
        ratio: g_last.rays_per_second / cr.rays_per_second,
        wall_ratio: wall_rps / cr.rays_per_second,
        max_abs_difference,
        matching_pixels,
    }
}

/// The unbiased GPU run of the best efficiency, and its gain over the baseline's.
fn best_run(runs: &[Run], gpu_default: Option<usize>) -> Option<Best> {
    let default_eff = gpu_default.and_then(|g| runs[g].last().efficiency);
    runs.iter()
        .filter(|r| r.device == "gpu" && r.unbiased)
        .filter_map(|r| r.last().efficiency.map(|e| (r, e)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(r, e)| Best {
            hemisphere: r.distribution(),
            sampler: r.sampler.clone(),
            efficiency: e,
            over_default: default_eff.map(|d| e / d),
        })
}

fn resolution_point(scene: &str, device: &str, request: &ImageRequest, raw: &RawRun) -> ScalingPoint {
    let c = raw.checkpoints.last().expect("checkpoints");
    let seconds = c.seconds(raw.timestamps);
    let s = &request.settings;
    ScalingPoint {
        scene: scene.into(),
        device: device.into(),
        series: "resolution".into(),
        x: s.width as f64 * s.height as f64,
        width: s.width,
        height: s.height,
        spp: c.spp,
        rays: c.rays,
        seconds,
        seconds_per_mray: seconds / (c.rays as f64 / 1e6).max(1e-12),
    }
}

/// Builds the CWBVH with every preset and traces cosine / independent with each, on the
/// GPU and (with the CPU in the plan) on the CPU reference: a session per preset and device.
fn bvh_presets(
    gpu: &Device,
    plan: &Plan,
    name: &str,
    mut scene: Scene,
    prefix: &str,
    tracker: &mut Tracker,
) -> Result<Vec<PresetResult>> {
    scene.settings.spp = plan.scaling_spp;
    let triangles = scene.world_triangle_count();
    let mut out: Vec<PresetResult> = Vec::new();
    for q in BuildQuality::ALL {
        tracker.stage(format!("{prefix}: BVH preset {}", q.name()));
        let options = BvhOptions { quality: q, ..BvhOptions::default() };
        let devices: Vec<Device> = std::iter::once(gpu.clone()).chain(plan.cpu.then(Device::cpu)).collect();
        let mut sessions = Session::on_devices(&devices, scene.clone(), &options)?.into_iter();
        let session = sessions.next().expect("the GPU's session");
        let setup = session.setup();
        let (build_seconds, convert_seconds) =
            (setup.bvh_build_seconds - setup.bvh_convert_seconds, setup.bvh_convert_seconds);
        let nodes = setup.bvh_nodes;
        let request = session.default_request();
        let raw = measure(&session, &request, &[plan.scaling_spp], tracker)?;
        drop(session);
        let c = raw.checkpoints.last().expect("checkpoints");
        let gpu_rays_per_second = c.rays as f64 / c.seconds(raw.timestamps).max(1e-12);
        let cpu_rays_per_second = match sessions.next() {
            Some(cpu) => {
                let raw = measure(&cpu, &request, &[plan.scaling_spp], tracker)?;
                let c = raw.checkpoints.last().expect("checkpoints");
                Some(c.rays as f64 / c.wall_seconds.max(1e-12))
            }
            None => None,
        };
        let gpu_break_even_rays = out.first().and_then(|fastest| {
            let extra = build_seconds - fastest.build_seconds;
            let saved = 1.0 / fastest.gpu_rays_per_second - 1.0 / gpu_rays_per_second;
            (extra > 0.0 && saved > 0.0).then(|| extra / saved)
        });
        out.push(PresetResult {
            scene: name.into(),
            triangles,
            preset: q.name().into(),
            build_seconds,
            convert_seconds,
            nodes,
            gpu_rays_per_second,
            cpu_rays_per_second,
            gpu_break_even_rays,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_keeps_the_aspect_ratio() {
        assert_eq!(fit(64, 512, 384), (64, 48));
        assert_eq!(fit(64, 384, 512), (48, 64));
        assert_eq!(fit(128, 512, 512), (128, 128));
        assert_eq!(fit(2, 16384, 1), (2, 1));
    }

    #[test]
    fn checkpoints_double_up_to_n() {
        assert_eq!(checkpoints(1), vec![1]);
        assert_eq!(checkpoints(16), vec![1, 2, 4, 8, 16]);
        assert_eq!(checkpoints(64).len(), 7);
    }
}
