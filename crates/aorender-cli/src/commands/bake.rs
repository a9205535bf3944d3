//! `aorender bake`: AO at every vertex (or face) of the user's meshes, written back into
//! their files, with the progress, time limit, checkpoints, resuming, sample-range shards
//! and signal handling of `render`.

use crate::args::{RunArgs, SamplingArgs, SceneArgs, read_shards, write_json};
use crate::phases::{self, Phases};
use crate::{memory, output, signals};
use anyhow::{Context, Result, anyhow, bail};
use aorender::bake::{
    Asset, AssetMesh, BakeAt, BakePlan, BakedTexture, Coverage, GeneratedUvs, Placement, TextureFiles, TextureLayout,
    TextureMap, TextureOptions, TexturePlan, TextureStats, TextureTarget, UNUSABLE_VALUE, UvWrap, WriteOptions,
    bytes_per_point, check_output, format_of, generate_uvs, map_path, output_path, plan_companions, plan_output,
    read_object,
};
use aorender::output::{FilePlan, OutputRules, write_output};
use aorender::scene::MeshObject;
use aorender::{
    Accumulation, Control, Device, Probe, Progress, ReadLimits, Session, merge, probe_film_bent_normals,
    probe_film_values,
};
use clap::ValueEnum;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

#[derive(clap::Args)]
#[command(mut_arg("scene", |a| a
    .required(true)
    .value_name("INPUT")
    .help("The mesh to bake (.obj, .ply, .gltf or .glb, each optionally gzipped: .gz), or a scene file (.toml) whose mesh objects are baked, all its objects occluding")))]
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

/// What unwrapping made, in the statistics.
#[derive(serde::Serialize)]
struct GeneratedReport {
    /// The set written (glTF TEXCOORD_n; 0 for OBJ and PLY).
    set: u32,
    charts: u32,
    atlases: usize,
    /// Fraction of the texture the charts' surface covers.
    utilization: f32,
    seconds: f64,
}

/// What a texture bake reports besides the points.
#[derive(serde::Serialize)]
struct TextureReport {
    width: u32,
    height: u32,
    uv_set: u32,
    textures: usize,
    points_per_texel: u32,
    samples_per_texel: u64,
    padding: u32,
    bit_depth: u8,
    overlapping_texels: usize,
    skipped_triangles: usize,
    wrapped_triangles: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    generated_uvs: Option<GeneratedReport>,
    /// Per texture: covered and padded texels, mean AO, the standard errors' RMS and maximum.
    maps: Vec<TextureStats>,
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
    /// Fills in the figures known once everything is written: the peaks and the process's
    /// seconds.
    fn end(&mut self) {
        self.heap_peak_bytes = memory::heap_peak_bytes();
        self.host_peak_bytes = aorender::peak_rss_bytes().unwrap_or(0);
        self.host_peak_bytes_per_triangle = phases::per(self.host_peak_bytes, self.triangles as u64);
        self.host_peak_bytes_per_point = phases::per(self.host_peak_bytes, self.points_traced as u64);
        self.phases.process_seconds = phases::process_seconds();
    }
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
    let mut texture = texture_options(&args, is_scene)?;
    if !is_scene && (texture.is_none() || !is_map(&args.output)) {
        check_output(&input, &args.output, args.overwrite)?;
    }
    // Before any work: no output onto an input or another output. A scene's outputs are
    // known once its objects are, and the files written beside a mesh once it is read.
    let mut files = FilePlan::new();
    files.scene(&input);
    for path in &args.merge {
        files.input(path, "a checkpoint --merge adds");
    }
    output::plan_resume(&mut files, &args.run);
    let new_directories = OutputRules { new_directories: true, ..OutputRules::default() };
    if texture.is_some() && is_map(&args.output) {
        files.output_with(&args.output, "-o", new_directories)?;
        if args.bent_normals {
            files.output_with(
                &sibling(&args.output, "_bent_normals.png"),
                "the bent normals map beside -o",
                new_directories,
            )?;
        }
    } else if !is_scene {
        let replacing = args.overwrite.then_some(input.as_path());
        files.output_with(&args.output, "-o", OutputRules { replacing, ..new_directories })?;
    }
    output::plan_run(&mut files, &args.run)?;
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
    let limits = ReadLimits::from_env()?;
    let mut scene = args.scene.load()?;
    args.sampling.apply(&mut scene)?;
    if scene.mesh_objects.is_empty() {
        bail!("{}: the scene has no mesh objects to bake", input.display());
    }
    if let Some(options) = texture.as_mut() {
        options.seed = scene.settings.seed;
    }
    let targets = match texture {
        None => targets(&mut files, &scene.mesh_objects, is_scene, &args.output, args.overwrite, &limits)?,
        Some(_) => {
            if scene.mesh_objects.len() > 1 {
                bail!(
                    "{}: the scene has {} mesh objects: a texture bake takes a scene with one (the others may be spheres, planes…)",
                    input.display(),
                    scene.mesh_objects.len()
                );
            }
            let object = scene.mesh_objects[0].clone();
            let asset: Arc<dyn Asset> = Arc::from(read_object(&object, &limits)?);
            vec![Target { object, asset, output: args.output.clone() }]
        }
    };
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
    // Generated texture coordinates, when the texture bake needs them.
    let (generated, generated_report) = match texture.as_mut() {
        Some(options) => match generated_uvs(&args, &input, &*targets[0].asset, options)? {
            Some((g, report)) => (Some(g), Some(report)),
            None => (None, None),
        },
        None => (None, None),
    };
    let with_uvs: Option<Vec<AssetMesh>> = generated.as_ref().map(|g| {
        let mut meshes = targets[0].asset.meshes().to_vec();
        for (m, uvs) in meshes.iter_mut().zip(&g.meshes) {
            m.uv_sets.push(uvs.uv_set());
        }
        meshes
    });
    let meshes: Vec<(&AssetMesh, Placement)> = targets
        .iter()
        .flat_map(|t| {
            let meshes = with_uvs.as_deref().unwrap_or(t.asset.meshes());
            meshes.iter().map(|m| (m, Placement::of(&t.object)))
        })
        .collect();
    // A texture bake too large for one block of points is traced a block at a time.
    let mut blocked: Option<(TextureLayout, Vec<Range<usize>>)> = None;
    let (plan, texture_plan) = match &texture {
        None => (BakePlan::new(meshes.iter().copied(), at), None),
        Some(options) => {
            let in_input = |e: aorender::Error| {
                anyhow!("{}: {}", input.display(), e.to_string().trim_start_matches("invalid settings: "))
            };
            let memory = memory::budget_bytes()?;
            let layout = TextureLayout::new(&meshes, options, memory).map_err(in_input)?;
            if layout.targets.len() > 1 && is_map(&args.output) {
                bail!(
                    "{}: its meshes use {} materials, each baked into its own texture: bake into a .glb or .gltf file",
                    input.display(),
                    layout.targets.len()
                );
            }
            let blocks = texture_blocks(&args, &input, &layout, options, memory)?;
            if blocks.len() <= 1 {
                (BakePlan::default(), Some(layout.plan(&meshes, 0..layout.covered_texels(), 0)))
            } else {
                blocked = Some((layout, blocks));
                (BakePlan::default(), None)
            }
        }
    };
    let probes: &[Probe] = texture_plan.as_ref().map_or(&plan.probes, |t| &t.probes);
    let load_seconds = load_start.elapsed().as_secs_f64();
    if probes.is_empty() && blocked.is_none() {
        match &texture_plan {
            Some(_) => bail!("{}: no triangle covers a texel with a usable normal: nothing to bake", input.display()),
            None => bail!("{}: no {} has a usable normal: nothing to bake", input.display(), singular(at)),
        }
    }
    let texture_targets: Vec<TextureTarget> = match (&texture_plan, &blocked) {
        (Some(tp), _) => tp.targets.clone(),
        (None, Some((layout, _))) => layout.targets.clone(),
        _ => Vec::new(),
    };
    if texture.is_some() && !is_map(&args.output) {
        let written = TextureFiles {
            maps: texture_targets.len(),
            bent_normals: args.bent_normals,
            generated_uvs: generated.is_some(),
        };
        let t = &targets[0];
        plan_companions(&mut files, &t.object, &*t.asset, (&t.output, "-o"), is_scene, Some(&written))?;
    }
    let settings = scene.settings.clone();
    let bvh = args.scene.bvh();
    let kind = args.scene.device.kind();
    let range = args.run.sample_range.clone().unwrap_or(0..args.samples);
    let expected =
        || Accumulation::probes(&scene, probes, args.samples, range.clone(), &settings, args.bent_normals, kind, &bvh);

    // The values: from the shards' sums, or traced.
    let mut stats = BakeStats {
        input: input.clone(),
        outputs: targets.iter().map(|t| t.output.clone()).collect(),
        at: at.name(),
        meshes: match texture {
            Some(_) => texture_targets.iter().map(|t| t.meshes.len()).sum(),
            None => plan.mesh_count(),
        },
        points: texture_plan.as_ref().map_or(plan.entry_count(), TexturePlan::covered_texels),
        points_traced: probes.len(),
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
        phases: Phases { load_seconds, ..Phases::default() },
        duplicates_dropped: 0,
        setup_seconds: 0.0,
        adapter: String::new(),
        hemisphere: settings.hemisphere.name(),
        sky: settings.sky.describe(),
        sampler: settings.sampler.name(),
        seed: settings.seed,
        max_distance: settings.max_distance,
        mean_ao: 0.0,
        triangles: 0,
        host_peak_bytes: 0,
        host_peak_bytes_per_triangle: None,
        host_peak_bytes_per_point: None,
        heap_peak_bytes: None,
        texture: None,
    };
    if let (Some((layout, blocks)), Some(options)) = (&blocked, &texture) {
        let traced = trace_blocks(&args, scene, (layout, blocks), &meshes, &stop, &mut stats)?;
        let mut maps = traced.maps;
        for map in &mut maps {
            map.pad(options.padding);
        }
        let counts = TexelCounts {
            overlapping: traced.overlapping_texels,
            skipped: layout.skipped_triangles,
            wrapped: layout.wrapped_triangles,
        };
        stats.points = maps.iter().map(|m| m.coverage.iter().filter(|c| **c == Coverage::Covered).count()).sum();
        let written = (&targets[0], generated.as_ref(), generated_report);
        return write_texture_bake(
            &args,
            options,
            &texture_targets,
            maps,
            counts,
            written,
            stats,
            checkpoint_path.as_deref(),
        );
    }
    let film = if args.merge.is_empty() {
        let resume = match &args.run.resume {
            Some(path) => {
                let saved = Accumulation::read_with(path, &limits)?;
                saved.check_resume(&expected()?)?;
                Some(saved)
            }
            None => None,
        };
        let acc = trace(&args, scene, probes, resume, checkpoint_path.as_deref(), &stop, &mut stats)?;
        let start = Instant::now();
        let film = acc.film()?;
        stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();
        film
    } else {
        let start = Instant::now();
        let shards = read_shards(&args.merge, &limits)?;
        stats.phases.load_seconds += start.elapsed().as_secs_f64();
        stats.triangles = scene.world_triangle_count();
        let this = expected()?;
        let diff = shards[0].1.settings.differences(&this.settings);
        if !diff.is_empty() {
            bail!(
                "{}: holds samples of another bake: {} (checkpoint's value first)",
                shards[0].0.display(),
                diff.join("; ")
            );
        }
        let start = Instant::now();
        let merged = merge(&shards)?;
        stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();
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
    let start = Instant::now();
    let values = probe_film_values(&film);
    let bent = probe_film_bent_normals(&film);
    let traced = values.len().max(1) as f64;
    stats.mean_ao = values.iter().map(|v| v.mean).sum::<f64>() / traced;
    stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();
    if let (Some(tp), Some(options)) = (&texture_plan, &texture) {
        let maps = tp.textures(&values, bent.as_deref(), options.padding);
        let counts = TexelCounts {
            overlapping: tp.overlapping_texels,
            skipped: tp.skipped_triangles,
            wrapped: tp.wrapped_triangles,
        };
        let written = (&targets[0], generated.as_ref(), generated_report);
        return write_texture_bake(
            &args,
            options,
            &texture_targets,
            maps,
            counts,
            written,
            stats,
            checkpoint_path.as_deref(),
        );
    }
    let start = Instant::now();
    let baked = plan.values(&values, bent.as_deref());
    stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();

    // Written back, file by file (each atomically).
    let writing = Instant::now();
    let options = WriteOptions { at, std_error: args.std_error, colors: args.colors };
    let mut baked = baked.into_iter();
    for t in &targets {
        let values: Vec<_> = baked.by_ref().take(t.asset.meshes().len()).collect();
        if let Some(dir) = t.output.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
        }
        for note in t.asset.write(&t.output, &values, &options)? {
            crate::say!("note: {}: {note}", t.output.display());
        }
    }
    stats.phases.write_seconds += writing.elapsed().as_secs_f64();
    stats.end();
    let json = serde_json::to_string_pretty(&stats)?;
    if let Some(path) = &args.run.stats {
        write_json(path, &json)?;
    }
    let written: Vec<String> = targets.iter().map(|t| t.output.display().to_string()).collect();
    crate::say!(
        "{}: {} {} × {} samples in {:.2} s ({:.1} M AO rays/s) on {}; mean AO {:.4}; {}",
        written.join(", "),
        stats.points,
        plural(at),
        stats.samples_per_point,
        stats.render_seconds,
        stats.rays_per_second / 1e6,
        stats.adapter,
        stats.mean_ao,
        stats.phases.line()
    );
    if plan.unusable > 0 {
        crate::say!(
            "note: {} {} without a usable normal (unreferenced, or only degenerate faces) got AO {UNUSABLE_VALUE}",
            plan.unusable,
            plural(at)
        );
    }
    output::print(&format!("{json}\n"))?;
    finish(&stats, &written, checkpoint_path.as_deref())
}

/// What a texture bake counted while placing its points.
struct TexelCounts {
    overlapping: usize,
    skipped: usize,
    wrapped: usize,
}

/// Writes a texture bake's `maps` (one per target, padded) as `-o` asks: the map alone, or
/// the mesh (`target`'s asset, with `generated` coordinates) referencing them; then the
/// statistics and the summary line.
#[allow(clippy::too_many_arguments)]
fn write_texture_bake(
    args: &BakeArgs,
    options: &TextureOptions,
    targets: &[TextureTarget],
    maps: Vec<BakedTexture>,
    counts: TexelCounts,
    (target, generated, generated_report): (&Target, Option<&GeneratedUvs>, Option<GeneratedReport>),
    mut stats: BakeStats,
    checkpoint_path: Option<&Path>,
) -> Result<()> {
    let report = TextureReport {
        width: options.width,
        height: options.height,
        uv_set: options.uv_set,
        textures: maps.len(),
        points_per_texel: options.points,
        samples_per_texel: u64::from(options.points) * u64::from(stats.samples_per_point),
        padding: options.padding,
        bit_depth: args.bit_depth,
        overlapping_texels: counts.overlapping,
        skipped_triangles: counts.skipped,
        wrapped_triangles: counts.wrapped,
        generated_uvs: generated_report,
        maps: maps.iter().map(|m| m.stats()).collect(),
    };
    let writing = Instant::now();
    let mut written = vec![args.output.clone()];
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    }
    if is_map(&args.output) {
        let map = &maps[0];
        let bytes = if is_exr(&args.output) { map.ao_exr()? } else { map.ao_png(args.bit_depth)? };
        let bent = map.bent_png(args.bit_depth).transpose()?;
        if let Some(png) = bent {
            let path = sibling(&args.output, "_bent_normals.png");
            write_output(&path, &png)?;
            written.push(path);
        }
        write_output(&args.output, &bytes)?;
    } else {
        let mut encoded = Vec::with_capacity(maps.len());
        for (map, t) in maps.iter().zip(targets) {
            encoded.push(TextureMap {
                material: t.material,
                meshes: t.meshes.clone(),
                uv_set: options.uv_set,
                png: map.ao_png(args.bit_depth)?,
                bent_png: map.bent_png(args.bit_depth).transpose()?,
                repeat: options.wrap == UvWrap::Repeat || counts.wrapped > 0,
            });
        }
        for note in target.asset.write_textures(&args.output, &encoded, generated)? {
            crate::say!("note: {}: {note}", args.output.display());
        }
        if format_of(&args.output) != Some("glTF") {
            written.push(map_path(&args.output, "ao"));
            if args.bent_normals {
                written.push(map_path(&args.output, "bent_normals"));
            }
        }
    }
    stats.phases.write_seconds += writing.elapsed().as_secs_f64();
    let covered: usize = report.maps.iter().map(|m| m.covered_texels).sum();
    let rms = (report.maps.iter().map(|m| m.rms_std_error.powi(2) * m.covered_texels as f64).sum::<f64>()
        / covered.max(1) as f64)
        .sqrt();
    stats.mean_ao =
        report.maps.iter().map(|m| m.mean_ao * m.covered_texels as f64).sum::<f64>() / covered.max(1) as f64;
    stats.outputs = written.clone();
    stats.end();
    let written: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
    crate::say!(
        "{}: {}×{} texture, {} texels × {} points × {} samples in {:.2} s ({:.1} M AO rays/s) on {}; mean AO {:.4}, RMS standard error {:.4}; {}",
        written.join(", "),
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
    if counts.overlapping > 0 {
        crate::say!(
            "note: {} texels are covered by overlapping charts (mirrored or stacked UVs): each holds the mean over the surfaces mapped to it",
            counts.overlapping
        );
    }
    if counts.skipped > 0 {
        crate::say!(
            "note: {} triangles without texture coordinates at a corner or of zero area in UV space were not baked",
            counts.skipped
        );
    }
    stats.texture = Some(report);
    let json = serde_json::to_string_pretty(&stats)?;
    if let Some(path) = &args.run.stats {
        write_json(path, &json)?;
    }
    output::print(&format!("{json}\n"))?;
    finish(&stats, &written, checkpoint_path)
}

/// The most bytes of points a texture bake traces at once, when nothing needs all its
/// points in one film: a larger bake is traced a block of texels at a time, so that its
/// memory is its textures' and one block's whatever its size.
const BLOCK_BYTES: u64 = 1 << 30;

/// The blocks of covered texels a texture bake traces one after another: one when its
/// points fit [`BLOCK_BYTES`] (and `memory`); several otherwise, unless a time limit,
/// checkpoints, a sample range or a merge needs every point in one film, when the bake
/// must fit `memory` whole. Refused, with the figures, when it cannot fit.
fn texture_blocks(
    args: &BakeArgs,
    input: &Path,
    layout: &TextureLayout,
    options: &TextureOptions,
    memory: u64,
) -> Result<Vec<Range<usize>>> {
    let per_point = bytes_per_point(args.bent_normals);
    let points = layout.nominal_points();
    let room = memory.saturating_sub(layout.bytes);
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    if points > u64::from(u32::MAX) {
        // A point's sample sequence is numbered by a 32-bit index.
        bail!(
            "{}: a {}×{} texture with {} points per texel has {points} points, more than the 2³² a bake numbers, and would need {:.2} GiB traced at once: choose a smaller --texture or fewer --texel-points",
            input.display(),
            options.width,
            options.height,
            options.points,
            gib(layout.bytes + points * per_point)
        );
    }
    let whole = args.run.time_limit.is_some()
        || args.run.checkpoint.is_some()
        || args.run.resume.is_some()
        || args.run.sample_range.is_some()
        || !args.merge.is_empty();
    if whole {
        if points * per_point > room {
            bail!(
                "{}: a {}×{} texture with {} points per texel needs {:.2} GiB for its textures and {points} points, more than the {:.2} GiB of memory available; with a time limit, checkpoints, a sample range or a merge every point is traced at once: choose a smaller --texture or fewer --texel-points, or leave those out to trace in blocks",
                input.display(),
                options.width,
                options.height,
                options.points,
                gib(layout.bytes + points * per_point),
                gib(memory)
            );
        }
        return Ok(std::iter::once(0..layout.covered_texels()).collect());
    }
    let block = room.min(BLOCK_BYTES) / per_point;
    if block < u64::from(options.points) {
        bail!(
            "{}: a {}×{} texture needs {:.2} GiB for its textures and the points of a texel, more than the {:.2} GiB of memory available: choose a smaller --texture or fewer --texel-points",
            input.display(),
            options.width,
            options.height,
            gib(layout.bytes + u64::from(options.points) * per_point),
            gib(memory)
        );
    }
    Ok(layout.blocks(block))
}

/// What [`trace_blocks`] made.
struct Traced {
    /// The textures, their covered texels baked (not padded).
    maps: Vec<BakedTexture>,
    overlapping_texels: usize,
}

/// Traces a texture bake one block of texels after another on one session (the BVH built
/// once), each block's points taking the sample sequences they have in the whole bake, and
/// writes each block's texels into the textures before placing the next block's points.
/// A signal ends the bake after the current pass, writing nothing.
fn trace_blocks(
    args: &BakeArgs,
    scene: aorender::Scene,
    (layout, blocks): (&TextureLayout, &[Range<usize>]),
    meshes: &[(&AssetMesh, Placement)],
    stop: &AtomicBool,
    stats: &mut BakeStats,
) -> Result<Traced> {
    let settings = scene.settings.clone();
    stats.triangles = scene.world_triangle_count();
    let opening = Instant::now();
    let device = Device::open(args.scene.device.kind(), args.scene.adapter.as_deref())?;
    stats.phases.adapter_seconds = opening.elapsed().as_secs_f64();
    let session = Session::new(&device, scene, &args.scene.bvh())?;
    let mut maps = layout.blank_textures(args.bent_normals);
    let (mut first, mut overlapping_texels, mut traced) = (0u32, 0, 0);
    let bar = signals::PassProgress::new(args.samples * blocks.len() as u32, "samples");
    let (mut rays, mut seconds) = (0u64, 0.0f64);
    for (b, block) in blocks.iter().enumerate() {
        let plan = layout.plan(meshes, block.clone(), first);
        if plan.probes.is_empty() {
            continue;
        }
        let done = b as u32 * args.samples;
        let mut on_progress = |p: &Progress| {
            bar.update(&Progress {
                samples_done: done + p.samples_done,
                samples_total: args.samples * blocks.len() as u32,
                rays: rays + p.rays,
                elapsed: seconds + p.elapsed,
            })
        };
        let mut control = Control { stop: Some(stop), progress: Some(&mut on_progress), ..Control::default() };
        let mut render =
            session.probe_render_from(&plan.probes, first, args.samples, None, &settings, args.bent_normals)?;
        render.run(&mut control)?;
        let out = render.finish()?;
        if out.stats.interrupted {
            bar.finish();
            let signal = signals::stop_signal();
            crate::say!(
                "aorender: interrupted by {} in block {} of {}; nothing was written",
                signals::signal_name(signal),
                b + 1,
                blocks.len()
            );
            std::process::exit(128 + signal);
        }
        let acc = &out.accumulation;
        (rays, seconds) = (rays + acc.ao_rays, seconds + acc.render_seconds);
        stats.phases.bvh_build_seconds = out.stats.bvh_build_seconds;
        stats.setup_seconds += out.stats.setup_seconds;
        stats.adapter = out.stats.adapter.clone();
        stats.phases.add_render(&out.stats);
        // The session's upload is once, not once a block.
        stats.phases.upload_seconds = out.stats.upload_seconds;
        let start = Instant::now();
        let values = probe_film_values(&out.film);
        let bent = probe_film_bent_normals(&out.film);
        drop(out);
        plan.fill(&mut maps, &values, bent.as_deref());
        stats.phases.host_stats_seconds += start.elapsed().as_secs_f64();
        overlapping_texels += plan.overlapping_texels;
        traced += plan.probes.len();
        first += plan.probes.len() as u32;
    }
    bar.finish();
    if traced == 0 {
        bail!("{}: no triangle covers a texel with a usable normal: nothing to bake", stats.input.display());
    }
    stats.samples_per_point = args.samples;
    stats.points_traced = traced;
    stats.ao_rays = rays;
    stats.render_seconds = seconds;
    stats.rays_per_second = rays as f64 / seconds.max(1e-9);
    Ok(Traced { maps, overlapping_texels })
}

/// Exits as `render` does after an interrupted bake; notes a time limit.
fn finish(stats: &BakeStats, written: &[String], checkpoint_path: Option<&Path>) -> Result<()> {
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
        if let Some(path) = checkpoint_path {
            message += &format!("; continue with --resume {}", path.display());
        }
        crate::say!("aorender: {message}");
        output::flush()?;
        std::process::exit(128 + signal);
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

/// Traces the plan's probes on the device: the accumulation when the samples asked for
/// are done, the time limit is reached or a signal stops it (then `stats.interrupted`).
fn trace(
    args: &BakeArgs,
    scene: aorender::Scene,
    probes: &[Probe],
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
    stats.triangles = scene.world_triangle_count();
    let mut adapter_seconds = 0.0;
    let out = (|| {
        let opening = Instant::now();
        let device = Device::open(args.scene.device.kind(), args.scene.adapter.as_deref())?;
        adapter_seconds = opening.elapsed().as_secs_f64();
        let session = Session::new(&device, scene, &args.scene.bvh())?;
        let mut render =
            session.probe_render(probes, args.samples, args.run.sample_range.clone(), &settings, args.bent_normals)?;
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
        crate::say!(
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
    stats.phases.adapter_seconds = adapter_seconds;
    stats.phases.bvh_build_seconds = out.stats.bvh_build_seconds;
    stats.phases.add_render(&out.stats);
    stats.duplicates_dropped = out.stats.duplicates_dropped;
    stats.setup_seconds = out.stats.setup_seconds;
    stats.adapter = out.stats.adapter.clone();
    Ok(acc)
}

/// The files to bake: for a mesh input, its one object into `output`; for a scene file,
/// each mesh object into the directory `output`, under its file's name (with the object's
/// number added when the file is placed by several objects). Each file is read once;
/// the outputs are entered in `plan`.
fn targets(
    plan: &mut FilePlan,
    objects: &[MeshObject],
    is_scene: bool,
    output: &Path,
    overwrite: bool,
    limits: &ReadLimits,
) -> Result<Vec<Target>> {
    let mut assets: Vec<(PathBuf, Arc<dyn Asset>)> = Vec::new();
    let mut targets = Vec::with_capacity(objects.len());
    for object in objects {
        let asset = match assets.iter().find(|(p, _)| *p == object.path) {
            Some((_, a)) => a.clone(),
            None => {
                let a: Arc<dyn Asset> = Arc::from(read_object(object, limits)?);
                assets.push((object.path.clone(), a.clone()));
                a
            }
        };
        let out = output_path(objects, object, is_scene, output);
        check_output(&object.path, &out, overwrite)?;
        if is_scene {
            plan_output(plan, object, &out, is_scene, overwrite, "-o")?;
        }
        plan_companions(plan, object, &*asset, (&out, "-o"), is_scene, None)?;
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

/// Whether `path` names a texture map file (`.png` or `.exr`) rather than a mesh.
fn is_map(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) || is_exr(path)
}

fn is_exr(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr"))
}

/// `path` with its extension replaced by `suffix` (`map.png` → `map_bent_normals.png`).
fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    path.with_file_name(format!("{stem}{suffix}"))
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

/// Unwraps the asset's meshes when `--generate-uvs` asks for it (auto: when no mesh has
/// any texture coordinates) and points `options` at the new set; checked before any ray.
fn generated_uvs(
    args: &BakeArgs,
    input: &Path,
    asset: &dyn Asset,
    options: &mut TextureOptions,
) -> Result<Option<(GeneratedUvs, GeneratedReport)>> {
    let meshes = asset.meshes();
    let any = meshes.iter().any(|m| !m.uv_sets.is_empty());
    let generate = match args.generate_uvs {
        GenerateArg::Never => false,
        GenerateArg::Auto => !any,
        GenerateArg::Always => true,
    };
    if !generate {
        if !meshes.iter().any(|m| m.uv_set(options.uv_set).is_some()) {
            let never = if args.generate_uvs == GenerateArg::Never && !any { " (--generate-uvs never)" } else { "" };
            bail!("{}{never}", no_uv_message(input, &meshes.iter().collect::<Vec<_>>(), options.uv_set));
        }
        return Ok(None);
    }
    let gltf = format_of(&args.output) == Some("glTF");
    if any && !gltf {
        bail!(
            "{}: the mesh has texture coordinates, and {} files hold one set: bake into them (--generate-uvs auto), or convert the mesh to glTF",
            input.display(),
            format_of(input).unwrap_or("these")
        );
    }
    if is_map(&args.output) {
        bail!(
            "{}: the mesh has no texture coordinates, and a map alone would lose the generated ones: write the mesh (-o NAME.{}) to get both, or --generate-uvs never",
            args.output.display(),
            input.extension().and_then(|e| e.to_str()).unwrap_or("glb")
        );
    }
    // A new set after the file's own (glTF numbers them from 0 without gaps).
    let set = meshes.iter().flat_map(|m| m.uv_sets.iter().map(|s| s.set + 1)).max().unwrap_or(0);
    let start = std::time::Instant::now();
    let generated = generate_uvs(meshes, set, options)
        .map_err(|e| anyhow!("{}: {}", input.display(), e.to_string().trim_start_matches("invalid settings: ")))?;
    let report = GeneratedReport {
        set,
        charts: generated.charts,
        atlases: generated.atlases,
        utilization: generated.utilization,
        seconds: start.elapsed().as_secs_f64(),
    };
    options.uv_set = set;
    Ok(Some((generated, report)))
}

/// Why nothing can be baked into a texture: no mesh has the set.
fn no_uv_message(input: &Path, meshes: &[&aorender::bake::AssetMesh], set: u32) -> String {
    let mut sets: Vec<u32> = meshes.iter().flat_map(|m| m.uv_sets.iter().map(|s| s.set)).collect();
    sets.sort_unstable();
    sets.dedup();
    let others = if sets.is_empty() {
        "it has none".to_string()
    } else {
        format!(
            "it has set{} {}",
            if sets.len() == 1 { "" } else { "s" },
            sets.iter().map(u32::to_string).collect::<Vec<_>>().join(", ")
        )
    };
    let hint = if sets.is_empty() {
        "generate them (--generate-uvs auto), or unwrap the mesh first"
    } else {
        "choose one with --uv-set, or generate a new set (--generate-uvs always)"
    };
    format!("{}: no mesh has texture coordinates of set {set} ({others}): {hint}", input.display())
}

fn parse_bit_depth(text: &str) -> Result<u8, String> {
    match text {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(format!("'{text}': a PNG map has 8 or 16 bits per channel")),
    }
}
