//! AO at given points and normals (`aorender probe`): the hemisphere integral without a
//! camera, for checking closed forms at exact locations and for baking AO into vertices.
//!
//! A probe is a position and a normal; its value is 1/π ∫ V(x, ω) cos θ dω over the
//! hemisphere around the normal (albedo 1), estimated with the scene's hemisphere
//! distribution, sampler, seed and maximum distance. The AO rays start at the position
//! offset along the normal (Wächter & Binder), as from a surface hit. Sample `i` of probe
//! `k` uses the sampler's numbers for pixel `(k, 0)` and index `i`, on the GPU and on the
//! CPU reference alike.

use crate::bvh::{self, GpuBvh};
use crate::cpu::CpuTracer;
use crate::error::{Error, Result};
use crate::gpu::{GpuContext, GpuProbePoint, GpuRenderer};
use crate::render::{Device, RenderOptions};
use crate::scene::Scene;
use glam::Vec3;
use std::path::Path;
use std::time::Instant;

/// Rounds per GPU pass: each round is up to `TARGET_SLOTS` AO rays, so a pass stays far
/// below a second even on lavapipe and GPU watchdogs never fire.
const PROBE_PASS_ROUNDS: u32 = 64;
/// Film slots the probe kernel aims to keep busy per dispatch: points × lanes.
const TARGET_SLOTS: u32 = 1 << 16;

/// A point and the normal of its hemisphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    /// Position.
    pub position: Vec3,
    /// Unit normal.
    pub normal: Vec3,
}

impl Probe {
    /// A probe; the normal is normalised. Errors name the problem.
    pub fn new(position: Vec3, normal: Vec3) -> std::result::Result<Probe, String> {
        if !position.is_finite() || !normal.is_finite() {
            return Err("non-finite coordinate".into());
        }
        let len = normal.length();
        if !(len > 0.0 && len.is_finite()) {
            return Err("zero normal".into());
        }
        Ok(Probe { position, normal: normal / len })
    }
}

/// The estimate at one probe.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ProbeValue {
    /// Mean of the samples.
    pub mean: f64,
    /// Standard error of the mean, from the sample variance (an overestimate for the
    /// stratified and Sobol samplers).
    pub std_error: f64,
    /// Samples taken.
    pub samples: u64,
}

/// Values and figures of a probe run.
#[derive(Clone, Debug)]
pub struct ProbeOutput {
    /// One value per probe, in input order.
    pub values: Vec<ProbeValue>,
    /// AO rays traced.
    pub rays: u64,
    /// Seconds spent tracing (BVH build and setup excluded).
    pub seconds: f64,
    /// Adapter name, or "cpu".
    pub adapter: String,
}

/// Reads probes from a text file: one per line, `x y z nx ny nz` (whitespace or commas),
/// `#` starts a comment. Errors name the file and line.
pub fn read_probes(path: &Path) -> Result<Vec<Probe>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::scene(path, format!("cannot read: {e}")))?;
    parse_probes(&text).map_err(|m| Error::scene(path, m))
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
        let probe = Probe::new(Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5])).map_err(at)?;
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

/// Lanes per probe: enough film slots to fill the device, at most one per sample.
fn lanes_for(points: usize, samples: u32) -> u32 {
    (TARGET_SLOTS / points.max(1) as u32).clamp(1, samples.max(1))
}

/// Mean and standard error of the sums of `n` samples.
fn value_from_sums(sum: f64, sum_sq: f64, n: u64) -> ProbeValue {
    let nf = n as f64;
    let mean = sum / nf;
    let var = if n > 1 { ((sum_sq - nf * mean * mean) / (nf - 1.0)).max(0.0) } else { 0.0 };
    ProbeValue { mean, std_error: (var / nf).sqrt(), samples: n }
}

/// Estimates AO at every probe with `samples` samples each, using the scene's hemisphere,
/// sampler, seed and maximum distance (its camera, image size and spp are ignored).
pub fn probe(scene: &Scene, options: &RenderOptions, probes: &[Probe], samples: u32) -> Result<ProbeOutput> {
    probe_with(None, scene, options, probes, samples)
}

/// [`probe`] on an already open adapter (`None` opens the one `options` names), so many
/// small probe runs share one device.
pub fn probe_with(
    ctx: Option<&GpuContext>,
    scene: &Scene,
    options: &RenderOptions,
    probes: &[Probe],
    samples: u32,
) -> Result<ProbeOutput> {
    let s = &scene.settings;
    s.validate().map_err(|m| Error::scene(&scene.name, m))?;
    if samples == 0 {
        return Err(Error::scene(&scene.name, "samples per probe must be at least 1"));
    }
    let lanes = lanes_for(probes.len(), samples);
    let rounds = samples.div_ceil(lanes);
    let points: Vec<GpuProbePoint> = probes
        .iter()
        .map(|p| GpuProbePoint { position: p.position.to_array(), _pad0: 0.0, normal: p.normal.to_array(), _pad1: 0.0 })
        .collect();
    let (sums, rays, seconds, adapter) = match options.device {
        Device::Gpu => {
            let owned;
            let ctx = match ctx {
                Some(c) => c,
                None => {
                    owned = GpuContext::new(options.adapter.as_deref())?;
                    &owned
                }
            };
            let gpu_bvh = GpuBvh::build(scene, options.bvh_layout, options.bvh_quality);
            let mut renderer = GpuRenderer::for_probes(ctx, scene, &gpu_bvh, &points, lanes, samples)?;
            drop(gpu_bvh);
            let start = Instant::now();
            let (mut done, mut rays) = (0u32, 0u64);
            while done < rounds {
                let count = (rounds - done).min(PROBE_PASS_ROUNDS);
                rays += renderer.render_pass(done, count)?.ao_rays;
                done += count;
            }
            let film = renderer.read_film(0)?;
            (
                film.sum.into_iter().zip(film.sum_sq).collect::<Vec<_>>(),
                rays,
                start.elapsed().as_secs_f64(),
                ctx.description.name.clone(),
            )
        }
        Device::Cpu => {
            let tracer = CpuTracer::new(scene, bvh::build_cwbvh(scene, options.bvh_quality));
            let start = Instant::now();
            let sums = tracer.probe_lanes(s, probes, lanes, samples);
            (sums, samples as u64 * probes.len() as u64, start.elapsed().as_secs_f64(), "cpu".into())
        }
    };
    let values = (0..probes.len())
        .map(|k| {
            let lane_sums = &sums[k * lanes as usize..(k + 1) * lanes as usize];
            let (sum, sum_sq) = lane_sums.iter().fold((0.0, 0.0), |(a, b), &(x, y)| (a + x, b + y));
            value_from_sums(sum, sum_sq, samples as u64)
        })
        .collect();
    Ok(ProbeOutput { values, rays, seconds, adapter })
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

    #[test]
    fn lanes_fill_the_device_without_exceeding_samples() {
        assert_eq!(lanes_for(1, 1 << 20), TARGET_SLOTS);
        assert_eq!(lanes_for(1, 100), 100);
        assert_eq!(lanes_for(1 << 20, 1000), 1);
        assert_eq!(lanes_for(64, 1 << 20), TARGET_SLOTS / 64);
    }

    #[test]
    fn sums_give_mean_and_standard_error() {
        // Samples 0, 1, 1, 0: mean 1/2, variance 1/3, standard error √(1/12).
        let v = value_from_sums(2.0, 2.0, 4);
        assert_eq!(v.mean, 0.5);
        assert!((v.std_error - (1.0f64 / 12.0).sqrt()).abs() < 1e-15);
    }
}
