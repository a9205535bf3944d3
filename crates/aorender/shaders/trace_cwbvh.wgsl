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
    var s = traversal_at(0u);
    // The instance being traversed, and where the top level resumes after it: its state,
    // whose stack entries stay below base_sp.
    var instance = NO_INSTANCE;
    var base_sp = 0u;
    var top = s;
    loop {
        if (!take_step()) {
            break;
        }
        advance_leaf(&s);
        if (s.leaf.y != 0u) {
            let local = msb24(s.leaf.y);
            s.leaf.y &= ~(1u << local);
            let slot = s.leaf.x + local;
            let p = load_primitive(slot);
            if (HAS_INSTANCES && bitcast<u32>(p.b.w) == PRIM_INSTANCE) {
                instance = slot;
                base_sp = s.sp;
                top = s;
                let to_object = load_affine(bitcast<u32>(p.a.z));
                ray = ray_state(affine_inverse_point(to_object, o), affine_vector(to_object, d));
                s = traversal_at(bitcast<u32>(p.a.y));
                s.sp = base_sp;
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
        let index = next_node(&s, base_sp, ray.oct_inv4);
        if (index != NO_NODE) {
            let node = load_node(index);
            enter_node(&s, node.n0, node.n1, intersect_node(node, ray.o, ray.inv_d, ray.oct_inv4, hit.t));
        }
        if (traversal_done(s, base_sp)) {
            if (HAS_INSTANCES && instance != NO_INSTANCE) {
                instance = NO_INSTANCE;
                base_sp = 0u;
                ray = ray_state(o, d);
                s = top;
            } else {
                break;
            }
        }
    }
    share_steps();
    return hit;
}
