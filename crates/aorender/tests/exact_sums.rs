//! Sums that do not depend on the device or on how the samples are split: every sample
//! is added to its block as integers (`film::quantize_sample`, `shaders/sums.wgsl`), so
//! the adapter's sums are the CPU reference's bit for bit wherever the two compute the
//! same samples (on lavapipe, everywhere), and shards split at any sample index merge to
//! the single run's bits.

mod common;
use aorender::film::{BLOCK_SAMPLES, BlockSums, OUT_OF_RANGE_BIT, quantize_sample};
use aorender::scene::{Plane, Sphere};
use aorender::{Accumulation, Control, Film, Hemisphere, ImageRequest, Probe, Sampler, Scene, Session};
use common::kernel::{self, TestKernel};
use common::*;
use glam::Vec3;
use std::path::PathBuf;

const PROBE_NAME: &str = "sums_probe.wgsl";
const PROBE: &str = include_str!("kernels/sums_probe.wgsl");

/// f32 values for samples of bound 2^`e`: every magnitude from 2^(e − 70) up, both signs
/// (xorshift, fixed seed), the edges of the ranges the quanta are exact in, subnormals,
/// zeros, and, with `outside`, values past the bound, infinities and NaN.
fn sample_values(e: i32, n: usize, outside: bool) -> Vec<f32> {
    let mut x = 0x2545_f491_4f6c_dd1du64 ^ e as u64;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let bound = 2f64.powi(e).min(f32::MAX as f64) as f32;
    let mut v: Vec<f32> = (0..n)
        .map(|_| {
            let r = next();
            let m = ((r >> 11) as f64 / (1u64 << 53) as f64 * 2f64.powi(e - (r % 71) as i32)).min(bound as f64);
            if r >> 63 == 1 { -(m as f32) } else { m as f32 }
        })
        .collect();
    for k in [1, 4, 5, 31, 32, 54, 55, 56, 78, 79] {
        let p = (2f64.powi(e - k) as f32).max(f32::from_bits(1));
        v.extend([p, -p, f32::from_bits(p.to_bits() + 1), f32::from_bits(p.to_bits() - 1)]);
    }
    v.extend([0.0, -0.0, bound, -bound, f32::from_bits(1), -f32::from_bits(0x7f_ffff), 0.8, -0.7]);
    if outside {
        let past = f32::from_bits(bound.to_bits() + 1);
        v.extend([past, -past, 4.0 * bound, f32::INFINITY, f32::NEG_INFINITY, f32::NAN]);
    }
    v
}

fn words(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect()
}

/// The kernel's quantisation and 64-bit addition give the Rust reference's words for
/// every value, in range or not, at every scale; 256 samples added in order into a slot
/// (carries across words, negative sums, a sample out of range among them) give the
/// reference's slot.
#[test]
fn the_kernel_quantises_and_adds_samples_as_the_reference_does() {
    kernel::validate(PROBE_NAME, &kernel::compose(PROBE_NAME, PROBE));
    if !gpu_available() {
        return;
    }
    let probe = TestKernel::new(PROBE_NAME, PROBE, &["quantize", "accumulate"], 1);
    for e in [0, 1, 3, 20, 127, 129] {
        let values = sample_values(e, 50_000, true);
        let n = values.len() as u32;
        let gpu: Vec<[u32; 4]> = probe.run("quantize", [n, e as u32, 0, 0], &[&words(&values)], n, 1);
        for (v, w) in values.iter().zip(&gpu) {
            let (q, sq) = quantize_sample(*v, e);
            let expected = BlockSums { sum: vec![q], sum_sq: vec![sq] }.to_words()[0];
            assert_eq!(*w, expected, "e {e}: {v:e} ({:#010x})", v.to_bits());
        }
        // Slots of 256 in-range samples each; the third slot gets a sample out of range.
        let per = BLOCK_SAMPLES as usize;
        let mut values = sample_values(e, 64 * per, false);
        values.truncate(64 * per);
        values[2 * per + 100] = f32::NAN;
        let gpu: Vec<[u32; 4]> = probe.run("accumulate", [64, e as u32, per as u32, 0], &[&words(&values)], 64, 1);
        let mut reference = BlockSums::new(64);
        for (k, v) in values.iter().enumerate() {
            reference.add(k / per, *v, e);
        }
        assert_eq!(gpu, reference.to_words(), "e {e}: slots of 256 samples");
        assert_ne!(reference.sum_sq[2] & OUT_OF_RANGE_BIT, 0);
        assert!(reference.sum.iter().any(|&s| s < 0) && reference.sum.iter().any(|&s| s > 1 << 32));
    }
}

/// A mesh (the bumpy floor and open box), a sphere and a plane, albedos that are not
/// sums of powers of two, a background that camera rays reach.
fn mixed_scene() -> (Scene, tempfile::TempDir) {
    let dir = temp_dir();
    let obj = dir.path().join("floor_and_box.obj");
    write_obj(&obj, &floor_and_box());
    let mut scene = Scene::load(&obj).expect("mesh loads");
    scene.spheres.push(Sphere { center: Vec3::new(1.1, 0.45, 0.9), radius: 0.4, albedo: 0.7 });
    scene.planes.push(Plane { normal: Vec3::Y, point: Vec3::new(0.0, -0.05, 0.0), albedo: 0.6 });
    let s = &mut scene.settings;
    (s.width, s.height, s.spp, s.sampling.seed, s.background) = (24, 16, 300, 5, 0.3);
    (scene, dir)
}

/// Shard boundaries off every block and replicate boundary: a shard of one sample, one
/// that crosses the block boundary at 256.
const SPLITS: [u32; 6] = [0, 1, 37, 255, 257, 300];

/// The merge of `session`'s renders of `request` over the sample ranges between
/// consecutive `splits`, each its own render.
fn merged_shards(session: &Session, request: &ImageRequest, splits: &[u32]) -> aorender::Merged {
    let shards: Vec<(PathBuf, Accumulation)> = splits
        .windows(2)
        .map(|r| {
            let request = ImageRequest { samples: Some(r[0]..r[1]), ..request.clone() };
            let out = session.render(&request).and_then(|r| r.complete(&mut Control::default()));
            let out = out.unwrap_or_else(|e| panic!("{}: shard {}..{}: {e}", session_label(session), r[0], r[1]));
            (PathBuf::from(format!("{}..{}", r[0], r[1])), out.accumulation)
        })
        .collect();
    aorender::merge(&shards).unwrap_or_else(|e| panic!("{e}"))
}

fn assert_same_film(a: &Film, b: &Film, what: &str) {
    assert!(a.image_mean() > 0.05, "{what}: nothing in view");
    assert_eq!(a.sum, b.sum, "{what}: Σv");
    assert_eq!(a.sum_sq, b.sum_sq, "{what}: Σv²");
    assert_eq!(a, b, "{what}: the films");
}

/// For every hemisphere and sampler, on the CPU and every GPU configuration (each BVH
/// layout; the cooperative traversal where the adapter has it), the merge of shards split
/// at [`SPLITS`] is the device's single run, bit for bit, and the merge says so. With
/// Sobol points in replicates of 16, shards split on replicate boundaries that are not
/// block boundaries merge to the single run's replicate squares too.
///
/// Where the adapter rounds f32 arithmetic as the CPU does, its single run is also the
/// CPU reference's, bit for bit. lavapipe (a CPU adapter) does: IEEE operations, nothing
/// fused. A GPU's compiler may fuse a product into a sum and its division and square root
/// need not be correctly rounded (Vulkan allows 2.5 ulp and more), so some of its samples
/// differ from the CPU's in their last bits, and a ray that grazes an edge can then hit
/// on one side only: there the device's sums are exact for its own samples, which the
/// shard merges check.
#[test]
fn gpu_and_cpu_sums_are_equal_and_shards_split_anywhere_merge_exactly() {
    let (scene, _dir) = mixed_scene();
    let cpu = session(&scene, &Config::cpu());
    let mut sessions = vec![(Config::cpu(), session(&scene, &Config::cpu()))];
    if gpu_available() {
        sessions.extend(gpu_configs().into_iter().map(|c| (c, session(&scene, &c))));
    }
    let mut cases: Vec<(Hemisphere, Sampler, u32, Vec<u32>)> = Hemisphere::ALL
        .into_iter()
        .flat_map(|h| Sampler::ALL.into_iter().map(move |s| (h, s, 0, SPLITS.to_vec())))
        .collect();
    cases.push((Hemisphere::Uniform, Sampler::Sobol, 16, vec![0, 16, 112, 272, 300]));
    for (hemisphere, sampler, replicate, splits) in cases {
        let mut settings = scene.settings.clone();
        settings.sampling.replicate = (replicate > 0).then_some(replicate);
        (settings.sampling.hemisphere, settings.sampling.sampler) = (hemisphere, sampler);
        let request = ImageRequest { camera: scene.camera, settings, samples: None };
        let reference = render_request(&cpu, &request);
        for (config, session) in &sessions {
            let what = format!("{}, {}, replicate {replicate}, {}", hemisphere.name(), sampler.name(), label(config));
            let single = render_request(session, &request);
            if rounds_as_the_cpu(config) {
                assert_same_film(&reference, &single, &format!("{what} against the CPU reference"));
            } else {
                let apart = reference.sum.iter().zip(&single.sum).filter(|(a, b)| a != b).count();
                eprintln!("{what}: {apart} of {} pixels apart from the CPU reference", single.sum.len());
            }
            let merged = merged_shards(session, &request, &splits);
            assert!(merged.same_as_single_run, "{what}: the merge does not call itself the single run");
            assert_same_film(&single, &merged.film, &what);
            if replicate > 0 {
                assert_eq!(merged.film.replicates, 300 / 16, "{what}");
            }
        }
    }
}

/// True when `config`'s device rounds f32 arithmetic as the CPU reference does: the CPU
/// itself, or a CPU adapter (lavapipe).
fn rounds_as_the_cpu(config: &Config) -> bool {
    match config.device {
        aorender::DeviceKind::Cpu => true,
        aorender::DeviceKind::Gpu => gpu_adapter().ctx.description.device_type == "Cpu",
    }
}

/// Probe films, one slot a point and four with bent normals (the AO and the escaped
/// directions' components, negative ones among them), split at sample indices off every
/// block: on each device the merge of the shards is the device's single run, bit for bit,
/// and its AO sums are the CPU reference's. (The directions themselves are float
/// arithmetic a shader compiler may contract: on lavapipe their last bits differ from
/// the CPU's, and so do their sums.)
#[test]
fn probe_and_bent_normal_films_split_anywhere_merge_exactly() {
    let (scene, _dir) = mixed_scene();
    let probes: Vec<Probe> = [[0.0, 0.2, 0.0], [1.0, 0.1, -0.5], [-1.5, 0.05, 1.0], [0.8, 0.0, 0.6]]
        .iter()
        .map(|&p| Probe::new(Vec3::from(p), Vec3::new(0.3, 1.0, -0.2)).unwrap())
        .collect();
    let cpu = session(&scene, &Config::cpu());
    let mut sessions = vec![(Config::cpu(), session(&scene, &Config::cpu()))];
    if gpu_available() {
        sessions.extend(gpu_configs().into_iter().map(|c| (c, session(&scene, &c))));
    }
    let run = |session: &Session, settings: &aorender::Settings, bent: bool, range: std::ops::Range<u32>| {
        let render = session.probe_render(&probes, 300, Some(range), settings, bent);
        render.and_then(|r| r.complete(&mut Control::default())).unwrap_or_else(|e| panic!("{e}")).accumulation
    };
    for (hemisphere, sampler) in [(Hemisphere::Uniform, Sampler::Sobol), (Hemisphere::Cosine, Sampler::Independent)] {
        let mut settings = scene.settings.clone();
        (settings.sampling.hemisphere, settings.sampling.sampler) = (hemisphere, sampler);
        for bent in [false, true] {
            let reference = run(&cpu, &settings, bent, 0..300).film().unwrap();
            if bent {
                assert!(reference.sum.iter().any(|&s| s < 0.0), "no negative component to sum");
            }
            let ao_slots =
                |film: &Film| -> Vec<f64> { film.sum.iter().step_by(if bent { 4 } else { 1 }).copied().collect() };
            for (config, session) in &sessions {
                let what = format!("{}, {}, bent {bent}, {}", hemisphere.name(), sampler.name(), label(config));
                let single = run(session, &settings, bent, 0..300).film().unwrap();
                let shards: Vec<(PathBuf, Accumulation)> = SPLITS
                    .windows(2)
                    .map(|r| (PathBuf::from(format!("{}..{}", r[0], r[1])), run(session, &settings, bent, r[0]..r[1])))
                    .collect();
                let merged = aorender::merge(&shards).unwrap();
                assert!(merged.same_as_single_run, "{what}");
                assert_eq!(merged.film, single, "{what}: the merge against the device's single run");
                assert!(ao_slots(&single).iter().any(|&s| s > 0.0), "{what}: no AO");
                assert_eq!(ao_slots(&single), ao_slots(&reference), "{what}: AO sums against the CPU reference's");
            }
        }
    }
}

/// Two films of 64 samples a pixel: 400 pixels of independent Bernoulli samples (0 or
/// 0.8, p from 0.1 to 0.9; xorshift streams of their own), then pixels without spread:
/// open on both sides (0.8 every sample), and one whose value is `flat` on the second.
fn films_with_flat_pixels(flat: f64) -> (Film, Film) {
    let mut films = [Film::new(410, 1), Film::new(410, 1)];
    for (k, film) in films.iter_mut().enumerate() {
        film.samples = 64;
        let mut x = 0x853c_49e6_748f_ea9bu64 + k as u64;
        for i in 0..400 {
            let p = 0.1 + 0.8 * i as f64 / 400.0;
            for _ in 0..64 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let v = if ((x >> 11) as f64 / (1u64 << 53) as f64) < p { 0.8f32 as f64 } else { 0.0 };
                film.sum[i] += v;
                film.sum_sq[i] += v * v;
            }
        }
        for i in 400..410 {
            let v = if k == 1 && i == 409 { flat } else { 0.8f32 as f64 };
            (film.sum[i], film.sum_sq[i]) = (64.0 * v, 64.0 * v * v);
        }
    }
    let [a, b] = films;
    (a, b)
}

/// The statistical comparison of two renders takes pixels without spread on either side
/// by their bounded-value intervals: equal ones and ones a rounding apart pass (no z² of
/// a difference over a zero variance), an open pixel against a closed one fails.
#[test]
fn pixels_without_spread_are_compared_by_their_intervals() {
    let (a, b) = films_with_flat_pixels(0.8f32 as f64);
    assert_statistical_agreement(&a, &b, 1.6, "exact");
    let (a, b) = films_with_flat_pixels(0.8f32 as f64 * (1.0 + 1e-7));
    assert_statistical_agreement(&a, &b, 1.6, "a rounding apart");
    let (a, b) = films_with_flat_pixels(0.0);
    let failed = std::panic::catch_unwind(|| assert_statistical_agreement(&a, &b, 1.6, "open against closed"));
    let message = failed.expect_err("an open pixel agreed with a closed one");
    let text = message.downcast_ref::<String>().cloned().unwrap_or_default();
    assert!(text.contains("pixel 409, no spread on either side"), "{text}");
}
