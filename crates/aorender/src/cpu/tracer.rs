//! The CPU reference tracer: obvhs's own CWBVH traversal (`ray_traverse` for camera
//! rays, `ray_traverse_miss` as the occlusion query) and the same camera, random numbers,
//! warps and shading as `shaders/ao.wgsl`, multi-threaded over rows (or probe slots) with
//! rayon.

use crate::bvh::{GpuPrimitive, PRIM_INSTANCE, PRIM_SPHERE, SceneCwbvh, gpu_primitive, mesh_primitive};
use crate::film::{BlockSums, add_sample};
use crate::geometry::{
    AffineRows, InverseAffine, Plane, SurfacePoint, instance_hit_point, intersect_plane, intersect_sphere,
    intersect_triangle, plane_hit_point, sphere_hit_point, triangle_hit_point,
};
use crate::probe::Probe;
use crate::sampler::PointSampler;
use crate::sampling::{above_surface, offset_ray_origin};
use crate::scene::{Camera, RayGen, Sampling, Scene, Settings};
use crate::sky::SkySample;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use rayon::prelude::*;

/// What a ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HitKind {
    /// Primitive at this position of the leaf-ordered primitive array.
    Primitive(usize),
    /// Plane index.
    Plane(usize),
    /// Primitive `slot` of the leaf-ordered primitives of instance `instance`'s mesh.
    Instance { instance: usize, slot: usize },
}

/// A scene prepared for CPU tracing: the CWBVHs and their primitives in leaf order, in the
/// GPU's record format so both read the same numbers.
pub struct CpuTracer {
    bvh: Option<CwBvh>,
    primitives: Vec<GpuPrimitive>,
    meshes: Vec<(CwBvh, Vec<GpuPrimitive>)>,
    instances: Vec<CpuInstance>,
    planes: Vec<Plane>,
}

/// An instance: its mesh, its maps and its albedo.
struct CpuInstance {
    mesh: usize,
    to_object: InverseAffine,
    to_world: AffineRows,
    albedo: f32,
}

/// obvhs's CWBVH node test skips boxes that end nearer than its `EPSILON` (1e-4) along
/// the ray, so geometry closer than that to an AO ray's origin would be missed. The BVH is
/// traversed from an origin moved back by this much, and the primitives are intersected
/// with the real ray; hit distances are reported to obvhs in the moved ray's terms.
///
/// The distance is fixed rather than relative to the origin: the moved origin is rounded,
/// which displaces the traversal ray sideways by up to half an ulp of its coordinates, and
/// a displaced ray can pass beside a box the real ray touches (a relative distance of 16
/// ulps let rays escape a closed box 1e6 from the origin). Beyond |o| ≈ 2^12, 2e-4 is
/// under half an ulp and the origin does not move at all; there only geometry within 1e-4
/// of the origin, closer than an ulp, can be skipped.
const TRAVERSAL_BACKOFF: f32 = 2e-4;

/// obvhs's ray for traversing an instance's mesh, and the map from the ray's `t` to the
/// traversal's. obvhs treats direction components below `f32::EPSILON` as that small and
/// clamps its box distances at 1e-4, both meant for unit directions, but a ray carried
/// into a mesh's space is as long as the inverse scale makes it: the traversal runs along
/// the unit direction, from the origin moved back by [`TRAVERSAL_BACKOFF`] of it, and
/// distances are converted to it rounded up by 2⁻²⁰ (a box is never culled early).
fn traversal_ray(o: Vec3, d: Vec3, t_max: f32) -> (Ray, impl Fn(f32) -> f32) {
    let length = d.length();
    let unit = d / length;
    let scale = length * (1.0 + 1.0 / (1u32 << 20) as f32);
    let to_traversal = move |t: f32| t * scale + TRAVERSAL_BACKOFF;
    let ray = Ray::new(Vec3A::from(o - TRAVERSAL_BACKOFF * unit), Vec3A::from(unit), 0.0, to_traversal(t_max));
    (ray, to_traversal)
}

fn v3(a: [f32; 4]) -> Vec3 {
    Vec3::new(a[0], a[1], a[2])
}

impl CpuTracer {
    /// Bytes it holds for tracing: the CWBVHs' nodes and primitive indices and the
    /// leaf-ordered records, top level and meshes.
    pub fn bytes(&self) -> u64 {
        let bvh = |b: &CwBvh| std::mem::size_of_val(&b.nodes[..]) + std::mem::size_of_val(&b.primitive_indices[..]);
        let top = self.bvh.as_ref().map_or(0, bvh) + std::mem::size_of_val(&self.primitives[..]);
        let meshes: usize = self.meshes.iter().map(|(b, p)| bvh(b) + std::mem::size_of_val(&p[..])).sum();
        (top + meshes) as u64
    }

    /// Prepares `scene` with its already built CWBVHs.
    pub fn new(scene: &Scene, bvh: SceneCwbvh) -> CpuTracer {
        let primitives = match &bvh.top {
            Some(b) => b.primitive_indices.iter().map(|&id| gpu_primitive(scene, id as usize)).collect(),
            None => Vec::new(),
        };
        let meshes = scene
            .meshes
            .iter()
            .zip(bvh.meshes)
            .map(|(m, b)| {
                let prims = b.primitive_indices.iter().map(|&i| mesh_primitive(&m.triangles[i as usize]));
                let prims = prims.collect();
                (b, prims)
            })
            .collect();
        let instances = scene
            .instances
            .iter()
            .map(|i| CpuInstance {
                mesh: i.mesh as usize,
                to_object: i.to_object(),
                to_world: i.to_world_rows(),
                albedo: i.albedo,
            })
            .collect();
        CpuTracer { bvh: bvh.top, primitives, meshes, instances, planes: scene.planes.clone() }
    }

    /// The instance a top-level record stands for, if it is one.
    fn instance_of(p: &GpuPrimitive) -> Option<usize> {
        (p.b[3].to_bits() == PRIM_INSTANCE).then(|| p.a[0].to_bits() as usize)
    }

    /// The ray in instance `i`'s mesh space (the same operations as the kernel's).
    fn to_instance(&self, i: usize, o: Vec3, d: Vec3) -> (&(CwBvh, Vec<GpuPrimitive>), Vec3, Vec3) {
        let inst = &self.instances[i];
        (&self.meshes[inst.mesh], inst.to_object.point(o), inst.to_object.vector(d))
    }

    /// Closest hit in `(0, t_max)` among instance `i`'s triangles: its distance and slot.
    fn closest_in_instance(&self, i: usize, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, usize)> {
        let ((bvh, prims), o, d) = self.to_instance(i, o, d);
        let mut hit = RayHit::none();
        let mut t_exact = t_max;
        let (ray, to_traversal) = traversal_ray(o, d, t_max);
        let found = bvh.ray_traverse(ray, &mut hit, |_, slot| {
            let p = &prims[slot];
            let t = intersect_triangle(o, d, 0.0, t_exact, v3(p.a), v3(p.b), v3(p.c));
            if t < t_exact {
                t_exact = t;
                to_traversal(t)
            } else {
                f32::INFINITY
            }
        });
        found.then_some((t_exact, hit.primitive_id as usize))
    }

    /// Whether any of instance `i`'s triangles lies in `(0, t_max)`.
    fn occluded_in_instance(&self, i: usize, o: Vec3, d: Vec3, t_max: f32) -> bool {
        let ((bvh, prims), o, d) = self.to_instance(i, o, d);
        let (ray, to_traversal) = traversal_ray(o, d, t_max);
        !bvh.ray_traverse_miss(ray, |_, slot| {
            let p = &prims[slot];
            let t = intersect_triangle(o, d, 0.0, t_max, v3(p.a), v3(p.b), v3(p.c));
            if t < t_max { to_traversal(t) } else { f32::INFINITY }
        })
    }

    fn intersect_primitive(&self, slot: usize, o: Vec3, d: Vec3, t_max: f32) -> f32 {
        let p = &self.primitives[slot];
        if p.b[3].to_bits() == PRIM_SPHERE {
            intersect_sphere(o, d, 0.0, t_max, v3(p.a), p.b[0])
        } else {
            intersect_triangle(o, d, 0.0, t_max, v3(p.a), v3(p.b), v3(p.c))
        }
    }

    /// Closest hit in `(0, t_max)`.
    pub fn closest(&self, o: Vec3, d: Vec3, t_max: f32) -> Option<(f32, HitKind)> {
        let mut best: Option<(f32, HitKind)> = None;
        let mut t_best = t_max;
        for (i, plane) in self.planes.iter().enumerate() {
            let t = intersect_plane(o, d, 0.0, t_best, plane);
            if t < t_best {
                t_best = t;
                best = Some((t, HitKind::Plane(i)));
            }
        }
        if let Some(bvh) = &self.bvh {
            let mut hit = RayHit::none();
            let mut t_exact = t_best;
            let mut kind = None;
            let ray = Ray::new(Vec3A::from(o - TRAVERSAL_BACKOFF * d), Vec3A::from(d), 0.0, t_best + TRAVERSAL_BACKOFF);
            bvh.ray_traverse(ray, &mut hit, |_, slot| {
                let hit = match Self::instance_of(&self.primitives[slot]) {
                    Some(i) => self
                        .closest_in_instance(i, o, d, t_exact)
                        .map(|(t, s)| (t, HitKind::Instance { instance: i, slot: s })),
                    None => {
                        let t = self.intersect_primitive(slot, o, d, t_exact);
                        (t < t_exact).then_some((t, HitKind::Primitive(slot)))
                    }
                };
                match hit {
                    Some((t, k)) if t < t_exact => {
                        t_exact = t;
                        kind = Some(k);
                        t + TRAVERSAL_BACKOFF
                    }
                    _ => f32::INFINITY,
                }
            });
            if let Some(k) = kind {
                best = Some((t_exact, k));
            }
        }
        best
    }

    /// True when something lies in `(0, t_max)` along the ray.
    pub fn occluded(&self, o: Vec3, d: Vec3, t_max: f32) -> bool {
        if self.planes.iter().any(|p| intersect_plane(o, d, 0.0, t_max, p) < t_max) {
            return true;
        }
        match &self.bvh {
            Some(bvh) => {
                let ray =
                    Ray::new(Vec3A::from(o - TRAVERSAL_BACKOFF * d), Vec3A::from(d), 0.0, t_max + TRAVERSAL_BACKOFF);
                !bvh.ray_traverse_miss(ray, |_, slot| match Self::instance_of(&self.primitives[slot]) {
                    Some(i) if self.occluded_in_instance(i, o, d, t_max) => TRAVERSAL_BACKOFF,
                    Some(_) => f32::INFINITY,
                    None => {
                        let t = self.intersect_primitive(slot, o, d, t_max);
                        if t < t_max { t + TRAVERSAL_BACKOFF } else { f32::INFINITY }
                    }
                })
            }
            None => false,
        }
    }

    /// The surface point of a hit (with its error bound and geometric normal) and its albedo.
    pub fn surface(&self, o: Vec3, d: Vec3, t: f32, kind: HitKind) -> (SurfacePoint, f32) {
        match kind {
            HitKind::Plane(i) => (plane_hit_point(o, d, t, &self.planes[i]), self.planes[i].albedo),
            HitKind::Instance { instance, slot } => {
                let inst = &self.instances[instance];
                let p = &self.meshes[inst.mesh].1[slot];
                (instance_hit_point(&inst.to_world, &inst.to_object, o, d, t, [v3(p.a), v3(p.b), v3(p.c)]), inst.albedo)
            }
            HitKind::Primitive(slot) => {
                let p = &self.primitives[slot];
                if p.b[3].to_bits() == PRIM_SPHERE {
                    (sphere_hit_point(o, d, t, v3(p.a), p.b[0]), p.a[3])
                } else {
                    // The record holds the vertices (v0, v1, v2).
                    (triangle_hit_point(o, d, t, v3(p.a), v3(p.b), v3(p.c)), p.a[3])
                }
            }
        }
    }

    /// AO value at a surface point `p` with normal `n`, within `error` of its surface along
    /// `n`, for hemisphere numbers `u`: a camera hit's, in `shaders/ao.wgsl`'s `shade_sample`.
    pub fn ao_at(&self, p: Vec3, n: Vec3, error: f32, u: glam::Vec2, sampling: &Sampling) -> f32 {
        let sample = sampling.sky.sample(sampling.hemisphere, n, u);
        self.estimate(offset_ray_origin(p, n, error), sample.w, &sample, sampling).0
    }

    /// The AO ray of `probe` for hemisphere numbers `u` (origin, direction, and the sky's
    /// sample): about its normal, from its position pushed off its surface along the
    /// surface's normal (its normal where it has none), a direction below the surface
    /// mirrored above it. The twin of `probe_ray` in `shaders/ao.wgsl`.
    pub fn probe_ray(probe: &Probe, u: glam::Vec2, sampling: &Sampling) -> (Vec3, Vec3, SkySample) {
        let sample = sampling.sky.sample(sampling.hemisphere, probe.normal, u);
        let g = probe.surface_normal;
        let off = if g == Vec3::ZERO { probe.normal } else { g };
        let w = above_surface(sample.w, g);
        (offset_ray_origin(probe.position, off, probe.error), w, sample)
    }

    /// The estimate of one sample of `probe` and, when its ray escaped, its world direction.
    pub fn probe_sample(&self, probe: &Probe, u: glam::Vec2, sampling: &Sampling) -> (f32, Option<Vec3>) {
        let (o, w, sample) = Self::probe_ray(probe, u, sampling);
        self.estimate(o, w, &sample, sampling)
    }

    /// The estimate of the AO ray from `o` along `w` (the sky's `sample`) and, when it
    /// escaped, `w`.
    fn estimate(&self, o: Vec3, w: Vec3, sample: &SkySample, sampling: &Sampling) -> (f32, Option<Vec3>) {
        let t_max = sampling.max_distance.unwrap_or(f32::MAX);
        if self.occluded(o, w, t_max) { (sample.blocked, None) } else { (sample.open, Some(w)) }
    }

    /// Adds samples `first .. first + count` (of `samples`) of every probe to `sums`,
    /// four slots a probe: the AO estimate, then the x, y and z of the directions that
    /// escaped, from one ray a sample; sample i of probe k takes the numbers
    /// [`CpuTracer::probe_pass`] takes with one lane. Values are summed in the quanta of
    /// samples of bound 2^`e` ([`BlockSums`]). The twin of `probe_bent_sample` in
    /// `shaders/ao.wgsl`. Returns the AO rays traced.
    // The request and the block: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn probe_bent_pass(
        &self,
        sampling: &Sampling,
        probes: &[Probe],
        first_point: u32,
        samples: u32,
        sums: &mut BlockSums,
        e: i32,
        first: u32,
        count: u32,
    ) -> u64 {
        let sampler = PointSampler::new(sampling.sampler, sampling.seed, samples, sampling.replicate_samples());
        sums.sum
            .par_chunks_mut(4)
            .zip(sums.sum_sq.par_chunks_mut(4))
            .enumerate()
            .map(|(k, (sum, sum_sq))| {
                let p = &probes[k];
                let mut rays = 0;
                for index in first..(first + count).min(samples) {
                    let u = sampler.uniforms(first_point + k as u32, 0, index);
                    let (v, open) = self.probe_sample(p, glam::Vec2::new(u[2], u[3]), sampling);
                    let d = open.unwrap_or(Vec3::ZERO);
                    for (c, x) in [v, d.x, d.y, d.z].into_iter().enumerate() {
                        add_sample(&mut sum[c], &mut sum_sq[c], x, e);
                    }
                    rays += 1;
                }
                rays
            })
            .sum()
    }

    /// One sample of pixel `(px, py)`: its value and whether an AO ray was traced. The
    /// twin of `shade_sample` in `shaders/ao.wgsl`.
    pub fn shade_sample(
        &self,
        rg: &RayGen,
        settings: &Settings,
        sampler: &PointSampler,
        px: u32,
        py: u32,
        sample_index: u32,
    ) -> (f32, bool) {
        let u = sampler.uniforms(px, py, sample_index);
        let (o, d) = rg.ray(px as f32 + u[0], py as f32 + u[1], settings.width, settings.height);
        let Some((t, kind)) = self.closest(o, d, f32::MAX) else {
            return (settings.background, false);
        };
        let (hit, albedo) = self.surface(o, d, t, kind);
        // The hemisphere faces the side the camera ray came from.
        let n = if hit.n.dot(d) > 0.0 { -hit.n } else { hit.n };
        (albedo * self.ao_at(hit.p, n, hit.error, glam::Vec2::new(u[2], u[3]), &settings.sampling), true)
    }

    /// Adds probe rounds `first .. first + count` to `sums`, whose slots are `lanes` per
    /// probe (probe k's lanes at `k × lanes ..`): round r gives lane l of probe k the
    /// sample index r × lanes + l, up to `samples`, as on the GPU; probe k takes the
    /// numbers of pixel (`first_point` + k, 0). Values are summed in the quanta of samples
    /// of bound 2^`e`. Returns the AO rays traced.
    // The request and the block: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn probe_pass(
        &self,
        sampling: &Sampling,
        probes: &[Probe],
        first_point: u32,
        samples: u32,
        lanes: u32,
        sums: &mut BlockSums,
        e: i32,
        first: u32,
        count: u32,
    ) -> u64 {
        let sampler = PointSampler::new(sampling.sampler, sampling.seed, samples, sampling.replicate_samples());
        sums.sum
            .par_iter_mut()
            .zip(sums.sum_sq.par_iter_mut())
            .enumerate()
            .map(|(slot, (sum, sum_sq))| {
                let (k, lane) = (slot / lanes as usize, slot as u32 % lanes);
                let p = &probes[k];
                let mut rays = 0;
                for round in first..first + count {
                    let index = round as u64 * lanes as u64 + lane as u64;
                    if index >= samples as u64 {
                        break;
                    }
                    let u = sampler.uniforms(first_point + k as u32, 0, index as u32);
                    let v = self.probe_sample(p, glam::Vec2::new(u[2], u[3]), sampling).0;
                    add_sample(sum, sum_sq, v, e);
                    rays += 1;
                }
                rays
            })
            .sum()
    }

    /// Adds samples `first .. first + count` of every pixel of the image of `settings`
    /// seen by `camera` to `sums`, in the quanta of samples of bound 2^`e`
    /// ([`BlockSums`]); returns the number of AO rays traced. Pixels marked in `inactive`
    /// (empty: none) are left as they are.
    // The request and the block: grouping them would only rename them.
    #[allow(clippy::too_many_arguments)]
    pub fn render_pass(
        &self,
        camera: &Camera,
        settings: &Settings,
        sums: &mut BlockSums,
        e: i32,
        first: u32,
        count: u32,
        inactive: &[bool],
    ) -> u64 {
        let s = settings;
        let rg = camera.ray_gen(s.width, s.height);
        let sampler = PointSampler::new(s.sampling.sampler, s.sampling.seed, s.spp, s.sampling.replicate_samples());
        let w = s.width as usize;
        sums.sum
            .par_chunks_mut(w)
            .zip(sums.sum_sq.par_chunks_mut(w))
            .enumerate()
            .map(|(y, (sum, sum_sq))| {
                let mut rays = 0u64;
                for x in 0..w {
                    if inactive.get(y * w + x).copied().unwrap_or(false) {
                        continue;
                    }
                    for k in 0..count {
                        let (v, traced) =
                            self.shade_sample(&rg, s, &sampler, x as u32, y as u32, first.wrapping_add(k));
                        add_sample(&mut sum[x], &mut sum_sq[x], v, e);
                        rays += traced as u64;
                    }
                }
                rays
            })
            .sum()
    }
}
