//! The mesh loaders on the command line: a glTF file's primitives that are not triangles
//! are skipped with one warning line, and a render holds at most two copies of the
//! geometry on its heap.

mod common;
use base64::Engine;
use common::*;
use serde_json::json;

// --- glTF -----------------------------------------------------------------------------

/// A glTF file whose mesh has a POINTS and a LINES primitive beside its triangle: the
/// render skips them with one warning line naming the file, and succeeds. (Which triangles
/// each mode gives, and the warning as the library reports it, are library tests.)
#[test]
fn gltf_primitives_that_are_not_triangles_are_skipped_with_one_warning_line() {
    let dir = temp_dir();
    let positions: Vec<u8> =
        [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    let data = base64::engine::general_purpose::STANDARD.encode(&positions);
    let doc = json!({
        "asset": { "version": "2.0" },
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [
            { "attributes": { "POSITION": 0 } },
            { "attributes": { "POSITION": 0 }, "mode": 0 },
            { "attributes": { "POSITION": 0 }, "mode": 1 }
        ] }],
        "accessors": [{ "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0] }],
        "bufferViews": [{ "buffer": 0, "byteLength": positions.len() }],
        "buffers": [{ "byteLength": positions.len(), "uri": format!("data:application/octet-stream;base64,{data}") }]
    });
    let path = dir.path().join("modes_data.gltf");
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();

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
