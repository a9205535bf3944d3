//! The checkpoint file: an [`Accumulation`] (the raw sums of a render, what it was
//! rendered from, and the sample indices it holds) in a versioned little-endian file
//! written atomically.
//!
//! An accumulation holds the exact fixed-point sums of the finished 256-sample blocks
//! ([`ExactSums`], see [`BLOCK_SAMPLES`]) and the device's sums of the block in progress
//! ([`BlockSums`]: 64-bit integers, the same on every device for the same samples).
//! Loading it back continues the render from the same bits; adding the exact sums of
//! accumulations of disjoint sample ranges (`accumulation::merge`) is exact integer
//! addition.
//!
//! File layout (version 4; versions 1 to 3 are read too), every number little-endian:
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `AOCKPT\r\n` |
//! | 4 | format version (u32) |
//! | 32 | BLAKE3 hash of the scene's geometry and camera |
//! | 4 × 4 | width, height, samples per pixel, strata per axis (u32) |
//! | 8 × 1 | hemisphere, sampler, device, BVH layout, BVH quality (codes below), has max distance, has a block in progress, flags (u8) |
//! | 4 × 3 | max distance, background (f32), seed (u32) |
//! | 4 × 3 | exponents of the sums' quanta (i32 × 2), samples per block (u32) |
//! | 4 × 4 | first sample, end of the range, next sample, samples of the block in progress (u32) |
//! | 8 + 4 + 8 | AO rays (u64), passes (u32), render seconds (f64) |
//! | 4 + n | adapter name: length (u32, at most 4096), UTF-8 |
//! | 4 + 4 | samples per replicate (u32); film layout, sky, sky sampling and sky normalisation codes (u8; version 2 and 3: the film layout, then three zero bytes, the uniform sky) |
//! | 4 × 4 | version 4: the sky's up vector, ground albedo (f32) |
//! | 8 + 4 | complete replicates (u64), groups of replicate sums (u32, 0 for none) |
//! | 32 × pixels | exact sums: Σv for every pixel, then Σv² (i128) |
//! | 16 × groups | Σ of the squares of complete replicates' sums, per group (i128) |
//! | 9 × pixels | with the per-pixel flag (an adaptive render): each pixel's samples, then its complete replicates (u32), then whether it is no longer sampled (u8, 0 or 1) |
//! | 16 × pixels | block in progress, when present: Σv (i64) for every pixel, then Σv² (u64), in the quanta of [`BlockSums`] |
//! | 32 | BLAKE3 hash of every byte before it |
//!
//! The reader checks the magic, the version and every field's range, computes the file's
//! expected length from the header and compares it with the actual length before it
//! allocates or reads the sums, then streams the sums (holding them once, never the file
//! beside them) and checks the hash.
//!
//! The codes of the enumerations are fixed numbers of this format, independent of the
//! order in which the command line lists the values:
//!
//! | field | codes |
//! |---|---|
//! | hemisphere | 0 uniform, 1 cosine, 2 cosine-polar |
//! | sampler | 0 independent, 1 stratified, 2 grid, 3 sobol |
//! | device | 0 GPU, 1 CPU |
//! | BVH layout | 0 BVH2, 1 CWBVH |
//! | BVH quality | 0 fastest, 1 fast, 2 medium, 3 slow |
//! | film layout | 0 image, 1 probes, 2 probes with bent normals |
//! | sky | 0 uniform, 1 overcast |
//! | sky sampling | 0 horizon, 1 control-variate, 2 weighted |
//! | sky normalisation | 0 horizontal, 1 surface |
//!
//! A version 1 file has none of the replicate fields: it is an image whose samples are
//! one replicate (independent ones: replicates of one sample each). Versions 1 and 2
//! hold the block in progress as the device's floats (GPU: Σv, its Neumaier
//! compensation, Σv², its compensation, 4 × f32 per pixel; CPU: Σv then Σv², f64): each
//! pair is added in f64 and rounded to the nearest quantum of a block's integers when
//! read.

use super::policy::write_output_with;
use crate::accumulation::{Accumulation, AccumulationParts, FilmLayout, SampleSettings};
use crate::error::{Error, Result};
use crate::film::{BLOCK_SAMPLES, BlockSums, ExactSums, OUT_OF_RANGE_BIT};
use crate::kinds::{BuildQuality, BvhLayout, DeviceKind};
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::scene::input::vec_bytes;
use crate::scene::{ReadLimits, Sampling};
use crate::sky::{Sky, SkyModel, SkyNormalise, SkySampling};
use std::io::{Read, Write};
use std::path::Path;

/// The first bytes of a checkpoint file.
pub const MAGIC: [u8; 8] = *b"AOCKPT\r\n";
/// The format version this build writes (it reads 1 and 2 as well).
pub const VERSION: u32 = 4;
/// The most film slots a checkpoint holds: those of the largest image.
const MAX_SLOTS: u64 = crate::scene::MAX_IMAGE_SIDE as u64 * crate::scene::MAX_IMAGE_SIDE as u64;
/// Longest adapter name stored.
const MAX_ADAPTER_NAME: usize = 4096;
/// Flag: the blocks follow the absolute grid of [`BLOCK_SAMPLES`] (cleared when a render
/// whose last block was cut short by its end is continued past that end).
const FLAG_ON_GRID: u8 = 1;
/// Flag: the sums are counted per pixel (an adaptive render stopped sampling some).
const FLAG_PER_PIXEL: u8 = 2;

/// The file's code of a hemisphere distribution.
fn hemisphere_code(h: Hemisphere) -> u8 {
    match h {
        Hemisphere::Uniform => 0,
        Hemisphere::Cosine => 1,
        Hemisphere::CosinePolar => 2,
    }
}

fn hemisphere_of(code: u8) -> Option<Hemisphere> {
    Hemisphere::ALL.into_iter().find(|&h| hemisphere_code(h) == code)
}

/// The file's code of a sampler.
fn sampler_code(s: Sampler) -> u8 {
    match s {
        Sampler::Independent => 0,
        Sampler::Stratified => 1,
        Sampler::Grid => 2,
        Sampler::Sobol => 3,
    }
}

fn sampler_of(code: u8) -> Option<Sampler> {
    Sampler::ALL.into_iter().find(|&s| sampler_code(s) == code)
}

/// The file's code of a device.
fn device_code(d: DeviceKind) -> u8 {
    match d {
        DeviceKind::Gpu => 0,
        DeviceKind::Cpu => 1,
    }
}

fn device_of(code: u8) -> Option<DeviceKind> {
    [DeviceKind::Gpu, DeviceKind::Cpu].into_iter().find(|&d| device_code(d) == code)
}

/// The file's code of a BVH layout.
fn layout_code(l: BvhLayout) -> u8 {
    match l {
        BvhLayout::Bvh2 => 0,
        BvhLayout::Cwbvh => 1,
    }
}

fn layout_of(code: u8) -> Option<BvhLayout> {
    BvhLayout::ALL.into_iter().find(|&l| layout_code(l) == code)
}

/// The file's code of a BVH build preset.
fn quality_code(q: BuildQuality) -> u8 {
    match q {
        BuildQuality::Fastest => 0,
        BuildQuality::Fast => 1,
        BuildQuality::Medium => 2,
        BuildQuality::Slow => 3,
    }
}

fn quality_of(code: u8) -> Option<BuildQuality> {
    BuildQuality::ALL.into_iter().find(|&q| quality_code(q) == code)
}

/// The file's code of a film layout.
fn film_code(f: FilmLayout) -> u8 {
    match f {
        FilmLayout::Image => 0,
        FilmLayout::Probes => 1,
        FilmLayout::BentProbes => 2,
    }
}

fn film_of(code: u8) -> Option<FilmLayout> {
    [FilmLayout::Image, FilmLayout::Probes, FilmLayout::BentProbes].into_iter().find(|&f| film_code(f) == code)
}

/// Why the bytes of a checkpoint are unusable, in one line (the file is named by the
/// caller).
struct Invalid(String);

impl From<String> for Invalid {
    fn from(message: String) -> Self {
        Invalid(message)
    }
}

impl From<&str> for Invalid {
    fn from(message: &str) -> Self {
        Invalid(message.to_string())
    }
}

impl Accumulation {
    /// Writes the checkpoint file under the output policy: a regular file atomically (to
    /// a temporary file beside it, then renamed), a FIFO or a device written into.
    pub fn write(&self, path: &Path) -> Result<()> {
        write_output_with(path, &mut |w| {
            let mut w = HashingWriter { inner: w, hasher: blake3::Hasher::new() };
            self.write_body(&mut w)?;
            let hash = *w.hasher.finalize().as_bytes();
            w.inner.write_all(&hash)
        })
    }

    fn write_body(&self, w: &mut dyn Write) -> std::io::Result<()> {
        let (s, m) = (self.settings(), &self.settings().sampling);
        w.write_all(&MAGIC)?;
        w.write_all(&VERSION.to_le_bytes())?;
        w.write_all(&s.scene_hash)?;
        for v in [s.width, s.height, s.spp, s.strata] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&[
            hemisphere_code(m.hemisphere),
            sampler_code(m.sampler),
            device_code(self.device()),
            layout_code(self.bvh_layout()),
            quality_code(self.bvh_quality()),
            m.max_distance.is_some() as u8,
            self.partial().is_some() as u8,
            if self.on_grid() { FLAG_ON_GRID } else { 0 }
                | if self.exact().pixel_samples.is_empty() { 0 } else { FLAG_PER_PIXEL },
        ])?;
        w.write_all(&m.max_distance.unwrap_or(0.0).to_le_bytes())?;
        w.write_all(&s.background.to_le_bytes())?;
        w.write_all(&m.seed.to_le_bytes())?;
        w.write_all(&self.exact().sum_exponent.to_le_bytes())?;
        w.write_all(&self.exact().sq_exponent.to_le_bytes())?;
        w.write_all(&BLOCK_SAMPLES.to_le_bytes())?;
        for v in [self.first(), self.end(), self.next(), self.partial_samples()] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&self.ao_rays().to_le_bytes())?;
        w.write_all(&self.passes().to_le_bytes())?;
        w.write_all(&self.render_seconds().to_le_bytes())?;
        let name = &self.adapter().as_bytes()[..self.adapter().len().min(MAX_ADAPTER_NAME)];
        w.write_all(&(name.len() as u32).to_le_bytes())?;
        w.write_all(name)?;
        w.write_all(&s.replicate().to_le_bytes())?;
        w.write_all(&[film_code(s.layout), m.sky.model.code(), m.sky.sampling.code(), m.sky.normalise.code()])?;
        for v in m.sky.up.to_array().into_iter().chain([m.sky.ground_albedo]) {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&self.exact().replicates.to_le_bytes())?;
        w.write_all(&(self.exact().replicate_sq.len() as u32).to_le_bytes())?;
        let mut buf = Vec::with_capacity(1 << 16);
        let flush = |w: &mut dyn Write, buf: &mut Vec<u8>, force: bool| -> std::io::Result<()> {
            if force || buf.len() >= 1 << 16 {
                w.write_all(buf)?;
                buf.clear();
            }
            Ok(())
        };
        for v in self.exact().sum.iter().chain(&self.exact().sum_sq).chain(&self.exact().replicate_sq) {
            buf.extend_from_slice(&v.to_le_bytes());
            flush(w, &mut buf, false)?;
        }
        for v in self.exact().pixel_samples.iter().chain(&self.exact().pixel_replicates) {
            buf.extend_from_slice(&v.to_le_bytes());
            flush(w, &mut buf, false)?;
        }
        if !self.exact().pixel_samples.is_empty() {
            let stopped = |i: usize| self.exact().stopped.get(i).copied().unwrap_or(false);
            for i in 0..self.exact().pixel_samples.len() {
                buf.push(stopped(i) as u8);
                flush(w, &mut buf, false)?;
            }
        }
        if let Some(block) = self.partial() {
            for v in &block.sum {
                buf.extend_from_slice(&v.to_le_bytes());
                flush(w, &mut buf, false)?;
            }
            for v in &block.sum_sq {
                buf.extend_from_slice(&v.to_le_bytes());
                flush(w, &mut buf, false)?;
            }
        }
        flush(w, &mut buf, true)
    }

    /// Reads a checkpoint file, checking it whole before use, within the read budget of
    /// [`ReadLimits::from_env`].
    pub fn read(path: &Path) -> Result<Accumulation> {
        Accumulation::read_with(path, &ReadLimits::from_env()?)
    }

    /// [`Accumulation::read`] within `limits`: the sums the header describes must fit in
    /// the budget, or the file is refused before they are read.
    pub fn read_with(path: &Path, limits: &ReadLimits) -> Result<Accumulation> {
        let err = |m: String| Error::checkpoint(path, m);
        let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
        let len = file.metadata().map_err(|e| err(e.to_string()))?.len();
        let mut acc =
            Accumulation::from_stream(&mut std::io::BufReader::new(file), len, limits).map_err(|e| err(e.0))?;
        acc.set_source(path);
        Ok(acc)
    }

    /// Parses the bytes of a checkpoint file; the error says what is wrong in one line.
    pub fn from_bytes(mut bytes: &[u8]) -> Result<Accumulation> {
        let len = bytes.len() as u64;
        let limits = ReadLimits::with_memory(u64::MAX);
        Accumulation::from_stream(&mut bytes, len, &limits).map_err(|e| Error::checkpoint("checkpoint", e.0))
    }

    /// The bytes of memory the sums of a read checkpoint hold.
    pub fn memory_bytes(&self) -> u64 {
        let e = self.exact();
        let partial = self.partial().map_or(0, |b| vec_bytes(&b.sum) + vec_bytes(&b.sum_sq));
        vec_bytes(&e.sum)
            + vec_bytes(&e.sum_sq)
            + vec_bytes(&e.replicate_sq)
            + vec_bytes(&e.pixel_samples)
            + vec_bytes(&e.pixel_replicates)
            + vec_bytes(&e.stopped)
            + partial
    }

    /// Parses a checkpoint of `len` bytes from `stream`. Memory is taken only after the
    /// header's figures agree with `len` and fit in `limits`, so a damaged or hostile
    /// header cannot ask for more than the file holds or the budget allows.
    fn from_stream(stream: &mut dyn Read, len: u64, limits: &ReadLimits) -> Result<Accumulation, Invalid> {
        let head = read_head(stream)?;
        let header = Header::parse(&head, len)?;
        header.check()?;
        header.check_length(len, limits)?;
        let mut hasher = blake3::Hasher::new();
        hasher.update(&head[..header.size]);
        // The rest of the file: what `head` read past the header, then the stream.
        let mut body = Body { stream: (&head[header.size..]).chain(stream), hasher, len };
        let exact = header.read_exact_sums(&mut body)?;
        let partial = header.read_block_in_progress(&mut body, &exact)?;
        body.check_hash()?;
        Ok(header.into_accumulation(exact, partial))
    }
}

/// The first bytes of a checkpoint: its header whole, at most, and perhaps the start of
/// its sums.
fn read_head(stream: &mut dyn Read) -> Result<Vec<u8>, Invalid> {
    // The fixed fields (through the adapter name's length), the name at most, and the
    // replicate fields after it.
    const FIXED_HEADER: usize = 8 + 4 + 32 + 16 + 8 + 12 + 12 + 16 + 20 + 4 + 20 + 16;
    let mut head = Vec::new();
    stream
        .take((FIXED_HEADER + MAX_ADAPTER_NAME) as u64)
        .read_to_end(&mut head)
        .map_err(|e| format!("cannot read: {e}"))?;
    Ok(head)
}

/// The fields of a checkpoint's header, as read (codes already decoded).
struct Header {
    version: u32,
    scene_hash: [u8; 32],
    width: u32,
    height: u32,
    spp: u32,
    strata: u32,
    hemisphere: Hemisphere,
    sampler: Sampler,
    device: DeviceKind,
    bvh_layout: BvhLayout,
    bvh_quality: BuildQuality,
    has_max_distance: bool,
    has_partial: bool,
    flags: u8,
    max_distance: f32,
    background: f32,
    seed: u32,
    sum_exponent: i32,
    sq_exponent: i32,
    block: u32,
    first: u32,
    end: u32,
    next: u32,
    partial_samples: u32,
    ao_rays: u64,
    passes: u32,
    render_seconds: f64,
    adapter: String,
    replicate: u32,
    layout: FilmLayout,
    sky: Sky,
    replicates: u64,
    groups: u32,
    /// The header's bytes: where the sums begin.
    size: usize,
}

/// The fields after the adapter name (version 2 on).
struct ReplicateFields {
    replicate: u32,
    layout: FilmLayout,
    sky: Sky,
    replicates: u64,
    groups: u32,
}

fn invalid(what: &str, code: u8) -> Invalid {
    Invalid(format!("invalid {what} code {code}"))
}

impl Header {
    /// Reads the header's fields from the first bytes of a file of `len` bytes, checking
    /// the magic, the version, the codes and the flags as they come.
    fn parse(bytes: &[u8], len: u64) -> Result<Header, Invalid> {
        let mut r = Reader { bytes, at: 0, len };
        if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
            return Err("not an aorender checkpoint (no AOCKPT header)".into());
        }
        r.at = MAGIC.len();
        let version = r.u32()?;
        if !(1..=VERSION).contains(&version) {
            return Err(
                format!("checkpoint format version {version}; this aorender reads versions 1 to {VERSION}").into()
            );
        }
        let scene_hash: [u8; 32] = r.take(32)?.try_into().expect("32 bytes");
        let (width, height, spp, strata) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        let codes = r.take(8)?;
        let hemisphere = hemisphere_of(codes[0]).ok_or_else(|| invalid("hemisphere", codes[0]))?;
        let sampler = sampler_of(codes[1]).ok_or_else(|| invalid("sampler", codes[1]))?;
        let device = device_of(codes[2]).ok_or_else(|| invalid("device", codes[2]))?;
        let bvh_layout = layout_of(codes[3]).ok_or_else(|| invalid("BVH layout", codes[3]))?;
        let bvh_quality = quality_of(codes[4]).ok_or_else(|| invalid("BVH quality", codes[4]))?;
        let (has_max_distance, has_partial, flags) = (codes[5], codes[6], codes[7]);
        if has_max_distance > 1 || has_partial > 1 || flags & !(FLAG_ON_GRID | FLAG_PER_PIXEL) != 0 {
            return Err("invalid flags".into());
        }
        let (max_distance, background, seed) = (r.f32()?, r.f32()?, r.u32()?);
        let (sum_exponent, sq_exponent, block) = (r.u32()? as i32, r.u32()? as i32, r.u32()?);
        let (first, end, next, partial_samples) = (r.u32()?, r.u32()?, r.u32()?, r.u32()?);
        let (ao_rays, passes, render_seconds) = (r.u64()?, r.u32()?, r.f64()?);
        let name_len = r.u32()? as usize;
        if name_len > MAX_ADAPTER_NAME {
            return Err(format!("adapter name of {name_len} bytes (at most {MAX_ADAPTER_NAME})").into());
        }
        let adapter = String::from_utf8(r.take(name_len)?.to_vec()).map_err(|_| "adapter name is not UTF-8")?;
        let ReplicateFields { replicate, layout, sky, replicates, groups } = if version == 1 {
            let replicate = if sampler == Sampler::Independent { 1 } else { 0 };
            ReplicateFields { replicate, layout: FilmLayout::Image, sky: Sky::default(), replicates: 0, groups: 0 }
        } else {
            read_replicate_fields(&mut r, version)?
        };
        Ok(Header {
            version,
            scene_hash,
            width,
            height,
            spp,
            strata,
            hemisphere,
            sampler,
            device,
            bvh_layout,
            bvh_quality,
            has_max_distance: has_max_distance == 1,
            has_partial: has_partial == 1,
            flags,
            max_distance,
            background,
            seed,
            sum_exponent,
            sq_exponent,
            block,
            first,
            end,
            next,
            partial_samples,
            ao_rays,
            passes,
            render_seconds,
            adapter,
            replicate,
            layout,
            sky,
            replicates,
            groups,
            size: r.at,
        })
    }

    /// Checks every field's range and their agreement with each other.
    fn check(&self) -> Result<(), Invalid> {
        let (width, height, spp, replicate, sampler) =
            (self.width, self.height, self.spp, self.replicate, self.sampler);
        // An image is at most MAX_IMAGE_SIDE on a side; a probe film (bake: one slot per point) may be
        // long and narrow, within the same number of slots.
        if width == 0 || height == 0 || width as u64 * height as u64 > MAX_SLOTS {
            return Err(format!("invalid film size {width}x{height} (at most {MAX_SLOTS} slots)").into());
        }
        if spp == 0
            || sampler.check_replicate(replicate).is_err()
            || replicate != sampler.replicate_samples(Some(replicate))
            || self.strata != sampler.strata_per_axis(spp, replicate)
        {
            let strata = self.strata;
            return Err(format!("invalid samples per pixel {spp}, strata {strata} or replicate {replicate}").into());
        }
        // A NaN distance is refused too.
        if (self.has_max_distance && (self.max_distance.is_nan() || self.max_distance < 0.0))
            || !self.background.is_finite()
        {
            return Err("invalid max distance or background".into());
        }
        if self.block != BLOCK_SAMPLES {
            let block = self.block;
            return Err(format!("written with blocks of {block} samples; this aorender uses {BLOCK_SAMPLES}").into());
        }
        let (sum_exponent, sq_exponent) = (self.sum_exponent, self.sq_exponent);
        let e = sum_exponent - ExactSums::exponents(1.0).0;
        if !(0..=crate::film::MAX_VALUE_EXPONENT).contains(&e)
            || (sum_exponent, sq_exponent) != ExactSums::exponents(2f64.powi(e))
        {
            return Err(format!("invalid sum scales 2^{sum_exponent}, 2^{sq_exponent}").into());
        }
        let (first, end, next, partial_samples) = (self.first, self.end, self.next, self.partial_samples);
        if !(first <= next && next <= end && end <= spp) {
            return Err(format!("invalid sample range: first {first}, next {next}, end {end}, of {spp}").into());
        }
        if partial_samples > next - first
            || partial_samples > BLOCK_SAMPLES
            || (partial_samples > 0) != self.has_partial
        {
            return Err(format!("invalid block in progress of {partial_samples} samples").into());
        }
        let render_seconds = self.render_seconds;
        if !(render_seconds >= 0.0 && render_seconds.is_finite()) {
            return Err(format!("invalid render time {render_seconds}").into());
        }
        Ok(())
    }

    /// The film's slots.
    fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    fn per_pixel(&self) -> bool {
        self.flags & FLAG_PER_PIXEL != 0
    }

    /// Checks the length the header implies against the file's `len`, and the memory its
    /// sums take against `limits`, before any sum is read.
    fn check_length(&self, len: u64, limits: &ReadLimits) -> Result<(), Invalid> {
        let pixels = self.pixels();
        let (replicates, groups) = (self.replicates, self.groups);
        if groups as u64 > pixels || replicates > u32::MAX as u64 {
            return Err(format!("invalid replicates: {replicates} in {groups} groups").into());
        }
        let expected = self.size as u64
            + 32 * pixels
            + 16 * groups as u64
            + if self.per_pixel() { 9 * pixels } else { 0 }
            + if self.has_partial { 16 * pixels } else { 0 }
            + 32;
        if len != expected {
            return Err(format!("truncated or corrupt: {len} bytes, but its header describes {expected}").into());
        }
        // What the sums take in memory: their bytes in the file, but the flags (a byte
        // each in both) and the hashes.
        let memory = expected - self.size as u64 - 32;
        if memory > limits.memory() {
            return Err(limits.exceeded_message("the checkpoint").into());
        }
        Ok(())
    }

    /// Reads the exact sums of the finished blocks, the replicate sums and the per-pixel
    /// counts.
    fn read_exact_sums(&self, body: &mut Body<impl Read>) -> Result<ExactSums, Invalid> {
        let n = self.pixels() as usize;
        let i128_of = |c: &[u8]| i128::from_le_bytes(c.try_into().expect("16 bytes"));
        let sum = body.read_vec(n, 16, i128_of)?;
        let sum_sq = body.read_vec(n, 16, i128_of)?;
        let replicate_sq = body.read_vec(self.groups as usize, 16, i128_of)?;
        let (pixel_samples, pixel_replicates, stopped) = if self.per_pixel() {
            let u = |c: &[u8]| u32::from_le_bytes(c.try_into().expect("4 bytes"));
            let (samples, replicates) = (body.read_vec(n, 4, u)?, body.read_vec(n, 4, u)?);
            let flags = body.read_vec(n, 1, |c| c[0])?;
            if flags.iter().any(|&f| f > 1) {
                return Err("invalid per-pixel flags".into());
            }
            (samples, replicates, flags.into_iter().map(|f| f == 1).collect())
        } else {
            (Vec::new(), Vec::new(), Vec::new())
        };
        if pixel_samples.iter().any(|&k| k > self.next - self.first) {
            return Err("a pixel holds more samples than the range".into());
        }
        Ok(ExactSums {
            width: self.width,
            height: self.height,
            sum_exponent: self.sum_exponent,
            sq_exponent: self.sq_exponent,
            sum,
            sum_sq,
            replicate_sq,
            replicates: self.replicates,
            pixel_samples,
            pixel_replicates,
            stopped,
        })
    }

    /// Reads the sums of the block in progress, when the file holds one.
    fn read_block_in_progress(
        &self,
        body: &mut Body<impl Read>,
        exact: &ExactSums,
    ) -> Result<Option<BlockSums>, Invalid> {
        let n = self.pixels() as usize;
        if !self.has_partial {
            return Ok(None);
        }
        if self.version >= 3 {
            let sum = body.read_vec(n, 8, |c| i64::from_le_bytes(c.try_into().expect("8 bytes")))?;
            let sum_sq = body.read_vec(n, 8, |c| u64::from_le_bytes(c.try_into().expect("8 bytes")))?;
            if sum_sq.iter().any(|&q| q & OUT_OF_RANGE_BIT != 0) {
                return Err("a sum of samples in the block in progress is out of range".into());
            }
            return Ok(Some(BlockSums { sum, sum_sq }));
        }
        // The device's floats of versions 1 and 2, rounded to the block's quanta.
        let e = exact.value_exponent();
        let floats: Vec<(f64, f64)> = match self.device {
            DeviceKind::Gpu => body.read_vec(n, 16, |c| {
                let f = |k: usize| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes")) as f64;
                (f(0) + f(1), f(2) + f(3))
            })?,
            DeviceKind::Cpu => {
                let f = |c: &[u8]| f64::from_le_bytes(c.try_into().expect("8 bytes"));
                let (sum, sum_sq) = (body.read_vec(n, 8, f)?, body.read_vec(n, 8, f)?);
                sum.into_iter().zip(sum_sq).collect()
            }
        };
        let block = BlockSums::from_floats(floats.into_iter(), e)
            .map_err(|e| Invalid(format!("the block in progress: {e}")))?;
        Ok(Some(block))
    }

    /// The accumulation the header and its sums describe.
    fn into_accumulation(self, exact: ExactSums, partial: Option<BlockSums>) -> Accumulation {
        Accumulation::from_parts(AccumulationParts {
            settings: SampleSettings {
                scene_hash: self.scene_hash,
                width: self.width,
                height: self.height,
                spp: self.spp,
                strata: self.strata,
                layout: self.layout,
                background: self.background,
                sampling: Sampling {
                    hemisphere: self.hemisphere,
                    sampler: self.sampler,
                    max_distance: self.has_max_distance.then_some(self.max_distance),
                    seed: self.seed,
                    replicate: Some(self.replicate),
                    sky: self.sky,
                },
            },
            device: self.device,
            bvh_layout: self.bvh_layout,
            bvh_quality: self.bvh_quality,
            adapter: self.adapter,
            first: self.first,
            end: self.end,
            next: self.next,
            partial_samples: self.partial_samples,
            on_grid: self.flags & FLAG_ON_GRID != 0,
            ao_rays: self.ao_rays,
            passes: self.passes,
            render_seconds: self.render_seconds,
            exact,
            partial,
            // The power of two the sums' scale was set from: at least the largest sample.
            max_value: 2f64.powi(self.sum_exponent - ExactSums::exponents(1.0).0),
        })
    }
}

/// Reads the replicate fields, the film layout and (version 4) the sky that follow the
/// adapter name in versions 2 on.
fn read_replicate_fields(r: &mut Reader<'_>, version: u32) -> Result<ReplicateFields, Invalid> {
    let mut sky = Sky::default();
    let replicate = r.u32()?;
    let codes = r.take(4)?;
    let layout = film_of(codes[0]).ok_or_else(|| invalid("film layout", codes[0]))?;
    if version < 4 && codes[1..] != [0, 0, 0] {
        return Err("invalid reserved bytes".into());
    }
    if version >= 4 {
        sky.model = SkyModel::from_code(codes[1]).ok_or_else(|| invalid("sky", codes[1]))?;
        sky.sampling = SkySampling::from_code(codes[2]).ok_or_else(|| invalid("sky sampling", codes[2]))?;
        sky.normalise = SkyNormalise::from_code(codes[3]).ok_or_else(|| invalid("sky normalisation", codes[3]))?;
        sky.up = glam::Vec3::new(r.f32()?, r.f32()?, r.f32()?);
        sky.ground_albedo = r.f32()?;
        sky.validate().map_err(|e| Invalid(format!("invalid sky: {e}")))?;
    }
    Ok(ReplicateFields { replicate, layout, sky, replicates: r.u64()?, groups: r.u32()? })
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
    fn truncated(&self, e: std::io::Error) -> Invalid {
        Invalid(format!("truncated or unreadable: {} bytes: {e}", self.len))
    }

    /// Reads the file's closing hash and compares it with that of every byte before it.
    fn check_hash(&mut self) -> Result<(), Invalid> {
        let computed = self.hasher.finalize();
        let mut hash = [0u8; 32];
        self.stream.read_exact(&mut hash).map_err(|e| self.truncated(e))?;
        if computed.as_bytes() != &hash {
            return Err("corrupt: its contents do not match their checksum".into());
        }
        Ok(())
    }

    /// `n` elements of `size` bytes each, converted by `convert`.
    fn read_vec<T>(&mut self, n: usize, size: usize, convert: impl Fn(&[u8]) -> T) -> Result<Vec<T>, Invalid> {
        let mut out = Vec::new();
        out.try_reserve_exact(n).map_err(|_| Invalid(format!("cannot allocate memory for {n} pixels of sums")))?;
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
    fn take(&mut self, n: usize) -> Result<&'a [u8], Invalid> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| Invalid(format!("truncated: {} bytes, ends inside its header", self.len)))?;
        let b = &self.bytes[self.at..end];
        self.at = end;
        Ok(b)
    }

    fn u32(&mut self) -> Result<u32, Invalid> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }

    fn u64(&mut self) -> Result<u64, Invalid> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }

    fn f32(&mut self) -> Result<f32, Invalid> {
        Ok(f32::from_bits(self.u32()?))
    }

    fn f64(&mut self) -> Result<f64, Invalid> {
        Ok(f64::from_bits(self.u64()?))
    }
}
