//! The `aorender` command: render, compare sample counts and samplers, probe points,
//! check closed forms, merge shards, benchmark, list adapters. The command line,
//! progress bars, signals and printing live here; the engine is the `aorender` library.

use anyhow::{Result, bail};
use aorender_cli::commands::{accuracy, bake, compare, merge, probe, render};
use aorender_cli::{bench, memory, output};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "aorender", version, about = "GPU ambient-occlusion renderer")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene file (.toml) or a bare mesh (.obj, .ply, .gltf, .glb, each optionally
    /// .gz); the built-in aobench scene by default.
    Render(render::RenderArgs),
    /// Render a grid of sample counts (columns) by hemispheres and samplers (rows) into one labelled PNG.
    Compare(compare::CompareArgs),
    /// AO at points and normals read from a file (x y z nx ny nz per line), written as CSV.
    Probe(probe::ProbeArgs),
    /// Bake AO into a mesh file's vertices, faces or texture (PLY, OBJ, glTF/GLB), or into
    /// every mesh object of a scene file.
    Bake(bake::BakeArgs),
    /// Run the closed-form accuracy suite on the CPU reference and the adapter and write its
    /// table as Markdown (docs/accuracy.md).
    Accuracy(accuracy::AccuracyArgs),
    /// Combine the accumulations (checkpoint files) of disjoint sample ranges of one render
    /// into its image.
    Merge(merge::MergeArgs),
    /// Measure convergence, speed and scaling of every sampler on real scenes, GPU and CPU.
    Bench(bench::BenchArgs),
    /// List the adapters wgpu finds.
    Adapters,
}

/// Counts aorender's heap, for the `heap_peak_bytes` statistic.
#[global_allocator]
static HEAP: memory::CountingAlloc = memory::CountingAlloc;

fn main() {
    aorender_cli::phases::start_clock();
    // A panic inside wgpu that the library turns into an error is reported as that error.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !aorender::catching_panics() {
            default_hook(info);
        }
    }));
    let result = run();
    memory::write_test_heap_peak();
    if let Err(e) = result {
        aorender_cli::say!("aorender: {e:#}");
        std::process::exit(1);
    }
}

/// Parses the command line; usage errors are reported in one line (exit 2).
fn parse() -> Cli {
    match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if e.use_stderr() => {
            let text = e.to_string();
            let mut lines = text.lines();
            let first = lines.next().unwrap_or("invalid arguments");
            let mut first = first.strip_prefix("error: ").unwrap_or(first).to_string();
            if first.ends_with(':') {
                // A list follows (the missing arguments): on the same line.
                let items: Vec<&str> = lines.take_while(|l| l.starts_with(' ')).map(str::trim).collect();
                first = format!("{first} {}", items.join(", "));
            }
            aorender_cli::say!("aorender: {first} (see aorender --help)");
            std::process::exit(2);
        }
        // --help and --version
        Err(e) => e.exit(),
    }
}

fn run() -> Result<()> {
    match parse().command {
        Command::Adapters => {
            let adapters = aorender::list_adapters();
            if adapters.is_empty() {
                bail!("no adapters found: install a Vulkan driver (mesa-vulkan-drivers on Debian/Ubuntu)");
            }
            let lines: String = adapters
                .iter()
                .map(|a| format!("{}\t{}\t{}\t{}\n", a.name, a.backend, a.device_type, a.driver))
                .collect();
            output::print(&lines)
        }
        Command::Render(args) => render::run(args),
        Command::Compare(args) => compare::command(args),
        Command::Probe(args) => probe::run(args),
        Command::Bake(args) => bake::run(args),
        Command::Accuracy(args) => accuracy::run(args),
        Command::Merge(args) => merge::run(args),
        Command::Bench(args) => bench::command(args),
    }
}
