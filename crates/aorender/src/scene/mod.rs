//! Scene files and mesh formats → one in-memory [`Scene`]: primitives as the scene file
//! states them (triangles, exact spheres, infinite planes, instanced meshes), a camera and
//! the render settings. The loaders keep only what ambient occlusion needs (positions and
//! faces); what they skip is reported in [`Scene::warnings`].

mod camera;
mod file;
pub(crate) mod files;
mod frame;
pub(crate) mod gltf;
mod inflate;
pub(crate) mod input;
mod load;
pub(crate) mod mesh;
pub(crate) mod meshes;
pub(crate) mod obj;
pub(crate) mod ply;
pub(crate) mod ply_data;
mod types;

pub use crate::geometry::Plane;
pub use camera::{Camera, Projection, RayGen};
pub use file::{DEFAULT_SCENE, DEFAULT_SCENE_NAME};
pub use files::input_files;
pub use frame::LocalFrame;
pub(crate) use frame::round_up;
pub use input::{DEFAULT_LINE_BYTES, FIXED_READ_BUDGET, LoadOptions, READ_BUDGET_VARIABLE, ReadLimits, read_text};
pub(crate) use meshes::extension;
pub use meshes::mesh_triangles;
pub use types::{
    Bounds, Instance, InstancedMesh, MAX_IMAGE_SIDE, MAX_NORMAL_LENGTH_SQUARED, MIN_NORMAL_LENGTH_SQUARED, MeshObject,
    Sampling, Scene, Settings, Sphere, Triangle, Warning, place_point,
};

#[cfg(feature = "testing")]
pub use input::times_opened;
#[cfg(feature = "testing")]
pub use meshes::load_mesh;
#[cfg(feature = "testing")]
pub use obj::read_obj_triangles;
#[cfg(feature = "testing")]
pub use ply::read_ply_mesh;
