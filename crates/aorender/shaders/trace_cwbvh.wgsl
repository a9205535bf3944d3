//#import cwbvh.wgsl
//#import per_lane.wgsl
// Traversal of the compressed 8-wide BVH, a ray per lane, as one loop that tests a
// primitive and visits a node in each iteration.

// Closest hit within (0, t_max) or, with any_hit, the first hit found; none where
// t_max <= 0. A leaf entry that is an instance (src/bvh/layout.rs PRIM_INSTANCE) carries
// the ray into its mesh's space and continues at its mesh's root, stacking on top of the
// top level's entries; once those are done, the top level resumes where it left off. The
// direction is not renormalized, so t means the same in both spaces.
//
// Each iteration tests one primitive of the leaf in front and visits one node: lavapipe
// runs a SIMD batch's lanes in lockstep through both halves of a branch, so an iteration
// that did only one of the two would pay for both. A leaf found while another's
// primitives are still being tested waits in a second slot; a node is visited only while
// that slot is free.
fn trace(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    share_steps();
    var hit = trace_planes(o, d, t_max, any_hit);
    if (frame.node_count == 0u || t_max <= 0.0 || (any_hit && hit.kind != HIT_NONE)) {
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
