//! Helpers shared by the command-line tests.
#![allow(dead_code)]

use aorender::gpu::context::GpuContext;
use aorender::{BvhLayout, BvhOptions, DeviceKind};
use std::path::PathBuf;

/// True when a GPU adapter can be opened. In CI (`CI` set) a missing adapter fails the
/// test; elsewhere the test is skipped, loudly, with the reason.
pub fn gpu_available() -> bool {
    match GpuContext::new(None) {
        Ok(_) => true,
        Err(e) if std::env::var_os("CI").is_some() => panic!("CI requires a GPU adapter: {e}"),
        Err(e) => {
            eprintln!("SKIPPED: no GPU adapter ({e})");
            false
        }
    }
}

/// How a library render runs: the device and how the scene is prepared on it.
#[derive(Clone, Copy, Debug, Default)]
pub struct RenderOptions {
    /// GPU or CPU.
    pub device: DeviceKind,
    /// BVH build preset, layout and geometry storage.
    pub bvh: BvhOptions,
}

/// The GPU configurations: one per BVH layout.
pub fn gpu_options() -> Vec<RenderOptions> {
    [BvhLayout::Bvh2, BvhLayout::Cwbvh]
        .into_iter()
        .map(|layout| RenderOptions { device: DeviceKind::Gpu, bvh: BvhOptions { layout, ..Default::default() } })
        .collect()
}

/// The CPU reference, then every GPU configuration when an adapter exists.
pub fn all_options() -> Vec<RenderOptions> {
    let mut all = vec![RenderOptions { device: DeviceKind::Cpu, ..Default::default() }];
    if gpu_available() {
        all.extend(gpu_options());
    }
    all
}

/// "cpu", or "gpu/LAYOUT".
pub fn label(options: &RenderOptions) -> String {
    match options.device {
        DeviceKind::Cpu => "cpu".into(),
        DeviceKind::Gpu => format!("gpu/{}", options.bvh.layout.name()),
    }
}

/// A temporary directory for files a test writes.
pub fn temp_dir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temporary directory")
}

/// The repository root (two levels above this crate).
pub fn repo() -> PathBuf {
    let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().and_then(std::path::Path::parent).expect("crates/aorender-cli is two levels down").to_path_buf()
}

/// The `aorender` binary with `args` in `cwd`, ready to run.
fn command(args: &[&str], cwd: &std::path::Path) -> std::process::Command {
    let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_aorender"));
    command.args(args).current_dir(cwd).env("XDG_RUNTIME_DIR", std::env::temp_dir());
    command
}

/// Runs the `aorender` binary with `args` in `cwd`.
pub fn aorender(args: &[&str], cwd: &std::path::Path) -> std::process::Output {
    command(args, cwd).output().expect("aorender runs")
}

/// Runs the `aorender` binary with `args` in `cwd` on `threads` rayon threads; panics
/// with its output unless it succeeds.
pub fn aorender_on_threads(args: &[&str], cwd: &std::path::Path, threads: usize) -> std::process::Output {
    let out = command(args, cwd).env("RAYON_NUM_THREADS", threads.to_string()).output().expect("aorender runs");
    assert!(out.status.success(), "{args:?} on {threads} threads: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// Runs `aorender bake` with `args` in `dir`; panics with its output unless it succeeds.
/// A glTF output (`-o NAME.glb` or `.gltf`) must pass the Khronos glTF-Validator with no
/// error or warning its input (a glTF input) does not have ([`assert_valid_gltf`]).
pub fn bake(dir: &std::path::Path, args: &[&str]) -> String {
    let out = aorender(&[&["bake"][..], args].concat(), dir);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "bake {args:?}: {stderr}");
    if let Some((output, input)) = gltf_output(args) {
        let input = input.map(|i| dir.join(i));
        assert_valid_gltf(&dir.join(output), input.as_deref());
    }
    stderr
}

/// Bakes `input` with `common` options (`samples` samples a point) into `{tag}-NAME.ext`
/// in `dir` four ways: at once (`full`); stopped at once by a time limit with a checkpoint
/// and resumed (`resumed`); and in two shards of half the samples each, merged in the
/// other order (`merged`). Returns the names of the full, resumed and merged outputs.
pub fn bake_whole_resumed_and_merged(
    dir: &std::path::Path,
    input: &str,
    ext: &str,
    tag: &str,
    samples: u32,
    common: &[&str],
) -> [String; 3] {
    let file = |n: &str| format!("{tag}-{n}.{ext}");
    let (full, part, resumed, shard, merged) =
        (file("full"), file("part"), file("resumed"), file("shard"), file("merged"));
    let samples_arg = samples.to_string();
    let common = [common, &["--samples", &samples_arg]].concat();
    bake(dir, &[&[input, "-o", &full][..], &common].concat());
    let ck = format!("{tag}.ck");
    let stopped =
        bake(dir, &[&[input, "-o", &part, "--checkpoint", &ck, "--time-limit", "1e-9"][..], &common].concat());
    assert!(stopped.contains("time limit reached"), "{stopped}");
    bake(dir, &[&[input, "-o", &resumed, "--resume", &ck][..], &common].concat());
    let (a, b) = (format!("{tag}-a.ck"), format!("{tag}-b.ck"));
    let (first, second) = (format!("0..{}", samples / 2), format!("{}..{samples}", samples / 2));
    bake(dir, &[&[input, "-o", &shard, "--sample-range", &first, "--checkpoint", &a][..], &common].concat());
    bake(dir, &[&[input, "-o", &shard, "--sample-range", &second, "--checkpoint", &b][..], &common].concat());
    bake(dir, &[&[input, "-o", &merged, "--merge", &b, &a][..], &common].concat());
    [full, resumed, merged]
}

/// Runs `aorender bake` on the CPU reference with `args` in `cwd`, which must fail with
/// exit status 1 and one line, `aorender: ...`, that contains `expect`; returns the line.
pub fn bake_refused(args: &[&str], cwd: &std::path::Path, expect: &str) -> String {
    let out = aorender(&[&["bake", "--device", "cpu"][..], args].concat(), cwd);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{args:?}: {stderr}");
    assert!(lines[0].starts_with("aorender: ") && lines[0].contains(expect), "{args:?}: {stderr}");
    lines[0].to_string()
}

/// `scenes/dragons.toml` written into `dir` with each of its nine dragons read through a
/// file name of its own (links to the one file), so they are not instances of one mesh
/// but 7.8M triangles in one BVH. Returns the scene file.
pub fn flattened_dragons(dir: &std::path::Path) -> PathBuf {
    let mut text = std::fs::read_to_string(repo().join("scenes/dragons.toml")).unwrap();
    for i in 0..9 {
        let name = format!("dragon{i}.ply.gz");
        std::os::unix::fs::symlink(repo().join("scenes/dragon_vrip.ply.gz"), dir.join(&name)).unwrap();
        text = text.replacen("file = \"dragon_vrip.ply.gz\"", &format!("file = \"{name}\""), 1);
    }
    assert!(!text.contains("dragon_vrip"));
    let scene = dir.join("dragons.toml");
    std::fs::write(&scene, text).unwrap();
    scene
}

/// The quads of an (n + 1) × (n + 1) grid of vertices numbered row by row, wound so that
/// a grid laid out in x (along a row) and z (across rows) faces +y.
pub fn grid_quads(n: u32) -> Vec<Vec<u32>> {
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let k = j * (n + 1) + i;
            f.push(vec![k, k + n + 1, k + n + 2, k + 1]);
        }
    }
    f
}

/// One issue the Khronos glTF-Validator reports.
#[derive(Clone, Debug, serde::Deserialize)]
pub struct GltfIssue {
    /// Its code, e.g. `UNUSED_OBJECT`.
    pub code: String,
    /// 0 error, 1 warning, 2 information, 3 hint.
    pub severity: u8,
    /// Where: a JSON pointer.
    pub pointer: String,
    /// In words.
    pub message: String,
}

#[derive(serde::Deserialize)]
struct GltfReport {
    issues: Vec<GltfIssue>,
}

/// The issues the Khronos glTF-Validator (`scripts/validate-gltf`, installed from npm on
/// first use) finds in each of `files`. `None` when node or npm is missing: a failure in
/// CI (`CI` set), a loud skip elsewhere.
pub fn gltf_issues(files: &[&std::path::Path]) -> Option<Vec<Vec<GltfIssue>>> {
    let out = std::process::Command::new("bash")
        .arg(repo().join("scripts/validate-gltf"))
        .args(files)
        .output()
        .expect("bash runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    match out.status.code() {
        Some(0) => {}
        Some(3) if std::env::var_os("CI").is_none() => {
            eprintln!("SKIPPED: the glTF validator cannot run ({})", stderr.trim());
            return None;
        }
        _ => panic!("scripts/validate-gltf {files:?} failed: {stderr}"),
    }
    let reports: Vec<GltfReport> = serde_json::from_slice(&out.stdout).expect("the validator's JSON");
    assert_eq!(reports.len(), files.len());
    Some(reports.into_iter().map(|r| r.issues).collect())
}

/// Asserts that the Khronos glTF-Validator finds in `output` no error or warning whose
/// code it does not find in `input` (when given), and no unused object unless `input`
/// has one too. Returns the output's issues (`None` when the validator cannot run
/// outside CI).
pub fn assert_valid_gltf(output: &std::path::Path, input: Option<&std::path::Path>) -> Option<Vec<GltfIssue>> {
    let files: Vec<&std::path::Path> = [Some(output), input].into_iter().flatten().collect();
    let mut reports = gltf_issues(&files)?;
    let theirs = if input.is_some() { reports.pop().unwrap_or_default() } else { Vec::new() };
    let ours = reports.pop().unwrap_or_default();
    let known = |i: &GltfIssue| theirs.iter().any(|t| t.code == i.code);
    // glTF has no material slot for a bent normals map: the texture the bake references
    // from a material's extras is one the validator cannot see used.
    let bent = bent_normal_textures(output);
    let expected =
        |i: &GltfIssue| i.code == "UNUSED_OBJECT" && bent.iter().any(|t| i.pointer == format!("/textures/{t}"));
    let new: Vec<&GltfIssue> =
        ours.iter().filter(|i| (i.severity <= 1 || i.code == "UNUSED_OBJECT") && !known(i) && !expected(i)).collect();
    assert!(new.is_empty(), "{}: the glTF validator finds {new:#?}", output.display());
    Some(ours)
}

/// The textures a glTF file's materials name in `extras.bentNormalTexture`.
fn bent_normal_textures(path: &std::path::Path) -> Vec<u64> {
    let mut bytes = std::fs::read(path).unwrap_or_default();
    if path.extension().is_some_and(|e| e == "gz") {
        let mut plain = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut plain).unwrap();
        bytes = plain;
    }
    let json = match gltf::binary::Glb::from_slice(&bytes) {
        Ok(glb) => glb.json.into_owned(),
        Err(_) => bytes,
    };
    let doc: serde_json::Value = serde_json::from_slice(&json).unwrap_or_default();
    let materials = doc["materials"].as_array().cloned().unwrap_or_default();
    materials.iter().filter_map(|m| m["extras"]["bentNormalTexture"]["index"].as_u64()).collect()
}

/// The first of `args` that names a glTF output (`-o NAME.glb`, `.gltf`, either
/// gzipped), and the input (the first argument) when it is a glTF file.
pub fn gltf_output(args: &[&str]) -> Option<(String, Option<String>)> {
    let is_gltf = |a: &str| {
        let a = a.strip_suffix(".gz").unwrap_or(a);
        a.ends_with(".glb") || a.ends_with(".gltf")
    };
    let at = args.iter().position(|a| *a == "-o" || *a == "--output")?;
    let output = args.get(at + 1).filter(|o| is_gltf(o))?;
    let input = args.first().filter(|i| is_gltf(i) && !i.starts_with('-'));
    Some((output.to_string(), input.map(|i| i.to_string())))
}

/// The phases `--stats` gives a render, probe or bake, in seconds: together, less
/// `overlap_seconds` (what ran beside the main thread: the device's opening while the
/// scene loaded), they account for the process (`process_seconds`) with `other_seconds`,
/// what none of them holds.
pub const PHASES: [&str; 14] = [
    "start_seconds",
    "load_seconds",
    "bvh_build_seconds",
    "scene_seconds",
    "adapter_seconds",
    "upload_seconds",
    "pipeline_seconds",
    "pass_seconds",
    "readback_seconds",
    "host_stats_seconds",
    "checkpoint_seconds",
    "write_seconds",
    "request_seconds",
    "teardown_seconds",
];

/// The phases as the summary line names them, in its order.
pub const SUMMARY_PHASES: [&str; 17] = [
    "start ",
    "load ",
    "BVH ",
    "scene ",
    "adapter ",
    "upload ",
    "pipeline ",
    "request ",
    "passes ",
    "read-back ",
    "statistics ",
    "writing ",
    "teardown ",
    "other ",
    "beside loading ",
    "whole ",
    " s (compiling ",
];

/// Checks that the summary line in `stderr` names every phase, in order.
pub fn check_summary(stderr: &str, device: &str) {
    let line =
        stderr.lines().find(|l| l.contains(" whole ")).unwrap_or_else(|| panic!("{device}: no summary: {stderr}"));
    let mut at = 0;
    for phase in &SUMMARY_PHASES[..SUMMARY_PHASES.len() - 1] {
        let found = line[at..]
            .find(phase)
            .unwrap_or_else(|| panic!("{device}: the summary lacks {phase:?} after {at}: {line}"));
        at += found + phase.len();
    }
    assert!(line.contains(SUMMARY_PHASES[SUMMARY_PHASES.len() - 1]), "{device}: {line}");
    match device {
        "cpu" => assert!(!line.contains(", cache "), "{device}: {line}"),
        _ => assert!(line.contains(", cache "), "{device}: the pipeline cache's state is not said: {line}"),
    }
    assert!(line.contains(" round trips), "), "{device}: the summary lacks the round trips: {line}");
}

/// Checks the accounting of a command's statistics on `device` ("cpu" or "gpu"): every
/// phase present, finite and non-negative, their sum less what overlapped within the
/// whole process (to the rounding of their clocks), the overlap no more than the device's
/// opening and the pipelines', and none on the CPU; bytes read back and round trips on the
/// GPU, at least one a pass, and none on the CPU; `checks` present; the peak memory per
/// triangle and per point (where `points` is given) the peak's share. Returns the sum of
/// the phases on the main thread's timeline and the whole process's seconds.
pub fn check_phases(stats: &serde_json::Value, device: &str, points: Option<u64>) -> (f64, f64) {
    let seconds = |key: &str| {
        let s = stats[key].as_f64().unwrap_or_else(|| panic!("{device}: stats lack {key}: {stats}"));
        assert!(s.is_finite() && s >= 0.0, "{device}: {key} {s}");
        s
    };
    let overlap = seconds("overlap_seconds");
    let beside = seconds("adapter_seconds") + seconds("pipeline_seconds");
    assert!(overlap <= beside, "{device}: {overlap} s overlapped of an opening and pipelines of {beside} s");
    if device == "cpu" {
        assert_eq!(overlap, 0.0, "the CPU reference opens on the main thread, at once");
    }
    let sum: f64 = PHASES.iter().map(|k| seconds(k)).sum::<f64>() - overlap;
    let whole = seconds("process_seconds");
    assert!(whole > 0.0, "{device}: the process took no time");
    assert!(sum <= whole * (1.0 + 1e-6) + 1e-3, "{device}: phases {sum} s, whole {whole} s");
    // What no phase holds is named: the phases and it add up to the whole.
    let other = seconds("other_seconds");
    match sum <= whole {
        true => assert!((sum + other - whole).abs() <= 1e-9 * whole, "{device}: {sum} + {other} s, whole {whole} s"),
        false => assert_eq!(other, 0.0, "{device}: phases {sum} s past the whole {whole} s"),
    }
    let compile = seconds("compile_seconds");
    assert!(compile <= seconds("pipeline_seconds"), "{device}: compiling {compile} s outside the pipeline's");
    let cache = stats["pipeline_cache"].as_str().unwrap_or_else(|| panic!("{device}: stats lack pipeline_cache"));
    match device {
        "cpu" => assert_eq!(cache, "", "the CPU reference has no pipeline cache"),
        _ => assert!(["hit", "miss", "rejected", "off", "unsupported"].contains(&cache), "{device}: cache {cache}"),
    }
    let readback = stats["readback_bytes"].as_u64().expect("readback_bytes");
    let round_trips = stats["round_trips"].as_u64().unwrap_or_else(|| panic!("{device}: stats lack round_trips"));
    match device {
        "cpu" => assert_eq!((readback, round_trips), (0, 0), "the CPU reference reads nothing back"),
        _ => {
            assert!(readback > 0, "{device}: nothing read back");
            // Each pass reads its counters back; a bake's or probe's blocks have passes of their own.
            let passes = stats["passes"].as_u64().unwrap_or(1);
            assert!(round_trips >= passes.max(1), "{device}: {round_trips} round trips for {passes} passes");
        }
    }
    assert!(stats["checks"].as_u64().is_some(), "{device}: stats lack checks");
    let peak = stats["host_peak_bytes"].as_u64().expect("host_peak_bytes") as f64;
    assert!(peak > 0.0, "{device}: no peak");
    let triangles = stats["triangles"].as_u64().expect("triangles");
    match triangles {
        0 => assert!(stats["host_peak_bytes_per_triangle"].is_null(), "{device}: per triangle without triangles"),
        n => {
            let per = stats["host_peak_bytes_per_triangle"].as_f64().expect("host_peak_bytes_per_triangle");
            assert!((per * n as f64 / peak - 1.0).abs() < 1e-9, "{device}: {per} bytes a triangle of {n}, peak {peak}");
        }
    }
    if let Some(points) = points {
        let per = stats["host_peak_bytes_per_point"].as_f64().expect("host_peak_bytes_per_point");
        assert!(
            (per * points as f64 / peak - 1.0).abs() < 1e-9,
            "{device}: {per} bytes a point of {points}, peak {peak}"
        );
    }
    (sum, whole)
}

/// The statistics file `name` in `dir`, parsed.
pub fn stats_json(dir: &std::path::Path, name: &str) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(dir.join(name)).unwrap()).unwrap()
}
