//#import sampling.wgsl
// Point samplers: the WGSL twin of src/sampler.rs (same names, same bits).

// STRATA_SALT, SOBOL_SHUFFLE_SALT, SOBOL_SCRAMBLE_SALT and ONE_MINUS_EPSILON come with
// the generated header, from src/sampler.rs.

// The point at `jitter` inside cell `cell` of an n x n grid (row-major).
fn stratum_point(cell: u32, n: u32, jitter: vec2f) -> vec2f {
    let inv = 1.0 / f32(n);
    let p = (vec2f(f32(cell % n), f32(cell / n)) + jitter) * inv;
    return min(p, vec2f(ONE_MINUS_EPSILON));
}

// Element i of a random permutation of 0..l chosen by p (Kensler 2013), with at most
// PERMUTE_WALK_LIMIT cycle-walking steps.
fn permute(i_in: u32, l: u32, p: u32) -> u32 {
    var w = l - 1u;
    w |= w >> 1u;
    w |= w >> 2u;
    w |= w >> 4u;
    w |= w >> 8u;
    w |= w >> 16u;
    var i = i_in;
    for (var k = 0u; k < PERMUTE_WALK_LIMIT; k++) {
        i ^= p;
        i *= 0xe170893du;
        i ^= p >> 16u;
        i ^= (i & w) >> 4u;
        i ^= p >> 8u;
        i *= 0x0929eb3fu;
        i ^= p >> 23u;
        i ^= (i & w) >> 1u;
        i *= 1u | (p >> 27u);
        i *= 0x6935fa69u;
        i ^= (i & w) >> 11u;
        i *= 0x74dcb303u;
        i ^= (i & w) >> 2u;
        i *= 0x9e501cc3u;
        i ^= (i & w) >> 2u;
        i *= 0xc860a3dfu;
        i &= w;
        i ^= i >> 5u;
        if (i < l) {
            break;
        }
    }
    return (i + p % l) % l;
}

// Hash-based Owen scrambling, most significant bit first (pbrt-v4 FastOwenScrambler).
fn nested_uniform_scramble(v_in: u32, seed: u32) -> u32 {
    var v = reverseBits(v_in);
    v ^= v * 0x3d20adeau;
    v += seed;
    v *= (seed >> 16u) | 1u;
    v ^= v * 0x05526c56u;
    v ^= v * 0x53a22864u;
    return reverseBits(v);
}

// Second Sobol dimension: the subset transform of the index bits, then bit reversal.
fn sobol_dim1(index: u32) -> u32 {
    var y = index;
    y ^= (y & 0xaaaaaaaau) >> 1u;
    y ^= (y & 0xccccccccu) >> 2u;
    y ^= (y & 0xf0f0f0f0u) >> 4u;
    y ^= (y & 0xff00ff00u) >> 8u;
    y ^= (y & 0xffff0000u) >> 16u;
    return reverseBits(y);
}

// Point `index` of a 2-D Owen-scrambled Sobol sequence with a shuffled index.
fn sobol_2d(index: u32, shuffle_seed: u32, seed_x: u32, seed_y: u32) -> vec2f {
    let i = nested_uniform_scramble(index, shuffle_seed);
    let x = nested_uniform_scramble(reverseBits(i), seed_x);
    let y = nested_uniform_scramble(sobol_dim1(i), seed_y);
    return vec2f(u32_to_unit_float(x), u32_to_unit_float(y));
}

// The numbers of sample `index` of pixel (px, py): (jitter x, y, hemisphere u1, u2), in
// replicates of `replicate` samples (0: one sequence).
fn sample_point_uniforms(sampler_id: u32, px: u32, py: u32, index: u32, seed: u32, strata: u32, replicate: u32) -> vec4f {
    let independent = sample_uniforms(px, py, index, seed);
    if (sampler_id == SAMPLER_SOBOL) {
        // Replicate k is the first points of a sequence of its own.
        var k = 0u;
        var i = index;
        if (replicate != 0u) {
            k = index / replicate;
            i = index % replicate;
        }
        let shuffle = pcg4d(vec4u(px, py, seed, SOBOL_SHUFFLE_SALT + k));
        let scramble = pcg4d(vec4u(px, py, seed, SOBOL_SCRAMBLE_SALT + k));
        let a = sobol_2d(i, shuffle.x, scramble.x, scramble.y);
        let b = sobol_2d(i, shuffle.y, scramble.z, scramble.w);
        return vec4f(a, b);
    }
    if (sampler_id == SAMPLER_STRATIFIED || sampler_id == SAMPLER_GRID) {
        let cells = strata * strata;
        let block = index / cells;
        let keys = pcg4d(vec4u(px, py, block, seed ^ STRATA_SALT));
        let jitter = select(independent, vec4f(0.5), sampler_id == SAMPLER_GRID);
        let j = index % cells;
        let a = stratum_point(permute(j, cells, keys.x), strata, jitter.xy);
        let b = stratum_point(permute(j, cells, keys.y), strata, jitter.zw);
        return vec4f(a, b);
    }
    return independent;
}
