//#import trace_common.wgsl
// What a traversal of a ray per lane (trace_bvh2.wgsl, trace_cwbvh.wgsl) gives the kernel's
// entry points; trace_cwbvh_group.wgsl gives the same for a ray per group of lanes.

// Called by each entry point first.
fn begin_traversal(lid: u32) {
    lane = lid;
}

// Whether a loop around `trace` goes on: while the lane is live.
fn rays_left(live: bool) -> bool {
    return live;
}
