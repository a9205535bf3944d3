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
use rayon::prelude::*;
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
    // its corners from the result, so shared vertices stay bit-identical. A vertex that
    // leaves f32 keeps its position, which its error names (the first such, by number).
    let first_bad = positions
        .par_iter_mut()
        .enumerate()
        .with_min_len(PLACE_PIECE)
        .filter_map(|(k, p)| {
            let q = place_point(transform, *p);
            let bad = non_finite_coordinate(q).map(|c| (k, c));
            if bad.is_none() {
                *p = q;
            }
            bad
        })
        .min_by_key(|(k, _)| *k);
    if let Some((k, c)) = first_bad {
        let name = vertex_name(&mesh.names, k, positions[k]);
        return Err(Error::scene(path, format!("{name} has a non-finite coordinate after the transform ({c})")));
    }
    placed_triangles(path, &positions, &mesh.triangles, albedo, meter)
}

/// Triangles a thread checks or writes at a time when a mesh is placed.
const PLACE_PIECE: usize = 1 << 14;

/// [`mesh_triangles_within`] for the triangles `indices` of the vertices `positions`, over
/// threads: each piece of triangles is checked (the first error by number is reported, as
/// one pass would) and counted, then written into its place of one allocation, in order.
fn placed_triangles(
    path: &Path,
    positions: &[Vec3],
    indices: &[[u32; 3]],
    albedo: f32,
    meter: &mut Meter,
) -> Result<Vec<Triangle>> {
    meter.charge(path, (indices.len() * std::mem::size_of::<Triangle>()) as u64)?;
    let corners = |t: &[u32; 3]| t.map(|i| positions[i as usize]);
    let kept: Vec<Result<usize>> = indices
        .par_chunks(PLACE_PIECE)
        .enumerate()
        .map(|(c, piece)| {
            let mut n = 0;
            for (j, t) in piece.iter().enumerate() {
                n += usize::from(kept_triangle(path, c * PLACE_PIECE + j, &corners(t))?);
            }
            Ok(n)
        })
        .collect();
    let kept = kept.into_iter().collect::<Result<Vec<usize>>>()?;
    let total = kept.iter().sum();
    if total == 0 {
        return Err(Error::scene(path, "mesh has no triangles of non-zero area"));
    }
    // Zeroed pages from the allocator: each is first touched by the thread that fills it.
    let mut out: Vec<Triangle> = bytemuck::zeroed_vec(total);
    let mut rest = &mut out[..];
    let mut pieces = Vec::with_capacity(kept.len());
    for &n in &kept {
        let (piece, after) = rest.split_at_mut(n);
        pieces.push(piece);
        rest = after;
    }
    pieces.into_par_iter().zip(indices.par_chunks(PLACE_PIECE)).for_each(|(to, from)| {
        let made = from.iter().map(corners).filter(|v| normal_length_squared(v) >= MIN_NORMAL_LENGTH_SQUARED);
        for (t, v) in to.iter_mut().zip(made) {
            *t = Triangle { v, albedo };
        }
    });
    Ok(out)
}

/// The squared length of the normal of the triangle `v`, as the renderers compute it
/// (src/geometry.rs, shaders/intersect.wgsl).
fn normal_length_squared(v: &[Vec3; 3]) -> f32 {
    let n = (v[1] - v[0]).cross(v[2] - v[0]);
    n.dot(n)
}

/// Whether triangle `i` (from 0) of vertices `v` is kept: an error for a non-finite
/// coordinate or a normal too large for f32, false for a degenerate one.
fn kept_triangle(path: &Path, i: usize, v: &[Vec3; 3]) -> Result<bool> {
    if let Some(c) = v.iter().find_map(|&p| non_finite_coordinate(p)) {
        return Err(Error::scene(path, format!("triangle {} has a non-finite coordinate ({c})", i + 1)));
    }
    let l2 = normal_length_squared(v);
    if l2.is_nan() || l2 > MAX_NORMAL_LENGTH_SQUARED {
        return Err(Error::scene(
            path,
            format!("triangle {} is too large for f32: its normal has squared length {l2}", i + 1),
        ));
    }
    Ok(l2 >= MIN_NORMAL_LENGTH_SQUARED)
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
        if kept_triangle(path, i, &v)? {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool")
    }

    /// A strip of `n` vertices and its triangles, every fifth triangle degenerate (a
    /// repeated corner), spanning several pieces of the parallel placement.
    fn strip(n: usize) -> IndexedMesh {
        let positions = (0..n).map(|k| Vec3::new(k as f32 * 0.25, (k % 2) as f32, (k % 7) as f32 * 1e-3)).collect();
        let triangles =
            (0..n as u32 - 2).map(|k| if k.is_multiple_of(5) { [k, k, k + 1] } else { [k, k + 1, k + 2] }).collect();
        IndexedMesh { positions, triangles, ..Default::default() }
    }

    #[test]
    fn placed_meshes_have_one_pass_bits_and_first_errors_on_any_number_of_threads() {
        let path = Path::new("strip.ply");
        let mesh = strip(5 * PLACE_PIECE + 77);
        let transform = glam::Mat4::from_scale_rotation_translation(
            Vec3::new(1.5, 0.5, 3.0),
            glam::Quat::from_rotation_z(0.7),
            Vec3::new(-4.0, 2.0, 1e3),
        );
        // One pass: every vertex placed once, then the triangles made and checked in order.
        let placed: Vec<Vec3> = mesh.positions.iter().map(|&p| place_point(&transform, p)).collect();
        let corners = mesh.triangles.iter().map(|t| t.map(|i| placed[i as usize]));
        let expected = mesh_triangles(path, corners, 0.5).unwrap();
        assert_eq!(expected.len(), mesh.triangles.len() - mesh.triangles.len().div_ceil(5));
        let bits = |t: &[Triangle]| t.iter().map(|t| t.v.map(|v| v.to_array().map(f32::to_bits))).collect::<Vec<_>>();
        let place = |mesh: &IndexedMesh, transform: &glam::Mat4| {
            place_mesh(path, mesh.positions.clone(), mesh, 0.5, transform, &mut Meter::unlimited())
        };
        // Vertices that leave f32 under a scale, two in later pieces: the first is named.
        let mut far = mesh.clone();
        for k in [3 * PLACE_PIECE + 5, 4 * PLACE_PIECE + 1, 3 * PLACE_PIECE + 9] {
            far.positions[k].x = 1e30;
        }
        let scale = glam::Mat4::from_scale(Vec3::splat(1e10));
        // A triangle whose normal overflows, after a degenerate one, in a later piece.
        let mut large = mesh.clone();
        let t = 4 * PLACE_PIECE + 3;
        large.positions[t + 2] = Vec3::new(1e19, -1e19, 0.0);
        for threads in [1, 2, 5] {
            let pool = pool(threads);
            let got = pool.install(|| place(&mesh, &transform)).unwrap();
            assert!(bits(&got) == bits(&expected) && got.iter().all(|t| t.albedo == 0.5), "{threads} threads");
            let err = pool.install(|| place(&far, &scale)).unwrap_err().to_string();
            let vertex =
                format!("vertex {} has a non-finite coordinate after the transform (x = inf)", 3 * PLACE_PIECE + 5);
            assert!(err.contains(&vertex), "{threads} threads: {err}");
            let err = pool.install(|| place(&large, &glam::Mat4::IDENTITY)).unwrap_err().to_string();
            assert!(err.contains(&format!("triangle {} is too large for f32", t + 1)), "{threads} threads: {err}");
        }
        // Nothing of non-zero area: the mesh is refused.
        let flat = IndexedMesh { triangles: vec![[0, 0, 1]; 3 * PLACE_PIECE], ..mesh.clone() };
        let err = pool(3).install(|| place(&flat, &transform)).unwrap_err().to_string();
        assert!(err.contains("mesh has no triangles of non-zero area"), "{err}");
    }
}
