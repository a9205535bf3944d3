//! Error estimates that hold for every sampler: the reported 95 % intervals contain the
//! true value for 93–97 % of points (closed forms) and pixels (a converged scan), the
//! image-level RMSE estimate is within 10 % of the measured RMSE, and renders that stop at
//! an error target meet it.

mod common;

use aorender::Sampling;
use aorender::accumulation::max_sample_value;
use aorender::closed_form::configurations;
use aorender::geometry::Plane;
use aorender::scene::Sphere;
use aorender::{
    Accumulation, Control, DeviceKind, ErrorTarget, Film, Hemisphere, ImageRequest, Probe, SampleRange, Sampler, Scene,
    Session, Settings, interval_95, merge,
};
use common::{Config, device, gpu_available, repo, session};
use glam::Vec3;

/// Samples per point or pixel of the coverage tests: 16 replicates of 4 for stratified
/// and Sobol, 64 independent samples.
const SAMPLES: u32 = 64;

/// The devices a test runs on: the CPU reference, and the GPU where there is one.
fn kinds() -> Vec<DeviceKind> {
    let mut k = vec![DeviceKind::Cpu];
    if gpu_available() {
        k.push(DeviceKind::Gpu);
    }
    k
}

/// Degrees of freedom of the error estimate of `samples` samples drawn with `settings`.
fn dof(settings: &Settings, samples: u32) -> u64 {
    match settings.sampling.replicate_samples() {
        1 => samples as u64 - 1,
        b => (samples / b) as u64 - 1,
    }
}

/// A floor under a sphere of radius 1 whose centre is 1.5 above the origin, and `n`
/// points on the floor from the origin outwards, with their AO 1 − h r² / d³.
fn floor_under_sphere(n: usize) -> (Scene, Vec<Probe>, Vec<f64>) {
    let (h, r) = (1.5f32, 1.0f32);
    let mut scene = Scene::from_triangles("floor under a sphere", Vec::new());
    scene.spheres.push(Sphere { center: Vec3::new(0.0, h, 0.0), radius: r, albedo: 1.0 });
    scene.planes.push(Plane { normal: Vec3::Y, point: Vec3::ZERO, albedo: 1.0 });
    let mut probes = Vec::new();
    let mut exact = Vec::new();
    for i in 0..n {
        // Out to 3 radii: AO from 0.56 at the origin towards 0.96.
        let x = 3.0 * i as f32 / n as f32;
        let p = Vec3::new(x, 0.0, 0.37 * x);
        probes.push(Probe::new(p, Vec3::Y).unwrap());
        let d = (Vec3::new(0.0, h, 0.0) - p).as_dvec3().length();
        exact.push(1.0 - h as f64 * (r * r) as f64 / (d * d * d));
    }
    (scene, probes, exact)
}

/// The share of reported 95 % intervals around `mean` that contain the reference,
/// each side widened by the reference's own 95 % half-width (1.96 of its standard error,
/// in quadrature), over the points that `counted` admits. An exact reference (a closed
/// form: `reference_se` `None`) counts every such point; a converged one only the pixels whose value varied in it, not those
/// that every sample found the same (background, surfaces open all round), whose value
/// is known exactly. Returns how many were counted, and how many of those had a zero
/// standard error (every sample equal).
fn coverage(
    mean: &[f64],
    se: &[f64],
    intervals: &[(f64, f64)],
    reference: &[f64],
    reference_se: Option<&[f64]>,
    counted: impl Fn(usize) -> bool,
) -> Coverage {
    let mut c = Coverage::default();
    for (i, &(lo, hi)) in intervals.iter().enumerate() {
        let r = reference_se.map_or(0.0, |e| 1.96 * e[i]);
        if reference_se.is_some() && r == 0.0 || !counted(i) {
            continue;
        }
        c.counted += 1;
        c.degenerate += (se[i] == 0.0) as usize;
        let (below, above) = ((mean[i] - lo).hypot(r), (hi - mean[i]).hypot(r));
        let d = reference[i] - mean[i];
        c.covered += (-below <= d && d <= above) as usize;
    }
    c
}

#[derive(Default)]
struct Coverage {
    counted: usize,
    covered: usize,
    degenerate: usize,
}

impl Coverage {
    fn share(&self) -> f64 {
        self.covered as f64 / self.counted.max(1) as f64
    }
}

/// A floor under a sphere of radius 0.55 at height 1, and `n` points on the floor
/// whose occlusion h r² / d³ falls from 0.30 under it to 0.003 far out, evenly in its
/// logarithm: AO from 0.70 to 0.997, most points nearly open.
fn nearly_open_floor(n: usize) -> (Scene, Vec<Probe>, Vec<f64>) {
    let (h, r) = (1.0f64, 0.55f64);
    let mut scene = Scene::from_triangles("floor under a small sphere", Vec::new());
    scene.spheres.push(Sphere { center: Vec3::new(0.0, h as f32, 0.0), radius: r as f32, albedo: 1.0 });
    scene.planes.push(Plane { normal: Vec3::Y, point: Vec3::ZERO, albedo: 1.0 });
    let mut probes = Vec::new();
    let mut exact = Vec::new();
    for i in 0..n {
        let occlusion = 0.30 * (0.01f64).powf(i as f64 / n as f64);
        let d = (h * r * r / occlusion).cbrt();
        let x = (d * d - h * h).max(0.0).sqrt() as f32;
        let p = Vec3::new(0.6 * x, 0.0, 0.8 * x);
        probes.push(Probe::new(p, Vec3::Y).unwrap());
        let d = (Vec3::new(0.0, h as f32, 0.0) - p).as_dvec3().length();
        exact.push(1.0 - h * r * r / (d * d * d));
    }
    (scene, probes, exact)
}

/// Points counted by the coverage tests, at least: with 2,000, the binomial standard
/// error of a 95 % coverage is 0.49 %, so the 93–97 % window is 4.1 standard errors wide
/// on each side.
const POINTS: usize = 2000;

#[test]
fn probe_intervals_cover_the_closed_form_for_every_sampler() {
    // The nearly open floor counts the points where an occluded ray is expected among the
    // samples (occlusion at least 1 / spp): below that, no event is the likely outcome,
    // which any interval with room for an unseen event covers, and the share covered says
    // nothing of the interval. Three times the points keep 2,000 counted at 16 samples.
    let scenes = [
        ("sphere over a floor", floor_under_sphere(POINTS), false),
        ("nearly open floor", nearly_open_floor(3 * POINTS), true),
    ];
    let mut failures = Vec::new();
    for (name, (scene, probes, exact), partly_occluded) in scenes {
        for kind in kinds() {
            let session = Session::new(&device(kind), scene.clone(), &Default::default()).unwrap();
            for spp in [16, 64, 256] {
                for (hemisphere, sampler) in configurations() {
                    // Eight replicates at 16 samples (the fewest an error target decides
                    // on, `MIN_TARGET_REPLICATES`), sixteen at 64 and 256.
                    let replicate = Some(sampler.replicate_for(spp, (spp / 2).min(16)));
                    let settings = Settings {
                        sampling: Sampling { hemisphere, sampler, seed: 11, replicate, ..Sampling::default() },
                        ..Settings::default()
                    };
                    let values = session.probe(&probes, spp, &settings).unwrap().values;
                    let mean: Vec<f64> = values.iter().map(|v| v.mean).collect();
                    let se: Vec<f64> = values.iter().map(|v| v.std_error).collect();
                    let d = dof(&settings, spp);
                    // A probe sample is a visibility of 0 or 1 under the cosine
                    // estimators, a weight 2 cos θ of at most 2 under the uniform one.
                    let upper = if hemisphere == Hemisphere::Uniform { 2.0 } else { 1.0 };
                    let intervals: Vec<_> =
                        values.iter().map(|v| interval_95(v.mean, v.std_error, d, v.samples, upper)).collect();
                    let expected = |i: usize| !partly_occluded || (1.0 - exact[i]) * spp as f64 >= 1.0;
                    let cov = coverage(&mean, &se, &intervals, &exact, None, expected);
                    let (c, n) = (cov.share(), cov.counted);
                    assert!(n >= POINTS, "{name}: {n} points counted at {spp} spp");
                    let what = format!("{name}, {kind:?} {} {} {spp} spp", hemisphere.name(), sampler.name());
                    eprintln!(
                        "{what}: {:.2} % of {n} points covered ({} with every sample equal)",
                        100.0 * c,
                        cov.degenerate
                    );
                    if !(0.93..=0.97).contains(&c) {
                        failures.push(format!("{what}: 95 % intervals cover {:.2} % of {n} points", 100.0 * c));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The bunny at 64 × 64, its camera's framing.
fn bunny() -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (scene.settings.width, scene.settings.height) = (64, 64);
    scene.settings.sampling.max_distance = Some(0.05);
    scene
}

/// A converged film of `scene`: `spp` independent samples a pixel on the CPU reference.
fn converged(scene: &Scene, spp: u32) -> Film {
    let settings = Settings {
        spp,
        sampling: Sampling { seed: 1234, sampler: Sampler::Independent, ..scene.settings.sampling },
        ..scene.settings.clone()
    };
    common::render_settings(&session(scene, &Config::cpu()), &settings)
}

/// The measured RMSE of `film` against `reference`, the reference's own variance
/// taken out: √(mean (m − r)² − mean se_r²).
fn measured_rmse(film: &Film, reference: &Film) -> f64 {
    let (m, r, se_r) = (film.mean(), reference.mean(), reference.std_error());
    let n = m.len() as f64;
    let ms: f64 = m.iter().zip(&r).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / n;
    let ref_var: f64 = se_r.iter().map(|e| e * e).sum::<f64>() / n;
    (ms - ref_var).max(0.0).sqrt()
}

#[test]
fn image_intervals_and_rmse_estimates_hold_for_every_sampler_on_a_scan() {
    let scene = bunny();
    let reference = converged(&scene, 4096);
    let (r, r_se) = (reference.mean(), reference.std_error());
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        for (hemisphere, sampler) in configurations() {
            let replicate = Some(sampler.replicate_for(SAMPLES, 16));
            let settings = Settings {
                spp: SAMPLES,
                sampling: Sampling { hemisphere, sampler, seed: 5, replicate, ..scene.settings.sampling },
                ..scene.settings.clone()
            };
            let film = common::render_settings(&session, &settings);
            let range = SampleRange::of(hemisphere, 0.0, max_sample_value(&scene, 0.0));
            let intervals = film.intervals_95(range).unwrap();
            let cov = coverage(&film.mean(), &film.std_error(), &intervals, &r, Some(&r_se), |_| true);
            let (c, n) = (cov.share(), cov.counted);
            let (estimate, measured) = (film.rmse_estimate().unwrap(), measured_rmse(&film, &reference));
            eprintln!(
                "{kind:?} {} {}: {:.2} % of {n} pixels covered ({} with every sample equal); \
                 RMSE estimated {estimate:.5}, measured {measured:.5}",
                hemisphere.name(),
                sampler.name(),
                100.0 * c,
                cov.degenerate
            );
            let what = format!("{kind:?} {} {}", hemisphere.name(), sampler.name());
            assert!((0.93..=0.97).contains(&c), "{what}: 95 % intervals cover {:.2} % of {n} pixels", 100.0 * c);
            assert!(
                (estimate / measured - 1.0).abs() <= 0.10,
                "{what}: RMSE estimated {estimate}, measured {measured}"
            );
        }
    }
}

/// The mean of the seeds' image means, the converged image's mean, and the standard
/// error of their difference (the seeds' spread and the reference's own).
fn mean_over_seeds(means: &[f64], reference: &Film) -> (f64, f64, f64) {
    let n = means.len() as f64;
    let avg = means.iter().sum::<f64>() / n;
    let sd = (means.iter().map(|m| (m - avg) * (m - avg)).sum::<f64>() / (n - 1.0)).sqrt();
    let (truth, truth_se) = (reference.image_mean(), common::image_mean_std_error(reference));
    (avg, truth, (sd * sd / n + truth_se * truth_se).sqrt())
}

/// Renders that stop at an error target meet it in at least 95 % of seeds, for every
/// sampler with an error estimate, uniform ones and adaptive ones (which give each pixel
/// replicates in proportion to its standard deviation, and so take fewer samples); and
/// the stopping decisions leave no bias the seeds can see: the image mean over 20 seeds
/// agrees with the converged mean within 4 standard errors (the bias is printed against
/// the target).
#[test]
fn renders_with_an_error_target_meet_it_uniform_or_adaptive() {
    let mut scene = bunny();
    (scene.settings.width, scene.settings.height) = (32, 32);
    // Its variance a twentieth of the renders' at the target, so that the measured RMSE
    // is the render's.
    let reference = converged(&scene, 16384);
    // Reached after about 40 replicates of 16 Sobol samples and 600 independent ones.
    let target = 0.006;
    let seeds = 20u32;
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        for sampler in [Sampler::Independent, Sampler::Stratified, Sampler::Sobol] {
            let mut mean_samples = [0.0; 2];
            for adaptive in [false, true] {
                let what = format!("{kind:?} {}{}", sampler.name(), if adaptive { " adaptive" } else { "" });
                let (mut met, mut means) = (0, Vec::new());
                for seed in 0..seeds {
                    // Independent samples are their own replicates unless an adaptive
                    // render needs replicates to decide at; stratified and Sobol points
                    // are in replicates of 16.
                    let replicate = (adaptive || sampler != Sampler::Independent).then_some(16);
                    let settings = Settings {
                        spp: 4096,
                        sampling: Sampling { sampler, seed, replicate, ..scene.settings.sampling },
                        ..scene.settings.clone()
                    };
                    let request = ImageRequest { camera: scene.camera, settings, samples: None };
                    let mut control =
                        Control { target: Some(ErrorTarget::Rmse(target)), adaptive, ..Control::default() };
                    let out = session.render(&request).unwrap().complete(&mut control).unwrap();
                    assert_eq!(out.stats.ended_by, "target", "{what} seed {seed}");
                    let measured = measured_rmse(&out.film, &reference);
                    met += (measured <= target) as u32;
                    means.push(out.film.image_mean());
                    mean_samples[adaptive as usize] += out.stats.mean_samples_per_pixel / seeds as f64;
                }
                let (avg, truth, se) = mean_over_seeds(&means, &reference);
                eprintln!(
                    "{what}: target met in {met} of {seeds}; {:.0} samples a pixel on average; image mean \
                     {avg:.6} against {truth:.6}: bias {:+.2e} ({:.3} of the target, {:+.2} standard errors)",
                    mean_samples[adaptive as usize],
                    avg - truth,
                    (avg - truth).abs() / target,
                    (avg - truth) / se
                );
                assert!(met * 100 >= 95 * seeds, "{what}: target met in {met} of {seeds} seeds");
                assert!(
                    (avg - truth).abs() <= 4.0 * se,
                    "{what}: image mean {avg} against {truth} (4 SE = {})",
                    4.0 * se
                );
            }
            assert!(
                mean_samples[1] <= mean_samples[0],
                "{kind:?} {}: adaptive {} samples against uniform {}",
                sampler.name(),
                mean_samples[1],
                mean_samples[0]
            );
        }
    }
}

/// Replicate sums survive checkpoints and merges: a Sobol render cut into shards at
/// replicate boundaries merges to the uninterrupted render's bits, and a render resumed
/// from a checkpoint taken mid-replicate ends with the same bits and error.
#[test]
fn replicates_resume_and_merge_to_the_same_bits() {
    let mut scene = bunny();
    (scene.settings.width, scene.settings.height) = (24, 24);
    let settings = Settings {
        spp: 96,
        sampling: Sampling { sampler: Sampler::Sobol, seed: 3, replicate: Some(4), ..scene.settings.sampling },
        ..scene.settings.clone()
    };
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        let request = |samples| ImageRequest { camera: scene.camera, settings: settings.clone(), samples };
        let whole = session.render(&request(None)).unwrap().complete(&mut Control::default()).unwrap();
        assert_eq!((whole.film.replicate, whole.film.replicates), (4, 24), "{kind:?}");
        // Shards at 32 and 64 (multiples of the replicate), merged in another order.
        let mut shards = Vec::new();
        for (i, range) in [(64..96), (0..32), (32..64)].into_iter().enumerate() {
            let out = session.render(&request(Some(range))).unwrap().complete(&mut Control::default()).unwrap();
            shards.push((format!("shard{i}").into(), out.accumulation));
        }
        let merged = merge(&shards).unwrap();
        assert!(merged.film == whole.film, "{kind:?}: merged replicates differ from the whole render's");
        // Interrupted after 7 samples (inside the second replicate), saved, resumed.
        let mut first = session.render(&request(None)).unwrap();
        first.run_to(7, &mut Control { sizing: aorender::PassSizing::Fixed(3), ..Control::default() }).unwrap();
        let saved = Accumulation::from_bytes(&checkpoint_bytes(&first.accumulation().unwrap())).unwrap();
        assert_eq!(saved.samples(), 7);
        let mut resumed = session.render(&request(None)).unwrap();
        resumed.resume(saved).unwrap();
        let out = resumed.complete(&mut Control::default()).unwrap();
        assert!(out.film == whole.film, "{kind:?}: the resumed render differs from the whole one");
        assert_eq!(out.stats.rmse_estimate, whole.stats.rmse_estimate);
    }
}

/// The bytes of `acc` as a checkpoint file.
fn checkpoint_bytes(acc: &Accumulation) -> Vec<u8> {
    let dir = common::temp_dir();
    let path = dir.path().join("c.ck");
    acc.write(&path).unwrap();
    std::fs::read(&path).unwrap()
}

#[test]
fn replicate_sizes_are_checked_and_one_replicate_has_no_estimate() {
    let scene = bunny();
    let s = |sampler, replicate| Settings {
        sampling: Sampling { sampler, replicate: Some(replicate), ..Sampling::default() },
        ..Settings::default()
    };
    assert!(s(Sampler::Sobol, 3).validate().unwrap_err().to_string().contains("power of two"));
    assert!(s(Sampler::Stratified, 8).validate().unwrap_err().to_string().contains("1, 4, 16, 64 or 256"));
    assert!(s(Sampler::Sobol, 512).validate().is_err());
    assert!(s(Sampler::Stratified, 64).validate().is_ok() && s(Sampler::Sobol, 0).validate().is_ok());
    // One replicate of Sobol points: the film reports no error estimate, and a target is
    // refused before any work.
    let session = session(&scene, &Config::cpu());
    let settings = Settings { spp: 16, ..s(Sampler::Sobol, 0) };
    let request = ImageRequest { camera: scene.camera, settings, samples: None };
    let out = session.render(&request).unwrap().complete(&mut Control::default()).unwrap();
    assert_eq!(out.film.rmse_estimate(), None);
    assert_eq!(out.stats.rmse_estimate, None);
    let mut control = Control { target: Some(ErrorTarget::Rmse(0.01)), ..Control::default() };
    let err = session.render(&request).unwrap().complete(&mut control).err().expect("refused");
    assert!(err.to_string().contains("needs an error estimate"), "{err}");
    let mut control = Control { target: Some(ErrorTarget::PointStdError(0.01)), ..Control::default() };
    let image = ImageRequest { settings: Settings { spp: 16, ..Settings::default() }, ..request };
    assert!(session.render(&image).unwrap().complete(&mut control).is_err());
}

#[test]
fn probes_with_a_target_stop_when_every_point_meets_it() {
    let (scene, probes, _) = floor_under_sphere(20);
    let session = Session::new(&device(DeviceKind::Cpu), scene, &Default::default()).unwrap();
    let settings = Settings {
        sampling: Sampling {
            sampler: Sampler::Sobol,
            replicate: Some(16),
            hemisphere: Hemisphere::Cosine,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut control = Control { target: Some(ErrorTarget::PointStdError(0.005)), ..Control::default() };
    let out = session.probe_with(&probes, 1 << 16, &settings, &mut control).unwrap();
    let most = out.values.iter().map(|v| v.std_error).fold(0.0, f64::max);
    let samples = out.values[0].samples;
    assert!(most <= 0.005 && samples < 1 << 16, "max standard error {most} after {samples} samples");
    // One replicate fewer would not have met it: the render stopped at the first check
    // that met the target, not later.
    assert!(samples >= 8 * 16, "{samples} samples: fewer than eight replicates");
}

/// An adaptive render stopped part-way and resumed from its checkpoint stops sampling
/// the same pixels at the same points, and ends with the uninterrupted render's bits.
#[test]
fn adaptive_renders_resume_to_the_same_bits() {
    let mut scene = bunny();
    (scene.settings.width, scene.settings.height) = (32, 32);
    let settings = Settings {
        spp: 4096,
        sampling: Sampling { seed: 9, replicate: Some(16), ..scene.settings.sampling },
        ..scene.settings.clone()
    };
    let request = ImageRequest { camera: scene.camera, settings, samples: None };
    let control = || Control { target: Some(ErrorTarget::Rmse(0.008)), adaptive: true, ..Control::default() };
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        let whole = session.render(&request).unwrap().complete(&mut control()).unwrap();
        assert!(whole.stats.mean_samples_per_pixel < whole.stats.samples_per_pixel as f64, "{kind:?}: not adaptive");
        // Stopped inside a replicate, after some pixels stopped being sampled.
        let stop_at = whole.stats.samples_per_pixel - 24;
        let mut first = session.render(&request).unwrap();
        let mut c = Control { sizing: aorender::PassSizing::Fixed(5), ..control() };
        first.run_to(stop_at, &mut c).unwrap();
        let saved = Accumulation::from_bytes(&checkpoint_bytes(&first.accumulation().unwrap())).unwrap();
        assert!(saved.inactive().iter().any(|&off| off), "{kind:?}: no pixel had stopped");
        let mut resumed = session.render(&request).unwrap();
        resumed.resume(saved).unwrap();
        let out = resumed.complete(&mut control()).unwrap();
        assert_eq!(out.stats.samples_per_pixel, whole.stats.samples_per_pixel, "{kind:?}");
        assert!(out.film == whole.film, "{kind:?}: the resumed adaptive render differs from the whole one");
    }
}

/// Background pixels (whose footprint misses the bunny's boxes: their value is exact)
/// take one replicate in an adaptive render; no pixel whose rays ever meet the bunny is
/// among them (its converged value is exactly the background in every one), and they are
/// most of the background.
#[test]
fn background_pixels_of_an_adaptive_render_take_one_replicate() {
    let mut scene = bunny();
    (scene.settings.width, scene.settings.height) = (48, 48);
    let (w, h) = (scene.settings.width, scene.settings.height);
    let background = aorender::background_pixels(&scene, &scene.camera, w, h, 0.0);
    let reference = converged(&scene, 1024);
    let empty: Vec<bool> = reference.sum_sq.iter().map(|&s| s == 0.0).collect();
    let (clear, missed) = (background.iter().filter(|&&b| b).count(), empty.iter().filter(|&&e| e).count());
    eprintln!("{clear} of {} pixels clear, {missed} with no sample but the background in the reference", w * h);
    for i in 0..background.len() {
        assert!(!background[i] || empty[i], "pixel {i} is clear, but its rays met the bunny");
    }
    assert!(clear * 10 >= missed * 7, "{clear} pixels clear of {missed} that saw nothing");
    let settings = Settings {
        spp: 4096,
        sampling: Sampling { seed: 2, replicate: Some(16), ..scene.settings.sampling },
        ..scene.settings.clone()
    };
    let request = ImageRequest { camera: scene.camera, settings, samples: None };
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        let mut control = Control { target: Some(ErrorTarget::Rmse(0.008)), adaptive: true, ..Control::default() };
        let out = session.render(&request).unwrap().complete(&mut control).unwrap();
        assert_eq!(out.stats.ended_by, "target", "{kind:?}");
        let film = &out.film;
        for (i, &b) in background.iter().enumerate() {
            if b {
                assert_eq!((film.samples_of(i), film.sum[i]), (16, 0.0), "{kind:?} pixel {i}");
            } else if !empty[i] {
                assert!(film.samples_of(i) >= 8 * 16, "{kind:?} pixel {i}: {} samples", film.samples_of(i));
            }
        }
    }
}

/// Shards of an adaptive render (each deciding on its own samples, and running to the
/// end of its range when the target is not met there) merge exactly: in any order to the
/// same bits, each pixel's count the sum of its counts in the shards.
#[test]
fn adaptive_shards_merge_exactly_in_any_order() {
    let mut scene = bunny();
    (scene.settings.width, scene.settings.height) = (24, 24);
    let settings = Settings {
        spp: 768,
        sampling: Sampling { seed: 4, replicate: Some(16), ..scene.settings.sampling },
        ..scene.settings.clone()
    };
    let session = session(&scene, &Config::cpu());
    let mut shards = Vec::new();
    for (i, range) in [(0..384), (384..768)].into_iter().enumerate() {
        let request = ImageRequest { camera: scene.camera, settings: settings.clone(), samples: Some(range) };
        let mut control = Control { target: Some(ErrorTarget::Rmse(0.008)), adaptive: true, ..Control::default() };
        let out = session.render(&request).unwrap().complete(&mut control).unwrap();
        assert!(out.stats.adaptive, "shard {i} stopped no pixel");
        assert_eq!(out.stats.ended_by, "samples", "shard {i} met the target inside its range");
        shards.push((std::path::PathBuf::from(format!("shard{i}")), out.accumulation));
    }
    let forward = merge(&shards).unwrap();
    shards.reverse();
    let backward = merge(&shards).unwrap();
    assert!(forward.film == backward.film, "the merge depends on the order of the shards");
    let film = &forward.film;
    for i in 0..film.sum.len() {
        let counted: u64 = shards.iter().map(|(_, a)| a.film().unwrap().samples_of(i)).sum();
        assert_eq!(film.samples_of(i), counted, "pixel {i}");
    }
    assert!(film.rmse_estimate().is_some());
}
