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

/// Independent renders agree: the image means within 4 standard errors, and the
/// per-pixel z-scores have mean square within 4 of its own standard errors of the value
/// expected for two estimates whose variances are themselves estimated from n samples.
pub fn assert_statistical_agreement(gpu: &Film, cpu: &Film, what: &str) {
    let (mg, mc) = (gpu.image_mean(), cpu.image_mean());
    let (sg, sc) = (image_mean_std_error(gpu), image_mean_std_error(cpu));
    let sigma = (sg * sg + sc * sc).sqrt();
    assert!(sigma > 0.0, "{what}: zero variance, the test could not detect a difference");
    assert!(
        (mg - mc).abs() <= 4.0 * sigma,
        "{what}: image means {mg} (GPU) and {mc} (CPU) differ by more than 4σ = {}",
        4.0 * sigma
    );

    let (a, b) = (gpu.mean(), cpu.mean());
    let (ea, eb) = (gpu.std_error(), cpu.std_error());
    let z2: Vec<f64> = (0..a.len())
        .filter(|&i| ea[i] > 0.0 || eb[i] > 0.0 || a[i] != b[i])
        .map(|i| (a[i] - b[i]).powi(2) / (ea[i] * ea[i] + eb[i] * eb[i]))
        .collect();
    assert!(z2.len() > 100, "{what}: only {} pixels vary", z2.len());
    let m = z2.iter().sum::<f64>() / z2.len() as f64;
    let sd = (z2.iter().map(|z| (z - m).powi(2)).sum::<f64>() / (z2.len() - 1) as f64).sqrt();
    let se = sd / (z2.len() as f64).sqrt();
    // A t-distributed z with ν = 2(n - 1) degrees of freedom has E[z²] = ν/(ν - 2).
    let nu = 2.0 * (gpu.samples as f64 - 1.0);
    let expected = nu / (nu - 2.0);
    eprintln!("{what}: mean {mg:.5} vs {mc:.5} (σ {sigma:.2e}); mean z² {m:.3} ± {se:.3} over {} pixels", z2.len());
    assert!((m - expected).abs() <= 4.0 * se, "{what}: mean z² {m} is not {expected} ± 4·{se}");
}

/// A bumpy floor with an open-bottomed box on it: 1,162 triangles.
pub fn floor_and_box() -> Vec<[[f32; 3]; 3]> {
    let mut tris = Vec::new();
    let n = 24;
    let h = |i: usize, j: usize| 0.15 * ((i as f32 * 0.7).sin() * (j as f32 * 0.5).cos());
    let p = |i: usize, j: usize| [i as f32 / n as f32 * 4.0 - 2.0, h(i, j), j as f32 / n as f32 * 4.0 - 2.0];
    for i in 0..n {
        for j in 0..n {
            tris.push([p(i, j), p(i + 1, j), p(i + 1, j + 1)]);
            tris.push([p(i, j), p(i + 1, j + 1), p(i, j + 1)]);
        }
    }
    let c = |x: f32, y: f32, z: f32| [x * 0.5, y * 0.8, z * 0.5];
    let quads = [
        [c(-1., 0., -1.), c(1., 0., -1.), c(1., 1., -1.), c(-1., 1., -1.)],
        [c(-1., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(-1., 1., 1.)],
        [c(-1., 0., -1.), c(-1., 0., 1.), c(-1., 1., 1.), c(-1., 1., -1.)],
        [c(1., 0., -1.), c(1., 0., 1.), c(1., 1., 1.), c(1., 1., -1.)],
        [c(-1., 1., -1.), c(1., 1., -1.), c(1., 1., 1.), c(-1., 1., 1.)],
    ];
    for q in quads {
        tris.push([q[0], q[1], q[2]]);
        tris.push([q[0], q[2], q[3]]);
    }
    tris
}

/// `scenes/dragons.toml` written into `dir` with each of its nine dragons read through a
/// file name of its own (links to the one file), so they are not instances of one mesh
/// but 7.8M triangles in one BVH. Returns the scene file.
pub fn flattened_dragons(dir: &std::path::Path) -> PathBuf {
    let mut text = std::fs::read_to_string(repo().join("scenes/dragons.toml")).unwrap();
    for i in 0..9 {
        let name = format!("dragon{i}.ply.gz");
        std::os::unix::fs::symlink(repo().join("scenes/dragon_vrip.ply.gz"), dir.join(&name)).unwrap();
        text = text.replacen("file = \"dragon_vrip.ply.gz\"", &format!("file = \"{name}\""), 1);
    }
    assert!(!text.contains("dragon_vrip"));
    let scene = dir.join("dragons.toml");
    std::fs::write(&scene, text).unwrap();
    scene
}
