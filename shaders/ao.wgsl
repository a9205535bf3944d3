//#import sampler.wgsl
//#import trace.wgsl
// The AO kernel: one pixel per invocation, dispatch.sample_count samples of it in order
// (each a camera ray, then one AO ray from its hit), added one by one to the pixel's
// compensated running sums: the same additions, in the same order, as one sample per
// dispatch.

// Per-workgroup counts, added to the global counters once per workgroup: one global
// atomic per invocation costs lavapipe's two worker threads a contended cache line.
var<workgroup> workgroup_counters: array<atomic<u32>, COUNTER_COUNT>;
// AO rays of this invocation, added to workgroup_counters once at its end.
var<private> ao_rays: u32 = 0u;

// Neumaier's compensated addition: (sum, compensation) + x.
fn add_compensated(acc: vec2f, x: f32) -> vec2f {
    let t = acc.x + x;
    var c: f32;
    if (abs(acc.x) >= abs(x)) {
        c = (acc.x - t) + x;
    } else {
        c = (x - t) + acc.x;
    }
    return vec2f(t, acc.y + c);
}

fn camera_ray(pixel: vec2f) -> array<vec3f, 2> {
    let sx = 2.0 * pixel.x / f32(frame.width) - 1.0;
    let sy = 1.0 - 2.0 * pixel.y / f32(frame.height);
    if (frame.orthographic != 0u) {
        return array<vec3f, 2>(frame.eye + sx * frame.right + sy * frame.up, frame.forward);
    }
    return array<vec3f, 2>(frame.eye, normalize(frame.forward + sx * frame.right + sy * frame.up));
}

// The hemisphere estimate at p with normal n, p within `error` of its surface along n,
// for hemisphere numbers u: one AO ray, then 0 or cos(theta) / (pi pdf). The twin of
// CpuTracer::ao_at.
fn ao_value(p: vec3f, n: vec3f, error: f32, u: vec2f) -> f32 {
    let w_local = sample_hemisphere(frame.hemisphere, u);
    let w = local_to_world(w_local, n);
    ao_rays += 1u;
    let shadow = trace(offset_ray_origin(p, n, error), w, frame.max_distance, true);
    if (shadow.kind != HIT_NONE) {
        return 0.0;
    }
    return hemisphere_weight(frame.hemisphere, w_local);
}

// AO value of one sample: albedo x the hemisphere estimate, or the background.
fn shade_sample(px: vec2u, u: vec4f) -> f32 {
    let ray = camera_ray(vec2f(px) + u.xy);
    let o = ray[0];
    let d = ray[1];
    let hit = trace(o, d, INF, false);
    if (hit.kind == HIT_NONE) {
        return frame.background;
    }
    var surface: SurfacePoint;
    var albedo: f32;
    if (hit.kind == HIT_PLANE) {
        let plane = planes[hit.index];
        surface = plane_hit_point(o, d, hit.t, plane.normal, plane.point);
        albedo = plane.albedo;
    } else if (HAS_INSTANCES && hit.instance != NO_INSTANCE) {
        // The instance record: (index, root node, first data record, albedo); the data is
        // world-to-object rows, then object-to-world rows.
        let record = load_primitive(hit.instance);
        let data = bitcast<u32>(record.a.z);
        let prim = load_primitive(hit.index);
        surface = instance_hit_point(
            load_affine(data + 1u), load_affine(data), o, d, hit.t, prim.a.xyz, prim.b.xyz, prim.c.xyz,
        );
        albedo = record.a.w;
    } else {
        let prim = load_primitive(hit.index);
        albedo = prim.a.w;
        if (bitcast<u32>(prim.b.w) == PRIM_SPHERE) {
            surface = sphere_hit_point(o, d, hit.t, prim.a.xyz, prim.b.x);
        } else {
            // The record holds the vertices (v0, v1, v2).
            surface = triangle_hit_point(o, d, hit.t, prim.a.xyz, prim.b.xyz, prim.c.xyz);
        }
    }
    // The hemisphere faces the side the camera ray came from.
    let n = select(surface.n, -surface.n, dot(surface.n, d) > 0.0);
    return albedo * ao_value(surface.p, n, surface.error, u.zw);
}

// Adds one sample's value to the running sums `acc` (a film slot), or counts it void
// when its traversal ran out of budget.
fn accumulate(acc: vec4f, value: f32) -> vec4f {
    if (truncated) {
        atomicAdd(&workgroup_counters[COUNTER_TRUNCATED], 1u);
        return acc;
    }
    return vec4f(add_compensated(acc.xy, value), add_compensated(acc.zw, value * value));
}

// Adds the workgroup's counts to the global counters (after a barrier).
fn flush_counters(lid: u32) {
    if (lid == 0u) {
        // Written out rather than looped: every loop counts against lavapipe's cap.
        atomicAdd(&counters[COUNTER_AO_RAYS], atomicLoad(&workgroup_counters[COUNTER_AO_RAYS]));
        atomicAdd(&counters[COUNTER_TRUNCATED], atomicLoad(&workgroup_counters[COUNTER_TRUNCATED]));
    }
}

@compute @workgroup_size(WORKGROUP_WIDTH, WORKGROUP_HEIGHT, 1)
fn render_sample(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_index) lid: u32) {
    load_constants();
    if (gid.x < frame.width && gid.y < frame.height) {
        let i = gid.y * frame.width + gid.x;
        var acc = film[i];
        for (var k = 0u; k < dispatch.sample_count; k++) {
            let index = dispatch.first_sample + k;
            let u = sample_point_uniforms(frame.point_sampler, gid.x, gid.y, index, frame.seed, frame.strata);
            acc = accumulate(acc, shade_sample(gid.xy, u));
        }
        film[i] = acc;
        atomicAdd(&workgroup_counters[COUNTER_AO_RAYS], ao_rays);
    }
    workgroupBarrier();
    flush_counters(lid);
}

// AO at given points (aorender probe). The film holds frame.width lanes per point for
// frame.height points; lane l of point k takes sample indices l, l + lanes, l + 2 lanes, ...
// below frame.probe_samples: round r is the sample r × lanes + l, and an invocation adds
// rounds dispatch.first_sample .. + dispatch.sample_count in order.
@compute @workgroup_size(PROBE_WORKGROUP_SIZE, 1, 1)
fn probe_sample(@builtin(global_invocation_id) gid: vec3u, @builtin(local_invocation_index) lid: u32) {
    load_constants();
    let lanes = frame.width;
    let slot = gid.x;
    if (slot < lanes * frame.height) {
        let point = slot / lanes;
        let q = probe_points[point];
        var acc = film[slot];
        for (var k = 0u; k < dispatch.sample_count; k++) {
            let index = (dispatch.first_sample + k) * lanes + slot % lanes;
            if (index >= frame.probe_samples) {
                break;
            }
            let u = sample_point_uniforms(frame.point_sampler, point, 0u, index, frame.seed, frame.strata);
            // A probe point is exact as given: no offset.
            acc = accumulate(acc, ao_value(q.position, q.normal, 0.0, u.zw));
        }
        film[slot] = acc;
        atomicAdd(&workgroup_counters[COUNTER_AO_RAYS], ao_rays);
    }
    workgroupBarrier();
    flush_counters(lid);
}
