//! The accumulation of a render: the exact sums of its finished blocks of samples and the
//! device's sums of the block in progress, what the samples were rendered from, and the
//! sample indices they cover. It can be continued from the same bits (`resume`), and
//! accumulations of disjoint sample ranges merge exactly ([`merge`]). The checkpoint file
//! format (`output::checkpoint`) stores it.
//!
//! Samples are summed in blocks of [`BLOCK_SAMPLES`] sample indices: the device sums a
//! block in 64-bit fixed point ([`BlockSums`], the same integers on every device for the
//! same samples), then the block is shifted exactly into the wider [`ExactSums`]. Every
//! addition is an integer's, so the sums do not depend on how the samples were split.

use crate::error::{Error, Result};
use crate::film::{
    BLOCK_SAMPLES, BlockSums, ErrorEstimator, ExactSums, Film, REPLICATE_SQ_SHIFT, SampleRange, rmse_bound,
    standard_error,
};
use crate::gpu::stats::{AdaptQuery, AdaptSums, CheckQuery, CheckSums};
use crate::kinds::{BuildQuality, BvhLayout, BvhOptions, DeviceKind};
use crate::probe::{Probe, ProbeValue, checked, probe_film_bent_normals, probe_film_values};
use crate::sampler::Sampler;
use crate::scene::{Camera, Projection, Sampling, Scene, Settings};
use crate::sky::Sky;
use glam::Vec3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Everything a sample's value depends on besides its index and the device: two
/// accumulations with equal `SampleSettings` hold samples of the same render. Built in
/// one place, [`SampleSettings::new`], for images and probe films alike.
#[derive(Clone, Debug)]
pub struct SampleSettings {
    /// BLAKE3 hash of the geometry (every triangle, sphere and plane with its albedo) and
    /// the camera, as the renderers receive them.
    pub scene_hash: [u8; 32],
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel of the render (with `strata`, what the cell samplers depend on).
    pub spp: u32,
    /// Cells per axis of the cell samplers ([`Sampler::strata_per_axis`]), 1 for the others.
    pub strata: u32,
    /// What the film's slots hold.
    pub layout: FilmLayout,
    /// Value of camera rays that miss.
    pub background: f32,
    /// The request's sampling, its replicate size resolved (`Some` of
    /// [`Sampling::replicate_samples`]).
    pub sampling: Sampling,
}

impl SampleSettings {
    /// The identity of a film of `layout`, `width` × `height` slots (for probes: lanes ×
    /// points) of `spp` samples each, whose scene (and camera, or points) hash to
    /// `scene_hash` ([`scene_hash`], `probes_hash`), drawn with `sampling`.
    pub fn new(
        scene_hash: [u8; 32],
        layout: FilmLayout,
        width: u32,
        height: u32,
        spp: u32,
        background: f32,
        sampling: &Sampling,
    ) -> SampleSettings {
        SampleSettings {
            scene_hash,
            width,
            height,
            spp,
            strata: sampling.strata(spp),
            layout,
            background,
            sampling: Sampling { replicate: Some(sampling.replicate_samples()), ..*sampling },
        }
    }

    /// The identity of an image of `settings` whose scene and camera hash to `scene_hash`.
    pub fn image(scene_hash: [u8; 32], settings: &Settings) -> SampleSettings {
        let s = settings;
        SampleSettings::new(scene_hash, FilmLayout::Image, s.width, s.height, s.spp, s.background, &s.sampling)
    }

    /// Samples per replicate ([`Sampler::replicate_samples`]).
    pub fn replicate(&self) -> u32 {
        self.sampling.replicate_samples()
    }

    /// What differs between `self` (a checkpoint's) and `other` (this render's) that
    /// changes the samples, as "name: checkpoint's value, not this render's"; empty when
    /// the samples are the same. The samples per pixel matter only through the strata.
    pub fn differences(&self, other: &SampleSettings) -> Vec<String> {
        let mut d = Vec::new();
        let check = |d: &mut Vec<String>, name: &str, a: String, b: String| {
            if a != b {
                d.push(format!("{name} {a}, not {b}"));
            }
        };
        check(&mut d, "size", format!("{}x{}", self.width, self.height), format!("{}x{}", other.width, other.height));
        let (a, b) = (&self.sampling, &other.sampling);
        check(&mut d, "seed", a.seed.to_string(), b.seed.to_string());
        check(&mut d, "hemisphere", a.hemisphere.name().into(), b.hemisphere.name().into());
        check(&mut d, "sampler", a.sampler.name().into(), b.sampler.name().into());
        check(&mut d, "sky", a.sky.describe(), b.sky.describe());
        if self.strata != other.strata {
            d.push(format!(
                "samples per pixel {} ({}×{} strata), not {} ({}×{} strata)",
                self.spp, self.strata, self.strata, other.spp, other.strata, other.strata
            ));
        }
        check(&mut d, "samples per replicate", self.replicate().to_string(), other.replicate().to_string());
        check(&mut d, "film", format!("{:?}", self.layout), format!("{:?}", other.layout));
        let distance = |m: Option<f32>| m.map_or("unlimited".to_string(), |m| format!("{m} ({:#010x})", m.to_bits()));
        check(&mut d, "max distance", distance(a.max_distance), distance(b.max_distance));
        check(
            &mut d,
            "background",
            format!("{} ({:#010x})", self.background, self.background.to_bits()),
            format!("{} ({:#010x})", other.background, other.background.to_bits()),
        );
        if self.scene_hash != other.scene_hash {
            d.push("scene: its geometry or camera differ".into());
        }
        d
    }
}

/// Samples between two checks of an [`ErrorTarget`] when every sample is a replicate of
/// its own (the independent sampler); otherwise the checks come at the ends of replicates
/// (`render::check_due` says which).
pub const TARGET_CHECK_SAMPLES: u32 = 16;
/// Replicates an estimate needs before a target can stop a render: seven degrees of
/// freedom at least.
pub const MIN_TARGET_REPLICATES: u64 = 8;

/// The share of an adaptive render's target its allocation aims at ([`Accumulation::allocation`]): below 1,
/// so that the image's RMSE bound, above the estimate, meets the target when the pixels
/// have the replicates allocated to them.
pub const ADAPTIVE_SHARE: f64 = 0.9;

/// The 97.5 % quantile of Student's t with `dof` ≥ 1 degrees of freedom in f32: the
/// table and the Cornish–Fisher expansion of [`crate::film::t_quantile_975`], its
/// coefficients rounded to f32 (`stats.wgsl`'s `t975`, step for step).
// The literals are the shader's, digit for digit: both round them to the same f32.
#[allow(clippy::excessive_precision)]
fn t975(dof: u32) -> f32 {
    match dof {
        0 | 1 => 12.706_204_7,
        2 => 4.302_652_73,
        3 => 3.182_446_31,
        4 => 2.776_445_11,
        5 => 2.570_581_84,
        6 => 2.446_911_85,
        _ => {
            let v = dof as f32;
            1.959_964_04
                + 2.372_271_3 / v
                + 2.822_498_56 / (v * v)
                + 2.555_849_79 / (v * v * v)
                + 1.589_534_04 / ((v * v) * (v * v))
        }
    }
}

/// The signed fixed-point `x` in quanta of 2^`e` as f32, as `stats.wgsl`'s `wide_to_f32`
/// makes it: its magnitude's four 32-bit words, each rounded to f32 and scaled, added
/// from the highest.
pub fn wide_to_f32(x: i128, e: i32) -> f32 {
    let m = x.unsigned_abs();
    let word = |j: u32, k: i32| (((m >> (32 * j)) as u32) as f32 as f64 * 2f64.powi(k)) as f32;
    let f = word(3, e + 96) + word(2, e + 64) + word(1, e + 32) + word(0, e);
    if x < 0 { -f } else { f }
}

/// What an adaptive render's decisions take of one pixel, in f32, step for step what
/// `stats.wgsl`'s `adaptive_pixel` computes on a device, so that both decide alike:
/// (v, mean, σ, k), v the variance of its mean from its `k` replicates of `b` samples
/// (`film::standard_error` squared) and σ the standard deviation of a replicate's mean
/// the allocation takes: the larger of the standard error and the width of the pixel's
/// 95 % interval over 2 × 1.96 (Wilson's score interval where the samples are nearly
/// binary, the Jeffreys bound where they were all equal: [`crate::film::interval_95`]),
/// times √k. A pixel whose samples happen to be nearly equal is so not taken for one
/// without error. v and σ are 0 before a second replicate (an exact pixel's value).
pub fn pixel_sigma(
    sums: (i128, i128, i128),
    samples: u32,
    k: u32,
    query: &AdaptQuery,
    exponents: (i32, i32),
) -> [f32; 4] {
    let (range, max_value) = query.range_code();
    let n = samples as f32;
    let s = wide_to_f32(sums.0, exponents.0);
    let mean = if samples > 0 { s / n } else { 0.0 };
    if k < 2 {
        return [0.0, mean, 0.0, k as f32];
    }
    let q = wide_to_f32(sums.1, exponents.1);
    let r = wide_to_f32(sums.2, exponents.1 + REPLICATE_SQ_SHIFT);
    let (kf, b) = (k as f32, query.replicate as f32);
    let variance = ((r / (b * b) - (kf * mean) * mean) / (kf - 1.0)).max(0.0);
    let v = (variance * b) / n;
    let se = v.sqrt();
    let upper = if range == 0 && s > 0.0 && q > 0.0 { (q / s).min(max_value) } else { max_value };
    let lower = if range == 2 { -max_value } else { mean.min(0.0) };
    let width = if se > 1e-9 * upper.abs().max(f32::MIN_POSITIVE) {
        let t = t975(k - 1);
        let (lo, hi) = (lower.min(mean), upper.max(mean));
        let range = hi - lo;
        let share = (mean - lo) / range;
        let e = se / range;
        let spread = share * (1.0 - share);
        if range > 0.0 && spread > 0.0 {
            let kw = ((t * t) * (e * e)) / spread;
            let centre = (share + 0.5 * kw) / (1.0 + kw);
            let half = (kw * (spread + 0.25 * kw)).sqrt() / (1.0 + kw);
            range * ((centre + half).min(1.0) - (centre - half).max(0.0))
        } else {
            2.0 * (t * se)
        }
    } else {
        let jeffreys = (3.841_458_8 / (2.0 * n + 1.0)).min(1.0);
        jeffreys * mean.max(0.0) + jeffreys * (upper - mean).max(0.0)
    };
    let sigma = se.max(width / 3.92) * kf.sqrt();
    [v, mean, sigma, kf]
}

/// Pixels on each side of a pixel, in its row, whose σ decide its share of an adaptive
/// render's replicates (`share_sigma`; `stats.wgsl`'s `SHARE_NEIGHBOURS`).
pub const SHARE_NEIGHBOURS: usize = 2;

/// The σ̃ that decides pixel `i`'s share of an adaptive render's replicates, from the σ of
/// the pixels around it and never its own (`sigmas`: each pixel's `pixel_sigma` σ, rows of
/// `width`), in f32 step for step as `stats.wgsl`'s `share_sigma`: the root mean square
/// of the σ of the pixels up to `SHARE_NEIGHBOURS` on either side in its row that have
/// one (σ > 0: an exact pixel's tells nothing of this one's spread), or, where none has,
/// the largest σ a replicate's mean can have, half the samples' range (`bound`). Its
/// neighbours' samples are independent of its own, so its stopping time is too, and its
/// mean is unbiased at whatever count it stops (docs/sampling.md). In a row, so that a
/// render in bands of rows decides as the unsplit one.
pub fn share_sigma(sigmas: &[f32], i: usize, width: usize, bound: f32) -> f32 {
    let x = i % width.max(1);
    let (mut sum, mut count) = (0.0f32, 0u32);
    for d in 0..2 * SHARE_NEIGHBOURS {
        let nx = (x + d + usize::from(d >= SHARE_NEIGHBOURS)).wrapping_sub(SHARE_NEIGHBOURS);
        let j = (i - x).wrapping_add(nx);
        if nx < width && j < sigmas.len() && sigmas[j] > 0.0 {
            sum += sigmas[j] * sigmas[j];
            count += 1;
        }
    }
    if count == 0 { bound } else { (sum / count as f32).sqrt() }
}

/// Pixel i's term of the allocation's normaliser, σᵢ² / σ̃ᵢ (0 for an exact pixel), in f32
/// as `stats.wgsl`'s `reduce` takes it ([`Accumulation::allocation`]).
fn share_weight(sigma: f32, share: f32) -> f32 {
    if sigma > 0.0 && share > 0.0 { (sigma * sigma) / share } else { 0.0 }
}

/// Slots of a workgroup of `stats.wgsl`'s reductions.
const REDUCE_WORKGROUP: usize = 256;

/// Sums `terms` as `stats.wgsl`'s `reduce` and `reduce_groups` do, in f32: workgroups of
/// 256 slots halved in a tree, their sums strided over 256 lanes and halved again.
fn tree_sum(terms: &[[f32; 4]]) -> [f32; 4] {
    let halve = |shared: &mut [[f32; 4]; REDUCE_WORKGROUP]| {
        let mut half = REDUCE_WORKGROUP / 2;
        while half > 0 {
            for l in 0..half {
                let other = shared[l + half];
                for (a, b) in shared[l].iter_mut().zip(other) {
                    *a += b;
                }
            }
            half /= 2;
        }
        shared[0]
    };
    let partial: Vec<[f32; 4]> = terms
        .chunks(REDUCE_WORKGROUP)
        .map(|chunk| {
            let mut shared = [[0.0f32; 4]; REDUCE_WORKGROUP];
            shared[..chunk.len()].copy_from_slice(chunk);
            halve(&mut shared)
        })
        .collect();
    let mut shared = [[0.0f32; 4]; REDUCE_WORKGROUP];
    for (g, p) in partial.iter().enumerate() {
        for (a, b) in shared[g % REDUCE_WORKGROUP].iter_mut().zip(p) {
            *a += b;
        }
    }
    halve(&mut shared)
}

/// The decision an adaptive render takes from its [`AdaptSums`] (`Accumulation::allocation`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Allocation {
    /// Replicates a pixel is given per unit of its σ: it stops once k ≥ σ × this.
    pub per_sigma: f32,
    /// Whether the image's RMSE bound already meets the target.
    pub met: bool,
}

/// An accuracy to stop at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ErrorTarget {
    /// An image's root-mean-square error against its converged value, at most this,
    /// with 99 % confidence ([`Film::rmse_bound`]).
    Rmse(f64),
    /// The same, relative to the image's mean.
    RelativeRmse(f64),
    /// Every probe point's standard error at most this.
    PointStdError(f64),
}

impl ErrorTarget {
    /// The target's value.
    pub fn value(self) -> f64 {
        match self {
            ErrorTarget::Rmse(e) | ErrorTarget::RelativeRmse(e) | ErrorTarget::PointStdError(e) => e,
        }
    }
}

/// What the slots of a film hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilmLayout {
    /// One pixel a slot.
    Image,
    /// A row of lanes a probe point: lane l takes the point's samples l, l + lanes, ….
    Probes,
    /// Four slots a probe point: the AO, then the x, y and z of the escaped directions.
    BentProbes,
}

/// How the device's sums of a pass range become replicate sums: every `take` rounds
/// (pass indices: samples of an image, rounds of a probe film) the device's sums are
/// taken; each of `groups` groups (pixels or points), `stride` slots apart, yields
/// `per_take` replicate sums of `summed` consecutive slots each.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReplicatePlan {
    /// Rounds per replicate (or per take, when one round holds several).
    pub take: u32,
    /// Groups: pixels or points.
    pub groups: usize,
    /// Slots from one group to the next.
    pub stride: usize,
    /// Slots summed into one replicate sum.
    pub summed: usize,
    /// Replicates of a group in one take.
    pub per_take: usize,
}

impl SampleSettings {
    /// How the replicates' sums are taken, when the samples are in replicates of two or
    /// more (`None` for independent samples, one replicate, or a probe film whose lanes
    /// do not tile the replicates).
    pub fn replicate_plan(&self) -> Option<ReplicatePlan> {
        let b = self.replicate();
        if b < 2 {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        match self.layout {
            FilmLayout::Image => Some(ReplicatePlan { take: b, groups: w * h, stride: 1, summed: 1, per_take: 1 }),
            FilmLayout::BentProbes => Some(ReplicatePlan { take: b, groups: h, stride: w, summed: 1, per_take: 1 }),
            FilmLayout::Probes => {
                let lanes = self.width;
                if b.is_multiple_of(lanes) {
                    Some(ReplicatePlan { take: b / lanes, groups: h, stride: w, summed: w, per_take: 1 })
                } else if lanes.is_multiple_of(b) {
                    let per_take = (lanes / b) as usize;
                    Some(ReplicatePlan { take: 1, groups: h, stride: w, summed: b as usize, per_take })
                } else {
                    None
                }
            }
        }
    }

    /// How the error of this film is estimated once it holds `replicates` complete
    /// replicates.
    pub fn error_estimator(&self, replicates: u64) -> ErrorEstimator {
        match self.replicate() {
            1 => ErrorEstimator::Samples,
            0 => ErrorEstimator::None,
            _ if self.replicate_plan().is_none() || replicates < 2 => ErrorEstimator::None,
            size => ErrorEstimator::Replicates { size, count: replicates },
        }
    }

    /// Samples of a point in rounds `rounds` of a probe film (lane l of round r takes
    /// sample r × lanes + l, below the samples per point); of a pixel for an image.
    pub fn samples_in(&self, rounds: std::ops::Range<u32>) -> u64 {
        match self.layout {
            FilmLayout::Image | FilmLayout::BentProbes => {
                (rounds.end.min(self.spp) as u64).saturating_sub(rounds.start as u64)
            }
            FilmLayout::Probes => {
                let lanes = self.width as u64;
                let at = |r: u32| (r as u64 * lanes).min(self.spp as u64);
                at(rounds.end).saturating_sub(at(rounds.start))
            }
        }
    }
}

/// BLAKE3 hash of the scene's geometry and camera, with every float by its bits. The
/// camera's eye and target count as the f32 values its rays start from where that is
/// what they are (a scene rendered where it is, or a camera at f32 coordinates), as they
/// always have, so that older checkpoints still match; else by their f64 bits, with the
/// scene's origin.
pub fn scene_hash(scene: &Scene, camera: &Camera) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
    let c = camera;
    let exact = |v: glam::DVec3| v.as_vec3().as_dvec3() == v;
    let as_f32 = scene.origin == glam::DVec3::ZERO
        && ((exact(c.eye) && exact(c.look_at)) || scene.local_origin() == glam::DVec3::ZERO);
    if as_f32 {
        h.update(b"aorender scene v1");
        for f in [c.eye.as_vec3(), c.look_at.as_vec3()].iter().flat_map(|v| v.to_array()) {
            h.update(&f.to_le_bytes());
        }
    } else {
        h.update(b"aorender scene v2");
        for f in [c.eye, c.look_at, scene.origin].iter().flat_map(|v| v.to_array()) {
            h.update(&f.to_le_bytes());
        }
    }
    let projection = match c.projection {
        Projection::Perspective { vfov_deg } => [0.0, vfov_deg],
        Projection::Orthographic { height } => [1.0, height],
    };
    for f in c.up.to_array().into_iter().chain(projection) {
        h.update(&f.to_le_bytes());
    }
    hash_geometry(&mut h, scene);
    *h.finalize().as_bytes()
}

/// Feeds `h` the counts of the scene's primitives, then every triangle, sphere, plane,
/// instanced mesh and instance, every float by its bits.
fn hash_geometry(h: &mut blake3::Hasher, scene: &Scene) {
    let mut buf: Vec<u8> = Vec::with_capacity(1 << 16);
    let put = |h: &mut blake3::Hasher, buf: &mut Vec<u8>, floats: &[f32]| {
        for f in floats {
            buf.extend_from_slice(&f.to_le_bytes());
        }
        if buf.len() >= 1 << 16 {
            h.update(buf);
            buf.clear();
        }
    };
    for (name, count) in
        [("triangles", scene.triangles.len()), ("spheres", scene.spheres.len()), ("planes", scene.planes.len())]
    {
        buf.extend_from_slice(name.as_bytes());
        buf.extend_from_slice(&(count as u64).to_le_bytes());
    }
    // A triangle is its vertices' nine floats and its albedo, in that order.
    put_records(h, &mut buf, &scene.triangles);
    for s in &scene.spheres {
        put(h, &mut buf, &[s.center.x, s.center.y, s.center.z, s.radius, s.albedo]);
    }
    for p in &scene.planes {
        put(h, &mut buf, &[p.normal.x, p.normal.y, p.normal.z, p.point.x, p.point.y, p.point.z, p.albedo]);
    }
    // Instanced meshes and their placements (nothing for a scene without them).
    for m in &scene.meshes {
        buf.extend_from_slice(b"mesh");
        buf.extend_from_slice(&(m.triangles.len() as u64).to_le_bytes());
        put_records(h, &mut buf, &m.triangles);
    }
    for i in &scene.instances {
        buf.extend_from_slice(b"instance");
        buf.extend_from_slice(&i.mesh.to_le_bytes());
        put(h, &mut buf, &i.to_world.to_cols_array());
        put(h, &mut buf, &[i.albedo]);
    }
    h.update(&buf);
}

/// Feeds `h` what `buf` gathered, then the floats of `records` (plain floats, no padding)
/// in order, each by its little-endian bytes.
fn put_records<T: bytemuck::Pod>(h: &mut blake3::Hasher, buf: &mut Vec<u8>, records: &[T]) {
    h.update(buf);
    buf.clear();
    let floats: &[f32] = bytemuck::cast_slice(records);
    if cfg!(target_endian = "little") {
        // The records in memory are the stream's bytes; BLAKE3 spreads one large update over
        // threads, where gathering them a float at a time cost more than the hash itself.
        let bytes: &[u8] = bytemuck::cast_slice(floats);
        if bytes.len() >= 1 << 17 {
            h.update_rayon(bytes)
        } else {
            h.update(bytes)
        };
    } else {
        for piece in floats.chunks(1 << 14) {
            h.update(&piece.iter().flat_map(|f| f.to_le_bytes()).collect::<Vec<u8>>());
        }
    }
}

/// BLAKE3 hash of the scene's geometry alone, every float by its bits (with the scene's
/// origin, which probe points are relative to, where it is not zero).
pub fn geometry_hash(scene: &Scene) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
    h.update(b"aorender geometry v1");
    hash_geometry(&mut h, scene);
    if scene.origin != glam::DVec3::ZERO {
        for f in scene.origin.to_array() {
            h.update(&f.to_le_bytes());
        }
    }
    *h.finalize().as_bytes()
}

/// BLAKE3 hash of probe points, by their bits, over the scene whose geometry hashes to
/// `geometry` ([`geometry_hash`]): what the samples of a probe request depend on besides
/// their sampling.
pub fn probes_hash(geometry: &[u8; 32], probes: &[Probe]) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
    h.update(b"aorender probes v2");
    h.update(geometry);
    h.update(&(probes.len() as u64).to_le_bytes());
    // The same bytes as one update a float, gathered: BLAKE3 hashes a stream, and an
    // update of four bytes costs as much as one of hundreds. Pieces are gathered on
    // threads, a batch at a time so that the gathered bytes stay bounded, and hashed in order.
    let gather = |piece: &[Probe]| {
        let mut buf: Vec<u8> = Vec::with_capacity(piece.len() * 40);
        for p in piece {
            for c in p.position.to_array().into_iter().chain(p.normal.to_array()).chain([p.error]) {
                buf.extend_from_slice(&c.to_le_bytes());
            }
            // Only where there is one, so that a checkpoint of probes without one still matches.
            if p.surface_normal != Vec3::ZERO {
                for c in p.surface_normal.to_array() {
                    buf.extend_from_slice(&c.to_le_bytes());
                }
            }
        }
        buf
    };
    for batch in probes.chunks(PROBE_HASH_PIECE * 64) {
        let pieces: Vec<Vec<u8>> = batch.par_chunks(PROBE_HASH_PIECE).map(gather).collect();
        for piece in &pieces {
            h.update_rayon(piece);
        }
    }
    *h.finalize().as_bytes()
}

/// Points a rayon task estimates at least in [`Accumulation::lane_probe_values`].
const PROBE_VALUES_CHUNK: usize = 1 << 12;

/// Probes gathered into one piece of [`probes_hash`]'s stream (at most 640 KiB of bytes, large
/// enough for BLAKE3 to spread over threads).
const PROBE_HASH_PIECE: usize = 1 << 14;

/// The largest magnitude of a probe sample: a hemisphere weight, at most 2 (the uniform
/// hemisphere's 2 cos θ).
// Classic AO's bounds, which the tests use; requests take the sky's (`Sky::max_weight`).
#[cfg_attr(not(feature = "testing"), allow(dead_code))]
pub const MAX_PROBE_SAMPLE: f64 = 2.0;

/// The largest magnitude a sample of `scene` can take with background `background`:
/// twice the largest albedo (the uniform hemisphere's weight 2 cos θ is at most 2), or
/// the background's.
#[cfg_attr(not(feature = "testing"), allow(dead_code))]
pub fn max_sample_value(scene: &Scene, background: f32) -> f64 {
    max_image_sample(scene, background, &Sky::default())
}

/// The largest magnitude a sample of `scene` can take with background `background` under
/// `sky`: the largest albedo times the sky's largest weight ([`Sky::max_weight`]), or the
/// background's.
pub fn max_image_sample(scene: &Scene, background: f32, sky: &Sky) -> f64 {
    let albedo = scene
        .triangles
        .iter()
        .map(|t| t.albedo)
        .chain(scene.spheres.iter().map(|s| s.albedo))
        .chain(scene.instances.iter().map(|i| i.albedo))
        .chain(scene.planes.iter().map(|p| p.albedo))
        .fold(0.0f64, |m, a| m.max(a as f64));
    (sky.max_weight() * albedo).max((background as f64).abs())
}

/// The accumulation of a render: the samples `first .. next` of every pixel, what they
/// were rendered from, and how.
#[derive(Clone, Debug)]
pub struct Accumulation {
    /// What the samples depend on.
    settings: SampleSettings,
    /// The device that rendered them.
    device: DeviceKind,
    /// BVH layout the GPU traversed.
    bvh_layout: BvhLayout,
    /// BVH build preset.
    bvh_quality: BuildQuality,
    /// Adapter name (`cpu` for the CPU reference).
    adapter: String,
    /// First sample index of the range rendered.
    first: u32,
    /// End of the range asked for.
    end: u32,
    /// Samples `first .. next` are in the sums.
    next: u32,
    /// Samples of the block in progress (in `partial`, not yet in `exact`).
    partial_samples: u32,
    /// False once the replicates whose sums are taken no longer follow their absolute grid
    /// (a render whose last replicate was cut short by its end, continued past that end:
    /// that replicate is not whole in either part). Always true without replicates: the
    /// sums of blocks cut anywhere add to the same integers.
    on_grid: bool,
    /// AO rays traced so far.
    ao_rays: u64,
    /// Passes run so far.
    passes: u32,
    /// Seconds spent rendering so far.
    render_seconds: f64,
    /// Exact sums of the finished blocks.
    exact: ExactSums,
    /// The device's sums of the block in progress, when it has samples.
    partial: Option<BlockSums>,
    /// The file it was read from, for messages (not stored).
    source: Option<PathBuf>,
    /// The largest magnitude of a sample (`max_sample_value`), for the intervals of an
    /// adaptive render's decisions (not stored: a resumed render takes its own).
    max_value: f64,
    /// The pixels whose every camera ray misses the geometry ([`crate::footprint::background_pixels`]),
    /// which an adaptive render stops after their first replicate; empty where unknown
    /// (not stored: a resumed render takes its own).
    background: Vec<bool>,
}

/// The stored parts of an [`Accumulation`], as a checkpoint holds them.
pub(crate) struct AccumulationParts {
    pub(crate) settings: SampleSettings,
    pub(crate) device: DeviceKind,
    pub(crate) bvh_layout: BvhLayout,
    pub(crate) bvh_quality: BuildQuality,
    pub(crate) adapter: String,
    pub(crate) first: u32,
    pub(crate) end: u32,
    pub(crate) next: u32,
    pub(crate) partial_samples: u32,
    pub(crate) on_grid: bool,
    pub(crate) ao_rays: u64,
    pub(crate) passes: u32,
    pub(crate) render_seconds: f64,
    pub(crate) exact: ExactSums,
    pub(crate) partial: Option<BlockSums>,
    pub(crate) max_value: f64,
}

impl Accumulation {
    /// An empty accumulation of samples `first .. end` of a render of `settings`, on
    /// `device` with the given BVH, whose samples are at most `max_value` in magnitude
    /// (`max_sample_value`: twice the largest albedo, or the background's magnitude).
    pub fn new(
        settings: SampleSettings,
        device: DeviceKind,
        bvh_layout: BvhLayout,
        bvh_quality: BuildQuality,
        first: u32,
        end: u32,
        max_value: f64,
    ) -> Accumulation {
        let (width, height) = (settings.width, settings.height);
        Accumulation {
            settings,
            device,
            bvh_layout,
            bvh_quality,
            adapter: String::new(),
            first,
            end,
            next: first,
            partial_samples: 0,
            on_grid: true,
            ao_rays: 0,
            passes: 0,
            render_seconds: 0.0,
            exact: ExactSums::new(width, height, max_value),
            partial: None,
            source: None,
            max_value,
            background: Vec::new(),
        }
    }

    /// An accumulation read back from its stored parts (a checkpoint's): not from a file
    /// yet, with no background pixels known.
    pub(crate) fn from_parts(parts: AccumulationParts) -> Accumulation {
        let AccumulationParts {
            settings,
            device,
            bvh_layout,
            bvh_quality,
            adapter,
            first,
            end,
            next,
            partial_samples,
            on_grid,
            ao_rays,
            passes,
            render_seconds,
            exact,
            partial,
            max_value,
        } = parts;
        Accumulation {
            settings,
            device,
            bvh_layout,
            bvh_quality,
            adapter,
            first,
            end,
            next,
            partial_samples,
            on_grid,
            ao_rays,
            passes,
            render_seconds,
            exact,
            partial,
            source: None,
            max_value,
            background: Vec::new(),
        }
    }

    /// What the samples depend on.
    pub fn settings(&self) -> &SampleSettings {
        &self.settings
    }

    /// The device that rendered the samples.
    pub fn device(&self) -> DeviceKind {
        self.device
    }

    /// BVH layout the GPU traversed.
    pub fn bvh_layout(&self) -> BvhLayout {
        self.bvh_layout
    }

    /// BVH build preset.
    pub fn bvh_quality(&self) -> BuildQuality {
        self.bvh_quality
    }

    /// Adapter name (`cpu` for the CPU reference; empty until a device renders).
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    /// First sample index of the range rendered.
    pub fn first(&self) -> u32 {
        self.first
    }

    /// End of the range asked for.
    pub fn end(&self) -> u32 {
        self.end
    }

    /// The next sample index to render: samples `first .. next` are held.
    pub fn next(&self) -> u32 {
        self.next
    }

    /// Samples of the block in progress (in [`Accumulation::partial`], not yet in the
    /// exact sums).
    pub fn partial_samples(&self) -> u32 {
        self.partial_samples
    }

    /// Whether the replicates whose sums are taken still follow their absolute grid.
    pub fn on_grid(&self) -> bool {
        self.on_grid
    }

    /// AO rays traced so far.
    pub fn ao_rays(&self) -> u64 {
        self.ao_rays
    }

    /// Passes run so far.
    pub fn passes(&self) -> u32 {
        self.passes
    }

    /// Seconds spent rendering so far.
    pub fn render_seconds(&self) -> f64 {
        self.render_seconds
    }

    /// Exact sums of the finished blocks.
    pub fn exact(&self) -> &ExactSums {
        &self.exact
    }

    /// The device's sums of the block in progress, when they were read back.
    pub fn partial(&self) -> Option<&BlockSums> {
        self.partial.as_ref()
    }

    /// The file the accumulation was read from, for messages.
    pub fn source(&self) -> Option<&Path> {
        self.source.as_deref()
    }

    /// The largest magnitude of a sample, for the intervals of an adaptive render's
    /// decisions.
    pub fn max_value(&self) -> f64 {
        self.max_value
    }

    /// The pixels whose every camera ray misses the geometry; empty where unknown.
    pub fn background(&self) -> &[bool] {
        &self.background
    }

    /// Names the adapter that renders the samples from here on.
    pub fn set_adapter(&mut self, name: impl Into<String>) {
        self.adapter = name.into();
    }

    /// Names the file the accumulation was read from, for messages.
    pub(crate) fn set_source(&mut self, path: &Path) {
        self.source = Some(path.to_path_buf());
    }

    /// Marks the pixels whose every camera ray misses the geometry.
    pub(crate) fn set_background(&mut self, background: Vec<bool>) {
        self.background = background;
    }

    /// Counts a pass of `count` samples from `next` that traced `ao_rays` AO rays: its
    /// samples join the block in progress.
    pub fn record_pass(&mut self, count: u32, ao_rays: u64) {
        self.ao_rays += ao_rays;
        self.next += count;
        self.partial_samples += count;
        self.passes += 1;
    }

    /// Counts the block in progress as folded into the exact sums, with `replicates`
    /// whole replicates more.
    pub(crate) fn end_block(&mut self, replicates: u64) {
        self.exact.replicates += replicates;
        self.partial_samples = 0;
    }

    /// Sets the seconds spent rendering so far.
    pub(crate) fn set_render_seconds(&mut self, seconds: f64) {
        self.render_seconds = seconds;
    }

    /// Holds `block`, the device's sums of the block in progress (of
    /// [`Accumulation::partial_samples`] samples), or none once they go back to it.
    pub fn set_partial(&mut self, block: Option<BlockSums>) {
        // A block's sums without its samples would be counted as none.
        debug_assert!(block.is_none() || self.partial_samples > 0, "sums of an empty block");
        self.partial = block;
    }

    /// Takes the sums of the block in progress out, to go back onto a device.
    pub(crate) fn take_partial(&mut self) -> Option<BlockSums> {
        self.partial.take()
    }

    /// The exact sums, for a device that keeps them to read its own into.
    pub(crate) fn exact_mut(&mut self) -> &mut ExactSums {
        &mut self.exact
    }

    /// Continues the range to `end`. A last replicate cut short by the old end was taken
    /// as it was: neither it nor its rest is whole, and its square is lost.
    pub(crate) fn extend_to(&mut self, end: u32) {
        if self.end == end {
            return;
        }
        let replicates = self.settings.replicate_plan().is_some();
        if replicates && self.next == self.end && !self.end.is_multiple_of(self.take_rounds()) {
            self.on_grid = false;
        }
        self.end = end;
    }

    /// Takes what is not stored from `run`, the render continuing this accumulation: its
    /// largest sample, background pixels and adapter.
    pub(crate) fn adopt_run(&mut self, run: &Accumulation) {
        self.max_value = run.max_value;
        self.background.clone_from(&run.background);
        self.adapter.clone_from(&run.adapter);
    }

    /// Empties the accumulation back to its first sample, keeping what it is of.
    pub(crate) fn restart(&mut self) {
        self.exact.clear();
        (self.next, self.partial_samples, self.on_grid) = (self.first, 0, true);
        (self.ao_rays, self.passes, self.render_seconds) = (0, 0, 0.0);
        self.partial = None;
    }

    /// An empty accumulation of samples `samples` of an image of `settings` of `scene`
    /// seen by `camera`, on a device of `kind` with the BVH of `bvh`: what a render of it
    /// starts from. [`Accumulation::check_resume`] against it tells whether a checkpoint
    /// can be continued before any work is done.
    pub fn image(
        scene: &Scene,
        camera: &Camera,
        settings: &Settings,
        samples: std::ops::Range<u32>,
        kind: DeviceKind,
        bvh: &BvhOptions,
    ) -> Accumulation {
        // The CPU reference always traverses obvhs's CWBVH.
        let layout = if kind == DeviceKind::Cpu { BvhLayout::Cwbvh } else { bvh.layout };
        Accumulation::new(
            SampleSettings::image(scene_hash(scene, camera), settings),
            kind,
            layout,
            bvh.quality,
            samples.start,
            samples.end,
            max_image_sample(scene, settings.background, &settings.sampling.sky),
        )
    }

    /// An empty accumulation of sample indices `samples` (of `spp` a probe) at `probes` in
    /// `scene`, one film slot per probe, with the sampling of `settings`, on a device of
    /// `kind` with the BVH of `bvh`: what `Session::probe_render` starts from, so that a
    /// checkpoint can be checked against it before any work is done. [`Error::Probe`]
    /// names a bad probe.
    // The request of `Session::probe_render` and the device: grouping them would only
    // rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn probes(
        scene: &Scene,
        probes: &[Probe],
        spp: u32,
        samples: std::ops::Range<u32>,
        settings: &Settings,
        bent_normals: bool,
        kind: DeviceKind,
        bvh: &BvhOptions,
    ) -> Result<Accumulation> {
        let layout = if kind == DeviceKind::Cpu { BvhLayout::Cwbvh } else { bvh.layout };
        // The probes as the request traces them (and hashes them).
        let hash = probes_hash(&geometry_hash(scene), &checked(probes)?);
        let (slots, film) = if bent_normals { (4, FilmLayout::BentProbes) } else { (1, FilmLayout::Probes) };
        let points = probes.len() as u32;
        let settings = SampleSettings::new(hash, film, slots, points, spp, settings.background, &settings.sampling);
        let max_value = settings.sampling.sky.max_weight();
        Ok(Accumulation::new(settings, kind, layout, bvh.quality, samples.start, samples.end, max_value))
    }

    /// The estimate at each probe of an accumulation of `Session::probe_render`: mean and
    /// standard error of the samples held.
    pub fn probe_values(&self) -> Result<Vec<ProbeValue>> {
        self.check_probe_slots()?;
        Ok(probe_film_values(&self.film()?))
    }

    /// The estimate at each probe of a probe film of any number of lanes: the slots of a
    /// point added exactly, with the standard error of [`SampleSettings::error_estimator`].
    /// Points are estimated in chunks on rayon's threads: each on its own, so the same
    /// bits on any number of threads.
    pub fn lane_probe_values(&self) -> Result<Vec<ProbeValue>> {
        // The sums as they are where no block is in progress, not a copy of them.
        let owned;
        let sums = match self.partial {
            None => &self.exact,
            Some(_) => {
                owned = self.sums()?;
                &owned
            }
        };
        let s = &self.settings;
        let n = s.samples_in(self.first..self.next);
        let estimator = s.error_estimator(sums.replicates).or_samples();
        let lanes = s.width as usize;
        Ok((0..s.height as usize)
            .into_par_iter()
            .with_min_len(PROBE_VALUES_CHUNK)
            .map(|k| {
                let (sum, sum_sq) = sums.sum_range(k * lanes..(k + 1) * lanes);
                let r = sums.replicate_sq_value(k);
                ProbeValue { mean: sum / n as f64, std_error: standard_error(estimator, n, sum, sum_sq, r), samples: n }
            })
            .collect())
    }

    /// The bent normal of each probe of an accumulation of `Session::probe_render` with
    /// bent normals: the mean direction of the rays that escaped (zero where none did).
    pub fn bent_normals(&self) -> Result<Vec<Vec3>> {
        self.check_probe_slots()?;
        probe_film_bent_normals(&self.film()?).ok_or_else(|| self.error("holds no bent normals"))
    }

    fn check_probe_slots(&self) -> Result<()> {
        match self.settings.width {
            1 | 4 => Ok(()),
            w => Err(self.error(format!("holds {w} slots a point, not 1 or 4"))),
        }
    }

    /// Samples per pixel held.
    pub fn samples(&self) -> u32 {
        self.next - self.first
    }

    /// The sums as a film: the exact sums, plus the block in progress shifted into the same
    /// quanta (as [`merge`] adds it).
    pub fn film(&self) -> Result<Film> {
        if self.partial.is_none() {
            // Nothing to add: the sums as they are, not a copy of them.
            return Ok(self.exact.to_film(self.samples() as u64, self.film_replicate()));
        }
        Ok(self.counted_sums()?.to_film(self.samples() as u64, self.film_replicate()))
    }

    /// [`Accumulation::sums`], with the block in progress counted in the samples of the
    /// pixels it holds when the sums are counted per pixel.
    pub fn counted_sums(&self) -> Result<ExactSums> {
        let mut sums = self.sums()?;
        if self.partial.is_some() && !sums.pixel_samples.is_empty() {
            for (n, off) in sums.pixel_samples.iter_mut().zip(self.inactive()) {
                if !off {
                    *n += self.partial_samples;
                }
            }
        }
        Ok(sums)
    }

    /// Samples of the finished blocks of the pixels still sampled.
    pub fn finished(&self) -> u32 {
        self.samples() - self.partial_samples
    }

    /// The pixels an adaptive render no longer samples (empty while it samples all).
    pub fn inactive(&self) -> Vec<bool> {
        self.exact.stopped.clone()
    }

    /// What an adaptive render's decisions need besides the sums.
    pub fn adapt_query(&self) -> AdaptQuery {
        AdaptQuery { replicate: self.settings.replicate(), range: self.sample_range(), width: self.settings.width }
    }

    /// Each pixel's samples, complete replicates and whether it is stopped, from the
    /// exact sums' counts (every pixel the finished blocks' where they are not counted
    /// per pixel).
    fn pixel_counts(&self) -> Vec<(u32, u32, bool)> {
        let e = &self.exact;
        if e.pixel_samples.is_empty() {
            return vec![(self.finished(), e.replicates as u32, false); e.sum.len()];
        }
        (0..e.sum.len())
            .map(|i| (e.pixel_samples[i], e.pixel_replicates[i], e.stopped.get(i).copied().unwrap_or(false)))
            .collect()
    }

    /// Each pixel's `pixel_sigma` (v, mean, σ, k) over the exact sums, and the σ̃ that
    /// decides its share (`share_sigma`).
    fn adapt_pixels(&self) -> (Vec<[f32; 4]>, Vec<f32>) {
        let (query, e) = (self.adapt_query(), (self.exact.sum_exponent, self.exact.sq_exponent));
        let counts = self.pixel_counts();
        let x = &self.exact;
        let pixels: Vec<[f32; 4]> = (0..x.sum.len())
            .map(|i| {
                let r = x.replicate_sq.get(i).copied().unwrap_or(0);
                pixel_sigma((x.sum[i], x.sum_sq[i], r), counts[i].0, counts[i].1, &query, e)
            })
            .collect();
        let sigmas: Vec<f32> = pixels.iter().map(|p| p[2]).collect();
        let bound = query.sigma_bound();
        let shares = (0..sigmas.len()).map(|i| share_sigma(&sigmas, i, query.width as usize, bound)).collect();
        (pixels, shares)
    }

    /// The image-level sums of an adaptive render's decisions over the exact sums, in f32
    /// in the tree a device's `stats.wgsl` sums them in (`pixel_sigma`, `share_sigma`):
    /// what the CPU reference decides from, and the reference a device's sums are held to.
    pub fn adapt_sums(&self) -> AdaptSums {
        let counts = self.pixel_counts();
        let (pixels, shares) = self.adapt_pixels();
        let terms: Vec<[f32; 4]> = pixels
            .iter()
            .zip(&shares)
            .map(|(&[v, mean, sigma, _], &share)| [v, v * v, mean, share_weight(sigma, share)])
            .collect();
        let [variance, variance_sq, mean, sigma] = tree_sum(&terms);
        let fewest = counts.iter().filter(|c| !(c.2 && c.1 < 2)).map(|c| c.1).min();
        let most = counts.iter().map(|c| c.1).max().unwrap_or(0);
        AdaptSums { variance, variance_sq, mean, sigma, fewest, most, pixels: counts.len() as u64 }
    }

    /// The allocation an adaptive render's decision takes from `sums`, once every pixel
    /// that is not exact has `MIN_TARGET_REPLICATES` replicates (`None` before, or for a
    /// target that is not an image's). For a mean square error (1/P) Σ σᵢ² / kᵢ at a
    /// given total of replicates, the best kᵢ is in proportion to σᵢ, the standard
    /// deviation of pixel i's replicate means (`pixel_sigma`), which saves
    /// mean(σ²) / mean(σ)² of the replicates of uniform sampling. A share taken from σᵢ's
    /// own estimate biases the pixel's mean (it stops when its estimate is low, which on
    /// nearly open pixels comes with a high mean), so kᵢ ∝ σ̃ᵢ, its neighbours' σ
    /// (`share_sigma`): kᵢ = σ̃ᵢ Σ(σⱼ² / σ̃ⱼ) / (P e′²) gives an error of e′ with each
    /// pixel's own σ in the sum (`AdaptSums::sigma`). e′ is `ADAPTIVE_SHARE` of the target over the ratio of the image's RMSE
    /// bound (`film::rmse_bound`) to its estimate, so that the bound, above the estimate,
    /// meets the target when the pixels have the replicates allocated to them.
    pub fn allocation(&self, target: ErrorTarget, sums: &AdaptSums) -> Option<Allocation> {
        let fewest = sums.fewest.unwrap_or(sums.most) as u64;
        if fewest < MIN_TARGET_REPLICATES || sums.pixels == 0 {
            return None;
        }
        let p = sums.pixels as f64;
        let (v, v_sq) = (sums.variance as f64, sums.variance_sq as f64);
        let bound = rmse_bound(v, v_sq, sums.pixels, fewest - 1)?;
        let estimate = (v / p).sqrt();
        let inflation = if estimate > 0.0 { bound / estimate } else { 1.0 };
        let e = match target {
            ErrorTarget::Rmse(e) => e,
            ErrorTarget::RelativeRmse(r) => r * (sums.mean as f64 / p).abs(),
            ErrorTarget::PointStdError(_) => return None,
        };
        let e_alloc = ADAPTIVE_SHARE * e / inflation;
        Some(Allocation { per_sigma: (sums.sigma as f64 / (p * e_alloc * e_alloc)) as f32, met: bound <= e })
    }

    /// An adaptive render's decision after a complete replicate, on the exact sums in host
    /// memory (a device that keeps the sums takes the same steps on its own: `render`):
    /// the background pixels (`background`, whose value is exact) stop after the first;
    /// once the `MIN_TARGET_REPLICATES`th is in, the pixels still sampled that have the
    /// replicates of their [`Accumulation::allocation`] stop, unless that would stop
    /// every pixel before the image's RMSE bound meets the target. Returns the new mask
    /// when a pixel stopped.
    pub fn adapt(&mut self, target: ErrorTarget) -> Result<Option<Vec<bool>>> {
        if self.exact.replicates == 0 || self.partial_samples > 0 || matches!(target, ErrorTarget::PointStdError(_)) {
            return Ok(None);
        }
        let mut changed = false;
        if let Some(mask) = self.with_background() {
            self.stop(&mask);
            changed = true;
        }
        if self.exact.replicates >= MIN_TARGET_REPLICATES
            && let Some(a) = self.allocation(target, &self.adapt_sums())
        {
            let mask = self.allocated(&a);
            let stops = mask.iter().zip(self.pixel_counts()).filter(|(off, c)| **off && !c.2).count();
            // The bound is of these sums: where it is not met yet, the pixels go on.
            if stops > 0 && (a.met || !mask.iter().all(|&off| off)) {
                self.stop(&mask);
                changed = true;
            }
        }
        Ok(changed.then(|| self.inactive()))
    }

    /// The pixels stopped, with those still sampled that have the replicates allocation
    /// `a` gives them added: k ≥ σ̃ × `per_sigma`, σ̃ decided by the neighbours (`share_sigma`).
    pub(crate) fn allocated(&self, a: &Allocation) -> Vec<bool> {
        let (pixels, shares) = self.adapt_pixels();
        self.pixel_counts()
            .iter()
            .zip(pixels.iter().zip(&shares))
            .map(|(c, (p, &share))| c.2 || p[3] >= share * a.per_sigma)
            .collect()
    }

    /// The stopped pixels with the background ones added, when that adds one.
    pub fn with_background(&self) -> Option<Vec<bool>> {
        let stopped = |i: usize| self.exact.stopped.get(i).copied().unwrap_or(false);
        if !self.background.iter().enumerate().any(|(i, &b)| b && !stopped(i)) {
            return None;
        }
        Some(
            (0..self.exact.sum.len()).map(|i| stopped(i) || self.background.get(i).copied().unwrap_or(false)).collect(),
        )
    }

    /// Stops sampling the pixels marked in `mask`, counting samples per pixel from now on.
    pub fn stop(&mut self, mask: &[bool]) {
        self.exact.count_per_pixel(self.finished());
        self.exact.stopped.copy_from_slice(mask);
    }

    /// Whether `sums`, an adaptive render's ([`Accumulation::adapt_sums`] or a device's),
    /// meet `target`: every pixel that is not exact has `MIN_TARGET_REPLICATES`
    /// replicates and the image's RMSE bound is within the target.
    pub fn adaptive_target_met(&self, target: ErrorTarget, sums: &AdaptSums) -> bool {
        self.allocation(target, sums).is_some_and(|a| a.met)
    }

    /// The replicate size a film of this accumulation reports: 0 where the replicates'
    /// sums are not taken ([`SampleSettings::replicate_plan`]).
    fn film_replicate(&self) -> u32 {
        match self.settings.replicate() {
            0 | 1 => self.settings.replicate(),
            b if self.settings.replicate_plan().is_some() => b,
            _ => 0,
        }
    }

    /// What one of this accumulation's samples can be, for its intervals.
    pub fn sample_range(&self) -> SampleRange {
        let sampling = &self.settings.sampling;
        if sampling.sky.is_uniform() {
            SampleRange::of(sampling.hemisphere, self.settings.background, self.max_value)
        } else if sampling.sky.sampling == crate::sky::SkySampling::ControlVariate {
            SampleRange::Signed(self.max_value)
        } else {
            SampleRange::Bounded(self.max_value)
        }
    }

    /// Why `target` cannot stop this accumulation, as [`Error::Settings`]: no valid error
    /// estimate (one replicate, the grid sampler), or a target of the other kind of
    /// film (a point's standard error for an image, an image's RMSE for probes).
    pub fn check_target(&self, target: ErrorTarget) -> Result<()> {
        let s = &self.settings;
        if !(target.value().is_finite() && target.value() > 0.0) {
            return Err(Error::settings(format!("an error target must be positive, got {}", target.value())));
        }
        if s.error_estimator(u64::MAX) == ErrorEstimator::None {
            return Err(Error::settings(format!(
                "an error target needs an error estimate, which the {} sampler has only in replicates \
                 (samples per replicate {}: give a power of two{})",
                s.sampling.sampler.name(),
                s.replicate(),
                if s.sampling.sampler == Sampler::Stratified { " of four" } else { "" }
            )));
        }
        let image = s.layout == FilmLayout::Image;
        if image == matches!(target, ErrorTarget::PointStdError(_)) {
            let what = if image { "an image" } else { "probe points" };
            return Err(Error::settings(format!("{target:?} is not a target for {what}")));
        }
        Ok(())
    }

    /// Why this render cannot be adaptive: no image target, or samples not in
    /// replicates (whose ends are where the decisions are taken).
    pub fn check_adaptive(&self, target: Option<ErrorTarget>) -> Result<()> {
        if !matches!(target, Some(ErrorTarget::Rmse(_) | ErrorTarget::RelativeRmse(_))) {
            return Err(Error::settings("adaptive sampling needs an image's error target"));
        }
        if self.settings.layout != FilmLayout::Image || self.settings.replicate_plan().is_none() {
            return Err(Error::settings(
                "adaptive sampling needs the samples in replicates of 2 or more (--replicate N)",
            ));
        }
        Ok(())
    }

    /// Rounds between two checks of an error target: a replicate's take, or
    /// `TARGET_CHECK_SAMPLES` samples of independent ones.
    pub fn target_check_rounds(&self) -> u32 {
        match self.settings.replicate_plan() {
            Some(plan) => plan.take,
            None if self.settings.layout == FilmLayout::Probes => {
                (TARGET_CHECK_SAMPLES / self.settings.width.max(1)).max(1)
            }
            None => TARGET_CHECK_SAMPLES,
        }
    }

    /// Whether the samples held meet `target`: at least `MIN_TARGET_REPLICATES`
    /// replicates, and the image's RMSE bound ([`Film::rmse_bound`]) or every point's
    /// standard error within it.
    pub fn target_met(&self, target: ErrorTarget) -> Result<bool> {
        let sums = self.sums()?;
        let s = &self.settings;
        let replicates = match s.replicate() {
            1 => s.samples_in(self.first..self.next),
            _ => sums.replicates,
        };
        if replicates < MIN_TARGET_REPLICATES {
            return Ok(false);
        }
        Ok(match target {
            ErrorTarget::Rmse(e) => self.film()?.rmse_bound().is_some_and(|b| b <= e),
            ErrorTarget::RelativeRmse(r) => {
                let film = self.film()?;
                film.rmse_bound().is_some_and(|b| b <= r * film.image_mean().abs())
            }
            ErrorTarget::PointStdError(e) => {
                let values = match s.layout {
                    FilmLayout::Probes => self.lane_probe_values()?,
                    _ => probe_film_values(&self.film()?),
                };
                values.iter().all(|v| v.std_error <= e)
            }
        })
    }

    /// How a device reduces this image's sums for a check of its target, when every pixel
    /// has the same samples: from the replicates where they are taken.
    pub fn check_query(&self) -> CheckQuery {
        let s = &self.settings;
        let replicates = s.replicate_plan().map(|_| (s.replicate(), self.exact.replicates));
        CheckQuery { samples: self.samples() as u64, replicates }
    }

    /// Complete replicates the target's estimate has (samples, for independent ones).
    pub fn target_replicates(&self) -> u64 {
        match self.settings.replicate() {
            1 => self.settings.samples_in(self.first..self.next),
            _ => self.exact.replicates,
        }
    }

    /// Whether `sums`, a device's reduction of this image's exact sums (every pixel with
    /// the same samples, none in a block in progress), meet `target`: the rule of
    /// [`Accumulation::target_met`], with Σv, Σv² and the image's mean from `sums`.
    pub fn target_met_by(&self, target: ErrorTarget, sums: &CheckSums) -> bool {
        if self.target_replicates() < MIN_TARGET_REPLICATES || sums.pixels == 0 {
            return false;
        }
        let dof = self.settings.error_estimator(self.exact.replicates).degrees_of_freedom(self.samples() as u64);
        let Some(bound) = rmse_bound(sums.variance, sums.variance_sq, sums.pixels, dof) else {
            return false;
        };
        match target {
            ErrorTarget::Rmse(e) => bound <= e,
            ErrorTarget::RelativeRmse(r) => bound <= r * (sums.mean / sums.pixels as f64).abs(),
            ErrorTarget::PointStdError(_) => false,
        }
    }

    /// Whether the samples of rounds `rounds`, the block just finished, are one whole
    /// replicate of every group, whose square is to be added.
    pub fn whole_replicate(&self, rounds: std::ops::Range<u32>) -> bool {
        let Some(plan) = self.settings.replicate_plan() else {
            return false;
        };
        // A point's samples in a full take: a round is a sample of an image, lanes samples
        // of a point of a probe film.
        let full = match self.settings.layout {
            FilmLayout::Probes => plan.take as u64 * self.settings.width as u64,
            FilmLayout::Image | FilmLayout::BentProbes => plan.take as u64,
        };
        rounds.start.is_multiple_of(plan.take)
            && rounds.end - rounds.start == plan.take
            && self.settings.samples_in(rounds) == full
    }

    /// Rounds between two takes of the device's sums: a replicate's, or a block's.
    pub fn take_rounds(&self) -> u32 {
        self.settings.replicate_plan().map_or(BLOCK_SAMPLES, |p| p.take.min(BLOCK_SAMPLES))
    }

    /// Adds the device's sums of rounds `rounds` (taken from it): to the exact sums, and,
    /// when they are whole replicates, their squares to the replicates' sums.
    pub fn add_taken(&mut self, block: &BlockSums, rounds: std::ops::Range<u32>) -> Result<()> {
        // Which pixels the block holds.
        let active: Vec<bool> = self.inactive().iter().map(|&off| !off).collect();
        self.exact.add_block(block).map_err(|e| self.error(e))?;
        let taken = rounds.end - rounds.start;
        for (n, &on) in self.exact.pixel_samples.iter_mut().zip(&active) {
            *n += if on { taken } else { 0 };
        }
        let Some(plan) = self.settings.replicate_plan() else {
            return Ok(());
        };
        if !self.whole_replicate(rounds) {
            return Ok(());
        }
        let mut sums = Vec::with_capacity(plan.groups * plan.per_take);
        for g in 0..plan.groups {
            for j in 0..plan.per_take {
                let first = g * plan.stride + j * plan.summed;
                sums.push((first..first + plan.summed).map(|i| block.sum[i] as i128).sum::<i128>());
            }
        }
        self.exact.add_replicates(&sums, plan.per_take as u64).map_err(|e| self.error(e))?;
        for (k, &on) in self.exact.pixel_replicates.iter_mut().zip(&active) {
            *k += on as u32;
        }
        Ok(())
    }

    /// The exact sums with the block in progress, if any, shifted into the same quanta and
    /// added.
    pub fn sums(&self) -> Result<ExactSums> {
        let mut exact = self.exact.clone();
        if let Some(block) = &self.partial {
            exact.add_block(block).map_err(|e| self.error(e))?;
        }
        Ok(exact)
    }

    /// [`Error::Checkpoint`] naming the file this accumulation was read from.
    pub fn error(&self, message: impl std::fmt::Display) -> Error {
        Error::checkpoint(self.source.clone().unwrap_or_else(|| "checkpoint".into()), message)
    }

    /// Why this accumulation cannot be continued by `other`, an empty accumulation of the
    /// render asked for (its settings, device, BVH and sample range): an
    /// [`Error::Checkpoint`]; `Ok` when it can.
    pub fn check_resume(&self, other: &Accumulation) -> Result<()> {
        let (device, bvh_layout, bvh_quality) = (other.device, other.bvh_layout, other.bvh_quality);
        let (first, end) = (other.first, other.end);
        let err = |m: String| Err(self.error(m));
        let diff = self.settings.differences(&other.settings);
        if !diff.is_empty() {
            return err(format!(
                "checkpoint of another scene or other settings: {} (checkpoint's value first)",
                diff.join("; ")
            ));
        }
        if self.device != device {
            return err(format!(
                "checkpoint rendered with --device {}, not {}: its sums continue only on the same device",
                self.device.name(),
                device.name()
            ));
        }
        if self.bvh_layout != bvh_layout || self.bvh_quality != bvh_quality {
            return err(format!(
                "checkpoint rendered with --bvh-layout {} --bvh-quality {}, not {} {}",
                self.bvh_layout.name(),
                self.bvh_quality.name(),
                bvh_layout.name(),
                bvh_quality.name()
            ));
        }
        if self.exact.sum_exponent != other.exact.sum_exponent {
            return err("checkpoint's sums are scaled for other albedos".into());
        }
        if self.first != first {
            return err(format!(
                "checkpoint holds samples from index {} (--sample-range {}..{}), not from {first}",
                self.first, self.first, self.end
            ));
        }
        if self.next > end {
            return err(format!(
                "checkpoint already holds samples {}..{}, past the end {end} asked for",
                self.first, self.next
            ));
        }
        Ok(())
    }
}

/// The result of [`merge`].
#[derive(Clone, Debug)]
pub struct Merged {
    /// The merged sums.
    pub film: Film,
    /// First sample index held.
    pub first: u32,
    /// One past the last sample index held.
    pub end: u32,
    /// True when the merge has the same bits as one uninterrupted render of `first..end`
    /// on the shards' adapter: one adapter rendered them all and, when the samples are in
    /// replicates whose sums are taken, every shard boundary is a multiple of the
    /// replicate and every shard's replicates follow that grid. The sums of samples add
    /// to the same integers wherever the shards split; a replicate cut by a boundary is
    /// whole in neither shard, and its square is missing.
    pub same_as_single_run: bool,
    /// The shards, in sample order.
    pub shards: Vec<MergedShard>,
}

/// A shard of a [`Merged`] accumulation.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MergedShard {
    /// Its file.
    pub file: PathBuf,
    /// First sample index.
    pub first_sample: u32,
    /// Samples per pixel it holds.
    pub samples: u32,
    /// The device's adapter.
    pub adapter: String,
}

/// Combines accumulations of disjoint sample ranges of one render, given with their files.
/// They must hold samples of the same scene and settings and together one contiguous range
/// of sample indices; the order given does not matter. The exact sums are added as
/// integers (each shard's block in progress, if any, shifted into the same quanta first),
/// so the result does not depend on the order or grouping of the shards.
pub fn merge(shards: &[(PathBuf, Accumulation)]) -> Result<Merged> {
    let Some((first_path, first)) = shards.first() else {
        return Err(Error::checkpoint("merge", "no accumulations given"));
    };
    for (path, a) in &shards[1..] {
        let diff = a.settings.differences(&first.settings);
        if !diff.is_empty() {
            return Err(Error::checkpoint(
                path,
                format!("holds samples of another render than {}: {}", first_path.display(), diff.join("; ")),
            ));
        }
        if a.exact.sum_exponent != first.exact.sum_exponent {
            return Err(Error::checkpoint(path, "its sums are scaled differently"));
        }
    }
    let mut order: Vec<&(PathBuf, Accumulation)> = shards.iter().collect();
    order.sort_by_key(|(_, a)| (a.first, a.next));
    for pair in order.windows(2) {
        let ((pa, a), (pb, b)) = (pair[0], pair[1]);
        if b.first < a.next {
            return Err(Error::checkpoint(
                pb,
                format!(
                    "its samples {}..{} overlap those of {} ({}..{})",
                    b.first,
                    b.next,
                    pa.display(),
                    a.first,
                    a.next
                ),
            ));
        }
        if b.first > a.next {
            return Err(Error::checkpoint(
                pb,
                format!(
                    "samples {}..{} are missing between {} (which ends at {}) and this file (which starts at {}): \
                     finish the shard that renders them (--resume) or render them",
                    a.next,
                    b.first,
                    pa.display(),
                    a.next,
                    b.first
                ),
            ));
        }
    }
    let mut exact = first.exact.clone();
    exact.clear();
    // Adaptive shards count their samples per pixel; the others then do too.
    let per_pixel = order.iter().any(|(_, a)| !a.exact.pixel_samples.is_empty());
    if per_pixel {
        exact.count_per_pixel(0);
    }
    for (path, a) in &order {
        let mut sums = a.counted_sums()?;
        if per_pixel {
            sums.count_per_pixel(a.samples());
            sums.stopped.clear();
        }
        exact.add(&sums).map_err(|m| Error::checkpoint(path, m))?;
    }
    let (lo, hi) = (order[0].1.first, order[order.len() - 1].1.next);
    let unit = first.settings.replicate_plan().map_or(1, |p| p.take);
    let aligned = order.windows(2).all(|p| p[0].1.next % unit == 0);
    let on_grid = order.iter().all(|(_, a)| a.on_grid);
    let one_adapter = order.iter().all(|(_, a)| a.adapter == first.adapter && a.device == first.device);
    Ok(Merged {
        film: exact.to_film((hi - lo) as u64, first.film_replicate()),
        first: lo,
        end: hi,
        same_as_single_run: aligned && on_grid && one_adapter,
        shards: order
            .iter()
            .map(|(path, a)| MergedShard {
                file: path.clone(),
                first_sample: a.first,
                samples: a.samples(),
                adapter: a.adapter.clone(),
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sky::SkyModel;

    /// A pool of `threads` threads, for checks that a parallel path's bits do not depend on them.
    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool")
    }

    /// [`Accumulation::lane_probe_values`] on one thread, through the film, point after
    /// point: the reference the parallel estimate is held to.
    fn lane_probe_values_serial(acc: &Accumulation) -> Vec<ProbeValue> {
        let sums = acc.sums().expect("sums");
        let s = &acc.settings;
        let n = s.samples_in(acc.first..acc.next);
        let estimator = s.error_estimator(sums.replicates).or_samples();
        let film = sums.to_film(n, acc.film_replicate());
        let lanes = s.width as usize;
        (0..s.height as usize)
            .map(|k| {
                let (sum, sum_sq) = sums.sum_range(k * lanes..(k + 1) * lanes);
                let r = film.replicate_sq.get(k).copied().unwrap_or(0.0);
                ProbeValue { mean: sum / n as f64, std_error: standard_error(estimator, n, sum, sum_sq, r), samples: n }
            })
            .collect()
    }

    /// The probes' estimates from lanes' exact sums are the same bits on 1, 2, 3 and 8
    /// threads as on one thread through the film, with and without replicates, at
    /// numbers of points around the chunks the threads take.
    #[test]
    fn lane_probe_values_are_the_same_on_any_number_of_threads() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = move |m: u64| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x % m
        };
        let c = PROBE_VALUES_CHUNK as u32;
        for (points, lanes, replicate) in
            [(1, 1, None), (c - 1, 3, None), (c, 1, Some(4)), (c + 1, 2, Some(4)), (3 * c + 5, 4, None)]
        {
            let sampling = Sampling { replicate, ..Sampling::default() };
            let spp = 16 * lanes;
            let settings = SampleSettings::new([3; 32], FilmLayout::Probes, lanes, points, spp, 0.0, &sampling);
            let mut acc =
                Accumulation::new(settings, DeviceKind::Cpu, BvhLayout::Cwbvh, BuildQuality::Fast, 0, 16, 2.0);
            acc.record_pass(16, u64::from(spp) * u64::from(points));
            let slots = (points * lanes) as usize;
            let exact = acc.exact_mut();
            // Sums of up to 16 samples of up to 2^30 quanta each, their squares consistent.
            exact.sum = (0..slots).map(|_| next(16 << 30) as i128).collect();
            exact.sum_sq = exact.sum.iter().map(|&v| v * v / 16 + next(1 << 40) as i128).collect();
            if replicate.is_some() {
                exact.replicate_sq = (0..slots).map(|_| next(1 << 50) as i128).collect();
                exact.replicates = 4;
            }
            acc.end_block(0);
            let expected = lane_probe_values_serial(&acc);
            assert_eq!(expected.len(), points as usize);
            assert!(expected.iter().all(|v| v.mean > 0.0 && v.std_error.is_finite()), "{points} points");
            let bits = |v: &[ProbeValue]| -> Vec<(u64, u64, u64)> {
                v.iter().map(|p| (p.mean.to_bits(), p.std_error.to_bits(), p.samples)).collect()
            };
            for threads in [1, 2, 3, 8] {
                let got = pool(threads).install(|| acc.lane_probe_values()).expect("values");
                assert!(bits(&got) == bits(&expected), "{points} points × {lanes} lanes on {threads} threads");
            }
        }
    }

    #[test]
    fn geometry_hash_is_the_stream_of_every_float_by_its_bits() {
        use crate::scene::{Instance, InstancedMesh, Plane, Sphere, Triangle};
        let p = |i: usize, k: f32| Vec3::new(i as f32 * k, -(i as f32) - k, 1e-3 * i as f32 + k);
        // Enough triangles for a hash spread over threads (megabytes), and every other kind.
        let mut scene = Scene::default_scene();
        scene.triangles =
            (0..60_000).map(|i| Triangle { v: [p(i, 0.5), p(i, 1.5), p(i, -2.0)], albedo: 0.25 }).collect();
        scene.spheres = vec![Sphere { center: p(3, 1.0), radius: 0.5, albedo: 0.7 }];
        scene.planes = vec![Plane { normal: Vec3::Y, point: p(5, 0.1), albedo: 0.9 }];
        scene.meshes = vec![InstancedMesh {
            name: "m".into(),
            triangles: (0..9_000).map(|i| [p(i, 1.0), p(i, 2.0), p(i, 3.0)]).collect(),
        }];
        scene.instances = vec![Instance { mesh: 0, to_world: glam::Mat4::from_scale(Vec3::splat(2.0)), albedo: 0.5 }];
        // The stream as written a float at a time.
        let mut h = blake3::Hasher::new();
        h.update(b"aorender geometry v1");
        for (name, count) in [("triangles", 60_000u64), ("spheres", 1), ("planes", 1)] {
            h.update(name.as_bytes());
            h.update(&count.to_le_bytes());
        }
        fn floats(h: &mut blake3::Hasher, fs: &[f32]) {
            for f in fs {
                h.update(&f.to_le_bytes());
            }
        }
        for t in &scene.triangles {
            let v = t.v;
            floats(&mut h, &[v[0].x, v[0].y, v[0].z, v[1].x, v[1].y, v[1].z, v[2].x, v[2].y, v[2].z, t.albedo]);
        }
        let s = scene.spheres[0];
        floats(&mut h, &[s.center.x, s.center.y, s.center.z, s.radius, s.albedo]);
        let q = scene.planes[0];
        floats(&mut h, &[q.normal.x, q.normal.y, q.normal.z, q.point.x, q.point.y, q.point.z, q.albedo]);
        h.update(b"mesh");
        h.update(&9_000u64.to_le_bytes());
        for [a, b, c] in &scene.meshes[0].triangles {
            floats(&mut h, &[a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z]);
        }
        h.update(b"instance");
        h.update(&0u32.to_le_bytes());
        floats(&mut h, &scene.instances[0].to_world.to_cols_array());
        floats(&mut h, &[0.5]);
        let expected = *h.finalize().as_bytes();
        for threads in [1, 2, 5] {
            assert_eq!(pool(threads).install(|| geometry_hash(&scene)), expected, "{threads} threads");
        }
        scene.triangles[59_999].albedo = 0.5;
        assert_ne!(geometry_hash(&scene), expected);
    }

    /// Probe `i` of the hash tests: every float differs from probe to probe, and every third
    /// has no surface normal, so it hashes fewer bytes.
    fn numbered_probe(i: usize) -> crate::probe::Probe {
        crate::probe::Probe {
            position: Vec3::new(i as f32, 0.5 * i as f32, -(i as f32)),
            normal: Vec3::new(0.0, 1.0, 1e-3 * i as f32),
            error: 1e-6 * i as f32,
            surface_normal: if i.is_multiple_of(3) { Vec3::ZERO } else { Vec3::Y },
        }
    }

    #[test]
    fn probes_hash_over_several_batches_is_the_stream_of_its_floats() {
        // Two batches of pieces and part of a third.
        let probes: Vec<_> = (0..PROBE_HASH_PIECE * 64 * 2 + 777).map(numbered_probe).collect();
        let geometry = [3u8; 32];
        let mut stream: Vec<u8> = Vec::new();
        for p in &probes {
            for c in p.position.to_array().into_iter().chain(p.normal.to_array()).chain([p.error]) {
                stream.extend_from_slice(&c.to_le_bytes());
            }
            if p.surface_normal != Vec3::ZERO {
                stream.extend(p.surface_normal.to_array().iter().flat_map(|c| c.to_le_bytes()));
            }
        }
        let mut h = blake3::Hasher::new();
        h.update(b"aorender probes v2");
        h.update(&geometry);
        h.update(&(probes.len() as u64).to_le_bytes());
        h.update(&stream);
        let expected = *h.finalize().as_bytes();
        for threads in [1, 2, 5] {
            assert_eq!(pool(threads).install(|| probes_hash(&geometry, &probes)), expected, "{threads} threads");
        }
    }

    #[test]
    fn probes_hash_as_when_each_float_was_its_own_update() {
        // Enough probes to fill the gathered updates several times.
        let probes: Vec<_> = (0..10_000).map(numbered_probe).collect();
        let geometry = [7u8; 32];
        let mut h = blake3::Hasher::new();
        h.update(b"aorender probes v2");
        h.update(&geometry);
        h.update(&(probes.len() as u64).to_le_bytes());
        for p in &probes {
            for c in p.position.to_array().into_iter().chain(p.normal.to_array()).chain([p.error]) {
                h.update(&c.to_le_bytes());
            }
            if p.surface_normal != Vec3::ZERO {
                for c in p.surface_normal.to_array() {
                    h.update(&c.to_le_bytes());
                }
            }
        }
        assert_eq!(probes_hash(&geometry, &probes), *h.finalize().as_bytes());
        assert_ne!(probes_hash(&geometry, &probes[1..]), probes_hash(&geometry, &probes));
    }

    /// The identity keeps the request's `Sampling` with its replicate size resolved, so a
    /// request that leaves the size to the sampler and one that names that size hold the
    /// same samples; each other change of the sampling is one difference, named.
    #[test]
    fn the_identity_resolves_the_replicate_size_and_names_each_difference() {
        let hash = [7u8; 32];
        for (sampler, resolved) in [(Sampler::Independent, 1), (Sampler::Stratified, 0), (Sampler::Sobol, 0)] {
            let left = Sampling { sampler, ..Sampling::default() };
            let named = Sampling { replicate: Some(resolved), ..left };
            let a = SampleSettings::new(hash, FilmLayout::Image, 8, 4, 16, 0.0, &left);
            let b = SampleSettings::new(hash, FilmLayout::Image, 8, 4, 16, 0.0, &named);
            assert_eq!((a.sampling.replicate, a.replicate()), (Some(resolved), resolved), "{sampler:?}");
            assert!(a.differences(&b).is_empty(), "{sampler:?}: {:?}", a.differences(&b));
        }
        let base = Sampling { sampler: Sampler::Sobol, replicate: Some(4), ..Sampling::default() };
        let id = |s: &Sampling| SampleSettings::new(hash, FilmLayout::Probes, 4, 3, 64, 0.0, s);
        let overcast = Sky { model: SkyModel::Overcast, ..Sky::default() };
        let cases = [
            (Sampling { seed: 1, ..base }, "seed 0, not 1"),
            (Sampling { hemisphere: crate::sampling::Hemisphere::Uniform, ..base }, "hemisphere cosine, not uniform"),
            (Sampling { replicate: Some(8), ..base }, "samples per replicate 4, not 8"),
            (Sampling { max_distance: Some(0.5), ..base }, "max distance unlimited, not 0.5"),
            (Sampling { sky: overcast, ..base }, "sky uniform, not overcast"),
        ];
        for (other, expect) in cases {
            let d = id(&base).differences(&id(&other));
            assert!(d.len() == 1 && d[0].starts_with(expect), "expected {expect:?}, got {d:?}");
        }
        // An image's identity from the same sampling keeps the same `Sampling`.
        let image = SampleSettings::image(hash, &Settings { sampling: base, ..Settings::default() });
        assert_eq!(image.sampling, id(&base).sampling);
    }

    /// An adaptive render's accumulation of `width` × `height` pixels of 0/1 samples in 8
    /// replicates of 16: pixel i's replicates have `ones(i)` samples that are 1.
    fn binary_replicates(width: u32, height: u32, ones: impl Fn(usize) -> [u32; 8]) -> Accumulation {
        let sampling = Sampling { replicate: Some(16), ..Sampling::default() };
        let settings = SampleSettings::new([0; 32], FilmLayout::Image, width, height, 4096, 0.0, &sampling);
        let mut acc =
            Accumulation::new(settings, DeviceKind::Cpu, BvhLayout::default(), BuildQuality::default(), 0, 4096, 1.0);
        acc.next = 8 * 16;
        acc.exact.replicates = 8;
        acc.exact.replicate_sq = vec![0; (width * height) as usize];
        for i in 0..(width * height) as usize {
            set_pixel(&mut acc, i, ones(i));
        }
        acc
    }

    /// Sets pixel `i`'s exact sums to replicates of 16 samples with `ones` samples 1 each.
    fn set_pixel(acc: &mut Accumulation, i: usize, ones: [u32; 8]) {
        let x = &mut acc.exact;
        let quantum = |e: i32| 1i128 << -e;
        let total: i128 = ones.iter().map(|&c| c as i128).sum();
        x.sum[i] = total * quantum(x.sum_exponent);
        x.sum_sq[i] = total * quantum(x.sq_exponent);
        x.replicate_sq[i] =
            ones.iter().map(|&c| (c * c) as i128).sum::<i128>() * quantum(x.sq_exponent + REPLICATE_SQ_SHIFT);
    }

    /// Replicates of a nearly open pixel, `seed` choosing which.
    fn nearly_open(seed: usize) -> [u32; 8] {
        std::array::from_fn(|r| 16 - ((seed * 7 + r * 3) % 5) as u32 / 2)
    }

    #[test]
    fn a_pixel_share_is_its_row_neighbours_rms_sigma_never_its_own() {
        // Two rows of 5; 0 marks an exact pixel.
        let sigmas = [0.3, 0.4, 0.0, 0.2, 0.5, 0.1, 0.0, 0.0, 0.0, 0.0];
        let rms = |s: &[f32]| (s.iter().map(|&x| x as f64 * x as f64).sum::<f64>() / s.len() as f64).sqrt();
        let expected = [
            rms(&[0.4]),
            rms(&[0.3, 0.2]),
            rms(&[0.3, 0.4, 0.2, 0.5]),
            rms(&[0.4, 0.5]),
            rms(&[0.2]),
            // Nothing from the row above; no neighbour with an estimate: the bound.
            0.75,
            rms(&[0.1]),
            rms(&[0.1]),
            0.75,
            0.75,
        ];
        for (i, want) in expected.into_iter().enumerate() {
            let got = share_sigma(&sigmas, i, 5, 0.75) as f64;
            assert!((got - want).abs() <= 1e-6 * want, "pixel {i}: σ̃ {got}, expected {want}");
            // Its own σ does not enter; a neighbour's does.
            let mut own = sigmas;
            own[i] = 0.9;
            assert_eq!(share_sigma(&own, i, 5, 0.75), share_sigma(&sigmas, i, 5, 0.75), "pixel {i}");
        }
        let mut neighbour = sigmas;
        neighbour[3] = 0.9;
        assert_ne!(share_sigma(&neighbour, 2, 5, 0.75), share_sigma(&sigmas, 2, 5, 0.75));
        assert_eq!(share_weight(0.0, 0.5), 0.0);
        assert_eq!(share_weight(0.5, 0.25), 1.0);
    }

    #[test]
    fn an_adaptive_pixel_stops_whatever_its_own_samples_and_not_whatever_its_neighbours() {
        let (width, height, i) = (6, 2, 8);
        let acc = binary_replicates(width, height, nearly_open);
        let per_sigma: Vec<f32> = (0..400).map(|j| 0.5 * 1.02f32.powi(j)).collect();
        let stops = |acc: &Accumulation| -> Vec<bool> {
            per_sigma.iter().map(|&p| acc.allocated(&Allocation { per_sigma: p, met: false })[i]).collect()
        };
        let own_sigma = |acc: &Accumulation| acc.adapt_pixels().0[i][2];
        let before = stops(&acc);
        assert!(before.contains(&true) && before.contains(&false), "the sweep crosses the pixel's share");
        // Its own samples, from nearly open to half occluded and to all open: its decision
        // stays, though its own σ moves it (the rule of a share from its own σ would not).
        for ones in [[8, 9, 7, 8, 10, 6, 8, 8], [16; 8], [0, 16, 0, 16, 0, 16, 0, 16]] {
            let mut perturbed = acc.clone();
            set_pixel(&mut perturbed, i, ones);
            let own_rule =
                |acc: &Accumulation| -> Vec<bool> { per_sigma.iter().map(|&p| 8.0 >= own_sigma(acc) * p).collect() };
            assert_ne!(own_rule(&perturbed), own_rule(&acc), "{ones:?}: a share from its own σ would move");
            assert_eq!(stops(&perturbed), before, "pixel {i} with its replicates {ones:?}");
        }
        // A neighbour's samples in its row move it; one in the row above does not.
        let mut neighbour = acc.clone();
        set_pixel(&mut neighbour, i + 1, [8, 9, 7, 8, 10, 6, 8, 8]);
        assert_ne!(stops(&neighbour), before, "a neighbour's spread decides the pixel's share");
        let mut above = acc.clone();
        set_pixel(&mut above, i - width as usize, [8, 9, 7, 8, 10, 6, 8, 8]);
        assert_eq!(stops(&above), before);
    }
}
