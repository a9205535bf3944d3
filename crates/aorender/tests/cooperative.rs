//! The cooperative traversal (eight lanes trace each ray together) against the per-lane
//! one: the same films, bit for bit, for images (sizes whose edges leave lanes of a group
//! idle, adaptive renders whose finished pixels do), probes with several lanes a point and
//! a point count that leaves a group part-empty, and bent normals; in storage buffers and
//! textures, whole and split into chunks; and under lavapipe's loop cap, where a pass that
//! runs out of budget is rendered again. It needs subgroups, which lavapipe has.

mod common;
use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::gpu::GpuDevice;
use aorender::gpu::layout::FrameUniforms;
use aorender::gpu::{GpuScene, GpuTarget, Traversal};
use aorender::{
    BvhOptions, Control, ErrorTarget, Film, GeometryStorage, Hemisphere, Probe, Sampler, Scene, Session, Settings,
};
use common::*;
use glam::Vec3;
use std::sync::Arc;

const TRAVERSALS: [Traversal; 2] = [Traversal::PerLane, Traversal::Cooperative];

/// The adapter can run the cooperative traversal (in CI it must: lavapipe can).
fn cooperative_available() -> bool {
    if !gpu_available() {
        return false;
    }
    let ok = gpu_adapter().ctx.cooperative_traversal();
    if !ok {
        assert!(std::env::var_os("CI").is_none(), "CI's adapter must run the cooperative traversal");
        eprintln!("SKIPPED: the adapter has no subgroups of eight lanes or more");
    }
    ok
}

/// The bunny at 61 × 37 pixels: neither a multiple of the 8 × 8 workgroup.
fn bunny() -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (scene.settings.width, scene.settings.height, scene.settings.spp) = (61, 37, 16);
    scene
}

/// The default scene (spheres on a plane) at 45 × 30.
fn aobench() -> Scene {
    let mut scene = Scene::default_scene();
    (scene.settings.width, scene.settings.height, scene.settings.spp) = (45, 30, 16);
    scene
}

fn session_with(scene: &Scene, traversal: Traversal) -> Session {
    let options = BvhOptions { traversal: Some(traversal), ..BvhOptions::default() };
    let session = Session::new(&gpu_device(), scene.clone(), &options).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(session.setup().traversal, traversal.name());
    session
}

fn assert_same_film(a: &Film, b: &Film, what: &str) {
    assert!(a.sum.iter().any(|&s| s != 0.0), "{what}: an empty film");
    assert_eq!(a.sum, b.sum, "{what}: sums");
    assert_eq!(a.sum_sq, b.sum_sq, "{what}: sums of squares");
}

/// Images: the uniform hemisphere (a value per sample, not 0 or the albedo), each sampler.
#[test]
fn cooperative_images_are_the_per_lane_films() {
    if !cooperative_available() {
        return;
    }
    for scene in [bunny(), aobench()] {
        let sessions = TRAVERSALS.map(|t| session_with(&scene, t));
        for sampler in Sampler::ALL {
            let settings = Settings { sampler, hemisphere: Hemisphere::Uniform, ..scene.settings.clone() };
            let [a, b] = [0, 1].map(|k| render_settings(&sessions[k], &settings));
            assert_same_film(&a, &b, &format!("{}, {}", scene.name, sampler.name()));
        }
    }
}

/// An adaptive render stops sampling the pixels within the target: their lanes trace
/// nothing while the rest of their group goes on. Both traversals take the same
/// decisions, pass by pass, so the films and the samples per pixel are the same.
#[test]
fn cooperative_adaptive_renders_are_the_per_lane_ones() {
    if !cooperative_available() {
        return;
    }
    let scene = bunny();
    let settings = Settings { spp: 256, replicate: Some(16), ..scene.settings.clone() };
    let films = TRAVERSALS.map(|t| {
        let session = session_with(&scene, t);
        let request = aorender::ImageRequest { camera: scene.camera, settings: settings.clone(), samples: None };
        let mut control = Control { target: Some(ErrorTarget::Rmse(0.02)), adaptive: true, ..Control::default() };
        let out = session.render(&request).and_then(|r| r.complete(&mut control)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(out.stats.ended_by, "target");
        assert!(out.stats.mean_samples_per_pixel < 256.0, "no pixel stopped early");
        out.film
    });
    assert_same_film(&films[0], &films[1], "adaptive bunny");
    assert_eq!(films[0].pixel_samples, films[1].pixel_samples);
}

/// Probes: 37 points above the bunny's floor of rays (a group left part-empty), with
/// several lanes a point; and the bent normals' four slots a point.
#[test]
fn cooperative_probes_are_the_per_lane_values() {
    if !cooperative_available() {
        return;
    }
    let scene = bunny();
    let (lo, hi) = (Vec3::new(-0.09, 0.035, -0.06), Vec3::new(0.06, 0.18, 0.06));
    let probes: Vec<Probe> = (0..37)
        .map(|i| {
            let f = |k: u32| ((i * k + 3) % 37) as f32 / 36.0;
            let position = lo + (hi - lo) * Vec3::new(f(7), f(11), f(13));
            Probe {
                position,
                normal: Vec3::new(f(5) - 0.5, 1.0, f(3) - 0.5).normalize(),
                error: 0.0,
                surface_normal: Vec3::ZERO,
            }
        })
        .collect();
    let settings = Settings { hemisphere: Hemisphere::Uniform, max_distance: Some(0.05), ..scene.settings.clone() };
    let sessions = TRAVERSALS.map(|t| session_with(&scene, t));
    let values = sessions.each_ref().map(|s| s.probe(&probes, 200, &settings).unwrap_or_else(|e| panic!("{e}")));
    assert!(values[0].values.iter().any(|v| v.mean > 0.0 && v.mean < 1.0), "no probe partly occluded");
    for (k, (a, b)) in values[0].values.iter().zip(&values[1].values).enumerate() {
        assert_eq!((a.mean, a.std_error, a.samples), (b.mean, b.std_error, b.samples), "probe {k}");
    }
    assert_eq!(values[0].rays, values[1].rays);
    let bent = sessions.each_ref().map(|s| {
        let render = s.probe_render(&probes, 64, None, &settings, true).unwrap_or_else(|e| panic!("{e}"));
        render.complete(&mut Control::default()).unwrap_or_else(|e| panic!("{e}")).film
    });
    assert_same_film(&bent[0], &bent[1], "bent normals");
}

/// `bvh` uploaded to `dev` in `storage`, traced as `traversal` says, and the target of the
/// scene's image.
fn image_target(
    dev: &Arc<GpuDevice>,
    scene: &Scene,
    bvh: &GpuBvh,
    storage: GeometryStorage,
    traversal: Traversal,
) -> (GpuScene, GpuTarget) {
    let gs = GpuScene::upload(&dev.ctx, scene, bvh, storage, Some(traversal)).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(gs.traversal, traversal);
    let s = &scene.settings;
    let frame = FrameUniforms::image(&scene.camera, s, gs.node_count, gs.plane_count, value_exponent_of(scene));
    let target = GpuTarget::image(dev, &gs, frame, s.sampler, s.hemisphere).unwrap_or_else(|e| panic!("{e}"));
    (gs, target)
}

/// The node and primitive reads a texel at a time, from storage buffers or textures,
/// whole or split into chunks, give the per-lane traversal's film.
#[test]
fn cooperative_reads_geometry_in_buffers_or_textures_whole_or_split() {
    if !cooperative_available() {
        return;
    }
    let mut scene = bunny();
    scene.settings.hemisphere = Hemisphere::Uniform;
    let whole = gpu_adapter();
    let split = gpu_device_with(|ctx| {
        ctx.limit_chunk_bytes(200_000);
        ctx.limit_texture_size(600, 16);
    });
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let film = |dev: &Arc<GpuDevice>, storage, traversal| {
        let (gs, mut target) = image_target(dev, &scene, &bvh, storage, traversal);
        target.render_pass(0, 8).unwrap_or_else(|e| panic!("{e}"));
        (target.read_film(8).unwrap_or_else(|e| panic!("{e}")), gs.geometry_bindings())
    };
    let (reference, _) = film(&whole, GeometryStorage::Buffers, Traversal::PerLane);
    for storage in [GeometryStorage::Buffers, GeometryStorage::Textures] {
        for (dev, split) in [(&whole, false), (&split, true)] {
            let (f, bindings) = film(dev, storage, Traversal::Cooperative);
            assert_eq!(bindings > 2, split, "{storage:?}: {bindings} bindings");
            assert_same_film(&reference, &f, &format!("{storage:?}, {bindings} bindings"));
        }
    }
}

/// With more samples per invocation than the loop cap allows for sure, a cooperative
/// pass may run out of budget, and is then rendered again with the safe count: the film
/// is the one-sample-per-invocation film either way.
#[test]
fn cooperative_passes_stay_within_the_loop_cap() {
    if !cooperative_available() {
        return;
    }
    let mut scene = bunny();
    scene.settings.hemisphere = Hemisphere::Uniform;
    let dev = gpu_adapter();
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let films: Vec<Film> = [1, u32::MAX]
        .into_iter()
        .map(|per| {
            let (_, mut target) = image_target(&dev, &scene, &bvh, dev.ctx.preferred_storage(), Traversal::Cooperative);
            target.set_samples_per_invocation(per);
            target.render_pass(0, 64).unwrap_or_else(|e| panic!("{per} samples per invocation: {e}"));
            target.read_film(64).unwrap_or_else(|e| panic!("{e}"))
        })
        .collect();
    assert_same_film(&films[0], &films[1], "64 samples, 1 or all per invocation");
}

/// A scene the cooperative traversal cannot trace (instances; the BVH2 layout) is traced
/// a ray per lane by default and refused, in one line, when asked for.
#[test]
fn cooperative_traversal_is_refused_where_it_cannot_run() {
    if !cooperative_available() {
        return;
    }
    let dir = temp_dir();
    write_obj(&dir.path().join("mesh.obj"), &floor_and_box());
    let mut text = String::from(
        "[camera]\ntype = \"perspective\"\neye = [3.0, 4.0, 6.0]\nlook_at = [0.0, 0.0, -0.5]\nfov = 50.0\n",
    );
    for x in [0.0, 3.0] {
        text +=
            &format!("[[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\ntransform = {{ translate = [{x}, 0, 0] }}\n");
    }
    let instanced = scene_from_toml(&text, dir.path());
    assert!(!instanced.instances.is_empty());
    let auto = Session::new(&gpu_device(), instanced.clone(), &BvhOptions::default()).unwrap();
    assert_eq!(auto.setup().traversal, "per-lane");
    for (scene, layout) in [(&instanced, BvhLayout::Cwbvh), (&bunny(), BvhLayout::Bvh2)] {
        let options = BvhOptions { layout, traversal: Some(Traversal::Cooperative), ..BvhOptions::default() };
        let e = Session::new(&gpu_device(), scene.clone(), &options).err().expect("refused").to_string();
        assert!(e.contains("cooperative traversal needs") && !e.contains('\n'), "{e}");
    }
}
