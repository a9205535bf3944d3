//! Regular files replaced atomically: written to a temporary file beside the target,
//! synced, then renamed over it, so that a reader sees the old file or the whole new one,
//! never a part. A process about to exit in the middle of a write can remove its
//! temporary files.

use crate::error::{Error, Result};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Temporary files being written by [`replace_atomically`], for
/// [`remove_temporary_files`].
static TEMPORARY_FILES: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Streams `write`'s output to a temporary file in `file`'s directory (buffered), syncs
/// it, then renames it over `file`; errors name `path`, the output as the user gave it
/// (`file` is where it leads). On failure the temporary file is removed and `file` is
/// left as it was.
pub(super) fn replace_atomically(
    path: &Path,
    file: &Path,
    write: &mut dyn FnMut(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    let err = |m: String| Error::output(path, m);
    let dir = match file.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = file.file_name().ok_or_else(|| err("not a file path".into()))?.to_string_lossy();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    lock_temporary_files().push(tmp.clone());
    let result = (|| -> std::io::Result<()> {
        let mut f = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp)?);
        write(&mut f)?;
        let f = f.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        std::fs::rename(&tmp, file)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    lock_temporary_files().retain(|p| p != &tmp);
    result.map_err(|e| err(e.to_string()))
}

fn lock_temporary_files() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    // The list stays valid whatever a panicking writer left: recover it.
    TEMPORARY_FILES.lock().unwrap_or_else(|e| e.into_inner())
}

/// Removes the temporary files of writes still in progress (for a process about to exit
/// in the middle of one); returns how many were removed. Their targets are untouched.
pub fn remove_temporary_files() -> usize {
    let files = std::mem::take(&mut *lock_temporary_files());
    files.iter().filter(|p| std::fs::remove_file(p).is_ok()).count()
}
