//! `aorender bake`: AO at every vertex (or face) of the user's meshes, written back into
//! their files, with the progress, time limit, checkpoints, resuming, sample-range shards
//! and signal handling of `render`.

use crate::args::{RunArgs, SamplingArgs, SceneArgs, parse_bit_depth, read_shards, write_json};
use crate::phases::{self, Phases};
use crate::run::{self, RunControl};
use crate::{memory, output, signals};
use anyhow::{Result, anyhow, bail};
use aorender::bake::{
    Bake, BakeAt, BakeRequest, BakeTrace, GenerateUvs, TextureOptions, TextureReport, TextureRequest, UNUSABLE_VALUE,
    UvWrap, check_mesh_output, check_output, is_map, sibling,
};
use aorender::output::{FilePlan, OutputRules};
use aorender::{Accumulation, Device, DeviceOpening, ReadLimits, Ready, Scene, Session};
use clap::ValueEnum;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

#[derive(clap::Args)]
#[command(mut_arg("scene", |a| a
    .required(true)
    .value_name("INPUT")
    .help(concat!("The mesh to bake: ", crate::mesh_formats!(), "; or a scene file (.toml) whose mesh objects are baked, all its objects occluding"))))]
pub struct BakeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Output: for a mesh input, a mesh file whose extension picks its format (.ply, .obj,
    /// .gltf or .glb, optionally .gz; a texture bake: .png or .exr too); a directory for a
    /// scene file (one file per mesh object).
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
    /// Bake into a texture of SIZE (N or WxH texels) addressed by the mesh's texture
    /// coordinates, instead of into vertices: glTF/GLB output gets it as each baked
    /// material's occlusionTexture; `-o NAME.png` or `NAME.exr` writes the map alone (the
    /// only output for OBJ and PLY, whose files are unchanged).
    #[arg(long, value_name = "SIZE")]
    texture: Option<String>,
    /// The texture coordinate set to bake into (glTF TEXCOORD_n; OBJ and PLY have set 0).
    #[arg(long, default_value_t = 0, value_name = "N")]
    uv_set: u32,
    /// Texels of padding (dilation) around the charts.
    #[arg(long, default_value_t = 4, value_name = "PX")]
    padding: u32,
    /// Bits per channel of the PNG map: 8 or 16.
    #[arg(long, default_value_t = 8, value_parser = parse_bit_depth)]
    bit_depth: u8,
    /// Positions traced per texel (each with --samples samples, its own sample sequence).
    #[arg(long, default_value_t = 4, value_name = "K")]
    texel_points: u32,
    /// Texture coordinates outside [0, 1]: follow the file (repeat where its own
    /// textures on the set repeat: glTF samplers; else refuse), refuse, or repeat.
    #[arg(long, value_enum, default_value = "file")]
    uv_wrap: WrapArg,
    /// Lightmap texture coordinates for the texture bake: generate them when the mesh has
    /// none (auto), always (a new set: glTF TEXCOORD_n), or never. They are written into
    /// the output mesh.
    #[arg(long, value_enum, default_value = "auto")]
    generate_uvs: GenerateArg,
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

/// `--uv-wrap`.
#[derive(Clone, Copy, ValueEnum)]
enum WrapArg {
    File,
    Refuse,
    Repeat,
}

/// `--generate-uvs`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum GenerateArg {
    Auto,
    Always,
    Never,
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
    #[serde(flatten)]
    phases: Phases,
    duplicates_dropped: usize,
    setup_seconds: f64,
    adapter: String,
    hemisphere: &'static str,
    /// The sky and its sampling.
    sky: String,
    sampler: &'static str,
    seed: u32,
    max_distance: Option<f32>,
    mean_ao: f64,
    triangles: usize,
    host_peak_bytes: u64,
    host_peak_bytes_per_triangle: Option<f64>,
    host_peak_bytes_per_point: Option<f64>,
    heap_peak_bytes: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    texture: Option<TextureReport>,
}

impl BakeStats {
    /// The figures known once the bake is planned.
    fn new(input: &std::path::Path, bake: &Bake, settings: &aorender::Settings, load_seconds: f64) -> BakeStats {
        let range = bake.request().range();
        let at = bake.request().at;
        BakeStats {
            input: input.to_path_buf(),
            outputs: bake.targets().iter().map(|t| t.output.clone()).collect(),
            at: at.name(),
            meshes: bake.mesh_count(),
            points: bake.points(),
            points_traced: bake.probes().len(),
            points_without_normal: bake.plan().unusable,
            unusable_value: UNUSABLE_VALUE,
            file_normals: bake.plan().file_normals,
            samples_per_point: 0,
            samples_requested: range.end - range.start,
            first_sample: range.start,
            samples_resumed: 0,
            interrupted: false,
            ao_rays: 0,
            render_seconds: 0.0,
            rays_per_second: 0.0,
            phases: Phases { load_seconds, ..Phases::default() },
            duplicates_dropped: 0,
            setup_seconds: 0.0,
            adapter: String::new(),
            hemisphere: settings.sampling.hemisphere.name(),
            sky: settings.sampling.sky.describe(),
            sampler: settings.sampling.sampler.name(),
            seed: settings.sampling.seed,
            max_distance: settings.sampling.max_distance,
            mean_ao: 0.0,
            triangles: 0,
            host_peak_bytes: 0,
            host_peak_bytes_per_triangle: None,
            host_peak_bytes_per_point: None,
            heap_peak_bytes: None,
            texture: None,
        }
    }

    /// Adds what tracing (or merging) gave.
    fn add_trace(&mut self, trace: &BakeTrace, bake: &Bake) {
        self.samples_per_point = trace.samples;
        self.samples_resumed = trace.samples_resumed;
        self.interrupted = trace.interrupted;
        self.points_traced = trace.points_traced(bake);
        self.ao_rays = trace.rays;
        self.render_seconds = trace.seconds;
        if !trace.renders.is_empty() {
            self.rays_per_second = trace.rays as f64 / trace.seconds.max(1e-9);
        }
        self.adapter = trace.adapter.clone();
        self.phases.host_stats_seconds += trace.host_seconds;
        for r in &trace.renders {
            self.phases.add_render(r);
            self.setup_seconds += r.setup_seconds;
        }
        if let Some(last) = trace.renders.last() {
            self.phases.bvh_build_seconds = last.bvh_build_seconds;
            // The session's upload is once, not once a block.
            self.phases.upload_seconds = last.upload_seconds;
            if bake.blocks() == 1 {
                self.duplicates_dropped = last.duplicates_dropped;
            }
        }
    }

    /// Fills in the figures known once everything is written: the peaks and the process's
    /// seconds.
    fn end(&mut self) {
        self.heap_peak_bytes = memory::heap_peak_bytes();
        self.host_peak_bytes = aorender::peak_rss_bytes().unwrap_or(0);
        self.host_peak_bytes_per_triangle = phases::per(self.host_peak_bytes, self.triangles as u64);
        self.host_peak_bytes_per_point = phases::per(self.host_peak_bytes, self.points_traced as u64);
        self.phases.close();
    }
}

pub fn run(args: BakeArgs) -> Result<()> {
    let Some(input) = args.scene.scene.clone() else {
        bail!("missing INPUT: the mesh or scene file to bake (see aorender bake --help)");
    };
    let stop = Arc::new(AtomicBool::new(false));
    signals::install(stop.clone())?;
    let is_scene = input.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    let texture = texture_options(&args, is_scene)?;
    let mut files = plan_files(&args, &input, is_scene, texture.is_some())?;
    let checkpoint_path = check_run_options(&args)?;

    let (load_start, start_seconds) = (std::time::Instant::now(), phases::process_seconds());
    // The device opens beside the loading and the BVH build (a merge traces nothing).
    let kind = args.scene.device.kind();
    let opening =
        args.merge.is_empty().then(|| Device::open_beside(kind, args.scene.adapter.as_deref(), Ready::Points));
    let limits = ReadLimits::from_env()?;
    let (mut scene, read) = args.scene.load_for_bake()?;
    args.sampling.apply(&mut scene)?;
    let request = request(&args, texture, &limits)?;
    let bake = Bake::with_inputs(&scene, &read, &input, &request, &mut files)?;
    drop(read);
    let load_seconds = load_start.elapsed().as_secs_f64();
    let settings = scene.settings.clone();
    let at = request.at;

    let mut stats = BakeStats::new(&input, &bake, &settings, load_seconds);
    stats.phases.start_seconds = start_seconds;
    stats.triangles = scene.world_triangle_count();

    // The sums: from the shards', or traced.
    let trace = match opening {
        Some(opening) => trace(&args, &stop, checkpoint_path.as_deref(), opening, scene, &bake, &limits, &mut stats)?,
        None => merge_shards(&args, scene, &bake, &limits, &mut stats)?,
    };
    stats.add_trace(&trace, &bake);

    let start = Instant::now();
    let baked = bake.finish(trace)?;
    stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();
    stats.mean_ao = baked.mean_ao;
    stats.points = baked.points;

    // Written back, file by file (each atomically).
    let writing = Instant::now();
    let written = bake.write(&baked, stats.samples_per_point)?;
    stats.phases.write_seconds += writing.elapsed().as_secs_f64();
    for (path, note) in &written.notes {
        crate::say!("note: {}: {note}", path.display());
    }
    stats.outputs = written.files.clone();
    stats.end();
    let files: Vec<String> = written.files.iter().map(|p| p.display().to_string()).collect();
    say_written(&files, written.texture, &bake, at, &mut stats);
    let json = serde_json::to_string_pretty(&stats)?;
    if let Some(path) = &args.run.stats {
        write_json(path, &json)?;
    }
    output::print(&format!("{json}\n"))?;
    if stats.interrupted {
        let done = format!(
            "{} of {} samples per point; {} {} them",
            stats.samples_per_point,
            stats.samples_requested,
            files.join(" and "),
            if files.len() == 1 { "holds" } else { "hold" }
        );
        return run::exit_interrupted(&done, checkpoint_path.as_deref());
    }
    if stats.samples_per_point < stats.samples_requested {
        crate::say!(
            "time limit reached after {} of {} samples per point",
            stats.samples_per_point,
            stats.samples_requested
        );
    }
    Ok(())
}

/// Checks the output against the input, and plans the files before any work: no output
/// onto an input or another output. A scene's outputs are known once its objects are,
/// and the files written beside a mesh once it is read.
fn plan_files(args: &BakeArgs, input: &Path, is_scene: bool, texture: bool) -> Result<FilePlan> {
    if !is_scene && (!texture || !is_map(&args.output)) {
        // A bake into vertices or faces writes any mesh format; a texture bake its input's.
        if texture {
            check_output(input, &args.output, args.overwrite)?;
        } else {
            check_mesh_output(input, &args.output, args.overwrite)?;
        }
    }
    let mut files = FilePlan::new();
    files.scene(input);
    for path in &args.merge {
        files.input(path, "a checkpoint --merge adds");
    }
    output::plan_resume(&mut files, &args.run);
    let new_directories = OutputRules { new_directories: true, ..OutputRules::default() };
    if texture && is_map(&args.output) {
        files.output_with(&args.output, "-o", new_directories)?;
        if args.bent_normals {
            files.output_with(
                &sibling(&args.output, "_bent_normals.png"),
                "the bent normals map beside -o",
                new_directories,
            )?;
        }
    } else if !is_scene {
        let replacing = args.overwrite.then_some(input);
        files.output_with(&args.output, "-o", OutputRules { replacing, ..new_directories })?;
    }
    output::plan_run(&mut files, &args.run)?;
    Ok(files)
}

/// Checks the samples, the checkpoint options and that `--merge` comes alone; returns
/// where checkpoints are saved.
fn check_run_options(args: &BakeArgs) -> Result<Option<PathBuf>> {
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
    Ok(checkpoint_path)
}

/// Traces the bake's samples (resuming `--resume`'s checkpoint) on the device `opening`
/// opens, under the run's control; a stop inside a block, or before any sample, ends the
/// process with nothing written.
// The run's pieces: grouping them would only rename them.
#[allow(clippy::too_many_arguments)]
fn trace(
    args: &BakeArgs,
    stop: &AtomicBool,
    checkpoint_path: Option<&Path>,
    opening: DeviceOpening,
    scene: Scene,
    bake: &Bake,
    limits: &ReadLimits,
    stats: &mut BakeStats,
) -> Result<BakeTrace> {
    let bvh = args.scene.bvh();
    let kind = args.scene.device.kind();
    let resume = match &args.run.resume {
        Some(path) => {
            let saved = Accumulation::read_with(path, limits)?;
            saved.check_resume(&bake.expected(&scene, kind, &bvh)?)?;
            Some(saved)
        }
        None => None,
    };
    let (mut setup, mut teardown_seconds) = (None, 0.0);
    let rc = RunControl {
        stop,
        run: &args.run,
        checkpoint: checkpoint_path,
        total: args.samples * bake.blocks() as u32,
        unit: "samples",
        target: None,
        adaptive: false,
    };
    let trace = run::traced(rc, |control| {
        let session = Session::beside(opening, scene, &bvh, |_, _| Ok(()))?;
        let device = session.device().clone();
        setup = Some(session.setup().clone());
        let trace = session.bake(bake, resume, control);
        let teardown = Instant::now();
        drop((session, device));
        teardown_seconds = teardown.elapsed().as_secs_f64();
        trace
    })?;
    if let Some(setup) = &setup {
        stats.phases.set_opening(setup);
    }
    stats.phases.teardown_seconds = teardown_seconds;
    if let Some(b) = trace.interrupted_block {
        let signal = signals::stop_signal();
        crate::say!(
            "aorender: interrupted by {} in block {} of {}; nothing was written",
            signals::signal_name(signal),
            b + 1,
            bake.blocks()
        );
        std::process::exit(128 + signal);
    }
    if trace.samples == 0 {
        run::exit_before_any_sample("traced");
    }
    Ok(trace)
}

/// The bake's sums from `--merge`'s finished shards.
fn merge_shards(
    args: &BakeArgs,
    scene: Scene,
    bake: &Bake,
    limits: &ReadLimits,
    stats: &mut BakeStats,
) -> Result<BakeTrace> {
    let start = Instant::now();
    let shards = read_shards(&args.merge, limits)?;
    stats.phases.load_seconds += start.elapsed().as_secs_f64();
    let expected = bake.expected(&scene, args.scene.device.kind(), &args.scene.bvh())?;
    drop(scene);
    Ok(bake.merge(&shards, &expected)?)
}

/// Says in a line what was written (a texture bake's report, or the points baked and any
/// without a usable normal).
fn say_written(files: &[String], texture: Option<TextureReport>, bake: &Bake, at: BakeAt, stats: &mut BakeStats) {
    match (texture, bake.texture_options()) {
        (Some(report), Some(options)) => {
            say_texture(files, options, &report, stats);
            stats.texture = Some(report);
        }
        _ => {
            crate::say!(
                "{}: {} {} × {} samples in {:.2} s ({:.1} M AO rays/s) on {}; mean AO {:.4}; {}",
                files.join(", "),
                stats.points,
                plural(at),
                stats.samples_per_point,
                stats.render_seconds,
                stats.rays_per_second / 1e6,
                stats.adapter,
                stats.mean_ao,
                stats.phases.line()
            );
            let unusable = bake.plan().unusable;
            if unusable > 0 {
                crate::say!(
                    "note: {unusable} {} without a usable normal (unreferenced, or only degenerate faces) got AO {UNUSABLE_VALUE}",
                    plural(at)
                );
            }
        }
    }
}

/// The library's request for `args`.
fn request(args: &BakeArgs, texture: Option<TextureOptions>, limits: &ReadLimits) -> Result<BakeRequest> {
    let texture = match texture {
        Some(options) => Some(TextureRequest {
            options,
            generate_uvs: match args.generate_uvs {
                GenerateArg::Auto => GenerateUvs::Auto,
                GenerateArg::Always => GenerateUvs::Always,
                GenerateArg::Never => GenerateUvs::Never,
            },
            bit_depth: args.bit_depth,
            memory_bytes: memory::budget_bytes()?,
        }),
        None => None,
    };
    Ok(BakeRequest {
        at: match args.at {
            AtArg::Vertices => BakeAt::Vertices,
            AtArg::Faces => BakeAt::Faces,
        },
        samples: args.samples,
        sample_range: args.run.sample_range.clone(),
        bent_normals: args.bent_normals,
        std_error: args.std_error,
        colors: args.colors,
        output: Some(args.output.clone()),
        output_name: "-o".to_string(),
        overwrite: args.overwrite,
        texture,
        one_film: args.run.time_limit.is_some()
            || args.run.checkpoint.is_some()
            || args.run.resume.is_some()
            || args.run.sample_range.is_some()
            || !args.merge.is_empty(),
        limits: limits.clone(),
        settings: None,
    })
}

/// The summary line of a texture bake, and its notes.
fn say_texture(files: &[String], options: &TextureOptions, report: &TextureReport, stats: &BakeStats) {
    let covered: usize = report.maps.iter().map(|m| m.covered_texels).sum();
    let rms = (report.maps.iter().map(|m| m.rms_std_error.powi(2) * m.covered_texels as f64).sum::<f64>()
        / covered.max(1) as f64)
        .sqrt();
    crate::say!(
        "{}: {}×{} texture, {} texels × {} points × {} samples in {:.2} s ({:.1} M AO rays/s) on {}; mean AO {:.4}, RMS standard error {:.4}; {}",
        files.join(", "),
        options.width,
        options.height,
        covered,
        options.points,
        stats.samples_per_point,
        stats.render_seconds,
        stats.rays_per_second / 1e6,
        stats.adapter,
        stats.mean_ao,
        rms,
        stats.phases.line()
    );
    if report.overlapping_texels > 0 {
        crate::say!(
            "note: {} texels are covered by overlapping charts (mirrored or stacked UVs): each holds the mean over the surfaces mapped to it",
            report.overlapping_texels
        );
    }
    if report.skipped_triangles > 0 {
        crate::say!(
            "note: {} triangles without texture coordinates at a corner or of zero area in UV space were not baked",
            report.skipped_triangles
        );
    }
}

fn plural(at: BakeAt) -> &'static str {
    match at {
        BakeAt::Vertices => "vertices",
        BakeAt::Faces => "faces",
    }
}

/// `--texture` and its companions, checked before anything is loaded; `None` for a
/// bake into vertices.
fn texture_options(args: &BakeArgs, is_scene: bool) -> Result<Option<TextureOptions>> {
    let Some(size) = &args.texture else {
        if is_map(&args.output) {
            bail!(
                "{}: a bake into vertices writes a mesh file; bake a texture (--texture SIZE) to write a map",
                args.output.display()
            );
        }
        return Ok(None);
    };
    let parse = |s: &str| s.trim().parse::<u32>().ok();
    let (width, height) = match size.split_once(['x', 'X', '×']) {
        Some((w, h)) => (parse(w), parse(h)),
        None => (parse(size), parse(size)),
    };
    let (Some(width), Some(height)) = (width, height) else {
        bail!("invalid option: --texture {size}: expected a size in texels, N or WxH (for example 2048)");
    };
    let options = TextureOptions {
        width,
        height,
        uv_set: args.uv_set,
        points: args.texel_points,
        padding: args.padding,
        wrap: match args.uv_wrap {
            WrapArg::File => UvWrap::File,
            WrapArg::Refuse => UvWrap::Refuse,
            WrapArg::Repeat => UvWrap::Repeat,
        },
        seed: args.scene.seed.unwrap_or(0),
    };
    options.validate().map_err(|e| {
        anyhow!("invalid option: --texture: {}", e.to_string().trim_start_matches("invalid settings: "))
    })?;
    if is_scene && !is_map(&args.output) {
        bail!("{}: a scene file's texture bake writes the map itself: -o NAME.png or NAME.exr", args.output.display());
    }
    if matches!(args.at, AtArg::Faces) {
        bail!(
            "invalid option: --at faces bakes per face, not into a texture: leave out one of --at faces and --texture"
        );
    }
    if args.std_error || args.colors {
        bail!(
            "invalid option: --std-error and --colors are for vertex bakes: a texture's standard errors go into the G channel of a .exr map (-o NAME.exr)"
        );
    }
    Ok(Some(options))
}
