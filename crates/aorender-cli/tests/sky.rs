//! The overcast sky on the command line: bad values get one line before any work,
//! checkpoints record the sky and refuse a resume or a merge with another one, and
//! resumed and merged shards give the single run's bits.

mod common;
use common::*;

const RENDER: [&str; 9] = ["render", "--device", "cpu", "--width", "24", "--height", "16", "--spp", "16"];

/// Runs `args`; asserts a non-zero exit, one line on standard error containing every
/// word of `expect`, and no output file.
fn refused(dir: &std::path::Path, args: &[&str], expect: &[&str]) {
    let out = aorender(args, dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: not one line: {stderr}");
    for word in expect {
        assert!(stderr.contains(word), "{args:?}: '{word}' not in: {stderr}");
    }
    for name in ["out.png", "out.json", "ao.json"] {
        assert!(!dir.join(name).exists(), "{args:?} wrote {name}");
    }
}

#[test]
fn bad_sky_values_get_one_line_before_any_work() {
    let dir = temp_dir();
    let cases: &[(&[&str], &[&str])] = &[
        (&["--sky", "overcast", "--up", "0,0,0"], &["--up", "finite and non-zero"]),
        (&["--sky", "overcast", "--up", "nan,1,0"], &["--up", "finite and non-zero"]),
        (&["--sky", "overcast", "--up", "inf,1,0"], &["--up", "finite and non-zero"]),
        (&["--sky", "overcast", "--up", "0,1"], &["--up", "X,Y,Z"]),
        (&["--sky", "overcast", "--ground-albedo", "1.5"], &["--ground-albedo", "outside [0, 1]"]),
        (&["--sky", "overcast", "--ground-albedo", "-0.25"], &["--ground-albedo", "outside [0, 1]"]),
        (&["--sky", "overcast", "--ground-albedo", "nan"], &["--ground-albedo", "outside [0, 1]"]),
        (&["--sky-normalise", "surface"], &["--sky-normalise needs --sky overcast"]),
        (&["--sky", "uniform", "--ground-albedo", "0.5"], &["--ground-albedo needs --sky overcast"]),
        (&["--sky-sampling", "control-variate"], &["--sky-sampling needs --sky overcast"]),
        (
            &["--sky", "overcast", "--sky-sampling", "weighted", "--sky-normalise", "surface"],
            &["surface normalisation", "unbounded"],
        ),
    ];
    for (extra, expect) in cases {
        refused(dir.path(), &[&RENDER[..], &["-o", "out.png"], extra].concat(), expect);
    }
    // The other commands take the same options.
    std::fs::write(dir.path().join("points.txt"), "0 0 0 0 1 0\n").unwrap();
    let probe = ["probe", "--device", "cpu", "--points", "points.txt", "-o", "ao.csv", "--sky-normalise", "surface"];
    refused(dir.path(), &probe, &["--sky-normalise needs --sky overcast"]);
    assert!(!dir.path().join("ao.csv").exists());
    let compare = ["compare", "--device", "cpu", "--spp", "1", "-o", "out.png", "--sky", "overcast", "--up", "0,0,0"];
    refused(dir.path(), &compare, &["--up"]);
}

#[test]
fn checkpoints_record_the_sky_resume_and_merge_to_the_single_runs_bits() {
    let dir = temp_dir();
    let d = dir.path();
    let sky = ["--sky", "overcast", "--up", "0,1,0.2", "--ground-albedo", "0.3", "--sky-sampling", "control-variate"];
    let run = |extra: &[&str]| {
        let out = aorender(&[&RENDER[..], &sky[..], extra].concat(), d);
        assert!(out.status.success(), "{extra:?}: {}", String::from_utf8_lossy(&out.stderr));
    };
    run(&["-o", "whole.pfm"]);
    run(&["--sample-range", "0..5", "--checkpoint", "a.ckpt", "-o", "a.pfm"]);
    run(&["--sample-range", "5..16", "--checkpoint", "b.ckpt", "-o", "b.pfm"]);
    let merged = aorender(&["merge", "a.ckpt", "b.ckpt", "-o", "merged.pfm"], d);
    assert!(merged.status.success(), "{}", String::from_utf8_lossy(&merged.stderr));
    let whole = std::fs::read(d.join("whole.pfm")).unwrap();
    assert_eq!(std::fs::read(d.join("merged.pfm")).unwrap(), whole, "merged shards differ from one run");

    // A resume with another sky is refused, naming it; with the same one it continues to
    // the single run's bits.
    std::fs::copy(d.join("a.ckpt"), d.join("r.ckpt")).unwrap();
    let grey = ["--sky", "overcast", "--up", "0,1,0.2", "--ground-albedo", "0.4", "--sky-sampling", "control-variate"];
    for other in [&["--sky", "uniform"][..], &["--sky", "overcast"][..], &grey[..]] {
        let out = aorender(&[&RENDER[..], other, &["--resume", "r.ckpt", "-o", "out.png"]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && stderr.contains("sky overcast"), "{other:?}: {stderr}");
        assert!(!d.join("out.png").exists());
    }
    run(&["--resume", "r.ckpt", "-o", "resumed.pfm"]);
    assert_eq!(std::fs::read(d.join("resumed.pfm")).unwrap(), whole, "the resumed render differs from one run");

    // Shards of two skies do not merge.
    let uniform =
        aorender(&[&RENDER[..], &["--sample-range", "5..16", "--checkpoint", "u.ckpt", "-o", "u.pfm"]].concat(), d);
    assert!(uniform.status.success());
    let mixed = aorender(&["merge", "a.ckpt", "u.ckpt", "-o", "mixed.pfm"], d);
    let stderr = String::from_utf8_lossy(&mixed.stderr);
    assert!(!mixed.status.success() && stderr.contains("sky"), "{stderr}");
    assert!(!d.join("mixed.pfm").exists());
}

#[test]
fn compare_records_the_sky_of_its_cells() {
    let dir = temp_dir();
    let d = dir.path();
    let args = [
        "compare",
        "--device",
        "cpu",
        "--width",
        "16",
        "--height",
        "12",
        "--spp",
        "1,4",
        "--sky",
        "overcast",
        "--sky-sampling",
        "control-variate",
        "-o",
        "grid.png",
        "--stats",
        "grid.json",
    ];
    let out = aorender(&args, d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("grid.json")).unwrap()).unwrap();
    let sky = stats["sky"].as_str().expect("a sky");
    assert!(sky.starts_with("overcast") && sky.contains("control-variate sampling"), "{sky}");
    let uniform = aorender(
        &[
            "compare", "--device", "cpu", "--width", "16", "--height", "12", "--spp", "1", "-o", "u.png", "--stats",
            "u.json",
        ],
        d,
    );
    assert!(uniform.status.success());
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("u.json")).unwrap()).unwrap();
    assert_eq!(stats["sky"], "uniform");
}
