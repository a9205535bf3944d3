//#import cwbvh.wgsl
// Cooperative traversal of the compressed 8-wide BVH: the eight lanes of a group (a
// subgroup of eight, or eight consecutive lanes of a wider one) trace one ray together,
// as Embree's single-ray kernels put a node's eight children in eight SIMD lanes (Lier,
// Stamminger & Selgrad, "CPU-style SIMD ray traversal on GPUs", HPG 2018). Every value of
// the traversal's state is the same in the group's lanes; what differs is the work:
//   - a node is read a texel per lane (lanes 0 to 4, the five texels) and handed round by
//     shuffles; lane i tests child i, and the hit bits are OR-ed by a butterfly of
//     shuffles;
//   - a leaf's primitives are tested eight at a time, one per lane, and the nearest hit
//     found by a butterfly.
// The group traces its lanes' rays in turn, so `trace` must be called by all eight lanes
// together, each with its own ray (t_max <= 0 for a lane with none); every branch the
// traversal takes is the same in all of them.
//
// Requires subgroup operations with subgroups of a multiple of eight lanes. Instances
// are not handled (the host traces scenes with instances a ray per lane).

// The lane's index in its group, and the subgroup invocation id of the group's lane 0.
var<private> group_lane: u32;
var<private> group_base: u32;

// Called by each entry point first, with every lane of the workgroup active.
fn begin_traversal(lid: u32) {
    lane = lid;
    // The invocation's subgroup id: its place among the active lanes, all of them here.
    let id = subgroupExclusiveAdd(1u);
    group_lane = id % GROUP_LANES;
    group_base = id - group_lane;
}

// x OR-ed over the group.
fn group_or(x: u32) -> u32 {
    let a = x | subgroupShuffleXor(x, 1u);
    let b = a | subgroupShuffleXor(a, 2u);
    return b | subgroupShuffleXor(b, 4u);
}

// Whether any lane of the group is live: a loop around `trace` runs while one is.
fn rays_left(live: bool) -> bool {
    return group_or(select(0u, 1u, live)) != 0u;
}

// Closest hit within (0, t_max) or, with any_hit, the first hit found, for each lane's
// ray. any_hit must be the same in all lanes of the group.
fn trace(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    share_steps();
    var hit = trace_planes(o, d, t_max, any_hit);
    let wants = frame.node_count != 0u && t_max > 0.0 && !(any_hit && hit.kind != HIT_NONE);
    var rays = group_or(select(0u, 1u << group_lane, wants));
    loop {
        if (rays == 0u || !take_step()) {
            break;
        }
        let r = firstTrailingBit(rays);
        rays &= rays - 1u;
        let source = group_base + r;
        let found = trace_group(subgroupShuffle(o, source), subgroupShuffle(d, source), subgroupShuffle(hit.t, source), any_hit);
        if (group_lane == r && found.kind != HIT_NONE) {
            hit = found;
        }
    }
    share_steps();
    return hit;
}

// One step of a butterfly that finds the nearest hit in the group: (t as bits, lane)
// against the lane `mask` away's, the smaller t and then the lower lane. t is never
// negative, so its bits order as it does.
fn group_nearest(a: vec2u, mask: u32) -> vec2u {
    let b = subgroupShuffleXor(a, mask);
    return select(a, b, b.x < a.x || (b.x == a.x && b.y < a.y));
}

// Hit bits of child `group_lane` of the node whose texels are n0 .. n4.
fn intersect_child(n0: vec4u, n1: vec4u, n2: vec4u, n3: vec4u, n4: vec4u, ray: RayState, t_max: f32) -> u32 {
    let w = child_words(n1, n2, n3, n4, group_lane);
    let nf = node_frame(n0, ray.o, ray.inv_d);
    return child_hit4(w.meta4, w.lo, w.hi, nf, ray.oct_inv4, t_max, w.shift);
}

// One ray, the same in every lane of the group, traced by all of them: the traversal of
// trace_cwbvh.wgsl (a primitive and a node each iteration, the two newest stack entries
// in registers) with a node's children and a leaf's primitives spread over the lanes.
fn trace_group(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    var hit = Hit(t_max, HIT_NONE, 0u, NO_INSTANCE);
    let ray = ray_state(o, d);
    var s = traversal_at(0u);
    loop {
        if (!take_step()) {
            break;
        }
        advance_leaf(&s);
        if (s.leaf.y != 0u) {
            // The leaf's eight highest primitives still to test, slot top - i in lane i:
            // the order the per-lane traversal tests them in.
            let top = msb24(s.leaf.y);
            let local = top - group_lane;
            let mine = group_lane <= top && ((s.leaf.y >> local) & 1u) != 0u;
            s.leaf.y &= select(0u, (1u << (top - 7u)) - 1u, top >= 7u);
            var t = hit.t;
            if (mine) {
                t = intersect_record(load_primitive(s.leaf.x + local), ray.o, ray.d, ray.sh, ray.op, hit.t);
            }
            // The nearest, and on equal distances the lowest lane (the per-lane
            // traversal keeps the first of equal hits). Written out: a loop would count
            // against lavapipe's iteration cap.
            let best = group_nearest(group_nearest(group_nearest(vec2u(bitcast<u32>(t), group_lane), 1u), 2u), 4u);
            if (bitcast<f32>(best.x) < hit.t) {
                hit = Hit(bitcast<f32>(best.x), HIT_PRIMITIVE, s.leaf.x + top - best.y, NO_INSTANCE);
                if (any_hit) {
                    break;
                }
            }
        }
        let index = next_node(&s, 0u, ray.oct_inv4);
        if (index != NO_NODE) {
            // The node, read a texel per lane (lanes 0 to 4) and handed round.
            let texel = load_node_texel(index, min(group_lane, 4u));
            let n0 = subgroupShuffle(texel, group_base);
            let n1 = subgroupShuffle(texel, group_base + 1u);
            let n2 = subgroupShuffle(texel, group_base + 2u);
            let n3 = subgroupShuffle(texel, group_base + 3u);
            let n4 = subgroupShuffle(texel, group_base + 4u);
            enter_node(&s, n0, n1, group_or(intersect_child(n0, n1, n2, n3, n4, ray, hit.t)));
        }
        if (traversal_done(s, 0u)) {
            break;
        }
    }
    return hit;
}
