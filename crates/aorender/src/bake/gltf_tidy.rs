//! The last steps of writing a baked glTF file, on its JSON and the bytes of the buffer the
//! bake writes (the GLB's binary chunk, or a `.gltf`'s new `NAME.bin`):
//!
//! - **Embedding** ([`embed`]): a GLB holds everything. The input's other buffers (files
//!   beside a `.gltf`, `data:` URIs) are appended to the binary chunk and their views
//!   pointed at it; images named by URI become buffer views with their MIME type.
//! - **Pruning** ([`prune`]): the objects the bake left without a reference (the
//!   accessors of primitives rewritten on split vertices, a replaced `occlusionTexture`'s
//!   texture, image and sampler, the embedded buffers) are removed and every index
//!   renumbered. Only objects the input itself used are candidates: what the input kept
//!   unused stays, and an object referenced only from an extension this module does not
//!   know is never seen as used, so never removed.
//! - **Compaction** ([`compact`]): the written buffer keeps only the bytes its remaining
//!   views cover.
//!
//! References are followed by [`visit`], which knows the core schema (glTF 2.0,
//! section 5) and the extensions that name accessors, buffer views, buffers or images;
//! a texture is referenced by any `…Texture` object with an `index` inside a material,
//! which covers the `KHR_materials_*` extensions.

use ::gltf::json::Value;
use base64::Engine;
use std::collections::{BTreeMap, BTreeSet};

/// The kinds of glTF objects a bake can leave unused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum Kind {
    Textures,
    Samplers,
    Images,
    Accessors,
    BufferViews,
    Buffers,
}

impl Kind {
    /// The top-level array of the kind.
    pub(crate) fn key(self) -> &'static str {
        match self {
            Kind::Textures => "textures",
            Kind::Samplers => "samplers",
            Kind::Images => "images",
            Kind::Accessors => "accessors",
            Kind::BufferViews => "bufferViews",
            Kind::Buffers => "buffers",
        }
    }

    /// In the order in which removing one kind can leave the next unused.
    const ALL: [Kind; 6] =
        [Kind::Textures, Kind::Samplers, Kind::Images, Kind::Accessors, Kind::BufferViews, Kind::Buffers];
}

/// Extensions of a texture that name an image in place of `source`.
const IMAGE_EXTENSIONS: [&str; 4] = ["KHR_texture_basisu", "EXT_texture_webp", "EXT_texture_avif", "MSFT_texture_dds"];
/// Extensions of a buffer view that name a buffer.
const MESHOPT: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

/// Calls `f` with every reference to an object of `kind` in `doc` (the JSON value holding
/// the index).
pub(crate) fn visit(doc: &mut Value, kind: Kind, f: &mut dyn FnMut(&mut Value)) {
    match kind {
        Kind::Textures => {
            for material in array_mut(doc, "materials") {
                texture_infos(material, f);
            }
        }
        Kind::Samplers => {
            for texture in array_mut(doc, "textures") {
                apply(texture.get_mut("sampler"), f);
            }
        }
        Kind::Images => {
            for texture in array_mut(doc, "textures") {
                apply(texture.get_mut("source"), f);
                for ext in IMAGE_EXTENSIONS {
                    apply(
                        texture.get_mut("extensions").and_then(|e| e.get_mut(ext)).and_then(|e| e.get_mut("source")),
                        f,
                    );
                }
            }
        }
        Kind::Accessors => {
            for mesh in array_mut(doc, "meshes") {
                for primitive in mesh.get_mut("primitives").and_then(Value::as_array_mut).into_iter().flatten() {
                    values_of(primitive.get_mut("attributes"), f);
                    apply(primitive.get_mut("indices"), f);
                    for target in primitive.get_mut("targets").and_then(Value::as_array_mut).into_iter().flatten() {
                        values_of(Some(target), f);
                    }
                }
            }
            for skin in array_mut(doc, "skins") {
                apply(skin.get_mut("inverseBindMatrices"), f);
            }
            for animation in array_mut(doc, "animations") {
                for sampler in animation.get_mut("samplers").and_then(Value::as_array_mut).into_iter().flatten() {
                    apply(sampler.get_mut("input"), f);
                    apply(sampler.get_mut("output"), f);
                }
            }
            for node in array_mut(doc, "nodes") {
                let instancing = node.get_mut("extensions").and_then(|e| e.get_mut("EXT_mesh_gpu_instancing"));
                values_of(instancing.and_then(|e| e.get_mut("attributes")), f);
            }
        }
        Kind::BufferViews => {
            for accessor in array_mut(doc, "accessors") {
                apply(accessor.get_mut("bufferView"), f);
                if let Some(sparse) = accessor.get_mut("sparse") {
                    apply(sparse.get_mut("indices").and_then(|i| i.get_mut("bufferView")), f);
                    apply(sparse.get_mut("values").and_then(|v| v.get_mut("bufferView")), f);
                }
            }
            for image in array_mut(doc, "images") {
                apply(image.get_mut("bufferView"), f);
            }
            for mesh in array_mut(doc, "meshes") {
                for primitive in mesh.get_mut("primitives").and_then(Value::as_array_mut).into_iter().flatten() {
                    let draco = primitive.get_mut("extensions").and_then(|e| e.get_mut("KHR_draco_mesh_compression"));
                    apply(draco.and_then(|d| d.get_mut("bufferView")), f);
                }
            }
        }
        Kind::Buffers => {
            for view in array_mut(doc, "bufferViews") {
                apply(view.get_mut("buffer"), f);
                for ext in MESHOPT {
                    apply(view.get_mut("extensions").and_then(|e| e.get_mut(ext)).and_then(|e| e.get_mut("buffer")), f);
                }
            }
        }
    }
}

/// `doc[key]`'s elements, none when it is not an array.
fn array_mut<'v>(doc: &'v mut Value, key: &str) -> impl Iterator<Item = &'v mut Value> {
    doc.get_mut(key).and_then(Value::as_array_mut).into_iter().flatten()
}

fn apply(value: Option<&mut Value>, f: &mut dyn FnMut(&mut Value)) {
    if let Some(v) = value.filter(|v| v.is_u64()) {
        f(v);
    }
}

/// Every value of an object of indices (a primitive's attributes, a morph target).
fn values_of(object: Option<&mut Value>, f: &mut dyn FnMut(&mut Value)) {
    for v in object.and_then(Value::as_object_mut).into_iter().flat_map(|o| o.values_mut()) {
        apply(Some(v), f);
    }
}

/// The `index` of every texture info under a material: any object named `…Texture`.
fn texture_infos(value: &mut Value, f: &mut dyn FnMut(&mut Value)) {
    let Some(object) = value.as_object_mut() else { return };
    for (key, v) in object.iter_mut() {
        if key.ends_with("Texture") && v.is_object() {
            apply(v.get_mut("index"), f);
        } else if v.is_object() {
            texture_infos(v, f);
        }
    }
}

/// The indices of `kind` that `doc` references.
pub(crate) fn used(doc: &Value, kind: Kind) -> BTreeSet<usize> {
    let mut doc = doc.clone();
    let mut out = BTreeSet::new();
    visit(&mut doc, kind, &mut |v| {
        out.insert(v.as_u64().unwrap_or(u64::MAX) as usize);
    });
    out
}

/// Removes from `doc` every object of the kinds above that `was_used` (the input's
/// references, by the input's index `i` at the output's index `i + shift(kind)`) lists
/// and nothing in `doc` references any longer, renumbering the references to the rest.
/// Returns the (output's) indices of the objects of each kind that went.
pub(crate) fn prune(doc: &mut Value, input: &Value, shift: impl Fn(Kind) -> usize) -> BTreeMap<Kind, BTreeSet<usize>> {
    let mut removed = BTreeMap::new();
    for kind in Kind::ALL {
        let before: BTreeSet<usize> = used(input, kind).into_iter().map(|i| i + shift(kind)).collect();
        let now = used(doc, kind);
        let len = doc.get(kind.key()).and_then(Value::as_array).map_or(0, Vec::len);
        let gone: BTreeSet<usize> = before.difference(&now).copied().filter(|&i| i < len).collect();
        if gone.is_empty() {
            continue;
        }
        let mut map = vec![usize::MAX; len];
        let mut next = 0;
        for (i, m) in map.iter_mut().enumerate() {
            if !gone.contains(&i) {
                *m = next;
                next += 1;
            }
        }
        visit(doc, kind, &mut |v| {
            if let Some(&m) = v.as_u64().and_then(|i| map.get(i as usize)) {
                *v = m.into();
            }
        });
        if let Some(items) = doc.get_mut(kind.key()).and_then(Value::as_array_mut) {
            let mut i = 0;
            items.retain(|_| {
                i += 1;
                !gone.contains(&(i - 1))
            });
        }
        removed.insert(kind, gone);
    }
    removed
}

/// Rebuilds buffer `buffer`'s bytes `data` with only the ranges its buffer views cover,
/// each at the same offset modulo 4 (so accessors keep their alignment), and moves the
/// views. Left as it is when a view is meshopt-compressed (its extension holds offsets
/// of its own).
pub(crate) fn compact(doc: &mut Value, data: &mut Vec<u8>, buffer: usize) {
    let views =
        array_mut(doc, "bufferViews").filter(|v| v.get("buffer").and_then(Value::as_u64) == Some(buffer as u64));
    let mut ranges = Vec::new();
    for view in views {
        if view.get("extensions").and_then(Value::as_object).is_some_and(|e| MESHOPT.iter().any(|m| e.contains_key(*m)))
        {
            return;
        }
        let number = |key: &str| view.get(key).and_then(Value::as_u64).unwrap_or(0) as usize;
        let (start, length) = (number("byteOffset"), number("byteLength"));
        if start + length > data.len() {
            return;
        }
        ranges.push((start, start + length));
    }
    ranges.sort_unstable();
    // Overlapping ranges (views may share bytes) merged.
    let mut merged: Vec<(usize, usize)> = Vec::new();
    for (s, e) in ranges {
        match merged.last_mut() {
            Some(last) if s <= last.1 => last.1 = last.1.max(e),
            _ => merged.push((s, e)),
        }
    }
    let mut out = Vec::with_capacity(merged.iter().map(|(s, e)| e - s + 3).sum());
    let mut moved = Vec::with_capacity(merged.len());
    for (s, e) in &merged {
        let at = out.len().next_multiple_of(4) + s % 4;
        out.resize(at, 0);
        out.extend_from_slice(&data[*s..*e]);
        moved.push((*s, *e, at));
    }
    for view in array_mut(doc, "bufferViews").filter(|v| v.get("buffer").and_then(Value::as_u64) == Some(buffer as u64))
    {
        let offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        let Some(&(s, _, at)) = moved.iter().find(|(s, e, _)| offset >= *s && offset < (*e).max(*s + 1)) else {
            continue;
        };
        let new = at + (offset - s);
        if new == offset {
            continue;
        }
        if new == 0 {
            if let Some(o) = view.as_object_mut() {
                o.remove("byteOffset");
            }
        } else {
            view["byteOffset"] = new.into();
        }
    }
    *data = out;
}

/// An image or buffer held by a URI, as bytes: a `data:` URI decoded, else `None`.
pub(crate) fn data_uri(uri: &str) -> Option<(String, Vec<u8>)> {
    let rest = uri.strip_prefix("data:")?;
    let (meta, payload) = rest.split_once(',')?;
    let (mime, base64) = match meta.strip_suffix(";base64") {
        Some(m) => (m, true),
        None => (meta, false),
    };
    let bytes = if base64 {
        base64::engine::general_purpose::STANDARD.decode(payload.trim()).ok()?
    } else {
        percent_encoding::percent_decode_str(payload).collect()
    };
    Some((mime.to_string(), bytes))
}

/// The MIME type glTF names for an image's bytes, from their signature.
pub(crate) fn image_mime(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("image/png")
    } else if bytes.starts_with(&[0xff, 0xd8, 0xff]) {
        Some("image/jpeg")
    } else if bytes.len() >= 12 && &bytes[0..4] == b"RIFF" && &bytes[8..12] == b"WEBP" {
        Some("image/webp")
    } else if bytes.starts_with(b"\xabKTX 20\xbb\r\n\x1a\n") {
        Some("image/ktx2")
    } else if bytes.starts_with(b"DDS ") {
        Some("image/vnd-ms.dds")
    } else if bytes.len() >= 12 && &bytes[4..12] == b"ftypavif" {
        Some("image/avif")
    } else {
        None
    }
}

/// `doc[key]` as an array, made one when missing.
pub(crate) fn array<'v>(doc: &'v mut Value, key: &str) -> &'v mut Vec<Value> {
    if !doc[key].is_array() {
        doc[key] = Value::Array(Vec::new());
    }
    match &mut doc[key] {
        Value::Array(a) => a,
        _ => unreachable!("made an array above"),
    }
}

/// Appends `bytes` to `data` (4-byte aligned) as a new buffer view of `buffer`; returns
/// the view's index.
pub(crate) fn add_view(doc: &mut Value, data: &mut Vec<u8>, buffer: usize, bytes: &[u8]) -> usize {
    data.resize(data.len().next_multiple_of(4), 0);
    let offset = data.len();
    data.extend_from_slice(bytes);
    let views = array(doc, "bufferViews");
    let mut view = Value::Object(Default::default());
    view["buffer"] = buffer.into();
    if offset > 0 {
        view["byteOffset"] = offset.into();
    }
    view["byteLength"] = bytes.len().into();
    views.push(view);
    views.len() - 1
}

/// Moves every buffer of `doc` but `buffer` that holds bytes (`bytes(i)`: buffer `i`'s,
/// `None` for one without, such as a meshopt fallback) into `data`, buffer `buffer`'s
/// bytes: their views now point into it. The buffers left unused are for [`prune`].
pub(crate) fn embed_buffers(
    doc: &mut Value,
    data: &mut Vec<u8>,
    buffer: usize,
    mut bytes: impl FnMut(usize) -> Option<Vec<u8>>,
) {
    let count = doc.get("buffers").and_then(Value::as_array).map_or(0, Vec::len);
    let mut base: BTreeMap<usize, usize> = BTreeMap::new();
    for i in (0..count).filter(|&i| i != buffer) {
        if doc["buffers"][i].get("uri").is_none() {
            continue;
        }
        let Some(b) = bytes(i) else { continue };
        data.resize(data.len().next_multiple_of(4), 0);
        base.insert(i, data.len());
        data.extend_from_slice(&b);
    }
    for view in array_mut(doc, "bufferViews") {
        let Some(&start) = view.get("buffer").and_then(Value::as_u64).and_then(|b| base.get(&(b as usize))) else {
            continue;
        };
        let offset = view.get("byteOffset").and_then(Value::as_u64).unwrap_or(0) as usize;
        view["buffer"] = buffer.into();
        view["byteOffset"] = (start + offset).into();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn pruning_removes_what_the_input_used_and_the_output_does_not() {
        let input = json!({
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2}]}],
            "accessors": [{"bufferView": 0}, {"bufferView": 1}, {"bufferView": 2}, {"bufferView": 3}],
            "bufferViews": [{"buffer": 0}, {"buffer": 0}, {"buffer": 1}, {"buffer": 0}],
            "buffers": [{"byteLength": 4}, {"byteLength": 4, "uri": "b.bin"}],
            "materials": [{"occlusionTexture": {"index": 0}, "extensions": {"KHR_materials_clearcoat": {"clearcoatTexture": {"index": 1}}}}],
            "textures": [{"source": 0, "sampler": 0}, {"source": 1}],
            "images": [{"uri": "a.png"}, {"uri": "b.png"}],
            "samplers": [{}]
        });
        let mut out = input.clone();
        // The primitive rewritten onto accessors 4 and 5 (a view 4), the occlusion texture
        // replaced by texture 2 of image 2.
        out["meshes"][0]["primitives"][0] = json!({"attributes": {"POSITION": 4, "NORMAL": 1}, "indices": 5});
        out["accessors"].as_array_mut().unwrap().extend([json!({"bufferView": 4}), json!({"bufferView": 4})]);
        out["bufferViews"].as_array_mut().unwrap().push(json!({"buffer": 0}));
        out["textures"].as_array_mut().unwrap().push(json!({"source": 2, "sampler": 0}));
        out["images"].as_array_mut().unwrap().push(json!({"bufferView": 4}));
        out["materials"][0]["occlusionTexture"]["index"] = 2.into();
        let removed = prune(&mut out, &input, |_| 0);
        // Accessor 3 was unused in the input too: kept. Buffer 1 lost its only view.
        let gone = |k: Kind| removed.get(&k).map(|s| s.iter().copied().collect::<Vec<_>>()).unwrap_or_default();
        assert_eq!(gone(Kind::Accessors), [0, 2]);
        assert_eq!(gone(Kind::Textures), [0]);
        assert_eq!(gone(Kind::Images), [0]);
        assert!(gone(Kind::Samplers).is_empty(), "still used by the new texture");
        assert_eq!(gone(Kind::BufferViews), [0, 2]);
        assert_eq!(gone(Kind::Buffers), [1]);
        assert_eq!(
            out["meshes"][0]["primitives"][0],
            json!({"attributes": {"POSITION": 2, "NORMAL": 0}, "indices": 3})
        );
        assert_eq!(
            out["accessors"],
            json!([{"bufferView": 0}, {"bufferView": 1}, {"bufferView": 2}, {"bufferView": 2}])
        );
        assert_eq!(out["bufferViews"], json!([{"buffer": 0}, {"buffer": 0}, {"buffer": 0}]));
        assert_eq!(out["textures"], json!([{"source": 0}, {"source": 1, "sampler": 0}]));
        assert_eq!(out["materials"][0]["occlusionTexture"]["index"], 1);
        assert_eq!(out["materials"][0]["extensions"]["KHR_materials_clearcoat"]["clearcoatTexture"]["index"], 0);
        assert_eq!(out["images"], json!([{"uri": "b.png"}, {"bufferView": 2}]));
        assert_eq!(out["buffers"], json!([{"byteLength": 4}]));
    }

    #[test]
    fn compaction_keeps_the_viewed_bytes_at_their_alignment() {
        let mut doc = json!({"bufferViews": [
            {"buffer": 0, "byteOffset": 8, "byteLength": 4},
            {"buffer": 0, "byteOffset": 21, "byteLength": 3},
            {"buffer": 1, "byteOffset": 0, "byteLength": 2},
            {"buffer": 0, "byteOffset": 10, "byteLength": 4}
        ]});
        let mut data: Vec<u8> = (0..32).collect();
        compact(&mut doc, &mut data, 0);
        // 8..14 (two overlapping views) at 0, 21..24 at 9 (21 mod 4 = 1).
        assert_eq!(data, [8, 9, 10, 11, 12, 13, 0, 0, 0, 21, 22, 23]);
        let offsets: Vec<Value> =
            doc["bufferViews"].as_array().unwrap().iter().map(|v| v["byteOffset"].clone()).collect();
        assert_eq!(offsets, [Value::Null, 9.into(), 0.into(), 2.into()]);
    }

    #[test]
    fn data_uris_and_image_types_are_read() {
        assert_eq!(
            data_uri("data:application/octet-stream;base64,AAEC"),
            Some(("application/octet-stream".into(), vec![0, 1, 2]))
        );
        assert_eq!(data_uri("a.bin"), None);
        assert_eq!(image_mime(b"\x89PNG\r\n\x1a\nrest"), Some("image/png"));
        assert_eq!(image_mime(&[0xff, 0xd8, 0xff, 0xe0]), Some("image/jpeg"));
        assert_eq!(image_mime(b"BM"), None);
    }
}
