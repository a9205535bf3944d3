//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod kernel;

use aorender::bvh::GpuBvh;
use aorender::gpu::GpuDevice;
use aorender::gpu::context::GpuContext;
use aorender::gpu::layout::FrameUniforms;
use aorender::gpu::{GpuScene, GpuTarget};
use aorender::{
    BvhLayout, BvhOptions, Control, Device, DeviceKind, Film, GeometryStorage, ImageRequest, Scene, Session, Settings,
    Traversal,
};
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

/// The GPU device the tests of one binary share, opened on first use, or why none opens.
fn shared_gpu() -> &'static Result<Device, String> {
    static GPU: OnceLock<Result<Device, String>> = OnceLock::new();
    GPU.get_or_init(|| Device::gpu(None).map_err(|e| e.to_string()))
}

/// True when a GPU adapter can be opened. In CI (`CI` set) a missing adapter fails the
/// test; elsewhere the test is skipped, loudly, with the reason.
pub fn gpu_available() -> bool {
    match shared_gpu() {
        Ok(_) => true,
        Err(e) if std::env::var_os("CI").is_some() => panic!("CI requires a GPU adapter: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: no GPU adapter ({e})");
            false
        }
    }
}

/// The shared GPU device (check [`gpu_available`] first).
pub fn gpu_device() -> Device {
    shared_gpu().clone().unwrap_or_else(|e| panic!("no GPU adapter: {e}"))
}

/// A device of `kind`: the shared GPU device, or the CPU reference.
pub fn device(kind: DeviceKind) -> Device {
    match kind {
        DeviceKind::Gpu => gpu_device(),
        DeviceKind::Cpu => Device::cpu(),
    }
}

/// A second GPU device of the test binary's, on the same adapter, that traces every
/// scene that allows it cooperatively, or `None` where the adapter cannot.
pub fn cooperative_gpu_device() -> Option<Device> {
    static GPU: OnceLock<Option<Device>> = OnceLock::new();
    GPU.get_or_init(|| {
        let mut ctx = GpuContext::new(None).ok()?;
        ctx.prefer_traversal(Traversal::Cooperative);
        (ctx.preferred_traversal() == Traversal::Cooperative).then(|| Device::from_gpu(GpuDevice::new(ctx)))
    })
    .clone()
}

/// Where and how a test renders: the device, and how the scene is prepared on it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Config {
    /// GPU or CPU.
    pub device: DeviceKind,
    /// BVH build, layout and geometry storage.
    pub bvh: BvhOptions,
    /// On the GPU, the device that traces cooperatively wherever the scene allows it
    /// ([`cooperative_gpu_device`]).
    pub cooperative: bool,
}

impl Config {
    /// The CPU reference.
    pub fn cpu() -> Config {
        Config { device: DeviceKind::Cpu, ..Default::default() }
    }

    /// The GPU with the BVH in `layout`.
    pub fn gpu(layout: BvhLayout) -> Config {
        Config { device: DeviceKind::Gpu, bvh: BvhOptions { layout, ..Default::default() }, cooperative: false }
    }
}

/// The GPU configurations: one per BVH layout, traced a ray per lane, and the compressed
/// wide BVH traced cooperatively where the adapter can.
pub fn gpu_configs() -> Vec<Config> {
    let mut configs: Vec<Config> = [BvhLayout::Bvh2, BvhLayout::Cwbvh].into_iter().map(Config::gpu).collect();
    if cooperative_gpu_device().is_some() {
        configs.push(Config { cooperative: true, ..Config::gpu(BvhLayout::Cwbvh) });
    }
    configs
}

/// The CPU reference, then every GPU configuration when an adapter exists.
pub fn all_configs() -> Vec<Config> {
    let mut all = vec![Config::cpu()];
    if gpu_available() {
        all.extend(gpu_configs());
    }
    all
}

/// "cpu", or "gpu/LAYOUT".
pub fn label(config: &Config) -> String {
    match config.device {
        DeviceKind::Cpu => "cpu".into(),
        DeviceKind::Gpu if config.cooperative => format!("gpu/{}/cooperative", config.bvh.layout.name()),
        DeviceKind::Gpu => format!("gpu/{}", config.bvh.layout.name()),
    }
}

/// "cpu", or "gpu/LAYOUT", of a session.
pub fn session_label(session: &Session) -> String {
    match session.device().kind() {
        DeviceKind::Cpu => "cpu".into(),
        DeviceKind::Gpu => format!("gpu/{}/{}", session.setup().bvh_layout.name(), session.setup().traversal),
    }
}

/// `scene` prepared as `config` says (its BVH built and uploaded), panicking with the
/// error's text on failure.
pub fn session(scene: &Scene, config: &Config) -> Session {
    let device = match config.device {
        DeviceKind::Gpu if config.cooperative => cooperative_gpu_device().expect("the adapter traces cooperatively"),
        kind => device(kind),
    };
    Session::new(&device, scene.clone(), &config.bvh)
        .unwrap_or_else(|e| panic!("{} session of {} failed: {e}", label(config), scene.name))
}

/// Renders `request` to the end of its samples, panicking with the error's text on failure.
pub fn render_request(session: &Session, request: &ImageRequest) -> Film {
    match session.render(request).and_then(|r| r.complete(&mut Control::default())) {
        Ok(out) => out.film,
        Err(e) => panic!("{} render of {} failed: {e}", session_label(session), session.scene().name),
    }
}

/// Renders the session's scene through its own camera with `settings`, every sample.
pub fn render_settings(session: &Session, settings: &Settings) -> Film {
    render_request(session, &ImageRequest { camera: session.scene().camera, settings: settings.clone(), samples: None })
}

/// Renders `scene` (its camera and settings) as `config` says, panicking with the
/// error's text on failure.
pub fn render_with(scene: &Scene, config: &Config) -> Film {
    render_settings(&session(scene, config), &scene.settings)
}

/// Renders `scene` on a device of `kind` with the default BVH options.
pub fn render_on(scene: &Scene, kind: DeviceKind) -> Film {
    render_with(scene, &Config { device: kind, ..Default::default() })
}

/// The shared GPU device's adapter and pipelines (check [`gpu_available`] first).
pub fn gpu_adapter() -> Arc<GpuDevice> {
    gpu_device().as_gpu().expect("a GPU device").clone()
}

/// A GPU device on a context of its own, opened on the default adapter and set up by
/// `setup` (test limits, `CPU_LANES`) before it is used.
pub fn gpu_device_with(setup: impl FnOnce(&mut GpuContext)) -> Arc<GpuDevice> {
    let mut ctx = GpuContext::new(None).expect("adapter opens");
    setup(&mut ctx);
    Arc::new(GpuDevice::new(ctx))
}

/// `bvh` (built from `scene`) uploaded to `dev` with the geometry in `storage` (the
/// adapter's preference when `None`), and a target rendering the image of the scene's
/// camera and settings on it.
pub fn gpu_image(
    dev: &Arc<GpuDevice>,
    scene: &Scene,
    bvh: &GpuBvh,
    storage: Option<GeometryStorage>,
) -> aorender::Result<(GpuScene, GpuTarget)> {
    let storage = storage.unwrap_or_else(|| dev.ctx.preferred_storage());
    let gs = GpuScene::upload(&dev.ctx, scene, bvh, storage, None)?;
    let s = &scene.settings;
    let frame = FrameUniforms::image(&scene.camera, s, gs.node_count, gs.plane_count, value_exponent_of(scene));
    let target = GpuTarget::image(dev, &gs, frame, s.sampler, s.hemisphere)?;
    Ok((gs, target))
}

/// The bound 2^e of the samples of an image of `scene` (its albedos and background), as
/// a session sets it: e.
pub fn value_exponent_of(scene: &Scene) -> i32 {
    aorender::film::value_exponent(aorender::accumulation::max_sample_value(scene, scene.settings.background))
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

/// The repository root (the workspace's, where `scenes/` is).
pub fn repo() -> PathBuf {
    crate_dir().ancestors().nth(2).expect("the crate lies two levels below the workspace").to_path_buf()
}

/// The library crate's directory (where `tests/` and `shaders/` are).
pub fn crate_dir() -> PathBuf {
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

/// Independent renders agree: the image means within 4 standard errors, and the
/// per-pixel z-scores have mean square within 4 of its own standard errors of the value
/// expected for two estimates whose variances are themselves estimated from n samples.
/// A pixel whose samples were all the same on both sides (no spread: an open or a closed
/// pixel under cosine sampling) has no z-score: its two means, samples of magnitude at
/// most `max_value`, must lie within each other's bounded-value 95 % intervals
/// ([`aorender::interval_95`]: equal means always do).
pub fn assert_statistical_agreement(gpu: &Film, cpu: &Film, max_value: f64, what: &str) {
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
    // What interval_95 takes for no spread at all.
    let flat = |e: f64| e <= 1e-9 * max_value;
    let mut z2 = Vec::new();
    let mut both_flat = 0;
    for i in 0..a.len() {
        if flat(ea[i]) && flat(eb[i]) {
            both_flat += 1;
            let interval = |film: &Film, mean: f64| {
                let n = film.samples_of(i);
                aorender::interval_95(mean, 0.0, n.saturating_sub(1), n, max_value)
            };
            let ((la, ha), (lb, hb)) = (interval(gpu, a[i]), interval(cpu, b[i]));
            assert!(
                la <= b[i] && b[i] <= ha && lb <= a[i] && a[i] <= hb,
                "{what}: pixel {i}, no spread on either side: {} ([{la}, {ha}]) and {} ([{lb}, {hb}])",
                a[i],
                b[i]
            );
            continue;
        }
        z2.push((a[i] - b[i]).powi(2) / (ea[i] * ea[i] + eb[i] * eb[i]));
    }
    assert!(z2.len() > 100, "{what}: only {} pixels vary", z2.len());
    let m = z2.iter().sum::<f64>() / z2.len() as f64;
    let sd = (z2.iter().map(|z| (z - m).powi(2)).sum::<f64>() / (z2.len() - 1) as f64).sqrt();
    let se = sd / (z2.len() as f64).sqrt();
    // A t-distributed z with ν = 2(n - 1) degrees of freedom has E[z²] = ν/(ν - 2).
    let nu = 2.0 * (gpu.samples as f64 - 1.0);
    let expected = nu / (nu - 2.0);
    eprintln!(
        "{what}: mean {mg:.5} vs {mc:.5} (σ {sigma:.2e}); mean z² {m:.3} ± {se:.3} over {} pixels ({both_flat} without \
         spread on either side)",
        z2.len()
    );
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
