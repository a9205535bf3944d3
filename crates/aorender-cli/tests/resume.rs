//! Interruption and resumption: SIGINT or SIGTERM during a real render writes the image,
//! stats and checkpoint of the samples done and exits non-zero; `--resume` continues the
//! checkpoint to the same bits as a render that never stopped, on the GPU and the CPU
//! reference; checkpoints of other scenes or settings, and damaged ones, are refused.

mod common;
use aorender::scene::MAX_IMAGE_SIDE;
use aorender::{
    Accumulation, BuildQuality, BvhLayout, BvhOptions, Control, Device, DeviceKind, Hemisphere, ImageRequest, Progress,
    RenderOutput, SaveFn, Scene, Session,
};
use common::*;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The binary with `args`, run in `cwd`, its output captured.
fn spawn(args: &[&str], cwd: &Path) -> Child {
    spawn_with(args, cwd, &[])
}

/// [`spawn`] with environment variables.
fn spawn_with(args: &[&str], cwd: &Path, env: &[(&str, &std::ffi::OsStr)]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_aorender"))
        .args(args)
        .current_dir(cwd)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .envs(env.iter().copied())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("aorender starts")
}

fn send(child: &Child, signal: libc::c_int) {
    // SAFETY: kill(2) with the pid of a child this test spawned and has not reaped.
    let r = unsafe { libc::kill(child.id() as libc::pid_t, signal) };
    assert_eq!(r, 0, "kill failed");
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// Waits until `file` exists (the render's first checkpoint); panics if the process ends first.
fn wait_for_file(child: &mut Child, file: &Path) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while !file.exists() {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            if let Some(mut e) = child.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
            }
            panic!("render ended ({status}) before writing {}: {stderr}", file.display());
        }
        assert!(Instant::now() < deadline, "no checkpoint after 120 s");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Temporary files left in `dir`.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".tmp") || n.ends_with(".probe"))
        .collect()
}

/// Arguments of the test render: `scene` (the built-in one when `None`) with the uniform
/// hemisphere (its values 2ρ cos θ are not sums of powers of two, so float rounding is
/// exercised).
fn render_args(device: &str, scene: Option<&Path>, width: u32, spp: u32) -> Vec<String> {
    let (w, h, n) = (width.to_string(), (width * 3 / 4).to_string(), spp.to_string());
    let mut args = strings(&["render"]);
    args.extend(scene.map(|p| p.display().to_string()));
    args.extend(strings(&["--device", device, "--width", &w, "--height", &h, "--hemisphere", "uniform", "--spp", &n]));
    args
}

fn run_ok(args: &[String], extra: &[&str], d: &Path) {
    let args: Vec<&str> = args.iter().map(String::as_str).chain(extra.iter().copied()).collect();
    let out = aorender(&args, d);
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// Interrupts a real render with SIGINT partway, inside a block, checks what it wrote,
/// resumes it to the full count and compares with a render that was never interrupted:
/// the raw accumulation and the image are identical.
fn interrupt_and_resume(device: &str) {
    let dir = temp_dir();
    let d = dir.path();
    // An image large enough that a 0.25 s pass holds fewer samples than a block (so a stop
    // can fall inside one), and a sample count (over two blocks) that takes at least 2 s.
    // The rate is the passes' alone (checkpoints of a large film take seconds of their own);
    // where the built-in scene at 4096 pixels is still too fast (a GPU), the bunny.
    let bunny = repo().join("scenes/bunny.obj");
    let (mut width, mut spp, mut scene) = (128u32, 600u32, None);
    let (full_seconds, rate) = loop {
        for f in ["full.ck", "full.pfm", "full.json"] {
            let _ = std::fs::remove_file(d.join(f));
        }
        let args = render_args(device, scene, width, spp);
        run_ok(&args, &["--checkpoint", "full.ck", "-o", "full.pfm", "--stats", "full.json"], d);
        let stats = json(&d.join("full.json"));
        let seconds = stats["render_seconds"].as_f64().unwrap();
        let rate = spp as f64 / stats["pass_seconds"].as_f64().unwrap().max(1e-3);
        if rate > 800.0 && width < 4096 {
            width *= 2;
        } else if rate > 800.0 && scene.is_none() {
            scene = Some(bunny.as_path());
        } else if seconds < 2.0 {
            spp = spp.max((2.5 * spp as f64 / seconds.max(1e-3)) as u32);
        } else {
            break (seconds, rate);
        }
    };
    let name = scene.map_or("the built-in scene".into(), |p| p.display().to_string());
    eprintln!(
        "{device}: {name}, {width} pixels wide, {spp} spp in {full_seconds:.2} s ({rate:.0} samples/s in passes)"
    );
    let args = render_args(device, scene, width, spp);

    // A stop falls at the end of a pass; a pass ends on a block boundary now and then: try again then.
    let mut stops = Vec::new();
    let (part, done) = loop {
        for f in ["ck", "part.pfm", "part.json"] {
            let _ = std::fs::remove_file(d.join(f));
        }
        let extra = ["--checkpoint", "ck", "--checkpoint-interval", "0.1", "-o", "part.pfm", "--stats", "part.json"];
        let full_args: Vec<&str> = args.iter().map(String::as_str).chain(extra).collect();
        let mut child = spawn(&full_args, d);
        wait_for_file(&mut child, &d.join("ck"));
        send(&child, libc::SIGINT);
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(130), "{device}: exit status after SIGINT; stderr: {stderr}");
        assert!(stderr.contains("interrupted by SIGINT"), "{device}: {stderr}");
        assert!(!stderr.contains("panicked"), "{device}: {stderr}");

        // The image and stats are those of the samples done, which the checkpoint holds.
        let stats = json(&d.join("part.json"));
        let done = stats["samples_per_pixel"].as_u64().unwrap() as u32;
        assert!(0 < done && done < spp, "{device}: interrupted after {done} of {spp}");
        assert_eq!(stats["interrupted"], true);
        assert!(stderr.contains(&format!("after {done} of {spp}")), "{device}: {stderr}");
        let part = Accumulation::read(&d.join("ck")).unwrap();
        assert_eq!(part.samples(), done, "{device}: the checkpoint holds the samples of the image");
        let from_checkpoint = d.join("from_checkpoint.pfm");
        aorender::output::write_image(&part.film().unwrap(), &from_checkpoint).unwrap();
        assert_eq!(std::fs::read(d.join("part.pfm")).unwrap(), std::fs::read(&from_checkpoint).unwrap());
        if part.partial().is_some() {
            break (part, done);
        }
        stops.push(done);
        assert!(stops.len() < 8, "{device}: every stop fell on a block boundary: after {stops:?} samples");
    };
    eprintln!("{device}: stopped after {done} samples, {} inside a block", part.partial_samples());

    run_ok(&args, &["--resume", "ck", "-o", "resumed.pfm", "--stats", "resumed.json"], d);
    let stats = json(&d.join("resumed.json"));
    assert_eq!(stats["samples_per_pixel"].as_u64(), Some(spp as u64));
    assert_eq!(stats["samples_resumed"].as_u64(), Some(done as u64));
    assert_eq!(stats["interrupted"], false);

    let full = Accumulation::read(&d.join("full.ck")).unwrap();
    let resumed = Accumulation::read(&d.join("ck")).unwrap();
    assert_eq!((resumed.first(), resumed.next()), (0, spp));
    assert!(resumed.partial().is_none() && full.partial().is_none());
    assert!(resumed.exact() == full.exact(), "{device}: the resumed accumulation differs from the uninterrupted one");
    assert_eq!(resumed.ao_rays(), full.ao_rays(), "{device}: AO rays");
    assert_eq!(std::fs::read(d.join("resumed.pfm")).unwrap(), std::fs::read(d.join("full.pfm")).unwrap());
    assert!(leftovers(d).is_empty(), "{device}: {:?}", leftovers(d));
}

#[test]
fn sigint_then_resume_is_bit_identical_on_the_cpu() {
    interrupt_and_resume("cpu");
}

#[test]
fn sigint_then_resume_is_bit_identical_on_the_gpu() {
    if gpu_available() {
        interrupt_and_resume("gpu");
    }
}

/// A second signal stops at once (no waiting for the pass): exit 128 + signal, no
/// temporary file left, and the checkpoint and image are whole or absent.
#[test]
fn a_second_sigterm_stops_at_once_and_leaves_no_corrupt_file() {
    let dir = temp_dir();
    let d = dir.path();
    // Passes of a large image take a good part of a second: the second signal lands inside one.
    let args = [
        "render",
        "--device",
        "cpu",
        "--width",
        "1024",
        "--height",
        "1024",
        "--spp",
        "100000",
        "--checkpoint",
        "ck",
        "--checkpoint-interval",
        "0.1",
        "-o",
        "out.pfm",
    ];
    let mut child = spawn(&args, d);
    wait_for_file(&mut child, &d.join("ck"));
    send(&child, libc::SIGTERM);
    std::thread::sleep(Duration::from_millis(20));
    let sent = Instant::now();
    send(&child, libc::SIGTERM);
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(sent.elapsed() < Duration::from_secs(2), "took {:?} to stop", sent.elapsed());
    assert_eq!(out.status.code(), Some(143), "stderr: {stderr}");
    assert!(stderr.contains("stopped at once by a second SIGTERM"), "{stderr}");
    assert!(leftovers(d).is_empty(), "{:?}", leftovers(d));
    let ck = Accumulation::read(&d.join("ck")).expect("the checkpoint is whole");
    assert!(ck.samples() > 0);
    if d.join("out.pfm").exists() {
        assert_eq!(std::fs::read(d.join("out.pfm")).unwrap().len(), "Pf\n1024 1024\n-1.0\n".len() + 1024 * 1024 * 4);
    }
}

/// Saving and continuing a library render.
#[derive(Default)]
struct Checkpointing<'a> {
    /// An accumulation to continue (from [`Accumulation::read`]).
    resume: Option<Accumulation>,
    /// Seconds between two saves, at least; zero or less saves after every pass.
    interval: f64,
    /// Receives the accumulation to save.
    save: Option<SaveFn<'a>>,
}

/// Renders the scene's own view through the library: opens the device, prepares the
/// scene on it, continues `checkpointing.resume` if given, and saves through
/// `checkpointing.save`.
fn render_resumable<'a>(
    scene: &Scene,
    options: &RenderOptions,
    checkpointing: Checkpointing<'a>,
    progress: &'a mut dyn FnMut(&Progress),
) -> aorender::Result<RenderOutput> {
    let device = Device::open(options.device, None)?;
    let session = Session::new(&device, scene.clone(), &options.bvh)?;
    let request = ImageRequest { camera: scene.camera, settings: scene.settings.clone(), samples: None };
    let mut render = session.render(&request)?;
    let Checkpointing { resume, interval, save } = checkpointing;
    if let Some(acc) = resume {
        render.resume(acc)?;
    }
    render.run(&mut Control { save, save_interval: interval, progress: Some(progress), ..Default::default() })?;
    render.finish()
}

fn aobench(spp: u32) -> Scene {
    let mut scene = Scene::default_scene();
    let s = &mut scene.settings;
    (s.width, s.height, s.spp, s.sampling.hemisphere) = (8, 6, spp, Hemisphere::Uniform);
    scene
}

/// Through the library: a render saved after every pass, continued from each of those
/// checkpoints (through its file), ends with the bits of the uninterrupted render.
#[test]
fn resuming_from_any_pass_gives_the_same_bits() {
    let dir = temp_dir();
    let scene = aobench(700);
    for options in all_options() {
        let what = label(&options);
        let mut saved = Vec::new();
        let mut save = |a: &Accumulation| {
            saved.push(a.clone());
            Ok(())
        };
        let checkpointing = Checkpointing { resume: None, interval: 0.0, save: Some(&mut save) };
        let full = render_resumable(&scene, &options, checkpointing, &mut |_| {}).unwrap();
        // Passes grow at most eightfold and stop at block ends: 1, 8, 64, then three more.
        assert!(full.stats.passes >= 6, "{what}: {} passes", full.stats.passes);
        assert_eq!(saved.len() as u32, full.stats.passes, "{what}: a checkpoint after every pass");
        assert!(saved.iter().any(|a| a.partial().is_some()), "{what}: no checkpoint inside a block");
        for (k, checkpoint) in saved.iter().enumerate() {
            let path = dir.path().join(format!("{k}.ck"));
            checkpoint.write(&path).unwrap();
            let resume = Some(Accumulation::read(&path).unwrap());
            let out = render_resumable(&scene, &options, Checkpointing { resume, ..Default::default() }, &mut |_| {})
                .unwrap();
            let a = &out.accumulation;
            assert!(
                a.exact() == full.accumulation.exact(),
                "{what}: resumed from sample {} differs",
                checkpoint.next()
            );
            assert_eq!(out.film, full.film, "{what}: resumed from sample {}", checkpoint.next());
            assert_eq!(out.stats.samples_resumed, checkpoint.samples());
        }
    }
}

/// The file format: every truncation and every flipped byte is refused with a message,
/// never a panic; the written file reads back to the same accumulation.
#[test]
fn damaged_checkpoint_bytes_are_refused() {
    let dir = temp_dir();
    let scene = aobench(300);
    let options = RenderOptions { device: DeviceKind::Cpu, ..Default::default() };
    let mut last = None;
    let mut save = |a: &Accumulation| {
        if a.partial().is_some() {
            last = Some(a.clone());
        }
        Ok(())
    };
    render_resumable(
        &scene,
        &options,
        Checkpointing { resume: None, interval: 0.0, save: Some(&mut save) },
        &mut |_| {},
    )
    .unwrap();
    let acc = last.expect("a checkpoint inside a block");
    let path = dir.path().join("a.ck");
    acc.write(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let back = Accumulation::from_bytes(&bytes).unwrap();
    assert!(back.exact() == acc.exact() && back.partial() == acc.partial() && back.next() == acc.next());
    for len in 0..bytes.len() {
        let e = Accumulation::from_bytes(&bytes[..len]).unwrap_err().to_string();
        assert!(e.contains("truncated") || e.contains("not an aorender checkpoint"), "length {len}: {e}");
    }
    for at in (0..bytes.len()).step_by(7) {
        let mut b = bytes.clone();
        b[at] ^= 0x10;
        assert!(Accumulation::from_bytes(&b).is_err(), "byte {at} flipped was accepted");
    }
}

/// Runs a render that must be refused; checks exit, one line naming `names`, and that
/// neither the output nor the checkpoint `ck` changed.
fn assert_refused(args: &[&str], d: &Path, names: &[&str]) {
    std::fs::write(d.join("out.png"), b"previous image").unwrap();
    let ck_before = std::fs::read(d.join("ck")).ok();
    let out = aorender(args, d);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
    assert_eq!(lines.len(), 1, "{args:?}: {stderr}");
    for name in names {
        assert!(lines[0].contains(name), "{args:?}: '{}' lacks '{name}'", lines[0]);
    }
    assert_eq!(std::fs::read(d.join("out.png")).unwrap(), b"previous image", "{args:?} wrote the image");
    assert_eq!(std::fs::read(d.join("ck")).ok(), ck_before, "{args:?} touched the checkpoint");
    assert!(leftovers(d).is_empty(), "{args:?}: {:?}", leftovers(d));
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

/// `render --resume ck` with the options of the checkpoint's render, `extra` replacing
/// or adding options (`("", FILE)` is the scene).
fn resume_args(extra: &[(&str, &str)]) -> Vec<String> {
    let mut options = vec![
        ("--device", "cpu"),
        ("--width", "16"),
        ("--height", "12"),
        ("--spp", "300"),
        ("--seed", "3"),
        ("--sampler", "stratified"),
    ];
    for &(key, value) in extra {
        match options.iter_mut().find(|(k, _)| *k == key) {
            Some(o) => o.1 = value,
            None => options.push((key, value)),
        }
    }
    let mut args = strings(&["render", "--resume", "ck", "-o", "out.png"]);
    for (key, value) in options {
        if !key.is_empty() {
            args.push(key.to_string());
        }
        args.push(value.to_string());
    }
    args
}

#[test]
fn checkpoints_of_other_renders_and_damaged_ones_are_refused() {
    let dir = temp_dir();
    let d = dir.path();
    let base = ["render", "--device", "cpu", "--width", "16", "--height", "12", "--spp", "300", "--seed", "3"];
    let out = aorender(&[&base[..], &["--checkpoint", "ck", "--sampler", "stratified", "-o", "first.png"]].concat(), d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    std::fs::write(
        d.join("other.toml"),
        "[camera]\ntype = \"perspective\"\neye = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 45\n\
         [[object]]\ntype = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\n",
    )
    .unwrap();
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (resume_args(&[("--seed", "4")]), vec!["ck", "seed 3, not 4"]),
        (resume_args(&[("--width", "17")]), vec!["ck", "size 16x12, not 17x12"]),
        (resume_args(&[("--sampler", "independent")]), vec!["ck", "sampler stratified, not independent"]),
        (resume_args(&[("--spp", "400")]), vec!["ck", "samples per pixel 300"]),
        (resume_args(&[("--hemisphere", "uniform")]), vec!["ck", "hemisphere"]),
        (resume_args(&[("--max-distance", "2")]), vec!["ck", "max distance unlimited"]),
        (resume_args(&[("--bvh-quality", "fast")]), vec!["ck", "--bvh-quality medium"]),
        (resume_args(&[("--device", "gpu")]), vec!["ck", "--device cpu, not gpu"]),
        (resume_args(&[("--sample-range", "10..300")]), vec!["ck", "from index 0"]),
        (resume_args(&[("", "other.toml")]), vec!["ck", "geometry or camera"]),
        // A fresh render must not overwrite an existing checkpoint.
        (strings(&["render", "--device", "cpu", "--checkpoint", "ck", "-o", "out.png"]), vec!["ck", "--resume ck"]),
        (strings(&["render", "--sample-range", "0..8", "-o", "out.png"]), vec!["--sample-range needs --checkpoint"]),
        (
            strings(&["render", "--spp", "8", "--sample-range", "0..9", "--checkpoint", "x.ck", "-o", "out.png"]),
            vec!["0..9"],
        ),
        (strings(&["render", "--checkpoint", "missing/dir/x.ck", "-o", "out.png"]), vec!["missing/dir/x.ck"]),
        (strings(&["render", "--checkpoint-interval", "0", "-o", "out.png"]), vec!["--checkpoint-interval"]),
        (strings(&["render", "--resume", "nothing.ck", "-o", "out.png"]), vec!["nothing.ck"]),
    ];
    for (args, names) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_refused(&args, d, names);
    }

    // Damaged files: each one line naming the file, nothing overwritten.
    let good = std::fs::read(d.join("ck")).unwrap();
    let damaged: [(&str, Vec<u8>, &str); 4] = [
        ("truncated", good[..good.len() - 100].to_vec(), "truncated"),
        (
            "flipped",
            {
                let mut b = good.clone();
                let at = b.len() / 2;
                b[at] ^= 1;
                b
            },
            "corrupt",
        ),
        ("text", b"not a checkpoint\n".to_vec(), "not an aorender checkpoint"),
        ("empty", Vec::new(), "not an aorender checkpoint"),
    ];
    for (name, bytes, expect) in damaged {
        std::fs::write(d.join("ck"), &bytes).unwrap();
        let args = resume_args(&[]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_refused(&args, d, &["ck", expect]);
        assert_eq!(std::fs::read(d.join("ck")).unwrap(), bytes, "{name}");
    }
}

/// A failed checkpoint write (its directory gone) is an error naming the file; the
/// render stops and the image is not written.
#[test]
fn a_checkpoint_that_cannot_be_written_stops_the_render_with_the_file_named() {
    let dir = temp_dir();
    let sub = dir.path().join("sub");
    std::fs::create_dir(&sub).unwrap();
    let args = [
        "render",
        "--device",
        "cpu",
        "--width",
        "256",
        "--height",
        "256",
        "--spp",
        "1000000",
        "--checkpoint",
        "sub/ck",
        "--checkpoint-interval",
        "0.1",
        "-o",
        "out.png",
    ];
    let mut child = spawn(&args, dir.path());
    wait_for_file(&mut child, &sub.join("ck"));
    std::fs::remove_dir_all(&sub).unwrap();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].contains("sub/ck"), "{stderr}");
    assert!(!dir.path().join("out.png").exists());
}

/// Raising the sample count of a finished render whose end is a multiple of the block
/// size continues it exactly (the independent sampler's samples do not depend on it).
#[test]
fn a_finished_render_extends_to_more_samples_exactly() {
    let options = RenderOptions { device: DeviceKind::Cpu, ..Default::default() };
    let first = render_resumable(&aobench(256), &options, Checkpointing::default(), &mut |_| {}).unwrap();
    let resume = Some(first.accumulation);
    let more =
        render_resumable(&aobench(600), &options, Checkpointing { resume, ..Default::default() }, &mut |_| {}).unwrap();
    let direct = render_resumable(&aobench(600), &options, Checkpointing::default(), &mut |_| {}).unwrap();
    assert!(more.accumulation.exact() == direct.accumulation.exact());
    assert!(more.accumulation.on_grid());
}

/// A signal while the scene loads or its BVH builds ends the process at once with
/// 128 + signal and one line, writing nothing: no image, stats, checkpoint or temporary
/// file. The scene is `dragons.toml` with its dragons flattened into one BVH of 7.8M
/// triangles ([`flattened_dragons`]): seconds to load and seconds to build. The process
/// announces each phase as it begins (the library's `testing` phase hook), and the signal
/// is sent a moment into the phase, however fast the machine.
#[test]
fn a_signal_while_loading_or_building_the_bvh_writes_nothing() {
    use aorender::phase::TEST_PHASE_FILE_ENV;
    let scenes = temp_dir();
    let scene = flattened_dragons(scenes.path());
    let scene = scene.to_str().unwrap();
    for (signal, name, phase) in [(libc::SIGINT, "SIGINT", "load"), (libc::SIGTERM, "SIGTERM", "bvh")] {
        let dir = temp_dir();
        let d = dir.path();
        let phases = scenes.path().join(format!("phases-{name}"));
        let args = ["render", scene, "--device", "cpu", "--checkpoint", "ck", "--stats", "stats.json", "-o", "out.png"];
        let mut child = spawn_with(&args, d, &[(TEST_PHASE_FILE_ENV, phases.as_os_str())]);
        let entered = Instant::now();
        while !std::fs::read_to_string(&phases).unwrap_or_default().lines().any(|l| l == phase) {
            assert!(child.try_wait().unwrap().is_none(), "{name}: the render ended before its {phase} phase");
            assert!(entered.elapsed() < Duration::from_secs(120), "{name}: no {phase} phase after two minutes");
            std::thread::sleep(Duration::from_millis(5));
        }
        // Well inside the phase: each takes seconds on this scene.
        std::thread::sleep(Duration::from_millis(200));
        send(&child, signal);
        let sent = Instant::now();
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        let seen = std::fs::read_to_string(&phases).unwrap();
        assert_eq!(seen.lines().last(), Some(phase), "{name}: the signal came after the {phase} phase: {seen}");
        assert!(sent.elapsed() < Duration::from_secs(2), "{name}: took {:?} to stop", sent.elapsed());
        assert_eq!(out.status.code(), Some(128 + signal), "{name}: {stderr}");
        let lines: Vec<&str> = stderr.lines().collect();
        assert_eq!(lines.len(), 1, "{name}: {stderr}");
        assert!(lines[0].starts_with(&format!("aorender: interrupted by {name}")), "{stderr}");
        assert!(lines[0].contains("nothing was written"), "{stderr}");
        let files: Vec<_> = std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert!(files.is_empty(), "{name}: wrote {files:?}");
    }
}

/// A header claiming the largest image (16384 × 16384, 8 GiB of sums) is refused by its
/// length before anything is allocated; a sparse file of exactly that length is read in a
/// process whose address space cannot hold the sums: one line naming the file, exit 1, no
/// abort and no output.
#[test]
fn a_header_claiming_a_huge_image_is_refused_without_allocating_it() {
    let dir = temp_dir();
    let d = dir.path();
    let scene = aobench(300);
    let bvh = BvhOptions { layout: BvhLayout::Cwbvh, quality: BuildQuality::Medium, ..Default::default() };
    let acc = Accumulation::image(&scene, &scene.camera, &scene.settings, 0..300, DeviceKind::Cpu, &bvh);
    acc.write(&d.join("small.ck")).unwrap();
    let mut bytes = std::fs::read(d.join("small.ck")).unwrap();
    let header = bytes.len() - 32 * 8 * 6 - 32;
    // Width and height follow the magic, the version and the scene hash.
    assert_eq!(&bytes[44..52], [8u32.to_le_bytes(), 6u32.to_le_bytes()].concat());
    bytes[44..48].copy_from_slice(&MAX_IMAGE_SIDE.to_le_bytes());
    bytes[48..52].copy_from_slice(&MAX_IMAGE_SIDE.to_le_bytes());
    let described = header as u64 + 32 * MAX_IMAGE_SIDE as u64 * MAX_IMAGE_SIDE as u64 + 32;
    let e = Accumulation::from_bytes(&bytes).unwrap_err().to_string();
    assert!(e.contains(&format!("{} bytes, but its header describes {described}", bytes.len())), "{e}");

    let huge = d.join("huge.ck");
    std::fs::write(&huge, &bytes).unwrap();
    std::fs::OpenOptions::new().write(true).open(&huge).unwrap().set_len(described).unwrap();
    let mut command = Command::new(env!("CARGO_BIN_EXE_aorender"));
    command.args(["merge", "huge.ck", "-o", "out.pfm"]).current_dir(d);
    // SAFETY: setrlimit is async-signal-safe and touches only the child being started.
    unsafe {
        std::os::unix::process::CommandExt::pre_exec(&mut command, || {
            let l = libc::rlimit { rlim_cur: 1 << 30, rlim_max: 1 << 30 };
            if libc::setrlimit(libc::RLIMIT_AS, &l) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let out = command.output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].starts_with("aorender: huge.ck: cannot allocate memory"), "{stderr}");
    assert!(!d.join("out.pfm").exists());
}
