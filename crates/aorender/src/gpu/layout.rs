//! Everything the Rust host and the WGSL kernel share, in one place: the kernel's sizes and
//! counters, the constants of the sampling and intersection code, the structs bound to
//! the kernel (declared once with [`gpu_struct!`]) and the bindings. The WGSL side is
//! generated from these tables ([`wgsl_header`], [`wgsl_bindings`]); the layout test
//! compares each struct's size and field offsets with naga's.

use crate::bvh::PRIM_TRIANGLE;
use crate::bvh::{CWBVH_STACK_SIZE, CwNodeWords, GpuNode, GpuPrimitive, INVALID_INDEX, PRIM_INSTANCE, PRIM_SPHERE};
use crate::film::{INACTIVE_SLOT_BITS, OUT_OF_RANGE_BIT, SAMPLE_FRACTION_BITS};
use crate::geometry::{BOX_EXIT_WIDENING, Plane, gamma};
use crate::mirror::{GpuStruct, StructLayout, gpu_struct};
use crate::sampler::Sampler;
use crate::sampler::{ONE_MINUS_EPSILON, PERMUTE_WALK_LIMIT, SOBOL_SCRAMBLE_SALT, SOBOL_SHUFFLE_SALT, STRATA_SALT};
use crate::sampling::Hemisphere;
use crate::scene::{Camera, Sampling, Settings};
use crate::sky::{SKY_UNIFORM, SkyNormalise, SkySampling};

/// Workgroup size of the AO kernel: an 8 × 8 tile of pixels (ao.wgsl `tile_pixel` lays
/// them out for that size).
pub const WORKGROUP_SIZE: [u32; 2] = [8, 8];
/// Workgroup size of the probe kernel (one dimension: point × lane slots).
pub const PROBE_WORKGROUP_SIZE: u32 = 64;
/// Invocations in a workgroup of either kernel: the columns of the CWBVH traversal's
/// stacks in workgroup memory.
pub const TRAVERSAL_LANES: u32 = 64;
/// Lanes of a cooperative traversal's group, which trace each of their rays together
/// (`shaders/trace_cwbvh_group.wgsl`): a node's eight children, one a lane.
pub const GROUP_LANES: u32 = 8;
const _: () = assert!(TRAVERSAL_LANES.is_multiple_of(GROUP_LANES));
const _: () = assert!(WORKGROUP_SIZE[0] == 8 && WORKGROUP_SIZE[1] == 8);
const _: () = assert!(WORKGROUP_SIZE[0] * WORKGROUP_SIZE[1] == TRAVERSAL_LANES);
const _: () = assert!(PROBE_WORKGROUP_SIZE == TRAVERSAL_LANES);
// The stacks (8-byte entries) and the workgroup counters fit the 16 KiB of workgroup
// memory that WebGPU's default limits promise.
const _: () = assert!(
    TRAVERSAL_LANES * CWBVH_STACK_SIZE * 8 + COUNTER_COUNT * 4
        <= wgpu::Limits::downlevel_defaults().max_compute_workgroup_storage_size
);
/// Counter of AO rays traced in a pass.
pub const COUNTER_AO_RAYS: u32 = 0;
/// Counter of samples voided by the traversal budget in a pass.
pub const COUNTER_TRUNCATED: u32 = 1;
/// Number of counters.
pub const COUNTER_COUNT: u32 = 2;
/// Word of the counters' buffer where a listed pass's live pixels begin (its film slots,
/// `gpu/compact.rs`): the list shares the counters' binding, so the geometry keeps every
/// storage binding it had, and 256 bytes in, an offset every adapter can bind.
pub const LIVE_LIST: u32 = 64;
/// Most samples (dispatches) in one pass.
pub const MAX_PASS_SAMPLES: u32 = 1024;
/// Stride of the per-dispatch constants (the largest `min_storage_buffer_offset_alignment`).
pub(crate) const DISPATCH_STRIDE: u64 = 256;

gpu_struct! {
    /// Per-render constants (WGSL `Frame`).
    pub struct FrameUniforms as "Frame" {
        /// Eye position.
        pub eye: [f32; 3] = "vec3f",
        /// 1 for orthographic.
        pub orthographic: u32 = "u32",
        /// Image-plane x axis, half the view width.
        pub right: [f32; 3] = "vec3f",
        /// Image width, or probe lanes per point.
        pub width: u32 = "u32",
        /// Image-plane y axis, half the view height.
        pub up: [f32; 3] = "vec3f",
        /// Image height, or probe points.
        pub height: u32 = "u32",
        /// View direction.
        pub forward: [f32; 3] = "vec3f",
        /// Random seed.
        pub seed: u32 = "u32",
        /// AO ray length (INF when unlimited).
        pub max_distance: f32 = "f32",
        /// Value of camera rays that miss.
        pub background: f32 = "f32",
        /// Number of planes.
        pub plane_count: u32 = "u32",
        /// Number of BVH nodes (0 when the scene has no finite primitives).
        pub node_count: u32 = "u32",
        /// Cells per axis of the stratified and grid samplers.
        pub strata: u32 = "u32",
        /// Samples per point of the probe kernel.
        pub probe_samples: u32 = "u32",
        /// Samples per replicate of the point sampler (0: one sequence).
        pub replicate: u32 = "u32",
        /// Index of the target's first probe point in the request; 0 for images.
        pub first_point: u32 = "u32",
        /// Image row of the target's first film row (images split in bands); 0 for probes.
        pub first_row: u32 = "u32",
        /// e, 2^e bounding every sample: sums in quanta of 2^(e − 54), squares of 2^(2e − 54).
        pub value_exponent: i32 = "i32",
        /// The sky's `SKY` constant (`Sky::shader_id`), which the pipeline is specialised for.
        pub sky: u32 = "u32",
        /// The overcast sky's normalisation (`SKY_NORMALISE_*`).
        pub sky_normalise: u32 = "u32",
        /// The unit zenith.
        pub sky_up: [f32; 3] = "vec3f",
        /// Albedo of the ground below the horizon.
        pub ground_albedo: f32 = "f32",
        /// 0, read rather than known by the kernel, so products stay unfused (exact.wgsl).
        pub zero: u32 = "u32",
        /// Padding to 16 bytes.
        pub _pad: [u32; 3] = "array<u32, 3>",
    }
}

gpu_struct! {
    /// Per-dispatch constants (WGSL `Dispatch`), bound at a [`DISPATCH_STRIDE`] stride.
    pub struct DispatchUniforms as "Dispatch" {
        /// First sample index (image) or round (probes) of the dispatch.
        pub first_sample: u32 = "u32",
        /// Samples or rounds each invocation adds, in order.
        pub sample_count: u32 = "u32",
        /// Traversal loop iterations for all of them together.
        pub traversal_budget: u32 = "u32",
        /// Image pixels listed in `counters` from `LIVE_LIST` that it renders (0: its tiles').
        pub listed: u32 = "u32",
    }
}

gpu_struct! {
    /// A point and the normal of its hemisphere (WGSL `ProbePoint`).
    pub struct GpuProbePoint as "ProbePoint" {
        /// Position.
        pub position: [f32; 3] = "vec3f",
        /// Bound on the distance to its surface along the surface normal: the ray's offset.
        pub error: f32 = "f32",
        /// Unit normal of the hemisphere.
        pub normal: [f32; 3] = "vec3f",
        /// Padding.
        pub _pad1: f32 = "f32",
        /// Unit normal of its surface where it is not `normal`, else zero (the offset's).
        pub surface_normal: [f32; 3] = "vec3f",
        /// Padding.
        pub _pad2: f32 = "f32",
    }
}

gpu_struct! {
    /// An infinite plane through `point` (WGSL `Plane`).
    pub struct GpuPlane as "Plane" {
        /// Unit normal.
        pub normal: [f32; 3] = "vec3f",
        /// Albedo.
        pub albedo: f32 = "f32",
        /// A point of the plane.
        pub point: [f32; 3] = "vec3f",
        /// Padding.
        pub _pad: f32 = "f32",
    }
}

impl From<&Plane> for GpuPlane {
    fn from(p: &Plane) -> Self {
        GpuPlane { normal: p.normal.to_array(), albedo: p.albedo, point: p.point.to_array(), _pad: 0.0 }
    }
}

impl FrameUniforms {
    /// The constants a request's sampling sets, for `spp` samples per pixel or point
    /// (what the cell samplers' strata depend on): every sampling parameter the kernel
    /// reads comes from here. The others are zero, `one` 1.
    pub fn sampling(sampling: &Sampling, spp: u32) -> Self {
        let s = sampling;
        FrameUniforms {
            seed: s.seed,
            max_distance: s.max_distance.map_or(f32::MAX, |d| d.min(f32::MAX)),
            strata: s.strata(spp),
            replicate: s.replicate_samples(),
            sky: s.sky.shader_id(),
            sky_normalise: s.sky.normalise.code() as u32,
            sky_up: s.sky.unit_up().to_array(),
            ground_albedo: s.sky.ground_albedo,
            zero: 0,
            ..bytemuck::Zeroable::zeroed()
        }
    }

    /// The constants of an image of `settings` seen by `camera`, over a BVH of
    /// `node_count` nodes and `plane_count` planes, its samples at most 2^`value_exponent`
    /// in magnitude (`film::value_exponent`).
    pub fn image(camera: &Camera, settings: &Settings, node_count: u32, plane_count: u32, value_exponent: i32) -> Self {
        let s = settings;
        let rg = camera.ray_gen(s.width, s.height);
        FrameUniforms {
            eye: rg.eye_ws.to_array(),
            orthographic: rg.orthographic as u32,
            right: rg.right_ws.to_array(),
            width: s.width,
            up: rg.up_ws.to_array(),
            height: s.height,
            forward: rg.forward_ws.to_array(),
            background: s.background,
            plane_count,
            node_count,
            value_exponent,
            ..FrameUniforms::sampling(&s.sampling, s.spp)
        }
    }

    /// The constants of `points` probe points of `samples` samples each, spread over
    /// `lanes` slots a point, with the sampling of `settings`, the samples at most
    /// 2^`value_exponent` in magnitude.
    pub fn probes(
        settings: &Settings,
        lanes: u32,
        points: u32,
        samples: u32,
        node_count: u32,
        plane_count: u32,
        value_exponent: i32,
    ) -> Self {
        FrameUniforms {
            width: lanes,
            height: points,
            background: settings.background,
            plane_count,
            node_count,
            probe_samples: samples,
            value_exponent,
            ..FrameUniforms::sampling(&settings.sampling, samples)
        }
    }
}

/// Every struct bound to the kernel or read from its geometry, in declaration order.
pub const STRUCTS: [StructLayout; 7] = [
    FrameUniforms::LAYOUT,
    DispatchUniforms::LAYOUT,
    GpuPrimitive::LAYOUT,
    GpuProbePoint::LAYOUT,
    GpuPlane::LAYOUT,
    GpuNode::LAYOUT,
    CwNodeWords::LAYOUT,
];

/// A constant shared by Rust and WGSL.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Constant {
    /// A `u32`.
    U32(&'static str, u32),
    /// An `f32`, written in WGSL as a hexadecimal float so that it is exact.
    F32(&'static str, f32),
}

/// The constants Rust and WGSL share, each defined in Rust.
pub fn constants() -> Vec<Constant> {
    use Constant::{F32, U32};
    vec![
        U32("INVALID_INDEX", INVALID_INDEX),
        U32("INACTIVE_SLOT", INACTIVE_SLOT_BITS),
        U32("SAMPLE_FRACTION_BITS", SAMPLE_FRACTION_BITS as u32),
        U32("OUT_OF_RANGE_HIGH", (OUT_OF_RANGE_BIT >> 32) as u32),
        U32("PRIM_TRIANGLE", PRIM_TRIANGLE),
        U32("PRIM_SPHERE", PRIM_SPHERE),
        U32("PRIM_INSTANCE", PRIM_INSTANCE),
        U32("WORKGROUP_WIDTH", WORKGROUP_SIZE[0]),
        U32("WORKGROUP_HEIGHT", WORKGROUP_SIZE[1]),
        U32("PROBE_WORKGROUP_SIZE", PROBE_WORKGROUP_SIZE),
        U32("TRAVERSAL_LANES", TRAVERSAL_LANES),
        U32("GROUP_LANES", GROUP_LANES),
        U32("COUNTER_AO_RAYS", COUNTER_AO_RAYS),
        U32("COUNTER_TRUNCATED", COUNTER_TRUNCATED),
        U32("COUNTER_COUNT", COUNTER_COUNT),
        U32("LIVE_LIST", LIVE_LIST),
        U32("HEMISPHERE_UNIFORM", Hemisphere::Uniform.shader_id()),
        U32("HEMISPHERE_COSINE", Hemisphere::Cosine.shader_id()),
        U32("HEMISPHERE_COSINE_POLAR", Hemisphere::CosinePolar.shader_id()),
        U32("SKY_UNIFORM", SKY_UNIFORM),
        U32("SKY_HORIZON", 1 + SkySampling::Horizon.code() as u32),
        U32("SKY_CONTROL_VARIATE", 1 + SkySampling::ControlVariate.code() as u32),
        U32("SKY_WEIGHTED", 1 + SkySampling::Weighted.code() as u32),
        U32("SKY_NORMALISE_SURFACE", SkyNormalise::Surface.code() as u32),
        U32("SAMPLER_INDEPENDENT", Sampler::Independent.shader_id()),
        U32("SAMPLER_STRATIFIED", Sampler::Stratified.shader_id()),
        U32("SAMPLER_GRID", Sampler::Grid.shader_id()),
        U32("SAMPLER_SOBOL", Sampler::Sobol.shader_id()),
        U32("PERMUTE_WALK_LIMIT", PERMUTE_WALK_LIMIT),
        U32("STRATA_SALT", STRATA_SALT),
        U32("SOBOL_SHUFFLE_SALT", SOBOL_SHUFFLE_SALT),
        U32("SOBOL_SCRAMBLE_SALT", SOBOL_SCRAMBLE_SALT),
        F32("ONE_MINUS_EPSILON", ONE_MINUS_EPSILON),
        F32("INF", f32::MAX),
        F32("BOX_EXIT_WIDENING", BOX_EXIT_WIDENING),
        F32("PI", std::f32::consts::PI),
        F32("FRAC_PI_2", std::f32::consts::FRAC_PI_2),
        F32("FRAC_PI_4", std::f32::consts::FRAC_PI_4),
        F32("FRAC_1_PI", std::f32::consts::FRAC_1_PI),
        F32("GAMMA1", gamma(1)),
        F32("GAMMA2", gamma(2)),
        F32("GAMMA3", gamma(3)),
        F32("GAMMA4", gamma(4)),
        F32("GAMMA5", gamma(5)),
        F32("GAMMA6", gamma(6)),
        F32("GAMMA8", gamma(8)),
        F32("GAMMA16", gamma(16)),
    ]
}

/// `x` as an exact WGSL hexadecimal float literal, e.g. `0x1.00000ep+0f`.
pub fn hex_f32(x: f32) -> String {
    if x == 0.0 {
        return if x.is_sign_negative() { "-0.0f".into() } else { "0.0f".into() };
    }
    let bits = x.to_bits();
    let sign = if bits >> 31 == 1 { "-" } else { "" };
    let exponent = ((bits >> 23) & 0xff) as i32;
    let mantissa = bits & 0x7f_ffff;
    // Normal numbers only: the shared constants are never subnormal, infinite or NaN.
    assert!(exponent != 0 && exponent != 0xff, "{x} is not a normal f32");
    // 23 mantissa bits as six hex digits (shifted left by one to fill 24 bits).
    format!("{sign}0x1.{:06x}p{:+}f", mantissa << 1, exponent - 127)
}

/// How the kernel may use a binding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

/// One of the kernel's fixed bindings (the geometry's are numbered by
/// [`node_binding`] and [`primitive_binding`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Binding {
    /// `@binding` number in group 0.
    pub index: u32,
    /// WGSL variable name.
    pub name: &'static str,
    /// WGSL type.
    pub ty: &'static str,
    /// Read-only or read-write storage.
    pub access: Access,
    /// Bound with a dynamic offset (one per dispatch).
    pub dynamic_offset: bool,
    /// What it holds, copied into the WGSL as a comment.
    pub doc: &'static str,
}

/// The frame's constants.
pub const FRAME: Binding = Binding {
    index: 0,
    name: "frame_binding",
    ty: "Frame",
    access: Access::Read,
    dynamic_offset: false,
    doc: "per-render constants",
};
/// The dispatch's constants, at a dynamic offset per dispatch.
pub const DISPATCH: Binding = Binding {
    index: 1,
    name: "dispatch_binding",
    ty: "Dispatch",
    access: Access::Read,
    dynamic_offset: true,
    doc: "per-dispatch constants, at a dynamic offset",
};
/// The infinite planes.
pub const PLANES: Binding = Binding {
    index: 4,
    name: "planes",
    ty: "array<Plane>",
    access: Access::Read,
    dynamic_offset: false,
    doc: "the infinite planes (one zeroed element when there are none)",
};
/// The film: per slot, the block's Σv and Σv² as 64-bit integers in two words each.
pub const FILM: Binding = Binding {
    index: 5,
    name: "film",
    ty: "array<vec4u>",
    access: Access::ReadWrite,
    dynamic_offset: false,
    doc: "per pixel or probe lane: the block's sum (low, high word; two's complement) and sum of squares (low, high)",
};
/// The pass counters.
pub const COUNTERS: Binding = Binding {
    index: 6,
    name: "counters",
    ty: "array<atomic<u32>>",
    access: Access::ReadWrite,
    dynamic_offset: false,
    doc: "COUNTER_AO_RAYS, COUNTER_TRUNCATED; from LIVE_LIST, an adaptive image's live pixels (gpu/compact.rs)",
};
/// The probe points.
pub const PROBE_POINTS: Binding = Binding {
    index: 7,
    name: "probe_points",
    ty: "array<ProbePoint>",
    access: Access::Read,
    dynamic_offset: false,
    doc: "the points of probe_sample (one zeroed element for images)",
};
/// The fixed bindings, by number.
pub const BINDINGS: [Binding; 6] = [FRAME, DISPATCH, PLANES, FILM, COUNTERS, PROBE_POINTS];

/// The binding of node chunk `k`: 2, then 8, 10, 12, …
pub fn node_binding(k: u32) -> u32 {
    if k == 0 { 2 } else { 8 + 2 * (k - 1) }
}

/// The binding of primitive chunk `k`: 3, then 9, 11, 13, …
pub fn primitive_binding(k: u32) -> u32 {
    if k == 0 { 3 } else { 9 + 2 * (k - 1) }
}

/// Storage bindings of the kernel besides the node and primitive chunks.
pub const OTHER_STORAGE_BINDINGS: u32 = BINDINGS.len() as u32;

/// The generated header every composed shader starts with: the shared constants and
/// structs.
pub fn wgsl_header() -> String {
    let mut s = String::from("// Generated by src/gpu/layout.rs: the constants and structs Rust and WGSL share.\n");
    for c in constants() {
        s += &match c {
            Constant::U32(name, v) => format!("const {name}: u32 = {v}u;\n"),
            Constant::F32(name, v) => format!("const {name}: f32 = {}; // {v:?}\n", hex_f32(v)),
        };
    }
    for layout in STRUCTS {
        s += "\n";
        s += &layout.wgsl();
    }
    s
}

/// The generated `resources.wgsl`: the kernel's fixed bindings.
pub fn wgsl_bindings() -> String {
    let mut s = String::from("// Generated by src/gpu/layout.rs: the AO kernel's fixed bindings.\n");
    for b in BINDINGS {
        let access = match b.access {
            Access::Read => "read",
            Access::ReadWrite => "read_write",
        };
        s += &format!("// {}\n@group(0) @binding({}) var<storage, {access}> {}: {};\n", b.doc, b.index, b.name, b.ty);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hex_floats_are_exact() {
        for x in [1.0f32, 0.5, 1.0000008, ONE_MINUS_EPSILON, f32::MAX, std::f32::consts::PI, gamma(3), -2.75] {
            let text = hex_f32(x);
            let (mantissa, exponent) = text.trim_end_matches('f').split_once('p').unwrap();
            let negative = mantissa.starts_with('-');
            let digits = mantissa.trim_start_matches('-').trim_start_matches("0x1.");
            let m = 1.0 + u32::from_str_radix(digits, 16).unwrap() as f64 / (1u64 << 24) as f64;
            let v = m * 2f64.powi(exponent.parse().unwrap());
            assert_eq!(if negative { -v } else { v } as f32, x, "{text}");
        }
        assert_eq!(hex_f32(1.0), "0x1.000000p+0f");
        assert_eq!(hex_f32(f32::MAX), "0x1.fffffep+127f");
    }

    #[test]
    fn bindings_are_distinct_and_leave_room_for_the_geometry() {
        let mut numbers: Vec<u32> = BINDINGS.iter().map(|b| b.index).collect();
        numbers.extend((0..4).flat_map(|k| [node_binding(k), primitive_binding(k)]));
        let count = numbers.len();
        numbers.sort_unstable();
        numbers.dedup();
        assert_eq!(numbers.len(), count, "two bindings share a number");
    }
}
