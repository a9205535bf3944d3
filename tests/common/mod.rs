//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod kernel;

use aorender::bvh::BvhLayout;
use aorender::gpu::GpuContext;
use aorender::{Device, Film, RenderOptions, Scene, render};
use std::path::PathBuf;

/// True when a GPU adapter can be opened. In CI (`CI` set) a missing adapter fails the
/// test; elsewhere the test is skipped, loudly, with the reason.
pub fn gpu_available() -> bool {
    match GpuContext::new(None) {
        Ok(_) => true,
        Err(e) if std::env::var_os("CI").is_some() => panic!("CI requires a GPU adapter: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: no GPU adapter ({e})");
            false
        }
    }
}

/// Renders on `device`, panicking with the error's text on failure.
pub fn render_on(scene: &Scene, device: Device) -> Film {
    render_with(scene, &RenderOptions { device, ..Default::default() })
}

/// Renders with `options`, panicking with the error's text on failure.
pub fn render_with(scene: &Scene, options: &RenderOptions) -> Film {
    match render(scene, options, &mut |_| {}) {
        Ok(out) => out.film,
        Err(e) => panic!("{} render of {} failed: {e}", label(options), scene.name),
    }
}

/// The GPU configurations: one per BVH layout.
pub fn gpu_options() -> Vec<RenderOptions> {
    [BvhLayout::Bvh2, BvhLayout::Cwbvh]
        .into_iter()
        .map(|bvh_layout| RenderOptions { device: Device::Gpu, bvh_layout, ..Default::default() })
        .collect()
}

/// The CPU reference, then every GPU configuration when an adapter exists.
pub fn all_options() -> Vec<RenderOptions> {
    let mut all = vec![RenderOptions { device: Device::Cpu, ..Default::default() }];
    if gpu_available() {
        all.extend(gpu_options());
    }
    all
}

/// "cpu", or "gpu/LAYOUT".
pub fn label(options: &RenderOptions) -> String {
    match options.device {
        Device::Cpu => "cpu".into(),
        Device::Gpu => format!("gpu/{}", options.bvh_layout.name()),
    }
}

/// A scene from TOML text; mesh paths resolve against `dir`.
pub fn scene_from_toml(text: &str, dir: &std::path::Path) -> Scene {
    Scene::from_toml_str(text, &dir.join("test.toml"), dir).expect("test scene parses")
}

/// Standard error of the image mean: per-pixel estimates are independent.
pub fn image_mean_std_error(film: &Film) -> f64 {
    let se = film.std_error();
    (se.iter().map(|s| s * s).sum::<f64>()).sqrt() / se.len() as f64
}

/// A temporary directory for files a test writes.
pub fn temp_dir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temporary directory")
}

/// The repository root.
pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Writes triangles as an OBJ file.
pub fn write_obj(path: &std::path::Path, triangles: &[[[f32; 3]; 3]]) {
    let mut text = String::new();
    for t in triangles {
        for v in t {
            text += &format!("v {} {} {}\n", v[0], v[1], v[2]);
        }
    }
    for i in 0..triangles.len() {
        text += &format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3);
    }
    std::fs::write(path, text).expect("write OBJ");
}

/// Runs the `aorender` binary with `args` in `cwd`.
pub fn aorender(args: &[&str], cwd: &std::path::Path) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_aorender"))
        .args(args)
        .current_dir(cwd)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .output()
        .expect("aorender runs")
}
