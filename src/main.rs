//! The `aorender` command: render, compare sample counts and samplers, list adapters.

use anyhow::{Context, Result, bail};
use aorender::args::{hemisphere_parser, sampler_parser};
use aorender::bvh::{BuildQuality, BvhLayout};
use aorender::checkpoint::{self, Accumulation};
use aorender::compare::{self, CompareProgress};
use aorender::render::{Checkpointing, render_resumable};
use aorender::shaders::GeometryStorage;
use aorender::{Device, Hemisphere, Progress, RenderOptions, Sampler, Scene};
use clap::{Parser, Subcommand, ValueEnum};
use std::io::{IsTerminal, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

#[derive(Parser)]
#[command(name = "aorender", version, about = "GPU ambient-occlusion renderer")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene file (.toml) or a bare mesh (.obj); the built-in aobench scene by default.
    Render(RenderArgs),
    /// Render a grid of sample counts (columns) by hemispheres and samplers (rows) into one labelled PNG.
    Compare(CompareArgs),
    /// AO at points and normals read from a file (x y z nx ny nz per line), written as CSV.
    Probe(ProbeArgs),
    /// Run the closed-form accuracy suite on the CPU reference and the adapter and write its
    /// table as Markdown (docs/accuracy.md).
    Accuracy(AccuracyArgs),
    /// Combine the accumulations (checkpoint files) of disjoint sample ranges of one render
    /// into its image.
    Merge(MergeArgs),
    /// Measure convergence, speed and scaling of every sampler on real scenes, GPU and CPU.
    Bench(aorender::bench::BenchArgs),
    /// List the adapters wgpu finds.
    Adapters,
}

#[derive(clap::Args)]
struct MergeArgs {
    /// Checkpoint files of the shards (`render --sample-range START..END --checkpoint FILE`).
    #[arg(required = true)]
    inputs: Vec<PathBuf>,
    /// Output image: .png (8-bit sRGB), .exr or .pfm (32-bit float, linear).
    #[arg(short, long)]
    output: PathBuf,
    /// Write the merge's statistics as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
}

#[derive(clap::Args)]
struct AccuracyArgs {
    /// Output Markdown file.
    #[arg(short, long, default_value = "docs/accuracy.md")]
    output: PathBuf,
    /// Samples per point, comma-separated: one column each.
    #[arg(long, value_delimiter = ',', default_value = "100,10000,1000000")]
    samples: Vec<u32>,
    /// Skip the CPU reference.
    #[arg(long)]
    no_cpu: bool,
    /// Skip the adapter.
    #[arg(long)]
    no_gpu: bool,
    /// Substring of the adapter's name to use.
    #[arg(long)]
    adapter: Option<String>,
}

#[derive(Clone, Copy, ValueEnum)]
enum DeviceArg {
    Gpu,
    Cpu,
}

#[derive(Clone, Copy, ValueEnum)]
enum QualityArg {
    Fastest,
    Fast,
    Medium,
    Slow,
}

#[derive(Clone, Copy, ValueEnum)]
enum LayoutArg {
    Bvh2,
    Cwbvh,
}

#[derive(Clone, Copy, ValueEnum)]
enum StorageArg {
    /// Textures on a CPU adapter (lavapipe), storage buffers on a GPU.
    Auto,
    Buffers,
    Textures,
}

/// Image size options shared by `render` and `compare`.
#[derive(clap::Args)]
struct SizeArgs {
    /// Image width (default: the scene's).
    #[arg(long)]
    width: Option<u32>,
    /// Image height (default: the scene's).
    #[arg(long)]
    height: Option<u32>,
}

impl SizeArgs {
    fn apply(&self, scene: &mut Scene) {
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
struct SceneArgs {
    /// Scene file (.toml) or mesh (.obj). Default: the built-in aobench scene.
    scene: Option<PathBuf>,
    /// AO rays longer than this are unoccluded (default: the scene's, else unlimited).
    #[arg(long, allow_negative_numbers = true)]
    max_distance: Option<f32>,
    /// Random seed (default: the scene's, else 0).
    #[arg(long)]
    seed: Option<u32>,
    /// GPU (wgpu compute) or the CPU reference renderer.
    #[arg(long, value_enum, default_value = "gpu")]
    device: DeviceArg,
    /// Pick the adapter whose name contains this (case-insensitive).
    #[arg(long)]
    adapter: Option<String>,
    /// BVH build preset (obvhs).
    #[arg(long, value_enum, default_value = "medium")]
    bvh_quality: QualityArg,
    /// BVH node layout the GPU traverses.
    #[arg(long, value_enum, default_value = "cwbvh")]
    bvh_layout: LayoutArg,
    /// What holds the BVH and the primitives on the GPU: storage buffers or textures.
    #[arg(long, value_enum, default_value = "auto")]
    geometry_storage: StorageArg,
}

impl SceneArgs {
    /// The scene with the distance and seed options applied (not yet validated).
    fn load(&self) -> Result<Scene> {
        let mut scene = match &self.scene {
            Some(path) => Scene::load(path)?,
            None => Scene::default_scene(),
        };
        let s = &mut scene.settings;
        if self.max_distance.is_some() {
            s.max_distance = self.max_distance;
        }
        if let Some(seed) = self.seed {
            s.seed = seed;
        }
        Ok(scene)
    }

    /// The device and BVH options.
    fn options(&self, time_limit: Option<f64>) -> RenderOptions {
        RenderOptions {
            device: match self.device {
                DeviceArg::Gpu => Device::Gpu,
                DeviceArg::Cpu => Device::Cpu,
            },
            adapter: self.adapter.clone(),
            time_limit,
            bvh_quality: match self.bvh_quality {
                QualityArg::Fastest => BuildQuality::Fastest,
                QualityArg::Fast => BuildQuality::Fast,
                QualityArg::Medium => BuildQuality::Medium,
                QualityArg::Slow => BuildQuality::Slow,
            },
            bvh_layout: match self.bvh_layout {
                LayoutArg::Bvh2 => BvhLayout::Bvh2,
                LayoutArg::Cwbvh => BvhLayout::Cwbvh,
            },
            geometry_storage: match self.geometry_storage {
                StorageArg::Auto => None,
                StorageArg::Buffers => Some(GeometryStorage::Buffers),
                StorageArg::Textures => Some(GeometryStorage::Textures),
            },
            sample_range: None,
            stop: None,
        }
    }
}

/// Refuses an output path whose extension is not one of `allowed` (lower case, no dot),
/// before any time is spent rendering.
fn check_output_extension(path: &Path, allowed: &[&str]) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if allowed.contains(&ext.as_str()) {
        return Ok(());
    }
    let mut expected: Vec<String> = allowed.iter().map(|e| format!(".{e}")).collect();
    let last = expected.pop().unwrap_or_default();
    let expected = if expected.is_empty() { last } else { format!("{} or {last}", expected.join(", ")) };
    bail!("{}: unsupported output format: expected {expected}", path.display());
}

#[derive(clap::Args)]
struct RenderArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    size: SizeArgs,
    /// Output image: .png (8-bit sRGB), .exr or .pfm (32-bit float, linear).
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,
    /// Samples per pixel (default: the scene's).
    #[arg(long)]
    spp: Option<u32>,
    /// AO direction distribution (default: the scene's, else cosine).
    #[arg(long, value_parser = hemisphere_parser())]
    hemisphere: Option<Hemisphere>,
    /// Placement of the pixel and hemisphere numbers (default: the scene's, else independent).
    #[arg(long, value_parser = sampler_parser())]
    sampler: Option<Sampler>,
    /// Stop after the pass that passes this many seconds, with the samples done so far.
    #[arg(long, allow_negative_numbers = true)]
    time_limit: Option<f64>,
    /// Write render statistics as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Save the raw accumulation to this file every --checkpoint-interval seconds and at
    /// exit (atomically); an existing file is refused unless it is the one --resume names.
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Continue the accumulation saved in this checkpoint (and keep saving to it unless
    /// --checkpoint names another file).
    #[arg(long)]
    resume: Option<PathBuf>,
    /// Seconds between checkpoints (stretched so that saving takes at most a tenth of the time).
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    checkpoint_interval: f64,
    /// Render only the sample indices START..END of the --spp samples (a shard for
    /// `aorender merge`; needs --checkpoint).
    #[arg(long, value_name = "START..END", value_parser = parse_sample_range)]
    sample_range: Option<Range<u32>>,
}

/// `START..END` with START < END.
fn parse_sample_range(text: &str) -> Result<Range<u32>, String> {
    let (a, b) = text.split_once("..").ok_or_else(|| format!("expected START..END, got '{text}'"))?;
    let number = |t: &str, name: &str| match t.trim() {
        "" => Err(format!("{name} is missing in '{text}' (expected START..END)")),
        t => t.parse::<u32>().map_err(|e| format!("{name} '{t}' in '{text}' is not a sample index: {e}")),
    };
    let (a, b) = (number(a, "START")?, number(b, "END")?);
    if a >= b {
        return Err(format!("'{text}' is empty: START must be below END"));
    }
    Ok(a..b)
}

#[derive(clap::Args)]
struct CompareArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    size: SizeArgs,
    /// Output image (.png).
    #[arg(short, long, default_value = "compare.png")]
    output: PathBuf,
    /// Samples per pixel of the columns, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,4,9,16,256,1024")]
    spp: Vec<u32>,
    /// Hemisphere distributions of the rows, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = hemisphere_parser(), default_value = "uniform,cosine")]
    hemisphere: Vec<Hemisphere>,
    /// Point samplers, comma-separated; each gets one row per hemisphere.
    #[arg(long, value_delimiter = ',', value_parser = sampler_parser(), default_value = "independent")]
    sampler: Vec<Sampler>,
    /// Write the statistics of every cell as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
}

#[derive(clap::Args)]
struct ProbeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Probe points: one `x y z nx ny nz` per line (spaces or commas; `#` comments).
    #[arg(long)]
    points: PathBuf,
    /// Output CSV (x,y,z,nx,ny,nz,ao,std_error,samples); `-` for standard output.
    #[arg(short, long, default_value = "-")]
    output: PathBuf,
    /// Samples per probe.
    #[arg(long, default_value_t = 4096)]
    samples: u32,
    /// AO direction distribution (default: the scene's, else cosine).
    #[arg(long, value_parser = hemisphere_parser())]
    hemisphere: Option<Hemisphere>,
    /// Placement of the hemisphere numbers (default: the scene's, else independent).
    #[arg(long, value_parser = sampler_parser())]
    sampler: Option<Sampler>,
}

/// Counts aorender's heap, for the `heap_peak_bytes` statistic.
#[global_allocator]
static HEAP: aorender::memory::CountingAlloc = aorender::memory::CountingAlloc;

fn main() {
    // A panic inside wgpu that the library turns into an error is reported as that error.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !aorender::gpu::catching_panics() {
            default_hook(info);
        }
    }));
    if let Err(e) = run() {
        eprintln!("aorender: {e:#}");
        std::process::exit(1);
    }
}

/// Parses the command line; usage errors are reported in one line (exit 2).
fn parse() -> Cli {
    match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if e.use_stderr() => {
            let text = e.to_string();
            let first = text.lines().next().unwrap_or("invalid arguments");
            let first = first.strip_prefix("error: ").unwrap_or(first);
            eprintln!("aorender: {first} (see aorender --help)");
            std::process::exit(2);
        }
        // --help and --version
        Err(e) => e.exit(),
    }
}

fn run() -> Result<()> {
    match parse().command {
        Command::Adapters => {
            let adapters = aorender::gpu::list_adapters();
            if adapters.is_empty() {
                bail!("no adapters found: install a Vulkan driver (mesa-vulkan-drivers on Debian/Ubuntu)");
            }
            for a in adapters {
                println!("{}\t{}\t{}\t{}", a.name, a.backend, a.device_type, a.driver);
            }
            Ok(())
        }
        Command::Render(args) => render_command(args),
        Command::Compare(args) => compare_command(args),
        Command::Probe(args) => probe_command(args),
        Command::Accuracy(args) => accuracy_command(args),
        Command::Merge(args) => merge_command(args),
        Command::Bench(args) => aorender::bench::command(args),
    }
}

fn accuracy_command(args: AccuracyArgs) -> Result<()> {
    use aorender::accuracy;
    if args.samples.is_empty() || args.samples.contains(&0) {
        bail!("--samples: every count must be at least 1");
    }
    check_output_extension(&args.output, &["md"])?;
    let mut devices = Vec::new();
    if !args.no_cpu {
        devices.push(Device::Cpu);
    }
    let ctx = if args.no_gpu { None } else { Some(aorender::gpu::GpuContext::new(args.adapter.as_deref())?) };
    if ctx.is_some() {
        devices.push(Device::Gpu);
    }
    if devices.is_empty() {
        bail!("--no-cpu and --no-gpu leave nothing to run");
    }
    let runs = accuracy::report_runs(args.samples.len()) * devices.len();
    let bar = indicatif::ProgressBar::new(runs as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} probe runs  {msg}  eta {eta}")
            .expect("a valid template"),
    );
    let mut reports = Vec::new();
    for device in devices {
        bar.set_message(format!("{device:?}"));
        reports.push(accuracy::report(ctx.as_ref(), device, &args.samples, &mut || bar.inc(1))?);
    }
    bar.finish_and_clear();
    let counts = args.samples.iter().map(u32::to_string).collect::<Vec<_>>().join(",");
    let command = format!("aorender accuracy --samples {counts}");
    let md = accuracy::markdown(&reports, &args.samples, &command);
    aorender::film::write_atomically(&args.output, md.as_bytes())?;
    for r in &reports {
        let pass = r.rows.iter().filter(|row| row.pass()).count();
        eprintln!("{}: {pass} of {} points pass", r.adapter, r.rows.len());
    }
    Ok(())
}

fn probe_command(args: ProbeArgs) -> Result<()> {
    let mut scene = args.scene.load()?;
    let s = &mut scene.settings;
    if let Some(h) = args.hemisphere {
        s.hemisphere = h;
    }
    if let Some(p) = args.sampler {
        s.sampler = p;
    }
    s.validate().map_err(anyhow::Error::msg).context("invalid option")?;
    if args.samples == 0 {
        bail!("invalid option: --samples must be at least 1");
    }
    let to_stdout = args.output.as_os_str() == "-";
    if !to_stdout {
        check_output_extension(&args.output, &["csv"])?;
    }
    let probes = aorender::probe::read_probes(&args.points)?;
    let out = aorender::probe::probe(&scene, &args.scene.options(None), &probes, args.samples)?;
    let csv = aorender::probe::to_csv(&probes, &out.values);
    if to_stdout {
        print!("{csv}");
    } else {
        aorender::film::write_atomically(&args.output, csv.as_bytes())?;
    }
    eprintln!(
        "{} probes × {} samples in {:.2} s ({:.1} M AO rays/s) on {}",
        probes.len(),
        args.samples,
        out.seconds,
        out.rays as f64 / out.seconds.max(1e-9) / 1e6,
        out.adapter
    );
    Ok(())
}

/// The signal that asked the render to stop (0 for none).
static STOP_SIGNAL: AtomicI32 = AtomicI32::new(0);
/// Set when the render's first pass has finished: before that (loading the scene, building
/// the BVH, setting up the device, the first pass) a signal ends the process at once.
static FIRST_PASS_DONE: AtomicBool = AtomicBool::new(false);

/// Name of a signal number.
fn signal_name(signal: i32) -> String {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGINT, SIGTERM};
        match signal {
            SIGINT => return "SIGINT".into(),
            SIGTERM => return "SIGTERM".into(),
            _ => {}
        }
    }
    format!("signal {signal}")
}

/// On SIGINT or SIGTERM, sets `stop`: the render finishes its pass and the outputs are
/// written. A second signal removes the temporary files of writes in progress (their
/// targets are untouched) and exits at once with status 128 + signal. Before the first
/// pass has finished there is nothing to write: a signal exits at once.
#[cfg(unix)]
fn install_signal_handlers(stop: Arc<AtomicBool>) -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]).context("cannot handle signals")?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for signal in signals.forever() {
                if !FIRST_PASS_DONE.load(Ordering::SeqCst) {
                    aorender::film::remove_temporary_files();
                    eprintln!(
                        "aorender: interrupted by {} before the first pass finished (loading the scene, building the \
                         BVH or setting up the device); nothing was written",
                        signal_name(signal)
                    );
                    signal_hook::low_level::exit(128 + signal);
                }
                if STOP_SIGNAL.compare_exchange(0, signal, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                    stop.store(true, Ordering::SeqCst);
                    eprintln!("{}: finishing the current pass (a second signal stops at once)", signal_name(signal));
                } else {
                    aorender::film::remove_temporary_files();
                    eprintln!(
                        "aorender: stopped at once by a second {}; files being written were left as they were",
                        signal_name(signal)
                    );
                    signal_hook::low_level::exit(128 + signal);
                }
            }
        })
        .context("cannot start the signal thread")?;
    Ok(())
}

#[cfg(not(unix))]
fn install_signal_handlers(_stop: Arc<AtomicBool>) -> Result<()> {
    Ok(())
}

/// Fails when no file can be created beside `path` (before any time is spent rendering).
fn check_writable(path: &Path) -> Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path.file_name().with_context(|| format!("{}: not a file path", path.display()))?;
    let probe = dir.join(format!(".{}.{}.probe", name.to_string_lossy(), std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .with_context(|| format!("{}: cannot write beside it", path.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

fn render_command(args: RenderArgs) -> Result<()> {
    // Before loading: a signal while a large scene loads or its BVH builds ends the process.
    let stop = Arc::new(AtomicBool::new(false));
    install_signal_handlers(stop.clone())?;
    let load_start = std::time::Instant::now();
    let mut scene = args.scene.load()?;
    let load_seconds = load_start.elapsed().as_secs_f64();
    args.size.apply(&mut scene);
    let s = &mut scene.settings;
    if let Some(n) = args.spp {
        s.spp = n;
    }
    if let Some(h) = args.hemisphere {
        s.hemisphere = h;
    }
    if let Some(p) = args.sampler {
        s.sampler = p;
    }
    s.validate().map_err(anyhow::Error::msg).context("invalid option")?;
    if let Some(t) = args.time_limit
        && (t.is_nan() || t <= 0.0)
    {
        bail!("invalid option: --time-limit must be positive, got {t}");
    }
    let interval = args.checkpoint_interval;
    if !(interval.is_finite() && interval > 0.0) {
        bail!("invalid option: --checkpoint-interval must be positive, got {interval}");
    }
    if let Some(r) = &args.sample_range
        && r.end > s.spp
    {
        bail!("invalid option: --sample-range {}..{} ends past the {} samples per pixel", r.start, r.end, s.spp);
    }
    check_output_extension(&args.output, &["png", "exr", "pfm"])?;
    let checkpoint_path = args.checkpoint.clone().or_else(|| args.resume.clone());
    if args.sample_range.is_some() && checkpoint_path.is_none() {
        bail!(
            "invalid option: --sample-range needs --checkpoint FILE, the shard's accumulation that `aorender merge` combines"
        );
    }
    if let Some(path) = &args.checkpoint
        && args.resume.as_ref() != Some(path)
        && path.exists()
    {
        bail!(
            "{}: a checkpoint already exists: continue it with --resume {}, or remove it",
            path.display(),
            path.display()
        );
    }
    let resume = match &args.resume {
        Some(path) => Some(Accumulation::read(path)?),
        None => None,
    };
    if let Some(path) = &checkpoint_path {
        check_writable(path)?;
    }
    let resumed_adapter = resume.as_ref().map(|a| a.adapter.clone());
    let mut options = args.scene.options(args.time_limit);
    options.sample_range = args.sample_range.clone();
    options.stop = Some(stop);

    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = indicatif::ProgressBar::new(scene.settings.spp as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} spp  {msg}  eta {eta}")
                .expect("valid template"),
        );
        bar
    });
    let mut on_progress = |p: &Progress| {
        FIRST_PASS_DONE.store(true, Ordering::SeqCst);
        if let Some(bar) = &bar {
            bar.set_length(p.samples_total as u64);
            bar.set_position(p.samples_done as u64);
            bar.set_message(format!("{:.1} M rays/s", p.rays as f64 / p.elapsed.max(1e-9) / 1e6));
        }
    };
    let mut save_to = |acc: &Accumulation| -> aorender::Result<()> {
        match &checkpoint_path {
            Some(path) => acc.write(path),
            None => Ok(()),
        }
    };
    let checkpointing =
        Checkpointing { resume, interval, save: if checkpoint_path.is_some() { Some(&mut save_to) } else { None } };
    let mut out = render_resumable(&scene, &options, checkpointing, &mut on_progress).map_err(|e| {
        // The adapter failed mid-render: the last checkpoint saved before it is whole.
        let adapter_failed = matches!(e, aorender::Error::DeviceLost { .. } | aorender::Error::OutOfMemory { .. });
        match &checkpoint_path {
            Some(path) if adapter_failed && path.exists() => anyhow::anyhow!(
                "{e}; the last checkpoint, {}, is intact: continue with --resume {}",
                path.display(),
                path.display()
            ),
            _ => e.into(),
        }
    })?;
    out.stats.load_seconds = load_seconds;
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let st = &out.stats;
    let signal = STOP_SIGNAL.load(Ordering::SeqCst);
    if st.samples_per_pixel == 0 {
        eprintln!(
            "aorender: interrupted by {} before any sample was rendered; nothing was written",
            signal_name(signal)
        );
        std::process::exit(128 + signal);
    }
    out.film.write_image(&args.output)?;
    let json = serde_json::to_string_pretty(&out.stats)?;
    if let Some(path) = &args.stats {
        aorender::film::write_atomically(path, format!("{json}\n").as_bytes())?;
    }
    eprintln!(
        "{}: {}x{} at {} spp in {:.2} s ({:.1} M rays/s, load {:.2} s, BVH {:.2} s) on {} ({}); mean {:.4}",
        args.output.display(),
        st.width,
        st.height,
        st.samples_per_pixel,
        st.render_seconds,
        st.rays_per_second / 1e6,
        st.load_seconds,
        st.bvh_build_seconds,
        st.adapter,
        st.backend,
        st.image_mean
    );
    if let Some(adapter) = resumed_adapter
        && adapter != st.adapter
    {
        eprintln!(
            "note: the checkpoint was rendered on {adapter} and continued on {}: the sums equal an uninterrupted \
             render's within float rounding, not bit for bit",
            st.adapter
        );
    }
    println!("{json}");
    if st.interrupted {
        let mut written = vec![args.output.display().to_string()];
        written.extend(args.stats.as_ref().map(|p| p.display().to_string()));
        let mut message = format!(
            "interrupted by {} after {} of {} samples per pixel; {} hold them",
            signal_name(signal),
            st.samples_per_pixel,
            st.samples_requested,
            written.join(" and ")
        );
        if let Some(path) = &checkpoint_path {
            message += &format!("; continue with --resume {}", path.display());
        }
        eprintln!("aorender: {message}");
        std::io::stdout().flush()?;
        std::process::exit(128 + signal);
    }
    if st.samples_per_pixel < st.samples_requested {
        eprintln!("time limit reached after {} of {} samples per pixel", st.samples_per_pixel, st.samples_requested);
    }
    Ok(())
}

/// What `aorender merge` reports.
#[derive(serde::Serialize)]
struct MergeStats {
    samples_per_pixel: u32,
    first_sample: u32,
    width: u32,
    height: u32,
    image_mean: f64,
    same_as_single_run: bool,
    shards: Vec<checkpoint::MergedShard>,
}

fn merge_command(args: MergeArgs) -> Result<()> {
    check_output_extension(&args.output, &["png", "exr", "pfm"])?;
    let mut shards = Vec::with_capacity(args.inputs.len());
    for path in &args.inputs {
        shards.push((path.clone(), Accumulation::read(path)?));
    }
    let merged = checkpoint::merge(&shards)?;
    merged.film.write_image(&args.output)?;
    let stats = MergeStats {
        samples_per_pixel: merged.end - merged.first,
        first_sample: merged.first,
        width: merged.film.width,
        height: merged.film.height,
        image_mean: merged.film.image_mean(),
        same_as_single_run: merged.same_as_single_run,
        shards: merged.shards,
    };
    let json = serde_json::to_string_pretty(&stats)?;
    if let Some(path) = &args.stats {
        aorender::film::write_atomically(path, format!("{json}\n").as_bytes())?;
    }
    eprintln!(
        "{}: {}x{}, samples {}..{} from {} shards; mean {:.4}",
        args.output.display(),
        stats.width,
        stats.height,
        merged.first,
        merged.end,
        stats.shards.len(),
        stats.image_mean
    );
    if !stats.same_as_single_run {
        eprintln!(
            "note: a shard boundary is not a multiple of {} samples, a shard was continued past an unaligned end, \
             or the shards come from different adapters: the sums equal a single render's within float rounding, \
             not bit for bit",
            aorender::film::BLOCK_SAMPLES
        );
    }
    println!("{json}");
    Ok(())
}

fn compare_command(args: CompareArgs) -> Result<()> {
    let mut scene = args.scene.load()?;
    args.size.apply(&mut scene);
    compare::validate(&args.spp, &args.hemisphere, &args.sampler)
        .map_err(anyhow::Error::msg)
        .context("invalid option")?;
    scene.settings.spp = args.spp.iter().copied().max().unwrap_or(1);
    scene.settings.validate().map_err(anyhow::Error::msg).context("invalid option")?;
    check_output_extension(&args.output, &["png"])?;
    let options = args.scene.options(None);

    let mut on_progress = |p: &CompareProgress| {
        if p.render.is_none() {
            eprintln!(
                "rendering {}/{} at {} spp ({} of {})",
                p.hemisphere.name(),
                p.sampler.name(),
                p.spp,
                p.cell + 1,
                p.cells
            );
        }
    };
    let grid = compare::run(&scene, &options, &args.spp, &args.hemisphere, &args.sampler, &mut on_progress)?;
    grid.write_png(&args.output)?;
    if let Some(path) = &args.stats {
        let json = serde_json::to_string_pretty(&grid)?;
        aorender::film::write_atomically(path, format!("{json}\n").as_bytes())?;
    }
    println!("{:<12} {:<12} {:>6} {:>8} {:>8}", "sampler", "hemisphere", "spp", "mean", "seconds");
    for c in &grid.cells {
        println!(
            "{:<12} {:<12} {:>6} {:>8.4} {:>8.2}",
            c.sampler.name(),
            c.hemisphere.name(),
            c.spp,
            c.image_mean,
            c.render_seconds
        );
    }
    eprintln!(
        "{}: {} cells of {}x{} in {:.1} s on {} ({})",
        args.output.display(),
        grid.cells.len(),
        grid.width,
        grid.height,
        grid.total_seconds,
        grid.adapter,
        grid.backend
    );
    Ok(())
}
