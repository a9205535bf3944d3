//! Images of a film's per-pixel means: `.png` (8-bit, sRGB-encoded), `.exr` and `.pfm`
//! (32-bit float, linear), and of their standard errors (`.exr`, `.pfm`), written
//! atomically.

use super::policy::{write_output, write_output_with};
use crate::error::{Error, Result};
use crate::film::{ErrorEstimator, Film};
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// The image formats, by extension.
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "exr", "pfm"];

/// Writes the image; the extension picks the format: `.png` (8-bit sRGB-encoded,
/// values clamped to [0, 1]), `.exr` or `.pfm` (32-bit float, linear).
pub fn write_image(film: &Film, path: &Path) -> Result<()> {
    let mean: Vec<f32> = film.mean().into_par_iter().map(|v| v as f32).collect();
    write_values(&mean, film.width, film.height, path)
}

/// The float image formats, by extension: what [`write_error_image`] writes.
pub const FLOAT_IMAGE_EXTENSIONS: [&str; 2] = ["exr", "pfm"];

/// Writes the per-pixel standard error of the film's means ([`Film::std_error`]) as a
/// float image, `.exr` or `.pfm`; without a valid estimate (fewer than two complete
/// replicates, or one replicate of stratified or Sobol points) every pixel is infinity.
pub fn write_error_image(film: &Film, path: &Path) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if !FLOAT_IMAGE_EXTENSIONS.contains(&ext.as_str()) {
        return Err(Error::output(path, "an error image holds float values: use .exr or .pfm"));
    }
    let se: Vec<f32> = match film.error_estimator() {
        ErrorEstimator::None => vec![f32::INFINITY; film.sum.len()],
        _ => film.std_error().into_par_iter().map(|v| v as f32).collect(),
    };
    write_values(&se, film.width, film.height, path)
}

/// Writes `values`, a `w` × `h` image row by row, in the format of the extension.
fn write_values(values: &[f32], w: u32, h: u32, path: &Path) -> Result<()> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    let out_err = |m: String| Error::output(path, m);
    let mean = values;
    let bytes = match ext.as_str() {
        "png" => {
            let px: Vec<u8> = mean.par_iter().map(|&v| linear_to_srgb8(v)).collect();
            let img = image::GrayImage::from_raw(w, h, px).expect("buffer matches size");
            encode(image::DynamicImage::ImageLuma8(img), image::ImageFormat::Png).map_err(|e| out_err(e.to_string()))?
        }
        "exr" => {
            let rgb: Vec<f32> = mean.par_iter().flat_map_iter(|&v| [v, v, v]).collect();
            let img = image::Rgb32FImage::from_raw(w, h, rgb).expect("buffer matches size");
            encode(image::DynamicImage::ImageRgb32F(img), image::ImageFormat::OpenExr)
                .map_err(|e| out_err(e.to_string()))?
        }
        "pfm" => return write_output_with(path, &mut |out| write_pfm(out, w, h, mean)),
        "" => return Err(out_err("no file extension: expected .png, .exr or .pfm".into())),
        e => return Err(out_err(format!("unsupported image format '.{e}': expected .png, .exr or .pfm"))),
    };
    write_output(path, &bytes)
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

/// The encoded bytes of `img`, or the encoder's message.
pub fn encode(img: image::DynamicImage, format: image::ImageFormat) -> Result<Vec<u8>, image::ImageError> {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, format)?;
    Ok(buf.into_inner())
}

/// Greyscale PFM ("Pf"): little-endian (scale -1), rows bottom to top, streamed a row at
/// a time.
fn write_pfm(out: &mut dyn Write, w: u32, h: u32, v: &[f32]) -> std::io::Result<()> {
    write!(out, "Pf\n{w} {h}\n-1.0\n")?;
    let mut bytes = Vec::with_capacity(w as usize * 4);
    for row in v.chunks_exact(w as usize).rev() {
        bytes.clear();
        bytes.extend(row.iter().flat_map(|x| x.to_le_bytes()));
        out.write_all(&bytes)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pfm_rows_go_bottom_to_top_in_little_endian_after_the_header() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("film.pfm");
        let mut film = Film::new(3, 2);
        film.samples = 2;
        film.sum = vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        write_image(&film, &path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let header = b"Pf\n3 2\n-1.0\n";
        assert_eq!(&bytes[..header.len()], header);
        let values: Vec<f32> =
            bytes[header.len()..].chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        assert_eq!(values, [1.5, 2.0, 2.5, 0.0, 0.5, 1.0]);
    }
}
