//! The statistics a GPU keeps on the device: the exact sums it folds its blocks and
//! replicates into are the CPU reference's integers bit for bit, the image-level sums its
//! checks reduce are the host's within their f32 rounding, an adaptive render's decisions
//! taken on the device are the host rule's bit for bit, and target renders resumed from a
//! checkpoint end with the uninterrupted render's bits.

mod common;

use aorender::Sampling;
use aorender::accumulation::max_sample_value;
use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::film::{ExactSums, SampleRange};
use aorender::gpu::stats::{AdaptQuery, AdaptSums, Stop};
use aorender::{
    Accumulation, Control, DeviceKind, ErrorTarget, ImageRequest, PassSizing, RunEnd, Sampler, Scene, Settings,
};
use common::{Config, gpu_available, gpu_device_with, gpu_image, repo, session};

/// The bunny, framed bare, at `w`×`h` with AO rays of at most 0.05.
fn bunny(w: u32, h: u32) -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (scene.settings.width, scene.settings.height) = (w, h);
    scene.settings.sampling.max_distance = Some(0.05);
    scene
}

/// The devices a test runs on: the CPU reference, and the GPU where there is one.
fn kinds() -> Vec<DeviceKind> {
    let mut k = vec![DeviceKind::Cpu];
    if gpu_available() {
        k.push(DeviceKind::Gpu);
    }
    k
}

/// On an image whose pixel count is no multiple of a workgroup, for independent samples
/// and replicates of Sobol and stratified points, with samples past a block and a
/// replicate cut short at the end: the GPU's exact sums (folded on the device) are the
/// CPU reference's (added on the host) integer for integer, and the device's Σv, Σv² and
/// Σ mean agree with the host's f64 ones within the f32 rounding of each pixel's terms.
#[test]
fn device_sums_are_the_host_sums_and_checks_reduce_them() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    let scene = bunny(29, 23);
    let cpu = session(&scene, &Config::cpu());
    let gpu = session(&scene, &Config { device: DeviceKind::Gpu, ..Default::default() });
    for (sampler, replicate, spp) in
        [(Sampler::Independent, None, 261), (Sampler::Sobol, Some(4), 46), (Sampler::Stratified, Some(16), 272)]
    {
        let what = format!("{} in replicates of {replicate:?}, {spp} spp", sampler.name());
        let settings = Settings {
            spp,
            sampling: Sampling { sampler, replicate, seed: 7, ..scene.settings.sampling },
            ..scene.settings.clone()
        };
        let request = ImageRequest { camera: scene.camera, settings, samples: None };
        let reference = cpu.render(&request).unwrap().complete(&mut Control::default()).unwrap();
        let mut render = gpu.render(&request).unwrap();
        render.run(&mut Control { sizing: PassSizing::Fixed(7), ..Control::default() }).unwrap();
        let sums = render.device_check_sums().unwrap().expect("the GPU keeps an image's sums");
        let out = render.finish().unwrap();
        assert!(out.accumulation.exact() == reference.accumulation.exact(), "{what}: the device's integers differ");
        assert!(out.film == reference.film, "{what}: the films differ");

        // The host's sums, and a bound on the f32 rounding of each pixel's terms: its
        // two terms (the replicates' or samples' second moment and k m² or n m²) are
        // each within a few ulps, 2^-21 of their size.
        let film = &out.film;
        let (mean, se) = (film.mean(), film.std_error());
        let n = film.samples as f64;
        let (mut v_sum, mut v_sq, mut tolerance) = (0.0, 0.0, 0.0);
        for i in 0..mean.len() {
            let v = se[i] * se[i];
            let terms = match replicate {
                Some(b) => {
                    let (b, k) = (b as f64, film.replicates as f64);
                    (film.replicate_sq[i] / (b * b) + k * mean[i] * mean[i]) / (k - 1.0) * b / n
                }
                None => (film.sum_sq[i] + n * mean[i] * mean[i]) / (n - 1.0) / n,
            };
            let t = terms * 2f64.powi(-21);
            (v_sum, v_sq, tolerance) = (v_sum + v, v_sq + v * v, tolerance + t);
        }
        let means: f64 = mean.iter().sum();
        eprintln!(
            "{what}: Σv {:.6e} on the device, {v_sum:.6e} on the host (tolerance {tolerance:.1e}); Σ mean {:.6} and {means:.6}",
            sums.variance, sums.mean
        );
        assert_eq!(sums.pixels, mean.len() as u64, "{what}");
        assert!(tolerance < 1e-3 * v_sum, "{what}: a tolerance of {tolerance} cannot tell Σv = {v_sum} apart");
        assert!((sums.variance - v_sum).abs() <= tolerance, "{what}: Σv {} against {v_sum}", sums.variance);
        let sq_tolerance = 2.0 * tolerance * se.iter().map(|e| e * e).fold(0.0, f64::max) + 1e-4 * v_sq;
        assert!((sums.variance_sq - v_sq).abs() <= sq_tolerance, "{what}: Σv² {} against {v_sq}", sums.variance_sq);
        assert!((sums.mean - means).abs() <= 1e-5 * means, "{what}: Σ mean {} against {means}", sums.mean);
    }
}

/// The bytes of `acc` as a checkpoint file, read back.
fn through_checkpoint(acc: &Accumulation) -> Accumulation {
    let dir = common::temp_dir();
    let path = dir.path().join("c.ck");
    acc.write(&path).unwrap();
    Accumulation::from_bytes(&std::fs::read(&path).unwrap()).unwrap()
}

/// A render with an error target stopped part-way (inside a replicate, past several
/// checks), saved and resumed stops at the same sample and ends with the uninterrupted
/// render's bits, on the CPU reference and on the GPU (whose sums and checks are on the
/// device), for independent samples and Sobol replicates.
#[test]
fn target_renders_resume_to_the_same_bits() {
    let scene = bunny(24, 24);
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        for (sampler, replicate) in [(Sampler::Independent, None), (Sampler::Sobol, Some(16))] {
            let what = format!("{kind:?} {}", sampler.name());
            let settings = Settings {
                spp: 1 << 14,
                sampling: Sampling { sampler, replicate, seed: 4, ..scene.settings.sampling },
                ..scene.settings.clone()
            };
            let request = ImageRequest { camera: scene.camera, settings, samples: None };
            let control = || Control { target: Some(ErrorTarget::Rmse(0.01)), ..Control::default() };
            let whole = session.render(&request).unwrap().complete(&mut control()).unwrap();
            assert_eq!(whole.stats.ended_by, "target", "{what}");
            let spp = whole.stats.samples_per_pixel;
            assert!((8 * 16..1 << 14).contains(&spp), "{what}: stopped at {spp}");
            let mut first = session.render(&request).unwrap();
            let stop_at = spp - 21;
            first.run_to(stop_at, &mut Control { sizing: PassSizing::Fixed(5), ..control() }).unwrap();
            assert_eq!(first.samples(), stop_at, "{what}: the target stopped the first part");
            let saved = through_checkpoint(&first.accumulation().unwrap());
            let mut resumed = session.render(&request).unwrap();
            resumed.resume(saved).unwrap();
            let out = resumed.complete(&mut control()).unwrap();
            assert_eq!(out.stats.samples_per_pixel, spp, "{what}");
            assert!(out.film == whole.film, "{what}: the resumed render differs from the whole one");
            assert!(out.accumulation.exact() == whole.accumulation.exact(), "{what}");
        }
    }
}

/// The statistics' JSON keeps its words now that the fields are typed: the settings'
/// names, the sky and error estimator described, what ended the render and its target
/// as a name and a value, on every device.
#[test]
fn statistics_json_holds_the_words_of_the_typed_fields() {
    let scene = bunny(12, 10);
    for kind in kinds() {
        let session = session(&scene, &Config { device: kind, ..Default::default() });
        let settings = Settings {
            sampling: Sampling { sampler: Sampler::Sobol, replicate: Some(4), seed: 2, ..scene.settings.sampling },
            spp: 1 << 12,
            ..scene.settings.clone()
        };
        let request = ImageRequest { camera: scene.camera, settings: settings.clone(), samples: None };
        let target = ErrorTarget::RelativeRmse(0.2);
        let runs = [
            (Control { target: Some(target), ..Control::default() }, "target"),
            (Control { time_limit: Some(0.0), sizing: PassSizing::Fixed(1), ..Control::default() }, "time limit"),
            (Control::default(), "samples"),
        ];
        for (mut control, ended_by) in runs {
            let out = session.render(&request).unwrap().complete(&mut control).unwrap();
            let json = serde_json::to_value(&out.stats).unwrap();
            let what = format!("{kind:?} ended by {ended_by}");
            assert_eq!(json["ended_by"], ended_by, "{what}");
            assert_eq!(json["hemisphere"], settings.sampling.hemisphere.name(), "{what}");
            assert_eq!(json["sampler"], "sobol", "{what}");
            assert_eq!(json["sky"], settings.sampling.sky.describe(), "{what}");
            assert_eq!(json["bvh_layout"], out.stats.bvh_layout.name(), "{what}");
            assert_eq!(json["error_estimator"], out.film.error_estimator().describe(), "{what}");
            let expected_target =
                if ended_by == "target" { serde_json::json!(["relative_rmse", 0.2]) } else { serde_json::Value::Null };
            assert_eq!(json["target"], expected_target, "{what}");
        }
    }
}

/// The checks of a target come after every stretch (replicate) up to the 32nd, then at
/// most a sixteenth of the stretches apart and at least a thirty-second: a render that
/// meets its target after k stretches stops within k / 16 more, and one of k stretches
/// checks about 16 log2(k / 16) times.
#[test]
fn target_checks_are_spaced_by_a_sixteenth_of_the_render() {
    let due: Vec<u64> = (1..=1u64 << 16).filter(|&k| aorender::render::check_due(k)).collect();
    assert!((1..=32).all(|k| due.contains(&k)), "not every stretch up to 32 is checked");
    for pair in due.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        assert!(b - a <= (a / 16).max(1), "checks at {a} and {b}: more than a sixteenth apart");
        assert!(a < 32 || (b - a) * 32 >= a, "checks at {a} and {b}: closer than a thirty-second");
    }
    assert!(due.len() <= 16 * 13, "{} checks in 2^16 stretches", due.len());
}

/// An adaptive render whose decisions a GPU takes on the device (its sums, counts and
/// allocation there, a few bytes read back a decision) decides as the CPU reference's
/// host rule does, pixel for pixel: on an image whose pixel count is no multiple of a
/// workgroup, in replicates of 4 and 16, both end with the same bits (the same pixels
/// stopped after the same replicates), and part-way the device's image-level sums of the
/// rule are the host's bit for bit. The device reads back less than one film a replicate,
/// which the host rule would need.
#[test]
fn adaptive_decisions_on_the_device_are_the_host_rules() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    let scene = bunny(29, 23);
    let cpu = session(&scene, &Config::cpu());
    let gpu = session(&scene, &Config { device: DeviceKind::Gpu, ..Default::default() });
    for (sampler, replicate, target) in [(Sampler::Sobol, 16, 0.01), (Sampler::Independent, 4, 0.015)] {
        let what = format!("{} in replicates of {replicate}", sampler.name());
        let sampling = Sampling { sampler, replicate: Some(replicate), seed: 3, ..scene.settings.sampling };
        let settings = Settings { sampling, spp: 1 << 13, ..scene.settings.clone() };
        let request = ImageRequest { camera: scene.camera, settings, samples: None };
        let control = || Control { target: Some(ErrorTarget::Rmse(target)), adaptive: true, ..Control::default() };
        let reference = cpu.render(&request).unwrap().complete(&mut control()).unwrap();
        let out = gpu.render(&request).unwrap().complete(&mut control()).unwrap();
        let (r, g) = (reference.accumulation.exact(), out.accumulation.exact());
        let stopped = r.stopped.iter().filter(|&&s| s).count();
        eprintln!(
            "{what}: {} spp, {:.1} on average, {stopped} of {} pixels stopped early; {} checks, {} bytes read back \
             on the device",
            out.stats.samples_per_pixel,
            out.stats.mean_samples_per_pixel,
            r.sum.len(),
            out.stats.checks,
            out.stats.readback_bytes
        );
        assert_eq!(reference.stats.ended_by, "target", "{what}");
        assert!(stopped > 0 && r.pixel_replicates.iter().any(|&k| k as u64 > 8), "{what}: nothing was adaptive");
        assert_eq!(g.stopped, r.stopped, "{what}: other pixels stopped");
        assert_eq!(g.pixel_replicates, r.pixel_replicates, "{what}: the pixels stopped after other replicates");
        assert!(out.accumulation.exact() == reference.accumulation.exact(), "{what}: the sums differ");
        assert!(out.film == reference.film, "{what}: the films differ");
        let replicates = out.stats.samples_per_pixel as u64 / replicate as u64;
        let film_bytes = 16 * r.sum.len() as u64;
        assert!(
            out.stats.readback_bytes < replicates * film_bytes,
            "{what}: {} bytes read back, not less than a film a replicate ({})",
            out.stats.readback_bytes,
            replicates * film_bytes
        );

        // Part-way, past the first decisions: the device's sums of the rule are the host's.
        let mut render = gpu.render(&request).unwrap();
        let part = (out.stats.samples_per_pixel / 2).next_multiple_of(replicate);
        render.run_to(part, &mut control()).unwrap();
        let device = render.device_adapt_sums().unwrap().expect("the GPU keeps an adaptive image's sums");
        let host = render.accumulation().unwrap().adapt_sums();
        assert_eq!(device, host, "{what}: the device's sums of the rule at {part} spp");
    }
}

/// The GPU sessions of `scene` whose workgroups' sums are taken by one invocation (lanes
/// in lockstep, `true`) and in shared memory (`false`): `stats.wgsl`'s two formulations,
/// whichever the adapter is.
fn both_formulations(scene: &Scene) -> Vec<(bool, aorender::Session)> {
    [true, false]
        .into_iter()
        .map(|cpu_lanes| {
            let dev =
                std::sync::Arc::into_inner(gpu_device_with(|ctx| ctx.set_cpu_lanes(cpu_lanes))).expect("one owner");
            let session = aorender::Session::new(&aorender::Device::from_gpu(dev), scene.clone(), &Default::default());
            (cpu_lanes, session.unwrap_or_else(|e| panic!("{e}")))
        })
        .collect()
}

/// An adaptive render on an image of many workgroups of 256 slots, some of them all
/// background: a check evaluates the rule again only for the pixels folded or stopped
/// since the last, and sums again only the workgroups beside one of them, keeping the
/// others' evaluations and sums. Stopped to check after every replicate from the first
/// decision on, the device's image-level sums of the rule are the host's bit for bit each
/// time, and the render ends with the CPU reference's bits, checked or not in between;
/// with the workgroups summed by one invocation and in shared memory alike.
#[test]
fn kept_evaluations_give_the_host_rules_at_every_check() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    let scene = bunny(96, 80);
    let cpu = session(&scene, &Config::cpu());
    let replicate = 8;
    let sampling = Sampling { sampler: Sampler::Sobol, replicate: Some(replicate), seed: 5, ..scene.settings.sampling };
    let settings = Settings { sampling, spp: 1 << 12, ..scene.settings.clone() };
    let request = ImageRequest { camera: scene.camera, settings, samples: None };
    let control = || Control { target: Some(ErrorTarget::Rmse(0.005)), adaptive: true, ..Control::default() };
    let reference = cpu.render(&request).unwrap().complete(&mut control()).unwrap();
    let r = reference.accumulation.exact();
    assert_eq!(reference.stats.ended_by, "target");
    // Workgroups whose pixels all stopped after their first replicate (background), and
    // pixels that went on past the first decisions: both kinds of workgroup are there.
    let background = r.pixel_replicates.chunks(256).filter(|g| g.iter().all(|&k| k <= 1)).count();
    let late = r.pixel_replicates.iter().filter(|&&k| k as u64 > 2 * 8).count();
    eprintln!(
        "{} spp, {:.1} on average; {background} of {} workgroups all background, {late} pixels past 16 replicates",
        reference.stats.samples_per_pixel,
        reference.stats.mean_samples_per_pixel,
        r.sum.len().div_ceil(256)
    );
    assert!(background > 0 && late > 0, "the image does not exercise kept workgroups");

    for (cpu_lanes, gpu) in both_formulations(&scene) {
        let what = if cpu_lanes { "one invocation a workgroup" } else { "workgroups in shared memory" };
        let mut render = gpu.render(&request).unwrap();
        let mut checked = 0;
        for k in 8.. {
            let end = render.run_to(k * replicate, &mut control()).unwrap();
            let device = render.device_adapt_sums().unwrap().expect("the GPU keeps an adaptive image's sums");
            let host = render.accumulation().unwrap().adapt_sums();
            assert_eq!(device, host, "{what}: the device's sums of the rule after {k} replicates");
            checked += 1;
            if end != RunEnd::Done {
                break;
            }
        }
        let out = render.finish().unwrap();
        eprintln!("{what}: {checked} checks held against the host's");
        let exact = out.accumulation.exact();
        assert!(exact == reference.accumulation.exact(), "{what}: the sums differ from the CPU reference's");
        assert_eq!(exact.stopped, r.stopped, "{what}: other pixels stopped");
        assert!(out.film == reference.film, "{what}: the films differ");
    }
}

/// What a check keeps from the last: the evaluations of the pixels neither folded nor
/// stopped since, and the sums of the workgroups none of whose pixels, nor those up to two
/// slots beside them in their row, changed. On a film of 119 workgroups of 256 slots,
/// whose rows of 203 pixels cross them, with pixels stopped a few at a time by the
/// device's own allocation, each check's image-level sums are those of the same check
/// keeping nothing, bit for bit; with the workgroups summed by one invocation and in
/// shared memory alike, each formulation's sums the other's.
#[test]
fn a_check_that_keeps_what_did_not_change_sums_as_one_that_keeps_nothing() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    let scene = bunny(203, 150);
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let mut all = Vec::new();
    for cpu_lanes in [true, false] {
        let dev = gpu_device_with(|ctx| ctx.set_cpu_lanes(cpu_lanes));
        let target = gpu_image(&dev, &scene, &bvh, None).unwrap_or_else(|e| panic!("{e}")).1;
        all.push(checks_keeping_and_not(target, &scene, cpu_lanes));
    }
    assert!(all[0] == all[1], "the two formulations' sums differ");
}

/// Each check's sums of a render on `target` (pixels stopped a few at a time by the
/// device's allocation), held against the same check keeping nothing.
fn checks_keeping_and_not(mut target: aorender::gpu::GpuTarget, scene: &Scene, cpu_lanes: bool) -> Vec<AdaptSums> {
    let what = if cpu_lanes { "one invocation a workgroup" } else { "workgroups in shared memory" };
    let max = max_sample_value(scene, scene.settings.background);
    let exponents = ExactSums::exponents(max);
    let replicate = 4;
    let query = AdaptQuery { replicate, range: SampleRange::Binary(max), width: 203 };
    let (mut sums, mut stopping, mut live) = (Vec::new(), 0, 203 * 150);
    for k in 1..=40u32 {
        target.render_pass((k - 1) * replicate, replicate).unwrap();
        target.fold(true, replicate).unwrap();
        if k < 3 {
            continue;
        }
        let (kept, _) = target.adapt_check(query, exponents).unwrap();
        target.forget_kept();
        let (fresh, _) = target.adapt_check(query, exponents).unwrap();
        assert_eq!(kept, fresh, "{what}: the check after {k} replicates");
        sums.push(kept);
        // The pixels whose σ̃ is at most k / 160 stop: a few more each replicate.
        let (stops, going) = target.allocate(query, exponents, 160.0, Stop::Always).unwrap();
        assert_eq!(stops + going, live, "the pixels still sampled");
        live = going;
        stopping += (stops > 0 && going > 0) as u32;
    }
    eprintln!("{what}: {} checks; {stopping} stopped some pixels and left others; {live} left", sums.len());
    assert!(stopping >= 10 && live > 0, "{what}: pixels did not stop a few at a time");
    sums
}
