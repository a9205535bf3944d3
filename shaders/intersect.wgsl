// Ray-primitive intersection: the WGSL twin of src/geometry.rs. Each returns the hit
// distance in (t_min, t_max) or INF.

const INF: f32 = 0x1.fffffep+127f;

// Moeller-Trumbore on precomputed edges; both sides.
fn intersect_triangle(o: vec3f, d: vec3f, t_min: f32, t_max: f32, v0: vec3f, e1: vec3f, e2: vec3f) -> f32 {
    let p = cross(d, e2);
    let det = dot(e1, p);
    if (det == 0.0) {
        return INF;
    }
    let inv_det = 1.0 / det;
    let s = o - v0;
    let u = dot(s, p) * inv_det;
    let q = cross(s, e1);
    let v = dot(d, q) * inv_det;
    let t = dot(e2, q) * inv_det;
    if (u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > t_min && t < t_max) {
        return t;
    }
    return INF;
}

// Cancellation-free ray-sphere (Haines et al., Ray Tracing Gems ch. 7); d is unit length.
fn intersect_sphere(o: vec3f, d: vec3f, t_min: f32, t_max: f32, center: vec3f, radius: f32) -> f32 {
    let f = o - center;
    let b = -dot(f, d);
    let l = f + b * d;
    let disc = radius * radius - dot(l, l);
    if (disc < 0.0) {
        return INF;
    }
    let c = dot(f, f) - radius * radius;
    let q = b + select(-sqrt(disc), sqrt(disc), b >= 0.0);
    var t0 = 0.0;
    var t1 = 0.0;
    if (q != 0.0) {
        t0 = c / q;
        t1 = q;
    }
    let near = min(t0, t1);
    let far = max(t0, t1);
    if (near > t_min && near < t_max) {
        return near;
    }
    if (far > t_min && far < t_max) {
        return far;
    }
    return INF;
}

// Infinite plane n.x = d, both sides.
fn intersect_plane(o: vec3f, d: vec3f, t_min: f32, t_max: f32, n: vec3f, plane_d: f32) -> f32 {
    let denom = dot(n, d);
    if (denom == 0.0) {
        return INF;
    }
    let t = (plane_d - dot(n, o)) / denom;
    if (t > t_min && t < t_max) {
        return t;
    }
    return INF;
}

// Slab test; returns the entry distance or INF. The exit distance is widened by
// 1 + 2 gamma(3) so rounding never culls a box the ray touches (Ize, "Robust BVH Ray
// Traversal", JCGT 2013).
fn intersect_box(bmin: vec3f, bmax: vec3f, o: vec3f, inv_d: vec3f, t_max: f32) -> f32 {
    let t0 = (bmin - o) * inv_d;
    let t1 = (bmax - o) * inv_d;
    let lo = min(t0, t1);
    let hi = max(t0, t1);
    let t_near = max(max(lo.x, lo.y), max(lo.z, 0.0));
    let t_far = min(min(hi.x, hi.y), min(hi.z, t_max)) * 1.0000008;
    return select(INF, t_near, t_near <= t_far);
}

// 1/d with each component kept away from zero, so the slab test never computes 0 * inf.
fn safe_inverse(d: vec3f) -> vec3f {
    let tiny = vec3f(1e-30);
    return 1.0 / select(d, select(-tiny, tiny, d >= vec3f(0.0)), abs(d) < tiny);
}
