//#import trace_common.wgsl
//#import cwbvh_node.wgsl
// What both traversals of obvhs's compressed 8-wide BVH (Ylitie, Karras & Laine,
// "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017)
// share beside the node's decoder (src/bvh/cwbvh/node.wgsl): the ray's derived values,
// the stacks' workgroup memory, and the traversal's state and its steps (TraceState).
// trace_cwbvh.wgsl traces a ray per lane, trace_cwbvh_group.wgsl a ray per group of eight
// lanes.

//#import node_bindings.wgsl

// firstLeadingBit(x) for 0 < x < 2^24. On a CPU adapter from the exponent of f32(x),
// which is exact below 2^24: lavapipe's firstLeadingBit is a table lookup per nibble.
fn msb24(x: u32) -> u32 {
    if (CPU_LANES) {
        return (bitcast<u32>(f32(i32(x))) >> 23u) - 127u;
    }
    return firstLeadingBit(x);
}

// What the traversal derives from a ray once: the node test's inverse direction and
// octant, the triangle test's shear and permuted origin.
struct RayState {
    o: vec3f,
    d: vec3f,
    inv_d: vec3f,
    oct_inv4: u32,
    sh: Shear,
    op: vec3f,
}

fn ray_state(o: vec3f, d: vec3f) -> RayState {
    let sh = make_shear(d);
    let oct_inv4 = octant_inverse4(d);
    return RayState(o, d, safe_inverse(d), oct_inv4, sh, permute_axes(o, sh.k));
}

// The traversal stacks of a workgroup's invocations, entry k of invocation `lane` at
// k × TRAVERSAL_LANES + lane. In workgroup memory rather than a private array: lavapipe
// reads and writes a private array at a per-lane index through every one of its entries,
// workgroup memory at one address per lane. Each lane's access is a turn of a loop over
// the SIMD batch's lanes, and a read costs a store-forwarding stall per lane that reads,
// so the traversal keeps its two newest entries in registers (NEAR_ENTRIES) and only
// older ones come here.
var<workgroup> stacks: array<vec2u, STACK_SIZE * TRAVERSAL_LANES>;
// Stack entries held in registers (near0, near1).
const NEAR_ENTRIES: u32 = 2u;

// Where a traversal stands: the node group being visited (first child node, hit bits in
// 24..32 | imask), the stack's newest entries (near0 the newest, `near` of them in use)
// and `sp` older ones in `stacks`, and the leaves whose primitives wait: (first
// primitive, hit bits) of the one in front and of the next.
struct TraceState {
    node_group: vec2u,
    near0: vec2u,
    near1: vec2u,
    near: u32,
    sp: u32,
    leaf: vec2u,
    leaf_next: vec2u,
}

// At the root, whose group is node 0 alone.
fn traversal_at(root: u32) -> TraceState {
    return TraceState(vec2u(root, 0x80000000u), vec2u(0u), vec2u(0u), 0u, 0u, vec2u(0u), vec2u(0u));
}

// Brings the next leaf to the front once the front one's primitives are done.
fn advance_leaf(s: ptr<function, TraceState>) {
    if ((*s).leaf.y == 0u) {
        (*s).leaf = (*s).leaf_next;
        (*s).leaf_next = vec2u(0u, 0u);
    }
}

// The next node to visit, nearest first, its group's others pushed; popped from the
// stack (above `base_sp`) when the current group is done. NO_NODE when none is left, or
// while a leaf waits behind the front one (a node is visited only while that slot is
// free).
fn next_node(s: ptr<function, TraceState>, base_sp: u32, oct_inv4: u32) -> u32 {
    if ((*s).leaf_next.y != 0u) {
        return NO_NODE;
    }
    if (((*s).node_group.y & 0xff000000u) == 0u) {
        if ((*s).near != 0u) {
            (*s).node_group = (*s).near0;
            (*s).near0 = (*s).near1;
            (*s).near -= 1u;
        } else if ((*s).sp > base_sp) {
            (*s).sp -= 1u;
            (*s).node_group = stacks[(*s).sp * TRAVERSAL_LANES + lane];
        }
    }
    if (((*s).node_group.y & 0xff000000u) == 0u) {
        return NO_NODE;
    }
    let hits_imask = (*s).node_group.y;
    let child_bit = 24u + msb24(hits_imask >> 24u);
    (*s).node_group.y &= ~(1u << child_bit);
    if (((*s).node_group.y & 0xff000000u) != 0u) {
        if ((*s).near == NEAR_ENTRIES) {
            stacks[(*s).sp * TRAVERSAL_LANES + lane] = (*s).near1;
            (*s).sp += 1u;
        }
        (*s).near1 = (*s).near0;
        (*s).near0 = (*s).node_group;
        (*s).near = min((*s).near + 1u, NEAR_ENTRIES);
    }
    let slot_index = (child_bit - 24u) ^ (oct_inv4 & 0xffu);
    return child_node_index((*s).node_group.x, hits_imask, slot_index);
}

// Takes in the node just visited, whose first texels are n0 and n1, and its children's
// hit bits: its inner children become the group to visit, its leaves wait.
fn enter_node(s: ptr<function, TraceState>, n0: vec4u, n1: vec4u, hitmask: u32) {
    (*s).node_group = vec2u(n1.x, (hitmask & 0xff000000u) | (n0.w >> 24u));
    let leaf = vec2u(n1.y, hitmask & 0x00ffffffu);
    if ((*s).leaf.y == 0u) {
        (*s).leaf = leaf;
    } else {
        (*s).leaf_next = leaf;
    }
}

// Nothing is left to test or visit above `base_sp`.
fn traversal_done(s: TraceState, base_sp: u32) -> bool {
    return s.leaf.y == 0u && s.leaf_next.y == 0u && (s.node_group.y & 0xff000000u) == 0u && s.near == 0u
        && s.sp == base_sp;
}

// next_node's answer when there is none.
const NO_NODE: u32 = 0xffffffffu;

