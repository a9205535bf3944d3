//! What a render leaves on disk: images of its film, checkpoint files of its
//! accumulation, all written atomically.

mod atomic;
mod checkpoint;
mod image;

pub use atomic::{remove_temporary_files, write_atomically, write_atomically_with};
pub use checkpoint::{MAGIC, VERSION};
pub use image::{
    FLOAT_IMAGE_EXTENSIONS, IMAGE_EXTENSIONS, encode, linear_to_srgb, linear_to_srgb8, write_error_image, write_image,
};
