//! Baking into PLY files (not yet written).

use super::asset::{Asset, AssetMesh, BakedValues, WriteOptions};
use crate::error::{Error, Result};
use std::path::Path;

/// A PLY file read for baking.
pub struct PlyAsset {
    meshes: Vec<AssetMesh>,
}

impl PlyAsset {
    /// Reads `path` for baking.
    pub fn read(path: &Path) -> Result<PlyAsset> {
        Err(Error::scene(path, "baking into this format is not available yet"))
    }
}

impl Asset for PlyAsset {
    fn meshes(&self) -> &[AssetMesh] {
        &self.meshes
    }

    fn write(&self, path: &Path, _values: &[BakedValues], _options: &WriteOptions) -> Result<Vec<String>> {
        Err(Error::output(path, "baking into this format is not available yet"))
    }
}
