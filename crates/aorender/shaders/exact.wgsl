// f32 arithmetic that rounds as IEEE 754 does on every Vulkan adapter. Vulkan makes only
// OpFAdd, OpFSub, OpFMul and conversions correctly rounded, and lets a driver fuse a
// product into the sum it feeds (naga's SPIR-V carries no NoContraction); OpFDiv may be
// 2.5 ulp off and sqrt is 1/inversesqrt. `exact_mul` keeps a product out of any fusion,
// and `exact_div` and `exact_sqrt` correct the hardware's result with integer arithmetic,
// so the triangle test (intersect.wgsl) and the adaptive rule (stats.wgsl) give the CPU
// reference's bits. Loops are bounded by a few steps, far below lavapipe's cap.

// 0, read at run time (`Frame.zero` through bindings.wgsl's load_constants,
// `StatsParams.zero`, or a test kernel's parameter), so no compiler can prove it zero;
// each entry point sets it before any arithmetic.
var<private> opaque_zero: u32;

// x, behind an integer operation the compiler cannot see through: a product passed here
// cannot be fused with what follows, nor a sum factored around it.
fn exact(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ opaque_zero);
}

// a × b, rounded on its own whatever sum it feeds.
fn exact_mul(a: f32, b: f32) -> f32 {
    return exact(a * b);
}

// a × b, 64 bits (low, high).
fn mul32(a: u32, b: u32) -> vec2u {
    let a0 = a & 0xffffu;
    let a1 = a >> 16u;
    let b0 = b & 0xffffu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    return vec2u((p00 & 0xffffu) | (mid << 16u), p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u));
}

// x + y and x − y, 64 bits, wrapping (sums.wgsl's are not imported: this file stands alone).
fn exact_add64(x: vec2u, y: vec2u) -> vec2u {
    let lo = x.x + y.x;
    return vec2u(lo, x.y + y.y + select(0u, 1u, lo < x.x));
}

fn exact_sub64(x: vec2u, y: vec2u) -> vec2u {
    return vec2u(x.x - y.x, x.y - y.y - select(0u, 1u, x.x < y.x));
}

// -1, 0 or 1 as the 64-bit x is below, equal to or above y.
fn compare64(x: vec2u, y: vec2u) -> i32 {
    if (x.y != y.y) {
        return select(-1, 1, x.y > y.y);
    }
    if (x.x != y.x) {
        return select(-1, 1, x.x > y.x);
    }
    return 0;
}

// x × 2^k, x below 2^25 and k in 0..=25.
fn exact_shl(x: u32, k: u32) -> vec2u {
    let carried = select(0u, x >> ((32u - k) & 31u), k > 0u);
    return vec2u(x << k, carried);
}

// A finite nonzero magnitude (the bits of |x|) as m × 2^e, m in [2^23, 2^24).
struct Unpacked {
    m: u32,
    e: i32,
}

fn exact_unpack(magnitude: u32) -> Unpacked {
    let field = magnitude >> 23u;
    if (field == 0u) {
        // Subnormal: shift the leading bit up to bit 23.
        let shift = countLeadingZeros(magnitude) - 8u;
        return Unpacked(magnitude << shift, -149 - i32(shift));
    }
    return Unpacked((magnitude & 0x7fffffu) | 0x800000u, i32(field) - 150);
}

// m / 2^23 in [1, 2), for m in [2^23, 2^24): an operand the hardware divides well.
fn significand(m: u32) -> f32 {
    return bitcast<f32>((m & 0x7fffffu) | 0x3f800000u);
}

const EXACT_NAN: u32 = 0x7fc00000u;
const EXACT_INF: u32 = 0x7f800000u;
// Correction steps: from within 3 ulps of the significands' quotient, at most 7 are
// taken (6 units, plus the truncation to an integer); Vulkan's bound is 2.5 ulps.
const EXACT_STEPS: u32 = 12u;

// a / b correctly rounded (IEEE 754, to nearest, ties to even).
fn exact_div(a: f32, b: f32) -> f32 {
    let ma = exact_unpack(max(bitcast<u32>(a) & 0x7fffffffu, 1u)).m;
    let mb = exact_unpack(max(bitcast<u32>(b) & 0x7fffffffu, 1u)).m;
    // Both in [1, 2): no subnormal, overflow or range limit of OpFDiv is near.
    return div_rounded(a, b, significand(ma) / significand(mb));
}

// a / b correctly rounded, from `ratio`, within a few ulps of the quotient of their
// significands (each m / 2^23 in [1, 2) of exact_unpack). The quotient is an integer q
// in quanta 2^g of the result's binade (2^-149 below the normal range): q is the
// integer nearest ma 2^s / mb, which holds when (2q − 1) mb ≤ 2 ma 2^s ≤ (2q + 1) mb,
// with an even q at either equality; each step moves q by one toward it.
fn div_rounded(a: f32, b: f32, ratio: f32) -> f32 {
    let ua = bitcast<u32>(a);
    let ub = bitcast<u32>(b);
    let sign = (ua ^ ub) & 0x80000000u;
    let xa = ua & 0x7fffffffu;
    let xb = ub & 0x7fffffffu;
    if (xa > EXACT_INF || xb > EXACT_INF || (xa == 0u && xb == 0u) || (xa == EXACT_INF && xb == EXACT_INF)) {
        return bitcast<f32>(EXACT_NAN);
    }
    if (xa == EXACT_INF || xb == 0u) {
        return bitcast<f32>(sign | EXACT_INF);
    }
    if (xa == 0u || xb == EXACT_INF) {
        return bitcast<f32>(sign);
    }
    let pa = exact_unpack(xa);
    let pb = exact_unpack(xb);
    // |a / b| = (ma / mb) 2^d, in [2^e, 2^(e + 1)).
    let d = pa.e - pb.e;
    let e = d - select(0, 1, pa.m < pb.m);
    if (e > 127) {
        return bitcast<f32>(sign | EXACT_INF);
    }
    if (e < -150) {
        // Below half the smallest subnormal.
        return bitcast<f32>(sign);
    }
    let g = max(e - 23, -149);
    let s = d - g; // in -1..=24
    let twice = exact_shl(pa.m, u32(s + 1));
    var q = u32(max(ldexp(ratio, s), 0.0));
    // 2 q mb, moved by 2 mb with q: (2q ± 1) mb is it ± mb.
    var p = mul32(2u * q, pb.m);
    let mb = vec2u(pb.m, 0u);
    let mb2 = vec2u(2u * pb.m, 0u);
    for (var step = 0u; step < EXACT_STEPS; step++) {
        let above = compare64(twice, exact_add64(p, mb));
        let below = select(1, compare64(twice, exact_sub64(p, mb)), q > 0u);
        let odd = (q & 1u) == 1u;
        if (above > 0 || (above == 0 && odd)) {
            q += 1u;
            p = exact_add64(p, mb2);
        } else if (below < 0 || (below == 0 && odd)) {
            q -= 1u;
            p = exact_sub64(p, mb2);
        } else {
            break;
        }
    }
    // The binade's exponent field and q (whose 2^23 bit, when set, adds the hidden 1).
    let base = u32(max(e + 126, 0)) << 23u;
    return bitcast<f32>(sign | (base + q));
}

// sqrt(x) correctly rounded (IEEE 754).
fn exact_sqrt(x: f32) -> f32 {
    let magnitude = bitcast<u32>(x) & 0x7fffffffu;
    let p = exact_unpack(max(magnitude, 1u));
    // The significand in [1, 4) whose root sqrt_rounded takes.
    let scaled = ldexp(f32(p.m << select(1u, 0u, (p.e & 1) == 1)), -23);
    return sqrt_rounded(x, sqrt(scaled));
}

// sqrt(x) correctly rounded, from `root`, within a few ulps of the square root of x's
// significand scaled into [1, 4): x = M 2^(e') with M = m or 2m, e' odd, M / 2^23 in
// [1, 4). The root is r 2^((e' − 23) / 2) with r the integer nearest sqrt(M 2^23), in
// [2^23, 2^24]: (2r − 1)² < 4 M 2^23 < (2r + 1)² (never equal: odd against even).
fn sqrt_rounded(x: f32, root: f32) -> f32 {
    let ux = bitcast<u32>(x);
    let magnitude = ux & 0x7fffffffu;
    if (magnitude == 0u) {
        return x;
    }
    if (magnitude > EXACT_INF || (ux >> 31u) == 1u) {
        return bitcast<f32>(EXACT_NAN);
    }
    if (magnitude == EXACT_INF) {
        return x;
    }
    let p = exact_unpack(magnitude);
    let odd = (p.e & 1) == 1;
    let m = p.m << select(1u, 0u, odd);
    let e = select(p.e - 1, p.e, odd);
    let twice = exact_shl(m, 25u);
    var r = u32(max(ldexp(root, 23), 0.0));
    // 4 r², moved with r: (2r ± 1)² is it ± 4r + 1.
    var w = mul32(2u * r, 2u * r);
    for (var step = 0u; step < EXACT_STEPS; step++) {
        let up = exact_add64(w, vec2u(4u * r + 1u, 0u));
        let down = exact_add64(exact_sub64(w, vec2u(4u * r, 0u)), vec2u(1u, 0u));
        if (compare64(up, twice) < 0) {
            w = exact_add64(w, vec2u(8u * r + 4u, 0u));
            r += 1u;
        } else if (r > 0u && compare64(down, twice) > 0) {
            w = exact_add64(exact_sub64(w, vec2u(8u * r, 0u)), vec2u(4u, 0u));
            r -= 1u;
        } else {
            break;
        }
    }
    // Always a normal number: r 2^h with h = (e − 23) / 2, exponent field h + 150.
    let h = (e - 23) / 2;
    return bitcast<f32>(u32(h + 149) * 0x800000u + r);
}
