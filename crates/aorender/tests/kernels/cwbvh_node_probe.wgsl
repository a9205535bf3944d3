//#import cwbvh_node.wgsl
// Test probe for tests/cwbvh_node.rs: the library's CWBVH node decoder on the adapter.
// Invocation i decodes child slot i % 8 of node i / 8 as the traversals do, for rays whose
// direction's signs are the bits of `octant` (x, y, z from bit 2 down): its box from the
// node's frame for a ray from the origin with inverse direction 1 (where a plane's t is
// its coordinate), the hit bits child_hit4 gives a ray that meets the child, and the node
// (an inner child) or the first primitive (a leaf) those bits name. No loops, so
// lavapipe's per-invocation loop cap is never near.

struct Params {
    count: u32, // nodes × 8
    octant: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> nodes: array<CwNode>;
// Per invocation: (box minimum bits, hit bits), (box maximum bits, node or first primitive).
@group(0) @binding(2) var<storage, read_write> outputs: array<vec4u>;

const CWBVH_NODE_PROBE_GROUP: u32 = 64u;

@compute @workgroup_size(64)
fn decode(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = gid.x + gid.y * groups.x * CWBVH_NODE_PROBE_GROUP;
    if (i >= params.count) {
        return;
    }
    let node = nodes[i / 8u];
    let w = child_words(node.n1, node.n2, node.n3, node.n4, i % 8u);
    let placed = node_frame(node.n0, vec3f(0.0), vec3f(1.0));
    let lo = child_planes(w.lo, w.shift, placed.scale, placed.origin);
    let hi = child_planes(w.hi, w.shift, placed.scale, placed.origin);
    // A frame of zero scale puts every plane at t = 0, inside [0, t_max]: the ray meets
    // every child.
    let everywhere = NodeFrame(vec3f(0.0), vec3f(0.0), vec3<bool>(false));
    let d = select(vec3f(1.0), vec3f(-1.0), (vec3u(params.octant) & vec3u(4u, 2u, 1u)) != vec3u(0u));
    let oct_inv4 = octant_inverse4(d);
    let hits = child_hit4(w.meta4, w.lo, w.hi, everywhere, oct_inv4, 1.0, w.shift);
    var index = 0u;
    if ((hits >> 24u) != 0u) {
        // As next_node: the hit bit's slot, back in the node's order.
        let slot = (firstLeadingBit(hits >> 24u)) ^ (oct_inv4 & 0xffu);
        index = child_node_index(node.n1.x, node.n0.w >> 24u, slot);
    } else if (hits != 0u) {
        // As the traversals: a leaf's primitives from the first primitive on.
        index = node.n1.y + firstTrailingBit(hits);
    }
    outputs[2u * i] = vec4u(bitcast<vec3u>(lo), hits);
    outputs[2u * i + 1u] = vec4u(bitcast<vec3u>(hi), index);
}
