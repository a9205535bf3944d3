//! The on-disk cache of converged references, keyed by a hash of everything the image
//! depends on: the scene's geometry (so the mesh files' contents, as loaded), camera and
//! view settings, and the reference's own sampling.

use super::metrics::Reference;
use anyhow::{Context, Result};
use aorender::{Scene, scene_hash};
use std::path::{Path, PathBuf};

/// First bytes of a reference file; the number changes with the layout or the meaning.
const MAGIC: &[u8; 8] = b"AOREF003";

/// How a reference is sampled (all that the key needs besides the scene).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReferenceSampling {
    /// Samples per pixel.
    pub samples: u32,
    /// Seed, different from the benchmark's.
    pub seed: u32,
}

/// The cache key of `scene`'s reference: a BLAKE3 hash, in hex, of the crate version,
/// the image size, distance limit and background, `sampling`, and the scene's geometry and
/// camera (`aorender::scene_hash`: every float by its bits, so the mesh files' contents as
/// loaded), and an overcast sky. The scene's own spp, hemisphere, sampler, sky sampling and
/// seed do not enter: every unbiased configuration converges to the same image.
pub fn key(scene: &Scene, sampling: ReferenceSampling) -> String {
    let mut h = blake3::Hasher::new();
    h.update(MAGIC);
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    let s = &scene.settings;
    h.update(&s.width.to_le_bytes());
    h.update(&s.height.to_le_bytes());
    h.update(&s.sampling.max_distance.map_or(u32::MAX, f32::to_bits).to_le_bytes());
    h.update(&s.background.to_bits().to_le_bytes());
    // The overcast sky changes the image (its sampling does not); the uniform sky keeps the
    // keys it had before there were skies.
    if !s.sampling.sky.is_uniform() {
        let k = &s.sampling.sky;
        h.update(&[k.model.code(), k.normalise.code()]);
        for v in k.up.to_array().into_iter().chain([k.ground_albedo]) {
            h.update(&v.to_bits().to_le_bytes());
        }
    }
    h.update(&sampling.samples.to_le_bytes());
    h.update(&sampling.seed.to_le_bytes());
    h.update(&scene_hash(scene, &scene.camera));
    h.finalize().to_hex()[..32].to_string()
}

/// The file of a scene's reference in `dir`.
pub fn path(dir: &Path, scene: &Scene, key: &str) -> PathBuf {
    let name: String =
        scene.name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
    dir.join(format!("{name}-{key}.aoref"))
}

/// A reference as stored: the image and how long it took.
#[derive(Clone, Debug, PartialEq)]
pub struct Stored {
    /// The image.
    pub reference: Reference,
    /// Seconds it took to render.
    pub seconds: f64,
    /// Where it was rendered ("gpu: adapter" or "cpu").
    pub device: String,
}

/// Little-endian: magic, width, height (u32), samples (u64), seconds (f64), device name
/// length (u32) and bytes, then the per-pixel means and variances (f64 each).
pub fn encode(stored: &Stored) -> Vec<u8> {
    let r = &stored.reference;
    let mut out = Vec::with_capacity(40 + stored.device.len() + 16 * r.mean.len());
    out.extend_from_slice(MAGIC);
    out.extend(r.width.to_le_bytes());
    out.extend(r.height.to_le_bytes());
    out.extend(r.samples.to_le_bytes());
    out.extend(stored.seconds.to_le_bytes());
    out.extend((stored.device.len() as u32).to_le_bytes());
    out.extend(stored.device.as_bytes());
    for v in r.mean.iter().chain(&r.variance) {
        out.extend(v.to_le_bytes());
    }
    out
}

/// Why a stored reference cannot be used (it is then rendered again and replaced).
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// The file could not be read.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The file ends at this byte, before its data does.
    #[error("truncated at byte {0}")]
    Truncated(usize),
    /// The file does not start with this version's magic.
    #[error("not a reference file of this version")]
    Version,
    /// The adapter's name is not UTF-8.
    #[error("device name is not UTF-8")]
    DeviceName,
    /// Bytes after the image.
    #[error("{0} bytes past the end of the image")]
    Trailing(usize),
    /// A mean or variance that no render makes.
    #[error("non-finite value or negative variance")]
    Values,
    /// A reference of another size or sample count than the one asked for.
    #[error("holds {}x{} at {} spp, expected {}x{} at {}", held.0, held.1, held.2, expected.0, expected.1, expected.2)]
    Size {
        /// Its width, height and samples.
        held: (u32, u32, u64),
        /// The width, height and samples asked for.
        expected: (u32, u32, u32),
    },
}

/// Parses [`encode`]'s bytes.
pub fn decode(bytes: &[u8]) -> std::result::Result<Stored, CacheError> {
    let mut at = 0usize;
    let mut take = |n: usize| -> std::result::Result<&[u8], CacheError> {
        let s = bytes.get(at..at + n).ok_or(CacheError::Truncated(at))?;
        at += n;
        Ok(s)
    };
    if take(8)? != MAGIC {
        return Err(CacheError::Version);
    }
    let u32_at = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    let width = u32_at(take(4)?);
    let height = u32_at(take(4)?);
    let samples = u64::from_le_bytes(take(8)?.try_into().expect("8 bytes"));
    let seconds = f64::from_le_bytes(take(8)?.try_into().expect("8 bytes"));
    let name_len = u32_at(take(4)?) as usize;
    let device = String::from_utf8(take(name_len)?.to_vec()).map_err(|_| CacheError::DeviceName)?;
    let pixels = width as usize * height as usize;
    let mut floats = |n: usize| -> std::result::Result<Vec<f64>, CacheError> {
        Ok(take(8 * n)?.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect())
    };
    let mean = floats(pixels)?;
    let variance = floats(pixels)?;
    if at != bytes.len() {
        return Err(CacheError::Trailing(bytes.len() - at));
    }
    if mean.iter().chain(&variance).any(|v| !v.is_finite()) || variance.iter().any(|&v| v < 0.0) {
        return Err(CacheError::Values);
    }
    Ok(Stored { reference: Reference { width, height, samples, mean, variance }, seconds, device })
}

/// The stored reference at `path`: `Ok(None)` when there is none, `Err` with the reason
/// when the file is there but unusable (it is then rendered again and replaced).
pub fn load(path: &Path, width: u32, height: u32, samples: u32) -> std::result::Result<Option<Stored>, CacheError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e.into()),
    };
    let stored = decode(&bytes)?;
    let r = &stored.reference;
    if (r.width, r.height, r.samples) != (width, height, samples as u64) {
        return Err(CacheError::Size { held: (r.width, r.height, r.samples), expected: (width, height, samples) });
    }
    Ok(Some(stored))
}

/// Writes `stored` to `path` atomically, creating its directory.
pub fn save(path: &Path, stored: &Stored) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the directory", dir.display()))?;
    }
    aorender::output::write_output(path, &encode(stored))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stored() -> Stored {
        Stored {
            reference: Reference {
                width: 3,
                height: 2,
                samples: 4096,
                mean: vec![0.0, 0.25, 0.5, 0.75, 1.0, 0.125],
                variance: vec![0.0, 1e-5, 2e-5, 3e-5, 0.0, 5e-6],
            },
            seconds: 12.5,
            device: "cpu".into(),
        }
    }

    #[test]
    fn a_reference_round_trips_and_damage_is_refused() {
        let s = stored();
        let bytes = encode(&s);
        assert_eq!(decode(&bytes).unwrap(), s);
        assert!(decode(&bytes[..bytes.len() - 1]).unwrap_err().to_string().contains("truncated"));
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(decode(&longer).unwrap_err().to_string().contains("past the end"));
        let mut other = bytes.clone();
        other[7] ^= 1;
        assert!(decode(&other).unwrap_err().to_string().contains("version"));
    }

    #[test]
    fn load_checks_the_size_and_tells_a_missing_file_from_a_bad_one() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.aoref");
        assert_eq!(load(&p, 3, 2, 4096).ok(), Some(None));
        save(&p, &stored()).unwrap();
        assert_eq!(load(&p, 3, 2, 4096).unwrap().unwrap(), stored());
        assert!(load(&p, 3, 2, 1024).unwrap_err().to_string().contains("expected 3x2 at 1024"));
        std::fs::write(&p, b"junk").unwrap();
        assert!(load(&p, 3, 2, 4096).is_err());
    }

    /// The key changes with the geometry, the view and the reference's sampling, and not
    /// with the settings the benchmark varies.
    #[test]
    fn the_key_follows_what_the_image_depends_on() {
        let base = Scene::default_scene();
        let sampling = ReferenceSampling { samples: 1024, seed: 1 };
        let k = key(&base, sampling);
        let mut same = base.clone();
        same.settings.spp = 7;
        same.settings.sampling.seed = 99;
        same.settings.sampling.sampler = aorender::Sampler::Sobol;
        same.settings.sampling.hemisphere = aorender::Hemisphere::Uniform;
        assert_eq!(key(&same, sampling), k);
        let overcast = aorender::Sky { model: aorender::SkyModel::Overcast, ..aorender::Sky::default() };
        let mut sky = base.clone();
        sky.settings.sampling.sky = overcast;
        let ks = key(&sky, sampling);
        assert_ne!(ks, k, "the sky changes the image");
        sky.settings.sampling.sky.sampling = aorender::SkySampling::ControlVariate;
        assert_eq!(key(&sky, sampling), ks, "the sky's sampling does not");
        sky.settings.sampling.sky.ground_albedo = 0.5;
        assert_ne!(key(&sky, sampling), ks, "the ground does");
        let mut changes: Vec<Scene> = Vec::new();
        let mut s = base.clone();
        s.spheres[0].radius = f32::from_bits(s.spheres[0].radius.to_bits() + 1);
        changes.push(s);
        let mut s = base.clone();
        s.settings.width += 1;
        changes.push(s);
        let mut s = base.clone();
        s.settings.sampling.max_distance = Some(1.0);
        changes.push(s);
        let mut s = base.clone();
        s.camera.eye.y += 0.5;
        changes.push(s);
        for s in &changes {
            assert_ne!(key(s, sampling), k);
        }
        assert_ne!(key(&base, ReferenceSampling { samples: 2048, seed: 1 }), k);
        assert_ne!(key(&base, ReferenceSampling { samples: 1024, seed: 2 }), k);
    }
}
