//! Host mirrors of the structs in `shaders/bindings.wgsl` (all bound as storage buffers). The layout
//! test compares each size with naga's.

use crate::scene::{Plane, Scene};
use bytemuck::{Pod, Zeroable};

/// Mirror of WGSL `Frame`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct FrameUniforms {
    /// Eye position.
    pub eye: [f32; 3],
    /// 1 for orthographic.
    pub orthographic: u32,
    /// Image-plane x axis, half the view width.
    pub right: [f32; 3],
    /// Image width.
    pub width: u32,
    /// Image-plane y axis, half the view height.
    pub up: [f32; 3],
    /// Image height.
    pub height: u32,
    /// View direction.
    pub forward: [f32; 3],
    /// Random seed.
    pub seed: u32,
    /// AO ray length (`f32::MAX` when unlimited).
    pub max_distance: f32,
    /// Background value.
    pub background: f32,
    /// Number of planes.
    pub plane_count: u32,
    /// Number of BVH nodes (0: no finite primitives).
    pub node_count: u32,
    /// Cells per axis of the stratified and grid samplers.
    pub strata: u32,
    /// Samples per point of the probe kernel.
    pub probe_samples: u32,
    /// Padding to the WGSL struct's 16-byte multiple.
    pub _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<FrameUniforms>() == 96);

impl FrameUniforms {
    /// The uniforms of a scene with `node_count` BVH nodes.
    pub fn new(scene: &Scene, node_count: u32) -> Self {
        let s = &scene.settings;
        let rg = scene.camera.ray_gen(s.width, s.height);
        FrameUniforms {
            eye: rg.eye_ws.to_array(),
            orthographic: rg.orthographic as u32,
            right: rg.right_ws.to_array(),
            width: s.width,
            up: rg.up_ws.to_array(),
            height: s.height,
            forward: rg.forward_ws.to_array(),
            seed: s.seed,
            max_distance: s.max_distance.map_or(f32::MAX, |d| d.min(f32::MAX)),
            background: s.background,
            plane_count: scene.planes.len() as u32,
            node_count,
            strata: s.sampler.strata_per_axis(s.spp),
            probe_samples: 0,
            _pad: [0; 2],
        }
    }
}

/// Mirror of WGSL `Dispatch` (bound at a 256-byte stride).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct DispatchUniforms {
    /// Index of the first sample (image) or round (probes) this dispatch renders.
    pub first_sample: u32,
    /// Samples or rounds each invocation renders, one after another.
    pub sample_count: u32,
    /// Traversal loop iterations each invocation may spend on all its samples.
    pub traversal_budget: u32,
    /// Padding to 16 bytes.
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<DispatchUniforms>() == 16);

/// Mirror of WGSL `ProbePoint`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuProbePoint {
    /// Position.
    pub position: [f32; 3],
    /// Padding.
    pub _pad0: f32,
    /// Unit normal of the hemisphere.
    pub normal: [f32; 3],
    /// Padding.
    pub _pad1: f32,
}
const _: () = assert!(std::mem::size_of::<GpuProbePoint>() == 32);

/// Mirror of WGSL `Plane`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuPlane {
    /// Unit normal.
    pub normal: [f32; 3],
    /// Albedo.
    pub albedo: f32,
    /// A point of the plane.
    pub point: [f32; 3],
    /// Padding.
    pub _pad: f32,
}
const _: () = assert!(std::mem::size_of::<GpuPlane>() == 32);

impl From<&Plane> for GpuPlane {
    fn from(p: &Plane) -> Self {
        GpuPlane { normal: p.normal.to_array(), albedo: p.albedo, point: p.point.to_array(), _pad: 0.0 }
    }
}
