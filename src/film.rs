//! Accumulation (per-pixel sums of sample values and their squares), statistics, and
//! image outputs written atomically (to a temporary file beside the target, then renamed).

use crate::error::{Error, Result};
use std::io::Write;
use std::path::Path;

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
    let err = |m: String| Error::Output { path: path.to_path_buf(), message: m };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path.file_name().ok_or_else(|| err("not a file path".into()))?.to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(err(e.to_string()));
    }
    Ok(())
}
