//! The bulk PLY readers against the element-at-a-time reader they replace: the same
//! vertices and triangles, bit for bit, on the shipped dragons, the test corpus and the
//! dragon written in other layouts (binary of either byte order, doubles, lists before and
//! after the index list, skipped elements with lists); the same error, word for word, on
//! truncated, lying, over-budget and endless input.

use aorender::scene::{ReadLimits, read_ply_mesh};
use glam::Vec3;
use std::path::{Path, PathBuf};

#[path = "common/ply_layouts.rs"]
#[allow(dead_code)]
mod ply_layouts;
use ply_layouts::{FORMATS, Layout, damaged, endless, small_files, write_ply};

type Mesh = (Vec<Vec3>, Vec<[u32; 3]>);

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Both readers' results for `path`, checked to agree: equal meshes (positions compared
/// as bits) or equal messages.
fn agree(path: &Path, limits: &ReadLimits) -> Result<Mesh, String> {
    let reference = read_ply_mesh(path, limits, false).map_err(|e| e.to_string());
    let bulk = read_ply_mesh(path, limits, true).map_err(|e| e.to_string());
    type Bits = Result<(Vec<[u32; 3]>, Vec<[u32; 3]>), String>;
    let bits = |r: &Result<Mesh, String>| -> Bits {
        r.clone().map(|(p, t)| (p.iter().map(|v| v.to_array().map(f32::to_bits)).collect(), t))
    };
    assert_eq!(bits(&bulk), bits(&reference), "{}", path.display());
    bulk
}

#[test]
fn the_bulk_readers_give_the_reference_meshes_on_the_dragons_and_the_corpus() {
    let limits = ReadLimits::with_memory(4 << 30);
    let scenes = root().join("scenes");
    for name in ["dragon_vrip.ply.gz", "dragon_vrip_res2.ply.gz", "dragon_vrip_res3.ply.gz", "dragon_vrip_res4.ply.gz"]
    {
        let mesh = agree(&scenes.join(name), &limits).unwrap_or_else(|e| panic!("{e}"));
        assert!(mesh.1.len() > 10_000, "{name}: {} triangles", mesh.1.len());
    }
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let mut corpus = 0;
    for dir in ["malformed", "fuzz_regressions"] {
        for entry in std::fs::read_dir(tests.join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if path.to_string_lossy().contains(".ply") {
                let _ = agree(&path, &limits);
                corpus += 1;
            }
        }
    }
    assert!(corpus >= 15, "{corpus} PLY files in the corpus");
}

#[test]
fn the_bulk_readers_give_the_reference_meshes_in_every_layout() {
    let limits = ReadLimits::with_memory(4 << 30);
    let dragon = agree(&root().join("scenes/dragon_vrip_res2.ply.gz"), &limits).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for format in FORMATS {
        for layout in [Layout::Plain, Layout::Normals, Layout::Rich] {
            let path = dir.path().join(format!("{format}-{layout:?}.ply"));
            std::fs::write(&path, write_ply(&dragon.0, &dragon.1, format, layout)).unwrap();
            let mesh = agree(&path, &limits).unwrap_or_else(|e| panic!("{format} {layout:?}: {e}"));
            let quads = match layout {
                Layout::Plain => 0,
                Layout::Normals => (dragon.1.len() - 1).div_ceil(7),
                Layout::Rich => dragon.1.len().div_ceil(3) - usize::from(dragon.1.len() % 3 == 1),
            };
            assert_eq!(mesh.1.len(), dragon.1.len() + quads, "{format} {layout:?}");
            // The plain layout keeps the f32 coordinates as they are.
            if let Layout::Plain = layout {
                assert_eq!(mesh, dragon, "{format}");
            }
        }
    }
}

/// A small dragon in every format and the plain and rich layouts, with its header's length.
fn small_dragons() -> Vec<(String, Vec<u8>, usize)> {
    let dragon = agree(&root().join("scenes/dragon_vrip_res4.ply.gz"), &ReadLimits::with_memory(1 << 30)).unwrap();
    small_files(&dragon.0, &dragon.1, &[Layout::Plain, Layout::Rich])
}

#[test]
fn truncated_and_lying_files_fail_as_before() {
    let limits = ReadLimits::with_memory(1 << 30);
    let dir = tempfile::tempdir().unwrap();
    let mut failures = 0;
    for (name, bytes, header) in small_dragons() {
        failures += damaged(dir.path(), &name, &bytes, header, |path| agree(path, &limits).is_err());
    }
    assert!(failures > 6 * 97, "{failures} failures");
}

#[test]
fn over_budget_files_fail_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("budget.ply");
    for (name, bytes, _) in small_dragons() {
        std::fs::write(&path, &bytes).unwrap();
        let need = {
            let (p, t) = agree(&path, &ReadLimits::with_memory(1 << 30)).unwrap();
            (p.len() * 12 + t.len() * 12) as u64
        };
        // Budgets around what the mesh needs: refused at the header, while reading the
        // vertices, the faces, or a face's lists; or read.
        let mut refused = 0;
        for k in 1..=24 {
            refused += usize::from(agree(&path, &ReadLimits::with_memory(need * k / 12)).is_err());
        }
        assert!((6..24).contains(&refused), "{name}: {refused} budgets of 24 refused");
        // A face whose list would take more than the budget leaves it.
        let lines = ReadLimits::with_memory(4 << 20).with_line_bytes(64);
        let _ = agree(&path, &lines);
    }
}

#[test]
fn endless_input_fails_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let limits = ReadLimits::with_memory(1 << 20);
    let cases: [(&str, &str, &'static [u8]); 4] = [
        // Faces of zeros past the input cap: each face a list of no entries in a skipped
        // element first.
        (
            "binary_little_endian",
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
             element junk 1000000000000\nproperty list uchar uchar v\nelement face 1\n\
             property list uchar int vertex_indices\n",
            &[0],
        ),
        // A vertex whose list goes on for ever.
        (
            "binary_big_endian",
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
             property list uint uchar v\nelement face 1\nproperty list uchar int vertex_indices\n",
            &[0xff],
        ),
        // Faces (0, 0, 0) after 13 vertices (12 copies of the element), and data after the
        // last of them.
        (
            "binary_little_endian",
            "element vertex 13\nproperty float x\nproperty float y\nproperty float z\n\
             element face 80000\nproperty list uchar int vertex_indices\n",
            &[3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ),
        // Lines of an element before the faces, past the input cap.
        (
            "ascii",
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
             element junk 1000000000000\nproperty float v\nelement face 1\n\
             property list uchar int vertex_indices\n",
            b"0 0 0\n",
        ),
    ];
    for (k, (format, elements, element)) in cases.into_iter().enumerate() {
        let header = format!("ply\nformat {format} 1.0\n{elements}end_header\n");
        let mut messages = Vec::new();
        for bulk in [false, true] {
            let (path, writer) = endless(dir.path(), &format!("endless-{k}.ply"), &header, element);
            let message = read_ply_mesh(&path, &limits, bulk).map(|_| ()).unwrap_err().to_string();
            drop(std::fs::remove_file(&path));
            writer.join().unwrap();
            messages.push(message);
        }
        assert_eq!(messages[0], messages[1], "case {k}");
        println!("case {k}: {}", messages[1]);
    }
}

#[test]
fn plain_binary_runs_give_way_to_polygons_bad_indices_and_bad_coordinates_as_before() {
    let limits = ReadLimits::with_memory(1 << 30);
    let dragon = agree(&root().join("scenes/dragon_vrip_res4.ply.gz"), &limits).unwrap();
    let (nv, nf) = (dragon.0.len(), dragon.1.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain.ply");
    let mut differences = 0;
    for format in ["binary_little_endian", "binary_big_endian"] {
        let bytes = write_ply(&dragon.0, &dragon.1, format, Layout::Plain);
        let header = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let word = |v: u32| if format == "binary_big_endian" { v.to_be_bytes() } else { v.to_le_bytes() };
        let face = |k: usize| header + nv * 12 + k * 13;
        // (byte offset, bytes written there): a face's count of 4 and of 2 (the faces after
        // it misread), an index of -1, of the vertex count and past `int`'s range as
        // `uint`, a NaN and an infinite coordinate, in the middle of a buffer and at the
        // last face.
        let edits: Vec<(usize, Vec<u8>)> = vec![
            (face(nf / 2), vec![4]),
            (face(nf / 3), vec![2]),
            (face(nf / 2) + 5, word(u32::MAX).to_vec()),
            (face(nf - 1) + 9, word(nv as u32).to_vec()),
            (face(7) + 1, word(1 << 31).to_vec()),
            (header + 12 * (nv / 2) + 4, word(f32::NAN.to_bits()).to_vec()),
            (header + 12 * (nv - 1) + 8, word(f32::INFINITY.to_bits()).to_vec()),
        ];
        for (at, patch) in edits {
            let mut bad = bytes.clone();
            bad[at..at + patch.len()].copy_from_slice(&patch);
            std::fs::write(&path, &bad).unwrap();
            let message = agree(&path, &limits).map(|_| ()).unwrap_err();
            assert!(message.contains("plain.ply"), "{format}: {message}");
            differences += 1;
        }
        // A quad every 1000 faces (its fourth corner the next face's first), read whole.
        let mut quads = bytes[..face(0)].to_vec();
        for (k, t) in dragon.1.iter().enumerate() {
            let quad = k % 1000 == 999 && k + 1 < nf;
            quads.push(if quad { 4 } else { 3 });
            for &i in t.iter().chain(quad.then(|| &dragon.1[k + 1][0])) {
                quads.extend_from_slice(&word(i));
            }
        }
        std::fs::write(&path, &quads).unwrap();
        let mesh = agree(&path, &limits).unwrap_or_else(|e| panic!("{format}: {e}"));
        assert_eq!(mesh.1.len(), nf + (nf - 1) / 1000, "{format}");
    }
    assert_eq!(differences, 14);
}

#[test]
fn ascii_blocks_read_in_parallel_fail_where_and_as_the_line_at_a_time_reader_fails() {
    let limits = ReadLimits::with_memory(1 << 30);
    let dragon = agree(&root().join("scenes/dragon_vrip_res2.ply.gz"), &limits).unwrap();
    let (nv, nf) = (dragon.0.len(), dragon.1.len());
    let text = String::from_utf8(write_ply(&dragon.0, &dragon.1, "ascii", Layout::Plain)).unwrap();
    let header = text.find("end_header\n").unwrap() + 11;
    let lines: Vec<&str> = text[header..].lines().collect();
    assert_eq!(lines.len(), nv + nf);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ascii.ply");
    let long = "0 ".repeat(40_000);
    // (line of the data, its replacement, whether the file still reads): lines the fast
    // path refuses (a hexagon, many blanks), values the grammar refuses, a coordinate past
    // f32, indices out of range, a line longer than the line limit; in the first block,
    // past a block's end (1 MiB a thread) and at the last line.
    let edits: [(usize, &str, bool); 9] = [
        (nv + 5, "6 0 1 2 3 4 5", true),
        (nv / 2, "  0.5\t\t0.25   0.125  ", true),
        (3, "0.5 0.25 nan", false),
        (nv - 1, "1e39 0 0", false),
        (nv + nf / 2, "3 0 1 -1", false),
        (nv + nf - 1, &format!("3 0 1 {nv}"), false),
        (nv + nf / 3, "3 0 1 2x", false),
        (nv / 3, "0.5 0.25", false),
        (nv + nf / 4, &long, false),
    ];
    let pools = [1, 3].map(|n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap());
    for (k, (at, line, reads)) in edits.iter().enumerate() {
        let mut edited = lines.clone();
        edited[*at] = line;
        std::fs::write(&path, format!("{}{}\n", &text[..header], edited.join("\n"))).unwrap();
        let limits = ReadLimits::with_memory(1 << 30).with_line_bytes(1 << 16);
        for pool in &pools {
            let result = pool.install(|| agree(&path, &limits));
            assert_eq!(result.is_ok(), *reads, "edit {k}: {:?}", result.map(|_| ()));
        }
    }
}
