//#import bindings.wgsl
//#import intersect.wgsl
//#import primitive_bindings.wgsl
//#import batch.wgsl
//#import lanes.wgsl
// What both BVH traversals share: the hit record, the iteration budget, primitives and
// planes. Every traversal loop iteration is counted in `steps` against
// dispatch.traversal_budget: lavapipe silently ends a SIMD batch of invocations after
// 65,535 loop iterations, counting each iteration that any of them runs, and the host
// leaves room in that cap for the other loops of the kernel.

const HIT_NONE: u32 = 0u;
const HIT_PRIMITIVE: u32 = 1u;
const HIT_PLANE: u32 = 2u;

// Top-level traversal (no instance entered).
const NO_INSTANCE: u32 = 0xffffffffu;

// What the scene holds (src/gpu/pipeline.rs sets these per scene; the defaults keep every
// path). The compiler drops the paths of what a scene lacks: lavapipe runs a SIMD batch's
// lanes in lockstep and executes every branch that is not constant, taken or not.
// Instances in the BVH.
override HAS_INSTANCES: bool = true;
// Spheres among the primitives.
override HAS_SPHERES: bool = true;
// Triangles among the primitives (placed once or in instanced meshes).
override HAS_TRIANGLES: bool = true;
// Infinite planes.
override HAS_PLANES: bool = true;

struct Hit {
    t: f32,
    kind: u32,      // HIT_*
    index: u32,     // primitive or plane index
    instance: u32,  // the slot of the instance record a primitive was reached through, or NO_INSTANCE
}

// The invocation's index in its workgroup, below TRAVERSAL_LANES (each entry point sets
// it): its column of a traversal's workgroup stacks.
var<private> lane: u32;

// Loop iterations spent so far, as the batch counts them where the device has subgroup
// operations: share_steps, before and after every traversal, gives the invocations that
// trace together the largest count among them, and within a traversal's loop those
// still running count every iteration the batch runs.
var<private> steps: u32 = 0u;
// Set when a traversal ran out of budget: its answer is wrong and the sample is void.
var<private> truncated: bool = false;

fn share_steps() {
    steps = batch_max(steps);
}

// Counts one loop iteration; false (and `truncated` set) once the budget is spent.
fn take_step() -> bool {
    if (steps >= dispatch.traversal_budget) {
        truncated = true;
        return false;
    }
    steps += 1u;
    return true;
}

// Primitive i of the leaf-ordered array against the ray (bindings.wgsl gives the record);
// sh and op are the ray's shear and permuted origin (make_shear, permute_axes), computed once
// per ray by the traversal.
fn intersect_primitive(i: u32, o: vec3f, d: vec3f, sh: Shear, op: vec3f, t_max: f32) -> f32 {
    return intersect_record(load_primitive(i), o, d, sh, op, t_max);
}

fn intersect_record(p: Primitive, o: vec3f, d: vec3f, sh: Shear, op: vec3f, t_max: f32) -> f32 {
    if (is_sphere(p)) {
        return intersect_sphere(o, d, 0.0, t_max, p.a.xyz, p.b.x);
    }
    return triangle_test_sheared(op, sh, 0.0, t_max, p.a.xyz, p.b.xyz, p.c.xyz).x;
}

// Whether a primitive record (not an instance) is a sphere rather than a triangle.
fn is_sphere(p: Primitive) -> bool {
    return HAS_SPHERES && (!HAS_TRIANGLES || bitcast<u32>(p.b.w) == PRIM_SPHERE);
}

// The infinite planes, which stay outside the BVH.
fn trace_planes(o: vec3f, d: vec3f, t_max: f32, any_hit: bool) -> Hit {
    var hit = Hit(t_max, HIT_NONE, 0u, NO_INSTANCE);
    if (!HAS_PLANES) {
        return hit;
    }
    for (var i = 0u; i < frame.plane_count; i++) {
        if (!take_step()) {
            break;
        }
        let t = intersect_plane(o, d, 0.0, hit.t, planes[i].normal, planes[i].point);
        if (t < hit.t) {
            hit = Hit(t, HIT_PLANE, i, NO_INSTANCE);
            if (any_hit) {
                break;
            }
        }
    }
    return hit;
}

// Record `slot` as an affine map (one of an instance's rows records, src/bvh/layout.rs).
fn load_affine(slot: u32) -> Affine {
    let p = load_primitive(slot);
    return Affine(p.a, p.b, p.c);
}
