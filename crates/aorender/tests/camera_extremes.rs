//! The extremes that need the camera path (hit points computed from rays, then offset):
//! 2^20 samples per pixel accumulated in passes, and grazing camera rays, at every scale
//! and position of `aorender::closed_form::Variant`.

mod common;
use aorender::closed_form::Variant;
use aorender::gpu::MAX_PASS_SAMPLES;
use aorender::scene::{Camera, Plane, Projection, Settings, Sphere};
use aorender::{Control, DeviceKind, Film, Hemisphere, PassSizing, Sampler, Scene};
use common::*;
use glam::{DVec3, Vec3};

fn scene(camera: Camera, planes: Vec<Plane>, spheres: Vec<Sphere>, width: u32, spp: u32) -> Scene {
    Scene {
        name: "extreme".into(),
        path: None,
        camera,
        origin: DVec3::ZERO,
        settings: Settings { width, height: width, spp, ..Default::default() },
        triangles: Vec::new(),
        meshes: Vec::new(),
        instances: Vec::new(),
        spheres,
        planes,
        warnings: Vec::new(),
        mesh_objects: Vec::new(),
    }
}

/// Mean over the image of per-pixel means, and its standard error (every pixel estimates
/// the same value).
fn mean_and_error(film: &Film) -> (f64, f64) {
    (film.image_mean(), image_mean_std_error(film))
}

/// 2^20 samples per pixel of a 4×4 view, a few nanometres wide, of one point on a floor
/// under a sphere (1 − cos β (r/d)²), on the CPU reference and on the adapter: at every
/// power of 4 from 2^10 the image mean is within 4 standard errors of the closed form and
/// the standard error times √N stays put (the error shrinks as 1/√N over the whole range),
/// and the adapter's sums equal the reference's bit for bit (both add the same samples as
/// integers). The uniform hemisphere gives every sample its own value (2 cos θ or 0).
#[test]
fn two_to_the_twenty_samples_converge_to_the_closed_form() {
    const SPP: u32 = 1 << 20;
    // Seen obliquely from the side away from the sphere, so no view ray comes near it.
    let camera = Camera {
        eye: DVec3::new(-3.0, 3.0, 0.0),
        look_at: DVec3::ZERO,
        up: Vec3::Y,
        projection: Projection::Orthographic { height: 1e-6 },
    };
    let floor = Plane { normal: Vec3::Y, point: Vec3::ZERO, albedo: 1.0 };
    let sphere = Sphere { center: Vec3::new(0.5, 0.875, 0.0), radius: 0.5, albedo: 1.0 };
    let mut s = scene(camera, vec![floor], vec![sphere], 4, SPP);
    s.settings.sampling.sampler = Sampler::Independent;
    s.settings.sampling.hemisphere = Hemisphere::Uniform;
    let to_centre = sphere.center.as_dvec3();
    let (h, d, r) = (to_centre.y, to_centre.length(), 0.5f64);
    let expected = 1.0 - h * r * r / (d * d * d);
    let checkpoints: Vec<u32> = (10..=20).step_by(2).map(|k| 1u32 << k).collect();

    // The films at each checkpoint, from one render run on in stretches.
    let films_at = |kind: DeviceKind| -> Vec<Film> {
        let session = session(&s, &Config { device: kind, ..Default::default() });
        let mut render = session.render(&session.default_request()).unwrap_or_else(|e| panic!("{e}"));
        let mut control = Control { sizing: PassSizing::Fixed(MAX_PASS_SAMPLES), ..Default::default() };
        checkpoints
            .iter()
            .map(|&target| {
                render.run_to(target, &mut control).unwrap_or_else(|e| panic!("{e}"));
                render.film().unwrap_or_else(|e| panic!("{e}"))
            })
            .collect()
    };
    let check = |film: &Film, what: &str, scaled: &mut Vec<f64>| {
        let (mean, se) = mean_and_error(film);
        let n = film.samples;
        eprintln!("{what} N = 2^{}: {mean:.7} ± {se:.2e}, expected {expected:.7}", n.trailing_zeros());
        assert!(se > 0.0);
        assert!((mean - expected).abs() <= 4.0 * se, "{what} at N = {n}: {mean} is not {expected} ± 4·{se}");
        scaled.push(se * (n as f64).sqrt());
    };
    let cpu_at = films_at(DeviceKind::Cpu);
    let mut cpu_scaled = Vec::new();
    for film in &cpu_at {
        check(film, "cpu", &mut cpu_scaled);
    }
    // σ = SE·√N is a property of the estimator: within 5% from 2^10 to 2^20 (its own
    // relative standard error at 2^10 × 16 pixels is under 1%).
    let (lo, hi) = cpu_scaled.iter().fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    assert!(hi / lo < 1.05, "cpu: σ·√N drifts: {cpu_scaled:?}");

    if !gpu_available() {
        return;
    }
    let mut gpu_scaled = Vec::new();
    for (k, film) in films_at(DeviceKind::Gpu).iter().enumerate() {
        check(film, "gpu", &mut gpu_scaled);
        // The same samples, added as integers: the same sums.
        assert_eq!(film.sum, cpu_at[k].sum, "sums at N = {}", checkpoints[k]);
        assert_eq!(film.sum_sq, cpu_at[k].sum_sq, "sums of squares at N = {}", checkpoints[k]);
    }
    let (lo, hi) = gpu_scaled.iter().fold((f64::MAX, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    assert!(hi / lo < 1.05, "gpu: σ·√N drifts: {gpu_scaled:?}");
}

/// Orthographic views of a floor in front of an infinite wall, the rays `angle` radians
/// above the floor: every hit, on the floor or on the wall, has AO 1/2. Self-intersection
/// at grazing hit points would pull the mean down; a leak would push it up. Every scale
/// and position, both devices.
#[test]
fn grazing_camera_rays_see_one_half_everywhere() {
    let mut devices = vec![DeviceKind::Cpu];
    if gpu_available() {
        devices.push(DeviceKind::Gpu);
    }
    for v in Variant::all().into_iter().filter(|v| v.axis == 1 && !v.negative) {
        // At 1e6 from the origin an ulp is 1/16, and a hit within half an ulp of the floor–
        // wall corner rounds onto it, where neither plane can occlude the other: the
        // translated view is made 64 times larger, so that its features span a thousand
        // ulps and such hits are a negligible fraction.
        let unit = if v.offset != 0.0 { 64.0 } else { 1.0 };
        let at = |p: DVec3| (p * v.scale * unit + DVec3::splat(v.offset)).as_vec3();
        for angle in [1e-2f64, 1e-4, 1e-6] {
            // Looking toward +x at the wall x = 4, down at `angle`, through the floor point
            // (0, 0, 0) from 1 above the floor (so that no view ray starts on the floor at 1e6
            // from the origin, where an ulp is 1/16), 1/sin(angle) away.
            let dir = DVec3::new(angle.cos(), -angle.sin(), 0.0);
            let camera = Camera {
                eye: at(-dir / angle.sin()).as_dvec3(),
                look_at: at(DVec3::ZERO).as_dvec3(),
                up: Vec3::Y,
                projection: Projection::Orthographic { height: (0.5 * v.scale * unit) as f32 },
            };
            let floor = Plane { normal: Vec3::Y, point: at(DVec3::ZERO), albedo: 1.0 };
            let wall = Plane { normal: -Vec3::X, point: at(DVec3::new(4.0, 0.0, 0.0)), albedo: 1.0 };
            let s = scene(camera, vec![floor, wall], Vec::new(), 16, 64);
            for &device in &devices {
                let film = render_on(&s, device);
                let (mean, se) = mean_and_error(&film);
                let what = format!("{} angle {angle:e} {device:?}", v.name());
                eprintln!("{what}: {mean:.5} ± {se:.1e}");
                assert!((mean - 0.5).abs() <= 4.0 * se, "{what}: {mean} is not 0.5 ± 4·{se}");
            }
        }
    }
}
