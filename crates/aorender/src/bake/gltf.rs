//! Baking into glTF files (`.gltf`, `.glb`, either gzipped). The meshes are read by the
//! scene loader (`scene::gltf`), one per triangle primitive under each node, so their
//! positions are bit for bit the ones the rays are traced against. The file is written
//! back from its JSON kept as a value, so every node, mesh, material, extension, extras
//! and unknown field survives; the values go into new accessors on each primitive:
//! `COLOR_0` (grey, unless the primitive has its own), `_AO`, and `_AO_STD_ERROR` and
//! `_BENT_NORMAL` when asked for (glTF's custom attributes start with `_`).
//!
//! A mesh placed by several nodes is occluded differently at each placement: every node
//! after the first gets its own copy of the mesh, sharing its accessors and material.

use super::{Asset, AssetMesh, BakeAt, BakedValues, WriteOptions, is_gzip_name};
use crate::error::{Error, Result};
use crate::output::{write_atomically, write_atomically_with};
use crate::scene::extension;
use crate::scene::gltf::{GltfBytes, read_gltf};
use crate::scene::input::one_line;
use crate::scene::meshes::stem;
use ::gltf::json::{Value, deserialize, serialize};
use flate2::Compression;
use flate2::write::GzEncoder;
use percent_encoding::{AsciiSet, CONTROLS, percent_decode_str, utf8_percent_encode};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// glTF's `componentType` for 32-bit floats.
const FLOAT: u32 = 5126;
/// glTF's `target` for vertex attributes.
const ARRAY_BUFFER: u32 = 34962;
/// Custom attributes this bake writes (besides `COLOR_0`).
const AO: &str = "_AO";
const AO_STD_ERROR: &str = "_AO_STD_ERROR";
const BENT_NORMAL: &str = "_BENT_NORMAL";

/// Characters a relative URI's path cannot hold as they are (RFC 3986, section 3.3).
const URI_PATH: &AsciiSet = &CONTROLS
    .add(b' ')
    .add(b'"')
    .add(b'#')
    .add(b'%')
    .add(b'<')
    .add(b'>')
    .add(b'?')
    .add(b'[')
    .add(b'\\')
    .add(b']')
    .add(b'^')
    .add(b'`')
    .add(b'{')
    .add(b'|')
    .add(b'}');

/// A glTF file read for baking.
pub struct GltfAsset {
    /// The file read, to resolve its relative URIs.
    path: PathBuf,
    meshes: Vec<AssetMesh>,
    /// Where each mesh is in the file.
    targets: Vec<Target>,
    /// The file's JSON, untouched.
    json: Value,
    /// The GLB binary chunk, when buffer 0 is stored in it.
    bin: Option<Vec<u8>>,
    /// What the loader skipped, one line each.
    warnings: Vec<String>,
}

/// A primitive placed by a node: where an [`AssetMesh`] came from.
struct Target {
    node: usize,
    mesh: usize,
    primitive: usize,
}

impl GltfAsset {
    /// Reads `path` for baking: one mesh per triangle primitive under each node of the
    /// default scene, in the order the scene loader places them.
    pub fn read(path: &Path) -> Result<GltfAsset> {
        let (placed, (json, bin)) = read_gltf(path, true, |bytes: GltfBytes| {
            (deserialize::from_slice::<Value>(bytes.json), bytes.bin.filter(|_| bytes.glb).map(<[u8]>::to_vec))
        })?;
        let json = json.map_err(|e| Error::scene(path, format!("invalid glTF JSON: {}", one_line(&e.to_string()))))?;
        if !json.is_object() {
            return Err(Error::scene(path, "invalid glTF JSON: not an object"));
        }
        // The binary chunk is buffer 0's when that buffer has no URI (glTF 2.0, 4.4.3.3).
        let bin_is_buffer_0 = json.get("buffers").and_then(|b| b.get(0)).is_some_and(|b| b.get("uri").is_none());
        let bin = bin.filter(|_| bin_is_buffer_0);
        let mut meshes = Vec::with_capacity(placed.placements.len());
        let mut targets = Vec::with_capacity(placed.placements.len());
        for placement in placed.placements {
            let base = placement.vertices.start;
            let triangles = &placed.mesh.triangles[placement.triangles.clone()];
            let face_starts = (0..=triangles.len())
                .map(|f| u32::try_from(3 * f))
                .collect::<std::result::Result<Vec<u32>, _>>()
                .map_err(|_| Error::scene(path, format!("{}: too many triangles to bake", placement.label)))?;
            // The loader's indices are `base + i` with `i` below the accessor's count.
            let face_indices = triangles.iter().flatten().map(|&v| (v as usize - base) as u32).collect();
            meshes.push(AssetMesh {
                label: placement.label,
                positions: placed.mesh.positions[placement.vertices].to_vec(),
                normals: placement.normals,
                face_starts,
                face_indices,
            });
            targets.push(Target { node: placement.node, mesh: placement.mesh, primitive: placement.primitive });
        }
        if meshes.is_empty() {
            return Err(Error::scene(path, "the scene has no triangle primitives to bake"));
        }
        Ok(GltfAsset { path: path.to_path_buf(), meshes, targets, json, bin, warnings: placed.mesh.warnings })
    }

    /// Checks there is one set of values per mesh, one value per vertex.
    fn check_values(&self, path: &Path, values: &[BakedValues], options: &WriteOptions) -> Result<()> {
        if values.len() != self.meshes.len() {
            return Err(Error::output(
                path,
                format!("{} sets of values for the {} meshes of the file", values.len(), self.meshes.len()),
            ));
        }
        for (mesh, v) in self.meshes.iter().zip(values) {
            let n = mesh.positions.len();
            let bent = v.bent_normals.as_ref().map_or(n, Vec::len);
            let std_error = if options.std_error { v.std_error.len() } else { n };
            if v.ao.len() != n || std_error != n || bent != n {
                return Err(Error::output(
                    path,
                    format!(
                        "{}: {} AO values, {} standard errors and {bent} bent normals for {n} vertices",
                        mesh.label,
                        v.ao.len(),
                        v.std_error.len()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The mesh each target's values go into: the node's own mesh for the first node
    /// placing it, a copy of it (added to `doc`, the node pointed at it) for the others.
    fn meshes_to_fill(&self, doc: &mut Value, notes: &mut Vec<String>) -> Vec<usize> {
        let mut first_node: HashMap<usize, usize> = HashMap::new();
        let mut copy_of_node: HashMap<usize, usize> = HashMap::new();
        let mut copies: BTreeMap<usize, Vec<(usize, usize)>> = BTreeMap::new();
        let mut out = Vec::with_capacity(self.targets.len());
        for t in &self.targets {
            let first = *first_node.entry(t.mesh).or_insert(t.node);
            if first == t.node {
                out.push(t.mesh);
                continue;
            }
            if let Some(&copy) = copy_of_node.get(&t.node) {
                out.push(copy);
                continue;
            }
            let original = self.json.get("meshes").and_then(|m| m.get(t.mesh)).cloned().unwrap_or(Value::Null);
            let meshes = array(doc, "meshes");
            meshes.push(original);
            let copy = meshes.len() - 1;
            if let Some(node) = doc.get_mut("nodes").and_then(|n| n.get_mut(t.node)) {
                node["mesh"] = copy.into();
            }
            copy_of_node.insert(t.node, copy);
            copies.entry(t.mesh).or_default().push((t.node, copy));
            out.push(copy);
        }
        for (mesh, placed) in copies {
            let name = self.json["meshes"][mesh].get("name").and_then(Value::as_str);
            let name = name.map(|n| format!(" ({:?})", one_line(n))).unwrap_or_default();
            let nodes: Vec<String> = placed.iter().map(|(node, _)| node.to_string()).collect();
            let meshes: Vec<String> = placed.iter().map(|(_, copy)| copy.to_string()).collect();
            notes.push(format!(
                "mesh {mesh}{name} is placed by {} nodes: to carry their own AO, node{} {} now use{} {} of it (mesh{} {})",
                placed.len() + 1,
                plural(placed.len()),
                nodes.join(", "),
                if placed.len() == 1 { "s" } else { "" },
                if placed.len() == 1 { "a copy" } else { "copies" },
                if placed.len() == 1 { "" } else { "es" },
                meshes.join(", ")
            ));
        }
        out
    }
}

impl Asset for GltfAsset {
    fn meshes(&self) -> &[AssetMesh] {
        &self.meshes
    }

    fn write(&self, path: &Path, values: &[BakedValues], options: &WriteOptions) -> Result<Vec<String>> {
        let fail = |message: String| Error::output(path, message);
        if options.at == BakeAt::Faces {
            return Err(fail(
                "glTF has no per-face attributes: bake at vertices, or per face into a .ply file".to_string(),
            ));
        }
        let glb = match extension(path).as_str() {
            "glb" => true,
            "gltf" => false,
            ext => return Err(fail(format!("cannot write glTF to a '.{ext}' file: expected .gltf or .glb"))),
        };
        self.check_values(path, values, options)?;
        let mut notes = self.warnings.clone();
        let mut doc = self.json.clone();
        let input_dir = directory(&self.path);
        let output_dir = directory(path);
        if !same_directory(&input_dir, &output_dir) {
            rebase_uris(&mut doc, &input_dir, &output_dir);
        }

        // The new data goes after the GLB binary chunk's, in buffer 0; without one, into a
        // new buffer: first for a GLB (where the binary chunk's buffer must be), last for
        // a .gltf (where no index changes).
        let mut data = self.bin.clone().unwrap_or_default();
        pad(&mut data, 0);
        let buffer = if self.bin.is_some() {
            0
        } else if glb {
            insert_first_buffer(&mut doc);
            0
        } else {
            let buffers = array(&mut doc, "buffers");
            buffers.push(object([]));
            buffers.len() - 1
        };

        let fill = self.meshes_to_fill(&mut doc, &mut notes);
        let mut kept_colors = BTreeSet::new();
        for (((t, mesh), v), &fill) in self.targets.iter().zip(&self.meshes).zip(values).zip(&fill) {
            let n = mesh.positions.len();
            if n == 0 {
                continue;
            }
            let has_color =
                self.json["meshes"][t.mesh]["primitives"][t.primitive]["attributes"].get("COLOR_0").is_some();
            let mut added: Vec<(&str, Option<usize>)> = Vec::new();
            if has_color {
                if kept_colors.insert((t.mesh, t.primitive)) {
                    notes.push(format!("{}: its own COLOR_0 is kept; AO went into its _AO attribute only", mesh.label));
                }
            } else {
                let grey = v.ao.iter().flat_map(|&a| [a, a, a, 1.0]);
                added.push(("COLOR_0", Some(add_accessor(&mut doc, &mut data, buffer, "VEC4", n, grey))));
            }
            added.push((AO, Some(add_accessor(&mut doc, &mut data, buffer, "SCALAR", n, v.ao.iter().copied()))));
            let std_error = options
                .std_error
                .then(|| add_accessor(&mut doc, &mut data, buffer, "SCALAR", n, v.std_error.iter().copied()));
            added.push((AO_STD_ERROR, std_error));
            let bent = v
                .bent_normals
                .as_ref()
                .map(|b| add_accessor(&mut doc, &mut data, buffer, "VEC3", n, b.iter().flat_map(|d| d.to_array())));
            added.push((BENT_NORMAL, bent));
            let attributes = doc
                .get_mut("meshes")
                .and_then(|m| m.get_mut(fill))
                .and_then(|m| m.get_mut("primitives"))
                .and_then(|p| p.get_mut(t.primitive))
                .and_then(|p| p.get_mut("attributes"))
                .and_then(Value::as_object_mut)
                .ok_or_else(|| fail(format!("{}: the primitive's attributes are missing from the JSON", mesh.label)))?;
            for (name, accessor) in added {
                match accessor {
                    Some(a) => attributes.insert(name.to_string(), a.into()),
                    // One left by an earlier bake would contradict the new AO.
                    None => attributes.remove(name),
                };
            }
        }
        if data.is_empty() {
            // A buffer holds at least one byte.
            data.extend([0; 4]);
        }

        let buffers = array(&mut doc, "buffers");
        buffers[buffer]["byteLength"] = data.len().into();
        if glb {
            let json = serialize::to_vec(&doc).map_err(|e| fail(format!("cannot serialise the glTF JSON: {e}")))?;
            let bytes = glb_bytes(json, data).ok_or_else(|| fail("the GLB would exceed 4 GiB".to_string()))?;
            write_maybe_gzipped(path, &bytes)?;
        } else {
            let (bin_path, uri) = self.bin_file(path, &input_dir, &output_dir, &mut notes);
            buffers[buffer]["uri"] = uri.into();
            let json =
                serialize::to_vec_pretty(&doc).map_err(|e| fail(format!("cannot serialise the glTF JSON: {e}")))?;
            // Everything is encoded before the first file is written, so that what can fail
            // between the two writes is the disk alone.
            let json = if is_gzip_name(path) { gzip(&json).map_err(|e| fail(e.to_string()))? } else { json };
            write_atomically(&bin_path, &data)?;
            write_atomically(path, &json)?;
        }
        Ok(notes)
    }
}

impl GltfAsset {
    /// The file beside a `.gltf` output that holds its new buffer, and the URI naming it:
    /// `<stem>.bin`, or `<stem>_ao.bin`, `<stem>_ao2.bin`… when the input uses a file of
    /// that name (baking a file over itself must not overwrite its own buffers).
    fn bin_file(&self, path: &Path, input_dir: &Path, output_dir: &Path, notes: &mut Vec<String>) -> (PathBuf, String) {
        let used: BTreeSet<PathBuf> = self.external_files().map(|f| comparable(&input_dir.join(f))).collect();
        let stem = stem(path);
        for k in 0.. {
            let name = match k {
                0 => format!("{stem}.bin"),
                1 => format!("{stem}_ao.bin"),
                k => format!("{stem}_ao{k}.bin"),
            };
            let file = output_dir.join(&name);
            if !used.contains(&comparable(&file)) {
                if k > 0 {
                    notes.push(format!("the new data is in {name}: the input uses {stem}.bin"));
                }
                return (file, utf8_percent_encode(&name, URI_PATH).to_string());
            }
        }
        unreachable!("the input names finitely many files")
    }

    /// The relative file names of the input's external buffers and images.
    fn external_files(&self) -> impl Iterator<Item = PathBuf> + '_ {
        ["buffers", "images"]
            .into_iter()
            .filter_map(|key| self.json.get(key).and_then(Value::as_array))
            .flatten()
            .filter_map(|item| item.get("uri").and_then(Value::as_str))
            .filter_map(relative_file)
    }
}

/// `doc[key]` as an array, made one when missing.
fn array<'v>(doc: &'v mut Value, key: &str) -> &'v mut Vec<Value> {
    if !doc[key].is_array() {
        doc[key] = Value::Array(Vec::new());
    }
    match &mut doc[key] {
        Value::Array(a) => a,
        _ => unreachable!("made an array above"),
    }
}

/// A JSON object of `fields`.
fn object<const N: usize>(fields: [(&str, Value); N]) -> Value {
    Value::Object(fields.into_iter().map(|(k, v)| (k.to_string(), v)).collect())
}

fn plural(n: usize) -> &'static str {
    if n == 1 { "" } else { "s" }
}

/// Pads `data` with `byte` to a multiple of 4 bytes.
fn pad(data: &mut Vec<u8>, byte: u8) {
    data.resize(data.len().next_multiple_of(4), byte);
}

/// Appends `values` (`count` elements of `kind`) to `data` in a new buffer view of
/// `buffer` and adds a float accessor of them; returns the accessor's index.
fn add_accessor(
    doc: &mut Value,
    data: &mut Vec<u8>,
    buffer: usize,
    kind: &str,
    count: usize,
    values: impl Iterator<Item = f32>,
) -> usize {
    pad(data, 0);
    let offset = data.len();
    data.extend(values.flat_map(f32::to_le_bytes));
    let views = array(doc, "bufferViews");
    views.push(object([
        ("buffer", buffer.into()),
        ("byteOffset", offset.into()),
        ("byteLength", (data.len() - offset).into()),
        ("target", ARRAY_BUFFER.into()),
    ]));
    let view = views.len() - 1;
    let accessors = array(doc, "accessors");
    accessors.push(object([
        ("bufferView", view.into()),
        ("componentType", FLOAT.into()),
        ("count", count.into()),
        ("type", kind.into()),
    ]));
    accessors.len() - 1
}

/// Makes room for the GLB binary chunk's buffer at index 0: every reference to a buffer
/// moves up by one (buffer views, and the meshopt extensions' fallback views).
fn insert_first_buffer(doc: &mut Value) {
    array(doc, "buffers").insert(0, object([]));
    let shift = |index: Option<&mut Value>| {
        if let Some(index) = index
            && let Some(i) = index.as_u64()
        {
            *index = (i + 1).into();
        }
    };
    for view in array(doc, "bufferViews") {
        shift(view.get_mut("buffer"));
        for ext in ["EXT_meshopt_compression", "KHR_meshopt_compression"] {
            shift(view.get_mut("extensions").and_then(|e| e.get_mut(ext)).and_then(|e| e.get_mut("buffer")));
        }
    }
}

/// The GLB container of `json` and `bin` (glTF 2.0, section 4.4), or `None` past 4 GiB.
fn glb_bytes(mut json: Vec<u8>, mut bin: Vec<u8>) -> Option<Vec<u8>> {
    pad(&mut json, b' ');
    pad(&mut bin, 0);
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let word = |n: usize| u32::try_from(n).ok().map(u32::to_le_bytes);
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend(word(total)?);
    out.extend(word(json.len())?);
    out.extend(b"JSON");
    out.extend(json);
    out.extend(word(bin.len())?);
    out.extend(b"BIN\0");
    out.extend(bin);
    Some(out)
}

fn gzip(bytes: &[u8]) -> std::io::Result<Vec<u8>> {
    let mut encoder = GzEncoder::new(Vec::new(), Compression::default());
    encoder.write_all(bytes)?;
    encoder.finish()
}

/// Writes `bytes` to `path` atomically, gzipped when its name ends in `.gz`.
fn write_maybe_gzipped(path: &Path, bytes: &[u8]) -> Result<()> {
    if !is_gzip_name(path) {
        return write_atomically(path, bytes);
    }
    write_atomically_with(path, &mut |w| {
        let mut encoder = GzEncoder::new(w, Compression::default());
        encoder.write_all(bytes)?;
        encoder.finish().map(|_| ())
    })
}

/// The directory a file's relative URIs are resolved from.
fn directory(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// `path` made absolute, with its symbolic links resolved when it exists, for comparisons.
fn comparable(path: &Path) -> PathBuf {
    path.canonicalize().or_else(|_| std::path::absolute(path).map(|p| normalise(&p))).unwrap_or_else(|_| path.into())
}

fn same_directory(a: &Path, b: &Path) -> bool {
    comparable(a) == comparable(b)
}

/// `path` with `.` and `dir/..` removed, without touching the file system.
fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// The relative file name a URI gives, percent-decoded; `None` for `data:` and other
/// URIs with a scheme, and for absolute paths.
fn relative_file(uri: &str) -> Option<PathBuf> {
    if uri.contains(':') {
        return None;
    }
    let name = percent_decode_str(uri).decode_utf8().ok()?;
    let path = PathBuf::from(&*name);
    (!name.starts_with('/') && path.is_relative()).then_some(path)
}

/// Rewrites the relative URIs of buffers and images so that from `to` they name the
/// files they named from `from`.
fn rebase_uris(doc: &mut Value, from: &Path, to: &Path) {
    let (from, to) = (comparable(from), comparable(to));
    for key in ["buffers", "images"] {
        let Some(items) = doc.get_mut(key).and_then(Value::as_array_mut) else { continue };
        for item in items {
            let Some(uri) = item.get_mut("uri") else { continue };
            let rebased =
                uri.as_str().and_then(relative_file).and_then(|f| relative_path(&normalise(&from.join(f)), &to));
            if let Some(rebased) = rebased {
                *uri = rebased.into();
            }
        }
    }
}

/// The URI of the absolute `file` relative to the absolute directory `dir`, with `/`
/// separators and percent-encoded; `None` when no relative path leads there (another
/// drive) or a component is not UTF-8.
fn relative_path(file: &Path, dir: &Path) -> Option<String> {
    let file: Vec<Component> = file.components().collect();
    let dir: Vec<Component> = dir.components().collect();
    let common = file.iter().zip(&dir).take_while(|(a, b)| a == b).count();
    if common == 0 {
        return None;
    }
    let mut parts: Vec<String> = vec!["..".to_string(); dir.len() - common];
    for c in &file[common..] {
        match c {
            Component::Normal(s) => parts.push(utf8_percent_encode(s.to_str()?, URI_PATH).to_string()),
            Component::ParentDir => parts.push("..".to_string()),
            _ => return None,
        }
    }
    Some(parts.join("/"))
}
