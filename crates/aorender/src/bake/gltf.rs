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

use super::asset::{
    Asset, AssetMesh, BakeAt, BakedValues, GeneratedUvs, TextureFiles, TextureMap, UvSet, WriteOptions,
};
use super::gltf_tidy::{self, array};
use crate::error::{Error, Result};
use crate::output::{normalise, write_output, write_output_with};
use crate::scene::extension;
use crate::scene::files::relative_file;
use crate::scene::gltf::{GltfBytes, UriError, json_memory, read_buffers, read_gltf, uri_file};
use crate::scene::input::is_gzip as is_gzip_name;
use crate::scene::input::one_line;
use crate::scene::input::{Input, LoadOptions, Meter};
use crate::scene::mesh::IndexedMesh;
use crate::scene::meshes::stem;
use ::gltf::json::{Value, deserialize, serialize};
use percent_encoding::{AsciiSet, CONTROLS, utf8_percent_encode};
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
    /// How it was read, to read its buffers again.
    options: LoadOptions,
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
    /// [`GltfAsset::read_with`] within the read budget of [`LoadOptions::from_env`],
    /// external URIs refused.
    #[cfg(test)]
    pub fn read(path: &Path) -> Result<GltfAsset> {
        GltfAsset::read_with(path, &LoadOptions::from_env()?)
    }

    /// Reads `path` for baking: one mesh per triangle primitive under each node of the
    /// default scene, in the order the scene loader places them, within the read budget
    /// of `options`. Its buffer URIs are followed, and its image URIs (which the output
    /// refers to) accepted, as `options` allow.
    pub fn read_with(path: &Path, options: &LoadOptions) -> Result<GltfAsset> {
        GltfAsset::read_for_scene(path, options).map(|(asset, _)| asset)
    }

    /// [`GltfAsset::read_with`], with the mesh the scene loader reads from the file: one
    /// parse for both.
    pub(crate) fn read_for_scene(path: &Path, options: &LoadOptions) -> Result<(GltfAsset, IndexedMesh)> {
        let mut meter = Meter::new(&options.limits, "the glTF file's data");
        let (placed, (json, bin)) = read_gltf(path, true, options, &mut meter, |bytes: GltfBytes| {
            // The JSON as a value, and the binary chunk's copy, are held with the rest.
            let held = json_memory(bytes.json) + bytes.bin.filter(|_| bytes.glb).map_or(0, |b| b.len() as u64);
            (held, deserialize::from_slice::<Value>(bytes.json), bytes.bin.filter(|_| bytes.glb).map(<[u8]>::to_vec))
        })
        .and_then(|(placed, (held, json, bin))| meter.charge(path, held).map(|()| (placed, (json, bin))))?;
        let json = json.map_err(|e| Error::scene(path, format!("invalid glTF JSON: {}", one_line(&e.to_string()))))?;
        if !json.is_object() {
            return Err(Error::scene(path, "invalid glTF JSON: not an object"));
        }
        // Images are not read, but the output refers to them: they must be where a
        // buffer could be.
        for (i, image) in json.get("images").and_then(Value::as_array).into_iter().flatten().enumerate() {
            if let Some(uri) = image.get("uri").and_then(Value::as_str).filter(|u| !u.starts_with("data:")) {
                uri_file(path, uri, options.allow_external_uris, false)
                    .map_err(|e| Error::scene(path, format!("image {i}: {e}")))?;
            }
        }
        // The meshes' copies of the positions, their corners and coordinates.
        let corners = 3 * placed.mesh.triangles.len() as u64;
        let uv_corners: u64 =
            placed.placements.iter().map(|p| p.texcoords.len() as u64 * 3 * p.triangles.len() as u64).sum();
        meter.charge(path, 12 * placed.mesh.positions.len() as u64 + 8 * corners + 8 * uv_corners)?;
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
            let face_indices: Vec<u32> = triangles.iter().flatten().map(|&v| (v as usize - base) as u32).collect();
            let uv_sets = placement
                .texcoords
                .iter()
                .map(|(set, uv)| UvSet { set: *set, corners: face_indices.iter().map(|&v| uv[v as usize]).collect() })
                .collect();
            meshes.push(AssetMesh {
                label: placement.label,
                positions: placed.mesh.positions[placement.vertices].to_vec(),
                normals: placement.normals,
                face_starts,
                face_indices,
                to_file: glam::DMat3::from_mat4(placement.world).inverse().as_mat3(),
                uv_sets,
                uv_v_down: true,
                material: placement.material,
                repeating_sets: Vec::new(),
            });
            targets.push(Target { node: placement.node, mesh: placement.mesh, primitive: placement.primitive });
        }
        if meshes.is_empty() {
            return Err(Error::scene(path, "the scene has no triangle primitives to bake"));
        }
        for mesh in &mut meshes {
            mesh.repeating_sets = repeating_sets(&json, mesh.material);
        }
        let options = options.clone();
        let warnings = placed.mesh.warnings.clone();
        Ok((GltfAsset { path: path.to_path_buf(), options, meshes, targets, json, bin, warnings }, placed.mesh))
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
        let (glb, mut doc, _, _) = self.output_document(path)?;
        self.check_values(path, values, options)?;
        let mut notes = self.warnings.clone();

        // The new data goes after the GLB binary chunk's, in buffer 0; without one, into a
        // new buffer: first for a GLB (where the binary chunk's buffer must be), last for
        // a .gltf (where no index changes).
        let mut data = self.bin.clone().unwrap_or_default();
        pad(&mut data, 0);
        let (buffer, shift) = self.owned_buffer(&mut doc, glb, true);
        let buffer = buffer.expect("a bake into vertices writes a buffer");

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
                // A colour is in [0, 1] (glTF 2.0, 3.7.2.1), whatever values it is given.
                let grey = v.ao.iter().map(|a| a.clamp(0.0, 1.0)).flat_map(|a| [a, a, a, 1.0]);
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
        self.emit(path, Draft { glb, doc, data, buffer: Some(buffer), shift, files: Vec::new() }, &mut notes)?;
        Ok(notes)
    }
    fn companion_files(&self, path: &Path, texture: Option<&TextureFiles>) -> Vec<(PathBuf, &'static str)> {
        if extension(path) != "gltf" {
            return Vec::new();
        }
        let (input_dir, output_dir) = (directory(&self.path), directory(path));
        let mut files = Vec::new();
        if texture.is_none_or(|t| t.generated_uvs) || self.bin.is_some() {
            files.push((self.bin_file(path, &input_dir, &output_dir, &mut Vec::new()).0, "the glTF buffer"));
        }
        if let Some(t) = texture {
            // In the order write_textures names them.
            let (used, stem) = (self.used_files(&input_dir), stem(path));
            let mut images: Vec<PathBuf> = Vec::new();
            for _ in 0..t.maps {
                let names: &[&'static str] = if t.bent_normals { &["ao", "bent_normals"] } else { &["ao"] };
                for &name in names {
                    let file = image_file(&output_dir, &stem, name, &used, images.iter());
                    let role = if name == "ao" { "the AO map" } else { "the bent normals map" };
                    images.push(file.clone());
                    files.push((file, role));
                }
            }
        }
        files
    }

    fn write_textures(&self, path: &Path, maps: &[TextureMap], uvs: Option<&GeneratedUvs>) -> Result<Vec<String>> {
        let fail = |message: String| Error::output(path, message);
        let (glb, mut doc, _, output_dir) = self.output_document(path)?;
        let mut notes = self.warnings.clone();
        // A GLB's images go into its binary chunk (buffer 0, made when missing); a .gltf's
        // into PNG files beside it.
        let mut data = self.bin.clone().unwrap_or_default();
        let (buffer, shift) = self.owned_buffer(&mut doc, glb, uvs.is_some());
        // Generated coordinates: each baked primitive's vertices split along the seams,
        // in new accessors (after the binary chunk's data; a .gltf's in a new buffer file).
        let fill = match (uvs, buffer) {
            (Some(uvs), Some(buffer)) => {
                let fill = self.meshes_to_fill(&mut doc, &mut notes);
                self.split_primitives(&mut doc, &mut data, buffer, &fill, uvs).map_err(|e| fail(e.to_string()))?;
                fill
            }
            _ => self.targets.iter().map(|t| t.mesh).collect(),
        };
        let input_dir = directory(&self.path);
        let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
        let used: BTreeSet<PathBuf> = self.external_files().map(|f| comparable(&input_dir.join(f))).collect();
        let stem = stem(path);
        let mut add_image = |doc: &mut Value, png: &[u8], name: &str| -> usize {
            let image = if glb {
                pad(&mut data, 0);
                let offset = data.len();
                data.extend_from_slice(png);
                let views = array(doc, "bufferViews");
                views.push(object([
                    ("buffer", 0.into()),
                    ("byteOffset", offset.into()),
                    ("byteLength", png.len().into()),
                ]));
                object([("bufferView", (views.len() - 1).into()), ("mimeType", "image/png".into())])
            } else {
                let file = image_file(&output_dir, &stem, name, &used, files.iter().map(|(f, _)| f));
                let uri = file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
                files.push((file, png.to_vec()));
                object([("uri", utf8_percent_encode(&uri, URI_PATH).to_string().into())])
            };
            let images = array(doc, "images");
            images.push(image);
            images.len() - 1
        };
        for map in maps {
            let wrap = if map.repeat { 10497 } else { 33071 };
            // LINEAR magnification, LINEAR_MIPMAP_LINEAR minification; one such sampler is
            // shared by every map that wraps alike, the file's own when it has it.
            let wanted = object([
                ("magFilter", 9729.into()),
                ("minFilter", 9987.into()),
                ("wrapS", wrap.into()),
                ("wrapT", wrap.into()),
            ]);
            let samplers = array(&mut doc, "samplers");
            let sampler = match samplers.iter().position(|s| *s == wanted) {
                Some(s) => s,
                None => {
                    samplers.push(wanted);
                    samplers.len() - 1
                }
            };
            let texture = |doc: &mut Value, image: usize| {
                let textures = array(doc, "textures");
                textures.push(object([("sampler", sampler.into()), ("source", image.into())]));
                textures.len() - 1
            };
            let image = add_image(&mut doc, &map.png, "ao");
            let ao = texture(&mut doc, image);
            let bent = map.bent_png.as_ref().map(|png| {
                let image = add_image(&mut doc, png, "bent_normals");
                texture(&mut doc, image)
            });
            let material = match map.material {
                Some(m) => m,
                None => {
                    let materials = array(&mut doc, "materials");
                    materials.push(object([("name", "AO".into())]));
                    let m = materials.len() - 1;
                    for &i in &map.meshes {
                        let t = &self.targets[i];
                        if let Some(p) = doc
                            .get_mut("meshes")
                            .and_then(|ms| ms.get_mut(fill[i]))
                            .and_then(|ms| ms.get_mut("primitives"))
                            .and_then(|ps| ps.get_mut(t.primitive))
                        {
                            p["material"] = m.into();
                        }
                    }
                    notes.push(format!(
                        "{} primitive(s) without a material got material {m} for the AO texture",
                        map.meshes.len()
                    ));
                    m
                }
            };
            let Some(entry) = doc.get_mut("materials").and_then(|ms| ms.get_mut(material)).filter(|m| m.is_object())
            else {
                return Err(fail(format!("material {material} is missing from the JSON")));
            };
            if entry.get("occlusionTexture").is_some() {
                notes.push(format!("material {material}: its occlusionTexture was replaced by the baked one"));
            }
            entry["occlusionTexture"] = object([("index", ao.into()), ("texCoord", map.uv_set.into())]);
            if let Some(bent) = bent {
                if !entry["extras"].is_object() && !entry["extras"].is_null() {
                    notes.push(format!("material {material}: its extras are not an object: the bent normals texture ({bent}) is not referenced"));
                } else {
                    entry["extras"]["bentNormalTexture"] =
                        object([("index", bent.into()), ("texCoord", map.uv_set.into())]);
                }
            }
        }
        self.emit(path, Draft { glb, doc, data, buffer, shift, files }, &mut notes)?;
        Ok(notes)
    }
}

/// An output being assembled: its JSON, the bytes of the buffer the bake writes, and the
/// files to write beside a `.gltf`.
struct Draft {
    glb: bool,
    doc: Value,
    /// Buffer `buffer`'s bytes: the GLB's binary chunk, or a `.gltf`'s `NAME.bin`.
    data: Vec<u8>,
    /// The buffer the bake writes; `None` for a `.gltf` output that needs none.
    buffer: Option<usize>,
    /// How far the input's buffers moved up in `doc` (1 when a GLB's binary chunk buffer
    /// was put first).
    shift: usize,
    /// Files beside a `.gltf` output (its images), with their bytes.
    files: Vec<(PathBuf, Vec<u8>)>,
}

impl GltfAsset {
    /// The buffer the bake writes into `doc` and how far the input's buffers moved: buffer
    /// 0 for a GLB (made first when the input has no binary chunk) or an input GLB's chunk;
    /// else, when `needed`, a new buffer after the file's.
    fn owned_buffer(&self, doc: &mut Value, glb: bool, needed: bool) -> (Option<usize>, usize) {
        if self.bin.is_some() {
            (Some(0), 0)
        } else if glb {
            insert_first_buffer(doc);
            (Some(0), 1)
        } else if needed {
            let buffers = array(doc, "buffers");
            buffers.push(object([]));
            (Some(buffers.len() - 1), 0)
        } else {
            (None, 0)
        }
    }

    /// Finishes and writes an output: a GLB gets every buffer and image of the input in
    /// its binary chunk; the objects the bake left unused are removed and the written
    /// buffer keeps only the bytes still viewed ([`gltf_tidy`]); a `.gltf` gets its
    /// buffer as `NAME.bin` and `draft.files` beside it, written before the JSON.
    fn emit(&self, path: &Path, mut draft: Draft, notes: &mut Vec<String>) -> Result<()> {
        let fail = |message: String| Error::output(path, message);
        if draft.glb {
            self.embed(&mut draft, notes)?;
        }
        let Draft { glb, mut doc, mut data, buffer, shift, mut files } = draft;
        let removed = gltf_tidy::prune(&mut doc, &self.json, |k| if k == gltf_tidy::Kind::Buffers { shift } else { 0 });
        let buffer = buffer.map(|b| {
            let before = removed.get(&gltf_tidy::Kind::Buffers).map_or(0, |r| r.range(..b).count());
            b - before
        });
        if let Some(buffer) = buffer {
            gltf_tidy::compact(&mut doc, &mut data, buffer);
            if data.is_empty() {
                // A buffer holds at least one byte.
                data.extend([0; 4]);
            }
            array(&mut doc, "buffers")[buffer]["byteLength"] = data.len().into();
        }
        if glb {
            let json = serialize::to_vec(&doc).map_err(|e| fail(format!("cannot serialise the glTF JSON: {e}")))?;
            let bytes = glb_bytes(json, data).ok_or_else(|| fail("the GLB would exceed 4 GiB".to_string()))?;
            return write_maybe_gzipped(path, &bytes);
        }
        if let Some(buffer) = buffer {
            let (input_dir, output_dir) = (directory(&self.path), directory(path));
            let (bin_path, uri) = self.bin_file(path, &input_dir, &output_dir, notes);
            array(&mut doc, "buffers")[buffer]["uri"] = uri.into();
            pad(&mut data, 0);
            files.insert(0, (bin_path, data));
        }
        let json = serialize::to_vec_pretty(&doc).map_err(|e| fail(format!("cannot serialise the glTF JSON: {e}")))?;
        // Everything is encoded before the first file is written, so that what can fail
        // between the writes is the disk alone.
        let json = if is_gzip_name(path) { gzip(&json).map_err(|e| fail(e.to_string()))? } else { json };
        for (file, bytes) in &files {
            write_output(file, bytes)?;
        }
        write_output(path, &json)
    }

    /// Moves the input's other buffers and its images named by URI into the GLB's binary
    /// chunk (buffer 0). An image that cannot be read or whose type is unknown keeps its
    /// URI, with a note.
    fn embed(&self, draft: &mut Draft, notes: &mut Vec<String>) -> Result<()> {
        let external = |v: &Value| v.get("uri").is_some();
        let buffers =
            draft.doc.get("buffers").and_then(Value::as_array).map_or(0, |b| b.iter().filter(|b| external(b)).count());
        if buffers > 0 {
            let mut bytes = read_buffers(&self.path, &self.options)?;
            let shift = draft.shift;
            gltf_tidy::embed_buffers(&mut draft.doc, &mut draft.data, 0, |i| {
                i.checked_sub(shift).and_then(|i| bytes.get_mut(i)).map(std::mem::take)
            });
        }
        let mut meter = Meter::new(&self.options.limits, "the images");
        let count = self.json.get("images").and_then(Value::as_array).map_or(0, Vec::len);
        for i in 0..count {
            let Some(uri) = self.json["images"][i].get("uri").and_then(Value::as_str) else { continue };
            let (mime, bytes) = match gltf_tidy::data_uri(uri) {
                Some((mime, bytes)) => (Some(mime).filter(|m| m.starts_with("image/")), bytes),
                None => match self.read_image(uri, &mut meter) {
                    Ok(bytes) => (None, bytes),
                    Err(e) => {
                        notes.push(format!("image {i} ({uri}) could not be read, so the GLB names it: {e}"));
                        continue;
                    }
                },
            };
            let declared = self.json["images"][i].get("mimeType").and_then(Value::as_str).map(str::to_string);
            let Some(mime) = gltf_tidy::image_mime(&bytes).map(str::to_string).or(mime).or(declared) else {
                notes.push(format!("image {i} ({uri}) is of a type glTF does not name, so the GLB keeps its URI"));
                continue;
            };
            let view = gltf_tidy::add_view(&mut draft.doc, &mut draft.data, 0, &bytes);
            let image = &mut draft.doc["images"][i];
            if let Some(o) = image.as_object_mut() {
                o.remove("uri");
            }
            image["bufferView"] = view.into();
            image["mimeType"] = mime.into();
        }
        Ok(())
    }
}

impl GltfAsset {
    /// The bytes of the image file `uri` names, within the read budget and, unless the
    /// file was read with external URIs allowed, from the file's folder alone.
    fn read_image(&self, uri: &str, meter: &mut Meter) -> std::result::Result<Vec<u8>, ImageError> {
        let file = uri_file(&self.path, uri, self.options.allow_external_uris, true)?;
        let input = Input::open_plain(&file, meter.limits()).map_err(ImageError::Read)?;
        input.read_all(&file, meter).map_err(ImageError::Read)
    }

    /// Rewrites each baked primitive (in the meshes `fill` gives each target) on its
    /// vertices split along the seams of `uvs`: every attribute and morph target gathered
    /// through `xref` into new accessors of `buffer` (their bytes appended to `data`), the
    /// generated set added as `TEXCOORD_n`, and new 32-bit triangle indices.
    fn split_primitives(
        &self,
        doc: &mut Value,
        data: &mut Vec<u8>,
        buffer: usize,
        fill: &[usize],
        uvs: &GeneratedUvs,
    ) -> std::result::Result<(), SplitError> {
        let buffers = read_buffers(&self.path, &self.options).map_err(SplitError::Buffers)?;
        for (i, (t, mesh)) in self.targets.iter().zip(&self.meshes).enumerate() {
            let Some(generated) = uvs.meshes.get(i).filter(|u| !u.xref.is_empty()) else { continue };
            let primitive = &self.json["meshes"][t.mesh]["primitives"][t.primitive];
            let fail = |why: AccessorError| SplitError::Primitive { mesh: mesh.label.clone(), why };
            let gather = |doc: &mut Value, data: &mut Vec<u8>, accessor: &Value, position: bool| {
                let index = accessor.as_u64().ok_or_else(|| fail(AccessorError::NotAnIndex))?;
                let (bytes, size) = accessor_bytes(&self.json, &buffers, index as usize).map_err(fail)?;
                let mut out = Vec::with_capacity(generated.xref.len() * size);
                for &v in &generated.xref {
                    let v = v as usize;
                    out.extend_from_slice(
                        bytes.get(v * size..(v + 1) * size).ok_or_else(|| fail(AccessorError::PastAttribute))?,
                    );
                }
                Ok::<usize, SplitError>(add_gathered(
                    doc,
                    data,
                    buffer,
                    &self.json["accessors"][index as usize],
                    &out,
                    size,
                    position,
                ))
            };
            let mut attributes = object([]);
            for (name, accessor) in primitive["attributes"].as_object().into_iter().flatten() {
                attributes[name.as_str()] = gather(doc, data, accessor, name == "POSITION")?.into();
            }
            let set = format!("TEXCOORD_{}", generated.set);
            let coordinates = generated.uvs.iter().flat_map(|c| c.to_array());
            attributes[set.as_str()] = add_accessor(doc, data, buffer, "VEC2", generated.uvs.len(), coordinates).into();
            let mut targets = Vec::new();
            for target in primitive.get("targets").and_then(Value::as_array).into_iter().flatten() {
                let mut out = object([]);
                for (name, accessor) in target.as_object().into_iter().flatten() {
                    out[name.as_str()] = gather(doc, data, accessor, name == "POSITION")?.into();
                }
                targets.push(out);
            }
            let indices = add_indices(doc, data, buffer, &generated.corners);
            let Some(p) = doc
                .get_mut("meshes")
                .and_then(|m| m.get_mut(fill[i]))
                .and_then(|m| m.get_mut("primitives"))
                .and_then(|p| p.get_mut(t.primitive))
                .filter(|p| p.is_object())
            else {
                return Err(fail(AccessorError::MissingPrimitive));
            };
            p["attributes"] = attributes;
            p["indices"] = indices.into();
            // The loader gave strips and fans as triangles: the new indices list those.
            p["mode"] = 4.into();
            if !targets.is_empty() {
                p["targets"] = Value::Array(targets);
            }
        }
        Ok(())
    }
}

impl GltfAsset {
    /// What a write to `path` starts from: whether it is a GLB, the file's JSON with its
    /// relative URIs rebased to `path`'s directory, the input's directory and the output's.
    fn output_document(&self, path: &Path) -> Result<(bool, Value, PathBuf, PathBuf)> {
        let glb = match extension(path).as_str() {
            "glb" => true,
            "gltf" => false,
            ext => {
                let message = format!("cannot write glTF to a '.{ext}' file: expected .gltf or .glb");
                return Err(Error::output(path, message));
            }
        };
        let mut doc = self.json.clone();
        let input_dir = directory(&self.path);
        let output_dir = directory(path);
        if !same_directory(&input_dir, &output_dir) {
            rebase_uris(&mut doc, &input_dir, &output_dir);
        }
        Ok((glb, doc, input_dir, output_dir))
    }

    /// The files a `.gltf` output's external buffers and images resolve to, as
    /// [`comparable`] gives them.
    fn used_files(&self, input_dir: &Path) -> BTreeSet<PathBuf> {
        self.external_files().map(|f| comparable(&input_dir.join(f))).collect()
    }

    /// The file beside a `.gltf` output that holds its new buffer, and the URI naming it:
    /// `<stem>.bin`, or `<stem>_ao.bin`, `<stem>_ao2.bin`… when the input uses a file of
    /// that name (baking a file over itself must not overwrite its own buffers).
    fn bin_file(&self, path: &Path, input_dir: &Path, output_dir: &Path, notes: &mut Vec<String>) -> (PathBuf, String) {
        let used = self.used_files(input_dir);
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

/// The texture coordinate sets along which every texture of `material` on that set
/// repeats in both directions (glTF 2.0, 5.26: a texture without a sampler, or a sampler
/// without a wrap mode, repeats).
fn repeating_sets(json: &Value, material: Option<usize>) -> Vec<u32> {
    const REPEAT: u64 = 10497;
    let Some(m) = material.and_then(|m| json.get("materials")?.get(m)) else { return Vec::new() };
    let pbr = m.get("pbrMetallicRoughness");
    let infos = [
        pbr.and_then(|p| p.get("baseColorTexture")),
        pbr.and_then(|p| p.get("metallicRoughnessTexture")),
        m.get("normalTexture"),
        m.get("occlusionTexture"),
        m.get("emissiveTexture"),
    ];
    let mut sets: BTreeMap<u32, bool> = BTreeMap::new();
    for info in infos.into_iter().flatten() {
        let set = info.get("texCoord").and_then(Value::as_u64).unwrap_or(0) as u32;
        let sampler = info
            .get("index")
            .and_then(Value::as_u64)
            .and_then(|t| json.get("textures")?.get(t as usize)?.get("sampler")?.as_u64())
            .and_then(|s| json.get("samplers")?.get(s as usize));
        let wrap = |key: &str| sampler.and_then(|s| s.get(key)?.as_u64()).unwrap_or(REPEAT);
        let repeats = wrap("wrapS") == REPEAT && wrap("wrapT") == REPEAT;
        *sets.entry(set).or_insert(true) &= repeats;
    }
    sets.into_iter().filter(|(_, r)| *r).map(|(s, _)| s).collect()
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

/// Bytes of one component of glTF's `componentType`.
fn component_bytes(component_type: Option<u64>) -> std::result::Result<usize, AccessorError> {
    match component_type {
        Some(5120 | 5121) => Ok(1),
        Some(5122 | 5123) => Ok(2),
        Some(5125 | 5126) => Ok(4),
        t => Err(AccessorError::ComponentType(t)),
    }
}

/// Why an image of a glTF file could not be read into a GLB.
#[derive(Debug, thiserror::Error)]
enum ImageError {
    /// Its URI names no file the asset may read.
    #[error(transparent)]
    Uri(#[from] UriError),
    /// The file could not be read (the message without the file, which the URI names).
    #[error("{}", .0.message())]
    Read(Error),
}

/// Why the vertices of a baked primitive could not be split along its texture seams.
#[derive(Debug, thiserror::Error)]
enum SplitError {
    /// The asset's buffers could not be read.
    #[error("{0}")]
    Buffers(Error),
    /// A primitive (of the mesh named) whose attributes could not be gathered.
    #[error("{mesh}: cannot add texture coordinates: {why}")]
    Primitive { mesh: String, why: AccessorError },
}

/// What is wrong with an accessor of a primitive being rewritten.
#[derive(Debug, thiserror::Error)]
enum AccessorError {
    #[error("an attribute is not an accessor index")]
    NotAnIndex,
    #[error("index past the attribute")]
    PastAttribute,
    #[error("the primitive is missing from the JSON")]
    MissingPrimitive,
    #[error("a buffer view is missing")]
    MissingView,
    #[error("its vertex data is compressed (meshopt)")]
    Meshopt,
    #[error("a buffer view lies outside its buffer")]
    ViewOutside,
    #[error("accessor {0} is missing")]
    Missing(usize),
    #[error("an accessor has no count")]
    NoCount,
    /// An accessor whose type (as the JSON gives it) is no vertex attribute's.
    #[error("accessor {index} has type {ty:?}, not a vertex attribute's")]
    Type { index: usize, ty: Option<String> },
    #[error("unknown componentType {0:?}")]
    ComponentType(Option<u64>),
    #[error("accessor {0} overruns its view")]
    Overrun(usize),
    #[error("accessor {0}: sparse indices overrun")]
    SparseIndices(usize),
    #[error("accessor {0}: sparse values overrun")]
    SparseValues(usize),
    #[error("accessor {0}: a sparse index is out of range")]
    SparseIndex(usize),
}

/// The bytes of buffer view `view`, and its stride when it gives one.
fn view_bytes<'a>(
    json: &Value,
    buffers: &'a [Vec<u8>],
    view: Option<u64>,
) -> std::result::Result<(&'a [u8], Option<usize>), AccessorError> {
    let v = view.and_then(|i| json["bufferViews"].get(i as usize)).ok_or(AccessorError::MissingView)?;
    if v.get("extensions").and_then(Value::as_object).is_some_and(|e| e.keys().any(|k| k.contains("meshopt"))) {
        return Err(AccessorError::Meshopt);
    }
    let number = |key: &str| v.get(key).and_then(Value::as_u64).map(|n| n as usize);
    let (offset, length) = (number("byteOffset").unwrap_or(0), number("byteLength").unwrap_or(0));
    let bytes = number("buffer")
        .and_then(|b| buffers.get(b))
        .and_then(|b| b.get(offset..offset + length))
        .ok_or(AccessorError::ViewOutside)?;
    Ok((bytes, number("byteStride")))
}

/// Accessor `index`'s elements, tightly packed (an accessor without a view is zeros, a
/// sparse one has its substitutions applied), and the bytes of one element.
fn accessor_bytes(
    json: &Value,
    buffers: &[Vec<u8>],
    index: usize,
) -> std::result::Result<(Vec<u8>, usize), AccessorError> {
    let a = json["accessors"].get(index).ok_or(AccessorError::Missing(index))?;
    let count = a["count"].as_u64().ok_or(AccessorError::NoCount)? as usize;
    let components = match a["type"].as_str() {
        Some("SCALAR") => 1,
        Some("VEC2") => 2,
        Some("VEC3") => 3,
        Some("VEC4") => 4,
        t => return Err(AccessorError::Type { index, ty: t.map(str::to_string) }),
    };
    let component = component_bytes(a["componentType"].as_u64())?;
    let size = components * component;
    let mut out = vec![0u8; count * size];
    let offset = |v: &Value| v.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
    if a.get("bufferView").is_some() {
        let (bytes, stride) = view_bytes(json, buffers, a["bufferView"].as_u64())?;
        let (start, stride) = (offset(a), stride.unwrap_or(size));
        for i in 0..count {
            let at = start + i * stride;
            let element = bytes.get(at..at + size).ok_or(AccessorError::Overrun(index))?;
            out[i * size..(i + 1) * size].copy_from_slice(element);
        }
    }
    if let Some(sparse) = a.get("sparse") {
        let n = sparse["count"].as_u64().unwrap_or(0) as usize;
        let (ix, vx) = (&sparse["indices"], &sparse["values"]);
        let (indices, _) = view_bytes(json, buffers, ix["bufferView"].as_u64())?;
        let (values, _) = view_bytes(json, buffers, vx["bufferView"].as_u64())?;
        let width = component_bytes(ix["componentType"].as_u64())?;
        for k in 0..n {
            let at = offset(ix) + k * width;
            let raw = indices.get(at..at + width).ok_or(AccessorError::SparseIndices(index))?;
            let i = raw.iter().rev().fold(0usize, |acc, &b| (acc << 8) | usize::from(b));
            let at = offset(vx) + k * size;
            let value = values.get(at..at + size).ok_or(AccessorError::SparseValues(index))?;
            out.get_mut(i * size..(i + 1) * size).ok_or(AccessorError::SparseIndex(index))?.copy_from_slice(value);
        }
    }
    Ok((out, size))
}

/// Adds an accessor like `like` (type, component type, normalisation, name, extras) of
/// `bytes` (elements of `size` bytes, each stored on a 4-byte boundary as vertex
/// attributes must be) in a new view of `buffer`. A `POSITION` (`position`, of the mesh
/// or of a morph target), which glTF requires to have bounds, and any accessor whose
/// original had them, gets the bounds of the elements it holds.
fn add_gathered(
    doc: &mut Value,
    data: &mut Vec<u8>,
    buffer: usize,
    like: &Value,
    bytes: &[u8],
    size: usize,
    position: bool,
) -> usize {
    pad(data, 0);
    let offset = data.len();
    let stride = size.next_multiple_of(4);
    for element in bytes.chunks_exact(size) {
        data.extend_from_slice(element);
        data.resize(data.len() + stride - size, 0);
    }
    let count = bytes.len() / size;
    let views = array(doc, "bufferViews");
    let mut view = object([
        ("buffer", buffer.into()),
        ("byteOffset", offset.into()),
        ("byteLength", (data.len() - offset).max(stride).into()),
        ("target", ARRAY_BUFFER.into()),
    ]);
    if stride != size {
        view["byteStride"] = stride.into();
    }
    views.push(view);
    let view = views.len() - 1;
    let mut accessor = object([
        ("bufferView", view.into()),
        ("componentType", like["componentType"].clone()),
        ("count", count.into()),
        ("type", like["type"].clone()),
    ]);
    for key in ["normalized", "name", "extras"] {
        if let Some(v) = like.get(key).filter(|v| **v != Value::Bool(false)) {
            accessor[key] = v.clone();
        }
    }
    if (position || like.get("min").is_some() || like.get("max").is_some())
        && let Some((lo, hi)) = bounds(bytes, size, like["componentType"].as_u64())
    {
        accessor["min"] = lo.into();
        accessor["max"] = hi.into();
    }
    let accessors = array(doc, "accessors");
    accessors.push(accessor);
    accessors.len() - 1
}

/// The per-component minimum and maximum of `bytes` (elements of `size` bytes of
/// components of `component_type`), as glTF's `min` and `max` hold them (integers for
/// integer components); `None` when there is no element.
fn bounds(bytes: &[u8], size: usize, component_type: Option<u64>) -> Option<(Vec<Value>, Vec<Value>)> {
    let width = component_bytes(component_type).ok()?;
    let n = size / width;
    let read = |c: &[u8]| -> f64 {
        match component_type {
            Some(5120) => f64::from(c[0] as i8),
            Some(5121) => f64::from(c[0]),
            Some(5122) => f64::from(i16::from_le_bytes([c[0], c[1]])),
            Some(5123) => f64::from(u16::from_le_bytes([c[0], c[1]])),
            Some(5125) => f64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            _ => f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
        }
    };
    let (mut lo, mut hi) = (vec![f64::INFINITY; n], vec![f64::NEG_INFINITY; n]);
    for element in bytes.chunks_exact(size) {
        for (c, part) in element.chunks_exact(width).enumerate() {
            let v = read(part);
            (lo[c], hi[c]) = (lo[c].min(v), hi[c].max(v));
        }
    }
    if bytes.len() < size {
        return None;
    }
    let json = |v: Vec<f64>| -> Vec<Value> {
        v.into_iter()
            .map(|x| if component_type == Some(u64::from(FLOAT)) { x.into() } else { (x as i64).into() })
            .collect()
    };
    Some((json(lo), json(hi)))
}

/// Adds a 32-bit index accessor of `indices` in a new view of `buffer`.
fn add_indices(doc: &mut Value, data: &mut Vec<u8>, buffer: usize, indices: &[u32]) -> usize {
    pad(data, 0);
    let offset = data.len();
    data.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    let views = array(doc, "bufferViews");
    views.push(object([
        ("buffer", buffer.into()),
        ("byteOffset", offset.into()),
        ("byteLength", (data.len() - offset).into()),
        // ELEMENT_ARRAY_BUFFER.
        ("target", 34963.into()),
    ]));
    let view = views.len() - 1;
    let accessors = array(doc, "accessors");
    // UNSIGNED_INT.
    accessors.push(object([
        ("bufferView", view.into()),
        ("componentType", 5125.into()),
        ("count", indices.len().into()),
        ("type", "SCALAR".into()),
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
pub(crate) fn glb_bytes(mut json: Vec<u8>, mut bin: Vec<u8>) -> Option<Vec<u8>> {
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
    crate::output::gzip::gzip(bytes)
}

/// The PNG file beside a `.gltf` output that holds its image `name` (`ao`,
/// `bent_normals`): `<stem>_<name>.png`, or `<stem>_<name>1.png`… when the input uses
/// that file or an earlier image of this output (`taken`) has it.
fn image_file<'a>(
    output_dir: &Path,
    stem: &str,
    name: &str,
    used: &BTreeSet<PathBuf>,
    taken: impl Iterator<Item = &'a PathBuf> + Clone,
) -> PathBuf {
    for k in 0.. {
        let file = output_dir.join(if k == 0 { format!("{stem}_{name}.png") } else { format!("{stem}_{name}{k}.png") });
        if !used.contains(&comparable(&file)) && !taken.clone().any(|f| *f == file) {
            return file;
        }
    }
    unreachable!("the input and the output name finitely many files")
}

/// Writes `bytes` to `path` under the output policy, gzipped when its name ends in `.gz`.
fn write_maybe_gzipped(path: &Path, bytes: &[u8]) -> Result<()> {
    if !is_gzip_name(path) {
        return write_output(path, bytes);
    }
    write_output_with(path, &mut |w| {
        let mut encoder = crate::output::gzip::GzipWriter::new(w)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::meshes::read_mesh;
    use ::gltf::Gltf;
    use ::gltf::accessor::{DataType, Dimensions};
    use ::gltf::buffer::Source;
    use ::gltf::mesh::Semantic;
    use base64::Engine;
    use glam::Vec3;
    use percent_encoding::percent_decode_str;
    use serde_json::json;
    use std::io::Read;

    fn engine() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/2CylinderEngine.glb")
    }

    fn f32_bytes(values: impl IntoIterator<Item = f32>) -> Vec<u8> {
        values.into_iter().flat_map(f32::to_le_bytes).collect()
    }

    const TETRA: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    const STRIP: [[f32; 3]; 4] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    const COLORS: [f32; 16] = [1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.5, 0.5, 0.5, 1.0];

    /// A scene of a tetrahedron with normals placed by two nodes (with a points primitive
    /// the bake skips) and a triangle strip with its own COLOR_0, under a root node; a
    /// material with an extension and extras, an image, an unknown field. Buffer 0 is the
    /// file `geom.bin` (returned), buffer 1 a `data:` URI.
    fn fixture() -> (Value, Vec<u8>) {
        let mut geom = f32_bytes(TETRA.into_iter().flatten());
        geom.extend(f32_bytes(TETRA.into_iter().flat_map(|p| p.map(|c| c - 0.25))));
        geom.extend([0u16, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3].into_iter().flat_map(u16::to_le_bytes));
        geom.extend(f32_bytes(STRIP.into_iter().flatten()));
        assert_eq!(geom.len(), 168);
        let colors = base64::engine::general_purpose::STANDARD.encode(f32_bytes(COLORS));
        let doc = json!({
            "asset": {"version": "2.0", "generator": "by hand", "extras": {"note": "kept"}},
            "extensionsUsed": ["KHR_materials_emissive_strength"],
            "x_unknown": {"a": [1, 2, 3]},
            "scene": 0,
            "scenes": [{"nodes": [0], "name": "main"}],
            "nodes": [
                {"name": "root", "translation": [1.0, 2.0, 3.0], "children": [1, 2, 3]},
                {"name": "left", "mesh": 0, "rotation": [0.0, 0.0, 1.0, 1.0]},
                {"name": "right", "mesh": 0, "scale": [2.0, 0.5, 1.0], "translation": [5.0, 0.0, 0.0], "extras": {"tag": 7}},
                {"name": "strip", "mesh": 1, "matrix": [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -4.0, 1.0]}
            ],
            "meshes": [
                {"name": "tetra", "primitives": [
                    {"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "material": 0, "extras": {"p": 1}},
                    {"attributes": {"POSITION": 0}, "mode": 0}
                ]},
                {"name": "strip", "primitives": [{"attributes": {"POSITION": 3, "COLOR_0": 4}, "mode": 5}]}
            ],
            "materials": [{
                "name": "paint",
                "emissiveFactor": [1.0, 1.0, 1.0],
                "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 2.0}},
                "extras": {"m": true}
            }],
            "images": [{"uri": "tex%20ture.png"}],
            "buffers": [
                {"uri": "geom.bin", "byteLength": 168},
                {"uri": format!("data:application/octet-stream;base64,{colors}"), "byteLength": 64}
            ],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 48, "target": 34962},
                {"buffer": 0, "byteOffset": 48, "byteLength": 48, "target": 34962},
                {"buffer": 0, "byteOffset": 96, "byteLength": 24, "target": 34963},
                {"buffer": 0, "byteOffset": 120, "byteLength": 48},
                {"buffer": 1, "byteLength": 64}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]},
                {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
                {"bufferView": 2, "componentType": 5123, "count": 12, "type": "SCALAR"},
                {"bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
                {"bufferView": 4, "componentType": 5126, "count": 4, "type": "VEC4"}
            ]
        });
        (doc, geom)
    }

    /// Writes the fixture into `dir` as `name`: a `.gltf` beside `geom.bin`, or a `.glb`
    /// with `geom.bin` as its binary chunk. Returns the path and the JSON written.
    fn write_fixture(dir: &Path, name: &str) -> (PathBuf, Value) {
        let (mut doc, geom) = fixture();
        let path = dir.join(name);
        // The image the fixture names, for a GLB output to embed.
        let mut png = std::io::Cursor::new(Vec::new());
        image::GrayImage::new(2, 2).write_to(&mut png, image::ImageFormat::Png).unwrap();
        std::fs::write(dir.join("tex ture.png"), png.into_inner()).unwrap();
        if name.ends_with(".glb") {
            doc["buffers"][0] = json!({"byteLength": 168});
            std::fs::write(&path, glb_bytes(serde_json::to_vec(&doc).unwrap(), geom).unwrap()).unwrap();
        } else {
            std::fs::write(dir.join("geom.bin"), geom).unwrap();
            std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
        }
        (path, doc)
    }

    /// Distinct values for every vertex of every mesh.
    fn values(asset: &GltfAsset, bent: bool) -> Vec<BakedValues> {
        (asset.meshes().iter().enumerate())
            .map(|(i, m)| {
                let n = m.positions.len();
                BakedValues {
                    ao: (0..n).map(|k| 0.1 * (i + 1) as f32 + 0.01 * k as f32).collect(),
                    std_error: (0..n).map(|k| 0.001 * (k + 1) as f32).collect(),
                    bent_normals: bent.then(|| (0..n).map(|k| Vec3::new(i as f32, k as f32, 1.0)).collect()),
                }
            })
            .collect()
    }

    /// The loader's triangles, their corners' positions as bits.
    fn loaded_triangles(path: &Path) -> Vec<[[u32; 3]; 3]> {
        // An output in another folder refers to the input's files there (`../geom.bin`).
        let options = LoadOptions { allow_external_uris: true, ..LoadOptions::from_env().unwrap() };
        let mesh = read_mesh(path, &options, &mut Meter::unlimited(), None).unwrap_or_else(|e| panic!("{e}"));
        mesh.triangles.iter().map(|t| t.map(|i| mesh.positions[i as usize].to_array().map(f32::to_bits))).collect()
    }

    /// The assets' faces, in order, their corners' positions as bits.
    fn asset_triangles(asset: &GltfAsset) -> Vec<[[u32; 3]; 3]> {
        let mut out = Vec::new();
        for mesh in asset.meshes() {
            for f in 0..mesh.face_count() {
                let face = mesh.face(f);
                assert_eq!(face.len(), 3, "{}", mesh.label);
                out.push([0, 1, 2].map(|c| mesh.positions[face[c] as usize].to_array().map(f32::to_bits)));
            }
        }
        out
    }

    #[test]
    fn positions_are_the_scene_loaders_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let (gltf, _) = write_fixture(dir.path(), "scene.gltf");
        let (glb, _) = write_fixture(dir.path(), "scene.glb");
        for path in [engine(), gltf, glb] {
            let asset = GltfAsset::read(&path).unwrap_or_else(|e| panic!("{e}"));
            let want = loaded_triangles(&path);
            assert!(asset_triangles(&asset) == want, "{}: the positions differ from the loader's", path.display());
        }
        let asset = GltfAsset::read(&dir.path().join("scene.gltf")).unwrap();
        let meshes = asset.meshes();
        let labels: Vec<&str> = meshes.iter().map(|m| m.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "node 1 mesh 0 (\"tetra\") primitive 0",
                "node 2 mesh 0 (\"tetra\") primitive 0",
                "node 3 mesh 1 (\"strip\") primitive 0"
            ]
        );
        // The tetrahedron placed twice, differently; the strip triangulated into 2 faces.
        assert_ne!(meshes[0].positions, meshes[1].positions);
        assert_eq!((meshes[0].face_count(), meshes[2].face_count()), (4, 2));
        assert_eq!(meshes[2].face_indices, [0, 1, 2, 2, 1, 3]);
        // Normals by the normal matrix: node 1 turns a quarter about z, node 2 scales by
        // (2, 0.5, 1), which divides the normal's components by the same.
        let file = TETRA.map(|p| Vec3::from(p.map(|c| c - 0.25)));
        let left = meshes[0].normals.as_ref().unwrap();
        let right = meshes[1].normals.as_ref().unwrap();
        for k in 0..4 {
            let n = file[k];
            assert!(left[k].abs_diff_eq(Vec3::new(-n.y, n.x, n.z), 1e-6), "{} {}", left[k], n);
            assert!(right[k].abs_diff_eq(Vec3::new(n.x / 2.0, n.y * 2.0, n.z), 1e-6), "{} {}", right[k], n);
        }
        assert_eq!(meshes[2].normals, None);
    }

    /// The bytes of `path`, gunzipped when it is named `.gz`.
    fn read_plain(path: &Path) -> Vec<u8> {
        let bytes = std::fs::read(path).unwrap();
        if !is_gzip_name(path) {
            return bytes;
        }
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&bytes[..]).read_to_end(&mut out).unwrap();
        out
    }

    /// `path` read by the `gltf` crate (which validates it), its buffers loaded.
    fn independent_read(path: &Path) -> (Gltf, Vec<Vec<u8>>) {
        let gltf = Gltf::from_slice(&read_plain(path)).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let buffers = gltf
            .buffers()
            .map(|b| match b.source() {
                Source::Bin => gltf.blob.clone().expect("the GLB has a binary chunk"),
                Source::Uri(uri) => match uri.strip_prefix("data:") {
                    Some(data) => {
                        let (_, payload) = data.split_once(";base64,").unwrap();
                        base64::engine::general_purpose::STANDARD.decode(payload).unwrap()
                    }
                    None => {
                        let name = percent_decode_str(uri).decode_utf8().unwrap();
                        std::fs::read(directory(path).join(&*name)).unwrap()
                    }
                },
            })
            .collect();
        (gltf, buffers)
    }

    /// Asserts that the Khronos glTF-Validator (`scripts/validate-gltf`) finds in `output`
    /// no error, warning or unused object whose code it does not find in `input`. Outside
    /// CI, a missing node or npm skips the check, loudly.
    fn assert_valid(output: &Path, input: &Path) {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/validate-gltf");
        let out = std::process::Command::new("bash").arg(script).arg(output).arg(input).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        if out.status.code() == Some(3) && std::env::var_os("CI").is_none() {
            eprintln!("SKIPPED: the glTF validator cannot run ({})", stderr.trim());
            return;
        }
        assert!(out.status.success(), "scripts/validate-gltf: {stderr}");
        let reports: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
        let issues = |r: &Value| -> Vec<(String, u64, String)> {
            let list = r["issues"].as_array().unwrap().iter();
            list.map(|i| {
                (i["code"].as_str().unwrap().into(), i["severity"].as_u64().unwrap(), i["pointer"].to_string())
            })
            .collect()
        };
        let (ours, theirs) = (issues(&reports[0]), issues(&reports[1]));
        let new: Vec<_> = ours
            .iter()
            .filter(|(code, severity, _)| *severity <= 1 || code == "UNUSED_OBJECT")
            .filter(|(code, ..)| !theirs.iter().any(|t| t.0 == *code))
            .collect();
        assert!(new.is_empty(), "{}: the validator finds {new:?}", output.display());
    }

    /// The floats of a tightly packed float accessor.
    fn floats(accessor: &::gltf::Accessor, buffers: &[Vec<u8>]) -> Vec<f32> {
        assert_eq!(accessor.data_type(), DataType::F32);
        let view = accessor.view().unwrap();
        assert!(view.stride().is_none_or(|s| s == accessor.size()));
        assert_eq!(view.offset() % 4, 0);
        let len = accessor.count() * accessor.size();
        assert!(accessor.offset() + len <= view.length());
        let start = view.offset() + accessor.offset();
        let data = &buffers[view.buffer().index()][start..start + len];
        data.chunks(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
    }

    /// The output's JSON less what the bake adds, its buffers and URIs put back as in
    /// `input`, so that what is left must equal `input`.
    fn without_additions(out: &Value, input: &Value, shift: usize) -> Value {
        let mut out = out.clone();
        for key in ["accessors", "bufferViews", "meshes"] {
            let n = input[key].as_array().unwrap().len();
            out[key].as_array_mut().unwrap().truncate(n);
        }
        for (m, mesh) in out["meshes"].as_array_mut().unwrap().iter_mut().enumerate() {
            for (p, primitive) in mesh["primitives"].as_array_mut().unwrap().iter_mut().enumerate() {
                let attributes = primitive["attributes"].as_object_mut().unwrap();
                for name in [AO, AO_STD_ERROR, BENT_NORMAL] {
                    attributes.remove(name);
                }
                if input["meshes"][m]["primitives"][p]["attributes"].get("COLOR_0").is_none() {
                    attributes.remove("COLOR_0");
                }
            }
        }
        for (node, original) in out["nodes"].as_array_mut().unwrap().iter_mut().zip(input["nodes"].as_array().unwrap())
        {
            if let Some(mesh) = original.get("mesh") {
                node["mesh"] = mesh.clone();
            }
        }
        for view in out["bufferViews"].as_array_mut().unwrap() {
            view["buffer"] = (view["buffer"].as_u64().unwrap().saturating_sub(shift as u64)).into();
        }
        if out["buffers"].as_array().unwrap().len() > 1 {
            out["buffers"] = input["buffers"].clone();
            out["images"] = input["images"].clone();
        }
        out
    }

    #[test]
    fn round_trips_through_gltf_and_glb_outputs() {
        // (input, output, write std_error and bent normals)
        let cases = [
            ("scene.gltf", "out/baked.gltf", true),
            ("scene.gltf", "out/baked.glb", true),
            ("scene.gltf", "baked.gltf", false),
            ("scene.glb", "baked.glb.gz", true),
            ("scene.glb", "out/baked.gltf.gz", false),
            ("scene.glb", "baked.glb", false),
        ];
        for (input, output, extra) in cases {
            let what = format!("{input} → {output}");
            let dir = tempfile::tempdir().unwrap();
            std::fs::create_dir(dir.path().join("out")).unwrap();
            let (input_path, input_json) = write_fixture(dir.path(), input);
            let output_path = dir.path().join(output);
            let asset = GltfAsset::read(&input_path).unwrap_or_else(|e| panic!("{what}: {e}"));
            let values = values(&asset, extra);
            let options = WriteOptions { std_error: extra, ..WriteOptions::default() };
            let notes = asset.write(&output_path, &values, &options).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!(notes.len(), 3, "{what}: {notes:?}");
            assert!(notes[0].contains("2 POINTS"), "{what}: {notes:?}");
            assert_eq!(
                notes[1],
                "mesh 0 (\"tetra\") is placed by 2 nodes: to carry their own AO, node 2 now uses a copy of it (mesh 2)"
            );
            assert!(
                notes[2].starts_with("node 3 mesh 1 (\"strip\") primitive 0: its own COLOR_0"),
                "{what}: {notes:?}"
            );

            // The project's loader finds the same triangles, and the same meshes to bake.
            assert!(loaded_triangles(&output_path) == loaded_triangles(&input_path), "{what}: triangles differ");
            assert_valid(&output_path, &input_path);
            let allowed = LoadOptions { allow_external_uris: true, ..LoadOptions::from_env().unwrap() };
            let again = GltfAsset::read_with(&output_path, &allowed).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert!(asset_triangles(&again) == asset_triangles(&asset), "{what}: meshes differ");

            // The gltf crate validates the file and finds the values on each node's primitive.
            let (gltf, buffers) = independent_read(&output_path);
            let mut node_meshes = Vec::new();
            for (node, v) in [1, 2, 3].into_iter().zip(&values) {
                let node = gltf.nodes().nth(node).unwrap();
                let mesh = node.mesh().unwrap();
                node_meshes.push(mesh.index());
                let primitive = mesh.primitives().next().unwrap();
                let n = v.ao.len();
                let get = |name: &str| primitive.get(&Semantic::Extras(name.to_string()));
                let ao = get("AO").unwrap_or_else(|| panic!("{what}: no _AO"));
                assert_eq!((ao.count(), ao.dimensions()), (n, Dimensions::Scalar));
                assert_eq!(floats(&ao, &buffers), v.ao, "{what}");
                let color = primitive.get(&Semantic::Colors(0)).unwrap();
                assert_eq!((color.count(), color.dimensions()), (n, Dimensions::Vec4));
                let grey: Vec<f32> = v.ao.iter().flat_map(|&a| [a, a, a, 1.0]).collect();
                if node.index() == 3 {
                    // The strip's own colours are kept.
                    assert_eq!(color.index(), 4);
                    assert_eq!(floats(&color, &buffers), COLORS);
                } else {
                    assert_eq!(floats(&color, &buffers), grey, "{what}");
                }
                match get("AO_STD_ERROR") {
                    Some(a) => assert_eq!(floats(&a, &buffers), v.std_error, "{what}"),
                    None => assert!(!extra, "{what}: no _AO_STD_ERROR"),
                }
                match (get("BENT_NORMAL"), &v.bent_normals) {
                    (Some(a), Some(b)) => {
                        assert_eq!(a.dimensions(), Dimensions::Vec3);
                        let want: Vec<f32> = b.iter().flat_map(|d| d.to_array()).collect();
                        assert_eq!(floats(&a, &buffers), want, "{what}");
                    }
                    (None, None) => {}
                    _ => panic!("{what}: _BENT_NORMAL where not asked for, or missing"),
                }
            }
            // The mesh placed twice now has one mesh per placement.
            assert_eq!(node_meshes, [0, 2, 1], "{what}");

            // Everything else of the input is still there.
            let out_glb = output.contains(".glb");
            let out_json: Value = serde_json::to_value(gltf.document.clone().into_json()).unwrap();
            let out_json = match out_glb {
                true => {
                    let bytes = read_plain(&output_path);
                    let glb = ::gltf::binary::Glb::from_slice(&bytes).unwrap();
                    serde_json::from_slice(&glb.json).unwrap()
                }
                false => serde_json::from_slice(&read_plain(&output_path)).unwrap_or(out_json),
            };
            let input_glb = input.ends_with(".glb");
            let shift = usize::from(out_glb && !input_glb);
            let moved = output.starts_with("out/");
            let rebased = |uri: &str| if moved { format!("../{uri}") } else { uri.to_string() };
            let in_buffers = input_json["buffers"].as_array().unwrap();
            let out_buffers = out_json["buffers"].as_array().unwrap();
            if out_glb {
                // Self-contained: one buffer, the binary chunk, holding every view's bytes
                // as the input had them, and the image.
                assert_eq!(out_buffers.len(), 1, "{what}");
                assert!(out_buffers[0].get("uri").is_none(), "{what}");
                let (input_gltf, input_buffers) = independent_read(&input_path);
                for (view, original) in gltf.views().zip(input_gltf.views()) {
                    let bytes = |v: &::gltf::buffer::View, b: &[Vec<u8>]| {
                        b[v.buffer().index()][v.offset()..v.offset() + v.length()].to_vec()
                    };
                    assert_eq!(bytes(&view, &buffers), bytes(&original, &input_buffers), "{what}");
                }
                let image = gltf.images().next().unwrap();
                let ::gltf::image::Source::View { view, mime_type } = image.source() else {
                    panic!("{what}: the image is not in the GLB")
                };
                assert_eq!(mime_type, "image/png");
                let png = &buffers[0][view.offset()..view.offset() + view.length()];
                assert_eq!(png, std::fs::read(dir.path().join("tex ture.png")).unwrap(), "{what}");
                let output_alone = without_additions(&out_json, &input_json, shift);
                let mut input_json = input_json.clone();
                for (o, i) in output_alone["bufferViews"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .zip(input_json["bufferViews"].as_array_mut().unwrap())
                {
                    i["buffer"] = o["buffer"].clone();
                    i.as_object_mut().unwrap().remove("byteOffset");
                    if let Some(offset) = o.get("byteOffset") {
                        i["byteOffset"] = offset.clone();
                    }
                }
                input_json["images"][0] = output_alone["images"][0].clone();
                input_json["buffers"] = output_alone["buffers"].clone();
                assert_eq!(output_alone, input_json, "{what}");
                continue;
            }
            assert_eq!(out_json["images"][0]["uri"], rebased("tex%20ture.png"), "{what}");
            assert_eq!(out_buffers.len(), in_buffers.len() + usize::from(!input_glb), "{what}");
            for (i, b) in in_buffers.iter().enumerate().skip(usize::from(input_glb)) {
                let o = &out_buffers[i + shift];
                assert_eq!(o["byteLength"], b["byteLength"], "{what}");
                match b["uri"].as_str().unwrap() {
                    uri if uri.starts_with("data:") => assert_eq!(o["uri"], uri, "{what}"),
                    uri => assert_eq!(o["uri"], rebased(uri), "{what}"),
                }
            }
            let main = if input_glb || out_glb { 0 } else { in_buffers.len() };
            let main_length = out_buffers[main]["byteLength"].as_u64().unwrap() as usize;
            assert_eq!(buffers[main].len().next_multiple_of(4), main_length.next_multiple_of(4), "{what}");
            if out_glb {
                assert!(out_buffers[main].get("uri").is_none(), "{what}");
            } else {
                assert_eq!(out_buffers[main]["uri"], "baked.bin", "{what}");
            }
            assert_eq!(without_additions(&out_json, &input_json, shift), input_json, "{what}");
        }
    }

    #[test]
    fn the_engine_round_trips_with_its_binary_chunk() {
        let asset = GltfAsset::read(&engine()).unwrap_or_else(|e| panic!("{e}"));
        let values = values(&asset, false);
        let dir = tempfile::tempdir().unwrap();
        for name in ["engine.glb", "engine.gltf"] {
            let path = dir.path().join(name);
            asset.write(&path, &values, &WriteOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(loaded_triangles(&path) == loaded_triangles(&engine()), "{name}: triangles differ");
            assert_valid(&path, &engine());
            let (gltf, buffers) = independent_read(&path);
            // Every placement has its own _AO with its own values.
            let mut seen = 0;
            for node in gltf.nodes() {
                let Some(mesh) = node.mesh() else { continue };
                for primitive in mesh.primitives() {
                    let ao = primitive.get(&Semantic::Extras("AO".to_string())).unwrap();
                    let i =
                        asset.targets.iter().position(|t| (t.node, t.primitive) == (node.index(), primitive.index()));
                    assert_eq!(floats(&ao, &buffers), values[i.unwrap()].ao, "{name}");
                    seen += 1;
                }
            }
            assert_eq!(seen, asset.meshes().len(), "{name}");
        }
    }

    #[test]
    fn faces_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (input, _) = write_fixture(dir.path(), "scene.gltf");
        let asset = GltfAsset::read(&input).unwrap();
        let output = dir.path().join("faces.glb");
        let options = WriteOptions { at: BakeAt::Faces, ..WriteOptions::default() };
        let message = asset.write(&output, &values(&asset, false), &options).unwrap_err().to_string();
        assert!(message.contains("faces.glb") && message.contains(".ply"), "{message}");
        assert!(!output.exists());
    }

    #[test]
    fn baking_a_file_over_itself_keeps_its_buffer_file() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = write_fixture(dir.path(), "geom.gltf");
        let asset = GltfAsset::read(&path).unwrap();
        let before = loaded_triangles(&path);
        let notes = asset.write(&path, &values(&asset, false), &WriteOptions::default()).unwrap();
        assert!(notes.iter().any(|n| n.contains("geom_ao.bin")), "{notes:?}");
        assert!(dir.path().join("geom_ao.bin").exists());
        assert!(loaded_triangles(&path) == before);
        std::fs::create_dir(dir.path().join("input")).unwrap();
        let (input, _) = write_fixture(&dir.path().join("input"), "geom.gltf");
        assert_valid(&path, &input);
        // Baking the result again replaces its values rather than piling them up: the
        // three _AO accessors of the first bake go, three new ones come last.
        let again = GltfAsset::read(&path).unwrap();
        let json: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        let accessors = json["accessors"].as_array().unwrap().len();
        again.write(&path, &values(&again, false), &WriteOptions::default()).unwrap();
        let json: Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert_eq!(json["accessors"].as_array().unwrap().len(), accessors);
        let ao = &json["meshes"][0]["primitives"][0]["attributes"][AO];
        assert!(ao.as_u64().unwrap() as usize >= accessors - 3, "{ao}");
        assert_valid(&path, &input);
    }

    /// The files a directory holds.
    fn listing(dir: &Path) -> BTreeSet<PathBuf> {
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect()
    }

    #[test]
    fn companion_files_are_the_files_written_beside_the_output() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let (path, _) = write_fixture(d, "geom.gltf");
        let asset = GltfAsset::read(&path).unwrap();
        for (output, bin) in [("baked.gltf", "baked.bin"), ("geom.gltf", "geom_ao.bin")] {
            let output = d.join(output);
            let companions = asset.companion_files(&output, None);
            assert_eq!(companions, [(d.join(bin), "the glTF buffer")]);
            let before = listing(d);
            asset.write(&output, &values(&asset, false), &WriteOptions::default()).unwrap();
            let made: BTreeSet<PathBuf> = listing(d).difference(&before).cloned().collect();
            let expected: BTreeSet<PathBuf> = companions
                .into_iter()
                .map(|(f, _)| f)
                .chain([output.clone()])
                .filter(|f| !before.contains(f))
                .collect();
            assert_eq!(made, expected);
        }
        // Two materials' maps with bent normals (the second's names numbered): each map
        // where the listing says, the input's own image untouched.
        std::fs::write(d.join("tex ture.png"), b"kept").unwrap();
        let map = |material: Option<usize>, meshes: Vec<usize>| TextureMap {
            material,
            meshes,
            uv_set: 0,
            png: b"ao".to_vec(),
            bent_png: Some(b"bent".to_vec()),
            repeat: false,
        };
        let maps = [map(Some(0), vec![0]), map(None, vec![1])];
        for output in ["tex ture.gltf", "textured.glb"] {
            let output = d.join(output);
            let files = TextureFiles { maps: 2, bent_normals: true, generated_uvs: false };
            let companions = asset.companion_files(&output, Some(&files));
            let before = listing(d);
            asset.write_textures(&output, &maps, None).unwrap();
            let made: BTreeSet<PathBuf> = listing(d).difference(&before).cloned().collect();
            let expected: BTreeSet<PathBuf> =
                companions.iter().map(|(f, _)| f.clone()).chain([output.clone()]).collect();
            assert_eq!(made, expected, "{}", output.display());
            if output.extension().is_some_and(|e| e == "gltf") {
                let names: Vec<&str> = companions.iter().map(|(_, what)| *what).collect();
                assert_eq!(names, ["the AO map", "the bent normals map", "the AO map", "the bent normals map"]);
                assert!(companions[2].0.ends_with("tex ture_ao1.png"), "{companions:?}");
            } else {
                assert!(companions.is_empty(), "a GLB holds its maps");
            }
        }
        assert_eq!(std::fs::read(d.join("tex ture.png")).unwrap(), b"kept");
    }
}
