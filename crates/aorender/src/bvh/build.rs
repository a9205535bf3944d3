//! Building the scene's BVHs with obvhs: the top level over triangles, spheres and
//! instances, and one BVH per instanced mesh in its own space.

use super::chunked;
use super::ploc::bvh2_over;
use super::quality::BuildQuality;
use super::stages::{Stage, timed};
use crate::geometry::AffineRows;
use crate::scene::Scene;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::{aabb::Aabb, bvh2::Bvh2};
use rayon::prelude::*;

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

    /// The key of primitive `id` ([`distinct`]); an instance has none (each is its own).
    fn key(&self, id: usize) -> Option<Key> {
        let (n_tri, n_sphere) = (self.scene.triangles.len(), self.scene.spheres.len());
        if id < n_tri {
            let t = &self.scene.triangles[id];
            Some(triangle_key(&t.v, t.albedo))
        } else if id < n_tri + n_sphere {
            let s = &self.scene.spheres[id - n_tri];
            let mut key = [0; 11];
            key[0] = 1;
            for (k, x) in s.center.to_array().into_iter().chain([s.radius, s.albedo]).enumerate() {
                key[k + 1] = x.to_bits();
            }
            Some(key)
        } else {
            None
        }
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
#[cfg(feature = "testing")]
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
/// world (the BVH2 layout has no second level): call it with [`Scene::flattened`]. Copies
/// are left out ([`distinct`]); their count comes with it.
pub fn build_bvh2(scene: &Scene, quality: BuildQuality) -> (Bvh2, usize) {
    debug_assert!(scene.instances.is_empty());
    let boxes = TopBoxes::new(scene);
    let kept = distinct(boxes.len(), &|id| boxes.key(id));
    let aabbs: Vec<Aabb> = match &kept {
        Some(ids) => ids.iter().map(|&id| boxes.get(id as usize)).collect(),
        None => (0..boxes.len()).map(|id| boxes.get(id)).collect(),
    };
    if aabbs.is_empty() {
        return (Bvh2::default(), 0);
    }
    let mut bvh = bvh2_over(&aabbs, &quality.params());
    let dropped = remap(&mut bvh.primitive_indices, kept.as_deref(), boxes.len());
    (bvh, dropped)
}

/// obvhs's compressed 8-wide BVHs of a scene: the top level over its triangles, spheres
/// and instances, and one over each instanced mesh, in its own space.
#[derive(Clone, Debug, Default)]
pub struct SceneCwbvh {
    /// The top level; `None` when the scene has no finite primitives.
    pub top: Option<CwBvh>,
    /// One per `Scene::meshes` entry.
    pub meshes: Vec<CwBvh>,
    /// Primitives left out as copies of others ([`distinct`]), top level and meshes
    /// together.
    pub duplicates: usize,
}

/// Most primitives in one octree cell of a CWBVH build (see [`chunked`]): each cell being
/// built takes about 320 bytes × this, 5 MB.
pub const BUILD_CELL: usize = 1 << 14;

/// Builds the scene's CWBVHs, in octree cells of at most [`BUILD_CELL`] primitives.
pub fn build_cwbvh(scene: &Scene, quality: BuildQuality) -> SceneCwbvh {
    build_cwbvh_in_cells(scene, quality, BUILD_CELL)
}

/// Builds the scene's CWBVHs in octree cells of at most `cell` primitives, copies left
/// out ([`distinct`]).
pub fn build_cwbvh_in_cells(scene: &Scene, quality: BuildQuality, cell: usize) -> SceneCwbvh {
    let mut duplicates = 0;
    let meshes = scene
        .meshes
        .iter()
        .map(|m| {
            let aabb = |i: usize| triangle_aabb(&m.triangles[i]);
            let key = |i: usize| Some(triangle_key(&m.triangles[i], 0.0));
            let (bvh, dropped) = build_distinct(m.triangles.len(), &aabb, &key, quality, cell);
            duplicates += dropped;
            bvh.expect("an instanced mesh has triangles")
        })
        .collect();
    let boxes = TopBoxes::new(scene);
    let (top, dropped) = build_distinct(boxes.len(), &|id| boxes.get(id), &|id| boxes.key(id), quality, cell);
    SceneCwbvh { top, meshes, duplicates: duplicates + dropped }
}

/// The CWBVH over primitives `0..count` in cells of at most `cell`, copies left out
/// ([`distinct`]), and how many were.
fn build_distinct(
    count: usize,
    aabb: &(dyn Fn(usize) -> Aabb + Sync),
    key: &(dyn Fn(usize) -> Option<Key> + Sync),
    quality: BuildQuality,
    cell: usize,
) -> (Option<CwBvh>, usize) {
    let kept = timed(Stage::Distinct, || distinct(count, key));
    let mut bvh = match &kept {
        Some(ids) => chunked::build_cwbvh_in_cells(ids.len(), &|k| aabb(ids[k] as usize), quality, cell),
        None => chunked::build_cwbvh_in_cells(count, aabb, quality, cell),
    };
    let dropped = match &mut bvh {
        Some(b) => remap(&mut b.primitive_indices, kept.as_deref(), count),
        None => 0,
    };
    (bvh, dropped)
}

/// Maps a BVH's primitive indices, positions in `kept`, back to primitive ids; returns
/// how many of `count` primitives `kept` leaves out.
fn remap(indices: &mut [u32], kept: Option<&[u32]>, count: usize) -> usize {
    let Some(kept) = kept else { return 0 };
    for p in indices {
        *p = kept[*p as usize];
    }
    count - kept.len()
}

/// Copies of one record from which all but the first are left out of the BVH. Meshes
/// carry a stray duplicate or three (the decimated dragons of `scenes/` have pairs):
/// those stay, and with them the BVH obvhs builds.
pub const MIN_COPIES: usize = 16;

/// What a ray meets of a primitive, by its bits: its kind, then a triangle's vertices
/// and albedo, or a sphere's centre, radius and albedo. Two primitives with one key are
/// one to every ray: the device's records and the CPU reference's are made of these bits.
pub type Key = [u32; 11];

/// The key of a triangle of vertices `v` and albedo `albedo`.
fn triangle_key(v: &[Vec3; 3], albedo: f32) -> Key {
    let mut key = [0; 11];
    for (k, x) in v.iter().flat_map(|p| p.to_array()).chain([albedo]).enumerate() {
        key[k + 1] = x.to_bits();
    }
    key
}

/// The primitives among `0..count` to build a BVH over when some come in [`MIN_COPIES`]
/// or more copies: all but the later copies of those, in order; `None` when there are
/// none. A copy is a primitive whose key (`key`; `None`: never a copy) an earlier one
/// has. A ray meets it exactly as it meets the first (the same distance, surface point
/// and albedo; an occlusion test as blocked), so leaving it out changes no image bit,
/// and a stack of copies costs a ray one intersection instead of one each, which
/// lavapipe's loop cap (65,535 iterations) could not afford past about 30,000.
pub fn distinct(count: usize, key: &(dyn Fn(usize) -> Option<Key> + Sync)) -> Option<Vec<u32>> {
    // Each key's 32-bit hash (none: never a copy), and how many keys fall in each of
    // about `count` buckets of them (saturating). Copies share a bucket, so without a
    // bucket of MIN_COPIES there are none; an ordinary mesh's fullest bucket holds a few.
    let hashes: Vec<Option<u32>> = (0..count).into_par_iter().map(|id| key(id).map(|k| key_hash(&k))).collect();
    let buckets = count.next_power_of_two().max(1024);
    let bucket = |h: u32| (h as usize) & (buckets - 1);
    let mut fill = vec![0u8; buckets];
    for h in hashes.iter().flatten() {
        let c = &mut fill[bucket(*h)];
        *c = c.saturating_add(1);
    }
    if !fill.iter().any(|&c| c as usize >= MIN_COPIES) {
        return None;
    }
    // The keys of the full buckets: a hash above its id, sorted, so that copies are in
    // runs of equal hashes, each run in id order.
    let mut keys: Vec<u64> = hashes
        .iter()
        .enumerate()
        .filter_map(|(id, h)| {
            h.filter(|&h| fill[bucket(h)] as usize >= MIN_COPIES).map(|h| (h as u64) << 32 | id as u64)
        })
        .collect();
    drop((hashes, fill));
    keys.par_sort_unstable();
    let mut dropped = vec![false; count];
    let mut any = false;
    // Each key of a run, with the ids that have it, in order.
    let mut groups: Vec<(Key, Vec<u32>)> = Vec::new();
    for run in keys.chunk_by(|a, b| a >> 32 == b >> 32).filter(|run| run.len() >= MIN_COPIES) {
        // Distinct keys in a run share a hash by chance: compare them all.
        groups.clear();
        for &packed in run {
            let id = packed as u32;
            let k = key(id as usize).expect("a key was hashed");
            match groups.iter_mut().find(|(first, _)| *first == k) {
                Some((_, ids)) => ids.push(id),
                None => groups.push((k, vec![id])),
            }
        }
        for (_, ids) in groups.iter().filter(|(_, ids)| ids.len() >= MIN_COPIES) {
            for &id in &ids[1..] {
                dropped[id as usize] = true;
            }
            any = true;
        }
    }
    drop(keys);
    any.then(|| (0..count as u32).filter(|&id| !dropped[id as usize]).collect())
}

/// A 32-bit hash of a key (FxHash's multiply-rotate over its words).
fn key_hash(k: &Key) -> u32 {
    let h = k.iter().fold(0u64, |h, &w| (h.rotate_left(5) ^ w as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95));
    (h >> 32) as u32
}
