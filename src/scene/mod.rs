//! The in-memory scene: primitives as the scene file states them (triangles, exact spheres,
//! infinite planes), a camera and the render settings. Scene files and mesh formats are
//! parsed into it by the submodules.

mod file;
mod gltf;
mod input;
mod mesh;
mod obj;
mod ply;

pub use file::{DEFAULT_SCENE, DEFAULT_SCENE_NAME};

use crate::camera::{Camera, Projection};
use crate::error::{Error, Result};
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use glam::Vec3;
use std::path::Path;

/// A triangle with its albedo.
#[derive(Clone, Copy, Debug, PartialEq)]
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

/// An infinite plane through `point` with unit `normal`, hit from both sides. Kept as a
/// point rather than `n·x = d`: a ray's distance to it is then `n·(point − o)`, whose
/// rounding error scales with the distance rather than with |o| (exact for an axis
/// normal), so planes stay exact far from the origin.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub normal: Vec3,
    /// A point of the plane.
    pub point: Vec3,
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
    /// Object to world, as the scene file gives it: every vertex of the mesh is finite
    /// under it.
    pub to_world: glam::Mat4,
    /// Diffuse reflectance ρ of this placement.
    pub albedo: f32,
}

impl Instance {
    /// Object to world as three rows `(m0, m1, m2, t)` (what the kernels read).
    pub fn to_world_rows(&self) -> crate::geometry::AffineRows {
        crate::geometry::AffineRows::from_mat4(&self.to_world)
    }

    /// World to object: the inverse of `to_world`.
    pub fn to_object(&self) -> crate::geometry::InverseAffine {
        crate::geometry::InverseAffine::of(&self.to_world)
    }
}

/// Image size and sampling defaults; command-line options override them.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Samples per pixel (each: one camera ray and at most one AO ray).
    pub spp: u32,
    /// AO direction distribution.
    pub hemisphere: Hemisphere,
    /// Placement of the pixel-jitter and hemisphere numbers.
    pub sampler: Sampler,
    /// AO rays longer than this are unoccluded; `None` is no limit.
    pub max_distance: Option<f32>,
    /// Value of camera rays that hit nothing.
    pub background: f32,
    /// Seed of the random numbers.
    pub seed: u32,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            width: 512,
            height: 512,
            spp: 64,
            hemisphere: Hemisphere::Cosine,
            sampler: Sampler::Independent,
            max_distance: None,
            background: 0.0,
            seed: 0,
        }
    }
}

impl Settings {
    /// Checks ranges; the message names the offending setting.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("image size must be positive, got {}x{}", self.width, self.height));
        }
        if self.width > 16384 || self.height > 16384 {
            return Err(format!("image size {}x{} exceeds 16384 on a side", self.width, self.height));
        }
        if self.spp == 0 {
            return Err("samples per pixel must be at least 1".into());
        }
        if let Some(d) = self.max_distance
            && (d.is_nan() || d < 0.0)
        {
            return Err(format!("max distance must be zero or positive, got {d}"));
        }
        if !self.background.is_finite() {
            return Err("background must be finite".into());
        }
        Ok(())
    }
}

/// A scene ready to render.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Human-readable name (file stem or "aobench").
    pub name: String,
    /// The camera.
    pub camera: Camera,
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
    /// Loads a scene file (`.toml`) or a bare mesh (`.obj`, `.ply`, `.gltf`, `.glb`, each
    /// also gzipped as `.gz`), framed automatically.
    pub fn load(path: &Path) -> Result<Scene> {
        match extension(path).as_str() {
            "toml" if input::is_gzip(path) => Err(Error::scene(path, "a scene file cannot be gzipped")),
            "toml" => file::load_scene_file(path),
            ext if MESH_EXTENSIONS.contains(&ext) => Scene::from_mesh_file(path),
            "" => Err(Error::scene(path, format!("no file extension: expected .toml or {MESH_FORMATS}"))),
            ext => Err(Error::scene(path, format!("unsupported file type '.{ext}': expected .toml or {MESH_FORMATS}"))),
        }
    }

    /// The built-in default scene (`scenes/aobench.toml`).
    pub fn default_scene() -> Scene {
        file::parse_scene(DEFAULT_SCENE, Path::new(DEFAULT_SCENE_NAME), Path::new("."))
            .expect("the built-in scene is valid")
    }

    /// Parses a scene from TOML text; mesh paths resolve against `base_dir`.
    pub fn from_toml_str(text: &str, path: &Path, base_dir: &Path) -> Result<Scene> {
        file::parse_scene(text, path, base_dir)
    }

    /// A bare mesh, albedo 1, looked at from eye = centre + normalize(0.6, 0.45, 1.0) ×
    /// 1.2 × diagonal with up +Y and a 45° vertical field of view; no distance limit.
    pub fn from_mesh_file(path: &Path) -> Result<Scene> {
        let triangles = load_mesh(path, 1.0, &glam::Mat4::IDENTITY)?;
        let mut scene = Scene {
            name: stem(path),
            camera: Camera {
                eye: Vec3::ZERO,
                look_at: Vec3::NEG_Z,
                up: Vec3::Y,
                projection: Projection::Perspective { vfov_deg: 45.0 },
            },
            settings: Settings::default(),
            triangles,
            meshes: Vec::new(),
            instances: Vec::new(),
            spheres: Vec::new(),
            planes: Vec::new(),
        };
        scene.camera = scene.auto_camera();
        Ok(scene)
    }

    /// The automatic framing used for bare meshes.
    pub fn auto_camera(&self) -> Camera {
        let b = self.bounds().unwrap_or(Bounds { min: Vec3::splat(-1.0), max: Vec3::splat(1.0) });
        let centre = 0.5 * (b.min + b.max);
        let diagonal = (b.max - b.min).length().max(f32::MIN_POSITIVE);
        Camera {
            eye: centre + Vec3::new(0.6, 0.45, 1.0).normalize() * 1.2 * diagonal,
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
    /// `triangles`, as the loader placed meshes before instancing (each vertex through
    /// `Mat4::transform_point3`, degenerate results dropped).
    pub fn flattened(&self) -> Scene {
        let mut scene = Scene { meshes: Vec::new(), instances: Vec::new(), ..self.clone() };
        for instance in &self.instances {
            let m = &instance.to_world;
            let world = self.meshes[instance.mesh as usize].triangles.iter().map(|t| t.map(|v| m.transform_point3(v)));
            scene
                .triangles
                .extend(world.filter(|&v| !is_degenerate(v)).map(|v| Triangle { v, albedo: instance.albedo }));
        }
        scene
    }

    /// Bounds of triangles, instances and spheres; `None` when the scene has none.
    pub fn bounds(&self) -> Option<Bounds> {
        let mut min = Vec3::splat(f32::INFINITY);
        let mut max = Vec3::splat(f32::NEG_INFINITY);
        for t in &self.triangles {
            for v in t.v {
                min = min.min(v);
                max = max.max(v);
            }
        }
        for instance in &self.instances {
            for t in &self.meshes[instance.mesh as usize].triangles {
                for v in t {
                    let w = instance.to_world.transform_point3(*v);
                    min = min.min(w);
                    max = max.max(w);
                }
            }
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

/// Loads a triangle mesh (`.obj`, `.ply`, `.gltf` or `.glb`, each optionally gzipped as
/// `.gz`), applying `transform`. Rejects empty meshes, vertices with a NaN or infinite
/// coordinate (in the file, or after the transform) and triangles too large to normalize;
/// drops degenerate triangles (zero area, a repeated vertex), which no ray can hit and
/// whose normal is undefined. Errors name the vertex or triangle.
pub fn load_mesh(path: &Path, albedo: f32, transform: &glam::Mat4) -> Result<Vec<Triangle>> {
    let mut mesh = read_mesh(path)?;
    let positions = std::mem::take(&mut mesh.positions);
    place_mesh(path, positions, &mesh, albedo, transform)
}

/// Reads a mesh file as it is stored: its vertices and triangles, checked to index them.
pub(crate) fn read_mesh(path: &Path) -> Result<mesh::IndexedMesh> {
    let mesh = match extension(path).as_str() {
        "obj" => obj::load_obj(path)?,
        "ply" => ply::load_ply(path)?,
        "gltf" | "glb" => gltf::load_gltf(path)?,
        ext => {
            return Err(Error::scene(path, format!("unsupported mesh format '.{ext}': expected {MESH_FORMATS}")));
        }
    };
    if mesh.triangles.is_empty() {
        return Err(Error::scene(path, "mesh has no triangles"));
    }
    let n = mesh.positions.len();
    if let Some(i) = mesh.triangles.iter().flatten().find(|&&i| i as usize >= n) {
        return Err(Error::scene(path, format!("vertex index {i} is out of range ({n} vertices)")));
    }
    Ok(mesh)
}

/// The triangles of `mesh` (read from `path`) placed in the world by `transform`;
/// `positions` are the mesh's vertices (its own, taken out, or a copy), transformed in place.
pub(crate) fn place_mesh(
    path: &Path,
    mut positions: Vec<Vec3>,
    mesh: &mesh::IndexedMesh,
    albedo: f32,
    transform: &glam::Mat4,
) -> Result<Vec<Triangle>> {
    // Each distinct vertex goes through the transform once, and every triangle below takes
    // its corners from the result, so shared vertices stay bit-identical.
    for (k, p) in positions.iter_mut().enumerate() {
        let q = transform.transform_point3(*p);
        if let Some(c) = non_finite_coordinate(q) {
            let name = mesh.names.name(k, *p);
            return Err(Error::scene(path, format!("{name} has a non-finite coordinate after the transform ({c})")));
        }
        *p = q;
    }
    mesh_triangles(path, mesh.triangles.iter().map(|t| t.map(|i| positions[i as usize])), albedo)
}

/// The triangles of a mesh in world space, as the scene keeps them: rejects a non-finite
/// coordinate and triangles too large to normalize, drops degenerate triangles (zero
/// area, a repeated vertex), which no ray can hit and whose normal is undefined, and
/// rejects a mesh left empty. `path` names the mesh in errors.
pub fn mesh_triangles(
    path: &Path,
    triangles: impl IntoIterator<Item = [Vec3; 3]>,
    albedo: f32,
) -> Result<Vec<Triangle>> {
    let triangles = triangles.into_iter();
    // One allocation of the final size when the count is known: no copy while growing.
    let mut out = Vec::with_capacity(triangles.size_hint().0);
    for (i, v) in triangles.enumerate() {
        if let Some(c) = v.iter().find_map(|&p| non_finite_coordinate(p)) {
            return Err(Error::scene(path, format!("triangle {} has a non-finite coordinate ({c})", i + 1)));
        }
        // The normal as the renderers compute it (src/geometry.rs, shaders/intersect.wgsl).
        let n = (v[1] - v[0]).cross(v[2] - v[0]);
        let l2 = n.dot(n);
        if l2.is_nan() || l2 > MAX_NORMAL_LENGTH_SQUARED {
            return Err(Error::scene(
                path,
                format!("triangle {} is too large for f32: its normal has squared length {l2}", i + 1),
            ));
        }
        if l2 >= MIN_NORMAL_LENGTH_SQUARED {
            out.push(Triangle { v, albedo });
        }
    }
    if out.is_empty() {
        return Err(Error::scene(path, "mesh has no triangles of non-zero area"));
    }
    Ok(out)
}

/// Extensions of the mesh formats, before an optional `.gz`.
const MESH_EXTENSIONS: [&str; 4] = ["obj", "ply", "gltf", "glb"];
/// The mesh formats, for error messages.
const MESH_FORMATS: &str = "a mesh (.obj, .ply, .gltf or .glb, optionally gzipped as .gz)";

/// The file's extension in lower case; for a gzipped file (`.gz`), the one before it.
fn extension(path: &Path) -> String {
    let inner = if input::is_gzip(path) { path.file_stem().map(Path::new) } else { Some(path) };
    inner.and_then(Path::extension).and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase()
}

/// The file's name without its extension (and without `.gz`).
fn stem(path: &Path) -> String {
    let inner = if input::is_gzip(path) { path.file_stem().map(Path::new) } else { Some(path) };
    inner.and_then(Path::file_stem).and_then(|s| s.to_str()).unwrap_or("scene").to_string()
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
