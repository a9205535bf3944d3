//! `aorender bake --texture` end to end, on the CPU reference and the adapter: a floor
//! under a sphere matches the closed form per texel within 4 standard errors, a convex
//! closed mesh bakes to exactly 1 in every covered texel, a UV sphere's map has no seam,
//! a GLB's materials reference the new texture (read back and validated by the `gltf`
//! crate), and bad input is refused in one line before any work, with nothing written.

mod common;
use common::*;
use glam::{DVec2, DVec3};
use std::path::Path;

/// The devices to bake on: the CPU reference, and the adapter when there is one.
fn devices() -> Vec<&'static str> {
    let mut d = vec!["cpu"];
    if gpu_available() {
        d.push("gpu");
    }
    d
}

/// One vertex of a test mesh: position, normal, texture coordinates (v up, OBJ's and
/// PLY's convention).
#[derive(Clone, Copy)]
struct Vertex {
    p: DVec3,
    n: DVec3,
    uv: DVec2,
}

/// An ASCII PLY of `vertices` (with normals and `s t`) and `faces`.
fn ply(vertices: &[Vertex], faces: &[Vec<u32>]) -> String {
    let mut s = format!("ply\nformat ascii 1.0\nelement vertex {}\n", vertices.len());
    for name in ["x", "y", "z", "nx", "ny", "nz", "s", "t"] {
        s += &format!("property float {name}\n");
    }
    s += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", faces.len());
    for v in vertices {
        let (p, n, uv) = (v.p.as_vec3(), v.n.as_vec3(), v.uv.as_vec2());
        s += &format!("{} {} {} {} {} {} {} {}\n", p.x, p.y, p.z, n.x, n.y, n.z, uv.x, uv.y);
    }
    for f in faces {
        s += &format!("{}", f.len());
        for i in f {
            s += &format!(" {i}");
        }
        s += "\n";
    }
    s
}

/// An n × n grid on y = 0 over [-half, half]² facing +y, its UVs (x, z) mapped onto `uv`
/// (lower corner and size).
fn floor(n: u32, half: f64, uv: (DVec2, f64)) -> (Vec<Vertex>, Vec<Vec<u32>>) {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (s, t) = (i as f64 / n as f64, j as f64 / n as f64);
            let p = DVec3::new(-half + 2.0 * half * s, 0.0, -half + 2.0 * half * t);
            v.push(Vertex { p, n: DVec3::Y, uv: uv.0 + uv.1 * DVec2::new(s, t) });
        }
    }
    (v, grid_quads(n))
}

/// A UV sphere (latitude-longitude, the seam at u = 0 and 1 with its vertices doubled)
/// of radius `r` about `c`, with its exact normals.
fn uv_sphere(c: DVec3, r: f64, nu: u32, nv: u32) -> (Vec<Vertex>, Vec<Vec<u32>>) {
    let mut v = Vec::new();
    for j in 0..=nv {
        let theta = std::f64::consts::PI * j as f64 / nv as f64;
        for i in 0..=nu {
            let phi = std::f64::consts::TAU * i as f64 / nu as f64;
            let n = DVec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
            v.push(Vertex { p: c + r * n, n, uv: DVec2::new(i as f64 / nu as f64, 1.0 - j as f64 / nv as f64) });
        }
    }
    let mut f = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            let a = j * (nu + 1) + i;
            f.push(vec![a, a + 1, a + nu + 2, a + nu + 1]);
        }
    }
    (v, f)
}

/// A cube of side 2 about `c` with a normal per face and each face in its own cell of a
/// 3 × 2 grid of UV cells, with gaps between them.
fn cube(c: DVec3) -> (Vec<Vertex>, Vec<Vec<u32>>) {
    let (mut v, mut f) = (Vec::new(), Vec::new());
    for (k, n) in [DVec3::X, -DVec3::X, DVec3::Y, -DVec3::Y, DVec3::Z, -DVec3::Z].into_iter().enumerate() {
        let a = n.any_orthonormal_vector();
        let b = n.cross(a);
        let cell = DVec2::new((k % 3) as f64 / 3.0, (k / 3) as f64 / 2.0) + DVec2::splat(0.05);
        let base = v.len() as u32;
        for (s, t) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            let p = c + n + (2.0 * s - 1.0) * a + (2.0 * t - 1.0) * b;
            v.push(Vertex { p, n, uv: cell + DVec2::new(s * 0.23, t * 0.4) });
        }
        f.push(vec![base, base + 1, base + 2, base + 3]);
    }
    (v, f)
}

/// A scene file of the mesh `file` and `more` (other objects' TOML).
fn scene(file: &str, more: &str) -> String {
    format!(
        "[camera]\ntype = \"perspective\"\neye = [0, 5, 5]\nlook_at = [0, 0, 0]\nfov = 45\n\n\
         [[object]]\ntype = \"mesh\"\nfile = \"{file}\"\n\n{more}"
    )
}

/// An EXR map's texels: (AO, standard error, covered), row-major from the top.
fn read_exr(path: &Path) -> (u32, u32, Vec<(f32, f32, bool)>) {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgba32f();
    let texels = img.pixels().map(|p| (p.0[0], p.0[1], p.0[2] == 1.0)).collect();
    (img.width(), img.height(), texels)
}

/// A floor under a sphere: cosine-weighted AO at a floor point whose normal makes the
/// angle β with the direction to the centre at distance d is 1 − cos β (r/d)². Baked
/// with one point a texel (its centre), every texel matches it at its centre within 4
/// of its standard errors, and the texels' deviations average to zero within 4 of
/// their standard errors.
#[test]
fn a_floor_under_a_sphere_matches_the_closed_form_in_every_texel() {
    let dir = temp_dir();
    let d = dir.path();
    let half = 3.0;
    let (v, f) = floor(12, half, (DVec2::ZERO, 1.0));
    std::fs::write(d.join("floor.ply"), ply(&v, &f)).unwrap();
    let (centre, r) = (DVec3::new(0.25, 1.5, -0.5), 1.0);
    let sphere =
        format!("[[object]]\ntype = \"sphere\"\ncenter = [{}, {}, {}]\nradius = {r}\n", centre.x, centre.y, centre.z);
    std::fs::write(d.join("scene.toml"), scene("floor.ply", &sphere)).unwrap();
    let closed_form = |p: DVec3| {
        let to = centre - p;
        1.0 - to.y / to.length() * (r / to.length()).powi(2)
    };
    let size = 16;
    for device in devices() {
        let out = format!("{device}.exr");
        let args =
            ["scene.toml", "-o", &out, "--texture", "16", "--texel-points", "1", "--samples", "4096", "--seed", "3"];
        bake(d, &[&args[..], &["--device", device]].concat());
        let (w, h, texels) = read_exr(&d.join(&out));
        assert_eq!((w, h), (size, size));
        let (mut worst, mut sum_z) = (0.0f64, 0.0);
        for (i, &(ao, se, covered)) in texels.iter().enumerate() {
            assert!(covered, "{device}: texel {i} is not covered: the floor's UVs fill the texture");
            let (x, y) = ((i as u32 % size) as f64, (i as u32 / size) as f64);
            let (s, t) = ((x + 0.5) / size as f64, 1.0 - (y + 0.5) / size as f64);
            let expected = closed_form(DVec3::new(-half + 2.0 * half * s, 0.0, -half + 2.0 * half * t));
            let z = (ao as f64 - expected) / (se as f64).max(1e-12);
            worst = worst.max(z.abs());
            sum_z += z;
            assert!(z.abs() < 4.0, "{device}: texel ({x}, {y}): {ao} ± {se} against {expected}");
        }
        let n = texels.len() as f64;
        assert!((sum_z / n).abs() < 4.0 / n.sqrt(), "{device}: the mean deviation is {} standard errors", sum_z / n);
        eprintln!("{device}: largest deviation {worst:.2} standard errors over {n} texels, mean {:.3}", sum_z / n);
    }
}

/// Nothing outside a convex body occludes it: every covered texel of a cube whose faces
/// have their own normals bakes to exactly 1 with cosine-weighted sampling, the
/// chart-edge texels included (their points are moved onto the chart).
#[test]
fn a_convex_closed_mesh_bakes_to_one_in_every_covered_texel() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = cube(DVec3::new(0.3, -0.2, 1.5));
    std::fs::write(d.join("cube.ply"), ply(&v, &f)).unwrap();
    for device in devices() {
        let out = format!("{device}.exr");
        bake(
            d,
            &["cube.ply", "-o", &out, "--texture", "96x64", "--device", device, "--samples", "32", "--padding", "2"],
        );
        let (_, _, texels) = read_exr(&d.join(&out));
        let covered: Vec<_> = texels.iter().filter(|t| t.2).collect();
        assert!(covered.len() > 6 * 20 * 25, "{device}: {} covered texels", covered.len());
        assert!(covered.iter().all(|t| t.0 == 1.0 && t.1 == 0.0), "{device}: a covered texel below 1");
        assert!(texels.len() > covered.len(), "the cells leave gaps");
    }
}

/// A UV sphere above a floor plane: its AO depends on the latitude alone, so the texels
/// on the two sides of the seam (the first and the last column) agree within their noise
/// (4 standard errors of the difference) in every row.
#[test]
fn a_uv_spheres_map_has_no_seam() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = uv_sphere(DVec3::new(0.0, 1.5, 0.0), 1.0, 48, 24);
    std::fs::write(d.join("sphere.ply"), ply(&v, &f)).unwrap();
    let plane = "[[object]]\ntype = \"plane\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n";
    std::fs::write(d.join("scene.toml"), scene("sphere.ply", plane)).unwrap();
    for device in devices() {
        let out = format!("{device}.exr");
        bake(d, &["scene.toml", "-o", &out, "--texture", "96x48", "--device", device, "--samples", "64"]);
        let (w, h, texels) = read_exr(&d.join(&out));
        let mut darkest = 1.0f32;
        for y in 0..h as usize {
            let (a, b) = (texels[y * w as usize], texels[y * w as usize + w as usize - 1]);
            assert!(a.2 && b.2, "{device}: row {y}: the seam's texels are covered");
            darkest = darkest.min(a.0);
            let sigma = (a.1 as f64).hypot(b.1 as f64);
            assert!(((a.0 - b.0) as f64).abs() < 4.0 * sigma.max(1e-12), "{device}: row {y}: {a:?} against {b:?}");
        }
        assert!(darkest < 0.3, "{device}: the floor occludes the sphere's underside ({darkest})");
    }
}

/// A glTF of a UV-mapped floor quad with a material (and extras) and a UV-mapped cube
/// above it without one, in a `data:` URI buffer; the floor's u scaled by `uv_scale`, its
/// material given a base colour texture (whose sampler repeats) when `textured`.
fn gltf_fixture(uv_scale: f32, textured: bool) -> serde_json::Value {
    use base64::Engine;
    let (fv, _) = floor(1, 2.0, (DVec2::ZERO, 1.0));
    let (cv, _) = cube(DVec3::new(0.0, 1.5, 0.0));
    let mut bytes = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut push = |data: Vec<f32>, kind: &str, count: usize, component: u32| {
        let offset = bytes.len();
        bytes.extend(data.iter().flat_map(|x| x.to_le_bytes()));
        views.push(serde_json::json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len() - offset}));
        let mut a = serde_json::json!({"bufferView": views.len() - 1, "componentType": component, "count": count, "type": kind});
        if kind == "VEC3" {
            let p: Vec<[f32; 3]> = data.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
            let lo = p.iter().fold([f32::MAX; 3], |m, q| [m[0].min(q[0]), m[1].min(q[1]), m[2].min(q[2])]);
            let hi = p.iter().fold([f32::MIN; 3], |m, q| [m[0].max(q[0]), m[1].max(q[1]), m[2].max(q[2])]);
            a["min"] = serde_json::json!(lo);
            a["max"] = serde_json::json!(hi);
        }
        accessors.push(a);
        accessors.len() - 1
    };
    let mut prims = Vec::new();
    // glTF's v runs down the image: flip the test meshes' v.
    let floor_faces = vec![[0u32, 2, 3], [0, 3, 1]];
    let cube_faces = (0..6).flat_map(|k| [[4 * k, 4 * k + 1, 4 * k + 2], [4 * k, 4 * k + 2, 4 * k + 3]]).collect();
    for (vs, faces, uv_scale) in [(fv, floor_faces, uv_scale), (cv, cube_faces, 1.0)] {
        let pos = push(vs.iter().flat_map(|v| v.p.as_vec3().to_array()).collect(), "VEC3", vs.len(), 5126);
        let nor = push(vs.iter().flat_map(|v| v.n.as_vec3().to_array()).collect(), "VEC3", vs.len(), 5126);
        let uv = push(
            vs.iter().flat_map(|v| [v.uv.x as f32 * uv_scale, 1.0 - v.uv.y as f32]).collect(),
            "VEC2",
            vs.len(),
            5126,
        );
        let idx = push(faces.iter().flatten().map(|&i| f32::from_bits(i)).collect(), "SCALAR", faces.len() * 3, 5125);
        prims.push(
            serde_json::json!({"attributes": {"POSITION": pos, "NORMAL": nor, "TEXCOORD_0": uv}, "indices": idx}),
        );
    }
    prims[0]["material"] = 0.into();
    let uri =
        format!("data:application/octet-stream;base64,{}", base64::engine::general_purpose::STANDARD.encode(&bytes));
    let mut doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "floor", "mesh": 0}, {"name": "cube", "mesh": 1}],
        "meshes": [{"primitives": [prims[0]]}, {"primitives": [prims[1]]}],
        "materials": [{"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0]}, "extras": {"kept": true}}],
        "buffers": [{"uri": uri, "byteLength": bytes.len()}],
        "bufferViews": views,
        "accessors": accessors
    });
    if textured {
        doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = serde_json::json!({"index": 0});
        doc["textures"] = serde_json::json!([{"source": 0, "sampler": 0}]);
        doc["samplers"] = serde_json::json!([{"magFilter": 9729}]);
        doc["images"] = serde_json::json!([{"uri": "colour.png"}]);
    }
    doc
}

/// The output GLB validates with the `gltf` crate; each material (the floor's, and the one
/// made for the cube) references a new texture on TEXCOORD_0 whose PNG decodes to the
/// requested size and depth; the rest of the file is kept. A `.gltf` output gets its PNGs
/// beside it.
#[test]
fn a_glb_references_the_baked_texture_from_its_materials() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("model.gltf"), serde_json::to_vec(&gltf_fixture(1.0, false)).unwrap()).unwrap();
    for device in devices() {
        let out = format!("{device}.glb");
        let args = [
            "model.gltf",
            "-o",
            &out,
            "--texture",
            "64x32",
            "--bit-depth",
            "16",
            "--device",
            device,
            "--samples",
            "16",
        ];
        bake(d, &args);
        let bytes = std::fs::read(d.join(&out)).unwrap();
        let gltf = ::gltf::Gltf::from_slice(&bytes).unwrap_or_else(|e| panic!("{device}: {e}"));
        let bin = gltf.blob.clone().expect("a binary chunk");
        let materials: Vec<_> = gltf.materials().collect();
        assert_eq!(materials.len(), 2, "{device}: the cube got a material");
        assert_eq!(materials[0].name(), Some("paint"));
        assert!(materials[0].extras().as_ref().is_some_and(|e| e.get().contains("kept")));
        for mesh in gltf.meshes() {
            let material = mesh.primitives().next().unwrap().material();
            let occlusion = material.occlusion_texture().expect("an occlusion texture");
            assert_eq!(occlusion.tex_coord(), 0);
            let ::gltf::image::Source::View { view, mime_type } = occlusion.texture().source().source() else {
                panic!("{device}: the image is not in the binary chunk");
            };
            assert_eq!(mime_type, "image/png");
            let png = &bin[view.offset()..view.offset() + view.length()];
            let img = image::load_from_memory(png).unwrap();
            assert_eq!((img.width(), img.height(), img.color()), (64, 32, image::ColorType::L16));
        }
    }
    // The floor's u runs to 1.5 and its material's texture repeats: the bake follows.
    std::fs::write(d.join("wrapped.gltf"), serde_json::to_vec(&gltf_fixture(1.5, true)).unwrap()).unwrap();
    bake(d, &["wrapped.gltf", "-o", "wrapped.glb", "--texture", "32", "--device", "cpu", "--samples", "4"]);
    let gltf = ::gltf::Gltf::from_slice(&std::fs::read(d.join("wrapped.glb")).unwrap()).unwrap();
    let floor = gltf.materials().next().unwrap().occlusion_texture().unwrap().texture();
    assert_eq!(floor.sampler().wrap_s(), ::gltf::texture::WrappingMode::Repeat);
    assert!(floor.source().index() > 0, "a new image beside the colour texture");
    bake(d, &["model.gltf", "-o", "out.gltf", "--texture", "32", "--device", "cpu", "--samples", "4"]);
    let doc: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("out.gltf")).unwrap()).unwrap();
    let images = doc["images"].as_array().unwrap();
    assert_eq!(images.len(), 2);
    for image in images {
        let img = image::open(d.join(image["uri"].as_str().unwrap())).unwrap();
        assert_eq!((img.width(), img.height(), img.color()), (32, 32, image::ColorType::L8));
    }
}

/// Bad input gets one line on stderr, exit status 1, before any work, and nothing written.
#[test]
fn bad_input_is_refused_in_one_line_with_nothing_written() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(2, 1.0, (DVec2::ZERO, 1.0));
    std::fs::write(d.join("floor.ply"), ply(&v, &f)).unwrap();
    let (v, f) = floor(2, 1.0, (DVec2::new(0.5, 0.0), 1.0));
    std::fs::write(d.join("wide.ply"), ply(&v, &f)).unwrap();
    std::fs::write(d.join("wide.gltf"), serde_json::to_vec(&gltf_fixture(1.5, false)).unwrap()).unwrap();
    std::fs::copy(repo().join("scenes/bunny.obj"), d.join("bunny.obj")).unwrap();
    for (args, expect) in [
        (&["bunny.obj", "-o", "b.png", "--texture", "256", "--generate-uvs", "never"][..], "of set 0 (it has none)"),
        (&["floor.ply", "-o", "f.png", "--texture", "64", "--uv-set", "1"][..], "of set 1 (it has set 0)"),
        (&["wide.ply", "-o", "f.png", "--texture", "64"][..], "outside [0, 1]"),
        (&["wide.gltf", "-o", "f.glb", "--texture", "64"][..], "outside [0, 1]"),
        (&["floor.ply", "-o", "f.png", "--texture", "16384", "--texel-points", "256"][..], "GiB"),
        (&["floor.ply", "-o", "f.png", "--texture", "0"][..], "1 to 16384 texels"),
        (&["floor.ply", "-o", "f.png", "--texture", "100000"][..], "1 to 16384 texels"),
        (&["floor.ply", "-o", "f.png", "--texture", "big"][..], "expected a size in texels"),
        (&["floor.ply", "-o", "f.png", "--texture", "64", "--texel-points", "0"][..], "points per texel"),
        (&["floor.ply", "-o", "f.png"][..], "--texture SIZE"),
        (&["floor.ply", "-o", "f.png", "--texture", "64", "--at", "faces"][..], "--at faces"),
    ] {
        bake_refused(args, d, expect);
    }
    // A bit depth other than 8 or 16 is clap's to refuse (status 2).
    let out = aorender(&["bake", "floor.ply", "-o", "f.png", "--texture", "8", "--bit-depth", "12"], d);
    assert_eq!(out.status.code(), Some(2));
    let mut left: Vec<_> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["bunny.obj", "floor.ply", "wide.gltf", "wide.ply"]);
}

/// A texture bake stopped and resumed, and one traced as two sample-range shards and
/// merged, write the uninterrupted bake's map bit for bit (bent normals too: four film
/// slots a point).
#[test]
fn resumed_and_merged_texture_bakes_are_bit_identical() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = uv_sphere(DVec3::new(0.0, 1.5, 0.0), 1.0, 24, 12);
    std::fs::write(d.join("sphere.ply"), ply(&v, &f)).unwrap();
    let plane = "[[object]]\ntype = \"plane\"\npoint = [0, 0, 0]\nnormal = [0, 1, 0]\n";
    std::fs::write(d.join("scene.toml"), scene("sphere.ply", plane)).unwrap();
    for device in devices() {
        let common = ["--device", device, "--texture", "48x24", "--bent-normals"];
        let [full, resumed, merged] = bake_whole_resumed_and_merged(d, "scene.toml", "exr", device, 64, &common);
        for other in [&resumed, &merged] {
            for suffix in [".exr", "_bent_normals.png"] {
                let name = |n: &str| n.replace(".exr", suffix);
                assert_eq!(
                    std::fs::read(d.join(name(other))).unwrap(),
                    std::fs::read(d.join(name(&full))).unwrap(),
                    "{device}: {other} {suffix}"
                );
            }
        }
    }
}
