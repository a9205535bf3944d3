//! What a render leaves on disk: images of its film, checkpoint files of its
//! accumulation, and the output policy that every file aorender writes follows. Every
//! write goes through [`write_output_with`]; a command gathers its inputs and outputs in
//! a [`FilePlan`] before any work, so that a clash is refused before anything is traced
//! or written.
//!
//! - A regular file (or a new one in an existing directory) is replaced atomically: a
//!   temporary file beside it, synced, renamed over it.
//! - A symbolic link is followed, through any chain of links: when it leads to a regular
//!   file, or to a file that does not exist yet in an existing directory, that file is
//!   replaced (or made) atomically and the link stays a link.
//! - A FIFO or a character device (`/dev/null`, `/dev/stdout`, a terminal) is opened and
//!   written into, never replaced.
//! - A directory, a block device or a socket is refused.
//! - No output is an input of its command or another of its outputs. Files are compared
//!   by identity: device and inode where the file exists, else the path it resolves to
//!   (links followed, `..` resolved by the file system), so hard links, symbolic links
//!   and other spellings of one file are caught. Character devices are sinks, not files:
//!   several outputs may go to `/dev/null`, and `/dev/stdin` and `/dev/stdout` on one
//!   terminal do not clash.

mod atomic;
mod blocks;
mod checkpoint;
pub mod gzip;
mod image;
mod policy;

pub use atomic::remove_temporary_files;
pub use blocks::write_rows;
pub use checkpoint::{MAGIC, VERSION};
pub use image::{
    FLOAT_IMAGE_EXTENSIONS, IMAGE_EXTENSIONS, encode, linear_to_srgb, linear_to_srgb8, write_error_image, write_image,
};
pub(crate) use policy::normalise;
pub use policy::{Destination, FilePlan, OutputRules, destination, same_file, write_output, write_output_with};
