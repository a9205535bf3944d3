//! What a scene cannot have, refused in one line before the work: a film past the host
//! memory budget (a 16384² image from a 200-byte scene), a BVH deeper than the GPU's
//! traversal stack. And what it can: copies of a triangle, counted.

mod common;
use aorender::gpu::context::TEST_STACK_ENTRIES_ENV;
use aorender::host_memory::FILM_BUDGET_ENV;
use aorender::scene::MAX_IMAGE_SIDE;
use aorender::{Device, DeviceKind};
use common::*;
use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};

/// What a run of the binary left: its exit status, its stderr, and its peak resident
/// memory (the kernel's `ru_maxrss` of the child alone).
struct Run {
    code: Option<i32>,
    stderr: String,
    max_rss: u64,
}

/// Runs the binary with `args` in `cwd` and `env` set, measuring its peak memory.
// The child is reaped by `wait4`, which `Child::wait` cannot replace: it gives the
// child's own resource use.
#[allow(clippy::zombie_processes)]
fn run(args: &[&str], cwd: &Path, env: &[(&str, &str)]) -> Run {
    let mut child = Command::new(env!("CARGO_BIN_EXE_aorender"))
        .args(args)
        .current_dir(cwd)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .envs(env.iter().copied())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("aorender runs");
    let mut stderr = String::new();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let (mut status, mut usage) = (0, unsafe { std::mem::zeroed::<libc::rusage>() });
    // SAFETY: waits for this test's own child, which `Child` has not reaped.
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as libc::pid_t, "wait4 failed");
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    Run { code, stderr, max_rss: usage.ru_maxrss as u64 * 1024 }
}

/// The single `aorender:` line of a run's stderr (asserted), with no panic.
fn one_line(run: &Run, what: &str) -> String {
    assert!(!run.stderr.contains("panicked"), "{what}: {}", run.stderr);
    let lines: Vec<&str> = run.stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{what}: expected one line, got: {}", run.stderr);
    assert!(lines[0].starts_with("aorender: "), "{what}: {}", run.stderr);
    lines[0].to_string()
}

/// The devices to check: the CPU reference, and the adapter where there is one.
fn devices() -> Vec<&'static str> {
    if gpu_available() { vec!["cpu", "gpu"] } else { vec!["cpu"] }
}

/// The largest image (16384²) of a small mesh with the film budget set to 100 MB: refused in one line
/// naming the file, the bytes the film needs (the library's estimate) and the budget,
/// exit 1, nothing written, and the process never near the film's size (its peak resident
/// memory under 512 MiB, where the film alone would take 34 GiB).
#[test]
fn a_film_past_the_budget_is_refused_before_any_work() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::copy(repo().join("scenes/teapot.obj"), d.join("teapot.obj")).unwrap();
    for device in devices() {
        let side = MAX_IMAGE_SIDE.to_string();
        let args = ["render", "teapot.obj", "--width", &side, "--height", &side, "--device", device];
        let args = [&args[..], &["-o", "out.png", "--stats", "stats.json"]].concat();
        let out = run(&args, d, &[(FILM_BUDGET_ENV, "100000000")]);
        let line = one_line(&out, device);
        assert_eq!(out.code, Some(1), "{device}: {line}");
        let kind = if device == "cpu" { DeviceKind::Cpu } else { DeviceKind::Gpu };
        let needed = Device::open(kind, None).unwrap().film_bytes(MAX_IMAGE_SIDE as u64 * MAX_IMAGE_SIDE as u64, false);
        let expect = format!(
            "aorender: teapot.obj: a {side}x{side} image needs {needed} bytes of host memory, past the film budget of \
             100000000 bytes (set by {FILM_BUDGET_ENV})"
        );
        assert_eq!(line, expect, "{device}");
        assert!(!d.join("out.png").exists() && !d.join("stats.json").exists(), "{device}: wrote an output");
        eprintln!("{device}: refused with a peak of {} MiB", out.max_rss >> 20);
        assert!(out.max_rss < 512 << 20, "{device}: peak resident memory {} bytes", out.max_rss);
    }
    // A budget that is not a number.
    let out = run(&["render", "teapot.obj", "--device", "cpu", "-o", "out.png"], d, &[(FILM_BUDGET_ENV, "lots")]);
    let line = one_line(&out, "bad budget");
    assert_eq!(out.code, Some(1));
    assert!(line.contains(&format!("{FILM_BUDGET_ENV} must be a number of bytes, not 'lots'")), "{line}");
    assert!(!d.join("out.png").exists());
}

/// The estimate holds what a render holds: a 1024² image's heap peak (the binary's count
/// of its own allocations) over that of an 8² image of the same scene is within the
/// library's estimate of its film, on the CPU reference and the adapter, with samples
/// alone and in replicates; on a CPU adapter (lavapipe), whose device memory is host
/// memory, so is the process's resident peak.
#[test]
fn the_film_estimate_bounds_what_a_render_holds() {
    let dir = temp_dir();
    let d = dir.path();
    for device in devices() {
        for replicated in [false, true] {
            let peaks = [8u32, 1024].map(|side| {
                let side = side.to_string();
                let mut args = vec!["render", "--width", &side, "--height", &side, "--device", device];
                args.extend(["-o", "out.exr", "--stats", "stats.json"]);
                if replicated {
                    args.extend(["--sampler", "sobol", "--replicate", "8", "--spp", "16"]);
                } else {
                    args.extend(["--spp", "1"]);
                }
                let out = run(&args, d, &[]);
                assert_eq!(out.code, Some(0), "{device}: {}", out.stderr);
                let json: serde_json::Value =
                    serde_json::from_slice(&std::fs::read(d.join("stats.json")).unwrap()).unwrap();
                (json["heap_peak_bytes"].as_u64().unwrap(), out.max_rss)
            });
            let kind = if device == "cpu" { DeviceKind::Cpu } else { DeviceKind::Gpu };
            let dev = Device::open(kind, None).unwrap();
            let estimate = dev.film_bytes(1024 * 1024 - 64, replicated);
            let heap = peaks[1].0 - peaks[0].0;
            let rss = peaks[1].1.saturating_sub(peaks[0].1);
            let what = format!("{device}, replicated {replicated}");
            eprintln!("{what}: heap {heap} bytes, resident {rss} bytes, estimate {estimate} bytes");
            assert!(heap <= estimate, "{what}: the heap grew by {heap} bytes, past the estimate {estimate}");
            if dev.info().device_type == "Cpu" {
                assert!(rss <= estimate, "{what}: the resident peak grew by {rss} bytes, past the estimate {estimate}");
            }
        }
    }
}

/// A BVH deeper than the GPU kernel's traversal stack (the stack taken as two entries
/// deep through the test hook) is refused in one line naming the file and the way out:
/// the CPU reference, which then renders it.
#[test]
fn a_bvh_too_deep_for_the_gpu_is_refused_naming_the_file() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    std::fs::copy(repo().join("scenes/teapot.obj"), d.join("teapot.obj")).unwrap();
    let size = ["--width", "16", "--height", "16", "--spp", "1"];
    for layout in ["cwbvh", "bvh2"] {
        let args = [&["render", "teapot.obj", "-o", "out.png", "--bvh-layout", layout][..], &size].concat();
        let out = run(&args, d, &[(TEST_STACK_ENTRIES_ENV, "2")]);
        let line = one_line(&out, layout);
        assert_eq!(out.code, Some(1), "{line}");
        assert!(line.starts_with(&format!("aorender: teapot.obj: its {layout} BVH is ")), "{line}");
        assert!(line.contains("levels deep, past the 2 the GPU kernel's traversal stack holds"), "{line}");
        assert!(line.contains("the CPU reference (`--device cpu`)"), "{line}");
        assert!(!d.join("out.png").exists(), "{layout}: wrote an image");
    }
    let args = [&["render", "teapot.obj", "-o", "out.png", "--device", "cpu"][..], &size].concat();
    let out = run(&args, d, &[(TEST_STACK_ENTRIES_ENV, "2")]);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(d.join("out.png").exists());
}

/// Copies of a triangle are left out of the BVH and counted in the summary line and the
/// statistics.
#[test]
fn copies_are_counted_in_the_summary() {
    let dir = temp_dir();
    let d = dir.path();
    let mut obj = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 4\n");
    obj += &"f 1 2 3\n".repeat(1000);
    std::fs::write(d.join("copies.obj"), obj).unwrap();
    for device in devices() {
        let args = ["render", "copies.obj", "--width", "16", "--height", "16", "--spp", "1", "--device", device];
        let out = run(&[&args[..], &["-o", "out.png", "--stats", "stats.json"]].concat(), d, &[]);
        assert_eq!(out.code, Some(0), "{device}: {}", out.stderr);
        assert!(out.stderr.contains("; 999 copies of triangles or spheres left out of the BVH"), "{}", out.stderr);
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("stats.json")).unwrap()).unwrap();
        assert_eq!(json["duplicates_dropped"], 999, "{device}");
        assert_eq!(json["triangles"], 1001, "{device}");
    }
}
