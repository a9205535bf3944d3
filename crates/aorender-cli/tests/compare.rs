//! `aorender compare`: the command's image and stats, and its refusal of bad lists and
//! outputs before rendering anything. (The grid's composition and the lists' validation
//! are unit tests of `src/commands/compare.rs`.)

mod common;
use aorender::{Hemisphere, Sampler};
use common::*;

use aorender_cli::commands::compare::Comparison;

#[test]
fn compare_writes_grid_and_stats() {
    let dir = temp_dir();
    let d = dir.path();
    let args = [
        "compare",
        "--width",
        "64",
        "--height",
        "32",
        "--spp",
        "1,4",
        "--sampler",
        "independent,stratified",
        "--device",
        "cpu",
        "-o",
        "grid.png",
        "--stats",
        "grid.json",
    ];
    let output = aorender(&args, d);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("rendering cosine/stratified at 4 spp (8 of 8)"), "{stderr}");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(stdout.lines().count(), 1 + 8, "a header and one line per cell: {stdout}");

    // Rows: for each sampler, for each hemisphere (uniform, then cosine by default).
    let rows = [
        (Sampler::Independent, Hemisphere::Uniform),
        (Sampler::Independent, Hemisphere::Cosine),
        (Sampler::Stratified, Hemisphere::Uniform),
        (Sampler::Stratified, Hemisphere::Cosine),
    ];
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("grid.json")).unwrap()).unwrap();
    assert_eq!(json["scene"], "aobench");
    assert_eq!((json["width"].as_u64(), json["height"].as_u64()), (Some(64), Some(32)));
    let cells = json["cells"].as_array().expect("cells");
    assert_eq!(cells.len(), 8);
    for (i, cell) in cells.iter().enumerate() {
        let (sampler, hemisphere) = rows[i / 2];
        let spp = [1, 4][i % 2];
        assert_eq!(cell["sampler"], sampler.name(), "cell {i}");
        assert_eq!(cell["hemisphere"], hemisphere.name(), "cell {i}");
        assert_eq!(cell["spp"], spp, "cell {i}");
        assert_eq!(cell["samples_per_pixel"], spp, "cell {i}");
        let mean = cell["image_mean"].as_f64().unwrap();
        assert!(mean > 0.2 && mean < 0.8, "cell {i}: mean {mean}");
        for key in ["render_seconds", "rays_per_second"] {
            assert!(cell[key].as_f64().is_some_and(|x| x >= 0.0), "cell {i}: {key}");
        }
    }

    // The image has the library's layout for this shape.
    let img = image::open(d.join("grid.png")).expect("PNG").to_luma8();
    let expected = Comparison {
        scene: "aobench".into(),
        width: 64,
        height: 32,
        seed: 0,
        sky: "uniform".into(),
        adapter: String::new(),
        backend: String::new(),
        total_seconds: 0.0,
        cells: Vec::new(),
        spps: vec![1, 4],
        rows: rows.to_vec(),
        tiles: vec![vec![0.0; 64 * 32]; 8],
    }
    .image();
    assert_eq!(img.dimensions(), expected.dimensions());
    assert!(img.width() > 2 * 64 && img.height() > 4 * 32);
    let mut files: Vec<String> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    files.sort();
    assert_eq!(files, ["grid.json", "grid.png"], "only the image and the stats, no temporary files");
}

#[test]
fn bad_input_is_one_line_and_no_output() {
    let dir = temp_dir();
    let d = dir.path();
    let base = ["compare", "--width", "8", "--height", "8", "--device", "cpu", "--stats", "s.json"];
    let cases: &[(&[&str], &str, &str)] = &[
        (&["--spp", "0", "-o", "g.png"], "g.png", "at least 1"),
        (&["--spp", "1,0", "-o", "g.png"], "g.png", "at least 1"),
        (&["--spp", "", "-o", "g.png"], "g.png", "--spp"),
        (&["--spp", "1,,4", "-o", "g.png"], "g.png", "--spp"),
        (&["--spp", "4,1,4", "-o", "g.png"], "g.png", "listed twice"),
        (&["--hemisphere", "cosine,cosine", "-o", "g.png"], "g.png", "cosine"),
        (&["--hemisphere", "spherical", "-o", "g.png"], "g.png", "spherical"),
        (&["--sampler", "halton", "-o", "g.png"], "g.png", "halton"),
        (&["--sampler", "", "-o", "g.png"], "g.png", "--sampler"),
        (&["-o", "g.jpg"], "g.jpg", "g.jpg"),
        (&["--max-distance", "-1", "-o", "g.png"], "g.png", "max distance"),
        (&["missing.toml", "-o", "g.png"], "g.png", "missing.toml"),
    ];
    for (extra, out, expect) in cases {
        let args = [&base[..], extra].concat();
        let output = aorender(&args, d);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{args:?} succeeded");
        assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
        let lines: Vec<&str> = stderr.lines().collect();
        assert_eq!(lines.len(), 1, "{args:?}: expected one line, got: {stderr}");
        assert!(lines[0].starts_with("aorender: ") && lines[0].contains(expect), "{args:?}: {}", lines[0]);
        assert!(!d.join(out).exists(), "{args:?} wrote {out}");
        assert!(!d.join("s.json").exists(), "{args:?} wrote the stats");
        assert_eq!(std::fs::read_dir(d).unwrap().count(), 0, "{args:?} left files");
    }
}
