//! `aorender probe`: AO at points and normals read from a text file, written as CSV.

use crate::args::{SamplingArgs, SceneArgs, check_output_extension};
use anyhow::{Result, anyhow, bail};
use aorender::output::write_atomically;
use aorender::scene::read_text;
use aorender::{Control, ErrorTarget, Probe, ProbeValue, ReadLimits, Sampler, Session};
use glam::Vec3;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct ProbeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Probe points: one `x y z nx ny nz` per line (spaces or commas; `#` comments).
    #[arg(long)]
    points: PathBuf,
    /// Output CSV (x,y,z,nx,ny,nz,ao,std_error,samples); `-` for standard output.
    #[arg(short, long, default_value = "-")]
    output: PathBuf,
    /// Samples per probe; with --target-error, the most to take.
    #[arg(long, default_value_t = 4096)]
    samples: u32,
    /// Stop once every point's standard error is at most E (checked after every
    /// replicate, from eight replicates on).
    #[arg(long, value_name = "E")]
    target_error: Option<f64>,
    #[command(flatten)]
    sampling: SamplingArgs,
}

pub fn run(args: ProbeArgs) -> Result<()> {
    let mut scene = args.scene.load()?;
    args.sampling.apply(&mut scene)?;
    if args.samples == 0 {
        bail!("invalid option: --samples must be at least 1");
    }
    let to_stdout = args.output.as_os_str() == "-";
    if !to_stdout {
        check_output_extension(&args.output, &["csv"])?;
    }
    let probes = read_probes(&args.points, &args.scene.load_options()?.limits)?;
    let target = args.target_error.map(ErrorTarget::PointStdError);
    if target.is_some() && args.sampling.replicate.is_none() {
        scene.settings.replicate = Some(scene.settings.sampler.replicate_for(args.samples.min(256), 16));
    }
    let settings = scene.settings.clone();
    let session = Session::new(&args.scene.device()?, scene, &args.scene.bvh())?;
    let mut control = Control { target, ..Control::default() };
    let out = session.probe_with(&probes, args.samples, &settings, &mut control).map_err(|e| match e {
        aorender::Error::Settings { .. } => anyhow!("invalid option: {}", e.message()),
        e => e.into(),
    })?;
    let csv = to_csv(&probes, &out.values);
    if to_stdout {
        print!("{csv}");
    } else {
        write_atomically(&args.output, csv.as_bytes())?;
    }
    let samples = out.values.first().map_or(0, |v| v.samples);
    eprintln!(
        "{} probes × {samples} samples in {:.2} s ({:.1} M AO rays/s) on {}",
        probes.len(),
        out.seconds,
        out.rays as f64 / out.seconds.max(1e-9) / 1e6,
        out.adapter
    );
    if matches!(settings.sampler, Sampler::Sobol | Sampler::Stratified)
        && settings.sampler.replicate_samples(settings.replicate) == 0
    {
        eprintln!(
            "note: std_error is the spread of single samples, which overestimates the error of {} points: \
             --replicate N gives a valid one",
            settings.sampler.name()
        );
    }
    if let Some(e) = args.target_error {
        let most = out.values.iter().map(|v| v.std_error).fold(0.0, f64::max);
        let met = if most <= e { "met" } else { "not met" };
        eprintln!("error target {e} {met}: the largest standard error is {most:.3e} after {samples} samples");
    }
    Ok(())
}

/// Bytes of memory a probe file takes per byte of its text, with its probes: a line of
/// 12 bytes (`0 0 0 0 0 1`) becomes a 28-byte probe, in a vector that grows by doubling.
const PROBE_TEXT_BYTES_PER_BYTE: u64 = 8;

/// Reads probes from a text file within `limits`: one per line, `x y z nx ny nz`
/// (whitespace or commas), `#` starts a comment. Errors name the file and line.
pub fn read_probes(path: &Path, limits: &ReadLimits) -> Result<Vec<Probe>> {
    let text = read_text(path, limits, PROBE_TEXT_BYTES_PER_BYTE, "the probe file")?;
    parse_probes(&text).map_err(|m| anyhow!("{}: {m}", path.display()))
}

/// Parses the text of a probe file.
pub fn parse_probes(text: &str) -> std::result::Result<Vec<Probe>, String> {
    let mut probes = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        let fields: Vec<&str> = line.split(|c: char| c.is_whitespace() || c == ',').filter(|f| !f.is_empty()).collect();
        if fields.is_empty() {
            continue;
        }
        let at = |m: String| format!("line {}: {m}", i + 1);
        if fields.len() != 6 {
            return Err(at(format!("expected 6 numbers (x y z nx ny nz), found {}", fields.len())));
        }
        let mut v = [0f32; 6];
        for (k, f) in fields.iter().enumerate() {
            v[k] = f.parse().map_err(|_| at(format!("'{f}' is not a number")))?;
        }
        let probe =
            Probe::new(Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5])).map_err(|e| at(e.message()))?;
        probes.push(probe);
    }
    if probes.is_empty() {
        return Err("no probes".into());
    }
    Ok(probes)
}

/// The probe values as CSV: `x,y,z,nx,ny,nz,ao,std_error,samples`.
pub fn to_csv(probes: &[Probe], values: &[ProbeValue]) -> String {
    let mut out = String::from("x,y,z,nx,ny,nz,ao,std_error,samples\n");
    for (p, v) in probes.iter().zip(values) {
        let (a, n) = (p.position, p.normal);
        out += &format!("{},{},{},{},{},{},{},{},{}\n", a.x, a.y, a.z, n.x, n.y, n.z, v.mean, v.std_error, v.samples);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_probe_lines() {
        let p = parse_probes("# header\n1 2 3 0 0 2\n\n4,5,6, 0,-1,0 # trailing\n").unwrap();
        assert_eq!(p.len(), 2);
        assert_eq!(p[0].position, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(p[0].normal, Vec3::Z);
        assert_eq!(p[1].normal, -Vec3::Y);
    }

    #[test]
    fn rejects_bad_probe_lines() {
        for (text, expect) in [
            ("1 2 3 0 0", "line 1: expected 6 numbers"),
            ("1 2 3 0 0 1\n1 2 x 0 0 1", "line 2: 'x' is not a number"),
            ("1 2 3 0 0 0", "line 1: zero normal"),
            ("1 2 nan 0 0 1", "line 1: non-finite"),
            ("1 2 3 0 0 inf", "line 1: non-finite"),
            ("# nothing\n", "no probes"),
        ] {
            let e = parse_probes(text).unwrap_err();
            assert!(e.contains(expect), "{text:?}: {e}");
        }
    }
}
