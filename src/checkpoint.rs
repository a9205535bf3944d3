//! Checkpoints: the raw accumulation of a render, what it was rendered from, and the
//! sample indices it holds, in a versioned little-endian file written atomically.
//!
//! An [`Accumulation`] holds the exact fixed-point sums of the finished 256-sample blocks
//! ([`ExactSums`], see [`BLOCK_SAMPLES`]) and the device's own sums of the block in
//! progress (the GPU film's f32 words or the CPU reference's f64 sums). Loading it back
//! into the same device continues the render from the same bits; adding the exact sums of
//! accumulations of disjoint sample ranges ([`merge`]) is exact integer addition.
//!
//! File layout (version 1), every number little-endian:
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `AOCKPT\r\n` |
//! | 4 | format version (u32) |
//! | 32 | BLAKE3 hash of the scene's geometry and camera |
//! | 4 × 4 | width, height, samples per pixel, strata per axis (u32) |
//! | 8 × 1 | hemisphere, sampler, device, BVH layout, BVH quality, has max distance, has a block in progress, flags (u8) |
//! | 4 × 3 | max distance, background (f32), seed (u32) |
//! | 4 × 3 | exponents of the sums' quanta (i32 × 2), samples per block (u32) |
//! | 4 × 4 | first sample, end of the range, next sample, samples of the block in progress (u32) |
//! | 8 + 4 + 8 | AO rays (u64), passes (u32), render seconds (f64) |
//! | 4 + n | adapter name: length (u32, at most 4096), UTF-8 |
//! | 32 × pixels | exact sums: Σv for every pixel, then Σv² (i128) |
//! | 16 × pixels | block in progress, when present: GPU, 4 × f32 per pixel; CPU, Σv then Σv² (f64) |
//! | 32 | BLAKE3 hash of every byte before it |
//!
//! The reader checks the magic, the version and every field's range, computes the file's
//! expected length from the header and compares it with the actual length before it
//! allocates or reads the sums, then streams the sums (holding them once, never the file
//! beside them) and checks the hash.

use crate::bvh::{BuildQuality, BvhLayout};
use crate::film::{BLOCK_SAMPLES, BlockSums, ExactSums, Film};
use crate::render::Device;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::scene::Scene;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The first bytes of a checkpoint file.
pub const MAGIC: [u8; 8] = *b"AOCKPT\r\n";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;
/// Longest adapter name stored.
const MAX_ADAPTER_NAME: usize = 4096;
/// Flag: the blocks follow the absolute grid of [`BLOCK_SAMPLES`] (cleared when a render
/// whose last block was cut short by its end is continued past that end).
const FLAG_ON_GRID: u8 = 1;

/// A checkpoint file that cannot be used, in one line naming the file.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct CheckpointError {
    /// The checkpoint file.
    pub path: PathBuf,
    /// What is wrong with it.
    pub message: String,
}

impl CheckpointError {
    fn new(path: &Path, message: impl std::fmt::Display) -> Self {
        CheckpointError { path: path.to_path_buf(), message: message.to_string() }
    }
}

/// Everything a sample's value depends on besides its index and the device: two
/// accumulations with equal `SampleSettings` hold samples of the same render.
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
    /// Hemisphere distribution.
    pub hemisphere: Hemisphere,
    /// Point sampler.
    pub sampler: Sampler,
    /// AO distance limit.
    pub max_distance: Option<f32>,
    /// Value of camera rays that miss.
    pub background: f32,
    /// Seed.
    pub seed: u32,
}

impl SampleSettings {
    /// The settings of `scene` as it will be rendered.
    pub fn of(scene: &Scene) -> SampleSettings {
        let s = &scene.settings;
        SampleSettings {
            scene_hash: scene_hash(scene),
            width: s.width,
            height: s.height,
            spp: s.spp,
            strata: s.sampler.strata_per_axis(s.spp),
            hemisphere: s.hemisphere,
            sampler: s.sampler,
            max_distance: s.max_distance,
            background: s.background,
            seed: s.seed,
        }
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
        check(&mut d, "seed", self.seed.to_string(), other.seed.to_string());
        check(&mut d, "hemisphere", self.hemisphere.name().into(), other.hemisphere.name().into());
        check(&mut d, "sampler", self.sampler.name().into(), other.sampler.name().into());
        if self.strata != other.strata {
            d.push(format!(
                "samples per pixel {} ({}×{} strata), not {} ({}×{} strata)",
                self.spp, self.strata, self.strata, other.spp, other.strata, other.strata
            ));
        }
        let distance = |m: Option<f32>| m.map_or("unlimited".to_string(), |m| format!("{m} ({:#010x})", m.to_bits()));
        check(&mut d, "max distance", distance(self.max_distance), distance(other.max_distance));
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

/// BLAKE3 hash of the scene's geometry and camera, with every float by its bits.
pub fn scene_hash(scene: &Scene) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
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
    h.update(b"aorender scene v1");
    let c = &scene.camera;
    let projection = match c.projection {
        crate::camera::Projection::Perspective { vfov_deg } => [0.0, vfov_deg],
        crate::camera::Projection::Orthographic { height } => [1.0, height],
    };
    put(&mut h, &mut buf, &[c.eye.x, c.eye.y, c.eye.z, c.look_at.x, c.look_at.y, c.look_at.z]);
    put(&mut h, &mut buf, &[c.up.x, c.up.y, c.up.z, projection[0], projection[1]]);
    for (name, count) in
        [("triangles", scene.triangles.len()), ("spheres", scene.spheres.len()), ("planes", scene.planes.len())]
    {
        buf.extend_from_slice(name.as_bytes());
        buf.extend_from_slice(&(count as u64).to_le_bytes());
    }
    for t in &scene.triangles {
        let v = t.v;
        put(&mut h, &mut buf, &[v[0].x, v[0].y, v[0].z, v[1].x, v[1].y, v[1].z, v[2].x, v[2].y, v[2].z, t.albedo]);
    }
    for s in &scene.spheres {
        put(&mut h, &mut buf, &[s.center.x, s.center.y, s.center.z, s.radius, s.albedo]);
    }
    for p in &scene.planes {
        put(&mut h, &mut buf, &[p.normal.x, p.normal.y, p.normal.z, p.point.x, p.point.y, p.point.z, p.albedo]);
    }
    // Instanced meshes and their placements; a scene without them hashes as before.
    for m in &scene.meshes {
        buf.extend_from_slice(b"mesh");
        buf.extend_from_slice(&(m.triangles.len() as u64).to_le_bytes());
        for [a, b, c] in &m.triangles {
            put(&mut h, &mut buf, &[a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z]);
        }
    }
    for i in &scene.instances {
        buf.extend_from_slice(b"instance");
        buf.extend_from_slice(&i.mesh.to_le_bytes());
        put(&mut h, &mut buf, &i.to_world.to_cols_array());
        put(&mut h, &mut buf, &[i.albedo]);
    }
    h.update(&buf);
    *h.finalize().as_bytes()
}

/// The largest magnitude a sample of `scene` can take: twice the largest albedo (the
/// uniform hemisphere's weight 2 cos θ is at most 2), or the background's.
pub fn max_sample_value(scene: &Scene) -> f64 {
    let albedo = scene
        .triangles
        .iter()
        .map(|t| t.albedo)
        .chain(scene.spheres.iter().map(|s| s.albedo))
        .chain(scene.instances.iter().map(|i| i.albedo))
        .chain(scene.planes.iter().map(|p| p.albedo))
        .fold(0.0f64, |m, a| m.max(a as f64));
    (2.0 * albedo).max((scene.settings.background as f64).abs())
}

/// The accumulation of a render: the samples `first .. next` of every pixel, what they
/// were rendered from, and how.
#[derive(Clone, Debug)]
pub struct Accumulation {
    /// What the samples depend on.
    pub settings: SampleSettings,
    /// The device that rendered them.
    pub device: Device,
    /// BVH layout the GPU traversed.
    pub bvh_layout: BvhLayout,
    /// BVH build preset.
    pub bvh_quality: BuildQuality,
    /// Adapter name (`cpu` for the CPU reference).
    pub adapter: String,
    /// First sample index of the range rendered.
    pub first: u32,
    /// End of the range asked for.
    pub end: u32,
    /// Samples `first .. next` are in the sums.
    pub next: u32,
    /// Samples of the block in progress (in `partial`, not yet in `exact`).
    pub partial_samples: u32,
    /// False once the blocks no longer follow the absolute grid of [`BLOCK_SAMPLES`].
    pub on_grid: bool,
    /// AO rays traced so far.
    pub ao_rays: u64,
    /// Passes run so far.
    pub passes: u32,
    /// Seconds spent rendering so far.
    pub render_seconds: f64,
    /// Exact sums of the finished blocks.
    pub exact: ExactSums,
    /// The device's sums of the block in progress, when it has samples.
    pub partial: Option<BlockSums>,
    /// The file it was read from, for messages (not stored).
    pub source: Option<PathBuf>,
}

/// Command-line name of a BVH preset.
fn quality_name(q: BuildQuality) -> &'static str {
    match q {
        BuildQuality::Fastest => "fastest",
        BuildQuality::Fast => "fast",
        BuildQuality::Medium => "medium",
        BuildQuality::Slow => "slow",
    }
}

const QUALITIES: [BuildQuality; 4] =
    [BuildQuality::Fastest, BuildQuality::Fast, BuildQuality::Medium, BuildQuality::Slow];
const LAYOUTS: [BvhLayout; 2] = [BvhLayout::Bvh2, BvhLayout::Cwbvh];
const DEVICES: [Device; 2] = [Device::Gpu, Device::Cpu];

fn device_name(d: Device) -> &'static str {
    match d {
        Device::Gpu => "gpu",
        Device::Cpu => "cpu",
    }
}

fn index_of<T: PartialEq>(all: &[T], x: &T) -> u8 {
    all.iter().position(|a| a == x).expect("a listed value") as u8
}

impl Accumulation {
    /// An empty accumulation of samples `first .. end` of `scene`.
    pub fn new(
        scene: &Scene,
        device: Device,
        bvh_layout: BvhLayout,
        bvh_quality: BuildQuality,
        first: u32,
        end: u32,
    ) -> Accumulation {
        let s = &scene.settings;
        Accumulation {
            settings: SampleSettings::of(scene),
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
            exact: ExactSums::new(s.width, s.height, max_sample_value(scene)),
            partial: None,
            source: None,
        }
    }

    /// Samples per pixel held.
    pub fn samples(&self) -> u32 {
        self.next - self.first
    }

    /// The sums as a film: the exact sums, plus the block in progress rounded to the same
    /// quanta (as [`merge`] adds it).
    pub fn film(&self) -> Result<Film, String> {
        match &self.partial {
            None => Ok(self.exact.to_film(self.samples() as u64)),
            Some(block) => {
                let mut exact = self.exact.clone();
                exact.add_block(block)?;
                Ok(exact.to_film(self.samples() as u64))
            }
        }
    }

    /// Why this accumulation cannot be continued by a render of `scene` on `device` with
    /// the given BVH, over samples `first .. end`; `Ok` when it can.
    pub fn check_resume(
        &self,
        scene: &Scene,
        device: Device,
        bvh_layout: BvhLayout,
        bvh_quality: BuildQuality,
        first: u32,
        end: u32,
    ) -> Result<(), String> {
        let diff = self.settings.differences(&SampleSettings::of(scene));
        if !diff.is_empty() {
            return Err(format!(
                "checkpoint of another scene or other settings: {} (checkpoint's value first)",
                diff.join("; ")
            ));
        }
        if self.device != device {
            return Err(format!(
                "checkpoint rendered with --device {}, not {}: its sums continue only on the same device",
                device_name(self.device),
                device_name(device)
            ));
        }
        if self.bvh_layout != bvh_layout || self.bvh_quality != bvh_quality {
            return Err(format!(
                "checkpoint rendered with --bvh-layout {} --bvh-quality {}, not {} {}",
                self.bvh_layout.name(),
                quality_name(self.bvh_quality),
                bvh_layout.name(),
                quality_name(bvh_quality)
            ));
        }
        if self.exact.sum_exponent != ExactSums::exponents(max_sample_value(scene)).0 {
            return Err("checkpoint's sums are scaled for other albedos".into());
        }
        if self.first != first {
            return Err(format!(
                "checkpoint holds samples from index {} (--sample-range {}..{}), not from {first}",
                self.first, self.first, self.end
            ));
        }
        if self.next > end {
            return Err(format!(
                "checkpoint already holds samples {}..{}, past the end {end} asked for",
                self.first, self.next
            ));
        }
        Ok(())
    }

    /// Writes the checkpoint file atomically (to a temporary file beside it, then renamed).
    pub fn write(&self, path: &Path) -> crate::Result<()> {
        crate::film::write_atomically_with(path, &mut |w| {
            let mut w = HashingWriter { inner: w, hasher: blake3::Hasher::new() };
            self.write_body(&mut w)?;
            let hash = *w.hasher.finalize().as_bytes();
            w.inner.write_all(&hash)
        })
    }

    fn write_body(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let s = &self.settings;
        w.write_all(&MAGIC)?;
        w.write_all(&VERSION.to_le_bytes())?;
        w.write_all(&s.scene_hash)?;
        for v in [s.width, s.height, s.spp, s.strata] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&[
            index_of(&Hemisphere::ALL, &s.hemisphere),
            index_of(&Sampler::ALL, &s.sampler),
            index_of(&DEVICES, &self.device),
            index_of(&LAYOUTS, &self.bvh_layout),
            index_of(&QUALITIES, &self.bvh_quality),
            s.max_distance.is_some() as u8,
            self.partial.is_some() as u8,
            if self.on_grid { FLAG_ON_GRID } else { 0 },
        ])?;
        w.write_all(&s.max_distance.unwrap_or(0.0).to_le_bytes())?;
        w.write_all(&s.background.to_le_bytes())?;
        w.write_all(&s.seed.to_le_bytes())?;
        w.write_all(&self.exact.sum_exponent.to_le_bytes())?;
        w.write_all(&self.exact.sq_exponent.to_le_bytes())?;
        w.write_all(&BLOCK_SAMPLES.to_le_bytes())?;
        for v in [self.first, self.end, self.next, self.partial_samples] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&self.ao_rays.to_le_bytes())?;
        w.write_all(&self.passes.to_le_bytes())?;
        w.write_all(&self.render_seconds.to_le_bytes())?;
        let name = &self.adapter.as_bytes()[..self.adapter.len().min(MAX_ADAPTER_NAME)];
        w.write_all(&(name.len() as u32).to_le_bytes())?;
        w.write_all(name)?;
        let mut buf = Vec::with_capacity(1 << 16);
        let flush = |w: &mut dyn Write, buf: &mut Vec<u8>, force: bool| -> std::io::Result<()> {
            if force || buf.len() >= 1 << 16 {
                w.write_all(buf)?;
                buf.clear();
            }
            Ok(())
        };
        for v in self.exact.sum.iter().chain(&self.exact.sum_sq) {
            buf.extend_from_slice(&v.to_le_bytes());
            flush(w, &mut buf, false)?;
        }
        match &self.partial {
            None => {}
            Some(BlockSums::Gpu(words)) => {
                for f in words.iter().flatten() {
                    buf.extend_from_slice(&f.to_le_bytes());
                    flush(w, &mut buf, false)?;
                }
            }
            Some(BlockSums::Cpu { sum, sum_sq }) => {
                for f in sum.iter().chain(sum_sq) {
                    buf.extend_from_slice(&f.to_le_bytes());
                    flush(w, &mut buf, false)?;
                }
            }
        }
        flush(w, &mut buf, true)
    }

    /// Reads a checkpoint file, checking it whole before use.
    pub fn read(path: &Path) -> Result<Accumulation, CheckpointError> {
        let err = |m: String| CheckpointError::new(path, m);
        let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
        let len = file.metadata().map_err(|e| err(e.to_string()))?.len();
        let mut acc = Accumulation::from_stream(&mut std::io::BufReader::new(file), len).map_err(err)?;
        acc.source = Some(path.to_path_buf());
        Ok(acc)
    }

    /// Parses the bytes of a checkpoint file; the error says what is wrong in one line.
    pub fn from_bytes(mut bytes: &[u8]) -> Result<Accumulation, String> {
        let len = bytes.len() as u64;
        Accumulation::from_stream(&mut bytes, len)
    }

    /// Parses a checkpoint of `len` bytes from `stream`. Memory is taken only after the
    /// header's figures agree with `len`, so a damaged or hostile header cannot ask for
    /// more than the file holds.
    fn from_stream(stream: &mut dyn Read, len: u64) -> Result<Accumulation, String> {
        // The fixed fields (through the adapter name's length), and the name at most.
        const FIXED_HEADER: usize = 8 + 4 + 32 + 16 + 8 + 12 + 12 + 16 + 20 + 4;
        let mut head = Vec::new();
        stream
            .take((FIXED_HEADER + MAX_ADAPTER_NAME) as u64)
            .read_to_end(&mut head)
            .map_err(|e| format!("cannot read: {e}"))?;
        let bytes = &head[..];
        let mut r = Reader { bytes, at: 0, len };
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            return Err("not an aorender checkpoint (no AOCKPT header)".into());
        }
        r.at = MAGIC.len();
        let version = r.u32()?;
        if version != VERSION {
            return Err(format!("checkpoint format version {version}; this aorender reads version {VERSION}"));
        }
        let scene_hash: [u8; 32] = r.take(32)?.try_into().expect("32 bytes");
        let (width, height, spp, strata) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        let codes = r.take(8)?;
        let pick = |what: &str, i: u8, n: usize| -> Result<usize, String> {
            if (i as usize) < n { Ok(i as usize) } else { Err(format!("invalid {what} code {i}")) }
        };
        let hemisphere = Hemisphere::ALL[pick("hemisphere", codes[0], Hemisphere::ALL.len())?];
        let sampler = Sampler::ALL[pick("sampler", codes[1], Sampler::ALL.len())?];
        let device = DEVICES[pick("device", codes[2], DEVICES.len())?];
        let bvh_layout = LAYOUTS[pick("BVH layout", codes[3], LAYOUTS.len())?];
        let bvh_quality = QUALITIES[pick("BVH quality", codes[4], QUALITIES.len())?];
        let (has_max_distance, has_partial, flags) = (codes[5], codes[6], codes[7]);
        if has_max_distance > 1 || has_partial > 1 || flags & !FLAG_ON_GRID != 0 {
            return Err("invalid flags".into());
        }
        let (max_distance, background, seed) = (r.f32()?, r.f32()?, r.u32()?);
        let (sum_exponent, sq_exponent, block) = (r.u32()? as i32, r.u32()? as i32, r.u32()?);
        let (first, end, next, partial_samples) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        let (ao_rays, passes, render_seconds) = (r.u64()?, r.u32()?, r.f64()?);
        let name_len = r.u32()? as usize;
        if name_len > MAX_ADAPTER_NAME {
            return Err(format!("adapter name of {name_len} bytes (at most {MAX_ADAPTER_NAME})"));
        }
        let adapter = String::from_utf8(r.take(name_len)?.to_vec()).map_err(|_| "adapter name is not UTF-8")?;

        if !(1..=16384).contains(&width) || !(1..=16384).contains(&height) {
            return Err(format!("invalid image size {width}x{height}"));
        }
        if spp == 0 || strata != sampler.strata_per_axis(spp) {
            return Err(format!("invalid samples per pixel {spp} or strata {strata}"));
        }
        // A NaN distance is refused too.
        if (has_max_distance == 1 && (max_distance.is_nan() || max_distance < 0.0)) || !background.is_finite() {
            return Err("invalid max distance or background".into());
        }
        if block != BLOCK_SAMPLES {
            return Err(format!("written with blocks of {block} samples; this aorender uses {BLOCK_SAMPLES}"));
        }
        let e = sum_exponent - ExactSums::exponents(1.0).0;
        if !(0..=256).contains(&e) || (sum_exponent, sq_exponent) != ExactSums::exponents(2f64.powi(e)) {
            return Err(format!("invalid sum scales 2^{sum_exponent}, 2^{sq_exponent}"));
        }
        if !(first <= next && next <= end && end <= spp) {
            return Err(format!("invalid sample range: first {first}, next {next}, end {end}, of {spp}"));
        }
        if partial_samples > next - first
            || partial_samples > BLOCK_SAMPLES
            || (partial_samples > 0) != (has_partial == 1)
        {
            return Err(format!("invalid block in progress of {partial_samples} samples"));
        }
        if !(render_seconds >= 0.0 && render_seconds.is_finite()) {
            return Err(format!("invalid render time {render_seconds}"));
        }
        // The length the header implies, checked against the file's before reading the sums.
        let pixels = width as u64 * height as u64;
        let expected = r.at as u64 + 32 * pixels + if has_partial == 1 { 16 * pixels } else { 0 } + 32;
        if len != expected {
            return Err(format!("truncated or corrupt: {len} bytes, but its header describes {expected}"));
        }
        let mut hasher = blake3::Hasher::new();
        hasher.update(&bytes[..r.at]);
        // The rest of the file: what `head` read past the header, then the stream.
        let mut body = Body { stream: (&bytes[r.at..]).chain(stream), hasher, len };
        let n = pixels as usize;
        let sum = body.read_vec(n, 16, |c| i128::from_le_bytes(c.try_into().expect("16 bytes")))?;
        let sum_sq = body.read_vec(n, 16, |c| i128::from_le_bytes(c.try_into().expect("16 bytes")))?;
        let exact = ExactSums { width, height, sum_exponent, sq_exponent, sum, sum_sq };
        let partial = if has_partial == 0 {
            None
        } else {
            Some(match device {
                Device::Gpu => BlockSums::Gpu(body.read_vec(n, 16, |c| {
                    std::array::from_fn(|k| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes")))
                })?),
                Device::Cpu => {
                    let f = |c: &[u8]| f64::from_le_bytes(c.try_into().expect("8 bytes"));
                    BlockSums::Cpu { sum: body.read_vec(n, 8, f)?, sum_sq: body.read_vec(n, 8, f)? }
                }
            })
        };
        let computed = body.hasher.finalize();
        let mut hash = [0u8; 32];
        body.stream.read_exact(&mut hash).map_err(|e| body.truncated(e))?;
        if computed.as_bytes() != &hash {
            return Err("corrupt: its contents do not match their checksum".into());
        }
        Ok(Accumulation {
            settings: SampleSettings {
                scene_hash,
                width,
                height,
                spp,
                strata,
                hemisphere,
                sampler,
                max_distance: (has_max_distance == 1).then_some(max_distance),
                background,
                seed,
            },
            device,
            bvh_layout,
            bvh_quality,
            adapter,
            first,
            end,
            next,
            partial_samples,
            on_grid: flags & FLAG_ON_GRID != 0,
            ao_rays,
            passes,
            render_seconds,
            exact,
            partial,
            source: None,
        })
    }
}

/// A writer that hashes what passes through it.
struct HashingWriter<'a> {
    inner: &'a mut dyn Write,
    hasher: blake3::Hasher,
}

impl Write for HashingWriter<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// The sums of a checkpoint after its header, hashed as they are read.
struct Body<R: Read> {
    stream: R,
    hasher: blake3::Hasher,
    /// The file's length, for messages.
    len: u64,
}

impl<R: Read> Body<R> {
    fn truncated(&self, e: std::io::Error) -> String {
        format!("truncated or unreadable: {} bytes: {e}", self.len)
    }

    /// `n` elements of `size` bytes each, converted by `convert`.
    fn read_vec<T>(&mut self, n: usize, size: usize, convert: impl Fn(&[u8]) -> T) -> Result<Vec<T>, String> {
        let mut out = Vec::new();
        out.try_reserve_exact(n).map_err(|_| format!("cannot allocate memory for {n} pixels of sums"))?;
        let mut chunk = vec![0u8; size * 65_536];
        let mut left = n;
        while left > 0 {
            let take = left.min(65_536);
            let bytes = &mut chunk[..take * size];
            self.stream.read_exact(bytes).map_err(|e| self.truncated(e))?;
            self.hasher.update(bytes);
            out.extend(bytes.chunks_exact(size).map(&convert));
            left -= take;
        }
        Ok(out)
    }
}

/// Bounds-checked little-endian reads of a header.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    /// The whole file's length, for messages.
    len: u64,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| format!("truncated: {} bytes, ends inside its header", self.len))?;
        let b = &self.bytes[self.at..end];
        self.at = end;
        Ok(b)
    }

    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }

    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }

    fn f32(&mut self) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32()?))
    }

    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64()?))
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
    /// on the shards' adapter: every shard boundary is a multiple of [`BLOCK_SAMPLES`],
    /// every shard's blocks follow that grid, and one adapter rendered them all.
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
/// integers (each shard's block in progress, if any, rounded to the same quanta first), so
/// the result does not depend on the order or grouping of the shards.
pub fn merge(shards: &[(PathBuf, Accumulation)]) -> Result<Merged, CheckpointError> {
    let Some((first_path, first)) = shards.first() else {
        return Err(CheckpointError::new(Path::new("merge"), "no accumulations given"));
    };
    for (path, a) in &shards[1..] {
        let diff = a.settings.differences(&first.settings);
        if !diff.is_empty() {
            return Err(CheckpointError::new(
                path,
                format!("holds samples of another render than {}: {}", first_path.display(), diff.join("; ")),
            ));
        }
        if a.exact.sum_exponent != first.exact.sum_exponent {
            return Err(CheckpointError::new(path, "its sums are scaled differently"));
        }
    }
    let mut order: Vec<&(PathBuf, Accumulation)> = shards.iter().collect();
    order.sort_by_key(|(_, a)| (a.first, a.next));
    for pair in order.windows(2) {
        let ((pa, a), (pb, b)) = (pair[0], pair[1]);
        if b.first < a.next {
            return Err(CheckpointError::new(
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
            return Err(CheckpointError::new(
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
    exact.sum.fill(0);
    exact.sum_sq.fill(0);
    for (path, a) in &order {
        exact.add(&a.exact).map_err(|m| CheckpointError::new(path, m))?;
        if let Some(block) = &a.partial {
            exact.add_block(block).map_err(|m| CheckpointError::new(path, m))?;
        }
    }
    let (lo, hi) = (order[0].1.first, order[order.len() - 1].1.next);
    let aligned = order.windows(2).all(|p| p[0].1.next % BLOCK_SAMPLES == 0);
    let on_grid = order.iter().all(|(_, a)| a.on_grid);
    let one_adapter = order.iter().all(|(_, a)| a.adapter == first.adapter && a.device == first.device);
    Ok(Merged {
        film: exact.to_film((hi - lo) as u64),
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
