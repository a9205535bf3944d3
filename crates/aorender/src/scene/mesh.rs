//! The indexed triangle mesh every loader returns: each distinct vertex stored once, so
//! that the object transform touches it once and shared vertices stay bit-identical.

use glam::{DVec3, Vec3};
use std::path::PathBuf;

/// Vertices and triangles of a mesh file, in the file's space (a glTF node hierarchy
/// already applied). Every index is below `positions.len()`.
#[derive(Clone, Debug, Default)]
pub(crate) struct IndexedMesh {
    /// The point of the file's space the positions are relative to: zero, unless the
    /// loader placed the mesh far from the origin for its size (a glTF node hierarchy,
    /// in f64), where it keeps the positions' accuracy (see `frame::grid_origin`).
    pub origin: DVec3,
    /// Distinct vertex positions, all finite, relative to `origin`.
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
    /// How errors name a vertex.
    pub names: VertexNames,
    /// What the loader skipped, one line each (the file is named by the caller).
    pub warnings: Vec<String>,
}

/// How an error names vertex `k` of an [`IndexedMesh`] in terms of its file
/// (`meshes::vertex_name` turns it into words).
#[derive(Clone, Debug, Default)]
pub(crate) enum VertexNames {
    /// `vertex k`, counted from 0 as the file's faces count them (PLY).
    #[default]
    FromZero,
    /// An OBJ file, searched again for the `v` line of the vertex's position (the
    /// `tobj` meshes do not keep the file's vertex numbers).
    Obj(PathBuf),
    /// Consecutive ranges, each from its first vertex with a label (glTF: node, mesh,
    /// accessor); vertex `k` is `label vertex (k - start)`.
    Ranges(Vec<(usize, String)>),
}

/// `base + i` as a `u32` vertex index, or `None` when the mesh has too many vertices.
pub(crate) fn vertex_index(base: usize, i: usize) -> Option<u32> {
    base.checked_add(i).and_then(|v| u32::try_from(v).ok())
}
