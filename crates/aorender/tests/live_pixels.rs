//! An adaptive image's passes, once pixels have stopped, dispatch the live pixels alone
//! (`gpu/compact.rs`): the list the device makes is the live pixels in tile order, each
//! tile's in the kernel's order, for any stopped pixels and films past one workgroup of
//! the scan's reach; and a listed pass renders the film of a pass over every tile, bit
//! for bit, as adaptive renders do with and without the list, and on the CPU reference.

mod common;

use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::film::INACTIVE_SLOT_BITS;
use aorender::gpu::GpuTarget;
use aorender::gpu::layout::WORKGROUP_SIZE;
use aorender::{Control, DeviceKind, ErrorTarget, ImageRequest, Sampler, Sampling, Scene, Settings};
use common::*;

/// The bunny, framed bare, at `w`×`h` with AO rays of at most 0.05.
fn bunny(w: u32, h: u32) -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    (scene.settings.width, scene.settings.height) = (w, h);
    scene.settings.sampling.max_distance = Some(0.05);
    scene
}

/// A stream of pseudo-random numbers in [0, 1) (xorshift64*), the same on every run.
struct Numbers(u64);

impl Numbers {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A mask of `n` pixels, each stopped with probability `p`.
fn random_mask(n: usize, p: f64, numbers: &mut Numbers) -> Vec<bool> {
    (0..n).map(|_| numbers.next() < p).collect()
}

/// The live pixels of a `w`×`h` film under `stopped`, in the order the device must list
/// them: tiles row by row, each tile's pixels in `tile_pixel`'s order (ao.wgsl): 4 × 2
/// blocks of 8 lanes, 8 × 4 halves of 32.
fn expected_list(w: u32, h: u32, stopped: &[bool]) -> Vec<u32> {
    let [tw, th] = WORKGROUP_SIZE;
    let mut list = Vec::new();
    for ty in 0..h.div_ceil(th) {
        for tx in 0..w.div_ceil(tw) {
            for lid in 0..tw * th {
                let x = tx * tw + ((lid & 3) | ((lid >> 1) & 4));
                let y = ty * th + (((lid >> 2) & 1) | ((lid >> 3) & 6));
                if x < w && y < h && !stopped[(y * w + x) as usize] {
                    list.push(y * w + x);
                }
            }
        }
    }
    list
}

/// The target of `scene`'s image on the shared adapter.
fn target(scene: &Scene) -> GpuTarget {
    let bvh = GpuBvh::build(scene, BvhLayout::Cwbvh, BuildQuality::default());
    gpu_image(&gpu_adapter(), scene, &bvh, None).unwrap_or_else(|e| panic!("{e}")).1
}

/// For random stopped pixels (few, half, most, all but one, all), on films whose sides
/// are no multiple of a tile, one of more tiles than a block of the scan (256) and one of
/// more blocks than the scan's workgroup has invocations (256), the device's list is the
/// host's, and its count the number of live pixels.
#[test]
fn the_list_holds_the_live_pixels_in_tile_order() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to list");
        return;
    }
    let mut numbers = Numbers(0x9e37_79b9_7f4a_7c15);
    for (w, h) in [(29, 23), (203, 150), (2101, 2050)] {
        let mut target = target(&bunny(w, h));
        let tiles = w.div_ceil(8) * h.div_ceil(8);
        let n = (w * h) as usize;
        let mut masks: Vec<(String, Vec<bool>)> =
            [0.1, 0.5, 0.97].map(|p| (format!("{p} stopped"), random_mask(n, p, &mut numbers))).into();
        let mut one_left = vec![true; n];
        one_left[n - 1 - n / 3] = false;
        masks.push(("all but one stopped".into(), one_left));
        masks.push(("all stopped".into(), vec![true; n]));
        for (what, mask) in &masks {
            let what = format!("{w}×{h} ({tiles} tiles), {what}");
            target.stop_pixels(mask).unwrap_or_else(|e| panic!("{what}: {e}"));
            let (list, found) = target.live_pixels().unwrap().unwrap_or_else(|| panic!("{what}: no list made"));
            let expected = expected_list(w, h, mask);
            assert_eq!(found as usize, expected.len(), "{what}: the listing counted other pixels");
            assert!(list == expected, "{what}: the list differs from the host's");
        }
        // Every pixel sampled again: passes go back to every tile.
        target.stop_pixels(&[]).unwrap();
        assert!(target.live_pixels().unwrap().is_none(), "{w}×{h}: a list kept with no pixel stopped");
    }
}

/// A listed pass renders the film of a pass over every tile, bit for bit, with the
/// per-lane and (where the adapter has it) the cooperative traversal: with most pixels
/// stopped, with all stopped (nothing dispatched: the film keeps its marks) and, after
/// the stopped pixels are sampled again, with none.
#[test]
fn listed_passes_render_the_bits_of_every_tile() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    // Spheres on a plane.
    let mut scene = Scene::default_scene();
    (scene.settings.width, scene.settings.height) = (61, 37);
    let n = 61 * 37;
    let tiles_only = gpu_device_with(|ctx| ctx.set_list_live_pixels(false));
    let mut numbers = Numbers(7);
    let most = random_mask(n, 0.85, &mut numbers);
    let cases: [(&str, Vec<bool>); 3] =
        [("most stopped", most.clone()), ("all stopped", vec![true; n]), ("none stopped", Vec::new())];
    let cooperative = cooperative_gpu_device().and_then(|d| d.as_gpu().cloned());
    let devices = [Some(("per lane", gpu_adapter())), cooperative.map(|d| ("cooperative", d))];
    for (traversal, dev) in devices.into_iter().flatten() {
        let bvh = GpuBvh::build(&scene, BvhLayout::Cwbvh, BuildQuality::default());
        let film = |dev: &std::sync::Arc<aorender::gpu::GpuDevice>, mask: &[bool], listed: bool| {
            let (_, mut target) = gpu_image(dev, &scene, &bvh, None).unwrap_or_else(|e| panic!("{e}"));
            // "none stopped": stopped first, then sampled again, so a stale list would show.
            target.stop_pixels(if mask.is_empty() { &most } else { mask }).unwrap();
            target.stop_pixels(mask).unwrap();
            if mask.is_empty() {
                // As a render that starts again does: the film loses its marks.
                target.clear_film().unwrap();
            }
            assert_eq!(target.live_pixels().unwrap().is_some(), listed, "{traversal}: listing");
            target.render_pass(3, 9).unwrap_or_else(|e| panic!("{e}"));
            target.render_pass(12, 4).unwrap_or_else(|e| panic!("{e}"));
            target.film_words().unwrap()
        };
        for (what, mask) in &cases {
            let listed = film(&dev, mask, !mask.is_empty());
            let tiled = film(&tiles_only, mask, false);
            let what = format!("{traversal}, {what}");
            // The stopped pixels keep their marks; the live ones have samples (those that
            // see the background, 0, have none to show).
            let marked = listed.iter().filter(|w| w[3] == INACTIVE_SLOT_BITS).count();
            assert_eq!(marked, mask.iter().filter(|&&s| s).count(), "{what}: other pixels marked stopped");
            let sampled = listed.iter().filter(|w| w[3] != INACTIVE_SLOT_BITS && **w != [0; 4]).count();
            assert_eq!(sampled > 0, marked < n, "{what}: {sampled} pixels sampled, {marked} stopped");
            assert!(listed == tiled, "{what}: the listed pass's film differs from every tile's");
        }
    }
}

/// Adaptive renders whose pixels stop at several decisions, on an image whose sides are
/// no multiple of a tile, end with the same bits (sums, per-pixel counts, stopped
/// pixels) whether their passes list the live pixels or dispatch every tile, and as the
/// CPU reference's.
#[test]
fn adaptive_renders_end_with_the_same_bits_listed_or_not() {
    if !gpu_available() {
        eprintln!("no GPU adapter: nothing to compare");
        return;
    }
    let scene = bunny(29, 23);
    let tiles_only = aorender::Device::from_gpu(
        std::sync::Arc::into_inner(gpu_device_with(|ctx| ctx.set_list_live_pixels(false))).expect("one owner"),
    );
    let sessions = [
        session(&scene, &Config::cpu()),
        session(&scene, &Config { device: DeviceKind::Gpu, ..Default::default() }),
        aorender::Session::new(&tiles_only, scene.clone(), &Default::default()).unwrap_or_else(|e| panic!("{e}")),
    ];
    for (sampler, replicate, target) in [(Sampler::Sobol, 8, 0.01), (Sampler::Independent, 4, 0.02)] {
        let what = format!("{} in replicates of {replicate}", sampler.name());
        let sampling = Sampling { sampler, replicate: Some(replicate), seed: 11, ..scene.settings.sampling };
        let settings = Settings { sampling, spp: 1 << 12, ..scene.settings.clone() };
        let request = ImageRequest { camera: scene.camera, settings, samples: None };
        let outs: Vec<_> = sessions
            .iter()
            .map(|s| {
                let mut control =
                    Control { target: Some(ErrorTarget::Rmse(target)), adaptive: true, ..Control::default() };
                s.render(&request).unwrap().complete(&mut control).unwrap_or_else(|e| panic!("{what}: {e}"))
            })
            .collect();
        let r = outs[0].accumulation.exact();
        let stopped = r.stopped.iter().filter(|&&s| s).count();
        let decisions = r.pixel_replicates.iter().collect::<std::collections::BTreeSet<_>>().len();
        eprintln!("{what}: {stopped} of {} pixels stopped early, after {decisions} replicate counts", r.sum.len());
        assert_eq!(outs[0].stats.ended_by, "target", "{what}");
        assert!(stopped > r.sum.len() / 2, "{what}: most pixels should stop early");
        assert!(decisions > 2, "{what}: the pixels stopped at too few decisions to list them again");
        for (out, name) in outs[1..].iter().zip(["listed", "every tile"]) {
            let g = out.accumulation.exact();
            assert_eq!(g.stopped, r.stopped, "{what}, {name}: other pixels stopped");
            assert_eq!(g.pixel_samples, r.pixel_samples, "{what}, {name}: other per-pixel samples");
            assert_eq!(g.pixel_replicates, r.pixel_replicates, "{what}, {name}: other per-pixel replicates");
            assert!(g == r, "{what}, {name}: the sums differ");
            assert!(out.film == outs[0].film, "{what}, {name}: the films differ");
        }
    }
}
