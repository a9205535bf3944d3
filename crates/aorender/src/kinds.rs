//! The choices a render's samples are made with, described apart from the code that makes
//! them: the kind of device, the BVH's node layout and build preset, and on a GPU where
//! the kernel reads the geometry from and how its lanes share the rays. The checkpoint
//! format and the accumulation record them, so they sit below the BVH and the devices,
//! which give them their meaning (`bvh::layout`, `bvh::quality`, `gpu::shaders`, `device`).

/// Which kind of device renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum DeviceKind {
    /// WGSL compute shaders on a wgpu adapter.
    #[default]
    Gpu,
    /// The multi-threaded CPU reference.
    Cpu,
}

impl DeviceKind {
    /// The name used on the command line: `gpu` or `cpu`.
    pub fn name(self) -> &'static str {
        match self {
            DeviceKind::Gpu => "gpu",
            DeviceKind::Cpu => "cpu",
        }
    }
}

/// How the scene is prepared on a device.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BvhOptions {
    /// obvhs's build preset.
    pub quality: BuildQuality,
    /// The node layout the GPU traverses (the CPU reference always traverses obvhs's
    /// CWBVH).
    pub layout: BvhLayout,
    /// Where the GPU kernel reads the geometry from; `None` is the adapter's preference
    /// ([`GeometryStorage::preferred`]).
    pub geometry_storage: Option<GeometryStorage>,
    /// How the GPU kernel's lanes share the rays; `None` is the adapter's preference where
    /// the scene allows it.
    pub traversal: Option<Traversal>,
}

/// The node layout the GPU traverses (serialised as [`BvhLayout::name`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BvhLayout {
    /// Binary BVH, both children's boxes in each 64-byte node (`shaders/trace_bvh2.wgsl`).
    Bvh2,
    /// obvhs's compressed 8-wide BVH, 80-byte nodes (`shaders/trace_cwbvh.wgsl`).
    #[default]
    Cwbvh,
}

impl BvhLayout {
    /// Every layout.
    pub const ALL: [BvhLayout; 2] = [BvhLayout::Bvh2, BvhLayout::Cwbvh];

    /// The name used on the command line and in stats.
    pub fn name(self) -> &'static str {
        match self {
            BvhLayout::Bvh2 => "bvh2",
            BvhLayout::Cwbvh => "cwbvh",
        }
    }
}

/// BVH build quality: obvhs's presets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BuildQuality {
    /// `BvhBuildParams::fastest_build`.
    Fastest,
    /// `BvhBuildParams::fast_build`.
    Fast,
    /// `BvhBuildParams::medium_build`.
    #[default]
    Medium,
    /// `BvhBuildParams::slow_build`.
    Slow,
}

impl BuildQuality {
    /// Every preset, fastest build first.
    pub const ALL: [BuildQuality; 4] =
        [BuildQuality::Fastest, BuildQuality::Fast, BuildQuality::Medium, BuildQuality::Slow];

    /// The name used on the command line and in stats.
    pub fn name(self) -> &'static str {
        match self {
            BuildQuality::Fastest => "fastest",
            BuildQuality::Fast => "fast",
            BuildQuality::Medium => "medium",
            BuildQuality::Slow => "slow",
        }
    }
}

/// How the kernel's invocations share the tracing of rays.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Traversal {
    /// Each invocation traces its own rays (`trace_bvh2.wgsl`, `trace_cwbvh.wgsl`).
    #[default]
    PerLane,
    /// Groups of eight invocations trace their rays one at a time, together: a node's
    /// eight children and a leaf's primitives spread over the lanes
    /// (`trace_cwbvh_group.wgsl`). Needs subgroup operations with subgroups of a multiple
    /// of eight lanes, the compressed wide BVH and a scene without instances.
    Cooperative,
}

impl Traversal {
    /// Name, as in the stats and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Traversal::PerLane => "per-lane",
            Traversal::Cooperative => "cooperative",
        }
    }
}

/// Where the kernel reads the BVH nodes and the primitives from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum GeometryStorage {
    /// Storage buffers: `array<T>` indexed by element.
    #[default]
    Buffers,
    /// Read-only storage textures (`texture_storage_2d<rgba32uint, read>`), an element in
    /// consecutive texels of one row, read with `textureLoad`. Mesa's lavapipe (22.x) reads
    /// a storage buffer at a per-invocation index one lane and one word at a time, behind a
    /// branch each, but an image load as one inlined gather for all lanes (a sampled
    /// texture's texel fetch is a call that also handles mip levels): several times faster
    /// there.
    Textures,
}

impl GeometryStorage {
    /// Name, as in the stats and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            GeometryStorage::Buffers => "buffers",
            GeometryStorage::Textures => "textures",
        }
    }
}
