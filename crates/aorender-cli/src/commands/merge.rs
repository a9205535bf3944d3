//! `aorender merge`: the accumulations of disjoint sample ranges of one render (the
//! checkpoints of its shards) combined into its image.

use crate::args::{check_output_extension, read_shards, write_json};
use crate::output;
use anyhow::Result;
use aorender::output::{FilePlan, IMAGE_EXTENSIONS, write_image};
use aorender::{MergedShard, ReadLimits, merge};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct MergeArgs {
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

/// What `aorender merge` reports.
#[derive(serde::Serialize)]
struct MergeStats {
    samples_per_pixel: u32,
    first_sample: u32,
    width: u32,
    height: u32,
    image_mean: f64,
    same_as_single_run: bool,
    shards: Vec<MergedShard>,
}

pub fn run(args: MergeArgs) -> Result<()> {
    check_output_extension(&args.output, &IMAGE_EXTENSIONS)?;
    let mut plan = FilePlan::new();
    for path in &args.inputs {
        plan.input(path, "a checkpoint to merge");
    }
    plan.output(&args.output, "-o")?;
    if let Some(path) = &args.stats {
        plan.output(path, "--stats")?;
    }
    let shards = read_shards(&args.inputs, &ReadLimits::from_env()?)?;
    let merged = merge(&shards)?;
    write_image(&merged.film, &args.output)?;
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
        write_json(path, &json)?;
    }
    crate::say!(
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
        crate::say!(
            "note: the shards come from different adapters, or a shard boundary cuts a replicate of the error \
             estimate (whose square is then in neither shard): the merge is not bit for bit a single render's"
        );
    }
    output::print(&format!("{json}\n"))?;
    Ok(())
}
