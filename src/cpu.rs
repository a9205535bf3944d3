//! The CPU reference renderer: obvhs's own CWBVH traversal (`ray_traverse` for camera
//! rays, `ray_traverse_miss` as the occlusion query), multi-threaded over rows with rayon,
//! and the same camera, random numbers, warps and shading as `shaders/ao.wgsl`.

use crate::bvh::{GpuPrimitive, PRIM_SPHERE};
use crate::camera::RayGen;
use crate::film::Film;
use crate::geometry::{intersect_plane, intersect_sphere, intersect_triangle, sphere_hit_point};
use crate::sampler::PointSampler;
use crate::sampling::{local_to_world, offset_ray_origin};
use crate::scene::{Plane, Scene, Settings};
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
}

/// A scene prepared for CPU tracing: the CWBVH and its primitives in leaf order, in the
/// GPU's record format so both read the same numbers.
pub struct CpuTracer {
    bvh: Option<CwBvh>,
    primitives: Vec<GpuPrimitive>,
    planes: Vec<Plane>,
}

fn v3(a: [f32; 4]) -> Vec3 {
    Vec3::new(a[0], a[1], a[2])
}

impl CpuTracer {
    /// Prepares `scene` with an already built CWBVH (`None` when there are no finite primitives).
    pub fn new(scene: &Scene, bvh: Option<CwBvh>) -> CpuTracer {
        let primitives = match &bvh {
            Some(b) => b.primitive_indices.iter().map(|&id| crate::bvh::gpu_primitive(scene, id as usize)).collect(),
            None => Vec::new(),
        };
        CpuTracer { bvh, primitives, planes: scene.planes.clone() }
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
            let ray = Ray::new(Vec3A::from(o), Vec3A::from(d), 0.0, t_best);
            if bvh.ray_traverse(ray, &mut hit, |r, slot| self.intersect_primitive(slot, o, d, r.tmax)) {
                best = Some((hit.t, HitKind::Primitive(hit.primitive_id as usize)));
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
                let ray = Ray::new(Vec3A::from(o), Vec3A::from(d), 0.0, t_max);
                !bvh.ray_traverse_miss(ray, |r, slot| self.intersect_primitive(slot, o, d, r.tmax))
            }
            None => false,
        }
    }

    /// Surface point, geometric normal and albedo of a hit.
    pub fn surface(&self, o: Vec3, d: Vec3, t: f32, kind: HitKind) -> (Vec3, Vec3, f32) {
        match kind {
            HitKind::Plane(i) => (o + t * d, self.planes[i].normal, self.planes[i].albedo),
            HitKind::Primitive(slot) => {
                let p = &self.primitives[slot];
                if p.b[3].to_bits() == PRIM_SPHERE {
                    let (point, n) = sphere_hit_point(o, d, t, v3(p.a), p.b[0]);
                    (point, n, p.a[3])
                } else {
                    (o + t * d, v3(p.b).cross(v3(p.c)).normalize(), p.a[3])
                }
            }
        }
    }

    /// AO value at a surface point with normal `n` for hemisphere numbers `u`; the twin of
    /// the shader's tail of `shade_sample`.
    pub fn ao_at(&self, p: Vec3, n: Vec3, u: glam::Vec2, settings: &Settings) -> f32 {
        let w_local = settings.hemisphere.sample(u);
        let w = local_to_world(w_local, n);
        let t_max = settings.max_distance.unwrap_or(f32::MAX);
        if self.occluded(offset_ray_origin(p, n), w, t_max) { 0.0 } else { settings.hemisphere.weight(w_local) }
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
        let (p, mut n, albedo) = self.surface(o, d, t, kind);
        if n.dot(d) > 0.0 {
            n = -n;
        }
        (albedo * self.ao_at(p, n, glam::Vec2::new(u[2], u[3]), settings), true)
    }

    /// Adds samples `first .. first + count` of every pixel to `film`; returns the number
    /// of AO rays traced.
    pub fn render_pass(&self, scene: &Scene, film: &mut Film, first: u32, count: u32) -> u64 {
        let s = &scene.settings;
        let rg = scene.camera.ray_gen(s.width, s.height);
        let sampler = PointSampler::new(s.sampler, s.seed, s.spp);
        let w = s.width as usize;
        let ao_rays: u64 = film
            .sum
            .par_chunks_mut(w)
            .zip(film.sum_sq.par_chunks_mut(w))
            .enumerate()
            .map(|(y, (sum, sum_sq))| {
                let mut rays = 0u64;
                for x in 0..w {
                    for k in 0..count {
                        let (v, traced) =
                            self.shade_sample(&rg, s, &sampler, x as u32, y as u32, first.wrapping_add(k));
                        sum[x] += v as f64;
                        sum_sq[x] += (v as f64) * (v as f64);
                        rays += traced as u64;
                    }
                }
                rays
            })
            .sum();
        film.samples += count as u64;
        ao_rays
    }
}
