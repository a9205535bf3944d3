//! Points on surfaces that are not vertices (`Session::locate`), and texels whose
//! interpolated normal is not their triangle's, on the CPU reference and the adapter:
//!
//! - points sampled uniformly on a real mesh's triangles (computed in f64, rounded to f32)
//!   read what the same points moved 10⁻⁴ × the diagonal along their normals read, each
//!   within 4 standard errors of the difference and in the mean, and none is dark where
//!   the moved one is open; taken as given, some are (the test can fail); GPU and CPU
//!   agree bit for bit;
//! - on instances, spheres and planes alike;
//! - vertex points are left exactly as they are (today's values, bit for bit), points off
//!   every surface too, and are counted; the tolerance is checked;
//! - a convex mesh with smooth vertex normals bakes to exactly 1 in every texel with
//!   cosine sampling (and does not without mirroring directions above the surface), and
//!   over a floor every texel agrees with a probe at its point and normal.

mod common;
use aorender::Sampling;
use aorender::bake::{BakeAt, BakePlan, Placement, TextureOptions, TexturePlan, UvWrap, read_asset};
use aorender::{Control, Probe, ProbeValue, Scene, Session, Settings, SurfaceTolerance};
use common::*;
use glam::{DMat3, DVec3, Mat4, Vec3};
use std::path::Path;

/// splitmix64: a fixed stream of numbers in [0, 1).
struct Numbers(u64);

impl Numbers {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` points uniform on the surface of `triangles` (f64), with their triangles' unit
/// normals.
fn sample_on(triangles: &[[DVec3; 3]], count: usize, seed: u64) -> Vec<(DVec3, DVec3)> {
    let mut cdf = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for t in triangles {
        total += (t[1] - t[0]).cross(t[2] - t[0]).length();
        cdf.push(total);
    }
    let mut rng = Numbers(seed);
    (0..count)
        .map(|_| {
            let u = rng.next() * total;
            let t = triangles[cdf.partition_point(|&c| c < u).min(triangles.len() - 1)];
            let (r1, r2) = (rng.next().sqrt(), rng.next());
            let p = t[0] * (1.0 - r1) + t[1] * (r1 * (1.0 - r2)) + t[2] * (r1 * r2);
            (p, (t[1] - t[0]).cross(t[2] - t[0]).normalize())
        })
        .collect()
}

/// The probes at `points` rounded to f32, and at the same points moved `by` along their
/// normals.
fn probes_and_moved(points: &[(DVec3, DVec3)], by: f64) -> (Vec<Probe>, Vec<Probe>) {
    points
        .iter()
        .map(|&(p, n)| {
            (Probe::new(p.as_vec3(), n.as_vec3()).unwrap(), Probe::new((p + by * n).as_vec3(), n.as_vec3()).unwrap())
        })
        .unzip()
}

fn values(session: &Session, probes: &[Probe], samples: u32, seed: u32) -> Vec<ProbeValue> {
    let settings = Settings { sampling: Sampling { seed, ..Sampling::default() }, ..Settings::default() };
    session.probe(probes, samples, &settings).expect("probe runs").values
}

/// Each value within 4 standard errors of its reference (of the difference), the means
/// too, and no point below 0.05 whose reference is above 0.5. Returns the points that
/// fail, for a negative control.
fn disagreements(values: &[ProbeValue], reference: &[ProbeValue]) -> Vec<usize> {
    let mut bad = Vec::new();
    for (k, (a, b)) in values.iter().zip(reference).enumerate() {
        let se = (a.std_error.powi(2) + b.std_error.powi(2)).sqrt();
        if (a.mean - b.mean).abs() > 4.0 * se || (a.mean < 0.05 && b.mean > 0.5) {
            bad.push(k);
        }
    }
    bad
}

fn check_against_moved(what: &str, values: &[ProbeValue], reference: &[ProbeValue]) {
    let bad = disagreements(values, reference);
    assert!(
        bad.is_empty(),
        "{what}: {} of {} points disagree with the moved points, the first {}: {:?} against {:?}",
        bad.len(),
        values.len(),
        bad[0],
        values[bad[0]],
        reference[bad[0]]
    );
    let n = values.len() as f64;
    let mean = |v: &[ProbeValue]| v.iter().map(|v| v.mean).sum::<f64>() / n;
    let se =
        values.iter().zip(reference).map(|(a, b)| a.std_error.powi(2) + b.std_error.powi(2)).sum::<f64>().sqrt() / n;
    let (a, b) = (mean(values), mean(reference));
    assert!((a - b).abs() <= 4.0 * se, "{what}: mean {a} against the moved points' {b} ± 4·{se:.2e}");
}

/// `a` and `b` are the same probes, naming the first that differs.
fn assert_same(a: &[Probe], b: &[Probe], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    if let Some(k) = (0..a.len()).find(|&k| a[k] != b[k]) {
        panic!("{what}: probe {k} is {:?}, not {:?}", a[k], b[k]);
    }
}

fn teapot() -> Scene {
    Scene::load(&repo().join("scenes/teapot.obj")).expect("teapot loads")
}

fn diagonal(scene: &Scene) -> f64 {
    let b = scene.bounds().expect("bounds");
    (b.max - b.min).as_dvec3().length()
}

#[test]
fn points_sampled_on_a_mesh_read_what_points_just_above_it_read() {
    let scene = teapot();
    let triangles: Vec<[DVec3; 3]> = scene.triangles.iter().map(|t| t.v.map(Vec3::as_dvec3)).collect();
    let points = sample_on(&triangles, 2000, 7);
    let (given, moved) = probes_and_moved(&points, 1e-4 * diagonal(&scene));
    let mut located_values = Vec::new();
    for config in [Config::cpu()].into_iter().chain(gpu_available().then(Config::default)) {
        let session = session(&scene, &config);
        let located = session.locate(&given, SurfaceTolerance::Relative).unwrap();
        assert_eq!(located.off_surface(), 0, "{}: every sampled point is on the mesh", label(&config));
        let reference = values(&session, &moved, 256, 3);
        let found = values(&session, &located.probes, 256, 3);
        check_against_moved(&format!("teapot, {}", label(&config)), &found, &reference);
        // The points as given: some sit under their triangles and read dark.
        let as_given = values(&session, &given, 256, 3);
        let dark = disagreements(&as_given, &reference);
        assert!(!dark.is_empty(), "{}: no point taken as given disagrees: the control is void", label(&config));
        located_values.push(found);
    }
    if let [cpu, gpu] = &located_values[..] {
        assert_eq!(cpu, gpu, "the adapter's values are the CPU reference's, bit for bit");
    }
}

/// A scene file of `objects` in `dir`, the teapot copied beside it.
fn scene_file(dir: &Path, objects: &str) -> Scene {
    std::fs::copy(repo().join("scenes/teapot.obj"), dir.join("teapot.obj")).unwrap();
    let camera = "[camera]\ntype = \"perspective\"\nfov = 40.0\neye = [0.0, 3.0, 6.0]\nlook_at = [0.0, 0.0, 0.0]\n";
    scene_from_toml(&format!("{camera}{objects}"), dir)
}

#[test]
fn points_on_instances_spheres_and_planes_are_found() {
    let dir = temp_dir();
    let scene = scene_file(
        dir.path(),
        r#"
[[object]]
type = "mesh"
file = "teapot.obj"
transform = { scale = 0.4, rotate = [10.0, 20.0, 30.0], translate = [2.0, 0.0, 0.0] }
[[object]]
type = "mesh"
file = "teapot.obj"
transform = { scale = [0.3, 0.5, 0.4], rotate = [0.0, 45.0, 0.0], translate = [-2.0, 0.0, 0.5] }
[[object]]
type = "sphere"
center = [0.0, 0.7, -1.5]
radius = 0.6
[[object]]
type = "plane"
point = [0.0, -0.3, 0.0]
normal = [0.1, 1.0, 0.05]
"#,
    );
    assert_eq!(scene.instances.len(), 2, "the teapot placed twice is instanced");
    let mut points = Vec::new();
    for (k, instance) in scene.instances.iter().enumerate() {
        let m = instance.to_world.as_dmat4();
        let (linear, t) = (DMat3::from_mat4(m), m.w_axis.truncate());
        let world: Vec<[DVec3; 3]> = scene.meshes[instance.mesh as usize]
            .triangles
            .iter()
            .map(|tri| tri.map(|v| linear * v.as_dvec3() + t))
            .collect();
        points.extend(sample_on(&world, 400, 11 + k as u64));
    }
    let mut rng = Numbers(5);
    let sphere = scene.spheres[0];
    let plane = scene.planes[0];
    let (c, r) = (sphere.center.as_dvec3(), sphere.radius as f64);
    let n = plane.normal.as_dvec3().normalize();
    let (t1, t2) = (n.any_orthonormal_pair().0, n.any_orthonormal_pair().1);
    for _ in 0..300 {
        let z = 2.0 * rng.next() - 1.0;
        let phi = std::f64::consts::TAU * rng.next();
        let u = DVec3::new((1.0 - z * z).sqrt() * phi.cos(), z, (1.0 - z * z).sqrt() * phi.sin());
        points.push((c + r * u, u));
        let (a, b) = (6.0 * rng.next() - 3.0, 6.0 * rng.next() - 3.0);
        points.push((plane.point.as_dvec3() + a * t1 + b * t2, n));
    }
    let (given, moved) = probes_and_moved(&points, 1e-4 * 6.0);
    let mut located_values = Vec::new();
    for config in [Config::cpu()].into_iter().chain(gpu_available().then(Config::default)) {
        let session = session(&scene, &config);
        let located = session.locate(&given, SurfaceTolerance::Relative).unwrap();
        assert_eq!(located.off_surface(), 0, "{}: every point is on a surface", label(&config));
        let reference = values(&session, &moved, 256, 3);
        let found = values(&session, &located.probes, 256, 3);
        check_against_moved(&format!("instances, sphere and plane, {}", label(&config)), &found, &reference);
        located_values.push(found);
    }
    if let [cpu, gpu] = &located_values[..] {
        assert_eq!(cpu, gpu, "the adapter's values are the CPU reference's, bit for bit");
    }
}

#[test]
fn vertices_and_points_off_every_surface_are_left_as_they_are() {
    let scene = teapot();
    let path = repo().join("scenes/teapot.obj");
    let asset = read_asset(&path).unwrap();
    let plan = BakePlan::new(
        asset.meshes().iter().map(|m| (m, Placement { to_world: Mat4::IDENTITY, instanced: false })),
        BakeAt::Vertices,
    );
    let session = session(&scene, &Config::cpu());
    // The bake's own vertex probes: exactly on their triangles, their values today's bit for bit.
    let located = session.locate(&plan.probes, SurfaceTolerance::Relative).unwrap();
    assert_eq!(located.off_surface(), 0);
    assert_same(&located.probes, &plan.probes, "vertex probes are left exactly as they are");
    // Points 1 % of the diagonal off the mesh (and one far away): on no surface, as given.
    let d = diagonal(&scene);
    let off: Vec<Probe> = plan.probes[..50]
        .iter()
        .map(|p| Probe::new(p.position + (0.01 * d) as f32 * p.normal, p.normal).unwrap())
        .chain([Probe::new(Vec3::splat(1e3), Vec3::Y).unwrap()])
        .collect();
    let mixed: Vec<Probe> = off.iter().chain(&plan.probes[50..60]).copied().collect();
    let located = session.locate(&mixed, SurfaceTolerance::Relative).unwrap();
    assert_eq!(located.off_surface(), off.len(), "the points off the mesh are counted");
    assert_same(&located.probes, &mixed, "points off the mesh are left as they are");
    assert_eq!(located.on_surface, [vec![false; off.len()], vec![true; 10]].concat());
    // A tolerance of 1 % of the diagonal takes them (but not the far one).
    let wide = session.locate(&off, SurfaceTolerance::distance((0.011 * d) as f32).unwrap()).unwrap();
    assert_eq!(wide.off_surface(), 1);
    assert!(wide.probes[..50].iter().all(|p| p.error > (0.009 * d) as f32), "offset by their distances");
}

#[test]
fn bad_tolerances_are_refused() {
    for bad in [-1.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let e = SurfaceTolerance::distance(bad).unwrap_err().to_string();
        assert!(e.contains("surface tolerance must be a finite distance of at least 0"), "{bad}: {e}");
    }
    let session = session(&teapot(), &Config::cpu());
    let probe = [Probe::new(Vec3::ZERO, Vec3::Y).unwrap()];
    assert!(session.locate(&probe, SurfaceTolerance::Distance(-1.0)).is_err());
    assert_eq!(SurfaceTolerance::distance(0.0).unwrap(), SurfaceTolerance::Distance(0.0));
}

/// A UV sphere of `segments` × `rings` quads (fans at the poles) around `centre`, with
/// smooth vertex normals (`vn`, the unit position) and latitude-longitude `vt`.
fn uv_sphere_obj(path: &Path, centre: [f64; 3], radius: f64, segments: usize, rings: usize) {
    let mut text = String::new();
    let position = |r: usize, s: usize| -> usize {
        match r {
            0 => 1,
            r if r == rings => 2,
            r => 3 + (r - 1) * segments + s % segments,
        }
    };
    let mut dirs = vec![DVec3::Y, -DVec3::Y];
    for r in 1..rings {
        for s in 0..segments {
            let (theta, phi) =
                (std::f64::consts::PI * r as f64 / rings as f64, std::f64::consts::TAU * s as f64 / segments as f64);
            dirs.push(DVec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin()));
        }
    }
    for d in &dirs {
        let p = DVec3::from(centre) + radius * *d;
        text += &format!("v {} {} {}\nvn {} {} {}\n", p.x, p.y, p.z, d.x, d.y, d.z);
    }
    for r in 0..=rings {
        for s in 0..=segments {
            text += &format!("vt {} {}\n", s as f64 / segments as f64, 1.0 - r as f64 / rings as f64);
        }
    }
    let corner = |r: usize, s: usize| {
        let (v, t) = (position(r, s), 1 + r * (segments + 1) + s);
        format!("{v}/{t}/{v}")
    };
    for r in 0..rings {
        for s in 0..segments {
            let (a, b, c, d) = (corner(r, s), corner(r + 1, s), corner(r + 1, s + 1), corner(r, s + 1));
            if r > 0 {
                text += &format!("f {a} {c} {d}\n");
            }
            if r + 1 < rings {
                text += &format!("f {a} {b} {c}\n");
            }
        }
    }
    std::fs::write(path, text).unwrap();
}

/// The texels of `obj` baked into a `size`² texture (one point a texel), traced in `scene`.
fn texel_probes(obj: &Path, size: u32) -> Vec<Probe> {
    let asset = read_asset(obj).unwrap();
    let meshes: Vec<_> =
        asset.meshes().iter().map(|m| (m, Placement { to_world: Mat4::IDENTITY, instanced: false })).collect();
    let options =
        TextureOptions { width: size, height: size, uv_set: 0, points: 1, padding: 2, wrap: UvWrap::File, seed: 0 };
    TexturePlan::new(&meshes, &options, false, u64::MAX).unwrap().probes
}

fn bake_values(session: &Session, probes: &[Probe], samples: u32, seed: u32) -> Vec<ProbeValue> {
    let settings = Settings { sampling: Sampling { seed, ..Sampling::default() }, ..Settings::default() };
    let mut render = session.probe_render(probes, samples, None, &settings, false).unwrap();
    render.run(&mut Control::default()).unwrap();
    render.finish().unwrap().accumulation.probe_values().unwrap()
}

#[test]
fn a_convex_mesh_with_smooth_normals_bakes_to_exactly_one() {
    let dir = temp_dir();
    let obj = dir.path().join("sphere.obj");
    uv_sphere_obj(&obj, [0.0; 3], 1.0, 8, 6);
    let scene = Scene::load(&obj).unwrap();
    let probes = texel_probes(&obj, 48);
    // The interpolated normals lean far from their triangles'.
    let lean =
        probes.iter().filter(|p| p.surface_normal != Vec3::ZERO && p.normal.dot(p.surface_normal) < 0.95).count();
    assert!(lean > probes.len() / 10, "only {lean} of {} texels lean more than 18°", probes.len());
    let mut all = Vec::new();
    for config in [Config::cpu()].into_iter().chain(gpu_available().then(Config::default)) {
        let session = session(&scene, &config);
        let values = bake_values(&session, &probes, 64, 0);
        let below = values.iter().filter(|v| v.mean != 1.0).count();
        assert_eq!(below, 0, "{}: {below} of {} texels are not exactly 1", label(&config), values.len());
        // Without mirroring, rays about the interpolated normal enter the sphere.
        let unmirrored: Vec<Probe> = probes.iter().map(|p| Probe { surface_normal: Vec3::ZERO, ..*p }).collect();
        let control = bake_values(&session, &unmirrored, 64, 0);
        assert!(control.iter().any(|v| v.mean < 1.0), "{}: the control is void", label(&config));
        all.push(values);
    }
    if let [cpu, gpu] = &all[..] {
        assert_eq!(cpu, gpu, "the adapter's values are the CPU reference's, bit for bit");
    }
}

#[test]
fn texels_over_a_floor_agree_with_probes_at_their_points() {
    let dir = temp_dir();
    uv_sphere_obj(&dir.path().join("sphere.obj"), [0.0, 1.2, 0.0], 1.0, 8, 6);
    let scene = scene_from_toml(
        "[camera]\ntype = \"perspective\"\nfov = 40.0\neye = [0.0, 3.0, 6.0]\nlook_at = [0.0, 0.0, 0.0]\n[[object]]\ntype = \"mesh\"\nfile = \"sphere.obj\"\n\
         [[object]]\ntype = \"plane\"\npoint = [0.0, 0.0, 0.0]\nnormal = [0.0, 1.0, 0.0]\n",
        dir.path(),
    );
    let texels = texel_probes(&dir.path().join("sphere.obj"), 40);
    for config in [Config::cpu()].into_iter().chain(gpu_available().then(Config::default)) {
        let session = session(&scene, &config);
        let baked = bake_values(&session, &texels, 256, 0);
        // The same points and normals as a user would give them: found on the sphere.
        let given: Vec<Probe> = texels.iter().map(|p| Probe::new(p.position, p.normal).unwrap()).collect();
        let located = session.locate(&given, SurfaceTolerance::Relative).unwrap();
        assert_eq!(located.off_surface(), 0);
        let probed = values(&session, &located.probes, 256, 1);
        let bad = disagreements(&baked, &probed);
        assert!(
            bad.is_empty(),
            "{}: {} of {} texels disagree with the probes, the first: {:?} against {:?}",
            label(&config),
            bad.len(),
            baked.len(),
            baked[bad[0]],
            probed[bad[0]]
        );
        assert!(baked.iter().any(|v| v.mean < 0.9), "the floor occludes the sphere's underside");
    }
}
