//! Typed errors of the library. Each displays as one line naming the file, the setting or
//! the limit at fault.

use std::path::PathBuf;

/// Everything the library can fail with.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A scene file, mesh file or scene description is unreadable or invalid.
    #[error("{}: {message}", path.display())]
    Scene {
        /// The file at fault (the scene file, or the mesh it names), or the scene's name.
        path: PathBuf,
        /// What is wrong, in one line.
        message: String,
    },
    /// A setting of a request is out of range (image size, samples, distance, sample
    /// range, a camera that is not well defined).
    #[error("invalid settings: {message}")]
    Settings {
        /// What is wrong, in one line.
        message: String,
    },
    /// A probe point that cannot be evaluated (non-finite, or a zero normal).
    #[error("probe {index}: {message}")]
    Probe {
        /// The point's index, from 0.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// A checkpoint that cannot be read, or that does not fit the render asked to
    /// continue it.
    #[error("{}: {message}", path.display())]
    Checkpoint {
        /// The checkpoint file (or what names the accumulation, for one made in memory).
        path: PathBuf,
        /// What is wrong with it.
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
    /// A request whose film would take more host memory than the film budget
    /// (`host_memory::film_budget`): refused before any of it is made.
    #[error("{}: {what} needs {needed} bytes of host memory, past the film budget of {budget} bytes ({basis})", path.display())]
    FilmBudget {
        /// The scene's file (or its name).
        path: PathBuf,
        /// The film, in words ("a 16384x16384 image").
        what: String,
        /// Bytes it needs at its peak.
        needed: u64,
        /// Bytes the budget allows.
        budget: u64,
        /// How the budget was set.
        basis: String,
    },
    /// A shader invocation hit its traversal budget; its result would have been wrong.
    #[error(
        "{}: {count} rays exceeded the per-invocation traversal budget of {budget} steps \
         (lavapipe silently stops a shader after 65,535 loop iterations); the pass was discarded; \
         the CPU reference (`--device cpu`) has no such limit",
        path.display()
    )]
    TraversalBudget {
        /// The scene's file (or its name).
        path: PathBuf,
        /// Rays that ran out of budget in the failed pass.
        count: u64,
        /// The budget in loop iterations.
        budget: u32,
    },
    /// The shader sources could not be put together (a file missing from
    /// `AORENDER_SHADER_DIR`, or an import that names no file).
    #[error("{0}")]
    Shader(String),
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

    /// Shorthand for [`Error::Settings`].
    pub fn settings(message: impl std::fmt::Display) -> Self {
        Error::Settings { message: message.to_string() }
    }

    /// Shorthand for [`Error::Checkpoint`].
    pub fn checkpoint(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        Error::Checkpoint { path: path.into(), message: message.to_string() }
    }

    /// Shorthand for [`Error::Output`].
    pub fn output(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> Self {
        Error::Output { path: path.into(), message: message.to_string() }
    }

    /// The message without the file or setting it names (for errors that are re-attached
    /// to another file, such as a camera's fault reported against its scene file).
    pub fn message(&self) -> String {
        match self {
            Error::Scene { message, .. }
            | Error::Settings { message }
            | Error::Probe { message, .. }
            | Error::Checkpoint { message, .. }
            | Error::Output { message, .. } => message.clone(),
            other => other.to_string(),
        }
    }
}

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
