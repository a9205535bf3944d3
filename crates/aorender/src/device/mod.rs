//! The two devices behind one interface: a GPU adapter (WGSL compute shaders through
//! wgpu) or the CPU reference. [`Device`] is an opened one; preparing a scene on it
//! ([`Prepared`]: BVH build and upload) and making a request's film on that ([`Passes`])
//! is all the rest of the engine asks of a device.
//!
//! ```text
//! open (DeviceKind, Device: adapter or CPU, film budget)
//!   → prepare (BvhOptions, Setup, Prepared: BVH build, upload, a request's film)
//!       → gpu (GpuTarget's passes, films over several targets) ─┐
//!       → cpu (the reference's image and probe films)         ─┴→ passes (the Passes trait)
//! ```

mod cpu;
mod gpu;
mod open;
mod passes;
mod prepare;

pub use open::{Device, DeviceKind, DeviceOpening, OpenedDevice, Ready};
pub(crate) use passes::Passes;
pub(crate) use prepare::{Built, Prepared};
pub use prepare::{BvhOptions, Setup};
