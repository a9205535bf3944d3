//#import sampler.wgsl
//#import sums.wgsl
//#import tiles.wgsl
//#import traversal.wgsl
// traversal.wgsl is generated for each pipeline: an import of the chosen traversal,
// trace_bvh2.wgsl, trace_cwbvh.wgsl or trace_cwbvh_group.wgsl (src/gpu/shaders.rs).
// The AO kernel: one pixel per invocation, dispatch.sample_count samples of it (each a
// camera ray, then one AO ray from its hit), added one by one to the pixel's block sums in
// 64-bit integers (sums.wgsl): exact, so the film is the same however the samples are
// split into dispatches, passes, shards or devices.
//
// Every invocation of a workgroup runs the same loops and calls `trace` together, a lane
// with nothing to trace (outside the image, past its samples, its camera ray missed)
// passing an empty interval: a cooperative traversal (trace_cwbvh_group.wgsl) needs its
// whole group. `rays_left` ends a loop once no lane that traces with this one is live.

// Per-workgroup counts, added to the global counters once per workgroup: one global
// atomic per invocation costs lavapipe's two worker threads a contended cache line.
var<workgroup> workgroup_counters: array<atomic<u32>, COUNTER_COUNT>;
// AO rays of this invocation, added to workgroup_counters once at its end.
var<private> ao_rays: u32 = 0u;

// The render's point sampler (SAMPLER_*), hemisphere mapping (HEMISPHERE_*) and sky
// (SKY_*), set per pipeline by src/gpu/pipeline.rs, so that only the chosen one is
// compiled in.
override SAMPLER: u32;
override HEMISPHERE: u32;
override SKY: u32;

fn camera_ray(pixel: vec2f) -> array<vec3f, 2> {
    let sx = 2.0 * pixel.x / f32(frame.width) - 1.0;
    let sy = 1.0 - 2.0 * pixel.y / f32(frame.height);
    if (frame.orthographic != 0u) {
        return array<vec3f, 2>(frame.eye + sx * frame.right + sy * frame.up, frame.forward);
    }
    return array<vec3f, 2>(frame.eye, normalize(frame.forward + sx * frame.right + sy * frame.up));
}

// The AO ray from p with normal n, p within `error` of its surface along n, for
// hemisphere numbers u; open and blocked are the sample's value where it escapes or not.
struct AoRay {
    o: vec3f,
    d: vec3f,
    open: f32,
    blocked: f32,
}

// The sky's direction and values for numbers u about the unit normal n: the hemisphere's
// own weight for the uniform sky (classic AO), else the overcast sky's.
fn sky_sample(n: vec3f, u: vec2f) -> SkySample {
    if (SKY == SKY_UNIFORM) {
        let w_local = sample_hemisphere(HEMISPHERE, u);
        return SkySample(local_to_world(w_local, n), hemisphere_weight(HEMISPHERE, w_local), 0.0);
    }
    return sample_overcast(SKY, frame.sky_normalise, frame.sky_up, frame.ground_albedo, HEMISPHERE, n, u);
}

fn ao_ray(p: vec3f, n: vec3f, error: f32, u: vec2f) -> AoRay {
    let s = sky_sample(n, u);
    return AoRay(offset_ray_origin(p, n, error), s.w, s.open, s.blocked);
}

// The AO ray of probe q for hemisphere numbers u: about its normal, from its position
// pushed off its surface by its error bound along the surface's normal (its normal where
// it has none), a direction below the surface mirrored above it. The twin of
// CpuTracer::probe_ray.
fn probe_ray(q: ProbePoint, u: vec2f) -> AoRay {
    let s = sky_sample(q.normal, u);
    let g = q.surface_normal;
    let off = select(g, q.normal, all(g == vec3f(0.0)));
    let d = above_surface(s.w, g);
    return AoRay(offset_ray_origin(q.position, off, q.error), d, s.open, s.blocked);
}

// The first hit of an AO ray within the maximum distance, counted; nothing where the lane
// is not live.
fn trace_ao(ray: AoRay, live: bool) -> Hit {
    ao_rays += select(0u, 1u, live);
    return trace(ray.o, ray.d, select(0.0, frame.max_distance, live), true);
}

// The estimate of an AO ray that found `shadow`: its value where blocked or where open.
fn ao_estimate(shadow: Hit, open: f32, blocked: f32) -> f32 {
    if (shadow.kind != HIT_NONE) {
        return blocked;
    }
    return open;
}

// Where a camera ray hit, and the albedo there.
struct CameraHit {
    surface: SurfacePoint,
    albedo: f32,
}

fn camera_hit(o: vec3f, d: vec3f, hit: Hit) -> CameraHit {
    if (HAS_PLANES && hit.kind == HIT_PLANE) {
        let plane = planes[hit.index];
        return CameraHit(plane_hit_point(o, d, hit.t, plane.normal, plane.point), plane.albedo);
    }
    if (HAS_INSTANCES && hit.instance != NO_INSTANCE) {
        // The instance record: (index, root node, first data record, albedo); the data is
        // world-to-object rows, then object-to-world rows.
        let record = load_primitive(hit.instance);
        let data = bitcast<u32>(record.a.z);
        let prim = load_primitive(hit.index);
        let surface = instance_hit_point(
            load_affine(data + 1u), load_affine(data), o, d, hit.t, prim.a.xyz, prim.b.xyz, prim.c.xyz,
        );
        return CameraHit(surface, record.a.w);
    }
    let prim = load_primitive(hit.index);
    if (is_sphere(prim)) {
        return CameraHit(sphere_hit_point(o, d, hit.t, prim.a.xyz, prim.b.x), prim.a.w);
    }
    // The record holds the vertices (v0, v1, v2).
    return CameraHit(triangle_hit_point(o, d, hit.t, prim.a.xyz, prim.b.xyz, prim.c.xyz), prim.a.w);
}

// AO value of one sample: albedo x the hemisphere estimate, or the background. The camera
// ray and then, where it hits, the AO ray are traced at one call site, in two turns of a
// loop: a SIMD batch none of whose camera rays hit ends the loop instead of running a
// second traversal masked (lavapipe executes both sides of every branch). A lane that is
// not live traces nothing.
fn shade_sample(px: vec2u, u: vec4f, live: bool) -> f32 {
    let camera = camera_ray(vec2f(px) + u.xy);
    var o = camera[0];
    var d = camera[1];
    var t_max = select(0.0, INF, live);
    var is_ao_ray = false;
    var albedo = 0.0;
    var open = 0.0;
    var blocked = 0.0;
    var value = frame.background;
    loop {
        let hit = trace(o, d, t_max, is_ao_ray);
        if (is_ao_ray) {
            if (t_max > 0.0) {
                value = albedo * ao_estimate(hit, open, blocked);
            }
            break;
        }
        is_ao_ray = true;
        if (hit.kind == HIT_NONE) {
            t_max = 0.0;
        } else {
            let h = camera_hit(o, d, hit);
            albedo = h.albedo;
            // The hemisphere faces the side the camera ray came from.
            let n = select(h.surface.n, -h.surface.n, dot(h.surface.n, d) > 0.0);
            let ray = ao_ray(h.surface.p, n, h.surface.error, u.zw);
            ao_rays += 1u;
            o = ray.o;
            d = ray.d;
            open = ray.open;
            blocked = ray.blocked;
            t_max = frame.max_distance;
        }
        if (!rays_left(t_max > 0.0)) {
            break;
        }
    }
    return value;
}

// Adds one sample's value to the block sums `acc` (a film slot), or counts it void when
// its traversal ran out of budget.
fn accumulate(acc: vec4u, value: f32) -> vec4u {
    if (truncated) {
        atomicAdd(&workgroup_counters[COUNTER_TRUNCATED], 1u);
        return acc;
    }
    return add_sample(acc, value, frame.value_exponent);
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
fn render_sample(
    @builtin(workgroup_id) tile: vec3u,
    @builtin(num_workgroups) groups: vec3u,
    @builtin(local_invocation_index) lid: u32,
) {
    load_constants();
    begin_traversal(lid);
    // The target's film holds the rows of its band, from frame.first_row. A listed pass
    // (an adaptive render's, once pixels have stopped) takes the n-th live pixel of
    // the list in `counters` from LIVE_LIST, the workgroups numbered row by row: each live pixel is still rendered
    // by one invocation, with the same samples, and no lane waits on a stopped one.
    var pixel: vec2u;
    var inside: bool;
    if (dispatch.listed > 0u) {
        let n = (tile.y * groups.x + tile.x) * (WORKGROUP_WIDTH * WORKGROUP_HEIGHT) + lid;
        inside = n < dispatch.listed;
        let slot = atomicLoad(&counters[LIVE_LIST + select(0u, n, inside)]);
        pixel = vec2u(slot % frame.width, slot / frame.width + frame.first_row);
    } else {
        pixel = tile_pixel(tile.xy, lid) + vec2u(0u, frame.first_row);
        inside = pixel.x < frame.width && pixel.y < frame.height;
    }
    let i = select(0u, (pixel.y - frame.first_row) * frame.width + pixel.x, inside);
    var acc = film[i];
    // A pixel an adaptive render no longer samples is marked in its slot's last word.
    let live = inside && acc.w != INACTIVE_SLOT;
    for (var k = 0u; k < dispatch.sample_count; k++) {
        if (!rays_left(live)) {
            break;
        }
        let index = dispatch.first_sample + k;
        let u = sample_point_uniforms(SAMPLER, pixel.x, pixel.y, index, frame.seed, frame.strata, frame.replicate);
        let value = shade_sample(pixel, u, live);
        if (live) {
            acc = accumulate(acc, value);
        }
    }
    if (live) {
        film[i] = acc;
        atomicAdd(&workgroup_counters[COUNTER_AO_RAYS], ao_rays);
    }
    workgroupBarrier();
    flush_counters(lid);
}

// AO at given points (aorender probe). The film holds frame.width lanes per point for
// frame.height points; lane l of point k takes sample indices l, l + lanes, l + 2 lanes, ...
// below frame.probe_samples: round r is the sample r × lanes + l, and an invocation adds
// rounds dispatch.first_sample .. + dispatch.sample_count in order. Sequences are numbered
// by the point's index in the request (frame.first_point: targets split the points). The
// dispatch is 2-D when one dimension's workgroups cannot cover the slots: rows of
// groups.x workgroups.
@compute @workgroup_size(PROBE_WORKGROUP_SIZE, 1, 1)
fn probe_sample(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) groups: vec3u,
) {
    load_constants();
    begin_traversal(lid);
    let lanes = frame.width;
    let at = gid.y * groups.x * PROBE_WORKGROUP_SIZE + gid.x;
    let valid = at < lanes * frame.height;
    let slot = select(0u, at, valid);
    let point = slot / lanes;
    let q = probe_points[point];
    var acc = film[slot];
    for (var k = 0u; k < dispatch.sample_count; k++) {
        let index = (dispatch.first_sample + k) * lanes + slot % lanes;
        let live = valid && index < frame.probe_samples;
        if (!rays_left(live)) {
            break;
        }
        let u = sample_point_uniforms(SAMPLER, frame.first_point + point, 0u, index, frame.seed, frame.strata, frame.replicate);
        let ray = probe_ray(q, u.zw);
        let value = ao_estimate(trace_ao(ray, live), ray.open, ray.blocked);
        if (live) {
            acc = accumulate(acc, value);
        }
    }
    if (valid) {
        film[slot] = acc;
        atomicAdd(&workgroup_counters[COUNTER_AO_RAYS], ao_rays);
    }
    workgroupBarrier();
    flush_counters(lid);
}

// AO and the bent normal at given points (aorender bake --bent-normals). The film holds
// four slots per point (frame.width = 4): the AO estimate, then the sums of the x, y and
// z of the unoccluded directions (world space), all from one ray a sample. Sample i of
// point k takes the numbers probe_sample takes with one lane, so the AO is the same.
@compute @workgroup_size(PROBE_WORKGROUP_SIZE, 1, 1)
fn probe_bent_sample(
    @builtin(global_invocation_id) gid: vec3u,
    @builtin(local_invocation_index) lid: u32,
    @builtin(num_workgroups) groups: vec3u,
) {
    load_constants();
    begin_traversal(lid);
    // Rows of groups.x workgroups, as probe_sample's.
    let at = gid.y * groups.x * PROBE_WORKGROUP_SIZE + gid.x;
    let valid = at < frame.height;
    let point = select(0u, at, valid);
    let q = probe_points[point];
    let base = point * 4u;
    var ao = film[base];
    var bx = film[base + 1u];
    var by = film[base + 2u];
    var bz = film[base + 3u];
    for (var k = 0u; k < dispatch.sample_count; k++) {
        let index = dispatch.first_sample + k;
        let live = valid && index < frame.probe_samples;
        if (!rays_left(live)) {
            break;
        }
        let u = sample_point_uniforms(SAMPLER, frame.first_point + point, 0u, index, frame.seed, frame.strata, frame.replicate);
        let ray = probe_ray(q, u.zw);
        let shadow = trace_ao(ray, live);
        let open = select(vec3f(0.0), ray.d, shadow.kind == HIT_NONE);
        if (live && truncated) {
            atomicAdd(&workgroup_counters[COUNTER_TRUNCATED], 1u);
        } else if (live) {
            let e = frame.value_exponent;
            ao = add_sample(ao, ao_estimate(shadow, ray.open, ray.blocked), e);
            bx = add_sample(bx, open.x, e);
            by = add_sample(by, open.y, e);
            bz = add_sample(bz, open.z, e);
        }
    }
    if (valid) {
        film[base] = ao;
        film[base + 1u] = bx;
        film[base + 2u] = by;
        film[base + 3u] = bz;
        atomicAdd(&workgroup_counters[COUNTER_AO_RAYS], ao_rays);
    }
    workgroupBarrier();
    flush_counters(lid);
}
