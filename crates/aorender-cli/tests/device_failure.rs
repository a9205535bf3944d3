//! The adapter failing mid-render: a lost device (a real one, `wgpu::Device::destroy`
//! through the `AORENDER_TEST_LOSE_DEVICE_AFTER_PASSES` hook) and an adapter out of memory
//! (lavapipe's device memory is process memory: a child under `RLIMIT_AS`) each end the
//! render with one error line naming the adapter and a non-zero exit, write no image, and
//! leave the last checkpoint whole and resumable. A panic inside wgpu's polling (here, a
//! buffer-mapping callback) becomes an error, not an unwinding panic.

mod common;
use aorender::gpu::context::GpuContext;
use aorender::gpu::target::TEST_LOSE_DEVICE_ENV;
use aorender::{Accumulation, BuildQuality, BvhLayout, BvhOptions, DeviceKind, Scene};
use common::*;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Output};

/// The binary with `args` in `cwd`, with `env` set and, when given, its address space
/// limited to `limit` bytes.
fn run(args: &[&str], cwd: &Path, env: &[(&str, &str)], limit: Option<u64>) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_aorender"));
    command.args(args).current_dir(cwd).env("XDG_RUNTIME_DIR", std::env::temp_dir()).envs(env.iter().copied());
    if let Some(bytes) = limit {
        // SAFETY: setrlimit is async-signal-safe and touches only the child being started.
        unsafe {
            command.pre_exec(move || {
                let l = libc::rlimit { rlim_cur: bytes as libc::rlim_t, rlim_max: bytes as libc::rlim_t };
                if libc::setrlimit(libc::RLIMIT_AS, &l) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    command.output().expect("aorender runs")
}

/// The lines of stderr, and the single `aorender:` error line among them (asserted).
fn one_error_line(out: &Output, what: &str) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!stderr.contains("panicked"), "{what}: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{what}: expected one line, got: {stderr}");
    assert!(lines[0].starts_with("aorender: "), "{what}: {stderr}");
    lines[0].to_string()
}

/// Files in `dir` other than `keep`.
fn files_besides(dir: &Path, keep: &[&str]) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect();
    names.sort();
    names
}

/// The device is destroyed after three passes of a checkpointed render: one line naming
/// the loss and the adapter, exit 1, no image, and the checkpoint of the passes before
/// it, which `--resume` continues to the bits of a render that never failed.
#[test]
fn a_lost_device_leaves_a_checkpoint_that_resumes_to_the_same_bits() {
    if !gpu_available() {
        return;
    }
    let adapter = GpuContext::new(None).unwrap().description.name.clone();
    let dir = temp_dir();
    let d = dir.path();
    let base = ["render", "--width", "64", "--height", "48", "--spp", "600", "--hemisphere", "uniform"];
    let with = |extra: &[&'static str]| -> Vec<&str> { base.iter().chain(extra).copied().collect() };

    let full = run(&with(&["--checkpoint", "full.ck", "-o", "full.pfm"]), d, &[], None);
    assert!(full.status.success(), "{}", String::from_utf8_lossy(&full.stderr));

    let lost = run(
        &with(&["--checkpoint", "ck", "--checkpoint-interval", "0.001", "-o", "out.pfm", "--stats", "out.json"]),
        d,
        &[(TEST_LOSE_DEVICE_ENV, "3")],
        None,
    );
    let line = one_error_line(&lost, "lost device");
    assert_eq!(lost.status.code(), Some(1), "{line}");
    assert!(line.contains("device lost") && line.contains(&adapter), "{line}");
    assert!(line.contains("--resume ck"), "{line}");
    assert_eq!(files_besides(d, &["full.ck", "full.pfm"]), ["ck"], "only the checkpoint is written");

    let ck = Accumulation::read(&d.join("ck")).expect("the checkpoint is whole");
    assert!((1..=3).contains(&ck.passes()), "the checkpoint holds {} passes", ck.passes());
    assert!(0 < ck.samples() && ck.samples() < 600, "{} samples", ck.samples());

    let resumed = run(&with(&["--resume", "ck", "-o", "resumed.pfm"]), d, &[], None);
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let (full_ck, resumed_ck) =
        (Accumulation::read(&d.join("full.ck")).unwrap(), Accumulation::read(&d.join("ck")).unwrap());
    assert_eq!(resumed_ck.samples(), 600);
    assert!(resumed_ck.exact() == full_ck.exact(), "the resumed sums differ from the uninterrupted ones");
    assert_eq!(std::fs::read(d.join("resumed.pfm")).unwrap(), std::fs::read(d.join("full.pfm")).unwrap());

    // Lost before the first pass: nothing to save, nothing written.
    std::fs::remove_file(d.join("ck")).unwrap();
    let early = run(&with(&["--checkpoint", "ck", "-o", "out.pfm"]), d, &[(TEST_LOSE_DEVICE_ENV, "0")], None);
    let line = one_error_line(&early, "lost before the first pass");
    assert_eq!(early.status.code(), Some(1), "{line}");
    assert!(line.contains("device lost") && line.contains(&adapter), "{line}");
    assert_eq!(files_besides(d, &["full.ck", "full.pfm", "resumed.pfm"]), Vec::<String>::new());
}

/// Resuming a large render in a process whose address space is too small for the film
/// on the adapter. The limit is found by raising it from where the driver cannot load
/// until the render gets past loading the driver and the checkpoint: the first failure
/// there is the film's allocation, which must be a clean error naming the adapter.
#[test]
fn an_adapter_out_of_memory_is_one_line_and_keeps_the_checkpoint() {
    if !gpu_available() {
        return;
    }
    let adapter = GpuContext::new(None).unwrap().description.name.clone();
    let dir = temp_dir();
    let d = dir.path();
    // 8 Mi pixels: the film and its readback take 128 MiB each on the adapter.
    let (width, height) = (4096u32, 2048u32);
    let toml = format!(
        "[image]\nwidth = {width}\nheight = {height}\n[sampling]\nspp = 1\n\
         [camera]\ntype = \"perspective\"\neye = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 45\n"
    );
    std::fs::write(d.join("big.toml"), toml).unwrap();
    // A checkpoint of this render that holds no samples yet (rendering one would take
    // seconds on a software adapter); the resumed render allocates the film right away.
    let scene = Scene::load(&d.join("big.toml")).unwrap();
    let bvh = BvhOptions { layout: BvhLayout::Cwbvh, quality: BuildQuality::Medium, ..Default::default() };
    let acc = Accumulation::image(&scene, &scene.camera, &scene.settings, 0..1, DeviceKind::Gpu, &bvh);
    acc.write(&d.join("ck")).unwrap();
    let original = std::fs::read(d.join("ck")).unwrap();
    drop(acc);

    let args = ["render", "big.toml", "--resume", "ck", "-o", "out.pfm", "--stats", "out.json"];
    let step = 32 * width as u64 * height as u64 / 3;
    let mut outcomes = Vec::new();
    let mut limit = 256u64 << 20;
    let line = loop {
        assert!(limit < 64 << 30, "no limit up to 64 GiB failed on the adapter: {outcomes:#?}");
        let out = run(&args, d, &[], Some(limit));
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(!out.status.success(), "the render succeeded under {} MiB first: {outcomes:#?}", limit >> 20);
        assert_eq!(std::fs::read(d.join("ck")).unwrap(), original, "under {} MiB: {stderr}", limit >> 20);
        assert_eq!(files_besides(d, &["big.toml", "ck"]), Vec::<String>::new(), "under {} MiB", limit >> 20);
        if stderr.contains("out of memory on the adapter") {
            break one_error_line(&out, &format!("under {} MiB", limit >> 20));
        }
        outcomes.push(format!("{} MiB: {:?}: {}", limit >> 20, out.status.code(), stderr.lines().last().unwrap_or("")));
        limit += step;
    };
    eprintln!("out of memory on the adapter under {} MiB, after {outcomes:#?}", limit >> 20);
    assert!(line.contains(&adapter), "{line}");
    assert!(line.contains("the last checkpoint, ck, is intact"), "{line}");
    Accumulation::read(&d.join("ck")).expect("the checkpoint still reads");
}

/// A panic in a callback that wgpu runs while polling (a buffer mapping's) comes back
/// from [`GpuContext::wait`] as an error with its message; the context stays usable.
#[test]
fn a_panic_inside_a_wgpu_callback_becomes_an_error() {
    if !gpu_available() {
        return;
    }
    let ctx = GpuContext::new(None).unwrap();
    let buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("mapped"),
        size: 256,
        usage: wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    buffer.map_async(wgpu::MapMode::Read, .., |_| panic!("mapping callback fails on purpose"));
    let e = ctx.wait().expect_err("the callback's panic is an error");
    assert!(e.to_string().contains("mapping callback fails on purpose"), "{e}");
    assert!(!aorender::catching_panics());
    ctx.wait().expect("waiting again works");
}
