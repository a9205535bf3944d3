// Resources of the AO kernel. Host mirrors: src/gpu/layout.rs (sizes checked by tests).

// Per-render constants.
struct Frame {
    eye: vec3f,
    orthographic: u32,
    right: vec3f,       // image-plane x axis, half the view width
    width: u32,
    up: vec3f,          // image-plane y axis, half the view height
    height: u32,
    forward: vec3f,
    seed: u32,
    max_distance: f32,  // INF when unlimited
    background: f32,
    plane_count: u32,
    node_count: u32,    // 0 when the scene has no finite primitives
    strata: u32,        // cells per axis of the stratified and grid samplers
    probe_samples: u32, // samples per point of probe_sample
    _pad: vec2u,
}

// Per-dispatch constants, bound with a dynamic offset.
struct Dispatch {
    first_sample: u32,      // first sample index (image) or round (probes)
    sample_count: u32,      // samples or rounds each invocation adds, in order
    traversal_budget: u32,  // traversal loop iterations for all of them together
    _pad: u32,
}

// Triangle: (v0, albedo), (v1, tag), (v2, 0), the vertices exactly as loaded (shared
// vertices are bit-identical, which the watertight test needs). Sphere: (centre, albedo),
// (radius, 0, 0, tag).
struct Primitive {
    a: vec4f,
    b: vec4f,
    c: vec4f,
}

// A point and the normal of its hemisphere (probe_sample).
struct ProbePoint {
    position: vec3f,
    normal: vec3f,
}

// An infinite plane through `point` (src/scene/mod.rs Plane).
struct Plane {
    normal: vec3f,
    albedo: f32,
    point: vec3f,
    _pad: f32,
}

// Every binding is a storage buffer, none a uniform buffer: Mesa's lavapipe (22.x) inlines
// the uniform-buffer values a shader branches on and recompiles the kernel each time a
// bind group is set, which is every dispatch here (7 ms and 1.2 MB that is never freed,
// per dispatch). tests/shaders.rs keeps uniform buffers out.
@group(0) @binding(0) var<storage, read> frame_binding: Frame;
@group(0) @binding(1) var<storage, read> dispatch_binding: Dispatch;
// Their private copies, which every function reads: lavapipe reads a storage buffer one
// lane at a time even where the address is the same for all, and the traversal checks
// its budget at every step. Each entry point calls load_constants first.
var<private> frame: Frame;
var<private> dispatch: Dispatch;

fn load_constants() {
    frame = frame_binding;
    dispatch = dispatch_binding;
}
// Bindings 2 and 3, and 8 and up, hold the BVH nodes and the primitives, split into
// chunks that each fit one binding: the composer generates them with load_node and
// load_primitive (src/shaders.rs, node_bindings.wgsl and primitive_bindings.wgsl).
@group(0) @binding(4) var<storage, read> planes: array<Plane>;
// Per pixel: (sum, compensation, sum of squares, compensation).
@group(0) @binding(5) var<storage, read_write> film: array<vec4f>;
// COUNTER_AO_RAYS, COUNTER_TRUNCATED.
@group(0) @binding(6) var<storage, read_write> counters: array<atomic<u32>, COUNTER_COUNT>;
// The points of probe_sample (one zeroed element for images).
@group(0) @binding(7) var<storage, read> probe_points: array<ProbePoint>;
