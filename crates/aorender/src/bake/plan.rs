//! The points of a bake: every vertex (or face centroid) of every baked mesh placed in
//! the world as a probe, with its normal and the bound on its distance to the surface the
//! rays are traced against; and the probes' estimates handed back per mesh.

use super::asset::{AssetMesh, BakeAt, BakedValues};
use crate::geometry::{AffineRows, InverseAffine, gamma, instance_point};
use crate::probe::{Probe, ProbeValue};
use crate::scene::{MIN_NORMAL_LENGTH_SQUARED, MeshObject, place_point};
use glam::{DVec3, Mat3, Mat4, Vec3};
use rayon::prelude::*;

/// How a baked mesh is placed in the scene: by `to_world` into the scene's triangles (each
/// vertex through [`place_point`], as the loader placed it), or as an instance
/// whose rays are carried into the mesh's own space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Object to world.
    pub to_world: Mat4,
    /// Whether the scene holds the mesh as an instance (`Scene::instances`) rather than
    /// as world-space triangles.
    pub instanced: bool,
}

impl Placement {
    /// The placement of `object` in `scene`.
    pub fn of(object: &MeshObject) -> Placement {
        Placement { to_world: object.to_world, instanced: object.instance.is_some() }
    }
}

/// The value an entry without a usable normal gets (a vertex no face uses, or whose
/// faces and file normal are all degenerate): 1, fully open, with standard error 0 — it
/// darkens nothing it is multiplied into. [`BakePlan::unusable`] counts them.
pub const UNUSABLE_VALUE: f32 = 1.0;

/// Where an entry's value comes from in [`BakePlan`]: a probe's index, or none.
const NO_PROBE: u32 = u32::MAX;

/// The points of a bake: every vertex (or face) of every baked mesh as a probe — its
/// position in the world, its normal, and the bound on its distance to the surface the
/// rays are traced against — and where each probe's value goes back to.
#[derive(Clone, Debug, Default)]
pub struct BakePlan {
    /// The probes, mesh after mesh.
    pub probes: Vec<Probe>,
    /// For each mesh, for each entry: the index of its probe, or [`NO_PROBE`].
    entries: Vec<Vec<u32>>,
    /// Entries without a usable normal: they get [`UNUSABLE_VALUE`].
    pub unusable: usize,
    /// Entries whose normal is the file's.
    pub file_normals: usize,
    /// For each mesh: world directions into its file's space.
    to_file: Vec<Mat3>,
}

impl BakePlan {
    /// The plan of baking `meshes`, each with its placement, at `at`.
    pub fn new<'a>(meshes: impl IntoIterator<Item = (&'a AssetMesh, Placement)>, at: BakeAt) -> BakePlan {
        let mut plan = BakePlan::default();
        for (mesh, placement) in meshes {
            let entries = match at {
                BakeAt::Vertices => plan.add_vertices(mesh, &placement),
                BakeAt::Faces => plan.add_faces(mesh, &placement),
            };
            plan.entries.push(entries);
            plan.to_file.push(mesh.to_file * Mat3::from_mat4(placement.to_world).inverse());
        }
        plan
    }

    /// Number of meshes.
    pub fn mesh_count(&self) -> usize {
        self.entries.len()
    }

    /// Number of entries (vertices or faces) in all meshes.
    pub fn entry_count(&self) -> usize {
        self.entries.iter().map(Vec::len).sum()
    }

    /// The values of every mesh from the probes' estimates (`values[k]` of `probes[k]`)
    /// and, when given, the probes' mean escaped directions (world space), which become
    /// unit bent normals in each file's space: the probe's normal where no ray escaped,
    /// zero for an entry without a usable normal.
    pub fn values(&self, values: &[ProbeValue], bent: Option<&[Vec3]>) -> Vec<BakedValues> {
        self.entries
            .iter()
            .zip(&self.to_file)
            .map(|(entries, to_file)| {
                let value = |&k: &u32| (k != NO_PROBE).then(|| values[k as usize]);
                let bent_normal = |bent: &[Vec3], k: u32| {
                    if k == NO_PROBE {
                        return Vec3::ZERO;
                    }
                    let b = bent[k as usize];
                    let b = if usable(b) { b } else { self.probes[k as usize].normal };
                    (*to_file * b).normalize()
                };
                BakedValues {
                    ao: entries.iter().map(|k| value(k).map_or(UNUSABLE_VALUE, |v| v.mean as f32)).collect(),
                    std_error: entries.iter().map(|k| value(k).map_or(0.0, |v| v.std_error as f32)).collect(),
                    bent_normals: bent.map(|b| entries.iter().map(|&k| bent_normal(b, k)).collect()),
                }
            })
            .collect()
    }

    /// Adds a probe at `p` (in the mesh's space) with world normal `n` (usable), `p`
    /// within `e` (componentwise) of the mesh's surface; returns its index.
    fn push(&mut self, placement: &Placement, p: Vec3, e: Vec3, n: Vec3) -> u32 {
        self.probes.push(place(placement, p, e, n));
        self.probes.len() as u32 - 1
    }

    fn add_vertices(&mut self, mesh: &AssetMesh, placement: &Placement) -> Vec<u32> {
        let (normals, file) = vertex_normals(mesh, placement);
        self.file_normals += file;
        // The probes made over threads, then numbered in vertex order.
        let made: Vec<Option<Probe>> = normals
            .par_iter()
            .enumerate()
            .map(|(i, normal)| normal.map(|n| place(placement, mesh.positions[i], Vec3::ZERO, n)))
            .collect();
        self.probes.reserve(made.iter().flatten().count());
        made.into_iter()
            .map(|probe| match probe {
                Some(probe) => {
                    self.probes.push(probe);
                    self.probes.len() as u32 - 1
                }
                None => {
                    self.unusable += 1;
                    NO_PROBE
                }
            })
            .collect()
    }

    fn add_faces(&mut self, mesh: &AssetMesh, placement: &Placement) -> Vec<u32> {
        let m = placement.to_world;
        (0..mesh.face_count())
            .map(|f| {
                let face = mesh.face(f);
                let world: Vec<DVec3> =
                    face.iter().map(|&i| place_point(&m, mesh.positions[i as usize]).as_dvec3()).collect();
                let normal = polygon_area_vector(world.iter().copied()).as_vec3();
                if face.len() < 3 || !usable(normal) {
                    self.unusable += 1;
                    return NO_PROBE;
                }
                // The area-weighted centroid of the fan triangles and its largest distance to
                // their planes (a polygon need not be planar; the rounding of the centroid
                // to f32 is included): in the world, from the corners as the scene holds
                // them, for triangles placed into the world; in the mesh's space for an
                // instance, whose rays meet the mesh there.
                let corners: Vec<DVec3> = if placement.instanced {
                    face.iter().map(|&i| mesh.positions[i as usize].as_dvec3()).collect()
                } else {
                    world
                };
                let (c, distance) = centroid(&corners);
                if placement.instanced {
                    return self.push(placement, c, Vec3::splat(distance), normal);
                }
                let n = normal.normalize();
                self.probes.push(Probe { position: c, normal: n, error: distance, surface_normal: Vec3::ZERO });
                self.probes.len() as u32 - 1
            })
            .collect()
    }
}

/// A probe at `p` (in the mesh's space) with world normal `n` (usable), `p` within `e`
/// (componentwise) of the mesh's surface.
fn place(placement: &Placement, p: Vec3, e: Vec3, n: Vec3) -> Probe {
    let n = n.normalize();
    if placement.instanced {
        let rows = AffineRows::from_mat4(&placement.to_world);
        let back = InverseAffine::of(&placement.to_world);
        let point = instance_point(&rows, &back, p, e, n);
        Probe { position: point.p, normal: n, error: point.error, surface_normal: Vec3::ZERO }
    } else {
        // A vertex, as the loader placed it: exactly on the world's triangles. (Points
        // inside triangles placed into the world never come here: their bound is found
        // in the world, from the corners as the scene holds them.)
        debug_assert_eq!(e, Vec3::ZERO);
        Probe { position: place_point(&placement.to_world, p), normal: n, error: 0.0, surface_normal: Vec3::ZERO }
    }
}

/// The world normal of every vertex of `mesh` as the bake uses it: the file's where it is
/// usable, else the sum of its faces' area vectors; `None` where neither is usable. With
/// the number that are the file's.
pub(super) fn vertex_normals(mesh: &AssetMesh, placement: &Placement) -> (Vec<Option<Vec3>>, usize) {
    let m = placement.to_world;
    let normal_matrix = Mat3::from_mat4(m).as_dmat3().inverse().transpose();
    // Area-weighted face normals (twice the area), in the world, summed per vertex.
    let world: Vec<DVec3> = mesh.positions.par_iter().map(|&p| place_point(&m, p).as_dvec3()).collect();
    let area = area_sums(mesh, &world);
    let (normals, from_file): (Vec<Option<Vec3>>, Vec<bool>) = (0..mesh.positions.len())
        .into_par_iter()
        .map(|i| {
            let file = mesh.normals.as_ref().map(|n| (normal_matrix * n[i].as_dvec3()).as_vec3());
            let (normal, from_file) = match file {
                Some(n) if usable(n) => (n, true),
                _ => (area[i].as_vec3(), false),
            };
            (usable(normal).then_some(normal), from_file)
        })
        .unzip();
    (normals, from_file.iter().filter(|&&f| f).count())
}

/// Vertices below which [`area_sums`] gives a thread no share of its own.
const AREA_SHARE: usize = 1 << 12;

/// Per vertex of `mesh`, the sum of the area vectors of the faces it is a corner of
/// (`world`: its vertices in the world), over threads: each owns a range of vertices
/// and goes through every face in order, so that each vertex adds its faces' vectors
/// in face order, as one pass over the faces does, and gets the same bits whatever the
/// number of threads.
fn area_sums(mesh: &AssetMesh, world: &[DVec3]) -> Vec<DVec3> {
    let mut area: Vec<DVec3> = bytemuck::zeroed_vec(world.len());
    let shares = rayon::current_num_threads().min(world.len() / AREA_SHARE).max(1);
    let share = world.len().div_ceil(shares).max(1);
    area.par_chunks_mut(share).enumerate().for_each(|(r, own)| {
        let mine = r * share..r * share + own.len();
        for f in 0..mesh.face_count() {
            let face = mesh.face(f);
            if !face.iter().any(|&i| mine.contains(&(i as usize))) {
                continue;
            }
            let n = polygon_area_vector(face.iter().map(|&i| world[i as usize]));
            for &i in face.iter().filter(|&&i| mine.contains(&(i as usize))) {
                own[i as usize - mine.start] += n;
            }
        }
    });
    area
}

/// A probe at the barycentric coordinates `b` (of corners 1 and 2) of the triangle `tri`
/// (vertex indices) of `mesh` under `placement`, with the world normal `n` (usable): the
/// point rounded to f32, the triangle's normal as its surface normal, and its largest
/// distance to the triangle's plane as the offset bound along it, found where the rays
/// meet the triangle (the world for triangles placed into it, the mesh's space for an
/// instance). Rays leave along the triangle's normal, not `n`: a step along an
/// interpolated normal whose coordinates' signs differ from the triangle's can round the
/// origin under the triangle, where every ray hits it.
pub(super) fn triangle_probe(mesh: &AssetMesh, placement: &Placement, tri: [u32; 3], b: [f64; 2], n: Vec3) -> Probe {
    let corner = |i: u32| {
        let p = mesh.positions[i as usize];
        if placement.instanced { p.as_dvec3() } else { place_point(&placement.to_world, p).as_dvec3() }
    };
    let [a, p1, p2] = tri.map(corner);
    let point = (a + b[0] * (p1 - a) + b[1] * (p2 - a)).as_vec3();
    let distance = plane_bound(point, &[a, p1, p2]);
    let n = n.normalize();
    let face = (p1 - a).cross(p2 - a);
    let (position, g, error) = if placement.instanced {
        let rows = AffineRows::from_mat4(&placement.to_world);
        let back = InverseAffine::of(&placement.to_world);
        let to_world_normal = glam::DMat3::from_mat4(placement.to_world.as_dmat4()).inverse().transpose();
        let g = (to_world_normal * face).normalize_or_zero().as_vec3();
        let world = instance_point(&rows, &back, point, Vec3::splat(distance), g);
        (world.p, g, world.error * (1.0 + gamma(4)))
    } else {
        // The offset and each coordinate's step along g reach at least (1 − 4ε)·error.
        (point, face.normalize_or_zero().as_vec3(), distance * (1.0 + gamma(4)))
    };
    let g = if g.dot(n) < 0.0 { -g } else { g };
    Probe { position, normal: n, error, surface_normal: if g == n { Vec3::ZERO } else { g } }
}

/// The area-weighted centroid of a polygon's fan triangles, rounded to f32, and a bound on
/// its distance to their planes.
fn centroid(corners: &[DVec3]) -> (Vec3, f32) {
    let (mut sum, mut total) = (DVec3::ZERO, 0.0);
    for k in 1..corners.len() - 1 {
        let a = (corners[k] - corners[0]).cross(corners[k + 1] - corners[0]).length();
        sum += a * (corners[0] + corners[k] + corners[k + 1]) / 3.0;
        total += a;
    }
    let c = if total > 0.0 { sum / total } else { corners.iter().sum::<DVec3>() / corners.len() as f64 };
    let c = c.as_vec3();
    (c, plane_bound(c, corners))
}

/// A bound on the distance of `c` to the planes of the fan triangles of `corners`.
fn plane_bound(c: Vec3, corners: &[DVec3]) -> f32 {
    let mut distance = 0.0f64;
    for k in 1..corners.len() - 1 {
        let n = (corners[k] - corners[0]).cross(corners[k + 1] - corners[0]);
        if n.length() > 0.0 {
            distance = distance.max((c.as_dvec3() - corners[0]).dot(n.normalize()).abs());
        }
    }
    // The f64 arithmetic's own rounding, generously.
    (distance * (1.0 + 1e-9) + 1e-12 * c.as_dvec3().abs().max_element()) as f32 * (1.0 + gamma(1))
}
/// Twice the area times the unit normal of a polygon, summed over its fan triangles.
fn polygon_area_vector(mut corners: impl Iterator<Item = DVec3>) -> DVec3 {
    let (Some(first), Some(mut previous)) = (corners.next(), corners.next()) else { return DVec3::ZERO };
    // The fan's cross products added in order from zero, without gathering the corners.
    let mut sum = DVec3::ZERO;
    for c in corners {
        sum += (previous - first).cross(c - first);
        previous = c;
    }
    sum
}

/// Whether a normal can be normalised in f32.
fn usable(n: Vec3) -> bool {
    n.is_finite() && n.length_squared() >= MIN_NORMAL_LENGTH_SQUARED && n.length_squared().is_finite()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The normals as one pass over the faces computes them, for comparison.
    fn one_pass_normals(mesh: &AssetMesh, placement: &Placement) -> (Vec<Option<Vec3>>, usize) {
        let m = placement.to_world;
        let normal_matrix = Mat3::from_mat4(m).as_dmat3().inverse().transpose();
        let world: Vec<DVec3> = mesh.positions.iter().map(|&p| place_point(&m, p).as_dvec3()).collect();
        let mut area = vec![DVec3::ZERO; mesh.positions.len()];
        for f in 0..mesh.face_count() {
            let face = mesh.face(f);
            let c: Vec<DVec3> = face.iter().map(|&i| world[i as usize]).collect();
            let n: DVec3 = (1..c.len().saturating_sub(1)).map(|k| (c[k] - c[0]).cross(c[k + 1] - c[0])).sum();
            for &i in face {
                area[i as usize] += n;
            }
        }
        let mut file_normals = 0;
        let normals = (0..mesh.positions.len())
            .map(|i| {
                let file = mesh.normals.as_ref().map(|n| (normal_matrix * n[i].as_dvec3()).as_vec3());
                let normal = match file {
                    Some(n) if usable(n) => {
                        file_normals += 1;
                        n
                    }
                    _ => area[i].as_vec3(),
                };
                usable(normal).then_some(normal)
            })
            .collect();
        (normals, file_normals)
    }

    #[test]
    fn vertex_normals_have_one_pass_bits_on_any_number_of_threads() {
        // A pseudo-random mesh whose faces (triangles, quads, a pentagon, repeated corners)
        // join vertices far apart in number, so that faces straddle the threads' shares.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        let vertices = 5 * AREA_SHARE + 123;
        let unit = |v: u32| v as f32 / (1u32 << 31) as f32 - 0.5;
        let positions: Vec<Vec3> = (0..vertices).map(|_| Vec3::new(unit(next()), unit(next()), unit(next()))).collect();
        let (mut face_starts, mut face_indices) = (vec![0u32], Vec::new());
        for f in 0..3 * vertices {
            let corners = [3, 3, 4, 3, 5][f % 5];
            let near = next() as usize % vertices;
            for _ in 0..corners {
                // Mostly nearby vertices, now and then any vertex, sometimes one twice.
                let i = if next().is_multiple_of(8) {
                    next() as usize % vertices
                } else {
                    (near + next() as usize % 64) % vertices
                };
                face_indices.push(i as u32);
            }
            face_starts.push(face_indices.len() as u32);
        }
        // File normals, every seventh unusable (zero) so the face normals fill in.
        let normals: Vec<Vec3> = (0..vertices)
            .map(|k| if k.is_multiple_of(7) { Vec3::ZERO } else { Vec3::new(unit(next()), 1.0, unit(next())) })
            .collect();
        let mut mesh = AssetMesh { positions, face_starts, face_indices, ..Default::default() };
        let placement = Placement {
            to_world: Mat4::from_scale_rotation_translation(
                Vec3::new(1.5, 0.7, 2.0),
                glam::Quat::from_rotation_y(0.3),
                Vec3::new(10.0, -3.0, 0.25),
            ),
            instanced: false,
        };
        let bits = |(n, file): (Vec<Option<Vec3>>, usize)| {
            (n.iter().map(|v| v.map(|v| v.to_array().map(f32::to_bits))).collect::<Vec<_>>(), file)
        };
        for with_file in [false, true] {
            mesh.normals = with_file.then(|| normals.clone());
            let expected = bits(one_pass_normals(&mesh, &placement));
            assert!(expected.0.iter().filter(|n| n.is_some()).count() > vertices * 9 / 10);
            assert_eq!(expected.1 > 0, with_file);
            for threads in [1, 2, 3, 8] {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a thread pool");
                let got = bits(pool.install(|| vertex_normals(&mesh, &placement)));
                assert!(got == expected, "{threads} threads, file normals: {with_file}");
            }
        }
    }
}
