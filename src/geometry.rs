//! Ray–primitive intersection, mirrored by `shaders/intersect.wgsl`.
//!
//! Each function returns the hit distance `t` in `(t_min, t_max)` or `f32::INFINITY`.

use crate::scene::Plane;
use glam::Vec3;

/// Möller & Trumbore, "Fast, Minimum Storage Ray/Triangle Intersection" (JGT 1997), on
/// the precomputed edges `e1 = v1 - v0`, `e2 = v2 - v0`. Both sides are hit.
pub fn intersect_triangle(o: Vec3, d: Vec3, t_min: f32, t_max: f32, v0: Vec3, e1: Vec3, e2: Vec3) -> f32 {
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det == 0.0 {
        return f32::INFINITY;
    }
    let inv_det = 1.0 / det;
    let s = o - v0;
    let u = s.dot(p) * inv_det;
    let q = s.cross(e1);
    let v = d.dot(q) * inv_det;
    let t = e2.dot(q) * inv_det;
    if u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > t_min && t < t_max { t } else { f32::INFINITY }
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
