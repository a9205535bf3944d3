//! The mesh loaders on the command line: a glTF file's primitives that are not triangles
//! are skipped with one warning line, and a render holds at most two copies of the
//! geometry on its heap.

mod common;
use base64::Engine;
use common::*;
use serde_json::json;
use std::path::Path;

// --- glTF -----------------------------------------------------------------------------

/// A glTF binary buffer being filled, each piece aligned to 4 bytes.
#[derive(Default)]
struct Buffer {
    bytes: Vec<u8>,
    views: Vec<serde_json::Value>,
}

impl Buffer {
    /// Appends `data` as a new buffer view; returns its index.
    fn view(&mut self, data: &[u8]) -> usize {
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        self.views.push(json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() }));
        self.bytes.extend_from_slice(data);
        self.views.len() - 1
    }
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn position_accessor(view: usize, count: usize) -> serde_json::Value {
    json!({ "bufferView": view, "componentType": 5126, "count": count, "type": "VEC3",
            "min": [-10.0, -10.0, -10.0], "max": [10.0, 10.0, 10.0] })
}

/// The document `doc` with `buffer` as buffer 0, in a data: URI, written as
/// `dir/STEM_data.gltf`.
fn write_gltf_data(dir: &Path, stem: &str, mut doc: serde_json::Value, buffer: &Buffer) -> std::path::PathBuf {
    doc["bufferViews"] = json!(buffer.views);
    let length = buffer.bytes.len();
    let data = base64::engine::general_purpose::STANDARD.encode(&buffer.bytes);
    doc["buffers"] = json!([{ "byteLength": length, "uri": format!("data:application/octet-stream;base64,{data}") }]);
    let path = dir.join(format!("{stem}_data.gltf"));
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
    path
}

/// A glTF file whose mesh has POINTS and LINES primitives beside its triangles: the render
/// skips them with one warning line naming the file, and succeeds.
#[test]
fn gltf_primitives_that_are_not_triangles_are_skipped_with_one_warning_line() {
    let dir = temp_dir();
    let mut buffer = Buffer::default();
    // A unit square in z = 0: 0 (0,0), 1 (1,0), 2 (0,1), 3 (1,1).
    let square = buffer.view(&f32_bytes(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0]));
    let u8s = buffer.view(&[0u8, 1, 2]);
    let u16s = buffer.view(&[1u16, 3, 2].map(u16::to_le_bytes).concat());
    let u32s = buffer.view(&[0u32, 1, 3, 2].map(u32::to_le_bytes).concat());
    let doc = json!({
        "asset": { "version": "2.0" },
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [
            { "attributes": { "POSITION": 0 }, "indices": 1 },
            { "attributes": { "POSITION": 0 }, "indices": 2, "mode": 4 },
            { "attributes": { "POSITION": 0 }, "mode": 5 },
            { "attributes": { "POSITION": 0 }, "indices": 3, "mode": 6 },
            { "attributes": { "POSITION": 0 }, "mode": 0 },
            { "attributes": { "POSITION": 0 }, "indices": 3, "mode": 1 }
        ] }],
        "accessors": [
            position_accessor(square, 4),
            { "bufferView": u8s, "componentType": 5121, "count": 3, "type": "SCALAR" },
            { "bufferView": u16s, "componentType": 5123, "count": 3, "type": "SCALAR" },
            { "bufferView": u32s, "componentType": 5125, "count": 4, "type": "SCALAR" }
        ]
    });
    let path = write_gltf_data(dir.path(), "modes", doc, &buffer);

    // The skipped POINTS and LINES primitives are one warning line; the render succeeds.
    let output = aorender(
        &[
            "render",
            path.to_str().unwrap(),
            "--device",
            "cpu",
            "--width",
            "8",
            "--height",
            "8",
            "--spp",
            "1",
            "-o",
            "m.png",
        ],
        dir.path(),
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(
        lines[0].starts_with("aorender: warning: ")
            && lines[0].contains("modes_data.gltf")
            && lines[0].ends_with("skipped 2 primitives that are not triangles: 1 LINES, 1 POINTS"),
        "{}",
        lines[0]
    );
}

// --- Memory ---------------------------------------------------------------------------

/// From loading to the last pass, `aorender render` holds at most two copies of the
/// geometry on its own heap: the loaded scene, its BVH, the build's workspace (octree
/// cells built a few at a time) and the primitive records, made piece by piece as they
/// are uploaded, together stay under twice the scene's bytes. The binary counts its heap
/// (`heap_peak_bytes`); the driver's memory (on lavapipe, the device buffers) is not in
/// it. The full dragon (871k triangles), and nine of it flattened into one BVH (7.8M).
#[test]
fn rendering_holds_at_most_two_copies_of_the_geometry() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    for scene in [repo().join("scenes/dragon_vrip.ply.gz"), flattened_dragons(d)] {
        let name = scene.file_name().unwrap().to_string_lossy().to_string();
        let args = ["--width", "16", "--height", "16", "--spp", "1", "-o", "out.png", "--stats", "stats.json"];
        let out = aorender(&[&["render", scene.to_str().unwrap()][..], &args].concat(), d);
        assert!(out.status.success(), "{name}: {}", String::from_utf8_lossy(&out.stderr));
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("stats.json")).unwrap()).unwrap();
        let scene_bytes = json["scene_bytes"].as_u64().unwrap();
        let peak = json["heap_peak_bytes"].as_u64().expect("the binary counts its heap");
        let triangles = json["triangles"].as_u64().unwrap();
        eprintln!(
            "{name}: {triangles} triangles, scene {scene_bytes} bytes, heap peak {peak} bytes ({:.2} copies), \
             resident peak {}",
            peak as f64 / scene_bytes as f64,
            json["host_peak_bytes"]
        );
        assert!(triangles > 800_000, "{name}: {triangles} triangles");
        assert!(peak >= scene_bytes, "{name}: a heap peak of {peak} bytes cannot hold the {scene_bytes}-byte scene");
        assert!(peak <= 2 * scene_bytes, "{name}: heap peak {peak} bytes > two copies of {scene_bytes}");
    }
}
