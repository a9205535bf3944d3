//! Typed errors of the library. Each displays as one line naming the file or the limit.

use std::path::PathBuf;

/// Everything the library can fail with.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file, mesh file or scene description is unreadable or invalid.
    #[error("{}: {message}", path.display())]
    Scene {
        /// The file at fault (the scene file, or the mesh it names).
        path: PathBuf,
        /// What is wrong, in one line.
        message: String,
    },
    /// No usable adapter, or the device failed.
    #[error("{0}")]
    Gpu(String),
    /// The adapter's device was lost (a driver reset, a removed GPU, or `destroy`):
    /// nothing more can be rendered on it.
    #[error("device lost on the adapter {adapter}: {message}")]
    DeviceLost {
        /// The adapter's name.
        adapter: String,
        /// What the driver said, in one line.
        message: String,
    },
    /// The adapter ran out of memory for a buffer or a submission.
    #[error("out of memory on the adapter {adapter}: {message}")]
    OutOfMemory {
        /// The adapter's name.
        adapter: String,
        /// What the driver said, in one line.
        message: String,
    },
    /// The scene needs more than the adapter allows.
    #[error("{what} needs {needed} bytes but the adapter's {limit_name} is {limit} bytes")]
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes the scene needs.
        needed: u64,
        /// The adapter's limit.
        limit: u64,
        /// The wgpu limit's name.
        limit_name: &'static str,
    },
    /// A shader invocation hit its traversal budget; its result would have been wrong.
    #[error(
        "{count} rays exceeded the per-invocation traversal budget of {budget} steps \
         (lavapipe silently stops a shader after 65,535 loop iterations); the pass was discarded"
    )]
    TraversalBudget {
        /// Rays that ran out of budget in the failed pass.
        count: u64,
        /// The budget in loop iterations.
        budget: u32,
    },
    /// An output file could not be written.
    #[error("{}: {message}", path.display())]
    Output {
        /// The output path.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl Error {
    /// Shorthand for [`Error::Scene`].
    pub fn scene(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        Error::Scene { path: path.into(), message: message.to_string() }
    }
}

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
