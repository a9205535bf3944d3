//! The device layouts of a BVH: obvhs's CWBVH nodes as they are, or BVH2 nodes with both
//! children's boxes, and the primitive records in leaf order that both read.

use super::build::{SceneCwbvh, build_bvh2, build_cwbvh};
use super::cwbvh::placed;
use super::ploc::cwbvh_depth;
use super::quality::BuildQuality;
use crate::geometry::AffineRows;
use crate::mirror::gpu_struct;
use crate::scene::Scene;
use glam::Vec3;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::node::CwBvhNode;
use rayon::prelude::*;

/// Marks an absent child (only when the root itself is a leaf).
pub const INVALID_INDEX: u32 = u32::MAX;
/// CWBVH nodes (1.3 MB) or primitive records (0.8 MB) a thread writes at a time.
const NODES_A_PIECE: usize = 1 << 14;
/// Primitive tag stored in `GpuPrimitive::b[3]`'s bits.
pub const PRIM_TRIANGLE: u32 = 0;
/// Primitive tag of a sphere.
pub const PRIM_SPHERE: u32 = 1;
/// Primitive tag of an instance: `a = (instance index, root node, first data record,
/// albedo)` as bits (the albedo as a float). The root and data fields are the GPU's (the
/// node where its mesh's BVH starts and the record of its world-to-object rows, followed
/// by its object-to-world rows), filled in as the records are made ([`GpuRecords::write`]).
pub const PRIM_INSTANCE: u32 = 2;
/// Most entries of the BVH2 traversal stack in the shader; deeper trees are refused.
pub const BVH2_STACK_SIZE: u32 = 64;
/// Most entries of the CWBVH traversal stack (one per level at most); deeper trees are
/// refused. The kernel's stacks hold as many entries as its BVH is deep
/// ([`GpuBvh::stack_size`]), no more; at most 31 so that a workgroup's 64 stacks fit its
/// 16 KiB of workgroup memory beside the counters (`gpu::layout` checks).
pub const CWBVH_STACK_SIZE: u32 = 31;

// The layout is named in `kinds`, below the checkpoint format that records it.
pub use crate::kinds::BvhLayout;

impl BvhLayout {
    /// Most entries of the shader's traversal stack: the deepest tree it can traverse.
    pub fn stack_size(self) -> u32 {
        match self {
            BvhLayout::Bvh2 => BVH2_STACK_SIZE,
            BvhLayout::Cwbvh => CWBVH_STACK_SIZE,
        }
    }

    /// Bytes of one node as the kernel reads it.
    pub fn node_size(self) -> usize {
        match self {
            BvhLayout::Bvh2 => std::mem::size_of::<GpuNode>(),
            BvhLayout::Cwbvh => std::mem::size_of::<CwBvhNode>(),
        }
    }
}

gpu_struct! {
    /// BVH2 node with both children's boxes. A child with `count == 0` is an inner node
    /// (`index` into the node array); `count > 0` is a leaf of `count` primitives starting
    /// at `index` in the primitive array; `index == INVALID_INDEX` is no child.
    pub struct GpuNode as "Node" {
        /// Child A box minimum.
        pub a_min: [f32; 3] = "vec3f",
        /// Child A index.
        pub a_index: u32 = "u32",
        /// Child A box maximum.
        pub a_max: [f32; 3] = "vec3f",
        /// Child A primitive count (0: inner node).
        pub a_count: u32 = "u32",
        /// Child B box minimum.
        pub b_min: [f32; 3] = "vec3f",
        /// Child B index.
        pub b_index: u32 = "u32",
        /// Child B box maximum.
        pub b_max: [f32; 3] = "vec3f",
        /// Child B primitive count (0: inner node).
        pub b_count: u32 = "u32",
    }
}
const _: () = assert!(std::mem::size_of::<GpuNode>() == 64);

gpu_struct! {
    /// A primitive in leaf order. Triangle: `a = (v0, albedo)`, `b = (v1, tag)`,
    /// `c = (v2, 0)`, the vertices exactly as the scene holds them: triangles that share a
    /// vertex store the same bits for it, which the watertight intersection test needs
    /// (edge vectors would round differently in each triangle). Sphere: `a = (centre,
    /// albedo)`, `b = (radius, 0, 0, tag)`, `c = 0`. The tag is stored as the bits of
    /// `b[3]`. An instance: see [`PRIM_INSTANCE`]; its two data records hold affine rows.
    pub struct GpuPrimitive as "Primitive" {
        /// First vertex or centre, and albedo.
        pub a: [f32; 4] = "vec4f",
        /// Second vertex or radius, and the tag bits.
        pub b: [f32; 4] = "vec4f",
        /// Third vertex.
        pub c: [f32; 4] = "vec4f",
    }
}
const _: () = assert!(std::mem::size_of::<GpuPrimitive>() == 48);

/// The record of top-level primitive `id` (triangles, spheres, instances).
pub fn gpu_primitive(scene: &Scene, id: usize) -> GpuPrimitive {
    let n_tri = scene.triangles.len();
    let n_sphere = scene.spheres.len();
    if id < n_tri {
        let t = &scene.triangles[id];
        let [v0, v1, v2] = t.v;
        GpuPrimitive {
            a: [v0.x, v0.y, v0.z, t.albedo],
            b: [v1.x, v1.y, v1.z, f32::from_bits(PRIM_TRIANGLE)],
            c: [v2.x, v2.y, v2.z, 0.0],
        }
    } else if id < n_tri + n_sphere {
        let s = &scene.spheres[id - n_tri];
        GpuPrimitive {
            a: [s.center.x, s.center.y, s.center.z, s.albedo],
            b: [s.radius, 0.0, 0.0, f32::from_bits(PRIM_SPHERE)],
            c: [0.0; 4],
        }
    } else {
        let i = id - n_tri - n_sphere;
        GpuPrimitive {
            a: [f32::from_bits(i as u32), 0.0, 0.0, scene.instances[i].albedo],
            b: [0.0, 0.0, 0.0, f32::from_bits(PRIM_INSTANCE)],
            c: [0.0; 4],
        }
    }
}

/// The record of a triangle of an instanced mesh (no albedo: the instance has it).
pub fn mesh_primitive(v: &[Vec3; 3]) -> GpuPrimitive {
    let [v0, v1, v2] = *v;
    GpuPrimitive {
        a: [v0.x, v0.y, v0.z, 0.0],
        b: [v1.x, v1.y, v1.z, f32::from_bits(PRIM_TRIANGLE)],
        c: [v2.x, v2.y, v2.z, 0.0],
    }
}

/// An affine map's rows as one record.
fn rows_record(rows: &AffineRows) -> GpuPrimitive {
    GpuPrimitive { a: rows.0[0], b: rows.0[1], c: rows.0[2] }
}

/// The GPU form of a scene's BVH.
#[derive(Clone, Debug, Default)]
pub struct GpuBvh {
    /// Node layout.
    pub layout: BvhLayout,
    /// Nodes as uploaded (`GpuNode`s or obvhs `CwBvhNode`s); the root is node 0. Empty
    /// when the scene has no finite primitives.
    pub node_bytes: Vec<u8>,
    /// Number of nodes.
    pub node_count: u32,
    /// Primitive records in leaf order.
    pub records: GpuRecords,
    /// Depth of the deepest inner node (root = 1): a bound on the traversal stack.
    pub depth: u32,
    /// Primitives left out as copies of others (`build::distinct`).
    pub duplicates: usize,
}

/// The primitive records of a [`GpuBvh`], in the order the device holds them.
#[derive(Clone, Debug)]
pub enum GpuRecords {
    /// Made in full on the host (the BVH2 layout, whose scene may be a flattened copy).
    Made(Vec<GpuPrimitive>),
    /// Made from the scene piece by piece as they are uploaded, so the host never holds a
    /// second full copy of the geometry: the top level's primitives in `top` order, then
    /// each instanced mesh's triangles in its BVH's order, then two records per instance
    /// (its world-to-object and object-to-world rows).
    Cwbvh {
        /// The top level's primitive ids (triangles, spheres, instances) in leaf order.
        top: Vec<u32>,
        /// Each instanced mesh's triangle indices in its BVH's leaf order.
        meshes: Vec<Vec<u32>>,
        /// The node where each instanced mesh's BVH starts.
        roots: Vec<u32>,
        /// Instances in the scene.
        instances: usize,
    },
}

impl Default for GpuRecords {
    fn default() -> Self {
        GpuRecords::Made(Vec::new())
    }
}

impl GpuRecords {
    /// Number of records.
    pub fn len(&self) -> usize {
        match self {
            GpuRecords::Made(r) => r.len(),
            GpuRecords::Cwbvh { top, meshes, instances, .. } => {
                top.len() + meshes.iter().map(Vec::len).sum::<usize>() + 2 * instances
            }
        }
    }

    /// Whether there are none.
    #[cfg(feature = "testing")]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Writes records `first..first + out.len()` into `out`. `scene` must be the scene the
    /// BVH was built from.
    pub fn write(&self, scene: &Scene, first: usize, out: &mut [GpuPrimitive]) {
        let (top, meshes, roots) = match self {
            GpuRecords::Made(r) => {
                out.copy_from_slice(&r[first..first + out.len()]);
                return;
            }
            GpuRecords::Cwbvh { top, meshes, roots, .. } => (top, meshes, roots),
        };
        // Where each mesh's records start; the instances' rows follow the last.
        let mut mesh_starts = Vec::with_capacity(meshes.len());
        let mut data_base = top.len();
        for ids in meshes {
            mesh_starts.push(data_base);
            data_base += ids.len();
        }
        let record = |k: usize| {
            if k < top.len() {
                let mut p = gpu_primitive(scene, top[k] as usize);
                if p.b[3].to_bits() == PRIM_INSTANCE {
                    let i = p.a[0].to_bits();
                    p.a[1] = f32::from_bits(roots[scene.instances[i as usize].mesh as usize]);
                    p.a[2] = f32::from_bits(data_base as u32 + 2 * i);
                }
                p
            } else if k < data_base {
                let m = mesh_starts.partition_point(|&s| s <= k) - 1;
                mesh_primitive(&scene.meshes[m].triangles[meshes[m][k - mesh_starts[m]] as usize])
            } else {
                let instance = &scene.instances[(k - data_base) / 2];
                let rows =
                    if (k - data_base).is_multiple_of(2) { instance.to_object().0 } else { instance.to_world_rows() };
                rows_record(&rows)
            }
        };
        out.par_chunks_mut(NODES_A_PIECE).enumerate().for_each(|(c, piece)| {
            for (slot, k) in piece.iter_mut().zip(first + c * NODES_A_PIECE..) {
                *slot = record(k);
            }
        });
    }
}

impl GpuBvh {
    /// Entries the kernel's traversal stack needs: one per level below the root at most
    /// (a traversal pushes the rest of a node's hit children before descending), and at
    /// least one, for an array of nonzero size.
    pub fn stack_size(&self) -> u32 {
        self.depth.max(1)
    }

    /// The most traversal loop iterations one ray can take through this BVH of `scene`
    /// (planes aside). Every iteration visits a node or tests a primitive reference, and
    /// a ray meets each of the top level's at most once; the nodes and references of an
    /// instanced mesh, once per instance that the ray enters, plus the iteration that
    /// may return it to the top level with nothing left to do there.
    pub fn ray_steps(&self, scene: &Scene) -> u64 {
        match &self.records {
            GpuRecords::Made(records) => self.node_count as u64 + records.len() as u64,
            GpuRecords::Cwbvh { top, meshes, roots, .. } => {
                let top_nodes = roots.first().copied().unwrap_or(self.node_count);
                // The meshes' nodes follow the top level's, each mesh's from its root on.
                let mesh_nodes = |m: usize| roots.get(m + 1).copied().unwrap_or(self.node_count) - roots[m];
                let entered: u64 = scene
                    .instances
                    .iter()
                    .map(|i| 1 + mesh_nodes(i.mesh as usize) as u64 + meshes[i.mesh as usize].len() as u64)
                    .sum();
                top_nodes as u64 + top.len() as u64 + entered
            }
        }
    }

    /// Bytes to upload: nodes and primitive records.
    pub fn bytes(&self) -> u64 {
        (self.node_bytes.len() + self.records.len() * std::mem::size_of::<GpuPrimitive>()) as u64
    }

    /// Builds the BVH of `scene` in `layout`.
    pub fn build(scene: &Scene, layout: BvhLayout, quality: BuildQuality) -> GpuBvh {
        match layout {
            BvhLayout::Bvh2 if scene.instances.is_empty() => {
                let (bvh, duplicates) = build_bvh2(scene, quality);
                GpuBvh { duplicates, ..GpuBvh::from_bvh2(scene, &bvh) }
            }
            BvhLayout::Bvh2 => {
                let flat = scene.flattened();
                let (bvh, duplicates) = build_bvh2(&flat, quality);
                GpuBvh { duplicates, ..GpuBvh::from_bvh2(&flat, &bvh) }
            }
            BvhLayout::Cwbvh => GpuBvh::from_cwbvh(scene, &build_cwbvh(scene, quality)),
        }
    }

    /// Lays out obvhs's CWBVHs as they are, one after the other: the top level (its root is
    /// node 0), then each mesh's, whose child and primitive indices are moved by where its
    /// nodes and primitives start. Primitive records follow each BVH's `primitive_indices`;
    /// after them come two records per instance, its world-to-object and object-to-world
    /// rows. The records are made from `scene` when they are uploaded ([`GpuRecords`]).
    pub fn from_cwbvh(scene: &Scene, bvh: &SceneCwbvh) -> GpuBvh {
        let Some(top) = &bvh.top else {
            return GpuBvh { layout: BvhLayout::Cwbvh, ..Default::default() };
        };
        // Nodes go straight into the upload bytes, sized exactly; the primitive records are
        // made at upload.
        let node_size = std::mem::size_of::<CwBvhNode>();
        let node_count = bvh.top.iter().chain(&bvh.meshes).map(|b| b.nodes.len()).sum::<usize>();
        // Zeroed pages from the allocator, filled over threads (each page first touched by
        // the thread that fills it).
        let mut node_bytes: Vec<u8> = bytemuck::zeroed_vec(node_count * node_size);
        let (top_bytes, mut rest) = node_bytes.split_at_mut(top.nodes.len() * node_size);
        let piece = NODES_A_PIECE * node_size;
        top_bytes
            .par_chunks_mut(piece)
            .zip(bytemuck::cast_slice::<_, u8>(&top.nodes).par_chunks(piece))
            .for_each(|(to, from)| to.copy_from_slice(from));
        let mut prim_base = top.primitive_indices.len() as u32;
        let mut node_base = top.nodes.len() as u32;
        let mut roots = Vec::with_capacity(bvh.meshes.len());
        for blas in &bvh.meshes {
            roots.push(node_base);
            let (bytes, after) = std::mem::take(&mut rest).split_at_mut(blas.nodes.len() * node_size);
            bytes.par_chunks_mut(piece).zip(blas.nodes.par_chunks(NODES_A_PIECE)).for_each(|(to, from)| {
                for (t, n) in to.chunks_exact_mut(node_size).zip(from) {
                    t.copy_from_slice(bytemuck::bytes_of(&placed(n, node_base, prim_base)));
                }
            });
            rest = after;
            node_base += blas.nodes.len() as u32;
            prim_base += blas.primitive_indices.len() as u32;
        }
        let records = GpuRecords::Cwbvh {
            top: top.primitive_indices.clone(),
            meshes: bvh.meshes.iter().map(|b| b.primitive_indices.clone()).collect(),
            roots,
            instances: scene.instances.len(),
        };
        // A ray inside an instance stacks its mesh's nodes on top of the top level's.
        let depth = cwbvh_depth(top) + bvh.meshes.iter().map(cwbvh_depth).max().unwrap_or(0);
        GpuBvh {
            layout: BvhLayout::Cwbvh,
            node_count: node_count as u32,
            node_bytes,
            records,
            depth,
            duplicates: bvh.duplicates,
        }
    }

    /// Converts obvhs's BVH2 to the two-boxes-per-node layout.
    pub fn from_bvh2(scene: &Scene, bvh: &Bvh2) -> GpuBvh {
        if bvh.nodes.is_empty() {
            return GpuBvh { layout: BvhLayout::Bvh2, ..Default::default() };
        }
        let records =
            GpuRecords::Made(bvh.primitive_indices.iter().map(|&id| gpu_primitive(scene, id as usize)).collect());
        let child = |i: usize, gpu_index: &[u32]| -> ([f32; 3], [f32; 3], u32, u32) {
            let n = &bvh.nodes[i];
            let (min, max) = (n.aabb.min.to_array(), n.aabb.max.to_array());
            if n.is_leaf() { (min, max, n.first_index, n.prim_count) } else { (min, max, gpu_index[i], 0) }
        };
        // Number inner nodes in depth-first order so a subtree is contiguous.
        let mut gpu_index = vec![INVALID_INDEX; bvh.nodes.len()];
        let mut order = Vec::new();
        let mut stack = vec![(0usize, 1u32)];
        let mut depth = 1;
        while let Some((i, d)) = stack.pop() {
            let n = &bvh.nodes[i];
            if n.is_leaf() {
                continue;
            }
            depth = depth.max(d);
            gpu_index[i] = order.len() as u32;
            order.push(i);
            let first = n.first_index as usize;
            stack.push((first + 1, d + 1));
            stack.push((first, d + 1));
        }
        let nodes = if bvh.nodes[0].is_leaf() {
            let (min, max, index, count) = child(0, &gpu_index);
            vec![GpuNode {
                a_min: min,
                a_index: index,
                a_max: max,
                a_count: count,
                b_min: [0.0; 3],
                b_index: INVALID_INDEX,
                b_max: [0.0; 3],
                b_count: 0,
            }]
        } else {
            order
                .iter()
                .map(|&i| {
                    let first = bvh.nodes[i].first_index as usize;
                    let (a_min, a_max, a_index, a_count) = child(first, &gpu_index);
                    let (b_min, b_max, b_index, b_count) = child(first + 1, &gpu_index);
                    GpuNode { a_min, a_index, a_max, a_count, b_min, b_index, b_max, b_count }
                })
                .collect()
        };
        let nodes: Vec<GpuNode> = nodes;
        GpuBvh {
            layout: BvhLayout::Bvh2,
            node_bytes: bytemuck::cast_slice(&nodes).to_vec(),
            node_count: nodes.len() as u32,
            records,
            depth,
            duplicates: 0,
        }
    }
}
