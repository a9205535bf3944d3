//! Closed-form ambient occlusion at the extremes: scenes whose AO at given points is known
//! exactly (albedo 1, cosine-weighted visibility), each built in every variant of scale,
//! position and orientation, to validate a device against. `tests/accuracy.rs` checks
//! them on every device and unbiased sampler; `aorender accuracy` tabulates them
//! (`docs/accuracy.md`).
//!
//! Cases are stated in a frame where the surface normal is +y and the probe sits at or near
//! the origin, in f64; a [`Variant`] maps them to world space and rounds to f32. Expected
//! values are computed from the rounded world geometry, so rounding at 1e6 from the origin
//! changes the question rather than the answer's tolerance.

use crate::device::{BvhOptions, Device};
use crate::error::Result;
use crate::geometry::Plane;
use crate::probe::{Probe, ProbeValue};
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::scene::{Camera, Projection, Sampling, Scene, Settings, Sphere, Triangle, mesh_triangles};
use crate::session::Session;
use glam::{DVec3, Vec3};
use std::path::Path;

/// Where a case is placed: `world = scale · R(p) + (offset, offset, offset)`, with `R` the
/// signed axis permutation that takes the case's +y to `±axis`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Variant {
    /// Uniform scale.
    pub scale: f64,
    /// Translation along each axis.
    pub offset: f64,
    /// The world axis (0 x, 1 y, 2 z) that the case's +y becomes.
    pub axis: usize,
    /// Whether it becomes −axis.
    pub negative: bool,
}

impl Variant {
    /// The case as stated: unit scale, at the origin, normal +y.
    pub const BASE: Variant = Variant { scale: 1.0, offset: 0.0, axis: 1, negative: false };

    /// Scale 1, 1e-4 and 1e6, and translation by 1e6, each with the normal along each ±axis.
    pub fn all() -> Vec<Variant> {
        let mut out = Vec::new();
        for (scale, offset) in [(1.0, 0.0), (1e-4, 0.0), (1e6, 0.0), (1.0, 1e6)] {
            for axis in [1, 0, 2] {
                for negative in [false, true] {
                    out.push(Variant { scale, offset, axis, negative });
                }
            }
        }
        out
    }

    /// "×1e-4 −x", "+1e6 +z", "×1 +y".
    pub fn name(&self) -> String {
        let place = if self.offset != 0.0 { format!("+{:e}", self.offset) } else { format!("×{:e}", self.scale) };
        format!("{place} {}{}", if self.negative { "−" } else { "+" }, ["x", "y", "z"][self.axis])
    }

    /// A direction of the case frame in world space (exact: a signed permutation).
    fn vector(&self, v: DVec3) -> DVec3 {
        let mut w = DVec3::ZERO;
        w[self.axis] = if self.negative { -v.y } else { v.y };
        w[(self.axis + 1) % 3] = v.z;
        w[(self.axis + 2) % 3] = v.x;
        w
    }

    /// A point of the case frame in world space, rounded to f32.
    fn point(&self, p: DVec3) -> Vec3 {
        (self.vector(p) * self.scale + DVec3::splat(self.offset)).as_vec3()
    }

    fn normal(&self, n: DVec3) -> Vec3 {
        self.vector(n).normalize().as_vec3()
    }

    fn length(&self, l: f64) -> f32 {
        (l * self.scale) as f32
    }
}

/// A scene, points in it and the AO each must have.
#[derive(Clone, Debug)]
pub struct Case {
    /// What the case is, without its variant.
    pub name: String,
    /// The variant it was built in.
    pub variant: Variant,
    /// The scene (its camera is unused).
    pub scene: Scene,
    /// The points.
    pub probes: Vec<Probe>,
    /// The exact AO at each point.
    pub expected: Vec<f64>,
}

fn empty_scene(name: &str, v: &Variant) -> Scene {
    let camera = Camera {
        eye: v.point(DVec3::new(0.0, 2.0, 0.0)).as_dvec3(),
        look_at: v.point(DVec3::ZERO).as_dvec3(),
        up: v.normal(DVec3::Z),
        projection: Projection::Orthographic { height: v.length(1.0) },
    };
    Scene { camera, ..Scene::from_triangles(name, Vec::new()) }
}

/// The plane through case point `p` with case normal `n`.
fn plane(v: &Variant, p: DVec3, n: DVec3) -> Plane {
    Plane { normal: v.normal(n), point: v.point(p), albedo: 1.0 }
}

fn probe_at(v: &Variant, p: DVec3, n: DVec3) -> Probe {
    Probe::new(v.point(p), v.normal(n)).expect("case normals are non-zero")
}

/// 1 − h r² / d³ = 1 − cos β (r/d)²: a point on a plane under a sphere wholly above it,
/// from the rounded world values.
fn sphere_cap(p: &Probe, s: &Sphere) -> f64 {
    let to_centre = s.center.as_dvec3() - p.position.as_dvec3();
    let h = to_centre.dot(p.normal.as_dvec3());
    let d = to_centre.length();
    let r = s.radius as f64;
    assert!(h >= r, "the sphere must lie wholly above the plane");
    1.0 - h * r * r / (d * d * d)
}

/// A mesh of shared vertices, in f64 (before any placement and rounding).
#[derive(Clone, Debug, PartialEq)]
pub struct IndexedMesh {
    /// Vertex positions.
    pub vertices: Vec<DVec3>,
    /// Triangles as indices into `vertices`, wound outward.
    pub triangles: Vec<[usize; 3]>,
}

impl IndexedMesh {
    /// The triangles in world space: each vertex placed by `v` once, so that every
    /// triangle sharing it reads the same f32 value.
    fn place(&self, v: &Variant) -> Vec<[Vec3; 3]> {
        let world: Vec<Vec3> = self.vertices.iter().map(|&p| v.point(p)).collect();
        self.triangles.iter().map(|t| t.map(|i| world[i])).collect()
    }
}

/// The cube [-1, 1]³ as 12 triangles; corner i has x = bit 0, y = bit 1, z = bit 2.
pub fn unit_cube() -> IndexedMesh {
    let vertices =
        (0..8).map(|i| DVec3::new([-1.0, 1.0][i & 1], [-1.0, 1.0][(i >> 1) & 1], [-1.0, 1.0][i >> 2])).collect();
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let triangles = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    IndexedMesh { vertices, triangles }
}

/// The icosahedron subdivided `levels` times, vertices on the unit sphere.
pub fn unit_icosphere(levels: u32) -> IndexedMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<DVec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|&p| DVec3::from_array(p).normalize())
    .collect();
    let mut triangles: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut midpoints = std::collections::HashMap::new();
        let mut mid = |a: usize, b: usize, vertices: &mut Vec<DVec3>| -> usize {
            *midpoints.entry((a.min(b), a.max(b))).or_insert_with(|| {
                vertices.push((0.5 * (vertices[a] + vertices[b])).normalize());
                vertices.len() - 1
            })
        };
        let mut next = Vec::with_capacity(triangles.len() * 4);
        for [a, b, c] in triangles {
            let (ab, bc, ca) = (mid(a, b, &mut vertices), mid(b, c, &mut vertices), mid(c, a, &mut vertices));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    IndexedMesh { vertices, triangles }
}

/// The placed unit cube plus two degenerate triangles on an edge: a repeated vertex and
/// three collinear vertices.
fn cube(v: &Variant) -> Vec<[Vec3; 3]> {
    let mut tris = unit_cube().place(v);
    let (c0, c1) = (v.point(DVec3::splat(-1.0)), v.point(DVec3::new(1.0, -1.0, -1.0)));
    let mid = v.point(DVec3::new(0.0, -1.0, -1.0));
    tris.push([c0, c0, c1]);
    tris.push([c0, mid, c1]);
    tris
}

/// A floor of `count` slivers fanned around the origin out to `radius`, in the plane y = 0.
fn sliver_fan(v: &Variant, count: usize, radius: f64) -> Vec<[Vec3; 3]> {
    let rim: Vec<Vec3> = (0..count)
        .map(|k| {
            let phi = std::f64::consts::TAU * k as f64 / count as f64;
            v.point(DVec3::new(radius * phi.cos(), 0.0, radius * phi.sin()))
        })
        .collect();
    let apex = v.point(DVec3::ZERO);
    (0..count).map(|k| [apex, rim[k], rim[(k + 1) % count]]).collect()
}

fn mesh(name: &str, tris: Vec<[Vec3; 3]>) -> Vec<Triangle> {
    mesh_triangles(Path::new(name), tris, 1.0).expect("case meshes have triangles")
}

/// Every case in variant `v`. A case whose rounded geometry no longer poses its question
/// (a wall rounded onto the point) is left out of that variant.
pub fn cases(v: &Variant) -> Vec<Case> {
    let up = DVec3::Y;
    let mut out = Vec::new();
    let mut push = |name: String, scene: Scene, probes: Vec<Probe>, expected: Vec<f64>| {
        out.push(Case { name, variant: *v, scene, probes, expected });
    };

    // An unoccluded plane: 1.
    let mut s = empty_scene("open plane", v);
    s.planes.push(plane(v, DVec3::ZERO, up));
    let probes = vec![probe_at(v, DVec3::ZERO, up), probe_at(v, DVec3::new(3.0, 0.0, -7.0), up)];
    push("open plane".into(), s, probes, vec![1.0, 1.0]);

    // A plane under a sphere wholly above it: 1 − cos β (r/d)².
    for (r, d, beta_deg) in [(0.5f64, 1.0f64, 30.0f64), (0.3, 2.0, 60.0), (0.5, 1.0, 0.0)] {
        let beta = beta_deg.to_radians();
        let centre = DVec3::new(d * beta.sin(), d * beta.cos(), 0.0);
        let mut s = empty_scene("sphere cap", v);
        s.planes.push(plane(v, DVec3::ZERO, up));
        let sphere = Sphere { center: v.point(centre), radius: v.length(r), albedo: 1.0 };
        s.spheres.push(sphere);
        let probes = vec![probe_at(v, DVec3::ZERO, up)];
        let expected = probes.iter().map(|p| sphere_cap(p, &sphere)).collect();
        push(format!("plane under sphere r {r} d {d} β {beta_deg}°"), s, probes, expected);
    }

    // The same over a floor of 1,000 slivers fanned around the point (a shared vertex) and
    // a point inside a sliver near its tip.
    {
        let centre = DVec3::new(0.5, 0.875, 0.0);
        let mut s = empty_scene("sliver floor", v);
        s.triangles = mesh("sliver floor", sliver_fan(v, 1000, 10.0));
        let sphere = Sphere { center: v.point(centre), radius: v.length(0.5), albedo: 1.0 };
        s.spheres.push(sphere);
        let probes = vec![probe_at(v, DVec3::ZERO, up), probe_at(v, DVec3::new(2.5, 0.0, 0.0625), up)];
        let expected = probes.iter().map(|p| sphere_cap(p, &sphere)).collect();
        push("1,000-sliver floor under sphere r 0.5".into(), s, probes, expected);
    }

    // A floor in front of an infinite wall: 1/2 at any distance.
    for a in [0.0625f64, 1.0, 1024.0] {
        let mut s = empty_scene("wall", v);
        s.planes.push(plane(v, DVec3::ZERO, up));
        let wall = plane(v, DVec3::new(a, 0.0, 0.0), -DVec3::X);
        let p = probe_at(v, DVec3::ZERO, up);
        let distance = wall.normal.as_dvec3().dot(wall.point.as_dvec3() - p.position.as_dvec3());
        s.planes.push(wall);
        if distance != 0.0 {
            push(format!("floor before wall at {a}"), s, vec![p], vec![0.5]);
        }
    }

    // Under an infinite ceiling at height h with maximum distance R: (h/R)² for R ≥ h, 1
    // for R < h (0 and the smallest positive float included), 0 with no limit.
    for (h, r) in [(1.0f64, Some(2.0f64)), (0.5, Some(4.0)), (3.0, Some(3.0)), (1.0, None), (1.0, Some(0.0))] {
        let mut s = empty_scene("ceiling", v);
        let ceiling = plane(v, DVec3::new(0.0, h, 0.0), -up);
        s.planes.push(ceiling);
        s.settings.sampling.max_distance = r.map(|r| v.length(r));
        let p = probe_at(v, DVec3::ZERO, up);
        let height = ceiling.normal.as_dvec3().dot(ceiling.point.as_dvec3() - p.position.as_dvec3()).abs();
        let expected = match s.settings.sampling.max_distance {
            None => 0.0,
            Some(r) if (r as f64) < height => 1.0,
            Some(r) => (height / r as f64).powi(2),
        };
        let limit = r.map_or("∞".to_string(), |r| format!("{r}"));
        push(format!("ceiling h {h} R {limit}"), s, vec![p], vec![expected]);
    }
    {
        let mut s = empty_scene("ceiling", v);
        s.planes.push(plane(v, DVec3::new(0.0, 1.0, 0.0), -up));
        s.settings.sampling.max_distance = Some(f32::from_bits(1));
        push("ceiling h 1 R 1e-45".into(), s, vec![probe_at(v, DVec3::ZERO, up)], vec![1.0]);
    }

    // Inside closed meshes: 0 — nothing leaks through shared edges or vertices — and 1
    // with maximum distance 0.
    let inside = [
        (DVec3::ZERO, up),
        (DVec3::new(0.5, -0.25, 0.375), -DVec3::X),
        (DVec3::new(0.9375, 0.9375, 0.9375), DVec3::Z),
        (DVec3::new(-0.9375, 0.0, 0.5), -DVec3::X),
        (DVec3::new(0.25, -0.5, -0.125), DVec3::new(1.0, 1.0, 1.0)),
    ];
    for limit in [None, Some(0.0)] {
        let mut s = empty_scene("closed box", v);
        s.triangles = mesh("closed box", cube(v));
        s.settings.sampling.max_distance = limit;
        let probes: Vec<Probe> = inside.iter().map(|&(p, n)| probe_at(v, p, n)).collect();
        let value = if limit.is_some() { 1.0 } else { 0.0 };
        let name = if limit.is_some() { "inside a closed box, R 0" } else { "inside a closed box" };
        push(name.into(), s, probes.clone(), vec![value; probes.len()]);
    }
    {
        let mut s = empty_scene("icosphere", v);
        s.triangles = mesh("icosphere", unit_icosphere(2).place(v));
        let probes: Vec<Probe> = inside[..3]
            .iter()
            .map(|&(p, n)| (p * 0.5, n))
            .chain([(DVec3::new(0.0, 0.875, 0.0), up), (DVec3::new(0.0, -0.875, 0.0), up)])
            .map(|(p, n)| probe_at(v, p, n))
            .collect();
        push("inside a 320-triangle icosphere".into(), s, probes.clone(), vec![0.0; probes.len()]);
    }
    out
}

/// Whether an estimate agrees with the exact value: within 4 standard errors, plus the
/// f32 rounding of the sample values (when every sample is equal the standard error is 0).
pub fn agrees(value: &ProbeValue, expected: f64) -> bool {
    (value.mean - expected).abs() <= 4.0 * value.std_error + 4.0 * f32::EPSILON as f64 * expected.abs().max(1.0)
}

/// The configurations the suite runs: every hemisphere with every unbiased sampler.
pub fn configurations() -> Vec<(Hemisphere, Sampler)> {
    let mut out = Vec::new();
    for h in Hemisphere::ALL {
        for s in Sampler::ALL.into_iter().filter(|s| s.is_unbiased()) {
            out.push((h, s));
        }
    }
    out
}

impl Case {
    /// The case's scene prepared on `device`, for [`Case::estimate`].
    pub fn session(&self, device: &Device) -> Result<Session> {
        Session::new(device, self.scene.clone(), &BvhOptions::default())
    }

    /// Estimates at the case's probes with `samples` samples each, by `session` (made by
    /// [`Case::session`]), with the configuration's hemisphere and sampler and `seed`.
    pub fn estimate(
        &self,
        session: &Session,
        (hemisphere, sampler): (Hemisphere, Sampler),
        seed: u32,
        samples: u32,
    ) -> Result<Vec<ProbeValue>> {
        let settings = Settings {
            sampling: Sampling { hemisphere, sampler, seed, ..self.scene.settings.sampling },
            ..self.scene.settings.clone()
        };
        Ok(session.probe(&self.probes, samples, &settings)?.values)
    }
}
