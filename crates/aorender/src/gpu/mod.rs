//! The wgpu side: an adapter and its device, the loop budget lavapipe imposes, the table
//! of what Rust and WGSL share, the shader composer, the pipelines (and the opened adapter
//! that holds them), the session's geometry on the device and the targets that run passes.
//!
//! ```text
//! context (adapter, device, queue; faults)  ─┐
//! layout (shared constants, structs, bindings) → shaders (composition) → pipeline (cache; GpuDevice)
//! upload (GpuScene: nodes, primitives, planes) ─┴→ target (GpuTarget: film, passes)
//! ```

pub mod budget;
pub mod compact;
pub mod context;
pub mod fault;
pub mod layout;
pub mod pipeline;
pub mod shaders;
pub mod stats;
pub mod target;
pub mod upload;

pub use context::{AdapterInfo, list_adapters};
pub use fault::catching_panics;
pub use layout::{FrameUniforms, GpuProbePoint, MAX_PASS_SAMPLES};
pub use pipeline::GpuDevice;
pub use shaders::{GeometryStorage, Traversal};
pub use target::GpuTarget;
pub use upload::GpuScene;
