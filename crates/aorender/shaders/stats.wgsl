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
//
// An adaptive render's pixels have their own counts (`stats_counts`, added by `fold` to
// the pixels still sampled) and its decisions are taken here. Each check works only
// where something changed, and where lanes run in lockstep and pay for a branch's code
// whether or not one takes it (lavapipe's eight), the kernels walk runs of slots to the
// next one with work: a loop ends when every lane is done, a branch does not. On a CPU
// adapter none has a barrier, which costs lavapipe more the more code the kernel holds.

// - `evaluate` evaluates the rule of each pixel that changed since the last check
//   (accumulation.rs `pixel_sigma`, whose f32 steps these are) and keeps its (σ, v,
//   mean). `fold` and `stop_allocated` mark the pixels they change stale: a stopped
//   pixel's sums no longer change, so its rule is evaluated once, not at every check.
// - `group_sums` sums, one invocation a workgroup of 256 pixels (on a GPU,
//   `group_sums_shared`: the workgroup in shared memory), each pixel's (v, v², mean,
//   σ² / σ̃), σ̃ the root mean square of its row neighbours' kept σ (`share_sigma`), in
//   the tree of `reduce_shared`, and takes the fewest and most replicates. A workgroup
//   none of whose pixels, nor those up to SHARE_NEIGHBOURS slots beside them, changed
//   keeps its sums and extremes.
// - `allocate` counts the pixels still sampled that have the replicates an allocation
//   ∝ σ̃ gives them, and `stop_allocated` stops them, or only when some pixel goes on;
//   `mark` writes the stopped flags into the counts before they are read.

//#import sums.wgsl
//#import exact.wgsl

struct StatsParams {
    // Film slots.
    slots: u32,
    // Workgroups of 256 slots: the partial sums.
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
    // 0, exact.wgsl's `opaque_zero`.
    zero: u32,
    // Exponents of the quanta of Σv, Σv² and the replicates' squares.
    sum_exponent: i32,
    square_exponent: i32,
    replicate_exponent: i32,
    // 1: `stats_partial` has room for the kept evaluations (an adaptive render's).
    kept: u32,
    // Samples `fold` adds to the counts of the pixels it folds.
    taken: u32,
    // What a sample can be (accumulation.rs `RANGE_*`), and its largest magnitude.
    range: u32,
    max_value: f32,
    // `stop_allocated`: 1 stops the pixels `allocate` counted, 0 only when some pixel
    // goes on; and (both) replicates per unit of σ̃.
    met: u32,
    per_sigma: f32,
    // Pixels in a row of the image (a band holds whole rows).
    width: u32,
    _pad4: u32,
    _pad5: u32,
}

@group(0) @binding(0) var<storage, read_write> stats_film: array<vec4u>;
@group(0) @binding(1) var<storage, read_write> stats_sum: array<vec4u>;
@group(0) @binding(2) var<storage, read_write> stats_square: array<vec4u>;
@group(0) @binding(3) var<storage, read_write> stats_replicate: array<vec4u>;
// A storage buffer, not a uniform one: lavapipe would recompile the kernels at every
// dispatch for the uniform values they branch on (shaders/bindings.wgsl).
@group(0) @binding(4) var<storage, read> stats_params: StatsParams;
// Words: one partial sum (Σv, Σv², Σ mean, Σ σ² / σ̃) per workgroup of 256 slots, then the
// total (f32 bits, four words each); past them each pixel's kept evaluation in three
// regions (`kept_index`): σ's bits, v's, and the mean's bits inverted (0: stale, evaluated
// again; no mean is the NaN whose bits are all ones); then each workgroup's fewest and
// most replicates as `group_sums` took them (`group_index`). One binding more would pass
// the eight storage buffers every adapter allows a stage.
@group(0) @binding(5) var<storage, read_write> stats_partial: array<u32>;
// [0]: 2^32 − 1 − the first pixel whose block held a sample out of range (0: none).
// `group_sums`: [2] 2^32 − 1 − the fewest replicates of a pixel whose value is not exact
// (0: none), [3] the most of any. `allocate`: [1] the pixels that have their share, [2]
// those that go on. From [4], one word a workgroup of 256 slots: 1 where `evaluate`
// evaluated one of its pixels in this check.
@group(0) @binding(6) var<storage, read_write> stats_status: array<atomic<u32>>;
// Per pixel: samples folded, and complete replicates (bit 31: stopped, set by `mark`).
@group(0) @binding(7) var<storage, read_write> stats_counts: array<vec2u>;

// log2 of the ratio of a block's quanta to the exact sums' (film.rs BLOCK_SHIFT).
const BLOCK_SHIFT_WORDS: u32 = 1u;
const BLOCK_SHIFT_BITS: u32 = 7u;
// log2 of the ratio of the quantum of a replicate's square to that of its exact square
// (film.rs `add_replicates`: sq_exponent + REPLICATE_SQ_SHIFT − 2 (sum_exponent + BLOCK_SHIFT)).
const REPLICATE_SQUARE_SHIFT: u32 = 23u;

var<workgroup> stats_shared: array<vec4f, 256>;

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

// Kept regions of `stats_partial`: σ, v, and the mean's bits inverted (0: stale).
const KEPT_SIGMA: u32 = 0u;
const KEPT_VARIANCE: u32 = 1u;
const KEPT_MEAN: u32 = 2u;

// The word of `stats_partial` that holds pixel i's kept value `region`.
fn kept_index(region: u32, i: u32) -> u32 {
    return 4u * (stats_params.groups + 1u) + region * stats_params.slots + i;
}

fn kept(region: u32, i: u32) -> u32 {
    return stats_partial[kept_index(region, i)];
}

fn keep(region: u32, i: u32, value: u32) {
    stats_partial[kept_index(region, i)] = value;
}

// Fields of a workgroup's record: 2^32 − 1 − its fewest replicates of a pixel whose value
// is not exact (0: none), and its most.
const GROUP_FEWEST: u32 = 0u;
const GROUP_MOST: u32 = 1u;

// The word of `stats_partial` that holds field `field` of workgroup g's record.
fn group_index(g: u32, field: u32) -> u32 {
    return 4u * (stats_params.groups + 1u) + 3u * stats_params.slots + 2u * g + field;
}

// The first word of `stats_status` past the status: workgroup 0's evaluated flag.
const EVALUATED_BASE: u32 = 4u;

// Workgroup g's partial sum (or, g = `groups`, the total).
fn partial_sum(g: u32) -> vec4f {
    let b = 4u * g;
    return bitcast<vec4f>(vec4u(stats_partial[b], stats_partial[b + 1u], stats_partial[b + 2u], stats_partial[b + 3u]));
}

fn set_partial_sum(g: u32, x: vec4f) {
    let b = 4u * g;
    let u = bitcast<vec4u>(x);
    stats_partial[b] = u.x;
    stats_partial[b + 1u] = u.y;
    stats_partial[b + 2u] = u.z;
    stats_partial[b + 3u] = u.w;
}

// Pixel i's σ as `evaluate` kept it.
fn own_sigma(i: u32) -> f32 {
    return bitcast<f32>(kept(KEPT_SIGMA, i));
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
    if (stats_params.kept == 1u) {
        keep(KEPT_MEAN, i, 0u);
    }
    stats_counts[i] += vec2u(stats_params.taken, stats_params.replicate);
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
    // ldexp is an exact scaling; `exact` keeps a driver from fusing it as a product.
    let f = exact(ldexp(f32(m.w), e + 96)) + exact(ldexp(f32(m.z), e + 64)) + exact(ldexp(f32(m.y), e + 32))
        + exact(ldexp(f32(m.x), e));
    return select(f, -f, negative);
}

// Pixel i's (variance of its mean, mean): film.rs `standard_error` squared, in f32.
fn pixel_variance(i: u32) -> vec2f {
    let p = stats_params;
    let mean = exact_div(wide_to_f32(stats_sum[i], p.sum_exponent), p.n);
    var v: f32;
    if (p.replicate == 1u) {
        let r = wide_to_f32(stats_replicate[i], p.replicate_exponent);
        let spread = exact_div(r, p.b * p.b) - exact_mul(p.k * mean, mean);
        v = exact_div(max(exact_div(spread, p.k - 1.0), 0.0) * p.b, p.n);
    } else {
        let q = wide_to_f32(stats_square[i], p.square_exponent);
        v = exact_div(max(exact_div(q - exact_mul(p.n * mean, mean), p.n - 1.0), 0.0), p.n);
    }
    return vec2f(v, mean);
}

// The 97.5 % quantile of Student's t with `dof` ≥ 1 degrees of freedom, in f32
// (film.rs `t_quantile_975`), each division correctly rounded (accumulation.rs `t975`).
fn t975(dof: u32) -> f32 {
    switch dof {
        case 1u: { return 12.7062047; }
        case 2u: { return 4.30265273; }
        case 3u: { return 3.18244631; }
        case 4u: { return 2.77644511; }
        case 5u: { return 2.57058184; }
        case 6u: { return 2.44691185; }
        default: {
            let v = f32(dof);
            return 1.95996404 + exact_div(2.3722713, v) + exact_div(2.82249856, v * v)
                + exact_div(2.55584979, v * v * v) + exact_div(1.58953404, (v * v) * (v * v));
        }
    }
}

// An adaptive render's view of pixel i: (v, mean, σ, replicates), v its variance of the
// mean and σ the standard deviation of a replicate's mean the allocation takes (both 0
// before a second replicate: an exact pixel's, or no estimate yet, which the fewest
// replicates tell apart); accumulation.rs `pixel_sigma`, step for step. Every division
// and root is exact.wgsl's, correctly rounded, and every product that feeds a sum is
// kept apart from it, so the host's IEEE f32 steps give the same bits.
fn adaptive_pixel(i: u32) -> vec4f {
    let p = stats_params;
    let c = stats_counts[i];
    let kk = c.y & 0x7fffffffu;
    let n = f32(c.x);
    let s = wide_to_f32(stats_sum[i], p.sum_exponent);
    let mean = select(0.0, exact_div(s, n), c.x > 0u);
    if (kk < 2u) {
        return vec4f(0.0, mean, 0.0, f32(kk));
    }
    let q = wide_to_f32(stats_square[i], p.square_exponent);
    let r = wide_to_f32(stats_replicate[i], p.replicate_exponent);
    let k = f32(kk);
    let b = p.b;
    let variance = max(exact_div(exact_div(r, b * b) - exact_mul(k * mean, mean), k - 1.0), 0.0);
    let v = exact_div(variance * b, n);
    let se = exact_sqrt(v);
    var upper = p.max_value;
    if (p.range == 0u && s > 0.0 && q > 0.0) {
        upper = min(exact_div(q, s), p.max_value);
    }
    var lower = min(mean, 0.0);
    if (p.range == 2u) {
        lower = -p.max_value;
    }
    var width: f32;
    if (se > 1e-9 * max(abs(upper), 1.17549435e-38)) {
        let t = t975(kk - 1u);
        let lo = min(lower, mean);
        let hi = max(upper, mean);
        let range = hi - lo;
        let share = exact_div(mean - lo, range);
        let e = exact_div(se, range);
        let spread = exact_mul(share, 1.0 - share);
        if (range > 0.0 && spread > 0.0) {
            let kw = exact_div((t * t) * (e * e), spread);
            let centre = exact_div(share + exact_mul(0.5, kw), 1.0 + kw);
            let half = exact_div(exact_sqrt(kw * (spread + exact_mul(0.25, kw))), 1.0 + kw);
            width = range * (min(centre + half, 1.0) - max(centre - half, 0.0));
        } else {
            width = 2.0 * (t * se);
        }
    } else {
        let jeffreys = min(exact_div(3.8414588, exact_mul(2.0, n) + 1.0), 1.0);
        width = exact_mul(jeffreys, max(mean, 0.0)) + exact_mul(jeffreys, max(upper - mean, 0.0));
    }
    // Kept apart from the sums `reduce` adds it to.
    let sigma = exact_mul(max(se, exact_div(width, 3.92)), exact_sqrt(k));
    return vec4f(v, mean, sigma, k);
}

// Pixels on each side of a pixel, in its row, whose σ decide its share (accumulation.rs
// SHARE_NEIGHBOURS).
const SHARE_NEIGHBOURS: u32 = 2u;

// The largest standard deviation a replicate's mean can have: half the samples' range.
fn sigma_bound() -> f32 {
    return select(exact_mul(0.5, stats_params.max_value), stats_params.max_value, stats_params.range == 2u);
}

// The σ̃ that decides pixel i's share: the root mean square of the σ of the pixels up to
// SHARE_NEIGHBOURS on either side in its row that have one (σ > 0), never its own, so
// that its stopping is independent of its samples; `sigma_bound()` where none has.
// accumulation.rs `share_sigma`, step for step, on the σ `evaluate` kept; a loop of
// 2 × SHARE_NEIGHBOURS steps.
fn share_sigma(i: u32) -> f32 {
    let w = stats_params.width;
    let x = i % w;
    var sum = 0.0;
    var count = 0u;
    for (var d = 0u; d < 2u * SHARE_NEIGHBOURS; d++) {
        let nx = x + d + select(0u, 1u, d >= SHARE_NEIGHBOURS) - SHARE_NEIGHBOURS;
        let j = i - x + nx;
        if (nx < w && j < stats_params.slots) {
            let s = own_sigma(j);
            if (s > 0.0) {
                sum = sum + exact_mul(s, s);
                count += 1u;
            }
        }
    }
    if (count == 0u) {
        return sigma_bound();
    }
    return exact_sqrt(exact_div(sum, f32(count)));
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

// Consecutive slots an invocation of the kernels that walk runs looks after.
const RUN_SLOTS: u32 = 8u;

// The first slot of this invocation's run, in a dispatch of workgroups of 64 (a run past
// the slots' last is empty).
fn run_first(group: vec3u, n: vec3u, local: u32) -> u32 {
    return ((group.y * n.x + group.x) * 64u + local) * RUN_SLOTS;
}

// The end of the run that starts at `first`.
fn run_end(first: u32) -> u32 {
    return min(first + RUN_SLOTS, stats_params.slots);
}

// Whether slot i is a pixel still sampled.
fn is_live(i: u32) -> bool {
    return stats_film[i].w != INACTIVE_SLOT;
}

// The first slot from i, before `end`, whose kept evaluation is stale (`end`: none).
fn next_stale(i: u32, end: u32) -> u32 {
    var j = i;
    while (j < end && kept(KEPT_MEAN, j) != 0u) {
        j++;
    }
    return j;
}

// The first slot from i, before `end`, of a pixel still sampled (`end`: none).
fn next_live(i: u32, end: u32) -> u32 {
    var j = i;
    while (j < end && !is_live(j)) {
        j++;
    }
    return j;
}

// Evaluates the rule (an adaptive render's) of each pixel that changed since the last
// check, keeps it, and flags its workgroup of 256 slots. An invocation walks its run of
// RUN_SLOTS slots from stale one to stale one: where lanes run in lockstep and a branch
// costs its code whether or not a lane takes it (lavapipe), the rule is evaluated as
// often as the stalest lane needs, and not at all where every slot is kept. At most
// 2 × RUN_SLOTS steps besides the rule's own bounded loops.
@compute @workgroup_size(64)
fn evaluate(@builtin(workgroup_id) group: vec3u, @builtin(num_workgroups) n: vec3u,
        @builtin(local_invocation_index) local: u32) {
    opaque_zero = stats_params.zero;
    let first = run_first(group, n, local);
    let end = run_end(first);
    for (var i = next_stale(first, end); i < end; i = next_stale(i + 1u, end)) {
        let a = adaptive_pixel(i);
        keep(KEPT_SIGMA, i, bitcast<u32>(a.z));
        keep(KEPT_VARIANCE, i, bitcast<u32>(a.x));
        keep(KEPT_MEAN, i, ~bitcast<u32>(a.y));
        atomicStore(&stats_status[EVALUATED_BASE + i / 256u], 1u);
    }
}

// Pixel i's σ² / σ̃, from its kept σ > 0.
fn pixel_weight(i: u32) -> f32 {
    let sigma = own_sigma(i);
    let share = share_sigma(i);
    if (share > 0.0) {
        return exact_div(exact_mul(sigma, sigma), share);
    }
    return 0.0;
}

// Whether slot i (in range or not) has an estimate of σ, and so a weight.
fn has_sigma(i: u32) -> bool {
    return i < stats_params.slots && own_sigma(i) > 0.0;
}

// The first of workgroup g's slots from its l-th with a weight (256: none).
fn next_weighted(g: u32, l: u32) -> u32 {
    var j = l;
    while (j < 256u && !has_sigma(256u * g + j)) {
        j++;
    }
    return j;
}

// The bits of m, 0..256, in reverse order.
fn reverse8(m: u32) -> u32 {
    return reverseBits(m) >> 24u;
}

// Workgroup g's sums of its pixels' terms in the tree of `reduce_shared` (which adds the
// value at l + h to that at l for h = 128, 64, …, 1): its leaves taken in bit-reversed
// order and added as a binary counter carries, so that each addition has the operands,
// left and right, of the shared tree's. Slots past the last add zeros, as there. Also
// its fewest and most replicates (as `GROUP_*`).
fn group_tree(g: u32) -> array<vec4f, 2> {
    // The weights first, walking from one pixel with σ > 0 to the next (as `evaluate`
    // walks its run): the exact divisions run as often as the lane with the most such
    // pixels needs. At most 512 steps besides theirs.
    var weights: array<f32, 256>;
    for (var j = next_weighted(g, 0u); j < 256u; j = next_weighted(g, j + 1u)) {
        weights[j] = pixel_weight(256u * g + j);
    }
    var stack: array<vec4f, 9>;
    var depth = 0u;
    var fewest = 0u;
    var most = 0u;
    for (var m = 0u; m < 256u; m++) {
        let l = reverse8(m);
        let i = 256u * g + l;
        var x = vec4f(0.0);
        if (i < stats_params.slots) {
            let v = bitcast<f32>(kept(KEPT_VARIANCE, i));
            x = vec4f(v, exact_mul(v, v), bitcast<f32>(~kept(KEPT_MEAN, i)), weights[l]);
            let kk = stats_counts[i].y & 0x7fffffffu;
            if (!(stats_film[i].w == INACTIVE_SLOT && kk < 2u)) {
                fewest = max(fewest, 0xffffffffu - kk);
            }
            most = max(most, kk);
        }
        // Each trailing one of m closes a subtree whose left half is on the stack.
        for (var c = m; (c & 1u) == 1u; c >>= 1u) {
            depth -= 1u;
            x = stack[depth] + x;
        }
        stack[depth] = x;
        depth += 1u;
    }
    return array<vec4f, 2>(stack[0], bitcast<vec4f>(vec4u(fewest, most, 0u, 0u)));
}

// Adds a workgroup's fewest and most replicates to the status words.
fn add_extremes(fewest: u32, most: u32) {
    if (fewest != 0u) {
        atomicMax(&stats_status[2], fewest);
    }
    atomicMax(&stats_status[3], most);
}

// Whether `evaluate` evaluated a pixel in workgroup g or in one beside it (a pixel's σ̃
// reads σ up to SHARE_NEIGHBOURS slots away): its sums are to be taken again.
fn group_changed(g: u32) -> bool {
    var changed = 0u;
    for (var h = max(g, 1u) - 1u; h <= g + 1u && h < stats_params.groups; h++) {
        changed |= atomicLoad(&stats_status[EVALUATED_BASE + h]);
    }
    return changed != 0u;
}

// Keeps workgroup g's sums and extremes and adds its extremes to the status words.
fn keep_group(g: u32, sums: vec4f, fewest: u32, most: u32) {
    set_partial_sum(g, sums);
    stats_partial[group_index(g, GROUP_FEWEST)] = fewest;
    stats_partial[group_index(g, GROUP_MOST)] = most;
    add_extremes(fewest, most);
}

// Adds the extremes workgroup g kept to the status words.
fn add_kept_extremes(g: u32) {
    add_extremes(stats_partial[group_index(g, GROUP_FEWEST)], stats_partial[group_index(g, GROUP_MOST)]);
}

// One invocation a workgroup of 256 slots (after `evaluate`; for lanes in lockstep, the
// kernel without a barrier): its sums of the pixels' terms and its fewest and most
// replicates, taken again where `group_changed`, kept otherwise; either way added to the
// status words.
@compute @workgroup_size(64)
fn group_sums(@builtin(global_invocation_id) id: vec3u, @builtin(num_workgroups) n: vec3u) {
    opaque_zero = stats_params.zero;
    let g = id.y * n.x * 64u + id.x;
    if (g >= stats_params.groups) {
        return;
    }
    if (group_changed(g)) {
        let t = group_tree(g);
        let extremes = bitcast<vec4u>(t[1]);
        keep_group(g, t[0], extremes.x, extremes.y);
    } else {
        add_kept_extremes(g);
    }
}

// Whether this workgroup's sums are taken again, uniform across it once loaded.
var<workgroup> stats_flag: u32;
// This workgroup's fewest (as 2^32 − 1 − k) and most replicates.
var<workgroup> stats_fewest: atomic<u32>;
var<workgroup> stats_most: atomic<u32>;

// `group_sums` as a workgroup of 256 invocations, one a slot, the terms summed in
// `reduce_shared` (for GPUs, whose lanes branch apart in batches and whose workgroups
// share memory cheaply): the same sums and extremes.
@compute @workgroup_size(256)
fn group_sums_shared(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    opaque_zero = stats_params.zero;
    let i = stats_slot(group, local);
    // The last row of the dispatch may have workgroups past the slots' last.
    let g = group.y * stats_params.row_groups + group.x;
    if (local == 0u) {
        stats_flag = select(0u, 1u, g < stats_params.groups && group_changed(g));
    }
    if (workgroupUniformLoad(&stats_flag) == 0u) {
        if (local == 0u && g < stats_params.groups) {
            add_kept_extremes(g);
        }
        return;
    }
    var x = vec4f(0.0);
    if (i < stats_params.slots) {
        let v = bitcast<f32>(kept(KEPT_VARIANCE, i));
        var weight = 0.0;
        if (has_sigma(i)) {
            weight = pixel_weight(i);
        }
        x = vec4f(v, exact_mul(v, v), bitcast<f32>(~kept(KEPT_MEAN, i)), weight);
        let kk = stats_counts[i].y & 0x7fffffffu;
        if (!(stats_film[i].w == INACTIVE_SLOT && kk < 2u)) {
            atomicMax(&stats_fewest, 0xffffffffu - kk);
        }
        atomicMax(&stats_most, kk);
    }
    stats_shared[local] = x;
    reduce_shared(local);
    if (local == 0u) {
        keep_group(g, stats_shared[0], atomicLoad(&stats_fewest), atomicLoad(&stats_most));
    }
}

// Each pixel's (v, v², mean) summed per workgroup, v its variance of the mean.
@compute @workgroup_size(256)
fn reduce(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    opaque_zero = stats_params.zero;
    let i = stats_slot(group, local);
    var x = vec4f(0.0);
    if (i < stats_params.slots) {
        let vm = pixel_variance(i);
        x = vec4f(vm.x, exact_mul(vm.x, vm.x), vm.y, 0.0);
    }
    stats_shared[local] = x;
    reduce_shared(local);
    // The last row of the dispatch may have workgroups past the slots' last.
    let g = group.y * stats_params.row_groups + group.x;
    if (local == 0u && g < stats_params.groups) {
        set_partial_sum(g, stats_shared[0]);
    }
}

@compute @workgroup_size(256)
fn reduce_groups(@builtin(local_invocation_index) local: u32) {
    var x = vec4f(0.0);
    for (var g = local; g < stats_params.groups; g += 256u) {
        x += partial_sum(g);
    }
    stats_shared[local] = x;
    reduce_shared(local);
    if (local == 0u) {
        set_partial_sum(stats_params.groups, stats_shared[0]);
    }
}

// Whether pixel i, still sampled, has the replicates the allocation gives it:
// k ≥ σ̃ × per_sigma, σ̃ from the σ `evaluate` kept (the sums and counts have not
// changed since).
fn has_share(i: u32) -> bool {
    let k = f32(stats_counts[i].y & 0x7fffffffu);
    return k >= share_sigma(i) * stats_params.per_sigma;
}

// Counts the pixels still sampled that have their share ([1]) and those that go on ([2]),
// walking each run from live pixel to live pixel (as `evaluate` walks its run).
@compute @workgroup_size(64)
fn allocate(@builtin(workgroup_id) group: vec3u, @builtin(num_workgroups) n: vec3u,
        @builtin(local_invocation_index) local: u32) {
    opaque_zero = stats_params.zero;
    let first = run_first(group, n, local);
    let end = run_end(first);
    var counts = vec2u(0u);
    for (var i = next_live(first, end); i < end; i = next_live(i + 1u, end)) {
        counts += select(vec2u(0u, 1u), vec2u(1u, 0u), has_share(i));
    }
    if (counts.x > 0u) {
        atomicAdd(&stats_status[1], counts.x);
    }
    if (counts.y > 0u) {
        atomicAdd(&stats_status[2], counts.y);
    }
}

// Stops the pixels still sampled that have their share: with `met`, always; without, only
// when `allocate` before it counted some pixel that goes on (the bound is of these sums:
// where it is not met yet, the pixels go on). Walks runs as `allocate` does.
@compute @workgroup_size(64)
fn stop_allocated(@builtin(workgroup_id) group: vec3u, @builtin(num_workgroups) n: vec3u,
        @builtin(local_invocation_index) local: u32) {
    opaque_zero = stats_params.zero;
    if (stats_params.met == 0u && atomicLoad(&stats_status[2]) == 0u) {
        return;
    }
    let first = run_first(group, n, local);
    let end = run_end(first);
    // Stopped after the walk: a pixel's share reads its neighbours' σ, never their marks.
    var stops = 0u;
    for (var i = next_live(first, end); i < end; i = next_live(i + 1u, end)) {
        if (has_share(i)) {
            stops |= 1u << (i - first);
        }
    }
    for (var k = 0u; k < RUN_SLOTS; k++) {
        if ((stops & (1u << k)) != 0u) {
            stats_film[first + k] = vec4u(0u, 0u, 0u, INACTIVE_SLOT);
            // Its workgroup's fewest replicates may change with its mark.
            keep(KEPT_MEAN, first + k, 0u);
        }
    }
}

// Sets bit 31 of each pixel's replicate count where the pixel is stopped.
@compute @workgroup_size(256)
fn mark(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    let i = stats_slot(group, local);
    if (i >= stats_params.slots) {
        return;
    }
    let stopped = select(0u, 0x80000000u, stats_film[i].w == INACTIVE_SLOT);
    stats_counts[i].y = (stats_counts[i].y & 0x7fffffffu) | stopped;
}
