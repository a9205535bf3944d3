//! The TOML scene format (documented in the README). Unknown fields are errors.
//!
//! Positions and transforms are read in f64 and composed in f64. The scene's origin
//! ([`Scene::origin`]) is chosen from the first mesh or sphere, by the rule of the local
//! frame (zero unless it lies far from the origin for its size), and every primitive is
//! placed relative to it: a mesh by its transform composed with the two origins in f64
//! and held in f32 (as an instance's is), each vertex through it in f64 and rounded once.

use super::camera::{Camera, Projection};
use super::frame::grid_origin;
use super::input::{LoadOptions, Meter, vec_bytes};
use super::mesh::IndexedMesh;
use super::meshes::{MeshReader, mesh_bytes, mesh_triangles_within, place_mesh, read_mesh, vertex_name};
use super::types::{
    Instance, InstancedMesh, MeshObject as PlacedMesh, Sampling, Scene, Settings, Sphere, Triangle, Warning,
    non_finite_coordinate, place_point,
};
use crate::error::{Error, Result};
use crate::geometry::Plane;
use crate::sampler::Sampler;
use crate::sampling::Hemisphere;
use crate::sky::{Sky, SkyModel, SkyNormalise, SkySampling};
use glam::{DMat4, DVec3, Mat4, Vec3};
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Fails when a vertex of `mesh` (as read from `path`) has a non-finite coordinate under `m`,
/// naming it as `place_mesh` does.
fn check_placement(path: &Path, mesh: &IndexedMesh, m: &Mat4) -> Result<(), Error> {
    for (k, p) in mesh.positions.iter().enumerate() {
        if let Some(c) = non_finite_coordinate(place_point(m, *p)) {
            let name = vertex_name(&mesh.names, k, *p);
            return Err(Error::scene(path, format!("{name} has a non-finite coordinate after the transform ({c})")));
        }
    }
    Ok(())
}

/// The bounds, in f64, of the vertices of `mesh` placed by `m` (of its file's space), for
/// choosing the scene's origin; `None` when a vertex is not finite there.
fn placed_bounds(mesh: &IndexedMesh, m: &DMat4) -> Option<(DVec3, DVec3)> {
    let (mut min, mut max) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for p in &mesh.positions {
        let q = m.transform_point3(mesh.origin + p.as_dvec3());
        (min, max) = (min.min(q), max.max(q));
    }
    (min.is_finite() && max.is_finite() && min.x <= max.x).then_some((min, max))
}

/// `m` (from a file's space to the scene's own) composed with the mesh's origin and the
/// scene's, in f64, and held in f32: from the positions a loader read (relative to
/// `mesh_origin`) to the scene's stored coordinates (relative to `scene_origin`).
fn relative_placement(m: &DMat4, mesh_origin: DVec3, scene_origin: DVec3) -> Result<Mat4, TransformError> {
    let mut relative = *m * DMat4::from_translation(mesh_origin);
    relative.w_axis -= scene_origin.extend(0.0);
    let held = relative.as_mat4();
    if !held.is_finite() {
        return Err(TransformError("transform has an entry too large for f32".into()));
    }
    if held.determinant() == 0.0 {
        return Err(TransformError("transform is singular".into()));
    }
    Ok(held)
}

/// The default scene's text, compiled in so the binary renders without any files.
pub const DEFAULT_SCENE: &str = include_str!("../../../../scenes/aobench.toml");
/// Name reported for the built-in scene.
pub const DEFAULT_SCENE_NAME: &str = "scenes/aobench.toml";

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    #[serde(default)]
    image: ImageSection,
    #[serde(default)]
    sampling: SamplingSection,
    #[serde(default)]
    sky: SkySection,
    camera: CameraSection,
    #[serde(default, rename = "object")]
    objects: Vec<Object>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct ImageSection {
    width: Option<u32>,
    height: Option<u32>,
    background: Option<f32>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SamplingSection {
    spp: Option<u32>,
    hemisphere: Option<Hemisphere>,
    sampler: Option<Sampler>,
    max_distance: Option<f32>,
    seed: Option<u32>,
    replicate: Option<u32>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct SkySection {
    model: Option<SkyModel>,
    up: Option<[f32; 3]>,
    ground_albedo: Option<f32>,
    sampling: Option<SkySampling>,
    normalise: Option<SkyNormalise>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename_all = "lowercase")]
enum CameraKind {
    Perspective,
    Orthographic,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSection {
    #[serde(rename = "type")]
    kind: CameraKind,
    eye: [f64; 3],
    look_at: [f64; 3],
    #[serde(default = "default_up")]
    up: [f32; 3],
    /// Vertical field of view in degrees (perspective).
    fov: Option<f32>,
    /// View height in world units (orthographic).
    height: Option<f32>,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}

fn default_albedo() -> f32 {
    1.0
}

#[derive(Deserialize)]
#[serde(tag = "type", rename_all = "lowercase")]
enum Object {
    Mesh(MeshObject),
    Sphere(SphereObject),
    Plane(PlaneObject),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshObject {
    file: String,
    #[serde(default = "default_albedo")]
    albedo: f32,
    transform: Option<Transform>,
    /// Follow the glTF file's URIs outside its folder.
    #[serde(default)]
    allow_external_uris: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SphereObject {
    center: [f64; 3],
    radius: f32,
    #[serde(default = "default_albedo")]
    albedo: f32,
    transform: Option<Transform>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaneObject {
    point: [f64; 3],
    normal: [f32; 3],
    #[serde(default = "default_albedo")]
    albedo: f32,
    transform: Option<Transform>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Scale {
    Uniform(f64),
    Axes([f64; 3]),
}

/// Applied as scale, then rotation (about x, then y, then z, in degrees), then
/// translation; or a full row-major 4×4 `matrix` instead of those.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Transform {
    scale: Option<Scale>,
    rotate: Option<[f64; 3]>,
    translate: Option<[f64; 3]>,
    matrix: Option<[[f64; 4]; 4]>,
}

/// "has a non-finite entry (NaN)" for the first NaN or infinity in `values`.
fn non_finite_entry(values: &[f64]) -> Option<String> {
    values.iter().find(|v| !v.is_finite()).map(|v| format!("has a non-finite entry ({v})"))
}

/// Why a transform is unusable, in one line.
struct TransformError(String);

impl Transform {
    /// The transform in f64: from its object's space to the scene's own.
    fn matrix(&self) -> Result<DMat4, TransformError> {
        let scale: Option<Vec<f64>> = self.scale.as_ref().map(|s| match s {
            Scale::Uniform(s) => vec![*s],
            Scale::Axes(a) => a.to_vec(),
        });
        let fields = [
            ("scale", scale),
            ("rotate", self.rotate.map(|r| r.to_vec())),
            ("translate", self.translate.map(|t| t.to_vec())),
            ("matrix", self.matrix.map(|m| m.concat())),
        ];
        for (name, values) in fields {
            if let Some(e) = values.and_then(|v| non_finite_entry(&v)) {
                return Err(TransformError(format!("transform: {name} {e}")));
            }
        }
        let m = if let Some(rows) = self.matrix {
            if self.scale.is_some() || self.rotate.is_some() || self.translate.is_some() {
                return Err(TransformError("transform: give either matrix or scale/rotate/translate, not both".into()));
            }
            if rows[3] != [0.0, 0.0, 0.0, 1.0] {
                let [a, b, c, d] = rows[3];
                return Err(TransformError(format!(
                    "transform: matrix: the last row must be [0, 0, 0, 1], not [{a}, {b}, {c}, {d}]: a projective matrix is not an affine transform"
                )));
            }
            DMat4::from_cols_array_2d(&rows).transpose()
        } else {
            let s = match self.scale {
                None => DVec3::ONE,
                Some(Scale::Uniform(s)) => DVec3::splat(s),
                Some(Scale::Axes(a)) => DVec3::from(a),
            };
            let r = self.rotate.map(DVec3::from).unwrap_or(DVec3::ZERO);
            let rotation =
                glam::DQuat::from_euler(glam::EulerRot::ZYX, r.z.to_radians(), r.y.to_radians(), r.x.to_radians());
            let t = self.translate.map(DVec3::from).unwrap_or(DVec3::ZERO);
            DMat4::from_scale_rotation_translation(s, rotation, t)
        };
        if !m.is_finite() {
            return Err(TransformError("transform has a NaN or infinite entry".into()));
        }
        if m.determinant() == 0.0 {
            return Err(TransformError("transform is singular".into()));
        }
        Ok(m)
    }
}

/// One-line form of a TOML error: message and line.
fn toml_error(text: &str, e: &toml::de::Error) -> String {
    let msg = e.message().replace('\n', " ");
    match e.span() {
        Some(span) => {
            let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
            format!("line {line}: {}", msg.trim())
        }
        None => msg.trim().to_string(),
    }
}

/// A mesh file, the objects still to place it, and its index in the scene's meshes with
/// its vertices once read.
type MeshUse = (PathBuf, usize, Option<(u32, IndexedMesh)>);

/// The bytes a scene being loaded holds: its triangles, its instanced meshes, and the
/// meshes kept for the checks of their later instances.
fn retained_bytes(triangles: &Vec<Triangle>, meshes: &[InstancedMesh], mesh_uses: &[MeshUse]) -> u64 {
    vec_bytes(triangles)
        + meshes.iter().map(|m| vec_bytes(&m.triangles)).sum::<u64>()
        + mesh_uses.iter().filter_map(|(_, _, read)| read.as_ref()).map(|(_, m)| mesh_bytes(m)).sum::<u64>()
}

/// Parses the text of a scene file read from `path`; mesh paths resolve against `base_dir`.
/// The meshes are read as `options` say (by `reader` when there is one), everything the
/// scene holds at once charged to `meter` (which holds the text's charge already).
pub(super) fn parse_scene(
    text: &str,
    path: &Path,
    base_dir: &Path,
    options: &LoadOptions,
    meter: &mut Meter,
    mut reader: Option<&mut MeshReader>,
) -> Result<Scene> {
    let file: SceneFile = toml::from_str(text).map_err(|e| Error::scene(path, toml_error(text, &e)))?;
    let err = |m: String| Error::scene(path, m);

    let (defaults, d) = (Settings::default(), Sampling::default());
    let settings = Settings {
        width: file.image.width.unwrap_or(defaults.width),
        height: file.image.height.unwrap_or(defaults.height),
        background: file.image.background.unwrap_or(defaults.background),
        spp: file.sampling.spp.unwrap_or(defaults.spp),
        sampling: Sampling {
            hemisphere: file.sampling.hemisphere.unwrap_or(d.hemisphere),
            sampler: file.sampling.sampler.unwrap_or(d.sampler),
            max_distance: file.sampling.max_distance,
            seed: file.sampling.seed.unwrap_or(d.seed),
            replicate: file.sampling.replicate,
            sky: {
                let (d, k) = (d.sky, &file.sky);
                Sky {
                    model: k.model.unwrap_or(d.model),
                    up: k.up.map_or(d.up, Vec3::from),
                    ground_albedo: k.ground_albedo.unwrap_or(d.ground_albedo),
                    sampling: k.sampling.unwrap_or(d.sampling),
                    normalise: k.normalise.unwrap_or(d.normalise),
                }
            },
        },
    };
    settings.validate().map_err(|e| err(e.message()))?;

    let c = &file.camera;
    let projection = match c.kind {
        CameraKind::Perspective => {
            if c.height.is_some() {
                return Err(err("camera: 'height' is for orthographic cameras; use 'fov'".into()));
            }
            Projection::Perspective { vfov_deg: c.fov.ok_or_else(|| err("camera: perspective needs 'fov'".into()))? }
        }
        CameraKind::Orthographic => {
            if c.fov.is_some() {
                return Err(err("camera: 'fov' is for perspective cameras; use 'height'".into()));
            }
            Projection::Orthographic {
                height: c.height.ok_or_else(|| err("camera: orthographic needs 'height'".into()))?,
            }
        }
    };
    // Beyond f32's range is not finite either: the rays are made in f32.
    for (name, p) in
        [("eye", DVec3::from(c.eye).as_vec3()), ("look_at", DVec3::from(c.look_at).as_vec3()), ("up", c.up.into())]
    {
        if let Some(coordinate) = non_finite_coordinate(p) {
            return Err(err(format!("camera: {name} has a non-finite coordinate ({coordinate})")));
        }
    }
    let camera = Camera { eye: c.eye.into(), look_at: c.look_at.into(), up: c.up.into(), projection };
    camera.validate().map_err(|e| err(e.message()))?;

    // The scene's origin is the local frame's origin of all its meshes and spheres
    // ([`grid_origin`] of their bounds in f64), which is known once they are placed: the
    // objects are placed about zero first (what every scene near the origin keeps), and
    // again about that origin where it differs.
    let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene").to_string();
    let start = meter.used();
    let mut origin = DVec3::ZERO;
    for pass in 0..3 {
        let mut bounds = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        let placed =
            place_objects(&file.objects, path, (base_dir, reader.as_deref_mut()), options, meter, origin, &mut bounds);
        let wanted = if bounds.0.x <= bounds.1.x { grid_origin(bounds.0, bounds.1) } else { DVec3::ZERO };
        if wanted == origin || pass == 2 {
            let p = placed?;
            return Ok(Scene {
                name,
                path: Some(path.to_path_buf()),
                camera,
                origin,
                settings,
                triangles: p.triangles,
                meshes: p.meshes,
                instances: p.instances,
                spheres: p.spheres,
                planes: p.planes,
                warnings: p.warnings,
                mesh_objects: p.mesh_objects,
            });
        }
        drop(placed);
        meter.set_used(start);
        origin = wanted;
    }
    unreachable!("the third pass returns")
}

/// The objects of a scene file, placed.
struct Placed {
    triangles: Vec<Triangle>,
    meshes: Vec<InstancedMesh>,
    instances: Vec<Instance>,
    spheres: Vec<Sphere>,
    planes: Vec<Plane>,
    warnings: Vec<Warning>,
    mesh_objects: Vec<PlacedMesh>,
}

/// Places `objects` (of the scene file `path`, mesh paths relative to `base_dir`, read by
/// `reader` when there is one) relative
/// to the scene's `origin`, everything held charged to `meter`; `bounds` grows by each
/// mesh's and sphere's bounds in f64 before the object is placed (so that a failure still
/// leaves what was seen of the scene).
fn place_objects(
    objects: &[Object],
    path: &Path,
    (base_dir, mut reader): (&Path, Option<&mut MeshReader>),
    options: &LoadOptions,
    meter: &mut Meter,
    origin: DVec3,
    bounds: &mut (DVec3, DVec3),
) -> Result<Placed> {
    let err = |m: String| Error::scene(path, m);
    let mut grow = |b: Option<(DVec3, DVec3)>| {
        if let Some((lo, hi)) = b {
            *bounds = (bounds.0.min(lo), bounds.1.max(hi));
        }
    };
    let mut triangles: Vec<Triangle> = Vec::new();
    let mut spheres = Vec::new();
    let mut planes = Vec::new();
    // Mesh files placed by several objects become instanced meshes: read once, kept in
    // their own space, each object an instance. (path, objects placing it, its index in
    // `meshes` once read).
    let mut mesh_uses: Vec<MeshUse> = Vec::new();
    let mut warnings: Vec<Warning> = Vec::new();
    let mut meshes: Vec<InstancedMesh> = Vec::new();
    let mut instances: Vec<Instance> = Vec::new();
    let mut mesh_objects: Vec<PlacedMesh> = Vec::new();
    for object in objects {
        if let Object::Mesh(m) = object {
            let path = base_dir.join(&m.file);
            match mesh_uses.iter_mut().find(|(p, _, _)| *p == path) {
                Some((_, uses, _)) => *uses += 1,
                None => mesh_uses.push((path, 1, None)),
            }
        }
    }
    for (i, object) in objects.iter().enumerate() {
        // Names the object in errors: `object 3 (mesh "bunny.obj")`, `object 1 (sphere)`.
        let (kind, albedo, transform) = match object {
            Object::Mesh(m) => (format!("mesh {:?}", m.file), m.albedo, &m.transform),
            Object::Sphere(s) => ("sphere".to_string(), s.albedo, &s.transform),
            Object::Plane(p) => ("plane".to_string(), p.albedo, &p.transform),
        };
        let object_name = format!("object {} ({kind})", i + 1);
        let fail = |message: String| err(format!("{object_name}: {message}"));
        if !(albedo.is_finite() && albedo >= 0.0) {
            return Err(fail(format!("albedo must be finite and non-negative, got {albedo}")));
        }
        let m = match transform {
            Some(t) => t.matrix().map_err(|e| fail(e.0))?,
            None => DMat4::IDENTITY,
        };
        match object {
            Object::Mesh(mesh) => {
                // Errors in the mesh file name the scene file, the object and the mesh.
                let path = base_dir.join(&mesh.file);
                let in_scene_error = |e| match e {
                    Error::Scene { message, .. } => fail(message),
                    e => e,
                };
                let allow_external_uris = options.allow_external_uris || mesh.allow_external_uris;
                let options = LoadOptions { allow_external_uris, ..options.clone() };
                let base = meter.used().saturating_sub(retained_bytes(&triangles, &meshes, &mesh_uses));
                let entry = mesh_uses.iter_mut().find(|(p, _, _)| *p == path).expect("every mesh path was counted");
                if entry.1 == 1 && entry.2.is_none() {
                    let mut read = read_mesh(&path, &options, meter, reader.as_deref_mut()).map_err(in_scene_error)?;
                    warnings.extend(read.warnings.drain(..).map(|message| Warning { path: path.clone(), message }));
                    grow(placed_bounds(&read, &m));
                    let held = relative_placement(&m, read.origin, origin).map_err(|e| fail(e.0))?;
                    let positions = std::mem::take(&mut read.positions);
                    let placed = place_mesh(&path, positions, &read, albedo, &held, meter).map_err(in_scene_error)?;
                    // Exact growth: the scene never reserves room it will not fill (a large
                    // array grows by remapping its pages, not by copying them).
                    meter.charge(&path, vec_bytes(&placed)).map_err(in_scene_error)?;
                    triangles.reserve_exact(placed.len());
                    triangles.extend(placed);
                    drop(read);
                    meter.set_used(base + retained_bytes(&triangles, &meshes, &mesh_uses));
                    let to_world = held;
                    mesh_objects.push(PlacedMesh {
                        number: i + 1,
                        path,
                        to_world,
                        instance: None,
                        allow_external_uris,
                    });
                    continue;
                }
                if entry.2.is_none() {
                    let mut read = read_mesh(&path, &options, meter, reader.as_deref_mut()).map_err(in_scene_error)?;
                    warnings.extend(read.warnings.drain(..).map(|message| Warning { path: path.clone(), message }));
                    let tris = read.triangles.iter().map(|t| t.map(|k| read.positions[k as usize]));
                    let tris = mesh_triangles_within(&path, tris, albedo, meter).map_err(in_scene_error)?;
                    let kept = tris.len() * std::mem::size_of::<[Vec3; 3]>();
                    meter.charge(&path, kept as u64).map_err(in_scene_error)?;
                    meshes.push(InstancedMesh {
                        name: path.display().to_string(),
                        triangles: tris.into_iter().map(|t| t.v).collect(),
                    });
                    entry.2 = Some((meshes.len() as u32 - 1, read));
                }
                let (index, read) = entry.2.as_ref().expect("read above");
                grow(placed_bounds(read, &m));
                let held = relative_placement(&m, read.origin, origin).map_err(|e| fail(e.0))?;
                check_placement(&path, read, &held).map_err(in_scene_error)?;
                instances.push(Instance { mesh: *index, to_world: held, albedo });
                let instance = Some(instances.len() as u32 - 1);
                let (number, to_world) = (i + 1, held);
                mesh_objects.push(PlacedMesh { number, path: path.clone(), to_world, instance, allow_external_uris });
                // The file's vertices are kept for the checks of its later instances only.
                entry.1 -= 1;
                if entry.1 == 0 {
                    entry.2 = None;
                }
                meter.set_used(base + retained_bytes(&triangles, &meshes, &mesh_uses));
            }
            Object::Sphere(s) => {
                let (center, radius) = (DVec3::from(s.center), s.radius);
                if let Some(c) = non_finite_coordinate(center.as_vec3()) {
                    return Err(fail(format!("centre has a non-finite coordinate ({c})")));
                }
                if !(radius.is_finite() && radius > 0.0) {
                    return Err(fail(format!("radius must be finite and positive, got {radius}")));
                }
                // Spheres stay exact: only similarity transforms keep them spheres.
                let (scale, _, _) = m.to_scale_rotation_translation();
                let max_rel = (scale.abs().max_element() - scale.abs().min_element()) / scale.abs().max_element();
                if max_rel > 1e-5 {
                    return Err(fail(
                        "transform must be a similarity (uniform scale, rotation, translation) to keep a sphere exact"
                            .into(),
                    ));
                }
                let center = m.transform_point3(center);
                let radius = (radius as f64 * scale.abs().x) as f32;
                if center.is_finite() {
                    let r = DVec3::splat(radius as f64);
                    grow(Some((center - r, center + r)));
                }
                let center = (center - origin).as_vec3();
                if !center.is_finite() || !radius.is_finite() {
                    return Err(fail("the transformed sphere is not finite".into()));
                }
                spheres.push(Sphere { center, radius, albedo });
            }
            Object::Plane(p) => {
                let (point, normal) = (DVec3::from(p.point), Vec3::from(p.normal));
                for (what, v) in [("point", point.as_vec3()), ("normal", normal)] {
                    if let Some(c) = non_finite_coordinate(v) {
                        return Err(fail(format!("{what} has a non-finite coordinate ({c})")));
                    }
                }
                if normal.length_squared() == 0.0 {
                    return Err(fail("normal must be non-zero".into()));
                }
                let point = (m.transform_point3(point) - origin).as_vec3();
                // Normals transform by the inverse transpose; normalised in f32, as given.
                let normal = m.inverse().transpose().transform_vector3(normal.as_dvec3()).as_vec3().normalize();
                if !point.is_finite() || !normal.is_finite() {
                    return Err(fail("the transformed plane is not finite".into()));
                }
                planes.push(Plane { normal, point, albedo });
            }
        }
    }
    Ok(Placed { triangles, meshes, instances, spheres, planes, warnings, mesh_objects })
}
