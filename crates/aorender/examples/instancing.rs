//! Instanced meshes, flattened or two-level: how should a scene that places one mesh many
//! times be represented for tracing?
//!
//! `scenes/dragons.toml` places the 871k-triangle dragon nine times, each copy with its own
//! rotation and translation. Flattened, every copy's triangles are transformed to world
//! space and one CWBVH holds all of them (A; what `Scene::flattened` gives, and what the
//! renderer did before it kept instances). The alternative, which the renderer now uses
//! (`crates/aorender/src/bvh/mod.rs`), is two levels (B): one CWBVH over the mesh in its
//! own space (the BLAS), a CWBVH over the nine
//! instances' world-space boxes (the TLAS), and each ray carried into an instance's space by
//! the inverse of its affine transform. The direction is transformed but not renormalized,
//! so a hit distance `t` means the same in both spaces, scaled instances included, and one
//! running closest `t` serves every instance.
//!
//! Both are traversed with obvhs's own CWBVH traversal (closest hit and first hit) and the
//! renderer's watertight triangle test (`aorender::geometry::intersect_triangle`), in the
//! same way as `aorender::cpu::CpuTracer`; infinite planes are tested outside either BVH,
//! as there. Only the structure differs. The example reports
//!
//! - build time of the flattened BVH against BLAS + TLAS, on one thread and on all cores;
//! - memory of each: CWBVH nodes plus triangles at the renderer's 48 bytes a triangle
//!   (`aorender::bvh::GpuPrimitive`), plus the instance records for B;
//! - rays per second, on one thread and on all cores (rayon), for closest-hit camera rays
//!   (one per pixel centre of the scene's camera) and for AO any-hit rays (four
//!   cosine-distributed directions about the geometric normal at each camera hit, with no
//!   distance limit and limited to a quarter of the mesh's bounding-box diagonal);
//! - agreement on the same rays: hit/miss and occlusion mismatches between A and B, the
//!   largest relative difference of their closest `t`, and A against the renderer's
//!   `CpuTracer` on the same BVH (timed too, as a reference).
//!
//! Run it with
//!
//! ```text
//! cargo run --release -p aorender --features testing --example instancing [-- scenes/dragons.toml]
//! ```
//!
//! Any scene file made of triangle meshes and planes can be given; mesh objects that name
//! the same file become instances of one BLAS. The transforms are read from the scene file
//! (scale, rotate, translate or matrix, as the loader applies them) and checked against the
//! loaded scene's flattened triangles.

use anyhow::{Context, Result, ensure};
use aorender::Scene;
use aorender::bvh::{BuildQuality, SceneCwbvh, build_cwbvh};
use aorender::cpu::tracer::{CpuTracer, HitKind};
use aorender::geometry::{intersect_plane, intersect_triangle, plane_hit_point, triangle_hit_point};
use aorender::sampling::{local_to_world, offset_ray_origin, sample_cosine_hemisphere, sample_uniforms};
use aorender::scene::{Plane, Triangle, load_mesh};
use glam::{Affine3A, EulerRot, Mat4, Quat, Vec2, Vec3, Vec3A};
use obvhs::{BvhBuildParams, aabb::Aabb, cwbvh::CwBvh, cwbvh::node::CwBvhNode, ray::Ray, ray::RayHit};
use rayon::{ThreadPool, prelude::*};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Traversal starts this far behind the ray origin, as in `CpuTracer`: obvhs's box test
/// skips boxes that end within 1e-4 of the origin. Hits are reported in the moved ray's terms.
const BACKOFF: f32 = 2e-4;
/// Bytes of one triangle as the renderer stores it in leaf order (`GpuPrimitive`).
const TRIANGLE_BYTES: usize = 48;
/// AO directions per camera hit.
const AO_RAYS_PER_HIT: u32 = 4;
/// Timed repetitions of each trace; the fastest counts.
const REPEATS: u32 = 5;

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Hit {
    Plane(usize),
    /// A triangle by its index in the loaded scene (A).
    Mesh(u32),
    /// Triangle `.1` of the mesh of instance `.0` (B; instances in TLAS leaf order).
    Instance(u32, u32),
}

trait Tracer: Sync {
    /// Closest hit in `(0, t_max)`.
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Hit)>;
    /// Whether anything lies in `(0, t_max)`.
    fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool;
}

fn closest_plane(planes: &[Plane], o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Hit)> {
    let mut best = None;
    for (i, plane) in planes.iter().enumerate() {
        let t = intersect_plane(o, d, 0.0, best.map_or(t_max, |(t, _)| t), plane);
        if t < best.map_or(t_max, |(t, _)| t) {
            best = Some((t, Hit::Plane(i)));
        }
    }
    best
}

/// A CWBVH and its triangles in leaf order.
struct Blas {
    bvh: CwBvh,
    tris: Vec<[Vec3; 3]>,
}

impl Blas {
    fn new(bvh: CwBvh, triangles: &[Triangle]) -> Blas {
        let tris = bvh.primitive_indices.iter().map(|&i| triangles[i as usize].v).collect();
        Blas { bvh, tris }
    }

    fn bytes(&self) -> usize {
        self.bvh.nodes.len() * size_of::<CwBvhNode>() + self.tris.len() * TRIANGLE_BYTES
    }

    /// Closest hit in `(0, t_max)`: its `t` and leaf slot.
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, usize)> {
        let ray = Ray::new(Vec3A::from(o - BACKOFF * d), Vec3A::from(d), 0.0, t_max + BACKOFF);
        let (mut hit, mut t_best) = (RayHit::none(), t_max);
        let found = self.bvh.ray_traverse(ray, &mut hit, |_, slot| {
            let [a, b, c] = self.tris[slot];
            let t = intersect_triangle(o, d, 0.0, t_best, a, b, c);
            if t < t_best {
                t_best = t;
                t + BACKOFF
            } else {
                f32::INFINITY
            }
        });
        found.then_some((t_best, hit.primitive_id as usize))
    }

    fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        let ray = Ray::new(Vec3A::from(o - BACKOFF * d), Vec3A::from(d), 0.0, t_max + BACKOFF);
        !self.bvh.ray_traverse_miss(ray, |_, slot| {
            let [a, b, c] = self.tris[slot];
            let t = intersect_triangle(o, d, 0.0, t_max, a, b, c);
            if t < t_max { t + BACKOFF } else { f32::INFINITY }
        })
    }
}

/// A: every triangle in world space in one BVH.
struct Flat {
    blas: Blas,
    planes: Vec<Plane>,
}

impl Tracer for Flat {
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Hit)> {
        let best = closest_plane(&self.planes, o, d, t_max);
        match self.blas.closest(o, d, best.map_or(t_max, |(t, _)| t)) {
            Some((t, slot)) => Some((t, Hit::Mesh(self.blas.bvh.primitive_indices[slot]))),
            None => best,
        }
    }
    fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        self.planes.iter().any(|p| intersect_plane(o, d, 0.0, t_max, p) < t_max) || self.blas.occluded(o, d, t_max)
    }
}

/// One placement of a mesh.
#[derive(Clone, Copy)]
struct Instance {
    /// Index of its BLAS.
    blas: usize,
    to_world: Mat4,
    to_object: Affine3A,
}

/// B: a TLAS over instance boxes, one BLAS per distinct mesh in the mesh's own space.
struct TwoLevel {
    tlas: CwBvh,
    /// Instances in TLAS leaf order.
    instances: Vec<Instance>,
    blases: Vec<Blas>,
    planes: Vec<Plane>,
}

impl TwoLevel {
    fn bytes(&self) -> usize {
        let instances = self.instances.len() * (size_of::<Instance>() + size_of::<Aabb>());
        self.blases.iter().map(Blas::bytes).sum::<usize>() + self.tlas.nodes.len() * size_of::<CwBvhNode>() + instances
    }

    /// Instance `slot` and the ray in its space; the direction is not renormalized, so `t` carries over.
    fn to_object(&self, slot: usize, o: Vec3, d: Vec3) -> (&Instance, Vec3, Vec3) {
        let inst = &self.instances[slot];
        (inst, inst.to_object.transform_point3(o), inst.to_object.transform_vector3(d))
    }

    /// The world-space vertices of a triangle B hit.
    fn world_triangle(&self, hit: Hit, meshes: &[(PathBuf, Scene)]) -> Option<[Vec3; 3]> {
        let Hit::Instance(k, id) = hit else { return None };
        let inst = &self.instances[k as usize];
        Some(meshes[inst.blas].1.triangles[id as usize].v.map(|p| inst.to_world.transform_point3(p)))
    }
}

/// The world-space box of an instance: its mesh's box, corners transformed, padded against
/// the rounding of the ray's transform.
fn world_box(b: &Aabb, inst: &Instance) -> Aabb {
    let corners = (0..8).map(|i: u32| {
        let pick = |axis: usize| if i >> axis & 1 == 0 { b.min[axis] } else { b.max[axis] };
        Vec3A::from(inst.to_world.transform_point3(Vec3::new(pick(0), pick(1), pick(2))))
    });
    let (lo, hi) = corners.fold((Vec3A::INFINITY, Vec3A::NEG_INFINITY), |(l, h), c| (l.min(c), h.max(c)));
    let pad = 1e-5 * (hi - lo).length() + 1e-6 * lo.abs().max(hi.abs()).max_element();
    Aabb::new(lo - pad, hi + pad)
}

impl Tracer for TwoLevel {
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Hit)> {
        let mut best = closest_plane(&self.planes, o, d, t_max);
        let mut t_best = best.map_or(t_max, |(t, _)| t);
        let ray = Ray::new(Vec3A::from(o - BACKOFF * d), Vec3A::from(d), 0.0, t_best + BACKOFF);
        self.tlas.ray_traverse(ray, &mut RayHit::none(), |_, slot| {
            let (inst, lo, ld) = self.to_object(slot, o, d);
            let blas = &self.blases[inst.blas];
            match blas.closest(lo, ld, t_best) {
                Some((t, s)) => {
                    t_best = t;
                    best = Some((t, Hit::Instance(slot as u32, blas.bvh.primitive_indices[s])));
                    t + BACKOFF
                }
                None => f32::INFINITY,
            }
        });
        best
    }
    fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        if self.planes.iter().any(|p| intersect_plane(o, d, 0.0, t_max, p) < t_max) {
            return true;
        }
        let ray = Ray::new(Vec3A::from(o - BACKOFF * d), Vec3A::from(d), 0.0, t_max + BACKOFF);
        !self.tlas.ray_traverse_miss(ray, |_, slot| {
            let (inst, lo, ld) = self.to_object(slot, o, d);
            if self.blases[inst.blas].occluded(lo, ld, t_max) { 0.0 } else { f32::INFINITY }
        })
    }
}

/// The renderer's own CPU tracer on A's BVH, hits named as A names them.
struct Renderer<'a>(CpuTracer, &'a [u32]);

impl Tracer for Renderer<'_> {
    fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, Hit)> {
        self.0.closest(o, d, t_max).map(|(t, kind)| match kind {
            HitKind::Plane(i) => (t, Hit::Plane(i)),
            HitKind::Primitive(slot) => (t, Hit::Mesh(self.1[slot])),
            HitKind::Instance { .. } => unreachable!("the flattened scene has no instances"),
        })
    }
    fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        self.0.occluded(o, d, t_max)
    }
}

/// Numbers of a TOML value, arrays flattened.
fn floats(v: &toml::Value) -> Option<Vec<f32>> {
    match v {
        toml::Value::Float(x) => Some(vec![*x as f32]),
        toml::Value::Integer(i) => Some(vec![*i as f32]),
        toml::Value::Array(a) => a.iter().map(floats).collect::<Option<Vec<_>>>().map(|v| v.concat()),
        _ => None,
    }
}

/// An object's transform as the scene loader builds it: scale, then rotation about x, y
/// and z (degrees), then translation; or a row-major 4×4 `matrix`.
fn object_transform(object: &toml::Table) -> Result<Mat4> {
    let Some(t) = object.get("transform").and_then(toml::Value::as_table) else { return Ok(Mat4::IDENTITY) };
    let get = |key: &str, lens: &[usize]| -> Result<Option<Vec<f32>>> {
        let Some(v) = t.get(key) else { return Ok(None) };
        let v = floats(v).filter(|v| lens.contains(&v.len()));
        Ok(Some(v.with_context(|| format!("transform.{key}: expected {lens:?} numbers"))?))
    };
    if let Some(m) = get("matrix", &[16])? {
        return Ok(Mat4::from_cols_slice(&m).transpose());
    }
    let s = get("scale", &[1, 3])?
        .map_or(Vec3::ONE, |v| if v.len() == 1 { Vec3::splat(v[0]) } else { Vec3::from_slice(&v) });
    let r = get("rotate", &[3])?.map_or(Vec3::ZERO, |v| Vec3::from_slice(&v));
    let q = Quat::from_euler(EulerRot::ZYX, r.z.to_radians(), r.y.to_radians(), r.x.to_radians());
    let t = get("translate", &[3])?.map_or(Vec3::ZERO, |v| Vec3::from_slice(&v));
    Ok(Mat4::from_scale_rotation_translation(s, q, t))
}

/// Seconds and result of `f` in `pool`.
fn timed<T: Send>(pool: &ThreadPool, f: impl FnOnce() -> T + Send) -> (f64, T) {
    pool.install(|| {
        let start = Instant::now();
        let out = f();
        (start.elapsed().as_secs_f64(), out)
    })
}

/// Per tracer: the fastest of [`REPEATS`] runs on one thread and on all, the tracers
/// taking turns so that drift in the machine's speed affects them alike; and the result.
#[allow(clippy::type_complexity)]
fn measure<T: Send>(
    pools: &[ThreadPool; 2],
    tracers: &[&dyn Tracer],
    f: impl Fn(&dyn Tracer) -> Vec<T> + Sync,
) -> (Vec<[f64; 2]>, Vec<Vec<T>>) {
    let (mut secs, mut results) = (vec![[f64::INFINITY; 2]; tracers.len()], Vec::new());
    for (k, pool) in pools.iter().enumerate() {
        for repeat in 0..REPEATS {
            for (i, &tracer) in tracers.iter().enumerate() {
                let (s, out) = timed(pool, || f(tracer));
                secs[i][k] = secs[i][k].min(s);
                if k == 1 && repeat == 0 {
                    results.push(out);
                }
            }
        }
    }
    (secs, results)
}

fn main() -> Result<()> {
    let path = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "scenes/dragons.toml".into()));
    let start = Instant::now();
    let scene = Scene::load(&path).with_context(|| format!("loading {}", path.display()))?.flattened();
    eprintln!("loaded {} in {:.1} s", path.display(), start.elapsed().as_secs_f64());
    ensure!(scene.spheres.is_empty(), "only triangle meshes and planes are handled; the scene has spheres");

    // The instances, from the scene file; each distinct mesh file is read once, untransformed.
    let doc: toml::Table = std::fs::read_to_string(&path)?.parse()?;
    let base = path.parent().unwrap_or(Path::new("."));
    let (mut meshes, mut instances): (Vec<(PathBuf, Scene)>, Vec<Instance>) = (Vec::new(), Vec::new());
    let objects = doc.get("object").and_then(toml::Value::as_array).map_or(&[][..], |a| a.as_slice());
    for object in objects.iter().filter_map(toml::Value::as_table) {
        if object.get("type").and_then(toml::Value::as_str) != Some("mesh") {
            continue;
        }
        let file = base.join(object.get("file").and_then(toml::Value::as_str).context("mesh without a file")?);
        let blas = match meshes.iter().position(|(p, _)| *p == file) {
            Some(i) => i,
            None => {
                let triangles = load_mesh(&file, 1.0, &Mat4::IDENTITY)?;
                meshes.push((file, Scene { triangles, spheres: vec![], planes: vec![], ..Scene::default_scene() }));
                meshes.len() - 1
            }
        };
        let to_world = object_transform(object)?;
        ensure!(to_world.determinant() != 0.0, "singular transform");
        instances.push(Instance { blas, to_world, to_object: Affine3A::from_mat4(to_world).inverse() });
    }
    ensure!(!instances.is_empty(), "{} places no meshes", path.display());
    // The loader transforms each vertex once, as here, and drops triangles left degenerate:
    // every loaded triangle must be an instance's, transformed, bit for bit.
    let mut reproduced = 0;
    for inst in &instances {
        for t in &meshes[inst.blas].1.triangles {
            let w = t.v.map(|p| inst.to_world.transform_point3(p));
            reproduced += scene.triangles.get(reproduced).is_some_and(|s| s.v == w) as usize;
        }
    }

    let threads = rayon::current_num_threads();
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build();
    let pools = [pool(1)?, pool(threads)?];
    // Builds, on one thread and on all (the renderer's default quality); the second is kept.
    let (mut flat_s, mut blas_s, mut tlas_s, mut built) = ([0.0; 2], [0.0; 2], [0.0; 2], None);
    for (k, pool) in pools.iter().enumerate() {
        let (s, flat) = timed(pool, || build_cwbvh(&scene, BuildQuality::Medium).top);
        let build_blas = |m: &Scene| Blas::new(build_cwbvh(m, BuildQuality::Medium).top.expect("a mesh"), &m.triangles);
        let (b, blases) = timed(pool, || meshes.iter().map(|(_, m)| build_blas(m)).collect::<Vec<_>>());
        let (t, (tlas, leaf)) = timed(pool, || {
            let boxes: Vec<Aabb> =
                instances.iter().map(|inst| world_box(&blases[inst.blas].bvh.total_aabb, inst)).collect();
            let tlas =
                obvhs::cwbvh::builder::build_cwbvh(&boxes, BvhBuildParams::medium_build(), &mut Default::default());
            let leaf = tlas.primitive_indices.iter().map(|&i| instances[i as usize]).collect::<Vec<_>>();
            (tlas, leaf)
        });
        (flat_s[k], blas_s[k], tlas_s[k]) = (s, b, t);
        let planes = scene.planes.clone();
        built = Some((flat, TwoLevel { tlas, instances: leaf, blases, planes }));
    }
    let (flat, two) = built.context("no build")?;
    let flat = Flat { blas: Blas::new(flat.context("no triangles")?, &scene.triangles), planes: scene.planes.clone() };
    let flat_bvh = SceneCwbvh { top: Some(flat.blas.bvh.clone()), meshes: Vec::new(), duplicates: 0 };
    let renderer = Renderer(CpuTracer::new(&scene, flat_bvh), &flat.blas.bvh.primitive_indices);
    let tracers: [&dyn Tracer; 3] = [&flat, &two, &renderer];

    // Camera rays through pixel centres.
    let s = &scene.settings;
    let rg = scene.camera.ray_gen(s.width, s.height);
    let pixels = s.width * s.height;
    let camera: Vec<(Vec3, Vec3)> = (0..pixels)
        .map(|i| rg.ray((i % s.width) as f32 + 0.5, (i / s.width) as f32 + 0.5, s.width, s.height))
        .collect();
    let (cam_s, cam) =
        measure(&pools, &tracers, |t| camera.par_iter().map(|&(o, d)| t.closest(o, d, f32::MAX)).collect());
    // AO rays from A's camera hits: cosine-distributed about the normal facing the camera.
    let ao: Vec<(Vec3, Vec3)> = (0..pixels)
        .into_par_iter()
        .flat_map_iter(|i| {
            let (o, d) = camera[i as usize];
            let hit = cam[0][i as usize].map(|(t, hit)| match hit {
                Hit::Plane(k) => plane_hit_point(o, d, t, &scene.planes[k]),
                Hit::Mesh(id) => {
                    let [a, b, c] = scene.triangles[id as usize].v;
                    triangle_hit_point(o, d, t, a, b, c)
                }
                Hit::Instance(..) => unreachable!("A names the scene's triangles"),
            });
            hit.into_iter().flat_map(move |p| {
                let n = if p.n.dot(d) > 0.0 { -p.n } else { p.n };
                let origin = offset_ray_origin(p.p, n, p.error);
                (0..AO_RAYS_PER_HIT).map(move |k| {
                    let u = sample_uniforms(i % s.width, i / s.width, k, 0);
                    (origin, local_to_world(sample_cosine_hemisphere(Vec2::new(u[0], u[1])), n))
                })
            })
        })
        .collect();
    let bounds = meshes[0].1.bounds().context("mesh bounds")?;
    let limit = 0.25 * (bounds.max - bounds.min).length();
    let (ao_s, ao_occ) =
        measure(&pools, &tracers, |t| ao.par_iter().map(|&(o, d)| t.occluded(o, d, f32::MAX)).collect());
    let (aol_s, aol_occ) =
        measure(&pools, &tracers, |t| ao.par_iter().map(|&(o, d)| t.occluded(o, d, limit)).collect());

    // The table.
    let placed: usize = instances.iter().map(|i| meshes[i.blas].1.triangles.len()).sum();
    let (name, n_tri, n_inst, n_mesh) = (path.display(), scene.triangles.len(), instances.len(), meshes.len());
    let (n_cam, n_ao, n_planes, (w, h)) = (camera.len(), ao.len(), scene.planes.len(), (s.width, s.height));
    println!(
        "scene {name}: {n_tri} world-space triangles; {n_inst} instances of {n_mesh} mesh(es), {placed} triangles \
        placed; {n_planes} plane(s)"
    );
    println!(
        "rays: {n_cam} camera ({w}x{h} pixel centres, closest hit); {n_ao} AO (any hit, {AO_RAYS_PER_HIT} per \
        camera hit, unlimited and t < {limit:.4} = 0.25 x mesh box diagonal)"
    );
    println!("obvhs CWBVH, medium build; 1 and {threads} rayon thread(s); traces: fastest of {REPEATS} runs\n");
    let row = |name: String, v: [Option<f64>; 3], digits: usize| {
        let cell = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{x:.digits$}"));
        let ratio = v[0].zip(v[1]).map_or("-".to_string(), |(a, b)| format!("{:.3}", b / a));
        println!("{name:<36} {:>12} {:>12} {ratio:>7} {:>15}", cell(v[0]), cell(v[1]), cell(v[2]));
    };
    println!("{:<36} {:>12} {:>12} {:>7} {:>15}", "", "A flattened", "B two-level", "B/A", "CpuTracer on A");
    for (k, n) in [1, threads].iter().enumerate() {
        row(format!("build s, {n} thread(s)"), [Some(flat_s[k]), Some(blas_s[k] + tlas_s[k]), None], 3);
        row(format!("  of which TLAS ms, {n} thread(s)"), [None, Some(tlas_s[k] * 1e3), None], 3);
    }
    let nodes = |b: &CwBvh| b.nodes.len() as f64;
    let nodes_b = two.blases.iter().map(|b| nodes(&b.bvh)).sum::<f64>() + nodes(&two.tlas);
    row("CWBVH nodes".into(), [Some(nodes(&flat.blas.bvh)), Some(nodes_b), None], 0);
    let mib = |b: usize| Some(b as f64 / (1 << 20) as f64);
    row("memory MiB (nodes + 48 B/triangle)".into(), [mib(flat.blas.bytes()), mib(two.bytes()), None], 1);
    for (name, rays, secs) in [("camera", n_cam, &cam_s), ("AO unlimited", n_ao, &ao_s), ("AO limited", n_ao, &aol_s)] {
        for (k, n) in [1, threads].iter().enumerate() {
            let r = secs.iter().map(|t| Some(rays as f64 / t[k] / 1e6)).collect::<Vec<_>>();
            row(format!("{name} Mrays/s, {n} thread(s)"), [r[0], r[1], r[2]], 3);
        }
    }

    // Agreement on the same rays.
    let (mut hit_mismatch, mut other_surface, mut max_rel, mut beyond) = (0, 0, 0.0f32, 0);
    for (a, b) in cam[0].iter().zip(&cam[1]) {
        match (a, b) {
            (Some((ta, ha)), Some((tb, hb))) => {
                let rel = (ta - tb).abs() / ta;
                (max_rel, beyond) = (max_rel.max(rel), beyond + (rel > 1e-5) as usize);
                let same = match (ha, hb) {
                    (Hit::Mesh(id), _) => two.world_triangle(*hb, &meshes) == Some(scene.triangles[*id as usize].v),
                    _ => ha == hb,
                };
                other_surface += !same as usize;
            }
            (None, None) => {}
            _ => hit_mismatch += 1,
        }
    }
    let on_mesh = cam[0].iter().filter(|h| matches!(h, Some((_, Hit::Mesh(_))))).count();
    println!(
        "\nagreement, B vs A:\n  camera: {hit_mismatch} hit/miss mismatches of {n_cam} rays ({on_mesh} hit a mesh \
        in A); {other_surface} hit another surface; largest relative t difference {max_rel:.2e}, {beyond} above 1e-5"
    );
    let mismatches = |x: &[bool], y: &[bool]| x.iter().zip(y).filter(|(a, b)| a != b).count();
    for (name, occ) in [("AO unlimited", &ao_occ), ("AO limited", &aol_occ)] {
        let (differ, occluded) = (mismatches(&occ[0], &occ[1]), occ[0].iter().filter(|&&o| o).count());
        println!("  {name}: {differ} occlusion mismatches of {n_ao} rays ({occluded} occluded in A)");
    }
    let cam_same = cam[0].iter().zip(&cam[2]).filter(|(a, c)| a == c).count();
    let ao_same = 2 * n_ao - mismatches(&ao_occ[0], &ao_occ[2]) - mismatches(&aol_occ[0], &aol_occ[2]);
    println!(
        "CpuTracer vs A: identical closest hits on {cam_same}/{n_cam} camera rays, occlusion on {ao_same}/{} \
        AO rays",
        2 * n_ao
    );
    println!("loaded triangles reproduced bit for bit by transforming the instances' meshes: {reproduced}/{n_tri}");
    Ok(())
}
