//! What broke the merges of shards on an NVIDIA GPU when blocks were summed in floats.
//!
//! Before integer sums, the kernel added a block's samples in f32 with Neumaier's
//! compensation, `t = s + x; c += (s − t) + x`. A shader compiler that rewrites float
//! expressions algebraically sees `(s − (s + x)) + x = 0` and drops the compensation,
//! leaving a plain f32 sum, which depends on where the blocks start: shards split off
//! block boundaries then merge to other bits than the single run.
//!
//! This program takes the samples of the shard test (`crates/aorender-cli/tests/shards.rs`:
//! the built-in scene at 24 × 16, uniform hemisphere, seed 9, 600 samples), computed by the
//! CPU reference, and sums each pixel's blocks three ways, for the single run (blocks
//! 0..256, 256..512, 512..600) and for the unaligned shards 0..100, 100..333, 333..600
//! merged (blocks cut at 100, 256, 333, 512): compensated as written, with the
//! compensation dropped, and exactly. It prints pixel 155 and how many pixels differ
//! beyond the test's f32 bound. The NVIDIA H200 run of that test reported pixel 155 as
//! merged 43.24208068847656, single 43.24207782745361: the sums with the compensation
//! dropped, to every digit.
//!
//! `cargo run --release -p aorender --features testing --example lost_compensation`

use aorender::bvh::{BuildQuality, build_cwbvh};
use aorender::cpu::CpuTracer;
use aorender::sampler::PointSampler;
use aorender::{Hemisphere, Scene};

/// Neumaier's compensated f32 sum, as the kernel wrote it, added in f64 at the end.
fn compensated(v: &[f32]) -> f64 {
    let (mut s, mut c) = (0f32, 0f32);
    for &x in v {
        let t = s + x;
        c += if s.abs() >= x.abs() { (s - t) + x } else { (x - t) + s };
        s = t;
    }
    s as f64 + c as f64
}

/// The same with `(s − t) + x` simplified to 0: a plain f32 sum.
fn plain(v: &[f32]) -> f64 {
    v.iter().fold(0f32, |s, &x| s + x) as f64
}

/// The exact sum (f64 holds every partial sum of these samples exactly).
fn exact(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum()
}

/// One way of summing a block's samples.
type Sum = fn(&[f32]) -> f64;

fn main() {
    let mut scene = Scene::default_scene();
    let s = &mut scene.settings;
    (s.width, s.height, s.spp, s.sampling.hemisphere, s.sampling.seed) = (24, 16, 600, Hemisphere::Uniform, 9);
    let scene = scene;
    let s = &scene.settings;
    let tracer = CpuTracer::new(&scene, build_cwbvh(&scene, BuildQuality::default()));
    let rays = scene.camera.ray_gen(s.width, s.height);
    let sampler = PointSampler::new(s.sampling.sampler, s.sampling.seed, s.spp, s.sampling.replicate_samples());
    let samples: Vec<Vec<f32>> = (0..s.width * s.height)
        .map(|p| (0..s.spp).map(|k| tracer.shade_sample(&rays, s, &sampler, p % s.width, p / s.width, k).0).collect())
        .collect();
    let single = [0, 256, 512, 600];
    let merged = [0, 100, 256, 333, 512, 600];
    let blocks = |v: &[f32], cuts: &[usize], sum: Sum| -> f64 { cuts.windows(2).map(|w| sum(&v[w[0]..w[1]])).sum() };
    let ways: [(&str, Sum); 3] = [("compensated", compensated), ("compensation dropped", plain), ("exact", exact)];
    for (name, sum) in ways {
        let (a, b) = (blocks(&samples[155], &merged, sum), blocks(&samples[155], &single, sum));
        let beyond = samples
            .iter()
            .filter(|v| {
                let (a, b) = (blocks(v, &merged, sum), blocks(v, &single, sum));
                (a - b).abs() > f32::EPSILON as f64 / 2.0 * b.abs()
            })
            .count();
        println!(
            "{name:>21}: pixel 155 merged {a:.14}, single {b:.14}; {beyond} of {} pixels apart beyond f32 rounding",
            samples.len()
        );
    }
}
