//! Random numbers, hemisphere warps and shading frames.
//!
//! Every function here has a twin of the same name in `shaders/sampling.wgsl`; the
//! parity tests run both on the same inputs. Warps come as sample / pdf / inverse
//! (pbrt-v4, `util/sampling.h`), take `u ∈ [0,1)²`, and guard their square roots so
//! that `u` exactly 0 or the largest float below 1 never gives NaN.

use glam::{UVec4, Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, FRAC_PI_2, FRAC_PI_4, PI};

/// The 4-D PCG hash of Jarzynski & Olano, "Hash Functions for GPU Rendering" (JCGT 2020).
pub fn pcg4d(v: UVec4) -> UVec4 {
    let mut v = v * 1664525u32 + UVec4::splat(1013904223u32);
    v.x = v.x.wrapping_add(v.y.wrapping_mul(v.w));
    v.y = v.y.wrapping_add(v.z.wrapping_mul(v.x));
    v.z = v.z.wrapping_add(v.x.wrapping_mul(v.y));
    v.w = v.w.wrapping_add(v.y.wrapping_mul(v.z));
    v ^= v >> 16;
    v.x = v.x.wrapping_add(v.y.wrapping_mul(v.w));
    v.y = v.y.wrapping_add(v.z.wrapping_mul(v.x));
    v.z = v.z.wrapping_add(v.x.wrapping_mul(v.y));
    v.w = v.w.wrapping_add(v.y.wrapping_mul(v.z));
    v
}

/// Maps 32 random bits to a float in [0, 1) using the top 24 bits; the largest value
/// is `1 - 2^-24`, the largest `f32` below one.
pub fn u32_to_unit_float(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16777216.0)
}

/// The four uniform numbers of sample `sample_index` of pixel `(px, py)`: a pure
/// function of (pixel, sample index, seed), so a render is reproducible and any
/// range of sample indices can be rendered on its own.
pub fn sample_uniforms(px: u32, py: u32, sample_index: u32, seed: u32) -> [f32; 4] {
    let h = pcg4d(UVec4::new(px, py, sample_index, seed));
    [u32_to_unit_float(h.x), u32_to_unit_float(h.y), u32_to_unit_float(h.z), u32_to_unit_float(h.w)]
}

/// `sqrt(max(x, 0))`: rounding can make `1 - z²` slightly negative.
pub fn safe_sqrt(x: f32) -> f32 {
    x.max(0.0).sqrt()
}

/// Hemisphere distribution of AO directions (`--hemisphere`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Hemisphere {
    /// p(ω) = 1/2π; estimator 2ρ V cos θ.
    Uniform,
    /// p(ω) = cos θ/π via the concentric disk mapping; estimator ρ V.
    Cosine,
    /// p(ω) = cos θ/π via the polar disk mapping (r = √ξ₁, φ = 2πξ₂), the literal method of
    /// the lecture *Monte Carlo Integration I* (Nowrouzezahrai, ECSE 446/546, McGill); same
    /// estimator as `Cosine`, but it stretches the square's strata.
    CosinePolar,
}

impl Hemisphere {
    /// Every variant, in CLI order.
    pub const ALL: [Hemisphere; 3] = [Hemisphere::Uniform, Hemisphere::Cosine, Hemisphere::CosinePolar];

    /// The name used on the command line, in scene files and in stats.
    pub fn name(self) -> &'static str {
        match self {
            Hemisphere::Uniform => "uniform",
            Hemisphere::Cosine => "cosine",
            Hemisphere::CosinePolar => "cosine-polar",
        }
    }

    /// The variant called `name`.
    pub fn from_name(name: &str) -> Option<Hemisphere> {
        Hemisphere::ALL.into_iter().find(|h| h.name() == name)
    }

    /// The id the shader switches on (`HEMISPHERE_*` in `sampling.wgsl`).
    pub fn shader_id(self) -> u32 {
        match self {
            Hemisphere::Uniform => 0,
            Hemisphere::Cosine => 1,
            Hemisphere::CosinePolar => 2,
        }
    }

    /// Direction in the local frame (z = normal).
    pub fn sample(self, u: Vec2) -> Vec3 {
        match self {
            Hemisphere::Uniform => sample_uniform_hemisphere(u),
            Hemisphere::Cosine => sample_cosine_hemisphere(u),
            Hemisphere::CosinePolar => sample_cosine_hemisphere_polar(u),
        }
    }

    /// Solid-angle density of a local direction.
    pub fn pdf(self, w: Vec3) -> f32 {
        match self {
            Hemisphere::Uniform => uniform_hemisphere_pdf(),
            Hemisphere::Cosine | Hemisphere::CosinePolar => cosine_hemisphere_pdf(w.z),
        }
    }

    /// The numbers that `sample` maps to `w` (`w` a unit vector with z ≥ 0).
    pub fn invert(self, w: Vec3) -> Vec2 {
        match self {
            Hemisphere::Uniform => invert_uniform_hemisphere_sample(w),
            Hemisphere::Cosine => invert_cosine_hemisphere_sample(w),
            Hemisphere::CosinePolar => invert_cosine_hemisphere_polar_sample(w),
        }
    }

    /// The AO estimate of one unoccluded direction, `cos θ / (π p(ω))`, so that a fully
    /// open hemisphere averages to one (pbrt's normalisation).
    pub fn weight(self, w: Vec3) -> f32 {
        match self {
            Hemisphere::Uniform => 2.0 * w.z,
            Hemisphere::Cosine | Hemisphere::CosinePolar => 1.0,
        }
    }
}

/// Uniform hemisphere by inversion: z = ξ₁, φ = 2πξ₂ (the "better" form of the lecture
/// *Monte Carlo Integration I*).
pub fn sample_uniform_hemisphere(u: Vec2) -> Vec3 {
    let z = u.x;
    let r = safe_sqrt(1.0 - z * z);
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Density of [`sample_uniform_hemisphere`]: 1/2π.
pub fn uniform_hemisphere_pdf() -> f32 {
    0.5 * FRAC_1_PI
}

/// Inverse of [`sample_uniform_hemisphere`].
pub fn invert_uniform_hemisphere_sample(w: Vec3) -> Vec2 {
    let mut phi = w.y.atan2(w.x);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    Vec2::new(w.z, phi / (2.0 * PI))
}

/// Shirley & Chiu's concentric map from the square to the unit disk.
pub fn sample_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let o = 2.0 * u - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) =
        if o.x.abs() > o.y.abs() { (o.x, FRAC_PI_4 * (o.y / o.x)) } else { (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y)) };
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Inverse of [`sample_uniform_disk_concentric`].
pub fn invert_uniform_disk_concentric_sample(p: Vec2) -> Vec2 {
    let theta = p.y.atan2(p.x);
    let r = (p.x * p.x + p.y * p.y).sqrt();
    // Fold θ into [-π/4, 7π/4) to find the square's wedge.
    let t = if theta < -FRAC_PI_4 { theta + 2.0 * PI } else { theta };
    let o = if t < FRAC_PI_4 {
        Vec2::new(r, r * t / FRAC_PI_4)
    } else if t < 3.0 * FRAC_PI_4 {
        Vec2::new(r * (FRAC_PI_2 - t) / FRAC_PI_4, r)
    } else if t < 5.0 * FRAC_PI_4 {
        Vec2::new(-r, r * (PI - t) / FRAC_PI_4)
    } else {
        Vec2::new(r * (t - 3.0 * FRAC_PI_2) / FRAC_PI_4, -r)
    };
    (o + Vec2::ONE) * 0.5
}

/// The polar map from the square to the unit disk: r = √ξ₁, φ = 2πξ₂.
pub fn sample_uniform_disk_polar(u: Vec2) -> Vec2 {
    let r = u.x.sqrt();
    let theta = 2.0 * PI * u.y;
    r * Vec2::new(theta.cos(), theta.sin())
}

/// Inverse of [`sample_uniform_disk_polar`].
pub fn invert_uniform_disk_polar_sample(p: Vec2) -> Vec2 {
    let mut theta = p.y.atan2(p.x);
    if theta < 0.0 {
        theta += 2.0 * PI;
    }
    Vec2::new(p.x * p.x + p.y * p.y, theta / (2.0 * PI))
}

/// Cosine-weighted hemisphere: a point uniform on the disk projected up (Malley's method).
/// The height comes from the exact disk radius, √((1 − r)(1 + r)), not from 1 − x² − y²,
/// whose rounding in sin and cos would dominate near the horizon.
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = sample_uniform_disk_concentric(u);
    let o = (2.0 * u - Vec2::ONE).abs();
    let r = o.x.max(o.y);
    Vec3::new(d.x, d.y, safe_sqrt((1.0 - r) * (1.0 + r)))
}

/// Density of [`sample_cosine_hemisphere`]: cos θ / π.
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta * FRAC_1_PI
}

/// Inverse of [`sample_cosine_hemisphere`].
pub fn invert_cosine_hemisphere_sample(w: Vec3) -> Vec2 {
    invert_uniform_disk_concentric_sample(Vec2::new(w.x, w.y))
}

/// Cosine-weighted hemisphere through the polar disk map: the construction of the lecture
/// *Monte Carlo Integration I*.
/// The height is √(1 − ξ₁), exact up to one rounding.
pub fn sample_cosine_hemisphere_polar(u: Vec2) -> Vec3 {
    let d = sample_uniform_disk_polar(u);
    Vec3::new(d.x, d.y, safe_sqrt(1.0 - u.x))
}

/// Inverse of [`sample_cosine_hemisphere_polar`].
pub fn invert_cosine_hemisphere_polar_sample(w: Vec3) -> Vec2 {
    invert_uniform_disk_polar_sample(Vec2::new(w.x, w.y))
}

/// Orthonormal basis around a unit vector without a singularity: Duff et al.,
/// "Building an Orthonormal Basis, Revisited" (JCGT 2017), listing 3.
pub fn orthonormal_basis(n: Vec3) -> (Vec3, Vec3) {
    // `>= 0` rather than copysign, to treat -0.0 as the shader's `select` does.
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let s = Vec3::new(b, sign + n.y * n.y * a, -n.y);
    (t, s)
}

/// Local direction (z = `n`) to world space.
pub fn local_to_world(w: Vec3, n: Vec3) -> Vec3 {
    let (t, s) = orthonormal_basis(n);
    t * w.x + s * w.y + n * w.z
}

/// Moves a surface point `p`, which lies within `error` of its surface along the unit
/// normal `n`, to the normal's side of every point that rounding allows (pbrt-v4's
/// `OffsetRayOrigin`, §6.8.6): by `error` along `n`, then one float further in each
/// coordinate the offset moves. The offset scales with the point's own error bound, so it
/// is a few ulps at any scale and exactly 0 for a point given as exact (`error` 0).
pub fn offset_ray_origin(p: Vec3, n: Vec3, error: f32) -> Vec3 {
    let offset = error * n;
    let moved = p + offset;
    let step = |x: f32, o: f32| -> f32 {
        if o > 0.0 {
            next_float_up(x)
        } else if o < 0.0 {
            next_float_down(x)
        } else {
            x
        }
    };
    Vec3::new(step(moved.x, offset.x), step(moved.y, offset.y), step(moved.z, offset.z))
}

/// Direction `w` mirrored about the plane of the unit surface normal `g` when it points
/// below the surface (`w·g < 0`), else `w`: a direction sampled about a shading normal
/// that would leave into the surface is traced as its mirror image above it, so the
/// surface a probe lies on never occludes it (`g` zero leaves every direction as it is).
/// The twin of `above_surface` in `shaders/sampling.wgsl`.
pub fn above_surface(w: Vec3, g: Vec3) -> Vec3 {
    let c = w.dot(g);
    if c < 0.0 { w - 2.0 * c * g } else { w }
}

/// The next float above `x` (−0 is treated as +0); +∞ stays.
pub fn next_float_up(x: f32) -> f32 {
    if x == f32::INFINITY {
        return x;
    }
    let x = if x == 0.0 { 0.0 } else { x };
    let bits = x.to_bits();
    f32::from_bits(if x >= 0.0 { bits + 1 } else { bits - 1 })
}

/// The next float below `x` (+0 is treated as −0); −∞ stays.
pub fn next_float_down(x: f32) -> f32 {
    -next_float_up(-x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid over [0,1)² that includes 0 and the largest float below one.
    fn grid() -> Vec<Vec2> {
        let last = 1.0 - f32::EPSILON / 2.0;
        let mut xs: Vec<f32> = (0..33).map(|i| i as f32 / 33.0).collect();
        xs.push(last);
        xs.iter().flat_map(|&x| xs.iter().map(move |&y| Vec2::new(x, y))).collect()
    }

    #[test]
    fn unit_float_range_is_zero_to_below_one() {
        assert_eq!(u32_to_unit_float(0), 0.0);
        assert_eq!(u32_to_unit_float(u32::MAX), 1.0 - f32::EPSILON / 2.0);
    }

    #[test]
    fn warps_give_unit_upper_hemisphere_directions() {
        for h in Hemisphere::ALL {
            for u in grid() {
                let w = h.sample(u);
                assert!(w.is_finite(), "{h:?} {u}: {w}");
                assert!((w.length() - 1.0).abs() < 1e-5, "{h:?} {u}: |w| = {}", w.length());
                assert!(w.z >= 0.0, "{h:?} {u}: {w}");
            }
        }
    }

    #[test]
    fn sample_then_invert_returns_the_input() {
        for u in grid() {
            // φ wraps at 1 and the concentric map folds its boundary; compare on the circle.
            let close = |a: Vec2, b: Vec2| {
                let dx = (a.x - b.x).abs();
                let dy = (a.y - b.y).abs().min(1.0 - (a.y - b.y).abs());
                dx < 2e-4 && dy < 2e-4
            };
            let back = Hemisphere::Uniform.invert(Hemisphere::Uniform.sample(u));
            // At the pole (z = ξ₁ → 1) the circle shrinks to a point and φ is lost.
            assert!(close(u, back) || u.x == 1.0 - f32::EPSILON / 2.0, "uniform {u} -> {back}");
            let back = Hemisphere::Cosine.invert(Hemisphere::Cosine.sample(u));
            assert!((u - back).abs().max_element() < 2e-4, "cosine {u} -> {back}");
            let back = Hemisphere::CosinePolar.invert(Hemisphere::CosinePolar.sample(u));
            // At the centre (r = √ξ₁ = 0) φ is lost.
            assert!(close(u, back) || u.x == 0.0, "cosine-polar {u} -> {back}");
        }
    }

    #[test]
    fn pdfs_integrate_to_one() {
        // Midpoint rule in (cos θ, φ), where dω = d(cos θ) dφ.
        let n = 2000;
        for h in Hemisphere::ALL {
            let mut total = 0.0f64;
            for i in 0..n {
                let z = (i as f32 + 0.5) / n as f32;
                let w = Vec3::new(safe_sqrt(1.0 - z * z), 0.0, z);
                total += h.pdf(w) as f64 * (1.0 / n as f64) * 2.0 * std::f64::consts::PI;
            }
            assert!((total - 1.0).abs() < 1e-4, "{h:?} pdf integrates to {total}");
        }
    }

    #[test]
    fn weight_is_cos_over_pi_pdf() {
        for h in Hemisphere::ALL {
            for u in grid() {
                let w = h.sample(u);
                if h.pdf(w) > 1e-3 {
                    let expected = w.z / (PI * h.pdf(w));
                    assert!((h.weight(w) - expected).abs() < 1e-4, "{h:?} {w}");
                }
            }
        }
    }

    #[test]
    fn basis_is_orthonormal_for_axes_and_random_normals() {
        let mut normals = vec![Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z, Vec3::new(0.0, 0.0, -0.0)];
        for i in 0..1000u32 {
            let u = sample_uniforms(i, 7, 0, 3);
            let z = 2.0 * u[0] - 1.0;
            let r = safe_sqrt(1.0 - z * z);
            let phi = 2.0 * PI * u[1];
            normals.push(Vec3::new(r * phi.cos(), r * phi.sin(), z));
        }
        for n in normals {
            let n = if n.length_squared() == 0.0 { Vec3::Z } else { n };
            let (t, s) = orthonormal_basis(n);
            for (a, b) in [(t, s), (t, n), (s, n)] {
                assert!(a.dot(b).abs() < 1e-5, "{n}: not orthogonal");
            }
            for v in [t, s] {
                assert!((v.length() - 1.0).abs() < 1e-5, "{n}: not unit");
            }
            assert!((t.cross(s) - n).length() < 1e-5, "{n}: not right-handed");
        }
    }

    #[test]
    fn offset_moves_past_the_error_bound_at_every_scale() {
        for scale in [1e-6f32, 1e-4, 1e-2, 1.0, 1e3, 1e6] {
            for n in [Vec3::X, -Vec3::Y, Vec3::new(0.6, 0.0, 0.8), Vec3::new(-0.48, 0.6, -0.64)] {
                for p in [Vec3::new(1.0, -2.0, 0.5), Vec3::new(-3.0, 0.25, 7.0), Vec3::ZERO] {
                    let p = p * scale;
                    let error = crate::geometry::gamma(8) * n.abs().dot(p.abs());
                    let q = offset_ray_origin(p, n, error);
                    // In f64: at least the error bound along n, at most it plus an ulp or two per coordinate.
                    let moved = (q.as_dvec3() - p.as_dvec3()).dot(n.as_dvec3());
                    assert!(moved >= error as f64, "scale {scale}, p {p}, n {n}: moved {moved} < {error}");
                    let ulps = 3.0 * f32::EPSILON as f64 * (p.abs().max_element() as f64 + error as f64);
                    assert!(moved <= error as f64 + ulps + 1e-44, "offset too large at {p}: {moved}");
                    assert_eq!(offset_ray_origin(p, n, 0.0), p, "an exact point stays put");
                }
            }
        }
        assert_eq!(next_float_up(1.0), 1.0 + f32::EPSILON);
        assert_eq!(next_float_down(1.0), 1.0 - f32::EPSILON / 2.0);
        assert_eq!(next_float_up(-0.0), f32::from_bits(1));
        assert_eq!(next_float_down(0.0), -f32::from_bits(1));
        assert_eq!(next_float_up(-1.0), -1.0 + f32::EPSILON / 2.0);
        assert_eq!(next_float_up(f32::INFINITY), f32::INFINITY);
    }
}
