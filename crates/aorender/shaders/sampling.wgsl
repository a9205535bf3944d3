// Random numbers, hemisphere warps and shading frames: the WGSL twin of src/sampling.rs.
// Function names match the Rust ones; the parity tests run both on the same inputs.

// PI, FRAC_PI_2, FRAC_PI_4 and FRAC_1_PI come with the generated header (Rust's
// std::f32::consts).

// 4-D PCG hash (Jarzynski & Olano, JCGT 2020).
fn pcg4d(v_in: vec4u) -> vec4u {
    var v = v_in * 1664525u + 1013904223u;
    v.x += v.y * v.w;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v.w += v.y * v.z;
    v ^= v >> vec4u(16u);
    v.x += v.y * v.w;
    v.y += v.z * v.x;
    v.z += v.x * v.y;
    v.w += v.y * v.z;
    return v;
}

// Top 24 bits to [0, 1); the largest value is the largest f32 below one.
fn u32_to_unit_float(x: u32) -> f32 {
    return f32(x >> 8u) * (1.0 / 16777216.0);
}

// The four uniform numbers of one sample: (pixel jitter x, y, hemisphere u1, u2).
fn sample_uniforms(px: u32, py: u32, sample_index: u32, seed: u32) -> vec4f {
    let h = pcg4d(vec4u(px, py, sample_index, seed));
    return vec4f(u32_to_unit_float(h.x), u32_to_unit_float(h.y), u32_to_unit_float(h.z), u32_to_unit_float(h.w));
}

fn safe_sqrt(x: f32) -> f32 {
    return sqrt(max(x, 0.0));
}

// Uniform hemisphere: z = u1, phi = 2 pi u2; pdf 1/2pi.
fn sample_uniform_hemisphere(u: vec2f) -> vec3f {
    let z = u.x;
    let r = safe_sqrt(1.0 - z * z);
    let phi = 2.0 * PI * u.y;
    return vec3f(r * cos(phi), r * sin(phi), z);
}

fn uniform_hemisphere_pdf() -> f32 {
    return 0.5 * FRAC_1_PI;
}

fn invert_uniform_hemisphere_sample(w: vec3f) -> vec2f {
    var phi = atan2(w.y, w.x);
    if (phi < 0.0) {
        phi += 2.0 * PI;
    }
    return vec2f(w.z, phi / (2.0 * PI));
}

// Shirley-Chiu concentric map from the square to the unit disk.
fn sample_uniform_disk_concentric(u: vec2f) -> vec2f {
    let o = 2.0 * u - vec2f(1.0);
    if (o.x == 0.0 && o.y == 0.0) {
        return vec2f(0.0);
    }
    var r: f32;
    var theta: f32;
    if (abs(o.x) > abs(o.y)) {
        r = o.x;
        theta = FRAC_PI_4 * (o.y / o.x);
    } else {
        r = o.y;
        theta = FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y);
    }
    return r * vec2f(cos(theta), sin(theta));
}

fn invert_uniform_disk_concentric_sample(p: vec2f) -> vec2f {
    let theta = atan2(p.y, p.x);
    let r = sqrt(p.x * p.x + p.y * p.y);
    // Fold theta into [-pi/4, 7pi/4) to find the square's wedge.
    let t = select(theta, theta + 2.0 * PI, theta < -FRAC_PI_4);
    var o: vec2f;
    if (t < FRAC_PI_4) {
        o = vec2f(r, r * t / FRAC_PI_4);
    } else if (t < 3.0 * FRAC_PI_4) {
        o = vec2f(r * (FRAC_PI_2 - t) / FRAC_PI_4, r);
    } else if (t < 5.0 * FRAC_PI_4) {
        o = vec2f(-r, r * (PI - t) / FRAC_PI_4);
    } else {
        o = vec2f(r * (t - 3.0 * FRAC_PI_2) / FRAC_PI_4, -r);
    }
    return (o + vec2f(1.0)) * 0.5;
}

// Polar map from the square to the unit disk: r = sqrt(u1), phi = 2 pi u2.
fn sample_uniform_disk_polar(u: vec2f) -> vec2f {
    let r = sqrt(u.x);
    let theta = 2.0 * PI * u.y;
    return r * vec2f(cos(theta), sin(theta));
}

fn invert_uniform_disk_polar_sample(p: vec2f) -> vec2f {
    var theta = atan2(p.y, p.x);
    if (theta < 0.0) {
        theta += 2.0 * PI;
    }
    return vec2f(p.x * p.x + p.y * p.y, theta / (2.0 * PI));
}

// Cosine-weighted hemisphere: uniform disk point projected up; pdf cos(theta)/pi.
// The height comes from the exact disk radius, not from 1 - x^2 - y^2.
fn sample_cosine_hemisphere(u: vec2f) -> vec3f {
    let d = sample_uniform_disk_concentric(u);
    let o = abs(2.0 * u - vec2f(1.0));
    let r = max(o.x, o.y);
    return vec3f(d.x, d.y, safe_sqrt((1.0 - r) * (1.0 + r)));
}

fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    return cos_theta * FRAC_1_PI;
}

fn invert_cosine_hemisphere_sample(w: vec3f) -> vec2f {
    return invert_uniform_disk_concentric_sample(w.xy);
}

// Cosine-weighted hemisphere through the polar disk map (the construction of the lecture
// "Monte Carlo Integration I", Nowrouzezahrai, ECSE 446/546).
fn sample_cosine_hemisphere_polar(u: vec2f) -> vec3f {
    let d = sample_uniform_disk_polar(u);
    return vec3f(d.x, d.y, safe_sqrt(1.0 - u.x));
}

fn invert_cosine_hemisphere_polar_sample(w: vec3f) -> vec2f {
    return invert_uniform_disk_polar_sample(w.xy);
}

// Direction in the local frame (z = normal) for the hemisphere id (HEMISPHERE_*).
fn sample_hemisphere(hemisphere: u32, u: vec2f) -> vec3f {
    if (hemisphere == HEMISPHERE_UNIFORM) {
        return sample_uniform_hemisphere(u);
    }
    if (hemisphere == HEMISPHERE_COSINE_POLAR) {
        return sample_cosine_hemisphere_polar(u);
    }
    return sample_cosine_hemisphere(u);
}

// Solid-angle density of a local direction.
fn hemisphere_pdf(hemisphere: u32, w: vec3f) -> f32 {
    if (hemisphere == HEMISPHERE_UNIFORM) {
        return uniform_hemisphere_pdf();
    }
    return cosine_hemisphere_pdf(w.z);
}

// The numbers that sample_hemisphere maps to w.
fn invert_hemisphere(hemisphere: u32, w: vec3f) -> vec2f {
    if (hemisphere == HEMISPHERE_UNIFORM) {
        return invert_uniform_hemisphere_sample(w);
    }
    if (hemisphere == HEMISPHERE_COSINE_POLAR) {
        return invert_cosine_hemisphere_polar_sample(w);
    }
    return invert_cosine_hemisphere_sample(w);
}

// cos(theta) / (pi pdf): the AO estimate of one unoccluded direction.
fn hemisphere_weight(hemisphere: u32, w: vec3f) -> f32 {
    if (hemisphere == HEMISPHERE_UNIFORM) {
        return 2.0 * w.z;
    }
    return 1.0;
}

// Orthonormal basis without a singularity (Duff et al., JCGT 2017, listing 3).
fn orthonormal_basis(n: vec3f) -> mat2x3f {
    let sign = select(-1.0, 1.0, n.z >= 0.0);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = vec3f(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let s = vec3f(b, sign + n.y * n.y * a, -n.y);
    return mat2x3f(t, s);
}

fn local_to_world(w: vec3f, n: vec3f) -> vec3f {
    let ts = orthonormal_basis(n);
    return ts[0] * w.x + ts[1] * w.y + n * w.z;
}

// Moves p, within `error` of its surface along the unit normal n, past every point that
// rounding allows: by `error` along n, then one float further in each coordinate the
// offset moves (pbrt-v4's OffsetRayOrigin). The twin of offset_ray_origin in
// src/sampling.rs; error 0 leaves p as it is.
fn offset_ray_origin(p: vec3f, n: vec3f, error: f32) -> vec3f {
    let offset = error * n;
    let moved = p + offset;
    let up = next_float_up(moved);
    let down = -next_float_up(-moved);
    return select(select(moved, down, offset < vec3f(0.0)), up, offset > vec3f(0.0));
}

// w mirrored about the plane of the unit surface normal g when it points below it; g zero
// leaves it. The twin of above_surface in src/sampling.rs.
fn above_surface(w: vec3f, g: vec3f) -> vec3f {
    let c = dot(w, g);
    return select(w, w - 2.0 * c * g, c < 0.0);
}

// The next float above each (finite) component; -0 counts as +0.
fn next_float_up(x: vec3f) -> vec3f {
    let v = select(x, vec3f(0.0), x == vec3f(0.0));
    let bits = bitcast<vec3u>(v);
    return bitcast<vec3f>(select(bits - vec3u(1u), bits + vec3u(1u), v >= vec3f(0.0)));
}

// A sampled AO direction (world space) and the sample's value where it escapes or is
// blocked: the integrand kept apart from the distribution (src/sky.rs).
struct SkySample {
    w: vec3f,
    open: f32,
    blocked: f32,
}

// E(beta) / E_h of an unoccluded plane under the overcast sky, black ground.
// beta from acos_poly: the platform's acos is 1e-5 off on lavapipe.
fn overcast_plane(cos_beta: f32) -> f32 {
    let c = clamp(cos_beta, -1.0, 1.0);
    let a = acos_poly(abs(c));
    let pi_minus_beta = select(a, PI - a, c >= 0.0);
    let s = safe_sqrt(1.0 - c * c);
    return (3.0 * PI * (1.0 + c) + 8.0 * (pi_minus_beta * c + s)) / (14.0 * PI);
}

// acos x for x in [0, 1] (Abramowitz & Stegun 4.4.46).
fn acos_poly(x: f32) -> f32 {
    var p = -0.0012624911;
    p = p * x + 0.0066700901;
    p = p * x - 0.0170881256;
    p = p * x + 0.0308918810;
    p = p * x - 0.0501743046;
    p = p * x + 0.0889789874;
    p = p * x - 0.2145988016;
    p = p * x + 1.5707963050;
    return safe_sqrt(1.0 - x) * p;
}

// The overcast sky's radiance at z = cos(theta_z) above the horizon, L_z = 1.
fn overcast_radiance(z: f32) -> f32 {
    return (1.0 + 2.0 * max(z, 0.0)) / 3.0;
}

// A sample of the overcast sky about the unit normal n (sky: SKY_*, up: the unit zenith).
// The twin of sample_overcast in src/sky.rs.
fn sample_overcast(sky: u32, normalise: u32, up: vec3f, ground_albedo: f32, hemisphere: u32, n: vec3f, u: vec2f) -> SkySample {
    let c = clamp(dot(n, up), -1.0, 1.0);
    // Irradiances over E_h = 7 pi / 9 (L_z = 1): the sky's, the ground's, their sum.
    let e_sky = overcast_plane(c);
    let ground = ground_albedo * (7.0 / 9.0);
    let e_ground = ground_albedo * 0.5 * (1.0 - c);
    let e_total = e_sky + e_ground;
    var scale = 9.0 / (7.0 * PI);
    var closed = e_total;
    if (normalise == SKY_NORMALISE_SURFACE) {
        scale = select(0.0, 9.0 / (7.0 * PI * e_total), e_total > 0.0);
        closed = select(0.0, 1.0, e_total > 0.0);
    }
    if (sky == SKY_WEIGHTED) {
        let w_local = sample_hemisphere(hemisphere, u);
        let w = local_to_world(w_local, n);
        let z = dot(w, up);
        let radiance = select(ground, overcast_radiance(z), z > 0.0);
        return SkySample(w, PI * radiance * hemisphere_weight(hemisphere, w_local) * scale, 0.0);
    }
    // The sky's share of the directions: 1 over a black ground.
    let a = select(1.0, e_sky / e_total, e_ground > 0.0);
    // t1: -up in the tangent plane; any tangent where n is parallel to up.
    let v = c * n - up;
    let len = length(v);
    let t1 = select(orthonormal_basis(n)[0], v / len, len > 1e-6);
    let t2 = cross(n, t1);
    let d = sample_uniform_disk_concentric(u);
    let s = safe_sqrt((1.0 - d.y) * (1.0 + d.y));
    let split = -s + 2.0 * a * s;
    let upper = a > 0.0 && (a >= 1.0 || d.x <= split);
    // The disk's row [-s, s] squeezed onto the sky's [-s, c s] and the ground's [c s, s];
    // the height from (s - x)(s + x), s + x exact at the limb.
    var x: f32;
    var s_plus_x: f32;
    var f_over_p: f32;
    if (upper) {
        let k = (1.0 + c) / (2.0 * a);
        s_plus_x = (d.x + s) * k;
        x = s_plus_x - s;
        f_over_p = PI * k;
    } else {
        let k = (1.0 - c) / (2.0 * (1.0 - a));
        x = c * s + (d.x - split) * k;
        s_plus_x = x + s;
        f_over_p = PI * k * ground;
    }
    let h = safe_sqrt((s - x) * s_plus_x);
    let w = x * t1 + d.y * t2 + h * n;
    if (upper) {
        f_over_p = f_over_p * overcast_radiance(dot(w, up));
    }
    let value = f_over_p * scale;
    if (sky == SKY_CONTROL_VARIATE) {
        return SkySample(w, closed, closed - value);
    }
    return SkySample(w, value, 0.0);
}
