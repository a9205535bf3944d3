//! Hostile input: the scene and mesh loaders (`Scene::load`, `aorender::scene::load_mesh`)
//! and the checkpoint reader, fed mutated valid files of every format they accept (scene
//! TOML, OBJ, PLY ascii and binary, glTF and GLB, gzipped OBJ and PLY, checkpoints). No
//! input may panic, take more than a few seconds, allocate out of proportion to its size,
//! or fail with anything but one line naming the file.
//!
//! Mutations (bit flips, byte changes, insertions, deletions, duplicated runs and
//! format-specific tokens such as huge counts) are generated and shrunk by proptest from a
//! fixed seed, so a failure reproduces. `AORENDER_FUZZ_CASES` sets the cases per format
//! (default 300, a few seconds in all) and `AORENDER_FUZZ_SEED` the seed (a number), for
//! longer runs:
//!
//! ```sh
//! AORENDER_FUZZ_CASES=100000 AORENDER_FUZZ_SEED=7 cargo test --release --test fuzz_parsers
//! ```
//!
//! A failing input is written to `target/tmp/fuzz-failures/` (the shrunk one last); keep
//! it in `tests/fuzz_regressions/`, where `regressions_load_without_failing` replays every
//! file. An input that aborts the process (stack overflow, allocation failure) or hangs is
//! left at `target/tmp/fuzz/FORMAT/` as the last case run; the watchdog aborts a case that
//! runs over a minute and names that file.

use aorender::film::BlockSums;
use aorender::scene::MAX_IMAGE_SIDE;
use aorender::{Accumulation, BvhOptions, DeviceKind, Scene};
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::LazyLock;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------------------------
// Allocation accounting: bytes live on the loading thread while a load runs.

struct Counting;

thread_local! {
    static TRACKING: Cell<bool> = const { Cell::new(false) };
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

/// A tracked load may not hold more than this at once: past it the allocation fails (the
/// process aborts, leaving the case's file behind) rather than exhausting the machine.
const HARD_CAP: isize = 1 << 30;

fn track(delta: isize) -> bool {
    TRACKING.with(|t| {
        if !t.get() {
            return true;
        }
        LIVE.with(|l| {
            let live = l.get() + delta;
            if live > HARD_CAP {
                return false;
            }
            l.set(live);
            PEAK.with(|p| p.set(p.get().max(live)));
            true
        })
    })
}

// SAFETY: every call forwards to `System` with the same arguments; the bookkeeping only
// touches const-initialised thread-locals, which do not allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !track(layout.size() as isize) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        track(-(layout.size() as isize));
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !track(layout.size() as isize) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if !track(new_size as isize - layout.size() as isize) {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs `f` with this thread's allocations counted; returns its result and the most
/// bytes it held at once.
fn measured<T>(f: impl FnOnce() -> T) -> (T, usize) {
    LIVE.with(|l| l.set(0));
    PEAK.with(|p| p.set(0));
    TRACKING.with(|t| t.set(true));
    let out = f();
    TRACKING.with(|t| t.set(false));
    (out, PEAK.with(|p| p.get()).max(0) as usize)
}

/// The most a load may hold at once for `input` bytes of files: a fixed allowance for the
/// parsers' own tables plus 256 bytes per input byte (a face index of two characters
/// becomes a triangle of 48 bytes, and vectors grow by doubling).
fn allocation_bound(input: usize) -> usize {
    (16 << 20) + 256 * input
}

/// Longest a load of these small inputs may take.
const CASE_TIME_LIMIT: Duration = Duration::from_secs(5);

// ---------------------------------------------------------------------------------------
// Watchdog: a case that hangs aborts the process and names its input.

static CASE_STARTED_MS: AtomicU64 = AtomicU64::new(0);
static LAST_CASE: std::sync::Mutex<Option<PathBuf>> = std::sync::Mutex::new(None);

fn now_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

fn start_watchdog() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        std::thread::spawn(|| {
            loop {
                std::thread::sleep(Duration::from_secs(1));
                let started = CASE_STARTED_MS.load(Ordering::SeqCst);
                if started != 0 && now_ms().saturating_sub(started) > 60_000 {
                    let last = LAST_CASE.lock().map(|p| p.clone()).unwrap_or(None);
                    eprintln!("fuzz: a load ran over 60 s; its input is {last:?}");
                    std::process::abort();
                }
            }
        });
    });
}

// ---------------------------------------------------------------------------------------
// Seeds: small valid files of every format.

const OBJ: &str = "# a quad, a triangle and a pentagon\nmtllib none.mtl\no quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
vt 0 0\nvn 0 0 1\ng a\nusemtl x\nf 1/1/1 2/1/1 3/1/1 4/1/1\nv 0 0 1 1.0\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n\
v 2 0 0\nv 3 0 0\nv 3 1 0\nv 2.5 2 0\nv 2 1 0\nf 11 12 13 14 15\n";

const PLY_ASCII: &str = "ply\nformat ascii 1.0\ncomment a quad and a triangle\nelement vertex 5\n\
property float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 2\n\
property list uchar int vertex_indices\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n\
0 0 0 1\n1 0 0 2\n1 1 0 3\n0 1 0 4\n0.5 0.5 1 5\n4 0 1 2 3\n3 0 1 4\n0 1\n";

fn ply_binary(big_endian: bool) -> Vec<u8> {
    let format = if big_endian { "binary_big_endian" } else { "binary_little_endian" };
    let mut b = format!(
        "ply\nformat {format} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty double z\n\
         element face 1\nproperty list uchar uint vertex_index\nend_header\n"
    )
    .into_bytes();
    for (x, y, z) in [(0f32, 0f32, 0f64), (1.0, 0.0, 0.0), (0.0, 1.0, 0.5)] {
        if big_endian {
            b.extend(x.to_be_bytes().iter().chain(&y.to_be_bytes()).chain(&z.to_be_bytes()));
        } else {
            b.extend(x.to_le_bytes().iter().chain(&y.to_le_bytes()).chain(&z.to_le_bytes()));
        }
    }
    b.push(3);
    for i in 0u32..3 {
        b.extend(if big_endian { i.to_be_bytes() } else { i.to_le_bytes() });
    }
    b
}

/// Positions (3 × VEC3 f32) then indices (3 × u16, padded to 4 bytes): one triangle.
fn gltf_buffer() -> Vec<u8> {
    let mut b = Vec::new();
    for v in [0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        b.extend(v.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        b.extend(i.to_le_bytes());
    }
    b
}

fn gltf_json(uri: Option<&str>, byte_length: usize) -> String {
    let uri = uri.map(|u| format!(",\"uri\":\"{u}\"")).unwrap_or_default();
    format!(
        "{{\"asset\":{{\"version\":\"2.0\"}},\"scene\":0,\"scenes\":[{{\"nodes\":[0]}}],\
         \"nodes\":[{{\"children\":[1],\"translation\":[1,0,0]}},{{\"mesh\":0,\"scale\":[2,2,2]}}],\
         \"meshes\":[{{\"primitives\":[{{\"attributes\":{{\"POSITION\":0}},\"indices\":1,\"mode\":4}}]}}],\
         \"buffers\":[{{\"byteLength\":{byte_length}{uri}}}],\
         \"bufferViews\":[{{\"buffer\":0,\"byteOffset\":0,\"byteLength\":36}},\
         {{\"buffer\":0,\"byteOffset\":36,\"byteLength\":6}}],\
         \"accessors\":[{{\"bufferView\":0,\"componentType\":5126,\"count\":3,\"type\":\"VEC3\",\
         \"min\":[0,0,0],\"max\":[1,1,0]}},{{\"bufferView\":1,\"componentType\":5123,\"count\":3,\"type\":\"SCALAR\"}}]}}"
    )
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn gltf() -> Vec<u8> {
    let buffer = gltf_buffer();
    let uri = format!("data:application/octet-stream;base64,{}", base64(&buffer));
    gltf_json(Some(&uri), buffer.len()).into_bytes()
}

fn glb() -> Vec<u8> {
    let buffer = gltf_buffer();
    let mut json = gltf_json(None, buffer.len()).into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + buffer.len();
    let mut b = Vec::new();
    b.extend(b"glTF");
    b.extend(2u32.to_le_bytes());
    b.extend((total as u32).to_le_bytes());
    b.extend((json.len() as u32).to_le_bytes());
    b.extend(0x4E4F_534Au32.to_le_bytes());
    b.extend(&json);
    b.extend((buffer.len() as u32).to_le_bytes());
    b.extend(0x004E_4942u32.to_le_bytes());
    b.extend(&buffer);
    b
}

/// CRC-32 (IEEE), bit by bit.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

/// `bytes` as a gzip member of stored (uncompressed) DEFLATE blocks.
fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut g = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 255];
    let chunks: Vec<&[u8]> = bytes.chunks(65535).collect();
    for (k, chunk) in chunks.iter().enumerate() {
        g.push((k + 1 == chunks.len()) as u8);
        let n = chunk.len() as u16;
        g.extend(n.to_le_bytes());
        g.extend((!n).to_le_bytes());
        g.extend(*chunk);
    }
    g.extend(crc32(bytes).to_le_bytes());
    g.extend((bytes.len() as u32).to_le_bytes());
    g
}

fn scene_with_meshes() -> String {
    "[image]\nwidth = 16\nheight = 8\nbackground = 0.5\n\n[sampling]\nspp = 4\nhemisphere = \"uniform\"\n\
     sampler = \"stratified\"\nmax_distance = 2.0\nseed = 3\n\n[camera]\ntype = \"orthographic\"\n\
     eye = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nheight = 2.0\n\n\
     [[object]]\ntype = \"mesh\"\nfile = \"m.obj\"\nalbedo = 0.5\ntransform = { scale = 2, rotate = [0, 90, 0], translate = [1, 2, 3] }\n\n\
     [[object]]\ntype = \"mesh\"\nfile = \"m.ply\"\ntransform = { matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]] }\n\n\
     [[object]]\ntype = \"mesh\"\nfile = \"m.gltf\"\n\n[[object]]\ntype = \"mesh\"\nfile = \"m.glb\"\n\n\
     [[object]]\ntype = \"mesh\"\nfile = \"m.obj.gz\"\n\n\
     [[object]]\ntype = \"sphere\"\ncenter = [0, 0, 0]\nradius = 0.5\ntransform = { scale = [2, 2, 2] }\n\n\
     [[object]]\ntype = \"plane\"\npoint = [0, -1, 0]\nnormal = [0, 1, 0]\nalbedo = 0.8\n"
        .into()
}

/// A small checkpoint with a block in progress.
fn checkpoint_bytes() -> Vec<u8> {
    let mut scene = Scene::default_scene();
    (scene.settings.width, scene.settings.height) = (4, 3);
    let mut acc =
        Accumulation::image(&scene, &scene.camera, &scene.settings, 0..64, DeviceKind::Cpu, &BvhOptions::default());
    acc.record_pass(5, 0);
    acc.set_partial(Some(BlockSums { sum: vec![5 << 52; 12], sum_sq: vec![5 << 52; 12] }));
    acc.set_adapter("cpu");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("seed.ck");
    acc.write(&path).unwrap();
    std::fs::read(&path).unwrap()
}

/// Mesh files that seed scenes may name, written beside every scene case.
fn mesh_files() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("m.obj", OBJ.as_bytes().to_vec()),
        ("m.ply", ply_binary(false)),
        ("m.gltf", gltf()),
        ("m.glb", glb()),
        ("m.obj.gz", gzip(OBJ.as_bytes())),
    ]
}

// ---------------------------------------------------------------------------------------
// Mutations.

/// Fragments that parsers treat specially: numbers at the edges of their types, syntax,
/// and declarations of huge counts ([`LARGEST_IMAGE`] stands for the largest image's size).
const TOKEN_TEXT: &[&str] = &[
    "0",
    "-1",
    "-0",
    "1e39",
    "-1e39",
    "1e-45",
    "nan",
    "inf",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "99999999999999999999999",
    "2147483648",
    "\n",
    "\r\n",
    " ",
    "\0",
    "[",
    "]",
    "{",
    "}",
    "=",
    "\"",
    ",",
    "/",
    "#",
    "..",
    "\u{feff}",
    "é",
    "f 1 2 3\n",
    "f -1 -2 -3\n",
    "f 0 0 0\n",
    "f 1 2 4294967295\n",
    "v 1e38 1e38 1e38\n",
    "v 0 0 0 0\n",
    "element vertex 4294967295\n",
    "element face 2147483647\n",
    "property list uint uint vertex_indices\n",
    "property list uchar int vertex_index\n",
    "property double x\n",
    "format binary_big_endian 1.0\n",
    "end_header\n",
    "\"count\":4294967295",
    "\"byteLength\":4294967295",
    "\"byteOffset\":4294967295",
    "\"byteStride\":252",
    "\"componentType\":5121",
    "\"componentType\":5122",
    "\"type\":\"VEC2\"",
    "\"mode\":0",
    "\"children\":[0]",
    "\"uri\":\"missing.bin\"",
    "\"uri\":\"../../etc/passwd\"",
    "\"uri\":\"data:;base64,####\"",
    "\"extensionsRequired\":[\"KHR_draco_mesh_compression\"]",
    "\"sparse\":{\"count\":4294967295,\"indices\":{\"bufferView\":1,\"componentType\":5125},\"values\":{\"bufferView\":0}}",
    "[[object]]\ntype = \"mesh\"\nfile = \"m.ply\"\n",
    "[[object]]\ntype = \"mesh\"\nfile = \"/dev/zero.obj\"\n",
    "[[object]]\ntype = \"mesh\"\nfile = \"m.toml\"\n",
    "[[object]]\ntype = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1e-45\n",
    "transform = { matrix = [[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]] }\n",
    "transform = { scale = 1e30 }\n",
    LARGEST_IMAGE,
    "a = [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[",
    "x = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {a = {",
];

/// The place of the largest image's size among [`TOKEN_TEXT`].
const LARGEST_IMAGE: &str = "the largest image";

/// [`TOKEN_TEXT`] with the largest image's size written from the library's limit.
static TOKENS: LazyLock<Vec<String>> = LazyLock::new(|| {
    let largest = format!("width = {MAX_IMAGE_SIDE}\nheight = {MAX_IMAGE_SIDE}\n");
    TOKEN_TEXT.iter().map(|&t| if t == LARGEST_IMAGE { largest.clone() } else { t.to_string() }).collect()
});

#[derive(Clone, Debug)]
enum Mutation {
    Flip { at: usize, bit: u8 },
    Set { at: usize, byte: u8 },
    Insert { at: usize, bytes: Vec<u8> },
    Token { at: usize, token: usize, replace: usize },
    Delete { at: usize, len: usize },
    Duplicate { at: usize, len: usize, to: usize, times: usize },
    Truncate { at: usize },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let at = any::<usize>();
    prop_oneof![
        (at, 0u8..8).prop_map(|(at, bit)| Mutation::Flip { at, bit }),
        (at, any::<u8>()).prop_map(|(at, byte)| Mutation::Set { at, byte }),
        (at, proptest::collection::vec(any::<u8>(), 1..8)).prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        (at, 0..TOKENS.len(), 0usize..12).prop_map(|(at, token, replace)| Mutation::Token { at, token, replace }),
        (at, 1usize..64).prop_map(|(at, len)| Mutation::Delete { at, len }),
        (at, 1usize..64, any::<usize>(), 1usize..16).prop_map(|(at, len, to, times)| Mutation::Duplicate {
            at,
            len,
            to,
            times
        }),
        at.prop_map(|at| Mutation::Truncate { at }),
    ]
}

/// Longest mutated input: keeps every case small and quick.
const MAX_INPUT: usize = 1 << 16;

fn apply(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in mutations {
        let n = b.len();
        let pos = |at: usize| if n == 0 { 0 } else { at % (n + 1) };
        match m {
            Mutation::Flip { at, bit } if n > 0 => b[at % n] ^= 1 << bit,
            Mutation::Set { at, byte } if n > 0 => b[at % n] = *byte,
            Mutation::Insert { at, bytes } => {
                let p = pos(*at);
                b.splice(p..p, bytes.iter().copied());
            }
            Mutation::Token { at, token, replace } => {
                let p = pos(*at);
                let end = (p + replace).min(n);
                b.splice(p..end, TOKENS[*token].bytes());
            }
            Mutation::Delete { at, len } if n > 0 => {
                let p = at % n;
                b.drain(p..(p + len).min(n));
            }
            Mutation::Duplicate { at, len, to, times } if n > 0 => {
                let p = at % n;
                let run: Vec<u8> = b[p..(p + len).min(n)].to_vec();
                let q = to % (n + 1);
                for _ in 0..*times {
                    b.splice(q..q, run.iter().copied());
                }
            }
            Mutation::Truncate { at } => b.truncate(pos(*at)),
            _ => {}
        }
        b.truncate(MAX_INPUT);
    }
    b
}

// ---------------------------------------------------------------------------------------
// Loading one input.

/// What went wrong with one input, if anything.
fn check_load(path: &Path, input_bytes: usize) -> Result<(), String> {
    let name = path.file_name().unwrap().to_string_lossy().to_string();
    let is_checkpoint = name.ends_with(".ck");
    let is_scene = name.ends_with(".toml");
    let start = Instant::now();
    *LAST_CASE.lock().unwrap() = Some(path.to_path_buf());
    CASE_STARTED_MS.store(now_ms(), Ordering::SeqCst);
    let loaded = std::panic::catch_unwind(|| {
        measured(|| {
            let mut errors = Vec::new();
            if is_checkpoint {
                if let Err(e) = Accumulation::read(path) {
                    errors.push(e.to_string());
                }
            } else {
                if let Err(e) = Scene::load(path) {
                    errors.push(e.to_string());
                }
                if !is_scene && let Err(e) = aorender::scene::load_mesh(path, 1.0, &glam::Mat4::IDENTITY) {
                    errors.push(e.to_string());
                }
            }
            errors
        })
    });
    CASE_STARTED_MS.store(0, Ordering::SeqCst);
    let seconds = start.elapsed();
    let (errors, peak) = loaded.map_err(|p| {
        let what = p.downcast_ref::<String>().cloned().or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()));
        format!("panicked: {}", what.unwrap_or_default())
    })?;
    if seconds > CASE_TIME_LIMIT {
        return Err(format!("took {seconds:?}"));
    }
    if peak > allocation_bound(input_bytes) {
        return Err(format!("held {peak} bytes at once for {input_bytes} bytes of input"));
    }
    // One line naming the file (the scene file, or the mesh file it names).
    let dir = path.parent().unwrap().display().to_string();
    for e in errors {
        if e.contains('\n') || !e.starts_with(&dir) {
            return Err(format!("error is not one line naming the file: {e:?}"));
        }
    }
    Ok(())
}

/// A format to fuzz: seeds, and the file name a case is written to.
struct Target {
    name: &'static str,
    file: &'static str,
    seeds: Vec<Vec<u8>>,
}

fn env_number(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn fuzz(target: Target) {
    start_watchdog();
    let cases = env_number("AORENDER_FUZZ_CASES", 300) as u32;
    let seed = env_number("AORENDER_FUZZ_SEED", 1);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fuzz").join(target.name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut beside = 0;
    if target.file.ends_with(".toml") {
        for (name, bytes) in mesh_files() {
            beside += bytes.len();
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    }
    let failures = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("fuzz-failures");
    let path = dir.join(target.file);
    // Every seed loads as it is.
    for (k, s) in target.seeds.iter().enumerate() {
        std::fs::write(&path, s).unwrap();
        check_load(&path, s.len() + beside).unwrap_or_else(|e| panic!("{} seed {k}: {e}", target.name));
    }
    let config = Config { cases, failure_persistence: None, max_shrink_iters: 4096, ..Config::default() };
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..8 + target.name.len().min(24)].copy_from_slice(&target.name.as_bytes()[..target.name.len().min(24)]);
    let mut runner = TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &key));
    let strategy = (0..target.seeds.len(), proptest::collection::vec(mutation(), 1..6));
    let started = Instant::now();
    let result = runner.run(&strategy, |(k, mutations)| {
        let input = apply(&target.seeds[k], &mutations);
        std::fs::write(&path, &input).unwrap();
        check_load(&path, input.len() + beside).map_err(|e| {
            std::fs::create_dir_all(&failures).unwrap();
            let kept = failures.join(format!("{}-{}-{}", target.name, input.len(), target.file));
            std::fs::write(&kept, &input).unwrap();
            TestCaseError::fail(format!("{e} (input kept as {})", kept.display()))
        })
    });
    eprintln!("{}: {cases} cases in {:.1} s (seed {seed})", target.name, started.elapsed().as_secs_f64());
    if let Err(e) = result {
        panic!("{}: {e}", target.name);
    }
}

/// Runs `f` on a thread with the main thread's usual stack (8 MiB), as the binary would.
fn on_big_stack(f: impl FnOnce() + Send + 'static) {
    std::thread::Builder::new().stack_size(8 << 20).spawn(f).unwrap().join().unwrap();
}

#[test]
fn fuzz_scene_toml() {
    on_big_stack(|| {
        let seeds = vec![aorender::scene::DEFAULT_SCENE.as_bytes().to_vec(), scene_with_meshes().into_bytes()];
        fuzz(Target { name: "toml", file: "scene.toml", seeds })
    });
}

#[test]
fn fuzz_obj() {
    on_big_stack(|| fuzz(Target { name: "obj", file: "mesh.obj", seeds: vec![OBJ.as_bytes().to_vec()] }));
}

#[test]
fn fuzz_ply() {
    on_big_stack(|| {
        let seeds = vec![PLY_ASCII.as_bytes().to_vec(), ply_binary(false), ply_binary(true)];
        fuzz(Target { name: "ply", file: "mesh.ply", seeds })
    });
}

#[test]
fn fuzz_gltf() {
    on_big_stack(|| fuzz(Target { name: "gltf", file: "mesh.gltf", seeds: vec![gltf()] }));
}

#[test]
fn fuzz_glb() {
    on_big_stack(|| fuzz(Target { name: "glb", file: "mesh.glb", seeds: vec![glb()] }));
}

#[test]
fn fuzz_gzip() {
    on_big_stack(|| {
        fuzz(Target { name: "obj.gz", file: "mesh.obj.gz", seeds: vec![gzip(OBJ.as_bytes())] });
        fuzz(Target {
            name: "ply.gz",
            file: "mesh.ply.gz",
            seeds: vec![gzip(PLY_ASCII.as_bytes()), gzip(&ply_binary(true))],
        });
    });
}

#[test]
fn fuzz_checkpoint() {
    on_big_stack(|| fuzz(Target { name: "checkpoint", file: "accumulation.ck", seeds: vec![checkpoint_bytes()] }));
}

/// Every input in `tests/fuzz_regressions/` (found by fuzzing, or written by hand to
/// declare a huge size in a small file) loads without panicking, within the time and
/// allocation bounds, failing with one line naming the file.
#[test]
fn regressions_load_without_failing() {
    on_big_stack(|| {
        start_watchdog();
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions");
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e != "md"))
            .collect();
        files.sort();
        assert!(!files.is_empty(), "no regression inputs in {}", dir.display());
        let work = tempfile::tempdir().unwrap();
        for file in files {
            let bytes = std::fs::read(&file).unwrap();
            // Copied to a directory of its own: the error must name the copy.
            let name = file.file_name().unwrap();
            let path = work.path().join(name);
            std::fs::write(&path, &bytes).unwrap();
            if let Err(e) = check_load(&path, bytes.len()) {
                panic!("{}: {e}", file.display());
            }
        }
    });
}
