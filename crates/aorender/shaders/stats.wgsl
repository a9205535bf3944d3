// A render's exact sums kept on the device, and the image-level sums its stopping rule
// needs, reduced on the device so that a check reads back a few bytes, not the film.
//
// `fold` adds the block in the film to the exact sums and empties the block, as the host's
// film.rs `ExactSums::add_block` and `add_replicates` do, in the same integers: Σv and
// Σv² as 128-bit two's complement words (low first) in quanta 2^BLOCK_SHIFT times finer
// than the block's, and, when the block is one whole replicate, its Σv squared exactly
// and rounded once to the quanta of the replicates' squares (2^REPLICATE_SQUARE_SHIFT
// coarser, halves up). Integer arithmetic alone: every adapter adds the same bits.
//
// `reduce` turns each pixel's sums into its variance of the mean v (f32, the formula of
// film.rs `standard_error`) and sums v, v² and the mean over a workgroup; `reduce_groups`
// sums the workgroups' partial sums in one workgroup. Both are bounded loops (eight
// halvings; a stride over at most 65,536 partial sums), far below lavapipe's cap.

//#import sums.wgsl

struct StatsParams {
    // Film slots.
    slots: u32,
    // Workgroups of `reduce`: its partial sums.
    groups: u32,
    // 1: `fold` adds the block's square as a replicate's; `reduce` estimates the error
    // from the replicates. 0: from independent samples.
    replicate: u32,
    // Workgroups per row of the dispatch (a dispatch has at most 65,535 per dimension).
    row_groups: u32,
    // Samples per pixel, complete replicates, samples per replicate.
    n: f32,
    k: f32,
    b: f32,
    _pad: f32,
    // Exponents of the quanta of Σv, Σv² and the replicates' squares.
    sum_exponent: i32,
    square_exponent: i32,
    replicate_exponent: i32,
    _pad2: i32,
}

@group(0) @binding(0) var<storage, read_write> stats_film: array<vec4u>;
@group(0) @binding(1) var<storage, read_write> stats_sum: array<vec4u>;
@group(0) @binding(2) var<storage, read_write> stats_square: array<vec4u>;
@group(0) @binding(3) var<storage, read_write> stats_replicate: array<vec4u>;
@group(0) @binding(4) var<uniform> stats_params: StatsParams;
// One partial sum (Σv, Σv², Σ mean, 0) per workgroup of `reduce`, then the total.
@group(0) @binding(5) var<storage, read_write> stats_partial: array<vec4f>;
// [0]: 2^32 − 1 − the first pixel whose block held a sample out of range (0: none).
@group(0) @binding(6) var<storage, read_write> stats_status: array<atomic<u32>>;

// log2 of the ratio of a block's quanta to the exact sums' (film.rs BLOCK_SHIFT).
const BLOCK_SHIFT_WORDS: u32 = 1u;
const BLOCK_SHIFT_BITS: u32 = 7u;
// log2 of the ratio of the quantum of a replicate's square to that of its exact square
// (film.rs `add_replicates`: sq_exponent + REPLICATE_SQ_SHIFT − 2 (sum_exponent + BLOCK_SHIFT)).
const REPLICATE_SQUARE_SHIFT: u32 = 23u;

var<workgroup> stats_shared: array<vec3f, 256>;

// x + y, wrapping at 2^128.
fn add128(x: vec4u, y: vec4u) -> vec4u {
    let lo = add64(x.xy, y.xy);
    let carry = select(0u, 1u, lo.y < x.y || (lo.y == x.y && lo.x < x.x));
    let hi = add64(add64(x.zw, y.zw), vec2u(carry, 0u));
    return vec4u(lo, hi);
}

// -x, wrapping at 2^128.
fn neg128(x: vec4u) -> vec4u {
    return add128(~x, vec4u(1u, 0u, 0u, 0u));
}

// The 64-bit word x (signed when `signed`) extended to 128 bits and shifted left by
// 32 × BLOCK_SHIFT_WORDS + BLOCK_SHIFT_BITS = 39.
fn widen_shifted(x: vec2u, signed: bool) -> vec4u {
    let sign = select(0u, 0xffffffffu, signed && (x.y >> 31u) == 1u);
    let k = BLOCK_SHIFT_BITS;
    return vec4u(0u, x.x << k, (x.y << k) | (x.x >> (32u - k)), (sign << k) | (x.y >> (32u - k)));
}

// a × b, 64 bits.
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

// A replicate's Σv (two's complement, below 2^63 in magnitude) squared exactly and
// rounded to the quanta of the replicates' squares (halves up).
fn replicate_square(s: vec2u) -> vec4u {
    let m = select(s, neg64(s), (s.y >> 31u) == 1u);
    let low = mul32(m.x, m.x);
    let cross = mul32(m.x, m.y);
    let high = mul32(m.y, m.y);
    var sq = vec4u(low, high);
    let shifted_cross = vec4u(0u, cross.x, cross.y, 0u);
    sq = add128(add128(sq, shifted_cross), shifted_cross);
    sq = add128(sq, vec4u(1u << (REPLICATE_SQUARE_SHIFT - 1u), 0u, 0u, 0u));
    let k = REPLICATE_SQUARE_SHIFT;
    return vec4u(
        (sq.x >> k) | (sq.y << (32u - k)),
        (sq.y >> k) | (sq.z << (32u - k)),
        (sq.z >> k) | (sq.w << (32u - k)),
        sq.w >> k,
    );
}

// The slot of this invocation in a dispatch of rows of `row_groups` workgroups.
fn stats_slot(group: vec3u, local: u32) -> u32 {
    return (group.y * stats_params.row_groups + group.x) * 256u + local;
}

@compute @workgroup_size(256)
fn fold(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    let i = stats_slot(group, local);
    if (i >= stats_params.slots) {
        return;
    }
    let w = stats_film[i];
    if (w.w == INACTIVE_SLOT) {
        return;
    }
    stats_film[i] = vec4u(0u);
    if ((w.w & OUT_OF_RANGE_HIGH) != 0u) {
        atomicMax(&stats_status[0], 0xffffffffu - i);
        return;
    }
    stats_sum[i] = add128(stats_sum[i], widen_shifted(w.xy, true));
    stats_square[i] = add128(stats_square[i], widen_shifted(w.zw, false));
    if (stats_params.replicate == 1u) {
        stats_replicate[i] = add128(stats_replicate[i], replicate_square(w.xy));
    }
}

// The signed 128-bit x in quanta of 2^e, as f32.
fn wide_to_f32(x: vec4u, e: i32) -> f32 {
    let negative = (x.w >> 31u) == 1u;
    let m = select(x, neg128(x), negative);
    let f = ldexp(f32(m.w), e + 96) + ldexp(f32(m.z), e + 64) + ldexp(f32(m.y), e + 32) + ldexp(f32(m.x), e);
    return select(f, -f, negative);
}

// Pixel i's (variance of its mean, mean): film.rs `standard_error` squared, in f32.
fn pixel_variance(i: u32) -> vec2f {
    let p = stats_params;
    let mean = wide_to_f32(stats_sum[i], p.sum_exponent) / p.n;
    var v: f32;
    if (p.replicate == 1u) {
        let r = wide_to_f32(stats_replicate[i], p.replicate_exponent);
        v = max((r / (p.b * p.b) - p.k * mean * mean) / (p.k - 1.0), 0.0) * p.b / p.n;
    } else {
        let q = wide_to_f32(stats_square[i], p.square_exponent);
        v = max((q - p.n * mean * mean) / (p.n - 1.0), 0.0) / p.n;
    }
    return vec2f(v, mean);
}

// Sums stats_shared over the workgroup into stats_shared[0].
fn reduce_shared(local: u32) {
    for (var half = 128u; half > 0u; half >>= 1u) {
        workgroupBarrier();
        if (local < half) {
            stats_shared[local] += stats_shared[local + half];
        }
    }
    workgroupBarrier();
}

@compute @workgroup_size(256)
fn reduce(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    let i = stats_slot(group, local);
    var x = vec3f(0.0);
    if (i < stats_params.slots) {
        let vm = pixel_variance(i);
        x = vec3f(vm.x, vm.x * vm.x, vm.y);
    }
    stats_shared[local] = x;
    reduce_shared(local);
    // The last row of the dispatch may have workgroups past the slots' last.
    let g = group.y * stats_params.row_groups + group.x;
    if (local == 0u && g < stats_params.groups) {
        stats_partial[g] = vec4f(stats_shared[0], 0.0);
    }
}

@compute @workgroup_size(256)
fn reduce_groups(@builtin(local_invocation_index) local: u32) {
    var x = vec3f(0.0);
    for (var g = local; g < stats_params.groups; g += 256u) {
        x += stats_partial[g].xyz;
    }
    stats_shared[local] = x;
    reduce_shared(local);
    if (local == 0u) {
        stats_partial[stats_params.groups] = vec4f(stats_shared[0], 0.0);
    }
}
