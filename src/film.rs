//! Accumulation (per-pixel sums of sample values and their squares), statistics, and
//! image outputs written atomically (to a temporary file beside the target, then renamed).

use crate::error::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Per-pixel sums over the samples rendered so far. Pixel `(x, y)` is at `y * width + x`.
#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples in every pixel's sums.
    pub samples: u64,
    /// Σ value.
    pub sum: Vec<f64>,
    /// Σ value².
    pub sum_sq: Vec<f64>,
}

impl Film {
    /// An empty accumulation.
    pub fn new(width: u32, height: u32) -> Film {
        let n = width as usize * height as usize;
        Film { width, height, samples: 0, sum: vec![0.0; n], sum_sq: vec![0.0; n] }
    }

    /// Per-pixel estimates (sample means).
    pub fn mean(&self) -> Vec<f64> {
        let n = self.samples.max(1) as f64;
        self.sum.iter().map(|s| s / n).collect()
    }

    /// Per-pixel standard error of the mean, from the sample variance. It assumes
    /// independent samples: for stratified and Sobol samples it is an overestimate.
    pub fn std_error(&self) -> Vec<f64> {
        let n = self.samples as f64;
        if self.samples < 2 {
            return vec![f64::INFINITY; self.sum.len()];
        }
        self.sum
            .iter()
            .zip(&self.sum_sq)
            .map(|(s, q)| {
                let mean = s / n;
                let var = ((q / n - mean * mean) * n / (n - 1.0)).max(0.0);
                (var / n).sqrt()
            })
            .collect()
    }

    /// Mean over all pixels of the per-pixel estimates.
    pub fn image_mean(&self) -> f64 {
        let m = self.mean();
        m.iter().sum::<f64>() / m.len() as f64
    }

    /// Writes the image; the extension picks the format: `.png` (8-bit sRGB-encoded,
    /// values clamped to [0, 1]), `.exr` or `.pfm` (32-bit float, linear).
    pub fn write_image(&self, path: &Path) -> Result<()> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let out_err = |m: String| Error::Output { path: path.to_path_buf(), message: m };
        let mean: Vec<f32> = self.mean().into_iter().map(|v| v as f32).collect();
        let (w, h) = (self.width, self.height);
        let bytes = match ext.as_str() {
            "png" => {
                let px: Vec<u8> = mean.iter().map(|&v| linear_to_srgb8(v)).collect();
                let img = image::GrayImage::from_raw(w, h, px).expect("buffer matches size");
                encode(image::DynamicImage::ImageLuma8(img), image::ImageFormat::Png).map_err(out_err)?
            }
            "exr" => {
                let rgb: Vec<f32> = mean.iter().flat_map(|&v| [v, v, v]).collect();
                let img = image::Rgb32FImage::from_raw(w, h, rgb).expect("buffer matches size");
                encode(image::DynamicImage::ImageRgb32F(img), image::ImageFormat::OpenExr).map_err(out_err)?
            }
            "pfm" => pfm_bytes(w, h, &mean),
            "" => return Err(out_err("no file extension: expected .png, .exr or .pfm".into())),
            e => return Err(out_err(format!("unsupported image format '.{e}': expected .png, .exr or .pfm"))),
        };
        write_atomically(path, &bytes)
    }
}

/// Samples per block, the unit of exact accumulation: block `k` holds sample indices
/// `256k .. 256k + 256` (cut short by the ends of the rendered range). A device sums one
/// block at a time in its own arithmetic (compensated f32 on the GPU, f64 on the CPU);
/// each finished block is rounded once to a fixed-point integer and added to
/// [`ExactSums`], where addition is exact, so the result does not depend on how the
/// blocks were grouped into passes, runs or shards.
pub const BLOCK_SAMPLES: u32 = 256;

/// Per-pixel sums of the samples of one block, as the device keeps them.
#[derive(Clone, Debug, PartialEq)]
pub enum BlockSums {
    /// The GPU film's f32 words per pixel: Σv, its Neumaier compensation, Σv², its
    /// compensation.
    Gpu(Vec<[f32; 4]>),
    /// The CPU reference's f64 sums.
    Cpu {
        /// Σv.
        sum: Vec<f64>,
        /// Σv².
        sum_sq: Vec<f64>,
    },
}

impl BlockSums {
    /// Pixels.
    pub fn len(&self) -> usize {
        match self {
            BlockSums::Gpu(words) => words.len(),
            BlockSums::Cpu { sum, .. } => sum.len(),
        }
    }

    /// True when there are no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pixel `i`'s (Σv, Σv²); a compensated pair is added in f64, where two f32 add exactly
    /// unless their exponents are more than 29 apart.
    pub fn pixel(&self, i: usize) -> (f64, f64) {
        match self {
            BlockSums::Gpu(words) => {
                let t = words[i];
                (t[0] as f64 + t[1] as f64, t[2] as f64 + t[3] as f64)
            }
            BlockSums::Cpu { sum, sum_sq } => (sum[i], sum_sq[i]),
        }
    }
}

/// log2 of the most samples one pixel can accumulate: sample indices are 32-bit.
const MAX_SAMPLES_LOG2: i32 = 32;
/// log2 of the bound on the integers of [`ExactSums`]: 2^32 samples of the largest value
/// stay below it, and i128 holds twice it.
const MAGNITUDE_LOG2: i32 = 125;

/// 2^n as f64, exactly, for n in -1022..=1023.
fn pow2(n: i32) -> f64 {
    debug_assert!((-1022..=1023).contains(&n));
    f64::from_bits(((n + 1023) as u64) << 52)
}

/// Per-pixel sums of finished blocks in fixed point: Σv of pixel `i` is
/// `sum[i]` × 2^`sum_exponent`, Σv² is `sum_sq[i]` × 2^`sq_exponent`. The quanta are set
/// from the largest value a sample can take so that 2^32 samples fit; they are about
/// 2^-93 of that value, far below f64's resolution of any sum of samples. Integer
/// addition is associative: blocks added in any order or grouping give the same bits.
#[derive(Clone, Debug, PartialEq)]
pub struct ExactSums {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Exponent of the quantum of `sum`.
    pub sum_exponent: i32,
    /// Exponent of the quantum of `sum_sq`.
    pub sq_exponent: i32,
    /// Σv in quanta.
    pub sum: Vec<i128>,
    /// Σv² in quanta.
    pub sum_sq: Vec<i128>,
}

impl ExactSums {
    /// Zero sums for samples of magnitude at most `max_value`.
    pub fn new(width: u32, height: u32, max_value: f64) -> ExactSums {
        let (sum_exponent, sq_exponent) = ExactSums::exponents(max_value);
        let n = width as usize * height as usize;
        ExactSums { width, height, sum_exponent, sq_exponent, sum: vec![0; n], sum_sq: vec![0; n] }
    }

    /// The quanta's exponents for samples of magnitude at most `max_value` (taken as at
    /// least 1; non-finite is taken as the largest f32 doubled).
    pub fn exponents(max_value: f64) -> (i32, i32) {
        let v = if max_value.is_finite() { max_value.max(1.0) } else { 2.0 * f32::MAX as f64 };
        // The smallest e with 2^e ≥ v: at most 129 for any f32 value doubled.
        let mut e = 0;
        while e < 256 && pow2(e) < v {
            e += 1;
        }
        (e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2, 2 * e + MAX_SAMPLES_LOG2 - MAGNITUDE_LOG2)
    }

    /// Adds a finished block, each pixel's sums rounded to the nearest quantum. An error
    /// names the first pixel whose sum is not finite or out of range.
    pub fn add_block(&mut self, block: &BlockSums) -> Result<(), String> {
        if block.len() != self.sum.len() {
            return Err(format!("a block of {} pixels added to sums of {}", block.len(), self.sum.len()));
        }
        let w = self.width.max(1) as usize;
        for i in 0..self.sum.len() {
            let (s, q) = block.pixel(i);
            let bad = || format!("pixel ({}, {}): a sum of samples ({s}, squares {q}) is out of range", i % w, i / w);
            let s = quantize(s, self.sum_exponent).ok_or_else(bad)?;
            let q = quantize(q, self.sq_exponent).ok_or_else(bad)?;
            self.sum[i] = self.sum[i].checked_add(s).ok_or_else(bad)?;
            self.sum_sq[i] = self.sum_sq[i].checked_add(q).ok_or_else(bad)?;
        }
        Ok(())
    }

    /// Adds the sums of other samples of the same pixels, exactly.
    pub fn add(&mut self, other: &ExactSums) -> Result<(), String> {
        if (other.width, other.height, other.sum_exponent, other.sq_exponent)
            != (self.width, self.height, self.sum_exponent, self.sq_exponent)
        {
            return Err("sums of another size or scale".into());
        }
        for (a, b) in self.sum.iter_mut().zip(&other.sum).chain(self.sum_sq.iter_mut().zip(&other.sum_sq)) {
            *a = a.checked_add(*b).ok_or("a sum overflowed")?;
        }
        Ok(())
    }

    /// The sums as a [`Film`] of `samples` samples per pixel (each rounded once to f64).
    pub fn to_film(&self, samples: u64) -> Film {
        let (qs, qq) = (pow2(self.sum_exponent), pow2(self.sq_exponent));
        Film {
            width: self.width,
            height: self.height,
            samples,
            sum: self.sum.iter().map(|&s| s as f64 * qs).collect(),
            sum_sq: self.sum_sq.iter().map(|&q| q as f64 * qq).collect(),
        }
    }
}

/// `x` / 2^`exponent` rounded to the nearest integer (halves away from zero); `None`
/// when `x` is not finite or the result is not below 2^125 in magnitude.
fn quantize(x: f64, exponent: i32) -> Option<i128> {
    let y = (x * pow2(-exponent)).round();
    (y.abs() < pow2(MAGNITUDE_LOG2)).then_some(y as i128)
}

/// A linear value as the 8-bit sRGB code `.png` images store.
pub fn linear_to_srgb8(v: f32) -> u8 {
    (linear_to_srgb(v) * 255.0 + 0.5) as u8
}

/// The sRGB transfer function (IEC 61966-2-1), on [0, 1].
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.0031308 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}

fn encode(img: image::DynamicImage, format: image::ImageFormat) -> Result<Vec<u8>, String> {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, format).map_err(|e| e.to_string())?;
    Ok(buf.into_inner())
}

/// Greyscale PFM ("Pf"): little-endian (scale -1), rows bottom to top.
fn pfm_bytes(w: u32, h: u32, v: &[f32]) -> Vec<u8> {
    let mut out = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
    for row in v.chunks_exact(w as usize).rev() {
        for x in row {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    out
}

/// Writes `bytes` to a temporary file in the target's directory, then renames it over
/// the target, so a reader never sees a half-written file.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically_with(path, &mut |w| w.write_all(bytes))
}

/// Temporary files being written by [`write_atomically_with`], for
/// [`remove_temporary_files`].
static TEMPORARY_FILES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Streams `write`'s output to a temporary file in the target's directory (buffered),
/// syncs it, then renames it over the target: a reader sees the old file or the whole
/// new one, never a part. On failure the temporary file is removed and the target is
/// left as it was.
pub fn write_atomically_with(path: &Path, write: &mut dyn FnMut(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let err = |m: String| Error::Output { path: path.to_path_buf(), message: m };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path.file_name().ok_or_else(|| err("not a file path".into()))?.to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    lock_temporary_files().push(tmp.clone());
    let result = (|| -> std::io::Result<()> {
        let mut f = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
        write(&mut f)?;
        let f = f.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    lock_temporary_files().retain(|p| p != &tmp);
    result.map_err(|e| err(e.to_string()))
}

fn lock_temporary_files() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    // The list stays valid whatever a panicking writer left: recover it.
    TEMPORARY_FILES.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes the temporary files of writes still in progress (for a process about to exit
/// in the middle of one); returns how many were removed. Their targets are untouched.
pub fn remove_temporary_files() -> usize {
    let files = std::mem::take(&mut *lock_temporary_files());
    files.iter().filter(|p| std::fs::remove_file(p).is_ok()).count()
}
