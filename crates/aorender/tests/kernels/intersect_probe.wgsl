//#import intersect.wgsl
// Test probe for tests/robustness.rs: invocation i runs the library's WGSL
// intersect_triangle once, for ray i / triangle_count against triangle
// i % triangle_count, and writes the bits of the returned t. No loops of its own, so
// lavapipe's per-invocation loop cap is never near.
//
// Inputs are raw 32-bit words: floats travel as their bits, so the shader sees exactly
// the f32 values the Rust side used.

struct Params {
    triangle_count: u32,
    count: u32, // rays x triangles
    zero: u32, // 0, for exact.wgsl's `opaque_zero`
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Per ray: (o, t_min), (d, t_max).
@group(0) @binding(1) var<storage, read> rays: array<vec4u>;
// Per triangle: (v0, -), (v1, -), (v2, -).
@group(0) @binding(2) var<storage, read> triangles: array<vec4u>;
@group(0) @binding(3) var<storage, read_write> outputs: array<u32>;

const INTERSECT_PROBE_GROUP: u32 = 64u;

@compute @workgroup_size(64)
fn intersect(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    // Linear index over a 2-D grid of workgroups (the host splits large dispatches).
    let i = gid.x + gid.y * groups.x * INTERSECT_PROBE_GROUP;
    if (i >= params.count) {
        return;
    }
    opaque_zero = params.zero;
    let r = i / params.triangle_count;
    let k = i % params.triangle_count;
    let od = rays[2u * r];
    let dd = rays[2u * r + 1u];
    let t = intersect_triangle(
        bitcast<vec3f>(od.xyz), bitcast<vec3f>(dd.xyz), bitcast<f32>(od.w), bitcast<f32>(dd.w),
        bitcast<vec3f>(triangles[3u * k].xyz), bitcast<vec3f>(triangles[3u * k + 1u].xyz),
        bitcast<vec3f>(triangles[3u * k + 2u].xyz),
    );
    outputs[i] = bitcast<u32>(t);
}
