//! `aorender compare`: the grid's composition (tiles, labels, size), the command's image
//! and stats, and its refusal of bad lists and outputs before rendering anything.

mod common;
use aorender::compare::{self, Comparison, Grid, compose_grid};
use aorender::film::linear_to_srgb8;
use aorender::{Hemisphere, Sampler};
use common::*;
use image::GrayImage;

/// The sRGB code of a linear value, computed independently of the library.
fn srgb8(v: f64) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.0031308 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0).round() as u8
}

/// Bounding box (x0, y0, x1, y1), exclusive ends, and count of the pixels equal to `value`.
fn pixels_equal_to(img: &GrayImage, value: u8) -> ((u32, u32, u32, u32), usize) {
    let (mut x0, mut y0, mut x1, mut y1, mut n) = (u32::MAX, u32::MAX, 0, 0, 0);
    for (x, y, p) in img.enumerate_pixels() {
        if p.0[0] == value {
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            n += 1;
        }
    }
    ((x0, y0, x1, y1), n)
}

/// Pixels darker than the tiles' darkest value inside the rectangle [x0, x1) × [y0, y1).
fn dark_pixels(img: &GrayImage, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> usize {
    (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| img.get_pixel(x, y).0[0] < 32).count()
}

#[test]
fn grid_places_constant_tiles_and_dark_labels() {
    let (tw, th) = (120u32, 48u32);
    // Distinct sRGB codes, none of them the background or the text: each tile can be found
    // by its value. 4.0 is clamped to white.
    let values = [0.02, 0.1, 0.25, 0.5, 0.75, 4.0];
    let tiles: Vec<Vec<f64>> = values.iter().map(|&v| vec![v; (tw * th) as usize]).collect();
    let columns: Vec<String> = ["1 spp", "4 spp", "16 spp"].map(String::from).to_vec();
    let rows = vec![vec!["uniform".to_string(), "independent".to_string()], vec!["cosine".into(), "sobol".into()]];
    let img = compose_grid(&Grid {
        title: "test scene",
        columns: &columns,
        rows: &rows,
        tile_width: tw,
        tile_height: th,
        tiles: &tiles,
    });

    let mut boxes = Vec::new();
    for &v in &values {
        assert_eq!(linear_to_srgb8(v as f32), srgb8(v), "sRGB code of {v}");
        let (bbox, n) = pixels_equal_to(&img, srgb8(v));
        assert_eq!(n, (tw * th) as usize, "pixels of the tile of value {v}");
        assert_eq!((bbox.2 - bbox.0, bbox.3 - bbox.1), (tw, th), "tile of value {v} is not one rectangle");
        boxes.push(bbox);
    }
    assert_eq!(linear_to_srgb8(-1.0f32), 0);
    assert_eq!(linear_to_srgb8(f32::NAN), 0);

    // Row-major order, aligned, separated by a small gap.
    let gap_x = boxes[1].0 - boxes[0].2;
    let gap_y = boxes[3].1 - boxes[0].3;
    assert!((1..=16).contains(&gap_x) && (1..=16).contains(&gap_y), "gaps {gap_x}, {gap_y}");
    for r in 0..2 {
        for c in 0..3 {
            let b = boxes[r * 3 + c];
            assert_eq!(b.0, boxes[0].0 + c as u32 * (tw + gap_x), "tile {r},{c} x");
            assert_eq!(b.1, boxes[0].1 + r as u32 * (th + gap_y), "tile {r},{c} y");
        }
    }
    // The image: the tiles, labels above and left of them, and a narrow border.
    let last = boxes[5];
    assert!((1..=32).contains(&(img.width() - last.2)), "right border of {}", img.width() - last.2);
    assert!((1..=32).contains(&(img.height() - last.3)), "bottom border of {}", img.height() - last.3);
    let label_w = "independent".len() as u32 * 16;
    assert!(boxes[0].0 >= label_w, "row labels need {label_w} px, tiles start at {}", boxes[0].0);
    assert!(boxes[0].1 >= 2 * 16, "title and column labels need two lines, tiles start at {}", boxes[0].1);

    // Background is light; labels are dark text in their places.
    assert!(img.get_pixel(0, 0).0[0] > 200, "background is light");
    let top = boxes[0].1;
    let title_band = (0, 0, img.width(), top / 2);
    assert!(dark_pixels(&img, title_band) > 20, "title has no text");
    for (c, b) in boxes[..3].iter().enumerate() {
        assert!(dark_pixels(&img, (b.0, top / 2, b.2, top)) > 20, "column label {c} has no text");
    }
    for (r, b) in [boxes[0], boxes[3]].iter().enumerate() {
        let upper = dark_pixels(&img, (0, b.1, b.0, b.1 + th / 2));
        let lower = dark_pixels(&img, (0, b.1 + th / 2, b.0, b.3));
        assert!(upper > 20 && lower > 20, "row label {r} lacks a line of text: {upper}, {lower}");
    }
    // Nothing dark between the tiles.
    assert_eq!(dark_pixels(&img, (boxes[0].2, boxes[0].1, boxes[1].0, boxes[0].3)), 0);
}

#[test]
fn lists_are_validated() {
    let (h, s) = ([Hemisphere::Cosine], [Sampler::Independent]);
    assert!(compare::validate(&[1, 4], &h, &s).is_ok());
    /// Sample counts, hemispheres, samplers, and a word the message must contain.
    type Case<'a> = (&'a [u32], &'a [Hemisphere], &'a [Sampler], &'a str);
    let cases: &[Case] = &[
        (&[], &h, &s, "empty"),
        (&[1], &[], &s, "empty"),
        (&[1], &h, &[], "empty"),
        (&[1, 0], &h, &s, "at least 1"),
        (&[4, 1, 4], &h, &s, "4"),
        (&[1], &[Hemisphere::Uniform, Hemisphere::Uniform], &s, "uniform"),
        (&[1], &h, &[Sampler::Sobol, Sampler::Grid, Sampler::Sobol], "sobol"),
    ];
    for (spps, hemispheres, samplers, expect) in cases {
        let e = compare::validate(spps, hemispheres, samplers).expect_err("invalid lists");
        assert!(e.contains(expect) && !e.contains('\n'), "{spps:?} {hemispheres:?} {samplers:?}: {e}");
    }
}

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
