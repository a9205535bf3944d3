// Ray-primitive intersection: the WGSL twin of src/geometry.rs. Each returns the hit
// distance in (t_min, t_max) or INF.

const INF: f32 = 0x1.fffffep+127f;

// Watertight ray-triangle test of Woop, Benthin & Wald (JCGT 2013) on the stored
// vertices; both sides are hit and d need not be unit length. The twin of
// intersect_triangle in src/geometry.rs (whose comment has the full argument), operation
// for operation and in the same order, so the two agree bit for bit where the basic
// operations are IEEE. A shared edge's edge function is computed from the same sheared
// vertices with its operands swapped, so neighbours see exactly opposite values (this
// needs a*b - c*d kept as two rounded products, as lavapipe does). There is no f64
// fallback for edge functions that round to zero: rounding is monotone, so an f32 edge
// function has the right sign or is 0, and a 0 counts as either sign. That keeps the
// test conservative (a ray on an edge or vertex hits every triangle there) without f64,
// which most adapters lack. det == 0 (all three zero: edge-on, or a repeated vertex) is
// a miss.
fn intersect_triangle(o: vec3f, d: vec3f, t_min: f32, t_max: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> f32 {
    // The shear, a pure function of d: kz is the axis of largest |d| (ties to the lower
    // axis), and x and y swap when the ray runs toward -z to keep the winding.
    let ad = abs(d);
    var kz = 2u;
    if (ad.x >= ad.y && ad.x >= ad.z) {
        kz = 0u;
    } else if (ad.y >= ad.z) {
        kz = 1u;
    }
    var kx = select(kz + 1u, 0u, kz == 2u);
    var ky = select(kx + 1u, 0u, kx == 2u);
    let dz = d[kz];
    if (dz < 0.0) {
        let k = kx;
        kx = ky;
        ky = k;
    }
    let sx = d[kx] / dz;
    let sy = d[ky] / dz;
    let sz = 1.0 / dz;
    // Vertices relative to the origin, in the permuted axes.
    let ra = v0 - o;
    let rb = v1 - o;
    let rc = v2 - o;
    let a = vec3f(ra[kx], ra[ky], ra[kz]);
    let b = vec3f(rb[kx], rb[ky], rb[kz]);
    let c = vec3f(rc[kx], rc[ky], rc[kz]);
    // Sheared to the ray's frame: the ray is the z axis.
    let ax = a.x - sx * a.z;
    let ay = a.y - sy * a.z;
    let bx = b.x - sx * b.z;
    let by = b.y - sy * b.z;
    let cx = c.x - sx * c.z;
    let cy = c.y - sy * c.z;
    // Scaled barycentrics: twice the signed areas seen from the ray.
    let u = cx * by - cy * bx;
    let v = ax * cy - ay * cx;
    let w = bx * ay - by * ax;
    if ((u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0)) {
        return INF;
    }
    let det = u + v + w;
    if (det == 0.0) {
        return INF;
    }
    let az = sz * a.z;
    let bz = sz * b.z;
    let cz = sz * c.z;
    let t = (u * az + v * bz + w * cz) / det;
    if (t > t_min && t < t_max) {
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
