//! Pixels whose camera rays provably see no geometry: every ray of the pixel's
//! footprint (the square its jittered samples fall in, a little grown) misses every box
//! that bounds the scene's finite geometry and every infinite plane. Their value is the
//! background, exactly, whatever the samples, so an adaptive render stops them after
//! their first replicate.

use glam::{DVec3, Mat4, Vec3};
use rayon::prelude::*;

use crate::scene::{Camera, Projection, Scene};

/// Cells a side of the grid that triangles are binned into by their centroid: each
/// occupied cell's triangles give one box, so that the boxes follow the surface rather
/// than its bounds.
const GRID: usize = 16;
/// Pixels a side of the tiles whose frusta cull the boxes before the pixels' own.
const TILE: u32 = 16;
/// How far, in pixels, a footprint reaches beyond its pixel's square: the f32 rounding
/// of `x + jitter` at the largest image sizes, with room to spare.
const PIXEL_MARGIN: f64 = 0.01;
/// Boxes grow by this share of the distance from the eye to the scene's far side (the
/// rays are made in f32, the test in f64).
const RELATIVE_MARGIN: f64 = 1e-4;
/// The least |n · d| of a ray that a plane's test trusts to be pointing away: nearer
/// grazing, an f32 ray may cross it far away.
const GRAZING: f64 = 1e-3;

/// A box, in the scene's stored coordinates.
#[derive(Clone, Copy, Debug)]
struct Box3 {
    min: DVec3,
    max: DVec3,
}

impl Box3 {
    const EMPTY: Box3 = Box3 { min: DVec3::splat(f64::INFINITY), max: DVec3::splat(f64::NEG_INFINITY) };

    fn grow(&mut self, p: DVec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
}

/// A half-space n · (x − p) ≥ 0 that holds every ray of a footprint.
#[derive(Clone, Copy, Debug)]
struct Side {
    n: DVec3,
    p: DVec3,
}

impl Side {
    /// Whether `b` lies entirely outside.
    fn excludes(&self, b: &Box3) -> bool {
        let far = DVec3::new(
            if self.n.x >= 0.0 { b.max.x } else { b.min.x },
            if self.n.y >= 0.0 { b.max.y } else { b.min.y },
            if self.n.z >= 0.0 { b.max.z } else { b.min.z },
        );
        self.n.dot(far - self.p) < 0.0
    }
}

/// The camera's rays in f64, as `RayGen::ray` makes them in f32.
struct Rays {
    eye: DVec3,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    orthographic: bool,
    width: f64,
    height: f64,
}

impl Rays {
    fn new(camera: &Camera, width: u32, height: u32) -> Rays {
        let forward = (camera.look_at - camera.eye).normalize();
        let right = forward.cross(camera.up.as_dvec3()).normalize();
        let up = right.cross(forward);
        let aspect = width as f64 / height as f64;
        let (half_h, orthographic) = match camera.projection {
            Projection::Perspective { vfov_deg } => ((0.5 * (vfov_deg as f64).to_radians()).tan(), false),
            Projection::Orthographic { height } => (0.5 * height as f64, true),
        };
        Rays {
            eye: camera.eye,
            forward,
            right: right * half_h * aspect,
            up: up * half_h,
            orthographic,
            width: width as f64,
            height: height as f64,
        }
    }

    /// The ray through image point (x, y), unnormalised.
    fn ray(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let sx = 2.0 * x / self.width - 1.0;
        let sy = 1.0 - 2.0 * y / self.height;
        if self.orthographic {
            (self.eye + sx * self.right + sy * self.up, self.forward)
        } else {
            (self.eye, self.forward + sx * self.right + sy * self.up)
        }
    }

    /// The corner rays of the image rectangle [x0, x1] × [y0, y1], in order round it.
    fn corners(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> [(DVec3, DVec3); 4] {
        [self.ray(x0, y0), self.ray(x1, y0), self.ray(x1, y1), self.ray(x0, y1)]
    }

    /// The four sides of the rays through the rectangle, facing inwards.
    fn sides(&self, x0: f64, y0: f64, x1: f64, y1: f64) -> [Side; 4] {
        let c = self.corners(x0, y0, x1, y1);
        let (oc, dc) = self.ray(0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let inside = oc + dc;
        std::array::from_fn(|k| {
            let ((o0, d0), (o1, d1)) = (c[k], c[(k + 1) % 4]);
            // The plane through ray k and the point one step along ray k + 1: for a
            // pinhole d0 × d1, for parallel rays d × (o1 − o0).
            let n = d0.cross(o1 + d1 - o0);
            let n = if n.dot(inside - o0) < 0.0 { -n } else { n };
            Side { n, p: o0 }
        })
    }
}

/// Boxes that together hold every finite primitive of `scene`: the triangles binned by
/// centroid into a `GRID`³ grid (one box per occupied cell), a box per sphere and per
/// instance, each grown by `margin`.
fn boxes(scene: &Scene, margin: f64) -> Vec<Box3> {
    let mut out = Vec::new();
    if let Some(bounds) = scene.bounds() {
        let (lo, hi) = (bounds.min.as_dvec3(), bounds.max.as_dvec3());
        let scale = (hi - lo).max(DVec3::splat(f64::MIN_POSITIVE));
        let mut cells = vec![Box3::EMPTY; GRID * GRID * GRID];
        for t in &scene.triangles {
            let v = t.v.map(|p| p.as_dvec3());
            let centroid = (v[0] + v[1] + v[2]) / 3.0;
            let g = ((centroid - lo) / scale * GRID as f64).clamp(DVec3::ZERO, DVec3::splat(GRID as f64 - 1.0));
            let cell = &mut cells[(g.x as usize * GRID + g.y as usize) * GRID + g.z as usize];
            for p in v {
                cell.grow(p);
            }
        }
        out.extend(cells.into_iter().filter(|c| c.min.x <= c.max.x));
    }
    for s in &scene.spheres {
        let r = DVec3::splat(s.radius as f64);
        out.push(Box3 { min: s.center.as_dvec3() - r, max: s.center.as_dvec3() + r });
    }
    for instance in &scene.instances {
        let mesh = &scene.meshes[instance.mesh as usize].triangles;
        let (lo, hi) =
            mesh.iter().flatten().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), p| (a.min(*p), b.max(*p)));
        if lo.x <= hi.x {
            out.push(placed_box(&instance.to_world, lo, hi));
        }
    }
    for b in &mut out {
        b.min -= DVec3::splat(margin);
        b.max += DVec3::splat(margin);
    }
    out
}

/// A box holding the box [lo, hi] placed by the affine `m`: its placed corners'.
fn placed_box(m: &Mat4, lo: Vec3, hi: Vec3) -> Box3 {
    let m = m.as_dmat4();
    let mut b = Box3::EMPTY;
    for k in 0..8 {
        let corner = DVec3::new(
            if k & 1 == 0 { lo.x } else { hi.x } as f64,
            if k & 2 == 0 { lo.y } else { hi.y } as f64,
            if k & 4 == 0 { lo.z } else { hi.z } as f64,
        );
        b.grow(m.transform_point3(corner));
    }
    b
}

/// Whether every ray through the corners `c` (and so every ray between them) misses the
/// infinite plane through `p` with normal `n`: each points away from it, clearly, or the
/// plane is behind its origin. A ray (o, d) meets it at t > 0 when n · (p − o) and n · d
/// have the same sign; both are linear in the ray (a pinhole's rays share o, parallel
/// rays share d), so the corners decide for the rays between them.
fn misses_plane(c: &[(DVec3, DVec3); 4], n: DVec3, p: DVec3, margin: f64) -> bool {
    let n = n.normalize();
    c.iter().all(|&(o, d)| {
        let (side, towards) = (n.dot(p - o), n.dot(d.normalize()));
        side.abs() > margin && towards.abs() > GRAZING && side * towards < 0.0
    })
}

/// Per pixel of a `width` × `height` image of `scene` seen by `camera` (both in the
/// scene's stored coordinates, relative to [`Scene::origin`]): whether none of its
/// camera rays can meet any geometry, so that every sample is the background. A
/// conservative test: `true` only where the footprint (the pixel's square, where the
/// jitter of every sampler puts its rays, grown by `PIXEL_MARGIN`) misses the boxes that
/// bound the finite primitives, grown by `surface_shift` (how far preparing the scene
/// moved a surface) and a share of the scene's distance for rounding, and points away
/// from every infinite plane.
pub fn background_pixels(scene: &Scene, camera: &Camera, width: u32, height: u32, surface_shift: f64) -> Vec<bool> {
    let rays = Rays::new(camera, width, height);
    let reach = scene.bounds().map_or(0.0, |b| {
        let far = (b.min.as_dvec3() - camera.eye).abs().max((b.max.as_dvec3() - camera.eye).abs());
        far.length()
    });
    let margin = RELATIVE_MARGIN * reach + surface_shift;
    let boxes = boxes(scene, margin);
    let planes: Vec<(DVec3, DVec3)> = scene.planes.iter().map(|p| (p.normal.as_dvec3(), p.point.as_dvec3())).collect();
    let plane_margin = RELATIVE_MARGIN * (reach + camera.eye.length()) + surface_shift;
    let (tiles_x, tiles_y) = (width.div_ceil(TILE), height.div_ceil(TILE));
    let tiles: Vec<Vec<(u32, u32, bool)>> = (0..tiles_x * tiles_y)
        .into_par_iter()
        .map(|t| {
            let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
            let (x1, y1) = ((x0 + TILE).min(width), (y0 + TILE).min(height));
            let m = PIXEL_MARGIN;
            let tile = rays.sides(x0 as f64 - m, y0 as f64 - m, x1 as f64 + m, y1 as f64 + m);
            let seen: Vec<&Box3> = boxes.iter().filter(|b| !tile.iter().any(|s| s.excludes(b))).collect();
            let mut out = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (fx, fy) = (x as f64, y as f64);
                    let (a, b) = (fx - m, fy - m);
                    let (c, d) = (fx + 1.0 + m, fy + 1.0 + m);
                    let sides = rays.sides(a, b, c, d);
                    let corners = rays.corners(a, b, c, d);
                    let clear = seen.iter().all(|bx| sides.iter().any(|s| s.excludes(bx)))
                        && planes.iter().all(|&(n, p)| misses_plane(&corners, n, p, plane_margin));
                    out.push((x, y, clear));
                }
            }
            out
        })
        .collect();
    let mut mask = vec![false; width as usize * height as usize];
    for (x, y, clear) in tiles.into_iter().flatten() {
        mask[y as usize * width as usize + x as usize] = clear;
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Plane;
    use crate::scene::Sphere;

    fn camera(eye: DVec3, look_at: DVec3) -> Camera {
        Camera { eye, look_at, up: Vec3::Y, projection: Projection::Perspective { vfov_deg: 60.0 } }
    }

    #[test]
    fn a_plane_is_seen_below_the_horizon_and_not_above_it() {
        let mut scene = Scene::from_triangles("floor", Vec::new());
        scene.planes.push(Plane { normal: Vec3::Y, point: Vec3::ZERO, albedo: 1.0 });
        // Eye 1 above the floor looking level: the horizon is the image's middle row.
        let mask = background_pixels(&scene, &camera(DVec3::Y, DVec3::new(0.0, 1.0, -1.0)), 32, 32, 0.0);
        for y in 0..32 {
            let row = &mask[y * 32..(y + 1) * 32];
            // Rows whose whole footprint is clearly above the horizon are clear; the
            // middle rows, grazing it, and those below are not.
            let expected = y < 15;
            assert!(row.iter().all(|&c| c == expected), "row {y}: {row:?}");
        }
    }

    #[test]
    fn footprints_that_meet_a_sphere_are_never_clear() {
        let mut scene = Scene::from_triangles("sphere", Vec::new());
        scene.spheres.push(Sphere { center: Vec3::ZERO, radius: 0.5, albedo: 1.0 });
        let cam = camera(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO);
        let (w, h) = (64u32, 48u32);
        let mask = background_pixels(&scene, &cam, w, h, 0.0);
        let rays = Rays::new(&cam, w, h);
        let mut clear = 0;
        for y in 0..h {
            for x in 0..w {
                // 5 × 5 rays across the pixel: none may meet the sphere where it is clear.
                let hit = (0..25).any(|k| {
                    let (o, d) = rays.ray(x as f64 + (k % 5) as f64 / 4.0, y as f64 + (k / 5) as f64 / 4.0);
                    let d = d.normalize();
                    let b = o.dot(d);
                    b * b - (o.length_squared() - 0.25) >= 0.0
                });
                let c = mask[(y * w + x) as usize];
                assert!(!(c && hit), "pixel ({x}, {y}) is clear but a ray meets the sphere");
                clear += c as u32;
            }
        }
        // The sphere's box covers a fifth of the image, wide: most of the rest is clear.
        assert!(clear as f64 > 0.6 * (w * h) as f64, "{clear} of {} pixels clear", w * h);
    }
}
