//! Wavefront OBJ through `tobj`: polygons triangulated, every object and group merged.

use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// Reads every face of an OBJ file as world-space triangles (before the object transform).
pub fn load_obj(path: &Path) -> Result<Vec<[Vec3; 3]>> {
    let options = tobj::LoadOptions { triangulate: true, single_index: true, ..Default::default() };
    let file = std::fs::File::open(path).map_err(|e| Error::scene(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    // Materials are not part of an AO scene: ignore mtllib references.
    let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| Err(tobj::LoadError::OpenFileFailed))
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
    Ok(triangles)
}
