//#import trace_common.wgsl
// What both traversals of obvhs's compressed 8-wide BVH (Ylitie, Karras & Laine,
// "Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017)
// share: the node's child tests, following obvhs's node encoding, the ray's derived
// values, the stacks' workgroup memory, and the traversal's state and its steps
// (TraceState). trace_cwbvh.wgsl traces a ray per lane, trace_cwbvh_group.wgsl a ray per
// group of eight lanes.

// CwNode, obvhs's CwBvhNode as five vec4u words (src/bvh/layout.rs CwNodeWords, whose
// documentation gives the words), comes with the generated header.

//#import node_bindings.wgsl

// firstLeadingBit(x) for 0 < x < 2^24. On a CPU adapter from the exponent of f32(x),
// which is exact below 2^24: lavapipe's firstLeadingBit is a table lookup per nibble.
fn msb24(x: u32) -> u32 {
    if (CPU_LANES) {
        return (bitcast<u32>(f32(i32(x))) >> 23u) - 127u;
    }
    return firstLeadingBit(x);
}

// max(a, b) and min(a, b). On a CPU adapter as a comparison and a select, which x86
// does in one instruction (maxps, minps), and which gives b where either is NaN;
// lavapipe's max and min add a NaN check and a blend to each.
fn fmax_cpu(a: f32, b: f32) -> f32 {
    if (CPU_LANES) {
        return select(b, a, a > b);
    }
    return max(a, b);
}

fn fmin_cpu(a: f32, b: f32) -> f32 {
    if (CPU_LANES) {
        return select(b, a, a < b);
    }
    return min(a, b);
}

fn byte_at(word: u32, shift: u32) -> f32 {
    return f32((word >> shift) & 0xffu);
}

// A node's frame for a ray: the planes' scale and origin in units of t (a child's byte b
// on axis a lies at t = b × scale.a + origin.a), and the axes the ray runs toward -axis on.
struct NodeFrame {
    scale: vec3f,
    origin: vec3f,
    neg: vec3<bool>,
}

fn node_frame(n0: vec4u, o: vec3f, inv_d: vec3f) -> NodeFrame {
    let p = bitcast<vec3f>(n0.xyz);
    let e = (vec3u(n0.w, n0.w >> 8u, n0.w >> 16u) & vec3u(0xffu)) << vec3u(23u);
    return NodeFrame(bitcast<vec3f>(e) * inv_d, (p - o) * inv_d, inv_d < vec3f(0.0));
}

// Hit bits of the child whose bytes are at `shift` (0, 8, 16 or 24) of the words of four
// children: their meta bytes, and the low and high planes' bytes on each axis. For an
// inner child one bit at 24 + its traversal priority, for a leaf its primitives' unary
// count at their offset (obvhs's CwBvhNode::intersect_ray).
fn child_hit4(
    meta4: u32, lo: vec3u, hi: vec3u, nf: NodeFrame, oct_inv4: u32, t_max: f32, shift: u32,
) -> u32 {
    let is_inner4 = (meta4 & (meta4 << 1u)) & 0x10101010u;
    let inner_mask4 = (is_inner4 >> 4u) * 0xffu;
    let bit_index4 = (meta4 ^ (oct_inv4 & inner_mask4)) & 0x1f1f1f1fu;
    let child_bits4 = (meta4 >> 5u) & 0x07070707u;
    // Near and far planes swap where the ray runs toward -axis.
    let near = select(lo, hi, nf.neg);
    let far = select(hi, lo, nf.neg);
    return child_hit(near, far, shift, nf.scale, nf.origin, t_max, child_bits4, bit_index4);
}

// Hit bits of the four children whose bytes are in the given words.
fn intersect_children4(meta4: u32, lo: vec3u, hi: vec3u, nf: NodeFrame, oct_inv4: u32, t_max: f32) -> u32 {
    // Unrolled by hand: a loop here would count against lavapipe's iteration cap.
    return child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 0u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 8u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 16u)
        | child_hit4(meta4, lo, hi, nf, oct_inv4, t_max, 24u);
}

fn child_hit(
    near: vec3u, far: vec3u, shift: u32, scale: vec3f, origin: vec3f, t_max: f32,
    child_bits4: u32, bit_index4: u32,
) -> u32 {
    let tn3 = vec3f(byte_at(near.x, shift), byte_at(near.y, shift), byte_at(near.z, shift)) * scale + origin;
    let tf3 = vec3f(byte_at(far.x, shift), byte_at(far.y, shift), byte_at(far.z, shift)) * scale + origin;
    // On a CPU adapter a NaN plane distance (an overflowed scale times a zero byte)
    // cannot make tn or tf NaN, as the last operands, 0 and t_max, are not: it only
    // loosens the test.
    let tn = fmax_cpu(fmax_cpu(tn3.x, tn3.y), fmax_cpu(tn3.z, 0.0));
    // Widened as in intersect_box.
    let tf = fmin_cpu(fmin_cpu(tf3.x, tf3.y), fmin_cpu(tf3.z, t_max)) * BOX_EXIT_WIDENING;
    if (tn <= tf) {
        return ((child_bits4 >> shift) & 0xffu) << ((bit_index4 >> shift) & 0xffu);
    }
    return 0u;
}

fn intersect_node(node: CwNode, o: vec3f, inv_d: vec3f, oct_inv4: u32, t_max: f32) -> u32 {
    let nf = node_frame(node.n0, o, inv_d);
    let lo_a = vec3u(node.n2.x, node.n3.x, node.n4.x);
    let lo_b = vec3u(node.n2.y, node.n3.y, node.n4.y);
    let hi_a = vec3u(node.n2.z, node.n3.z, node.n4.z);
    let hi_b = vec3u(node.n2.w, node.n3.w, node.n4.w);
    return intersect_children4(node.n1.z, lo_a, hi_a, nf, oct_inv4, t_max)
        | intersect_children4(node.n1.w, lo_b, hi_b, nf, oct_inv4, t_max);
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
    let oct_inv4 = select(0x04040404u, 0u, d.x < 0.0) | select(0x02020202u, 0u, d.y < 0.0)
        | select(0x01010101u, 0u, d.z < 0.0);
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
    let relative_index = countOneBits(hits_imask & ~(0xffffffffu << slot_index));
    return (*s).node_group.x + relative_index;
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

