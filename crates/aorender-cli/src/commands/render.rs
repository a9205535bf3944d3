//! `aorender render`: one image, with progress, a time limit, checkpoints, resuming,
//! sample-range shards and signal handling.

use crate::args::{RunArgs, SamplingArgs, SceneArgs, SizeArgs, check_output_extension, invalid_option, write_json};
use crate::phases::{self, Phases};
use crate::run::{self, RunControl};
use crate::{memory, output, signals};
use anyhow::{Result, bail};
use aorender::output::{FLOAT_IMAGE_EXTENSIONS, FilePlan, IMAGE_EXTENSIONS, write_error_image, write_image};
use aorender::{
    Accumulation, BvhOptions, Control, Device, DeviceOpening, EndedBy, ErrorTarget, ImageRequest, Ready, RenderOutput,
    RenderStats, Sampler, Scene, Session, replicate_by_expected_cost,
};

/// Samples per pixel a render with an error target takes at most, unless --spp says.
const TARGET_SPP_CAP: u32 = 65536;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

#[derive(clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    size: SizeArgs,
    /// Output image: .png (8-bit sRGB), .exr or .pfm (32-bit float, linear).
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,
    /// Samples per pixel (default: the scene's); with an error target, the most to take
    /// (default 65536).
    #[arg(long)]
    spp: Option<u32>,
    /// Stop once the image's root-mean-square error against its converged value is at
    /// most E, with 99 % confidence (checked after every replicate up to the 32nd, then
    /// at most a sixteenth of the samples apart).
    #[arg(long, value_name = "E", conflicts_with = "target_relative_error")]
    target_error: Option<f64>,
    /// Stop once that error is at most R times the image's mean.
    #[arg(long, value_name = "R")]
    target_relative_error: Option<f64>,
    /// With an error target: after every replicate, stop sampling the pixels whose own
    /// error is already within the target, so that the samples go where the error is.
    #[arg(long)]
    adaptive: bool,
    /// With an error target and no --replicate: time a pass and a check on the device
    /// first, and measure the samples' spread, and take the replicate (16 to 256 samples)
    /// whose expected time to the target (samples past it, checks) is the least. The
    /// size then depends on the machine's speed, so the image can differ run to run; the
    /// statistics and a checkpoint record it.
    #[arg(long, conflicts_with = "replicate")]
    replicate_by_cost: bool,
    /// Also write each pixel's standard error (.exr or .pfm, 32-bit float).
    #[arg(long, value_name = "FILE")]
    error_image: Option<PathBuf>,
    #[command(flatten)]
    sampling: SamplingArgs,
    #[command(flatten)]
    run: RunArgs,
}

pub fn run(args: RenderArgs) -> Result<()> {
    // Before loading: a signal while a large scene loads or its BVH builds ends the process.
    let stop = Arc::new(AtomicBool::new(false));
    signals::install(stop.clone())?;
    plan_files(&args)?;
    let (load_start, start_seconds) = (std::time::Instant::now(), phases::process_seconds());
    // The device opens beside the loading and the BVH build: it needs nothing of the scene.
    let target = args.target_error.is_some() || args.target_relative_error.is_some();
    let ready = Ready::Images { target, adaptive: args.adaptive };
    let mut opening = Device::open_beside(args.scene.device.kind(), args.scene.adapter.as_deref(), ready);
    let mut scene = args.scene.load()?;
    let load_seconds = load_start.elapsed().as_secs_f64();
    args.size.apply(&mut scene);
    let (target, measure_replicate) = apply_settings(&args, &mut scene)?;
    let checkpoint_path = args.run.check(scene.settings.spp, "pixel")?;
    check_output_extension(&args.output, &IMAGE_EXTENSIONS)?;
    let bvh = args.scene.bvh();
    if let Some(path) = &args.error_image {
        check_output_extension(path, &FLOAT_IMAGE_EXTENSIONS)?;
    }
    let resume = read_resume(&args, &mut scene, target, &bvh)?;
    // A film past the budget is refused before the BVH is built where the device is open
    // by now, and before anything is uploaded where it is not.
    if let Some(device) = opening.ready() {
        device.check_image_budget(&scene, &scene.settings)?;
    }
    check_error_estimate(&args, &scene)?;
    let resumed_adapter = resume.as_ref().map(|a| a.adapter().to_string());

    let rc = RunControl {
        stop: &stop,
        run: &args.run,
        checkpoint: checkpoint_path.as_deref(),
        total: scene.settings.spp,
        unit: "spp",
        target,
        adaptive: args.adaptive,
    };
    let (mut out, teardown_seconds) =
        run::traced(rc, |control| render_image(&args, opening, scene, &bvh, resume, measure_replicate, control))?;
    out.stats.start_seconds = start_seconds;
    out.stats.teardown_seconds += teardown_seconds;
    out.stats.load_seconds = load_seconds;
    out.stats.heap_peak_bytes = memory::heap_peak_bytes();
    if out.stats.samples_per_pixel == 0 {
        run::exit_before_any_sample("rendered");
    }
    let json = write_outputs(&args, &mut out)?;
    let st = &out.stats;
    say_summary(&args, st, target, resumed_adapter);
    output::print(&format!("{json}\n"))?;
    if st.interrupted {
        let mut written = vec![args.output.display().to_string()];
        written.extend(args.run.stats.as_ref().map(|p| p.display().to_string()));
        let done = format!(
            "{} of {} samples per pixel; {} hold them",
            st.samples_per_pixel,
            st.samples_requested,
            written.join(" and ")
        );
        return run::exit_interrupted(&done, checkpoint_path.as_deref());
    }
    say_ending(st, target);
    Ok(())
}

/// Before any work: no output onto an input or another output, nor onto a directory.
fn plan_files(args: &RenderArgs) -> Result<()> {
    let mut plan = FilePlan::new();
    output::plan_scene(&mut plan, args.scene.scene.as_deref());
    output::plan_resume(&mut plan, &args.run);
    plan.output(&args.output, "-o")?;
    if let Some(path) = &args.error_image {
        plan.output(path, "--error-image")?;
    }
    output::plan_run(&mut plan, &args.run)?;
    Ok(())
}

/// Applies the sampling options and the error target to the scene's settings; returns
/// the target and whether the replicate size is to be measured.
fn apply_settings(args: &RenderArgs, scene: &mut Scene) -> Result<(Option<ErrorTarget>, bool)> {
    let target = match (args.target_error, args.target_relative_error) {
        (Some(e), _) => Some(ErrorTarget::Rmse(e)),
        (_, Some(r)) => Some(ErrorTarget::RelativeRmse(r)),
        _ => None,
    };
    let s = &mut scene.settings;
    match (args.spp, target) {
        (Some(n), _) => s.spp = n,
        (None, Some(_)) => s.spp = TARGET_SPP_CAP,
        (None, None) => {}
    }
    args.sampling.apply(scene)?;
    if args.adaptive && target.is_none() {
        bail!("invalid option: --adaptive needs --target-error or --target-relative-error");
    }
    if args.replicate_by_cost && target.is_none() {
        bail!("invalid option: --replicate-by-cost needs --target-error or --target-relative-error");
    }
    // Independent samples are their own replicates, unless an adaptive render needs
    // replicates to decide at.
    let s = &mut scene.settings;
    let mut measure_replicate = false;
    if target.is_some()
        && s.sampling.replicate.is_none()
        && (s.sampling.sampler != Sampler::Independent || args.adaptive)
    {
        s.sampling.replicate = Some(crate::args::target_replicate(s.sampling.sampler, s.spp));
        measure_replicate = args.replicate_by_cost && args.run.sample_range.is_none() && args.run.resume.is_none();
    }
    scene.settings.validate().map_err(invalid_option)?;
    Ok((target, measure_replicate))
}

/// Reads `--resume`'s checkpoint and checks that it holds samples of this very render
/// (taking its replicate size unless `--replicate` says), and that the target suits the
/// render, before any work.
fn read_resume(
    args: &RenderArgs,
    scene: &mut Scene,
    target: Option<ErrorTarget>,
    bvh: &BvhOptions,
) -> Result<Option<Accumulation>> {
    let resume = match &args.run.resume {
        Some(path) => {
            let saved = Accumulation::read_with(path, &args.scene.load_options()?.limits)?;
            if args.sampling.replicate.is_none() {
                scene.settings.sampling.replicate = saved.settings().sampling.replicate;
            }
            // Before any work: the checkpoint must hold samples of this very render.
            let s = &scene.settings;
            let range = args.run.sample_range.clone().unwrap_or(0..s.spp);
            let expected = Accumulation::image(scene, &scene.camera, s, range, args.scene.device.kind(), bvh);
            saved.check_resume(&expected)?;
            if let Some(t) = target {
                expected.check_target(t).map_err(invalid_option)?;
            }
            Some(saved)
        }
        None => {
            if let Some(t) = target {
                let s = &scene.settings;
                let kind = args.scene.device.kind();
                Accumulation::image(scene, &scene.camera, s, 0..s.spp, kind, bvh)
                    .check_target(t)
                    .map_err(invalid_option)?;
            }
            None
        }
    };
    Ok(resume)
}

/// `--error-image` needs samples in replicates.
fn check_error_estimate(args: &RenderArgs, scene: &Scene) -> Result<()> {
    let s = &scene.settings;
    if args.error_image.is_some() && s.sampling.sampler.replicate_samples(s.sampling.replicate) == 0 {
        bail!(
            "invalid option: --error-image needs an error estimate, which the {} sampler has only in replicates: \
             add --replicate N",
            s.sampling.sampler.name()
        );
    }
    Ok(())
}

/// Builds the session on the device `opening` opens and renders under `control`
/// (resuming, and with the replicate size measured when asked); returns the output and the
/// seconds the session and device took to free.
fn render_image(
    args: &RenderArgs,
    opening: DeviceOpening,
    scene: Scene,
    bvh: &BvhOptions,
    resume: Option<Accumulation>,
    measure_replicate: bool,
    control: &mut Control,
) -> aorender::Result<(RenderOutput, f64)> {
    // The film's bytes depend on whether the device's memory is the host's, known once
    // it is open.
    let session =
        Session::beside(opening, scene, bvh, |device, scene| device.check_image_budget(scene, &scene.settings))?;
    let device = session.device().clone();
    let mut request = ImageRequest { samples: args.run.sample_range.clone(), ..session.default_request() };
    let mut render = session.render(&request)?;
    if measure_replicate
        && let Some(target) = control.target
        && let Some(costs) = render.replicate_costs()?
    {
        let s = &request.settings;
        let least = s.sampling.replicate.unwrap_or(1);
        let most = s.sampling.sampler.replicate_for(s.spp, 16);
        let chosen = replicate_by_expected_cost(s.sampling.sampler, least, most, &costs, target, control.adaptive);
        if chosen != least {
            drop(render);
            request.settings.sampling.replicate = Some(chosen);
            render = session.render(&request)?;
        }
    }
    if let Some(acc) = resume {
        render.resume(acc)?;
    }
    render.run(control)?;
    let out = render.finish()?;
    let teardown = std::time::Instant::now();
    drop((session, device));
    Ok((out, teardown.elapsed().as_secs_f64()))
}

/// Writes the image, the error image and the statistics file; returns the statistics
/// as JSON.
fn write_outputs(args: &RenderArgs, out: &mut RenderOutput) -> Result<String> {
    let writing = std::time::Instant::now();
    write_image(&out.film, &args.output)?;
    if let Some(path) = &args.error_image {
        write_error_image(&out.film, path)?;
    }
    out.stats.write_seconds = writing.elapsed().as_secs_f64();
    let mut phases = Phases::of_render(&out.stats);
    phases.close();
    (out.stats.process_seconds, out.stats.other_seconds) = (Some(phases.process_seconds), phases.other_seconds);
    let json = serde_json::to_string_pretty(&out.stats)?;
    if let Some(path) = &args.run.stats {
        write_json(path, &json)?;
    }
    Ok(json)
}

/// Says in a line what was rendered, and whether a resumed render changed adapters.
fn say_summary(args: &RenderArgs, st: &RenderStats, target: Option<ErrorTarget>, resumed_adapter: Option<String>) {
    // Copies the BVH left out cost nothing and change nothing, but the user may want to know.
    let copies = match st.duplicates_dropped {
        0 => String::new(),
        n => format!("; {n} copies of triangles or spheres left out of the BVH"),
    };
    let checks = match target {
        Some(_) => format!(", {} checks", st.checks),
        None => String::new(),
    };
    crate::say!(
        "{}: {}x{} at {} spp in {:.2} s ({:.1} M rays/s{checks}) on {} ({}); mean {:.4}{copies}; {}",
        args.output.display(),
        st.width,
        st.height,
        st.samples_per_pixel,
        st.render_seconds,
        st.rays_per_second / 1e6,
        st.adapter,
        st.backend,
        st.image_mean,
        Phases::of_render(st).line()
    );
    if let Some(adapter) = resumed_adapter
        && adapter != st.adapter
    {
        crate::say!(
            "note: the checkpoint was rendered on {adapter} and continued on {}: the sums are exact, but the two \
             adapters' samples may differ in their last bits: not bit for bit an uninterrupted render on either",
            st.adapter
        );
    }
}

/// Says how a render that ran to its end ended: target met, out of time, or target not met.
fn say_ending(st: &RenderStats, target: Option<ErrorTarget>) {
    if st.ended_by == EndedBy::Target {
        crate::say!(
            "error target met after {} of at most {} samples per pixel ({:.1} on average; RMSE bound {:.3e})",
            st.samples_per_pixel,
            st.samples_requested,
            st.mean_samples_per_pixel,
            st.rmse_bound.unwrap_or(f64::NAN)
        );
    } else if st.samples_per_pixel < st.samples_requested {
        let why =
            if target.is_some() && st.ended_by == EndedBy::TimeLimit { "; the error target was not met" } else { "" };
        crate::say!(
            "time limit reached after {} of {} samples per pixel{why}",
            st.samples_per_pixel,
            st.samples_requested
        );
    } else if target.is_some() {
        crate::say!("the error target was not met within {} samples per pixel", st.samples_requested);
    }
}
