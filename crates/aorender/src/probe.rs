//! AO at given points and normals: the hemisphere integral without a camera, for closed
//! forms at exact locations and for baking AO into vertices and textures.
//!
//! A probe is a position and a normal; its value is 1/π ∫ V(x, ω) cos θ dω over the
//! hemisphere around the normal (albedo 1), estimated with a request's hemisphere
//! distribution, sampler, seed and maximum distance. The AO rays start at the position,
//! pushed off its surface by the probe's error bound (zero for a point given exactly on
//! its surface: a ray that starts on a triangle never hits it), along the surface's own
//! normal where the probe knows it. A probe whose normal is not its surface's (an
//! interpolated vertex normal) samples the hemisphere about its normal, and a direction
//! that leaves below the surface is mirrored above it, so the surface the point lies on
//! never occludes it. Sample `i` of probe `k` uses the
//! sampler's numbers for pixel `(k, 0)` and index `i`, on the GPU and on the CPU reference
//! alike; on either device a probe's samples are spread over several slots (lanes), and
//! slot sums are added exactly.

use crate::error::{Error, Result};
use crate::film::{Film, standard_error};
use glam::Vec3;
use rayon::prelude::*;

/// A point and the normal of its hemisphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    /// Position.
    pub position: Vec3,
    /// Unit normal: the hemisphere sampled.
    pub normal: Vec3,
    /// Bound on the distance between `position` and the surface the probe lies on, along
    /// `surface_normal` (along `normal` where that is zero); zero when it is exactly on
    /// it: the AO rays start that far off.
    pub error: f32,
    /// Unit normal of the surface the probe lies on, on the side of `normal`, where it
    /// differs from `normal` (an interpolated normal, a normal given with a point found
    /// on a surface); zero where it is unknown or is `normal` itself. Rays start off the
    /// surface along it, and a direction below the surface is mirrored above it.
    pub surface_normal: Vec3,
}

impl Probe {
    /// A probe; the normal is normalised. [`Error::Probe`] (with index 0) names the
    /// problem: a non-finite coordinate or a zero normal.
    pub fn new(position: Vec3, normal: Vec3) -> Result<Probe> {
        let bad = |message: &str| Error::Probe { index: 0, message: message.into() };
        if !position.is_finite() || !normal.is_finite() {
            return Err(bad("non-finite coordinate"));
        }
        let len = normal.length();
        if !(len > 0.0 && len.is_finite()) {
            return Err(bad("zero normal"));
        }
        Ok(Probe { position, normal: normal / len, error: 0.0, surface_normal: Vec3::ZERO })
    }

    /// [`Probe::new`] for a position within `error` of its surface along the normal (a
    /// vertex carried into the world by an instance's transform, for example). A negative
    /// or non-finite bound is refused.
    pub fn with_error(position: Vec3, normal: Vec3, error: f32) -> Result<Probe> {
        if !(error.is_finite() && error >= 0.0) {
            return Err(Error::Probe {
                index: 0,
                message: format!("error bound must be finite and non-negative, got {error}"),
            });
        }
        Ok(Probe { error, ..Probe::new(position, normal)? })
    }

    /// [`Probe::with_error`] for a point on a surface whose unit normal is
    /// `surface_normal` (turned to the side of `normal` here), `error` bounding the
    /// distance along it. A surface normal that is not finite or not of unit length
    /// (within 10⁻⁴) is refused.
    pub fn on_surface(position: Vec3, normal: Vec3, surface_normal: Vec3, error: f32) -> Result<Probe> {
        let probe = Probe::with_error(position, normal, error)?;
        let len = surface_normal.length();
        if !(surface_normal.is_finite() && (len - 1.0).abs() <= 1e-4) {
            return Err(Error::Probe {
                index: 0,
                message: format!("surface normal must be a unit vector, got {surface_normal}"),
            });
        }
        let g = if surface_normal.dot(probe.normal) < 0.0 { -surface_normal } else { surface_normal };
        Ok(Probe { surface_normal: if g == probe.normal { Vec3::ZERO } else { g }, ..probe })
    }
}

/// The probes checked, with unit normals however they were given (what a request traces):
/// [`Error::Probe`] names the first bad one.
pub fn checked(probes: &[Probe]) -> Result<Vec<Probe>> {
    let check = |(index, p): (usize, &Probe)| {
        let checked = match p.surface_normal {
            Vec3::ZERO => Probe::with_error(p.position, p.normal, p.error),
            g => Probe::on_surface(p.position, p.normal, g, p.error),
        };
        checked.map_err(|e| Error::Probe { index, message: e.message() })
    };
    // Over threads, which may stop at any bad probe: the error names the first.
    probes
        .par_iter()
        .enumerate()
        .map(check)
        .collect::<Result<Vec<Probe>>>()
        .map_err(|e| probes.iter().enumerate().map(check).find_map(|r| r.err()).unwrap_or(e))
}

/// The estimate at one probe.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ProbeValue {
    /// Mean of the samples.
    pub mean: f64,
    /// Standard error of the mean, from the sample variance (an overestimate for the
    /// stratified and Sobol samplers).
    pub std_error: f64,
    /// Samples taken.
    pub samples: u64,
}

impl ProbeValue {
    /// Mean and standard error of `n` samples whose sum is `sum` and sum of squares
    /// `sum_sq`.
    pub fn from_sums(sum: f64, sum_sq: f64, n: u64) -> ProbeValue {
        let nf = n as f64;
        let mean = sum / nf;
        let var = if n > 1 { ((sum_sq - nf * mean * mean) / (nf - 1.0)).max(0.0) } else { 0.0 };
        ProbeValue { mean, std_error: (var / nf).sqrt(), samples: n }
    }
}

/// The estimates of a film of `Session::probe_render`, one slot a point or four (with
/// bent normals, the AO first): each point's AO.
pub fn probe_film_values(film: &Film) -> Vec<ProbeValue> {
    let stride = film.width as usize;
    let estimator = film.error_estimator().or_samples();
    (0..film.height as usize)
        .map(|k| {
            let (sum, sum_sq) = (film.sum[k * stride], film.sum_sq[k * stride]);
            let r = film.replicate_sq.get(k).copied().unwrap_or(0.0);
            let mut value = ProbeValue::from_sums(sum, sum_sq, film.samples);
            value.std_error = standard_error(estimator, film.samples, sum, sum_sq, r);
            value
        })
        .collect()
}

/// The bent normals of a film of `Session::probe_render` with bent normals (four slots a
/// point): the mean direction of the rays that escaped, zero where none did; `None` for
/// a film without them.
pub fn probe_film_bent_normals(film: &Film) -> Option<Vec<Vec3>> {
    (film.width == 4).then(|| {
        let n = film.samples.max(1) as f64;
        film.sum.chunks_exact(4).map(|s| Vec3::new((s[1] / n) as f32, (s[2] / n) as f32, (s[3] / n) as f32)).collect()
    })
}

/// Film slots the probe kernel aims to keep busy per dispatch: points × lanes.
pub const TARGET_SLOTS: u32 = 1 << 16;

/// Lanes per probe: enough slots to fill the device, at most one per sample, a power of
/// two (so that lanes and replicates of a power-of-two size tile each other).
pub fn lanes_for(points: usize, samples: u32) -> u32 {
    let lanes = (TARGET_SLOTS / points.max(1) as u32).clamp(1, samples.max(1));
    1 << lanes.ilog2()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lanes_fill_the_device_without_exceeding_samples() {
        assert_eq!(lanes_for(1, 1 << 20), TARGET_SLOTS);
        assert_eq!(lanes_for(1, 100), 64);
        assert_eq!(lanes_for(1 << 20, 1000), 1);
        assert_eq!(lanes_for(64, 1 << 20), TARGET_SLOTS / 64);
    }

    #[test]
    fn sums_give_mean_and_standard_error() {
        // Samples 0, 1, 1, 0: mean 1/2, variance 1/3, standard error √(1/12).
        let v = ProbeValue::from_sums(2.0, 2.0, 4);
        assert_eq!(v.mean, 0.5);
        assert!((v.std_error - (1.0f64 / 12.0).sqrt()).abs() < 1e-15);
    }

    #[test]
    fn bad_probes_are_refused() {
        assert!(Probe::new(Vec3::ZERO, Vec3::ZERO).unwrap_err().to_string().contains("zero normal"));
        assert!(Probe::new(Vec3::NAN, Vec3::Z).unwrap_err().to_string().contains("non-finite"));
        assert_eq!(Probe::new(Vec3::ONE, Vec3::new(0.0, 0.0, 2.0)).unwrap().normal, Vec3::Z);
        let tilted = Vec3::new(0.0, 0.6, 0.8);
        assert!(Probe::on_surface(Vec3::ONE, Vec3::Z, Vec3::new(0.0, 0.0, 2.0), 0.0).is_err());
        assert!(Probe::on_surface(Vec3::ONE, Vec3::Z, Vec3::NAN, 0.0).is_err());
        assert!(Probe::on_surface(Vec3::ONE, Vec3::Z, tilted, -1.0).is_err());
    }

    #[test]
    fn checked_probes_name_the_first_bad_one_on_any_number_of_threads() {
        let good = |i: usize| Probe {
            position: Vec3::splat(i as f32),
            normal: Vec3::new(0.0, 0.0, 3.0),
            error: 1e-6,
            surface_normal: Vec3::ZERO,
        };
        let mut probes: Vec<Probe> = (0..200_000).map(good).collect();
        let normalised: Vec<Probe> =
            probes.iter().map(|p| Probe::with_error(p.position, p.normal, p.error).unwrap()).collect();
        assert_eq!(normalised[7].normal, Vec3::Z);
        // Bad ones late in the list, the first of them after a thread's share would start.
        for (k, bad) in [(150_001, Vec3::ZERO), (199_999, Vec3::NAN), (150_007, Vec3::ZERO)] {
            probes[k].normal = bad;
        }
        for threads in [1, 2, 7] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
            let err = pool.install(|| checked(&probes)).unwrap_err();
            assert!(matches!(err, Error::Probe { index: 150_001, .. }), "{threads} threads: {err}");
            assert_eq!(pool.install(|| checked(&normalised[..150_000])).unwrap(), normalised[..150_000]);
            assert_eq!(pool.install(|| checked(&probes[..150_000])).unwrap(), normalised[..150_000]);
        }
    }

    #[test]
    fn surface_normals_face_the_probes_side() {
        let g = Vec3::new(0.0, 0.6, -0.8);
        assert_eq!(Probe::on_surface(Vec3::ONE, Vec3::Z, g, 1e-6).unwrap().surface_normal, -g);
        assert_eq!(Probe::on_surface(Vec3::ONE, -Vec3::Z, g, 1e-6).unwrap().surface_normal, g);
        // The probe's own normal: nothing to mirror about, the offset along the normal.
        assert_eq!(Probe::on_surface(Vec3::ONE, Vec3::Z, -Vec3::Z, 1e-6).unwrap().surface_normal, Vec3::ZERO);
        let p = Probe::on_surface(Vec3::ONE, Vec3::Z, g, 1e-6).unwrap();
        assert_eq!(checked(&[p]).unwrap()[0], p);
    }
}
