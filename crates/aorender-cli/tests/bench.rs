//! `aorender bench --quick`, the CI smoke check of the benchmark: it exits 0, its JSON and
//! CSV hold every scene × configuration with finite positive figures, unbiased samplers
//! converge (independent sampling at the rate σ²/N), the plots decode, and a second run
//! reuses the cached references. Under the overcast sky its samplings are measured against
//! each other and agree with the closed form. Bad input is refused with a one-line error.

mod common;
use common::*;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::Path;

/// The scenes of `--quick`.
const QUICK_SCENES: [&str; 3] = ["aobench", "dragon_vrip_res4", "bunny"];
const HEMISPHERES: [&str; 3] = ["uniform", "cosine", "cosine-polar"];
const SAMPLERS: [&str; 4] = ["independent", "stratified", "grid", "sobol"];

fn run_bench(args: &[&str]) -> std::process::Output {
    let out = aorender(args, &repo());
    assert!(
        out.status.success(),
        "aorender {} failed ({:?}):\n{}",
        args.join(" "),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn f(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("{key} is not a number in {v}"))
}

fn s<'a>(v: &'a Value, key: &str) -> &'a str {
    v[key].as_str().unwrap_or_else(|| panic!("{key} is not a string in {v}"))
}

/// Checks one run's checkpoints: 1, 2, 4, …, N with finite positive timings and rays and
/// finite errors.
fn check_checkpoints(scene: &str, run: &Value, n: u64) {
    let cps = run["checkpoints"].as_array().expect("checkpoints");
    let spps: Vec<u64> = cps.iter().map(|c| c["spp"].as_u64().expect("spp")).collect();
    let expected: Vec<u64> = std::iter::successors(Some(1u64), |&k| (k < n).then_some(2 * k)).collect();
    assert_eq!(spps, expected, "{scene}: checkpoints of {run}");
    let mut last_rays = 0.0;
    for c in cps {
        for key in ["seconds", "wall_seconds", "rays", "rays_per_second", "rmse", "mse_std_error"] {
            let v = f(c, key);
            assert!(v.is_finite() && v > 0.0, "{scene}: {key} = {v} in {c}");
        }
        for key in ["mse", "rel_mse", "image_mean"] {
            assert!(f(c, key).is_finite(), "{scene}: {key} in {c}");
        }
        // Rays grow with samples: at least one camera ray per pixel per sample.
        assert!(f(c, "rays") > last_rays);
        last_rays = f(c, "rays");
    }
}

/// MSE at 1 and at N samples of a run, with their standard errors.
fn ends(run: &Value) -> ((f64, f64), (f64, f64), f64) {
    let cps = run["checkpoints"].as_array().expect("checkpoints");
    let (a, b) = (&cps[0], &cps[cps.len() - 1]);
    ((f(a, "mse"), f(a, "mse_std_error")), (f(b, "mse"), f(b, "mse_std_error")), f(b, "spp"))
}

#[test]
fn quick_mode_writes_complete_results_and_reuses_its_references() {
    if !gpu_available() {
        return;
    }
    let tmp = temp_dir();
    let out_dir = tmp.path().join("out");
    let cache = tmp.path().join("cache");
    let (out_s, cache_s) = (out_dir.to_str().unwrap(), cache.to_str().unwrap());
    let output = run_bench(&["bench", "--quick", "--out", out_s, "--cache", cache_s]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(stdout.contains("Convergence"), "no table on stdout:\n{stdout}");

    let results = read_json(&out_dir.join("results.json"));
    assert!(results["failures"].as_array().expect("failures").is_empty());
    let scenes = results["scenes"].as_array().expect("scenes");
    let names: Vec<&str> = scenes.iter().map(|sc| s(sc, "name")).collect();
    assert_eq!(names, QUICK_SCENES);

    let mut json_rows = BTreeSet::new();
    for sc in scenes {
        let name = s(sc, "name");
        let n = sc["max_spp"].as_u64().expect("max_spp");
        let floor = f(&sc["reference"], "rmse_floor");
        assert!(floor.is_finite() && floor > 0.0, "{name}: reference floor {floor}");
        assert_eq!(sc["reference"]["cached"], Value::Bool(false));
        let runs = sc["runs"].as_array().expect("runs");
        let mut configs = BTreeSet::new();
        for run in runs {
            let (dev, h, smp) = (s(run, "device"), s(run, "hemisphere"), s(run, "sampler"));
            check_checkpoints(name, run, n);
            for c in run["checkpoints"].as_array().unwrap() {
                json_rows.insert((
                    name.to_string(),
                    dev.to_string(),
                    h.to_string(),
                    smp.to_string(),
                    c["spp"].as_u64().unwrap(),
                ));
            }
            if dev == "gpu" {
                configs.insert((h, smp));
            }
            if smp == "grid" {
                continue;
            }
            // Every unbiased run converges: the MSE at N is below the MSE at 1 by more than
            // 4 standard errors of their difference.
            let ((m1, e1), (mn, en), spp) = ends(run);
            let margin = 4.0 * (e1 * e1 + en * en).sqrt();
            assert!(m1 - mn > margin, "{name} {dev} {h}/{smp}: MSE {m1} at 1 spp, {mn} at {spp} (± {margin})");
            // Independent samples: MSE(N) = MSE(1)/N, within 4 standard errors of the ratio.
            if smp == "independent" {
                let ratio = m1 / (spp * mn);
                let rel = ((e1 / m1).powi(2) + (en / mn).powi(2)).sqrt();
                assert!((ratio - 1.0).abs() < 4.0 * rel, "{name} {dev} {h}: MSE(1)/(N·MSE(N)) = {ratio} ± {rel}");
            }
        }
        let expected: BTreeSet<(&str, &str)> =
            HEMISPHERES.iter().flat_map(|h| SAMPLERS.iter().map(move |smp| (*h, *smp))).collect();
        assert_eq!(configs, expected, "{name}: GPU configurations");
        assert!(runs.iter().any(|r| s(r, "device") == "cpu"), "{name}: no CPU run");
        let gc = &sc["gpu_cpu"];
        for key in ["gpu_rays_per_second", "cpu_rays_per_second", "ratio"] {
            assert!(f(gc, key).is_finite() && f(gc, key) > 0.0, "{name}: {key}");
        }
        // The GPU and the CPU trace the same samples: the same image up to rays that graze
        // an edge, as in tests/gpu_vs_cpu.rs.
        assert!(f(gc, "matching_pixels") >= 0.99, "{name}: GPU and CPU images differ: {gc}");
        assert!(sc["best"]["efficiency"].as_f64().is_some_and(|e| e.is_finite() && e > 0.0), "{name}: best");
    }

    // The CSV holds the same rows, every number finite.
    let csv = std::fs::read_to_string(out_dir.join("results.csv")).expect("results.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("no column {name}"));
    let mut csv_rows = BTreeSet::new();
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), header.len(), "row {line}");
        for key in ["seconds", "wall_seconds", "rays", "rays_per_second", "rmse", "mse_std_error"] {
            let v: f64 = cells[col(key)].parse().unwrap_or_else(|e| panic!("{key} in {line}: {e}"));
            assert!(v.is_finite() && v > 0.0, "{key} in {line}");
        }
        for key in ["mse", "rel_mse", "reference_rmse_floor"] {
            let v: f64 = cells[col(key)].parse().unwrap_or_else(|e| panic!("{key} in {line}: {e}"));
            assert!(v.is_finite(), "{key} in {line}");
        }
        csv_rows.insert((
            cells[col("scene")].to_string(),
            cells[col("device")].to_string(),
            cells[col("hemisphere")].to_string(),
            cells[col("sampler")].to_string(),
            cells[col("spp")].parse::<u64>().expect("spp"),
        ));
    }
    assert_eq!(csv_rows, json_rows);

    // The presets and scaling series are there, with positive figures.
    let presets = results["bvh_presets"].as_array().expect("presets");
    let names: Vec<&str> = presets.iter().map(|p| s(p, "preset")).collect();
    assert_eq!(names, ["fastest", "fast", "medium", "slow"]);
    for p in presets {
        assert!(f(p, "build_seconds") > 0.0 && f(p, "gpu_rays_per_second") > 0.0 && f(p, "nodes") > 0.0, "{p}");
    }
    let scaling = results["scaling"].as_array().expect("scaling");
    for series in ["triangles", "resolution", "spp"] {
        let pts: Vec<&Value> = scaling.iter().filter(|p| s(p, "series") == series).collect();
        assert!(!pts.is_empty(), "no {series} series");
        for p in pts {
            assert!(f(p, "seconds_per_mray").is_finite() && f(p, "seconds_per_mray") > 0.0, "{p}");
        }
    }

    // The plots decode and are not blank.
    for png in ["convergence_spp.png", "convergence_seconds.png", "rays_vs_triangles.png", "scaling.png"] {
        let img = image::open(out_dir.join(png)).unwrap_or_else(|e| panic!("{png}: {e}")).to_rgb8();
        assert!(img.width() >= 400 && img.height() >= 300, "{png}: {}x{}", img.width(), img.height());
        let first = *img.get_pixel(0, 0);
        assert!(img.pixels().filter(|p| **p != first).count() > 1000, "{png} is blank");
    }

    // A second run reuses the references and, with the same seed, renders the same images.
    let again = tmp.path().join("again");
    run_bench(&[
        "bench",
        "--quick",
        "--no-cpu",
        "--hemisphere",
        "cosine",
        "--sampler",
        "independent",
        "--out",
        again.to_str().unwrap(),
        "--cache",
        cache_s,
    ]);
    let second = read_json(&again.join("results.json"));
    for (a, b) in scenes.iter().zip(second["scenes"].as_array().expect("scenes")) {
        assert_eq!(b["reference"]["cached"], Value::Bool(true), "{}", s(b, "name"));
        assert_eq!(a["reference"]["rmse_floor"], b["reference"]["rmse_floor"]);
        let runs = b["runs"].as_array().unwrap();
        assert_eq!(runs.len(), 1);
        let first =
            a["runs"].as_array().unwrap().iter().find(|r| {
                s(r, "device") == "gpu" && s(r, "hemisphere") == "cosine" && s(r, "sampler") == "independent"
            });
        let last = |r: &Value| r["checkpoints"].as_array().unwrap().last().unwrap()["mse"].clone();
        assert_eq!(last(first.expect("cosine/independent")), last(&runs[0]), "{}", s(b, "name"));
    }
}

/// The overcast sky's irradiance of an unoccluded plane tilted by `beta` from the zenith,
/// over a horizontal one's (docs/sampling.md).
fn overcast_plane(beta: f64) -> f64 {
    use std::f64::consts::PI;
    (3.0 * PI * (1.0 + beta.cos()) + 8.0 * ((PI - beta) * beta.cos() + beta.sin())) / (14.0 * PI)
}

/// `bench --sky overcast` on an open plane tilted by 60°, seen face-on so that every pixel
/// is the plane: a run per sky sampling, horizon the baseline; the control variate exact
/// with no variance, the others within 4 standard errors of the closed form, weighted
/// cosine sampling noisier than horizon-clipped sampling; the sky's table on stdout.
#[test]
fn overcast_sky_samplings_are_measured_against_each_other() {
    if !gpu_available() {
        return;
    }
    let tmp = temp_dir();
    let beta = 60f64.to_radians();
    let (sin, cos) = beta.sin_cos();
    let scene = tmp.path().join("plane.toml");
    std::fs::write(
        &scene,
        format!(
            "[camera]\ntype = \"orthographic\"\neye = [{}, {}, 0.0]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\n\
             height = 1.0\n\n[[object]]\ntype = \"plane\"\npoint = [0.0, 0.0, 0.0]\nnormal = [{sin}, {cos}, 0.0]\n",
            2.0 * sin,
            2.0 * cos
        ),
    )
    .unwrap();
    let out_dir = tmp.path().join("out");
    let cache = tmp.path().join("cache");
    let output = run_bench(&[
        "bench",
        scene.to_str().unwrap(),
        "--sky",
        "overcast",
        "--hemisphere",
        "cosine",
        "--sampler",
        "independent",
        "--no-cpu",
        "--size",
        "16",
        "--spp",
        "16",
        "--reference-spp",
        "64",
        "--out",
        out_dir.to_str().unwrap(),
        "--cache",
        cache.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&output.stdout);
    let table = stdout.split("Overcast sky").nth(1).unwrap_or_else(|| panic!("no sky table on stdout:\n{stdout}"));
    for sampling in ["horizon", "control-variate", "weighted cosine"] {
        assert!(table.lines().any(|l| l.starts_with("plane") && l.contains(sampling)), "no {sampling} row:\n{stdout}");
    }

    let results = read_json(&out_dir.join("results.json"));
    let sc = &results["scenes"][0];
    assert!(s(sc, "sky").starts_with("overcast (up 0,1,0"), "{}", s(sc, "sky"));
    let runs = sc["runs"].as_array().expect("runs");
    let names: Vec<&str> = runs.iter().map(|r| s(r, "sky_sampling")).collect();
    assert_eq!(names, ["horizon", "control-variate", "weighted"]);
    let baselines: Vec<bool> = runs.iter().map(|r| r["baseline"].as_bool().expect("baseline")).collect();
    assert_eq!(baselines, [true, false, false]);
    let expected = overcast_plane(beta);
    let pixel_samples = f(sc, "width") * f(sc, "height") * f(sc, "max_spp");
    let mut variance = std::collections::BTreeMap::new();
    for run in runs {
        let name = s(run, "sky_sampling");
        let var = f(run, "variance_per_sample");
        let mean = f(run["checkpoints"].as_array().unwrap().last().unwrap(), "image_mean");
        if name == "control-variate" {
            // Every sample is the closed form, in f32 (a few units of its last place).
            assert_eq!(var, 0.0, "control variate: variance {var}");
            assert!((mean - expected).abs() < 1e-6, "control variate: {mean}, closed form {expected}");
        } else {
            // Every pixel's mean is independent of the others': the image mean's standard
            // error is √(σ² / (pixels × N)).
            let se = (var / pixel_samples).sqrt();
            assert!(var > 0.0 && (mean - expected).abs() < 4.0 * se, "{name}: {mean} ± {se}, closed form {expected}");
            assert!(f(run, "variance_seconds") > 0.0, "{name}: {run}");
        }
        variance.insert(name, var);
    }
    // Weighted cosine sampling spends a quarter of its rays below the horizon at 60°.
    assert!(variance["weighted"] > variance["horizon"], "{variance:?}");
}

/// A scene path that does not exist, or does not parse, is refused in one line naming the
/// file, before anything runs; so are bad options.
#[test]
fn bad_scenes_and_options_are_refused_in_one_line() {
    let tmp = temp_dir();
    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "[camera]\ntype = \"perspective\"\nfov = 40\n").unwrap();
    let missing = tmp.path().join("missing.obj");
    let out_dir = tmp.path().join("out");
    let cases: [(Vec<&str>, String); 6] = [
        (vec!["bench", missing.to_str().unwrap()], format!("aorender: {}: ", missing.display())),
        (vec!["bench", bad.to_str().unwrap()], format!("aorender: {}: ", bad.display())),
        (vec!["bench", "--quick", "--spp", "12"], "aorender: invalid option: --spp must be a power of two".into()),
        (
            vec!["bench", "--quick", "--scenes-dir", tmp.path().to_str().unwrap()],
            format!("aorender: {}: no such file", tmp.path().join("dragon_vrip_res4.ply.gz").display()),
        ),
        (
            vec!["bench", "--quick", "--sky-sampling", "weighted"],
            "aorender: invalid option: --sky-sampling needs --sky overcast".into(),
        ),
        (
            vec!["bench", "--quick", "--sky", "overcast", "--sky-normalise", "surface", "--sky-sampling", "weighted"],
            "aorender: invalid option: surface normalisation needs the horizon or control-variate".into(),
        ),
    ];
    for (mut args, prefix) in cases {
        args.extend(["--out", out_dir.to_str().unwrap()]);
        let out = aorender(&args, &repo());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.starts_with(&prefix), "{args:?}: expected {prefix:?}, got {stderr}");
        assert!(!out_dir.exists(), "{args:?} wrote {}", out_dir.display());
    }
}
