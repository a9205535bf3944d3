//! aorender: ambient occlusion on the GPU (WGSL compute shaders through wgpu) over an
//! obvhs BVH, with a multi-threaded CPU reference renderer that takes the same samples.
//!
//! A pixel's value is ρ/π ∫ V(x, ω) cos θ dω over the hemisphere at the surface point its
//! camera ray hits, averaged over the pixel's area: fully open is the albedo ρ. AO at a
//! given point and normal is the same integral with albedo 1.
//!
//! The data flows one way: a scene file is loaded into a [`Scene`]; a [`Session`] builds
//! its BVH once and uploads it to a [`Device`] (a GPU adapter, or the CPU reference); each
//! request — an image with any camera and sampling settings, or AO at probe points — is
//! then rendered in passes ([`Render`]) into an [`Accumulation`] of exact sums, which gives
//! the [`Film`], can be saved as a checkpoint and continued, and merges exactly with the
//! accumulations of other sample ranges.
//!
//! ```
//! use aorender::{BvhOptions, Control, Device, Hemisphere, Probe, Sampler, Scene, Session};
//! use glam::Vec3;
//!
//! # fn main() -> aorender::Result<()> {
//! // The expensive work, once: open the device, build the BVH, upload it.
//! let scene = Scene::default_scene();
//! let device = Device::cpu(); // or Device::gpu(None)? for the best adapter
//! let session = Session::new(&device, scene, &BvhOptions::default())?;
//!
//! // Many requests: the scene's own view, smaller, at 16 samples per pixel …
//! let mut request = session.default_request();
//! (request.settings.width, request.settings.height, request.settings.spp) = (64, 64, 16);
//! let out = session.render(&request)?.complete(&mut Control::default())?;
//! aorender::output::write_image(&out.film, &std::env::temp_dir().join("aobench.png"))?;
//! println!("{:.1} M rays/s, image mean {:.4}", out.stats.rays_per_second / 1e6, out.stats.image_mean);
//!
//! // … then uniform directions from a Sobol sequence, with a progress callback …
//! request.settings.sampling.hemisphere = Hemisphere::Uniform;
//! request.settings.sampling.sampler = Sampler::Sobol;
//! let mut on_progress = |p: &aorender::Progress| eprintln!("{}/{} spp", p.samples_done, p.samples_total);
//! let mut control = Control { progress: Some(&mut on_progress), ..Control::default() };
//! let sobol = session.render(&request)?.complete(&mut control)?;
//! assert_eq!(sobol.stats.samples_per_pixel, 16);
//!
//! // … and AO at a point on the floor, facing up: the same session, no rebuild.
//! let probe = Probe::new(Vec3::new(0.0, -0.5, -2.0), Vec3::Y)?;
//! let ao = session.probe(&[probe], 4096, &request.settings)?;
//! println!("AO {:.4} ± {:.4}", ao.values[0].mean, ao.values[0].std_error);
//! assert!(ao.values[0].mean > 0.0 && ao.values[0].mean < 1.0);
//! # Ok(())
//! # }
//! ```

// The internal modules: private, but public to the crate's own tests and measurement
// programs when the `testing` feature is on (they are not part of the API).
#[cfg(feature = "testing")]
pub mod accumulation;
#[cfg(not(feature = "testing"))]
mod accumulation;
#[cfg(feature = "testing")]
pub mod bvh;
#[cfg(not(feature = "testing"))]
mod bvh;
#[cfg(feature = "testing")]
pub mod cpu;
#[cfg(not(feature = "testing"))]
mod cpu;
#[cfg(feature = "testing")]
pub mod device;
#[cfg(not(feature = "testing"))]
mod device;
#[cfg(feature = "testing")]
pub mod film;
#[cfg(not(feature = "testing"))]
mod film;
mod footprint;
#[cfg(feature = "testing")]
pub mod geometry;
#[cfg(not(feature = "testing"))]
mod geometry;
#[cfg(feature = "testing")]
pub mod gpu;
#[cfg(not(feature = "testing"))]
mod gpu;
#[cfg(feature = "testing")]
pub mod kinds;
#[cfg(not(feature = "testing"))]
mod kinds;
#[cfg(feature = "testing")]
pub mod mirror;
#[cfg(not(feature = "testing"))]
mod mirror;
#[cfg(feature = "testing")]
pub mod phase;
#[cfg(feature = "testing")]
pub mod probe;
#[cfg(not(feature = "testing"))]
mod probe;
#[cfg(feature = "testing")]
pub mod render;
#[cfg(not(feature = "testing"))]
mod render;
#[cfg(feature = "testing")]
pub mod sampler;
#[cfg(not(feature = "testing"))]
mod sampler;
#[cfg(feature = "testing")]
pub mod sampling;
#[cfg(not(feature = "testing"))]
mod sampling;
#[cfg(feature = "testing")]
pub mod session;
#[cfg(not(feature = "testing"))]
mod session;
#[cfg(feature = "testing")]
pub mod surface;
#[cfg(not(feature = "testing"))]
mod surface;

pub mod bake;
pub mod closed_form;
pub mod error;
pub mod host_memory;
pub mod output;
pub mod scene;
pub mod sky;

pub use accumulation::{Accumulation, ErrorTarget, FilmLayout, Merged, MergedShard, SampleSettings, merge, scene_hash};
pub use device::{BvhOptions, Device, DeviceKind, DeviceOpening, OpenedDevice, Ready, Setup};
pub use error::{Error, Result};
pub use film::{BLOCK_SAMPLES, ErrorEstimator, Film, SampleRange, interval_95, t_quantile_975};
pub use footprint::background_pixels;
pub use gpu::{AdapterInfo, GeometryStorage, Traversal, catching_panics, list_adapters};
pub use kinds::{BuildQuality, BvhLayout};
pub use probe::{Probe, ProbeValue, probe_film_bent_normals, probe_film_values};
pub use render::{
    Control, EndedBy, PassSizing, PassTimes, Progress, Render, RenderOutput, RenderStats, ReplicateCosts, RunEnd,
    SaveFn, peak_rss_bytes, replicate_by_expected_cost,
};
pub use sampler::Sampler;
pub use sampling::Hemisphere;
pub use scene::{Camera, LoadOptions, Projection, ReadLimits, Sampling, Scene, Settings};
pub use session::{ImageRequest, ProbeOutput, Session};
pub use sky::{Sky, SkyModel, SkyNormalise, SkySampling};
pub use surface::{Located, RELATIVE_TOLERANCE, SurfaceTolerance};
