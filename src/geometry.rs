//! Ray–primitive intersection, mirrored by `shaders/intersect.wgsl`.
//!
//! Each function returns the hit distance `t` in `(t_min, t_max)` or `f32::INFINITY`.

use crate::scene::Plane;
use glam::Vec3;

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
/// `t > t_min` is exact rather than widened by pbrt-v4's error bound on `t`: callers
/// offset their origins off the surface instead.
pub fn intersect_triangle(o: Vec3, d: Vec3, t_min: f32, t_max: f32, v0: Vec3, v1: Vec3, v2: Vec3) -> f32 {
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
    if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
        return f32::INFINITY;
    }
    let det = u + v + w;
    if det == 0.0 {
        return f32::INFINITY;
    }
    let az = sh.s.z * a.z;
    let bz = sh.s.z * b.z;
    let cz = sh.s.z * c.z;
    let t = (u * az + v * bz + w * cz) / det;
    if t > t_min && t < t_max { t } else { f32::INFINITY }
}

/// Ray–sphere with the cancellation-free quadratic of Haines et al., "Precision
/// Improvements for Ray/Sphere Intersection", Ray Tracing Gems ch. 7. `d` is unit length.
pub fn intersect_sphere(o: Vec3, d: Vec3, t_min: f32, t_max: f32, center: Vec3, radius: f32) -> f32 {
    let f = o - center;
    let b = -f.dot(d);
    // r² - |f + b d|²: the distance from the centre to the line, computed without squaring b.
    let l = f + b * d;
    let disc = radius * radius - l.dot(l);
    if disc < 0.0 {
        return f32::INFINITY;
    }
    let c = f.dot(f) - radius * radius;
    let q = b + disc.sqrt().copysign(b);
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
    let (near, far) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
    if near > t_min && near < t_max {
        near
    } else if far > t_min && far < t_max {
        far
    } else {
        f32::INFINITY
    }
}

/// Ray–plane, both sides.
pub fn intersect_plane(o: Vec3, d: Vec3, t_min: f32, t_max: f32, plane: &Plane) -> f32 {
    let denom = plane.normal.dot(d);
    if denom == 0.0 {
        return f32::INFINITY;
    }
    let t = (plane.d - plane.normal.dot(o)) / denom;
    if t > t_min && t < t_max { t } else { f32::INFINITY }
}

/// Sphere hit point projected back onto the surface, so offsets start from the surface,
/// and the outward normal there.
pub fn sphere_hit_point(o: Vec3, d: Vec3, t: f32, center: Vec3, radius: f32) -> (Vec3, Vec3) {
    let n = (o + t * d - center).normalize();
    (center + radius * n, n)
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
}
