//! The mesh loaders on the command line: a glTF file's primitives that are not triangles
//! are skipped with one warning line; files that other importers read (names and comments
//! in any encoding, byte-order marks, continued lines, glTF's optional fields and
//! material-only extensions) are rendered and baked, and their malformed variants refused
//! in one line naming the file and the line; a glTF mesh placed far away by its nodes is
//! probed at its points given where they are; and a render holds at most two copies of
//! the geometry on its heap.

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

// --- Files other importers read -------------------------------------------------------

/// A quad (two triangles, four vertices) as OBJ lines.
const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

/// A glTF document with one triangle (its POSITION accessor 0) in a buffer of `bytes`,
/// `uri` the buffer's URI, and `change` applied to the JSON.
fn gltf_doc(uri: &str, bytes: usize, change: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let mut doc = json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 } }] }],
        "accessors": [{ "bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0] }],
        "bufferViews": [{ "buffer": 0, "byteLength": 36 }],
        "buffers": [{ "byteLength": bytes, "uri": uri }]
    });
    change(&mut doc);
    serde_json::to_vec(&doc).unwrap()
}

/// A triangle's positions (36 bytes) and `extra` bytes after them, as a base64 data URI.
fn triangle_data(extra: usize) -> (String, usize) {
    let mut bytes: Vec<u8> =
        [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes.resize(36 + extra, 0);
    let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
    (format!("data:application/octet-stream;base64,{data}"), bytes.len())
}

/// A GLB container of `json` (padded with spaces) and no binary chunk.
fn glb(json: &[u8]) -> Vec<u8> {
    let mut chunk = json.to_vec();
    while !chunk.len().is_multiple_of(4) {
        chunk.push(b' ');
    }
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(20 + chunk.len() as u32).to_le_bytes());
    out.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&chunk);
    out
}

/// Files that are valid (each read by another importer: Blender, assimp, three.js) and
/// that the loaders refused, with the triangles a render finds in them and the points
/// (vertices) a bake takes, and a warning the render must give (empty for none).
fn valid_files() -> Vec<(&'static str, Vec<u8>, u64, u64, &'static str)> {
    let (uri, bytes) = triangle_data(0);
    // 44 bytes: base64 with one padding character, here left out.
    let (padded, padded_bytes) = triangle_data(8);
    let unpadded = padded.trim_end_matches('=').to_string();
    let (sparse_uri, sparse_bytes) = {
        let mut bytes: Vec<u8> =
            [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        bytes.extend_from_slice(&[1, 2, 0, 0]);
        let data = base64::engine::general_purpose::STANDARD.encode(&bytes);
        (format!("data:application/octet-stream;base64,{data}"), bytes.len())
    };
    let bom = |bytes: &[u8]| [&b"\xEF\xBB\xBF"[..], bytes].concat();
    let latin1 = [
        &b"# Export\xE9 par 3ds Max\nmtllib sc\xE8ne.mtl\no caf\xE9\ng groupe_\xE9t\xE9\n"[..],
        QUAD.as_bytes(),
        b"usemtl mat\xE9riau\nf 1 2 3 4 # la face \xE0 quatre coins\n",
    ]
    .concat();
    vec![
        ("latin1.obj", latin1, 2, 4, ""),
        ("bom.obj", bom(format!("{QUAD}f 1 2 3 4\n").replace('\n', "\r\n").as_bytes()), 2, 4, ""),
        (
            "continued.obj",
            b"v 0 0 0\nv 1 \\\n 0 0\nv 1 1 0\r\nv 0 1 \\\r\n0\nf 1 2 \\\n 3 \\\n 4\n".to_vec(),
            2,
            4,
            "",
        ),
        ("one_number_vt.obj", format!("{QUAD}vt 0.5\nvt 0.25\nf 1/1 2/2 3/1 4/2\n").into_bytes(), 2, 4, ""),
        (
            "bom.ply",
            bom(b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
                  element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"),
            2,
            4,
            "",
        ),
        ("bom.gltf", bom(&gltf_doc(&uri, bytes, |_| ())), 1, 3, ""),
        ("bom.glb", glb(&bom(&gltf_doc(&uri, bytes, |_| ()))), 1, 3, ""),
        ("unpadded.gltf", gltf_doc(&unpadded, padded_bytes, |_| ()), 1, 3, ""),
        (
            // A material extension of glTF 1.0's day, required: it changes no geometry.
            "technique.gltf",
            gltf_doc(&uri, bytes, |d| {
                d["extensionsUsed"] = json!(["KHR_technique_webgl"]);
                d["extensionsRequired"] = json!(["KHR_technique_webgl"]);
                d["materials"] = json!([{ "extensions": { "KHR_technique_webgl": { "technique": 0 } } }]);
                d["meshes"][0]["primitives"][0]["material"] = json!(0);
            }),
            1,
            3,
            "",
        ),
        (
            // An extension nobody knows, required, used by a material only.
            "material_extension.gltf",
            gltf_doc(&uri, bytes, |d| {
                d["extensionsUsed"] = json!(["EXT_made_up_shading"]);
                d["extensionsRequired"] = json!(["EXT_made_up_shading"]);
                d["materials"] = json!([{ "extensions": { "EXT_made_up_shading": { "glow": 1 } } }]);
                d["meshes"][0]["primitives"][0]["material"] = json!(0);
            }),
            1,
            3,
            "requires the glTF extension EXT_made_up_shading, which only its materials, textures or cameras use: ignored",
        ),
        (
            // An accessor without a buffer view holds zeros: texture coordinates here.
            "zero_accessor.gltf",
            gltf_doc(&uri, bytes, |d| {
                let accessors = d["accessors"].as_array_mut().unwrap();
                accessors.push(json!({ "componentType": 5126, "count": 3, "type": "VEC2" }));
                d["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = json!(1);
            }),
            1,
            3,
            "",
        ),
        (
            // Positions of zeros without a buffer view, two of them replaced sparsely: the
            // triangle's last two corners, indexed by the bytes 1 and 2 after them.
            "sparse.gltf",
            gltf_doc(&sparse_uri, sparse_bytes, |d| {
                d["bufferViews"] = json!([
                    { "buffer": 0, "byteOffset": 12, "byteLength": 24 },
                    { "buffer": 0, "byteOffset": 36, "byteLength": 2 }
                ]);
                d["accessors"][0] = json!({ "componentType": 5126, "count": 3, "type": "VEC3",
                    "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0],
                    "sparse": { "count": 2, "indices": { "bufferView": 1, "componentType": 5121 },
                                "values": { "bufferView": 0 } } });
            }),
            1,
            3,
            "",
        ),
        (
            "no_bounds.gltf",
            gltf_doc(&uri, bytes, |d| {
                let accessor = d["accessors"][0].as_object_mut().unwrap();
                accessor.remove("min");
                accessor.remove("max");
            }),
            1,
            3,
            "",
        ),
        (
            // An animation whose channel targets no node (KHR_animation_pointer's way).
            "pointer_animation.gltf",
            gltf_doc(&uri, bytes, |d| {
                d["extensionsUsed"] = json!(["KHR_animation_pointer"]);
                d["animations"] = json!([{
                    "channels": [{ "sampler": 0, "target": { "path": "pointer",
                        "extensions": { "KHR_animation_pointer": { "pointer": "/nodes/0/scale" } } } }],
                    "samplers": [{ "input": 0, "output": 0 }]
                }]);
            }),
            1,
            3,
            "",
        ),
        ("far.gltf", gltf_doc(&uri, bytes, |d| d["nodes"][0]["translation"] = json!([1e8, 0.0, -1e8])), 1, 3, ""),
    ]
}

/// Runs the command `args` (with `--device cpu`) on `file` in `dir`: its status, its
/// `aorender:` lines on stderr and its statistics.
fn run_on(dir: &std::path::Path, command: &str, file: &str, out: &str) -> (bool, Vec<String>, serde_json::Value) {
    let args = match command {
        "render" => vec!["render", file, "--device", "cpu", "--width", "16", "--height", "16", "--spp", "2", "-o", out],
        _ => vec!["bake", file, "--device", "cpu", "--samples", "4", "-o", out],
    };
    let output = aorender(&[&args[..], &["--stats", "stats.json"]].concat(), dir);
    let stderr = String::from_utf8_lossy(&output.stderr);
    let lines: Vec<String> = stderr.lines().filter(|l| l.starts_with("aorender")).map(String::from).collect();
    let stats = std::fs::read(dir.join("stats.json")).ok().and_then(|b| serde_json::from_slice(&b).ok());
    let _ = std::fs::remove_file(dir.join("stats.json"));
    (output.status.success(), lines, stats.unwrap_or_default())
}

#[test]
fn files_other_importers_read_are_rendered_and_baked() {
    let dir = temp_dir();
    let d = dir.path();
    for (file, bytes, triangles, points, warning) in valid_files() {
        std::fs::write(d.join(file), &bytes).unwrap();
        let (ok, lines, stats) = run_on(d, "render", file, "out.png");
        assert!(ok, "render {file}: {lines:?}");
        assert_eq!(stats["triangles"].as_u64(), Some(triangles), "render {file}: triangles");
        match warning {
            "" => assert!(lines.is_empty(), "render {file}: {lines:?}"),
            w => assert!(lines.len() == 1 && lines[0].contains(file) && lines[0].contains(w), "{file}: {lines:?}"),
        }
        let out = format!("baked_{file}");
        let (ok, lines, stats) = run_on(d, "bake", file, &out);
        assert!(ok, "bake {file}: {lines:?}");
        assert_eq!(stats["points"].as_u64(), Some(points), "bake {file}: points");
        assert!(d.join(&out).is_file(), "bake {file}: no output");
    }
}

#[test]
fn malformed_variants_are_refused_in_one_line_naming_the_file_and_line() {
    let dir = temp_dir();
    let d = dir.path();
    let (uri, bytes) = triangle_data(0);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "index.obj",
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec(),
            "line 4: invalid OBJ: face vertex index out of bounds (9, with 3 vertices)",
        ),
        // Lines are counted as the file has them, continued or not.
        (
            "continued.obj",
            b"v 0 0 0\nv 1 \\\n0 0\nv 0 1 0\nf 1 2 x\n".to_vec(),
            "line 5: invalid OBJ: the face corner 'x' has 'x', not an index",
        ),
        ("latin1_number.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 \xE9\nf 1 2 3\n".to_vec(), "line 3: invalid OBJ: "),
        (
            "short.obj",
            b"# a comment\nv 0 0\n".to_vec(),
            "line 2: invalid OBJ: a vertex position needs 3 numbers, found 2",
        ),
        (
            // Vertices are numbered through the whole file (a face may name one a later
            // object defines): an index past the file's last vertex is named at its line.
            "past.obj",
            b"v 0 0 0\nv 1 0 0\nf 1 2 3\no next\nv 0 1 0\nf 1 2 4\n".to_vec(),
            "line 6: invalid OBJ: face vertex index out of bounds (4, with 3 vertices)",
        ),
        (
            "zero.obj",
            format!("{QUAD}f 1 2 0\n").into_bytes(),
            "line 5: invalid OBJ: face vertex index out of bounds (0: OBJ counts from 1)",
        ),
        (
            "utf16.obj",
            [&[0xFF, 0xFE][..], &"v 0 0 0\n".encode_utf16().flat_map(u16::to_le_bytes).collect::<Vec<u8>>()].concat(),
            "UTF-16 text is not supported: convert the file to UTF-8",
        ),
        ("nul.obj", b"v 0 0 0\nv 1 0\x000\n".to_vec(), "line 2: invalid OBJ: a NUL byte"),
        (
            "geometry_extension.gltf",
            gltf_doc(&uri, bytes, |doc| {
                doc["extensionsRequired"] = json!(["EXT_made_up_geometry"]);
                doc["meshes"][0]["primitives"][0]["extensions"] = json!({ "EXT_made_up_geometry": {} });
            }),
            "requires the glTF extension EXT_made_up_geometry (used by mesh 0 primitive 0), which is not supported",
        ),
        (
            "version_1.gltf",
            serde_json::to_vec(&json!({ "asset": { "version": "1.0" }, "meshes": { "m": { "primitives": [] } } }))
                .unwrap(),
            "glTF 1.0 is not supported",
        ),
        // An empty scene (SceneWithoutNodes.gltf of assimp's tests) is read: it has nothing to render.
        (
            "empty_scene.gltf",
            br#"{"asset": {"version": "2.0"}, "scene": 0, "scenes": [{}]}"#.to_vec(),
            "mesh has no triangles: its scene 0 has no nodes",
        ),
        (
            "bad_base64.gltf",
            gltf_doc("data:application/octet-stream;base64,A!!", 3, |_| ()),
            "buffer 0: invalid base64 data URI",
        ),
    ];
    for (file, bytes, expect) in cases {
        std::fs::write(d.join(file), &bytes).unwrap();
        for command in ["render", "bake"] {
            let out = if command == "render" { "out.png".to_string() } else { format!("baked_{file}") };
            let output = aorender(&[command, file, "--device", "cpu", "-o", &out], d);
            let stderr = String::from_utf8_lossy(&output.stderr);
            assert_eq!(output.status.code(), Some(1), "{command} {file}: {stderr}");
            assert_eq!(stderr.lines().count(), 1, "{command} {file}: {stderr}");
            assert!(
                stderr.starts_with(&format!("aorender: {file}: ")) && stderr.contains(expect),
                "{command} {file}: {stderr}"
            );
        }
    }
}

/// A glTF triangle placed at 10⁸ by its node, probed at points given where they are (at
/// 10⁸): the values of the same triangle at the origin, bit for bit, and the points
/// written back as given.
#[test]
fn a_far_gltf_is_probed_where_its_points_are() {
    let dir = temp_dir();
    let d = dir.path();
    // A floor triangle and a wall triangle over it.
    let positions: Vec<u8> =
        [0.0f32, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, -0.5, 2.0, 0.0, -0.5, 0.0, 1.0, -0.5]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
    let data = base64::engine::general_purpose::STANDARD.encode(&positions);
    let uri = format!("data:application/octet-stream;base64,{data}");
    for (file, t) in [("near.gltf", [0.0, 0.0, 0.0]), ("far.gltf", [1e8, 0.0, -1e8])] {
        let doc = gltf_doc(&uri, positions.len(), |doc| {
            doc["nodes"][0]["translation"] = json!(t);
            doc["accessors"][0]["count"] = json!(6);
            doc["accessors"][0]["min"] = json!([0.0, 0.0, -2.0]);
            doc["accessors"][0]["max"] = json!([2.0, 1.0, 0.0]);
            doc["bufferViews"][0]["byteLength"] = json!(72);
        });
        std::fs::write(d.join(file), doc).unwrap();
        let points: String = [(0.5, -0.25), (1.0, -0.125), (0.25, -1.0)]
            .iter()
            .map(|(x, z)| format!("{} 0 {} 0 1 0\n", x + t[0], z + t[2]))
            .collect();
        std::fs::write(d.join(format!("{file}.txt")), points).unwrap();
    }
    let probe = |file: &str| -> Vec<Vec<String>> {
        let points = format!("{file}.txt");
        let args = ["probe", file, "--points", &points, "--device", "cpu", "--samples", "256", "-o", "-"];
        let output = aorender(&args, d);
        assert!(output.status.success(), "probe {file}: {}", String::from_utf8_lossy(&output.stderr));
        let csv = String::from_utf8(output.stdout).unwrap();
        csv.lines().skip(1).map(|l| l.split(',').map(String::from).collect()).collect()
    };
    let (near, far) = (probe("near.gltf"), probe("far.gltf"));
    assert_eq!(near.len(), 3);
    for (n, f) in near.iter().zip(&far) {
        assert_eq!(n[3..], f[3..], "the values differ: {n:?} against {f:?}");
        let x: f64 = f[0].parse().unwrap();
        let z: f64 = f[2].parse().unwrap();
        assert_eq!((x - 1e8, z + 1e8), (n[0].parse().unwrap(), n[2].parse().unwrap()), "the point as given");
    }
    assert!(near.iter().any(|v| v[6].parse::<f64>().unwrap() < 0.99), "no point is occluded: {near:?}");
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
