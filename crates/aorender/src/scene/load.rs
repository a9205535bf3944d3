//! Loading a scene: a scene file (`.toml`), a bare mesh framed automatically, or the
//! built-in aobench scene.

use super::camera::{Camera, Projection};
use super::file::{DEFAULT_SCENE, DEFAULT_SCENE_NAME, parse_scene};
use super::input::{self, LoadOptions, Meter};
use super::meshes::{MESH_EXTENSIONS, MESH_FORMATS, MeshReader, extension, place_mesh, read_mesh, stem};
use super::types::{MeshObject, Scene, Settings, Triangle, Warning};
use crate::error::{Error, Result};
use glam::{DVec3, Vec3};
use std::path::Path;

/// Bytes of memory a scene file's text may take per byte, with its parsed form (the TOML
/// parser's tables and the objects made of them).
const SCENE_TEXT_BYTES_PER_BYTE: u64 = 16;

impl Scene {
    /// Loads a scene file (`.toml`) or a bare mesh (`.obj`, `.ply`, `.gltf`, `.glb`, each
    /// also gzipped as `.gz`), framed automatically, within the read budget of
    /// [`LoadOptions::from_env`]. What the loaders skipped is in [`Scene::warnings`].
    pub fn load(path: &Path) -> Result<Scene> {
        Scene::load_with(path, &LoadOptions::from_env()?)
    }

    /// [`Scene::load`] with the read budget and URI policy of `options`. The scene and
    /// everything its meshes' readers hold at once must fit in the budget.
    pub fn load_with(path: &Path, options: &LoadOptions) -> Result<Scene> {
        Scene::load_reading(path, options, None)
    }

    /// [`Scene::load_with`], every mesh file read by `reader` when there is one.
    pub(crate) fn load_reading(path: &Path, options: &LoadOptions, reader: Option<&mut MeshReader>) -> Result<Scene> {
        #[cfg(feature = "testing")]
        crate::phase::enter("load");
        match extension(path).as_str() {
            "toml" if input::is_gzip(path) => Err(Error::scene(path, "a scene file cannot be gzipped")),
            "toml" => {
                let text = input::read_text(path, &options.limits, SCENE_TEXT_BYTES_PER_BYTE, "the scene")?;
                let mut meter = Meter::new(&options.limits, "the scene");
                meter.charge(path, text.len() as u64 * SCENE_TEXT_BYTES_PER_BYTE)?;
                parse_scene(&text, path, path.parent().unwrap_or(Path::new(".")), options, &mut meter, reader)
            }
            ext if MESH_EXTENSIONS.contains(&ext) => Scene::from_mesh_file_reading(path, options, reader),
            "" => Err(Error::scene(path, format!("no file extension: expected .toml or {MESH_FORMATS}"))),
            ext => Err(Error::scene(path, format!("unsupported file type '.{ext}': expected .toml or {MESH_FORMATS}"))),
        }
    }

    /// The built-in default scene (`scenes/aobench.toml`).
    pub fn default_scene() -> Scene {
        let options = LoadOptions { limits: input::ReadLimits::with_memory(u64::MAX), allow_external_uris: false };
        let mut meter = Meter::new(&options.limits, "the scene");
        let scene =
            parse_scene(DEFAULT_SCENE, Path::new(DEFAULT_SCENE_NAME), Path::new("."), &options, &mut meter, None);
        Scene { path: None, ..scene.expect("the built-in scene is valid") }
    }

    /// Parses a scene from TOML text; mesh paths resolve against `base_dir`, and are read
    /// within the read budget of [`LoadOptions::from_env`].
    pub fn from_toml_str(text: &str, path: &Path, base_dir: &Path) -> Result<Scene> {
        let options = LoadOptions::from_env()?;
        let mut meter = Meter::new(&options.limits, "the scene");
        parse_scene(text, path, base_dir, &options, &mut meter, None)
    }

    /// A bare mesh, albedo 1, looked at from eye = centre + normalize(0.6, 0.45, 1.0) ×
    /// 1.2 × diagonal with up +Y and a 45° vertical field of view; no distance limit. Read
    /// within the read budget of [`LoadOptions::from_env`].
    pub fn from_mesh_file(path: &Path) -> Result<Scene> {
        Scene::from_mesh_file_with(path, &LoadOptions::from_env()?)
    }

    /// [`Scene::from_mesh_file`] with the read budget and URI policy of `options`.
    pub fn from_mesh_file_with(path: &Path, options: &LoadOptions) -> Result<Scene> {
        Scene::from_mesh_file_reading(path, options, None)
    }

    /// [`Scene::from_mesh_file_with`], the mesh read by `reader` when there is one.
    fn from_mesh_file_reading(path: &Path, options: &LoadOptions, reader: Option<&mut MeshReader>) -> Result<Scene> {
        let mut meter = Meter::new(&options.limits, "the mesh");
        let mut mesh = read_mesh(path, options, &mut meter, reader)?;
        let positions = std::mem::take(&mut mesh.positions);
        let triangles = place_mesh(path, positions, &mesh, 1.0, &glam::Mat4::IDENTITY, &mut meter)?;
        let warnings = mesh.warnings.into_iter().map(|message| Warning { path: path.to_path_buf(), message });
        let mut scene = Scene {
            path: Some(path.to_path_buf()),
            warnings: warnings.collect(),
            mesh_objects: vec![MeshObject {
                number: 1,
                path: path.to_path_buf(),
                to_world: glam::Mat4::IDENTITY,
                instance: None,
                allow_external_uris: options.allow_external_uris,
            }],
            // The loader's positions are relative to the mesh's origin: the scene keeps them so.
            origin: mesh.origin,
            ..Scene::from_triangles(&stem(path), triangles)
        };
        scene.camera = scene.auto_camera();
        Ok(scene)
    }

    /// A scene of `triangles` alone (from [`super::mesh_triangles`], say), framed as a
    /// bare mesh is ([`Scene::auto_camera`]), with the default settings.
    pub fn from_triangles(name: &str, triangles: Vec<Triangle>) -> Scene {
        let mut scene = Scene {
            name: name.into(),
            path: None,
            camera: Camera {
                eye: DVec3::ZERO,
                look_at: DVec3::NEG_Z,
                up: Vec3::Y,
                projection: Projection::Perspective { vfov_deg: 45.0 },
            },
            origin: DVec3::ZERO,
            settings: Settings::default(),
            triangles,
            meshes: Vec::new(),
            instances: Vec::new(),
            spheres: Vec::new(),
            planes: Vec::new(),
            warnings: Vec::new(),
            mesh_objects: Vec::new(),
        };
        scene.camera = scene.auto_camera();
        scene
    }
}
