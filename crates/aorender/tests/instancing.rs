//! Meshes placed several times: kept once and traced through a second BVH level.
//!
//! - The instances flatten to exactly the triangles the loader places for each object on
//!   its own, and an instanced render agrees with the flattened scene's within standard
//!   errors.
//! - The GPU and the CPU reference trace instances with the same operations: with the same
//!   seed they agree pixel by pixel, also where a ray enters many instances of a grid with
//!   the top level's pending entries held while it traverses each mesh.
//! - Inside a closed instanced mesh every pixel is 0, and an open instanced floor returns
//!   its albedo in every sample, at scales 1e-4 to 1e6 and offsets up to 1e6, rotated:
//!   no ray leaks out, and no AO ray hits the surface it leaves, although it is traced
//!   in the mesh's own space through rounded transforms.

mod common;
use aorender::accumulation::max_sample_value;
use aorender::bvh::BvhLayout;
use aorender::{DeviceKind, Hemisphere, Sampler};
use common::*;
use std::path::Path;

/// Three placements of `mesh.obj`: as it is, rotated and scaled down beside it, and
/// rotated behind it with another albedo.
const PLACEMENTS: [&str; 3] = [
    "{ rotate = [0.0, 0.0, 0.0] }",
    "{ scale = 0.6, rotate = [0.0, 40.0, 0.0], translate = [2.5, 0.2, 0.5] }",
    "{ scale = [1.2, 0.7, 1.2], rotate = [5.0, -25.0, 10.0], translate = [-1.5, 0.1, -3.0] }",
];

/// A scene file placing `mesh.obj` once per entry of `placements`.
fn scene_text(placements: &[&str]) -> String {
    let mut text = String::from(
        r#"
        [image]
        width = 48
        height = 36
        [sampling]
        spp = 32
        [camera]
        type = "perspective"
        eye = [3.0, 4.0, 6.0]
        look_at = [0.0, 0.0, -0.5]
        fov = 50.0
        "#,
    );
    for (i, t) in placements.iter().enumerate() {
        let albedo = if i == 2 { 0.6 } else { 0.9 };
        text += &format!("[[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\nalbedo = {albedo}\ntransform = {t}\n");
    }
    text
}

fn write_mesh(dir: &Path) {
    write_obj(&dir.join("mesh.obj"), &floor_and_box());
}

#[test]
fn instances_are_kept_once_and_flatten_to_the_placed_triangles() {
    let dir = temp_dir();
    write_mesh(dir.path());
    let scene = scene_from_toml(&scene_text(&PLACEMENTS), dir.path());
    assert_eq!((scene.meshes.len(), scene.instances.len(), scene.triangles.len()), (1, 3, 0));
    let n = floor_and_box().len();
    assert_eq!(scene.meshes[0].triangles.len(), n);
    assert_eq!(scene.world_triangle_count(), 3 * n);
    // Each object on its own is placed by the loader directly into the world.
    let mut placed = Vec::new();
    for (i, t) in PLACEMENTS.iter().enumerate() {
        let mut one = scene_from_toml(&scene_text(&PLACEMENTS[..=i]), dir.path());
        if i == 0 {
            assert!(one.instances.is_empty(), "a mesh placed once is not instanced");
            placed.append(&mut one.triangles);
        } else {
            let mut single = scene_from_toml(&scene_text(&[t]), dir.path());
            assert!(single.instances.is_empty());
            for tri in &mut single.triangles {
                tri.albedo = if i == 2 { 0.6 } else { 0.9 };
            }
            placed.append(&mut single.triangles);
        }
    }
    let flat = scene.flattened();
    assert!(flat.instances.is_empty() && flat.meshes.is_empty());
    assert_eq!(flat.triangles.len(), placed.len());
    assert!(flat.triangles == placed, "the flattened instances differ from the triangles placed one by one");
    let bounds = (scene.bounds().unwrap(), flat.bounds().unwrap());
    assert_eq!((bounds.0.min, bounds.0.max), (bounds.1.min, bounds.1.max));
}

#[test]
fn instanced_and_flattened_scenes_agree() {
    let dir = temp_dir();
    write_mesh(dir.path());
    let mut scene = scene_from_toml(&scene_text(&PLACEMENTS), dir.path());
    scene.settings.sampling.seed = 1;
    let mut flat = scene.flattened();
    flat.settings.sampling.seed = 2;
    let (a, b) = (render_on(&scene, DeviceKind::Cpu), render_on(&flat, DeviceKind::Cpu));
    let max = max_sample_value(&scene, scene.settings.background);
    assert_statistical_agreement(&a, &b, max, "instanced (cpu) vs flattened (cpu)");
    if gpu_available() {
        let gpu = render_on(&scene, DeviceKind::Gpu);
        assert_statistical_agreement(&gpu, &b, max, "instanced (gpu) vs flattened (cpu)");
    }
}

#[test]
fn gpu_and_cpu_trace_instances_alike() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    write_mesh(dir.path());
    let mut scene = scene_from_toml(&scene_text(&PLACEMENTS), dir.path());
    let cpu_session = session(&scene, &Config::cpu());
    let gpu_sessions: Vec<(Config, aorender::Session)> =
        gpu_configs().into_iter().map(|c| (c, session(&scene, &c))).collect();
    for hemisphere in Hemisphere::ALL {
        for sampler in [Sampler::Independent, Sampler::Sobol] {
            scene.settings.sampling.hemisphere = hemisphere;
            scene.settings.sampling.sampler = sampler;
            let cpu = render_settings(&cpu_session, &scene.settings).mean();
            for (options, gpu_session) in &gpu_sessions {
                let what = format!("{} {} {}", hemisphere.name(), sampler.name(), label(options));
                let gpu = render_settings(gpu_session, &scene.settings).mean();
                let equal = gpu.iter().zip(&cpu).filter(|(a, b)| a == b).count();
                let close = gpu.iter().zip(&cpu).filter(|(a, b)| (*a - *b).abs() <= 1e-4).count();
                eprintln!("{what}: {equal} of {} pixels equal, {close} within 1e-4", gpu.len());
                // The BVH2 layout flattens the instances: its triangles round differently,
                // so a ray that grazes an edge may go the other way.
                assert!(close as f64 >= 0.99 * gpu.len() as f64, "{what}: only {close} pixels match");
            }
        }
    }
}

/// A 64 × 64 grid of small icospheres, each an instance, seen at a grazing angle along
/// its diagonal: a camera ray enters one instance after another, and each time the top
/// level's pending entries (in registers and, the top level being deep enough, in
/// workgroup memory on the GPU) must come back when the mesh is done, or the spheres
/// behind go missing. The CWBVH kernel agrees with the CPU pixel by pixel.
#[test]
fn gpu_and_cpu_trace_a_grid_of_instances_alike() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    write_obj(&dir.path().join("sphere.obj"), &icosphere());
    let mut text = String::from(
        r#"
        [image]
        width = 64
        height = 32
        [sampling]
        spp = 8
        [camera]
        type = "perspective"
        eye = [-1.5, 0.25, -1.5]
        look_at = [6.0, 0.0, 6.0]
        fov = 30.0
        "#,
    );
    for i in 0..64 {
        for j in 0..64 {
            // Rows a little out of line, so that rays pass between spheres and on.
            let x = i as f64 + 0.25 * ((j * 7 % 5) as f64 / 5.0);
            let z = j as f64 + 0.25 * ((i * 3 % 7) as f64 / 7.0);
            text += &format!(
                "[[object]]\ntype = \"mesh\"\nfile = \"sphere.obj\"\n\
                 transform = {{ scale = 0.3, translate = [{x}, 0.0, {z}] }}\n"
            );
        }
    }
    let scene = scene_from_toml(&text, dir.path());
    assert_eq!(scene.instances.len(), 4096);
    let cpu = render_on(&scene, DeviceKind::Cpu).mean();
    let gpu = render_with(&scene, &Config::gpu(BvhLayout::Cwbvh)).mean();
    let lit = cpu.iter().filter(|v| **v > 0.0).count();
    assert!(lit > cpu.len() / 3, "only {lit} of {} pixels see a sphere", cpu.len());
    let close = gpu.iter().zip(&cpu).filter(|(a, b)| (*a - *b).abs() <= 1e-4).count();
    assert!(close as f64 >= 0.99 * gpu.len() as f64, "only {close} of {} pixels match", gpu.len());
}

/// The icosphere of subdivision level 2 (radius 1, 320 triangles) of the accuracy suite.
fn icosphere() -> Vec<[[f32; 3]; 3]> {
    let m = aorender::closed_form::unit_icosphere(2);
    m.triangles.iter().map(|t| t.map(|i| m.vertices[i].as_vec3().to_array())).collect()
}

/// `(scale, offset)` of the instance the camera looks at: at an offset of 1e6 the f32
/// spacing is 1/16, so the 1e-4 mesh is offset by 1 instead.
const SCALES: [(f64, f64); 6] = [(1e-4, 0.0), (1e-4, 1.0), (1.0, 0.0), (1.0, 1e6), (1e6, 0.0), (1e6, 1e6)];

/// Two instances of `mesh.obj`, albedo 0.5, rotated by `rotate` (degrees) and scaled by
/// `scale`: the first at `offset` on every axis, the second moved from it by `scale` times
/// `beside`.
fn two_instances(
    camera: &str,
    scale: f64,
    offset: f64,
    background: f32,
    rotate: [[f64; 3]; 2],
    beside: [f64; 3],
) -> String {
    let first = [offset; 3];
    let second = [0, 1, 2].map(|k| offset + scale * beside[k]);
    let object = |rotate: [f64; 3], at: [f64; 3]| {
        format!(
            "[[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\nalbedo = 0.5\n\
             transform = {{ scale = {scale:?}, rotate = {rotate:?}, translate = {at:?} }}\n"
        )
    };
    format!(
        "[image]\nwidth = 32\nheight = 32\nbackground = {background:?}\n[sampling]\nspp = 16\n{camera}\n{}{}",
        object(rotate[0], first),
        object(rotate[1], second)
    )
}

#[test]
fn inside_an_instanced_closed_mesh_is_black() {
    let dir = temp_dir();
    write_obj(&dir.path().join("mesh.obj"), &icosphere());
    for (scale, offset) in SCALES {
        // Inside whatever the rotation: the icosphere's inner radius is above 0.9.
        let at = |p: [f64; 3]| p.map(|c| (offset + scale * c) as f32);
        let camera = format!(
            "[camera]\ntype = \"perspective\"\neye = {:?}\nlook_at = {:?}\nfov = 120.0",
            at([0.1, 0.2, 0.3]),
            at([1.0, 0.0, 0.0])
        );
        let rotate = [[17.0, 29.0, 41.0], [-8.0, 3.0, 60.0]];
        let text = two_instances(&camera, scale, offset, 1.0, rotate, [5.0, 0.0, 0.0]);
        let mut scene = scene_from_toml(&text, dir.path());
        assert_eq!(scene.instances.len(), 2);
        for options in all_configs() {
            let session = session(&scene, &options);
            for hemisphere in Hemisphere::ALL {
                scene.settings.sampling.hemisphere = hemisphere;
                let film = render_settings(&session, &scene.settings);
                let lit = film.mean().iter().filter(|v| **v != 0.0).count();
                eprintln!("scale {scale} offset {offset} {} {}: {lit} lit pixels", label(&options), hemisphere.name());
                assert_eq!(
                    lit,
                    0,
                    "scale {scale} offset {offset} {} {}: light leaks in",
                    label(&options),
                    hemisphere.name()
                );
            }
        }
    }
}

#[test]
fn an_open_instanced_floor_returns_its_albedo() {
    let dir = temp_dir();
    let quad = [[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0], [1.0, 0.0, 1.0], [-1.0, 0.0, 1.0]];
    write_obj(&dir.path().join("mesh.obj"), &[[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]);
    for (scale, offset) in SCALES {
        // Straight down onto the first instance (tilted by the rotation), seeing only it;
        // the second is beside it, below its horizon, and never in an AO ray's way.
        let camera = format!(
            "[camera]\ntype = \"orthographic\"\neye = {:?}\nlook_at = {:?}\nup = [0.0, 0.0, 1.0]\nheight = {:?}",
            [offset as f32, (offset + 4.0 * scale) as f32, offset as f32],
            [offset as f32; 3],
            (0.4 * scale) as f32
        );
        let rotate = [[20.0, 30.0, 0.0], [0.0, 0.0, 0.0]];
        let text = two_instances(&camera, scale, offset, 0.0, rotate, [5.0, -3.0, 0.0]);
        let mut scene = scene_from_toml(&text, dir.path());
        assert_eq!(scene.instances.len(), 2);
        for options in all_configs() {
            let session = session(&scene, &options);
            for hemisphere in [Hemisphere::Cosine, Hemisphere::CosinePolar] {
                scene.settings.sampling.hemisphere = hemisphere;
                let film = render_settings(&session, &scene.settings);
                let off: Vec<f64> = film.mean().iter().copied().filter(|v| *v != 0.5).collect();
                let what = format!("scale {scale} offset {offset} {} {}", label(&options), hemisphere.name());
                eprintln!("{what}: {} of {} pixels not 0.5", off.len(), film.mean().len());
                assert!(off.is_empty(), "{what}: pixels {:?} are not the albedo 0.5", &off[..off.len().min(8)]);
            }
        }
    }
}
