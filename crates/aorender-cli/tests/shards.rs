//! Shards: separate processes render disjoint sample ranges (`--sample-range`), `aorender
//! merge` combines their accumulations. The samples are summed as integers, so the merge
//! has the bits of the single render wherever the shards split, on block boundaries or
//! not. Shards of other renders, overlapping or leaving a gap are refused.

mod common;
use aorender::{Accumulation, BLOCK_SAMPLES};
use common::*;
use std::path::Path;
use std::process::{Command, Stdio};

fn json_of(bytes: &[u8]) -> serde_json::Value {
    serde_json::from_slice(bytes).unwrap()
}

/// The test render: the built-in scene with the uniform hemisphere (values that are not
/// sums of powers of two), `extra` appended (with seed 9 unless it sets `--seed`).
fn args<'a>(device: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["render", "--device", device, "--width", "24", "--height", "16", "--hemisphere", "uniform"];
    a.extend_from_slice(&["--spp", "600"]);
    if !extra.contains(&"--seed") {
        a.extend_from_slice(&["--seed", "9"]);
    }
    a.extend_from_slice(extra);
    a
}

/// Renders the shards `ranges` as separate processes running at the same time; returns
/// their checkpoint files, named from `name`.
fn render_shards(device: &str, name: &str, ranges: &[(u32, u32)], d: &Path) -> Vec<String> {
    let mut children = Vec::new();
    let mut files = Vec::new();
    for (k, &(a, b)) in ranges.iter().enumerate() {
        let range = format!("{a}..{b}");
        let (ck, image) = (format!("{name}{k}.ck"), format!("{name}{k}.pfm"));
        let child = Command::new(env!("CARGO_BIN_EXE_aorender"))
            .args(args(device, &["--sample-range", &range, "--checkpoint", &ck, "-o", &image]))
            .current_dir(d)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("aorender starts");
        children.push((range, child));
        files.push(ck);
    }
    for (range, child) in children {
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "{device} shard {range}: {}", String::from_utf8_lossy(&out.stderr));
        let stats = json_of(&out.stdout);
        let (a, b) = range.split_once("..").unwrap();
        let (a, b): (u64, u64) = (a.parse().unwrap(), b.parse().unwrap());
        assert_eq!(stats["first_sample"].as_u64(), Some(a));
        assert_eq!(stats["samples_per_pixel"].as_u64(), Some(b - a));
    }
    files
}

fn merge(files: &[&str], output: &str, d: &Path) -> serde_json::Value {
    let out = aorender(&[&["merge"][..], files, &["-o", output]].concat(), d);
    assert!(out.status.success(), "merge {files:?}: {}", String::from_utf8_lossy(&out.stderr));
    json_of(&out.stdout)
}

fn shards_merge_to_the_single_run(device: &str) {
    let dir = temp_dir();
    let d = dir.path();
    let out = aorender(&args(device, &["--checkpoint", "single.ck", "-o", "single.pfm"]), d);
    assert!(out.status.success(), "{device}: {}", String::from_utf8_lossy(&out.stderr));
    let single = Accumulation::read(&d.join("single.ck")).unwrap();
    let single_film = single.film().unwrap();

    // On block boundaries: the same bits as the single render, whatever the order given.
    assert_eq!(BLOCK_SAMPLES, 256);
    let files = render_shards(device, "aligned", &[(0, 256), (256, 512), (512, 600)], d);
    let stats = merge(&[&files[2], &files[0], &files[1]], "merged.pfm", d);
    assert_eq!(stats["same_as_single_run"], true, "{device}: {stats}");
    assert_eq!(stats["samples_per_pixel"], 600);
    assert_eq!(
        std::fs::read(d.join("merged.pfm")).unwrap(),
        std::fs::read(d.join("single.pfm")).unwrap(),
        "{device}: the merged image differs from the single render's"
    );
    let shards: Vec<_> = files.iter().map(|f| (d.join(f), Accumulation::read(&d.join(f)).unwrap())).collect();
    let merged = aorender::merge(&shards).unwrap();
    assert_eq!(merged.film, single_film, "{device}: merged sums differ from the single render's");

    // Elsewhere too: a shard of one sample, shards crossing the block boundary.
    let files = render_shards(device, "unaligned", &[(0, 1), (1, 100), (100, 333), (333, 600)], d);
    let stats = merge(&[&files[3], &files[0], &files[2], &files[1]], "unaligned.pfm", d);
    assert_eq!(stats["same_as_single_run"], true, "{device}: {stats}");
    assert_eq!(
        std::fs::read(d.join("unaligned.pfm")).unwrap(),
        std::fs::read(d.join("single.pfm")).unwrap(),
        "{device}: the image merged from unaligned shards differs from the single render's"
    );
    let shards: Vec<_> = files.iter().map(|f| (d.join(f), Accumulation::read(&d.join(f)).unwrap())).collect();
    let merged = aorender::merge(&shards).unwrap();
    assert_eq!(merged.film, single_film, "{device}: sums merged from unaligned shards differ from the single render's");
}

#[test]
fn cpu_shards_in_separate_processes_merge_to_the_single_run() {
    shards_merge_to_the_single_run("cpu");
}

#[test]
fn gpu_shards_in_separate_processes_merge_to_the_single_run() {
    if gpu_available() {
        shards_merge_to_the_single_run("gpu");
    }
}

/// GPU and CPU shards of one render merge (their samples are the same up to the float
/// rounding of the two devices) and the note says the bits may differ.
#[test]
fn shards_from_different_devices_merge_within_rounding() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    for (device, range, ck) in [("gpu", "0..256", "a.ck"), ("cpu", "256..600", "b.ck")] {
        let out = aorender(&args(device, &["--sample-range", range, "--checkpoint", ck, "-o", "x.pfm"]), d);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let out = aorender(&["merge", "a.ck", "b.ck", "-o", "m.png"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(json_of(&out.stdout)["same_as_single_run"], false);
    assert!(String::from_utf8_lossy(&out.stderr).contains("not bit for bit"));
}

#[test]
fn merge_refuses_overlaps_gaps_and_other_renders() {
    let dir = temp_dir();
    let d = dir.path();
    let shard = |range: &str, ck: &str, extra: &[&str]| {
        let out = aorender(
            &args("cpu", &[&["--sample-range", range, "--checkpoint", ck, "-o", "x.pfm"][..], extra].concat()),
            d,
        );
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    };
    shard("0..256", "a.ck", &[]);
    shard("256..512", "b.ck", &[]);
    shard("200..300", "overlap.ck", &[]);
    shard("512..600", "c.ck", &[]);
    shard("256..512", "seed.ck", &["--seed", "10"]);
    std::fs::write(d.join("junk.ck"), b"junk").unwrap();
    let cases: &[(&[&str], &[&str])] = &[
        (&["a.ck", "overlap.ck"], &["overlap.ck", "overlap", "a.ck"]),
        (&["a.ck", "a.ck"], &["a.ck", "overlap"]),
        (&["a.ck", "c.ck"], &["c.ck", "samples 256..512 are missing"]),
        (&["a.ck", "seed.ck"], &["seed.ck", "seed 10, not 9"]),
        (&["a.ck", "junk.ck"], &["junk.ck", "not an aorender checkpoint"]),
        (&["a.ck", "none.ck"], &["none.ck"]),
        (&["a.ck", "b.ck", "-o", "m.tiff"], &["m.tiff"]),
    ];
    for (inputs, expect) in cases {
        std::fs::write(d.join("m.png"), b"previous").unwrap();
        let mut a = vec!["merge"];
        a.extend_from_slice(inputs);
        if !inputs.contains(&"-o") {
            a.extend_from_slice(&["-o", "m.png"]);
        }
        let out = aorender(&a, d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{a:?} succeeded");
        let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
        assert_eq!(lines.len(), 1, "{a:?}: {stderr}");
        for e in *expect {
            assert!(lines[0].contains(e), "{a:?}: '{}' lacks '{e}'", lines[0]);
        }
        assert_eq!(std::fs::read(d.join("m.png")).unwrap(), b"previous", "{a:?} wrote the output");
    }
    let out = aorender(&["merge", "c.ck", "a.ck", "b.ck", "-o", "m.png"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}
