//! A bake parses each input once: the scene it traces and the file it writes back come
//! from one read of every mesh file (PLY in each encoding and gzipped, OBJ plain and
//! gzipped, glTF with an external buffer, GLB, and a scene file placing meshes twice and
//! far from the origin), and what it writes is byte for byte what a bake that reads its
//! inputs twice writes.

use aorender::bake::{Bake, BakeRequest, ReadInputs, load_for_bake};
use aorender::output::FilePlan;
use aorender::scene::times_opened;
use aorender::{BvhOptions, Control, Device, DeviceKind, LoadOptions, Scene, Session};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A closed box (corners 0 and `size`) as 8 vertices and 6 quads, counter-clockwise
/// seen from outside, indices from 0.
const QUADS: [[u32; 4]; 6] = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];

fn corners(size: f32) -> Vec<[f32; 3]> {
    (0..8).map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32].map(|c| c * size)).collect()
}

/// The box as an ASCII PLY.
fn ply_ascii(size: f32) -> Vec<u8> {
    let mut s = "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n\
        element face 6\nproperty list uchar int vertex_indices\nend_header\n"
        .to_string();
    for p in corners(size) {
        s += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for q in QUADS {
        s += &format!("4 {} {} {} {}\n", q[0], q[1], q[2], q[3]);
    }
    s.into_bytes()
}

/// The box as a binary little-endian PLY.
fn ply_binary(size: f32) -> Vec<u8> {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty float x\nproperty float y\n\
        property float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n"
        .to_vec();
    for p in corners(size) {
        p.iter().for_each(|c| b.extend(c.to_le_bytes()));
    }
    for q in QUADS {
        b.push(4);
        q.iter().for_each(|i| b.extend(i.to_le_bytes()));
    }
    b
}

/// The box as an OBJ, one face with relative indices.
fn obj(size: f32) -> Vec<u8> {
    let mut s = String::from("# a box\n");
    for p in corners(size) {
        s += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for q in &QUADS[..5] {
        s += &format!("f {} {} {} {}\n", q[0] + 1, q[1] + 1, q[2] + 1, q[3] + 1);
    }
    s += "f -7 -5 -1 -3\n";
    s.into_bytes()
}

/// The box as glTF triangles: the JSON, whose one buffer is the file `bin`, and the
/// buffer's bytes.
fn gltf(bin: &str) -> (Vec<u8>, Vec<u8>) {
    let mut data = Vec::new();
    corners(1.0).iter().flatten().for_each(|c| data.extend(c.to_le_bytes()));
    for q in QUADS {
        [q[0], q[1], q[2], q[0], q[2], q[3]].iter().for_each(|&i| data.extend((i as u16).to_le_bytes()));
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"mesh": 0, "translation": [3.0, 0.0, 0.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"uri": bin, "byteLength": data.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 96},
            {"buffer": 0, "byteOffset": 96, "byteLength": 72}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]},
            {"bufferView": 1, "componentType": 5123, "count": 36, "type": "SCALAR"}
        ]
    });
    (serde_json::to_vec(&json).unwrap(), data)
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Bakes `input` into `output` on the CPU, 8 samples a vertex: with the scene and the
/// files read once (`read_once`), or the scene loaded and then each file read again for
/// the bake. Returns every file written in `output`'s folder, and how many times each of `meshes` was opened
/// from the load to the write (the output policy's listing of a glTF file's buffers,
/// before any work, reads its JSON and is not counted).
fn bake(input: &Path, output: &Path, meshes: &[PathBuf], read_once: bool) -> (Vec<(PathBuf, Vec<u8>)>, Vec<usize>) {
    let mut files = FilePlan::new();
    files.scene(input);
    let before: Vec<usize> = meshes.iter().map(|m| times_opened(m)).collect();
    let options = LoadOptions::from_env().unwrap();
    let (scene, read) = if read_once {
        load_for_bake(input, &options).unwrap()
    } else {
        (Scene::load_with(input, &options).unwrap(), ReadInputs::default())
    };
    let request = BakeRequest { output: Some(output.to_path_buf()), ..BakeRequest::new(8) };
    let bake = Bake::with_inputs(&scene, &read, input, &request, &mut files).unwrap();
    drop(read);
    let session = Session::new(&Device::open(DeviceKind::Cpu, None).unwrap(), scene, &BvhOptions::default()).unwrap();
    let baked = bake.finish(session.bake(&bake, None, &mut Control::default()).unwrap()).unwrap();
    bake.write(&baked, 8).unwrap();
    let opened = meshes.iter().zip(before).map(|(m, b)| times_opened(m) - b).collect();
    (written(output.parent().unwrap()), opened)
}

/// Every file under `dir`, by path relative to it, with its bytes.
fn written(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            let name = PathBuf::from(path.file_name().unwrap());
            files.extend(written(&path).into_iter().map(|(p, b)| (name.join(p), b)));
        } else {
            files.push((PathBuf::from(path.file_name().unwrap()), std::fs::read(&path).unwrap()));
        }
    }
    files.sort();
    files
}

/// Bakes `input` both ways into folders of `dir`, checking that the read-once bake opened
/// each of `meshes` once (and the other `reads` times: its scene's reads and its own) and
/// that both wrote the same files.
fn check(dir: &Path, input: &Path, meshes: &[PathBuf], output: &str, reads: usize) {
    let out = |side: &str| {
        let folder = dir.join(format!("{side}-{}", input.file_name().unwrap().to_string_lossy()));
        std::fs::create_dir(&folder).unwrap();
        folder.join(output)
    };
    let (once, opened_once) = bake(input, &out("once"), meshes, true);
    let (twice, opened_twice) = bake(input, &out("twice"), meshes, false);
    for (k, mesh) in meshes.iter().enumerate() {
        assert_eq!(opened_once[k], 1, "{} opened by the bake of {}", mesh.display(), input.display());
        assert_eq!(opened_twice[k], reads, "{} opened by the bake that reads again", mesh.display());
    }
    assert!(!once.is_empty());
    assert!(once == twice, "{}: the bakes differ", input.display());
}

#[test]
fn a_bake_of_each_mesh_format_opens_its_input_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let write = |name: &str, bytes: &[u8]| {
        let path = d.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let cases = [
        (write("ascii.ply", &ply_ascii(1.0)), "ascii.ply"),
        (write("binary.ply", &ply_binary(1.0)), "binary.ply"),
        (write("box.ply.gz", &gzip(&ply_ascii(1.0))), "box.ply.gz"),
        (write("box.obj", &obj(1.0)), "box.obj"),
        (write("box.obj.gz", &gzip(&obj(1.0))), "gzipped.obj"),
        (repo().join("scenes/teapot.obj"), "teapot.obj"),
        (repo().join("scenes/2CylinderEngine.glb"), "engine.glb"),
    ];
    for (input, output) in cases {
        let copy = d.join(format!("in-{}", input.file_name().unwrap().to_string_lossy()));
        std::fs::copy(&input, &copy).unwrap();
        check(d, &copy, std::slice::from_ref(&copy), output, 2);
    }
    // A glTF file and its buffer: each opened once.
    let (json, data) = gltf("box data.bin");
    let input = write("box.gltf", &json);
    let bin = write("box data.bin", &data);
    check(d, &input, &[input.clone(), bin], "box.gltf", 2);
}

#[test]
fn a_bake_of_a_scene_file_opens_each_mesh_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ply = d.join("box.ply");
    std::fs::write(&ply, ply_binary(0.5)).unwrap();
    let obj_path = d.join("box.obj");
    std::fs::write(&obj_path, obj(0.25)).unwrap();
    let (json, data) = gltf("box.bin");
    let gltf_path = d.join("box.gltf");
    std::fs::write(&gltf_path, json).unwrap();
    std::fs::write(d.join("box.bin"), data).unwrap();
    // The PLY placed twice (instanced), the OBJ and the glTF once; then, far from the
    // origin, the scene is placed a second time about its own origin from what was read.
    let objects = |x: f64| {
        let mut text = "[camera]\ntype = \"perspective\"\neye = [0.0, 1.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\n\
            up = [0.0, 1.0, 0.0]\nfov = 45.0\n"
            .to_string();
        for (file, at) in
            [("box.ply", [0.0, 0.0]), ("box.ply", [1.0, 0.0]), ("box.obj", [0.0, 1.0]), ("box.gltf", [0.0, 2.0])]
        {
            text += &format!(
                "\n[[object]]\ntype = \"mesh\"\nfile = \"{file}\"\ntransform = {{ translate = [{:?}, {:?}, 0.0] }}\n",
                x + at[0],
                at[1]
            );
        }
        text
    };
    let near = d.join("near.toml");
    std::fs::write(&near, objects(0.0)).unwrap();
    check(d, &near, &[ply.clone(), obj_path.clone(), gltf_path.clone()], "near", 2);
    let far = d.join("far.toml");
    std::fs::write(&far, objects(1.0e6)).unwrap();
    let scene = Scene::load(&far).unwrap();
    assert_ne!(scene.origin, glam::DVec3::ZERO, "the scene is placed about its own origin");
    // Its loader reads each mesh for both placements, and the bake once more.
    check(d, &far, &[ply, obj_path, gltf_path], "far", 3);
}
