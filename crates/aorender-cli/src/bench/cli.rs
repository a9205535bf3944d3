//! `aorender bench` on the command line: the options, the built-in scene list, progress on
//! stderr, the files written and the table printed.

use super::{Plan, Progress, Results, ScenePlan, SkyPlan, plot, report};
use crate::args::{hemisphere_parser, named_parser, parse_ground_albedo, parse_up, sampler_parser};
use anyhow::{Context, Result, bail};
use aorender::output::{FilePlan, OutputRules};
use aorender::scene::MAX_IMAGE_SIDE;
use aorender::{Hemisphere, Sampler, Scene, SkyModel, SkyNormalise, SkySampling};
use glam::Vec3;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};

/// Options of `aorender bench`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {
    /// Scene files (.toml) or meshes to measure instead of the built-in list (see
    /// --with-builtin).
    #[arg(help = concat!("Scene files (.toml) or meshes (", crate::mesh_formats!(), ") to measure instead of the built-in list (see --with-builtin)"))]
    pub scenes: Vec<PathBuf>,
    /// Small images and sample counts on three small scenes: a smoke check that finishes
    /// in under a minute on lavapipe.
    #[arg(long)]
    pub quick: bool,
    /// Measure the built-in list as well as the SCENES given.
    #[arg(long)]
    pub with_builtin: bool,
    /// Leave the 7.8-million-triangle scene (scenes/dragons.toml) out of the built-in list.
    #[arg(long)]
    pub no_big: bool,
    /// Directory of the built-in list's scene files.
    #[arg(long, default_value = "scenes")]
    pub scenes_dir: PathBuf,
    /// Directory for results.json, the CSV files and the plots.
    #[arg(short, long, default_value = "target/bench")]
    pub out: PathBuf,
    /// Directory of the cached reference images.
    #[arg(long, default_value = "target/bench-cache")]
    pub cache: PathBuf,
    /// Samples per pixel of the progressive renders, N, for every scene (a power of two;
    /// a power of four gives the stratified sampler full n×n blocks).
    #[arg(long)]
    pub spp: Option<u32>,
    /// Samples per pixel of the references, for every scene (default 64 × N).
    #[arg(long)]
    pub reference_spp: Option<u32>,
    /// The images' longer side for every scene (the scene's aspect ratio gives the other).
    #[arg(long)]
    pub size: Option<u32>,
    /// Hemisphere distributions to measure, comma-separated (default: all).
    #[arg(long, value_delimiter = ',', value_parser = hemisphere_parser())]
    pub hemisphere: Vec<Hemisphere>,
    /// Point samplers to measure, comma-separated (default: all).
    #[arg(long, value_delimiter = ',', value_parser = sampler_parser())]
    pub sampler: Vec<Sampler>,
    /// Seed of the measured renders (the references use another).
    #[arg(long, default_value_t = 0)]
    pub seed: u32,
    /// Skip the CPU reference renderer (the references are then rendered on the GPU).
    #[arg(long)]
    pub no_cpu: bool,
    /// Use the adapter whose name contains this (case-insensitive).
    #[arg(long)]
    pub adapter: Option<String>,
    /// The sky of every scene, as `render --sky` (default: each scene's, else uniform).
    /// Under the overcast sky every --sky-sampling is measured.
    #[arg(long, value_parser = named_parser(SkyModel::ALL.map(SkyModel::name), SkyModel::from_name))]
    pub sky: Option<SkyModel>,
    /// The overcast sky's zenith, X,Y,Z, as `render --up`.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_up, allow_negative_numbers = true)]
    pub up: Option<Vec3>,
    /// Albedo of the ground below the overcast sky's horizon, as `render --ground-albedo`.
    #[arg(long, value_parser = parse_ground_albedo, allow_negative_numbers = true)]
    pub ground_albedo: Option<f32>,
    /// The overcast sky's samplings to measure against each other, comma-separated
    /// (default: horizon, control-variate and, with horizontal normalisation, weighted);
    /// horizon and control-variate once per point sampler, weighted with every hemisphere.
    #[arg(
        long,
        value_delimiter = ',',
        value_parser = named_parser(SkySampling::ALL.map(SkySampling::name), SkySampling::from_name)
    )]
    pub sky_sampling: Vec<SkySampling>,
    /// What the overcast sky's values are divided by, as `render --sky-normalise`.
    #[arg(long, value_parser = named_parser(SkyNormalise::ALL.map(SkyNormalise::name), SkyNormalise::from_name))]
    pub sky_normalise: Option<SkyNormalise>,
}

/// A scene of the built-in list: file (`None` for aobench), the image's longer side, N, and
/// whether the presets and the resolution series run on it.
struct Builtin {
    file: Option<&'static str>,
    size: u32,
    spp: u32,
    presets: bool,
    resolutions: bool,
}

/// The full run's list, smallest first. Sizes and sample counts keep the whole run,
/// references included, within 10 minutes on two cores with lavapipe (the README's
/// results give the time of each part).
const FULL: &[Builtin] = &[
    Builtin { file: None, size: 128, spp: 64, presets: false, resolutions: false },
    Builtin { file: Some("dragon_vrip_res4.ply.gz"), size: 96, spp: 32, presets: false, resolutions: false },
    Builtin { file: Some("dragon_vrip_res3.ply.gz"), size: 96, spp: 32, presets: false, resolutions: true },
    Builtin { file: Some("bunny.obj"), size: 96, spp: 32, presets: true, resolutions: false },
    Builtin { file: Some("dragon_vrip_res2.ply.gz"), size: 96, spp: 32, presets: true, resolutions: false },
    Builtin { file: Some("dragon_vrip.ply.gz"), size: 64, spp: 32, presets: false, resolutions: false },
    Builtin { file: Some(BIG_SCENE), size: 64, spp: 16, presets: false, resolutions: false },
];

/// The 7.8-million-triangle scene, left out by `--no-big`.
const BIG_SCENE: &str = "dragons.toml";

/// `--quick`'s list.
const QUICK: &[Builtin] = &[
    Builtin { file: None, size: 32, spp: 16, presets: false, resolutions: false },
    Builtin { file: Some("dragon_vrip_res4.ply.gz"), size: 32, spp: 16, presets: true, resolutions: true },
    Builtin { file: Some("bunny.obj"), size: 32, spp: 16, presets: false, resolutions: false },
];

/// References take this many times N samples: their own RMSE is then 1/8 of an
/// independent render's at N.
const REFERENCE_FACTOR: u32 = 64;

/// The plan the options describe; scenes named on the command line are loaded here, so a
/// bad one is reported before anything runs.
pub fn plan(args: &BenchArgs, command: String) -> Result<Plan> {
    if let Some(n) = args.spp
        && !n.is_power_of_two()
    {
        bail!("invalid option: --spp must be a power of two, got {n}");
    }
    if let Some(r) = args.reference_spp
        && r < 2
    {
        bail!("invalid option: --reference-spp must be at least 2, got {r}");
    }
    if let Some(s) = args.size
        && !(1..=MAX_IMAGE_SIDE).contains(&s)
    {
        bail!("invalid option: --size must be 1 to {MAX_IMAGE_SIDE}, got {s}");
    }
    let (list, scaling_spp, resolutions) =
        if args.quick { (QUICK, 4, vec![16, 32, 64]) } else { (FULL, 8, vec![64, 128, 256, 512]) };
    let reference_spp = |spp: u32| args.reference_spp.unwrap_or(spp.saturating_mul(REFERENCE_FACTOR));
    let sky = SkyPlan {
        model: args.sky,
        up: args.up,
        ground_albedo: args.ground_albedo,
        normalise: args.sky_normalise,
        samplings: args.sky_sampling.clone(),
    };
    let mut scenes = Vec::new();
    if args.scenes.is_empty() || args.with_builtin {
        for b in list {
            if args.no_big && b.file == Some(BIG_SCENE) {
                continue;
            }
            let path = b.file.map(|f| args.scenes_dir.join(f));
            if let Some(p) = &path
                && !p.is_file()
            {
                bail!(
                    "{}: no such file (the built-in list is read from --scenes-dir, by default `scenes` in the \
                     repository root)",
                    p.display()
                );
            }
            let size = args.size.unwrap_or(b.size);
            let spp = args.spp.unwrap_or(b.spp);
            scenes.push(ScenePlan {
                label: path.as_deref().map_or_else(|| "aobench".into(), scene_label),
                path,
                loaded: None,
                size,
                max_spp: spp,
                reference_spp: reference_spp(spp),
                presets: b.presets,
                resolutions: b.resolutions,
            });
        }
    }
    let first_user = scenes.len();
    for path in &args.scenes {
        let scene = Scene::load(path)?;
        // The sky options on this scene, checked before anything runs.
        sky.apply(&mut scene.clone())?;
        let size = args.size.unwrap_or(if args.quick { 32 } else { 128 });
        let spp = args.spp.unwrap_or(if args.quick { 16 } else { 64 });
        scenes.push(ScenePlan {
            label: scene_label(path),
            path: Some(path.clone()),
            loaded: Some(scene),
            size,
            max_spp: spp,
            reference_spp: reference_spp(spp),
            presets: false,
            resolutions: false,
        });
    }
    // Without the built-in list, the presets and resolutions run on the first scene given.
    if first_user == 0
        && let Some(s) = scenes.first_mut()
    {
        s.presets = true;
        s.resolutions = true;
    }
    if first_user > 0 {
        // The built-in list's scenes have the uniform sky.
        sky.apply(&mut Scene::default_scene())?;
    }
    for s in &scenes {
        if s.reference_spp < s.max_spp {
            bail!("invalid option: --reference-spp {} is below N = {} of {}", s.reference_spp, s.max_spp, s.label);
        }
    }
    Ok(Plan {
        scenes,
        hemispheres: if args.hemisphere.is_empty() { Hemisphere::ALL.to_vec() } else { args.hemisphere.clone() },
        samplers: if args.sampler.is_empty() { Sampler::ALL.to_vec() } else { args.sampler.clone() },
        seed: args.seed,
        sky,
        adapter: args.adapter.clone(),
        cpu: !args.no_cpu,
        cache_dir: args.cache.clone(),
        scaling_spp,
        resolutions,
        command,
        quick: args.quick,
    })
}

/// A scene's name: the file name without `.gz` and the format's extension.
fn scene_label(path: &Path) -> String {
    let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
    let name = name.strip_suffix(".gz").unwrap_or(&name).to_string();
    match name.rsplit_once('.') {
        Some((stem, _)) if !stem.is_empty() => stem.to_string(),
        _ => name,
    }
}

/// The files [`write_outputs`] writes into its directory.
const OUTPUT_FILES: [&str; 8] = [
    "results.json",
    "results.csv",
    "bvh_presets.csv",
    "scaling.csv",
    "convergence_spp.png",
    "convergence_seconds.png",
    "rays_vs_triangles.png",
    "scaling.png",
];

/// Writes the results and plots into `dir` ([`OUTPUT_FILES`]).
pub fn write_outputs(results: &Results, dir: &Path) -> Result<()> {
    let [json, csv, presets, scaling, spp, seconds, rays, scaling_plot] = OUTPUT_FILES.map(|name| dir.join(name));
    let write = |path: &Path, text: String| -> Result<()> {
        aorender::output::write_output(path, text.as_bytes())?;
        Ok(())
    };
    write(&json, format!("{}\n", serde_json::to_string_pretty(results)?))?;
    write(&csv, report::convergence_csv(results))?;
    write(&presets, report::presets_csv(results))?;
    write(&scaling, report::scaling_csv(results))?;
    plot::convergence(results, plot::Axis::Spp, &spp)?;
    plot::convergence(results, plot::Axis::Seconds, &seconds)?;
    plot::rays_vs_triangles(results, &rays)?;
    plot::scaling(results, &scaling_plot)?;
    Ok(())
}

/// Runs `aorender bench`.
pub fn command(args: BenchArgs) -> Result<()> {
    let words: Vec<String> = std::env::args().skip(1).collect();
    // Before any work: no result file onto a scene given, nor onto a directory or a block device.
    let mut files = FilePlan::new();
    for path in &args.scenes {
        files.scene(path);
    }
    for name in OUTPUT_FILES {
        let rules = OutputRules { new_directories: true, ..OutputRules::default() };
        files.output_with(&args.out.join(name), "-o", rules)?;
    }
    let plan = plan(&args, format!("aorender {}", words.join(" ")))?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create the directory", args.out.display()))?;
    std::fs::create_dir_all(&args.cache)
        .with_context(|| format!("{}: cannot create the directory", args.cache.display()))?;

    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new(1);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}%  {elapsed_precise}  eta {eta}  {wide_msg}")
                .expect("a valid template"),
        );
        bar
    });
    let mut last_stage = String::new();
    let mut on_progress = |p: &Progress| {
        match &bar {
            Some(bar) => {
                bar.set_length(p.total.max(1));
                bar.set_position(p.done);
                bar.set_message(p.stage.clone());
            }
            // Without a terminal, one line per stage.
            None if p.stage != last_stage => crate::say!("{}", p.stage),
            None => {}
        }
        last_stage.clone_from(&p.stage);
    };
    let results = super::run(&plan, &mut on_progress)?;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    write_outputs(&results, &args.out)?;
    crate::output::print(&report::table(&results))?;
    crate::say!("results and plots in {}", args.out.display());
    if !results.failures.is_empty() {
        let names: Vec<&str> = results.failures.iter().map(|f| f.scene.as_str()).collect();
        bail!("{} of {} scenes failed: {}", names.len(), plan.scenes.len(), names.join(", "));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_drop_gz_and_the_format() {
        assert_eq!(scene_label(Path::new("scenes/dragon_vrip.ply.gz")), "dragon_vrip");
        assert_eq!(scene_label(Path::new("bunny.obj")), "bunny");
        assert_eq!(scene_label(Path::new("dir/dragons.toml")), "dragons");
    }
}
