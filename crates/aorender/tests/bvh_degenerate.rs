//! BVHs over degenerate input: copies of one triangle, the fan of a polygon of a million
//! sides, the fan of a polyline face. Each builds as a tree O(log n) deep with O(n) nodes
//! (the structure of a near-linear build: obvhs's PLOC alone made chains n deep in n
//! passes of O(n) work), the GPU renders them as the CPU reference does, and on ordinary
//! meshes the build is still obvhs's, node for node.

mod common;
use aorender::Scene;
use aorender::bvh::build::{MIN_COPIES, build_cwbvh, primitive_aabbs};
use aorender::bvh::ploc::{build_ploc, bvh2_over, cwbvh_depth, cwbvh_over, depth, depth_bound, sorted_leaves};
use aorender::bvh::{BuildQuality, BvhLayout, GpuBvh};
use aorender::scene::Triangle;
use common::*;
use glam::Vec3;
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use std::path::Path;
use std::time::Duration;

/// Runs `f` on its own thread and fails if it takes longer than `limit`: a guard against
/// a build that hangs, not a measure of its speed (the assertions are on the trees).
fn within<T: Send + 'static>(limit: Duration, what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    let worker = std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(limit) {
        Ok(value) => value,
        Err(std::sync::mpsc::RecvTimeoutError::Timeout) => panic!("{what}: not done in {limit:?}"),
        // It panicked: pass its panic on.
        Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => match worker.join() {
            Err(panic) => std::panic::resume_unwind(panic),
            Ok(()) => unreachable!("{what}: the worker ended without a result"),
        },
    }
}

/// The hang guard of every build below: minutes, where each takes seconds.
const WATCHDOG: Duration = Duration::from_secs(600);

/// ⌈log₈ n⌉.
fn log8(n: usize) -> u32 {
    let mut levels = 0;
    while 8usize.pow(levels) < n {
        levels += 1;
    }
    levels
}

/// The bound the top-level CWBVH's depth is held to: 2 ⌈log₈ n⌉ + 8 levels, a cell's
/// bound (`cwbvh_depth_bound`, 2 ⌈log₈ n⌉ + 3) and the octree levels above the cells (a
/// curve of centroids, such as a polygon's fan, branches in two or three at each).
/// Chains of copies took n / 7 levels.
fn cwbvh_bound(n: usize) -> u32 {
    2 * log8(n) + 8
}

/// Writes an OBJ file of `vertices` and one face through all of them, in order.
fn write_polygon(path: &Path, vertices: &[[f32; 3]]) {
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    for v in vertices {
        writeln!(out, "v {} {} {}", v[0], v[1], v[2]).unwrap();
    }
    write!(out, "f").unwrap();
    for k in 1..=vertices.len() {
        write!(out, " {k}").unwrap();
    }
    writeln!(out).unwrap();
}

/// The checks every degenerate scene's BVHs pass: the CWBVH (in octree cells, as
/// sessions build it) valid, every primitive of `expected` in it once, at most
/// [`cwbvh_bound`] deep and with fewer nodes than primitives; the BVH2 layout's tree
/// within its bound and the GPU's stack.
fn check_trees(scene: Scene, what: &str, expected: usize) {
    let what = what.to_string();
    within(WATCHDOG, &what.clone(), move || {
        let bvh = build_cwbvh(&scene, BuildQuality::Medium);
        let top = bvh.top.as_ref().expect("a top level");
        let n = top.primitive_indices.len();
        assert_eq!(n + bvh.duplicates, scene.triangles.len(), "{what}");
        assert_eq!(n, expected, "{what}: primitives in the BVH");
        // obvhs's own check, where the BVH holds every primitive.
        if bvh.duplicates == 0 {
            top.validate(&primitive_aabbs(&scene), false);
        }
        let mut ids = top.primitive_indices.clone();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), n, "{what}: a primitive twice");
        let depth = cwbvh_depth(top);
        eprintln!("{what}: {n} primitives, cwbvh {} nodes, {depth} levels, bound {}", top.nodes.len(), cwbvh_bound(n));
        assert!(depth <= cwbvh_bound(n), "{what}: the CWBVH is {depth} levels deep");
        assert!(top.nodes.len() <= n.max(1), "{what}: {} nodes for {n} primitives", top.nodes.len());
        let gpu = GpuBvh::build(&scene, BvhLayout::Bvh2, BuildQuality::Medium);
        eprintln!("{what}: bvh2 {} nodes, {} levels", gpu.node_count, gpu.depth);
        assert!(gpu.depth as usize <= depth_bound(n), "{what}: the BVH2 is {} levels deep", gpu.depth);
        assert!(gpu.depth <= BvhLayout::Bvh2.stack_size(), "{what}: the BVH2 is {} levels deep", gpu.depth);
        assert!((gpu.node_count as usize) < 2 * n, "{what}: {} BVH2 nodes", gpu.node_count);
    });
}

/// `n` copies of one triangle, each its own albedo so that none is a duplicate of
/// another: every box and every centroid the same.
fn coincident(n: usize) -> Scene {
    let v = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let triangles = (0..n).map(|k| Triangle { v, albedo: 0.25 + k as f32 * 2f32.powi(-24) }).collect();
    Scene::from_triangles("coincident", triangles)
}

#[test]
fn coincident_triangles_build_shallow_trees() {
    for n in [100_000, 1_000_000] {
        // Every one of them in the BVH.
        check_trees(coincident(n), &format!("{n} coincident triangles"), n);
    }
}

/// Copies are left out of the BVH, 16 or more of one triangle: 1,000,000 copies with one
/// albedo leave one, and the count of the others; 15 copies stay, and so do the same
/// vertices with another albedo or in another order.
#[test]
fn copies_are_left_out_and_counted() {
    let v = [Vec3::ZERO, Vec3::X, Vec3::Y];
    let n = 1_000_000;
    let mut triangles = vec![Triangle { v, albedo: 0.5 }; n];
    triangles.push(Triangle { v, albedo: 0.75 });
    triangles.push(Triangle { v: [v[1], v[2], v[0]], albedo: 0.5 });
    triangles.extend(vec![Triangle { v: [v[0], v[1], Vec3::Z], albedo: 0.5 }; MIN_COPIES - 1]);
    let scene = Scene::from_triangles("copies", triangles);
    check_trees(scene, "copies", 3 + MIN_COPIES - 1);
}

/// One face of a million vertices on a circle, as an OBJ file: the loader's fan has every
/// triangle's box hold the first vertex, each box inside the next along the curve.
#[test]
fn a_polygon_of_a_million_sides_builds_a_shallow_tree() {
    let dir = temp_dir();
    let path = dir.path().join("polygon.obj");
    let n = 1_000_000;
    let vertices: Vec<[f32; 3]> = (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            [a.cos() as f32, a.sin() as f32, 0.0]
        })
        .collect();
    write_polygon(&path, &vertices);
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    // Neighbours on the circle round to collinear triples in f32 now and then: those
    // triangles are dropped as degenerate.
    let triangles = scene.triangles.len();
    assert!(triangles > n - 1000 && triangles <= n - 2, "{triangles} triangles");
    check_trees(scene, "a polygon of 1,000,000 sides", triangles);
}

/// One face through the points of a polyline (the shape of an importer's test file that
/// made a 37-level tree from a few hundred vertices): every fan triangle a sliver from
/// the first point.
#[test]
fn a_polyline_face_builds_a_shallow_tree() {
    let dir = temp_dir();
    let path = dir.path().join("polyline.obj");
    let n = 100_000;
    let vertices: Vec<[f32; 3]> =
        (0..n).map(|k| [k as f32 / n as f32, (k % 2) as f32 * 0.01, (k % 3) as f32 * 0.001]).collect();
    write_polygon(&path, &vertices);
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let triangles = scene.triangles.len();
    assert!(triangles > n / 2, "{triangles} triangles");
    check_trees(scene, "a polyline face of 100,000 points", triangles);
}

/// obvhs's presets, as `BuildQuality` names them.
const PRESETS: [(&str, BvhBuildParams); 4] = [
    ("fastest", BvhBuildParams::fastest_build()),
    ("fast", BvhBuildParams::fast_build()),
    ("medium", BvhBuildParams::medium_build()),
    ("slow", BvhBuildParams::slow_build()),
];

/// The boxes of a mesh's triangles, in order.
fn mesh_boxes(path: &Path) -> Vec<Aabb> {
    let scene = Scene::load(path).unwrap_or_else(|e| panic!("{e}"));
    primitive_aabbs(&scene)
}

/// On ordinary meshes the build is obvhs's own, node for node, for every preset: PLOC
/// (never stopped, never too deep), its CWBVH, and its BVH2 with leaves collapsed. The
/// films of the repository's scenes therefore do not change.
#[test]
fn ordinary_meshes_build_obvhs_trees_node_for_node() {
    let meshes =
        ["scenes/bunny.obj", "scenes/teapot.obj", "scenes/dragon_vrip_res4.ply.gz", "scenes/2CylinderEngine.glb"];
    for mesh in meshes {
        let boxes = mesh_boxes(&repo().join(mesh));
        let n = boxes.len();
        let ids: Vec<u32> = (0..n as u32).collect();
        for (quality, params) in PRESETS {
            let what = format!("{mesh}, {quality}");
            let ploc = build_ploc(sorted_leaves(&boxes, params.sort_precision), &params).unwrap_or_else(|| {
                panic!("{what}: PLOC stopped");
            });
            let theirs = obvhs::ploc::PlocBuilder::with_capacity(n).build(
                params.ploc_search_distance,
                &boxes,
                ids.clone(),
                params.sort_precision,
                params.search_depth_threshold,
            );
            assert!(bytemuck::cast_slice::<_, u8>(&ploc) == bytemuck::cast_slice::<_, u8>(&theirs.nodes), "{what}");
            assert!(depth(&ploc) <= depth_bound(n), "{what}: {} levels", depth(&ploc));

            let cw = cwbvh_over(&boxes, &params);
            let theirs = obvhs::cwbvh::builder::build_cwbvh(&boxes, params, &mut Default::default());
            assert!(bytemuck::cast_slice::<_, u8>(&cw.nodes) == bytemuck::cast_slice::<_, u8>(&theirs.nodes), "{what}");
            assert_eq!(cw.primitive_indices, theirs.primitive_indices, "{what}");

            let b2 = bvh2_over(&boxes, &params);
            let theirs = obvhs::bvh2::builder::build_bvh2(&boxes, params, &mut Default::default());
            assert!(bytemuck::cast_slice::<_, u8>(&b2.nodes) == bytemuck::cast_slice::<_, u8>(&theirs.nodes), "{what}");
            assert_eq!(b2.primitive_indices, theirs.primitive_indices, "{what}");
            eprintln!("{what}: {n} primitives, cwbvh {} levels, bvh2 {} levels", cwbvh_depth(&cw), depth(&b2.nodes));
        }
    }
}

/// The bunny standing on a floor made of `floor` (triangles under it), framed as a bare
/// mesh, 48 × 48 at 16 samples per pixel.
fn bunny_on(floor: Vec<Triangle>) -> Scene {
    let mut scene = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    scene.triangles.extend(floor);
    (scene.settings.width, scene.settings.height, scene.settings.spp) = (48, 48, 16);
    scene
}

/// A floor triangle under the bunny (its feet are at y ≈ 0.033).
const FLOOR: [Vec3; 3] = [Vec3::new(-0.4, 0.033, -0.3), Vec3::new(0.3, 0.033, -0.3), Vec3::new(0.0, 0.033, 0.4)];

/// Renders `scene` on the CPU reference and on the GPU in both layouts: every pixel the
/// same within float rounding (a GPU may round a sample's arithmetic otherwise), the floor
/// and the bunny in view; returns the duplicates the BVH left out.
fn gpu_matches_cpu(scene: &Scene, what: &str) -> usize {
    let cpu_session = session(scene, &Config::cpu());
    let cpu = render_settings(&cpu_session, &scene.settings);
    assert!(cpu.image_mean() > 0.1, "{what}: the scene is not in view");
    let duplicates = cpu_session.setup().bvh_duplicates;
    for layout in [BvhLayout::Cwbvh, BvhLayout::Bvh2] {
        let gpu_session = session(scene, &Config::gpu(layout));
        assert_eq!(gpu_session.setup().bvh_duplicates, duplicates, "{what}, {layout:?}");
        let gpu = render_settings(&gpu_session, &scene.settings);
        let (a, b) = (gpu.mean(), cpu.mean());
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst <= 1e-5, "{what}, {layout:?}: a pixel differs by {worst}");
    }
    duplicates
}

/// The bunny on a floor of 256, 10,000 and 100,000 copies of one triangle renders on the
/// GPU as on the CPU reference; the copies beyond the first are left out and counted
/// (before, 256 copies made a BVH 37 levels deep, past the GPU's stack, and 100,000 more
/// steps than lavapipe's loop cap lets a ray take).
#[test]
fn coincident_triangles_render_on_the_gpu_as_on_the_cpu() {
    if !gpu_available() {
        return;
    }
    for n in [256, 10_000, 100_000] {
        let scene = bunny_on(vec![Triangle { v: FLOOR, albedo: 0.8 }; n]);
        assert_eq!(gpu_matches_cpu(&scene, &format!("{n} copies")), n - 1);
    }
}

/// The bunny on a floor that is one polygon of 10,000 sides, fanned: the BVH is built in
/// parts (PLOC stops on the fan), and the GPU traces it as the CPU does.
#[test]
fn a_fanned_polygon_renders_on_the_gpu_as_on_the_cpu() {
    if !gpu_available() {
        return;
    }
    let n = 10_000;
    let at = |k: usize| {
        let a = std::f32::consts::TAU * k as f32 / n as f32;
        Vec3::new(0.4 * a.cos() - 0.02, 0.033, 0.4 * a.sin())
    };
    let fan: Vec<Triangle> = (1..n - 1).map(|k| Triangle { v: [at(0), at(k), at(k + 1)], albedo: 0.8 }).collect();
    let boxes: Vec<Aabb> = fan
        .iter()
        .map(|t| {
            let v = t.v.map(glam::Vec3A::from);
            Aabb::new(v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
        })
        .collect();
    let params = BvhBuildParams::medium_build();
    assert!(build_ploc(sorted_leaves(&boxes, params.sort_precision), &params).is_none(), "PLOC stops on the fan");
    assert_eq!(gpu_matches_cpu(&bunny_on(fan), "a fanned polygon"), 0);
}

/// Every render of a scene with copies reports the count it left out.
#[test]
fn the_statistics_count_the_duplicates() {
    let scene = bunny_on(vec![Triangle { v: FLOOR, albedo: 0.8 }; 20]);
    let s = session(&scene, &Config::cpu());
    let out = s.render(&s.default_request()).unwrap().complete(&mut aorender::Control::default()).unwrap();
    assert_eq!(out.stats.duplicates_dropped, 19);
}
