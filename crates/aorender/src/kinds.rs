//! The choices a render's samples are made with, described apart from the code that makes
//! them: the BVH's node layout and build preset. The checkpoint format and the
//! accumulation record them, so they sit below the BVH and the devices, which give them
//! their meaning (`bvh::layout`, `bvh::quality`).

/// The node layout the GPU traverses (serialised as [`BvhLayout::name`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BvhLayout {
    /// Binary BVH, both children's boxes in each 64-byte node (`shaders/trace.wgsl`).
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
