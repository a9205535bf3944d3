//! AO baked into the user's own mesh files: the meshes of an asset as the bake sees them
//! ([`AssetMesh`]: positions as the scene loader reads them, the file's normals, the
//! file's faces), the points traced for them ([`BakePlan`]), and the file written back
//! with the values added ([`Asset::write`]), every element, property, node and line the
//! bake does not touch preserved.
//!
//! One module per format: `ply`, `obj`, `gltf`.

mod asset;
pub(crate) mod gltf;
pub(crate) mod obj;
mod plan;
pub(crate) mod ply;

pub use asset::{Asset, AssetMesh, BakeAt, BakedValues, WriteOptions};
pub use plan::{BakePlan, Placement, UNUSABLE_VALUE};

use crate::error::{Error, Result};
use std::path::Path;

/// Reads a mesh file (`.ply`, `.obj`, `.gltf`, `.glb`, each optionally gzipped) for baking.
pub fn read_asset(path: &Path) -> Result<Box<dyn Asset>> {
    match crate::scene::extension(path).as_str() {
        "ply" => Ok(Box::new(ply::PlyAsset::read(path)?)),
        "obj" => Ok(Box::new(obj::ObjAsset::read(path)?)),
        "gltf" | "glb" => Ok(Box::new(gltf::GltfAsset::read(path)?)),
        ext => Err(Error::scene(path, format!("cannot bake into '.{ext}' files: expected .ply, .obj, .gltf or .glb"))),
    }
}
