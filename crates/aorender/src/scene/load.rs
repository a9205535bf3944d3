//! Loading a scene: a scene file (`.toml`), a bare mesh framed automatically, or the
//! built-in aobench scene.

use super::camera::{Camera, Projection};
use super::file::{DEFAULT_SCENE, DEFAULT_SCENE_NAME, parse_scene};
use super::input;
use super::meshes::{MESH_EXTENSIONS, MESH_FORMATS, extension, place_mesh, read_mesh, stem};
use super::types::{MeshObject, Scene, Settings, Triangle, Warning};
use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

impl Scene {
    /// Loads a scene file (`.toml`) or a bare mesh (`.obj`, `.ply`, `.gltf`, `.glb`, each
    /// also gzipped as `.gz`), framed automatically. What the loaders skipped is in
    /// [`Scene::warnings`].
    pub fn load(path: &Path) -> Result<Scene> {
        #[cfg(feature = "testing")]
        crate::phase::enter("load");
        match extension(path).as_str() {
            "toml" if input::is_gzip(path) => Err(Error::scene(path, "a scene file cannot be gzipped")),
            "toml" => {
                let text = std::fs::read_to_string(path).map_err(|e| Error::scene(path, e))?;
                parse_scene(&text, path, path.parent().unwrap_or(Path::new(".")))
            }
            ext if MESH_EXTENSIONS.contains(&ext) => Scene::from_mesh_file(path),
            "" => Err(Error::scene(path, format!("no file extension: expected .toml or {MESH_FORMATS}"))),
            ext => Err(Error::scene(path, format!("unsupported file type '.{ext}': expected .toml or {MESH_FORMATS}"))),
        }
    }

    /// The built-in default scene (`scenes/aobench.toml`).
    pub fn default_scene() -> Scene {
        let scene = parse_scene(DEFAULT_SCENE, Path::new(DEFAULT_SCENE_NAME), Path::new("."));
        Scene { path: None, ..scene.expect("the built-in scene is valid") }
    }

    /// Parses a scene from TOML text; mesh paths resolve against `base_dir`.
    pub fn from_toml_str(text: &str, path: &Path, base_dir: &Path) -> Result<Scene> {
        parse_scene(text, path, base_dir)
    }

    /// A bare mesh, albedo 1, looked at from eye = centre + normalize(0.6, 0.45, 1.0) ×
    /// 1.2 × diagonal with up +Y and a 45° vertical field of view; no distance limit.
    pub fn from_mesh_file(path: &Path) -> Result<Scene> {
        let mut mesh = read_mesh(path)?;
        let positions = std::mem::take(&mut mesh.positions);
        let triangles = place_mesh(path, positions, &mesh, 1.0, &glam::Mat4::IDENTITY)?;
        let warnings = mesh.warnings.into_iter().map(|message| Warning { path: path.to_path_buf(), message });
        Ok(Scene {
            path: Some(path.to_path_buf()),
            warnings: warnings.collect(),
            mesh_objects: vec![MeshObject {
                number: 1,
                path: path.to_path_buf(),
                to_world: glam::Mat4::IDENTITY,
                instance: None,
            }],
            ..Scene::from_triangles(&stem(path), triangles)
        })
    }

    /// A scene of `triangles` alone (from [`super::mesh_triangles`], say), framed as a
    /// bare mesh is ([`Scene::auto_camera`]), with the default settings.
    pub fn from_triangles(name: &str, triangles: Vec<Triangle>) -> Scene {
        let mut scene = Scene {
            name: name.into(),
            path: None,
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
            warnings: Vec::new(),
            mesh_objects: Vec::new(),
        };
        scene.camera = scene.auto_camera();
        scene
    }
}
