//! Probes (`Session::probe`): AO at exact points against closed forms (albedo 1,
//! cosine-weighted visibility), on the CPU reference and the adapter, for every hemisphere
//! and unbiased sampler; and the same numbers on both.

mod common;
use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::gpu::layout::{FrameUniforms, GpuProbePoint};
use aorender::gpu::{GpuScene, GpuTarget};
use aorender::{Hemisphere, Probe, Sampler, Scene};
use common::*;
use glam::Vec3;

const SAMPLES: u32 = 1 << 14;

fn devices() -> Vec<Config> {
    let mut all = vec![Config::cpu()];
    if gpu_available() {
        all.push(Config::default());
    }
    all
}

/// A scene of `objects` (TOML `[[object]]` tables); the camera is unused by probes.
fn scene(objects: &str, max_distance: Option<f32>) -> Scene {
    let dir = temp_dir();
    let mut scene = scene_from_toml(
        &format!(
            "[camera]\ntype = \"orthographic\"\neye = [0.0, 5.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nheight = 1.0\n{objects}"
        ),
        dir.path(),
    );
    scene.settings.sampling.max_distance = max_distance;
    scene
}

fn plane(point: [f64; 3], normal: [f64; 3]) -> String {
    format!("[[object]]\ntype = \"plane\"\npoint = {point:?}\nnormal = {normal:?}\n")
}

fn sphere(center: [f64; 3], radius: f64) -> String {
    format!("[[object]]\ntype = \"sphere\"\ncenter = {center:?}\nradius = {radius}\n")
}

/// Probes `probes` of `scene` with every hemisphere, unbiased sampler and device, and
/// checks each value against `expected` within 4 standard errors. A zero standard error
/// demands the exact value.
fn check(what: &str, scene: &mut Scene, probes: &[Probe], expected: &[f64]) {
    for options in devices() {
        let session = session(scene, &options);
        for hemisphere in Hemisphere::ALL {
            for sampler in Sampler::ALL.into_iter().filter(|s| s.is_unbiased()) {
                scene.settings.sampling.hemisphere = hemisphere;
                scene.settings.sampling.sampler = sampler;
                let out = session.probe(probes, SAMPLES, &scene.settings).expect("probe runs");
                for (k, (v, &e)) in out.values.iter().zip(expected).enumerate() {
                    let tag = format!("{what} probe {k}, {} {} {}", label(&options), hemisphere.name(), sampler.name());
                    assert_eq!(v.samples, SAMPLES as u64, "{tag}");
                    assert!(
                        (v.mean - e).abs() <= 4.0 * v.std_error,
                        "{tag}: {} is not {e} ± 4·{:.2e}",
                        v.mean,
                        v.std_error
                    );
                }
            }
        }
    }
}

#[test]
fn unoccluded_plane_is_one() {
    let mut s = scene(&plane([0.0; 3], [0.0, 1.0, 0.0]), None);
    let probes = [Probe::new(Vec3::ZERO, Vec3::Y).unwrap(), Probe::new(Vec3::new(3.0, 0.0, -7.0), Vec3::Y).unwrap()];
    check("open plane", &mut s, &probes, &[1.0, 1.0]);
}

#[test]
fn plane_under_a_sphere_is_one_minus_cos_beta_r2_over_d2() {
    // Spheres wholly above the floor at distance d, angle β from the normal.
    for (r, d, beta_deg, scale) in [(0.5f64, 1.0f64, 30.0f64, 1.0f64), (0.3, 2.0, 60.0, 1.0), (0.5, 1.0, 0.0, 1e6)] {
        let beta = beta_deg.to_radians();
        let center = [d * beta.sin() * scale, d * beta.cos() * scale, 0.0];
        let mut s = scene(&(plane([0.0; 3], [0.0, 1.0, 0.0]) + &sphere(center, r * scale)), None);
        let expected = 1.0 - beta.cos() * (r / d).powi(2);
        check(
            &format!("sphere r {r} d {d} β {beta_deg}° ×{scale}"),
            &mut s,
            &[Probe::new(Vec3::ZERO, Vec3::Y).unwrap()],
            &[expected],
        );
    }
}

#[test]
fn floor_in_front_of_a_wall_is_one_half_at_any_distance() {
    for a in [1e-2f64, 1.0, 1e3] {
        let mut s = scene(&(plane([0.0; 3], [0.0, 1.0, 0.0]) + &plane([a, 0.0, 0.0], [-1.0, 0.0, 0.0])), None);
        check(&format!("wall at {a}"), &mut s, &[Probe::new(Vec3::ZERO, Vec3::Y).unwrap()], &[0.5]);
    }
}

#[test]
fn point_under_a_ceiling_is_h_over_r_squared() {
    for (h, r) in [(1.0f64, 2.0f64), (0.5, 4.0), (3.0, 3.0)] {
        let mut s = scene(&plane([0.0, h, 0.0], [0.0, -1.0, 0.0]), Some(r as f32));
        check(&format!("ceiling h {h} R {r}"), &mut s, &[Probe::new(Vec3::ZERO, Vec3::Y).unwrap()], &[(h / r).powi(2)]);
    }
}

#[test]
fn gpu_and_cpu_take_the_same_samples() {
    if !gpu_available() {
        return;
    }
    let mut s = scene(&(plane([0.0; 3], [0.0, 1.0, 0.0]) + &sphere([0.3, 0.8, 0.1], 0.4)), None);
    let probes: Vec<Probe> =
        (0..50).map(|i| Probe::new(Vec3::new(i as f32 * 0.05 - 1.0, 0.0, 0.2), Vec3::Y).unwrap()).collect();
    let (cpu_session, gpu_session) = (session(&s, &Config::cpu()), session(&s, &Config::default()));
    for sampler in Sampler::ALL {
        s.settings.sampling.sampler = sampler;
        let cpu = cpu_session.probe(&probes, 1000, &s.settings).unwrap();
        let gpu = gpu_session.probe(&probes, 1000, &s.settings).unwrap();
        for (k, (c, g)) in cpu.values.iter().zip(&gpu.values).enumerate() {
            assert!((c.mean - g.mean).abs() < 1e-6, "{} probe {k}: cpu {} gpu {}", sampler.name(), c.mean, g.mean);
        }
    }
}

/// A probe dispatch wider than the adapter's workgroups per dimension runs as rows of
/// workgroups (a 2-D dispatch), and points past one target's storage bindings are split
/// over several targets: with the workgroups per dimension forced down to 3 (192
/// invocations), and then the points per target to 150 as well, 700 points take the CPU
/// reference's samples, AO and bent normals alike (as `bake` traces them), so no point
/// is skipped, traced twice or given another point's sequence; also when the render is
/// stopped after its first pass and resumed from its accumulation.
#[test]
fn probes_past_one_dispatch_dimension_or_one_target_match_the_cpu() {
    if !gpu_available() {
        return;
    }
    let s = scene(&(plane([0.0; 3], [0.0, 1.0, 0.0]) + &sphere([0.3, 0.8, 0.1], 0.4)), None);
    let probes: Vec<Probe> = (0..700)
        .map(|i| {
            Probe::new(Vec3::new((i % 35) as f32 * 0.06 - 1.0, 0.0, (i / 35) as f32 * 0.06 - 0.6), Vec3::Y).unwrap()
        })
        .collect();
    let (cpu_session, gpu_session) = (session(&s, &Config::cpu()), session(&s, &Config::default()));
    let bent = |session: &aorender::Session| {
        let mut render = session.probe_render(&probes, 64, None, &s.settings, true).unwrap();
        render.run(&mut aorender::Control::default()).unwrap();
        let film = render.finish().unwrap().accumulation.film().unwrap();
        (aorender::probe_film_values(&film), aorender::probe_film_bent_normals(&film).unwrap())
    };
    let cpu = cpu_session.probe(&probes, 256, &s.settings).unwrap();
    assert!(cpu.values.iter().any(|v| v.mean < 0.9), "the sphere occludes some points");
    let cpu_bent = bent(&cpu_session);
    for points_per_target in [0, 150] {
        aorender::gpu::target::limit_probe_groups_per_dimension(3);
        aorender::gpu::target::limit_probe_points_per_target(points_per_target);
        let gpu = gpu_session.probe(&probes, 256, &s.settings);
        let gpu_bent = bent(&gpu_session);
        // Stopped after its first pass and resumed: each target takes its part of the sums.
        let mut first = gpu_session.probe_render(&probes, 64, None, &s.settings, true).unwrap();
        first.run(&mut aorender::Control { time_limit: Some(1e-9), ..aorender::Control::default() }).unwrap();
        let saved = first.finish().unwrap().accumulation;
        assert!(saved.samples() < 64, "{points_per_target} points a target: the first run stopped early");
        let mut resumed = gpu_session.probe_render(&probes, 64, None, &s.settings, true).unwrap();
        resumed.resume(saved).unwrap();
        resumed.run(&mut aorender::Control::default()).unwrap();
        let resumed_film = resumed.finish().unwrap().accumulation.film().unwrap();
        aorender::gpu::target::limit_probe_groups_per_dimension(0);
        aorender::gpu::target::limit_probe_points_per_target(0);
        let tag = format!("{points_per_target} points a target");
        for (k, (c, g)) in cpu.values.iter().zip(&gpu.unwrap().values).enumerate() {
            assert!((c.mean - g.mean).abs() < 1e-6, "{tag}: probe {k}: cpu {} gpu {}", c.mean, g.mean);
        }
        let resumed = aorender::probe_film_values(&resumed_film);
        assert_eq!((resumed.len(), gpu_bent.0.len()), (probes.len(), probes.len()), "{tag}");
        for (k, c) in cpu_bent.0.iter().enumerate() {
            assert!((c.mean - resumed[k].mean).abs() < 1e-6, "{tag}: resumed probe {k}: AO");
            assert!((c.mean - gpu_bent.0[k].mean).abs() < 1e-6, "{tag}: bent probe {k}: AO");
            let (c, g) = (cpu_bent.1[k], gpu_bent.1[k]);
            assert!((c - g).length() < 1e-4, "{tag}: bent probe {k}: {c} {g}");
        }
    }
}

/// Probe invocations that render several rounds add them in the same order as one
/// dispatch per round: the sums are the same bit for bit (uniform hemisphere, so that
/// every sample has its own value), with passes that the rounds per invocation do not
/// divide and a last round that only some lanes take.
#[test]
fn rounds_per_invocation_leave_the_sums_unchanged() {
    if !gpu_available() {
        return;
    }
    let mut s = scene(&(plane([0.0; 3], [0.0, 1.0, 0.0]) + &sphere([0.3, 1.5, 0.0], 0.6)), None);
    s.settings.sampling.hemisphere = Hemisphere::Uniform;
    let points: Vec<GpuProbePoint> = [[0.0, 0.0, 0.0], [1.0, 0.0, -0.5], [-2.0, 0.0, 3.0]]
        .iter()
        .map(|&p| GpuProbePoint {
            position: p,
            error: 0.0,
            normal: [0.0, 1.0, 0.0],
            _pad1: 0.0,
            surface_normal: [0.0; 3],
            _pad2: 0.0,
        })
        .collect();
    let (lanes, samples) = (4u32, 1001u32);
    let rounds = samples.div_ceil(lanes);
    let dev = gpu_adapter();
    let settings = &s.settings;
    for layout in [BvhLayout::Bvh2, BvhLayout::Cwbvh] {
        let bvh = GpuBvh::build(&s, layout, BuildQuality::default());
        let gs = GpuScene::upload(&dev.ctx, &s, &bvh, dev.ctx.preferred_storage(), None).unwrap();
        let e = aorender::film::value_exponent(aorender::accumulation::MAX_PROBE_SAMPLE);
        let frame =
            FrameUniforms::probes(settings, lanes, points.len() as u32, samples, gs.node_count, gs.plane_count, e);
        let mut sums = Vec::new();
        for per in [1, 5, u32::MAX] {
            let mut renderer = GpuTarget::probes(
                &dev,
                &gs,
                frame,
                settings.sampling.sampler,
                settings.sampling.hemisphere,
                &points,
                false,
            )
            .unwrap();
            let per = renderer.set_samples_per_invocation(per);
            let mut done = 0;
            while done < rounds {
                let count = (rounds - done).min(37);
                renderer.render_pass(done, count).unwrap();
                done += count;
            }
            sums.push((per, renderer.read_film(0).unwrap()));
        }
        assert!(sums[2].0 > 37, "{layout:?}: only {} rounds per invocation were set", sums[2].0);
        for (per, film) in &sums[1..] {
            assert_eq!(film.sum, sums[0].1.sum, "{layout:?}: {per} rounds per invocation");
            assert_eq!(film.sum_sq, sums[0].1.sum_sq, "{layout:?}: {per} rounds per invocation");
        }
    }
}
