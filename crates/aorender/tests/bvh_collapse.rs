//! The BVH2 → CWBVH conversion (`bvh::collapse`) makes obvhs's CWBVH bit for bit: the same
//! nodes and primitive order as `obvhs::cwbvh::bvh2_to_cwbvh` on BVH2s of every shape the
//! build gives it (PLOC's trees reinserted, trees built in parts, balanced trees, and the
//! smallest ones), for one to three primitives a leaf.

mod common;
use aorender::Scene;
use aorender::bvh::build::primitive_aabbs;
use aorender::bvh::collapse;
use aorender::bvh::ploc::{build_balanced_bvh2, build_bvh2};
use common::*;
use glam::Vec3A;
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;

/// Asserts that both conversions of `bvh2` agree, for every leaf size.
fn same_as_obvhs(bvh2: &Bvh2, what: &str) {
    for leaf in 1..=3 {
        let ours = collapse::bvh2_to_cwbvh(bvh2, leaf);
        let theirs = obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh(bvh2, leaf, true, false);
        assert!(!ours.nodes.is_empty() || bvh2.nodes.is_empty(), "{what}: no nodes");
        assert!(
            bytemuck::cast_slice::<_, u8>(&ours.nodes) == bytemuck::cast_slice::<_, u8>(&theirs.nodes),
            "{what}, {leaf} a leaf: the nodes differ"
        );
        assert_eq!(ours.primitive_indices, theirs.primitive_indices, "{what}, {leaf} a leaf");
        assert_eq!(ours.total_aabb, theirs.total_aabb, "{what}, {leaf} a leaf");
    }
}

/// Boxes from a fixed random sequence: `n` small boxes in the unit cube.
fn random_boxes(n: usize) -> Vec<Aabb> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| {
            let c = Vec3A::new(uniform(), uniform(), uniform());
            let h = Vec3A::new(uniform(), uniform(), uniform()) * 0.02;
            Aabb::new(c - h, c + h)
        })
        .collect()
}

#[test]
fn the_conversion_is_obvhs_on_meshes_and_random_boxes() {
    let params = BvhBuildParams::medium_build();
    let mut inputs: Vec<(String, Vec<Aabb>)> =
        [1, 2, 3, 4, 9, 100, 5000].into_iter().map(|n| (format!("{n} random boxes"), random_boxes(n))).collect();
    for mesh in ["scenes/bunny.obj", "scenes/dragon_vrip_res4.ply.gz"] {
        let scene = Scene::load(&repo().join(mesh)).unwrap_or_else(|e| panic!("{e}"));
        inputs.push((mesh.to_string(), primitive_aabbs(&scene)));
    }
    for (what, boxes) in &inputs {
        // PLOC's tree as the build converts it: reinserted.
        let (mut ploc, _) = build_bvh2(boxes, &params, true);
        ReinsertionOptimizer::default().run(&mut ploc, params.reinsertion_batch_ratio, None);
        same_as_obvhs(&ploc, &format!("{what}, PLOC"));
        same_as_obvhs(&build_bvh2(boxes, &params, false).0, &format!("{what}, in parts"));
        same_as_obvhs(&build_balanced_bvh2(boxes, params.sort_precision), &format!("{what}, balanced"));
    }
}

#[test]
fn the_conversion_is_obvhs_on_coincident_and_flat_boxes() {
    let params = BvhBuildParams::medium_build();
    // One box for all (every cost ties), and boxes flat on an axis (zero extents).
    let one = vec![Aabb::new(Vec3A::ZERO, Vec3A::ONE); 3000];
    let flat: Vec<Aabb> = (0..3000)
        .map(|i| {
            let x = i as f32 / 3000.0;
            Aabb::new(Vec3A::new(x, 0.0, -1.0), Vec3A::new(x, 0.5, -1.0))
        })
        .collect();
    for (what, boxes) in [("coincident boxes", one), ("flat boxes", flat)] {
        same_as_obvhs(&build_bvh2(&boxes, &params, false).0, &format!("{what}, in parts"));
        same_as_obvhs(&build_balanced_bvh2(&boxes, params.sort_precision), &format!("{what}, balanced"));
    }
}
