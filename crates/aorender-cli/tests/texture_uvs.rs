//! `aorender bake --texture` of meshes without texture coordinates, which get generated
//! lightmap UVs: every output format, read back with an independent reader (`tobj`,
//! `ply-rs-bw`, the `gltf` crate), carries the new set inside [0, 1] with no two charts
//! in one texel and no two triangles over one point, references the map, and the map
//! looked up at the written coordinates holds the AO of the surface there; a convex
//! closed mesh bakes to exactly 1; `--generate-uvs never` refuses such a mesh.

mod common;
use common::*;
use glam::{DVec2, DVec3, Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

fn devices() -> Vec<&'static str> {
    let mut d = vec!["cpu"];
    if gpu_available() {
        d.push("gpu");
    }
    d
}

/// An icosphere of radius `r` about `c`: the icosahedron's faces split `levels` times,
/// every vertex pushed onto the sphere (the closed-form suite's).
fn icosphere(c: DVec3, r: f64, levels: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let m = aorender::closed_form::unit_icosphere(levels);
    (m.vertices.iter().map(|&p| c + r * p).collect(), m.triangles.iter().map(|t| t.map(|i| i as u32)).collect())
}

/// A triangle mesh without texture coordinates: positions, optional normals, triangles.
struct Mesh {
    p: Vec<DVec3>,
    n: Option<Vec<DVec3>>,
    f: Vec<[u32; 3]>,
}

/// A 6 × 6 floor (8 × 8 quads, two triangles each) on y = 0 facing +y and, in the same
/// mesh, an icosphere of radius `R` whose centre is `CENTRE`.
const CENTRE: DVec3 = DVec3::new(0.25, 1.5, -0.5);
const R: f64 = 1.0;
fn floor_and_ball() -> Mesh {
    let n = 8;
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            p.push(DVec3::new(-3.0 + 6.0 * i as f64 / n as f64, 0.0, -3.0 + 6.0 * j as f64 / n as f64));
        }
    }
    let mut f: Vec<[u32; 3]> =
        grid_quads(n).into_iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    let (sp, sf) = icosphere(CENTRE, R, 2);
    let base = p.len() as u32;
    p.extend(sp);
    f.extend(sf.into_iter().map(|t| t.map(|i| i + base)));
    Mesh { p, n: None, f }
}

/// An icosphere flat shaded: each face with its own three vertices and its normal.
fn faceted_icosphere() -> Mesh {
    let (v, f) = icosphere(DVec3::new(0.3, -0.2, 1.5), 1.0, 1);
    let (mut p, mut n, mut t) = (Vec::new(), Vec::new(), Vec::new());
    for [a, b, c] in f {
        let (a, b, c) = (v[a as usize], v[b as usize], v[c as usize]);
        let k = p.len() as u32;
        p.extend([a, b, c]);
        n.extend([(b - a).cross(c - a).normalize(); 3]);
        t.push([k, k + 1, k + 2]);
    }
    Mesh { p, n: Some(n), f: t }
}

fn write_obj(m: &Mesh, path: &Path) {
    let mut s = String::new();
    for p in &m.p {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for n in m.n.iter().flatten() {
        s += &format!("vn {} {} {}\n", n.x, n.y, n.z);
    }
    for t in &m.f {
        let [a, b, c] = t.map(|i| i + 1);
        s += &if m.n.is_some() { format!("f {a}//{a} {b}//{b} {c}//{c}\n") } else { format!("f {a} {b} {c}\n") };
    }
    std::fs::write(path, s).unwrap();
}

fn write_ply(m: &Mesh, path: &Path) {
    let mut s = format!("ply\nformat ascii 1.0\nelement vertex {}\n", m.p.len());
    let names: &[&str] = if m.n.is_some() { &["x", "y", "z", "nx", "ny", "nz"] } else { &["x", "y", "z"] };
    for name in names {
        s += &format!("property float {name}\n");
    }
    s += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", m.f.len());
    for (i, p) in m.p.iter().enumerate() {
        s += &format!("{} {} {}", p.x, p.y, p.z);
        if let Some(n) = &m.n {
            s += &format!(" {} {} {}", n[i].x, n[i].y, n[i].z);
        }
        s += "\n";
    }
    for [a, b, c] in &m.f {
        s += &format!("3 {a} {b} {c}\n");
    }
    std::fs::write(path, s).unwrap();
}

/// A GLB of the mesh (one primitive, a material without textures) in its binary chunk,
/// placed by `nodes` nodes 100 apart along x (each gets its own charts).
fn write_glb(m: &Mesh, path: &Path, nodes: usize) {
    let mut bytes: Vec<u8> = m.p.iter().flat_map(|p| p.as_vec3().to_array()).flat_map(f32::to_le_bytes).collect();
    let positions = bytes.len();
    let lo = m.p.iter().fold(DVec3::MAX, |a, &b| a.min(b)).as_vec3().to_array();
    let hi = m.p.iter().fold(DVec3::MIN, |a, &b| a.max(b)).as_vec3().to_array();
    if let Some(n) = &m.n {
        bytes.extend(n.iter().flat_map(|p| p.as_vec3().to_array()).flat_map(f32::to_le_bytes));
    }
    let normals = bytes.len() - positions;
    let start = bytes.len();
    bytes.extend(m.f.iter().flatten().flat_map(|i| i.to_le_bytes()));
    let nodes: Vec<serde_json::Value> = (0..nodes)
        .map(|k| serde_json::json!({"name": format!("model {k}"), "mesh": 0, "translation": [100.0 * k as f64, 0.0, 0.0]}))
        .collect();
    let mut doc = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"name": "paint"}],
        "buffers": [{"byteLength": bytes.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions},
            {"buffer": 0, "byteOffset": start, "byteLength": bytes.len() - start}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": m.p.len(), "type": "VEC3", "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5125, "count": 3 * m.f.len(), "type": "SCALAR"}
        ]
    });
    if normals > 0 {
        doc["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({"buffer": 0, "byteOffset": positions, "byteLength": normals}));
        doc["accessors"]
            .as_array_mut()
            .unwrap()
            .push(serde_json::json!({"bufferView": 2, "componentType": 5126, "count": m.p.len(), "type": "VEC3"}));
        doc["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = 2.into();
    }
    // The GLB container: header, JSON chunk (padded with spaces), BIN chunk.
    let mut json = serde_json::to_vec(&doc).unwrap();
    json.resize(json.len().next_multiple_of(4), b' ');
    bytes.resize(bytes.len().next_multiple_of(4), 0);
    let mut glb = Vec::new();
    glb.extend(b"glTF");
    glb.extend(2u32.to_le_bytes());
    glb.extend(((12 + 8 + json.len() + 8 + bytes.len()) as u32).to_le_bytes());
    glb.extend((json.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(json);
    glb.extend((bytes.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(bytes);
    std::fs::write(path, glb).unwrap();
}

/// What a baked output holds: its triangles (positions, and texture coordinates in
/// texel units, y down the image) and its map (16-bit).
struct Baked {
    triangles: Vec<([Vec3; 3], [DVec2; 3])>,
    map: image::ImageBuffer<image::Luma<u16>, Vec<u16>>,
}

/// A triangle as a file gives it: positions, and coordinates (v down the image).
type FileTriangle = ([Vec3; 3], [Vec2; 3]);

/// Reads the output `name` in `d` back with the format's independent reader.
fn read_back(d: &Path, name: &str) -> Baked {
    let path = d.join(name);
    let (tris, map): (Vec<FileTriangle>, image::DynamicImage) = match name.rsplit_once('.').unwrap().1 {
        "obj" => {
            let (models, _) = tobj::load_obj(&path, &tobj::LoadOptions { triangulate: true, ..Default::default() })
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            let mesh = &models[0].mesh;
            assert_eq!(mesh.texcoord_indices.len(), mesh.indices.len(), "{name}: every corner has a vt");
            let tris = (0..mesh.indices.len() / 3)
                .map(|t| {
                    let p = |k: usize| {
                        let i = mesh.indices[3 * t + k] as usize;
                        Vec3::from_slice(&mesh.positions[3 * i..3 * i + 3])
                    };
                    let uv = |k: usize| {
                        let i = mesh.texcoord_indices[3 * t + k] as usize;
                        Vec2::new(mesh.texcoords[2 * i], 1.0 - mesh.texcoords[2 * i + 1])
                    };
                    ([p(0), p(1), p(2)], [uv(0), uv(1), uv(2)])
                })
                .collect();
            (tris, image::open(d.join(name.replace(".obj", "_ao.png"))).unwrap())
        }
        "ply" => {
            use ply_rs_bw::ply::Property;
            let mut file = std::fs::File::open(&path).unwrap();
            let ply = ply_rs_bw::parser::Parser::<ply_rs_bw::ply::DefaultElement>::new().read_ply(&mut file).unwrap();
            let float = |p: &Property| match p {
                Property::Float(x) => *x,
                other => panic!("{name}: {other:?}"),
            };
            let vertices: Vec<Vec3> = ply.payload["vertex"]
                .iter()
                .map(|v| Vec3::new(float(&v["x"]), float(&v["y"]), float(&v["z"])))
                .collect();
            let tris = ply.payload["face"]
                .iter()
                .map(|f| {
                    let Property::ListInt(idx) = &f["vertex_indices"] else { panic!("{name}: face indices") };
                    let Some(Property::ListFloat(uv)) = f.get("texcoord") else { panic!("{name}: no texcoord list") };
                    assert_eq!(uv.len(), 2 * idx.len(), "{name}: u v per corner");
                    let p = [0, 1, 2].map(|k| vertices[idx[k] as usize]);
                    (p, [0, 1, 2].map(|k| Vec2::new(uv[2 * k], 1.0 - uv[2 * k + 1])))
                })
                .collect();
            (tris, image::open(d.join(name.replace(".ply", "_ao.png"))).unwrap())
        }
        _ => {
            let bytes = std::fs::read(&path).unwrap();
            let gltf = ::gltf::Gltf::from_slice(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            let bin = gltf.blob.clone().expect("a binary chunk");
            let mut tris = Vec::new();
            let mut png = None;
            for mesh in gltf.meshes() {
                for primitive in mesh.primitives() {
                    let occlusion = primitive.material().occlusion_texture().expect("an occlusion texture");
                    let set = occlusion.tex_coord();
                    let ::gltf::image::Source::View { view, .. } = occlusion.texture().source().source() else {
                        panic!("{name}: the image is not in the binary chunk");
                    };
                    png = Some(bin[view.offset()..view.offset() + view.length()].to_vec());
                    let reader = primitive.reader(|_| Some(&bin[..]));
                    let p: Vec<Vec3> = reader.read_positions().unwrap().map(Vec3::from).collect();
                    let uv: Vec<Vec2> =
                        reader.read_tex_coords(set).expect("the baked set").into_f32().map(Vec2::from).collect();
                    let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
                    for t in idx.chunks(3) {
                        tris.push(([0, 1, 2].map(|k| p[t[k] as usize]), [0, 1, 2].map(|k| uv[t[k] as usize])));
                    }
                }
            }
            (tris, image::load_from_memory(&png.expect("a map")).unwrap())
        }
    };
    let map = map.to_luma16();
    let size = DVec2::new(map.width() as f64, map.height() as f64);
    for (_, uv) in &tris {
        for c in uv {
            assert!(c.min_element() >= 0.0 && c.max_element() <= 1.0, "{name}: coordinate {c} outside [0, 1]");
        }
    }
    let triangles = tris.into_iter().map(|(p, uv)| (p, uv.map(|c| c.as_dvec2() * size))).collect();
    Baked { triangles, map }
}

fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

/// Barycentric coordinates of `q` in the UV triangle `t`.
fn barycentric(t: &[DVec2; 3], q: DVec2) -> [f64; 3] {
    let area = cross(t[1] - t[0], t[2] - t[0]);
    let b1 = cross(q - t[0], t[2] - t[0]) / area;
    let b2 = cross(t[1] - t[0], q - t[0]) / area;
    [1.0 - b1 - b2, b1, b2]
}

/// Whether the closed texel square at (x, y) meets the triangle (separating axes: the
/// square's two and the triangle's three edge normals).
fn meets(t: &[DVec2; 3], x: f64, y: f64) -> bool {
    let corners = [DVec2::new(x, y), DVec2::new(x + 1.0, y), DVec2::new(x, y + 1.0), DVec2::new(x + 1.0, y + 1.0)];
    let mut axes = vec![DVec2::X, DVec2::Y];
    for i in 0..3 {
        let e = t[(i + 1) % 3] - t[i];
        axes.push(DVec2::new(-e.y, e.x));
    }
    axes.iter().all(|a| {
        let (t0, t1) = t.iter().fold((f64::MAX, f64::MIN), |m, p| (m.0.min(p.dot(*a)), m.1.max(p.dot(*a))));
        let (s0, s1) = corners.iter().fold((f64::MAX, f64::MIN), |m, p| (m.0.min(p.dot(*a)), m.1.max(p.dot(*a))));
        t0 <= s1 && s0 <= t1
    })
}

/// The charts of the UV triangles: triangles sharing a corner's coordinates are one.
fn charts(triangles: &[([Vec3; 3], [DVec2; 3])]) -> Vec<usize> {
    let mut parent: Vec<usize> = (0..triangles.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut first: HashMap<(u64, u64), usize> = HashMap::new();
    for (t, (_, uv)) in triangles.iter().enumerate() {
        for c in uv {
            let other = *first.entry((c.x.to_bits(), c.y.to_bits())).or_insert(t);
            let (a, b) = (root(&mut parent, t), root(&mut parent, other));
            parent[a] = b;
        }
    }
    (0..triangles.len()).map(|t| root(&mut parent, t)).collect()
}

/// No texel meets two charts, and no point (4 × 4 a texel) lies strictly inside two
/// triangles.
fn assert_no_overlap(name: &str, b: &Baked) {
    let (w, h) = (b.map.width() as usize, b.map.height() as usize);
    let chart = charts(&b.triangles);
    let mut owner = vec![usize::MAX; w * h];
    let mut inside = vec![0u8; 16 * w * h];
    for (t, (_, uv)) in b.triangles.iter().enumerate() {
        let lo = uv[0].min(uv[1]).min(uv[2]).floor().max(DVec2::ZERO);
        let hi = uv[0].max(uv[1]).max(uv[2]).ceil().min(DVec2::new(w as f64, h as f64));
        for y in lo.y as usize..hi.y as usize {
            for x in lo.x as usize..hi.x as usize {
                if meets(uv, x as f64, y as f64) {
                    let o = &mut owner[y * w + x];
                    assert!(*o == usize::MAX || *o == chart[t], "{name}: texel ({x}, {y}) meets two charts");
                    *o = chart[t];
                }
                for s in 0..16 {
                    let q =
                        DVec2::new(x as f64 + (s % 4) as f64 * 0.25 + 0.125, y as f64 + (s / 4) as f64 * 0.25 + 0.125);
                    if barycentric(uv, q).iter().all(|&c| c > 1e-9) {
                        let k = (y * w + x) * 16 + s;
                        inside[k] += 1;
                        assert!(inside[k] == 1, "{name}: point {q} inside two triangles");
                    }
                }
            }
        }
    }
    let charts = chart.iter().collect::<std::collections::HashSet<_>>().len();
    assert!(charts > 1 && owner.iter().filter(|&&o| o != usize::MAX).count() > w * h / 10, "{name}: {charts} charts");
}

/// A floor and a ball in one mesh without texture coordinates (placed twice, 100 apart,
/// in the GLB), baked into each format:
/// every output carries the generated set inside [0, 1] without overlaps, references its
/// map, and every texel whose centre lies on a floor triangle holds the AO of the floor
/// point there: between the closed forms 1 − cos β (r/d)² of the ball's inscribed and
/// circumscribed spheres, within 5 standard errors of the mean of N samples (4 for the
/// mean deviation, plus half the bounds' width in standard errors).
#[test]
fn generated_uvs_are_written_into_every_format_and_address_the_baked_map() {
    let dir = temp_dir();
    let d = dir.path();
    let mesh = floor_and_ball();
    write_obj(&mesh, &d.join("in.obj"));
    write_ply(&mesh, &d.join("in.ply"));
    write_glb(&mesh, &d.join("in.glb"), 2);
    // The icosphere (level 2) lies between the sphere of radius R and its inscribed one.
    let (sp, sf) = icosphere(CENTRE, R, 2);
    let r_in = sf
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| sp[i as usize]);
            (CENTRE - a).dot((b - a).cross(c - a).normalize()).abs()
        })
        .fold(f64::MAX, f64::min);
    let samples = 1024;
    for device in devices() {
        for input in ["in.obj", "in.ply", "in.glb"] {
            let out = format!("{device}-{input}");
            let args = [input, "-o", &out, "--texture", "64", "--texel-points", "1", "--bit-depth", "16"];
            let s = samples.to_string();
            let run =
                aorender(&[&["bake"][..], &args, &["--samples", &s, "--device", device, "--seed", "5"]].concat(), d);
            assert!(run.status.success(), "{out}: {}", String::from_utf8_lossy(&run.stderr));
            let b = read_back(d, &out);
            // The GLB places the mesh twice: each node gets a copy with its own charts.
            let placements = if input.ends_with(".glb") { 2 } else { 1 };
            assert_eq!(b.triangles.len(), placements * mesh.f.len(), "{out}: the triangles");
            assert_no_overlap(&out, &b);
            let (mut checked, mut sum_z, mut slack) = (0, 0.0, 0.0f64);
            for (p, uv) in b.triangles.iter().filter(|(p, _)| p.iter().all(|q| q.y == 0.0)) {
                let lo = uv[0].min(uv[1]).min(uv[2]).floor();
                let hi = uv[0].max(uv[1]).max(uv[2]).ceil();
                for y in lo.y as u32..hi.y as u32 {
                    for x in lo.x as u32..hi.x as u32 {
                        let bary = barycentric(uv, DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                        if bary.iter().any(|&c| c < 1e-6) {
                            continue;
                        }
                        let q = (0..3).map(|k| bary[k] * p[k].as_dvec3()).sum::<DVec3>();
                        let to = CENTRE - q;
                        let ao = |r: f64| 1.0 - to.y / to.length() * (r / to.length()).powi(2);
                        let (lo, hi) = (ao(R), ao(r_in));
                        let value = b.map.get_pixel(x, y).0[0] as f64 / 65535.0;
                        let mid = 0.5 * (lo + hi);
                        let sigma = (mid * (1.0 - mid) / samples as f64).sqrt().max(1e-3);
                        // 5σ a texel: over about 1,200 texels, 4σ would fail one bake in twelve.
                        assert!(
                            value > lo - 5.0 * sigma && value < hi + 5.0 * sigma,
                            "{out}: texel ({x}, {y}) at {q}: {value} outside [{lo}, {hi}] ± 5 × {sigma}"
                        );
                        sum_z += (value - mid) / sigma;
                        slack = slack.max((hi - lo) / (2.0 * sigma));
                        checked += 1;
                    }
                }
            }
            assert!(checked > 500, "{out}: {checked} floor texels");
            let mean = sum_z / checked as f64;
            assert!(mean.abs() < 4.0 / (checked as f64).sqrt() + slack, "{out}: mean deviation {mean} σ");
            eprintln!("{out}: {checked} floor texels, mean deviation {:.3} σ", sum_z / checked as f64);
        }
    }
}

/// Nothing outside a convex body occludes it: a flat-shaded icosphere without texture
/// coordinates bakes through generated ones to exactly 1 in every covered texel (the
/// statistics' mean and largest standard error), and so the whole 16-bit map is white.
#[test]
fn a_convex_closed_mesh_bakes_to_one_through_generated_uvs() {
    let dir = temp_dir();
    let d = dir.path();
    write_ply(&faceted_icosphere(), &d.join("ball.ply"));
    for device in devices() {
        let out = format!("{device}.ply");
        let args = ["ball.ply", "-o", &out, "--texture", "64", "--bit-depth", "16", "--samples", "32"];
        let run = aorender(&[&["bake", "--device", device][..], &args].concat(), d);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let stats: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        let map = &stats["texture"]["maps"][0];
        assert!(map["covered_texels"].as_u64().unwrap() > 1000, "{device}: {map}");
        assert_eq!((map["mean_ao"].as_f64(), map["max_std_error"].as_f64()), (Some(1.0), Some(0.0)), "{device}");
        assert!(stats["texture"]["generated_uvs"]["charts"].as_u64().unwrap() >= 1);
        let b = read_back(d, &out);
        assert_no_overlap(&out, &b);
        assert!(b.map.pixels().all(|p| p.0[0] == 65535), "{device}: a texel below 1");
    }
}

/// With generation turned off, a mesh without texture coordinates is refused in one line
/// with status 1 and nothing written; so is a map alone of generated coordinates, and
/// a second set where OBJ and PLY hold one.
#[test]
fn meshes_without_uvs_are_refused_when_generation_is_off() {
    let dir = temp_dir();
    let d = dir.path();
    write_obj(&faceted_icosphere(), &d.join("ball.obj"));
    write_glb(&faceted_icosphere(), &d.join("ball.glb"), 1);
    std::fs::write(d.join("mapped.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n").unwrap();
    for (args, expect) in [
        (
            &["ball.obj", "-o", "out.obj", "--texture", "64", "--generate-uvs", "never"][..],
            "no mesh has texture coordinates of set 0",
        ),
        (&["ball.glb", "-o", "out.glb", "--texture", "64", "--generate-uvs", "never"][..], "(--generate-uvs never)"),
        (&["ball.obj", "-o", "out.png", "--texture", "64"][..], "would lose the generated ones"),
        (&["mapped.obj", "-o", "out.obj", "--texture", "64", "--generate-uvs", "always"][..], "hold one set"),
        (&["ball.obj", "-o", "out.obj", "--texture", "8", "--padding", "4"][..], "too small to unwrap"),
    ] {
        let line = bake_refused(&[&["--samples", "4"][..], args].concat(), d, expect);
        assert!(line.contains("ball.") || line.contains("mapped.") || line.contains("out."), "{line}");
    }
    let mut left: Vec<_> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["ball.glb", "ball.obj", "mapped.obj"]);
}

/// A bake into generated UVs writes the same bytes run to run and on any number of
/// threads: the bunny (62 charts) baked twice on three rayon threads and once on one, its
/// mesh with the new `vt` lines and its map compared byte for byte, and the statistics'
/// chart count the same.
#[test]
fn a_bake_into_generated_uvs_is_the_same_bytes_on_any_thread_count() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::copy(repo().join("scenes/bunny.obj"), d.join("bunny.obj")).unwrap();
    let bake_on = |threads: usize, name: &str| {
        let args = ["bake", "bunny.obj", "-o", name, "--texture", "256", "--samples", "2", "--device", "cpu"];
        let out = aorender_on_threads(&args, d, threads);
        let stats: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let charts = stats["texture"]["generated_uvs"]["charts"].as_u64().unwrap();
        let mesh = std::fs::read(d.join(name)).unwrap();
        let map = std::fs::read(d.join(name.replace(".obj", "_ao.png"))).unwrap();
        (charts, mesh, map)
    };
    let first = bake_on(3, "a.obj");
    assert!(first.0 > 10, "{} charts", first.0);
    assert!(String::from_utf8_lossy(&first.1).lines().filter(|l| l.starts_with("vt ")).count() > 35_000);
    for (threads, name) in [(3, "b.obj"), (1, "c.obj")] {
        let other = bake_on(threads, name);
        assert_eq!(other.0, first.0, "{name} on {threads} threads: the charts");
        assert!(other.1 == first.1, "{name} on {threads} threads: another mesh");
        assert!(other.2 == first.2, "{name} on {threads} threads: another map");
    }
}
