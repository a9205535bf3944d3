//#import sums.wgsl
// Test probe for tests/exact_sums.rs: the block sums of shaders/sums.wgsl on the adapter.
// `quantize` writes one sample's quanta per invocation; `accumulate` adds `per_slot`
// samples in order into one film slot per invocation, as the AO kernel does. Values
// travel as their bits, so the shader sees exactly the f32 values the Rust side used.

struct Params {
    count: u32,        // invocations
    value_exponent: u32, // e, as the bits of an i32
    per_slot: u32,     // samples a slot adds (accumulate)
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> values: array<u32>;
@group(0) @binding(2) var<storage, read_write> outputs: array<vec4u>;

const SUMS_PROBE_GROUP: u32 = 64u;

// (value low, high, square low, high) of sample i.
@compute @workgroup_size(64)
fn quantize(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = gid.x + gid.y * groups.x * SUMS_PROBE_GROUP;
    if (i >= params.count) {
        return;
    }
    let q = quantize_sample(bitcast<f32>(values[i]), bitcast<i32>(params.value_exponent));
    outputs[i] = vec4u(q.value, q.square);
}

// Slot i: samples i × per_slot .. (i + 1) × per_slot added to an empty slot.
@compute @workgroup_size(64)
fn accumulate(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = gid.x + gid.y * groups.x * SUMS_PROBE_GROUP;
    if (i >= params.count) {
        return;
    }
    var slot = vec4u(0u);
    for (var k = 0u; k < params.per_slot; k++) {
        slot = add_sample(slot, bitcast<f32>(values[i * params.per_slot + k]), bitcast<i32>(params.value_exponent));
    }
    outputs[i] = slot;
}
