//! Command-line values shared by the `aorender` commands: the scene and device options,
//! the image size, the value parsers and output checks.

use anyhow::{Result, bail};
use aorender::bake::{ReadInputs, load_for_bake};
use aorender::{
    Accumulation, BuildQuality, BvhLayout, BvhOptions, Device, DeviceKind, GeometryStorage, Hemisphere, LoadOptions,
    ReadLimits, Sampler, Scene, SkyModel, SkyNormalise, SkySampling, Traversal,
};
use clap::ValueEnum;
use clap::builder::TypedValueParser as _;
use glam::Vec3;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The mesh formats the loaders read, as every command's help names them.
#[macro_export]
macro_rules! mesh_formats {
    () => {
        "Wavefront OBJ (.obj), Stanford PLY (.ply, ASCII or binary), glTF 2.0 (.gltf with its \
         buffers, or .glb), each optionally gzipped (.gz)"
    };
}

/// Samples per replicate of a run with an error target, unless --replicate says (or
/// fewer, to make 16 replicates of the samples asked for): the target is checked after
/// every replicate.
pub const TARGET_REPLICATE: u32 = 16;
/// Replicates a run with an error target makes of its samples at least.
pub const TARGET_REPLICATES: u32 = 16;

/// The replicate size of a render or probe run of `samples` samples with an error target
/// and no --replicate: at most [`TARGET_REPLICATE`], and at least [`TARGET_REPLICATES`]
/// replicates where `sampler` allows.
pub fn target_replicate(sampler: Sampler, samples: u32) -> u32 {
    sampler.replicate_for(samples.min(TARGET_REPLICATE * TARGET_REPLICATES), TARGET_REPLICATES)
}

/// `--hemisphere` values: the library's names.
pub fn hemisphere_parser() -> impl clap::builder::TypedValueParser<Value = Hemisphere> {
    clap::builder::PossibleValuesParser::new(Hemisphere::ALL.map(Hemisphere::name))
        .map(|name: String| Hemisphere::from_name(&name).expect("a listed name"))
}

/// `--sampler` values: the library's names.
pub fn sampler_parser() -> impl clap::builder::TypedValueParser<Value = Sampler> {
    clap::builder::PossibleValuesParser::new(Sampler::ALL.map(Sampler::name))
        .map(|name: String| Sampler::from_name(&name).expect("a listed name"))
}

/// `--device`.
#[derive(Clone, Copy, ValueEnum)]
pub enum DeviceArg {
    Gpu,
    Cpu,
}

impl DeviceArg {
    /// The library's kind.
    pub fn kind(self) -> DeviceKind {
        match self {
            DeviceArg::Gpu => DeviceKind::Gpu,
            DeviceArg::Cpu => DeviceKind::Cpu,
        }
    }
}

/// `--bvh-quality`.
#[derive(Clone, Copy, ValueEnum)]
pub enum QualityArg {
    Fastest,
    Fast,
    Medium,
    Slow,
}

/// `--bvh-layout`.
#[derive(Clone, Copy, ValueEnum)]
pub enum LayoutArg {
    Bvh2,
    Cwbvh,
}

/// `--geometry-storage`.
#[derive(Clone, Copy, ValueEnum)]
pub enum StorageArg {
    /// Textures on a CPU adapter (lavapipe), storage buffers on a GPU.
    Auto,
    Buffers,
    Textures,
}

/// `--traversal`.
#[derive(Clone, Copy, ValueEnum)]
pub enum TraversalArg {
    /// What measured fastest on the adapter's kind, where the scene allows it.
    Auto,
    /// Each lane traces its own rays.
    PerLane,
    /// Eight lanes trace each ray together (subgroups; the cwbvh layout; no instances).
    Cooperative,
}

/// Image size options shared by `render` and `compare`.
#[derive(clap::Args)]
pub struct SizeArgs {
    /// Image width (default: the scene's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height (default: the scene's).
    #[arg(long)]
    pub height: Option<u32>,
}

impl SizeArgs {
    /// The scene's settings with the size options applied.
    pub fn apply(&self, scene: &mut Scene) {
        let s = &mut scene.settings;
        if let Some(w) = self.width {
            s.width = w;
        }
        if let Some(h) = self.height {
            s.height = h;
        }
    }
}

/// The scene and how to trace it: options shared by `render`, `compare` and `probe`.
#[derive(clap::Args)]
pub struct SceneArgs {
    /// Scene file (.toml) or mesh ([`crate::mesh_formats!`]). Default: the built-in aobench scene.
    #[arg(help = concat!("Scene file (.toml) or mesh: ", mesh_formats!(), ". Default: the built-in aobench scene"))]
    pub scene: Option<PathBuf>,
    /// AO rays longer than this are unoccluded (default: the scene's, else unlimited).
    #[arg(long, allow_negative_numbers = true)]
    pub max_distance: Option<f32>,
    /// Random seed (default: the scene's, else 0).
    #[arg(long)]
    pub seed: Option<u32>,
    /// GPU (wgpu compute) or the CPU reference renderer.
    #[arg(long, value_enum, default_value = "gpu")]
    pub device: DeviceArg,
    /// Pick the adapter whose name contains this (case-insensitive).
    #[arg(long)]
    pub adapter: Option<String>,
    /// BVH build preset (obvhs).
    #[arg(long, value_enum, default_value = "medium")]
    pub bvh_quality: QualityArg,
    /// BVH node layout the GPU traverses.
    #[arg(long, value_enum, default_value = "cwbvh")]
    pub bvh_layout: LayoutArg,
    /// What holds the BVH and the primitives on the GPU: storage buffers or textures.
    #[arg(long, value_enum, default_value = "auto")]
    pub geometry_storage: StorageArg,
    /// How the GPU kernel's lanes share the rays.
    #[arg(long, value_enum, default_value = "auto")]
    pub traversal: TraversalArg,
    /// Read glTF buffers and images whose URIs lead outside the glTF file's folder
    /// (absolute paths, `..`, symbolic links); refused by default.
    #[arg(long)]
    pub allow_external_uris: bool,
}

impl SceneArgs {
    /// The scene with the distance and seed options applied (not yet validated); the
    /// loaders' warnings are printed.
    pub fn load(&self) -> Result<Scene> {
        let scene = match &self.scene {
            Some(path) => Scene::load_with(path, &self.load_options()?)?,
            None => Scene::default_scene(),
        };
        Ok(self.loaded(scene))
    }

    /// [`SceneArgs::load`] for a bake: each mesh file parsed once, the bake's part of it
    /// kept for [`Bake::with_inputs`](aorender::bake::Bake::with_inputs).
    pub fn load_for_bake(&self) -> Result<(Scene, ReadInputs)> {
        let (scene, read) = match &self.scene {
            Some(path) => load_for_bake(path, &self.load_options()?)?,
            None => (Scene::default_scene(), ReadInputs::default()),
        };
        Ok((self.loaded(scene), read))
    }

    /// `scene` with the distance and seed options applied, its warnings printed.
    fn loaded(&self, mut scene: Scene) -> Scene {
        for w in &scene.warnings {
            crate::say!("aorender: warning: {w}");
        }
        let s = &mut scene.settings;
        if self.max_distance.is_some() {
            s.sampling.max_distance = self.max_distance;
        }
        if let Some(seed) = self.seed {
            s.sampling.seed = seed;
        }
        scene
    }

    /// How input files are read: the read budget ([`ReadLimits::from_env`]) and the URI
    /// option.
    pub fn load_options(&self) -> Result<LoadOptions> {
        Ok(LoadOptions { limits: ReadLimits::from_env()?, allow_external_uris: self.allow_external_uris })
    }

    /// Opens the device the options name.
    pub fn device(&self) -> Result<Device> {
        Ok(Device::open(self.device.kind(), self.adapter.as_deref())?)
    }

    /// How the scene is prepared on the device.
    pub fn bvh(&self) -> BvhOptions {
        BvhOptions {
            quality: match self.bvh_quality {
                QualityArg::Fastest => BuildQuality::Fastest,
                QualityArg::Fast => BuildQuality::Fast,
                QualityArg::Medium => BuildQuality::Medium,
                QualityArg::Slow => BuildQuality::Slow,
            },
            layout: match self.bvh_layout {
                LayoutArg::Bvh2 => BvhLayout::Bvh2,
                LayoutArg::Cwbvh => BvhLayout::Cwbvh,
            },
            geometry_storage: match self.geometry_storage {
                StorageArg::Auto => None,
                StorageArg::Buffers => Some(GeometryStorage::Buffers),
                StorageArg::Textures => Some(GeometryStorage::Textures),
            },
            traversal: match self.traversal {
                TraversalArg::Auto => None,
                TraversalArg::PerLane => Some(Traversal::PerLane),
                TraversalArg::Cooperative => Some(Traversal::Cooperative),
            },
        }
    }
}

/// An invalid setting as the command line reports it: "invalid option: …".
pub fn invalid_option(e: aorender::Error) -> anyhow::Error {
    anyhow::anyhow!("invalid option: {}", e.message())
}

/// Refuses an output path whose extension is not one of `allowed` (lower case, no dot),
/// before any time is spent rendering.
pub fn check_output_extension(path: &Path, allowed: &[&str]) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if allowed.contains(&ext.as_str()) {
        return Ok(());
    }
    let mut expected: Vec<String> = allowed.iter().map(|e| format!(".{e}")).collect();
    let last = expected.pop().unwrap_or_default();
    let expected = if expected.is_empty() { last } else { format!("{} or {last}", expected.join(", ")) };
    bail!("{}: unsupported output format: expected {expected}", path.display());
}

/// Writes `json` and a newline to `path` (under the library's output policy).
pub fn write_json(path: &Path, json: &str) -> Result<()> {
    aorender::output::write_output(path, format!("{json}\n").as_bytes())?;
    Ok(())
}

/// Reads the checkpoints of shards one after the other, their sums (held together for
/// the merge) within `limits`: each is read within what the ones before it left.
pub fn read_shards(paths: &[PathBuf], limits: &ReadLimits) -> Result<Vec<(PathBuf, Accumulation)>> {
    let mut shards = Vec::with_capacity(paths.len());
    let mut held = 0;
    for path in paths {
        let shard = Accumulation::read_with(path, &limits.after(held))?;
        held += shard.memory_bytes();
        shards.push((path.clone(), shard));
    }
    Ok(shards)
}

/// Why the text of an option's value (`--sample-range`, `--up`, `--ground-albedo`,
/// `--bit-depth`) is refused; clap prints it after the option's name.
#[derive(Debug, thiserror::Error)]
pub enum ValueError {
    /// A value not of the option's form (`START..END`, `X,Y,Z`).
    #[error("expected {form}, got '{text}'")]
    Form {
        /// The form expected.
        form: &'static str,
        /// The value given.
        text: String,
    },
    /// A sample range without its start or end.
    #[error("{bound} is missing in '{text}' (expected START..END)")]
    MissingBound {
        /// `START` or `END`.
        bound: &'static str,
        /// The value given.
        text: String,
    },
    /// A bound of a sample range that is no sample index.
    #[error("{bound} '{word}' in '{text}' is not a sample index: {source}")]
    SampleIndex {
        /// `START` or `END`.
        bound: &'static str,
        /// The bound as given.
        word: String,
        /// The value given.
        text: String,
        /// Why it does not parse.
        source: std::num::ParseIntError,
    },
    /// A sample range with no samples.
    #[error("'{0}' is empty: START must be below END")]
    EmptyRange(String),
    /// A component of a vector that is no number.
    #[error("'{word}' in '{text}' is not a number: {source}")]
    Component {
        /// The component as given.
        word: String,
        /// The value given.
        text: String,
        /// Why it does not parse.
        source: std::num::ParseFloatError,
    },
    /// A vector that is zero or not finite.
    #[error("'{0}' must be finite and non-zero")]
    ZeroVector(String),
    /// A value that is no number.
    #[error("'{text}' is not a number: {source}")]
    Number {
        /// The value given.
        text: String,
        /// Why it does not parse.
        source: std::num::ParseFloatError,
    },
    /// A number outside [0, 1].
    #[error("{0} is outside [0, 1]")]
    OutsideUnit(String),
    /// A PNG bit depth other than 8 or 16.
    #[error("'{0}': a PNG map has 8 or 16 bits per channel")]
    BitDepth(String),
}

/// `--sample-range START..END`: a non-empty range of sample indices.
pub fn parse_sample_range(text: &str) -> Result<Range<u32>, ValueError> {
    let (a, b) = text.split_once("..").ok_or_else(|| ValueError::Form { form: "START..END", text: text.into() })?;
    let number = |t: &str, bound: &'static str| match t.trim() {
        "" => Err(ValueError::MissingBound { bound, text: text.into() }),
        t => t.parse::<u32>().map_err(|source| ValueError::SampleIndex {
            bound,
            word: t.into(),
            text: text.into(),
            source,
        }),
    };
    let (a, b) = (number(a, "START")?, number(b, "END")?);
    if a >= b {
        return Err(ValueError::EmptyRange(text.into()));
    }
    Ok(a..b)
}

/// The sampling options of `render`, `probe` and `bake`.
#[derive(clap::Args)]
pub struct SamplingArgs {
    /// AO direction distribution (default: the scene's, else cosine).
    #[arg(long, value_parser = hemisphere_parser())]
    pub hemisphere: Option<Hemisphere>,
    /// How the sample numbers (pixel jitter, hemisphere) are placed (default: the scene's,
    /// else independent).
    #[arg(long, value_parser = sampler_parser())]
    pub sampler: Option<Sampler>,
    /// Samples per independently randomised replicate, from whose spread the error is
    /// estimated: a power of two up to 256 (of four for stratified). For stratified and
    /// Sobol, 0 is one replicate of all samples (the best point set, no error estimate;
    /// the default, or 16 with an error target); independent samples are their own
    /// replicates unless batched (16 with --adaptive). With --resume, the checkpoint's.
    #[arg(long, value_name = "N")]
    pub replicate: Option<u32>,
    /// The sky.
    #[command(flatten)]
    pub sky: SkyArgs,
}

impl SamplingArgs {
    /// The scene's settings with the options applied, the sampling checked.
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        let s = &mut scene.settings.sampling;
        if let Some(h) = self.hemisphere {
            s.hemisphere = h;
        }
        if let Some(p) = self.sampler {
            s.sampler = p;
        }
        if self.replicate.is_some() {
            s.replicate = self.replicate;
        }
        self.sky.apply(scene)
    }
}

/// The sky options of `render`, `probe`, `bake` and `compare`.
#[derive(clap::Args)]
pub struct SkyArgs {
    /// The sky: uniform (classic AO) or overcast (the CIE standard overcast sky, three
    /// times brighter at the zenith than at the horizon) (default: the scene's, else uniform).
    #[arg(long, value_parser = named_parser(SkyModel::ALL.map(SkyModel::name), SkyModel::from_name))]
    pub sky: Option<SkyModel>,
    /// The zenith of the overcast sky, X,Y,Z in the scene's coordinates (default: the
    /// scene's, else 0,1,0, glTF's +Y).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_up, allow_negative_numbers = true)]
    pub up: Option<Vec3>,
    /// Albedo of the ground below the overcast sky's horizon, in [0, 1] (default 0: black).
    #[arg(long, value_parser = parse_ground_albedo, allow_negative_numbers = true)]
    pub ground_albedo: Option<f32>,
    /// How the overcast sky is sampled: horizon (directions ∝ cos θ above the horizon),
    /// control-variate (those, exact where unoccluded) or weighted (--hemisphere's with
    /// the sky as a weight) (default horizon).
    #[arg(long, value_parser = named_parser(SkySampling::ALL.map(SkySampling::name), SkySampling::from_name))]
    pub sky_sampling: Option<SkySampling>,
    /// What the overcast sky's values are divided by: horizontal (an unoccluded upward
    /// surface renders its albedo, sides darker) or surface (every unoccluded point renders
    /// its albedo, as in classic AO) (default horizontal).
    #[arg(long, value_parser = named_parser(SkyNormalise::ALL.map(SkyNormalise::name), SkyNormalise::from_name))]
    pub sky_normalise: Option<SkyNormalise>,
}

impl SkyArgs {
    /// The scene's settings with the sky options applied and the sampling checked: an
    /// overcast sky's option given with the uniform sky is refused, naming it.
    pub fn apply(&self, scene: &mut Scene) -> Result<()> {
        let s = &mut scene.settings.sampling;
        if let Some(m) = self.sky {
            s.sky.model = m;
        }
        if let Some(up) = self.up {
            s.sky.up = up;
        }
        if let Some(a) = self.ground_albedo {
            s.sky.ground_albedo = a;
        }
        if let Some(m) = self.sky_sampling {
            s.sky.sampling = m;
        }
        if let Some(n) = self.sky_normalise {
            s.sky.normalise = n;
        }
        if s.sky.is_uniform() {
            let given = [
                (self.sky_normalise.is_some(), "--sky-normalise"),
                (self.sky_sampling.is_some(), "--sky-sampling"),
                (self.ground_albedo.is_some(), "--ground-albedo"),
            ];
            if let Some((_, name)) = given.into_iter().find(|g| g.0) {
                bail!("invalid option: {name} needs --sky overcast");
            }
        }
        s.validate().map_err(invalid_option)
    }
}

/// A parser of the names `names`, mapped by `from_name`.
pub fn named_parser<T: Clone + Send + Sync + 'static>(
    names: impl IntoIterator<Item = &'static str>,
    from_name: fn(&str) -> Option<T>,
) -> impl clap::builder::TypedValueParser<Value = T> {
    clap::builder::PossibleValuesParser::new(names).map(move |name: String| from_name(&name).expect("a listed name"))
}

/// `--up X,Y,Z`: three finite numbers, not all zero.
pub fn parse_up(text: &str) -> Result<Vec3, ValueError> {
    let parts: Vec<&str> = text.split(',').collect();
    let [x, y, z] = parts[..] else {
        return Err(ValueError::Form { form: "X,Y,Z", text: text.into() });
    };
    let number = |t: &str| {
        t.trim().parse::<f32>().map_err(|source| ValueError::Component { word: t.into(), text: text.into(), source })
    };
    let v = Vec3::new(number(x)?, number(y)?, number(z)?);
    if !v.is_finite() || v == Vec3::ZERO {
        return Err(ValueError::ZeroVector(text.into()));
    }
    Ok(v)
}

/// `--ground-albedo`: a number in [0, 1].
pub fn parse_ground_albedo(text: &str) -> Result<f32, ValueError> {
    let a: f32 = text.trim().parse().map_err(|source| ValueError::Number { text: text.into(), source })?;
    if !(0.0..=1.0).contains(&a) {
        return Err(ValueError::OutsideUnit(text.into()));
    }
    Ok(a)
}

/// `--bit-depth`: 8 or 16 bits per channel of a PNG map.
pub fn parse_bit_depth(text: &str) -> Result<u8, ValueError> {
    match text {
        "8" => Ok(8),
        "16" => Ok(16),
        _ => Err(ValueError::BitDepth(text.into())),
    }
}

/// How a long run is bounded, saved, continued and split: the options of `render` and
/// `bake`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Stop after the pass that passes this many seconds, with the samples done so far.
    #[arg(long, allow_negative_numbers = true)]
    pub time_limit: Option<f64>,
    /// Write the statistics as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Save the raw accumulation to this file every --checkpoint-interval seconds and at
    /// exit (atomically); an existing file is refused unless it is the one --resume names.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Continue the accumulation saved in this checkpoint (and keep saving to it unless
    /// --checkpoint names another file).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Seconds between checkpoints (stretched so that saving takes at most a tenth of the time).
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    pub checkpoint_interval: f64,
    /// Take only the sample indices START..END of all the samples: a shard, combined by
    /// `aorender merge` (images) or `bake --merge` (needs --checkpoint).
    #[arg(long, value_name = "START..END", value_parser = parse_sample_range)]
    pub sample_range: Option<Range<u32>>,
}

impl RunArgs {
    /// Checks the options before any work, `samples` being the samples per pixel (or
    /// point) asked for; returns the file to save checkpoints to, if any.
    pub fn check(&self, samples: u32, per: &str) -> Result<Option<PathBuf>> {
        if let Some(t) = self.time_limit
            && (t.is_nan() || t <= 0.0)
        {
            bail!("invalid option: --time-limit must be positive, got {t}");
        }
        let interval = self.checkpoint_interval;
        if !(interval.is_finite() && interval > 0.0) {
            bail!("invalid option: --checkpoint-interval must be positive, got {interval}");
        }
        if let Some(r) = &self.sample_range
            && r.end > samples
        {
            bail!("invalid option: --sample-range {}..{} ends past the {samples} samples per {per}", r.start, r.end);
        }
        let checkpoint = self.checkpoint.clone().or_else(|| self.resume.clone());
        if self.sample_range.is_some() && checkpoint.is_none() {
            bail!("invalid option: --sample-range needs --checkpoint FILE, the shard's accumulation to combine");
        }
        // A FIFO or a device is written into, not continued: only a file is a checkpoint.
        if let Some(path) = &self.checkpoint
            && !self.resume.as_ref().is_some_and(|r| aorender::output::same_file(r, path))
            && std::fs::metadata(path).is_ok_and(|m| m.is_file())
        {
            bail!(
                "{}: a checkpoint already exists: continue it with --resume {}, or remove it",
                path.display(),
                path.display()
            );
        }
        Ok(checkpoint)
    }
}
