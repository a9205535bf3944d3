//! `aorender bake` end to end, on the CPU reference and the adapter: closed forms through
//! the written files (a convex closed mesh is exactly 1 at every vertex and face, a floor
//! under a sphere is 1 − cos β (r/d)² within 4 standard errors, an open floor exactly 1),
//! instances baked per placement, the GPU agreeing with the CPU, resumed and sharded
//! bakes bit for bit the same file as one uninterrupted bake, a scene moved far from the
//! origin baking the origin's values bit for bit, and bad input refused in one line with
//! nothing written.

mod common;
use common::*;
use glam::DVec3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};
use std::path::Path;

/// The devices to bake on: the CPU reference, and the adapter when there is one.
fn devices() -> Vec<&'static str> {
    let mut d = vec!["cpu"];
    if gpu_available() {
        d.push("gpu");
    }
    d
}

/// An ASCII PLY of `positions` and `faces`, with normals when given.
fn ply(positions: &[DVec3], faces: &[Vec<u32>], normals: Option<&[DVec3]>) -> String {
    let mut s = format!("ply\nformat ascii 1.0\ncomment made by a test\nelement vertex {}\n", positions.len());
    s += "property float x\nproperty float y\nproperty float z\n";
    if normals.is_some() {
        s += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    s += &format!("element face {}\nproperty list uchar int vertex_indices\nend_header\n", faces.len());
    for (i, p) in positions.iter().enumerate() {
        s += &format!("{} {} {}", p.x as f32, p.y as f32, p.z as f32);
        if let Some(n) = normals {
            s += &format!(" {} {} {}", n[i].x as f32, n[i].y as f32, n[i].z as f32);
        }
        s += "\n";
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

/// An icosphere of radius `r` about `c`, subdivided `levels` times (the accuracy suite's).
fn icosphere(c: DVec3, r: f64, levels: u32) -> (Vec<DVec3>, Vec<Vec<u32>>) {
    let m = aorender::closed_form::unit_icosphere(levels);
    let faces = m.triangles.iter().map(|t| t.iter().map(|&i| i as u32).collect()).collect();
    (m.vertices.iter().map(|p| c + r * *p).collect(), faces)
}

/// A box with corners `lo` and `hi`, as six quads wound outwards.
fn cuboid(lo: DVec3, hi: DVec3) -> (Vec<DVec3>, Vec<Vec<u32>>) {
    let v = (0..8)
        .map(|i| DVec3::new([lo.x, hi.x][i & 1], [lo.y, hi.y][(i >> 1) & 1], [lo.z, hi.z][(i >> 2) & 1]))
        .collect();
    let f = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    (v, f.iter().map(|q| q.to_vec()).collect())
}

/// An n × n grid of quads on y = `y` spanning [-half, half]² in x and z, facing +y.
fn floor(n: u32, half: f64, y: f64) -> (Vec<DVec3>, Vec<Vec<u32>>) {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let s = |k: u32| -half + 2.0 * half * k as f64 / n as f64;
            v.push(DVec3::new(s(i), y, s(j)));
        }
    }
    (v, grid_quads(n))
}

/// The elements of a PLY file read with `ply-rs-bw`'s generic parser (an independent
/// reader of what the bake wrote).
fn read_ply(path: &Path) -> ply_rs_bw::ply::Ply<DefaultElement> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let bytes = if path.extension().is_some_and(|e| e == "gz") {
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut out).unwrap();
        out
    } else {
        bytes
    };
    Parser::<DefaultElement>::new().read_ply(&mut &bytes[..]).unwrap_or_else(|e| panic!("{}: {e:?}", path.display()))
}

fn float(e: &DefaultElement, name: &str) -> f32 {
    match e.get(name) {
        Some(Property::Float(v)) => *v,
        other => panic!("property {name}: {other:?}"),
    }
}

/// `quality` (and `quality_std_error`) of every element `element` of a baked PLY.
fn values(path: &Path, element: &str) -> (Vec<f32>, Vec<f32>) {
    let ply = read_ply(path);
    let rows = &ply.payload[element];
    let ao = rows.iter().map(|e| float(e, "quality")).collect();
    let se = rows
        .iter()
        .map(|e| if e.contains_key("quality_std_error") { float(e, "quality_std_error") } else { f32::NAN })
        .collect();
    (ao, se)
}

/// Nothing outside a convex body occludes it: every vertex and face of a closed convex
/// mesh (an icosphere, a box of quads) bakes to exactly 1 with cosine-weighted sampling,
/// and with uniform sampling (whose fully open estimate is not exactly 1) to the very
/// value of the same samples with every ray unoccluded (`--max-distance 0`).
#[test]
fn every_vertex_and_face_of_a_convex_closed_mesh_is_unoccluded() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = icosphere(DVec3::new(0.3, -0.2, 1.5), 2.0, 2);
    std::fs::write(d.join("ico.ply"), ply(&v, &f, None)).unwrap();
    let (v, f) = cuboid(DVec3::new(-1.0, -2.0, -0.5), DVec3::new(3.0, 1.0, 0.25));
    std::fs::write(d.join("box.ply"), ply(&v, &f, None)).unwrap();
    for device in devices() {
        for (mesh, at, element) in [
            ("ico.ply", "vertices", "vertex"),
            ("ico.ply", "faces", "face"),
            ("box.ply", "vertices", "vertex"),
            ("box.ply", "faces", "face"),
        ] {
            for hemisphere in ["cosine", "uniform"] {
                let out = format!("{device}-{at}-{hemisphere}-{mesh}");
                let open = format!("open-{out}");
                let args = ["--device", device, "--at", at, "--samples", "64", "--hemisphere", hemisphere];
                bake(d, &[&[mesh, "-o", &out][..], &args].concat());
                bake(d, &[&[mesh, "-o", &open, "--max-distance", "0"][..], &args].concat());
                let (ao, _) = values(&d.join(&out), element);
                let (unoccluded, _) = values(&d.join(&open), element);
                assert!(!ao.is_empty());
                for (k, a) in ao.iter().enumerate() {
                    let expected = if hemisphere == "cosine" { 1.0 } else { unoccluded[k] };
                    assert_eq!(*a, expected, "{device} {mesh} {at} {hemisphere}: {element} {k}");
                }
            }
        }
    }
}

/// A floor under a sphere: at a vertex whose normal makes the angle β with the direction
/// to the centre at distance d, cosine-weighted AO is 1 − cos β (r/d)² while the whole
/// sphere is above the horizon; the open floor around it is exactly 1.
#[test]
fn a_floor_under_a_sphere_matches_the_closed_form() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(12, 3.0, 0.0);
    std::fs::write(d.join("floor.ply"), ply(&v, &f, None)).unwrap();
    let (centre, r) = (DVec3::new(0.25, 1.5, -0.5), 1.0);
    let scene = format!(
        "[camera]\ntype = \"perspective\"\neye = [0, 5, 5]\nlook_at = [0, 0, 0]\nfov = 45\n\n\
         [[object]]\ntype = \"mesh\"\nfile = \"floor.ply\"\n\n\
         [[object]]\ntype = \"sphere\"\ncenter = [{}, {}, {}]\nradius = {r}\n",
        centre.x, centre.y, centre.z
    );
    std::fs::write(d.join("scene.toml"), scene).unwrap();
    for device in devices() {
        let out = format!("{device}-out");
        bake(d, &["scene.toml", "-o", &out, "--device", device, "--samples", "1024", "--std-error", "--seed", "7"]);
        let (ao, se) = values(&d.join(&out).join("floor.ply"), "vertex");
        assert_eq!(ao.len(), v.len());
        let mut worst: f64 = 0.0;
        for (k, p) in v.iter().enumerate() {
            let to = centre - *p;
            let cos_beta = to.y / to.length();
            let expected = 1.0 - cos_beta * (r / to.length()).powi(2);
            let z = (ao[k] as f64 - expected) / (se[k] as f64).max(1e-12);
            worst = worst.max(z.abs());
            assert!(z.abs() < 4.0, "{device}: vertex {k} at {p}: {} ± {} against {expected}", ao[k], se[k]);
        }
        eprintln!("{device}: largest deviation {worst:.2} standard errors over {} vertices", v.len());
    }
    // The floor alone: nothing occludes it.
    for device in devices() {
        let out = format!("{device}-open.ply");
        bake(d, &["floor.ply", "-o", &out, "--device", device, "--samples", "64"]);
        let (ao, _) = values(&d.join(&out), "vertex");
        assert!(ao.iter().all(|&a| a == 1.0), "{device}: {ao:?}");
    }
}

/// The same scene far from the origin (moved by 983,040 = 15 × 2¹⁶, exactly: every
/// coordinate is a multiple of 1/16) bakes the values it has at the origin, bit for bit:
/// the session moves the meshes and the bake's points into its local frame alike, and
/// the files keep their own positions.
#[test]
fn a_scene_far_from_the_origin_bakes_its_values_at_the_origin() {
    let dir = temp_dir();
    let d = dir.path();
    let (floor_v, floor_f) = floor(12, 3.0, 0.0);
    let (box_v, box_f) = cuboid(DVec3::new(-2.5, 0.0, -2.5), DVec3::new(-1.25, 1.5, -1.0));
    let (centre, r) = (DVec3::new(0.25, 1.5, -0.5), 1.0);
    for shift in [0.0, 983_040.0] {
        let moved = |v: &[DVec3]| v.iter().map(|p| *p + DVec3::splat(shift)).collect::<Vec<_>>();
        std::fs::write(d.join(format!("floor-{shift}.ply")), ply(&moved(&floor_v), &floor_f, None)).unwrap();
        std::fs::write(d.join(format!("box-{shift}.ply")), ply(&moved(&box_v), &box_f, None)).unwrap();
        let (eye, c) = (DVec3::new(0.0, 5.0, 5.0) + shift, centre + shift);
        let scene = format!(
            "[camera]\ntype = \"perspective\"\neye = [{}, {}, {}]\nlook_at = [{shift}, {shift}, {shift}]\nfov = 45\n\n\
             [[object]]\ntype = \"mesh\"\nfile = \"floor-{shift}.ply\"\n\n\
             [[object]]\ntype = \"mesh\"\nfile = \"box-{shift}.ply\"\n\n\
             [[object]]\ntype = \"sphere\"\ncenter = [{}, {}, {}]\nradius = {r}\n",
            eye.x, eye.y, eye.z, c.x, c.y, c.z
        );
        std::fs::write(d.join(format!("scene-{shift}.toml")), scene).unwrap();
    }
    for device in devices() {
        let baked = |shift: f64| {
            let out = format!("{device}-{shift}");
            let scene = format!("scene-{shift}.toml");
            bake(d, &[&scene, "-o", &out, "--device", device, "--samples", "256", "--hemisphere", "uniform"]);
            let floor = d.join(&out).join(format!("floor-{shift}.ply"));
            let first = &read_ply(&floor).payload["vertex"][0];
            assert_eq!(float(first, "x") as f64, floor_v[0].x + shift, "{device}: the file keeps its positions");
            let (floor_ao, _) = values(&floor, "vertex");
            let (box_ao, _) = values(&d.join(&out).join(format!("box-{shift}.ply")), "vertex");
            [floor_ao, box_ao].concat()
        };
        let (at_origin, far) = (baked(0.0), baked(983_040.0));
        assert!(at_origin.iter().any(|&a| a < 0.9), "{device}: the sphere and the box occlude the floor");
        let differ = far.iter().zip(&at_origin).filter(|(a, b)| a != b).count();
        assert_eq!(differ, 0, "{device}: {differ} of {} values differ far from the origin", far.len());
    }
}

/// One mesh file placed by two objects of a scene file (an instanced mesh): each placement
/// is baked into a file of its own, with its own occlusion; placed far apart with a short
/// maximum distance, every vertex of both (rays leaving instances carried through their
/// transforms, rotated and scaled) is exactly 1.
#[test]
fn each_placement_of_an_instanced_mesh_gets_its_own_values() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = icosphere(DVec3::ZERO, 1.0, 1);
    std::fs::write(d.join("ball.ply"), ply(&v, &f, None)).unwrap();
    let placed = |a: [f32; 3], b: [f32; 3], max_distance: f32| {
        format!(
            "[camera]\ntype = \"perspective\"\neye = [0, 0, 20]\nlook_at = [0, 0, 0]\nfov = 45\n\n[sampling]\nmax_distance = {max_distance}\n\n\
             [[object]]\ntype = \"mesh\"\nfile = \"ball.ply\"\ntransform = {{ translate = {a:?}, rotate = [30, 40, 50], scale = 1.7 }}\n\n\
             [[object]]\ntype = \"mesh\"\nfile = \"ball.ply\"\ntransform = {{ translate = {b:?}, rotate = [-10, 5, 80], scale = 0.6 }}\n"
        )
    };
    std::fs::write(d.join("apart.toml"), placed([-1000.0, 3.0, 2.0], [1000.0, -5.0, 7.0], 10.0)).unwrap();
    std::fs::write(d.join("close.toml"), placed([-1.0, 0.0, 0.0], [1.6, 0.0, 0.0], 100.0)).unwrap();
    for device in devices() {
        let out = format!("{device}-apart");
        bake(d, &["apart.toml", "-o", &out, "--device", device, "--samples", "64"]);
        for name in ["ball-1.ply", "ball-2.ply"] {
            let (ao, _) = values(&d.join(&out).join(name), "vertex");
            assert_eq!(ao.len(), v.len());
            assert!(ao.iter().all(|&a| a == 1.0), "{device} {name}: {ao:?}");
        }
        let out = format!("{device}-close");
        bake(d, &["close.toml", "-o", &out, "--device", device, "--samples", "256"]);
        let (a, _) = values(&d.join(&out).join("ball-1.ply"), "vertex");
        let (b, _) = values(&d.join(&out).join("ball-2.ply"), "vertex");
        assert!(a != b, "{device}: both placements got the same values");
        assert!(a.iter().chain(&b).any(|&x| x < 0.9), "{device}: the balls do not occlude each other");
    }
}

#[test]
fn the_gpu_and_the_cpu_bake_the_same_values() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    let bunny = repo().join("scenes/dragon_vrip_res4.ply.gz");
    let bunny = bunny.to_str().unwrap();
    for sampler in ["independent", "sobol"] {
        let cpu = format!("cpu-{sampler}.ply");
        let gpu = format!("gpu-{sampler}.ply");
        let args = ["--samples", "32", "--sampler", sampler, "--seed", "3", "--max-distance", "0.05", "--bent-normals"];
        bake(d, &[&[bunny, "-o", &cpu, "--device", "cpu"][..], &args].concat());
        bake(d, &[&[bunny, "-o", &gpu, "--device", "gpu"][..], &args].concat());
        let (c, _) = values(&d.join(&cpu), "vertex");
        let (g, _) = values(&d.join(&gpu), "vertex");
        assert_eq!(c.len(), g.len());
        let worst = c.iter().zip(&g).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "{sampler}: largest difference {worst}");
        for axis in ["bnx", "bny", "bnz"] {
            let read = |p: &str| -> Vec<f32> {
                read_ply(&d.join(p)).payload["vertex"].iter().map(|e| float(e, axis)).collect()
            };
            let worst = read(&cpu).iter().zip(&read(&gpu)).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(worst < 1e-5, "{sampler}: {axis} differs by {worst}");
        }
    }
}

/// A bake stopped by its time limit after its first pass and resumed, and a bake in two
/// sample-range shards merged, write the same bytes as one uninterrupted bake. The mesh
/// has more points (17,169) than an image has pixels on a side, as real scans do.
#[test]
fn resumed_and_merged_bakes_are_bit_identical() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(130, 3.0, 0.0);
    let (b, g) = cuboid(DVec3::new(-1.0, 0.0, -1.0), DVec3::new(1.0, 1.0, 1.0));
    let n = v.len() as u32;
    let faces: Vec<Vec<u32>> = f.into_iter().chain(g.into_iter().map(|q| q.iter().map(|i| i + n).collect())).collect();
    let positions: Vec<DVec3> = v.into_iter().chain(b).collect();
    std::fs::write(d.join("m.ply"), ply(&positions, &faces, None)).unwrap();
    for device in devices() {
        // Four slots a point: the AO and the bent normal's sums.
        let common = ["--device", device, "--std-error", "--bent-normals"];
        let [full, resumed, merged] = bake_whole_resumed_and_merged(d, "m.ply", "ply", device, 256, &common);
        assert_eq!(
            std::fs::read(d.join(&resumed)).unwrap(),
            std::fs::read(d.join(&full)).unwrap(),
            "{device}: resumed"
        );
        assert_eq!(std::fs::read(d.join(&merged)).unwrap(), std::fs::read(d.join(&full)).unwrap(), "{device}: merged");
    }
}

/// Vertices no face uses, and vertices whose faces are all degenerate, get the documented
/// value 1 and are counted; the others are baked.
#[test]
fn vertices_without_a_usable_normal_get_one_and_are_counted() {
    let dir = temp_dir();
    let d = dir.path();
    let (mut v, mut f) = floor(2, 1.0, 0.0);
    let n = v.len() as u32;
    // An unreferenced vertex, and a degenerate triangle (three collinear vertices) of its own.
    v.push(DVec3::new(0.0, 5.0, 0.0));
    v.extend([DVec3::new(0.0, 0.5, 0.0), DVec3::new(0.1, 0.5, 0.0), DVec3::new(0.2, 0.5, 0.0)]);
    f.push(vec![n + 1, n + 2, n + 3]);
    std::fs::write(d.join("m.ply"), ply(&v, &f, None)).unwrap();
    let err = bake(d, &["m.ply", "-o", "out.ply", "--device", "cpu", "--samples", "16", "--stats", "stats.json"]);
    assert!(err.contains("4 vertices without a usable normal"), "{err}");
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("stats.json")).unwrap()).unwrap();
    assert_eq!(stats["points_without_normal"], 4);
    assert_eq!(stats["points_traced"], n);
    let (ao, _) = values(&d.join("out.ply"), "vertex");
    assert!(ao.iter().all(|a| a.is_finite()));
    assert_eq!(&ao[n as usize..], &[1.0; 4]);
    // Their bent normal is (0, 0, 0): no direction; every other one is a unit vector.
    bake(d, &["m.ply", "-o", "bent.ply", "--device", "cpu", "--samples", "16", "--bent-normals"]);
    let ply = read_ply(&d.join("bent.ply"));
    let bent: Vec<[f32; 3]> =
        ply.payload["vertex"].iter().map(|e| [float(e, "bnx"), float(e, "bny"), float(e, "bnz")]).collect();
    assert_eq!(&bent[n as usize..], &[[0.0; 3]; 4]);
    for b in &bent[..n as usize] {
        assert!((b.iter().map(|c| c * c).sum::<f32>().sqrt() - 1.0).abs() < 1e-5, "{b:?}");
    }
}

/// The file's normals are used where it has them: a floor whose normals lean 60° toward a
/// wall sees it, the same floor with its geometric normals barely does.
#[test]
fn the_files_normals_are_used() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(2, 1.0, 0.0);
    let lean = DVec3::new(60f64.to_radians().sin(), 60f64.to_radians().cos(), 0.0);
    let normals = vec![lean; v.len()];
    std::fs::write(d.join("leaning.ply"), ply(&v, &f, Some(&normals))).unwrap();
    std::fs::write(d.join("plain.ply"), ply(&v, &f, None)).unwrap();
    let wall = "[camera]\ntype = \"perspective\"\neye = [0, 5, 5]\nlook_at = [0, 0, 0]\nfov = 45\n\n\
         [[object]]\ntype = \"plane\"\npoint = [1.5, 0, 0]\nnormal = [-1, 0, 0]\n\n\
         [[object]]\ntype = \"mesh\"\nfile = \"MESH\"\n";
    for mesh in ["leaning.ply", "plain.ply"] {
        std::fs::write(d.join(format!("{mesh}.toml")), wall.replace("MESH", mesh)).unwrap();
        bake(d, &[&format!("{mesh}.toml"), "-o", &format!("out-{mesh}"), "--device", "cpu", "--samples", "512"]);
    }
    let (leaning, _) = values(&d.join("out-leaning.ply").join("leaning.ply"), "vertex");
    let (plain, _) = values(&d.join("out-plain.ply").join("plain.ply"), "vertex");
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(mean(&leaning) < mean(&plain) - 0.1, "leaning {} plain {}", mean(&leaning), mean(&plain));
}

#[test]
fn bad_input_is_refused_in_one_line_with_nothing_written() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(2, 1.0, 0.0);
    std::fs::write(d.join("m.ply"), ply(&v, &f, None)).unwrap();
    let before = std::fs::read(d.join("m.ply")).unwrap();
    std::fs::write(
        d.join("empty.toml"),
        "[camera]\ntype = \"perspective\"\neye = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 45\n",
    )
    .unwrap();
    std::fs::write(d.join("bad.ply"), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n")
        .unwrap();
    for (args, expect) in [
        (&["m.ply", "-o", "m.ply"][..], "would replace the input"),
        (&["m.ply", "-o", "m.stl"][..], "cannot bake into '.stl' files"),
        (&["m.ply", "-o", "out.ply", "--samples", "0"][..], "--samples must be at least 1"),
        (&["m.ply", "-o", "out.ply", "--sample-range", "0..8"][..], "needs --checkpoint"),
        (&["empty.toml", "-o", "outdir"][..], "no mesh objects"),
        (&["bad.ply", "-o", "out.ply"][..], "bad.ply"),
        (&["missing.ply", "-o", "out.ply"][..], "missing.ply"),
    ] {
        bake_refused(args, d, expect);
    }
    assert_eq!(std::fs::read(d.join("m.ply")).unwrap(), before);
    let mut left: Vec<_> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["bad.ply", "empty.toml", "m.ply"]);
    // Writing over the input when asked to.
    let out = aorender(&["bake", "m.ply", "-o", "m.ply", "--overwrite", "--device", "cpu", "--samples", "4"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(values(&d.join("m.ply"), "vertex").0.len(), v.len());
}

/// Every format through the command: the baked file of each of the repository's meshes
/// loads again as the same triangles (rendering it gives the original's image, bit for
/// bit) and carries the values.
#[test]
fn every_format_round_trips_through_the_command() {
    let dir = temp_dir();
    let d = dir.path();
    let render = |mesh: &Path, out: &str| -> Vec<u8> {
        let args =
            ["render", mesh.to_str().unwrap(), "--device", "cpu", "--width", "48", "--height", "32", "--spp", "2"];
        let o = aorender(&[&args[..], &["-o", out]].concat(), d);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(d.join(out)).unwrap()
    };
    for (mesh, out) in [
        ("teapot.obj", "teapot-ao.obj"),
        ("dragon_vrip_res4.ply.gz", "dragon-ao.ply.gz"),
        ("2CylinderEngine.glb", "engine-ao.glb"),
        ("2CylinderEngine.glb", "engine-ao.gltf"),
    ] {
        let input = repo().join("scenes").join(mesh);
        let args = ["-o", out, "--device", "cpu", "--samples", "8", "--max-distance", "0.5", "--bent-normals"];
        bake(d, &[&[input.to_str().unwrap()][..], &args].concat());
        let original = render(&input, &format!("{out}-original.pfm"));
        let baked = render(&d.join(out), &format!("{out}-baked.pfm"));
        assert!(original == baked, "{mesh}: the baked file renders differently");
        let text = if out.ends_with(".gz") {
            let mut s = Vec::new();
            std::io::Read::read_to_end(
                &mut flate2::read::GzDecoder::new(&std::fs::read(d.join(out)).unwrap()[..]),
                &mut s,
            )
            .unwrap();
            s
        } else {
            std::fs::read(d.join(out)).unwrap()
        };
        let text = String::from_utf8_lossy(&text);
        match out.rsplit_once('.').unwrap().1 {
            "obj" => {
                let v: Vec<&str> = text.lines().filter(|l| l.starts_with("v ")).collect();
                assert!(!v.is_empty() && v.iter().all(|l| l.split_whitespace().count() == 7), "{mesh}");
            }
            "gz" => {
                let (ao, _) = values(&d.join(out), "vertex");
                assert!(ao.iter().all(|a| (0.0..=1.0).contains(a)) && ao.iter().any(|&a| a < 1.0), "{mesh}");
            }
            _ => assert!(["\"_AO\"", "\"COLOR_0\"", "\"_BENT_NORMAL\""].iter().all(|a| text.contains(a)), "{mesh}"),
        }
    }
}

/// The bent normal at each vertex of a floor beside a wall: from the same rays as the AO
/// (which is bit for bit the AO of a bake without bent normals), unit length, within 10°
/// of the normal where nothing occludes (the mean of 1024 cosine directions is 7
/// standard errors closer), and leaning away from the wall near it.
#[test]
fn bent_normals_lean_away_from_occluders() {
    let dir = temp_dir();
    let d = dir.path();
    let (v, f) = floor(12, 3.0, 0.0);
    std::fs::write(d.join("floor.ply"), ply(&v, &f, None)).unwrap();
    let wall = "[camera]\ntype = \"perspective\"\neye = [0, 5, 5]\nlook_at = [0, 0, 0]\nfov = 45\n\n\
         [[object]]\ntype = \"plane\"\npoint = [3.5, 0, 0]\nnormal = [-1, 0, 0]\n\n\
         [[object]]\ntype = \"mesh\"\nfile = \"floor.ply\"\n";
    std::fs::write(d.join("wall.toml"), wall).unwrap();
    for device in devices() {
        let args = ["--device", device, "--samples", "1024", "--seed", "5"];
        for (input, out) in [("floor.ply", format!("{device}-open.ply")), ("wall.toml", format!("{device}-wall"))] {
            bake(d, &[&[input, "-o", &out, "--bent-normals"][..], &args].concat());
            bake(d, &[&[input, "-o", &format!("plain-{out}")][..], &args].concat());
        }
        let open = d.join(format!("{device}-open.ply"));
        let walled = d.join(format!("{device}-wall")).join("floor.ply");
        for (bent, plain) in [
            (&open, d.join(format!("plain-{device}-open.ply"))),
            (&walled, d.join(format!("plain-{device}-wall")).join("floor.ply")),
        ] {
            assert_eq!(values(bent, "vertex").0, values(&plain, "vertex").0, "{device}: the AO changed");
        }
        let normals = |path: &Path| -> Vec<DVec3> {
            let ply = read_ply(path);
            ply.payload["vertex"]
                .iter()
                .map(|e| DVec3::new(float(e, "bnx") as f64, float(e, "bny") as f64, float(e, "bnz") as f64))
                .collect()
        };
        for (k, b) in normals(&open).iter().enumerate() {
            assert!((b.length() - 1.0).abs() < 1e-5, "{device}: vertex {k}: {b}");
            assert!(b.y > 10f64.to_radians().cos(), "{device}: open vertex {k} bends to {b}");
        }
        // The column of vertices nearest the wall (x = 3, 0.5 from it) leans away from it.
        let near: Vec<DVec3> =
            normals(&walled).into_iter().zip(&v).filter(|(_, p)| p.x > 2.9).map(|(b, _)| b).collect();
        assert_eq!(near.len(), 13);
        assert!(near.iter().all(|b| b.x < -0.2 && b.y > 0.0), "{device}: {near:?}");
    }
}

/// INPUT is required: without it `bake` is a usage error (status 2, one line naming it),
/// and its help names every format it reads, not a default scene.
#[test]
fn the_input_is_required_and_its_formats_are_listed() {
    let dir = temp_dir();
    let out = aorender(&["bake", "-o", "out.glb", "--device", "cpu"], dir.path());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.lines().count() == 1 && stderr.contains("<INPUT>"), "{stderr}");
    assert!(!dir.path().join("out.glb").exists());
    let help = aorender(&["bake", "--help"], dir.path());
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(help.contains("<INPUT>") && !help.contains("aobench"), "{help}");
    for format in [".obj", ".ply", ".gltf", ".glb", ".gz", ".toml"] {
        assert!(help.contains(format), "{format}: {help}");
    }
}

/// A bake's statistics account for its process phase by phase on both devices, with the
/// peak memory per triangle and per point traced; the summary line says the phases.
#[test]
fn bake_stats_account_for_every_phase() {
    let dir = temp_dir();
    let d = dir.path();
    let dragon = repo().join("scenes/dragon_vrip_res4.ply.gz");
    let mut devices = vec!["cpu"];
    if gpu_available() {
        devices.push("gpu");
    }
    for device in devices {
        let (output, json) = (format!("{device}.ply"), format!("{device}.json"));
        let args = [dragon.to_str().unwrap(), "-o", &output, "--samples", "32", "--stats", &json, "--device", device];
        let stderr = bake(d, &args);
        let stats = stats_json(d, &json);
        let points = stats["points_traced"].as_u64().unwrap();
        assert!(points > 1000, "{device}: {stats}");
        check_phases(&stats, device, Some(points));
        assert!(stats["triangles"].as_u64().unwrap() > 0 && stats["write_seconds"].as_f64().unwrap() > 0.0);
        assert_eq!(stats["checks"], 0);
        assert!(stderr.contains("read-back ") && stderr.contains("writing ") && stderr.contains("whole "), "{stderr}");
        check_summary(&stderr, device);
    }
}

/// A gzipped bake is one gzip member that holds the plain bake's bytes, and the same
/// bytes on any number of threads (its blocks are compressed in parallel): the full
/// dragon (33 MB of text, 32 blocks) into `.ply.gz` and, through the conversion writer,
/// `.obj.gz`, baked on one and on three rayon threads.
#[test]
fn gzipped_bakes_are_the_plain_bytes_and_the_same_on_any_thread_count() {
    let dir = temp_dir();
    let d = dir.path();
    let dragon = repo().join("scenes/dragon_vrip.ply.gz");
    let bake_on = |threads: usize, name: &str| -> Vec<u8> {
        let args = ["bake", dragon.to_str().unwrap(), "-o", name, "--samples", "1", "--device", "cpu", "--seed", "5"];
        aorender_on_threads(&args, d, threads);
        std::fs::read(d.join(name)).unwrap()
    };
    let gunzip = |gz: &[u8]| -> Vec<u8> {
        let mut text = Vec::new();
        // GzDecoder reads one member: data after it would be left unread.
        let mut decoder = flate2::read::GzDecoder::new(gz);
        std::io::Read::read_to_end(&mut decoder, &mut text).unwrap();
        assert!(decoder.into_inner().is_empty(), "bytes after the gzip member");
        text
    };
    for ext in ["ply", "obj"] {
        let plain = bake_on(2, &format!("plain.{ext}"));
        assert!(plain.len() > 30 << 20, "{ext}: {} bytes", plain.len());
        let one = bake_on(1, &format!("one.{ext}.gz"));
        let three = bake_on(3, &format!("three.{ext}.gz"));
        assert!(one.len() < plain.len() / 2, "{ext}: {} bytes gzipped of {}", one.len(), plain.len());
        assert!(one == three, "{ext}: the gzipped bytes differ between one thread and three");
        assert!(gunzip(&one) == plain, "{ext}: the gzipped bake holds other bytes than the plain one");
    }
}
