//! The output policy on the command line: no command writes onto one of its inputs or
//! onto another of its outputs, by any spelling; FIFOs and character devices are written
//! into and symbolic links followed, never replaced; directories, block devices and
//! sockets are refused before any work; a closed or full standard output ends the
//! program without a panic. On the CPU reference, where the GPU adds nothing.

mod common;

use common::{aorender, repo, temp_dir};
use std::collections::BTreeMap;
use std::os::fd::{FromRawFd, OwnedFd};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

/// A small, fast render on the CPU reference.
const RENDER: &[&str] = &["--width", "32", "--height", "32", "--spp", "2", "--device", "cpu"];

/// The same for `compare`, whose --spp is a list.
const COMPARE: &[&str] = &["--width", "32", "--height", "32", "--spp", "1", "--device", "cpu"];

/// A unit square with texture coordinates, for texture bakes.
const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 0 -1\nv 0 0 -1\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 1 0\n\
                    f 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n";

/// What a directory holds, recursively: each entry's type and, for a regular file, its
/// bytes, for a link, its target (devices, FIFOs and sockets are not opened).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, String> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            let t = std::fs::symlink_metadata(&path).unwrap().file_type();
            let what = if t.is_symlink() {
                format!("link to {}", std::fs::read_link(&path).unwrap().display())
            } else if t.is_dir() {
                stack.push(path.clone());
                "directory".into()
            } else if t.is_file() {
                format!("file {:?}", blake3::hash(&std::fs::read(&path).unwrap()))
            } else {
                format!("{t:?}")
            };
            out.insert(path.strip_prefix(dir).unwrap().to_path_buf(), what);
        }
    }
    out
}

/// The repository's teapot as `tp.obj`, the quad as `q.obj`, and `s.toml`, a scene that
/// places `m/tp.obj`, in a new directory.
fn workspace() -> tempfile::TempDir {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::copy(repo().join("scenes/teapot.obj"), d.join("tp.obj")).unwrap();
    std::fs::write(d.join("q.obj"), QUAD).unwrap();
    std::fs::create_dir(d.join("m")).unwrap();
    std::fs::copy(repo().join("scenes/teapot.obj"), d.join("m/tp.obj")).unwrap();
    std::fs::write(
        d.join("s.toml"),
        "[camera]\ntype = \"perspective\"\neye = [0.0, 4.0, 8.0]\nlook_at = [0.0, 1.0, 0.0]\nfov = 45.0\n\
         [[object]]\ntype = \"mesh\"\nfile = \"m/tp.obj\"\n",
    )
    .unwrap();
    std::fs::write(d.join("pts.csv"), "0 0 0 0 1 0\n").unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    dir
}

/// Runs `aorender args` in `dir`, which must fail with exit status 1 and the one line
/// `aorender: expect`, leaving every file in `dir` as it was.
fn refused(dir: &Path, args: &[&str], expect: &str) {
    let before = snapshot(dir);
    let out = aorender(args, dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    assert_eq!(stderr, format!("aorender: {expect}\n"), "{args:?}");
    assert!(out.stdout.is_empty(), "{args:?}");
    assert_eq!(snapshot(dir), before, "{args:?} changed the directory");
}

/// Runs `aorender args` in `dir`; it must succeed. Returns its standard output.
fn succeeds(dir: &Path, args: &[&str]) -> String {
    let out = aorender(args, dir);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn args<'a>(command: &'a str, first: &[&'a str], rest: &[&'a str]) -> Vec<&'a str> {
    [&[command][..], first, rest].concat()
}

#[test]
fn no_output_onto_an_input_in_any_spelling() {
    let dir = workspace();
    let d = dir.path();
    std::fs::hard_link(d.join("tp.obj"), d.join("hard.obj")).unwrap();
    std::os::unix::fs::symlink("tp.obj", d.join("soft.obj")).unwrap();
    for (spelling, suffix) in
        [("tp.obj", ""), ("./sub/../tp.obj", " (tp.obj)"), ("hard.obj", " (tp.obj)"), ("soft.obj", " (tp.obj)")]
    {
        let expect = format!("{spelling}: --stats would overwrite the input mesh{suffix}");
        refused(d, &args("render", &["tp.obj", "-o", "r.png", "--stats", spelling], RENDER), &expect);
        let bake = ["tp.obj", "-o", "b.obj", "--device", "cpu", "--samples", "4", "--stats", spelling];
        refused(d, &args("bake", &bake, &[]), &expect);
        refused(d, &args("compare", &["tp.obj", "-o", "c.png", "--stats", spelling], COMPARE), &expect);
    }
    // The scene file, and a mesh it names, however spelled.
    refused(
        d,
        &args("render", &["s.toml", "-o", "r.png", "--stats", "s.toml"], RENDER),
        "s.toml: --stats would overwrite the scene file",
    );
    for (spelling, suffix) in [("m/tp.obj", ""), ("sub/../m/tp.obj", " (m/tp.obj)")] {
        let expect = format!("{spelling}: --stats would overwrite the mesh that s.toml names{suffix}");
        refused(d, &args("render", &["s.toml", "-o", "r.png", "--stats", spelling], RENDER), &expect);
        refused(d, &args("bake", &["s.toml", "-o", "out", "--device", "cpu", "--stats", spelling], &[]), &expect);
    }
    // The --points file, the checkpoints merge adds, the checkpoint --resume continues.
    refused(
        d,
        &args("probe", &["tp.obj", "--points", "pts.csv", "-o", "./pts.csv", "--device", "cpu"], &[]),
        "./pts.csv: -o would overwrite the --points file (pts.csv)",
    );
    std::fs::write(d.join("ck.pfm"), "not a checkpoint").unwrap();
    refused(d, &["merge", "ck.pfm", "-o", "ck.pfm"], "ck.pfm: -o would overwrite a checkpoint to merge");
    refused(
        d,
        &args("render", &["tp.obj", "--resume", "ck.pfm", "-o", "ck.pfm"], RENDER),
        "ck.pfm: -o would overwrite the checkpoint --resume continues",
    );
    let bake = ["q.obj", "-o", "b.obj", "--device", "cpu", "--merge", "ck.pfm", "--stats", "ck.pfm"];
    refused(d, &args("bake", &bake, &[]), "ck.pfm: --stats would overwrite a checkpoint --merge adds");
}

#[test]
fn a_checkpoint_continues_the_one_resume_reads_by_any_spelling() {
    let dir = workspace();
    let d = dir.path();
    let spp = ["--spp", "64", "--device", "cpu", "--width", "8", "--height", "8"];
    let stopped =
        aorender(&args("render", &["q.obj", "-o", "a.pfm", "--checkpoint", "a.ck", "--time-limit", "1e-9"], &spp), d);
    assert!(stopped.status.success(), "{}", String::from_utf8_lossy(&stopped.stderr));
    let first = std::fs::read(d.join("a.ck")).unwrap();
    // The checkpoint it keeps saving to is the one it read: not a clash.
    let stdout = succeeds(
        d,
        &args("render", &["q.obj", "-o", "b.pfm", "--resume", "a.ck", "--checkpoint", "./sub/../a.ck"], &spp),
    );
    assert!(stdout.contains("\"samples_per_pixel\": 64"), "{stdout}");
    assert_ne!(std::fs::read(d.join("a.ck")).unwrap(), first, "the continued checkpoint was saved");
    assert!(kind(&d.join("a.ck")).is_file());
}

#[test]
fn outputs_of_one_command_never_share_a_file() {
    let dir = workspace();
    let d = dir.path();
    refused(
        d,
        &args("render", &["tp.obj", "-o", "x.pfm", "--error-image", "./x.pfm"], RENDER),
        "./x.pfm: --error-image and -o name the same file (x.pfm)",
    );
    refused(
        d,
        &args("render", &["tp.obj", "-o", "x.png", "--checkpoint", "x.png"], RENDER),
        "x.png: --checkpoint and -o name the same file",
    );
    refused(
        d,
        &args("render", &["tp.obj", "-o", "x.png", "--stats", "x.png"], RENDER),
        "x.png: --stats and -o name the same file",
    );
    refused(d, &["merge", "a.ck", "-o", "x.png", "--stats", "x.png"], "x.png: --stats and -o name the same file");
    // A texture bake's maps beside the mesh, or beside the map.
    let tex = ["--device", "cpu", "--texture", "16", "--samples", "4"];
    refused(
        d,
        &args("bake", &["q.obj", "-o", "b.obj", "--stats", "b_ao.png"], &tex),
        "b_ao.png: the AO map beside -o and --stats name the same file",
    );
    refused(
        d,
        &args("bake", &["q.obj", "-o", "m.png", "--bent-normals", "--checkpoint", "m_bent_normals.png"], &tex),
        "m_bent_normals.png: --checkpoint and the bent normals map beside -o name the same file",
    );
    // A scene's outputs: each other's, and the statistics'.
    std::fs::create_dir_all(d.join("a")).unwrap();
    std::fs::create_dir_all(d.join("b")).unwrap();
    std::fs::write(d.join("a/x.obj"), QUAD).unwrap();
    std::fs::write(d.join("b/x.obj"), QUAD).unwrap();
    std::fs::write(
        d.join("two.toml"),
        "[camera]\ntype = \"perspective\"\neye = [0.0, 4.0, 8.0]\nlook_at = [0.0, 1.0, 0.0]\nfov = 45.0\n\
         [[object]]\ntype = \"mesh\"\nfile = \"a/x.obj\"\n[[object]]\ntype = \"mesh\"\nfile = \"b/x.obj\"\n",
    )
    .unwrap();
    refused(
        d,
        &["bake", "two.toml", "-o", "out", "--device", "cpu"],
        "out/x.obj: the bake of object 2 (-o) and the bake of object 1 (-o) name the same file",
    );
    std::fs::create_dir(d.join("out")).unwrap();
    refused(
        d,
        &["bake", "s.toml", "-o", "out", "--device", "cpu", "--stats", "out/tp.obj"],
        "out/tp.obj: the bake of object 1 (-o) and --stats name the same file",
    );
}

/// Makes a device node `c major minor` (or `b`) at `path`; false where not permitted.
fn mknod(path: &Path, block: bool, major: u32, minor: u32) -> bool {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    let kind = if block { libc::S_IFBLK } else { libc::S_IFCHR };
    unsafe { libc::mknod(c.as_ptr(), kind | 0o666, libc::makedev(major, minor)) == 0 }
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo {}", path.display());
}

/// A thread that reads the FIFO `path` to its end.
fn read_fifo(path: &Path) -> std::thread::JoinHandle<Vec<u8>> {
    let path = path.to_path_buf();
    std::thread::spawn(move || std::fs::read(path).unwrap())
}

/// Ends the wait of a reader of the FIFO `path` that no writer opened (a command that
/// failed), so that its test fails on what was read instead of hanging.
fn release(path: &Path) {
    use std::os::unix::fs::OpenOptionsExt;
    let _ = std::fs::OpenOptions::new().write(true).custom_flags(libc::O_NONBLOCK).open(path);
}

/// Runs `aorender args` in `dir`, then releases the FIFOs `fifos`; it must succeed.
fn succeeds_into(dir: &Path, args: &[&str], fifos: &[&str]) -> String {
    let out = aorender(args, dir);
    for f in fifos {
        release(&dir.join(f));
    }
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn kind(path: &Path) -> std::fs::FileType {
    std::fs::symlink_metadata(path).unwrap().file_type()
}

/// Every file in `dir` whose name marks a temporary or probe file of a write.
fn leftovers(dir: &Path) -> Vec<PathBuf> {
    snapshot(dir)
        .into_keys()
        .filter(|p| p.to_string_lossy().ends_with(".tmp") || p.to_string_lossy().ends_with(".probe"))
        .collect()
}

#[test]
fn character_devices_are_written_into() {
    let dir = workspace();
    let d = dir.path();
    // `/dev/null` made here (root, as in CI), else the system's through a link: written
    // into either way, never replaced.
    let null = d.join("null.pfm");
    if !mknod(&null, false, 1, 3) {
        eprintln!("mknod is not permitted here: testing with the system's /dev/null, opened for writing only");
        std::os::unix::fs::symlink("/dev/null", &null).unwrap();
    }
    // Several outputs into one sink: the image, the error image, the statistics.
    let stdout = succeeds(
        d,
        &args("render", &["tp.obj", "-o", "null.pfm", "--error-image", "null.pfm", "--stats", "null.pfm"], RENDER),
    );
    assert!(stdout.contains("\"samples_per_pixel\": 2"), "{stdout}");
    assert!(std::fs::metadata(&null).unwrap().file_type().is_char_device());
    assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
    // /dev/stdout is where the CSV goes, whatever its name.
    let csv = succeeds(
        d,
        &["probe", "q.obj", "--points", "pts.csv", "-o", "/dev/stdout", "--samples", "4", "--device", "cpu"],
    );
    assert!(csv.starts_with("x,y,z,nx,ny,nz,ao,std_error,samples\n0,0,0,0,1,0,1,"), "{csv}");
}

#[test]
fn fifos_are_written_into_by_every_command() {
    let dir = workspace();
    let d = dir.path();
    for name in ["image.pfm", "stats.json", "ao.csv", "baked.obj"] {
        mkfifo(&d.join(name));
    }
    let (image, stats) = (read_fifo(&d.join("image.pfm")), read_fifo(&d.join("stats.json")));
    let render = args("render", &["tp.obj", "-o", "image.pfm", "--stats", "stats.json"], RENDER);
    let stdout = succeeds_into(d, &render, &["image.pfm", "stats.json"]);
    let image = image.join().unwrap();
    assert!(image.starts_with(b"Pf\n32 32\n-1.0\n") && image.len() == 14 + 32 * 32 * 4, "{} bytes", image.len());
    assert_eq!(String::from_utf8(stats.join().unwrap()).unwrap(), stdout, "the FIFO gets the statistics printed");
    let csv = read_fifo(&d.join("ao.csv"));
    succeeds_into(
        d,
        &["probe", "q.obj", "--points", "pts.csv", "-o", "ao.csv", "--samples", "4", "--device", "cpu"],
        &["ao.csv"],
    );
    let csv = String::from_utf8(csv.join().unwrap()).unwrap();
    assert!(csv.starts_with("x,y,z,nx,ny,nz,ao,std_error,samples\n"), "{csv}");
    let obj = read_fifo(&d.join("baked.obj"));
    succeeds_into(d, &["bake", "q.obj", "-o", "baked.obj", "--samples", "4", "--device", "cpu"], &["baked.obj"]);
    let obj = String::from_utf8(obj.join().unwrap()).unwrap();
    // Every vertex of the open quad is fully open: grey 1.
    assert_eq!(obj.lines().filter(|l| l.starts_with("v ") && l.ends_with(" 1 1 1")).count(), 4, "{obj}");
    for name in ["image.pfm", "stats.json", "ao.csv", "baked.obj"] {
        assert!(kind(&d.join(name)).is_fifo(), "{name} is still a FIFO");
    }
    assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
}

#[test]
fn symbolic_links_are_followed_and_stay_links() {
    let dir = workspace();
    let d = dir.path();
    std::fs::write(d.join("sub/old.json"), "old").unwrap();
    std::fs::write(d.join("sub/old.png"), "old").unwrap();
    std::os::unix::fs::symlink("sub/old.json", d.join("stats.json")).unwrap();
    std::os::unix::fs::symlink("sub/old.png", d.join("image.png")).unwrap();
    // A link to a file still to be made, in a directory that exists.
    std::os::unix::fs::symlink("sub/new.pfm", d.join("new.pfm")).unwrap();
    let stdout = succeeds(
        d,
        &args("render", &["tp.obj", "-o", "image.png", "--stats", "stats.json", "--error-image", "new.pfm"], RENDER),
    );
    assert_eq!(std::fs::read_to_string(d.join("sub/old.json")).unwrap(), stdout);
    assert!(std::fs::read(d.join("sub/old.png")).unwrap().starts_with(b"\x89PNG"));
    assert!(std::fs::read(d.join("sub/new.pfm")).unwrap().starts_with(b"Pf\n32 32\n"));
    // probe's CSV and bake's mesh through links too.
    std::fs::write(d.join("sub/old.obj"), "old").unwrap();
    std::os::unix::fs::symlink("sub/old.obj", d.join("baked.obj")).unwrap();
    std::os::unix::fs::symlink("sub/ao.csv", d.join("ao.csv")).unwrap();
    succeeds(d, &["probe", "q.obj", "--points", "pts.csv", "-o", "ao.csv", "--samples", "4", "--device", "cpu"]);
    succeeds(d, &["bake", "q.obj", "-o", "baked.obj", "--samples", "4", "--device", "cpu"]);
    assert!(
        std::fs::read_to_string(d.join("sub/ao.csv")).unwrap().starts_with("x,y,z,nx,ny,nz,ao,std_error,samples\n")
    );
    assert!(std::fs::read_to_string(d.join("sub/old.obj")).unwrap().contains("\nv 1 0 -1 1 1 1\n"));
    let links = [
        ("stats.json", "sub/old.json"),
        ("image.png", "sub/old.png"),
        ("new.pfm", "sub/new.pfm"),
        ("ao.csv", "sub/ao.csv"),
        ("baked.obj", "sub/old.obj"),
    ];
    for (link, target) in links {
        assert!(kind(&d.join(link)).is_symlink(), "{link}");
        assert_eq!(std::fs::read_link(d.join(link)).unwrap(), Path::new(target));
    }
    assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
    // A link to a directory, or into one that does not exist: refused before any work.
    std::os::unix::fs::symlink("sub", d.join("dir.json")).unwrap();
    std::os::unix::fs::symlink("missing/x.json", d.join("lost.json")).unwrap();
    let sub = d.canonicalize().unwrap().join("sub");
    refused(
        d,
        &args("render", &["tp.obj", "-o", "r.png", "--stats", "dir.json"], RENDER),
        &format!("dir.json: is a symbolic link to {}, a directory: name a file", sub.display()),
    );
    let missing = d.canonicalize().unwrap().join("missing");
    refused(
        d,
        &args("render", &["tp.obj", "-o", "r.png", "--stats", "lost.json"], RENDER),
        &format!(
            "lost.json: is a symbolic link to {}, in a directory that does not exist ({})",
            missing.join("x.json").display(),
            missing.display()
        ),
    );
}

#[test]
fn directories_block_devices_and_sockets_are_refused_before_any_work() {
    let dir = workspace();
    let d = dir.path();
    let not_a_file = "outputs go to regular files, FIFOs or character devices";
    refused(
        d,
        &args("render", &["tp.obj", "-o", "r.png", "--stats", "sub"], RENDER),
        "sub: is a directory: name a file",
    );
    refused(
        d,
        &args("render", &["tp.obj", "-o", "sub/", "--stats", "s.json"], RENDER),
        "sub/: is a directory: name a file",
    );
    let _socket = std::os::unix::net::UnixListener::bind(d.join("sock.png")).unwrap();
    refused(d, &args("render", &["tp.obj", "-o", "sock.png"], RENDER), &format!("sock.png: is a socket: {not_a_file}"));
    refused(
        d,
        &["bake", "q.obj", "-o", "b.obj", "--device", "cpu", "--checkpoint", "sock.png"],
        &format!("sock.png: is a socket: {not_a_file}"),
    );
    if mknod(&d.join("blk.pfm"), true, 7, 0) {
        refused(
            d,
            &args("render", &["tp.obj", "-o", "r.png", "--error-image", "blk.pfm"], RENDER),
            &format!("blk.pfm: is a block device: {not_a_file}"),
        );
        assert!(kind(&d.join("blk.pfm")).is_block_device());
    } else {
        eprintln!("mknod is not permitted here: the block device case is left out");
    }
    refused(
        d,
        &["probe", "q.obj", "--points", "pts.csv", "-o", "nodir/ao.csv", "--device", "cpu"],
        "nodir/ao.csv: is in a directory that does not exist (nodir)",
    );
}

/// Runs `aorender args` in `dir` with standard output `stdout`.
fn with_stdout(dir: &Path, args: &[&str], stdout: Stdio) -> Output {
    Command::new(env!("CARGO_BIN_EXE_aorender"))
        .args(args)
        .current_dir(dir)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .stdout(stdout)
        .stderr(Stdio::piped())
        .output()
        .expect("aorender runs")
}

/// The commands that print data, each small.
fn printing_commands() -> Vec<Vec<&'static str>> {
    vec![
        vec!["probe", "q.obj", "--points", "pts.csv", "--samples", "4", "--device", "cpu"],
        args("render", &["q.obj", "-o", "r.png"], RENDER),
        vec!["bake", "q.obj", "-o", "b.obj", "--samples", "4", "--device", "cpu"],
    ]
}

#[test]
fn a_closed_pipe_on_standard_output_ends_quietly_with_141() {
    let dir = workspace();
    for command in printing_commands() {
        let mut fds = [0; 2];
        assert_eq!(unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) }, 0);
        let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
        // The reader is gone before the first byte, as `| true` is.
        drop(read);
        let out = with_stdout(dir.path(), &command, Stdio::from(write));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(141), "{command:?}: {stderr}");
        assert!(!stderr.contains("panicked") && !stderr.contains("aorender:"), "{command:?}: {stderr}");
    }
}

/// A closed standard error loses the command's messages, not its exit status: a command
/// that fails still exits 1, one that succeeds 0, and neither panics (101).
#[test]
fn a_closed_pipe_on_standard_error_keeps_the_exit_status() {
    let dir = workspace();
    let failing = vec!["render", "missing.obj", "-o", "m.png", "--device", "cpu"];
    let cases = printing_commands().into_iter().map(|c| (c, 0)).chain([(failing, 1)]);
    for (command, status) in cases {
        let mut fds = [0; 2];
        assert_eq!(unsafe { libc::pipe2(fds.as_mut_ptr(), libc::O_CLOEXEC) }, 0);
        let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
        drop(read);
        let out = Command::new(env!("CARGO_BIN_EXE_aorender"))
            .args(&command)
            .current_dir(dir.path())
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(Stdio::null())
            .stderr(Stdio::from(write))
            .output()
            .expect("aorender runs");
        assert_eq!(out.status.code(), Some(status), "{command:?}");
    }
}

#[test]
fn a_full_standard_output_is_one_line_and_status_1() {
    let dir = workspace();
    for command in printing_commands() {
        let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
        let out = with_stdout(dir.path(), &command, Stdio::from(full));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{command:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{command:?}: {stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
        assert_eq!(
            errors,
            ["aorender: standard output: No space left on device (os error 28)"],
            "{command:?}: {stderr}"
        );
        assert!(stderr.ends_with("(os error 28)\n"), "{command:?}: the error is the last line: {stderr}");
    }
}
