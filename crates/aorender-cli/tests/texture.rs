//! `aorender bake --texture` end to end, on the CPU reference and the adapter: a floor
//! under a sphere matches the closed form per texel within 4 standard errors, a convex
//! closed mesh bakes to exactly 1 in every covered texel, a UV sphere's map has no seam,
//! a GLB's materials reference the new texture (read back and validated by the `gltf`
//! crate), and bad input is refused in one line before any work, with nothing written.

mod common;
use aorender::bake::MAX_TEXTURE_SIZE;
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
    let largest = MAX_TEXTURE_SIZE.to_string();
    let sizes = format!("1 to {MAX_TEXTURE_SIZE} texels");
    for (args, expect) in [
        (&["bunny.obj", "-o", "b.png", "--texture", "256", "--generate-uvs", "never"][..], "of set 0 (it has none)"),
        (&["floor.ply", "-o", "f.png", "--texture", "64", "--uv-set", "1"][..], "of set 1 (it has set 0)"),
        (&["wide.ply", "-o", "f.png", "--texture", "64"][..], "outside [0, 1]"),
        (&["wide.gltf", "-o", "f.glb", "--texture", "64"][..], "outside [0, 1]"),
        (&["floor.ply", "-o", "f.png", "--texture", largest.as_str(), "--texel-points", "256"][..], "GiB"),
        (&["floor.ply", "-o", "f.png", "--texture", "0"][..], sizes.as_str()),
        (&["floor.ply", "-o", "f.png", "--texture", "100000"][..], sizes.as_str()),
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

/// The JSON and the binary chunk of a GLB.
fn glb_parts(path: &Path) -> (serde_json::Value, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let glb = ::gltf::binary::Glb::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    (serde_json::from_slice(&glb.json).unwrap(), glb.bin.map(|b| b.into_owned()).unwrap_or_default())
}

/// A `.gltf` or `.glb` read by the `gltf` crate (which validates it), with its buffers.
fn read_gltf(path: &Path) -> (::gltf::Gltf, Vec<Vec<u8>>) {
    let gltf =
        ::gltf::Gltf::from_slice(&std::fs::read(path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let buffers = gltf
        .buffers()
        .map(|b| match b.source() {
            ::gltf::buffer::Source::Bin => gltf.blob.clone().expect("a binary chunk"),
            ::gltf::buffer::Source::Uri(uri) => std::fs::read(path.with_file_name(uri)).unwrap(),
        })
        .collect();
    (gltf, buffers)
}

/// A 4 × 4 RGB PNG.
fn png() -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    image::RgbImage::from_pixel(4, 4, image::Rgb([200, 100, 50])).write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// A GLB output holds everything: a `.gltf` whose buffer is a `data:` URI or a file
/// beside it, with an image beside it and one in a `data:` URI, baked into a GLB (per
/// vertex and into a texture) gives a GLB without a URI that, moved alone into another
/// directory, passes the Khronos validator with no error or warning, loads, and renders
/// as the input does.
#[test]
fn glb_outputs_are_self_contained() {
    use base64::Engine;
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("colour.png"), png()).unwrap();
    let mut embedded = gltf_fixture(1.0, true);
    let data = format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(png()));
    embedded["images"].as_array_mut().unwrap().push(serde_json::json!({"uri": data}));
    embedded["textures"].as_array_mut().unwrap().push(serde_json::json!({"source": 1}));
    embedded["materials"][0]["emissiveTexture"] = serde_json::json!({"index": 1});
    std::fs::write(d.join("embedded.gltf"), serde_json::to_vec(&embedded).unwrap()).unwrap();
    let mut external = embedded.clone();
    let uri = external["buffers"][0]["uri"].as_str().unwrap().to_string();
    let bytes = base64::engine::general_purpose::STANDARD.decode(uri.split_once(',').unwrap().1).unwrap();
    std::fs::write(d.join("geometry data.bin"), bytes).unwrap();
    external["buffers"][0]["uri"] = "geometry%20data.bin".into();
    std::fs::write(d.join("external.gltf"), serde_json::to_vec(&external).unwrap()).unwrap();
    std::fs::create_dir(d.join("alone")).unwrap();
    for input in ["embedded.gltf", "external.gltf"] {
        for texture in [false, true] {
            let out = format!("{}-{}.glb", input.trim_end_matches(".gltf"), if texture { "map" } else { "ao" });
            let mut args = vec![input, "-o", &out, "--device", "cpu", "--samples", "4"];
            if texture {
                args.extend(["--texture", "16", "--bent-normals"]);
            }
            bake(d, &args);
            let (json, bin) = glb_parts(&d.join(&out));
            assert_eq!(json["buffers"].as_array().unwrap().len(), 1, "{out}");
            assert!(!serde_json::to_string(&json).unwrap().contains("\"uri\""), "{out}: {json}");
            // The two input images, as they were, and two materials' AO and bent normal maps.
            let images = json["images"].as_array().unwrap();
            assert_eq!(images.len(), 2 + 4 * usize::from(texture), "{out}");
            for image in &images[..2] {
                let view = &json["bufferViews"][image["bufferView"].as_u64().unwrap() as usize];
                let start = view["byteOffset"].as_u64().unwrap_or(0) as usize;
                assert_eq!(bin[start..start + view["byteLength"].as_u64().unwrap() as usize], png(), "{out}");
                assert_eq!(image["mimeType"], "image/png");
            }
            let alone = d.join("alone").join(&out);
            std::fs::rename(d.join(&out), &alone).unwrap();
            if let Some(issues) = assert_valid_gltf(&alone, Some(&d.join(input))) {
                assert!(issues.iter().all(|i| i.severity > 1), "{out}: {issues:?}");
            }
            let render = |mesh: &Path| {
                let args = ["render", mesh.to_str().unwrap(), "--device", "cpu", "--width", "16", "--height", "16"];
                let o = aorender(&[&args[..], &["--spp", "1", "-o", "r.pfm"]].concat(), d);
                assert!(o.status.success(), "{}: {}", mesh.display(), String::from_utf8_lossy(&o.stderr));
                std::fs::read(d.join("r.pfm")).unwrap()
            };
            assert!(render(&alone) == render(&d.join(input)), "{out}: renders differently");
        }
    }
}

/// A two-target morph cube (as the glTF sample model AnimatedMorphCube, generated): a
/// texture bake splits its vertices along the generated charts and gathers its targets
/// onto them, each target's POSITION with bounds (which glTF requires) equal to the
/// displacements it holds, and keeping its name; the validator finds no error.
#[test]
fn morph_targets_keep_their_bounds_and_names() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, faces) = cube(DVec3::ZERO);
    let n = v.len();
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut add = |data: Vec<f32>, name: &str, bounds: bool| {
        let offset = bin.len();
        bin.extend(data.iter().flat_map(|x| x.to_le_bytes()));
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": offset, "byteLength": bin.len() - offset, "target": 34962}),
        );
        let mut a = serde_json::json!({"bufferView": views.len() - 1, "componentType": 5126, "count": n, "type": "VEC3", "name": name});
        if bounds {
            let lo =
                (0..3).map(|c| data.iter().skip(c).step_by(3).copied().fold(f32::MAX, f32::min)).collect::<Vec<_>>();
            let hi =
                (0..3).map(|c| data.iter().skip(c).step_by(3).copied().fold(f32::MIN, f32::max)).collect::<Vec<_>>();
            (a["min"], a["max"]) = (lo.into(), hi.into());
        }
        accessors.push(a);
        accessors.len() - 1
    };
    let positions = add(v.iter().flat_map(|v| v.p.as_vec3().to_array()).collect(), "positions", true);
    let normals = add(v.iter().flat_map(|v| v.n.as_vec3().to_array()).collect(), "normals", false);
    // Target 0 lifts the top face, target 1 pushes every vertex out along x.
    let lift = add(v.iter().flat_map(|v| [0.0, if v.p.y > 0.0 { 0.5 } else { 0.0 }, 0.0]).collect(), "lift", true);
    let push = add(v.iter().flat_map(|v| [(v.p.x * 0.25) as f32, 0.0, 0.0]).collect(), "push", true);
    let indices: Vec<u8> = faces
        .iter()
        .flat_map(|f| [f[0], f[1], f[2], f[0], f[2], f[3]])
        .flat_map(|i| (i as u16).to_le_bytes())
        .collect();
    let offset = bin.len();
    bin.extend(&indices);
    views.push(serde_json::json!({"buffer": 0, "byteOffset": offset, "byteLength": indices.len(), "target": 34963}));
    accessors.push(serde_json::json!({"bufferView": views.len() - 1, "componentType": 5123, "count": indices.len() / 2, "type": "SCALAR"}));
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"name": "morph cube", "weights": [0.0, 0.5], "extras": {"targetNames": ["lift", "push"]}, "primitives": [{
            "attributes": {"POSITION": positions, "NORMAL": normals},
            "indices": accessors.len() - 1,
            "targets": [{"POSITION": lift}, {"POSITION": push}]
        }]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors
    });
    let mut json = serde_json::to_vec(&json).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    glb.extend(b"glTF");
    glb.extend(2u32.to_le_bytes());
    glb.extend(((12 + 8 + json.len() + 8 + bin.len()) as u32).to_le_bytes());
    glb.extend((json.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(&json);
    glb.extend((bin.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(&bin);
    std::fs::write(d.join("morph.glb"), glb).unwrap();
    for out in ["morph-ao.glb", "morph-ao.gltf"] {
        bake(d, &["morph.glb", "-o", out, "--texture", "64", "--device", "cpu", "--samples", "4"]);
        let (gltf, buffers) = read_gltf(&d.join(out));
        let mesh = gltf.meshes().next().unwrap();
        assert!(mesh.extras().as_ref().is_some_and(|e| e.get().contains("targetNames")), "{out}");
        let primitive = mesh.primitives().next().unwrap();
        assert!(primitive.get(&::gltf::Semantic::TexCoords(0)).is_some(), "{out}: no generated coordinates");
        let targets: Vec<_> = primitive.morph_targets().collect();
        assert_eq!(targets.len(), 2, "{out}");
        for (target, name) in targets.iter().zip(["lift", "push"]) {
            let accessor = target.positions().unwrap();
            assert_eq!(accessor.name(), Some(name), "{out}");
            let reader = ::gltf::accessor::Iter::<[f32; 3]>::new(accessor.clone(), |b| Some(&buffers[b.index()]));
            let values: Vec<[f32; 3]> = reader.unwrap().collect();
            assert_eq!(values.len(), accessor.count());
            for c in 0..3 {
                let lo = values.iter().map(|p| p[c]).fold(f32::MAX, f32::min);
                let hi = values.iter().map(|p| p[c]).fold(f32::MIN, f32::max);
                let bound = |v: Option<::gltf::json::Value>| v.unwrap()[c].as_f64().unwrap() as f32;
                assert_eq!((bound(accessor.min()), bound(accessor.max())), (lo, hi), "{out}: {name}, component {c}");
            }
        }
    }
}

/// A texture bake of a real model with generated coordinates (2CylinderEngine, from
/// COLLADA2GLTF, 34 materials, meshes placed by several nodes) leaves no unused object
/// (the validator says so), shares one sampler between its maps, and keeps no byte its
/// views do not cover; with bent normals too, and as a `.gltf`.
#[test]
fn a_texture_bake_of_a_real_model_leaves_nothing_unused() {
    let dir = temp_dir();
    let d = dir.path();
    let engine = repo().join("scenes/2CylinderEngine.glb");
    let input = engine.to_str().unwrap();
    let common = ["--texture", "256", "--padding", "1", "--texel-points", "1", "--samples", "1", "--device", "cpu"];
    for (out, bent) in [("engine.glb", false), ("engine-bent.glb", true), ("engine.gltf", false)] {
        let mut args = [&[input, "-o", out][..], &common].concat();
        if bent {
            args.push("--bent-normals");
        }
        bake(d, &args);
        let (json, bin) = if out.ends_with(".glb") {
            glb_parts(&d.join(out))
        } else {
            let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join(out)).unwrap()).unwrap();
            let uri = json["buffers"][0]["uri"].as_str().unwrap();
            let bin = std::fs::read(d.join(uri)).unwrap();
            (json, bin)
        };
        assert_eq!(json["samplers"].as_array().unwrap().len(), 1, "{out}");
        assert_eq!(json["buffers"].as_array().unwrap().len(), 1, "{out}");
        let mut covered = vec![false; bin.len()];
        for view in json["bufferViews"].as_array().unwrap() {
            let start = view["byteOffset"].as_u64().unwrap_or(0) as usize;
            covered[start..start + view["byteLength"].as_u64().unwrap() as usize].fill(true);
        }
        // Only the padding that keeps each view on a 4-byte boundary is not viewed.
        let gaps = covered.chunk_by(|a, b| a == b).filter(|run| !run[0]).map(<[bool]>::len).max().unwrap_or(0);
        assert!(gaps < 4, "{out}: {gaps} bytes in a row that no view covers");
    }
}

/// glTF 2.0's default wrap is REPEAT: the floor's coordinates run to 1.5 under a base
/// colour texture without a sampler, and the bake takes them as `--uv-wrap repeat` does,
/// to the same bytes. An OBJ whose MTL texture map does not say `-clamp on` repeats as
/// well; one that does is refused.
#[test]
fn textures_without_a_sampler_and_mtl_maps_repeat() {
    let dir = temp_dir();
    let d = dir.path();
    let mut doc = gltf_fixture(1.5, true);
    doc["textures"][0].as_object_mut().unwrap().remove("sampler");
    doc.as_object_mut().unwrap().remove("samplers");
    std::fs::write(d.join("colour.png"), png()).unwrap();
    std::fs::write(d.join("nosampler.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    let common = ["--texture", "32", "--device", "cpu", "--samples", "4"];
    bake(d, &[&["nosampler.gltf", "-o", "file.glb"][..], &common].concat());
    bake(d, &[&["nosampler.gltf", "-o", "repeat.glb", "--uv-wrap", "repeat"][..], &common].concat());
    let (file, repeat) = (glb_parts(&d.join("file.glb")), glb_parts(&d.join("repeat.glb")));
    assert!(file == repeat, "the file's wrap is not REPEAT");
    let wrap = &file.0["samplers"][0];
    assert_eq!((wrap["wrapS"].as_u64(), wrap["wrapT"].as_u64()), (Some(10497), Some(10497)));

    // The floor's u runs over [0.25, 1.75] in an OBJ.
    let (v, f) = floor(2, 1.0, (DVec2::new(0.25, 0.0), 1.5));
    let mut obj = String::from("mtllib floor.mtl\n");
    for p in &v {
        obj += &format!("v {} {} {}\nvt {} {}\n", p.p.x, p.p.y, p.p.z, p.uv.x, p.uv.y);
    }
    obj += "usemtl tiles\n";
    for face in &f {
        obj += "f";
        for i in face {
            obj += &format!(" {}/{}", i + 1, i + 1);
        }
        obj += "\n";
    }
    std::fs::write(d.join("floor.obj"), &obj).unwrap();
    let plane = "[[object]]\ntype = \"sphere\"\ncenter = [0, 0.6, 0]\nradius = 0.5\n";
    std::fs::write(d.join("floor.toml"), scene("floor.obj", plane)).unwrap();
    for (mtl, wraps) in [("map_Kd -s 1 1 1 tiles.png\n", true), ("map_Kd -clamp on tiles.png\n", false)] {
        std::fs::write(d.join("floor.mtl"), format!("newmtl tiles\nKd 1 1 1\n{mtl}")).unwrap();
        let _ = std::fs::remove_file(d.join("file.exr"));
        if !wraps {
            bake_refused(&["floor.toml", "-o", "file.exr", "--texture", "32"], d, "outside [0, 1]");
            continue;
        }
        bake(d, &[&["floor.toml", "-o", "file.exr"][..], &common].concat());
        bake(d, &[&["floor.toml", "-o", "repeat.exr", "--uv-wrap", "repeat"][..], &common].concat());
        assert_eq!(std::fs::read(d.join("file.exr")).unwrap(), std::fs::read(d.join("repeat.exr")).unwrap());
        // Every texel is on the floor: u over 1.5 copies of the texture covers it all.
        let (_, _, texels) = read_exr(&d.join("file.exr"));
        assert!(texels.iter().all(|t| t.2), "a texel is off the floor");
    }
}

/// `aorender bake` with `args` in `dir` under the memory budget `limit` (bytes, through
/// `AORENDER_MEMORY_LIMIT`): its output.
fn bake_within(dir: &Path, limit: Option<u64>, args: &[&str]) -> std::process::Output {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_aorender"));
    command.arg("bake").args(args).current_dir(dir).env("XDG_RUNTIME_DIR", std::env::temp_dir());
    if let Some(limit) = limit {
        command.env("AORENDER_MEMORY_LIMIT", limit.to_string());
    }
    command.output().expect("aorender runs")
}

/// A texture bake larger than its memory budget is traced a block of texels at a time:
/// with bent normals (four film slots a point, where a plain bake has one) its heap's
/// peak stays within 1.5 times the plain bake's, both within the budget, and the maps are
/// those of the bake traced whole, byte for byte (on the CPU reference and the adapter). A budget the textures alone exceed is
/// refused before any work, and so is a bake with a checkpoint (which needs every point
/// in one film) past it.
#[test]
fn a_texture_bake_is_traced_in_blocks_within_its_memory_budget() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(8, 2.0, (DVec2::ZERO, 1.0));
    std::fs::write(d.join("floor.ply"), ply(&v, &f)).unwrap();
    let sphere = "[[object]]\ntype = \"sphere\"\ncenter = [0, 0.6, 0]\nradius = 0.5\n";
    std::fs::write(d.join("scene.toml"), scene("floor.ply", sphere)).unwrap();
    // 512² texels, 4 points each: a million points, 216 MB of them plain and 624 MB with
    // bent normals traced whole.
    const LIMIT: u64 = 64 << 20;
    let common = ["--texture", "512", "--samples", "2", "--device", "cpu"];
    let mut peaks = Vec::new();
    for bent in [false, true] {
        let mut heap = Vec::new();
        for (limit, out) in [(None, "whole.exr"), (Some(LIMIT), "blocks.exr")] {
            let mut args = [&["scene.toml", "-o", out][..], &common].concat();
            if bent {
                args.push("--bent-normals");
            }
            let o = bake_within(d, limit, &args);
            assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
            let stats: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
            assert_eq!(stats["points_traced"], 1 << 20);
            heap.push(stats["heap_peak_bytes"].as_u64().unwrap());
        }
        assert_eq!(std::fs::read(d.join("blocks.exr")).unwrap(), std::fs::read(d.join("whole.exr")).unwrap());
        if bent {
            let (a, b) = (d.join("blocks_bent_normals.png"), d.join("whole_bent_normals.png"));
            assert_eq!(std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
        }
        assert!(heap[1] <= LIMIT, "bent normals {bent}: {} bytes past the budget of {LIMIT}", heap[1]);
        assert!(heap[1] < heap[0] / 2, "bent normals {bent}: {heap:?}: the blocks took as much as the whole");
        peaks.push(heap[1]);
    }
    assert!(peaks[1] as f64 <= 1.5 * peaks[0] as f64, "bent normals: {} bytes, plain {}", peaks[1], peaks[0]);
    // On the adapter too, the blocks give the whole bake's maps.
    if gpu_available() {
        let common = ["--texture", "512", "--samples", "2", "--device", "gpu", "--bent-normals"];
        for (limit, out) in [(None, "gpu-whole.exr"), (Some(LIMIT), "gpu-blocks.exr")] {
            let o = bake_within(d, limit, &[&["scene.toml", "-o", out][..], &common].concat());
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
        for suffix in [".exr", "_bent_normals.png"] {
            let read = |name: &str| std::fs::read(d.join(name.replace(".exr", suffix))).unwrap();
            assert!(read("gpu-blocks.exr") == read("gpu-whole.exr"), "the adapter's blocks differ ({suffix})");
        }
    }

    for (limit, extra, expect) in
        [(1 << 20, &[][..], "for its texels"), (LIMIT, &["--checkpoint", "c.ck"][..], "every point is traced at once")]
    {
        let args = [&["scene.toml", "-o", "refused.exr"][..], &common, extra].concat();
        let o = bake_within(d, Some(limit), &args);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{stderr}");
        assert!(stderr.lines().count() == 1 && stderr.contains(expect) && stderr.contains("GiB"), "{stderr}");
        assert!(!d.join("refused.exr").exists() && !d.join("c.ck").exists());
    }
}
