//! obvhs's build presets.

use obvhs::BvhBuildParams;

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

    /// obvhs's parameters of the preset.
    pub(crate) fn params(self) -> BvhBuildParams {
        match self {
            BuildQuality::Fastest => BvhBuildParams::fastest_build(),
            BuildQuality::Fast => BvhBuildParams::fast_build(),
            BuildQuality::Medium => BvhBuildParams::medium_build(),
            BuildQuality::Slow => BvhBuildParams::slow_build(),
        }
    }
}
