//! BVH construction with obvhs and the GPU layouts of nodes and primitives.
//!
//! One BVH holds every finite primitive: triangles first (ids `0..n_tri`), then spheres,
//! then instances of meshes placed more than once, each of which refers to the BVH of its
//! mesh in the mesh's own space (two levels: a ray that reaches an instance continues in
//! that BVH, carried into the mesh's space). Infinite planes stay outside it. CWBVHs are
//! built in octree cells of bounded size (`chunked`) so the build's workspace stays
//! small beside the scene. Two GPU layouts: obvhs's CWBVH nodes as they are, or a BVH2
//! whose nodes carry both children's boxes (Aila & Laine, "Understanding the Efficiency of
//! Ray Traversal on GPUs", HPG 2009), so one 64-byte fetch tests two boxes. Primitive
//! records are stored in BVH leaf order, so leaves index them directly without an
//! indirection table.

pub mod build;
pub mod chunked;
pub mod collapse;
pub mod cwbvh;
pub mod layout;
pub mod ploc;
pub mod quality;
pub mod stages;

pub use build::{SceneCwbvh, build_cwbvh};
pub use cwbvh::CwNodeWords;
pub use layout::{
    BvhLayout, CWBVH_STACK_SIZE, GpuBvh, GpuNode, GpuPrimitive, INVALID_INDEX, PRIM_INSTANCE, PRIM_SPHERE,
    PRIM_TRIANGLE, gpu_primitive, mesh_primitive,
};
// The crate's own tests and examples name the preset here; the library reads it from `kinds`.
#[cfg(feature = "testing")]
pub use quality::BuildQuality;
