//! `aorender probe`: the command's CSV output and its input checks.

mod common;
use common::*;

#[test]
fn command_writes_csv_and_rejects_bad_points() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("points.txt"), "# x y z nx ny nz\n0 0 0 0 1 0\n5 0 0 0 2 0\n").unwrap();
    let out = aorender(&["probe", "--points", "points.txt", "-o", "ao.csv", "--samples", "64", "--device", "cpu"], d);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = std::fs::read_to_string(d.join("ao.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], "x,y,z,nx,ny,nz,ao,std_error,samples");
    assert_eq!(lines.len(), 3);
    assert!(lines[2].starts_with("5,0,0,0,1,0,"), "normal normalised: {}", lines[2]);
    assert!(lines[2].ends_with(",64"));

    for (points, message) in [
        ("0 0 0 0 1\n", "points.txt: line 1: expected 6 numbers"),
        ("0 0 0 0 0 0\n", "points.txt: line 1: zero normal"),
        ("0 0 nan 0 1 0\n", "points.txt: line 1: non-finite"),
        ("", "points.txt: no probes"),
    ] {
        std::fs::write(d.join("points.txt"), points).unwrap();
        let out = aorender(&["probe", "--points", "points.txt", "-o", "bad.csv", "--device", "cpu"], d);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{points:?}: {err}");
        assert!(err.contains(message) && err.lines().count() == 1, "{points:?}: {err}");
        assert!(!d.join("bad.csv").exists(), "{points:?}: output written");
    }
    let out = aorender(&["probe", "--points", "missing.txt", "--device", "cpu"], d);
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.txt: cannot read"));
    let out = aorender(&["probe", "--points", "points.txt", "--samples", "0", "--device", "cpu"], d);
    assert!(!out.status.success());
}

#[test]
fn points_on_no_surface_are_counted_and_the_tolerance_is_checked() {
    let dir = temp_dir();
    let d = dir.path();
    // On aobench's floor, and 5 above it.
    std::fs::write(d.join("points.txt"), "0 -0.5 -2 0 1 0\n# between\n0 4.5 -2 0 1 0\n").unwrap();
    let run = |extra: &[&str]| {
        let args = [&["probe", "--points", "points.txt", "-o", "ao.csv", "--samples", "64", "--device", "cpu"], extra];
        let out = aorender(&args.concat(), d);
        (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (code, err) = run(&[]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("2 probes × 64 samples") && err.contains("; 1 on no surface"), "{err}");
    assert!(err.contains("note: 1 of 2 points (the first on line 3 of points.txt) lie on no surface"), "{err}");
    // A tolerance past the second point's height takes it too.
    let (code, err) = run(&["--surface-tolerance", "5.5"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("; 0 on no surface") && !err.contains("note: "), "{err}");
    std::fs::remove_file(d.join("ao.csv")).unwrap();
    for bad in ["-1", "nan", "inf"] {
        let (code, err) = run(&[&format!("--surface-tolerance={bad}")]);
        assert_eq!(code, Some(1), "{bad}: {err}");
        assert!(
            err.starts_with(
                "aorender: invalid option: --surface-tolerance: surface tolerance must be a finite distance"
            ) && err.lines().count() == 1,
            "{bad}: {err}"
        );
        assert!(!d.join("ao.csv").exists(), "{bad}: output written");
    }
}

/// A probe run's statistics (`--stats`) account for its process phase by phase on both
/// devices, with the peak memory per point; with an error target they count its checks,
/// and the summary line says them.
#[test]
fn probe_stats_account_for_every_phase() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("points.txt"), "0 0 0 0 1 0\n1 0 -1 0 1 0\n-1 0.5 0 0 1 0\n").unwrap();
    let mut devices = vec!["cpu"];
    if gpu_available() {
        devices.push("gpu");
    }
    for device in devices {
        let args = ["probe", "--points", "points.txt", "-o", "ao.csv", "--samples", "256", "--device", device];
        let out = aorender(&[&args[..], &["--stats", "p.json"]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{device}: {stderr}");
        let stats = stats_json(d, "p.json");
        check_phases(&stats, device, Some(3));
        assert_eq!((stats["points"].as_u64(), stats["checks"].as_u64()), (Some(3), Some(0)), "{device}: {stats}");
        assert!(stderr.contains("read-back ") && stderr.contains("whole "), "{device}: {stderr}");
        check_summary(&stderr, device);

        let args = ["probe", "--points", "points.txt", "-o", "ao.csv", "--samples", "65536", "--device", device];
        let out = aorender(&[&args[..], &["--target-error", "0.02", "--stats", "t.json"]].concat(), d);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{device}: {stderr}");
        let stats = stats_json(d, "t.json");
        check_phases(&stats, device, Some(3));
        let checks = stats["checks"].as_u64().unwrap();
        assert!(checks >= 1, "{device}: {stats}");
        assert!(stats["largest_std_error"].as_f64().unwrap() <= 0.02, "{device}: {stats}");
        assert!(stderr.contains(&format!("({checks} checks)")), "{device}: {stderr}");
    }
}
