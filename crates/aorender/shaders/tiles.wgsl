// The order of a tile's pixels, shared by the AO kernel and the list of live pixels
// (compact.wgsl), so that a listed pass gives a SIMD batch the pixels a tile would.

// The pixel of invocation `lid` of the workgroup that renders the 8 x 8 tile `tile`:
// every 8 consecutive invocations (a SIMD batch on lavapipe) take a 4 x 2 block, every
// 32 an 8 x 4 half: rays of a batch stay close together, so their traversals differ less.
fn tile_pixel(tile: vec2u, lid: u32) -> vec2u {
    let x = (lid & 3u) | ((lid >> 1u) & 4u);
    let y = ((lid >> 2u) & 1u) | ((lid >> 3u) & 6u);
    return tile * vec2u(WORKGROUP_WIDTH, WORKGROUP_HEIGHT) + vec2u(x, y);
}
