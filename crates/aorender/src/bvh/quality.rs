//! obvhs's build presets: what each [`BuildQuality`] (described in `kinds`, where the
//! checkpoint format reads it) builds with.

pub use crate::kinds::BuildQuality;
use obvhs::BvhBuildParams;

impl BuildQuality {
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
