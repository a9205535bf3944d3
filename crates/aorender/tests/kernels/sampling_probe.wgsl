//#import sampler.wgsl
// Test probe for tests/distributions.rs: each invocation reads one input, calls the
// library's WGSL sampling functions once (no loops of its own, so lavapipe's
// per-invocation loop cap is never near) and writes two vec4f of results.
//
// Inputs are raw 32-bit words: floats travel as their bits, so the shader sees exactly
// the f32 values the Rust side used.

struct Params {
    // HEMISPHERE_* for `warp` and `pdf_at`, SAMPLER_* for `points`.
    id: u32,
    seed: u32,
    strata: u32,
    count: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> inputs: array<vec4u>;
// Two entries per invocation: outputs[2i] and outputs[2i + 1].
@group(0) @binding(2) var<storage, read_write> outputs: array<vec4f>;

const SAMPLING_PROBE_GROUP: u32 = 64u;

// Linear invocation index over a 2-D grid of workgroups (the host splits large
// dispatches so no dimension passes the workgroup-count limit).
fn probe_index(gid: vec3u, groups: vec3u) -> u32 {
    return gid.x + gid.y * groups.x * SAMPLING_PROBE_GROUP;
}

// Input (bits of u1, bits of u2, -, -); output (direction, pdf), (inverse of the direction, 0, 0).
@compute @workgroup_size(64)
fn warp(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = probe_index(gid, groups);
    if (i >= params.count) {
        return;
    }
    let u = bitcast<vec2f>(inputs[i].xy);
    let w = sample_hemisphere(params.id, u);
    outputs[2u * i] = vec4f(w, hemisphere_pdf(params.id, w));
    outputs[2u * i + 1u] = vec4f(invert_hemisphere(params.id, w), 0.0, 0.0);
}

// Input (bits of x, y, z, -): a direction; output (pdf, 0, 0, 0), (0, 0, 0, 0).
@compute @workgroup_size(64)
fn pdf_at(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = probe_index(gid, groups);
    if (i >= params.count) {
        return;
    }
    let w = bitcast<vec3f>(inputs[i].xyz);
    outputs[2u * i] = vec4f(hemisphere_pdf(params.id, w), 0.0, 0.0, 0.0);
    outputs[2u * i + 1u] = vec4f(0.0);
}

// Input (px, py, sample index, -); output sample_point_uniforms(...), (0, 0, 0, 0).
@compute @workgroup_size(64)
fn points(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = probe_index(gid, groups);
    if (i >= params.count) {
        return;
    }
    let v = inputs[i];
    outputs[2u * i] = sample_point_uniforms(params.id, v.x, v.y, v.z, params.seed, params.strata, v.w);
    outputs[2u * i + 1u] = vec4f(0.0);
}

// Input (bits of u1, u2, n.x, n.y): numbers and a unit normal (n.z = 0) under the zenith
// +Y; params.id is the SKY_* id, params.seed the normalisation, params.strata the bits of
// the ground albedo. Output (direction, value where open), (value where blocked, 0, 0, 0).
@compute @workgroup_size(64)
fn sky(@builtin(global_invocation_id) gid: vec3u, @builtin(num_workgroups) groups: vec3u) {
    let i = probe_index(gid, groups);
    if (i >= params.count) {
        return;
    }
    let u = bitcast<vec2f>(inputs[i].xy);
    let n = vec3f(bitcast<vec2f>(inputs[i].zw), 0.0);
    let ground = bitcast<f32>(params.strata);
    let s = sample_overcast(params.id, params.seed, vec3f(0.0, 1.0, 0.0), ground, HEMISPHERE_COSINE, n, u);
    outputs[2u * i] = vec4f(s.w, s.open);
    outputs[2u * i + 1u] = vec4f(s.blocked, 0.0, 0.0, 0.0);
}
