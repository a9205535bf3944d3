// A block's sums in 64-bit integers of two u32 words (low, high; Σv in two's
// complement): a sample's value in quanta of 2^(e − SAMPLE_FRACTION_BITS), its square in
// quanta of 2^(2e − SAMPLE_FRACTION_BITS), 2^e bounding every sample. Both come from the
// bits of the sample's f32 in integer arithmetic alone, which no compiler may fuse or
// reorder, so a block's sums are the CPU reference's (src/film.rs `quantize_sample`,
// `add_sample`) on every adapter that computed the same samples. Straight-line code: no
// loops count against lavapipe's cap. OUT_OF_RANGE_HIGH, the high word of
// film::OUT_OF_RANGE_BIT, marks a slot that received a sample out of range.

// x + y, wrapping at 2^64.
fn add64(x: vec2u, y: vec2u) -> vec2u {
    let lo = x.x + y.x;
    return vec2u(lo, x.y + y.y + select(0u, 1u, lo < x.x));
}

// x × 2^k for k in 0..=31.
fn shl64(x: vec2u, k: u32) -> vec2u {
    // x.x's bits that cross into the high word; none when k is 0 (a shift by 32 is not one).
    let carried = select(0u, x.x >> ((32u - k) & 31u), k > 0u);
    return vec2u(x.x << k, (x.y << k) | carried);
}

// x / 2^k for k in 1..=63, rounded to the nearest integer (halves up); x below 2^63.
fn shr64_rounded(x: vec2u, k: u32) -> vec2u {
    let h = k - 1u;
    let half = select(vec2u(1u << h, 0u), vec2u(0u, 1u << (h & 31u)), h >= 32u);
    let y = add64(x, half);
    let low = vec2u((y.x >> k) | (y.y << ((32u - k) & 31u)), y.y >> k);
    let high = vec2u(y.y >> (k & 31u), 0u);
    return select(low, high, k >= 32u);
}

// x × 2^k, rounded to the nearest integer where k is negative (film.rs `shift_rounded`).
fn shift_rounded(x: vec2u, k: i32) -> vec2u {
    let left = shl64(x, u32(clamp(k, 0, 31)));
    let right = shr64_rounded(x, u32(clamp(-k, 1, 63)));
    return select(right, left, k >= 0);
}

// -x, wrapping at 2^64.
fn neg64(x: vec2u) -> vec2u {
    return add64(~x, vec2u(1u, 0u));
}

// One sample in quanta: its value (two's complement) and its square.
struct SampleQuanta {
    value: vec2u,
    square: vec2u,
}

// The twin of film.rs `quantize_sample`: v / 2^(e − 54) and v² / 2^(2e − 54), rounded to
// the nearest quantum (halves away from zero), or (0, OUT_OF_RANGE) for a v not finite
// or past 2^e. v = m × 2^(b − 150), b the biased exponent (1 for subnormals); the square
// is the significand's, m² exact in 48 bits, never a float product.
fn quantize_sample(v: f32, e: i32) -> SampleQuanta {
    let bits = bitcast<u32>(v);
    let biased = (bits >> 23u) & 0xffu;
    let fraction = bits & 0x7fffffu;
    let m = select(fraction | 0x800000u, fraction, biased == 0u);
    let b = select(i32(biased), 1, biased == 0u);
    // v / 2^(e − 54) = m × 2^s.
    let s = b - 96 - e;
    let out = biased == 0xffu || s > 31 || (s == 31 && m > 0x800000u);
    let magnitude = shift_rounded(vec2u(m, 0u), s);
    // m² from 12-bit halves: a² 2^24 + 2ac 2^12 + c², each product below 2^25.
    let a = m >> 12u;
    let c = m & 0xfffu;
    let aa = a * a;
    let ac2 = 2u * a * c;
    let m2 = add64(add64(vec2u(aa << 24u, aa >> 8u), vec2u(ac2 << 12u, ac2 >> 20u)), vec2u(c * c, 0u));
    // v² / 2^(2e − 54) = m² × 2^(2s − 54).
    let square = shift_rounded(m2, 2 * s - i32(SAMPLE_FRACTION_BITS));
    let value = select(magnitude, neg64(magnitude), (bits >> 31u) == 1u);
    if (out) {
        return SampleQuanta(vec2u(0u), vec2u(0u, OUT_OF_RANGE_HIGH));
    }
    return SampleQuanta(value, square);
}

// A film slot (Σv low, high, Σv² low, high) with the sample v added: the twin of film.rs
// `add_sample`. An out-of-range sample's mark stays once set.
fn add_sample(slot: vec4u, v: f32, e: i32) -> vec4u {
    let q = quantize_sample(v, e);
    let sum = add64(slot.xy, q.value);
    var square = add64(slot.zw, q.square);
    square.y |= (q.square.y | slot.w) & OUT_OF_RANGE_HIGH;
    return vec4u(sum, square);
}
