//! An image whose film is past one storage binding (lavapipe binds 128 MiB: 2896² pixels)
//! renders in bands of rows, each a target of its own: with the film capped at a few
//! rows here, a small image takes several bands, and renders the unsplit film bit for
//! bit (also adaptively, and in replicates), resumes and merges to its bits, and agrees
//! with the CPU reference as the unsplit one does.

mod common;
use aorender::gpu::GpuDevice;
use aorender::gpu::context::GpuContext;
use aorender::gpu::target::image_rows_per_target;
use aorender::{Accumulation, Control, Device, ErrorTarget, Film, Hemisphere, ImageRequest, Sampler, Scene, Session};
use common::*;
use std::path::PathBuf;

/// A device on the default adapter whose films hold at most `bytes` each.
fn capped_device(bytes: u64) -> Device {
    let mut ctx = GpuContext::new(None).expect("adapter opens");
    ctx.limit_film_bytes(bytes);
    Device::from_gpu(GpuDevice::new(ctx))
}

/// The bunny, 44 × 37 (rows of a workgroup and a half; the last band 5 rows, the last
/// workgroup column half outside the image), uniform directions so that every sample has
/// its own value.
fn bunny(spp: u32) -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (scene.settings.width, scene.settings.height, scene.settings.spp) = (44, 37, spp);
    scene.settings.sampling.hemisphere = Hemisphere::Uniform;
    scene
}

/// A film of 8 rows of 44 pixels, 16 bytes each, and a little: bands of 8 rows.
const BAND_BYTES: u64 = 8 * 44 * 16 + 100;

/// The sessions of `scene` on the shared device and on one whose films hold 8 rows.
fn sessions(scene: &Scene) -> (Session, Session) {
    let whole = Session::new(&gpu_device(), scene.clone(), &Default::default()).unwrap();
    let banded = capped_device(BAND_BYTES);
    let rows = image_rows_per_target(banded.as_gpu().unwrap(), scene.settings.width);
    assert_eq!(rows, 8, "the cap makes bands of 8 rows");
    let banded = Session::new(&banded, scene.clone(), &Default::default()).unwrap();
    (whole, banded)
}

/// Every sum of two films, bit for bit.
fn assert_same_film(a: &Film, b: &Film, what: &str) {
    assert!(a.image_mean() > 0.1, "{what}: the bunny is not in view");
    assert_eq!(a.samples, b.samples, "{what}");
    assert_eq!(a.sum, b.sum, "{what}: sums");
    assert_eq!(a.sum_sq, b.sum_sq, "{what}: sums of squares");
    assert_eq!(a.replicate_sq, b.replicate_sq, "{what}: replicates' squares");
    assert_eq!(a.pixel_samples, b.pixel_samples, "{what}: samples per pixel");
}

/// The film of `request` on `session` under `control`.
fn render(session: &Session, request: &ImageRequest, control: &mut Control) -> Accumulation {
    let mut render = session.render(request).unwrap_or_else(|e| panic!("{e}"));
    render.run(control).unwrap_or_else(|e| panic!("{e}"));
    render.finish().unwrap_or_else(|e| panic!("{e}")).accumulation
}

#[test]
fn an_image_in_bands_renders_the_unsplit_film() {
    if !gpu_available() {
        return;
    }
    let scene = bunny(48);
    let (whole, banded) = sessions(&scene);
    let cpu = Session::new(&Device::cpu(), scene.clone(), &Default::default()).unwrap();
    for (sampler, replicate) in [(Sampler::Independent, None), (Sampler::Sobol, Some(8))] {
        let what = sampler.name();
        let mut request = whole.default_request();
        (request.settings.sampling.sampler, request.settings.sampling.replicate) = (sampler, replicate);
        let a = render(&whole, &request, &mut Control::default()).film().unwrap();
        let b = render(&banded, &request, &mut Control::default()).film().unwrap();
        assert_same_film(&a, &b, what);
        // As the unsplit film, the CPU reference's within the rounding of an adapter's samples.
        let c = render(&cpu, &request, &mut Control::default()).film().unwrap();
        let worst = b.mean().iter().zip(c.mean()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst <= 1e-5, "{what}: a pixel differs from the CPU reference's by {worst}");
    }
    // Adaptive: the pixels that stop are marked in each band's part of the film.
    let mut request = whole.default_request();
    (request.settings.spp, request.settings.sampling.replicate) = (256, Some(8));
    let control = || Control { target: Some(ErrorTarget::Rmse(0.02)), adaptive: true, ..Control::default() };
    let a = render(&whole, &request, &mut control()).film().unwrap();
    let b = render(&banded, &request, &mut control()).film().unwrap();
    assert!(!a.pixel_samples.is_empty(), "some pixels stopped early");
    assert_same_film(&a, &b, "adaptive");
}

#[test]
fn a_banded_render_resumes_and_merges_to_the_unsplit_bits() {
    if !gpu_available() {
        return;
    }
    let scene = bunny(512);
    let (whole, banded) = sessions(&scene);
    let request = whole.default_request();
    let full = render(&whole, &request, &mut Control::default()).film().unwrap();
    // Stopped after its first pass (its block in progress in the bands' films), then
    // continued in bands, and on the unsplit device.
    let stopped = render(&banded, &request, &mut Control { time_limit: Some(1e-9), ..Control::default() });
    assert!(stopped.samples() < 512 && stopped.partial().is_some(), "the first run stopped inside a block");
    for (session, what) in [(&banded, "resumed in bands"), (&whole, "resumed whole")] {
        let mut resumed = session.render(&request).unwrap();
        resumed.resume(stopped.clone()).unwrap();
        resumed.run(&mut Control::default()).unwrap();
        assert_same_film(&full, &resumed.finish().unwrap().accumulation.film().unwrap(), what);
    }
    // Two shards of 256 samples, in bands, merged.
    let shard = |range: std::ops::Range<u32>| {
        let request = ImageRequest { samples: Some(range.clone()), ..request.clone() };
        (PathBuf::from(format!("{range:?}")), render(&banded, &request, &mut Control::default()))
    };
    let merged = aorender::merge(&[shard(256..512), shard(0..256)]).unwrap();
    assert!(merged.same_as_single_run);
    assert_same_film(&full, &merged.film, "merged");
}
