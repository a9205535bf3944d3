//! Mesh files as triangles: read by format ([`read_mesh`]), checked, placed in the world
//! and stripped of triangles no ray can hit.

use super::input::{self, LoadOptions, Meter, vec_bytes};
use super::mesh::{IndexedMesh, VertexNames};
use super::types::{
    MAX_NORMAL_LENGTH_SQUARED, MIN_NORMAL_LENGTH_SQUARED, Triangle, non_finite_coordinate, place_point,
};
use super::{gltf, obj, ply};
use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// Loads a triangle mesh (`.obj`, `.ply`, `.gltf` or `.glb`, each optionally gzipped as
/// `.gz`), applying `transform`. Rejects empty meshes, vertices with a NaN or infinite
/// coordinate (in the file, or after the transform) and triangles too large to normalize;
/// drops degenerate triangles (zero area, a repeated vertex), which no ray can hit and
/// whose normal is undefined. Errors name the vertex or triangle; warnings are dropped.
#[cfg(feature = "testing")]
pub fn load_mesh(path: &Path, albedo: f32, transform: &glam::Mat4) -> Result<Vec<Triangle>> {
    let options = LoadOptions::from_env()?;
    let mut meter = Meter::new(&options.limits, "the mesh");
    let mut mesh = read_mesh(path, &options, &mut meter, None)?;
    let positions = std::mem::take(&mut mesh.positions);
    place_mesh(path, positions, &mesh, albedo, transform, &mut meter)
}

/// A mesh file's reader that stands in for the format's own and returns the mesh as that
/// one reads it: a bake's, which keeps what it writes back, so that the file is parsed once.
pub(crate) type MeshReader<'a> = dyn FnMut(&Path, &LoadOptions, &mut Meter) -> Result<IndexedMesh> + 'a;

/// Reads a mesh file as it is stored: its vertices and triangles, checked to index them,
/// by `reader` when there is one, else by the format's reader ([`read_format`]).
/// The readers charge what they hold to `meter`; once the file is read, the mesh alone
/// stays charged.
pub(crate) fn read_mesh(
    path: &Path,
    options: &LoadOptions,
    meter: &mut Meter,
    reader: Option<&mut MeshReader>,
) -> Result<IndexedMesh> {
    let held = meter.used();
    let mesh = match reader {
        Some(read) => read(path, options, meter)?,
        None => read_format(path, options, meter)?,
    };
    if mesh.triangles.is_empty() {
        return Err(Error::scene(path, "mesh has no triangles"));
    }
    let n = mesh.positions.len();
    if let Some(i) = mesh.triangles.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(Error::scene(path, format!("vertex index {i} is out of range ({n} vertices)")));
    }
    meter.set_used(held + mesh_bytes(&mesh));
    Ok(mesh)
}

/// Reads a mesh file by its format's reader, unchecked (see [`read_mesh`]).
pub(crate) fn read_format(path: &Path, options: &LoadOptions, meter: &mut Meter) -> Result<IndexedMesh> {
    match extension(path).as_str() {
        "obj" => obj::load_obj(path, meter),
        "ply" => ply::load_ply(path, meter),
        "gltf" | "glb" => gltf::load_gltf(path, options, meter),
        ext => Err(Error::scene(path, format!("unsupported mesh format '.{ext}': expected {MESH_FORMATS}"))),
    }
}

/// The bytes a read mesh holds.
pub(crate) fn mesh_bytes(mesh: &IndexedMesh) -> u64 {
    vec_bytes(&mesh.positions) + vec_bytes(&mesh.triangles)
}

/// The triangles of `mesh` (read from `path`) placed in the world by `transform` (each
/// vertex through [`place_point`]); `positions` are the mesh's vertices (its own, taken
/// out, or a copy), transformed in place.
/// The triangles are charged to `meter` before they are made.
pub(crate) fn place_mesh(
    path: &Path,
    mut positions: Vec<Vec3>,
    mesh: &IndexedMesh,
    albedo: f32,
    transform: &glam::Mat4,
    meter: &mut Meter,
) -> Result<Vec<Triangle>> {
    // Each distinct vertex goes through the transform once, and every triangle below takes
    // its corners from the result, so shared vertices stay bit-identical.
    for (k, p) in positions.iter_mut().enumerate() {
        let q = place_point(transform, *p);
        if let Some(c) = non_finite_coordinate(q) {
            let name = vertex_name(&mesh.names, k, *p);
            return Err(Error::scene(path, format!("{name} has a non-finite coordinate after the transform ({c})")));
        }
        *p = q;
    }
    mesh_triangles_within(path, mesh.triangles.iter().map(|t| t.map(|i| positions[i as usize])), albedo, meter)
}

/// The triangles of a mesh in world space, as the scene keeps them: rejects a non-finite
/// coordinate and triangles too large to normalize, drops degenerate triangles (zero
/// area, a repeated vertex), which no ray can hit and whose normal is undefined, and
/// rejects a mesh left empty. `path` names the mesh in errors.
pub fn mesh_triangles(
    path: &Path,
    triangles: impl IntoIterator<Item = [Vec3; 3]>,
    albedo: f32,
) -> Result<Vec<Triangle>> {
    mesh_triangles_within(path, triangles, albedo, &mut Meter::unlimited())
}

/// [`mesh_triangles`], the triangles charged to `meter` before they are made.
pub(crate) fn mesh_triangles_within(
    path: &Path,
    triangles: impl IntoIterator<Item = [Vec3; 3]>,
    albedo: f32,
    meter: &mut Meter,
) -> Result<Vec<Triangle>> {
    let triangles = triangles.into_iter();
    // One allocation of the final size when the count is known: no copy while growing.
    let count = triangles.size_hint().0;
    meter.charge(path, (count * std::mem::size_of::<Triangle>()) as u64)?;
    let mut out = Vec::with_capacity(count);
    for (i, v) in triangles.enumerate() {
        if let Some(c) = v.iter().find_map(|&p| non_finite_coordinate(p)) {
            return Err(Error::scene(path, format!("triangle {} has a non-finite coordinate ({c})", i + 1)));
        }
        // The normal as the renderers compute it (src/geometry.rs, shaders/intersect.wgsl).
        let n = (v[1] - v[0]).cross(v[2] - v[0]);
        let l2 = n.dot(n);
        if l2.is_nan() || l2 > MAX_NORMAL_LENGTH_SQUARED {
            return Err(Error::scene(
                path,
                format!("triangle {} is too large for f32: its normal has squared length {l2}", i + 1),
            ));
        }
        if l2 >= MIN_NORMAL_LENGTH_SQUARED {
            out.push(Triangle { v, albedo });
        }
    }
    if out.is_empty() {
        return Err(Error::scene(path, "mesh has no triangles of non-zero area"));
    }
    Ok(out)
}

/// Extensions of the mesh formats, before an optional `.gz`.
pub(crate) const MESH_EXTENSIONS: [&str; 4] = ["obj", "ply", "gltf", "glb"];
/// The mesh formats, for error messages.
pub(crate) const MESH_FORMATS: &str = "a mesh (.obj, .ply, .gltf or .glb, optionally gzipped as .gz)";

/// The file's extension in lower case; for a gzipped file (`.gz`), the one before it.
pub(crate) fn extension(path: &Path) -> String {
    let inner = if input::is_gzip(path) { path.file_stem().map(Path::new) } else { Some(path) };
    inner.and_then(Path::extension).and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase()
}

/// The file's name without its extension (and without `.gz`).
pub(crate) fn stem(path: &Path) -> String {
    let inner = if input::is_gzip(path) { path.file_stem().map(Path::new) } else { Some(path) };
    inner.and_then(Path::file_stem).and_then(|s| s.to_str()).unwrap_or("scene").to_string()
}

/// The name of vertex `k` of a mesh, whose position in the file is `position`, as its
/// file would number it.
pub(crate) fn vertex_name(names: &VertexNames, k: usize, position: Vec3) -> String {
    match names {
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
