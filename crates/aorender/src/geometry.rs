//! Ray–primitive intersection, mirrored by `shaders/intersect.wgsl`.
//!
//! Each function returns the hit distance `t` in `(t_min, t_max)` or `f32::INFINITY`.

use glam::Vec3;

/// An infinite plane through `point` with unit `normal`, hit from both sides. Kept as a
/// point rather than `n·x = d`: a ray's distance to it is then `n·(point − o)`, whose
/// rounding error scales with the distance rather than with |o| (exact for an axis
/// normal), so planes stay exact far from the origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vec3,
    /// A point of the plane.
    pub point: Vec3,
    /// Diffuse reflectance ρ.
    pub albedo: f32,
}

/// The ray-dependent part of the watertight triangle test: the axis permutation and the
/// shear that maps the ray to the +z axis. A pure function of `d`, so every triangle a ray
/// meets sees its shared vertices transformed by exactly the same operations.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Shear {
    /// Axes that become x, y and z (`kz` is the axis of largest |d|).
    k: [usize; 3],
    /// `(d[kx] / d[kz], d[ky] / d[kz], 1 / d[kz])`.
    s: Vec3,
}

impl Shear {
    fn new(d: Vec3) -> Shear {
        let a = d.abs();
        // Ties go to the lower axis; `intersect.wgsl` breaks them the same way.
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = if kz == 2 { 0 } else { kz + 1 };
        let mut ky = if kx == 2 { 0 } else { kx + 1 };
        // Swapping x and y when the ray runs toward -z keeps the winding, so the edge
        // functions of a triangle seen from its front are positive.
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let k = [kx, ky, kz];
        let dz = d[kz];
        Shear { k, s: Vec3::new(d[kx] / dz, d[ky] / dz, 1.0 / dz) }
    }

    fn permute(&self, v: Vec3) -> Vec3 {
        Vec3::new(v[self.k[0]], v[self.k[1]], v[self.k[2]])
    }
}

/// Woop, Benthin & Wald, "Watertight Ray/Triangle Intersection" (JCGT 2(1), 2013), in
/// single precision, on the vertices as stored. Both sides are hit; `d` need not be unit
/// length (`t` is in units of `d`). `shaders/intersect.wgsl` performs the same IEEE
/// operations in the same order, so the two agree bit for bit on an IEEE platform.
///
/// The vertices are translated to the ray origin, permuted and sheared so the ray is the
/// +z axis, and the signs of the three 2-D edge functions `U, V, W` decide the hit.
/// Watertightness: the shear is a pure function of `d` and a vertex has the same bits in
/// every triangle (`bvh::GpuPrimitive` stores vertices, not edges), so each vertex lands
/// on the same rounded 2-D point in every triangle: a slightly moved but still closed
/// mesh. The edge from P to Q has the function `E(P, Q) = Q.x·P.y − Q.y·P.x`; the
/// neighbour that runs the edge from Q to P computes `P.x·Q.y − P.y·Q.x`, exactly
/// `−E(P, Q)` because IEEE products commute and `x − y = −(y − x)`. Rounding is monotone,
/// so `fl(fl(a·b) − fl(c·d))` has the sign of `a·b − c·d` or is 0 (flushing denormals to
/// zero is monotone too): an edge function is never wrong in sign, only sometimes 0, and
/// then 0 on both sides of the edge.
///
/// Zeros, and why there is no f64 fallback: the paper, and pbrt-v4 on the CPU, recompute
/// an edge function that is exactly 0 in f64 to recover its sign; WGSL has no f64 on most
/// adapters and both sides must agree, so here a 0 counts as either sign instead (a hit
/// is all three edge functions ≥ 0 or all ≤ 0). That is conservative: a ray on, or within
/// rounding of, an edge or vertex hits every triangle there, where the f64 fallback would
/// pick one of them — which changes neither the occlusion test nor, beyond rounding, the
/// closest `t`. `det = U + V + W == 0` (all three 0: a triangle seen edge-on, or a
/// repeated vertex, whose `U, V, W` cancel exactly) is a miss. Distinct but collinear
/// vertices can still be hit once the shear has rounded them; the scene loader drops
/// triangles whose normal is degenerate, so no such triangle reaches this test.
///
/// The exact antisymmetry needs `a·b − c·d` evaluated as two rounded products and a
/// subtraction. Rust never contracts it into an FMA and lavapipe does not either
/// (`tests/robustness.rs` finds every `t` bit-identical); a shader compiler that did would
/// void the guarantee on its adapter.
///
/// A candidate hit must also lie beyond pbrt-v4's bound on the rounding error of `t`
/// (Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed., §6.8.7): a `t` that
/// rounding alone could have made positive is not a hit. A ray that starts on the
/// triangle, or within that error of it, therefore never hits it, at every scale.
pub fn intersect_triangle(o: Vec3, d: Vec3, t_min: f32, t_max: f32, v0: Vec3, v1: Vec3, v2: Vec3) -> f32 {
    triangle_test(o, d, t_min, t_max, v0, v1, v2).0
}

/// What the kernels' slab tests multiply a box's exit distance by, so that rounding never
/// culls a box the ray touches (Ize, "Robust BVH Ray Traversal", JCGT 2013): at least
/// 1 + 2γ(3), rounded up to 1 + 7 ulps. The CPU reference traverses with obvhs's own test.
pub const BOX_EXIT_WIDENING: f32 = 1.0000008;

/// γ(n) = nε / (1 − nε), ε = 2⁻²⁴: the bound on the relative error of n rounded
/// operations (pbrt-v4's `gamma`).
pub const fn gamma(n: u32) -> f32 {
    let ne = n as f32 * f32::EPSILON * 0.5;
    ne / (1.0 - ne)
}

/// The watertight test of [`intersect_triangle`], also returning its scaled barycentrics
/// `(U, V, W)` (the weights of `v0, v1, v2` times `det = U + V + W`); `t` is infinite on a miss.
pub fn triangle_test(o: Vec3, d: Vec3, t_min: f32, t_max: f32, v0: Vec3, v1: Vec3, v2: Vec3) -> (f32, Vec3) {
    const MISS: f32 = f32::INFINITY;
    let sh = Shear::new(d);
    // Vertices relative to the origin, in the permuted axes.
    let a = sh.permute(v0 - o);
    let b = sh.permute(v1 - o);
    let c = sh.permute(v2 - o);
    // Sheared to the ray's frame: the ray is the z axis.
    let ax = a.x - sh.s.x * a.z;
    let ay = a.y - sh.s.y * a.z;
    let bx = b.x - sh.s.x * b.z;
    let by = b.y - sh.s.y * b.z;
    let cx = c.x - sh.s.x * c.z;
    let cy = c.y - sh.s.y * c.z;
    // Scaled barycentrics: twice the signed areas seen from the ray.
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    let uvw = Vec3::new(u, v, w);
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return (MISS, uvw);
    }
    let det = u + v + w;
    if det == 0.0 {
        return (MISS, uvw);
    }
    let az = sh.s.z * a.z;
    let bz = sh.s.z * b.z;
    let cz = sh.s.z * c.z;
    let t = (u * az + v * bz + w * cz) / det;
    if !(t > t_min && t < t_max) {
        return (MISS, uvw);
    }
    // pbrt-v4's bound on the error of t; shaders/intersect.wgsl repeats it operation for
    // operation. The error of the sheared x and y is bounded with the z coordinates before
    // the scaling by 1/d_z, as the bound is derived (|s_x|, |s_y| <= 1), not after it as
    // pbrt-v4's code has it: scaled, they are in units of t, and for a short direction
    // (a ray carried into a mesh scaled up by 1e6 is 1e-6 long) the bound would exceed
    // every t and reject true hits.
    let max_zt = az.abs().max(bz.abs()).max(cz.abs());
    let max_z = a.z.abs().max(b.z.abs()).max(c.z.abs());
    let max_xt = ax.abs().max(bx.abs()).max(cx.abs());
    let max_yt = ay.abs().max(by.abs()).max(cy.abs());
    let delta_x = gamma(5) * (max_xt + max_z);
    let delta_y = gamma(5) * (max_yt + max_z);
    let delta_z = gamma(3) * max_zt;
    let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = u.abs().max(v.abs()).max(w.abs());
    let delta_t = 3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) / det.abs();
    if t > delta_t { (t, uvw) } else { (MISS, uvw) }
}

/// A point on a surface, as exact as the hit allows, and a bound on its distance from the
/// true surface along the normal: what [`crate::sampling::offset_ray_origin`] moves it by.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// The point.
    pub p: Vec3,
    /// Unit geometric normal (either side).
    pub n: Vec3,
    /// Bound on |(p − surface) · n|.
    pub error: f32,
}

/// The hit point of a ray on a triangle it hits, by barycentric interpolation of the
/// vertices (pbrt-v4 §6.8.6), whose error is γ(7)·Σ|bᵢvᵢ| componentwise however far the
/// ray came; one more γ for WGSL's division, which is within 2.5 ulp rather than exact.
/// Falls back to `o + t d` if the test no longer sees the hit.
pub fn triangle_hit_point(o: Vec3, d: Vec3, t: f32, v0: Vec3, v1: Vec3, v2: Vec3) -> SurfacePoint {
    let (p, n, p_error) = triangle_hit(o, d, t, v0, v1, v2);
    SurfacePoint { p, n, error: n.abs().dot(p_error) }
}

/// [`triangle_hit_point`]'s point, unit normal and componentwise error bound.
fn triangle_hit(o: Vec3, d: Vec3, t: f32, v0: Vec3, v1: Vec3, v2: Vec3) -> (Vec3, Vec3, Vec3) {
    let n = (v1 - v0).cross(v2 - v0).normalize();
    let (_, uvw) = triangle_test(o, d, 0.0, f32::INFINITY, v0, v1, v2);
    let det = uvw.x + uvw.y + uvw.z;
    let (p, p_error) = if det != 0.0 {
        let b = uvw * (1.0 / det);
        let (b0, b1, b2) = (b.x * v0, b.y * v1, b.z * v2);
        (b0 + b1 + b2, gamma(8) * (b0.abs() + b1.abs() + b2.abs()))
    } else {
        let p = o + t * d;
        (p, gamma(8) * p.abs())
    };
    (p, n, p_error)
}

/// An affine map as three rows `(m_i0, m_i1, m_i2, t_i)`: `y_i = ((m_i0 x + m_i1 y) + m_i2 z) + t_i`,
/// evaluated in that order by the CPU and the kernels alike (`shaders/intersect.wgsl`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineRows(pub [[f32; 4]; 3]);

impl AffineRows {
    /// The affine part of `m` (its last row is ignored, as `Mat4::transform_point3` does).
    pub fn from_mat4(m: &glam::Mat4) -> AffineRows {
        AffineRows([0, 1, 2].map(|i| m.row(i).to_array()))
    }

    /// The image of point `p`.
    pub fn point(&self, p: Vec3) -> Vec3 {
        let r = |k: usize| {
            let m = self.0[k];
            ((m[0] * p.x + m[1] * p.y) + m[2] * p.z) + m[3]
        };
        Vec3::new(r(0), r(1), r(2))
    }

    /// The image of direction `v` (no translation).
    pub fn vector(&self, v: Vec3) -> Vec3 {
        let r = |k: usize| {
            let m = self.0[k];
            (m[0] * v.x + m[1] * v.y) + m[2] * v.z
        };
        Vec3::new(r(0), r(1), r(2))
    }

    /// `|M| a + |t| b`: the linear part's absolute values times `a`, plus `b` times the
    /// translation's absolute values.
    fn abs_apply(&self, a: Vec3, b: f32) -> Vec3 {
        let r = |k: usize| {
            let m = self.0[k].map(f32::abs);
            m[0] * a.x + m[1] * a.y + m[2] * a.z + b * m[3]
        };
        Vec3::new(r(0), r(1), r(2))
    }

    /// The transpose of the linear part applied to `v`: with the rows of the inverse,
    /// how normals map.
    fn transpose_vector(&self, v: Vec3) -> Vec3 {
        let m = &self.0;
        let c = |j: usize| (m[0][j] * v.x + m[1][j] * v.y) + m[2][j] * v.z;
        Vec3::new(c(0), c(1), c(2))
    }

    /// The translation column.
    fn translation(&self) -> Vec3 {
        Vec3::new(self.0[0][3], self.0[1][3], self.0[2][3])
    }
}

/// The inverse of an affine map `y = L x + t`, kept as the rows of `L⁻¹` with `t` in the
/// last column and applied as `L⁻¹ (y − t)`. Subtracting `t` first keeps a point near the
/// instance exact where `L⁻¹ y − L⁻¹ t` would cancel: near an instance 1e6 from the origin,
/// `y − t` is exact (Sterbenz) and the object-space point is as good as at the origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseAffine(pub AffineRows);

impl InverseAffine {
    /// The inverse of `y = L x + t`: `L⁻¹` computed in f64 and rounded once, `t` as it is.
    pub fn of(m: &glam::Mat4) -> InverseAffine {
        let l = glam::DMat3::from_mat4(m.as_dmat4()).inverse();
        let t = m.w_axis;
        InverseAffine(AffineRows([0, 1, 2].map(|i| {
            let r = l.row(i).as_vec3();
            [r.x, r.y, r.z, t[i]]
        })))
    }

    /// The preimage of point `p`.
    pub fn point(&self, p: Vec3) -> Vec3 {
        self.0.vector(p - self.0.translation())
    }

    /// The preimage of direction `v`.
    pub fn vector(&self, v: Vec3) -> Vec3 {
        self.0.vector(v)
    }
}

/// The world-space hit point of an instance's triangle: the ray is carried into the mesh's
/// space by `to_object`, the point found there ([`triangle_hit_point`]) and carried back
/// by `to_world` (`y = L x + t`). The error bound covers, besides the object-space error e,
///
/// - the way to the world: the products and the first two sums within γ(3)|L||p|, the
///   last sum, adding t, within γ(1)|y|, and e carried by L: (1 + γ(3))|L| e;
/// - the way back: an AO ray from this point enters the instance again through
///   `to_object`, whose f32 entries are within half an ulp of the exact `L⁻¹`, and which
///   rounds `y − t` and then three times more: its origin lands within
///   γ(5)|L⁻¹||y − t| of the exact preimage of the world origin; carried to the world by
///   L (which preserves sides exactly in real arithmetic), that is |L| times it. `|y − t|`
///   is taken at the hit point plus twice the first error, for the offset of the origin;
///   what the offset's own share of the way back adds, at most γ(5)‖|L||L⁻¹|‖ of the
///   bound, is covered by the final factor 1 + γ(16).
///
/// The world origin is pushed off by the sum, so the object-space origin stays on the
/// side of the triangle it left. `shaders/intersect.wgsl` (`instance_hit_point`) repeats
/// the operations.
pub fn instance_hit_point(
    to_world: &AffineRows,
    to_object: &InverseAffine,
    o: Vec3,
    d: Vec3,
    t: f32,
    v: [Vec3; 3],
) -> SurfacePoint {
    let (oo, od) = (to_object.point(o), to_object.vector(d));
    let (p_object, n_object, e_object) = triangle_hit(oo, od, t, v[0], v[1], v[2]);
    let n = to_object.0.transpose_vector(n_object).normalize();
    instance_point(to_world, to_object, p_object, e_object, n)
}

/// A point of an instance's surface carried into the world, `p_object` within `e_object`
/// (componentwise) of the surface in the mesh's space, with world normal `n`: the point
/// and the bound of [`instance_hit_point`], which an AO ray from it is offset by. A mesh
/// vertex is exactly on its triangles (`e_object` zero): what a bake of an instanced mesh
/// starts its rays from.
pub fn instance_point(
    to_world: &AffineRows,
    to_object: &InverseAffine,
    p_object: Vec3,
    e_object: Vec3,
    n: Vec3,
) -> SurfacePoint {
    let p = to_world.point(p_object);
    let forward = gamma(3) * to_world.abs_apply(p_object.abs(), 0.0)
        + gamma(1) * p.abs()
        + (1.0 + gamma(3)) * to_world.abs_apply(e_object, 0.0);
    let q = (p - to_world.translation()).abs() + 2.0 * forward;
    let back = to_world.abs_apply(gamma(5) * to_object.0.abs_apply(q, 0.0), 0.0);
    SurfacePoint { p, n, error: n.abs().dot(forward + back) * (1.0 + gamma(16)) }
}

/// What entering an instance's mesh can cost a world point `p` near its surface: an AO
/// ray from `p`, pushed off along the unit world normal `n` by at most `slack`, is
/// carried into the mesh's space by `to_object`, whose origin lands within
/// γ(5)|L⁻¹||o − t| of the exact preimage ([`instance_hit_point`]'s way back); carried to
/// the world by `L`, that is at most this far along `n`.
pub fn instance_entry_error(to_world: &AffineRows, to_object: &InverseAffine, p: Vec3, slack: f32, n: Vec3) -> f32 {
    let q = (p - to_world.translation()).abs() + Vec3::splat(2.0 * slack);
    let back = to_world.abs_apply(gamma(5) * to_object.0.abs_apply(q, 0.0), 0.0);
    n.abs().dot(back) * (1.0 + gamma(16))
}

/// The hit point of a ray on a sphere, projected back onto the surface (pbrt-v4 §6.8.5):
/// within γ(8)·|p − c| of it, plus the rounding of adding the centre.
pub fn sphere_hit_point(o: Vec3, d: Vec3, t: f32, center: Vec3, radius: f32) -> SurfacePoint {
    let n = (o + t * d - center).normalize();
    let offset = radius * n;
    let p = center + offset;
    let p_error = gamma(8) * offset.abs() + gamma(1) * p.abs();
    SurfacePoint { p, n, error: n.abs().dot(p_error) }
}

/// The hit point of a ray on a plane, projected onto it: `q − n (n·(q − point))`. Its
/// distance from the plane is within γ(6)·|n|·|q − point| (the projection) plus γ(1)·|n|·|p|
/// (the rounding of the result's coordinates).
pub fn plane_hit_point(o: Vec3, d: Vec3, t: f32, plane: &Plane) -> SurfacePoint {
    let n = plane.normal;
    let q = o + t * d;
    let from_point = q - plane.point;
    let p = q - n * n.dot(from_point);
    let error = gamma(6) * n.abs().dot(from_point.abs()) + gamma(1) * n.abs().dot(p.abs());
    SurfacePoint { p, n, error }
}

/// Ray–sphere with the cancellation-free quadratic of Haines et al., "Precision
/// Improvements for Ray/Sphere Intersection", Ray Tracing Gems ch. 7. `d` is unit length.
///
/// `c = |o − centre|² − r²` says where the origin is: outside, on or inside. When |c| is
/// within its rounding error, γ(6)·(|o − centre|² + r²), the origin is on the sphere as far
/// as f32 can tell, and the root `c / q` near 0 is that contact, not a hit; only the
/// other root `q` can be.
pub fn intersect_sphere(o: Vec3, d: Vec3, t_min: f32, t_max: f32, center: Vec3, radius: f32) -> f32 {
    let f = o - center;
    let b = -f.dot(d);
    // r² - |f + b d|²: the distance from the centre to the line, computed without squaring b.
    let l = f + b * d;
    let disc = radius * radius - l.dot(l);
    if disc < 0.0 {
        return f32::INFINITY;
    }
    let ff = f.dot(f);
    let c = ff - radius * radius;
    let q = b + disc.sqrt().copysign(b);
    if q == 0.0 {
        return f32::INFINITY;
    }
    let t0 = if c.abs() <= gamma(6) * (ff + radius * radius) { f32::NEG_INFINITY } else { c / q };
    let t1 = q;
    let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
    if near > t_min && near < t_max {
        near
    } else if far > t_min && far < t_max {
        far
    } else {
        f32::INFINITY
    }
}

/// Ray–plane, both sides. The sign of `n·(point − o)` decides which side the origin is
/// on; within its rounding error, γ(5)·|n|·|point − o|, the origin is on the plane and the
/// ray does not hit it. The error scales with the distance to `point`, not with |o|: for
/// an axis normal it is that of one subtraction of nearby coordinates, usually none.
pub fn intersect_plane(o: Vec3, d: Vec3, t_min: f32, t_max: f32, plane: &Plane) -> f32 {
    let denom = plane.normal.dot(d);
    if denom == 0.0 {
        return f32::INFINITY;
    }
    let to_plane = plane.point - o;
    let num = plane.normal.dot(to_plane);
    if num.abs() <= gamma(5) * plane.normal.abs().dot(to_plane.abs()) {
        return f32::INFINITY;
    }
    let t = num / denom;
    if t > t_min && t < t_max { t } else { f32::INFINITY }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{pcg4d, u32_to_unit_float};
    use glam::{DVec3, UVec4};

    /// A point of [0, 1)³, a pure function of `(i, salt)`.
    fn random3(i: u32, salt: u32) -> DVec3 {
        let h = pcg4d(UVec4::new(i, salt, 0x51ed_270b, 0x2545_f491));
        DVec3::new(u32_to_unit_float(h.x) as f64, u32_to_unit_float(h.y) as f64, u32_to_unit_float(h.z) as f64)
    }

    #[test]
    fn degenerate_triangles_are_never_hit() {
        let (a, b) = (Vec3::new(0.3, -0.2, 1.0), Vec3::new(-0.4, 0.5, 1.2));
        let degenerate = [[a, a, b], [a, b, a], [b, a, a], [a, a, a]];
        for (k, tri) in degenerate.iter().enumerate() {
            for i in 0..4000 {
                let o = (2.0 * random3(i, 200 + k as u32) - DVec3::ONE).as_vec3();
                // Aimed at a vertex, at the segment's midpoint, or anywhere.
                let target = match i % 3 {
                    0 => a,
                    1 => 0.5 * (a + b),
                    _ => (2.0 * random3(i, 300) - DVec3::ONE).as_vec3(),
                };
                let t = intersect_triangle(o, target - o, 0.0, f32::INFINITY, tri[0], tri[1], tri[2]);
                assert_eq!(t, f32::INFINITY, "triangle {tri:?} hit from {o} toward {target}");
            }
        }
    }

    #[test]
    fn both_sides_are_hit_at_the_exact_distance() {
        let mut worst = 0.0f64;
        for i in 0..20_000 {
            let v = [random3(i, 400), random3(i, 401), random3(i, 402)].map(|p| 4.0 * p - DVec3::splat(2.0));
            let n = (v[1] - v[0]).cross(v[2] - v[0]);
            // Keep triangles that are not slivers and rays that are not grazing.
            let area = 0.5 * n.length();
            let longest = (v[1] - v[0]).length().max((v[2] - v[1]).length()).max((v[0] - v[2]).length());
            if area < 0.05 * longest * longest {
                continue;
            }
            let bary = random3(i, 403);
            let (s, t) = (bary.x, bary.y);
            let (s, t) = if s + t > 1.0 { (1.0 - s, 1.0 - t) } else { (s, t) };
            // Inside by a margin, so rounding cannot move it out.
            let (s, t) = (0.02 + 0.96 * s, 0.02 + 0.96 * t);
            let (s, t) = (s * 0.98, t * 0.98);
            let target = v[0] + s * (v[1] - v[0]) + t * (v[2] - v[0]);
            let o = 6.0 * random3(i, 404) - DVec3::splat(3.0);
            let d = (target - o).normalize();
            if (d.dot(n) / n.length()).abs() < 0.1 {
                continue;
            }
            let (vf, of, df) = (v.map(|p| p.as_vec3()), o.as_vec3(), d.as_vec3());
            let exact = (target - o).length();
            let got = intersect_triangle(of, df, 0.0, f32::INFINITY, vf[0], vf[1], vf[2]);
            assert!(got.is_finite(), "missed {v:?} from {o} along {d}");
            worst = worst.max((got as f64 - exact).abs() / exact);
            // The reverse ray through the same point hits the other side.
            let back = intersect_triangle(of + 2.0 * exact as f32 * df, -df, 0.0, f32::INFINITY, vf[0], vf[1], vf[2]);
            assert!(back.is_finite(), "back side of {v:?} missed");
            // Beyond t_max, or before t_min: a miss.
            assert_eq!(intersect_triangle(of, df, 0.0, got, vf[0], vf[1], vf[2]), f32::INFINITY);
            assert_eq!(intersect_triangle(of, df, got, f32::INFINITY, vf[0], vf[1], vf[2]), f32::INFINITY);
        }
        eprintln!("largest relative error of t: {worst:.2e}");
        assert!(worst < 1e-5, "relative error of t {worst}");
    }

    /// The slab tests' widening covers Ize's bound, rounded up to 1 + 7 ulps.
    #[test]
    fn box_exit_widening_covers_twice_gamma_3() {
        assert!(BOX_EXIT_WIDENING >= 1.0 + 2.0 * gamma(3));
        assert_eq!(BOX_EXIT_WIDENING.to_bits(), 1.0f32.to_bits() + 7);
    }
}
