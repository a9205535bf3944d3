//! A bake written into a format other than its input's: a new file made from the meshes
//! as the bake read them (positions bit for bit, faces, the file's normals) and the
//! values, with the attributes a bake of that format writes. Nothing else of the input
//! (materials, texture coordinates, other elements) is carried over.
//!
//! - PLY (binary little-endian): `x y z`, `nx ny nz` when every mesh has normals, and on
//!   the vertex (or face) element `quality`, `quality_std_error`, `bnx bny bnz` and a grey
//!   `red green blue` as a PLY→PLY bake names them; faces as `vertex_indices` lists.
//! - OBJ: `v x y z r g b` with the grey AO, `vn` when every mesh has normals, the faces.
//! - glTF (`.gltf` beside a `.bin`, or `.glb`): one node and mesh, a triangle-list
//!   primitive per mesh (polygons fanned) with `POSITION`, `NORMAL` when known and usable,
//!   grey `COLOR_0`, `_AO`, and `_AO_STD_ERROR` and `_BENT_NORMAL` when asked for.
//!
//! A glTF input's meshes are placed as its nodes place them, so bent normals, written
//! in each file's own space by the bake, are carried into that placed space here.

use super::asset::format_of;
use super::asset::{AssetMesh, BakeAt, BakedValues, WriteOptions};
use crate::error::{Error, Result};
use crate::output::gzip::GzipWriter;
use crate::output::{write_output, write_output_with, write_rows};

/// Rows (vertices, faces) one rayon task writes at a time: about a megabyte of text.
const BLOCK_ROWS: usize = 1 << 14;
use crate::scene::input::is_gzip;
use crate::scene::meshes::stem;
use glam::Vec3;
use serde_json::{Value, json};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The files other than `path` a converted bake into `path` writes: the buffer beside a
/// `.gltf`.
pub(crate) fn companion_files(path: &Path) -> Vec<(PathBuf, &'static str)> {
    if format_of(path) == Some("glTF") && !is_glb(path) {
        vec![(bin_path(path), "the glTF buffer")]
    } else {
        Vec::new()
    }
}

/// Writes `meshes` with `values[i]` baked into mesh `i` as a new file of the format
/// `path` names (optionally gzipped), atomically. Returns notes for the user.
pub(crate) fn write(
    path: &Path,
    meshes: &[AssetMesh],
    values: &[BakedValues],
    options: &WriteOptions,
) -> Result<Vec<String>> {
    let fail = |message: String| Error::output(path, message);
    if values.len() != meshes.len() {
        return Err(fail(format!("values for {} meshes, the input has {}", values.len(), meshes.len())));
    }
    for (m, v) in meshes.iter().zip(values) {
        let n = match options.at {
            BakeAt::Vertices => m.positions.len(),
            BakeAt::Faces => m.face_count(),
        };
        let bent = v.bent_normals.as_ref().map_or(n, Vec::len);
        let se = if options.std_error { v.std_error.len() } else { n };
        if v.ao.len() != n || bent != n || se != n {
            return Err(fail(format!("{}: {} AO values for {n} {}", m.label, v.ao.len(), options.at.name())));
        }
    }
    // Bent normals into the space the positions are written in.
    let bent: Vec<Option<Vec<Vec3>>> = meshes
        .iter()
        .zip(values)
        .map(|(m, v)| {
            let from_file = m.to_file.inverse();
            // Only a placement moves them: the identity keeps the bake's numbers as they are.
            let carry =
                |d: &Vec3| if m.to_file == glam::Mat3::IDENTITY { *d } else { (from_file * *d).normalize_or_zero() };
            v.bent_normals.as_ref().map(|b| b.iter().map(carry).collect())
        })
        .collect();
    let mut notes = match format_of(path) {
        Some("PLY") => write_ply(path, meshes, values, &bent, options)?,
        Some("OBJ") => write_obj(path, meshes, values, &bent, options)?,
        Some("glTF") => write_gltf(path, meshes, values, &bent, options)?,
        _ => return Err(fail("cannot bake into this file type: expected .ply, .obj, .gltf or .glb".to_string())),
    };
    if meshes.iter().any(|m| !m.uv_sets.is_empty() || m.material.is_some()) {
        notes.push(format!(
            "texture coordinates and materials not written: a bake into {} makes a new file of the mesh and its values",
            format_of(path).unwrap_or_default()
        ));
    }
    Ok(notes)
}

fn is_glb(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.strip_suffix(".gz").unwrap_or(&name).ends_with(".glb")
}

/// `STEM.bin` beside a `.gltf` (or `.gltf.gz`) file.
fn bin_path(path: &Path) -> PathBuf {
    path.with_file_name(format!("{}.bin", stem(path)))
}

/// Writes `bytes` from `body` to `path`, gzipped when its name ends in `.gz`.
fn emit(path: &Path, body: &dyn Fn(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let gzip = is_gzip(path);
    write_output_with(path, &mut |w| {
        if gzip {
            let mut encoder = GzipWriter::new(w)?;
            body(&mut encoder)?;
            encoder.finish().map(|_| ())
        } else {
            body(w)
        }
    })
}

/// Whether every mesh has normals (written only then: a file has them for all or none).
fn all_normals(meshes: &[AssetMesh]) -> bool {
    meshes.iter().all(|m| m.normals.is_some())
}

/// A grey level of AO in 0..=255, as a PLY→PLY bake writes `uchar` colours.
fn level(a: f32) -> u8 {
    (255.0 * a.clamp(0.0, 1.0)).round() as u8
}

fn write_ply(
    path: &Path,
    meshes: &[AssetMesh],
    values: &[BakedValues],
    bent: &[Option<Vec<Vec3>>],
    options: &WriteOptions,
) -> Result<Vec<String>> {
    let vertices: usize = meshes.iter().map(|m| m.positions.len()).sum();
    let faces: usize = meshes.iter().map(AssetMesh::face_count).sum();
    let normals = all_normals(meshes);
    let has_bent = bent.iter().all(Option::is_some) && !bent.is_empty();
    let widest = meshes.iter().flat_map(|m| (0..m.face_count()).map(|f| m.face(f).len())).max().unwrap_or(0);
    let count_type = if widest <= 255 { "uchar" } else { "uint" };
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment AO baked by aorender\nelement vertex {vertices}\n\
         property float x\nproperty float y\nproperty float z\n"
    );
    if normals {
        head += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    let mut added = "property float quality\n".to_string();
    if options.std_error {
        added += "property float quality_std_error\n";
    }
    if has_bent {
        added += "property float bnx\nproperty float bny\nproperty float bnz\n";
    }
    if options.colors {
        added += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    let at_vertices = options.at == BakeAt::Vertices;
    if at_vertices {
        head += &added;
    }
    head += &format!("element face {faces}\nproperty list {count_type} uint vertex_indices\n");
    if !at_vertices {
        head += &added;
    }
    head += "end_header\n";

    // The values of one element: AO, standard error, bent normal, colour.
    let put_values = |out: &mut Vec<u8>, v: &BakedValues, b: &Option<Vec<Vec3>>, k: usize| {
        out.extend(v.ao[k].to_le_bytes());
        if options.std_error {
            out.extend(v.std_error[k].to_le_bytes());
        }
        if let Some(b) = b.as_ref().filter(|_| has_bent) {
            out.extend(b[k].to_array().iter().flat_map(|c| c.to_le_bytes()));
        }
        if options.colors {
            out.extend([level(v.ao[k]); 3]);
        }
    };
    let body = |out: &mut dyn Write| -> std::io::Result<()> {
        out.write_all(head.as_bytes())?;
        for ((m, v), b) in meshes.iter().zip(values).zip(bent) {
            write_rows(out, m.positions.len(), BLOCK_ROWS, &|k, row| {
                row.extend(m.positions[k].to_array().iter().flat_map(|c| c.to_le_bytes()));
                if let Some(n) = m.normals.as_ref().filter(|_| normals) {
                    row.extend(n[k].to_array().iter().flat_map(|c| c.to_le_bytes()));
                }
                if at_vertices {
                    put_values(row, v, b, k);
                }
                Ok(())
            })?;
        }
        let mut first = 0u32;
        for ((m, v), b) in meshes.iter().zip(values).zip(bent) {
            write_rows(out, m.face_count(), BLOCK_ROWS, &|f, row| {
                let face = m.face(f);
                if widest <= 255 {
                    row.push(face.len() as u8);
                } else {
                    row.extend((face.len() as u32).to_le_bytes());
                }
                row.extend(face.iter().flat_map(|&i| (first + i).to_le_bytes()));
                if !at_vertices {
                    put_values(row, v, b, f);
                }
                Ok(())
            })?;
            first += m.positions.len() as u32;
        }
        Ok(())
    };
    emit(path, &body)?;
    Ok(Vec::new())
}

fn write_obj(
    path: &Path,
    meshes: &[AssetMesh],
    values: &[BakedValues],
    bent: &[Option<Vec<Vec3>>],
    options: &WriteOptions,
) -> Result<Vec<String>> {
    if options.at == BakeAt::Faces {
        return Err(Error::output(path, "OBJ has no per-face attribute to hold AO per face: bake it into a .ply file"));
    }
    let normals = all_normals(meshes);
    let body = |out: &mut dyn Write| -> std::io::Result<()> {
        writeln!(out, "# AO baked by aorender: each vertex's colour is its AO")?;
        for (m, v) in meshes.iter().zip(values) {
            write_rows(out, m.positions.len().min(v.ao.len()), BLOCK_ROWS, &|k, line| {
                let (p, g) = (m.positions[k], v.ao[k].clamp(0.0, 1.0));
                // Rust prints the shortest decimal that reads back as the same float.
                writeln!(line, "v {} {} {} {g} {g} {g}", p.x, p.y, p.z)
            })?;
        }
        if normals {
            for n in meshes.iter().filter_map(|m| m.normals.as_ref()) {
                write_rows(out, n.len(), BLOCK_ROWS, &|k, line| writeln!(line, "vn {} {} {}", n[k].x, n[k].y, n[k].z))?;
            }
        }
        let mut first = 1u64;
        for m in meshes {
            write_rows(out, m.face_count(), BLOCK_ROWS, &|f, line| {
                line.push(b'f');
                for &i in m.face(f) {
                    let k = first + u64::from(i);
                    if normals { write!(line, " {k}//{k}")? } else { write!(line, " {k}")? }
                }
                line.push(b'\n');
                Ok(())
            })?;
            first += m.positions.len() as u64;
        }
        Ok(())
    };
    emit(path, &body)?;
    let mut notes = Vec::new();
    let elsewhere = "OBJ has no place for them (.ply and .gltf/.glb have)";
    if options.std_error {
        notes.push(format!("standard errors not written: {elsewhere}"));
    }
    if bent.iter().any(Option::is_some) {
        notes.push(format!("bent normals not written: {elsewhere}"));
    }
    Ok(notes)
}

/// glTF's `componentType` codes and buffer view targets.
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The JSON and binary buffer of a glTF file being made.
struct Draft {
    data: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Draft {
    /// Appends `bytes` as a new buffer view and an accessor of `count` elements of `kind`;
    /// returns the accessor's index.
    fn add(&mut self, bytes: impl Iterator<Item = [u8; 4]>, kind: &str, count: usize, component: u32) -> usize {
        let offset = self.data.len();
        self.data.extend(bytes.flatten());
        let target = if component == UNSIGNED_INT { ELEMENT_ARRAY_BUFFER } else { ARRAY_BUFFER };
        self.views.push(json!({
            "buffer": 0, "byteOffset": offset, "byteLength": self.data.len() - offset, "target": target
        }));
        self.accessors.push(json!({
            "bufferView": self.views.len() - 1, "componentType": component, "count": count, "type": kind
        }));
        self.accessors.len() - 1
    }

    fn floats(&mut self, values: impl Iterator<Item = f32>, kind: &str, count: usize) -> usize {
        self.add(values.map(f32::to_le_bytes), kind, count, FLOAT)
    }
}

fn write_gltf(
    path: &Path,
    meshes: &[AssetMesh],
    values: &[BakedValues],
    bent: &[Option<Vec<Vec3>>],
    options: &WriteOptions,
) -> Result<Vec<String>> {
    let fail = |message: String| Error::output(path, message);
    if options.at == BakeAt::Faces {
        return Err(fail(
            "glTF has no per-face attributes: bake at vertices, or per face into a .ply file".to_string(),
        ));
    }
    let mut draft = Draft { data: Vec::new(), views: Vec::new(), accessors: Vec::new() };
    let mut primitives = Vec::new();
    let mut notes = Vec::new();
    for ((m, v), b) in meshes.iter().zip(values).zip(bent) {
        let n = m.positions.len();
        // glTF holds triangles: polygons are fanned from their first corner, as the scene
        // loader triangulates them.
        let mut indices = Vec::with_capacity(m.face_indices.len() * 3);
        for f in 0..m.face_count() {
            let face = m.face(f);
            for k in 1..face.len().saturating_sub(1) {
                indices.extend([face[0], face[k], face[k + 1]]);
            }
        }
        if n == 0 || indices.is_empty() {
            notes.push(format!("{}: no triangles, left out", m.label));
            continue;
        }
        let (lo, hi) =
            m.positions.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        if !(lo.is_finite() && hi.is_finite()) {
            return Err(fail(format!("{}: a vertex position is not finite, which glTF cannot hold", m.label)));
        }
        let position = draft.floats(m.positions.iter().flat_map(|p| p.to_array()), "VEC3", n);
        draft.accessors[position]["min"] = json!(lo.to_array());
        draft.accessors[position]["max"] = json!(hi.to_array());
        let mut attributes = serde_json::Map::new();
        attributes.insert("POSITION".into(), position.into());
        // glTF normals are unit length: the file's are normalised, and left out when one is
        // zero or not finite.
        if let Some(normals) = &m.normals {
            let unit: Vec<Vec3> = normals.iter().map(|d| d.normalize_or_zero()).collect();
            if unit.iter().all(|d| *d != Vec3::ZERO) {
                let a = draft.floats(unit.iter().flat_map(|d| d.to_array()), "VEC3", n);
                attributes.insert("NORMAL".into(), a.into());
            } else {
                notes.push(format!("{}: normals not written, since some are zero or not finite", m.label));
            }
        }
        // A colour is in [0, 1] (glTF 2.0, 3.7.2.1), whatever values it is given.
        let grey = v.ao.iter().map(|a| a.clamp(0.0, 1.0)).flat_map(|a| [a, a, a, 1.0]);
        attributes.insert("COLOR_0".into(), draft.floats(grey, "VEC4", n).into());
        attributes.insert("_AO".into(), draft.floats(v.ao.iter().copied(), "SCALAR", n).into());
        if options.std_error {
            let a = draft.floats(v.std_error.iter().copied(), "SCALAR", n);
            attributes.insert("_AO_STD_ERROR".into(), a.into());
        }
        if let Some(b) = b {
            attributes
                .insert("_BENT_NORMAL".into(), draft.floats(b.iter().flat_map(|d| d.to_array()), "VEC3", n).into());
        }
        let count = indices.len();
        let a = draft.add(indices.into_iter().map(u32::to_le_bytes), "SCALAR", count, UNSIGNED_INT);
        primitives.push(json!({ "attributes": attributes, "indices": a, "mode": 4 }));
    }
    if primitives.is_empty() {
        return Err(fail("no mesh has triangles to write".to_string()));
    }
    let glb = is_glb(path);
    let mut buffer = json!({ "byteLength": draft.data.len() });
    let bin = bin_path(path);
    if !glb {
        let name = bin.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let uri: String = percent_encoding::utf8_percent_encode(&name, URI_NAME).to_string();
        buffer["uri"] = uri.into();
    }
    let doc = json!({
        "asset": { "version": "2.0", "generator": concat!("aorender ", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": primitives }],
        "buffers": [buffer],
        "bufferViews": draft.views,
        "accessors": draft.accessors,
    });
    let json = if glb { serde_json::to_vec(&doc) } else { serde_json::to_vec_pretty(&doc) }
        .map_err(|e| fail(format!("cannot serialise the glTF JSON: {e}")))?;
    if glb {
        let bytes =
            super::gltf::glb_bytes(json, draft.data).ok_or_else(|| fail("the GLB would exceed 4 GiB".to_string()))?;
        emit(path, &|w| w.write_all(&bytes))?;
    } else {
        write_output(&bin, &draft.data)?;
        emit(path, &|w| w.write_all(&json))?;
    }
    Ok(notes)
}

/// What a file name in a URI escapes (RFC 3986: all but unreserved characters).
const URI_NAME: &percent_encoding::AsciiSet =
    &percent_encoding::NON_ALPHANUMERIC.remove(b'-').remove(b'.').remove(b'_').remove(b'~');
