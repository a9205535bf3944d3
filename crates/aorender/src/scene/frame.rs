//! The local frame a scene is rendered in. Every ray operation runs in f32, whose spacing
//! grows with the coordinates: a scene far from the origin would lose to its distance
//! the accuracy its own coordinates have (at 10⁶ an ulp is 1/16). The scene is therefore
//! moved, in f64, by a local origin near it before its BVH is built; cameras and probe
//! points are moved by the same origin, and everything a caller passes or reads back
//! stays in the scene's own coordinates.
//!
//! The origin is the centre of the finite primitives' bounds rounded to a multiple of a
//! power of two `G` at least twice the bounds' largest side, on each axis whose centre
//! lies at least `G` from zero, and 0 on the others. Every coordinate `x` within the
//! bounds (triangle vertices, sphere centres) then lies between half and twice that
//! axis's origin `o`, so `x − o` is exact in f32 (Sterbenz's lemma): the moved scene is
//! the same geometry, bit for bit. A plane's point or an instance's translation outside
//! the bounds may round; how far a surface can move then is kept, and a probe's offset
//! bound grows by it. A scene whose bounds are near the origin is not moved at all, nor
//! any of its films changed; and geometry whose bounds' centre is within `G/2` of the
//! origin, translated far away by a multiple of `G`, renders the same film bit for bit.
//!
//! The frame works on the scene's stored coordinates, which a loader that placed geometry
//! far away in f64 (a glTF node hierarchy, a scene file's transform) keeps relative to the
//! scene's own origin ([`Scene::origin`], chosen by the same rule): cameras, which are in
//! the scene's own coordinates, are moved by both.

use super::camera::Camera;
use super::types::{EMPTY_BOUNDS, Scene, fold_bounds};
use glam::{DVec3, Vec3};

/// The local origin of a scene and what moving the scene by it did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalFrame {
    /// The scene's point that becomes the local frame's zero, in the scene's stored
    /// coordinates (relative to [`Scene::origin`]; each component an f32 value; zero for a
    /// scene near the origin).
    pub origin: DVec3,
    /// How far moving the scene may have moved a surface: zero when every subtraction
    /// was exact, else the largest distance a moved point was rounded by (a triangle's
    /// points move by at most its vertices' largest move).
    pub surface_shift: f32,
}

impl LocalFrame {
    /// The frame of a scene left where it is.
    pub const IDENTITY: LocalFrame = LocalFrame { origin: DVec3::ZERO, surface_shift: 0.0 };

    /// Whether the frame moves anything.
    pub fn is_identity(&self) -> bool {
        self.origin == DVec3::ZERO
    }

    /// `p` in the local frame, subtracted in f64 and rounded once to f32, and the length
    /// of that rounding (zero when the subtraction is exact).
    pub fn point(&self, p: Vec3) -> (Vec3, f64) {
        if self.is_identity() {
            return (p, 0.0);
        }
        let exact = p.as_dvec3() - self.origin;
        let local = exact.as_vec3();
        (local, (local.as_dvec3() - exact).length())
    }

    /// `camera` (in the scene's own coordinates) in the local frame of a scene whose
    /// stored coordinates are relative to `scene_origin` ([`Scene::origin`]): its eye and
    /// target moved in f64 (rounded to f32 only when its rays are made), its directions
    /// kept.
    pub fn camera(&self, camera: &Camera, scene_origin: DVec3) -> Camera {
        let origin = scene_origin + self.origin;
        Camera { eye: camera.eye - origin, look_at: camera.look_at - origin, ..*camera }
    }
}

/// The origin's grid `G` over the bounds' largest side, at least: with `G` at least twice
/// the scene's size, every coordinate in the bounds is within a factor 2 of the origin.
const GRID_OVER_SIZE: f64 = 2.0;

/// Largest coordinate over `G`: keeps `G` at least 2⁻²⁰ of the coordinates, so that a
/// multiple of it near them has at most 21 significant bits, an f32 value.
const COORDINATE_OVER_GRID: f64 = (1u64 << 20) as f64;

impl Scene {
    /// The local origin of the scene (see [`LocalFrame`]): zero when its
    /// bounds are near the origin or it has no finite primitive.
    pub fn local_origin(&self) -> DVec3 {
        let Some((min, max)) = self.frame_bounds() else { return DVec3::ZERO };
        grid_origin(min, max)
    }

    /// Bounds of the finite primitives in f64 (spheres' centre ± radius exactly,
    /// instances as their mesh's bounds' corners carried into the world), for choosing the
    /// local origin; `None` when the scene has none.
    fn frame_bounds(&self) -> Option<(DVec3, DVec3)> {
        // The triangles' box in f32 widens exactly to theirs in f64, a zero's sign included.
        let (lo, hi) = fold_bounds(EMPTY_BOUNDS, &self.triangles, |t| t.v);
        let (mut min, mut max) = (lo.as_dvec3(), hi.as_dvec3());
        let mut add = |p: DVec3| {
            min = min.min(p);
            max = max.max(p);
        };
        for s in &self.spheres {
            let r = DVec3::splat(s.radius as f64);
            add(s.center.as_dvec3() - r);
            add(s.center.as_dvec3() + r);
        }
        let mesh_bounds: Vec<Option<(Vec3, Vec3)>> = self
            .meshes
            .iter()
            .map(|m| {
                let (lo, hi) = fold_bounds(EMPTY_BOUNDS, &m.triangles, |&t| t);
                (lo.x <= hi.x).then_some((lo, hi))
            })
            .collect();
        for instance in &self.instances {
            let Some((lo, hi)) = mesh_bounds[instance.mesh as usize] else { continue };
            let m = instance.to_world.as_dmat4();
            for corner in 0..8 {
                let pick = |bit: usize, l: f32, h: f32| (if corner & bit == 0 { l } else { h }) as f64;
                let c = DVec3::new(pick(1, lo.x, hi.x), pick(2, lo.y, hi.y), pick(4, lo.z, hi.z));
                add(m.transform_point3(c));
            }
        }
        (min.x <= max.x && min.is_finite() && max.is_finite()).then_some((min, max))
    }

    /// Moves the scene's primitives into the frame whose zero is `origin` (triangle
    /// vertices, sphere centres, plane points, instance translations), each coordinate
    /// subtracted in f64 and rounded once. The camera and the mesh objects keep the
    /// scene's coordinates (requests carry their own camera; bakes write positions back
    /// as the file has them).
    pub(crate) fn move_to(&mut self, origin: DVec3) -> LocalFrame {
        let frame = LocalFrame { origin, surface_shift: 0.0 };
        if frame.is_identity() {
            return frame;
        }
        let mut largest = 0.0f64;
        let mut shift = |p: &mut Vec3| {
            let (local, rounding) = frame.point(*p);
            *p = local;
            largest = largest.max(rounding);
        };
        for t in &mut self.triangles {
            t.v.iter_mut().for_each(&mut shift);
        }
        for s in &mut self.spheres {
            shift(&mut s.center);
        }
        for p in &mut self.planes {
            shift(&mut p.point);
        }
        for instance in &mut self.instances {
            let mut t = instance.to_world.w_axis.truncate();
            shift(&mut t);
            instance.to_world.w_axis = t.extend(instance.to_world.w_axis.w);
        }
        LocalFrame { origin, surface_shift: round_up(largest) }
    }

    /// Whether moving the scene by `origin` is exact: every coordinate [`Scene::move_to`]
    /// moves minus `origin` is an f32 value.
    pub(crate) fn moves_exactly(&self, origin: DVec3) -> bool {
        let frame = LocalFrame { origin, surface_shift: 0.0 };
        let exact = |p: Vec3| frame.point(p).1 == 0.0;
        self.triangles.iter().all(|t| t.v.iter().all(|&v| exact(v)))
            && self.spheres.iter().all(|s| exact(s.center))
            && self.planes.iter().all(|p| exact(p.point))
            && self.instances.iter().all(|i| exact(i.to_world.w_axis.truncate()))
    }
}

/// The origin of a frame for geometry within the bounds `min`..`max` (see [`LocalFrame`]):
/// on each axis whose bounds' centre lies at least `G` from zero, that centre rounded to a
/// multiple of `G`, the smallest power of two at least twice the bounds' largest side (and
/// at least 2⁻²⁰ of their largest coordinate); zero on the others. Each component is an f32
/// value. Loaders that place geometry far from the origin keep it relative to this point.
pub(crate) fn grid_origin(min: DVec3, max: DVec3) -> DVec3 {
    let size = (max - min).max_element();
    let largest = min.abs().max(max.abs()).max_element();
    let at_least = (GRID_OVER_SIZE * size).max(largest / COORDINATE_OVER_GRID);
    if !(at_least > 0.0 && at_least.is_finite()) {
        return DVec3::ZERO;
    }
    let mut grid = 2f64.powi(at_least.log2().ceil() as i32);
    if grid < at_least {
        grid *= 2.0; // log2 rounded down to a power just below
    }
    let centre = 0.5 * (min + max);
    let axis = |c: f64| if c.abs() < grid { 0.0 } else { (c / grid).round() * grid };
    let origin = DVec3::new(axis(centre.x), axis(centre.y), axis(centre.z));
    // Multiples of the grid below 2²¹ of it are f32 values; checked rather than assumed.
    if origin.as_vec3().as_dvec3() == origin { origin } else { DVec3::ZERO }
}

/// The smallest f32 at least `x` (a non-negative finite f64).
pub(crate) fn round_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x { f.next_up() } else { f }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Plane;
    use crate::scene::{Sphere, Triangle};

    /// A scene of `n` triangles and spheres at `centre`, `size` across, from a fixed
    /// sequence of numbers.
    fn scene_at(centre: DVec3, size: f64, n: u32, seed: u32) -> Scene {
        let mut state = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        let mut u = move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f64 / u32::MAX as f64 - 0.5
        };
        let mut point = || (centre + size * DVec3::new(u(), u(), u())).as_vec3();
        let triangles = (0..n).map(|_| Triangle { v: [point(), point(), point()], albedo: 1.0 }).collect();
        let mut scene = Scene::from_triangles("test", triangles);
        scene.spheres = (0..n).map(|_| Sphere { center: point(), radius: 0.0, albedo: 1.0 }).collect();
        scene
    }

    #[test]
    fn scenes_far_from_the_origin_move_exactly_and_back() {
        let mut moved = 0;
        for (i, &(offset, size)) in
            [(1e6, 1.0), (1e6, 1e3), (-3e7, 5.0), (123.456, 1.0), (5e-3, 1e-4), (1e30, 1e25), (2.0, 1.0), (0.0, 1.0)]
                .iter()
                .enumerate()
        {
            for axes in [DVec3::ONE, DVec3::X, DVec3::new(1.0, -1.0, 0.5)] {
                let mut scene = scene_at(offset * axes, size, 64, i as u32);
                let given = scene.clone();
                let origin = scene.local_origin();
                assert!(scene.moves_exactly(origin), "offset {offset}, size {size}: origin {origin}");
                let frame = scene.move_to(origin);
                assert_eq!(frame.surface_shift, 0.0);
                if origin != DVec3::ZERO {
                    moved += 1;
                    // The moved scene is near its local zero.
                    let local = scene.frame_bounds().expect("bounds");
                    let reach = local.0.abs().max(local.1.abs()).max_element();
                    assert!(reach <= 4.0 * size, "offset {offset}, size {size}: local coordinates up to {reach}");
                }
                scene.move_to(-origin);
                assert_eq!(scene.triangles, given.triangles);
                assert_eq!(scene.spheres, given.spheres);
            }
        }
        assert!(moved > 10, "only {moved} scenes were moved");
    }

    #[test]
    fn scenes_near_the_origin_stay() {
        for (offset, size) in [(0.0, 1.0), (1.0, 1.0), (-3.0, 2.0), (0.0, 1e-6), (7.0, 1e3)] {
            let scene = scene_at(DVec3::splat(offset), size, 16, 3);
            assert_eq!(scene.local_origin(), DVec3::ZERO, "offset {offset}, size {size}");
        }
        assert_eq!(Scene::default_scene().local_origin(), DVec3::ZERO);
        let planes_only = Scene { triangles: Vec::new(), ..Scene::default_scene() };
        assert_eq!(Scene { spheres: Vec::new(), ..planes_only }.local_origin(), DVec3::ZERO);
    }

    #[test]
    fn a_rounded_move_is_measured() {
        let mut scene = scene_at(DVec3::splat(1e6), 1.0, 4, 1);
        // A plane whose point lies near the world's origin: 0.3 − 10⁶ is not an f32.
        scene.planes.push(Plane { normal: Vec3::Y, point: Vec3::splat(0.3), albedo: 1.0 });
        let origin = scene.local_origin();
        assert!(!scene.moves_exactly(origin));
        let frame = scene.move_to(origin);
        let (local, rounding) = frame.point(Vec3::splat(0.3));
        assert_eq!(local, scene.planes[0].point);
        assert!(rounding > 0.0 && frame.surface_shift as f64 >= rounding);
        assert!(frame.surface_shift <= 0.1, "half an ulp at 10⁶ on each axis: {}", frame.surface_shift);
    }
}
