//! Building the scene's BVHs with obvhs: the top level over triangles, spheres and
//! instances, and one BVH per instanced mesh in its own space.

use super::chunked;
use super::quality::BuildQuality;
use crate::geometry::AffineRows;
use crate::scene::Scene;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::{aabb::Aabb, bvh2::Bvh2};

/// The boxes of the top level's primitives, by id: triangles, spheres, instances.
struct TopBoxes<'a> {
    scene: &'a Scene,
    instances: Vec<Aabb>,
}

impl<'a> TopBoxes<'a> {
    fn new(scene: &'a Scene) -> Self {
        let mesh_boxes: Vec<Aabb> = scene.meshes.iter().map(|m| mesh_aabb(&m.triangles)).collect();
        let instances =
            scene.instances.iter().map(|i| instance_aabb(&i.to_world_rows(), &mesh_boxes[i.mesh as usize])).collect();
        TopBoxes { scene, instances }
    }

    fn len(&self) -> usize {
        self.scene.triangles.len() + self.scene.spheres.len() + self.instances.len()
    }

    fn get(&self, id: usize) -> Aabb {
        let (n_tri, n_sphere) = (self.scene.triangles.len(), self.scene.spheres.len());
        if id < n_tri {
            triangle_aabb(&self.scene.triangles[id].v)
        } else if id < n_tri + n_sphere {
            let s = &self.scene.spheres[id - n_tri];
            let c = Vec3A::from(s.center);
            Aabb::new(c - s.radius, c + s.radius)
        } else {
            self.instances[id - n_tri - n_sphere]
        }
    }
}

/// Axis-aligned boxes of the BVH's primitives, in id order (triangles, spheres, instances).
pub fn primitive_aabbs(scene: &Scene) -> Vec<Aabb> {
    let boxes = TopBoxes::new(scene);
    (0..boxes.len()).map(|id| boxes.get(id)).collect()
}

fn triangle_aabb(v: &[Vec3; 3]) -> Aabb {
    let v = v.map(Vec3A::from);
    Aabb::new(v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
}

fn mesh_aabb(triangles: &[[Vec3; 3]]) -> Aabb {
    triangles.iter().fold(Aabb::empty(), |b, t| b.union(&triangle_aabb(t)))
}

/// The world box of an instance: the mesh box's corners through `to_world`, widened on
/// every axis by 2⁻²⁰ of its largest extent plus its largest coordinate, far more than the rounding of
/// the corners (γ(3)) and of the ray's way into the mesh's space, so a world ray is never
/// culled here that its object-space twin would hit.
fn instance_aabb(to_world: &AffineRows, b: &Aabb) -> Aabb {
    let mut out = Aabb::empty();
    for k in 0..8 {
        let pick = |bit: usize, lo: f32, hi: f32| if k & bit == 0 { lo } else { hi };
        let c = glam::Vec3::new(pick(1, b.min.x, b.max.x), pick(2, b.min.y, b.max.y), pick(4, b.min.z, b.max.z));
        let w = Vec3A::from(to_world.point(c));
        out.extend(w);
    }
    // One margin on every axis, so a box that is flat along an axis gets one too.
    let size = (out.max - out.min).max_element() + out.max.abs().max(out.min.abs()).max_element();
    let pad = Vec3A::splat(size * (1.0 / (1u32 << 20) as f32));
    Aabb::new(out.min - pad, out.max + pad)
}

/// Builds obvhs's BVH2 over the scene's finite primitives, instances flattened into the
/// world (the BVH2 layout has no second level): call it with [`Scene::flattened`].
pub fn build_bvh2(scene: &Scene, quality: BuildQuality) -> Bvh2 {
    debug_assert!(scene.instances.is_empty());
    let aabbs = primitive_aabbs(scene);
    if aabbs.is_empty() {
        return Bvh2::default();
    }
    obvhs::bvh2::builder::build_bvh2(&aabbs, quality.params(), &mut Default::default())
}

/// obvhs's compressed 8-wide BVHs of a scene: the top level over its triangles, spheres
/// and instances, and one over each instanced mesh, in its own space.
#[derive(Clone, Debug, Default)]
pub struct SceneCwbvh {
    /// The top level; `None` when the scene has no finite primitives.
    pub top: Option<CwBvh>,
    /// One per `Scene::meshes` entry.
    pub meshes: Vec<CwBvh>,
}

/// Most primitives in one octree cell of a CWBVH build (see [`chunked`]): each cell being
/// built takes about 320 bytes × this, 5 MB.
pub const BUILD_CELL: usize = 1 << 14;

/// Builds the scene's CWBVHs, in octree cells of at most [`BUILD_CELL`] primitives.
pub fn build_cwbvh(scene: &Scene, quality: BuildQuality) -> SceneCwbvh {
    build_cwbvh_in_cells(scene, quality, BUILD_CELL)
}

/// Builds the scene's CWBVHs in octree cells of at most `cell` primitives.
pub fn build_cwbvh_in_cells(scene: &Scene, quality: BuildQuality, cell: usize) -> SceneCwbvh {
    let meshes = scene
        .meshes
        .iter()
        .map(|m| {
            let aabb = |i: usize| triangle_aabb(&m.triangles[i]);
            chunked::build_cwbvh_in_cells(m.triangles.len(), &aabb, quality, cell)
                .expect("an instanced mesh has triangles")
        })
        .collect();
    let boxes = TopBoxes::new(scene);
    let top = chunked::build_cwbvh_in_cells(boxes.len(), &|id| boxes.get(id), quality, cell);
    SceneCwbvh { top, meshes }
}
