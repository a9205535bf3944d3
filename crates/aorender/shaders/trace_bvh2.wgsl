//#import trace_common.wgsl
//#import per_lane.wgsl
// BVH2 traversal as one loop that visits a node or a primitive per iteration.

// Node (src/bvh/layout.rs GpuNode, BVH2 with both children's boxes) comes with the
// generated header.

//#import node_bindings.wgsl

// Closest hit within (0, t_max) or, with any_hit, the first hit found; none where t_max <= 0.
fn trace(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    share_steps();
    var hit = trace_planes(o, d, t_max, any_hit);
    if (frame.node_count == 0u || t_max <= 0.0 || (any_hit && hit.kind != HIT_NONE)) {
        share_steps();
        return hit;
    }
    let inv_d = safe_inverse(d);
    let sh = make_shear(d);
    let op = permute_axes(o, sh.k);
    var stack: array<vec2u, STACK_SIZE>;
    var sp = 0u;
    // (index, count): count 0 is an inner node, count > 0 a run of primitives.
    var cur = vec2u(0u, 0u);
    loop {
        if (!take_step()) {
            break;
        }
        if (cur.y > 0u) {
            let t = intersect_primitive(cur.x, o, d, sh, op, hit.t);
            if (t < hit.t) {
                hit = Hit(t, HIT_PRIMITIVE, cur.x, NO_INSTANCE);
                if (any_hit) {
                    break;
                }
            }
            cur = vec2u(cur.x + 1u, cur.y - 1u);
            if (cur.y > 0u) {
                continue;
            }
        } else {
            let node = load_node(cur.x);
            let ta = intersect_box(node.a_min, node.a_max, o, inv_d, hit.t);
            var tb = INF;
            if (node.b_index != INVALID_INDEX) {
                tb = intersect_box(node.b_min, node.b_max, o, inv_d, hit.t);
            }
            let a = vec2u(node.a_index, node.a_count);
            let b = vec2u(node.b_index, node.b_count);
            if (ta < INF && tb < INF) {
                // Visit the nearer child first; the farther one waits on the stack.
                if (tb < ta) {
                    cur = b;
                    stack[sp] = a;
                } else {
                    cur = a;
                    stack[sp] = b;
                }
                sp += 1u;
                continue;
            }
            if (ta < INF) {
                cur = a;
                continue;
            }
            if (tb < INF) {
                cur = b;
                continue;
            }
        }
        if (sp == 0u) {
            break;
        }
        sp -= 1u;
        cur = stack[sp];
    }
    share_steps();
    return hit;
}
