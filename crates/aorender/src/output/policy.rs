//! The output policy ([the module docs](crate::output)): what a path may be written as,
//! and which paths one command may not write.

use crate::error::{Error, Result};
use std::fs::Metadata;
use std::io::Write;
use std::path::{Component, Path, PathBuf};

/// Symbolic links followed in a chain before giving up, as Linux's `MAXSYMLINKS`.
const MAX_LINKS: usize = 40;

/// How an output path is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Destination {
    /// A regular file, existing or not: written to a temporary file in its directory,
    /// synced, and renamed over it. The path is the file a symbolic link leads to (or the
    /// path itself), so that a link stays a link.
    Replace(PathBuf),
    /// A FIFO or a character device: opened for writing and written into.
    Stream(PathBuf),
}

impl Destination {
    /// The path written: the file a symbolic link leads to, or the path itself.
    pub fn path(&self) -> &Path {
        match self {
            Destination::Replace(p) | Destination::Stream(p) => p,
        }
    }
}

/// What a path leads to once symbolic links are followed.
struct Resolved {
    /// The file the path names, links followed; canonical where its directory exists.
    path: PathBuf,
    /// Its metadata (links followed), `None` when it does not exist.
    meta: Option<Metadata>,
    /// Whether a symbolic link was followed.
    via_link: bool,
    /// Whether the directory it would be made in exists.
    directory_exists: bool,
}

/// Follows `path` through its symbolic links to the file it names.
fn resolve(path: &Path) -> std::io::Result<Resolved> {
    let via_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    // An existing file is found by the kernel, which also follows /proc's links to
    // pipes and sockets (`/dev/stdout`), links that name no path.
    match std::fs::metadata(path) {
        Ok(m) => {
            let path = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
            return Ok(Resolved { path, meta: Some(m), via_link, directory_exists: true });
        }
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        Err(_) => {}
    }
    // A link to a file still to be made: followed link by link.
    let mut p = std::path::absolute(path)?;
    for _ in 0..=MAX_LINKS {
        match std::fs::symlink_metadata(&p) {
            Ok(m) if m.file_type().is_symlink() => {
                let target = std::fs::read_link(&p)?;
                // A relative target is relative to the link's own directory.
                p = p.parent().map_or_else(|| target.clone(), |dir| dir.join(&target));
            }
            Ok(m) => {
                let path = p.canonicalize().unwrap_or(p);
                return Ok(Resolved { path, meta: Some(m), via_link, directory_exists: true });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let (path, directory_exists) = resolve_missing(&p);
                return Ok(Resolved { path, meta: None, via_link, directory_exists });
            }
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::other("too many levels of symbolic links"))
}

/// The canonical form of a path that does not exist: its directory made canonical and
/// its name appended; and whether that directory exists. Under a directory that does not
/// exist, the nearest existing ancestor is made canonical and the rest appended.
fn resolve_missing(p: &Path) -> (PathBuf, bool) {
    if let (Some(dir), Some(name)) = (p.parent(), p.file_name())
        && let Ok(canonical) = dir.canonicalize()
    {
        let exists = canonical.is_dir();
        return (canonical.join(name), exists);
    }
    let p = normalise(p);
    let mut rest = Vec::new();
    let mut dir = p.clone();
    while let Some(name) = dir.file_name().map(|n| n.to_os_string()) {
        dir.pop();
        rest.push(name);
        if let Ok(canonical) = dir.canonicalize() {
            return (rest.iter().rev().fold(canonical, |p, n| p.join(n)), false);
        }
    }
    (p, false)
}

/// `path` with `.` and `dir/..` removed, without the file system (for paths under a
/// directory that does not exist yet).
pub(crate) fn normalise(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if matches!(out.components().next_back(), Some(Component::Normal(_))) => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// The kind of an existing file, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Regular,
    Directory,
    Fifo,
    CharDevice,
    BlockDevice,
    Socket,
    Other,
}

impl Kind {
    fn of(meta: &Metadata) -> Kind {
        let t = meta.file_type();
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if t.is_fifo() {
                return Kind::Fifo;
            }
            if t.is_char_device() {
                return Kind::CharDevice;
            }
            if t.is_block_device() {
                return Kind::BlockDevice;
            }
            if t.is_socket() {
                return Kind::Socket;
            }
        }
        if t.is_file() {
            Kind::Regular
        } else if t.is_dir() {
            Kind::Directory
        } else {
            Kind::Other
        }
    }

    fn name(self) -> &'static str {
        match self {
            Kind::Regular => "a regular file",
            Kind::Directory => "a directory",
            Kind::Fifo => "a FIFO",
            Kind::CharDevice => "a character device",
            Kind::BlockDevice => "a block device",
            Kind::Socket => "a socket",
            Kind::Other => "neither a file nor a device",
        }
    }
}

/// How `path` would be written, or why it cannot be: a directory, a block device, a
/// socket, a link that leads to one of those or into a directory that does not exist,
/// or a new file whose directory does not exist (unless `new_directories`: the writer
/// makes them).
fn classify(path: &Path, new_directories: bool) -> Result<(Destination, Resolved)> {
    let resolved = resolve(path).map_err(|e| Error::output(path, e))?;
    let leads = |what: &str| {
        if resolved.via_link {
            format!("is a symbolic link to {}, {what}", resolved.path.display())
        } else {
            format!("is {what}")
        }
    };
    let refuse = |kind: Kind| {
        let what = match kind {
            Kind::Directory => "a directory: name a file".to_string(),
            kind => format!("{}: outputs go to regular files, FIFOs or character devices", kind.name()),
        };
        Err(Error::output(path, leads(&what)))
    };
    let destination = match resolved.meta.as_ref().map(Kind::of) {
        Some(Kind::Regular) => Destination::Replace(resolved.path.clone()),
        Some(Kind::Fifo | Kind::CharDevice) => Destination::Stream(path.to_path_buf()),
        Some(kind) => return refuse(kind),
        None if resolved.directory_exists || new_directories => Destination::Replace(resolved.path.clone()),
        None => {
            let dir = if resolved.via_link { resolved.path.parent() } else { path.parent() };
            let dir = dir.filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
            return Err(Error::output(path, leads(&format!("in a directory that does not exist ({})", dir.display()))));
        }
    };
    Ok((destination, resolved))
}

/// How `path` is written under the output policy ([`crate::output`]), or an
/// [`Error::Output`] naming it and why it is refused.
pub fn destination(path: &Path) -> Result<Destination> {
    classify(path, false).map(|(d, _)| d)
}

/// A file's identity: device and inode where it exists, else the path it resolves to.
#[derive(Clone, Debug, PartialEq, Eq)]
enum FileId {
    Inode(u64, u64),
    Path(PathBuf),
}

/// The identity of a resolved path; `None` for a character device (a sink, not a file).
fn identity(resolved: &Resolved) -> Option<FileId> {
    match &resolved.meta {
        Some(m) if Kind::of(m) == Kind::CharDevice => None,
        #[cfg(unix)]
        Some(m) => {
            use std::os::unix::fs::MetadataExt;
            Some(FileId::Inode(m.dev(), m.ino()))
        }
        _ => Some(FileId::Path(resolved.path.clone())),
    }
}

/// Whether `a` and `b` name the same file (same device and inode, or the same resolved
/// path when missing), by any spelling: hard links, symbolic links, `dir/../file`. A
/// character device is a sink, never the same file as anything.
pub fn same_file(a: &Path, b: &Path) -> bool {
    let id = |p: &Path| resolve(p).ok().and_then(|r| identity(&r));
    matches!((id(a), id(b)), (Some(x), Some(y)) if x == y)
}

/// One file of a [`FilePlan`].
#[derive(Debug)]
struct Planned {
    path: PathBuf,
    role: String,
    id: Option<FileId>,
    output: bool,
}

/// How [`FilePlan::output_with`] treats an output.
#[derive(Clone, Copy, Debug, Default)]
pub struct OutputRules<'a> {
    /// The one input this output may replace (a checkpoint continuing the one `--resume`
    /// read, a bake allowed to write over its input).
    pub replacing: Option<&'a Path>,
    /// The writer makes missing directories, so a file in one is allowed.
    pub new_directories: bool,
}

/// The files one command reads and writes, checked together before any work: no output
/// may be an input or another output (by identity: [`same_file`]), and every output must
/// be writable under the policy ([`crate::output`]). Each refusal is one
/// [`Error::Output`] naming the output's path and both roles, e.g. `tp.obj: --stats
/// would overwrite the input mesh`.
#[derive(Debug, Default)]
pub struct FilePlan {
    files: Vec<Planned>,
}

impl FilePlan {
    /// An empty plan.
    pub fn new() -> Self {
        Self::default()
    }

    /// Records a file the command reads, with its role in words ("the input mesh", "the
    /// --points file"). A file that cannot be resolved is recorded by its path (reading
    /// it will fail with its own message).
    pub fn input(&mut self, path: &Path, role: impl Into<String>) {
        let id = match resolve(path) {
            Ok(r) => identity(&r),
            Err(_) => Some(FileId::Path(normalise(&std::path::absolute(path).unwrap_or_else(|_| path.into())))),
        };
        self.files.push(Planned { path: path.to_path_buf(), role: role.into(), id, output: false });
    }

    /// Records the files loading the scene `path` reads ([`crate::scene::input_files`]):
    /// the scene file or bare mesh, every mesh file a scene file names and every file a
    /// `.gltf` names.
    pub fn scene(&mut self, path: &Path) {
        for (file, role) in crate::scene::input_files(path) {
            self.input(&file, role);
        }
    }

    /// Checks and records an output with its role (the option that names it, `-o`,
    /// `--stats`, or a phrase such as "the AO map beside -o"): it must be writable under
    /// the policy and be neither an input nor an earlier output. Returns how it will be
    /// written.
    pub fn output(&mut self, path: &Path, role: &str) -> Result<Destination> {
        self.output_with(path, role, OutputRules::default())
    }

    /// [`FilePlan::output`] with exceptions: `rules.replacing` names the one input it may
    /// be, `rules.new_directories` allows a file in directories still to be made.
    pub fn output_with(&mut self, path: &Path, role: &str, rules: OutputRules<'_>) -> Result<Destination> {
        let (destination, resolved) = classify(path, rules.new_directories)?;
        let id = identity(&resolved);
        let allowed = rules.replacing.and_then(|p| resolve(p).ok()).and_then(|r| identity(&r));
        if let Some(id) = &id
            && let Some(other) = self.files.iter().find(|f| f.id.as_ref() == Some(id))
            && (other.output || allowed.as_ref() != Some(id))
        {
            let spelled = if other.path == path { String::new() } else { format!(" ({})", other.path.display()) };
            let message = if other.output {
                format!("{role} and {} name the same file{spelled}", other.role)
            } else {
                format!("{role} would overwrite {}{spelled}", other.role)
            };
            return Err(Error::output(path, message));
        }
        if let Destination::Replace(file) = &destination {
            check_writable(path, file)?;
        }
        self.files.push(Planned { path: path.to_path_buf(), role: role.to_string(), id, output: true });
        Ok(destination)
    }
}

/// Fails unless a temporary file can be made where `file` (what `path` resolves to) is
/// to be replaced: its directory, or the nearest one that exists when the writer makes
/// the rest.
fn check_writable(path: &Path, file: &Path) -> Result<()> {
    let mut dir = file.parent().unwrap_or(Path::new("/"));
    while !dir.exists() {
        dir = dir.parent().unwrap_or(Path::new("/"));
    }
    let name = file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let probe = dir.join(format!(".{name}.{}.probe", std::process::id()));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .map_err(|e| Error::output(path, format!("cannot write beside it: {e}")))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Writes `bytes` to `path` under the output policy: a regular file atomically, a FIFO or
/// character device by writing into it, anything else refused.
pub fn write_output(path: &Path, bytes: &[u8]) -> Result<()> {
    write_output_with(path, &mut |w| w.write_all(bytes))
}

/// Streams `write`'s output (buffered) to `path` under the output policy: a regular file
/// (or where a symbolic link leads) is written to a temporary file beside it, synced and
/// renamed over it, so that a reader sees the old file or the whole new one and a
/// failure leaves it as it was; a FIFO or a character device is opened and written into.
pub fn write_output_with(path: &Path, write: &mut dyn FnMut(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    match destination(path)? {
        Destination::Replace(file) => super::atomic::replace_atomically(path, &file, write),
        Destination::Stream(device) => {
            let result = (|| -> std::io::Result<()> {
                let f = std::fs::OpenOptions::new().write(true).open(&device)?;
                let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
                write(&mut w)?;
                w.flush()
            })();
            result.map_err(|e| Error::output(path, e))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp() -> PathBuf {
        let dir = std::env::temp_dir().join(format!("aorender-policy-{}-{}", std::process::id(), rand_suffix()));
        std::fs::create_dir_all(&dir).unwrap();
        // Resolved paths are canonical.
        dir.canonicalize().unwrap()
    }

    fn rand_suffix() -> u64 {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        NEXT.fetch_add(1, Ordering::Relaxed)
    }

    #[test]
    fn every_spelling_of_an_input_is_refused() {
        let dir = temp();
        let mesh = dir.join("tp.obj");
        std::fs::write(&mesh, "v 0 0 0\n").unwrap();
        std::fs::create_dir(dir.join("sub")).unwrap();
        std::fs::hard_link(&mesh, dir.join("hard.obj")).unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink("tp.obj", dir.join("soft.obj")).unwrap();
        let mut spellings = vec![mesh.clone(), dir.join("sub/../tp.obj"), dir.join("./tp.obj"), dir.join("hard.obj")];
        if cfg!(unix) {
            spellings.push(dir.join("soft.obj"));
        }
        for spelling in spellings {
            let mut plan = FilePlan::new();
            plan.input(&mesh, "the input mesh");
            let e = plan.output(&spelling, "--stats").unwrap_err().to_string();
            assert!(e.starts_with(&format!("{}: --stats would overwrite the input mesh", spelling.display())), "{e}");
            assert_eq!(e.lines().count(), 1, "{e}");
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn outputs_clash_with_each_other_even_before_they_exist() {
        let dir = temp();
        let mut plan = FilePlan::new();
        assert_eq!(plan.output(&dir.join("x.pfm"), "-o").unwrap(), Destination::Replace(dir.join("x.pfm")));
        // While "sub" does not exist, "sub/.." names no directory at all.
        let e = plan.output(&dir.join("sub/../x.pfm"), "--error-image").unwrap_err().to_string();
        let expect = format!("is in a directory that does not exist ({})", dir.join("sub/..").display());
        assert!(e.ends_with(&expect), "{e}");
        std::fs::create_dir(dir.join("sub")).unwrap();
        let e = plan.output(&dir.join("sub/../x.pfm"), "--error-image").unwrap_err().to_string();
        assert!(e.contains("--error-image and -o name the same file"), "{e}");
        assert!(plan.output(&dir.join("y.pfm"), "--error-image").is_ok());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn replacing_allows_only_the_named_input() {
        let dir = temp();
        let (resume, other) = (dir.join("a.ck"), dir.join("b.ck"));
        std::fs::write(&resume, "a").unwrap();
        std::fs::write(&other, "b").unwrap();
        let mut plan = FilePlan::new();
        plan.input(&resume, "the checkpoint --resume continues");
        plan.input(&other, "a checkpoint to merge");
        let rules = OutputRules { replacing: Some(&resume), ..Default::default() };
        assert!(plan.output_with(&dir.join("./a.ck"), "--checkpoint", rules).is_ok());
        let e = plan.output_with(&other, "-o", rules).unwrap_err().to_string();
        assert!(e.contains("-o would overwrite a checkpoint to merge"), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn directories_are_refused_and_missing_ones_allowed_only_when_made() {
        let dir = temp();
        let e = destination(&dir).unwrap_err().to_string();
        assert!(e.ends_with("is a directory: name a file"), "{e}");
        let deep = dir.join("a/b/c.ply");
        let e = destination(&deep).unwrap_err().to_string();
        assert!(e.contains("does not exist"), "{e}");
        let rules = OutputRules { new_directories: true, ..Default::default() };
        assert_eq!(FilePlan::new().output_with(&deep, "-o", rules).unwrap(), Destination::Replace(deep.clone()));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn links_are_followed_and_stay_links() {
        let dir = temp();
        let target = dir.join("target.json");
        std::fs::write(&target, "old").unwrap();
        std::os::unix::fs::symlink("target.json", dir.join("link.json")).unwrap();
        // A chain, and a link to a file still to be made.
        std::os::unix::fs::symlink("link.json", dir.join("chain.json")).unwrap();
        std::os::unix::fs::symlink("new.json", dir.join("dangling.json")).unwrap();
        write_output(&dir.join("chain.json"), b"new").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        write_output(&dir.join("dangling.json"), b"made").unwrap();
        assert_eq!(std::fs::read(dir.join("new.json")).unwrap(), b"made");
        for link in ["link.json", "chain.json", "dangling.json"] {
            assert!(std::fs::symlink_metadata(dir.join(link)).unwrap().file_type().is_symlink(), "{link}");
        }
        // Into a missing directory, to a directory, in a loop: refused.
        std::os::unix::fs::symlink("nowhere/x.json", dir.join("lost.json")).unwrap();
        std::os::unix::fs::symlink(".", dir.join("dir.json")).unwrap();
        std::os::unix::fs::symlink("loop.json", dir.join("loop.json")).unwrap();
        for (link, expect) in [
            ("lost.json", "does not exist"),
            ("dir.json", "is a symbolic link to"),
            ("loop.json", "Too many levels of symbolic links"),
        ] {
            let e = write_output(&dir.join(link), b"x").unwrap_err().to_string();
            assert!(e.contains(expect), "{link}: {e}");
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn a_fifo_is_written_into_not_replaced() {
        use std::os::unix::fs::FileTypeExt;
        let dir = temp();
        let fifo = dir.join("stats.fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        assert_eq!(destination(&fifo).unwrap(), Destination::Stream(fifo.clone()));
        write_output(&fifo, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[cfg(unix)]
    #[test]
    fn character_devices_are_sinks() {
        let null = Path::new("/dev/null");
        assert_eq!(destination(null).unwrap(), Destination::Stream(null.into()));
        let mut plan = FilePlan::new();
        plan.input(null, "the --points file");
        assert!(plan.output(null, "-o").is_ok());
        assert!(plan.output(null, "--stats").is_ok());
        write_output(null, b"discarded").unwrap();
        assert!(!same_file(null, null));
    }
}
