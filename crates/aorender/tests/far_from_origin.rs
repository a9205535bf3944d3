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
use aorender::Sampling;
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
    scene.settings = Settings {
        width: 192,
        height: 192,
        spp: 256,
        sampling: Sampling { max_distance: Some(625.6), ..Sampling::default() },
        ..Settings::default()
    };
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
    scene.settings = Settings {
        width: 96,
        height: 96,
        spp: 64,
        sampling: Sampling { sampler: Sampler::Sobol, ..scene.settings.sampling },
        ..scene.settings
    };
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
    let settings = Settings {
        sampling: Sampling { sampler: Sampler::Sobol, hemisphere: Hemisphere::Uniform, ..scene.settings.sampling },
        ..scene.settings.clone()
    };
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

// --- Placed far away by the files themselves -------------------------------------------
//
// The geometry far away is in the files: a bare mesh's coordinates, a glTF file's node
// translation, a scene file's transforms and positions. The camera (a bare mesh's
// automatic framing, a scene file's) is placed in f64, and the loaders keep geometry that
// they place far away relative to the scene's origin, so each renders the film of the same
// file at the origin, bit for bit: the same f32 numbers reach the device.

/// The film of each of `scenes` (name, scene) on every device, against the first's: the
/// same bits, and an image with something in view.
fn assert_same_films(scenes: &[(String, Scene)]) {
    let (first, reference) = &scenes[0];
    for config in all_configs() {
        let at_origin = render_with(reference, &config);
        let mean = at_origin.image_mean();
        assert!(mean > 0.02 && mean < 0.98, "{first} on {}: image mean {mean}, nothing in view", label(&config));
        for (name, scene) in &scenes[1..] {
            let film = render_with(scene, &config);
            let same = same_bits(&film, &at_origin);
            eprintln!(
                "{name} on {}: image mean {:.6} against {mean:.6} ({first}); same bits: {same}",
                label(&config),
                film.image_mean()
            );
            assert!(same, "{name} on {}: the film differs from {first}'s", label(&config));
        }
    }
}

/// Small, quick films: the comparisons are bit for bit.
fn small(mut scene: Scene) -> Scene {
    scene.settings = Settings { width: 40, height: 32, spp: 16, ..scene.settings };
    scene
}

#[test]
fn bare_meshes_far_from_the_origin_are_framed_and_rendered_as_at_the_origin() {
    let dir = temp_dir();
    let d = dir.path();
    // A unit triangle, at the origin and at 10⁷ (where an f32 step is 1, so its corners are
    // exact): framed in f32, the far one was shifted and cropped (mean 0.246 against 0.162).
    let triangle = |t: &str| format!("v {t}0 {t}0 {t}0\nv {t}1 {t}0 {t}0\nv {t}0 {t}1 {t}0\nf 1 2 3\n");
    std::fs::write(d.join("triangle.obj"), triangle("")).unwrap();
    std::fs::write(d.join("triangle_1e7.obj"), triangle("1000000")).unwrap();
    let load = |file: &str| (file.to_string(), small(Scene::load(&d.join(file)).expect("the mesh loads")));
    assert_same_films(&[load("triangle.obj"), load("triangle_1e7.obj")]);

    // A floor with a box on the grid of an f32 step where it is moved, and small enough
    // for the move to be a multiple of its local origin's grid `G`, so that it moves back
    // exactly: 64 across on the grid of 1 at 10⁷ (`G` = 128), 128 across on the grid of 8
    // at 10⁸ (`G` = 256).
    for (t, across, step) in [(1e7f32, 64.0f32, 1.0f32), (1e8, 128.0, 8.0)] {
        let mesh: Vec<[[f32; 3]; 3]> = floor_and_box()
            .iter()
            .map(|tri| tri.map(|v| v.map(|c| (c * across / 4.0 / step).round() * step)))
            .collect();
        let scenes: Vec<(String, Scene)> = [0.0, t]
            .iter()
            .map(|&shift| {
                let file = format!("floor_{across}_{shift:e}.obj");
                let moved_mesh: Vec<[[f32; 3]; 3]> =
                    mesh.iter().map(|tri| tri.map(|v| moved(Vec3::from(v), shift).to_array())).collect();
                write_obj(&d.join(&file), &moved_mesh);
                load(&file)
            })
            .collect();
        for (name, scene) in &scenes {
            assert_eq!(scene.origin, DVec3::ZERO, "{name}: an OBJ's coordinates are stored as they are");
        }
        assert_same_films(&scenes);
    }
}

/// A glTF document placing `positions` (one triangle each three) under a node with a
/// rotation, a scale and a translation, itself under a root node translated by `t`.
fn gltf_text(positions: &[f32], t: [f64; 3]) -> String {
    use base64::Engine;
    let bytes: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
    let (lo, hi) = positions.chunks(3).fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
        ([lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])], [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])])
    });
    let doc = serde_json::json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [
            { "children": [1], "translation": t },
            { "mesh": 0, "rotation": [0.0, 0.2588190451, 0.0, 0.9659258263], "scale": [1.5, 0.75, 1.5],
              "translation": [0.25, 0.125, -0.5] }
        ],
        "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 } }] }],
        "accessors": [{ "bufferView": 0, "componentType": 5126, "count": positions.len() / 3, "type": "VEC3",
                        "min": lo, "max": hi }],
        "bufferViews": [{ "buffer": 0, "byteLength": bytes.len() }],
        "buffers": [{ "byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{data}") }]
    });
    serde_json::to_string(&doc).unwrap()
}

#[test]
fn a_gltf_placed_far_away_by_its_nodes_renders_its_film_at_the_origin() {
    let dir = temp_dir();
    let d = dir.path();
    // The floor and box at their own scale (a few units, coordinates of every f32 value):
    // at 10⁸, where an f32 step is 8, placed in f32 they were nothing but slivers.
    let positions: Vec<f32> = floor_and_box().iter().flatten().flatten().copied().collect();
    let far = [1e8, -1e8, 1e8];
    std::fs::write(d.join("near.gltf"), gltf_text(&positions, [0.0; 3])).unwrap();
    std::fs::write(d.join("far.gltf"), gltf_text(&positions, far)).unwrap();
    let load = |file: &str| (file.to_string(), small(Scene::load(&d.join(file)).expect("the glTF file loads")));
    let scenes = [load("near.gltf"), load("far.gltf")];
    assert_eq!(scenes[0].1.origin, DVec3::ZERO);
    assert_eq!(scenes[1].1.origin, DVec3::from(far), "the far mesh is kept relative to its place");
    assert!(
        scenes[1].1.triangles == scenes[0].1.triangles,
        "the far mesh's stored triangles differ from the near one's"
    );
    let eye = scenes[1].1.camera.eye - scenes[0].1.camera.eye;
    assert_eq!(eye, DVec3::from(far), "the framing moves with the mesh, exactly");
    assert_same_films(&scenes);
}

/// A scene file: the floor and box (`mesh.obj`) rotated and moved, a sphere and a floor
/// plane, seen from a camera, everything moved by `t` (given as text).
fn far_scene_text(t: [f64; 3], matrix: bool) -> String {
    let at = |p: [f64; 3]| format!("[{}, {}, {}]", p[0] + t[0], p[1] + t[1], p[2] + t[2]);
    let transform = if matrix {
        // 30° about y, then moved by (0.5, 0.25, 0).
        let (c, s) = (0.8660254037844387, 0.5);
        format!(
            "{{ matrix = [[{c}, 0, {s}, {}], [0, 1, 0, {}], [{}, 0, {c}, {}], [0, 0, 0, 1]] }}",
            0.5 + t[0],
            0.25 + t[1],
            -s,
            t[2]
        )
    } else {
        format!("{{ rotate = [0, 30, 0], translate = {} }}", at([0.5, 0.25, 0.0]))
    };
    format!(
        "[image]\nwidth = 40\nheight = 32\n[sampling]\nspp = 16\nmax_distance = 1.5\n\
         [camera]\ntype = \"perspective\"\neye = {}\nlook_at = {}\nfov = 50\n\
         [[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\ntransform = {transform}\n\
         [[object]]\ntype = \"sphere\"\ncenter = {}\nradius = 0.375\n\
         [[object]]\ntype = \"plane\"\npoint = {}\nnormal = [0, 1, 0]\nalbedo = 0.5\n",
        at([2.5, 3.0, 4.5]),
        at([0.0, 0.0, -0.25]),
        at([0.75, 0.625, 0.5]),
        at([0.0, -0.125, 0.0]),
    )
}

#[test]
fn a_scene_file_placing_everything_far_away_renders_its_film_at_the_origin() {
    let dir = temp_dir();
    let d = dir.path();
    write_obj(&d.join("mesh.obj"), &floor_and_box());
    let far = [1e8, 1e8, -1e8];
    let mut scenes = Vec::new();
    for matrix in [false, true] {
        let form = if matrix { "matrix" } else { "rotate and translate" };
        for t in [[0.0; 3], far] {
            scenes.push((format!("the scene moved by {t:?} ({form})"), scene_from_toml(&far_scene_text(t, matrix), d)));
        }
    }
    assert_eq!(scenes[1].1.origin, DVec3::from(far), "the scene is kept relative to its first mesh's place");
    assert_eq!(scenes[1].1.spheres, scenes[0].1.spheres);
    assert_eq!(scenes[1].1.planes, scenes[0].1.planes);
    assert!(scenes[1].1.triangles == scenes[0].1.triangles, "the far mesh's stored triangles differ");
    assert_same_films(&scenes[..2]);
    assert_same_films(&scenes[2..]);
}
