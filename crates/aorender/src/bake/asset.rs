//! What the bake and the formats share: the meshes of an asset as the bake sees them, the
//! values it computed for them, and the writing options.

use crate::error::Result;
use crate::scene::mesh::{IndexedMesh, VertexNames};
use glam::{Mat3, Vec2, Vec3};
use std::path::{Path, PathBuf};

/// Where AO is baked.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BakeAt {
    /// At every vertex, about its normal.
    #[default]
    Vertices,
    /// At every face's centroid, about the face's normal.
    Faces,
}

impl BakeAt {
    /// The option's value: `vertices` or `faces`.
    pub fn name(self) -> &'static str {
        match self {
            BakeAt::Vertices => "vertices",
            BakeAt::Faces => "faces",
        }
    }
}

/// One mesh of an asset as the bake sees it: one placement of it in the asset's space
/// (for glTF, one primitive under one node, the node hierarchy applied; for PLY and OBJ,
/// the file's one mesh).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AssetMesh {
    /// Names the mesh in messages: the file, or the glTF node, mesh and primitive.
    pub label: String,
    /// Vertex positions, bit for bit as the scene loader reads them (so a vertex lies
    /// exactly on the triangles the rays are traced against).
    pub positions: Vec<Vec3>,
    /// The file's normal per vertex, in the same space as `positions`, not normalised;
    /// `None` when the file has none. A zero or non-finite one is unusable: the bake falls
    /// back to the area-weighted face normal there.
    pub normals: Option<Vec<Vec3>>,
    /// Face `f` has the corners `face_indices[face_starts[f] .. face_starts[f + 1]]`
    /// (indices into `positions`); `face_starts` has one entry more than there are faces.
    /// Faces are the file's, in its order (polygons are not triangulated here).
    pub face_starts: Vec<u32>,
    /// Corners of all faces, in order.
    pub face_indices: Vec<u32>,
    /// Carries a direction from the space of `positions` into the file's own (for glTF,
    /// the inverse of the node's world transform; the identity for the others): bent
    /// normals are written in the file's space.
    pub to_file: Mat3,
    /// The file's texture coordinate sets, one coordinate per face corner (parallel to
    /// `face_indices`; a corner without one is NaN), in the file's convention (see
    /// `uv_v_down`).
    pub uv_sets: Vec<UvSet>,
    /// Whether v = 0 is an image's top row (glTF) rather than its bottom row (OBJ, PLY).
    pub uv_v_down: bool,
    /// The glTF material of the primitive; meshes sharing one share a texture.
    pub material: Option<usize>,
    /// The texture coordinate sets the file's own textures on this mesh repeat along
    /// (glTF: the material's textures on the set, every one's sampler `REPEAT` in both
    /// directions, the default); empty for OBJ and PLY, which do not say.
    pub repeating_sets: Vec<u32>,
}

/// One set of texture coordinates of an [`AssetMesh`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UvSet {
    /// Its number: glTF's `TEXCOORD_n`; 0 for OBJ `vt` and PLY's vertex coordinates.
    pub set: u32,
    /// One coordinate per face corner.
    pub corners: Vec<Vec2>,
}

impl AssetMesh {
    /// Number of faces.
    pub fn face_count(&self) -> usize {
        self.face_starts.len().saturating_sub(1)
    }

    /// The texture coordinate set numbered `set`.
    pub fn uv_set(&self, set: u32) -> Option<&UvSet> {
        self.uv_sets.iter().find(|s| s.set == set)
    }

    /// The corners of face `f`.
    pub fn face(&self, f: usize) -> &[u32] {
        &self.face_indices[self.face_starts[f] as usize..self.face_starts[f + 1] as usize]
    }
}

/// Generated texture coordinates of one mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshUvs {
    /// The set's number (glTF `TEXCOORD_n`; 0 for OBJ and PLY).
    pub set: u32,
    /// For each new vertex, the mesh's vertex it copies.
    pub xref: Vec<u32>,
    /// For each new vertex, its coordinates in [0, 1]², in the file's convention (v down
    /// for glTF, up for OBJ and PLY).
    pub uvs: Vec<Vec2>,
    /// For each face corner (parallel to [`AssetMesh::face_indices`]), its new vertex.
    pub corners: Vec<u32>,
}

impl MeshUvs {
    /// The coordinates of every face corner: the [`UvSet`] the bake reads.
    pub fn uv_set(&self) -> UvSet {
        UvSet { set: self.set, corners: self.corners.iter().map(|&k| self.uvs[k as usize]).collect() }
    }
}

/// What unwrapping made of an asset's meshes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeneratedUvs {
    /// One entry per mesh of the asset, in its order.
    pub meshes: Vec<MeshUvs>,
    /// Charts in all atlases.
    pub charts: u32,
    /// Atlases made: one per texture (glTF material).
    pub atlases: usize,
    /// Fraction of the texture covered by the charts' surface, mean over the atlases.
    pub utilization: f32,
}

/// What a bake computed for one [`AssetMesh`]: one entry per vertex (or per face, for
/// [`BakeAt::Faces`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BakedValues {
    /// AO, 1 fully open.
    pub ao: Vec<f32>,
    /// Standard error of each value.
    pub std_error: Vec<f32>,
    /// Bent normals (unit mean unoccluded direction), when asked for.
    pub bent_normals: Option<Vec<Vec3>>,
}

/// What to write besides the AO itself.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WriteOptions {
    /// Vertices or faces.
    pub at: BakeAt,
    /// Write the standard error of each value.
    pub std_error: bool,
    /// Write AO as a grey colour too (PLY `red green blue`; OBJ and glTF always do).
    pub colors: bool,
}

/// A baked AO texture, encoded, and what it belongs to.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TextureMap {
    /// The glTF material whose `occlusionTexture` it becomes (`None`: a new material for
    /// `meshes`).
    pub material: Option<usize>,
    /// The meshes (indices into [`Asset::meshes`]) baked into it.
    pub meshes: Vec<usize>,
    /// The texture coordinate set it is addressed by.
    pub uv_set: u32,
    /// The AO as a PNG.
    pub png: Vec<u8>,
    /// The bent normals as a PNG, when baked.
    pub bent_png: Option<Vec<u8>>,
    /// Whether coordinates outside [0, 1] repeat it (else they are clamped).
    pub repeat: bool,
}

/// A mesh file read for baking: its meshes, and whatever of the file is needed to write
/// it back with the values added.
pub trait Asset: Send + Sync {
    /// The meshes to bake, in the order [`Asset::write`] takes their values.
    fn meshes(&self) -> &[AssetMesh];

    /// Writes the file to `path` (atomically: the old file or the whole new one) with
    /// `values[i]` added to mesh `i`. Returns notes for the user, one line each (for
    /// example, a glTF primitive whose own `COLOR_0` was kept).
    fn write(&self, path: &Path, values: &[BakedValues], options: &WriteOptions) -> Result<Vec<String>>;

    /// Writes the file to `path` (atomically) with `maps` as its materials' occlusion
    /// textures and `uvs` (one per mesh), when they were generated, as a new texture
    /// coordinate set. glTF embeds or references the maps; OBJ and PLY write them beside
    /// the mesh ([`map_path`]). Every other part of the file is kept.
    fn write_textures(&self, path: &Path, maps: &[TextureMap], uvs: Option<&GeneratedUvs>) -> Result<Vec<String>>;

    /// The files other than `path` that writing to `path` also writes, each with what it
    /// holds in words ("the AO map"): for [`Asset::write`] when `texture` is `None`, for
    /// [`Asset::write_textures`] of those maps otherwise. For the output policy's checks
    /// before any work ([`crate::output::FilePlan`]).
    fn companion_files(&self, path: &Path, texture: Option<&TextureFiles>) -> Vec<(PathBuf, &'static str)> {
        match texture {
            Some(t) => maps_beside(path, t),
            None => Vec::new(),
        }
    }
}

/// What a texture bake writes, as [`Asset::companion_files`] needs it: the number of
/// maps and whether each has a bent normals map, and whether texture coordinates were
/// generated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TextureFiles {
    /// Maps baked (one per material).
    pub maps: usize,
    /// Whether each map has a bent normals map too.
    pub bent_normals: bool,
    /// Whether generated texture coordinates are written.
    pub generated_uvs: bool,
}

/// The maps [`write_maps_beside`] writes beside an OBJ or PLY file written to `path`.
fn maps_beside(path: &Path, texture: &TextureFiles) -> Vec<(PathBuf, &'static str)> {
    let mut files = vec![(map_path(path, "ao"), "the AO map")];
    if texture.bent_normals {
        files.push((map_path(path, "bent_normals"), "the bent normals map"));
    }
    files
}

/// The file beside a mesh written to `path` that holds its map `name` (`ao`,
/// `bent_normals`): `STEM_NAME.png`.
pub fn map_path(path: &Path, name: &str) -> PathBuf {
    path.with_file_name(format!("{}_{name}.png", crate::scene::meshes::stem(path)))
}

/// Writes the maps of an OBJ or PLY file's one texture beside `path` (`STEM_ao.png`,
/// `STEM_bent_normals.png`): what [`Asset::write_textures`] does for formats without a
/// place for them.
pub(crate) fn write_maps_beside(path: &Path, maps: &[TextureMap]) -> Result<()> {
    let [map] = maps else {
        return Err(crate::error::Error::output(path, format!("{} textures for a file of one mesh", maps.len())));
    };
    crate::output::write_output(&map_path(path, "ao"), &map.png)?;
    if let Some(png) = &map.bent_png {
        crate::output::write_output(&map_path(path, "bent_normals"), png)?;
    }
    Ok(())
}

/// The format a file name says, with or without `.gz`: `PLY`, `OBJ` or `glTF` (`.gltf`
/// and `.glb` alike); `None` for another.
pub fn format_of(path: &Path) -> Option<&'static str> {
    let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
    let name = name.strip_suffix(".gz").unwrap_or(&name);
    match name.rsplit_once('.')?.1 {
        "ply" => Some("PLY"),
        "obj" => Some("OBJ"),
        "gltf" | "glb" => Some("glTF"),
        _ => None,
    }
}

/// The scene loader's form of `mesh`, read from a PLY file: every vertex, each face split
/// as a fan (v0, v(k-1), vk) as the loader splits polygons.
pub(crate) fn fan_mesh(mesh: &AssetMesh, names: VertexNames, warnings: Vec<String>) -> IndexedMesh {
    use rayon::prelude::*;
    let triangles: Vec<[u32; 3]> = if mesh.face_starts.par_windows(2).all(|w| w[1] - w[0] == 3) {
        // Triangles only (the usual mesh): each face is its corners, copied over threads.
        mesh.face_indices.par_chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
    } else {
        (0..mesh.face_count())
            .into_par_iter()
            .flat_map_iter(|f| {
                let c = mesh.face(f);
                (2..c.len()).map(move |k| [c[0], c[k - 1], c[k]])
            })
            .collect()
    };
    let positions = mesh.positions.par_iter().copied().collect();
    IndexedMesh { origin: glam::DVec3::ZERO, positions, triangles, names, warnings }
}
