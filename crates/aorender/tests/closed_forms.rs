//! AO values with closed forms, rendered through the whole pipeline (camera, BVH, kernel)
//! on the GPU and on the CPU reference. An orthographic view a few micrometres wide
//! makes each pixel's area average equal the point value to far below the noise.

mod common;
use aorender::{Film, Hemisphere};
use common::*;
use std::path::Path;

/// A 16×16 image at `spp` of the camera and objects in `body`, rendered by every device
/// and BVH layout with each of `hemispheres`; `check(film, what)` judges each image.
fn for_each_render(dir: &Path, spp: u32, body: &str, hemispheres: &[Hemisphere], check: impl Fn(&Film, &str)) {
    let text = format!("[image]\nwidth = 16\nheight = 16\n[sampling]\nspp = {spp}\n{body}");
    let mut scene = scene_from_toml(&text, dir);
    for options in all_configs() {
        let session = session(&scene, &options);
        for &hemisphere in hemispheres {
            scene.settings.sampling.hemisphere = hemisphere;
            let film = render_settings(&session, &scene.settings);
            check(&film, &format!("{} {}", label(&options), hemisphere.name()));
        }
    }
}

fn assert_within_4_sigma(film: &Film, expected: f64, what: &str) {
    let mean = film.image_mean();
    let se = image_mean_std_error(film);
    eprintln!("{what}: {mean:.5} expected {expected:.5} (σ {se:.2e})");
    assert!(se > 0.0, "{what}: zero variance where occlusion is partial");
    assert!((mean - expected).abs() <= 4.0 * se, "{what}: mean {mean} is not {expected} ± 4·{se}");
}

/// A floor and an orthographic camera looking at the origin along (-1, -1, 0): its rays
/// pass (2, 2, 0), clear of the occluders the tests put above the origin.
const VIEW_OF_ORIGIN: &str = r#"
    [camera]
    type = "orthographic"
    eye = [10.0, 10.0, 0.0]
    look_at = [0.0, 0.0, 0.0]
    height = 1e-5
    [[object]]
    type = "plane"
    point = [0.0, 0.0, 0.0]
    normal = [0.0, 1.0, 0.0]
"#;

#[test]
fn unoccluded_plane_is_exactly_the_albedo() {
    let body = r#"
        [camera]
        type = "perspective"
        eye = [0.3, 2.0, 0.1]
        look_at = [0.0, 0.0, 0.0]
        fov = 60.0
        [[object]]
        type = "plane"
        point = [0.0, 0.0, 0.0]
        normal = [0.0, 1.0, 0.0]
        albedo = 0.7
    "#;
    let dir = temp_dir();
    for_each_render(dir.path(), 64, body, &[Hemisphere::Cosine], |film, what| {
        for (i, v) in film.mean().iter().enumerate() {
            // Every sample is exactly 0.7f32; only the accumulation's rounding may show.
            assert!((v - 0.7f32 as f64).abs() <= 1e-6, "{what}: pixel {i} is {v}, expected 0.7");
        }
    });
}

#[test]
fn plane_under_a_sphere_is_one_minus_r_over_d_squared() {
    // Sphere of radius 1 centred 2 above the origin: AO at the origin is 1 - (1/2)² = 0.75.
    let body = format!("{VIEW_OF_ORIGIN}\n[[object]]\ntype = \"sphere\"\ncenter = [0.0, 2.0, 0.0]\nradius = 1.0\n");
    let dir = temp_dir();
    for_each_render(dir.path(), 256, &body, &Hemisphere::ALL, |film, what| assert_within_4_sigma(film, 0.75, what));
}

#[test]
fn plane_under_a_mesh_occluder_matches_its_view_factor() {
    // A square of half-width a at height h, centred above the origin, blocks the view
    // factor of four a×a rectangles with a corner above the point (Howell's catalogue,
    // differential area to a parallel rectangle): F = (4/π)·(x/√(1+x²))·atan(x/√(1+x²)),
    // x = a/h. AO is 1 - F.
    let (a, h) = (1.0f64, 2.0f64);
    let x = a / h;
    let s = (1.0 + x * x).sqrt();
    let view_factor = (4.0 / std::f64::consts::PI) * (x / s) * (x / s).atan();
    let dir = temp_dir();
    let (a32, h32) = (a as f32, h as f32);
    write_obj(
        &dir.path().join("square.obj"),
        &[
            [[-a32, h32, -a32], [a32, h32, -a32], [a32, h32, a32]],
            [[-a32, h32, -a32], [a32, h32, a32], [-a32, h32, a32]],
        ],
    );
    let body = format!("{VIEW_OF_ORIGIN}\n[[object]]\ntype = \"mesh\"\nfile = \"square.obj\"\n");
    for_each_render(dir.path(), 256, &body, &Hemisphere::ALL, |film, what| {
        assert_within_4_sigma(film, 1.0 - view_factor, what)
    });
}

#[test]
fn inside_a_closed_sphere_is_black() {
    let body = r#"
        [camera]
        type = "perspective"
        eye = [0.1, 0.2, 0.3]
        look_at = [1.0, 0.0, 0.0]
        fov = 120.0
        [[object]]
        type = "sphere"
        center = [0.0, 0.0, 0.0]
        radius = 1.0
    "#;
    let dir = temp_dir();
    for_each_render(dir.path(), 64, body, &Hemisphere::ALL, |film, what| {
        assert!(film.mean().iter().all(|&v| v == 0.0), "{what}: light inside a closed sphere");
    });
}
