//! `aorender bake`: AO at every vertex (or face) of the user's meshes, written back into
//! their files, with the progress, time limit, checkpoints, resuming, sample-range shards
//! and signal handling of `render`.

use crate::args::{RunArgs, SamplingArgs, SceneArgs, check_writable, write_json};
use crate::{memory, signals};
use anyhow::{Context, Result, anyhow, bail};
use aorender::bake::{
    Asset, BakeAt, BakePlan, Placement, UNUSABLE_VALUE, WriteOptions, check_output, format_of, output_path, read_asset,
};
use aorender::scene::MeshObject;
use aorender::{Accumulation, Control, Device, Progress, Session, merge, probe_film_bent_normals, probe_film_values};
use clap::ValueEnum;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

#[derive(clap::Args)]
pub struct BakeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Output: a mesh file of the input's format (.ply, .obj, .gltf or .glb, optionally
    /// .gz) for a mesh input; a directory for a scene file (one file per mesh object).
    #[arg(short, long)]
    output: PathBuf,
    /// Where AO is baked: at every vertex about its normal, or at every face's centroid.
    #[arg(long, value_enum, default_value = "vertices")]
    at: AtArg,
    /// Samples (AO rays) per vertex or face.
    #[arg(long, default_value_t = 256)]
    samples: u32,
    #[command(flatten)]
    sampling: SamplingArgs,
    /// Also write each value's standard error (PLY `quality_std_error`, glTF `_AO_STD_ERROR`).
    #[arg(long)]
    std_error: bool,
    /// Also write AO as a grey vertex colour in PLY output (OBJ and glTF always get one).
    #[arg(long)]
    colors: bool,
    /// Also write bent normals (the mean direction of the rays that escaped, normalised;
    /// PLY `bnx bny bnz`, glTF `_BENT_NORMAL`), from the same rays.
    #[arg(long)]
    bent_normals: bool,
    /// Allow the output to replace the input file.
    #[arg(long)]
    overwrite: bool,
    #[command(flatten)]
    run: RunArgs,
    /// Write the bake from these shards' checkpoints (`--sample-range … --checkpoint FILE`)
    /// instead of tracing: their sums are added exactly.
    #[arg(long, num_args = 1.., value_name = "CHECKPOINT")]
    merge: Vec<PathBuf>,
}

/// `--at`.
#[derive(Clone, Copy, ValueEnum)]
enum AtArg {
    Vertices,
    Faces,
}

/// What `aorender bake` reports.
#[derive(serde::Serialize)]
struct BakeStats {
    input: PathBuf,
    outputs: Vec<PathBuf>,
    at: &'static str,
    meshes: usize,
    points: usize,
    points_traced: usize,
    points_without_normal: usize,
    unusable_value: f32,
    file_normals: usize,
    samples_per_point: u32,
    samples_requested: u32,
    first_sample: u32,
    samples_resumed: u32,
    interrupted: bool,
    ao_rays: u64,
    render_seconds: f64,
    rays_per_second: f64,
    load_seconds: f64,
    bvh_build_seconds: f64,
    setup_seconds: f64,
    adapter: String,
    hemisphere: &'static str,
    sampler: &'static str,
    seed: u32,
    max_distance: Option<f32>,
    mean_ao: f64,
    heap_peak_bytes: Option<u64>,
}

/// One baked file: the mesh object it comes from, its asset, and where it goes.
struct Target {
    object: MeshObject,
    asset: Arc<dyn Asset>,
    output: PathBuf,
}

pub fn run(args: BakeArgs) -> Result<()> {
    let Some(input) = args.scene.scene.clone() else {
        bail!("missing INPUT: the mesh or scene file to bake (see aorender bake --help)");
    };
    let stop = Arc::new(AtomicBool::new(false));
    signals::install(stop.clone())?;
    let is_scene = input.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if !is_scene {
        check_output(&input, &args.output, args.overwrite)?;
    }
    if args.samples == 0 {
        bail!("invalid option: --samples must be at least 1");
    }
    let checkpoint_path = args.run.check(args.samples, "point")?;
    if !args.merge.is_empty()
        && (args.run.resume.is_some() || args.run.checkpoint.is_some() || args.run.sample_range.is_some())
    {
        bail!(
            "invalid option: --merge writes the bake from finished shards: it takes no --resume, --checkpoint or --sample-range"
        );
    }

    let load_start = std::time::Instant::now();
    let mut scene = args.scene.load()?;
    args.sampling.apply(&mut scene)?;
    if scene.mesh_objects.is_empty() {
        bail!("{}: the scene has no mesh objects to bake", input.display());
    }
    let targets = targets(&scene.mesh_objects, is_scene, &args.output, args.overwrite)?;
    let at = match args.at {
        AtArg::Vertices => BakeAt::Vertices,
        AtArg::Faces => BakeAt::Faces,
    };
    if at == BakeAt::Faces
        && let Some(t) = targets.iter().find(|t| format_of(&t.output).is_some_and(|f| f != "PLY"))
    {
        bail!(
            "{}: {} has no per-face attributes: bake --at faces into a PLY file (convert the mesh first)",
            t.output.display(),
            format_of(&t.output).unwrap_or_default()
        );
    }
    let meshes = targets.iter().flat_map(|t| t.asset.meshes().iter().map(|m| (m, Placement::of(&t.object))));
    let plan = BakePlan::new(meshes, at);
    let load_seconds = load_start.elapsed().as_secs_f64();
    if plan.probes.is_empty() {
        bail!("{}: no {} has a usable normal: nothing to bake", input.display(), singular(at));
    }
    for t in &targets {
        // The directory of a scene's outputs is made when they are written: until then the
        // nearest existing one must be writable.
        let mut probe = t.output.clone();
        while let Some(parent) = probe.parent().filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
            probe = parent.to_path_buf();
        }
        check_writable(&probe)?;
    }
    let settings = scene.settings.clone();
    let bvh = args.scene.bvh();
    let kind = args.scene.device.kind();
    let range = args.run.sample_range.clone().unwrap_or(0..args.samples);
    let expected = || {
        Accumulation::probes(
            &scene,
            &plan.probes,
            args.samples,
            range.clone(),
            &settings,
            args.bent_normals,
            kind,
            &bvh,
        )
    };

    // The values: from the shards' sums, or traced.
    let mut stats = BakeStats {
        input: input.clone(),
        outputs: targets.iter().map(|t| t.output.clone()).collect(),
        at: at.name(),
        meshes: plan.mesh_count(),
        points: plan.entry_count(),
        points_traced: plan.probes.len(),
        points_without_normal: plan.unusable,
        unusable_value: UNUSABLE_VALUE,
        file_normals: plan.file_normals,
        samples_per_point: 0,
        samples_requested: range.end - range.start,
        first_sample: range.start,
        samples_resumed: 0,
        interrupted: false,
        ao_rays: 0,
        render_seconds: 0.0,
        rays_per_second: 0.0,
        load_seconds,
        bvh_build_seconds: 0.0,
        setup_seconds: 0.0,
        adapter: String::new(),
        hemisphere: settings.hemisphere.name(),
        sampler: settings.sampler.name(),
        seed: settings.seed,
        max_distance: settings.max_distance,
        mean_ao: 0.0,
        heap_peak_bytes: None,
    };
    let film = if args.merge.is_empty() {
        let resume = match &args.run.resume {
            Some(path) => {
                let saved = Accumulation::read(path)?;
                saved.check_resume(&expected()?)?;
                Some(saved)
            }
            None => None,
        };
        if let Some(path) = &checkpoint_path {
            check_writable(path)?;
        }
        let acc = trace(&args, scene, &plan, resume, checkpoint_path.as_deref(), &stop, &mut stats)?;
        acc.film()?
    } else {
        let mut shards = Vec::with_capacity(args.merge.len());
        for path in &args.merge {
            shards.push((path.clone(), Accumulation::read(path)?));
        }
        let this = expected()?;
        let diff = shards[0].1.settings.differences(&this.settings);
        if !diff.is_empty() {
            bail!(
                "{}: holds samples of another bake: {} (checkpoint's value first)",
                shards[0].0.display(),
                diff.join("; ")
            );
        }
        let merged = merge(&shards)?;
        if merged.first != 0 || merged.end != args.samples {
            bail!(
                "the shards hold samples {}..{}, not all 0..{} of --samples {}",
                merged.first,
                merged.end,
                args.samples,
                args.samples
            );
        }
        stats.samples_per_point = merged.end - merged.first;
        stats.adapter = merged.shards.iter().map(|s| s.adapter.clone()).collect::<Vec<_>>().join(", ");
        merged.film
    };
    let values = probe_film_values(&film);
    let bent = probe_film_bent_normals(&film);
    let traced = values.len().max(1) as f64;
    stats.mean_ao = values.iter().map(|v| v.mean).sum::<f64>() / traced;
    let baked = plan.values(&values, bent.as_deref());

    // Written back, file by file (each atomically).
    let options = WriteOptions { at, std_error: args.std_error, colors: args.colors };
    let mut baked = baked.into_iter();
    for t in &targets {
        let values: Vec<_> = baked.by_ref().take(t.asset.meshes().len()).collect();
        if let Some(dir) = t.output.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
        }
        for note in t.asset.write(&t.output, &values, &options)? {
            eprintln!("note: {}: {note}", t.output.display());
        }
    }
    stats.heap_peak_bytes = memory::heap_peak_bytes();
    let json = serde_json::to_string_pretty(&stats)?;
    if let Some(path) = &args.run.stats {
        write_json(path, &json)?;
    }
    let written: Vec<String> = targets.iter().map(|t| t.output.display().to_string()).collect();
    eprintln!(
        "{}: {} {} × {} samples in {:.2} s ({:.1} M AO rays/s) on {}; mean AO {:.4}",
        written.join(", "),
        stats.points,
        plural(at),
        stats.samples_per_point,
        stats.render_seconds,
        stats.rays_per_second / 1e6,
        stats.adapter,
        stats.mean_ao
    );
    if plan.unusable > 0 {
        eprintln!(
            "note: {} {} without a usable normal (unreferenced, or only degenerate faces) got AO {UNUSABLE_VALUE}",
            plan.unusable,
            plural(at)
        );
    }
    println!("{json}");
    if stats.interrupted {
        let signal = signals::stop_signal();
        let mut message = format!(
            "interrupted by {} after {} of {} samples per point; {} {} them",
            signals::signal_name(signal),
            stats.samples_per_point,
            stats.samples_requested,
            written.join(" and "),
            if written.len() == 1 { "holds" } else { "hold" }
        );
        if let Some(path) = &checkpoint_path {
            message += &format!("; continue with --resume {}", path.display());
        }
        eprintln!("aorender: {message}");
        std::io::stdout().flush()?;
        std::process::exit(128 + signal);
    }
    if stats.samples_per_point < stats.samples_requested {
        eprintln!(
            "time limit reached after {} of {} samples per point",
            stats.samples_per_point, stats.samples_requested
        );
    }
    Ok(())
}

/// Traces the plan's probes on the device: the accumulation when the samples asked for
/// are done, the time limit is reached or a signal stops it (then `stats.interrupted`).
fn trace(
    args: &BakeArgs,
    scene: aorender::Scene,
    plan: &BakePlan,
    resume: Option<Accumulation>,
    checkpoint: Option<&Path>,
    stop: &AtomicBool,
    stats: &mut BakeStats,
) -> Result<Accumulation> {
    let settings = scene.settings.clone();
    let bar = signals::PassProgress::new(args.samples, "samples");
    let mut on_progress = |p: &Progress| bar.update(p);
    let mut save_to = |acc: &Accumulation| -> aorender::Result<()> {
        match checkpoint {
            Some(path) => acc.write(path),
            None => Ok(()),
        }
    };
    let mut control = Control {
        stop: Some(stop),
        time_limit: args.run.time_limit,
        progress: Some(&mut on_progress),
        save: if checkpoint.is_some() { Some(&mut save_to) } else { None },
        save_interval: args.run.checkpoint_interval,
        ..Control::default()
    };
    let resumed = resume.as_ref().map_or(0, |a| a.samples());
    let out = (|| {
        let device = Device::open(args.scene.device.kind(), args.scene.adapter.as_deref())?;
        let session = Session::new(&device, scene, &args.scene.bvh())?;
        let mut render = session.probe_render(
            &plan.probes,
            args.samples,
            args.run.sample_range.clone(),
            &settings,
            args.bent_normals,
        )?;
        if let Some(acc) = resume {
            render.resume(acc)?;
        }
        render.run(&mut control)?;
        render.finish()
    })()
    .map_err(|e| {
        let adapter_failed = matches!(e, aorender::Error::DeviceLost { .. } | aorender::Error::OutOfMemory { .. });
        match checkpoint {
            Some(path) if adapter_failed && path.exists() => anyhow!(
                "{e}; the last checkpoint, {}, is intact: continue with --resume {}",
                path.display(),
                path.display()
            ),
            _ => e.into(),
        }
    })?;
    bar.finish();
    let acc = out.accumulation;
    if acc.samples() == 0 {
        let signal = signals::stop_signal();
        eprintln!(
            "aorender: interrupted by {} before any sample was traced; nothing was written",
            signals::signal_name(signal)
        );
        std::process::exit(128 + signal);
    }
    stats.samples_per_point = acc.samples();
    stats.samples_resumed = resumed;
    stats.interrupted = out.stats.interrupted;
    stats.ao_rays = acc.ao_rays;
    stats.render_seconds = acc.render_seconds;
    stats.rays_per_second = acc.ao_rays as f64 / acc.render_seconds.max(1e-9);
    stats.bvh_build_seconds = out.stats.bvh_build_seconds;
    stats.setup_seconds = out.stats.setup_seconds;
    stats.adapter = out.stats.adapter.clone();
    Ok(acc)
}

/// The files to bake: for a mesh input, its one object into `output`; for a scene file,
/// each mesh object into the directory `output`, under its file's name (with the object's
/// number added when the file is placed by several objects). Each file is read once.
fn targets(objects: &[MeshObject], is_scene: bool, output: &Path, overwrite: bool) -> Result<Vec<Target>> {
    let mut assets: Vec<(PathBuf, Arc<dyn Asset>)> = Vec::new();
    let mut targets = Vec::with_capacity(objects.len());
    for object in objects {
        let asset = match assets.iter().find(|(p, _)| *p == object.path) {
            Some((_, a)) => a.clone(),
            None => {
                let a: Arc<dyn Asset> = Arc::from(read_asset(&object.path)?);
                assets.push((object.path.clone(), a.clone()));
                a
            }
        };
        let out = output_path(objects, object, is_scene, output);
        check_output(&object.path, &out, overwrite)?;
        targets.push(Target { object: object.clone(), asset, output: out });
    }
    Ok(targets)
}

fn singular(at: BakeAt) -> &'static str {
    match at {
        BakeAt::Vertices => "vertex",
        BakeAt::Faces => "face",
    }
}

fn plural(at: BakeAt) -> &'static str {
    match at {
        BakeAt::Vertices => "vertices",
        BakeAt::Faces => "faces",
    }
}
