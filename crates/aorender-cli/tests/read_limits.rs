//! Every reader is bounded, and no file outside a glTF file's folder is read: endless
//! pipes, `/dev/zero` in place of every kind of input, a glTF buffer naming `/dev/zero`, a
//! PLY header claiming 2³¹ vertices over an endless body, gzip bombs, checkpoints whose
//! header lies, and glTF URIs that leave the file's folder (absolute, `..`, a symbolic
//! link). Each run of the command must end within [`TIME_LIMIT`] (the harness kills it
//! and fails otherwise), exit with status 1 and one line naming the file and the limit,
//! and keep its heap under [`PEAK_BOUND`] (the binary's own count, which it writes to the
//! file `AORENDER_TEST_HEAP_PEAK_FILE` names: a refused run writes no statistics); none
//! may show the bytes of a file it read.

mod common;
use aorender::scene::MAX_IMAGE_SIDE;
use common::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The read budget of these runs (`AORENDER_READ_BUDGET`), small so that the budget, not
/// the machine, bounds them.
const BUDGET: &str = "32M";
const BUDGET_BYTES: u64 = 32 << 20;
/// The heap peak a run may reach: the budget, plus what the budget does not count (read
/// buffers of 64 KiB, a gzip window, a line of at most 1 MiB, the built-in scene).
const PEAK_BOUND: u64 = BUDGET_BYTES + (8 << 20);
/// Longest a run may take: each of them takes well under a second.
const TIME_LIMIT: Duration = Duration::from_secs(30);

/// How a bounded run of the command ended.
struct Run {
    code: Option<i32>,
    stderr: String,
    /// Heap peak, bytes.
    peak: u64,
    seconds: f64,
}

/// Runs `aorender args` in `dir` with the read budget [`BUDGET`] (see [`run_within`]).
fn run(args: &[&str], dir: &Path) -> Run {
    run_within(args, dir, BUDGET)
}

/// Runs `aorender args` in `dir` with the read budget `budget`; kills it and fails when it
/// runs past [`TIME_LIMIT`].
fn run_within(args: &[&str], dir: &Path, budget: &str) -> Run {
    let report = tempfile::NamedTempFile::new().unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_aorender"))
        .args(args)
        .current_dir(dir)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .env("AORENDER_READ_BUDGET", budget)
        .env("AORENDER_TEST_HEAP_PEAK_FILE", report.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("aorender runs");
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut text).unwrap();
        text
    });
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > TIME_LIMIT {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("aorender {args:?} did not end within {TIME_LIMIT:?}: killed");
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let seconds = start.elapsed().as_secs_f64();
    let stderr = reader.join().unwrap();
    let text = std::fs::read_to_string(report.path()).unwrap();
    let peak = text.trim().parse().unwrap_or_else(|_| panic!("aorender {args:?} wrote no heap peak: {stderr}"));
    Run { code: status.code(), stderr, peak, seconds }
}

/// Runs `aorender args` in `dir`, which must be refused within the bounds: exit status
/// 1, one line `aorender: ...` naming `file` and containing every one of `expect`.
/// Returns the line.
fn refused(args: &[&str], dir: &Path, file: &str, expect: &[&str]) -> String {
    refused_within(args, dir, BUDGET, file, expect)
}

/// [`refused`] with the read budget `budget`.
fn refused_within(args: &[&str], dir: &Path, budget: &str, file: &str, expect: &[&str]) -> String {
    let run = run_within(args, dir, budget);
    let what = format!("aorender {args:?}");
    eprintln!("{what}: {:.2} s, heap peak {:.1} MiB: {}", run.seconds, run.peak as f64 / 1048576.0, run.stderr.trim());
    assert_eq!(run.code, Some(1), "{what}: {}", run.stderr);
    let lines: Vec<&str> = run.stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{what}: more than one line: {}", run.stderr);
    let line = lines[0];
    assert!(line.starts_with("aorender: ") && line.contains(file), "{what}: the file is not named: {line}");
    for e in expect {
        assert!(line.contains(e), "{what}: '{line}' lacks '{e}'");
    }
    assert!(run.peak <= PEAK_BOUND, "{what}: heap peak {} bytes > {PEAK_BOUND}", run.peak);
    line.to_string()
}

/// The arguments of a small render of `input` on the CPU reference.
fn render(input: &str) -> Vec<&str> {
    vec!["render", input, "--device", "cpu", "--spp", "1", "--width", "8", "--height", "8", "-o", "out.png"]
}

/// A FIFO at `path`, fed by a thread with `head` then `chunk` again and again until the
/// reader closes its end. Dropping it ends the thread (opening the FIFO if the command
/// never did, so that the writer's open returns).
struct Fifo {
    path: PathBuf,
    writer: Option<std::thread::JoinHandle<()>>,
}

impl Fifo {
    fn new(path: &Path, head: Vec<u8>, chunk: Vec<u8>) -> Fifo {
        let name = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: `name` is a valid C string.
        assert_eq!(unsafe { libc::mkfifo(name.as_ptr(), 0o600) }, 0, "mkfifo: {}", std::io::Error::last_os_error());
        let fifo = path.to_path_buf();
        let writer = std::thread::spawn(move || {
            // Blocks until the reader opens it; a write fails (EPIPE) once it has closed it.
            let Ok(mut file) = std::fs::OpenOptions::new().write(true).open(&fifo) else { return };
            if file.write_all(&head).is_err() {
                return;
            }
            while file.write_all(&chunk).is_ok() {}
        });
        Fifo { path: path.to_path_buf(), writer: Some(writer) }
    }
}

impl Drop for Fifo {
    fn drop(&mut self) {
        use std::os::unix::fs::OpenOptionsExt;
        // A reader that opens and closes at once: the writer's open returns, its writes fail.
        let _ = std::fs::OpenOptions::new().read(true).custom_flags(libc::O_NONBLOCK).open(&self.path);
        if let Some(writer) = self.writer.take() {
            writer.join().unwrap();
        }
    }
}

#[test]
fn an_endless_obj_from_a_pipe_is_refused_at_the_budget() {
    let dir = temp_dir();
    let d = dir.path();
    let _fifo = Fifo::new(&d.join("endless.obj"), Vec::new(), b"v 1 2 3\n".repeat(8192));
    refused(
        &render("endless.obj"),
        d,
        "endless.obj",
        &["needs more than 32 MiB, the read budget (AORENDER_READ_BUDGET=32M)"],
    );
}

#[test]
fn endless_zeros_from_a_pipe_are_refused_at_the_line_length() {
    let dir = temp_dir();
    let d = dir.path();
    let _fifo = Fifo::new(&d.join("zeros.obj"), Vec::new(), vec![0; 1 << 16]);
    refused(&render("zeros.obj"), d, "zeros.obj", &["line 1 is longer than 1 MiB, the longest line"]);
    // A glTF file that starts as JSON and never ends.
    let _fifo = Fifo::new(&d.join("endless.gltf"), b"{\"asset\": ".to_vec(), vec![b' '; 1 << 16]);
    refused(&render("endless.gltf"), d, "endless.gltf", &["needs more than 32 MiB, the read budget"]);
}

#[test]
fn dev_zero_in_place_of_every_input_is_refused() {
    let dir = temp_dir();
    let d = dir.path();
    for name in ["zero.obj", "zero.ply", "zero.glb", "zero.gltf", "zero.toml", "zero.txt"] {
        std::os::unix::fs::symlink("/dev/zero", d.join(name)).unwrap();
    }
    refused(&render("zero.obj"), d, "zero.obj", &["line 1 is longer than 1 MiB"]);
    // A first line of at most 1 MiB (the longest header) that is not `ply`.
    refused(&render("zero.ply"), d, "zero.ply", &["not a PLY file: the first line is not 'ply'"]);
    // Neither a GLB header nor a JSON object: refused at the first byte.
    refused(&render("zero.glb"), d, "zero.glb", &["invalid glTF JSON: expected value at line 1 column 1"]);
    refused(&render("zero.gltf"), d, "zero.gltf", &["invalid glTF JSON: expected value at line 1 column 1"]);
    refused(&render("zero.toml"), d, "zero.toml", &["the scene needs more than 32 MiB, the read budget"]);
    let probe = ["probe", "--points", "zero.txt", "--device", "cpu", "--samples", "1", "-o", "out.csv"];
    refused(&probe, d, "zero.txt", &["the probe file needs more than 32 MiB, the read budget"]);
    assert!(!d.join("out.png").exists() && !d.join("out.csv").exists());
}

/// A glTF document with one triangle: positions in a `data:` URI (buffer 0), indices (3
/// unsigned ints) in buffer 1, at `uri`, whose byteLength is `length`.
fn triangle_gltf(uri: &str, length: usize) -> String {
    use base64::Engine;
    let positions: Vec<u8> = [0f32, 0., 0., 1., 0., 0., 0., 1., 0.].iter().flat_map(|f| f.to_le_bytes()).collect();
    let data = base64::engine::general_purpose::STANDARD.encode(positions);
    serde_json::json!({
        "asset": {"version": "2.0"},
        "nodes": [{"mesh": 0}],
        "buffers": [
            {"uri": format!("data:application/octet-stream;base64,{data}"), "byteLength": 36},
            {"uri": uri, "byteLength": length}
        ],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 1, "byteLength": 12}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    })
    .to_string()
}

#[test]
fn a_gltf_buffer_naming_dev_zero_is_refused_and_read_to_its_length_when_allowed() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("zero.gltf"), triangle_gltf("/dev/zero", 44)).unwrap();
    refused(
        &render("zero.gltf"),
        d,
        "zero.gltf",
        &["buffer 1: the URI \"/dev/zero\" leads outside the glTF file's folder"],
    );
    // Allowed, 44 bytes are read: indices 0, 0, 0, a triangle of no area.
    let args = [&render("zero.gltf")[..], &["--allow-external-uris"]].concat();
    refused(&args, d, "zero.gltf", &["mesh has no triangles of non-zero area"]);
}

#[test]
fn a_ply_header_claiming_2_31_vertices_over_an_endless_body_is_refused_before_reading() {
    let dir = temp_dir();
    let d = dir.path();
    let header = b"ply\nformat binary_little_endian 1.0\nelement vertex 2147483648\nproperty float x\n\
                   property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                   end_header\n";
    let _fifo = Fifo::new(&d.join("claim.ply"), header.to_vec(), vec![0; 1 << 16]);
    refused(
        &render("claim.ply"),
        d,
        "claim.ply",
        &["the header declares 2147483648 vertices and 1 face: the mesh needs more than 32 MiB, the read budget"],
    );
}

/// `head`, then `count` bytes `byte`, gzipped into `path` a megabyte at a time (at the
/// default level, whose lazy matching keeps a run near DEFLATE's limit of 1032:1 whatever
/// the backend).
fn gzip_bomb(path: &Path, head: &[u8], byte: u8, count: usize) {
    let file = std::fs::File::create(path).unwrap();
    let mut encoder = flate2::write::GzEncoder::new(std::io::BufWriter::new(file), flate2::Compression::default());
    encoder.write_all(head).unwrap();
    let chunk = vec![byte; 1 << 20];
    for _ in 0..count / chunk.len() {
        encoder.write_all(&chunk).unwrap();
    }
    encoder.finish().unwrap().flush().unwrap();
}

#[test]
fn gzip_bombs_are_refused_within_the_budget() {
    let dir = temp_dir();
    let d = dir.path();
    // 256 MiB of zeros (the bomb was 1 GiB in a 1 MB file: 3.15 GB at its peak),
    // of empty lines, and a PLY whose ignored element of 2^40 bytes is all zeros: each
    // past what a budget of 32 MiB lets a file hold decompressed (128 MiB).
    let size = 256 << 20;
    gzip_bomb(&d.join("zeros.obj.gz"), b"", 0, size);
    gzip_bomb(&d.join("empty.obj.gz"), b"", b'\n', size);
    let ply = b"ply\nformat binary_little_endian 1.0\nelement padding 1099511627776\nproperty uchar p\n\
                element vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\n\
                property list uchar int vertex_indices\nend_header\n";
    gzip_bomb(&d.join("padded.ply.gz"), ply, 0, size);
    for name in ["zeros.obj.gz", "empty.obj.gz", "padded.ply.gz"] {
        let bytes = std::fs::metadata(d.join(name)).unwrap().len();
        assert!(bytes < 2 << 20, "{name}: {bytes} bytes");
    }
    refused(&render("zeros.obj.gz"), d, "zeros.obj.gz", &["line 1 is longer than 1 MiB"]);
    refused(
        &render("empty.obj.gz"),
        d,
        "empty.obj.gz",
        &["more than 2 MiB of blank lines and comments by line", "1/16 of the read budget"],
    );
    refused(
        &render("padded.ply.gz"),
        d,
        "padded.ply.gz",
        &["the file holds more than 128 MiB decompressed, 4 times the read budget (AORENDER_READ_BUDGET=32M)"],
    );
}

/// A checkpoint of a 2 × 2 render whose header is made to describe a 16384 × 16384 film,
/// with the length that film would have (a sparse file: nothing is written).
fn lying_checkpoint(d: &Path) -> PathBuf {
    let out = aorender(
        &[
            "render",
            "--device",
            "cpu",
            "--spp",
            "256",
            "--width",
            "2",
            "--height",
            "2",
            "-o",
            "ck.png",
            "--checkpoint",
            "small.ck",
        ],
        d,
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let mut bytes = std::fs::read(d.join("small.ck")).unwrap();
    // Magic, version, hash, then width and height; the adapter name's length at 128, then
    // the replicate size, the film and sky codes, the sky's up vector and ground albedo,
    // the replicates and the count of replicate groups (format version 4).
    let name = u32::from_le_bytes(bytes[128..132].try_into().unwrap()) as usize;
    let header = 132 + name + 36;
    let groups = u32::from_le_bytes(bytes[header - 4..header].try_into().unwrap()) as u64;
    assert_eq!(bytes.len() as u64, header as u64 + 32 * 4 + 16 * groups + 32, "a checkpoint of 4 pixels");
    bytes[44..48].copy_from_slice(&MAX_IMAGE_SIDE.to_le_bytes());
    bytes[48..52].copy_from_slice(&MAX_IMAGE_SIDE.to_le_bytes());
    bytes.truncate(header);
    let path = d.join("huge.ck");
    let file = std::fs::File::create(&path).unwrap();
    (&file).write_all(&bytes).unwrap();
    file.set_len(header as u64 + 32 * MAX_IMAGE_SIDE as u64 * MAX_IMAGE_SIDE as u64 + 16 * groups + 32).unwrap();
    path
}

#[test]
fn checkpoints_whose_header_lies_are_refused_before_their_sums_are_read() {
    let dir = temp_dir();
    let d = dir.path();
    lying_checkpoint(d);
    let resume = [&render("")[..1], &["--resume", "huge.ck", "--device", "cpu", "-o", "out.png"]].concat();
    refused(&resume, d, "huge.ck", &["the checkpoint needs more than 32 MiB, the read budget"]);
    refused(&["merge", "huge.ck", "huge.ck", "-o", "m.png"], d, "huge.ck", &["the checkpoint needs more than 32 MiB"]);
    assert!(!d.join("out.png").exists() && !d.join("m.png").exists());
    // A merge holds its shards together: two of 800 KiB of sums each fit a budget of 2
    // MiB, not one of 1 MiB, where the second gets what the first left.
    for (range, name) in [("0..256", "a.ck"), ("256..512", "b.ck")] {
        let args = ["render", "--device", "cpu", "--spp", "512", "--width", "160", "--height", "160", "-o", "s.png"];
        let out = aorender(&[&args[..], &["--sample-range", range, "--checkpoint", name]].concat(), d);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let merge = ["merge", "a.ck", "b.ck", "-o", "m.png"];
    let ok = run_within(&merge, d, "2M");
    assert_eq!(ok.code, Some(0), "{}", ok.stderr);
    std::fs::remove_file(d.join("m.png")).unwrap();
    refused_within(
        &merge,
        d,
        "1M",
        "b.ck",
        &["the checkpoint needs more than 224 KiB, what is left of the read budget"],
    );
    assert!(!d.join("m.png").exists());
}

/// A folder `inner` holding glTF files whose index buffer lies outside it: in `outside/`
/// beside it (holding the bytes "root" three times, 1953460082 as a u32), named by an
/// absolute path, by `..`, and by a symbolic link in `inner`. Returns the three names.
fn escaping_gltfs(d: &Path) -> [&'static str; 3] {
    std::fs::create_dir_all(d.join("inner")).unwrap();
    std::fs::create_dir_all(d.join("outside")).unwrap();
    std::fs::write(d.join("outside/secret.bin"), b"rootrootroot").unwrap();
    let absolute = d.join("outside/secret.bin").canonicalize().unwrap();
    std::fs::write(d.join("inner/absolute.gltf"), triangle_gltf(absolute.to_str().unwrap(), 12)).unwrap();
    std::fs::write(d.join("inner/dotdot.gltf"), triangle_gltf("../outside/secret.bin", 12)).unwrap();
    std::os::unix::fs::symlink("../outside/secret.bin", d.join("inner/link.bin")).unwrap();
    std::fs::write(d.join("inner/link.gltf"), triangle_gltf("link.bin", 12)).unwrap();
    ["inner/absolute.gltf", "inner/dotdot.gltf", "inner/link.gltf"]
}

#[test]
fn gltf_uris_leaving_the_folder_are_refused_unless_allowed_and_their_bytes_never_shown() {
    let dir = temp_dir();
    let d = dir.path();
    for (file, how) in escaping_gltfs(d).into_iter().zip(["", "", " through a symbolic link"]) {
        let line = refused(&render(file), d, file, &[&format!("leads outside the glTF file's folder{how};")]);
        assert!(line.contains("--allow-external-uris"), "{line}");
        // Allowed, the file is read; its bytes are indices out of range, and the message
        // says which index, not its value.
        let allowed = [&render(file)[..], &["--allow-external-uris"]].concat();
        let line = refused(&allowed, d, file, &["index 0 is out of range for the 3 vertices of accessor 0"]);
        assert!(!line.contains("1953460082") && !line.contains("root"), "{line}");
    }
    for uri in ["/etc/passwd", "/proc/self/environ", "../../../../../../../../etc/passwd"] {
        std::fs::write(d.join("inner/system.gltf"), triangle_gltf(uri, 12)).unwrap();
        refused(&render("inner/system.gltf"), d, "system.gltf", &[&format!("the URI {uri:?} leads outside")]);
    }
    // The same file in the folder is read, and its out-of-range index is not shown either.
    std::fs::write(d.join("inner/secret.bin"), b"rootrootroot").unwrap();
    std::fs::write(d.join("inner/inside.gltf"), triangle_gltf("secret.bin", 12)).unwrap();
    let line = refused(&render("inner/inside.gltf"), d, "inside.gltf", &["index 0 is out of range"]);
    assert!(!line.contains("1953460082") && !line.contains("root"), "{line}");
}

#[test]
fn a_scene_file_and_the_bake_follow_external_uris_only_when_allowed() {
    let dir = temp_dir();
    let d = dir.path();
    escaping_gltfs(d);
    // A good triangle whose buffer lies outside the folder: indices 0, 1, 2.
    let indices: Vec<u8> = [0u32, 1, 2].iter().flat_map(|i| i.to_le_bytes()).collect();
    std::fs::write(d.join("outside/indices.bin"), indices).unwrap();
    std::fs::write(d.join("inner/good.gltf"), triangle_gltf("../outside/indices.bin", 12)).unwrap();
    let scene = |allow: &str| {
        format!(
            "[camera]\ntype = \"perspective\"\neye = [0.3, 0.3, 2.0]\nlook_at = [0.3, 0.3, 0.0]\nfov = 60.0\n\n\
             [[object]]\ntype = \"mesh\"\nfile = \"inner/good.gltf\"\n{allow}"
        )
    };
    std::fs::write(d.join("refused.toml"), scene("")).unwrap();
    std::fs::write(d.join("allowed.toml"), scene("allow_external_uris = true\n")).unwrap();
    refused(&render("refused.toml"), d, "refused.toml", &["object 1 (mesh \"inner/good.gltf\"): buffer 1: the URI"]);
    let ok = run(&render("allowed.toml"), d);
    assert_eq!(ok.code, Some(0), "{}", ok.stderr);
    // The bake reads the file again as the scene allowed, and writes it.
    let ok = run(&["bake", "allowed.toml", "-o", "baked", "--device", "cpu", "--samples", "4"], d);
    assert_eq!(ok.code, Some(0), "{}", ok.stderr);
    assert!(d.join("baked/good.gltf").is_file());
    // An image outside the folder: the renderer never reads images, but the bake's output
    // would refer to it.
    std::fs::copy(d.join("outside/indices.bin"), d.join("inner/indices.bin")).unwrap();
    let mut doc: serde_json::Value = serde_json::from_str(&triangle_gltf("indices.bin", 12)).unwrap();
    doc["images"] = serde_json::json!([{"uri": "../outside/secret.png"}]);
    std::fs::write(d.join("inner/image.gltf"), doc.to_string()).unwrap();
    let ok = run(&render("inner/image.gltf"), d);
    assert_eq!(ok.code, Some(0), "{}", ok.stderr);
    let bake = ["bake", "inner/image.gltf", "-o", "image-ao.gltf", "--device", "cpu", "--samples", "4"];
    refused(&bake, d, "image.gltf", &["image 0: the URI \"../outside/secret.png\" leads outside"]);
    assert!(!d.join("image-ao.gltf").exists());
    let allowed = [&bake[..], &["--allow-external-uris"]].concat();
    let ok = run(&allowed, d);
    assert_eq!(ok.code, Some(0), "{}", ok.stderr);
    assert!(d.join("image-ao.gltf").is_file());
}
