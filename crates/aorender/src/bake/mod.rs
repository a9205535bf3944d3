//! AO baked into the user's own mesh files: the meshes of an asset as the bake sees them
//! ([`AssetMesh`]: positions as the scene loader reads them, the file's normals, the
//! file's faces), the points traced for them ([`BakePlan`]), and the file written back
//! with the values added ([`Asset::write`]), every element, property, node and line the
//! bake does not touch preserved.
//!
//! One module per format: `ply`, `obj`, `gltf`; textures in `texture`, and their
//! coordinates, when a mesh has none, in `unwrap`; a bake into another format than its
//! input's in `convert`; reading and placing the files in
//! `files`; the whole job, a [`BakeRequest`] planned, traced and written, in `job`.

mod asset;
mod convert;
mod files;
pub(crate) mod gltf;
mod gltf_tidy;
mod job;
pub(crate) mod obj;
mod plan;
pub(crate) mod ply;
mod texture;
mod unwrap;

pub use asset::{
    Asset, AssetMesh, BakeAt, BakedValues, GeneratedUvs, MeshUvs, TextureFiles, TextureMap, UvSet, WriteOptions,
    format_of, map_path,
};
pub use files::{
    ReadInputs, check_mesh_output, check_output, load_for_bake, output_path, plan_companions, plan_output, read_asset,
    read_asset_with, read_object,
};
pub use job::{
    Bake, BakeRequest, BakeTarget, BakeTrace, Baked, GenerateUvs, GeneratedReport, TextureReport, TextureRequest,
    Written, is_map, sibling, singular,
};
pub use plan::{BakePlan, Placement, UNUSABLE_VALUE};
#[cfg(feature = "testing")]
pub use ply::PlyAsset;
pub use texture::{
    BYTES_PER_TEXEL, BakedTexture, Coverage, MAX_TEXTURE_SIZE, TextureLayout, TextureOptions, TexturePlan,
    TextureStats, TextureTarget, UvWrap, bytes_per_point, texture_targets,
};
pub use unwrap::generate_uvs;
