//! What an AO ray that escapes sees, kept apart from the distribution that samples it, as
//! pbrt-v4's `AOIntegrator` keeps the integrand apart from the pdf.
//!
//! A sample's value is `f(ω) / (p(ω) E)` where it escapes: `f` the integrand (sky radiance
//! × cos θ), `p` the direction's density and `E` the normalisation. The uniform sky is
//! classic AO (`f = cos θ / π`, `E = 1`) and keeps the hemisphere's own weights
//! ([`Hemisphere::weight`]). The overcast sky is the CIE standard overcast sky (Moon &
//! Spencer 1942), `L(ω) = L_z (1 + 2 cos θ_z) / 3` above the horizon of the scene's up
//! axis, and below it a ground of albedo ρ_g lit by that sky and seen as a uniform lower
//! hemisphere, `L_g = ρ_g E_h / π`. `docs/sampling.md` derives the closed forms and the
//! horizon-clipped sampler. Every function has a twin of the same name in
//! `shaders/sampling.wgsl`.

use crate::sampling::{Hemisphere, local_to_world, orthonormal_basis, safe_sqrt, sample_uniform_disk_concentric};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Why a [`Sky`] cannot be rendered, naming the option at fault.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SkyError {
    /// The up vector is zero, not finite, or does not normalise.
    #[error("up vector must be finite and non-zero, got {},{},{}", .0.x, .0.y, .0.z)]
    Up(Vec3),
    /// The ground albedo is outside [0, 1] (or NaN).
    #[error("ground albedo must be in [0, 1], got {0}")]
    GroundAlbedo(f32),
    /// An option of the overcast sky (named) given with the uniform sky.
    #[error("a {0} needs the overcast sky (sky = overcast)")]
    NeedsOvercast(&'static str),
    /// Weighted sampling with surface normalisation: unbounded samples.
    #[error(
        "surface normalisation needs the horizon or control-variate sky sampling: weighted \
         samples of a surface facing away from the sky are unbounded"
    )]
    WeightedSurface,
}

/// The sky that lights the scene (`--sky`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SkyModel {
    /// The same radiance from every direction of the hemisphere about the normal:
    /// classic AO.
    Uniform,
    /// The CIE standard overcast sky, three times brighter at the zenith than at the
    /// horizon, over a ground of [`Sky::ground_albedo`].
    Overcast,
}

/// How the overcast sky is sampled (`--sky-sampling`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SkySampling {
    /// Directions ∝ cos θ clipped to the sky above the horizon (and the ground below it in
    /// proportion to its light), weighted by the sky's radiance: weights in [1/3, 1] of
    /// the largest.
    Horizon,
    /// [`SkySampling::Horizon`]'s directions as a control variate: the closed form of the
    /// unoccluded point less the light of the occluded directions, so that an unoccluded
    /// point is exact.
    ControlVariate,
    /// The `--hemisphere` distribution about the normal with the sky as a weight, directions
    /// below the horizon included.
    Weighted,
}

/// What the overcast sky's values are divided by (`--sky-normalise`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SkyNormalise {
    /// The irradiance of an unoccluded upward-facing surface, 7π L_z / 9: it renders its
    /// albedo, and sides render darker than tops.
    Horizontal,
    /// The irradiance of the unoccluded surface of the point's own tilt: every unoccluded
    /// point renders its albedo, as in classic AO.
    Surface,
}

macro_rules! named {
    ($t:ty, $($v:ident = $name:literal / $id:literal),+) => {
        impl $t {
            /// Every variant, in CLI order.
            pub const ALL: [$t; [$($id),+].len()] = [$(<$t>::$v),+];

            /// The name used on the command line, in scene files, checkpoints' messages and stats.
            pub fn name(self) -> &'static str {
                match self { $(<$t>::$v => $name),+ }
            }

            /// The variant called `name`.
            pub fn from_name(name: &str) -> Option<$t> {
                <$t>::ALL.into_iter().find(|v| v.name() == name)
            }

            /// The number that stands for it in checkpoints and the kernel's constants.
            pub fn code(self) -> u8 {
                match self { $(<$t>::$v => $id),+ }
            }

            /// The variant of `code`.
            pub fn from_code(code: u8) -> Option<$t> {
                <$t>::ALL.into_iter().find(|v| v.code() == code)
            }
        }
    };
}
named!(SkyModel, Uniform = "uniform" / 0, Overcast = "overcast" / 1);
named!(SkySampling, Horizon = "horizon" / 0, ControlVariate = "control-variate" / 1, Weighted = "weighted" / 2);
named!(SkyNormalise, Horizontal = "horizontal" / 0, Surface = "surface" / 1);

/// The sky of a request and how it is sampled: part of [`crate::Settings`], which the CPU
/// reference, the GPU's constants, checkpoints, statistics and Python all read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sky {
    /// The sky's radiance.
    pub model: SkyModel,
    /// The zenith, in the scene's coordinates (normalised where used; glTF's +Y by default).
    pub up: Vec3,
    /// Albedo of the ground below the horizon, in [0, 1] (0: the black ground of the lecture
    /// *Monte Carlo Integration I*).
    pub ground_albedo: f32,
    /// How the overcast sky is sampled.
    pub sampling: SkySampling,
    /// What the overcast sky's values are divided by.
    pub normalise: SkyNormalise,
}

impl Default for Sky {
    fn default() -> Self {
        Sky {
            model: SkyModel::Uniform,
            up: Vec3::Y,
            ground_albedo: 0.0,
            sampling: SkySampling::Horizon,
            normalise: SkyNormalise::Horizontal,
        }
    }
}

/// One sampled AO direction and what the sample is worth if it escapes or is blocked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkySample {
    /// The direction, in world space.
    pub w: Vec3,
    /// The sample's value where the ray escapes.
    pub open: f32,
    /// The sample's value where the ray is blocked.
    pub blocked: f32,
}

/// The kernel's `SKY` constant of the uniform sky: today's classic AO code path.
pub const SKY_UNIFORM: u32 = 0;

impl Sky {
    /// True for classic AO.
    pub fn is_uniform(&self) -> bool {
        self.model == SkyModel::Uniform
    }

    /// The kernel's `SKY` constant: [`SKY_UNIFORM`], or 1 + the sampling's code.
    pub fn shader_id(&self) -> u32 {
        match self.model {
            SkyModel::Uniform => SKY_UNIFORM,
            SkyModel::Overcast => 1 + self.sampling.code() as u32,
        }
    }

    /// The sky as messages and statistics name it: "uniform", or "overcast (up 0,1,0,
    /// ground albedo 0, horizon sampling, horizontal normalisation)".
    pub fn describe(&self) -> String {
        if self.is_uniform() {
            return self.model.name().into();
        }
        let u = self.up;
        format!(
            "{} (up {},{},{}, ground albedo {}, {} sampling, {} normalisation)",
            self.model.name(),
            u.x,
            u.y,
            u.z,
            self.ground_albedo,
            self.sampling.name(),
            self.normalise.name()
        )
    }

    /// The unit zenith (scaled by its largest component first, so that a huge or tiny
    /// vector normalises without overflow).
    pub fn unit_up(&self) -> Vec3 {
        (self.up / self.up.abs().max_element()).normalize()
    }

    /// Checks the up vector and the ground albedo, and that the overcast sky's options
    /// are not given with the uniform sky: the error names the option in one line.
    pub fn validate(&self) -> Result<(), SkyError> {
        if !self.up.is_finite() || self.up == Vec3::ZERO || !self.unit_up().is_finite() {
            return Err(SkyError::Up(self.up));
        }
        if !(0.0..=1.0).contains(&self.ground_albedo) {
            return Err(SkyError::GroundAlbedo(self.ground_albedo));
        }
        if self.is_uniform() {
            let given = [
                (self.ground_albedo != 0.0, "ground albedo"),
                (self.normalise != SkyNormalise::Horizontal, "sky normalisation"),
                (self.sampling != SkySampling::Horizon, "sky sampling"),
            ];
            if let Some((_, option)) = given.into_iter().find(|g| g.0) {
                return Err(SkyError::NeedsOvercast(option));
            }
        }
        if self.sampling == SkySampling::Weighted && self.normalise == SkyNormalise::Surface {
            return Err(SkyError::WeightedSurface);
        }
        Ok(())
    }

    /// The largest magnitude of a sample at albedo 1: 2 for the uniform sky (the uniform
    /// hemisphere's 2 cos θ); for the overcast sky, three times the largest irradiance
    /// ratio (`docs/sampling.md`), 3 (1 + ρ_g).
    pub fn max_weight(&self) -> f64 {
        match self.model {
            SkyModel::Uniform => 2.0,
            SkyModel::Overcast => 3.0 * (1.0 + self.ground_albedo as f64),
        }
    }

    /// The direction and values of sample `u` about the unit normal `n` with the
    /// hemisphere distribution `hemisphere` (used by the uniform sky and
    /// [`SkySampling::Weighted`]).
    pub fn sample(&self, hemisphere: Hemisphere, n: Vec3, u: Vec2) -> SkySample {
        if self.is_uniform() {
            let w_local = hemisphere.sample(u);
            return SkySample { w: local_to_world(w_local, n), open: hemisphere.weight(w_local), blocked: 0.0 };
        }
        sample_overcast(
            self.shader_id(),
            self.normalise.code() as u32,
            self.unit_up(),
            self.ground_albedo,
            hemisphere,
            n,
            u,
        )
    }
}

/// E(β) / E_h: the overcast sky's irradiance of an unoccluded plane whose normal is at
/// `cos_beta` from the zenith, over that of an upward-facing one (black ground):
/// [3π(1 + cos β) + 8((π − β) cos β + sin β)] / (14π). β comes from [`acos_poly`], not
/// the platform's `acos`, whose error on lavapipe (about 10⁻⁵) would show in the control
/// variate's exact values.
pub fn overcast_plane(cos_beta: f32) -> f32 {
    let c = cos_beta.clamp(-1.0, 1.0);
    let a = acos_poly(c.abs());
    let pi_minus_beta = if c >= 0.0 { PI - a } else { a };
    let s = safe_sqrt(1.0 - c * c);
    (3.0 * PI * (1.0 + c) + 8.0 * (pi_minus_beta * c + s)) / (14.0 * PI)
}

/// acos x for x in [0, 1], within 2·10⁻⁸ before rounding: Abramowitz & Stegun 4.4.46,
/// √(1 − x) times a degree-7 polynomial.
// The published coefficients as printed; each rounds to the nearest f32, as in WGSL.
#[allow(clippy::excessive_precision)]
pub fn acos_poly(x: f32) -> f32 {
    let p = -0.001_262_491_1f32;
    let p = p * x + 0.006_670_090_1;
    let p = p * x - 0.017_088_125_6;
    let p = p * x + 0.030_891_881_0;
    let p = p * x - 0.050_174_304_6;
    let p = p * x + 0.088_978_987_4;
    let p = p * x - 0.214_598_801_6;
    let p = p * x + 1.570_796_305_0;
    safe_sqrt(1.0 - x) * p
}

/// [`overcast_plane`] in f64, for tests' expected values.
pub fn overcast_plane_f64(cos_beta: f64) -> f64 {
    use std::f64::consts::PI;
    let c = cos_beta.clamp(-1.0, 1.0);
    let beta = c.acos();
    (3.0 * PI * (1.0 + c) + 8.0 * ((PI - beta) * c + (1.0 - c * c).max(0.0).sqrt())) / (14.0 * PI)
}

/// The overcast sky's radiance at `z` = cos θ_z above the horizon, L_z = 1.
pub fn overcast_radiance(z: f32) -> f32 {
    (1.0 + 2.0 * z.max(0.0)) / 3.0
}

/// A sample of the overcast sky (`sky` the kernel's `SKY`, `normalise` the
/// [`SkyNormalise`] code, `up` the unit zenith) about the unit normal `n`. The twin of
/// `sample_overcast` in `shaders/sampling.wgsl`.
pub fn sample_overcast(
    sky: u32,
    normalise: u32,
    up: Vec3,
    ground_albedo: f32,
    hemisphere: Hemisphere,
    n: Vec3,
    u: Vec2,
) -> SkySample {
    let c = n.dot(up).clamp(-1.0, 1.0);
    // Irradiances over E_h = 7π/9 (L_z = 1): the sky's, the ground's, their sum.
    let e_sky = overcast_plane(c);
    let ground = ground_albedo * (7.0 / 9.0);
    let e_ground = ground_albedo * 0.5 * (1.0 - c);
    let e_total = e_sky + e_ground;
    // f / p times this is the sample's value.
    let scale = if normalise == SkyNormalise::Surface.code() as u32 {
        if e_total > 0.0 { 9.0 / (7.0 * PI * e_total) } else { 0.0 }
    } else {
        9.0 / (7.0 * PI)
    };
    let closed =
        if normalise == SkyNormalise::Surface.code() as u32 { if e_total > 0.0 { 1.0 } else { 0.0 } } else { e_total };
    if sky == 1 + SkySampling::Weighted.code() as u32 {
        let w_local = hemisphere.sample(u);
        let w = local_to_world(w_local, n);
        let z = w.dot(up);
        let radiance = if z > 0.0 { overcast_radiance(z) } else { ground };
        // weight = cos θ / (π p): f / p = π L weight.
        return SkySample { w, open: PI * radiance * hemisphere.weight(w_local) * scale, blocked: 0.0 };
    }
    // The sky's share of the directions: 1 over a black ground.
    let a = if e_ground > 0.0 { e_sky / e_total } else { 1.0 };
    // t1: −up in the tangent plane; any tangent where n is parallel to up.
    let v = c * n - up;
    let len = v.length();
    let t1 = if len > 1e-6 { v / len } else { orthonormal_basis(n).0 };
    let t2 = n.cross(t1);
    let d = sample_uniform_disk_concentric(u);
    let s = safe_sqrt((1.0 - d.y) * (1.0 + d.y));
    let split = -s + 2.0 * a * s;
    let upper = a > 0.0 && (a >= 1.0 || d.x <= split);
    // Squeeze the disk's row [−s, s] onto the sky's [−s, c s] (x ≤ split) and the ground's
    // [c s, s]: uniform on the projected disk in each part, so p ∝ cos θ there. The height
    // is √((s − x)(s + x)) with s + x kept exact at the limb, not √(1 − x² − y²), whose
    // rounding there would tip directions below the horizon.
    let (x, s_plus_x, f_over_p) = if upper {
        let k = (1.0 + c) / (2.0 * a);
        let s_plus_x = (d.x + s) * k;
        (s_plus_x - s, s_plus_x, PI * k)
    } else {
        let k = (1.0 - c) / (2.0 * (1.0 - a));
        let x = c * s + (d.x - split) * k;
        (x, x + s, PI * k * ground)
    };
    let h = safe_sqrt((s - x) * s_plus_x);
    let w = x * t1 + d.y * t2 + h * n;
    let f_over_p = if upper { f_over_p * overcast_radiance(w.dot(up)) } else { f_over_p };
    let value = f_over_p * scale;
    if sky == 1 + SkySampling::ControlVariate.code() as u32 {
        SkySample { w, open: closed, blocked: closed - value }
    } else {
        SkySample { w, open: value, blocked: 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plane_table_holds() {
        // The published values of E(β)/E_h.
        for (deg, v) in [
            (0.0, 1.0),
            (30.0, 0.90320),
            (45.0, 0.79747),
            (60.0, 0.66943),
            (90.0, 0.39618),
            (120.0, 0.16943),
            (150.0, 0.03718),
            (180.0, 0.0),
        ] {
            let c = f64::to_radians(deg).cos();
            assert!((overcast_plane_f64(c) - v).abs() < 5e-6, "{deg}°: {}", overcast_plane_f64(c));
            assert!((overcast_plane(c as f32) as f64 - v).abs() < 1e-5, "{deg}° f32");
        }
    }

    #[test]
    fn acos_poly_is_acos() {
        for i in 0..=10_000 {
            let x = i as f32 / 10_000.0;
            // 2e-8 from the polynomial, then a few f32 roundings of values up to π/2.
            assert!((acos_poly(x) as f64 - (x as f64).acos()).abs() < 4e-7, "{x}");
        }
    }

    #[test]
    fn huge_and_tiny_up_vectors_normalise() {
        for up in [Vec3::splat(1e30), Vec3::new(1e-45, 0.0, 0.0), Vec3::new(0.0, 3.0, 4.0)] {
            let sky = Sky { model: SkyModel::Overcast, up, ..Sky::default() };
            assert_eq!(sky.validate(), Ok(()));
            assert!((sky.unit_up().length() - 1.0).abs() < 1e-6, "{up}");
        }
    }

    #[test]
    fn validation_names_the_option() {
        let ok = Sky { model: SkyModel::Overcast, ..Sky::default() };
        assert_eq!(ok.validate(), Ok(()));
        let cases = [
            (Sky { up: Vec3::ZERO, ..ok }, "up vector"),
            (Sky { up: Vec3::new(f32::NAN, 1.0, 0.0), ..ok }, "up vector"),
            (Sky { up: Vec3::new(f32::INFINITY, 1.0, 0.0), ..ok }, "up vector"),
            (Sky { up: Vec3::new(0.0, -0.0, 0.0), ..ok }, "up vector"),
            (Sky { ground_albedo: 1.5, ..ok }, "ground albedo"),
            (Sky { ground_albedo: f32::NAN, ..ok }, "ground albedo"),
            (Sky { ground_albedo: -0.1, ..ok }, "ground albedo"),
            (Sky { normalise: SkyNormalise::Surface, ..Sky::default() }, "needs the overcast sky"),
            (Sky { ground_albedo: 0.5, ..Sky::default() }, "needs the overcast sky"),
            (Sky { sampling: SkySampling::Weighted, normalise: SkyNormalise::Surface, ..ok }, "surface normalisation"),
        ];
        for (sky, word) in cases {
            let e = sky.validate().expect_err("invalid").to_string();
            assert!(e.contains(word) && !e.contains('\n'), "{sky:?}: {e}");
        }
    }

    /// Normals at every β of the table and below the horizon, about a tilted up axis.
    fn normals(up: Vec3) -> Vec<Vec3> {
        let (t, _) = orthonormal_basis(up);
        [0.0f32, 30.0, 45.0, 60.0, 90.0, 120.0, 150.0, 180.0]
            .iter()
            .map(|d| (d.to_radians().cos() * up + d.to_radians().sin() * t).normalize())
            .collect()
    }

    #[test]
    fn horizon_samples_stay_above_the_horizon_and_are_bounded() {
        let up = Vec3::new(0.2, 0.9, -0.3).normalize();
        for ground in [0.0, 0.4, 1.0] {
            for n in normals(up) {
                for sampling in SkySampling::ALL {
                    for normalise in SkyNormalise::ALL {
                        let sky = Sky { model: SkyModel::Overcast, up, ground_albedo: ground, sampling, normalise };
                        if sky.validate().is_err() {
                            continue;
                        }
                        for i in 0..64u32 {
                            for j in 0..64u32 {
                                let u = Vec2::new(i as f32 / 64.0, j as f32 / 64.0);
                                let s = sky.sample(Hemisphere::Uniform, n, u);
                                assert!((s.w.length() - 1.0).abs() < 1e-4 && s.w.dot(n) >= -1e-6, "{n} {u}: {:?}", s.w);
                                let bound = sky.max_weight() as f32;
                                assert!(s.open.abs() <= bound && s.blocked.abs() <= bound, "{sky:?} {n}: {s:?}");
                                if ground == 0.0 && sampling != SkySampling::Weighted {
                                    assert!(s.w.dot(up) >= -1e-5, "{n} {u}: below the horizon {}", s.w.dot(up));
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn unoccluded_means_match_the_closed_form() {
        // A 256² grid of u: a deterministic quadrature of each estimator.
        let up = Vec3::new(0.0, 0.0, 1.0);
        for ground in [0.0f32, 0.6] {
            for n in normals(up) {
                let c = n.dot(up) as f64;
                let expected = overcast_plane_f64(c) + ground as f64 * 0.5 * (1.0 - c);
                for sampling in SkySampling::ALL {
                    let sky = Sky { model: SkyModel::Overcast, up, ground_albedo: ground, sampling, ..Sky::default() };
                    let m = 256;
                    let mut sum = 0.0f64;
                    for i in 0..m {
                        for j in 0..m {
                            let u = Vec2::new((i as f32 + 0.5) / m as f32, (j as f32 + 0.5) / m as f32);
                            sum += sky.sample(Hemisphere::Cosine, n, u).open as f64;
                        }
                    }
                    let mean = sum / (m * m) as f64;
                    assert!((mean - expected).abs() < 2e-3, "{sampling:?} ground {ground} β {c}: {mean} vs {expected}");
                }
            }
        }
    }
}
