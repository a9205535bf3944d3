//! Probe points found on the scene's surfaces.
//!
//! A point computed inside a triangle in floating point (sampled on a mesh, interpolated
//! from its corners) is almost never exactly on it: rounded to f32, half of such points
//! sit just under their surface, where a ray leaving it hits the surface itself and the
//! point reads dark. [`SurfaceIndex::locate`] finds the surface each probe point lies on,
//! within a tolerance, and gives the probe what a camera hit has (pbrt-v4 §6.8.6): the
//! surface's normal and a bound on the point's distance to it, by which its AO rays start
//! off the surface along that normal. A point that is a triangle's corner (a vertex) is
//! exactly on its surface and is left as it is; a point on no surface within the
//! tolerance is traced as given, and counted.
//!
//! The search is obvhs's BVH2 over the boxes of the scene's triangles and spheres (and of
//! the instances, each mesh with its own, searched in its own space), built once per
//! session, with the box of each point's tolerance; distances are computed in f64 from the
//! f32 geometry, and each bound includes its own rounding, so a point exactly on an
//! axis-aligned surface gets a bound of exactly zero.

use crate::error::{Error, Result};
use crate::geometry::{gamma, instance_entry_error};
use crate::probe::Probe;
use crate::scene::{Scene, round_up};
use glam::{DMat3, DVec3, Vec3, Vec3A};
use obvhs::BvhBuildParams;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use rayon::prelude::*;

/// The default tolerance relative to the largest absolute coordinate of the point and the
/// surface's corners: 2⁻¹⁸, 32 steps of f32 rounding there, above what computing a point
/// on a triangle in f32 or f64 and rounding it costs, and far below any feature.
pub const RELATIVE_TOLERANCE: f64 = 1.0 / (1u32 << 18) as f64;

/// How far from a surface a probe point may be and still be taken as on it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum SurfaceTolerance {
    /// [`RELATIVE_TOLERANCE`] of the largest absolute coordinate of the point and the
    /// surface's corners (a sphere's centre plus its radius; a plane's point).
    #[default]
    Relative,
    /// A distance in the scene's units: 0 takes only points exactly on a surface.
    Distance(f32),
}

impl SurfaceTolerance {
    /// A distance, checked: finite and non-negative.
    pub fn distance(d: f32) -> Result<SurfaceTolerance> {
        if d.is_finite() && d >= 0.0 {
            Ok(SurfaceTolerance::Distance(d))
        } else {
            Err(Error::settings(format!("surface tolerance must be a finite distance of at least 0, got {d}")))
        }
    }
}

/// Probes with the surfaces they lie on.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Located {
    /// The probes in input order: a point found on a surface with that surface's normal
    /// and its bound (a vertex, and a point on no surface, as given).
    pub probes: Vec<Probe>,
    /// Whether each point lies on a surface within the tolerance.
    pub on_surface: Vec<bool>,
}

impl Located {
    /// Points on no surface within the tolerance: traced as given.
    pub fn off_surface(&self) -> usize {
        self.on_surface.iter().filter(|&&on| !on).count()
    }
}

/// The scene's surfaces, searchable by position.
pub struct SurfaceIndex {
    /// Over the world triangles, then the spheres (`index - triangles`).
    top: Bvh2,
    /// Over the instances' world boxes.
    instances: Bvh2,
    /// Over each instanced mesh's triangles, in its space.
    meshes: Vec<Bvh2>,
    /// Each instance's maps.
    placements: Vec<Placement>,
    /// The largest absolute coordinate of the finite primitives.
    extent: f64,
}

/// An instance's maps in f64 (exact images of its f32 matrix), and its norm.
struct Placement {
    linear: DMat3,
    translation: DVec3,
    inverse: DMat3,
    /// max_i Σ_j |L_ij|.
    linear_norm: f64,
    /// max_i Σ_j |L⁻¹_ij|: how far a world step of `r` on each axis can move in the mesh.
    inverse_norm: f64,
}

/// The unit roundoff of f64.
const EPS64: f64 = f64::EPSILON / 2.0;

/// The nearest surface found so far for one point.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// Euclidean distance to the surface.
    distance: f64,
    /// Which surface: kind (triangle, sphere, instance's triangle, plane), indices; ties
    /// go to the first.
    key: (u8, u32, u32),
    /// Bound on the distance to the surface's plane (tangent plane), rounding included.
    bound: f64,
    /// Unit normal (either side).
    normal: DVec3,
    /// The instance, for an instance's triangle.
    instance: Option<u32>,
    /// The point is a corner of the triangle.
    vertex: bool,
}

impl Candidate {
    fn better(&self, other: &Option<Candidate>) -> bool {
        other.is_none_or(|o| (self.distance, self.key) < (o.distance, o.key))
    }
}

fn aabb(min: DVec3, max: DVec3) -> Aabb {
    let down = |x: f64| {
        let f = x as f32;
        if (f as f64) > x { f.next_down() } else { f }
    };
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x { f.next_up() } else { f }
    };
    Aabb::new(Vec3A::new(down(min.x), down(min.y), down(min.z)), Vec3A::new(up(max.x), up(max.y), up(max.z)))
}

fn build(aabbs: &[Aabb]) -> Bvh2 {
    if aabbs.is_empty() {
        return Bvh2::default();
    }
    obvhs::bvh2::builder::build_bvh2(aabbs, BvhBuildParams::fast_build(), &mut Default::default())
}

/// Calls `f` with every primitive of `bvh` whose box meets `query`.
fn each_in(bvh: &Bvh2, query: Aabb, mut f: impl FnMut(u32)) {
    bvh.aabb_traverse(query, |bvh, node| {
        let node = &bvh.nodes[node as usize];
        for i in node.first_index..node.first_index + node.prim_count {
            f(bvh.primitive_indices[i as usize]);
        }
        true
    });
}

/// Ericson's closest point of triangle `abc` to `p` (Real-Time Collision Detection, §5.1.5).
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + d1 / (d1 - d3) * ab;
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + d2 / (d2 - d6) * ac;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Point `p` against the triangle `v` (f64 images of f32 corners, within `corner_error`
/// of them): the Euclidean distance, a bound on the distance to its plane (the f64
/// rounding included: zero only for a point exactly on the plane), its unit normal.
fn triangle(p: DVec3, v: [DVec3; 3], corner_error: f64) -> Option<(f64, f64, DVec3)> {
    let (a, b) = (v[1] - v[0], v[2] - v[0]);
    let n = a.cross(b);
    let len = n.length();
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    let w = p - v[0];
    // Each product of the cross and dot products, and each difference, rounds once.
    let terms = DVec3::new(
        (a.y * b.z).abs() + (a.z * b.y).abs(),
        (a.z * b.x).abs() + (a.x * b.z).abs(),
        (a.x * b.y).abs() + (a.y * b.x).abs(),
    );
    let rounding = 8.0 * EPS64 * w.abs().dot(terms);
    let bound = (w.dot(n).abs() + rounding) / len * (1.0 + 4.0 * EPS64) + corner_error;
    let closest = closest_on_triangle(p, v[0], v[1], v[2]);
    Some(((p - closest).length(), bound, n / len))
}

impl SurfaceIndex {
    /// The index of `scene`'s surfaces (its planes are tested one by one).
    pub fn new(scene: &Scene) -> SurfaceIndex {
        let corners = |v: &[Vec3; 3]| {
            let (min, max) = (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]));
            aabb(min.as_dvec3(), max.as_dvec3())
        };
        let boxes: Vec<Aabb> = scene
            .triangles
            .iter()
            .map(|t| corners(&t.v))
            .chain(scene.spheres.iter().map(|s| {
                let (c, r) = (s.center.as_dvec3(), s.radius as f64);
                aabb(c - r * (1.0 + 4.0 * EPS64), c + r * (1.0 + 4.0 * EPS64))
            }))
            .collect();
        let top = build(&boxes);
        let meshes: Vec<Bvh2> =
            scene.meshes.iter().map(|m| build(&m.triangles.iter().map(corners).collect::<Vec<_>>())).collect();
        let placements: Vec<Placement> = scene
            .instances
            .iter()
            .map(|i| {
                let m = i.to_world.as_dmat4();
                let linear = DMat3::from_mat4(m);
                let inverse = linear.inverse();
                let norm = |a: DMat3| (0..3).map(|k| a.row(k).abs().element_sum()).fold(0.0, f64::max);
                let (linear_norm, inverse_norm) = (norm(linear), norm(inverse));
                Placement { linear, translation: m.w_axis.truncate(), inverse, linear_norm, inverse_norm }
            })
            .collect();
        let instance_boxes: Vec<Aabb> = scene
            .instances
            .iter()
            .zip(&placements)
            .map(|(i, pl)| {
                let (mut min, mut max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
                for t in &scene.meshes[i.mesh as usize].triangles {
                    for v in t {
                        let w = pl.linear * v.as_dvec3() + pl.translation;
                        (min, max) = (min.min(w), max.max(w));
                    }
                }
                let slack = 4.0 * EPS64 * min.abs().max(max.abs()).max_element();
                aabb(min - slack, max + slack)
            })
            .collect();
        let instances = build(&instance_boxes);
        let extent = scene.bounds().map_or(0.0, |b| b.min.abs().max(b.max.abs()).max_element() as f64);
        SurfaceIndex { top, instances, meshes, placements, extent }
    }

    /// Each probe on the surface it lies on within `tolerance` (see [`Located`]); the
    /// probes' own error bounds and surface normals are replaced, except a vertex's and a
    /// point's on no surface.
    pub fn locate(&self, scene: &Scene, probes: &[Probe], tolerance: SurfaceTolerance) -> Located {
        let (probes, on_surface) = probes
            .par_iter()
            .map(|probe| match self.nearest(scene, probe.position, tolerance) {
                None => (*probe, false),
                Some(c) if c.vertex => (*probe, true),
                Some(c) => {
                    let g = c.normal.as_vec3();
                    let mut bound = c.bound;
                    if let Some(i) = c.instance {
                        let instance = &scene.instances[i as usize];
                        let (rows, back) = (instance.to_world_rows(), instance.to_object());
                        bound += instance_entry_error(&rows, &back, probe.position, round_up(bound), g) as f64;
                    }
                    // The offset and each coordinate's step along g reach at least (1 − 4ε)·error.
                    let error = round_up(bound * (1.0 + gamma(4) as f64));
                    let located = Probe::on_surface(probe.position, probe.normal, g, error);
                    (located.expect("a unit normal and a finite bound"), true)
                }
            })
            .unzip();
        Located { probes, on_surface }
    }

    /// The nearest surface to `p` within the tolerance, a vertex at once.
    fn nearest(&self, scene: &Scene, p: Vec3, tolerance: SurfaceTolerance) -> Option<Candidate> {
        let pd = p.as_dvec3();
        let point_max = pd.abs().max_element();
        let allowed = |corner_max: f64| match tolerance {
            SurfaceTolerance::Distance(d) => d as f64,
            SurfaceTolerance::Relative => RELATIVE_TOLERANCE * point_max.max(corner_max),
        };
        // Every surface within the tolerance meets this box.
        let radius = match tolerance {
            SurfaceTolerance::Distance(d) => d as f64,
            SurfaceTolerance::Relative => RELATIVE_TOLERANCE * point_max.max(self.extent) * (1.0 + 1e-9),
        };
        let query = aabb(pd - radius, pd + radius);
        let mut best: Option<Candidate> = None;
        let triangles = scene.triangles.len() as u32;
        each_in(&self.top, query, |k| {
            if best.is_some_and(|b| b.vertex) {
                return;
            }
            let found = if k < triangles {
                let v = scene.triangles[k as usize].v;
                let Some((distance, bound, normal)) = triangle(pd, v.map(Vec3::as_dvec3), 0.0) else { return };
                let corner_max = v.iter().map(|c| c.abs().max_element()).fold(0.0f32, f32::max) as f64;
                if distance > allowed(corner_max) {
                    return;
                }
                let vertex = v.contains(&p);
                Candidate { distance, key: (0, k, 0), bound, normal, instance: None, vertex }
            } else {
                let s = &scene.spheres[(k - triangles) as usize];
                let (f, r) = (pd - s.center.as_dvec3(), s.radius as f64);
                let l = f.length();
                let distance = (l - r).abs();
                if l <= 0.0 || distance > allowed(s.center.abs().max_element() as f64 + r) {
                    return;
                }
                let bound = distance + 4.0 * EPS64 * (l + r);
                Candidate { distance, key: (1, k - triangles, 0), bound, normal: f / l, instance: None, vertex: false }
            };
            if found.vertex || found.better(&best) {
                best = Some(found);
            }
        });
        if best.is_some_and(|b| b.vertex) {
            return best;
        }
        each_in(&self.instances, query, |i| {
            let (instance, pl) = (&scene.instances[i as usize], &self.placements[i as usize]);
            let local = pl.inverse * (pd - pl.translation);
            let r = radius * pl.inverse_norm * (1.0 + 1e-9);
            let mesh = &scene.meshes[instance.mesh as usize];
            each_in(&self.meshes[instance.mesh as usize], aabb(local - r, local + r), |k| {
                let v = mesh.triangles[k as usize];
                let world = v.map(|v| pl.linear * v.as_dvec3() + pl.translation);
                // Each f64 image is within 3ε(|L||v| + |t|) of the exact one per axis, and
                // moving the corners moves the plane near the triangle by at most about as much.
                let v_max = v.iter().map(|c| c.abs().max_element()).fold(0.0f32, f32::max) as f64;
                let image = pl.linear_norm * v_max + pl.translation.abs().max_element();
                let corner_error = 16.0 * EPS64 * image;
                let corner_max = world.iter().map(|w| w.abs().max_element()).fold(0.0, f64::max);
                let Some((distance, bound, normal)) = triangle(pd, world, corner_error) else { return };
                if distance > allowed(corner_max) {
                    return;
                }
                let found = Candidate { distance, key: (2, i, k), bound, normal, instance: Some(i), vertex: false };
                if found.better(&best) {
                    best = Some(found);
                }
            });
        });
        for (i, plane) in scene.planes.iter().enumerate() {
            let (n, w) = (plane.normal.as_dvec3(), pd - plane.point.as_dvec3());
            let len = n.length();
            let distance = w.dot(n).abs() / len;
            if distance > allowed(plane.point.abs().max_element() as f64) {
                continue;
            }
            let bound = (w.dot(n).abs() + 4.0 * EPS64 * w.abs().dot(n.abs())) / len * (1.0 + 4.0 * EPS64);
            let found =
                Candidate { distance, key: (3, i as u32, 0), bound, normal: n / len, instance: None, vertex: false };
            if found.better(&best) {
                best = Some(found);
            }
        }
        best
    }
}
