//! `aorender bake` into a mesh format other than the input's: the output's extension
//! picks it. Each output is read back by an independent reader (ply-rs-bw, the OBJ text,
//! the glTF JSON and buffer) and its values compared with the same-format bake's, number
//! for number: both come from the same trace.

mod common;

use common::{bake, bake_refused, repo, temp_dir};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use serde_json::Value;
use std::path::Path;

/// What a baked file holds, read independently of the library: positions, faces (as
/// indices into the positions), and per vertex (or per face) AO, standard errors and bent
/// normals where the file has them.
#[derive(Debug, Default)]
struct Read {
    positions: Vec<[f32; 3]>,
    faces: Vec<Vec<u32>>,
    ao: Vec<f32>,
    std_error: Option<Vec<f32>>,
    bent: Option<Vec<[f32; 3]>>,
}

fn bytes(path: &Path) -> Vec<u8> {
    let raw = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    if path.extension().is_some_and(|e| e == "gz") {
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&raw[..]), &mut out).unwrap();
        out
    } else {
        raw
    }
}

fn read_ply(path: &Path, element: &str) -> Read {
    let ply = Parser::<DefaultElement>::new().read_ply(&mut &bytes(path)[..]).unwrap();
    let float = |e: &DefaultElement, name: &str| match e.get(name) {
        Some(Property::Float(v)) => Some(*v),
        None => None,
        other => panic!("{name}: {other:?}"),
    };
    let vertices = &ply.payload["vertex"];
    let rows = &ply.payload[element];
    let column = |name: &str| rows.iter().map(|e| float(e, name)).collect::<Option<Vec<f32>>>();
    let faces = ply.payload["face"]
        .iter()
        .map(|f| match &f["vertex_indices"] {
            Property::ListUInt(v) => v.clone(),
            Property::ListInt(v) => v.iter().map(|&i| i as u32).collect(),
            other => panic!("vertex_indices: {other:?}"),
        })
        .collect();
    let bent = match (column("bnx"), column("bny"), column("bnz")) {
        (Some(x), Some(y), Some(z)) => Some((0..x.len()).map(|i| [x[i], y[i], z[i]]).collect()),
        _ => None,
    };
    Read {
        positions: vertices.iter().map(|v| ["x", "y", "z"].map(|c| float(v, c).unwrap())).collect(),
        faces,
        ao: column("quality").expect("quality"),
        std_error: column("quality_std_error"),
        bent,
    }
}

/// An OBJ as the bake writes it: `v x y z r g b` (AO as the grey), `f` lines.
fn read_obj(path: &Path) -> Read {
    let text = String::from_utf8(bytes(path)).unwrap();
    let mut read = Read::default();
    for line in text.lines() {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.first() {
            Some(&"v") => {
                let f: Vec<f32> = words[1..].iter().map(|w| w.parse().unwrap()).collect();
                assert_eq!(f.len(), 6, "{line}");
                assert!(f[3] == f[4] && f[4] == f[5], "not grey: {line}");
                read.positions.push([f[0], f[1], f[2]]);
                read.ao.push(f[3]);
            }
            Some(&"f") => read
                .faces
                .push(words[1..].iter().map(|w| w.split('/').next().unwrap().parse::<u32>().unwrap() - 1).collect()),
            _ => {}
        }
    }
    read
}

/// The JSON and buffer 0 of a `.glb` or a `.gltf` beside its buffer.
fn gltf_parts(path: &Path) -> (Value, Vec<u8>) {
    let raw = bytes(path);
    match gltf::binary::Glb::from_slice(&raw) {
        Ok(glb) => (serde_json::from_slice(&glb.json).unwrap(), glb.bin.unwrap().into_owned()),
        Err(_) => {
            let doc: Value = serde_json::from_slice(&raw).unwrap();
            let uri = doc["buffers"][0]["uri"].as_str().unwrap().to_string();
            (doc, std::fs::read(path.with_file_name(uri)).unwrap())
        }
    }
}

/// Accessor `a`'s components as f32 (FLOAT, or UNSIGNED_INT indices), tightly packed.
fn accessor(doc: &Value, bin: &[u8], a: &Value) -> Vec<f32> {
    let acc = &doc["accessors"][a.as_u64().unwrap() as usize];
    let view = &doc["bufferViews"][acc["bufferView"].as_u64().unwrap() as usize];
    assert!(view.get("byteStride").is_none(), "packed");
    let width = match acc["type"].as_str().unwrap() {
        "SCALAR" => 1,
        "VEC3" => 3,
        "VEC4" => 4,
        t => panic!("{t}"),
    };
    let start = (view["byteOffset"].as_u64().unwrap_or(0) + acc["byteOffset"].as_u64().unwrap_or(0)) as usize;
    let n = acc["count"].as_u64().unwrap() as usize * width;
    let words = bin[start..start + 4 * n].chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]);
    match acc["componentType"].as_u64().unwrap() {
        5126 => words.map(f32::from_le_bytes).collect(),
        5125 => words.map(|w| u32::from_le_bytes(w) as f32).collect(),
        t => panic!("componentType {t}"),
    }
}

fn triples(v: Vec<f32>) -> Vec<[f32; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

/// A glTF file made by a conversion: its one mesh's primitives in order, their vertices
/// concatenated; COLOR_0 must be the grey of `_AO`.
fn read_converted_gltf(path: &Path) -> Read {
    let (doc, bin) = gltf_parts(path);
    assert_eq!(doc["meshes"].as_array().unwrap().len(), 1);
    let mut read = Read::default();
    let (mut std_error, mut bent) = (Vec::new(), Vec::new());
    for p in doc["meshes"][0]["primitives"].as_array().unwrap() {
        let at = &p["attributes"];
        let first = read.positions.len() as u32;
        read.positions.extend(triples(accessor(&doc, &bin, &at["POSITION"])));
        let ao = accessor(&doc, &bin, &at["_AO"]);
        let color = accessor(&doc, &bin, &at["COLOR_0"]);
        for (a, c) in ao.iter().zip(color.chunks_exact(4)) {
            assert_eq!(c, [a.clamp(0.0, 1.0), a.clamp(0.0, 1.0), a.clamp(0.0, 1.0), 1.0]);
        }
        read.ao.extend(ao);
        if let Some(a) = at.get("_AO_STD_ERROR") {
            std_error.extend(accessor(&doc, &bin, a));
        }
        if let Some(a) = at.get("_BENT_NORMAL") {
            bent.extend(triples(accessor(&doc, &bin, a)));
        }
        let indices = accessor(&doc, &bin, &p["indices"]);
        read.faces.extend(indices.chunks_exact(3).map(|t| t.iter().map(|&i| first + i as u32).collect()));
    }
    read.std_error = (!std_error.is_empty()).then_some(std_error);
    read.bent = (!bent.is_empty()).then_some(bent);
    read
}

/// The `_AO` and `_AO_STD_ERROR` of a same-format glTF bake of `input`, in the order of
/// the meshes the library reads from `input` (each `node N ... primitive P`).
fn read_same_format_gltf(path: &Path, input: &Path) -> Read {
    let (doc, bin) = gltf_parts(path);
    let asset = aorender::bake::read_asset(input).unwrap();
    let mut read = Read { std_error: Some(Vec::new()), ..Read::default() };
    for m in asset.meshes() {
        let words: Vec<&str> = m.label.split_whitespace().collect();
        let after = |w: &str| words[words.iter().position(|x| *x == w).unwrap() + 1].parse::<usize>().unwrap();
        let mesh = doc["nodes"][after("node")]["mesh"].as_u64().unwrap() as usize;
        let at = &doc["meshes"][mesh]["primitives"][after("primitive")]["attributes"];
        read.ao.extend(accessor(&doc, &bin, &at["_AO"]));
        read.std_error.as_mut().unwrap().extend(accessor(&doc, &bin, &at["_AO_STD_ERROR"]));
        // Into the placed space the conversion writes in.
        let from_file = m.to_file.inverse();
        let bent = triples(accessor(&doc, &bin, &at["_BENT_NORMAL"]));
        let placed = bent.iter().map(|b| {
            let d = glam::Vec3::from_array(*b);
            if d == glam::Vec3::ZERO { [0.0; 3] } else { (from_file * d).normalize().to_array() }
        });
        read.bent.get_or_insert_with(Vec::new).extend(placed);
    }
    read
}

fn read_any(path: &Path, element: &str) -> Read {
    let name = path.to_str().unwrap().trim_end_matches(".gz");
    match name.rsplit_once('.').unwrap().1 {
        "ply" => read_ply(path, element),
        "obj" => read_obj(path),
        _ => read_converted_gltf(path),
    }
}

/// The input's meshes as the library reads them for baking, concatenated: positions and
/// faces (fanned into triangles when `triangles`).
fn input_mesh(input: &Path, triangles: bool) -> (Vec<[f32; 3]>, Vec<Vec<u32>>) {
    let asset = aorender::bake::read_asset(input).unwrap();
    let (mut positions, mut faces) = (Vec::new(), Vec::new());
    for m in asset.meshes() {
        let first = positions.len() as u32;
        positions.extend(m.positions.iter().map(|p| p.to_array()));
        for f in 0..m.face_count() {
            let face: Vec<u32> = m.face(f).iter().map(|i| first + i).collect();
            if triangles {
                faces.extend((1..face.len() - 1).map(|k| vec![face[0], face[k], face[k + 1]]));
            } else {
                faces.push(face);
            }
        }
    }
    (positions, faces)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// A box of six quads over a floor of quads, written as an ASCII PLY with normals: polygons
/// the glTF output fans and the PLY and OBJ outputs keep.
fn boxes_ply() -> String {
    let mut v: Vec<[f32; 3]> =
        (0..8).map(|i| [[-0.5, 0.5][i & 1], [0.0, 1.0][(i >> 1) & 1], [-0.5, 0.5][(i >> 2) & 1]]).collect();
    let mut f: Vec<Vec<u32>> = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
        .map(|q| q.to_vec())
        .to_vec();
    let n = 4u32;
    for j in 0..=n {
        for i in 0..=n {
            v.push([-1.2 + 0.6 * i as f32, 0.0, -1.2 + 0.6 * j as f32]);
        }
    }
    for j in 0..n {
        for i in 0..n {
            let k = 8 + j * (n + 1) + i;
            f.push(vec![k, k + n + 1, k + n + 2, k + 1]);
        }
    }
    let mut s = format!("ply\nformat ascii 1.0\nelement vertex {}\n", v.len());
    s += "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\n";
    s += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", f.len());
    for (k, p) in v.iter().enumerate() {
        // The box's corners lean outwards; the floor faces up.
        let n = if k < 8 { [p[0], p[1] - 0.5, p[2]] } else { [0.0, 1.0, 0.0] };
        s += &format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]);
    }
    for face in &f {
        s += &format!("{} {}\n", face.len(), face.iter().map(u32::to_string).collect::<Vec<_>>().join(" "));
    }
    s
}

/// OBJ→PLY, PLY→OBJ, PLY→GLB, OBJ→glTF, GLB→PLY, a gzipped PLY into GLB and OBJ into a
/// gzipped PLY: the output holds the input's positions bit for bit and its faces (fanned
/// into triangles for glTF), and its AO (and standard errors and bent normals, where
/// both files hold them) equals the same-format bake's, number for number. OBJ holds AO
/// only as a colour in [0, 1], so it is compared with the other's clamped.
#[test]
fn a_bake_into_another_format_has_the_same_values_and_mesh() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("boxes.ply"), boxes_ply()).unwrap();
    let scenes = repo().join("scenes");
    let (teapot, engine, dragon) =
        (scenes.join("teapot.obj"), scenes.join("2CylinderEngine.glb"), scenes.join("dragon_vrip_res4.ply.gz"));
    let boxes = d.join("boxes.ply");
    let cases: [(&Path, &str, &str); 8] = [
        (&teapot, "teapot-same.obj", "teapot.ply"),
        (&teapot, "teapot-same.obj", "teapot.gltf"),
        (&teapot, "teapot-same.obj", "teapot.ply.gz"),
        (&boxes, "boxes-same.ply", "boxes.obj"),
        (&boxes, "boxes-same.ply", "boxes.glb"),
        (&engine, "engine-same.glb", "engine.ply"),
        (&dragon, "dragon-same.ply.gz", "dragon.glb"),
        (&dragon, "dragon-same.ply.gz", "dragon.obj"),
    ];
    for (input, same, other) in cases {
        let input_arg = input.to_str().unwrap();
        let common = ["--device", "cpu", "--samples", "8", "--max-distance", "0.5", "--std-error", "--bent-normals"];
        if !d.join(same).exists() {
            bake(d, &[&[input_arg, "-o", same][..], &common].concat());
        }
        let stderr = bake(d, &[&[input_arg, "-o", other, "--colors"][..], &common].concat());
        let asset = aorender::bake::read_asset(input).unwrap();
        let dropped = asset.meshes().iter().any(|m| !m.uv_sets.is_empty() || m.material.is_some());
        let noted = stderr.contains("texture coordinates and materials not written");
        assert_eq!(noted, dropped, "{stderr}");
        let what = format!("{} -> {other}", input.display());
        let got = read_any(&d.join(other), "vertex");
        let want = if same.contains(".glb") {
            read_same_format_gltf(&d.join(same), input)
        } else {
            read_any(&d.join(same), "vertex")
        };

        let gltf = other.contains(".gl");
        let (positions, faces) = input_mesh(input, gltf);
        assert!(got.positions == positions, "{what}: positions differ");
        assert!(got.faces == faces, "{what}: faces differ");
        assert_eq!(got.ao.len(), positions.len(), "{what}");
        let clamp = |v: &[f32]| v.iter().map(|a| a.clamp(0.0, 1.0)).collect::<Vec<_>>();
        let (got_ao, want_ao) = if other.ends_with(".obj") || same.ends_with(".obj") {
            (clamp(&got.ao), clamp(&want.ao))
        } else {
            (got.ao.clone(), want.ao.clone())
        };
        assert_eq!(bits(&got_ao), bits(&want_ao), "{what}: AO differs");
        assert!(got.ao.iter().any(|&a| a < 1.0), "{what}: something is occluded");
        if !other.ends_with(".obj") {
            let (g, w) = (got.std_error.as_ref().unwrap(), want.std_error.as_ref());
            if let Some(w) = w {
                assert_eq!(bits(g), bits(w), "{what}: standard errors differ");
            }
            let bent = got.bent.as_ref().unwrap_or_else(|| panic!("{what}: no bent normals"));
            // Unit length, or zero at a vertex without a usable normal (no point traced).
            let length = |b: &[f32; 3]| (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
            let off = bent.iter().find(|b| (length(b) - 1.0).abs() >= 1e-5 && length(b) != 0.0);
            assert!(off.is_none(), "{what}: a bent normal is not unit length: {off:?}");
            // The same-format bake's, carried through the glTF nodes' transforms.
            let Some(w) = want.bent.as_ref() else { continue };
            let close = bent.iter().zip(w).all(|(a, b)| (0..3).all(|k| (a[k] - b[k]).abs() <= 1e-6));
            assert!(bent.len() == w.len() && close, "{what}: bent normals differ");
            if input != engine.as_path() {
                assert!(bent == w, "{what}: bent normals differ");
            }
        }
    }
}

/// `--at faces` from an OBJ into PLY: one value per face of the OBJ on the face element,
/// the very values a PLY→PLY bake of the same mesh at faces gives.
#[test]
fn faces_bake_into_ply_from_another_format() {
    let dir = temp_dir();
    let d = dir.path();
    let teapot = repo().join("scenes/teapot.obj");
    let common = ["--device", "cpu", "--samples", "8", "--max-distance", "0.5", "--std-error"];
    bake(d, &[&[teapot.to_str().unwrap(), "-o", "mesh.ply"][..], &common].concat());
    bake(d, &[&[teapot.to_str().unwrap(), "-o", "faces.ply", "--at", "faces"][..], &common].concat());
    bake(d, &[&["mesh.ply", "-o", "same.ply", "--at", "faces"][..], &common].concat());
    let (got, want) = (read_ply(&d.join("faces.ply"), "face"), read_ply(&d.join("same.ply"), "face"));
    assert_eq!(got.ao.len(), input_mesh(&teapot, false).1.len());
    assert_eq!(bits(&got.ao), bits(&want.ao));
    assert_eq!(bits(got.std_error.as_ref().unwrap()), bits(want.std_error.as_ref().unwrap()));
    assert!(got.positions == want.positions && got.faces == want.faces);
}

/// An unknown output type, faces into OBJ or glTF, and a texture bake into another
/// format are refused in one line, with nothing written.
#[test]
fn bad_combinations_are_refused_in_one_line_writing_nothing() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("m.ply"), boxes_ply()).unwrap();
    std::fs::copy(repo().join("scenes/teapot.obj"), d.join("t.obj")).unwrap();
    for (args, expect) in [
        (&["m.ply", "-o", "m.stl"][..], "cannot bake into '.stl' files: expected .ply, .obj, .gltf or .glb"),
        (&["m.ply", "-o", "m.stl.gz"][..], "cannot bake into '.stl' files"),
        (&["m.ply", "-o", "out"][..], "cannot bake into a file without an extension"),
        (&["m.ply", "-o", "out.obj", "--at", "faces"][..], "OBJ has no per-face attributes"),
        (&["t.obj", "-o", "out.glb", "--at", "faces"][..], "glTF has no per-face attributes"),
        (&["t.obj", "-o", "out.ply", "--texture", "16"][..], "the output must be a OBJ file like the input"),
    ] {
        let line = bake_refused(args, d, expect);
        assert!(line.contains(args[2]) || line.contains(args[0]), "{line}");
    }
    let mut left: Vec<_> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["m.ply", "t.obj"]);
}
