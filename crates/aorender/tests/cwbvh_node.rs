//! The CWBVH node's WGSL decoder (`src/bvh/cwbvh/node.wgsl`) against its Rust side, on the
//! adapter: BVHs built by obvhs with every preset, of a mesh and of a scene with instanced
//! meshes, are laid out for the upload as the renderer does, and
//! `tests/kernels/cwbvh_node_probe.wgsl` decodes every child slot of every node for rays
//! of each of the eight octants. Each child's box is obvhs's own decoding of it, bit for
//! bit, and holds every primitive below it up to the rounding of the encoding and the
//! decoding (the kernel's box exits are widened for rounding); its hit bits and the node or primitives they
//! name are obvhs's, moved to the child's place in the upload; an empty slot is never hit.

mod common;
use aorender::Scene;
use aorender::bvh::build::{SceneCwbvh, build_cwbvh, primitive_aabbs};
use aorender::bvh::cwbvh::placed;
use aorender::bvh::{BuildQuality, GpuBvh};
use common::kernel::{self, TestKernel};
use common::*;
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::cwbvh::node::CwBvhNode;

/// The probe kernel's file name and text.
const PROBE_NAME: &str = "cwbvh_node_probe.wgsl";
const PROBE: &str = include_str!("kernels/cwbvh_node_probe.wgsl");

/// One of the scene's BVHs as laid out in the upload: its nodes start at `node_base`, its
/// primitive records at `primitive_base`; `content(id)` is the box of its primitive `id`.
struct Placed<'a> {
    bvh: &'a CwBvh,
    node_base: u32,
    primitive_base: u32,
    content: Box<dyn Fn(u32) -> Aabb + 'a>,
}

/// The scene's BVHs in upload order: the top level, then each instanced mesh's.
fn placements<'a>(scene: &'a Scene, cwbvh: &'a SceneCwbvh) -> Vec<Placed<'a>> {
    let top = cwbvh.top.as_ref().expect("the scene has primitives");
    let top_boxes = primitive_aabbs(scene);
    let mut out =
        vec![Placed { bvh: top, node_base: 0, primitive_base: 0, content: Box::new(move |id| top_boxes[id as usize]) }];
    let (mut node_base, mut primitive_base) = (top.nodes.len() as u32, top.primitive_indices.len() as u32);
    for (m, bvh) in cwbvh.meshes.iter().enumerate() {
        let triangles = &scene.meshes[m].triangles;
        let content = move |id: u32| {
            let [a, b, c] = triangles[id as usize];
            Aabb::new(a.min(b).min(c).into(), a.max(b).max(c).into())
        };
        out.push(Placed { bvh, node_base, primitive_base, content: Box::new(content) });
        node_base += bvh.nodes.len() as u32;
        primitive_base += bvh.primitive_indices.len() as u32;
    }
    out
}

/// The box of everything below child `slot` of node `n` of `p`.
fn child_content(p: &Placed, n: &CwBvhNode, slot: usize) -> Aabb {
    if n.is_leaf(slot) {
        let (first, count) = n.child_primitives(slot);
        (first..first + count).fold(Aabb::empty(), |b, k| b.union(&(p.content)(p.bvh.primitive_indices[k as usize])))
    } else {
        let child = &p.bvh.nodes[n.child_node_index(slot) as usize];
        (0..8).filter(|&s| !child.is_child_empty(s)).fold(Aabb::empty(), |b, s| b.union(&child_content(p, child, s)))
    }
}

/// The distance from `x` (finite, not negative) to the next float up.
fn ulp(x: f32) -> f32 {
    f32::from_bits(x.to_bits() + 1) - x
}

/// Decodes every node of `scene`'s CWBVH built with `quality` on the adapter and checks
/// each child against obvhs's decoding and the primitives below it.
fn check_decoding(probe: &TestKernel, scene: &Scene, quality: BuildQuality, what: &str) {
    let cwbvh = build_cwbvh(scene, quality);
    let gpu = GpuBvh::from_cwbvh(scene, &cwbvh);
    let uploaded: Vec<CwBvhNode> = bytemuck::pod_collect_to_vec(&gpu.node_bytes);
    let places = placements(scene, &cwbvh);
    assert_eq!(places.iter().map(|p| p.bvh.nodes.len()).sum::<usize>(), uploaded.len(), "{what}");
    let count = 8 * uploaded.len() as u32;
    let (mut checked, mut short) = ([0usize; 2], 0);
    for octant in 0..8u32 {
        let out: Vec<[u32; 4]> = probe.run("decode", [count, octant, 0, 0], &[&gpu.node_bytes], count, 2);
        // The ray's octant inverted, as octant_inverse4 gives it for each byte.
        let oct_inv = octant ^ 7;
        for p in &places {
            for (k, source) in p.bvh.nodes.iter().enumerate() {
                let index = p.node_base as usize + k;
                let node = placed(source, p.node_base, p.primitive_base);
                assert_eq!(uploaded[index], node, "{what}: node {index} is not obvhs's, placed");
                for slot in 0..8 {
                    let [lo, hi] = [&out[2 * (8 * index + slot)], &out[2 * (8 * index + slot) + 1]];
                    let (hits, named) = (lo[3], hi[3]);
                    let at = format!("{what}, octant {octant}: node {index} slot {slot}");
                    if node.is_child_empty(slot) {
                        assert_eq!(hits, 0, "{at}: an empty slot is hit");
                        continue;
                    }
                    let decoded = [0, 1, 2].map(|a| (f32::from_bits(lo[a]), f32::from_bits(hi[a])));
                    let expected = node.child_aabb(slot);
                    let content = child_content(p, source, slot);
                    for (a, (min, max)) in decoded.into_iter().enumerate() {
                        assert_eq!(min.to_bits(), expected.min[a].to_bits(), "{at}: minimum on axis {a}");
                        assert_eq!(max.to_bits(), expected.max[a].to_bits(), "{at}: maximum on axis {a}");
                        // The encoder rounds x − p before it rounds outwards to a step, and
                        // the decoder rounds step × byte + p: a plane may fall short of
                        // the content by these two roundings, one ulp of |x| or |p| at most.
                        let slack = |x: f32| ulp(x.abs().max(node.p[a].abs()));
                        let (want_min, want_max) = (content.min[a], content.max[a]);
                        assert!(
                            min <= want_min + slack(want_min) && want_max - slack(want_max) <= max,
                            "{at}: [{min}, {max}] on axis {a} does not hold [{want_min}, {want_max}]",
                        );
                        short += usize::from(min > want_min) + usize::from(max < want_max);
                    }
                    if node.is_leaf(slot) {
                        let (first, primitives) = node.child_primitives(slot);
                        assert_eq!(hits >> 24, 0, "{at}: a leaf's hit bits name an inner child");
                        assert_eq!((named, hits.count_ones()), (first, primitives), "{at}: the leaf's primitives");
                        let run = hits >> hits.trailing_zeros();
                        assert_eq!(run & (run + 1), 0, "{at}: the leaf's hit bits {hits:#x} are not one run");
                        checked[0] += 1;
                    } else {
                        let slot_bit = (node.child_meta[slot] as u32 & 0x1f) - 24;
                        assert_eq!(hits, 1 << (24 + (slot_bit ^ oct_inv)), "{at}: the inner child's hit bit");
                        assert_eq!(named, node.child_node_index(slot), "{at}: the inner child's node");
                        checked[1] += 1;
                    }
                }
            }
        }
    }
    eprintln!(
        "{what}: {} nodes, {} leaves and {} inner children decoded; {short} planes short of their content by rounding",
        uploaded.len(),
        checked[0],
        checked[1]
    );
    assert!(checked[0] > 0 && checked[1] > 0, "{what}: no leaf or no inner child");
}

#[test]
fn the_wgsl_decoder_gives_obvhs_children_placed_in_the_upload() {
    let probe_source = kernel::compose(PROBE_NAME, PROBE);
    kernel::validate(PROBE_NAME, &probe_source);
    let probe = TestKernel::new(PROBE_NAME, PROBE, &["decode"], 1);
    let bunny = Scene::load(&repo().join("scenes/bunny.obj")).unwrap_or_else(|e| panic!("{e}"));
    // A mesh placed three times (its own BVH, entered through instances) beside triangles
    // placed once (in the top level with the instances).
    let dir = temp_dir();
    write_obj(&dir.path().join("mesh.obj"), &floor_and_box());
    write_obj(&dir.path().join("once.obj"), &floor_and_box()[..40]);
    let mut text = String::from(
        "[camera]\ntype = \"perspective\"\neye = [3.0, 4.0, 6.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 50.0\n",
    );
    for t in ["[0.0, 0.0, 0.0]", "[4.5, 0.2, 0.5]", "[-1.5, 0.1, -5.0]"] {
        text += &format!("[[object]]\ntype = \"mesh\"\nfile = \"mesh.obj\"\ntransform = {{ translate = {t} }}\n");
    }
    text += "[[object]]\ntype = \"mesh\"\nfile = \"once.obj\"\ntransform = { translate = [0.0, 3.0, 0.0] }\n";
    let instanced = scene_from_toml(&text, dir.path());
    assert_eq!((instanced.instances.len(), instanced.meshes.len()), (3, 1), "the mesh is instanced");
    for quality in BuildQuality::ALL {
        check_decoding(&probe, &bunny, quality, &format!("bunny, {}", quality.name()));
        check_decoding(&probe, &instanced, quality, &format!("instances, {}", quality.name()));
    }
}
