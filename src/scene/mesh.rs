//! The indexed triangle mesh every loader returns: each distinct vertex stored once, so
//! that the object transform touches it once and shared vertices stay bit-identical.

use super::obj;
use glam::Vec3;
use std::path::{Path, PathBuf};

/// Vertices and triangles of a mesh file, in the file's space (a glTF node hierarchy
/// already applied). Every index is below `positions.len()`.
#[derive(Debug, Default)]
pub(crate) struct IndexedMesh {
    /// Distinct vertex positions, all finite.
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
    /// How errors name a vertex.
    pub names: VertexNames,
}

/// How an error names vertex `k` of an [`IndexedMesh`] in terms of its file.
#[derive(Debug, Default)]
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

impl VertexNames {
    /// The name of vertex `k`, whose position in the file is `position`.
    pub(crate) fn name(&self, k: usize, position: Vec3) -> String {
        match self {
            VertexNames::FromZero => format!("vertex {k}"),
            VertexNames::Obj(path) => obj::find_vertex(path, position)
                .map(|(number, line)| format!("vertex {number} (line {line})"))
                .unwrap_or_else(|| format!("the vertex at {position}")),
            VertexNames::Ranges(ranges) => {
                let i = ranges.partition_point(|(start, _)| *start <= k);
                match i.checked_sub(1).and_then(|i| ranges.get(i)) {
                    Some((start, label)) => format!("{label} vertex {}", k - start),
                    None => format!("vertex {k}"),
                }
            }
        }
    }
}

/// Prints a warning about `path` on stderr, in the one-line form of the binary's errors.
/// The mesh loaders' only output: skipped parts of a file still leave a valid scene.
pub(crate) fn warn(path: &Path, message: &str) {
    eprintln!("aorender: warning: {}: {message}", path.display());
}

/// `base + i` as a `u32` vertex index, or `None` when the mesh has too many vertices.
pub(crate) fn vertex_index(base: usize, i: usize) -> Option<u32> {
    base.checked_add(i).and_then(|v| u32::try_from(v).ok())
}
