//! A CWBVH built in octree cells (so the build's workspace stays bounded) is a valid obvhs
//! CWBVH holding every primitive exactly once, whatever the cell size, and a ray finds the
//! same nearest hit in it as in the CWBVH obvhs builds whole. The cells are built side by
//! side on rayon's threads, and the tree is the same, bit for bit, on any number of them.

mod common;
use aorender::Scene;
use aorender::bvh::BuildQuality;
use aorender::bvh::build::{build_cwbvh_in_cells, primitive_aabbs};
use aorender::cpu::CpuTracer;
use common::*;
use glam::Vec3;
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;

/// A scene with every kind of top-level primitive: the dragon's triangles, spheres, and a
/// teapot placed three times (instances of one mesh).
fn scene() -> Scene {
    let dir = repo().join("scenes");
    let mut text = String::from(
        "[camera]\ntype = \"perspective\"\neye = [0, 0.5, 2]\nlook_at = [0, 0, 0]\nfov = 45\n\n\
         [[object]]\ntype = \"mesh\"\nfile = \"dragon_vrip_res4.ply.gz\"\ntransform = { scale = [4, 4, 4] }\n",
    );
    for (k, x) in [-1.5f32, 0.0, 1.5].into_iter().enumerate() {
        text += &format!(
            "\n[[object]]\ntype = \"mesh\"\nfile = \"teapot.obj\"\n\
             transform = {{ scale = [0.1, 0.1, 0.1], rotate = [0, {}, 0], translate = [{x}, -0.5, -1] }}\n",
            40 * k
        );
        text += &format!("\n[[object]]\ntype = \"sphere\"\ncenter = [{x}, 0.6, -0.5]\nradius = 0.2\n");
    }
    let scene = Scene::from_toml_str(&text, &dir.join("cells.toml"), &dir).unwrap_or_else(|e| panic!("{e}"));
    assert!(scene.triangles.len() > 10_000 && scene.spheres.len() == 3 && scene.instances.len() == 3);
    scene
}

/// Sizes from one primitive a cell (the deepest joined tree) to the whole scene in one.
const CELLS: [usize; 5] = [1, 7, 300, 4096, usize::MAX];

#[test]
fn cells_of_any_size_give_a_valid_bvh_with_every_primitive_once() {
    let scene = scene();
    let top_boxes = primitive_aabbs(&scene);
    for cell in CELLS {
        let bvh = build_cwbvh_in_cells(&scene, BuildQuality::Medium, cell);
        let top = bvh.top.as_ref().expect("a top level");
        // obvhs's own check: every node reached once, child boxes quantized as stored and
        // holding their primitives, depth within its traversal stack.
        let result = top.validate(&top_boxes, false);
        eprintln!("cells of {cell}: {} nodes, depth {}", top.nodes.len(), result.max_depth);
        let mut ids = top.primitive_indices.clone();
        ids.sort_unstable();
        assert!(ids.iter().copied().eq(0..top_boxes.len() as u32), "cells of {cell}: not every primitive once");
        assert_eq!(bvh.meshes.len(), 1);
        let mesh = &scene.meshes[0].triangles;
        let mesh_boxes: Vec<Aabb> = mesh
            .iter()
            .map(|t| {
                let v = t.map(glam::Vec3A::from);
                Aabb::new(v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
            })
            .collect();
        bvh.meshes[0].validate(&mesh_boxes, false);
        let mut ids = bvh.meshes[0].primitive_indices.clone();
        ids.sort_unstable();
        assert!(ids.iter().copied().eq(0..mesh.len() as u32), "cells of {cell}: not every mesh triangle once");
    }
}

#[test]
fn cells_trace_the_same_nearest_hits_as_a_whole_build() {
    let scene = scene();
    let whole = CpuTracer::new(&scene, build_cwbvh_in_cells(&scene, BuildQuality::Medium, usize::MAX));
    // Rays from points spread around the scene towards points near its primitives (most
    // hit something, often not the primitive aimed at), and some in any direction.
    let boxes = primitive_aabbs(&scene);
    let (lo, hi) = (Vec3::new(-2.5, -1.0, -2.0), Vec3::new(2.5, 1.5, 1.5));
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let rays: Vec<(Vec3, Vec3)> = (0..20_000)
        .map(|k| {
            let o = lo + (hi - lo) * Vec3::new(uniform(), uniform(), uniform());
            let d = if k % 4 == 0 {
                Vec3::new(uniform(), uniform(), uniform()) - 0.5
            } else {
                let b = &boxes[((uniform() * boxes.len() as f32) as usize).min(boxes.len() - 1)];
                let jitter = (Vec3::new(uniform(), uniform(), uniform()) - 0.5) * 0.02;
                Vec3::from(b.center()) + jitter - o
            };
            (o, d.normalize())
        })
        .collect();
    let expected: Vec<Option<f32>> =
        rays.iter().map(|&(o, d)| whole.closest(o, d, f32::INFINITY).map(|h| h.0)).collect();
    let hits = expected.iter().filter(|t| t.is_some()).count();
    assert!(hits > rays.len() / 2 && hits < rays.len(), "{hits} of {} rays hit: a poor probe", rays.len());
    for cell in CELLS {
        let cells = CpuTracer::new(&scene, build_cwbvh_in_cells(&scene, BuildQuality::Medium, cell));
        for (k, (&(o, d), want)) in rays.iter().zip(&expected).enumerate() {
            let got = cells.closest(o, d, f32::INFINITY).map(|h| h.0);
            // The same triangles and the same intersection test: the same distance, bit for bit.
            assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "cells of {cell}: ray {k} from {o} along {d}");
            if let Some(t) = want {
                assert!(cells.occluded(o, d, t * 1.0001), "cells of {cell}: ray {k} is not occluded before its hit");
            }
        }
    }
}

/// The nodes and primitive order of every CWBVH of a build, as bytes.
fn tree_bytes(bvh: &aorender::bvh::SceneCwbvh) -> Vec<u8> {
    let mut bytes = Vec::new();
    for b in bvh.top.iter().chain(&bvh.meshes) {
        let b: &CwBvh = b;
        bytes.extend_from_slice(bytemuck::cast_slice(&b.nodes));
        bytes.extend_from_slice(bytemuck::cast_slice(&b.primitive_indices));
    }
    bytes
}

#[test]
fn cells_build_the_same_tree_on_any_number_of_threads() {
    let scene = scene();
    let n = primitive_aabbs(&scene).len();
    // One cell for all and one primitive short of it (the first cut), cells just under
    // and over 1/8 of the scene, and cells small enough for several built at once (one
    // lane per 16 cells, or as many as 64 MiB holds).
    let cells = [n, n - 1, n / 8, n / 8 + 1, n / 40, n / 40 + 1];
    for cell in cells {
        let pool = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
        let one = pool(1).install(|| build_cwbvh_in_cells(&scene, BuildQuality::Medium, cell));
        let expected = tree_bytes(&one);
        assert!(expected.len() > n, "cells of {cell}: an empty tree");
        for threads in [2, 3, 8] {
            let built = pool(threads).install(|| build_cwbvh_in_cells(&scene, BuildQuality::Medium, cell));
            assert!(tree_bytes(&built) == expected, "cells of {cell}: {threads} threads build another tree");
            assert_eq!(built.duplicates, one.duplicates);
        }
    }
}
