// The live pixels of an adaptive render's film (those whose slot is not marked
// INACTIVE_SLOT), listed for the AO kernel's listed passes: tile by tile in the film's
// tile order, each tile's in `tile_pixel`'s order, so that the list is the same for the
// same marks on every adapter and the consecutive invocations of a SIMD batch trace
// pixels as close together as a tile's.
//
// Three dispatches, every loop bounded far below lavapipe's cap of 65,535 iterations an
// invocation: `count_live` takes one tile an invocation (64 pixels) and scans its
// block's counts in workgroup memory (eight steps); `scan_blocks`, one workgroup, scans
// the blocks' totals, each invocation a run of ceil(blocks / 256) of them (2 at 8 M
// pixels, 64 at 268 M); `list_live` writes each tile's live pixels from its offset.

//#import tiles.wgsl

struct CompactParams {
    // Film slots per row, and film rows.
    width: u32,
    rows: u32,
    // Tiles per row, and tiles.
    tiles_x: u32,
    tiles: u32,
    // Blocks of COMPACT_BLOCK tiles.
    blocks: u32,
    // Workgroups per row of a dispatch over the tiles.
    row_groups: u32,
    _pad0: u32,
    _pad1: u32,
}

const COMPACT_BLOCK: u32 = 256u;

@group(0) @binding(0) var<storage, read> compact_film: array<vec4u>;
@group(0) @binding(1) var<storage, read> compact_params: CompactParams;
// Per tile: its live pixels as bits in tile_pixel order (low, high word), and the live
// pixels of the tiles before it in its block.
@group(0) @binding(2) var<storage, read_write> compact_tiles: array<vec4u>;
// Per block: its live pixels, then (after `scan_blocks`) those of the blocks before it;
// past the last block, the total.
@group(0) @binding(3) var<storage, read_write> compact_blocks: array<u32>;
// A listed pass's counters (the kernel's `counters`), then from word LIVE_LIST the live
// pixels' film slots, in order.
@group(0) @binding(4) var<storage, read_write> live_list: array<u32>;

var<workgroup> compact_shared: array<u32, COMPACT_BLOCK>;

// The inclusive prefix sum of `x` over the workgroup's invocations (Hillis–Steele).
fn workgroup_scan(local: u32, x: u32) -> u32 {
    compact_shared[local] = x;
    for (var d = 1u; d < COMPACT_BLOCK; d <<= 1u) {
        workgroupBarrier();
        var add = 0u;
        if (local >= d) {
            add = compact_shared[local - d];
        }
        workgroupBarrier();
        compact_shared[local] += add;
    }
    workgroupBarrier();
    return compact_shared[local];
}

// The tile of tile index t, in tiles.
fn compact_tile(t: u32) -> vec2u {
    let p = compact_params;
    return vec2u(t % p.tiles_x, t / p.tiles_x);
}

// The film slot of pixel `px` of the film, if inside it.
fn compact_slot(px: vec2u) -> u32 {
    return px.y * compact_params.width + px.x;
}

@compute @workgroup_size(256)
fn count_live(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    let p = compact_params;
    let block = group.y * p.row_groups + group.x;
    let t = block * COMPACT_BLOCK + local;
    var mask = vec2u(0u);
    if (t < p.tiles) {
        let tile = compact_tile(t);
        for (var lid = 0u; lid < WORKGROUP_WIDTH * WORKGROUP_HEIGHT; lid++) {
            let px = tile_pixel(tile, lid);
            if (px.x < p.width && px.y < p.rows && compact_film[compact_slot(px)].w != INACTIVE_SLOT) {
                mask[lid / 32u] |= 1u << (lid % 32u);
            }
        }
    }
    let count = countOneBits(mask.x) + countOneBits(mask.y);
    let inclusive = workgroup_scan(local, count);
    if (t < p.tiles) {
        compact_tiles[t] = vec4u(mask, inclusive - count, 0u);
    }
    if (local == COMPACT_BLOCK - 1u && block < p.blocks) {
        compact_blocks[block] = inclusive;
    }
}

@compute @workgroup_size(256)
fn scan_blocks(@builtin(local_invocation_index) local: u32) {
    let n = compact_params.blocks;
    let run = (n + COMPACT_BLOCK - 1u) / COMPACT_BLOCK;
    let start = min(local * run, n);
    let end = min(start + run, n);
    var sum = 0u;
    for (var b = start; b < end; b++) {
        sum += compact_blocks[b];
    }
    let inclusive = workgroup_scan(local, sum);
    var before = inclusive - sum;
    for (var b = start; b < end; b++) {
        let c = compact_blocks[b];
        compact_blocks[b] = before;
        before += c;
    }
    if (local == COMPACT_BLOCK - 1u) {
        compact_blocks[n] = inclusive;
    }
}

@compute @workgroup_size(256)
fn list_live(@builtin(workgroup_id) group: vec3u, @builtin(local_invocation_index) local: u32) {
    let p = compact_params;
    let t = (group.y * p.row_groups + group.x) * COMPACT_BLOCK + local;
    if (t >= p.tiles) {
        return;
    }
    let info = compact_tiles[t];
    var at = compact_blocks[t / COMPACT_BLOCK] + info.z;
    let tile = compact_tile(t);
    for (var lid = 0u; lid < WORKGROUP_WIDTH * WORKGROUP_HEIGHT; lid++) {
        if (((info[lid / 32u] >> (lid % 32u)) & 1u) != 0u) {
            live_list[LIVE_LIST + at] = compact_slot(tile_pixel(tile, lid));
            at++;
        }
    }
}
