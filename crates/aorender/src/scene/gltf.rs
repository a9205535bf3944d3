//! glTF 2.0 through the `gltf` crate: `.gltf` (buffers in files beside it or in `data:`
//! URIs) and `.glb`, either gzipped. The crate parses the GLB container and the JSON and
//! validates the document; the accessors are read here, with every byte range checked,
//! because the crate's own readers assume valid offsets (they can panic on a malformed
//! file) and read only `f32` positions (not `KHR_mesh_quantization`'s integers).
//!
//! The default scene (else the first, else every root node) is walked down its node
//! hierarchy, composing each node's matrix or translation × rotation × scale in f64; every
//! triangle, triangle-strip and triangle-fan primitive of every node's mesh is placed by
//! its node's world transform, in f64, and rounded once to f32 relative to the mesh's
//! origin (zero unless the nodes place the mesh far from the origin for its size, where
//! the positions keep the accuracy the file's have). Other primitive modes (points, lines) are skipped with a
//! warning. Skins and morph targets are not applied: the mesh is taken in its bind pose.
//!
//! [`read_gltf`] also says where each placed primitive went in the mesh (and reads its
//! normals), for baking values back into the file (`bake::gltf`).

use super::input::{Input, LoadOptions, Meter, UTF8_BOM, is_gzip, one_line};
use super::mesh::{IndexedMesh, VertexNames, vertex_index};
use crate::error::{Error, Result};
use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::binary::{self, ChunkType, Glb};
use ::gltf::buffer::{self, Source};
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::scene::Transform;
use ::gltf::{Accessor, Document, Node, json};
use base64::Engine;
use glam::{DMat3, DMat4, DQuat, DVec3, Vec2, Vec3};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use std::path::{Component, Path, PathBuf};

/// Required extensions this loader implements.
const IMPLEMENTED_EXTENSIONS: &[&str] = &["KHR_mesh_quantization"];

/// Extensions that change the geometry (compressed or instanced data, an offset of every
/// position) and that this loader does not implement: a file that requires one is refused.
const GEOMETRY_EXTENSIONS: &[&str] = &[
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
    "EXT_mesh_gpu_instancing",
    "CESIUM_RTC",
];

/// Prefixes of extensions that change only materials, textures, lights, animations or
/// metadata. Ambient occlusion uses none of them, and a file that requires one keeps its
/// geometry in core glTF, so it loads.
const APPEARANCE_EXTENSION_PREFIXES: &[&str] = &[
    "KHR_materials_",
    "KHR_texture_",
    "EXT_texture_",
    "MSFT_texture_",
    "MSFT_packing_",
    "KHR_lights_",
    "EXT_lights_",
    "KHR_technique",
    "KHR_animation_pointer",
    "KHR_xmp",
    "ADOBE_materials_",
    "CESIUM_primitive_outline",
    "EXT_mesh_features",
    "EXT_structural_metadata",
    "EXT_instance_features",
];

/// Reads a glTF or GLB file, gzipped or not, into one mesh in the scene's space.
pub(super) fn load_gltf(path: &Path, options: &LoadOptions, meter: &mut Meter) -> Result<IndexedMesh> {
    read_gltf(path, false, options, meter, |_| ()).map(|(loaded, ())| loaded.mesh)
}

/// A triangle primitive placed by a node, as [`read_gltf`] put it into its mesh.
#[derive(Clone, Debug)]
pub(crate) struct Placement {
    /// The node's index.
    pub node: usize,
    /// The node's mesh.
    pub mesh: usize,
    /// The primitive's index in its mesh.
    pub primitive: usize,
    /// Names the primitive in messages: `node n mesh m ("name") primitive p`.
    pub label: String,
    /// Its vertices in the loaded mesh: those of its POSITION accessor under this node,
    /// which the node's other primitives on the same accessor share.
    pub vertices: Range<usize>,
    /// Its triangles in the loaded mesh, in the order the primitive gives them.
    pub triangles: Range<usize>,
    /// Its NORMAL attribute placed by the node's normal matrix (the inverse transpose of
    /// its world transform), not normalised; `None` unless asked for and present.
    pub normals: Option<Vec<Vec3>>,
    /// Its `TEXCOORD_n` attributes as (n, one per position), when asked for (with
    /// `normals`); in the file's convention (v = 0 is an image's top row).
    pub texcoords: Vec<(u32, Vec<Vec2>)>,
    /// The primitive's material.
    pub material: Option<usize>,
    /// The node's world transform, which placed the vertices.
    pub world: DMat4,
}

/// A glTF file read as the scene loads it, with where each primitive went.
#[derive(Debug)]
pub(crate) struct PlacedGltf {
    /// Every placed primitive in one mesh, in the file's space.
    pub mesh: IndexedMesh,
    /// Each triangle primitive under each node, in the order their triangles were added.
    pub placements: Vec<Placement>,
}

/// The containers' bytes of a glTF file just loaded.
pub(crate) struct GltfBytes<'a> {
    /// The JSON: the whole file, or the GLB's JSON chunk.
    pub json: &'a [u8],
    /// True for a GLB.
    pub glb: bool,
    /// The GLB's binary chunk, when it has one.
    pub bin: Option<&'a [u8]>,
}

/// Reads a glTF or GLB file, gzipped or not, into one mesh in the scene's space, with the
/// placement of every primitive (their normals too when `normals` is set), and `keep`'s
/// result: it sees the file's bytes once the file has loaded. What it holds is charged to
/// `meter`; buffer URIs are followed as `options` allow.
pub(crate) fn read_gltf<T>(
    path: &Path,
    normals: bool,
    options: &LoadOptions,
    meter: &mut Meter,
    keep: impl FnOnce(GltfBytes) -> T,
) -> Result<(PlacedGltf, T)> {
    let bytes = read_file(path, meter)?;
    let glb = split_glb(path, &bytes)?;
    let json_bytes = without_bom(glb.as_ref().map_or(&bytes, |g| &g.json));
    let mut root = parse_json(path, json_bytes, meter)?;
    let ignored = check_required_extensions(path, &root)?;
    // The crate's validation refuses every required extension it does not implement
    // itself; the ones left were accepted above.
    root.extensions_required.clear();
    let document = validated(path, root)?;
    let bin = glb.as_ref().and_then(|g| g.bin.as_deref());
    let buffers = load_buffers(path, &document, bin, options, meter)?;
    let total_bytes = bytes.len() + buffers.iter().map(|b| b.len()).sum::<usize>();
    let mut placed = Loader { path, buffers: &buffers, total_bytes, normals }.load(&document, meter)?;
    for ext in ignored {
        placed.mesh.warnings.push(format!(
            "the file requires the glTF extension {ext}, which only its materials, textures or cameras use: ignored"
        ));
    }
    let kept = keep(GltfBytes { json: json_bytes, glb: glb.is_some(), bin });
    Ok((placed, kept))
}

/// Every buffer's bytes of a glTF or GLB file, gzipped or not, as [`read_gltf`] loads
/// them: for rewriting its vertex data (`bake::gltf`).
pub(crate) fn read_buffers(path: &Path, options: &LoadOptions) -> Result<Vec<Vec<u8>>> {
    let mut meter = Meter::new(&options.limits, "the glTF file's data");
    let bytes = read_file(path, &mut meter)?;
    let glb = split_glb(path, &bytes)?;
    let json_bytes = without_bom(glb.as_ref().map_or(&bytes, |g| &g.json));
    let mut root = parse_json(path, json_bytes, &mut meter)?;
    root.extensions_required.clear();
    let document = validated(path, root)?;
    let bin = glb.as_ref().and_then(|g| g.bin.as_deref());
    // The borrowed binary chunk is copied: count it again.
    meter.charge(path, bin.map_or(0, |b| b.len() as u64))?;
    Ok(load_buffers(path, &document, bin, options, &mut meter)?.into_iter().map(Cow::into_owned).collect())
}

/// Bytes of memory a glTF document's JSON takes once parsed, per byte of its text and
/// per object in it, at most: its numbers, strings and arrays take a few times their
/// text; an object (`{}`, three bytes of text, is a valid node) takes a struct of the
/// crate's, a few hundred bytes at most.
pub(crate) const JSON_BYTES_PER_BYTE: u64 = 8;
/// See [`JSON_BYTES_PER_BYTE`].
pub(crate) const JSON_BYTES_PER_OBJECT: u64 = 512;

/// The JSON objects in `json` (each `{` outside a string).
pub(crate) fn json_objects(json: &[u8]) -> u64 {
    let (mut objects, mut in_string, mut escaped) = (0, false, false);
    for &b in json {
        if in_string {
            match b {
                _ if escaped => escaped = false,
                b'\\' => escaped = true,
                b'"' => in_string = false,
                _ => {}
            }
        } else {
            match b {
                b'"' => in_string = true,
                b'{' => objects += 1,
                _ => {}
            }
        }
    }
    objects
}

/// The memory the parsed form of `json` may take (see [`JSON_BYTES_PER_BYTE`]).
pub(crate) fn json_memory(json: &[u8]) -> u64 {
    (json.len() as u64).saturating_mul(JSON_BYTES_PER_BYTE).saturating_add(json_objects(json) * JSON_BYTES_PER_OBJECT)
}

/// `json` without a UTF-8 byte-order mark (glTF forbids one; some writers add it).
fn without_bom(json: &[u8]) -> &[u8] {
    json.strip_prefix(UTF8_BOM).unwrap_or(json)
}

/// The glTF document of `json`, its parsed form charged to `meter` first. A file of
/// another major version than 2 is refused as such. glTF 2.0 leaves a scene's `nodes`
/// optional, which the crate's parser requires: a document it refuses is parsed again
/// with them filled in (and without its animations, which the parser also reads strictly
/// and ambient occlusion never uses).
fn parse_json(path: &Path, json: &[u8], meter: &mut Meter) -> Result<json::Root> {
    meter.charge(path, json_memory(json))?;
    let root = match json::deserialize::from_slice::<json::Root>(json) {
        Ok(root) => root,
        Err(e) => {
            check_version(path, declared_version(json).as_deref())?;
            // The failed parse gave its memory back: the second one takes the same charge.
            let patched = json::deserialize::from_slice::<json::Value>(json)
                .ok()
                .and_then(|mut value| fill_optional_fields(&mut value).then_some(value))
                .and_then(|value| json::deserialize::from_value::<json::Root>(value).ok());
            patched.ok_or_else(|| Error::scene(path, format!("invalid glTF JSON: {}", one_line(&e.to_string()))))?
        }
    };
    check_version(path, Some(&root.asset.version))?;
    Ok(root)
}

/// `asset.version` of a glTF document's JSON, when it has one, read without the rest.
fn declared_version(json: &[u8]) -> Option<String> {
    #[derive(serde::Deserialize)]
    struct Asset {
        version: json::Value,
    }
    #[derive(serde::Deserialize)]
    struct VersionOnly {
        asset: Asset,
    }
    let version = json::deserialize::from_slice::<VersionOnly>(json).ok()?.asset.version;
    Some(version.as_str().map_or_else(|| version.to_string(), str::to_string))
}

/// Refuses a glTF version other than 2.x, in words.
fn check_version(path: &Path, version: Option<&str>) -> Result<()> {
    match version {
        Some(v) if !(v == "2" || v.starts_with("2.")) => {
            let major = v.split('.').next().unwrap_or(v);
            Err(Error::scene(
                path,
                format!(
                    "glTF {major}.0 is not supported (the file's asset.version is {:?}): only glTF 2.0 is; convert it to glTF 2.0 first",
                    one_line(v)
                ),
            ))
        }
        _ => Ok(()),
    }
}

/// Fills in what glTF 2.0 leaves optional and the crate's parser requires: each scene's
/// `nodes` (none); and drops the animations, which the parser reads more strictly than
/// glTF does (a channel without a node) and which ambient occlusion never uses. Whether
/// anything changed.
fn fill_optional_fields(value: &mut json::Value) -> bool {
    let Some(root) = value.as_object_mut() else { return false };
    let mut changed = root.remove("animations").is_some();
    for scene in root.get_mut("scenes").and_then(json::Value::as_array_mut).into_iter().flatten() {
        if let Some(scene) = scene.as_object_mut()
            && !scene.contains_key("nodes")
        {
            scene.insert("nodes".into(), json::Value::Array(Vec::new()));
            changed = true;
        }
    }
    changed
}

/// The extensions the file requires that are accepted without being implemented, to be
/// reported: those that change only appearance are accepted silently; an unknown one is
/// accepted (and returned) when only materials, textures, images, samplers, cameras or
/// the file as a whole use it, and no mesh, primitive, accessor, buffer view, buffer,
/// node or scene. Any other (one that changes the geometry, one the geometry uses, one
/// used nowhere, whose effect cannot be told) is refused, naming it.
fn check_required_extensions(path: &Path, root: &json::Root) -> Result<Vec<String>> {
    let mut ignored = Vec::new();
    for name in &root.extensions_required {
        let name = name.as_str();
        if IMPLEMENTED_EXTENSIONS.contains(&name) || APPEARANCE_EXTENSION_PREFIXES.iter().any(|p| name.starts_with(p)) {
            continue;
        }
        let refused = |at: &str| {
            Error::scene(
                path,
                format!("the file requires the glTF extension {}{at}, which is not supported", one_line(name)),
            )
        };
        if GEOMETRY_EXTENSIONS.contains(&name) {
            return Err(refused(""));
        }
        if let Some(at) = geometry_use(root, name) {
            return Err(refused(&at));
        }
        if !appearance_use(root, name) {
            return Err(refused(""));
        }
        ignored.push(one_line(name));
    }
    Ok(ignored)
}

/// Whether a material, texture, image, sampler or camera, or the file as a whole, uses
/// the extension `name`.
fn appearance_use(root: &json::Root, name: &str) -> bool {
    let has = |others: Option<&json::Value>| others.is_some();
    root.materials.iter().any(|m| has(m.extensions.as_ref().and_then(|e| e.others.get(name))))
        || root.textures.iter().any(|t| has(t.extensions.as_ref().and_then(|e| e.others.get(name))))
        || root.images.iter().any(|i| has(i.extensions.as_ref().and_then(|e| e.others.get(name))))
        || root.samplers.iter().any(|s| has(s.extensions.as_ref().and_then(|e| e.others.get(name))))
        || root.cameras.iter().any(|c| has(c.extensions.as_ref().and_then(|e| e.others.get(name))))
        || has(root.extensions.as_ref().and_then(|e| e.others.get(name)))
}

/// Where the extension `name` is used by the geometry (` (used by mesh 0 primitive 1)`),
/// if it is: by a mesh, primitive, accessor, buffer view, buffer, node or scene.
fn geometry_use(root: &json::Root, name: &str) -> Option<String> {
    let at = |what: String| Some(format!(" (used by {what})"));
    for (m, mesh) in root.meshes.iter().enumerate() {
        if mesh.extensions.as_ref().is_some_and(|e| e.others.contains_key(name)) {
            return at(format!("mesh {m}"));
        }
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            if primitive.extensions.as_ref().is_some_and(|e| e.others.contains_key(name)) {
                return at(format!("mesh {m} primitive {p}"));
            }
        }
    }
    let lists: [(&str, Vec<bool>); 5] = [
        (
            "accessor",
            root.accessors.iter().map(|a| a.extensions.as_ref().is_some_and(|e| e.others.contains_key(name))).collect(),
        ),
        (
            "buffer view",
            root.buffer_views
                .iter()
                .map(|v| v.extensions.as_ref().is_some_and(|e| e.others.contains_key(name)))
                .collect(),
        ),
        (
            "buffer",
            root.buffers.iter().map(|b| b.extensions.as_ref().is_some_and(|e| e.others.contains_key(name))).collect(),
        ),
        (
            "node",
            root.nodes.iter().map(|n| n.extensions.as_ref().is_some_and(|e| e.others.contains_key(name))).collect(),
        ),
        (
            "scene",
            root.scenes.iter().map(|s| s.extensions.as_ref().is_some_and(|e| e.others.contains_key(name))).collect(),
        ),
    ];
    for (what, list) in lists {
        if let Some(i) = list.into_iter().position(|used| used) {
            return at(format!("{what} {i}"));
        }
    }
    None
}

/// The document of `root`, validated as the crate validates it, less what glTF 2.0
/// allows and the crate's validation refuses: an accessor without a buffer view (its
/// elements are zeros, glTF 2.0 section 5.1.1) and a POSITION accessor without `min` and
/// `max` (required, but only for bounds, which are computed here; other importers read
/// such files). The crate's validation indexes the accessor of each primitive's POSITION
/// without checking it exists: that is checked first, so a bad index is an error, not a
/// panic.
fn validated(path: &Path, root: json::Root) -> Result<Document> {
    use ::gltf::json::validation::{Error as Invalid, Validate};
    check_position_accessors_exist(path, &root)?;
    let mut errors = Vec::new();
    root.validate(&root, json::Path::new, &mut |at, error| errors.push((at(), error)));
    errors.retain(|(at, error)| {
        let at = at.as_str();
        let no_view = at.starts_with("accessors[") && at.ends_with("].bufferView") && *error == Invalid::Missing;
        let bounds = at.contains(".attributes[\"POSITION\"].") && (at.ends_with(".min") || at.ends_with(".max"));
        !(no_view || bounds)
    });
    if !errors.is_empty() {
        return Err(Error::scene(path, validation_message(&::gltf::Error::Validation(errors))));
    }
    Ok(Document::from_json_without_validation(root))
}

/// The bytes of a glTF file (the JSON) or a GLB file (as many as its header declares),
/// gzipped or not, charged to `meter` as they are read.
fn read_file(path: &Path, meter: &mut Meter) -> Result<Vec<u8>> {
    let mut input = Input::open(path, meter.limits())?;
    let mut bytes = Vec::new();
    input.read_into(path, &mut bytes, meter, 1, 12)?;
    if !(bytes.starts_with(b"glTF") && bytes.len() == 12) {
        // JSON text starts with an object: anything else is refused at its first byte
        // (as the parser would refuse it) rather than read to the end.
        if without_bom(&bytes).iter().find(|b| !b.is_ascii_whitespace()).is_some_and(|&b| b != b'{') {
            parse_json(path, &bytes, meter)?;
        }
        input.read_into(path, &mut bytes, meter, 1, u64::MAX)?;
        return Ok(bytes);
    }
    let length = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    input.read_into(path, &mut bytes, meter, 1, u64::from(length).saturating_sub(12))?;
    if is_gzip(path) {
        // The rest is read (and dropped) to check the stream's trailer.
        if let Err(e) = std::io::copy(&mut input, &mut std::io::sink()) {
            return Err(Error::scene(path, input.stream_error().map_or_else(|| e.to_string(), str::to_string)));
        }
    }
    Ok(bytes)
}

/// The GLB container of `bytes`, or `None` when they are glTF JSON. The header's length
/// and version are checked before the crate splits the chunks.
fn split_glb<'a>(path: &Path, bytes: &'a [u8]) -> Result<Option<Glb<'a>>> {
    if !bytes.starts_with(b"glTF") {
        return Ok(None);
    }
    let word = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    let (Some(version), Some(length)) = (word(4), word(8)) else {
        return Err(Error::scene(path, "truncated GLB header"));
    };
    if version != 2 {
        return Err(Error::scene(path, format!("GLB version {version} is not supported (expected 2)")));
    }
    let length = length as usize;
    if length > bytes.len() {
        return Err(Error::scene(
            path,
            format!("the GLB header declares {length} bytes but the file has {} (truncated?)", bytes.len()),
        ));
    }
    if length < 20 {
        return Err(Error::scene(path, format!("the GLB header declares {length} bytes, too few for a JSON chunk")));
    }
    let glb = Glb::from_slice(&bytes[..length]).map_err(|e| {
        let message = match e {
            ::gltf::Error::Binary(binary::Error::ChunkLength { ty, length, length_read }) => {
                format!("the GLB {} chunk declares {length} bytes but only {length_read} follow", chunk_name(ty))
            }
            ::gltf::Error::Binary(binary::Error::ChunkType(ty)) => {
                format!("unexpected GLB {} chunk", chunk_name(ty))
            }
            ::gltf::Error::Binary(binary::Error::UnknownChunkType(t)) => {
                format!("unknown GLB chunk type {:?}", String::from_utf8_lossy(&t))
            }
            e => format!("invalid GLB: {e}"),
        };
        Error::scene(path, message)
    })?;
    Ok(Some(glb))
}

fn chunk_name(ty: ChunkType) -> &'static str {
    match ty {
        ChunkType::Json => "JSON",
        ChunkType::Bin => "BIN",
    }
}

/// Fails when a primitive's POSITION names an accessor the file lacks.
fn check_position_accessors_exist(path: &Path, root: &json::Root) -> Result<()> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let position = json::validation::Checked::Valid(Semantic::Positions);
            if let Some(index) = primitive.attributes.get(&position)
                && index.value() >= root.accessors.len()
            {
                return Err(Error::scene(
                    path,
                    format!(
                        "mesh {m} primitive {p}: POSITION accessor {} does not exist (the file has {})",
                        index.value(),
                        root.accessors.len()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The first validation error, with its JSON path, and how many more there are.
fn validation_message(e: &::gltf::Error) -> String {
    match e {
        ::gltf::Error::Validation(errors) => match errors.as_slice() {
            [] => "invalid glTF".to_string(),
            [(path, error), rest @ ..] => {
                let more = if rest.is_empty() { String::new() } else { format!(" (and {} more)", rest.len()) };
                format!("invalid glTF: {}: {error}{more}", one_line(path.as_str()))
            }
        },
        e => format!("invalid glTF: {}", one_line(&e.to_string())),
    }
}

/// Every buffer's bytes: the GLB binary chunk borrowed, the others read from files in
/// `path`'s folder (or outside it, as `options` allow) or decoded from `data:` URIs, each
/// charged to `meter` before it is read.
fn load_buffers<'a>(
    path: &Path,
    document: &Document,
    bin: Option<&'a [u8]>,
    options: &LoadOptions,
    meter: &mut Meter,
) -> Result<Vec<Cow<'a, [u8]>>> {
    let mut out = Vec::new();
    for buffer in document.buffers() {
        let i = buffer.index();
        let data = match buffer.source() {
            Source::Bin => Cow::Borrowed(bin.ok_or_else(|| {
                Error::scene(path, format!("buffer {i} refers to the GLB binary chunk, which the file lacks"))
            })?),
            Source::Uri(uri) => Cow::Owned(read_uri(path, i, uri, buffer.length(), options, meter)?),
        };
        if data.len() < buffer.length() {
            return Err(Error::scene(
                path,
                format!("buffer {i} declares {} bytes but has {}", buffer.length(), data.len()),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// Base64 as glTF's `data:` URIs hold it (RFC 4648's alphabet), with or without the
/// padding at the end, which some writers leave out.
const BASE64: base64::engine::GeneralPurpose = base64::engine::GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    base64::engine::GeneralPurposeConfig::new()
        .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
);

/// The bytes of buffer `index`'s URI, `length` of them (its byteLength; fewer when the
/// file has fewer): base64 `data:`, or a file name relative to `path`'s folder.
fn read_uri(
    path: &Path,
    index: usize,
    uri: &str,
    length: usize,
    options: &LoadOptions,
    meter: &mut Meter,
) -> Result<Vec<u8>> {
    let fail = |message: String| Error::scene(path, format!("buffer {index}: {message}"));
    if let Some(data) = uri.strip_prefix("data:") {
        let (_, payload) =
            data.split_once(";base64,").ok_or_else(|| fail("only base64 data URIs are supported".into()))?;
        meter.charge(path, payload.len() as u64 / 4 * 3 + 3)?;
        return BASE64.decode(payload).map_err(|e| fail(format!("invalid base64 data URI: {e}")));
    }
    let file = uri_file(path, uri, options.allow_external_uris, true).map_err(|e| fail(e.to_string()))?;
    // Only byteLength bytes are read: a longer file (or a device) gives no more.
    let mut input = Input::open_plain(&file, meter.limits()).map_err(|e| fail(e.to_string()))?;
    let mut bytes = Vec::new();
    input.read_into(&file, &mut bytes, meter, 1, length as u64).map_err(|e| match e {
        Error::Scene { message, .. } => fail(format!("{}: {message}", file.display())),
        e => e,
    })?;
    Ok(bytes)
}

/// The file a relative URI of the glTF file `path` names: percent-decoded and resolved
/// against the file's folder. Unless `allow_external`, the file must lie in that folder
/// or below it once symbolic links are followed: a URI that is absolute or climbs out
/// with `..` is refused without touching the file system, one that leads out through a
/// link once it is resolved. A file that does not exist is an error when `must_exist`
/// (a buffer, to be read), else accepted (an image the output refers to, as the input
/// did).
pub(crate) fn uri_file(
    path: &Path,
    uri: &str,
    allow_external: bool,
    must_exist: bool,
) -> std::result::Result<PathBuf, UriError> {
    if uri.contains(':') {
        return Err(UriError::Unsupported(one_line(uri)));
    }
    let name = percent_encoding::percent_decode_str(uri).decode_utf8().map_err(|_| UriError::NotUtf8(one_line(uri)))?;
    let folder = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file = folder.join(&*name);
    if allow_external {
        return Ok(file);
    }
    let outside = |how: &'static str| UriError::Outside { uri: one_line(uri), how };
    let mut depth = 0usize;
    for c in Path::new(&*name).components() {
        match c {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir => depth = depth.checked_sub(1).ok_or_else(|| outside(""))?,
            Component::RootDir | Component::Prefix(_) => return Err(outside("")),
        }
    }
    let real_folder = folder.canonicalize().map_err(|e| UriError::Io(folder.to_path_buf(), e))?;
    let real = match file.canonicalize() {
        Ok(real) => real,
        Err(e) if !must_exist && e.kind() == std::io::ErrorKind::NotFound => return Ok(file),
        Err(e) => return Err(UriError::Io(file, e)),
    };
    if !real.starts_with(&real_folder) {
        return Err(outside(" through a symbolic link"));
    }
    Ok(real)
}

/// Why a URI of a glTF file names no file the loader may read ([`uri_file`]).
#[derive(Debug, thiserror::Error)]
pub(crate) enum UriError {
    /// A URI with a scheme other than `data:` (already on one line).
    #[error("unsupported URI {0:?}: expected a relative file name or a data: URI")]
    Unsupported(String),
    /// A URI whose percent-decoded bytes are not UTF-8.
    #[error("URI {0:?} is not UTF-8 once decoded")]
    NotUtf8(String),
    /// A file outside the glTF file's folder (`how`: how it leads there).
    #[error(
        "the URI {uri:?} leads outside the glTF file's folder{how}; files there are read only when external URIs \
         are allowed (--allow-external-uris)"
    )]
    Outside { uri: String, how: &'static str },
    /// The folder or the file could not be resolved.
    #[error("{}: {}", .0.display(), .1)]
    Io(PathBuf, std::io::Error),
}

/// Element `i`, component `c` of an accessor lives at `data[i * stride + c * size]`.
struct Elements<'a> {
    data: &'a [u8],
    stride: usize,
    count: usize,
    component: DataType,
    normalized: bool,
}

impl Elements<'_> {
    fn bytes<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut out = [0; N];
        if let Some(b) = self.data.get(at..at + N) {
            out.copy_from_slice(b);
        }
        out
    }

    /// Component `c` of element `i` as a float: normalized integers mapped to [-1, 1] or
    /// [0, 1] as the glTF specification gives (section 3.11), others converted.
    fn float(&self, i: usize, c: usize) -> f32 {
        let at = i * self.stride + c * self.component.size();
        let n = self.normalized;
        match self.component {
            DataType::F32 => f32::from_le_bytes(self.bytes(at)),
            DataType::I8 => {
                let v = f32::from(i8::from_le_bytes(self.bytes(at)));
                if n { (v / 127.0).max(-1.0) } else { v }
            }
            DataType::U8 => {
                let v = f32::from(self.bytes::<1>(at)[0]);
                if n { v / 255.0 } else { v }
            }
            DataType::I16 => {
                let v = f32::from(i16::from_le_bytes(self.bytes(at)));
                if n { (v / 32767.0).max(-1.0) } else { v }
            }
            DataType::U16 => {
                let v = f32::from(u16::from_le_bytes(self.bytes(at)));
                if n { v / 65535.0 } else { v }
            }
            DataType::U32 => u32::from_le_bytes(self.bytes(at)) as f32,
        }
    }

    /// Element `i` as an unsigned integer (index accessors).
    fn index(&self, i: usize) -> u32 {
        let at = i * self.stride;
        match self.component {
            DataType::U8 => self.bytes::<1>(at)[0].into(),
            DataType::U16 => u16::from_le_bytes(self.bytes(at)).into(),
            _ => u32::from_le_bytes(self.bytes(at)),
        }
    }
}

/// The indices of a primitive: read in place, or gathered when the accessor is sparse or
/// has no buffer view.
enum Indices<'a> {
    Direct(Elements<'a>),
    Gathered(Vec<u32>),
}

impl Indices<'_> {
    fn len(&self) -> usize {
        match self {
            Indices::Direct(e) => e.count,
            Indices::Gathered(v) => v.len(),
        }
    }

    fn get(&self, i: usize) -> u32 {
        match self {
            Indices::Direct(e) => e.index(i),
            Indices::Gathered(v) => v.get(i).copied().unwrap_or(0),
        }
    }
}

/// A mesh placed by a node: the node, its world transform, the mesh.
struct Instance<'a> {
    node: Node<'a>,
    world: DMat4,
    mesh: ::gltf::Mesh<'a>,
}

struct Loader<'a, 'b> {
    path: &'a Path,
    buffers: &'a [Cow<'b, [u8]>],
    /// Bytes of the file and its buffers: no accessor may claim more elements.
    total_bytes: usize,
    /// Read each primitive's NORMAL attribute too.
    normals: bool,
}

impl Loader<'_, '_> {
    fn error(&self, message: String) -> Error {
        Error::scene(self.path, message)
    }

    fn load(&self, document: &Document, meter: &mut Meter) -> Result<PlacedGltf> {
        let instances = self.instances(document)?;
        if let Some(scene) = document.default_scene().or_else(|| document.scenes().next())
            && scene.nodes().len() == 0
        {
            return Err(self.error(format!("mesh has no triangles: its scene {} has no nodes", scene.index())));
        }

        // Sizes first, so the mesh is allocated once at its final size.
        let mut placed: HashMap<(usize, usize), usize> = HashMap::new();
        let (mut vertices, mut triangles) = (0usize, 0usize);
        let mut skipped: BTreeMap<&'static str, usize> = BTreeMap::new();
        for instance in &instances {
            for (p, primitive) in instance.mesh.primitives().enumerate() {
                let mode = primitive.mode();
                if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                    *skipped.entry(mode_name(mode)).or_default() += 1;
                    continue;
                }
                let what = self.primitive_name(instance, p);
                let Some(positions) = primitive.get(&Semantic::Positions) else {
                    return Err(self.error(format!("{what} has no POSITION attribute")));
                };
                // Counts are checked against the bytes behind them before they size anything.
                self.elements(&positions, &what)?;
                let n = match primitive.indices() {
                    Some(indices) => {
                        self.elements(&indices, &what)?;
                        indices.count()
                    }
                    None => positions.count(),
                };
                if placed.insert((instance.node.index(), positions.index()), 0).is_none() {
                    vertices = vertices.saturating_add(positions.count());
                }
                let t = if mode == Mode::Triangles { n / 3 } else { n.saturating_sub(2) };
                triangles = triangles.saturating_add(t);
            }
        }
        // The hierarchy may place a mesh many times: refuse what indices cannot address or
        // memory cannot hold rather than abort.
        let too_many = || {
            self.error(format!(
                "the node hierarchy places {vertices} vertices and {triangles} triangles, too many to load"
            ))
        };
        if u32::try_from(vertices).is_err() || u32::try_from(triangles).is_err() {
            return Err(too_many());
        }
        let origin = self.origin(&instances, meter)?;
        let mesh_bytes = 12 * (vertices as u64 + triangles as u64);
        meter.charge(self.path, mesh_bytes)?;
        let mut mesh = IndexedMesh { origin, ..Default::default() };
        mesh.positions.try_reserve_exact(vertices).map_err(|_| too_many())?;
        mesh.triangles.try_reserve_exact(triangles).map_err(|_| too_many())?;
        let mut names = Vec::new();
        let mut placements = Vec::new();
        placed.clear();
        for instance in &instances {
            let n = instance.node.index();
            let m = instance.mesh.index();
            for (p, primitive) in instance.mesh.primitives().enumerate() {
                let mode = primitive.mode();
                if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                    continue;
                }
                let what = self.primitive_name(instance, p);
                let Some(positions) = primitive.get(&Semantic::Positions) else { continue };
                let base = match placed.get(&(n, positions.index())) {
                    Some(&base) => base,
                    None => {
                        let base = mesh.positions.len();
                        let label = format!(
                            "node {n} mesh {m}{} POSITION accessor {}",
                            quoted(instance.mesh.name()),
                            positions.index()
                        );
                        let mut relative = instance.world;
                        relative.w_axis -= origin.extend(0.0);
                        self.read_positions(&positions, relative, &label, &mut mesh.positions)?;
                        names.push((base, label));
                        placed.insert((n, positions.index()), base);
                        base
                    }
                };
                let count = positions.count();
                let normals = match primitive.get(&Semantic::Normals) {
                    Some(a) if self.normals => {
                        meter.charge(self.path, 12 * count as u64)?;
                        Some(self.read_normals(&a, count, instance.world, &what)?)
                    }
                    _ => None,
                };
                let texcoords = if self.normals {
                    let sets = primitive.attributes().filter(|(s, _)| matches!(s, Semantic::TexCoords(_))).count();
                    meter.charge(self.path, 8 * (sets * count) as u64)?;
                    self.read_texcoords(&primitive, count, &what)?
                } else {
                    Vec::new()
                };
                let first_triangle = mesh.triangles.len();
                // Gathered (sparse) indices are held while the primitive is read.
                let gathered = primitive.indices().filter(|a| a.sparse().is_some() || a.view().is_none());
                let gathered = gathered.map_or(0, |a| 4 * a.count() as u64);
                meter.charge(self.path, gathered)?;
                let indices = match primitive.indices() {
                    Some(a) => Some(self.read_indices(&a, &what)?),
                    None => None,
                };
                let len = indices.as_ref().map_or(count, Indices::len);
                let vertex = |j: usize| -> Result<u32> {
                    let v = indices.as_ref().map_or(j as u64, |ix| u64::from(ix.get(j)));
                    if v >= count as u64 {
                        // The value is the file's data (or another file's): never shown.
                        return Err(self.error(format!(
                            "{what}: index {j} is out of range for the {count} vertices of accessor {}",
                            positions.index()
                        )));
                    }
                    vertex_index(base, v as usize).ok_or_else(|| self.error("more than 2^32 vertices".into()))
                };
                match mode {
                    Mode::Triangles => {
                        for t in 0..len / 3 {
                            mesh.triangles.push([vertex(3 * t)?, vertex(3 * t + 1)?, vertex(3 * t + 2)?]);
                        }
                    }
                    Mode::TriangleStrip => {
                        // Every other triangle swaps its first two vertices to keep the winding.
                        for t in 0..len.saturating_sub(2) {
                            let (a, b) = if t % 2 == 0 { (t, t + 1) } else { (t + 1, t) };
                            mesh.triangles.push([vertex(a)?, vertex(b)?, vertex(t + 2)?]);
                        }
                    }
                    _ => {
                        for t in 1..len.saturating_sub(1) {
                            mesh.triangles.push([vertex(0)?, vertex(t)?, vertex(t + 1)?]);
                        }
                    }
                }
                drop(indices);
                meter.release(gathered);
                placements.push(Placement {
                    node: n,
                    mesh: m,
                    primitive: p,
                    label: what,
                    vertices: base..base + count,
                    triangles: first_triangle..mesh.triangles.len(),
                    normals,
                    texcoords,
                    material: primitive.material().index(),
                    world: instance.world,
                });
            }
        }
        mesh.names = VertexNames::Ranges(names);
        if !skipped.is_empty() {
            let total: usize = skipped.values().sum();
            let modes: Vec<String> = skipped.iter().map(|(mode, n)| format!("{n} {mode}")).collect();
            let message = format!("skipped {total} primitives that are not triangles: {}", modes.join(", "));
            mesh.warnings.push(message);
        }
        Ok(PlacedGltf { mesh, placements })
    }

    /// The point the mesh's positions are kept relative to ([`IndexedMesh::origin`]): by
    /// the rule of the local frame (`frame::grid_origin`), from the bounds of every placed
    /// position in f64, so that a mesh placed far away by its nodes keeps the accuracy its
    /// own coordinates have; zero for a mesh near the origin.
    fn origin(&self, instances: &[Instance], meter: &mut Meter) -> Result<DVec3> {
        let (mut min, mut max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        let mut seen = std::collections::HashSet::new();
        let mut scratch: Vec<Vec3> = Vec::new();
        for instance in instances {
            for (p, primitive) in instance.mesh.primitives().enumerate() {
                if !matches!(primitive.mode(), Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                    continue;
                }
                let Some(positions) = primitive.get(&Semantic::Positions) else { continue };
                if positions.dimensions() != Dimensions::Vec3
                    || !seen.insert((instance.node.index(), positions.index()))
                {
                    continue;
                }
                let what = self.primitive_name(instance, p);
                let grow = (positions.count().saturating_sub(scratch.capacity()) * 12) as u64;
                meter.charge(self.path, grow)?;
                scratch.clear();
                self.read_vec3(&positions, &what, &mut scratch)?;
                for q in scratch.iter().map(|p| instance.world.transform_point3(p.as_dvec3())).filter(|q| q.is_finite())
                {
                    (min, max) = (min.min(q), max.max(q));
                }
            }
        }
        meter.release((scratch.capacity() * 12) as u64);
        Ok(if min.x <= max.x { super::frame::grid_origin(min, max) } else { DVec3::ZERO })
    }

    fn primitive_name(&self, instance: &Instance, p: usize) -> String {
        let (n, m) = (instance.node.index(), instance.mesh.index());
        format!("node {n} mesh {m}{} primitive {p}", quoted(instance.mesh.name()))
    }

    /// The meshes of the default scene (else the first scene, else every root node) with
    /// their nodes' world transforms. The nodes must form a tree, as glTF requires.
    fn instances<'d>(&self, document: &'d Document) -> Result<Vec<Instance<'d>>> {
        let roots: Vec<Node<'d>> = match document.default_scene().or_else(|| document.scenes().next()) {
            Some(scene) => scene.nodes().collect(),
            None => {
                let mut is_child = vec![false; document.nodes().len()];
                for node in document.nodes() {
                    for child in node.children() {
                        if let Some(c) = is_child.get_mut(child.index()) {
                            *c = true;
                        }
                    }
                }
                document.nodes().filter(|n| !is_child.get(n.index()).copied().unwrap_or(false)).collect()
            }
        };
        let mut visited = vec![false; document.nodes().len()];
        let mut stack: Vec<(Node<'d>, DMat4)> = roots.into_iter().rev().map(|n| (n, DMat4::IDENTITY)).collect();
        let mut out = Vec::new();
        while let Some((node, parent)) = stack.pop() {
            let i = node.index();
            match visited.get_mut(i) {
                Some(seen) if !*seen => *seen = true,
                _ => {
                    return Err(
                        self.error(format!("node {i} is reached twice from the scene: glTF nodes must form a tree"))
                    );
                }
            }
            let world = parent * local_matrix(&node);
            if !world.is_finite() {
                return Err(self.error(format!(
                    "node {i}{}: its transform is not finite (or its rotation is zero)",
                    quoted(node.name())
                )));
            }
            if let Some(mesh) = node.mesh() {
                out.push(Instance { node: node.clone(), world, mesh });
            }
            let children: Vec<Node<'d>> = node.children().collect();
            stack.extend(children.into_iter().rev().map(|c| (c, world)));
        }
        Ok(out)
    }

    /// The element bytes of `view` from `offset`: `count` elements of `size` bytes each,
    /// checked to lie inside the view and the view inside its buffer.
    fn view_elements(
        &self,
        view: &buffer::View,
        offset: usize,
        count: usize,
        size: usize,
        what: &str,
    ) -> Result<(&[u8], usize)> {
        let b = view.buffer().index();
        let buffer = self.buffers.get(b).ok_or_else(|| self.error(format!("{what}: buffer {b} does not exist")))?;
        let range = view.offset().checked_add(view.length()).map(|end| view.offset()..end);
        let Some(data) = range.clone().and_then(|r| buffer.get(r)) else {
            return Err(self.error(format!(
                "{what}: buffer view {} ({} bytes from byte {}) lies outside buffer {b} of {} bytes",
                view.index(),
                view.length(),
                view.offset(),
                buffer.len()
            )));
        };
        let stride = view.stride().unwrap_or(size);
        if stride < size {
            return Err(self.error(format!(
                "{what}: buffer view {} has a stride of {stride} bytes, less than its {size}-byte elements",
                view.index()
            )));
        }
        if count == 0 {
            return Ok((&[], stride));
        }
        let end = (count - 1).checked_mul(stride).and_then(|b| b.checked_add(size)).and_then(|b| b.checked_add(offset));
        match end.and_then(|end| data.get(offset..end)) {
            Some(bytes) => Ok((bytes, stride)),
            None => Err(self.error(format!(
                "{what}: {count} elements from byte {offset} of buffer view {} run past its {} bytes",
                view.index(),
                data.len()
            ))),
        }
    }

    /// The elements of accessor `a`, without its sparse substitutions; `None` when it has
    /// no buffer view (all zeros).
    fn elements<'s>(&'s self, a: &Accessor, what: &str) -> Result<Option<Elements<'s>>> {
        let size = a.size();
        let Some(view) = a.view() else {
            if a.count() > self.total_bytes {
                return Err(self.error(format!(
                    "{what}: accessor {} declares {} elements, more than the file's {} bytes can hold",
                    a.index(),
                    a.count(),
                    self.total_bytes
                )));
            }
            return Ok(None);
        };
        let (data, stride) = self.view_elements(&view, a.offset(), a.count(), size, what)?;
        Ok(Some(Elements { data, stride, count: a.count(), component: a.data_type(), normalized: a.normalized() }))
    }

    /// The sparse substitutions of accessor `a` as (element, values) pairs, each index
    /// checked to be below the accessor's count.
    fn sparse<'s>(&'s self, a: &Accessor, what: &str) -> Result<Option<(Elements<'s>, Elements<'s>)>> {
        let Some(sparse) = a.sparse() else { return Ok(None) };
        let n = sparse.count();
        let indices = sparse.indices();
        let index_size = indices.index_type().size();
        let (data, _) = self.view_elements(&indices.view(), indices.offset(), n, index_size, what)?;
        let component = match index_size {
            1 => DataType::U8,
            2 => DataType::U16,
            _ => DataType::U32,
        };
        let index = Elements { data, stride: index_size, count: n, component, normalized: false };
        let values = sparse.values();
        let (data, _) = self.view_elements(&values.view(), values.offset(), n, a.size(), what)?;
        let value = Elements { data, stride: a.size(), count: n, component: a.data_type(), normalized: a.normalized() };
        for j in 0..n {
            if index.index(j) as usize >= a.count() {
                return Err(self.error(format!(
                    "{what}: sparse index {j} of accessor {} is out of range for its {} elements",
                    a.index(),
                    a.count()
                )));
            }
        }
        Ok(Some((index, value)))
    }

    /// Appends the positions of accessor `a`, placed by `world` (relative to the mesh's
    /// origin), to `out`.
    fn read_positions(&self, a: &Accessor, world: DMat4, label: &str, out: &mut Vec<Vec3>) -> Result<()> {
        let quantized = [DataType::I8, DataType::U8, DataType::I16, DataType::U16];
        if a.dimensions() != Dimensions::Vec3 || !(a.data_type() == DataType::F32 || quantized.contains(&a.data_type()))
        {
            return Err(self.error(format!(
                "{label}: positions must be VEC3 of floats (or of 8- or 16-bit integers, KHR_mesh_quantization), not {:?} of {:?}",
                a.dimensions(),
                a.data_type()
            )));
        }
        let base = out.len();
        self.read_vec3(a, label, out)?;
        let identity = world == DMat4::IDENTITY;
        for (k, p) in out[base..].iter_mut().enumerate() {
            // Which axis, not the value: the buffer's bytes are never shown.
            if let Some(axis) = non_finite_axis(*p) {
                return Err(self.error(format!("{label} vertex {k} has a non-finite {axis} coordinate")));
            }
            if !identity {
                *p = world.transform_point3(p.as_dvec3()).as_vec3();
                if let Some(axis) = non_finite_axis(*p) {
                    return Err(self.error(format!(
                        "{label} vertex {k} has a non-finite {axis} coordinate after the node transforms"
                    )));
                }
            }
        }
        Ok(())
    }

    /// The normals of accessor `a` (one per each of the `count` positions), placed by the
    /// normal matrix of `world`. They are not checked: the bake replaces an unusable one.
    fn read_normals(&self, a: &Accessor, count: usize, world: DMat4, what: &str) -> Result<Vec<Vec3>> {
        let quantized = [DataType::I8, DataType::I16].contains(&a.data_type()) && a.normalized();
        if a.dimensions() != Dimensions::Vec3 || !(a.data_type() == DataType::F32 || quantized) {
            return Err(self.error(format!(
                "{what}: normals must be VEC3 of floats (or of normalized 8- or 16-bit integers, KHR_mesh_quantization), not {:?} of {:?}",
                a.dimensions(),
                a.data_type()
            )));
        }
        if a.count() != count {
            return Err(self.error(format!(
                "{what}: its NORMAL accessor {} has {} elements but its POSITION accessor has {count}",
                a.index(),
                a.count()
            )));
        }
        let mut out = Vec::with_capacity(count);
        self.read_vec3(a, what, &mut out)?;
        if world != DMat4::IDENTITY {
            let normal_matrix = DMat3::from_mat4(world).inverse().transpose();
            for n in &mut out {
                *n = (normal_matrix * n.as_dvec3()).as_vec3();
            }
        }
        Ok(out)
    }

    /// Every `TEXCOORD_n` of `primitive` (one per each of its `count` positions): VEC2 of
    /// floats or of normalized unsigned 8- or 16-bit integers (glTF 2.0, 3.7.2.1).
    fn read_texcoords(&self, primitive: &::gltf::Primitive, count: usize, what: &str) -> Result<Vec<(u32, Vec<Vec2>)>> {
        let mut out = Vec::new();
        for (semantic, a) in primitive.attributes() {
            let Semantic::TexCoords(set) = semantic else { continue };
            let quantized = [DataType::U8, DataType::U16].contains(&a.data_type()) && a.normalized();
            if a.dimensions() != Dimensions::Vec2 || !(a.data_type() == DataType::F32 || quantized) {
                return Err(self.error(format!(
                    "{what}: TEXCOORD_{set} must be VEC2 of floats (or of normalized unsigned 8- or 16-bit integers), not {:?} of {:?}",
                    a.dimensions(),
                    a.data_type()
                )));
            }
            if a.count() != count {
                return Err(self.error(format!(
                    "{what}: its TEXCOORD_{set} accessor {} has {} elements but its POSITION accessor has {count}",
                    a.index(),
                    a.count()
                )));
            }
            let mut uv = match self.elements(&a, what)? {
                Some(e) => (0..count).map(|i| Vec2::new(e.float(i, 0), e.float(i, 1))).collect(),
                None => vec![Vec2::ZERO; count],
            };
            if let Some((index, value)) = self.sparse(&a, what)? {
                for j in 0..index.count {
                    if let Some(p) = uv.get_mut(index.index(j) as usize) {
                        *p = Vec2::new(value.float(j, 0), value.float(j, 1));
                    }
                }
            }
            out.push((set, uv));
        }
        out.sort_by_key(|(set, _)| *set);
        Ok(out)
    }

    /// Appends the elements of the VEC3 accessor `a`, its sparse substitutions applied.
    fn read_vec3(&self, a: &Accessor, what: &str, out: &mut Vec<Vec3>) -> Result<()> {
        let base = out.len();
        match self.elements(a, what)? {
            Some(e) => out.extend((0..a.count()).map(|i| Vec3::new(e.float(i, 0), e.float(i, 1), e.float(i, 2)))),
            None => out.resize(base + a.count(), Vec3::ZERO),
        }
        if let Some((index, value)) = self.sparse(a, what)? {
            for j in 0..index.count {
                if let Some(p) = out.get_mut(base + index.index(j) as usize) {
                    *p = Vec3::new(value.float(j, 0), value.float(j, 1), value.float(j, 2));
                }
            }
        }
        Ok(())
    }

    /// The indices of accessor `a`, which must be unsigned integer scalars.
    fn read_indices<'s>(&'s self, a: &Accessor, what: &str) -> Result<Indices<'s>> {
        let integer = matches!(a.data_type(), DataType::U8 | DataType::U16 | DataType::U32);
        if a.dimensions() != Dimensions::Scalar || !integer {
            return Err(self.error(format!(
                "{what}: indices must be SCALAR unsigned integers, not {:?} of {:?}",
                a.dimensions(),
                a.data_type()
            )));
        }
        let elements = self.elements(a, what)?;
        let sparse = self.sparse(a, what)?;
        Ok(match (elements, sparse) {
            (Some(e), None) => Indices::Direct(e),
            (elements, sparse) => {
                let mut v: Vec<u32> = match elements {
                    Some(e) => (0..a.count()).map(|i| e.index(i)).collect(),
                    None => vec![0; a.count()],
                };
                if let Some((index, value)) = sparse {
                    for j in 0..index.count {
                        if let Some(slot) = v.get_mut(index.index(j) as usize) {
                            *slot = value.index(j);
                        }
                    }
                }
                Indices::Gathered(v)
            }
        })
    }
}

/// The first axis (`x`, `y` or `z`) on which `p` is not finite.
fn non_finite_axis(p: Vec3) -> Option<&'static str> {
    p.to_array().iter().zip(["x", "y", "z"]).find(|(c, _)| !c.is_finite()).map(|(_, axis)| axis)
}

/// A node's local transform in f64: its matrix (column-major), or translation × rotation
/// × scale with the rotation normalised (a zero rotation gives NaN, refused by the caller).
fn local_matrix(node: &Node) -> DMat4 {
    match node.transform() {
        Transform::Matrix { matrix } => DMat4::from_cols_array_2d(&matrix.map(|c| c.map(f64::from))),
        Transform::Decomposed { translation, rotation, scale } => DMat4::from_scale_rotation_translation(
            DVec3::from(scale.map(f64::from)),
            DQuat::from_array(rotation.map(f64::from)).normalize(),
            DVec3::from(translation.map(f64::from)),
        ),
    }
}

fn mode_name(mode: Mode) -> &'static str {
    match mode {
        Mode::Points => "POINTS",
        Mode::Lines => "LINES",
        Mode::LineLoop => "LINE_LOOP",
        Mode::LineStrip => "LINE_STRIP",
        Mode::Triangles => "TRIANGLES",
        Mode::TriangleStrip => "TRIANGLE_STRIP",
        Mode::TriangleFan => "TRIANGLE_FAN",
    }
}

/// ` ("name")` for a named object, escaped to stay on one line; empty without a name.
fn quoted(name: Option<&str>) -> String {
    name.map(|n| format!(" ({:?})", one_line(n))).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_engine_has_121496_triangles_through_its_node_hierarchy() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/2CylinderEngine.glb");
        let options = LoadOptions::from_env().unwrap();
        let mesh = load_gltf(&path, &options, &mut Meter::unlimited()).unwrap_or_else(|e| panic!("{e}"));
        // 75,730 triangles in its 29 meshes, placed by 67 nodes.
        assert_eq!(mesh.triangles.len(), 121_496);
        // The scene drops the degenerate ones: 11,154 repeat a vertex index (leaving the
        // 110,342 other tools report) and 6 more have two corners at the same position.
        let p = |i: u32| mesh.positions[i as usize];
        let repeated = mesh.triangles.iter().filter(|t| t[0] == t[1] || t[1] == t[2] || t[0] == t[2]).count();
        let coincident =
            mesh.triangles.iter().filter(|t| p(t[0]) == p(t[1]) || p(t[1]) == p(t[2]) || p(t[0]) == p(t[2]));
        assert_eq!((repeated, coincident.count() - repeated), (11_154, 6));
    }

    #[test]
    fn uris_must_stay_in_the_files_folder_once_links_are_followed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().canonicalize().unwrap();
        std::fs::create_dir_all(d.join("model/sub")).unwrap();
        std::fs::write(d.join("model/sub/a.bin"), b"a").unwrap();
        std::fs::write(d.join("secret.bin"), b"s").unwrap();
        std::os::unix::fs::symlink("sub/a.bin", d.join("model/inside.bin")).unwrap();
        std::os::unix::fs::symlink("../secret.bin", d.join("model/outside.bin")).unwrap();
        std::os::unix::fs::symlink("..", d.join("model/up")).unwrap();
        let gltf = d.join("model/m.gltf");
        for uri in ["sub/a.bin", "./sub/../sub/a.bin", "sub%2Fa.bin", "inside.bin"] {
            assert_eq!(uri_file(&gltf, uri, false, true).ok(), Some(d.join("model/sub/a.bin")), "{uri}");
        }
        for (uri, how) in [
            ("../secret.bin", ""),
            ("sub/../../secret.bin", ""),
            ("/etc/passwd", ""),
            ("%2Fetc%2Fpasswd", ""),
            ("outside.bin", " through a symbolic link"),
            ("up/secret.bin", " through a symbolic link"),
        ] {
            let e = uri_file(&gltf, uri, false, true).unwrap_err().to_string();
            assert!(e.contains(&format!("leads outside the glTF file's folder{how};")), "{uri}: {e}");
        }
        // Outside but allowed: resolved against the folder, not checked.
        assert_eq!(uri_file(&gltf, "../secret.bin", true, true).ok(), Some(d.join("model/../secret.bin")));
        // A missing file in the folder: an error for a buffer, accepted for an image.
        assert!(uri_file(&gltf, "missing.png", false, true).unwrap_err().to_string().contains("No such file"));
        assert_eq!(uri_file(&gltf, "missing.png", false, false).ok(), Some(d.join("model/missing.png")));
        assert!(
            uri_file(&gltf, "http://example.com/a.bin", false, true)
                .unwrap_err()
                .to_string()
                .contains("unsupported URI")
        );
    }

    #[test]
    fn json_objects_are_counted_outside_strings() {
        assert_eq!(json_objects(br#"{"a": [{}, {"b": "{\"}"}], "c": "\\"} {"#), 4);
    }
}
