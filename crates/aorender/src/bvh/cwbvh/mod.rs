//! obvhs's compressed 8-wide BVH node (Ylitie, Karras & Laine, "Efficient Incoherent Ray
//! Traversal on GPUs Through Compressed Wide BVHs", HPG 2017) on the device: the Rust side
//! here, the WGSL decoder beside it in `node.wgsl` ([`NODE_WGSL`]), which the kernel's
//! traversals import as `cwbvh_node.wgsl`.
//!
//! obvhs encodes each node ([`CwBvhNode`], 80 bytes), and so does [`inner_node`] for the
//! nodes that join a build's octree cells; a cell's or an instanced mesh's nodes are moved
//! to where its nodes and primitives start ([`placed`]); the kernel reads the node as five
//! words ([`CwNodeWords`]). The decoder turns those words back into each child's box, hit
//! bits and the node or primitives they name. `tests/cwbvh_node.rs` runs it on the
//! adapter over built BVHs and compares every child with obvhs's own decoding and the
//! primitives below it.

use crate::mirror::gpu_struct;
use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::cwbvh::node::CwBvhNode;

/// The WGSL decoder of the node, `node.wgsl`, imported as `cwbvh_node.wgsl`.
pub const NODE_WGSL: &str = include_str!("node.wgsl");

gpu_struct! {
    /// obvhs's `CwBvhNode` (80 bytes) as the kernel reads it, five words at a time:
    /// `n0 = (p.x, p.y, p.z, e.x | e.y << 8 | e.z << 16 | imask << 24)`, `n1 = (child_base_idx,
    /// primitive_base_idx, child_meta[0..4], child_meta[4..8])`, `n2 = (child_min_x[0..4],
    /// [4..8], child_max_x[0..4], [4..8])`, `n3` the same for y and `n4` for z.
    pub struct CwNodeWords as "CwNode" {
        /// Origin and exponents, and the inner-child mask.
        pub n0: [u32; 4] = "vec4u",
        /// Child and primitive bases and the children's metadata.
        pub n1: [u32; 4] = "vec4u",
        /// Quantized x bounds of the children.
        pub n2: [u32; 4] = "vec4u",
        /// Quantized y bounds.
        pub n3: [u32; 4] = "vec4u",
        /// Quantized z bounds.
        pub n4: [u32; 4] = "vec4u",
    }
}
const _: () = assert!(std::mem::size_of::<CwBvhNode>() == 80);
const _: () = assert!(std::mem::size_of::<CwNodeWords>() == std::mem::size_of::<CwBvhNode>());

/// `node` with its child and primitive indices moved by `node_base` and `primitive_base`:
/// a node of a cell or a mesh placed after the nodes and primitives laid out before its
/// BVH's.
pub fn placed(node: &CwBvhNode, node_base: u32, primitive_base: u32) -> CwBvhNode {
    CwBvhNode {
        child_base_idx: node.child_base_idx + node_base,
        primitive_base_idx: node.primitive_base_idx + primitive_base,
        ..*node
    }
}

/// The quantisation frame of a node over `node_box`, as obvhs's `Bvh2Converter` makes it:
/// the node's minimum `p`, the exponent bytes of its power-of-two step per axis, and the
/// step's reciprocal.
pub fn node_frame(node_box: &Aabb) -> (Vec3A, [u8; 3], Vec3A) {
    let e = ((node_box.max - node_box.min).max(Vec3A::splat(1e-20)) * (1.0 / 255.0)).log2().ceil().exp2();
    let exponent = |x: f32| (x.to_bits() >> 23) as u8;
    (node_box.min, [exponent(e.x), exponent(e.y), exponent(e.z)], 1.0 / e)
}

/// Writes child `slot`'s box `b` into `node`, rounded outwards to 8 bits in the frame
/// ([`node_frame`]) of minimum `p` and step reciprocal `rcp_e`.
pub fn set_child_box(node: &mut CwBvhNode, slot: usize, b: &Aabb, p: Vec3A, rcp_e: Vec3A) {
    // obvhs pads by 0.0: min - p - 0.0 is min - p; max - p + 0.0 turns -0.0 into +0.0
    // (either rounds to the byte 0).
    let lo = ((b.min - p) * rcp_e).floor().clamp(Vec3A::ZERO, Vec3A::splat(255.0));
    let hi = ((b.max - p + 0.0) * rcp_e).ceil().clamp(Vec3A::ZERO, Vec3A::splat(255.0));
    node.child_min_x[slot] = lo.x as u8;
    node.child_min_y[slot] = lo.y as u8;
    node.child_min_z[slot] = lo.z as u8;
    node.child_max_x[slot] = hi.x as u8;
    node.child_max_y[slot] = hi.y as u8;
    node.child_max_z[slot] = hi.z as u8;
}

/// A CWBVH node whose children, all inner, are `(slot, box)`, quantized as obvhs's
/// `Bvh2Converter` does: the node's minimum and a power-of-two step per axis, the child
/// boxes rounded outwards to 8 bits.
pub fn inner_node(
    node_box: &Aabb,
    children: &[(usize, Aabb)],
    child_base_idx: u32,
    primitive_base_idx: u32,
) -> CwBvhNode {
    let (p, e, rcp_e) = node_frame(node_box);
    let mut node = CwBvhNode { p: p.into(), e, child_base_idx, primitive_base_idx, ..Default::default() };
    for &(slot, b) in children {
        set_child_box(&mut node, slot, &b, p, rcp_e);
        node.imask |= 1 << slot;
        node.child_meta[slot] = (24 + slot as u8) | 0b0010_0000;
    }
    node
}
