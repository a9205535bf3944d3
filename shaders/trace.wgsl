//#import bindings.wgsl
//#import intersect.wgsl
// BVH2 traversal as one loop that visits a node or a primitive per iteration, so the
// iterations of all of an invocation's rays can be counted against TRAVERSAL_BUDGET
// (lavapipe silently ends an invocation after 65,535 loop iterations).

const HIT_NONE: u32 = 0u;
const HIT_PRIMITIVE: u32 = 1u;
const HIT_PLANE: u32 = 2u;

struct Hit {
    t: f32,
    kind: u32,   // HIT_*
    index: u32,  // primitive or plane index
}

// Loop iterations spent by this invocation so far.
var<private> steps: u32 = 0u;
// Set when a traversal ran out of budget: its answer is wrong and the sample is void.
var<private> truncated: bool = false;

fn intersect_primitive(i: u32, o: vec3f, d: vec3f, t_max: f32) -> f32 {
    let p = primitives[i];
    if (bitcast<u32>(p.b.w) == PRIM_SPHERE) {
        return intersect_sphere(o, d, 0.0, t_max, p.a.xyz, p.b.x);
    }
    return intersect_triangle(o, d, 0.0, t_max, p.a.xyz, p.b.xyz, p.c.xyz);
}

// Closest hit within (0, t_max) or, with any_hit, the first hit found.
fn trace(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    var hit = Hit(t_max, HIT_NONE, 0u);
    for (var i = 0u; i < frame.plane_count; i++) {
        if (steps >= TRAVERSAL_BUDGET) {
            truncated = true;
            return hit;
        }
        steps += 1u;
        let t = intersect_plane(o, d, 0.0, hit.t, planes[i].normal, planes[i].d);
        if (t < hit.t) {
            hit = Hit(t, HIT_PLANE, i);
            if (any_hit) {
                return hit;
            }
        }
    }
    if (frame.node_count == 0u) {
        return hit;
    }
    let inv_d = safe_inverse(d);
    var stack: array<vec2u, STACK_SIZE>;
    var sp = 0u;
    // (index, count): count 0 is an inner node, count > 0 a run of primitives.
    var cur = vec2u(0u, 0u);
    loop {
        if (steps >= TRAVERSAL_BUDGET) {
            truncated = true;
            break;
        }
        steps += 1u;
        if (cur.y > 0u) {
            let t = intersect_primitive(cur.x, o, d, hit.t);
            if (t < hit.t) {
                hit = Hit(t, HIT_PRIMITIVE, cur.x);
                if (any_hit) {
                    break;
                }
            }
            cur = vec2u(cur.x + 1u, cur.y - 1u);
            if (cur.y > 0u) {
                continue;
            }
        } else {
            let node = nodes[cur.x];
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
    return hit;
}
