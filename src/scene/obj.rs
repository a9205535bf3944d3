//! Wavefront OBJ through `tobj`: polygons triangulated, every object and group merged.

use super::non_finite_coordinate;
use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// A vertex as an OBJ file states it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjVertex {
    /// Its line in the file, from 1.
    pub line: usize,
    /// Position, with a homogeneous `w` divided out as `tobj` does.
    pub position: Vec3,
}

/// An OBJ file's geometry.
#[derive(Clone, Debug, Default)]
pub struct ObjMesh {
    /// Every `v` line in file order: vertex `k` of the file (faces count from 1) is
    /// `vertices[k - 1]`.
    pub vertices: Vec<ObjVertex>,
    /// Every face, triangulated, as positions (before the object transform).
    pub triangles: Vec<[Vec3; 3]>,
}

/// The `v` lines of an OBJ text, parsed as `tobj` parses them (`f32::from_str`, which
/// accepts "nan" and "inf"); lines `tobj` would refuse are left for it to report.
fn scan_vertices(text: &str) -> Vec<ObjVertex> {
    let mut vertices = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("v") {
            continue;
        }
        let coords: Vec<f32> = words.by_ref().take(3).map_while(|w| w.parse().ok()).collect();
        let Ok([x, y, z]) = <[f32; 3]>::try_from(coords) else { continue };
        let rest: Vec<&str> = words.collect();
        let w = match rest.as_slice() {
            [w] => w.parse::<f32>().unwrap_or(1.0),
            _ => 1.0,
        };
        let position = if w == 1.0 { Vec3::new(x, y, z) } else { Vec3::new(x / w, y / w, z / w) };
        vertices.push(ObjVertex { line: i + 1, position });
    }
    vertices
}

/// Reads an OBJ file; rejects a vertex with a NaN or infinite coordinate, naming it.
pub fn load_obj(path: &Path) -> Result<ObjMesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::scene(path, e))?;
    let vertices = scan_vertices(&String::from_utf8_lossy(&bytes));
    for (k, v) in vertices.iter().enumerate() {
        if let Some(c) = non_finite_coordinate(v.position) {
            return Err(Error::scene(
                path,
                format!("vertex {} (line {}) has a non-finite coordinate ({c})", k + 1, v.line),
            ));
        }
    }
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    // Materials are not part of an AO scene: ignore mtllib references.
    let (models, _) = tobj::load_obj_buf(&mut bytes.as_slice(), &options, |_| Err(tobj::LoadError::OpenFileFailed))
        .map_err(|e| Error::scene(path, format!("invalid OBJ: {e}")))?;
    let mut triangles = Vec::new();
    for model in &models {
        let m = &model.mesh;
        let vertex = |i: u32| -> Result<Vec3> {
            let i = i as usize;
            m.positions
                .get(3 * i..3 * i + 3)
                .map(|p| Vec3::new(p[0], p[1], p[2]))
                .ok_or_else(|| Error::scene(path, format!("face index {i} is out of range in object '{}'", model.name)))
        };
        for f in m.indices.chunks_exact(3) {
            triangles.push([vertex(f[0])?, vertex(f[1])?, vertex(f[2])?]);
        }
    }
    Ok(ObjMesh { vertices, triangles })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertices_are_scanned_as_tobj_reads_them() {
        let text = "# c\nv 1 2 3\nvn 0 0 1\n  v 2 4 6 2\nv 1 2 3 0.5 0.5 0.5\nv nan 0 0\nv 0 -inf 1\nv x\n";
        let v = scan_vertices(text);
        let expect = [(2, Vec3::new(1.0, 2.0, 3.0)), (4, Vec3::new(1.0, 2.0, 3.0)), (5, Vec3::new(1.0, 2.0, 3.0))];
        assert_eq!(v.len(), 5);
        for (got, (line, p)) in v.iter().zip(expect) {
            assert_eq!((got.line, got.position), (line, p));
        }
        assert!(v[3].position.x.is_nan() && v[3].line == 6);
        assert_eq!(non_finite_coordinate(v[4].position).as_deref(), Some("y = -inf"));
    }
}
