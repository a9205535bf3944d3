//#import exact.wgsl
// Ray-primitive intersection: the WGSL twin of src/geometry.rs. Each returns the hit
// distance in (t_min, t_max) or INF.

// INF (the largest f32), GAMMA1 … GAMMA16 (gamma(n) = n eps / (1 - n eps), eps = 2^-24,
// the bound on the relative error of n rounded operations) and BOX_EXIT_WIDENING are
// defined in Rust (src/geometry.rs) and come with the generated header.

// Watertight ray-triangle test of Woop, Benthin & Wald (JCGT 2013) on the stored
// vertices; both sides are hit and d need not be unit length. The twin of
// intersect_triangle in src/geometry.rs (whose comment has the full argument), operation
// for operation and in the same order, so the two agree bit for bit where the basic
// operations are IEEE. A shared edge's edge function is computed from the same sheared
// vertices with its operands swapped, so neighbours see exactly opposite values. That
// needs a*b - c*d kept as two rounded products, which a compiler that fuses one of them
// into the subtraction breaks (rays leaked through shared edges of a closed mesh on an
// H200); every product here goes through exact.wgsl's `exact_mul`. There is no f64
// fallback for edge functions that round to zero: rounding is monotone, so an f32 edge
// function has the right sign or is 0, and a 0 counts as either sign. That keeps the
// test conservative (a ray on an edge or vertex hits every triangle there) without f64,
// which most adapters lack. det == 0 (all three zero: edge-on, or a repeated vertex) is
// a miss, and so is a t within pbrt-v4's bound on its rounding error.

fn intersect_triangle(o: vec3f, d: vec3f, t_min: f32, t_max: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> f32 {
    return triangle_test(o, d, t_min, t_max, v0, v1, v2).x;
}

// The shear of the watertight test, a pure function of the ray direction d (so a
// traversal computes it once per ray): kz is the axis of largest |d| (ties to the lower
// axis), and x and y swap when the ray runs toward -z to keep the winding; s is
// (d[kx] / d[kz], d[ky] / d[kz], 1 / d[kz]).
struct Shear {
    k: vec3u,
    s: vec3f,
}

fn make_shear(d: vec3f) -> Shear {
    let ad = abs(d);
    var kz = 2u;
    if (ad.x >= ad.y && ad.x >= ad.z) {
        kz = 0u;
    } else if (ad.y >= ad.z) {
        kz = 1u;
    }
    var kx = select(kz + 1u, 0u, kz == 2u);
    var ky = select(kx + 1u, 0u, kx == 2u);
    let dz = component(d, kz);
    if (dz < 0.0) {
        let k = kx;
        kx = ky;
        ky = k;
    }
    return Shear(vec3u(kx, ky, kz), vec3f(component(d, kx) / dz, component(d, ky) / dz, 1.0 / dz));
}

// v[k] by selects: a vector indexed by a varying index would go through memory.
fn component(v: vec3f, k: u32) -> f32 {
    return select(select(v.z, v.y, k == 1u), v.x, k == 0u);
}

// v in the permuted axes (v[kx], v[ky], v[kz]).
fn permute_axes(v: vec3f, k: vec3u) -> vec3f {
    return vec3f(component(v, k.x), component(v, k.y), component(v, k.z));
}

// The test of intersect_triangle as (t, U, V, W): t is INF on a miss; U, V, W are the
// scaled barycentrics (weights of v0, v1, v2 times det = U + V + W).
fn triangle_test(o: vec3f, d: vec3f, t_min: f32, t_max: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> vec4f {
    let sh = make_shear(d);
    return triangle_test_sheared(permute_axes(o, sh.k), sh, t_min, t_max, v0, v1, v2);
}

// triangle_test with the ray's shear and its origin in the permuted axes precomputed:
// permute_axes(v) - op is permute_axes(v - o), component for component.
fn triangle_test_sheared(op: vec3f, sh: Shear, t_min: f32, t_max: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> vec4f {
    let sx = sh.s.x;
    let sy = sh.s.y;
    let sz = sh.s.z;
    // Vertices relative to the origin, in the permuted axes.
    let a = permute_axes(v0, sh.k) - op;
    let b = permute_axes(v1, sh.k) - op;
    let c = permute_axes(v2, sh.k) - op;
    // Sheared to the ray's frame: the ray is the z axis.
    let ax = a.x - exact_mul(sx, a.z);
    let ay = a.y - exact_mul(sy, a.z);
    let bx = b.x - exact_mul(sx, b.z);
    let by = b.y - exact_mul(sy, b.z);
    let cx = c.x - exact_mul(sx, c.z);
    let cy = c.y - exact_mul(sy, c.z);
    // Scaled barycentrics: twice the signed areas seen from the ray.
    let u = exact_mul(cx, by) - exact_mul(cy, bx);
    let v = exact_mul(ax, cy) - exact_mul(ay, cx);
    let w = exact_mul(bx, ay) - exact_mul(by, ax);
    let miss = vec4f(INF, u, v, w);
    if ((u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0)) {
        return miss;
    }
    let det = u + v + w;
    if (det == 0.0) {
        return miss;
    }
    let az = sz * a.z;
    let bz = sz * b.z;
    let cz = sz * c.z;
    let t = (exact_mul(u, az) + exact_mul(v, bz) + exact_mul(w, cz)) / det;
    if (!(t > t_min && t < t_max)) {
        return miss;
    }
    // pbrt-v4's bound on the error of t (src/geometry.rs, operation for operation).
    let max_zt = max(max(abs(az), abs(bz)), abs(cz));
    let max_z = max(max(abs(a.z), abs(b.z)), abs(c.z));
    let max_xt = max(max(abs(ax), abs(bx)), abs(cx));
    let max_yt = max(max(abs(ay), abs(by)), abs(cy));
    let delta_x = GAMMA5 * (max_xt + max_z);
    let delta_y = GAMMA5 * (max_yt + max_z);
    let delta_z = GAMMA3 * max_zt;
    let delta_e = 2.0 * (GAMMA2 * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
    let max_e = max(max(abs(u), abs(v)), abs(w));
    let delta_t = 3.0 * (GAMMA3 * max_e * max_zt + delta_e * max_zt + delta_z * max_e) / abs(det);
    if (t > delta_t) {
        return vec4f(t, u, v, w);
    }
    return miss;
}

// Cancellation-free ray-sphere (Haines et al., Ray Tracing Gems ch. 7); d is unit length.
// When c is within its rounding error the origin is on the sphere and the root c / q
// near 0 is that contact, not a hit (src/geometry.rs).
fn intersect_sphere(o: vec3f, d: vec3f, t_min: f32, t_max: f32, center: vec3f, radius: f32) -> f32 {
    let f = o - center;
    let b = -dot(f, d);
    let l = f + b * d;
    let disc = radius * radius - dot(l, l);
    if (disc < 0.0) {
        return INF;
    }
    let ff = dot(f, f);
    let c = ff - radius * radius;
    let q = b + select(-sqrt(disc), sqrt(disc), b >= 0.0);
    if (q == 0.0) {
        return INF;
    }
    let t0 = select(c / q, -INF, abs(c) <= GAMMA6 * (ff + radius * radius));
    let t1 = q;
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

// Infinite plane through `point` with normal n, both sides; an origin within rounding
// of the plane does not hit it (src/geometry.rs).
fn intersect_plane(o: vec3f, d: vec3f, t_min: f32, t_max: f32, n: vec3f, point: vec3f) -> f32 {
    let denom = dot(n, d);
    if (denom == 0.0) {
        return INF;
    }
    let to_plane = point - o;
    let num = dot(n, to_plane);
    if (abs(num) <= GAMMA5 * dot(abs(n), abs(to_plane))) {
        return INF;
    }
    let t = num / denom;
    if (t > t_min && t < t_max) {
        return t;
    }
    return INF;
}

// A hit point as exact as the hit allows, its unit geometric normal (either side) and a
// bound on its distance from the surface along the normal (src/geometry.rs SurfacePoint).
struct SurfacePoint {
    p: vec3f,
    n: vec3f,
    error: f32,
}

// A triangle's hit point, unit normal and componentwise error bound.
struct TriangleHit {
    p: vec3f,
    n: vec3f,
    p_error: vec3f,
}

// By barycentric interpolation of the vertices: within GAMMA8 sum |b_i v_i| of the
// triangle however far the ray came (src/geometry.rs triangle_hit_point).
fn triangle_hit(o: vec3f, d: vec3f, t: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> TriangleHit {
    let n = normalize(cross(v1 - v0, v2 - v0));
    let r = triangle_test(o, d, 0.0, INF, v0, v1, v2);
    let det = r.y + r.z + r.w;
    var p: vec3f;
    var p_error: vec3f;
    if (det != 0.0) {
        let b = r.yzw * (1.0 / det);
        let b0 = b.x * v0;
        let b1 = b.y * v1;
        let b2 = b.z * v2;
        p = b0 + b1 + b2;
        p_error = GAMMA8 * (abs(b0) + abs(b1) + abs(b2));
    } else {
        p = o + t * d;
        p_error = GAMMA8 * abs(p);
    }
    return TriangleHit(p, n, p_error);
}

fn triangle_hit_point(o: vec3f, d: vec3f, t: f32, v0: vec3f, v1: vec3f, v2: vec3f) -> SurfacePoint {
    let h = triangle_hit(o, d, t, v0, v1, v2);
    return SurfacePoint(h.p, h.n, dot(abs(h.n), h.p_error));
}

// An affine map as rows (m_i0, m_i1, m_i2, t_i), evaluated as src/geometry.rs AffineRows is.
struct Affine {
    r0: vec4f,
    r1: vec4f,
    r2: vec4f,
}

fn affine_row_point(m: vec4f, p: vec3f) -> f32 {
    return ((m.x * p.x + m.y * p.y) + m.z * p.z) + m.w;
}

fn affine_point(m: Affine, p: vec3f) -> vec3f {
    return vec3f(affine_row_point(m.r0, p), affine_row_point(m.r1, p), affine_row_point(m.r2, p));
}

fn affine_row_vector(m: vec4f, v: vec3f) -> f32 {
    return (m.x * v.x + m.y * v.y) + m.z * v.z;
}

fn affine_vector(m: Affine, v: vec3f) -> vec3f {
    return vec3f(affine_row_vector(m.r0, v), affine_row_vector(m.r1, v), affine_row_vector(m.r2, v));
}

// The preimage of p under y = L x + t, from the rows of L^-1 with t in their last column:
// L^-1 (p - t) (src/geometry.rs InverseAffine).
fn affine_inverse_point(m: Affine, p: vec3f) -> vec3f {
    return affine_vector(m, p - vec3f(m.r0.w, m.r1.w, m.r2.w));
}

// |M| a + |t| b.
fn affine_row_abs(m: vec4f, a: vec3f, b: f32) -> f32 {
    let x = abs(m);
    return ((x.x * a.x + x.y * a.y) + x.z * a.z) + b * x.w;
}

fn affine_abs(m: Affine, a: vec3f, b: f32) -> vec3f {
    return vec3f(affine_row_abs(m.r0, a, b), affine_row_abs(m.r1, a, b), affine_row_abs(m.r2, a, b));
}

// The transpose of the linear part times v.
fn affine_transpose_vector(m: Affine, v: vec3f) -> vec3f {
    return (m.r0.xyz * v.x + m.r1.xyz * v.y) + m.r2.xyz * v.z;
}

// The world-space hit point of an instance's triangle, found in the mesh's space; the
// error bound covers the way there and back (src/geometry.rs instance_hit_point).
fn instance_hit_point(
    to_world: Affine, to_object: Affine, o: vec3f, d: vec3f, t: f32, v0: vec3f, v1: vec3f, v2: vec3f,
) -> SurfacePoint {
    let h = triangle_hit(affine_inverse_point(to_object, o), affine_vector(to_object, d), t, v0, v1, v2);
    let p = affine_point(to_world, h.p);
    let forward = GAMMA3 * affine_abs(to_world, abs(h.p), 0.0) + GAMMA1 * abs(p)
        + (1.0 + GAMMA3) * affine_abs(to_world, h.p_error, 0.0);
    let q = abs(p - vec3f(to_world.r0.w, to_world.r1.w, to_world.r2.w)) + 2.0 * forward;
    let back = affine_abs(to_world, GAMMA5 * affine_abs(to_object, q, 0.0), 0.0);
    let n = normalize(affine_transpose_vector(to_object, h.n));
    return SurfacePoint(p, n, dot(abs(n), forward + back) * (1.0 + GAMMA16));
}

// Projected back onto the sphere (src/geometry.rs sphere_hit_point).
fn sphere_hit_point(o: vec3f, d: vec3f, t: f32, center: vec3f, radius: f32) -> SurfacePoint {
    let n = normalize(o + t * d - center);
    let offset = radius * n;
    let p = center + offset;
    let p_error = GAMMA8 * abs(offset) + GAMMA1 * abs(p);
    return SurfacePoint(p, n, dot(abs(n), p_error));
}

// Projected onto the plane through `point` (src/geometry.rs plane_hit_point).
fn plane_hit_point(o: vec3f, d: vec3f, t: f32, n: vec3f, point: vec3f) -> SurfacePoint {
    let q = o + t * d;
    let from_point = q - point;
    let p = q - n * dot(n, from_point);
    let error = GAMMA6 * dot(abs(n), abs(from_point)) + GAMMA1 * dot(abs(n), abs(p));
    return SurfacePoint(p, n, error);
}

// Slab test; returns the entry distance or INF. The exit distance is widened by
// BOX_EXIT_WIDENING (at least 1 + 2 gamma(3)) so rounding never culls a box the ray
// touches (Ize, "Robust BVH Ray Traversal", JCGT 2013).
fn intersect_box(bmin: vec3f, bmax: vec3f, o: vec3f, inv_d: vec3f, t_max: f32) -> f32 {
    let t0 = (bmin - o) * inv_d;
    let t1 = (bmax - o) * inv_d;
    let lo = min(t0, t1);
    let hi = max(t0, t1);
    let t_near = max(max(lo.x, lo.y), max(lo.z, 0.0));
    let t_far = min(min(hi.x, hi.y), min(hi.z, t_max)) * BOX_EXIT_WIDENING;
    return select(INF, t_near, t_near <= t_far);
}

// 1/d with each component kept away from zero, so the slab test never computes 0 * inf.
fn safe_inverse(d: vec3f) -> vec3f {
    let tiny = vec3f(1e-30);
    return 1.0 / select(d, select(-tiny, tiny, d >= vec3f(0.0)), abs(d) < tiny);
}
