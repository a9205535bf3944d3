//! aorender: ambient occlusion on the GPU (WGSL compute shaders through wgpu) over an
//! obvhs BVH, with a multi-threaded CPU reference renderer.
//!
//! A pixel's value is ρ/π ∫ V(x, ω) cos θ dω, averaged over the pixel's area: fully open
//! is the albedo ρ.
//!
//! ```no_run
//! use aorender::{render, RenderOptions, Scene};
//! let mut scene = Scene::default_scene();
//! scene.settings.spp = 16;
//! let out = render(&scene, &RenderOptions::default(), &mut |_| {}).unwrap();
//! out.film.write_image("aobench.png".as_ref()).unwrap();
//! println!("{} rays/s", out.stats.rays_per_second);
//! ```

pub mod accuracy;
pub mod args;
pub mod bench;
pub mod bvh;
pub mod camera;
pub mod checkpoint;
pub mod compare;
pub mod cpu;
pub mod error;
pub mod film;
pub mod geometry;
pub mod gpu;
pub mod memory;
pub mod probe;
pub mod render;
pub mod sampler;
pub mod sampling;
pub mod scene;
pub mod shaders;

pub use error::{Error, Result};
pub use film::Film;
pub use render::{Device, Progress, RenderOptions, RenderOutput, RenderStats, render};
pub use sampler::Sampler;
pub use sampling::Hemisphere;
pub use scene::Scene;
