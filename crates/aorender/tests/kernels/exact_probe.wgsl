//#import exact.wgsl
// Test probe for tests/exact_f32.rs: one operation of shaders/exact.wgsl per invocation.
// Operands travel as their bits, so the shader sees exactly the f32 values the Rust side
// used, and results come back as bits. No loops of its own.

struct Params {
    count: u32, // invocations
    zero: u32, // 0, for exact.wgsl's `opaque_zero`
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Per invocation: (a, b, c, -), the operands of the entry point.
@group(0) @binding(1) var<storage, read> operands: array<vec4u>;
@group(0) @binding(2) var<storage, read_write> outputs: array<u32>;

const EXACT_PROBE_GROUP: u32 = 64u;

// The invocation's operands, or none past the last.
fn exact_probe_operands(gid: vec3u, groups: vec3u) -> vec4f {
    opaque_zero = params.zero;
    let i = gid.x + gid.y * groups.x * EXACT_PROBE_GROUP;
    return bitcast<vec4f>(operands[min(i, params.count - 1u)]);
}

fn exact_probe_write(gid: vec3u, groups: vec3u, r: f32) {
    let i = gid.x + gid.y * groups.x * EXACT_PROBE_GROUP;
    if (i < params.count) {
        outputs[i] = bitcast<u32>(r);
    }
}

// a / b from c, an approximation of the quotient of their significands.
@compute @workgroup_size(64)
fn divide_from(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let x = exact_probe_operands(gid, groups);
    exact_probe_write(gid, groups, div_rounded(x.x, x.y, x.z));
}

// sqrt(a) from c, an approximation of the root of a's significand scaled into [1, 4).
@compute @workgroup_size(64)
fn root_from(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let x = exact_probe_operands(gid, groups);
    exact_probe_write(gid, groups, sqrt_rounded(x.x, x.z));
}

@compute @workgroup_size(64)
fn divide(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let x = exact_probe_operands(gid, groups);
    exact_probe_write(gid, groups, exact_div(x.x, x.y));
}

@compute @workgroup_size(64)
fn root(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let x = exact_probe_operands(gid, groups);
    exact_probe_write(gid, groups, exact_sqrt(x.x));
}

// a × b − c with the product rounded on its own: an edge function's step.
@compute @workgroup_size(64)
fn multiply_subtract(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let x = exact_probe_operands(gid, groups);
    exact_probe_write(gid, groups, exact_mul(x.x, x.y) - x.z);
}
