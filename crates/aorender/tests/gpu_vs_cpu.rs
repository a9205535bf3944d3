//! The GPU kernel against the CPU reference: with independent seeds the two images agree
//! within their standard errors (image mean and per-pixel distribution); with the same
//! seed they trace the same random numbers and agree pixel by pixel.

mod common;
use aorender::accumulation::max_sample_value;
use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::gpu::GpuScene;
use aorender::gpu::context::GpuContext;
use aorender::{DeviceKind, GeometryStorage, Hemisphere, Sampler, Scene};
use common::*;

/// A small mesh scene: a bumpy grid floor with a box standing on it, written as OBJ.
fn mesh_scene(dir: &std::path::Path) -> Scene {
    let tris = floor_and_box();
    let obj = dir.join("floor_and_box.obj");
    write_obj(&obj, &tris);
    let mut scene = Scene::load(&obj).expect("mesh loads");
    scene.settings.width = 48;
    scene.settings.height = 48;
    scene.settings.spp = 64;
    scene
}

fn aobench() -> Scene {
    let mut scene = Scene::default_scene();
    scene.settings.width = 64;
    scene.settings.height = 64;
    scene.settings.spp = 64;
    scene
}

fn check_scene(mut scene: Scene, what: &str) {
    if !gpu_available() {
        return;
    }
    // The scene prepared once on the CPU and on the adapter in each layout; each render
    // below asks them for other settings.
    let cpu_session = session(&scene, &Config::cpu());
    let gpu_sessions: Vec<(Config, aorender::Session)> =
        gpu_configs().into_iter().map(|c| (c, session(&scene, &c))).collect();
    for (hemisphere, (options, gpu_session)) in
        Hemisphere::ALL.into_iter().flat_map(|h| gpu_sessions.iter().map(move |o| (h, o)))
    {
        scene.settings.sampling.hemisphere = hemisphere;
        for sampler in Sampler::ALL {
            let what = format!("{what}, {}, {}, {}", hemisphere.name(), sampler.name(), label(options));
            scene.settings.sampling.sampler = sampler;
            scene.settings.sampling.seed = 1;
            let gpu = render_settings(gpu_session, &scene.settings);
            // Same seed: the same random numbers, so the same samples up to rounding in
            // traversal (different BVH layouts); a pixel may differ where a ray grazes an edge.
            let cpu_same_seed = render_settings(&cpu_session, &scene.settings);
            if sampler == Sampler::Independent {
                // The per-pixel z-test needs independent samples within each pixel.
                scene.settings.sampling.seed = 2;
                let cpu = render_settings(&cpu_session, &scene.settings);
                assert_ne!(cpu.mean(), cpu_same_seed.mean(), "{what}: seeds must change the image");
                let max = max_sample_value(&scene, scene.settings.background);
                assert_statistical_agreement(&gpu, &cpu, max, &what);
            }
            let (a, b) = (gpu.mean(), cpu_same_seed.mean());
            let close = a.iter().zip(&b).filter(|(x, y)| (*x - *y).abs() <= 1e-4).count();
            assert!(
                close as f64 >= 0.99 * a.len() as f64,
                "{what}: with the same seed only {close} of {} pixels match",
                a.len()
            );
        }
    }
}

#[test]
fn aobench_gpu_agrees_with_cpu() {
    check_scene(aobench(), "aobench");
}

#[test]
fn mesh_gpu_agrees_with_cpu() {
    let dir = temp_dir();
    check_scene(mesh_scene(dir.path()), "mesh");
}

#[test]
fn gpu_render_is_reproducible() {
    if !gpu_available() {
        return;
    }
    let mut scene = aobench();
    scene.settings.spp = 8;
    for options in gpu_configs() {
        // Two sessions: each builds and uploads the BVH anew.
        let a = render_with(&scene, &options);
        let b = render_with(&scene, &options);
        assert_eq!(a.sum, b.sum, "{}: same seed, same adapter: identical accumulation", label(&options));
    }
}

/// An invocation that renders several samples adds them to the running sums in the same
/// order as one dispatch per sample: the film is the same bit for bit, whatever the
/// samples per invocation, with passes that they do not divide. The uniform hemisphere
/// gives every sample its own value (cosine-weighted ones are 0 or the albedo, whose sums
/// do not depend on the order).
#[test]
fn samples_per_invocation_leave_the_film_unchanged() {
    if !gpu_available() {
        return;
    }
    let dev = gpu_adapter();
    let dir = temp_dir();
    for (mut scene, what) in [(aobench(), "aobench"), (mesh_scene(dir.path()), "mesh")] {
        scene.settings.sampling.hemisphere = Hemisphere::Uniform;
        for layout in [BvhLayout::Bvh2, BvhLayout::Cwbvh] {
            let bvh = GpuBvh::build(&scene, layout, BuildQuality::default());
            let mut films = Vec::new();
            for per in [1, 3, u32::MAX] {
                let (_, mut renderer) = gpu_image(&dev, &scene, &bvh, None).unwrap();
                let per = renderer.set_samples_per_invocation(per);
                renderer.render_pass(0, 7).unwrap();
                renderer.render_pass(7, 57).unwrap();
                films.push((per, renderer.read_film(64).unwrap()));
            }
            let (most, _) = films[2];
            assert!(most > 7, "{what} {layout:?}: only {most} samples per invocation were set");
            for (per, film) in &films[1..] {
                assert_eq!(film.sum, films[0].1.sum, "{what} {layout:?}: {per} samples per invocation");
                assert_eq!(film.sum_sq, films[0].1.sum_sq, "{what} {layout:?}: {per} samples per invocation");
            }
        }
    }
}

/// Where the adapter has timestamp queries, a pass reports its GPU time: positive and no
/// longer than the pass took on the clock.
#[test]
fn passes_report_gpu_time_from_timestamps() {
    if !gpu_available() {
        return;
    }
    let dev = gpu_adapter();
    let scene = aobench();
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let (_, mut renderer) = gpu_image(&dev, &scene, &bvh, None).unwrap();
    let start = std::time::Instant::now();
    let pass = renderer.render_pass(0, 16).unwrap();
    let wall = start.elapsed().as_secs_f64();
    let has_timestamps = dev.ctx.device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
    assert_eq!(pass.gpu_seconds.is_some(), has_timestamps);
    if let Some(gpu) = pass.gpu_seconds {
        eprintln!("pass of 16 spp at 64²: {gpu:.6} s on the GPU, {wall:.6} s on the clock");
        assert!(gpu > 0.0 && gpu <= wall, "GPU time {gpu} s, wall {wall} s");
    }
}

/// Nodes and primitives in storage buffers or in textures, each whole or split across
/// several bindings (the chunks sized from the adapter's binding limits: buffers of at
/// most 8,000 bytes and textures of 600 × 2 texels, or larger where the adapter binds too
/// few to hold this small scene so), render the same film, bit for bit; a split into more
/// chunks than the adapter's bindings (or a cap below them) is an error with the numbers.
#[test]
fn geometry_in_buffers_or_textures_whole_or_split_renders_the_same_film() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let mut scene = mesh_scene(dir.path());
    scene.settings.sampling.hemisphere = Hemisphere::Uniform;
    let whole = gpu_adapter();
    let prim_size = std::mem::size_of::<aorender::bvh::GpuPrimitive>();
    for layout in [BvhLayout::Bvh2, BvhLayout::Cwbvh] {
        let bvh = GpuBvh::build(&scene, layout, BuildQuality::default());
        let (node_bytes, prim_bytes) = (bvh.node_bytes.len() as u64, (bvh.records.len() * prim_size) as u64);
        // Chunks of at most 8,000 bytes (600 × 2 texels) make three or more of the
        // primitives; larger ones where the adapter binds too few for that, each kind
        // taking at most half of what it binds.
        let chunk_bytes = |allowed: u32, at_least: u64| {
            let half = u64::from(allowed / 2).max(1);
            at_least.max(node_bytes.div_ceil(half)).max(prim_bytes.div_ceil(half))
        };
        let (buffers, _) = whole.ctx.geometry_bindings(GeometryStorage::Buffers);
        let (textures, _) = whole.ctx.geometry_bindings(GeometryStorage::Textures);
        let buffer_bytes = chunk_bytes(buffers, 8_000);
        // Rows of 600 texels of 16 bytes.
        let texture_rows = chunk_bytes(textures, 2 * 600 * 16).div_ceil(600 * 16) as u32;
        let split = gpu_device_with(|ctx| {
            ctx.limit_chunk_bytes(buffer_bytes);
            ctx.limit_texture_size(600, texture_rows);
        });
        eprintln!(
            "{layout:?}: {buffers} buffer and {textures} texture bindings allowed: chunks of {buffer_bytes} bytes, \
             textures of 600 × {texture_rows}"
        );
        assert!(prim_bytes > 2 * buffer_bytes.max(texture_rows as u64 * 600 * 16), "too few chunks to test");
        let contexts = [
            (&whole, GeometryStorage::Buffers),
            (&split, GeometryStorage::Buffers),
            (&whole, GeometryStorage::Textures),
            (&split, GeometryStorage::Textures),
        ];
        let render = |&(dev, storage): &(&std::sync::Arc<aorender::gpu::GpuDevice>, GeometryStorage)| {
            let (gs, mut renderer) = gpu_image(dev, &scene, &bvh, Some(storage)).unwrap();
            assert_eq!(gs.chunks.storage, storage);
            let bindings = gs.geometry_bindings();
            renderer.render_pass(0, 16).unwrap();
            (renderer.read_film(16).unwrap(), bindings)
        };
        let (a, a_bindings) = render(&contexts[0]);
        assert!(a.image_mean() > 0.0);
        assert_eq!(a_bindings, 2);
        for (k, ctx) in contexts.iter().enumerate().skip(1) {
            let (b, bindings) = render(ctx);
            let split = k % 2 == 1;
            assert_eq!(split, bindings > 3, "{layout:?} context {k}: {bindings} bindings");
            assert_eq!(a.sum, b.sum, "{layout:?} context {k}");
            assert_eq!(a.sum_sq, b.sum_sq, "{layout:?} context {k}");
        }
    }
    // One chunk a node or primitive, past what the adapter binds, or past eight bindings
    // where it binds more.
    let mut tiny = GpuContext::new(None).unwrap();
    tiny.limit_chunk_bytes(64);
    let allowed = tiny.geometry_bindings(GeometryStorage::Buffers).0.min(8);
    tiny.limit_geometry_bindings(allowed);
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let e = GpuScene::upload(&tiny, &scene, &bvh, GeometryStorage::Buffers, None)
        .expect_err("more chunks than the adapter's bindings")
        .to_string();
    assert!(e.contains("max_storage_buffers_per_shader_stage"), "{e}");
    assert!(e.contains(&format!("{} bytes", allowed as u64 * 64)), "{e}");
}

/// The traversal's formulations for CPU adapters (`CPU_LANES`: min and max as a
/// comparison and a select, the leading bit from a float's exponent) and the plain ones
/// render the same film, bit for bit, on the bunny and on the default scene's spheres.
#[test]
fn cpu_lane_formulations_render_the_same_film() {
    if !gpu_available() {
        return;
    }
    let mut bunny = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (bunny.settings.width, bunny.settings.height) = (64, 64);
    for scene in [bunny, aobench()] {
        let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
        let films = [false, true].map(|cpu_lanes| {
            let dev = gpu_device_with(|ctx| ctx.set_cpu_lanes(cpu_lanes));
            let (_, mut renderer) = gpu_image(&dev, &scene, &bvh, None).unwrap();
            renderer.render_pass(0, 16).unwrap();
            renderer.read_film(16).unwrap()
        });
        assert!(films[0].image_mean() > 0.05, "{}: nothing in view", scene.name);
        assert_eq!(films[0].sum, films[1].sum, "{}", scene.name);
        assert_eq!(films[0].sum_sq, films[1].sum_sq, "{}", scene.name);
    }
}

/// A mesh whose BVH is built in many octree cells and whose primitive records are made
/// and uploaded in many pieces (202,520 triangles: 9.7 MB of records, 1 MiB a piece)
/// renders like the CPU reference pixel by pixel with the same seed, in buffers and in
/// textures.
#[test]
fn a_mesh_uploaded_in_pieces_agrees_with_cpu() {
    if !gpu_available() {
        return;
    }
    let mut scene = Scene::load(&repo().join("scenes/dragon_vrip_res2.ply.gz")).unwrap_or_else(|e| panic!("{e}"));
    scene.settings.width = 32;
    scene.settings.height = 32;
    scene.settings.spp = 16;
    let cpu = render_on(&scene, DeviceKind::Cpu);
    let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
    let record_bytes = bvh.records.len() * std::mem::size_of::<aorender::bvh::GpuPrimitive>();
    assert!(record_bytes > 8 << 20, "{record_bytes} bytes of records: too few pieces to test");
    let dev = gpu_adapter();
    for storage in [GeometryStorage::Buffers, GeometryStorage::Textures] {
        let (_, mut renderer) = gpu_image(&dev, &scene, &bvh, Some(storage)).unwrap();
        renderer.render_pass(0, 16).unwrap();
        let gpu = renderer.read_film(16).unwrap();
        let (a, b) = (gpu.mean(), cpu.mean());
        assert!(gpu.image_mean() > 0.05, "{storage:?}: the mesh is not in view");
        let close = a.iter().zip(&b).filter(|(x, y)| (*x - *y).abs() <= 1e-4).count();
        assert!(close as f64 >= 0.99 * a.len() as f64, "{storage:?}: only {close} of {} pixels match", a.len());
    }
}
