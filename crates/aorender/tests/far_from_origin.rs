//! Scenes far from the origin are rendered in a local frame: the same f32 geometry moved
//! far away, its camera and probe points with it, renders the film it has at the origin.
//!
//! - Moved by a multiple of the local origin's grid (983,040 = 15 × 2¹⁶ is one for any
//!   scene up to 2¹⁵ across), every coordinate moves back exactly and the film is the
//!   same bit for bit: a mesh (the bunny scaled by 10⁴), spheres and a plane (aobench,
//!   as it is and scaled by 10³), instanced meshes, probe values and a bake's film.
//! - Moved by 10⁶, which is not such a multiple for the bunny and the scaled aobench, the
//!   geometry lands near the local origin but not on the origin's place, and the film
//!   agrees within 4 standard errors of the difference of the image means. (Traced at
//!   10⁶ in f32, the bunny rendered 0.17 % brighter: 18.6 standard errors at 512 × 512.)
//! - Scenes near the origin are not moved, so their films are unchanged; a far render's
//!   checkpoint is identified by the scene's own coordinates and resumes to the same bits.

mod common;
use aorender::scene::Triangle;
use aorender::{Accumulation, Control, Film, Hemisphere, ImageRequest, Probe, Sampler, Scene, Session, Settings};
use common::*;
use glam::{DVec3, Vec3};

/// A multiple of 2¹⁶ near 10⁶: a multiple of the local origin's grid for every scene here.
const GRID_SHIFT: f32 = 983_040.0;
/// 10⁶: for the bunny and aobench scaled by 10³, not a multiple of the local origin's grid.
const SHIFT: f32 = 1e6;

/// `p` moved by `t` on every axis; panics unless the sum is exact in f32.
fn moved(p: Vec3, t: f32) -> Vec3 {
    let q = p + Vec3::splat(t);
    assert_eq!(q.as_dvec3(), p.as_dvec3() + DVec3::splat(t as f64), "{p} + {t} is not exact in f32");
    q
}

/// `scene` moved by `t` on every axis, its camera with it: the same f32 geometry.
fn translated(scene: &Scene, t: f32) -> Scene {
    let mut s = scene.clone();
    for tri in &mut s.triangles {
        tri.v = tri.v.map(|v| moved(v, t));
    }
    for sphere in &mut s.spheres {
        sphere.center = moved(sphere.center, t);
    }
    for plane in &mut s.planes {
        plane.point = moved(plane.point, t);
    }
    for instance in &mut s.instances {
        let w = instance.to_world.w_axis;
        instance.to_world.w_axis = moved(w.truncate(), t).extend(w.w);
    }
    s.camera.eye = moved(s.camera.eye.as_vec3(), t).as_dvec3();
    s.camera.look_at = moved(s.camera.look_at.as_vec3(), t).as_dvec3();
    s
}

/// Rounds each coordinate of `p` to a multiple of `step` (a power of two).
fn on_grid(p: Vec3, step: f64) -> Vec3 {
    ((p.as_dvec3() / step).round() * step).as_vec3()
}

/// The Stanford bunny scaled by 10⁴, its vertices and camera on the 1/16 grid (so that
/// they move by 10⁶ exactly), with a maximum AO distance of 625.6.
fn bunny() -> Scene {
    let bunny = Scene::load(&repo().join("scenes/bunny.obj")).expect("the bunny loads");
    let grid = 1.0 / 16.0;
    let triangles = bunny.triangles.iter().map(|t| Triangle { v: t.v.map(|v| on_grid(v * 1e4, grid)), ..*t });
    let mut scene = Scene::from_triangles("bunny", triangles.collect());
    scene.camera.eye = on_grid(scene.camera.eye.as_vec3(), grid).as_dvec3();
    scene.camera.look_at = on_grid(scene.camera.look_at.as_vec3(), grid).as_dvec3();
    scene.settings = Settings { width: 192, height: 192, spp: 256, max_distance: Some(625.6), ..Settings::default() };
    scene
}

/// aobench (three spheres on a plane) with every length multiplied by `scale`, the
/// spheres' centres on the 1/16 grid.
fn aobench(scale: f32) -> Scene {
    let mut scene = Scene::default_scene();
    for s in &mut scene.spheres {
        (s.center, s.radius) = (on_grid(s.center * scale, 1.0 / 16.0), s.radius * scale);
    }
    for p in &mut scene.planes {
        p.point *= scale;
    }
    scene.camera.look_at *= scale as f64;
    scene.settings = Settings { width: 96, height: 96, spp: 64, sampler: Sampler::Sobol, ..scene.settings };
    scene
}

/// Three placements of the floor and box: rotated and scaled, translated by multiples of
/// 1/16 (so that they move exactly).
fn instances() -> Scene {
    let dir = temp_dir();
    write_obj(&dir.path().join("mesh.obj"), &floor_and_box());
    let mut text = String::from(
        r#"
        [image]
        width = 64
        height = 48
        [sampling]
        spp = 64
        hemisphere = "uniform"
        [camera]
        type = "perspective"
        eye = [3.0, 4.0, 6.0]
        look_at = [0.0, 0.0, -0.5]
        fov = 50.0
        "#,
    );
    for t in [
        "{ rotate = [0.0, 0.0, 0.0] }",
        "{ scale = 0.6, rotate = [0.0, 40.0, 0.0], translate = [2.5, 0.25, 0.5] }",
        "{ scale = [1.2, 0.7, 1.2], rotate = [5.0, -25.0, 10.0], translate = [-1.5, 0.125, -3.0] }",
    ] {
        text += &format!("[[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\nalbedo = 0.8\ntransform = {t}\n");
    }
    let scene = scene_from_toml(&text, dir.path());
    assert_eq!((scene.instances.len(), scene.triangles.len()), (3, 0), "the mesh is instanced");
    scene
}

/// Whether two films hold the same samples and sums, bit for bit.
fn same_bits(a: &Film, b: &Film) -> bool {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    a.samples == b.samples && bits(&a.sum) == bits(&b.sum) && bits(&a.sum_sq) == bits(&b.sum_sq)
}

/// The local origin `scene` is rendered about on `config`, and the film of its own view.
fn render_far(scene: &Scene, config: &Config) -> (DVec3, Film) {
    let session = session(scene, config);
    assert_eq!(session.frame().surface_shift, 0.0, "{}: the move is exact", scene.name);
    (session.frame().origin, render_settings(&session, &scene.settings))
}

/// The film of `scene` moved by `shift` against its film where it is, on every device:
/// the same bits when `shift` is a multiple of the local origin's grid (the scene then
/// moves back exactly onto itself), else image means within 4 standard errors of their
/// difference.
fn assert_far_film_is_the_origins(name: &str, scene: &Scene, shift: f32, bit_for_bit: bool) {
    assert_eq!(scene.local_origin(), DVec3::ZERO, "{name} is not moved where it is");
    let far = translated(scene, shift);
    for config in all_configs() {
        let what = format!("{name} moved by {shift} on {}", label(&config));
        let at_origin = render_with(scene, &config);
        let (origin, film) = render_far(&far, &config);
        let (m0, m) = (at_origin.image_mean(), film.image_mean());
        let (s0, s) = (image_mean_std_error(&at_origin), image_mean_std_error(&film));
        let sigma = (s0 * s0 + s * s).sqrt();
        let same = same_bits(&film, &at_origin);
        eprintln!(
            "{what}: rendered about {origin}; image mean {m:.6} against {m0:.6} ({:+.2} σ), same bits: {same}",
            (m - m0) / sigma
        );
        if bit_for_bit {
            assert!(same, "{what}: the film differs from the origin's");
            assert_eq!(origin, DVec3::splat(shift as f64), "{what}: the local origin is the shift");
        } else {
            assert!(sigma > 0.0, "{what}: zero variance, the comparison could not fail");
            assert!(
                (m - m0).abs() <= 4.0 * sigma,
                "{what}: image mean {m} against {m0}, more than 4σ = {}",
                4.0 * sigma
            );
            assert!(origin.min_element() > 0.5 * shift as f64, "{what}: rendered about {origin}");
        }
    }
}

#[test]
fn a_mesh_far_from_the_origin_renders_its_film_at_the_origin() {
    let scene = bunny();
    assert_far_film_is_the_origins("bunny × 1e4", &scene, GRID_SHIFT, true);
    assert_far_film_is_the_origins("bunny × 1e4", &scene, SHIFT, false);
}

#[test]
fn spheres_and_a_plane_far_from_the_origin_render_their_film_at_the_origin() {
    // aobench's grid is 8, of which 10⁶ is a multiple; scaled by 10³ its grid is 8,192.
    assert_far_film_is_the_origins("aobench", &aobench(1.0), SHIFT, true);
    assert_far_film_is_the_origins("aobench × 1e3", &aobench(1e3), GRID_SHIFT, true);
    assert_far_film_is_the_origins("aobench × 1e3", &aobench(1e3), SHIFT, false);
}

#[test]
fn instances_far_from_the_origin_render_their_film_at_the_origin() {
    let scene = instances();
    assert_far_film_is_the_origins("instances", &scene, GRID_SHIFT, true);
    assert_far_film_is_the_origins("instances", &scene, SHIFT, true);
    // 10⁶ + 8 is not a multiple of the instances' grid of 16.
    assert_far_film_is_the_origins("instances", &scene, SHIFT + 8.0, false);
}

/// Probes are given in the scene's coordinates and moved with the scene: at vertices of
/// the bunny (as a bake places them: on the triangles, no offset) moved far away, the
/// values and a bake's probe film with bent normals are the origin's bits.
#[test]
fn probes_far_from_the_origin_give_their_values_at_the_origin() {
    let scene = bunny();
    let far = translated(&scene, GRID_SHIFT);
    let probes = |t: f32| -> Vec<Probe> {
        let vertex = |tri: &Triangle| (tri.v[0], (tri.v[1] - tri.v[0]).cross(tri.v[2] - tri.v[0]));
        let points = scene.triangles.iter().step_by(97).map(vertex);
        points.map(|(p, n)| Probe::new(moved(p, t), n).expect("a probe")).collect()
    };
    let settings = Settings { sampler: Sampler::Sobol, hemisphere: Hemisphere::Uniform, ..scene.settings.clone() };
    for config in all_configs() {
        let what = label(&config);
        let (near, moved_away) = (session(&scene, &config), session(&far, &config));
        let at_origin = near.probe(&probes(0.0), 256, &settings).expect("probe at the origin");
        let away = moved_away.probe(&probes(GRID_SHIFT), 256, &settings).expect("probe far away");
        let mean = |v: &[aorender::ProbeValue]| v.iter().map(|v| v.mean).sum::<f64>() / v.len() as f64;
        eprintln!(
            "{what}: mean AO {} at {} probes, against {}",
            mean(&away.values),
            away.values.len(),
            mean(&at_origin.values)
        );
        assert!(at_origin.values.iter().any(|v| v.mean < 1.0), "{what}: no probe is occluded");
        let differ = away.values.iter().zip(&at_origin.values).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{what}: {differ} of {} probe values differ", away.values.len());

        let film = |s: &Session, t: f32| {
            let render = s.probe_render(&probes(t), 64, None, &settings, true).expect("a probe render");
            render.complete(&mut Control::default()).expect("probe render completes").film
        };
        assert!(
            same_bits(&film(&moved_away, GRID_SHIFT), &film(&near, 0.0)),
            "{what}: probe films with bent normals differ"
        );
    }
}

/// A far render's checkpoint is identified by the scene as given and resumes to the
/// uninterrupted render's bits.
#[test]
fn a_far_render_resumes_from_its_checkpoint() {
    let far = translated(&aobench(1e3), SHIFT);
    let settings = Settings { width: 32, height: 24, spp: 300, ..far.settings.clone() };
    let request = ImageRequest { camera: far.camera, settings: settings.clone(), samples: None };
    for config in all_configs() {
        let what = label(&config);
        let session = session(&far, &config);
        assert_ne!(session.frame().origin, DVec3::ZERO, "{what}: the scene is moved");
        let mut first = session.render(&request).expect("render starts");
        first.run_to(260, &mut Control::default()).expect("first part renders");
        let saved = first.accumulation().expect("its accumulation");
        assert!(saved.samples() < 300, "{what}: the render stopped early");
        saved
            .check_resume(&Accumulation::image(&far, &far.camera, &settings, 0..300, config.device, &config.bvh))
            .unwrap_or_else(|e| panic!("{what}: the checkpoint does not match the scene as given: {e}"));
        let mut resumed = session.render(&request).expect("render starts");
        resumed.resume(saved).expect("resumes");
        let resumed = resumed.complete(&mut Control::default()).expect("resumed render completes").film;
        let whole = render_request(&session, &request);
        assert!(same_bits(&resumed, &whole), "{what}: the resumed film differs from the uninterrupted one");
    }
}

/// The repository's scenes and the test scenes near the origin are left where they are,
/// so their films do not change.
#[test]
fn scenes_near_the_origin_are_not_moved() {
    let mut scenes = vec![Scene::default_scene(), aobench(1e3), bunny(), instances()];
    for file in ["bunny.obj", "teapot.obj", "2CylinderEngine.glb", "dragon_vrip_res4.ply.gz"] {
        scenes.push(Scene::load(&repo().join("scenes").join(file)).expect("scene loads"));
    }
    for scene in &scenes {
        assert_eq!(scene.local_origin(), DVec3::ZERO, "{} is moved", scene.name);
    }
    // And a scene moved by 10⁶ along one axis is moved back along that axis only.
    let mut far = Scene::default_scene();
    far.spheres.iter_mut().for_each(|s| s.center.z += SHIFT);
    assert_eq!(far.local_origin(), DVec3::new(0.0, 0.0, SHIFT as f64));
}
