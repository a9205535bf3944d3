//! A scene far from the origin against the same f32 geometry at the origin: the Stanford
//! bunny scaled by 10⁴ (its vertices and camera rounded to multiples of 1/16, so that
//! moving them by up to 2²⁰ is exact in f32), rendered where it is and moved by 10⁶ and by
//! 983,040 = 15 × 2¹⁶ with its camera, at 256 samples per pixel with a maximum AO distance
//! of 625.6. It reports each moved film's image mean against the origin's, in standard
//! errors of their difference (√(σ₁² + σ₂²)) and of the origin film's mean alone, and how
//! many pixels differ.
//!
//! ```text
//! cargo run --release -p aorender --example far_from_origin [-- [cpu|gpu] [SIDE] [SPP]]
//! ```
//!
//! (512 × 512 and 256 samples per pixel on the CPU reference by default.)

use aorender::Sampling;
use aorender::{BvhOptions, Control, Device, Film, ImageRequest, Scene, Session, Settings};
use glam::{DVec3, Vec3};
use std::path::PathBuf;

/// Rounds each coordinate of `p` to a multiple of `step` (a power of two).
fn on_grid(p: Vec3, step: f64) -> Vec3 {
    ((p.as_dvec3() / step).round() * step).as_vec3()
}

/// `p` moved by `t` on every axis; panics unless the sum is exact.
fn moved(p: Vec3, t: f32) -> Vec3 {
    let q = p + Vec3::splat(t);
    assert_eq!(q.as_dvec3(), p.as_dvec3() + DVec3::splat(t as f64), "{p} + {t} is not exact in f32");
    q
}

/// The bunny's triangles and camera moved by `t`, each coordinate exactly.
fn translated(scene: &Scene, t: f32) -> Scene {
    let mut s = scene.clone();
    for tri in &mut s.triangles {
        tri.v = tri.v.map(|v| moved(v, t));
    }
    s.camera.eye = moved(s.camera.eye.as_vec3(), t).as_dvec3();
    s.camera.look_at = moved(s.camera.look_at.as_vec3(), t).as_dvec3();
    s
}

fn standard_error(film: &Film) -> f64 {
    let se = film.std_error();
    se.iter().map(|s| s * s).sum::<f64>().sqrt() / se.len() as f64
}

fn main() -> aorender::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let device = match args.first().map(String::as_str) {
        Some("gpu") => Device::gpu(None)?,
        _ => Device::cpu(),
    };
    let side: u32 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(512);
    let spp: u32 = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(256);

    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/bunny.obj");
    let bunny = Scene::load(&path)?;
    let grid = 1.0 / 16.0;
    let triangles = bunny
        .triangles
        .iter()
        .map(|t| aorender::scene::Triangle { v: t.v.map(|v| on_grid(v * 1e4, grid)), ..*t })
        .collect();
    let mut origin = Scene::from_triangles("bunny", triangles);
    origin.camera.eye = on_grid(origin.camera.eye.as_vec3(), grid).as_dvec3();
    origin.camera.look_at = on_grid(origin.camera.look_at.as_vec3(), grid).as_dvec3();
    let settings = Settings {
        width: side,
        height: side,
        spp,
        sampling: Sampling { max_distance: Some(625.6), ..Sampling::default() },
        ..Settings::default()
    };
    let render = |scene: &Scene| -> aorender::Result<(Film, DVec3)> {
        let session = Session::new(&device, scene.clone(), &BvhOptions::default())?;
        let request = ImageRequest { camera: scene.camera, settings: settings.clone(), samples: None };
        Ok((session.render(&request)?.complete(&mut Control::default())?.film, session.frame().origin))
    };
    println!("bunny × 1e4, {side}×{side}, {spp} spp, max distance 625.6, on {}", device.info().name);
    let (at_origin, _) = render(&origin)?;
    let (m0, s0) = (at_origin.image_mean(), standard_error(&at_origin));
    println!("at the origin: image mean {m0:.6} ± {s0:.2e}");
    for shift in [1e6f32, 983040.0] {
        let (far, local_origin) = render(&translated(&origin, shift))?;
        let (m, s) = (far.image_mean(), standard_error(&far));
        let differing = far.sum.iter().zip(&at_origin.sum).filter(|(a, b)| a != b).count();
        let largest = far.mean().iter().zip(at_origin.mean()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        println!(
            "moved by {shift} (rendered about {local_origin}): image mean {m:.6} ± {s:.2e}, {:+.3} % = {:+.2} σ of the difference ({:+.2} σ of the \
             origin's mean); {differing} of {} pixels differ, by at most {largest:.3e}",
            100.0 * (m / m0 - 1.0),
            (m - m0) / (s * s + s0 * s0).sqrt(),
            (m - m0) / s0,
            far.sum.len()
        );
    }
    Ok(())
}
