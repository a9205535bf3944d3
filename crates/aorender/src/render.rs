//! The pass loop: one request's samples rendered in passes of a few samples per pixel
//! (or probe rounds), sized to a target time, until the sample range is done, a time
//! limit is reached or a stop is asked for; each finished block of samples goes into the
//! exact sums of the [`Accumulation`], which is handed to a save callback every few
//! seconds. Every render, comparison cell, benchmark run and probe request runs here.

use crate::accumulation::{Accumulation, ErrorTarget, FilmLayout, MIN_TARGET_REPLICATES};
use crate::device::{Passes, Setup};
use crate::error::Result;
use crate::film::{ErrorEstimator, Film};
use crate::gpu::stats::Stop;
use crate::kinds::BvhLayout;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::sky::Sky;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Seconds a pass aims for: long enough to amortise the round trip, short enough for
/// progress, time limits and GPU watchdogs.
const PASS_TARGET_SECONDS: f64 = 0.25;

/// Progress after each pass.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Samples per pixel done (with those of a checkpoint continued).
    pub samples_done: u32,
    /// Samples per pixel asked for: the length of the sample range.
    pub samples_total: u32,
    /// Camera and AO rays so far.
    pub rays: u64,
    /// Seconds of rendering so far.
    pub elapsed: f64,
}

/// Receives an accumulation to save.
pub type SaveFn<'a> = &'a mut dyn FnMut(&Accumulation) -> Result<()>;

/// How many samples a pass takes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PassSizing {
    /// As many as fit a quarter of a second (and what is left of a time limit),
    /// starting from one and growing at most eightfold a pass (the first passes' times
    /// include warm-up): a fast adapter reaches full-size passes within three round trips.
    Timed,
    /// This many, or what is left before the next stop: fixed, comparable passes (the
    /// benchmark's).
    Fixed(u32),
}

/// What may end a run of passes early, and what it reports along the way.
pub struct Control<'a> {
    /// Set from another thread (a signal handler) to stop after the current pass.
    pub stop: Option<&'a AtomicBool>,
    /// Stop after the pass that crosses this many seconds of the run.
    pub time_limit: Option<f64>,
    /// Called after every pass.
    pub progress: Option<&'a mut dyn FnMut(&Progress)>,
    /// Receives the accumulation every `save_interval` seconds and when the run ends
    /// (finished, out of time or stopped), not after an error: the last saved one stays.
    pub save: Option<SaveFn<'a>>,
    /// Seconds between two saves, at least; stretched so that saving takes at most a tenth
    /// of the render's time. Zero or less saves after every pass, however long saving
    /// takes.
    pub save_interval: f64,
    /// How passes are sized.
    pub sizing: PassSizing,
    /// Stop once the error estimate meets this target (checked at the ends of replicates,
    /// or of stretches of `TARGET_CHECK_SAMPLES` independent samples, where `check_due` says).
    pub target: Option<ErrorTarget>,
    /// With an image's target: after each complete replicate, stop sampling the pixels
    /// whose own error is already within the target (`Accumulation::adapt`), so that
    /// the samples go where the error is. Needs the samples in replicates.
    pub adaptive: bool,
}

impl Default for Control<'_> {
    fn default() -> Self {
        Control {
            stop: None,
            time_limit: None,
            progress: None,
            save: None,
            save_interval: 5.0,
            sizing: PassSizing::Timed,
            target: None,
            adaptive: false,
        }
    }
}

/// How a run of passes ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunEnd {
    /// Every sample asked for is in the accumulation.
    Done,
    /// The time limit was reached first.
    TimeLimit,
    /// A stop was asked for first.
    Stopped,
    /// The error target was met first.
    TargetMet,
}

impl RunEnd {
    /// In words, for statistics.
    pub fn name(self) -> &'static str {
        EndedBy::from(self).name()
    }
}

/// What ended a render, as its statistics report it ([`RenderStats::ended_by`]);
/// serialised as [`EndedBy::name`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum EndedBy {
    /// Every sample asked for.
    #[serde(rename = "samples")]
    Samples,
    /// The error target was met.
    #[serde(rename = "target")]
    Target,
    /// The time limit was reached.
    #[serde(rename = "time limit")]
    TimeLimit,
    /// A stop was asked for.
    #[serde(rename = "interrupted")]
    Interrupted,
    /// The render was finished before its passes were run to their end.
    #[serde(rename = "not run to its end")]
    Unfinished,
}

impl EndedBy {
    /// Every variant.
    pub const ALL: [EndedBy; 5] =
        [EndedBy::Samples, EndedBy::Target, EndedBy::TimeLimit, EndedBy::Interrupted, EndedBy::Unfinished];

    /// In words, as the statistics' JSON has it.
    pub fn name(self) -> &'static str {
        match self {
            EndedBy::Samples => "samples",
            EndedBy::Target => "target",
            EndedBy::TimeLimit => "time limit",
            EndedBy::Interrupted => "interrupted",
            EndedBy::Unfinished => "not run to its end",
        }
    }
}

impl From<RunEnd> for EndedBy {
    fn from(end: RunEnd) -> EndedBy {
        match end {
            RunEnd::Done => EndedBy::Samples,
            RunEnd::TimeLimit => EndedBy::TimeLimit,
            RunEnd::Stopped => EndedBy::Interrupted,
            RunEnd::TargetMet => EndedBy::Target,
        }
    }
}

impl std::fmt::Display for EndedBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Compares with the words of the statistics' JSON.
impl PartialEq<&str> for EndedBy {
    fn eq(&self, other: &&str) -> bool {
        self.name() == *other
    }
}

/// The statistics' words for the kind of an error target.
pub fn target_name(target: ErrorTarget) -> &'static str {
    match target {
        ErrorTarget::Rmse(_) => "rmse",
        ErrorTarget::RelativeRmse(_) => "relative_rmse",
        ErrorTarget::PointStdError(_) => "point_std_error",
    }
}

/// How the typed fields of [`RenderStats`] are written: as the words the statistics have
/// always used.
mod words {
    use crate::accumulation::ErrorTarget;
    use crate::film::ErrorEstimator;
    use crate::render::target_name;
    use crate::sky::Sky;
    use serde::Serializer;

    /// An error target as its kind's name and its value.
    pub fn target<S: Serializer>(target: &Option<ErrorTarget>, s: S) -> Result<S::Ok, S::Error> {
        match target {
            Some(t) => s.serialize_some(&(target_name(*t), t.value())),
            None => s.serialize_none(),
        }
    }

    /// An estimator in words ([`ErrorEstimator::describe`]).
    pub fn estimator<S: Serializer>(e: &ErrorEstimator, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&e.describe())
    }

    /// A sky in words ([`Sky::describe`]).
    pub fn sky<S: Serializer>(sky: &Sky, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&sky.describe())
    }
}

/// Figures of a finished render (serialised by `aorender render --stats`).
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
    /// Seconds to upload the geometry and create the pipeline (GPU), or to lay out the
    /// tracer's records (CPU).
    pub setup_seconds: f64,
    /// Of `setup_seconds`: seconds to upload the geometry to the device (GPU), or to lay
    /// out the tracer's records (CPU); with the exact sums written to a device that keeps
    /// them.
    pub upload_seconds: f64,
    /// Of `setup_seconds`: seconds to make the request's film and pipeline (compiling the
    /// kernel the first time the adapter sees its specialisation; on the CPU, the film),
    /// and the statistics kernels compiled while the device opened where the session
    /// opened it (`Session::beside`).
    pub pipeline_seconds: f64,
    /// Of `render_seconds`, this run's seconds in passes alone: submitting them and
    /// waiting for the rays (a checkpoint's aside).
    pub pass_seconds: f64,
    /// Seconds this run spent reading the film back from the device (on the CPU, taking
    /// the block's sums from the tracer's film).
    pub readback_seconds: f64,
    /// Bytes this run read back from the device: films and pass counters (0 on the CPU).
    pub readback_bytes: u64,
    /// Seconds this run spent on the host folding blocks into the exact sums, checking an
    /// error target, deciding adaptive masks, and making the film and its error estimates.
    pub host_stats_seconds: f64,
    /// Seconds this run spent saving checkpoints (their read-back included).
    pub checkpoint_seconds: f64,
    /// Times this run checked its error target (each stretch of replicates, and each
    /// replicate's adaptive masks); 0 without a target.
    pub checks: u32,
    /// Times the host waited for the device during the request (submissions waited on and
    /// buffer mappings: the pipeline's warm-up, each pass's counters, the read-backs); 0
    /// on the CPU.
    pub round_trips: u64,
    /// Seconds to open the device (the adapter and its logical device): the session's
    /// setup's where the session opened it beside its BVH build (`Session::beside`, as
    /// `aorender render` does), else set by the caller that opened it, or 0.
    pub adapter_seconds: f64,
    /// Of the phases' seconds, those that ran beside the main thread rather than on its
    /// timeline (the device opening while the scene loaded and its BVH was built): the
    /// phases less these add up to the whole process. 0 where nothing overlapped.
    pub overlap_seconds: f64,
    /// Seconds to write the outputs (image, error image): set by the caller that wrote
    /// them (`aorender render` does), 0 otherwise.
    pub write_seconds: f64,
    /// Seconds of the whole process from its start to the statistics: set by a program
    /// (`aorender render` does), `None` otherwise.
    pub process_seconds: Option<f64>,
    /// Seconds from the process's start to loading the scene (starting the program,
    /// reading the command line, checking outputs): set by a program, 0 otherwise.
    pub start_seconds: f64,
    /// Seconds of the session's setup beside the BVH build and the upload: moving the
    /// scene to its local frame and back, freeing the build's host copies.
    pub scene_seconds: f64,
    /// Seconds of the request beside its film and pipeline: checks, the scene's hash that
    /// names its checkpoints, its accumulation.
    pub request_seconds: f64,
    /// Of `pipeline_seconds`: seconds compiling pipelines (0 when the adapter had them),
    /// the statistics kernels compiled while the device opened included.
    pub compile_seconds: f64,
    /// `hit` when the driver's pipeline cache was read from disk and taken; `miss`
    /// (none yet), `rejected` (damaged or another driver's), `off`, or `unsupported`
    /// (the backend keeps none); empty on the CPU.
    pub pipeline_cache: String,
    /// Seconds freeing the request's device buffers, and the session's (the device, the
    /// scene) where a program sets it.
    pub teardown_seconds: f64,
    /// Seconds of the process in no phase above: `process_seconds` less the phases on the
    /// main thread's timeline, their sum less `overlap_seconds` (set with it).
    pub other_seconds: f64,
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
    /// Levels of the BVH as traversed (its deepest inner node's, the root 1; with
    /// instances, the top level's and the deepest mesh's added).
    pub bvh_depth: u32,
    /// Triangles and spheres the BVH leaves out as copies of others (the same vertices,
    /// or centre and radius, and albedo, to the bit, 16 times or more): every ray meets
    /// them as it meets the first, so the image is the same.
    pub duplicates_dropped: usize,
    /// Adapter name ("cpu" for the reference).
    pub adapter: String,
    /// wgpu backend, or "cpu".
    pub backend: String,
    /// Adapter device type, or "cpu".
    pub device_type: String,
    /// Driver.
    pub driver: String,
    /// Hemisphere distribution.
    pub hemisphere: Hemisphere,
    /// The sky and its sampling (written as [`Sky::describe`]).
    #[serde(serialize_with = "words::sky")]
    pub sky: Sky,
    /// 2-D point sampler of the hemisphere and pixel numbers.
    pub sampler: Sampler,
    /// Random seed.
    pub seed: u32,
    /// BVH layout traversed.
    pub bvh_layout: BvhLayout,
    /// Bytes of device memory allocated (GPU only).
    pub device_bytes: u64,
    /// Storage bindings the BVH nodes and primitives were split into (GPU only; 2 when
    /// each fits one binding).
    pub geometry_bindings: u32,
    /// What holds them on the device: `buffers` or `textures` (empty on the CPU).
    pub geometry_storage: String,
    /// How the kernel's lanes share the rays: `per-lane` or `cooperative` (empty on the
    /// CPU).
    pub traversal: String,
    /// Bytes of the scene's geometry on the host: its triangles, spheres and planes.
    pub scene_bytes: u64,
    /// Bytes of the BVH as traversed: its nodes and primitive records, as uploaded to the
    /// device (GPU) or held by the tracer (CPU).
    pub bvh_bytes: u64,
    /// Peak resident memory of the process so far, in bytes (Linux; 0 elsewhere).
    pub host_peak_bytes: u64,
    /// `host_peak_bytes` per triangle of the scene (`None` without triangles or a peak).
    pub host_peak_bytes_per_triangle: Option<f64>,
    /// `host_peak_bytes` per probe point, for a probe render (`None` for an image).
    pub host_peak_bytes_per_point: Option<f64>,
    /// The most bytes the program's own heap held at once so far: the loaded scene, the
    /// BVH build's workspace, the bytes prepared for upload; not the driver's. Filled in
    /// by a program that counts its allocations (`aorender` does); `None` otherwise.
    pub heap_peak_bytes: Option<u64>,
    /// Seconds to read and parse the scene and its meshes: set by the caller that loaded
    /// it (`aorender render` does), 0 for a scene made in memory.
    pub load_seconds: f64,
    /// Passes run (including those of a checkpoint the render continued).
    pub passes: u32,
    /// Mean of the image.
    pub image_mean: f64,
    /// Samples per pixel on average: `samples_per_pixel` unless an adaptive render stopped
    /// sampling some pixels earlier.
    pub mean_samples_per_pixel: f64,
    /// Whether an adaptive render gave its pixels different sample counts.
    pub adaptive: bool,
    /// What ended the render: `samples` (all asked for), `target`, `time limit` or
    /// `interrupted`.
    pub ended_by: EndedBy,
    /// The error target the render stopped at, if it had one (written as `rmse`,
    /// `relative_rmse` or `point_std_error`, and its value).
    #[serde(serialize_with = "words::target")]
    pub target: Option<ErrorTarget>,
    /// Samples per independently randomised replicate (1: independent samples; 0: one
    /// replicate of all samples, with no valid error estimate).
    pub replicate_samples: u32,
    /// Complete replicates held.
    pub replicates: u64,
    /// How the error is estimated (written in words).
    #[serde(serialize_with = "words::estimator")]
    pub error_estimator: ErrorEstimator,
    /// Degrees of freedom of the variance estimates (0: no estimate).
    pub error_degrees_of_freedom: u64,
    /// Estimated root-mean-square error of the image against its converged value: the
    /// root of the mean per-pixel variance of the mean; `null` without a valid estimate.
    pub rmse_estimate: Option<f64>,
    /// `rmse_estimate` over `image_mean`.
    pub relative_rmse_estimate: Option<f64>,
    /// The bound the error target is checked against: `rmse_estimate` raised to a
    /// one-sided 99 % bound on the realised RMSE ([`Film::rmse_bound`]).
    pub rmse_bound: Option<f64>,
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

/// What a render reports besides its samples: the scene's and the session's figures.
#[derive(Clone, Debug)]
pub(crate) struct RenderInfo {
    pub scene: String,
    pub triangles: usize,
    pub instances: usize,
    pub spheres: usize,
    pub planes: usize,
    pub scene_bytes: u64,
    pub setup: Setup,
    /// Seconds to make this request's film and pipeline.
    pub target_seconds: f64,
    /// Of those, seconds compiling pipelines.
    pub compile_seconds: f64,
    /// Seconds of the request beside its film and pipeline.
    pub request_seconds: f64,
    /// The device's round trips before the request made its film ([`Passes::round_trips`]).
    pub round_trips_before: u64,
}

/// Seconds and rays of the passes run so far.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PassTimes {
    /// Passes run by this render (a checkpoint's aside).
    pub passes: u32,
    /// Wall-clock seconds of the passes alone: submission and waiting, not reading the
    /// film back or saving.
    pub wall_seconds: f64,
    /// The passes' time on the adapter by timestamp queries; `None` when a pass had none
    /// (the CPU reference, or an adapter without timestamp queries).
    pub gpu_seconds: Option<f64>,
    /// AO rays the passes traced.
    pub ao_rays: u64,
    /// Seconds spent reading the film's block back from the device (on the CPU, taking
    /// the block's sums from the tracer's film).
    pub readback_seconds: f64,
    /// Bytes mapped from the device's readback buffers: films and pass counters (0 on
    /// the CPU).
    pub readback_bytes: u64,
    /// Seconds spent on the host folding blocks into the exact sums, deciding adaptive
    /// masks and checking an error target.
    pub host_stats_seconds: f64,
    /// Seconds spent saving checkpoints (their block's read-back included).
    pub checkpoint_seconds: f64,
    /// Seconds spent writing the exact sums to a device that keeps them, before its passes.
    pub upload_seconds: f64,
    /// Times an error target was checked (after a stretch of replicates, and an adaptive
    /// render's masks, each decided once a replicate).
    pub checks: u32,
    /// Times the host waited for the device since the request began making its film (its
    /// pipeline's warm-up, the passes, the read-backs; other requests on the same device
    /// at the same time included): 0 on the CPU.
    pub round_trips: u64,
}

/// What a render's samples and replicates cost on its device, and what its samples vary
/// by ([`Render::replicate_costs`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplicateCosts {
    /// Seconds a sample per pixel takes in a pass.
    pub per_sample: f64,
    /// Seconds of the work done once a replicate: a pass's fixed cost, the fold of the
    /// block into the exact sums and a check of the target.
    pub per_replicate: f64,
    /// The variance of one sample, averaged over the pixels, from the measurement's
    /// samples (their spread in each pixel; 0 where every pixel's samples were equal).
    pub sample_variance: f64,
    /// The image's mean over the measurement's samples (for a relative target).
    pub image_mean: f64,
}

/// The gain in samples of one scrambled Sobol or stratified sequence over independent
/// samples for the same error, as a range the rule takes log-uniform: measured 4.6 on
/// the bunny at 256² (1,216 independent samples against 480 Sobol in replicates of 16,
/// less their variance factor) and 4.7 on the dragon at 1080p (1,920 against 736).
const SEQUENCE_GAIN: (f64, f64) = (3.0, 7.0);
/// The same for independent samples: how far the need measured from a few samples per
/// pixel may be off.
const INDEPENDENT_GAIN: (f64, f64) = (1.0 / 1.5, 1.5);
/// What an adaptive render's allocation in proportion to σ and its background pixels'
/// single replicate save over uniform sampling: 3.6 on the bunny at 256² and 512², 6.2 on
/// the dragon at 1080p.
const ALLOCATION_GAIN: (f64, f64) = (2.0, 6.0);
/// Needs a replicate size's expected cost is averaged over.
const NEED_POINTS: u32 = 64;

/// The variance of the mean of replicates of `b` points relative to one sequence of as
/// many samples: 1 + 12.8 / b for Sobol and stratified points, through the bunny's 1.8 in
/// replicates of 16 and 1.2 in replicates of 64 (docs/sampling.md); 1 for independent
/// samples, which are their own replicates.
pub fn replicate_variance_factor(sampler: Sampler, b: u32) -> f64 {
    match sampler {
        Sampler::Sobol | Sampler::Stratified => 1.0 + 12.8 / b.max(1) as f64,
        Sampler::Independent | Sampler::Grid => 1.0,
    }
}

/// Replicates of `b` samples a render takes to reach `need` samples per pixel: the first
/// count from the `MIN_TARGET_REPLICATES`th whose samples reach it and, for a uniform
/// render, at which a check is due ([`check_due`]); an adaptive render decides after
/// every replicate.
pub fn replicates_to_reach(b: u32, need: f64, adaptive: bool) -> u64 {
    let reach = (need / b.max(1) as f64).ceil();
    let mut k = MIN_TARGET_REPLICATES.max(if reach.is_finite() && reach > 0.0 { reach.min(1e12) as u64 } else { 0 });
    while !adaptive && !check_due(k) {
        // The next multiple of the checks' spacing here (`check_due`'s step).
        let step = 1u64 << (63 - (k / 16).max(1).leading_zeros());
        k = k.next_multiple_of(step);
    }
    k
}

/// The expected seconds of a target render in replicates of `b`, from `costs`, for a
/// target `e` (an RMSE): each replicate costs its samples and the work once a replicate,
/// and the render stops at the replicate of [`replicates_to_reach`] the samples it needs.
/// That need is the independent samples the measured variance asks for (σ² / e²), times
/// the replicates' variance factor ([`replicate_variance_factor`]), over a gain the
/// measurement cannot see (the sequence's over independent samples, and an adaptive
/// allocation's over uniform sampling), taken log-uniform over its range.
pub fn expected_target_seconds(sampler: Sampler, b: u32, costs: &ReplicateCosts, e: f64, adaptive: bool) -> f64 {
    let mut gain = match sampler {
        Sampler::Sobol | Sampler::Stratified => SEQUENCE_GAIN,
        Sampler::Independent | Sampler::Grid => INDEPENDENT_GAIN,
    };
    if adaptive {
        gain = (gain.0 * ALLOCATION_GAIN.0, gain.1 * ALLOCATION_GAIN.1);
    }
    let need = costs.sample_variance.max(0.0) / (e * e) * replicate_variance_factor(sampler, b);
    let per_replicate = b as f64 * costs.per_sample + costs.per_replicate;
    let total: f64 = (0..NEED_POINTS)
        .map(|j| {
            let g = gain.1 * (gain.0 / gain.1).powf((j as f64 + 0.5) / NEED_POINTS as f64);
            replicates_to_reach(b, need / g, adaptive) as f64 * per_replicate
        })
        .sum();
    total / NEED_POINTS as f64
}

/// The replicate size of a render with an error target whose replicates were not asked
/// for, from measured costs: of the sizes `sampler` allows from `least` up to `most`, the
/// one whose expected seconds (`expected_target_seconds`) are the fewest, the smaller
/// on a tie. A larger replicate costs fewer checks and, for Sobol and stratified points,
/// less variance a sample, but stops on a coarser grid, from 8 of its replicates on; on
/// a device where a check costs little against a sample, the smaller wins. `least` where
/// a cost is not a finite number, or for a target that is not an image's.
pub fn replicate_by_expected_cost(
    sampler: Sampler,
    least: u32,
    most: u32,
    costs: &ReplicateCosts,
    target: ErrorTarget,
    adaptive: bool,
) -> u32 {
    let step = match sampler {
        Sampler::Grid => return 0,
        Sampler::Stratified => 4,
        Sampler::Independent | Sampler::Sobol => 2,
    };
    let e = match target {
        ErrorTarget::Rmse(e) => e,
        ErrorTarget::RelativeRmse(r) => r * costs.image_mean.abs(),
        ErrorTarget::PointStdError(_) => return least,
    };
    let finite = [costs.per_sample, costs.per_replicate, costs.sample_variance, e].iter().all(|x| x.is_finite());
    if !finite || e <= 0.0 || costs.per_sample <= 0.0 {
        return least;
    }
    let least = least.max(1);
    let (mut best, mut best_seconds) = (least, expected_target_seconds(sampler, least, costs, e, adaptive));
    let mut b = least;
    while b * step <= most.min(crate::sampler::MAX_REPLICATE_SAMPLES) {
        b *= step;
        let seconds = expected_target_seconds(sampler, b, costs, e, adaptive);
        if seconds < best_seconds {
            (best, best_seconds) = (b, seconds);
        }
    }
    best
}

/// A request in progress: its film on the device and its accumulation. Made by
/// `Session::render`; run with [`Render::run`] (or [`Render::run_to`], stopping at given
/// sample counts), then [`Render::finish`].
pub struct Render {
    passes: Box<dyn Passes>,
    acc: Accumulation,
    info: RenderInfo,
    /// Samples per pixel taken from a checkpoint.
    resumed: u32,
    /// Samples the next timed pass takes.
    count: u32,
    times: PassTimes,
    interrupted: bool,
    /// How the last run of passes ended, and the target it had.
    ended: Option<(RunEnd, Option<ErrorTarget>)>,
    /// Finds the accumulation's background pixels when an adaptive run first needs them:
    /// a render that is not adaptive never pays for the test.
    background: Option<BackgroundPixels>,
    /// Whether the device holds the exact sums (`Passes::fold`): the accumulation's are
    /// then those of the last [`Render::sync`].
    on_device: bool,
    /// Whether the device also takes an adaptive render's decisions, so that the
    /// per-pixel counts and stopped pixels are its own.
    adapting_on_device: bool,
    /// Whether this render has stopped the background pixels (after their first replicate).
    background_stopped: bool,
    /// The sample count at the device's last adaptive decision, and whether the sums it
    /// took found the target met: a check of the target at the same count reads the
    /// same sums (stopping a pixel changes none of them) and says the same.
    decided: Option<(u32, bool)>,
}

/// The bookkeeping of one run of passes ([`Render::run_to`]).
struct RunState {
    /// The sample index the run stops at.
    until: u32,
    /// Samples per pixel of the request's range, for progress.
    total: u32,
    /// Film slots, for progress.
    pixels: u64,
    start: Instant,
    /// The accumulation's render seconds before this run.
    seconds_before: f64,
    /// Passes this run has made.
    passes: u32,
    last_save: Instant,
    /// Seconds the last save took.
    save_seconds: f64,
}

impl RunState {
    /// A run of `samples` samples per pixel from where `acc` stands (at most to the end of
    /// its range).
    fn new(acc: &Accumulation, samples: u32) -> RunState {
        RunState {
            until: (acc.first() + samples.min(acc.end() - acc.first())).max(acc.next()),
            total: acc.end() - acc.first(),
            pixels: acc.settings().width as u64 * acc.settings().height as u64,
            start: Instant::now(),
            seconds_before: acc.render_seconds(),
            passes: 0,
            last_save: Instant::now(),
            save_seconds: 0.0,
        }
    }
}

/// What finds a render's background pixels ([`crate::footprint::background_pixels`]).
pub(crate) type BackgroundPixels = Box<dyn FnOnce() -> Vec<bool> + Send>;

impl Render {
    pub(crate) fn new(passes: Box<dyn Passes>, acc: Accumulation, info: RenderInfo) -> Render {
        Render {
            passes,
            acc,
            info,
            resumed: 0,
            count: 1,
            times: PassTimes { gpu_seconds: Some(0.0), ..Default::default() },
            interrupted: false,
            ended: None,
            background: None,
            on_device: false,
            adapting_on_device: false,
            background_stopped: false,
            decided: None,
        }
    }

    /// The render with `background` to find its background pixels, which an adaptive run
    /// stops after their first replicate.
    pub(crate) fn with_background(mut self, background: BackgroundPixels) -> Render {
        self.background = Some(background);
        self
    }

    /// Continues `saved`, an accumulation of the same scene, settings, device, BVH and
    /// first sample (a checkpoint's): the samples it holds are kept, its block in
    /// progress goes back onto the device, and the render goes on from its next sample to
    /// the end of this request's range. On the same adapter the result has the same bits
    /// as a render that never stopped.
    pub fn resume(&mut self, mut saved: Accumulation) -> Result<()> {
        saved.check_resume(&self.acc)?;
        saved.extend_to(self.acc.end());
        // An adaptive render's pixels that no longer take samples stay so (marked before
        // the block in progress is loaded, which keeps the marks).
        let inactive = saved.inactive();
        if inactive.iter().any(|&off| off) {
            self.passes.set_inactive(&inactive)?;
        }
        if let Some(block) = saved.take_partial() {
            self.passes.load(&block).map_err(|e| saved.error(e.message()))?;
        }
        saved.adopt_run(&self.acc);
        self.resumed = saved.samples();
        self.acc = saved;
        self.on_device = false;
        self.background_stopped = false;
        self.decided = None;
        Ok(())
    }

    /// Empties the film and the accumulation, keeping the film and pipeline made for the
    /// request: the render starts again from its first sample (after a warm-up pass that
    /// is not to be measured, say).
    pub fn restart(&mut self) -> Result<()> {
        if !self.acc.exact().stopped.is_empty() || self.adapting_on_device {
            // Every pixel is sampled again: the film loses its stopped pixels' marks.
            self.passes.set_inactive(&[])?;
            self.passes.take()?;
        } else if self.acc.partial_samples() > 0 {
            self.passes.take()?;
        }
        self.passes.take_readback_bytes();
        self.on_device = false;
        self.background_stopped = false;
        self.decided = None;
        self.acc.restart();
        self.resumed = 0;
        self.count = 1;
        self.times = PassTimes { gpu_seconds: Some(0.0), ..Default::default() };
        self.interrupted = false;
        self.ended = None;
        Ok(())
    }

    /// Measures what a sample and a replicate cost on this render's device, then empties
    /// the film as [`Render::restart`] does: a pass of one sample after a warm-up one and
    /// a pass of eight give the seconds a sample takes and a pass's fixed cost; a fold of
    /// a block into the exact sums and a check (the faster of two, after one that makes
    /// the sums) add the work done once a replicate; the ten samples' spread in each
    /// pixel, reduced on the device, gives the variance of a sample. `None` for a request of
    /// fewer than 16 samples, one that has samples already, or one whose device does not
    /// keep the sums (the CPU reference, whose statistics are host work beside its
    /// passes: its replicates are what the caller asks).
    pub fn replicate_costs(&mut self) -> Result<Option<ReplicateCosts>> {
        const PASS: u32 = 8;
        let acc = &self.acc;
        if acc.end() - acc.first() < 16 || acc.next() != acc.first() || !self.passes.keeps_sums() {
            return Ok(None);
        }
        let first = acc.first();
        self.passes.pass(first, 1)?;
        let t = Instant::now();
        self.passes.pass(first + 1, 1)?;
        let one = t.elapsed().as_secs_f64();
        let t = Instant::now();
        self.passes.pass(first + 2, PASS)?;
        let several = t.elapsed().as_secs_f64();
        let per_sample = ((several - one) / (PASS - 1) as f64).max(several / (2 * PASS) as f64);
        // The first fold makes the device's sums and compiles their kernels: not timed.
        self.passes.write_sums(acc.exact(), 0)?;
        self.passes.fold(true, PASS + 2)?;
        let exponents = (acc.exact().sum_exponent, acc.exact().sq_exponent);
        let mut statistics = f64::INFINITY;
        for _ in 0..2 {
            let t = Instant::now();
            self.passes.fold(true, 0)?;
            self.passes.check(acc.check_query(), exponents)?;
            statistics = statistics.min(t.elapsed().as_secs_f64());
        }
        // The ten samples' sums, as independent ones: each pixel's spread of a sample.
        let query = crate::gpu::stats::CheckQuery { samples: (PASS + 2) as u64, replicates: None };
        let (spread, _) = self.passes.check(query, exponents)?;
        let pixels = spread.pixels.max(1) as f64;
        self.passes.take()?;
        self.restart()?;
        Ok(Some(ReplicateCosts {
            per_sample,
            per_replicate: (one - per_sample).max(0.0) + statistics,
            sample_variance: spread.variance * (PASS + 2) as f64 / pixels,
            image_mean: spread.mean / pixels,
        }))
    }

    /// Samples per pixel done.
    pub fn samples(&self) -> u32 {
        self.acc.samples()
    }

    /// The passes' seconds and rays so far.
    pub fn times(&self) -> PassTimes {
        PassTimes { round_trips: self.round_trips(), ..self.times }
    }

    /// The device's round trips since the request began making its film.
    fn round_trips(&self) -> u64 {
        self.passes.round_trips().saturating_sub(self.info.round_trips_before)
    }

    /// Seconds it took to make this request's film and pipeline (compiling the pipeline
    /// the first time the adapter saw its specialisation).
    pub fn setup_seconds(&self) -> f64 {
        self.info.target_seconds
    }

    /// Bytes of device memory the request's film and buffers take (GPU; 0 on the CPU).
    pub fn device_bytes(&self) -> u64 {
        self.passes.device_bytes()
    }

    /// Runs passes to the end of the request's range (or until `control` ends it).
    pub fn run(&mut self, control: &mut Control) -> Result<RunEnd> {
        self.run_to(self.acc.end() - self.acc.first(), control)
    }

    /// Runs passes until `samples` samples per pixel are done (at most the range's
    /// length), the time limit is reached or a stop is asked for.
    pub fn run_to(&mut self, samples: u32, control: &mut Control) -> Result<RunEnd> {
        let end = self.run_passes(samples, control)?;
        self.ended = Some((end, control.target));
        Ok(end)
    }

    fn run_passes(&mut self, samples: u32, control: &mut Control) -> Result<RunEnd> {
        self.check_control(control)?;
        let device_sums = self.place_sums(control.adaptive)?;
        let mut run = RunState::new(&self.acc, samples);
        let end = loop {
            if self.acc.next() >= run.until {
                break RunEnd::Done;
            }
            if let Some(end) = self.interruption(control, &run) {
                break end;
            }
            let (block_end, check) = self.stretch_end(control);
            let count = self.pass_count(control, block_end, run.until);
            let seconds = self.run_pass(count)?;
            run.passes += 1;
            let all_met = match (self.acc.next() == block_end, device_sums) {
                (true, true) => self.end_block_on_device(control)?,
                (true, false) => self.end_block_on_host(control)?,
                (false, _) => false,
            };
            if all_met {
                break RunEnd::TargetMet;
            }
            self.size_next_pass(control, &run, seconds, count);
            self.acc.set_render_seconds(run.seconds_before + run.start.elapsed().as_secs_f64());
            self.report_progress(control, &run);
            self.save_if_due(control, device_sums, &mut run)?;
            let acc = &self.acc;
            let due =
                check.filter(|&c| acc.next().is_multiple_of(c) && check_due(((acc.next() - acc.first()) / c) as u64));
            if let (Some(target), Some(_)) = (control.target, due) {
                let met = match device_sums {
                    true => self.check_target_on_device(control.adaptive, target)?,
                    false => self.check_target_on_host(control.adaptive, target)?,
                };
                if met {
                    break RunEnd::TargetMet;
                }
            }
        };
        self.acc.set_render_seconds(run.seconds_before + run.start.elapsed().as_secs_f64());
        // Without a pass the last checkpoint is already this accumulation.
        if run.passes > 0
            && let Some(save) = control.save.as_mut()
        {
            let t = Instant::now();
            self.save_with(&mut **save, device_sums)?;
            self.times.checkpoint_seconds += t.elapsed().as_secs_f64();
        }
        self.times.readback_bytes += self.passes.take_readback_bytes();
        Ok(end)
    }

    /// Checks a run's target and adaptive sampling against the accumulation, and finds
    /// the background pixels the first time an adaptive run needs them.
    fn check_control(&mut self, control: &Control) -> Result<()> {
        if let Some(target) = control.target {
            self.acc.check_target(target)?;
        }
        if control.adaptive {
            self.acc.check_adaptive(control.target)?;
            if let Some(find) = self.background.take() {
                self.acc.set_background(find());
            }
        }
        Ok(())
    }

    /// Puts the exact sums where this run adds to them, and says whether that is the
    /// device.
    fn place_sums(&mut self, adaptive: bool) -> Result<bool> {
        // The device keeps the exact sums of an image, and the counts and decisions of an
        // adaptive run; a run that is not adaptive continuing an adaptive one's pixels
        // (which count their own samples) adds on the host.
        let device_sums = self.passes.keeps_sums()
            && self.acc.settings().layout == FilmLayout::Image
            && (adaptive || self.acc.exact().pixel_samples.is_empty());
        if device_sums && !self.on_device {
            let t = Instant::now();
            self.passes.write_sums(self.acc.exact(), self.acc.finished())?;
            self.times.upload_seconds += t.elapsed().as_secs_f64();
            self.on_device = true;
        } else if !device_sums {
            self.sync()?;
            self.on_device = false;
        }
        self.adapting_on_device |= device_sums && adaptive;
        Ok(device_sums)
    }

    /// How the run ends before its next pass, if it does: a stop asked for, or the time
    /// limit reached after at least one pass.
    fn interruption(&mut self, control: &Control, run: &RunState) -> Option<RunEnd> {
        if control.stop.is_some_and(|s| s.load(Ordering::SeqCst)) {
            self.interrupted = true;
            return Some(RunEnd::Stopped);
        }
        if let Some(limit) = control.time_limit
            && run.start.elapsed().as_secs_f64() >= limit
            && run.passes > 0
        {
            return Some(RunEnd::TimeLimit);
        }
        None
    }

    /// Where the next pass must stop at the latest, and the samples between two checks of
    /// the target (with one).
    fn stretch_end(&self, control: &Control) -> (u32, Option<u32>) {
        let acc = &self.acc;
        // A pass stays within one block, and within one replicate when their sums are
        // taken.
        let unit = acc.take_rounds();
        let block_end = ((acc.next() / unit) as u64 + 1) * unit as u64;
        let block_end = block_end.min(acc.end() as u64) as u32;
        // And within one stretch between two checks of the target.
        let check = control.target.map(|_| acc.target_check_rounds());
        let block_end = match check {
            Some(c) => block_end.min((((acc.next() / c) as u64 + 1) * c as u64).min(u32::MAX as u64) as u32),
            None => block_end,
        };
        (block_end, check)
    }

    /// The samples per pixel of the next pass.
    fn pass_count(&self, control: &Control, block_end: u32, until: u32) -> u32 {
        let count = match control.sizing {
            PassSizing::Timed => self.count,
            PassSizing::Fixed(n) => n.clamp(1, self.passes.max_pass_samples()),
        };
        count.min(block_end - self.acc.next()).min(until - self.acc.next())
    }

    /// Runs one pass of `count` samples per pixel and records it; returns its seconds.
    fn run_pass(&mut self, count: u32) -> Result<f64> {
        let pass_start = Instant::now();
        let report = self.passes.pass(self.acc.next(), count)?;
        let seconds = pass_start.elapsed().as_secs_f64().max(1e-6);
        self.times.passes += 1;
        self.times.wall_seconds += seconds;
        self.times.gpu_seconds = self.times.gpu_seconds.zip(report.gpu_seconds).map(|(a, b)| a + b);
        self.times.ao_rays += report.ao_rays;
        self.acc.record_pass(count, report.ao_rays);
        Ok(seconds)
    }

    /// Folds a finished block into the device's exact sums and, in an adaptive run, takes
    /// the device's decisions; true when every pixel has stopped.
    fn end_block_on_device(&mut self, control: &Control) -> Result<bool> {
        let acc = &mut self.acc;
        let t = Instant::now();
        let whole = acc.whole_replicate(acc.next() - acc.partial_samples()..acc.next());
        self.passes.fold(whole, acc.partial_samples())?;
        acc.end_block(whole as u64);
        self.times.host_stats_seconds += t.elapsed().as_secs_f64();
        if let (true, Some(target)) = (control.adaptive, control.target) {
            self.times.checks += 1;
            let (all, met) =
                adapt_on_device(self.passes.as_mut(), acc, target, &mut self.background_stopped, &mut self.times)?;
            self.decided = met.map(|met| (acc.next(), met));
            if all {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Reads a finished block back into the host's exact sums and, in an adaptive run,
    /// stops the pixels within the target; true when every pixel has stopped.
    fn end_block_on_host(&mut self, control: &Control) -> Result<bool> {
        let acc = &mut self.acc;
        let t = Instant::now();
        let block = self.passes.take()?;
        self.times.readback_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        acc.add_taken(&block, acc.next() - acc.partial_samples()..acc.next())?;
        acc.end_block(0);
        if let (true, Some(target)) = (control.adaptive, control.target) {
            self.times.checks += 1;
            if let Some(mask) = acc.adapt(target)? {
                self.passes.set_inactive(&mask)?;
                if mask.iter().all(|&off| off) {
                    self.times.host_stats_seconds += t.elapsed().as_secs_f64();
                    return Ok(true);
                }
            }
        }
        self.times.host_stats_seconds += t.elapsed().as_secs_f64();
        Ok(false)
    }

    /// Sizes the next timed pass from the last one's seconds per sample.
    fn size_next_pass(&mut self, control: &Control, run: &RunState, seconds: f64, count: u32) {
        let mut target = PASS_TARGET_SECONDS;
        if let Some(limit) = control.time_limit {
            target = target.min((limit - run.start.elapsed().as_secs_f64()).max(0.0));
        }
        let per_sample = seconds / count as f64;
        self.count = ((target / per_sample) as u32).clamp(1, (8 * self.count).min(self.passes.max_pass_samples()));
    }

    /// Tells the progress callback where the run stands.
    fn report_progress(&self, control: &mut Control, run: &RunState) {
        let acc = &self.acc;
        if let Some(progress) = control.progress.as_mut() {
            progress(&Progress {
                samples_done: acc.samples(),
                samples_total: run.total,
                rays: acc.samples() as u64 * run.pixels + acc.ao_rays(),
                elapsed: acc.render_seconds(),
            });
        }
    }

    /// Saves the accumulation when the save interval has passed (and the range is not
    /// done: the run's end saves it then).
    fn save_if_due(&mut self, control: &mut Control, device_sums: bool, run: &mut RunState) -> Result<()> {
        if let Some(save) = control.save.as_mut()
            && self.acc.next() < self.acc.end()
            && (control.save_interval <= 0.0
                || run.last_save.elapsed().as_secs_f64() >= control.save_interval.max(10.0 * run.save_seconds))
        {
            let t = Instant::now();
            self.save_with(&mut **save, device_sums)?;
            run.save_seconds = t.elapsed().as_secs_f64();
            self.times.checkpoint_seconds += run.save_seconds;
            run.last_save = Instant::now();
        }
        Ok(())
    }

    /// Hands `save` the accumulation with the device's sums and its block in progress.
    fn save_with(&mut self, save: &mut dyn FnMut(&Accumulation) -> Result<()>, device_sums: bool) -> Result<()> {
        let acc = &mut self.acc;
        if device_sums {
            sync_sums(self.passes.as_mut(), acc, self.adapting_on_device)?;
        }
        acc.set_partial(if acc.partial_samples() > 0 { Some(self.passes.read()?) } else { None });
        save(acc)?;
        acc.set_partial(None);
        Ok(())
    }

    /// Checks the target on the device's exact sums (once enough replicates are done);
    /// true when it is met.
    fn check_target_on_device(&mut self, adaptive: bool, target: ErrorTarget) -> Result<bool> {
        let acc = &mut self.acc;
        if acc.target_replicates() < MIN_TARGET_REPLICATES {
            return Ok(false);
        }
        if let (true, Some((at, met))) = (adaptive, self.decided)
            && at == acc.next()
        {
            return Ok(met);
        }
        let t = Instant::now();
        // A stretch of independent samples is folded whole: no replicate's
        // square is cut.
        if acc.partial_samples() > 0 {
            self.passes.fold(false, acc.partial_samples())?;
            acc.end_block(0);
        }
        let exponents = (acc.exact().sum_exponent, acc.exact().sq_exponent);
        let (met, bad) = match adaptive {
            true => {
                let (sums, bad) = self.passes.adapt_check(acc.adapt_query(), exponents)?;
                (acc.adaptive_target_met(target, &sums), bad)
            }
            false => {
                let (sums, bad) = self.passes.check(acc.check_query(), exponents)?;
                (acc.target_met_by(target, &sums), bad)
            }
        };
        self.times.readback_seconds += t.elapsed().as_secs_f64();
        if let Some(slot) = bad {
            return Err(out_of_range(acc, slot));
        }
        let t = Instant::now();
        self.times.host_stats_seconds += t.elapsed().as_secs_f64();
        self.times.checks += 1;
        Ok(met)
    }

    /// Checks the target on the host's sums with the block in progress read back; true
    /// when it is met.
    fn check_target_on_host(&mut self, adaptive: bool, target: ErrorTarget) -> Result<bool> {
        let acc = &mut self.acc;
        let t = Instant::now();
        acc.set_partial(if acc.partial_samples() > 0 { Some(self.passes.read()?) } else { None });
        self.times.readback_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        // An adaptive render's check is its decisions' rule, on the host's sums.
        let met = match adaptive && acc.partial().is_none() {
            true => Ok(acc.adaptive_target_met(target, &acc.adapt_sums())),
            false => acc.target_met(target),
        };
        acc.set_partial(None);
        self.times.host_stats_seconds += t.elapsed().as_secs_f64();
        self.times.checks += 1;
        met
    }

    /// Runs passes to the end of the range (or until `control` ends them) and finishes:
    /// [`Render::run`], then [`Render::finish`].
    pub fn complete(mut self, control: &mut Control) -> Result<RenderOutput> {
        self.run(control)?;
        self.finish()
    }

    /// The accumulation as it stands, its block in progress read back from the device.
    pub fn accumulation(&mut self) -> Result<Accumulation> {
        let t = Instant::now();
        self.sync()?;
        let mut acc = self.acc.clone();
        acc.set_partial(if acc.partial_samples() > 0 { Some(self.passes.read()?) } else { None });
        self.times.readback_seconds += t.elapsed().as_secs_f64();
        self.times.readback_bytes += self.passes.take_readback_bytes();
        Ok(acc)
    }

    /// The per-pixel sums so far: the exact sums, plus the block in progress shifted into
    /// the same quanta.
    pub fn film(&mut self) -> Result<Film> {
        self.accumulation()?.film()
    }

    /// The film, the figures and the accumulation of the render.
    pub fn finish(mut self) -> Result<RenderOutput> {
        // The accumulation moves out rather than being copied, and the device's request
        // goes before the film is made: the exact sums are the largest thing a request
        // holds (a bake's millions of points).
        let t = Instant::now();
        self.sync()?;
        let partial = if self.acc.partial_samples() > 0 { Some(self.passes.read()?) } else { None };
        let mut times = self.times;
        times.readback_seconds += t.elapsed().as_secs_f64();
        times.readback_bytes += self.passes.take_readback_bytes();
        let device_bytes = self.passes.device_bytes();
        times.round_trips = self.round_trips();
        let teardown = Instant::now();
        drop(self.passes);
        let teardown_seconds = teardown.elapsed().as_secs_f64();
        let host_stats = Instant::now();
        let mut accumulation = self.acc;
        accumulation.set_partial(partial);
        let film = accumulation.film()?;
        let acc = &accumulation;
        let s = acc.settings();
        let info = &self.info;
        let setup = &info.setup;
        let done = acc.samples();
        // Every pixel's samples: fewer than `done` where an adaptive render stopped.
        let pixel_samples: u64 = (0..film.sum.len()).map(|i| film.samples_of(i)).sum();
        let camera_rays = pixel_samples;
        let rays = camera_rays + acc.ao_rays();
        let (rmse_estimate, rmse_bound, image_mean) = (film.rmse_estimate(), film.rmse_bound(), film.image_mean());
        let error_estimator = film.error_estimator();
        times.host_stats_seconds += host_stats.elapsed().as_secs_f64();
        let host_peak_bytes = peak_rss_bytes().unwrap_or(0);
        let stats = RenderStats {
            scene: info.scene.clone(),
            samples_per_pixel: done,
            samples_requested: acc.end() - acc.first(),
            first_sample: acc.first(),
            samples_resumed: self.resumed,
            interrupted: self.interrupted,
            width: s.width,
            height: s.height,
            rays_traced: rays,
            camera_rays,
            ao_rays: acc.ao_rays(),
            render_seconds: acc.render_seconds(),
            bvh_build_seconds: setup.bvh_build_seconds,
            setup_seconds: setup.upload_seconds + info.target_seconds + setup.adapter_compile_seconds,
            upload_seconds: setup.upload_seconds + times.upload_seconds,
            pipeline_seconds: info.target_seconds + setup.adapter_compile_seconds,
            pass_seconds: times.wall_seconds,
            readback_seconds: times.readback_seconds,
            readback_bytes: times.readback_bytes,
            host_stats_seconds: times.host_stats_seconds,
            checkpoint_seconds: times.checkpoint_seconds,
            checks: times.checks,
            round_trips: times.round_trips,
            adapter_seconds: setup.adapter_seconds,
            overlap_seconds: (setup.adapter_seconds + setup.adapter_compile_seconds - setup.adapter_wait_seconds)
                .max(0.0),
            write_seconds: 0.0,
            process_seconds: None,
            start_seconds: 0.0,
            scene_seconds: setup.scene_seconds,
            request_seconds: info.request_seconds,
            compile_seconds: info.compile_seconds + setup.adapter_compile_seconds,
            pipeline_cache: setup.pipeline_cache.into(),
            teardown_seconds,
            other_seconds: 0.0,
            rays_per_second: rays as f64 / acc.render_seconds().max(1e-9),
            triangles: info.triangles,
            instances: info.instances,
            spheres: info.spheres,
            planes: info.planes,
            bvh_depth: setup.bvh_depth,
            duplicates_dropped: setup.bvh_duplicates,
            adapter: setup.adapter.name.clone(),
            backend: setup.adapter.backend.clone(),
            device_type: setup.adapter.device_type.clone(),
            driver: setup.adapter.driver.clone(),
            hemisphere: s.sampling.hemisphere,
            sky: s.sampling.sky,
            sampler: s.sampling.sampler,
            seed: s.sampling.seed,
            bvh_layout: setup.bvh_layout,
            device_bytes: setup.device_bytes + device_bytes,
            geometry_bindings: setup.geometry_bindings,
            geometry_storage: setup.geometry_storage.into(),
            traversal: setup.traversal.into(),
            scene_bytes: info.scene_bytes,
            bvh_bytes: setup.bvh_bytes,
            host_peak_bytes,
            host_peak_bytes_per_triangle: per(host_peak_bytes, info.triangles as u64),
            host_peak_bytes_per_point: match s.layout {
                FilmLayout::Image => None,
                _ => per(host_peak_bytes, s.height as u64),
            },
            heap_peak_bytes: None,
            load_seconds: 0.0,
            passes: acc.passes(),
            image_mean,
            mean_samples_per_pixel: pixel_samples as f64 / film.sum.len().max(1) as f64,
            adaptive: !film.pixel_samples.is_empty(),
            ended_by: match self.ended {
                Some((end, _)) => end.into(),
                None if done == acc.end() - acc.first() => EndedBy::Samples,
                None => EndedBy::Unfinished,
            },
            target: self.ended.and_then(|(_, t)| t),
            replicate_samples: film.replicate,
            replicates: film.replicates,
            error_estimator,
            error_degrees_of_freedom: error_estimator.degrees_of_freedom(film.samples),
            rmse_estimate,
            relative_rmse_estimate: rmse_estimate.map(|e| e / image_mean.abs()),
            rmse_bound,
        };
        Ok(RenderOutput { film, stats, accumulation })
    }
}

impl Render {
    /// The device's reduction of the image-level sums of the stopping rule over the
    /// samples held (all folded first), for tests that hold it against the host's; `None`
    /// where the device does not keep the sums or no pass has run.
    #[cfg(feature = "testing")]
    pub fn device_check_sums(&mut self) -> Result<Option<crate::gpu::stats::CheckSums>> {
        if !self.on_device {
            return Ok(None);
        }
        if self.acc.partial_samples() > 0 {
            // Independent samples only: a replicate cut here would lose its square.
            assert!(self.acc.settings().replicate_plan().is_none(), "a replicate in progress");
            self.passes.fold(false, self.acc.partial_samples())?;
            self.acc.end_block(0);
        }
        let exponents = (self.acc.exact().sum_exponent, self.acc.exact().sq_exponent);
        let (sums, bad) = self.passes.check(self.acc.check_query(), exponents)?;
        match bad {
            Some(slot) => Err(out_of_range(&self.acc, slot)),
            None => Ok(Some(sums)),
        }
    }

    /// The device's image-level sums of an adaptive render's decisions over the samples
    /// held, for tests that hold them against the host's ([`Accumulation::adapt_sums`]);
    /// `None` where the device does not keep the sums or no pass has run.
    #[cfg(feature = "testing")]
    pub fn device_adapt_sums(&mut self) -> Result<Option<crate::gpu::stats::AdaptSums>> {
        if !self.on_device || self.acc.partial_samples() > 0 {
            return Ok(None);
        }
        let exponents = (self.acc.exact().sum_exponent, self.acc.exact().sq_exponent);
        let (sums, bad) = self.passes.adapt_check(self.acc.adapt_query(), exponents)?;
        match bad {
            Some(slot) => Err(out_of_range(&self.acc, slot)),
            None => Ok(Some(sums)),
        }
    }

    /// Reads the device's exact sums into the accumulation, where the device keeps them.
    fn sync(&mut self) -> Result<()> {
        if self.on_device {
            sync_sums(self.passes.as_mut(), &mut self.acc, self.adapting_on_device)?;
        }
        Ok(())
    }
}

/// Reads the exact sums `passes` keeps into `acc` (with the replicates' squares once it
/// has any), and with `counts` the per-pixel counts and stopped pixels of an adaptive
/// render, once one has stopped.
fn sync_sums(passes: &mut dyn Passes, acc: &mut Accumulation, counts: bool) -> Result<()> {
    let replicates = acc.exact().replicates > 0 || !acc.exact().replicate_sq.is_empty();
    if let Some(slot) = passes.read_sums(acc.exact_mut(), replicates)? {
        return Err(out_of_range(acc, slot));
    }
    if counts {
        let counts = passes.read_counts()?;
        let x = acc.exact_mut();
        if counts.iter().any(|c| c.2) || !x.pixel_samples.is_empty() {
            x.pixel_samples = counts.iter().map(|c| c.0).collect();
            x.pixel_replicates = counts.iter().map(|c| c.1).collect();
            x.stopped = counts.iter().map(|c| c.2).collect();
        }
    }
    Ok(())
}

/// An adaptive render's decision after a block, on a device that keeps its sums: the
/// steps of [`Accumulation::adapt`], with the sums and the allocation on the device and
/// a few bytes read back. Returns whether every pixel has stopped, and whether the sums
/// the decision took meet the target (`None` where it took none).
fn adapt_on_device(
    passes: &mut dyn Passes,
    acc: &mut Accumulation,
    target: ErrorTarget,
    background_stopped: &mut bool,
    times: &mut PassTimes,
) -> Result<(bool, Option<bool>)> {
    if acc.exact().replicates == 0 || matches!(target, ErrorTarget::PointStdError(_)) {
        return Ok((false, None));
    }
    // The background pixels stop after their first replicate, before the device stops
    // any other in this run: the host's mask is still the device's.
    if !*background_stopped {
        *background_stopped = true;
        if let Some(mask) = acc.with_background() {
            passes.set_inactive(&mask)?;
            acc.stop(&mask);
            if mask.iter().all(|&off| off) {
                return Ok((true, None));
            }
        }
    }
    if acc.exact().replicates < MIN_TARGET_REPLICATES {
        return Ok((false, None));
    }
    let t = Instant::now();
    let (query, exponents) = (acc.adapt_query(), (acc.exact().sum_exponent, acc.exact().sq_exponent));
    let (sums, bad) = passes.adapt_check(query, exponents)?;
    if let Some(slot) = bad {
        return Err(out_of_range(acc, slot));
    }
    let Some(a) = acc.allocation(target, &sums) else {
        times.readback_seconds += t.elapsed().as_secs_f64();
        return Ok((false, Some(false)));
    };
    // The bound is of these sums: where it is not met yet, the pixels go on.
    let stop = if a.met { Stop::Always } else { Stop::IfAnyGoesOn };
    let (stops, going) = passes.allocate(query, exponents, a.per_sigma, stop)?;
    let apply = stops > 0 && stop.applies(going);
    times.readback_seconds += t.elapsed().as_secs_f64();
    Ok((apply && going == 0, Some(a.met)))
}

/// The error of a block that held a sample out of range at film slot `slot`, as the
/// host's exact sums report it.
fn out_of_range(acc: &Accumulation, slot: u32) -> crate::error::Error {
    let w = acc.settings().width.max(1);
    acc.error(format!(
        "pixel ({}, {}): a sample was not finite or larger than the scene's albedos and background allow",
        slot % w,
        slot / w
    ))
}

/// Whether a check of an error target is due after `stretches` stretches between two
/// checks (replicates, or `TARGET_CHECK_SAMPLES` independent samples): after every one up
/// to 32, then after every 2^j-th from 32 × 2^j on, so that the samples taken past the
/// stretch where the target was met are at most a sixteenth of the render and the checks
/// grow with the logarithm of its length. A function of the sample count alone: a
/// resumed render checks where the uninterrupted one did.
pub fn check_due(stretches: u64) -> bool {
    let step = (stretches / 16).max(1);
    // The largest power of two at most `step`.
    let step = 1u64 << (63 - step.leading_zeros());
    stretches.is_multiple_of(step)
}

/// `bytes` per item, for `items` of them (`None` for none).
fn per(bytes: u64, items: u64) -> Option<f64> {
    (items > 0 && bytes > 0).then(|| bytes as f64 / items as f64)
}

/// Peak resident memory of this process (Linux's `VmHWM`), in bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{Value, json};

    /// Costs of a sample `s` and of the work once a replicate `r` (seconds), and the
    /// variance of a sample that needs `independent` samples for an RMSE of `e`.
    fn costs(s: f64, r: f64, independent: f64, e: f64) -> ReplicateCosts {
        ReplicateCosts { per_sample: s, per_replicate: r, sample_variance: independent * e * e, image_mean: 0.25 }
    }

    /// A render stops at the first replicate, from the eighth, whose samples reach its
    /// need and (uniform) where a check is due; an adaptive one decides every replicate.
    #[test]
    fn renders_stop_at_the_first_due_replicate_that_reaches_the_need() {
        assert_eq!(replicates_to_reach(16, 0.0, false), 8);
        assert_eq!(replicates_to_reach(16, 100.0, false), 8);
        assert_eq!(replicates_to_reach(16, 16.0 * 20.0 + 1.0, false), 21);
        // Past 32 replicates a check is due every second one.
        assert_eq!(replicates_to_reach(16, 16.0 * 33.0, false), 34);
        assert_eq!(replicates_to_reach(16, 16.0 * 33.0, true), 33);
        assert_eq!(replicates_to_reach(64, f64::INFINITY, true), 8);
        // Far past 32 replicates, the next multiple of the spacing there.
        assert_eq!(replicates_to_reach(1, 1e12 + 1.0, false), 1_000_000_000_000u64.next_multiple_of(1 << 35));
        for need in (1..2000).map(|n| n as f64 * 7.3) {
            let k = replicates_to_reach(4, need, false);
            assert!(check_due(k) && k as f64 * 4.0 >= need, "{need}: {k}");
            assert!((8..k).all(|j| j as f64 * 4.0 < need || !check_due(j)), "{need}: {k}");
        }
    }

    /// Where the work once a replicate costs nothing and a larger replicate has no less
    /// variance (independent samples), a larger one only stops later: the least is
    /// chosen, its expected time never above a larger one's. Where the work once a
    /// replicate is as dear as many samples, the replicate grows; never past the most,
    /// in the sampler's steps; `least` where a cost is not a number.
    #[test]
    fn the_replicate_size_minimises_the_expected_time_to_the_target() {
        let rmse = ErrorTarget::Rmse(0.004);
        let free = costs(1e-3, 0.0, 1000.0, 0.004);
        for adaptive in [false, true] {
            assert_eq!(replicate_by_expected_cost(Sampler::Independent, 16, 256, &free, rmse, adaptive), 16);
            let t: Vec<f64> = [16, 32, 64, 128, 256]
                .iter()
                .map(|&b| expected_target_seconds(Sampler::Independent, b, &free, 0.004, adaptive))
                .collect();
            assert!(t.windows(2).all(|w| w[0] <= w[1]), "{t:?}");
        }
        // The work once a replicate as dear as 500 samples, for a need of about 1,000: the
        // eight replicates of 128 (their floor) cost less than any fewer larger or more
        // smaller ones.
        let dear = costs(1e-3, 0.5, 1000.0, 0.004);
        assert_eq!(replicate_by_expected_cost(Sampler::Independent, 16, 256, &dear, rmse, false), 128);
        assert_eq!(replicate_by_expected_cost(Sampler::Independent, 16, 64, &dear, rmse, false), 64);
        assert_eq!(replicate_by_expected_cost(Sampler::Stratified, 16, 256, &dear, rmse, false), 64);
        assert_eq!(replicate_by_expected_cost(Sampler::Grid, 16, 256, &dear, rmse, false), 0);
        let unknown = costs(1e-3, f64::NAN, 1000.0, 0.004);
        assert_eq!(replicate_by_expected_cost(Sampler::Sobol, 16, 256, &unknown, rmse, false), 16);
        // Every pixel exact: eight replicates of the least are all any render takes.
        let exact = costs(1e-3, 0.01, 0.0, 0.004);
        assert_eq!(replicate_by_expected_cost(Sampler::Sobol, 16, 256, &exact, rmse, false), 16);
        // A relative target is the image mean's share.
        let relative = ErrorTarget::RelativeRmse(0.004 / 0.25);
        assert_eq!(
            replicate_by_expected_cost(Sampler::Sobol, 16, 256, &dear, relative, false),
            replicate_by_expected_cost(Sampler::Sobol, 16, 256, &dear, rmse, false)
        );
    }

    /// The measured cases of docs/performance.md: on an H200 (the dragon at 1080p, a
    /// sample 0.56 ms, the work once a replicate about 1 ms, 1,920 independent samples
    /// for 0.003) Sobol replicates of 64 reached the target with 512 samples against 736
    /// in replicates of 16, and the rule takes more than 16; on lavapipe (the bunny at
    /// 256², a sample 57 ms, the work once a replicate 30 ms, 1,216 independent samples
    /// for 0.004) replicates of 64 took 512 against 480 and the rule takes fewer than 64;
    /// an adaptive render there, whose floor of eight replicates is most of its samples,
    /// keeps 16.
    #[test]
    fn the_replicate_size_follows_the_measured_cases() {
        let h200 = costs(0.41 / 736.0, 1e-3, 1920.0, 0.003);
        let b = replicate_by_expected_cost(Sampler::Sobol, 16, 256, &h200, ErrorTarget::Rmse(0.003), false);
        assert!(b > 16, "H200: {b}");
        let lavapipe = costs(0.057, 0.030, 1216.0, 0.004);
        let b = replicate_by_expected_cost(Sampler::Sobol, 16, 256, &lavapipe, ErrorTarget::Rmse(0.004), false);
        assert!(b < 64, "lavapipe: {b}");
        let b = replicate_by_expected_cost(Sampler::Sobol, 16, 256, &lavapipe, ErrorTarget::Rmse(0.004), true);
        assert_eq!(b, 16, "lavapipe, adaptive");
    }

    /// The typed statistics serialise to the words the JSON has always held.
    #[test]
    fn typed_statistics_serialise_as_their_words() {
        let words = EndedBy::ALL.map(EndedBy::name);
        assert_eq!(words, ["samples", "target", "time limit", "interrupted", "not run to its end"]);
        for e in EndedBy::ALL {
            assert_eq!(serde_json::to_value(e).unwrap(), e.name());
            assert!(e == e.name());
            assert_eq!(e.to_string(), e.name());
        }
        for (end, name) in [
            (RunEnd::Done, "samples"),
            (RunEnd::TimeLimit, "time limit"),
            (RunEnd::Stopped, "interrupted"),
            (RunEnd::TargetMet, "target"),
        ] {
            assert_eq!(EndedBy::from(end), name);
        }
        for h in Hemisphere::ALL {
            assert_eq!(serde_json::to_value(h).unwrap(), h.name());
        }
        for s in Sampler::ALL {
            assert_eq!(serde_json::to_value(s).unwrap(), s.name());
        }
        for l in BvhLayout::ALL {
            assert_eq!(serde_json::to_value(l).unwrap(), l.name());
        }
        let target = |t| words::target(&t, serde_json::value::Serializer).unwrap();
        assert_eq!(target(None), Value::Null);
        assert_eq!(target(Some(ErrorTarget::Rmse(0.5))), json!(["rmse", 0.5]));
        assert_eq!(target(Some(ErrorTarget::RelativeRmse(0.25))), json!(["relative_rmse", 0.25]));
        assert_eq!(target(Some(ErrorTarget::PointStdError(1e-3))), json!(["point_std_error", 1e-3]));
        for e in [ErrorEstimator::Samples, ErrorEstimator::Replicates { size: 16, count: 4 }, ErrorEstimator::None] {
            assert_eq!(words::estimator(&e, serde_json::value::Serializer).unwrap(), e.describe());
        }
        let sky = Sky { model: crate::sky::SkyModel::Overcast, ground_albedo: 0.3, ..Sky::default() };
        assert_eq!(words::sky(&sky, serde_json::value::Serializer).unwrap(), sky.describe());
    }
}
