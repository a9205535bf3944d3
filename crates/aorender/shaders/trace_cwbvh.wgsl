//#import trace_common.wgsl
// Traversal of obvhs's compressed 8-wide BVH (Ylitie, Karras & Laine, "Efficient
// Incoherent Ray Traversal on GPUs Through Compressed Wide BVHs", HPG 2017), following
// obvhs's node encoding and its `traverse!` macro, as one loop that tests a primitive and
// visits a node in each iteration.

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

// Hit bits of the four children whose bytes are in the given words: for an inner child
// one bit at 24 + its traversal priority, for a leaf its primitives' unary count at their
// offset (obvhs's CwBvhNode::intersect_ray).
fn intersect_children4(
    meta4: u32, lo: vec3u, hi: vec3u, scale: vec3f, origin: vec3f, neg: vec3<bool>,
    oct_inv4: u32, t_max: f32,
) -> u32 {
    let is_inner4 = (meta4 & (meta4 << 1u)) & 0x10101010u;
    let inner_mask4 = (is_inner4 >> 4u) * 0xffu;
    let bit_index4 = (meta4 ^ (oct_inv4 & inner_mask4)) & 0x1f1f1f1fu;
    let child_bits4 = (meta4 >> 5u) & 0x07070707u;
    // Near and far planes swap where the ray runs toward -axis.
    let near = select(lo, hi, neg);
    let far = select(hi, lo, neg);
    var mask = 0u;
    // Unrolled by hand: a loop here would count against lavapipe's iteration cap.
    mask |= child_hit(near, far, 0u, scale, origin, t_max, child_bits4, bit_index4);
    mask |= child_hit(near, far, 8u, scale, origin, t_max, child_bits4, bit_index4);
    mask |= child_hit(near, far, 16u, scale, origin, t_max, child_bits4, bit_index4);
    mask |= child_hit(near, far, 24u, scale, origin, t_max, child_bits4, bit_index4);
    return mask;
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
    let p = bitcast<vec3f>(node.n0.xyz);
    let e = (vec3u(node.n0.w, node.n0.w >> 8u, node.n0.w >> 16u) & vec3u(0xffu)) << vec3u(23u);
    let scale = bitcast<vec3f>(e) * inv_d;
    let origin = (p - o) * inv_d;
    let neg = inv_d < vec3f(0.0);
    let lo_a = vec3u(node.n2.x, node.n3.x, node.n4.x);
    let lo_b = vec3u(node.n2.y, node.n3.y, node.n4.y);
    let hi_a = vec3u(node.n2.z, node.n3.z, node.n4.z);
    let hi_b = vec3u(node.n2.w, node.n3.w, node.n4.w);
    return intersect_children4(node.n1.z, lo_a, hi_a, scale, origin, neg, oct_inv4, t_max)
        | intersect_children4(node.n1.w, lo_b, hi_b, scale, origin, neg, oct_inv4, t_max);
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

// Closest hit within (0, t_max) or, with any_hit, the first hit found. A leaf entry that
// is an instance (src/bvh/layout.rs PRIM_INSTANCE) carries the ray into its mesh's space and
// continues at its mesh's root, stacking on top of the top level's entries; once those
// are done, the top level resumes where it left off. The direction is not renormalized,
// so t means the same in both spaces.
//
// Each iteration tests one primitive of the leaf in front and visits one node: lavapipe
// runs a SIMD batch's lanes in lockstep through both halves of a branch, so an iteration
// that did only one of the two would pay for both. A leaf found while another's
// primitives are still being tested waits in a second slot; a node is visited only while
// that slot is free.
fn trace(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    share_steps();
    var hit = trace_planes(o, d, t_max, any_hit);
    if (frame.node_count == 0u || (any_hit && hit.kind != HIT_NONE)) {
        share_steps();
        return hit;
    }
    var ray = ray_state(o, d);
    var sp = 0u;
    // (first child node, hit bits in 24..32 | imask), and (first primitive, hit bits) of
    // the leaf in front and of the one waiting.
    var node_group = vec2u(0u, 0x80000000u);
    var prim_group = vec2u(0u, 0u);
    var prim_next = vec2u(0u, 0u);
    // The instance being traversed, and where the top level resumes after it.
    var instance = NO_INSTANCE;
    var base_sp = 0u;
    var top_node_group = vec2u(0u, 0u);
    var top_prim_group = vec2u(0u, 0u);
    var top_prim_next = vec2u(0u, 0u);
    // The stack's newest entries, near0 the newest, `near` of them in use; the entries
    // below them are in `stacks`, sp of them. The top level's, while an instance is
    // traversed.
    var near0 = vec2u(0u, 0u);
    var near1 = vec2u(0u, 0u);
    var near = 0u;
    var top_near0 = vec2u(0u, 0u);
    var top_near1 = vec2u(0u, 0u);
    var top_near = 0u;
    loop {
        if (!take_step()) {
            break;
        }
        if (prim_group.y == 0u) {
            prim_group = prim_next;
            prim_next = vec2u(0u, 0u);
        }
        if (prim_group.y != 0u) {
            let local = msb24(prim_group.y);
            prim_group.y &= ~(1u << local);
            let slot = prim_group.x + local;
            let p = load_primitive(slot);
            if (HAS_INSTANCES && bitcast<u32>(p.b.w) == PRIM_INSTANCE) {
                instance = slot;
                base_sp = sp;
                top_node_group = node_group;
                top_prim_group = prim_group;
                top_prim_next = prim_next;
                top_near0 = near0;
                top_near1 = near1;
                top_near = near;
                near = 0u;
                let to_object = load_affine(bitcast<u32>(p.a.z));
                ray = ray_state(affine_inverse_point(to_object, o), affine_vector(to_object, d));
                node_group = vec2u(bitcast<u32>(p.a.y), 0x80000000u);
                prim_group = vec2u(0u, 0u);
                prim_next = vec2u(0u, 0u);
            } else {
                let t = intersect_record(p, ray.o, ray.d, ray.sh, ray.op, hit.t);
                if (t < hit.t) {
                    hit = Hit(t, HIT_PRIMITIVE, slot, instance);
                    if (any_hit) {
                        break;
                    }
                }
            }
        }
        if (prim_next.y == 0u) {
            if ((node_group.y & 0xff000000u) == 0u) {
                if (near != 0u) {
                    node_group = near0;
                    near0 = near1;
                    near -= 1u;
                } else if (sp > base_sp) {
                    sp -= 1u;
                    node_group = stacks[sp * TRAVERSAL_LANES + lane];
                }
            }
            if ((node_group.y & 0xff000000u) != 0u) {
                let hits_imask = node_group.y;
                let child_bit = 24u + msb24(hits_imask >> 24u);
                node_group.y &= ~(1u << child_bit);
                if ((node_group.y & 0xff000000u) != 0u) {
                    if (near == NEAR_ENTRIES) {
                        stacks[sp * TRAVERSAL_LANES + lane] = near1;
                        sp += 1u;
                    }
                    near1 = near0;
                    near0 = node_group;
                    near = min(near + 1u, NEAR_ENTRIES);
                }
                let slot_index = (child_bit - 24u) ^ (ray.oct_inv4 & 0xffu);
                let relative_index = countOneBits(hits_imask & ~(0xffffffffu << slot_index));
                let node = load_node(node_group.x + relative_index);
                let hitmask = intersect_node(node, ray.o, ray.inv_d, ray.oct_inv4, hit.t);
                node_group = vec2u(node.n1.x, (hitmask & 0xff000000u) | (node.n0.w >> 24u));
                let leaf = vec2u(node.n1.y, hitmask & 0x00ffffffu);
                if (prim_group.y == 0u) {
                    prim_group = leaf;
                } else {
                    prim_next = leaf;
                }
            }
        }
        if (prim_group.y == 0u && prim_next.y == 0u && (node_group.y & 0xff000000u) == 0u && near == 0u && sp == base_sp) {
            if (HAS_INSTANCES && instance != NO_INSTANCE) {
                instance = NO_INSTANCE;
                base_sp = 0u;
                ray = ray_state(o, d);
                node_group = top_node_group;
                prim_group = top_prim_group;
                prim_next = top_prim_next;
                near0 = top_near0;
                near1 = top_near1;
                near = top_near;
            } else {
                break;
            }
        }
    }
    share_steps();
    return hit;
}
