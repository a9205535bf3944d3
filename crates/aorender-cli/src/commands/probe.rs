//! `aorender probe`: AO at points and normals read from a text file, written as CSV.

use crate::args::{SamplingArgs, SceneArgs, check_output_extension, write_json};
use crate::phases::{self, Phases};
use crate::{memory, output};
use anyhow::{Result, anyhow, bail};
use aorender::output::{Destination, FilePlan, write_output};
use aorender::scene::read_text;
use aorender::{
    Control, Device, ErrorTarget, Probe, ProbeValue, ReadLimits, Ready, Sampler, Session, SurfaceTolerance,
};
use glam::{DVec3, Vec3};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args)]
pub struct ProbeArgs {
    #[command(flatten)]
    scene: SceneArgs,
    /// Probe points: one `x y z nx ny nz` per line (spaces or commas; `#` comments).
    #[arg(long)]
    points: PathBuf,
    /// Output CSV (x,y,z,nx,ny,nz,ao,std_error,samples); `-` for standard output. A FIFO
    /// or a character device (`/dev/stdout`) is written into whatever its name.
    #[arg(short, long, default_value = "-")]
    output: PathBuf,
    /// Samples per probe; with --target-error, the most to take.
    #[arg(long, default_value_t = 4096)]
    samples: u32,
    /// Stop once every point's standard error is at most E (checked after every
    /// replicate, from eight replicates on).
    #[arg(long, value_name = "E")]
    target_error: Option<f64>,
    /// How far from a surface a point may be and still be taken as on it (scene units);
    /// default: 2^-18 of the largest coordinate of the point and the surface.
    #[arg(long, value_name = "D")]
    surface_tolerance: Option<f32>,
    #[command(flatten)]
    sampling: SamplingArgs,
    /// Write the statistics as JSON.
    #[arg(long, value_name = "FILE")]
    stats: Option<PathBuf>,
}

/// Figures of a probe run (`aorender probe --stats`).
#[derive(serde::Serialize)]
struct ProbeStats {
    points: usize,
    points_off_surface: usize,
    samples_per_point: u64,
    samples_requested: u32,
    target_error: Option<f64>,
    largest_std_error: f64,
    ao_rays: u64,
    render_seconds: f64,
    rays_per_second: f64,
    #[serde(flatten)]
    phases: Phases,
    adapter: String,
    hemisphere: &'static str,
    /// The sky and its sampling.
    sky: String,
    sampler: &'static str,
    seed: u32,
    triangles: usize,
    host_peak_bytes: u64,
    host_peak_bytes_per_triangle: Option<f64>,
    host_peak_bytes_per_point: Option<f64>,
    heap_peak_bytes: Option<u64>,
}

pub fn run(args: ProbeArgs) -> Result<()> {
    let to_stdout = args.output.as_os_str() == "-";
    let mut plan = FilePlan::new();
    output::plan_scene(&mut plan, args.scene.scene.as_deref());
    plan.input(&args.points, "the --points file");
    // A FIFO or a device (`-o /dev/stdout`) takes the CSV whatever its name.
    let stream = !to_stdout && matches!(plan.output(&args.output, "-o")?, Destination::Stream(_));
    if let Some(path) = &args.stats {
        plan.output(path, "--stats")?;
    }
    let mut phases = Phases { start_seconds: phases::process_seconds(), ..Phases::default() };
    let loading = Instant::now();
    // The device opens beside the loading and the BVH build: it needs nothing of the scene.
    let opening = Device::open_beside(args.scene.device.kind(), args.scene.adapter.as_deref(), Ready::Points);
    let mut scene = args.scene.load()?;
    args.sampling.apply(&mut scene)?;
    if args.samples == 0 {
        bail!("invalid option: --samples must be at least 1");
    }
    if !to_stdout && !stream {
        check_output_extension(&args.output, &["csv"])?;
    }
    let tolerance = match args.surface_tolerance {
        None => SurfaceTolerance::Relative,
        Some(d) => SurfaceTolerance::distance(d)
            .map_err(|e| anyhow!("invalid option: --surface-tolerance: {}", e.message()))?,
    };
    let (probes, lines) = read_probes(&args.points, &args.scene.load_options()?.limits, scene.origin)?;
    phases.load_seconds = loading.elapsed().as_secs_f64();
    let target = args.target_error.map(ErrorTarget::PointStdError);
    if target.is_some() && args.sampling.replicate.is_none() {
        scene.settings.sampling.replicate =
            Some(crate::args::target_replicate(scene.settings.sampling.sampler, args.samples));
    }
    let settings = scene.settings.clone();
    let session = Session::beside(opening, scene, &args.scene.bvh(), |_, _| Ok(()))?;
    let device = session.device().clone();
    let setup = session.setup();
    phases.set_opening(setup);
    (phases.bvh_build_seconds, phases.upload_seconds) = (setup.bvh_build_seconds, setup.upload_seconds);
    (phases.scene_seconds, phases.pipeline_cache) = (setup.scene_seconds, setup.pipeline_cache.to_string());
    let mut control = Control { target, ..Control::default() };
    // Placing the points on their surfaces is part of reading them.
    let locating = Instant::now();
    let located = session.locate(&probes, tolerance)?;
    phases.load_seconds += locating.elapsed().as_secs_f64();
    let out = session.probe_with(&located.probes, args.samples, &settings, &mut control).map_err(|e| match e {
        aorender::Error::Settings { .. } => anyhow!("invalid option: {}", e.message()),
        e => e.into(),
    })?;
    phases.pipeline_seconds += out.pipeline_seconds;
    phases.compile_seconds += out.compile_seconds;
    phases.request_seconds = out.request_seconds;
    phases.add_times(&out.times);
    let writing = Instant::now();
    let csv = to_csv(&probes, &out.values, session.scene().origin);
    if to_stdout {
        output::print(&csv)?;
    } else {
        write_output(&args.output, csv.as_bytes())?;
    }
    phases.write_seconds = writing.elapsed().as_secs_f64();
    let samples = out.values.first().map_or(0, |v| v.samples);
    let most = out.values.iter().map(|v| v.std_error).fold(0.0, f64::max);
    let triangles = session.scene().world_triangle_count();
    let teardown = Instant::now();
    drop((session, device));
    phases.teardown_seconds = teardown.elapsed().as_secs_f64();
    let host_peak_bytes = aorender::peak_rss_bytes().unwrap_or(0);
    phases.close();
    let line = phases.line();
    let stats = ProbeStats {
        points: probes.len(),
        points_off_surface: located.off_surface(),
        samples_per_point: samples,
        samples_requested: args.samples,
        target_error: args.target_error,
        largest_std_error: most,
        ao_rays: out.rays,
        render_seconds: out.seconds,
        rays_per_second: out.rays as f64 / out.seconds.max(1e-9),
        phases,
        adapter: out.adapter.clone(),
        hemisphere: settings.sampling.hemisphere.name(),
        sky: settings.sampling.sky.describe(),
        sampler: settings.sampling.sampler.name(),
        seed: settings.sampling.seed,
        triangles,
        host_peak_bytes,
        host_peak_bytes_per_triangle: phases::per(host_peak_bytes, triangles as u64),
        host_peak_bytes_per_point: phases::per(host_peak_bytes, probes.len() as u64),
        heap_peak_bytes: memory::heap_peak_bytes(),
    };
    if let Some(path) = &args.stats {
        write_json(path, &serde_json::to_string_pretty(&stats)?)?;
    }
    crate::say!(
        "{} probes × {samples} samples in {:.2} s ({:.1} M AO rays/s) on {}; {} on no surface; {line}",
        probes.len(),
        out.seconds,
        out.rays as f64 / out.seconds.max(1e-9) / 1e6,
        out.adapter,
        located.off_surface()
    );
    if let Some(first) = located.on_surface.iter().position(|&on| !on) {
        crate::say!(
            "note: {} of {} points (the first on line {} of {}) lie on no surface within the tolerance: \
             their rays start exactly at them (--surface-tolerance D to widen it)",
            located.off_surface(),
            probes.len(),
            lines[first],
            args.points.display()
        );
    }
    if matches!(settings.sampling.sampler, Sampler::Sobol | Sampler::Stratified)
        && settings.sampling.sampler.replicate_samples(settings.sampling.replicate) == 0
    {
        crate::say!(
            "note: std_error is the spread of single samples, which overestimates the error of {} points: \
             --replicate N gives a valid one",
            settings.sampling.sampler.name()
        );
    }
    if let Some(e) = args.target_error {
        let met = if most <= e { "met" } else { "not met" };
        crate::say!(
            "error target {e} {met}: the largest standard error is {most:.3e} after {samples} samples ({} checks)",
            stats.phases.checks
        );
    }
    Ok(())
}

/// Bytes of memory a probe file takes per byte of its text, with its probes: a line of
/// 12 bytes (`0 0 0 0 0 1`) becomes a 40-byte probe and its line number, in vectors that
/// grow by doubling, and the probe's copy found on its surface.
const PROBE_TEXT_BYTES_PER_BYTE: u64 = 12;

/// Reads probes from a text file within `limits`: one per line, `x y z nx ny nz`
/// (whitespace or commas), `#` starts a comment. Errors name the file and line. With
/// each probe's line number. The points are in the scene's own coordinates and are kept
/// relative to its `origin` (see [`parse_probes`]).
pub fn read_probes(path: &Path, limits: &ReadLimits, origin: DVec3) -> Result<(Vec<Probe>, Vec<usize>)> {
    let text = read_text(path, limits, PROBE_TEXT_BYTES_PER_BYTE, "the probe file")?;
    parse_probes(&text, origin).map_err(|m| anyhow!("{}: {m}", path.display()))
}

/// Parses the text of a probe file: the probes and their line numbers. Each point is
/// taken relative to `origin` (the scene's, which its primitives are stored relative to),
/// subtracted in f64 and rounded once; where that is zero, as given.
pub fn parse_probes(text: &str, origin: DVec3) -> std::result::Result<(Vec<Probe>, Vec<usize>), ProbeFileError> {
    let (mut probes, mut lines) = (Vec::new(), Vec::new());
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        let fields: Vec<&str> = line.split(|c: char| c.is_whitespace() || c == ',').filter(|f| !f.is_empty()).collect();
        if fields.is_empty() {
            continue;
        }
        let line = i + 1;
        if fields.len() != 6 {
            return Err(ProbeFileError::Fields { line, found: fields.len() });
        }
        let not_a_number = |f: &str| ProbeFileError::NotANumber { line, word: f.to_string() };
        let mut v = [0f32; 6];
        for (k, f) in fields.iter().enumerate() {
            v[k] = f.parse().map_err(|_| not_a_number(f))?;
        }
        let mut position = Vec3::new(v[0], v[1], v[2]);
        if origin != DVec3::ZERO {
            let mut p = [0f64; 3];
            for (k, f) in fields[..3].iter().enumerate() {
                p[k] = f.parse().map_err(|_| not_a_number(f))?;
            }
            position = (DVec3::from(p) - origin).as_vec3();
        }
        let probe = Probe::new(position, Vec3::new(v[3], v[4], v[5]))
            .map_err(|e| ProbeFileError::Probe { line, message: e.message() })?;
        probes.push(probe);
        lines.push(i + 1);
    }
    if probes.is_empty() {
        return Err(ProbeFileError::Empty);
    }
    Ok((probes, lines))
}

/// What is wrong with a probe file, naming the line (the reader adds the file).
#[derive(Debug, thiserror::Error)]
pub enum ProbeFileError {
    /// A line of other than six numbers.
    #[error("line {line}: expected 6 numbers (x y z nx ny nz), found {found}")]
    Fields {
        /// The line, from 1.
        line: usize,
        /// The fields it has.
        found: usize,
    },
    /// A field that is no number.
    #[error("line {line}: '{word}' is not a number")]
    NotANumber {
        /// The line, from 1.
        line: usize,
        /// The field.
        word: String,
    },
    /// A point the library refuses (a non-finite coordinate, a zero normal).
    #[error("line {line}: {message}")]
    Probe {
        /// The line, from 1.
        line: usize,
        /// The library's reason.
        message: String,
    },
    /// A file without a probe.
    #[error("no probes")]
    Empty,
}

/// The probe values as CSV: `x,y,z,nx,ny,nz,ao,std_error,samples`, the points back in the
/// scene's own coordinates (plus `origin`, in f64, where that is not zero).
pub fn to_csv(probes: &[Probe], values: &[ProbeValue], origin: DVec3) -> String {
    let mut out = String::from("x,y,z,nx,ny,nz,ao,std_error,samples\n");
    for (p, v) in probes.iter().zip(values) {
        let n = p.normal;
        let position = if origin == DVec3::ZERO {
            let a = p.position;
            format!("{},{},{}", a.x, a.y, a.z)
        } else {
            let a = origin + p.position.as_dvec3();
            format!("{},{},{}", a.x, a.y, a.z)
        };
        out += &format!("{position},{},{},{},{},{},{}\n", n.x, n.y, n.z, v.mean, v.std_error, v.samples);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_probe_lines() {
        let (p, lines) = parse_probes("# header\n1 2 3 0 0 2\n\n4,5,6, 0,-1,0 # trailing\n", DVec3::ZERO).unwrap();
        assert_eq!(lines, [2, 4]);
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
            let e = parse_probes(text, DVec3::ZERO).unwrap_err().to_string();
            assert!(e.contains(expect), "{text:?}: {e}");
        }
    }
}
