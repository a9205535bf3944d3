//! The in-memory scene: primitives as the scene file states them (triangles, exact
//! spheres, infinite planes, instanced meshes), a camera and the render settings.

use super::camera::{Camera, Projection};
use crate::error::{Error, Result};
use crate::geometry::{AffineRows, InverseAffine, Plane};
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::sky::Sky;
use glam::{DVec3, Mat4, Vec3};
use rayon::prelude::*;
use std::path::PathBuf;

/// The box no point is in: the start of [`fold_bounds`].
pub(crate) const EMPTY_BOUNDS: (Vec3, Vec3) = (Vec3::INFINITY, Vec3::NEG_INFINITY);

/// The box `(min, max)` grown by the finite points `points` gives of each of `items`, in
/// parallel: each thread's share folded in order from [`EMPTY_BOUNDS`], then the shares
/// combined in order and with `start`. Min and max are associative (a tie between +0 and −0
/// resolved by the operands' order, which this keeps) and the start is their identity,
/// so the bits are those of one fold over the points in order, a zero's sign included.
pub(crate) fn fold_bounds<T: Sync, const N: usize>(
    start: (Vec3, Vec3),
    items: &[T],
    points: impl Fn(&T) -> [Vec3; N] + Sync,
) -> (Vec3, Vec3) {
    let grow = |(min, max): (Vec3, Vec3), p: Vec3| (min.min(p), max.max(p));
    let join = |(a_min, a_max): (Vec3, Vec3), (b_min, b_max): (Vec3, Vec3)| (a_min.min(b_min), a_max.max(b_max));
    let found = items
        .par_iter()
        .with_min_len(1 << 14)
        .fold(|| EMPTY_BOUNDS, |b, item| points(item).into_iter().fold(b, grow))
        .reduce(|| EMPTY_BOUNDS, join);
    join(start, found)
}

/// A triangle with its albedo; laid out as its ten floats in order, which the scene hash
/// reads as bytes.
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Triangle {
    /// Vertices, world space.
    pub v: [Vec3; 3],
    /// Diffuse reflectance ρ.
    pub albedo: f32,
}

/// An exact sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    /// Centre, world space.
    pub center: Vec3,
    /// Radius.
    pub radius: f32,
    /// Diffuse reflectance ρ.
    pub albedo: f32,
}

/// A mesh placed by several objects of a scene file, kept once in its own space: each
/// placement is an [`Instance`] that carries rays into this space rather than copying the
/// triangles into the world (two-level BVH, `src/bvh/mod.rs`).
#[derive(Clone, Debug, PartialEq)]
pub struct InstancedMesh {
    /// The mesh file, for messages.
    pub name: String,
    /// Triangles in the mesh's own space, degenerate ones dropped.
    pub triangles: Vec<[Vec3; 3]>,
}

/// One placement of an [`InstancedMesh`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instance {
    /// Index into `Scene::meshes`.
    pub mesh: u32,
    /// Object to world (to the scene's stored coordinates, relative to [`Scene::origin`]),
    /// as the scene file gives it, composed in f64 and held in f32: every vertex of the
    /// mesh is finite under it ([`place_point`]).
    pub to_world: glam::Mat4,
    /// Diffuse reflectance ρ of this placement.
    pub albedo: f32,
}

impl Instance {
    /// Object to world as three rows `(m0, m1, m2, t)` (what the kernels read).
    pub fn to_world_rows(&self) -> AffineRows {
        AffineRows::from_mat4(&self.to_world)
    }

    /// World to object: the inverse of `to_world`.
    pub fn to_object(&self) -> InverseAffine {
        InverseAffine::of(&self.to_world)
    }
}

/// A mesh object of a scene file (or the one mesh of a mesh file), as placed: what a
/// bake computes AO on and writes back to.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshObject {
    /// The object's number in the scene file, from 1 (1 for a mesh file).
    pub number: usize,
    /// The mesh file.
    pub path: PathBuf,
    /// From the mesh's positions as its loader reads them to the scene's stored
    /// coordinates (relative to [`Scene::origin`]): the object's transform, composed in
    /// f64 with the two origins and held in f32.
    pub to_world: glam::Mat4,
    /// Its placement in `Scene::instances` when the mesh file is placed by several
    /// objects; `None` when its triangles went into `Scene::triangles`, each distinct
    /// vertex through [`place_point`] once.
    pub instance: Option<u32>,
    /// Whether the file's glTF URIs may lead outside its folder (as it was loaded).
    pub allow_external_uris: bool,
}

/// Largest image width and height.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Something a loader skipped that still leaves a valid scene (for example, glTF
/// primitives that are not triangles): reported to the caller rather than printed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Warning {
    /// The file it concerns.
    pub path: PathBuf,
    /// What was skipped, in one line.
    pub message: String,
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.message)
    }
}

/// What a request's samples are drawn with besides the image: the one owner of its
/// sampling parameters. [`Settings`] holds one; the CPU reference, the GPU's frame
/// constants (`gpu::layout::FrameUniforms::sampling`), a render's identity
/// (`SampleSettings`, which checkpoints store), statistics and Python read it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampling {
    /// AO direction distribution.
    pub hemisphere: Hemisphere,
    /// Placement of the pixel-jitter and hemisphere numbers.
    pub sampler: Sampler,
    /// AO rays longer than this are unoccluded; `None` is no limit.
    pub max_distance: Option<f32>,
    /// Seed of the random numbers.
    pub seed: u32,
    /// Samples per independently randomised replicate (`sampler` module doc); `None`
    /// for the sampler's default (one replicate of every sample for `stratified` and
    /// `sobol`: no valid error estimate).
    pub replicate: Option<u32>,
    /// The sky an AO ray that escapes sees (classic AO by default).
    pub sky: Sky,
}

impl Default for Sampling {
    fn default() -> Self {
        Sampling {
            hemisphere: Hemisphere::Cosine,
            sampler: Sampler::Independent,
            max_distance: None,
            seed: 0,
            replicate: None,
            sky: Sky::default(),
        }
    }
}

impl Sampling {
    /// Samples per replicate ([`Sampler::replicate_samples`]).
    pub fn replicate_samples(&self) -> u32 {
        self.sampler.replicate_samples(self.replicate)
    }

    /// Cells per axis of a request of `spp` samples per pixel or point
    /// ([`Sampler::strata_per_axis`]).
    pub fn strata(&self, spp: u32) -> u32 {
        self.sampler.strata_per_axis(spp, self.replicate_samples())
    }

    /// Checks what AO at a point depends on besides the hemisphere, sampler and seed (the
    /// maximum distance, the replicate size and the sky): [`Error::Settings`] naming it.
    pub fn validate(&self) -> Result<()> {
        self.sky.validate().map_err(Error::settings)?;
        if let Some(r) = self.replicate {
            self.sampler.check_replicate(r).map_err(Error::settings)?;
        }
        if let Some(d) = self.max_distance
            && (d.is_nan() || d < 0.0)
        {
            return Err(Error::settings(format!("max distance must be zero or positive, got {d}")));
        }
        Ok(())
    }
}

/// Image size and sampling: the scene file's defaults, and what a render request asks for.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel (each: one camera ray and at most one AO ray).
    pub spp: u32,
    /// Value of camera rays that hit nothing.
    pub background: f32,
    /// How the samples are drawn.
    pub sampling: Sampling,
}

impl Default for Settings {
    fn default() -> Self {
        Settings { width: 512, height: 512, spp: 64, background: 0.0, sampling: Sampling::default() }
    }
}

impl Settings {
    /// Checks ranges: [`Error::Settings`] naming the offending setting.
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::settings(format!("image size must be positive, got {}x{}", self.width, self.height)));
        }
        if self.width > MAX_IMAGE_SIDE || self.height > MAX_IMAGE_SIDE {
            return Err(Error::settings(format!(
                "image size {}x{} exceeds {MAX_IMAGE_SIDE} on a side",
                self.width, self.height
            )));
        }
        if self.spp == 0 {
            return Err(Error::settings("samples per pixel must be at least 1"));
        }
        self.sampling.validate()?;
        if !self.background.is_finite() {
            return Err(Error::settings("background must be finite"));
        }
        Ok(())
    }
}

/// A scene ready to render.
///
/// Its primitives (and probe points in it) are stored in f32 relative to
/// [`Scene::origin`], which is zero unless a loader placed geometry far from the origin
/// for its size (a glTF node hierarchy, a scene file's transform): then the geometry keeps
/// the accuracy its own coordinates have. Cameras are in the scene's own coordinates, in
/// f64.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Human-readable name (file stem or "aobench").
    pub name: String,
    /// The file it was read from (a scene file or a bare mesh); `None` for a scene made
    /// in memory and for the built-in one.
    pub path: Option<PathBuf>,
    /// The camera, in the scene's own coordinates.
    pub camera: Camera,
    /// The point of the scene's own coordinates that its stored primitives' coordinates
    /// are relative to (each component an f32 value; zero for a scene near the origin).
    pub origin: DVec3,
    /// Render settings.
    pub settings: Settings,
    /// Triangles of meshes placed once, transformed to world space.
    pub triangles: Vec<Triangle>,
    /// Meshes placed more than once, each in its own space.
    pub meshes: Vec<InstancedMesh>,
    /// Placements of `meshes`.
    pub instances: Vec<Instance>,
    /// Spheres.
    pub spheres: Vec<Sphere>,
    /// Infinite planes.
    pub planes: Vec<Plane>,
    /// What the loaders skipped (empty for a scene made in memory).
    pub warnings: Vec<Warning>,
    /// The mesh objects, in the scene file's order (empty for a scene made in memory).
    pub mesh_objects: Vec<MeshObject>,
}

/// Axis-aligned bounds of the finite primitives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Scene {
    /// What messages about the scene as a whole name: its file, or its name.
    pub fn source(&self) -> PathBuf {
        self.path.clone().unwrap_or_else(|| PathBuf::from(&self.name))
    }

    /// The automatic framing used for bare meshes: the eye at centre + normalize(0.6, 0.45,
    /// 1.0) × 1.2 × diagonal of the bounds, looking at their centre, in the scene's own
    /// coordinates. The centre is exact in f64 and the offset an f32 vector, so that their
    /// sum is exact too and a scene moved far away keeps its camera bit for bit in the
    /// frame it is rendered in.
    pub fn auto_camera(&self) -> Camera {
        let b = self.bounds().unwrap_or(Bounds { min: Vec3::splat(-1.0), max: Vec3::splat(1.0) });
        let (min, max) = (b.min.as_dvec3(), b.max.as_dvec3());
        let diagonal = (max - min).as_vec3().length().max(f32::MIN_POSITIVE);
        let offset = Vec3::new(0.6, 0.45, 1.0).normalize() * 1.2 * diagonal;
        let centre = self.origin + 0.5 * (min + max);
        Camera {
            eye: centre + offset.as_dvec3(),
            look_at: centre,
            up: Vec3::Y,
            projection: Projection::Perspective { vfov_deg: 45.0 },
        }
    }

    /// Bytes of the geometry held on the host: triangles, instanced meshes, instances,
    /// spheres and planes.
    pub fn geometry_bytes(&self) -> u64 {
        let mesh_triangles: usize = self.meshes.iter().map(|m| m.triangles.len()).sum();
        (self.triangles.len() * std::mem::size_of::<Triangle>()
            + mesh_triangles * std::mem::size_of::<[Vec3; 3]>()
            + self.instances.len() * std::mem::size_of::<Instance>()
            + self.spheres.len() * std::mem::size_of::<Sphere>()
            + self.planes.len() * std::mem::size_of::<Plane>()) as u64
    }

    /// Triangles in the world: those placed once and every placement of an instanced mesh.
    pub fn world_triangle_count(&self) -> usize {
        self.triangles.len()
            + self.instances.iter().map(|i| self.meshes[i.mesh as usize].triangles.len()).sum::<usize>()
    }

    /// The scene with every instance's triangles transformed into the world and added to
    /// `triangles`, as the loader places a mesh placed once (each vertex through
    /// [`place_point`], degenerate results dropped).
    pub fn flattened(&self) -> Scene {
        let mut scene = Scene { meshes: Vec::new(), instances: Vec::new(), ..self.clone() };
        for object in &mut scene.mesh_objects {
            object.instance = None;
        }
        for instance in &self.instances {
            let m = &instance.to_world;
            let world = self.meshes[instance.mesh as usize].triangles.iter().map(|t| t.map(|v| place_point(m, v)));
            scene
                .triangles
                .extend(world.filter(|&v| !is_degenerate(v)).map(|v| Triangle { v, albedo: instance.albedo }));
        }
        scene
    }

    /// Bounds of triangles, instances and spheres, in the stored coordinates (relative to
    /// [`Scene::origin`]); `None` when the scene has none.
    pub fn bounds(&self) -> Option<Bounds> {
        let (mut min, mut max) = fold_bounds(EMPTY_BOUNDS, &self.triangles, |t| t.v);
        for instance in &self.instances {
            let triangles = &self.meshes[instance.mesh as usize].triangles;
            (min, max) = fold_bounds((min, max), triangles, |t| t.map(|v| place_point(&instance.to_world, v)));
        }
        for s in &self.spheres {
            min = min.min(s.center - s.radius);
            max = max.max(s.center + s.radius);
        }
        (min.x <= max.x).then_some(Bounds { min, max })
    }

    /// Number of primitives the top-level BVH holds (triangles, spheres and instances).
    pub fn finite_primitive_count(&self) -> usize {
        self.triangles.len() + self.spheres.len() + self.instances.len()
    }
}

/// `p` placed by the affine `m` as the loaders place a mesh's vertices: in f64 (the
/// products and sums of f32 values exact or nearly), rounded once to f32.
pub fn place_point(m: &Mat4, p: Vec3) -> Vec3 {
    m.as_dmat4().transform_point3(p.as_dvec3()).as_vec3()
}

/// Smallest squared length of `(v1 - v0) × (v2 - v0)` of a triangle that is kept: below
/// it the geometric normal is zero or too small to normalize in f32 (on the GPU, where
/// denormals may flush to zero, too), so the triangle is dropped. Such a triangle has no
/// area to hit (twice its area is below 2^-60 ≈ 8.7e-19 world units²).
pub const MIN_NORMAL_LENGTH_SQUARED: f32 = f32::from_bits((127 - 120) << 23); // 2^-120
/// Whether a triangle's normal is too small to keep (see [`MIN_NORMAL_LENGTH_SQUARED`]).
// Negated so that a NaN normal counts as degenerate.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
pub(crate) fn is_degenerate(v: [Vec3; 3]) -> bool {
    let n = (v[1] - v[0]).cross(v[2] - v[0]);
    !(n.dot(n) >= MIN_NORMAL_LENGTH_SQUARED)
}

/// Largest squared normal length accepted: above it normalizing could overflow.
pub const MAX_NORMAL_LENGTH_SQUARED: f32 = f32::from_bits((127 + 120) << 23); // 2^120

/// "x = NaN", naming the first non-finite coordinate of `p`; `None` when it is finite.
pub(crate) fn non_finite_coordinate(p: Vec3) -> Option<String> {
    let axes = ["x", "y", "z"];
    p.to_array().iter().zip(axes).find(|(c, _)| !c.is_finite()).map(|(c, axis)| format!("{axis} = {c}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_length_bounds_are_powers_of_two() {
        assert_eq!(MIN_NORMAL_LENGTH_SQUARED as f64, 2f64.powi(-120));
        assert_eq!(MAX_NORMAL_LENGTH_SQUARED as f64, 2f64.powi(120));
    }
}
