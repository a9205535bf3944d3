//! `aorender accuracy`: the closed-form suite (`aorender::closed_form`) on the CPU
//! reference and the adapter, tabulated as Markdown (`docs/accuracy.md`).

use crate::args::check_output_extension;
use anyhow::{Result, bail};
use aorender::closed_form::{Variant, agrees, cases, configurations};
use aorender::output::{FilePlan, write_output};
use aorender::{Device, DeviceKind, Hemisphere, ProbeValue, Sampler};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct AccuracyArgs {
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

pub fn run(args: AccuracyArgs) -> Result<()> {
    if args.samples.is_empty() || args.samples.contains(&0) {
        bail!("--samples: every count must be at least 1");
    }
    check_output_extension(&args.output, &["md"])?;
    FilePlan::new().output(&args.output, "-o")?;
    let mut devices = Vec::new();
    if !args.no_cpu {
        devices.push(Device::cpu());
    }
    if !args.no_gpu {
        devices.push(Device::gpu(args.adapter.as_deref())?);
    }
    if devices.is_empty() {
        bail!("--no-cpu and --no-gpu leave nothing to run");
    }
    let runs = report_runs(args.samples.len()) * devices.len();
    let bar = indicatif::ProgressBar::new(runs as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} probe runs  {msg}  eta {eta}")
            .expect("a valid template"),
    );
    let mut reports = Vec::new();
    for device in &devices {
        bar.set_message(format!("{:?}", device.kind()));
        reports.push(report(device, &args.samples, &mut || bar.inc(1))?);
    }
    bar.finish_and_clear();
    let counts = args.samples.iter().map(u32::to_string).collect::<Vec<_>>().join(",");
    let command = format!("aorender accuracy --samples {counts}");
    let md = markdown(&reports, &args.samples, &command);
    write_output(&args.output, md.as_bytes())?;
    for r in &reports {
        let pass = r.rows.iter().filter(|row| row.pass()).count();
        crate::say!("{}: {pass} of {} points pass", r.adapter, r.rows.len());
    }
    Ok(())
}

/// The configuration of the table's rows.
pub const TABLE_CONFIGURATION: (Hemisphere, Sampler) = (Hemisphere::Cosine, Sampler::Independent);

/// One point of one case in one variant, estimated at each of the table's sample counts.
#[derive(Clone, Debug)]
pub struct TableRow {
    /// The case.
    pub case: String,
    /// The variant's name.
    pub variant: String,
    /// Index of the point in the case.
    pub point: usize,
    /// The exact value.
    pub expected: f64,
    /// The estimates, one per sample count.
    pub estimates: Vec<ProbeValue>,
}

impl TableRow {
    /// Whether every estimate agrees with the exact value. A small count's own standard
    /// error can be 0 by chance (a hundred samples of a point that sees 1.6% of the sky
    /// all miss a fifth of the time), so each estimate is judged with the larger of its own
    /// and σ/√n, σ from the largest count.
    pub fn pass(&self) -> bool {
        let sigma =
            self.estimates.iter().max_by_key(|e| e.samples).map_or(0.0, |e| e.std_error * (e.samples as f64).sqrt());
        self.estimates.iter().all(|e| {
            let se = e.std_error.max(sigma / (e.samples as f64).sqrt());
            agrees(&ProbeValue { std_error: se, ..*e }, self.expected)
        })
    }
}

/// One hemisphere and sampler over every case of the base variant.
#[derive(Clone, Debug)]
pub struct ConfigurationRow {
    /// Hemisphere.
    pub hemisphere: Hemisphere,
    /// Point sampler.
    pub sampler: Sampler,
    /// Estimates made.
    pub estimates: usize,
    /// Estimates that agree.
    pub agreeing: usize,
    /// Largest |mean − exact| / standard error (0 where both are 0).
    pub largest_z: f64,
}

/// The accuracy table of one device.
#[derive(Clone, Debug)]
pub struct DeviceReport {
    /// Adapter name, or "cpu".
    pub adapter: String,
    /// Every point of every case in every variant, with [`TABLE_CONFIGURATION`].
    pub rows: Vec<TableRow>,
    /// Every configuration over the base variant's cases at the largest count.
    pub configurations: Vec<ConfigurationRow>,
}

/// Number of probe runs [`report`] makes for `counts` sample counts (for progress bars).
pub fn report_runs(counts: usize) -> usize {
    let per_variant = cases(&Variant::BASE).len();
    Variant::all().len() * per_variant * counts + configurations().len() * per_variant
}

/// Runs the whole suite on one device; `tick` is called after each probe run.
pub fn report(device: &Device, counts: &[u32], tick: &mut dyn FnMut()) -> Result<DeviceReport> {
    let mut rows = Vec::new();
    for (vi, v) in Variant::all().iter().enumerate() {
        for (ci, case) in cases(v).iter().enumerate() {
            let session = case.session(device)?;
            let mut per_count = Vec::new();
            for (k, &n) in counts.iter().enumerate() {
                let seed = (vi * 1000 + ci * 10 + k) as u32;
                per_count.push(case.estimate(&session, TABLE_CONFIGURATION, seed, n)?);
                tick();
            }
            for (point, &expected) in case.expected.iter().enumerate() {
                rows.push(TableRow {
                    case: case.name.clone(),
                    variant: v.name(),
                    point,
                    expected,
                    estimates: per_count.iter().map(|values| values[point]).collect(),
                });
            }
        }
    }
    let n = counts.iter().copied().max().unwrap_or(1);
    let base = cases(&Variant::BASE);
    let sessions = base.iter().map(|case| case.session(device)).collect::<aorender::Result<Vec<_>>>()?;
    let mut configs = Vec::new();
    for (k, config) in configurations().into_iter().enumerate() {
        let mut row =
            ConfigurationRow { hemisphere: config.0, sampler: config.1, estimates: 0, agreeing: 0, largest_z: 0.0 };
        for (ci, (case, session)) in base.iter().zip(&sessions).enumerate() {
            let values = case.estimate(session, config, (50_000 + ci * 10 + k) as u32, n)?;
            tick();
            for (value, &expected) in values.iter().zip(&case.expected) {
                row.estimates += 1;
                row.agreeing += agrees(value, expected) as usize;
                let error = (value.mean - expected).abs();
                let z = if error == 0.0 { 0.0 } else { error / value.std_error };
                row.largest_z = row.largest_z.max(z);
            }
        }
        configs.push(row);
    }
    let adapter = match device.kind() {
        DeviceKind::Gpu => device.info().name,
        DeviceKind::Cpu => "cpu (obvhs CWBVH reference)".into(),
    };
    Ok(DeviceReport { adapter, rows, configurations: configs })
}

fn count_label(n: u32) -> String {
    let e = (n as f64).log10();
    if e.fract() == 0.0 && n >= 100 {
        let sup = ["⁰", "¹", "²", "³", "⁴", "⁵", "⁶", "⁷", "⁸", "⁹"];
        format!("10{}", e.to_string().chars().map(|c| sup[c.to_digit(10).unwrap() as usize]).collect::<String>())
    } else {
        n.to_string()
    }
}

/// The reports as Markdown (`docs/accuracy.md`).
pub fn markdown(reports: &[DeviceReport], counts: &[u32], command: &str) -> String {
    let labels: Vec<String> = counts.iter().map(|&n| count_label(n)).collect();
    let last = labels.last().cloned().unwrap_or_default();
    let mut md = String::new();
    md += "# Accuracy at the extremes\n\n";
    md += &format!("Generated by `{command}`; the cases are defined in `crates/aorender/src/closed_form.rs`.\n\n");
    md += "Each row is one point of a scene whose ambient occlusion has a closed form (albedo 1): \
           the exact value and the estimate with ";
    md += &labels.join(", ");
    md += &format!(
        " samples (cosine-weighted hemisphere, independent sampler), and the standard error at {last}. \
         A row passes when every estimate is within 4 standard errors of the exact value (plus 4 f32 \
         ulps, for estimates whose samples are all equal and whose standard error is 0); a count's \
         standard error is the larger of its own and σ/√n, with σ from the largest count, because a \
         hundred samples of a rarely occluded point can all agree by chance. Variants: \
         ×s scales the case about the origin, +1e6 translates it by 10⁶ along each axis, and ±x/y/z \
         is the axis the surface normal points along.\n\n"
    );
    for r in reports {
        let pass = r.rows.iter().filter(|row| row.pass()).count();
        md += &format!("## {}\n\n{pass} of {} points pass.\n\n", r.adapter, r.rows.len());
        md += "| hemisphere | sampler | estimates | within 4 SE | largest |z| |\n|---|---|---|---|---|\n";
        for c in &r.configurations {
            md += &format!(
                "| {} | {} | {} | {} | {:.2} |\n",
                c.hemisphere.name(),
                c.sampler.name(),
                c.estimates,
                c.agreeing,
                c.largest_z
            );
        }
        md += &format!("\n(Every case of the ×1 +y variant at {last} samples.)\n\n");
        md += "| case | variant | point | expected |";
        for l in &labels {
            md += &format!(" {l} |");
        }
        md += &format!(" SE at {last} | pass |\n|---|---|---|---|");
        md += &"---|".repeat(labels.len() + 2);
        md += "\n";
        for row in &r.rows {
            md += &format!("| {} | {} | {} | {:.6} |", row.case, row.variant, row.point, row.expected);
            for e in &row.estimates {
                md += &format!(" {:.6} |", e.mean);
            }
            let se = row.estimates.last().map_or(0.0, |e| e.std_error);
            md += &format!(" {se:.1e} | {} |\n", if row.pass() { "pass" } else { "**FAIL**" });
        }
        md += "\n";
    }
    md
}
