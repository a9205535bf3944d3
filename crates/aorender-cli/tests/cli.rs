//! The `aorender` command: a render writes its image and stats; bad input gives one line
//! naming the file and the problem, a non-zero exit, no panic, and no output file (an
//! existing one is left as it was).

mod common;
use common::*;
use std::path::Path;

/// Runs a render that must fail; checks exit, message and that `out` is untouched.
fn assert_rejected(args: &[&str], cwd: &Path, expect_in_message: &[&str]) {
    let out_path = cwd.join("out.png");
    std::fs::write(&out_path, b"previous image").unwrap();
    let output = aorender(args, cwd);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{args:?} succeeded; stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
    assert_eq!(lines.len(), 1, "{args:?}: expected one error line, got: {stderr}");
    for part in expect_in_message {
        assert!(lines[0].contains(part), "{args:?}: '{}' does not mention '{part}'", lines[0]);
    }
    assert_eq!(std::fs::read(&out_path).unwrap(), b"previous image", "{args:?} touched the output");
    let leftovers: Vec<_> = std::fs::read_dir(cwd)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{args:?} left temporary files: {leftovers:?}");
}

#[test]
fn bad_input_is_one_line_with_the_file_and_no_output() {
    let dir = temp_dir();
    let d = dir.path();
    let write = |name: &str, text: &str| std::fs::write(d.join(name), text).unwrap();
    let scene = |objects: &str| {
        format!("[camera]\ntype = \"perspective\"\neye = [0, 0, 5]\nlook_at = [0, 0, 0]\nfov = 45\n{objects}")
    };
    write("malformed.toml", "[camera\ntype = ");
    write("unknown_field.toml", &(scene("") + "\n[image]\nwidht = 10\n"));
    write("unknown_value.toml", &(scene("") + "\n[sampling]\nhemisphere = \"spherical\"\n"));
    write("empty.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    write("nan.obj", "v 0 0 0\nv NaN 0 0\nv 0 1 0\nf 1 2 3\n");
    write("bad_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n");
    write("uses_nan.toml", &scene("[[object]]\ntype = \"mesh\"\nfile = \"nan.obj\"\n"));
    write("uses_missing.toml", &scene("[[object]]\ntype = \"mesh\"\nfile = \"missing.obj\"\n"));
    write(
        "bad_sphere.toml",
        &scene("[[object]]\ntype = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1\ntransform = { scale = [1, 2, 1] }\n"),
    );
    let cases: &[(&[&str], &[&str])] = &[
        (&["render", "missing.toml", "-o", "out.png"], &["missing.toml"]),
        (&["render", "malformed.toml", "-o", "out.png"], &["malformed.toml", "line"]),
        (&["render", "unknown_field.toml", "-o", "out.png"], &["unknown_field.toml", "widht"]),
        (&["render", "unknown_value.toml", "-o", "out.png"], &["unknown_value.toml", "spherical"]),
        (&["render", "empty.obj", "-o", "out.png"], &["empty.obj", "no triangles"]),
        (&["render", "nan.obj", "-o", "out.png"], &["nan.obj", "NaN"]),
        (&["render", "bad_index.obj", "-o", "out.png"], &["bad_index.obj"]),
        (&["render", "uses_nan.toml", "-o", "out.png"], &["nan.obj", "NaN"]),
        (&["render", "uses_missing.toml", "-o", "out.png"], &["missing.obj"]),
        (&["render", "bad_sphere.toml", "-o", "out.png"], &["bad_sphere.toml", "similarity"]),
        (&["render", "scene.xyz", "-o", "out.png"], &["scene.xyz"]),
        (&["render", "--hemisphere", "spherical", "-o", "out.png"], &["spherical"]),
        (&["render", "--spp", "0", "-o", "out.png"], &["samples per pixel"]),
        (&["render", "--max-distance", "-1", "-o", "out.png"], &["max distance"]),
        (&["render", "-o", "out.tiff"], &["out.tiff"]),
    ];
    for (args, expect) in cases {
        assert_rejected(args, d, expect);
    }
}

#[test]
fn render_writes_image_and_stats() {
    let dir = temp_dir();
    let d = dir.path();
    let mut devices = vec!["cpu"];
    if gpu_available() {
        devices.push("gpu");
    }
    for device in devices {
        for ext in ["png", "exr", "pfm"] {
            let image = format!("aobench_{device}.{ext}");
            let stats = format!("stats_{device}.json");
            let args = ["render", "--width", "32", "--height", "24", "--spp", "4", "-o", &image, "--stats", &stats];
            let output = aorender(&[&args[..], &["--device", device]].concat(), d);
            assert!(output.status.success(), "{device}: {}", String::from_utf8_lossy(&output.stderr));
            let bytes = std::fs::read(d.join(&image)).unwrap();
            match ext {
                "png" => {
                    let img = image::load_from_memory(&bytes).unwrap();
                    assert_eq!((img.width(), img.height()), (32, 24));
                }
                "exr" => {
                    let img = image::load_from_memory(&bytes).unwrap();
                    assert_eq!((img.width(), img.height()), (32, 24));
                }
                _ => {
                    assert!(bytes.starts_with(b"Pf\n32 24\n-1.0\n"));
                    assert_eq!(bytes.len(), "Pf\n32 24\n-1.0\n".len() + 32 * 24 * 4);
                }
            }
            let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
            for key in [
                "samples_per_pixel",
                "width",
                "height",
                "rays_traced",
                "render_seconds",
                "bvh_build_seconds",
                "rays_per_second",
                "triangles",
                "adapter",
                "backend",
                "hemisphere",
                "sampler",
                "seed",
                "load_seconds",
                "scene_bytes",
                "host_peak_bytes",
                "heap_peak_bytes",
                "bvh_bytes",
                "device_bytes",
            ] {
                assert!(json.get(key).is_some(), "{device}: stats lack {key}");
            }
            // Three spheres and a plane, and a process that holds them.
            let scene_bytes = json["scene_bytes"].as_u64().unwrap();
            let expected =
                3 * std::mem::size_of::<aorender::scene::Sphere>() + std::mem::size_of::<aorender::scene::Plane>();
            assert_eq!(scene_bytes, expected as u64, "{device}");
            let peak = json["host_peak_bytes"].as_u64().unwrap();
            assert!(peak > 1 << 20, "{device}: peak resident memory {peak} bytes");
            let heap = json["heap_peak_bytes"].as_u64().expect("the binary counts its heap");
            assert!(heap >= scene_bytes && heap <= peak, "{device}: heap peak {heap} bytes, resident peak {peak}");
            assert!(json["bvh_bytes"].as_u64().unwrap() > 0, "{device}");
            assert!(json["load_seconds"].as_f64().unwrap() > 0.0, "{device}");
            if device == "gpu" {
                assert!(json["device_bytes"].as_u64().unwrap() > 0, "{device}");
            }
            assert_eq!(json["samples_per_pixel"], 4);
            assert_eq!(json["width"], 32);
            // aobench: every camera ray is traced, and the floor fills the lower half.
            let rays = json["rays_traced"].as_u64().unwrap();
            assert!(rays > 32 * 24 * 4 && rays < 2 * 32 * 24 * 4, "{device}: {rays} rays");
        }
    }
}

/// `--traversal cooperative` writes the image `per-lane` writes, byte for byte, and says
/// so in the stats; a scene it cannot trace (instances) is one line and no output.
#[test]
fn the_traversals_write_the_same_image() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    let bunny = repo().join("scenes/bunny.obj");
    let bunny = bunny.to_str().unwrap();
    let images = ["per-lane", "cooperative"].map(|traversal| {
        let (image, stats) = (format!("{traversal}.pfm"), format!("{traversal}.json"));
        let args = ["render", bunny, "--width", "40", "--height", "28", "--spp", "8", "--hemisphere", "uniform"];
        let output = aorender(&[&args[..], &["--traversal", traversal, "-o", &image, "--stats", &stats]].concat(), d);
        assert!(output.status.success(), "{traversal}: {}", String::from_utf8_lossy(&output.stderr));
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join(&stats)).unwrap()).unwrap();
        assert_eq!(json["traversal"], traversal);
        std::fs::read(d.join(&image)).unwrap()
    });
    assert_eq!(images[0], images[1]);
    std::fs::write(
        d.join("twice.toml"),
        format!(
            "[camera]\ntype = \"perspective\"\neye = [0.0, 0.1, 0.6]\nlook_at = [0.0, 0.1, 0.0]\nfov = 50.0\n\
             [[object]]\ntype = \"mesh\"\nfile = {bunny:?}\n\
             [[object]]\ntype = \"mesh\"\nfile = {bunny:?}\ntransform = {{ translate = [0.3, 0.0, 0.0] }}\n"
        ),
    )
    .unwrap();
    assert_rejected(&["render", "twice.toml", "--traversal", "cooperative", "-o", "out.png"], d, &["cooperative"]);
}

/// Every file of the malformed-mesh corpus (`crates/aorender/tests/malformed/`), rendered
/// as a bare mesh: one error line naming the file, a non-zero exit, no panic and no output.
#[test]
fn malformed_meshes_are_one_line_errors() {
    let dir = temp_dir();
    let corpus = repo().join("crates/aorender/tests/malformed");
    let mut files: Vec<String> =
        std::fs::read_dir(&corpus).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    files.sort();
    assert!(files.len() >= 10, "the corpus has only {} files", files.len());
    for file in &files {
        let path = corpus.join(file);
        assert_rejected(&["render", path.to_str().unwrap(), "-o", "out.png"], dir.path(), &[file]);
    }
}

/// `--sample-range START..END`: an empty or reversed range, an end past the samples per
/// pixel, a missing bound or `..`, and anything but two sample indices are one line naming
/// the option and the problem; nothing is written, not even the shard's checkpoint.
#[test]
fn bad_sample_ranges_are_refused() {
    let dir = temp_dir();
    let d = dir.path();
    let cases: &[(&str, &[&str])] = &[
        ("5..3", &["--sample-range", "5..3", "START must be below END"]),
        ("3..3", &["--sample-range", "3..3", "START must be below END"]),
        ("0..9", &["--sample-range", "0..9", "past the 8 samples per pixel"]),
        ("8..9", &["--sample-range", "8..9", "past the 8 samples per pixel"]),
        ("a..3", &["--sample-range", "START 'a'", "not a sample index"]),
        ("1..b", &["--sample-range", "END 'b'", "not a sample index"]),
        ("-1..3", &["--sample-range", "START '-1'", "not a sample index"]),
        ("0..4294967296", &["--sample-range", "END '4294967296'", "too large"]),
        ("1..2..3", &["--sample-range", "END '2..3'"]),
        ("5", &["--sample-range", "expected START..END"]),
        ("", &["--sample-range", "expected START..END"]),
        ("..4", &["--sample-range", "START is missing"]),
        ("2..", &["--sample-range", "END is missing"]),
    ];
    for (range, expect) in cases {
        let option = format!("--sample-range={range}");
        let args = ["render", "--device", "cpu", "--spp", "8", &option, "--checkpoint", "x.ck", "-o", "out.png"];
        assert_rejected(&args, d, expect);
        assert!(!d.join("x.ck").exists(), "{range}: a checkpoint was written");
    }
}

/// An error target stops the render and says so; the error image holds the per-pixel
/// standard errors the statistics' RMSE estimate comes from; a target or an error image
/// without a valid estimate, or an error image in an 8-bit format, is refused before any
/// work.
#[test]
fn error_targets_and_error_images() {
    let dir = temp_dir();
    let d = dir.path();
    let args = [
        "render",
        "--width",
        "24",
        "--height",
        "16",
        "--sampler",
        "sobol",
        "--target-error",
        "0.02",
        "--device",
        "cpu",
        "-o",
        "t.pfm",
        "--error-image",
        "se.pfm",
        "--stats",
        "t.json",
    ];
    let output = aorender(&args, d);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("error target met after"), "{stderr}");
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("t.json")).unwrap()).unwrap();
    assert_eq!(stats["ended_by"], "target");
    assert_eq!(stats["replicate_samples"], 16);
    let (bound, rmse) = (stats["rmse_bound"].as_f64().unwrap(), stats["rmse_estimate"].as_f64().unwrap());
    assert!(bound <= 0.02 && rmse <= bound, "bound {bound}, estimate {rmse}");
    assert!(stats["samples_per_pixel"].as_u64().unwrap() < 65536);
    // The RMSE estimate is the root of the mean of the error image's squares.
    let bytes = std::fs::read(d.join("se.pfm")).unwrap();
    let header = b"Pf\n24 16\n-1.0\n";
    assert!(bytes.starts_with(header));
    let se: Vec<f64> =
        bytes[header.len()..].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64).collect();
    let from_image = (se.iter().map(|e| e * e).sum::<f64>() / se.len() as f64).sqrt();
    assert!((from_image / rmse - 1.0).abs() < 1e-5, "error image {from_image}, statistics {rmse}");

    let sobol = ["render", "--width", "8", "--height", "8", "--sampler", "sobol", "--device", "cpu", "-o", "out.png"];
    assert_rejected(&[&sobol[..], &["--target-error", "0.01", "--replicate", "0"]].concat(), d, &["error estimate"]);
    assert_rejected(&[&sobol[..], &["--replicate", "3"]].concat(), d, &["replicate", "power of two"]);
    assert_rejected(&[&sobol[..], &["--error-image", "se.png"]].concat(), d, &["se.png"]);
    assert_rejected(&[&sobol[..], &["--target-error", "0"]].concat(), d, &["positive"]);
    assert_rejected(&[&sobol[..], &["--error-image", "se.pfm"]].concat(), d, &["--error-image", "--replicate"]);
}

/// `--replicate-by-cost` times a pass and a check on the GPU, measures the samples'
/// spread and takes a size the sampler allows (a power of two from 16 to 256), which the
/// statistics record and the render stops on; the CPU reference measures nothing and
/// keeps 16; without a target the option is refused.
#[test]
fn replicate_sizes_by_expected_cost() {
    let dir = temp_dir();
    let d = dir.path();
    let args = ["render", "--width", "32", "--height", "24", "--sampler", "sobol", "--target-error", "0.01"];
    let mut devices = vec!["cpu"];
    if gpu_available() {
        devices.push("gpu");
    }
    for device in devices {
        let more = ["--replicate-by-cost", "-o", "t.pfm", "--stats", "t.json", "--device", device];
        let out = aorender(&[&args[..], &more[..]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{device}: {stderr}");
        let stats = stats_json(d, "t.json");
        assert_eq!(stats["ended_by"], "target", "{device}");
        let b = stats["replicate_samples"].as_u64().unwrap();
        match device {
            "cpu" => assert_eq!(b, 16),
            _ => assert!(b.is_power_of_two() && (16..=256).contains(&b), "{device}: {b}"),
        }
        assert_eq!(stats["samples_per_pixel"].as_u64().unwrap() % b, 0, "{device}: {stats}");
        assert!(stats["rmse_bound"].as_f64().unwrap() <= 0.01, "{device}: {stats}");
    }
    let sobol = ["render", "--width", "8", "--height", "8", "--sampler", "sobol", "--device", "cpu", "-o", "out.png"];
    assert_rejected(&[&sobol[..], &["--replicate-by-cost"]].concat(), d, &["--replicate-by-cost", "--target-error"]);
}

/// A render's statistics account for its process phase by phase on both devices (start,
/// load, BVH, scene, adapter, upload, pipeline, request, passes, read-back, host
/// statistics, checkpoints, writing, teardown): each finite and non-negative, together
/// within the whole process and, on a render whose passes outweigh the fixed costs, at
/// least 80 % of it, `other_seconds` the rest, and the summary line names each in order;
/// the GPU reads back at least the film; a render with an error target counts its checks
/// and says how many.
#[test]
fn render_stats_account_for_every_phase() {
    let dir = temp_dir();
    let d = dir.path();
    let dragon = repo().join("scenes/dragon_vrip_res4.ply.gz");
    let mut devices = vec!["cpu"];
    if gpu_available() {
        devices.push("gpu");
    }
    for device in devices {
        let json = format!("{device}.json");
        let args = ["render", dragon.to_str().unwrap(), "--width", "192", "--height", "192", "--spp", "64"];
        let out = aorender(&[&args[..], &["-o", "d.png", "--stats", &json, "--device", device]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{device}: {stderr}");
        let stats = stats_json(d, &json);
        let (sum, whole) = check_phases(&stats, device, None);
        assert!(sum >= 0.8 * whole, "{device}: the phases account for {sum} s of {whole} s");
        assert!(stats["triangles"].as_u64().unwrap() > 0 && stats["host_peak_bytes_per_point"].is_null());
        if device == "gpu" {
            let film = 192 * 192 * 16;
            assert!(stats["readback_bytes"].as_u64().unwrap() >= film, "{device}: {stats}");
        }
        assert_eq!(stats["checks"], 0, "{device}: no target, no check");
        assert!(!stderr.contains(" checks"), "{device}: {stderr}");
        for phase in [
            "load ",
            "BVH ",
            "adapter ",
            "upload ",
            "pipeline ",
            "passes ",
            "read-back ",
            "statistics ",
            "writing ",
            "whole ",
        ] {
            assert!(stderr.contains(phase), "{device}: the summary lacks {phase}: {stderr}");
        }
        check_summary(&stderr, device);

        let args = ["render", "--width", "24", "--height", "16", "--sampler", "sobol", "--target-error", "0.02"];
        let out = aorender(&[&args[..], &["-o", "t.pfm", "--stats", "t.json", "--device", device]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{device}: {stderr}");
        let stats = stats_json(d, "t.json");
        check_phases(&stats, device, None);
        assert_eq!(stats["ended_by"], "target");
        let checks = stats["checks"].as_u64().unwrap();
        // Checked once a replicate at most: 16 samples each.
        let replicates = stats["samples_per_pixel"].as_u64().unwrap() / 16;
        assert!((1..=replicates).contains(&checks), "{device}: {checks} checks of {replicates} replicates");
        assert!(stderr.contains(&format!(", {checks} checks)")), "{device}: {stderr}");
    }
}

/// The driver's pipeline cache is kept on disk where the backend has one (Vulkan): the
/// first render on an adapter starts the file (`miss`), the next reads it (`hit`); a
/// damaged file, or one wgpu refuses (another adapter, driver or format), is ignored
/// (`rejected`) and replaced; `off` keeps none. The image is the same bits every time.
#[test]
fn the_pipeline_cache_on_disk_is_read_back_and_a_damaged_one_ignored() {
    if !gpu_available() {
        return;
    }
    let dir = temp_dir();
    let d = dir.path();
    let cache = d.join("cache");
    let render = |name: &str, setting: &std::path::Path| {
        let args = ["render", "--width", "32", "--height", "24", "--spp", "4", "--device", "gpu", "-o"];
        let (image, json) = (format!("{name}.pfm"), format!("{name}.json"));
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_aorender"))
            .args([&args[..], &[&image, "--stats", &json]].concat())
            .current_dir(d)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .env(aorender::gpu::pipeline::PIPELINE_CACHE_ENV, setting)
            .output()
            .expect("aorender runs");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{name}: {stderr}");
        let stats = stats_json(d, &json);
        assert!(stderr.contains(&format!(", cache {})", stats["pipeline_cache"].as_str().unwrap())), "{stderr}");
        (stats["pipeline_cache"].as_str().unwrap().to_string(), std::fs::read(d.join(&image)).unwrap())
    };
    let (first, image) = render("first", &cache);
    if first == "unsupported" {
        eprintln!("SKIPPED: the adapter's backend keeps no pipeline cache");
        return;
    }
    assert_eq!(first, "miss");
    let files: Vec<_> = std::fs::read_dir(&cache).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(files.len(), 1, "one cache file and no temporary one: {files:?}");
    let file = &files[0];
    let saved = std::fs::read(file).unwrap();
    assert!(saved.starts_with(b"AOPLC001") && saved.len() > 48, "{} bytes", saved.len());
    assert_eq!(render("second", &cache), ("hit".to_string(), image.clone()));

    // A flipped bit in wgpu's data: the file's hash no longer holds.
    let mut damaged = saved.clone();
    *damaged.last_mut().unwrap() ^= 1;
    // wgpu's own header naming another adapter, behind a hash that holds: wgpu refuses it.
    let mut foreign = saved.clone();
    let at = 48 + foreign[48..].windows(8).position(|w| w == b"WGPUPLCH").expect("wgpu's header") + 8 + 4 + 4 + 4;
    foreign[at..at + 8].iter_mut().for_each(|b| *b ^= 0x5a);
    let hash = *blake3::hash(&foreign[48..]).as_bytes();
    foreign[16..48].copy_from_slice(&hash);
    for (name, bytes) in [("truncated", &saved[..saved.len() / 2]), ("damaged", &damaged[..]), ("foreign", &foreign)] {
        std::fs::write(file, bytes).unwrap();
        assert_eq!(render(name, &cache), ("rejected".to_string(), image.clone()), "{name}");
        let now = std::fs::read(file).unwrap();
        assert!(now.starts_with(b"AOPLC001") && now != bytes, "{name}: the file is not replaced by this driver's");
    }
    assert_eq!(render("again", &cache), ("hit".to_string(), image.clone()));
    let (off, image_off) = render("off", std::path::Path::new("off"));
    assert_eq!((off.as_str(), image_off), ("off", image));
    assert!(!d.join("off").exists());
}
