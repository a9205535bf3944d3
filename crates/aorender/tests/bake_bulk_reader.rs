//! The bake's PLY reader in runs against its element-at-a-time reader: every element and
//! column the bake keeps (in the file's own types) and the mesh it traces, byte for byte,
//! on the shipped dragons, the shared scenes, the test corpus and the dragon written in
//! other layouts (binary of either byte order and ASCII, doubles, normals and colours,
//! polygons, lists before and after the index list, elements the mesh does not use); the
//! same error, word for word, on truncated, lying, corrupt, over-budget and endless input.

use aorender::bake::PlyAsset;
use aorender::scene::{LoadOptions, ReadLimits, read_ply_mesh};
use std::path::{Path, PathBuf};

#[path = "common/ply_layouts.rs"]
#[allow(dead_code)]
mod ply_layouts;
use ply_layouts::{FORMATS, Layout, damaged, endless, small_files, write_ply};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn options(limits: ReadLimits) -> LoadOptions {
    LoadOptions { limits, allow_external_uris: false }
}

/// Both readers' results for `path`, checked to agree: the same bytes, or the same
/// message. The bytes, or the message.
fn agree(path: &Path, limits: &ReadLimits) -> Result<Vec<u8>, String> {
    let options = options(limits.clone());
    let reference = PlyAsset::read_bits(path, &options, false).map_err(|e| e.to_string());
    let bulk = PlyAsset::read_bits(path, &options, true).map_err(|e| e.to_string());
    match (&reference, &bulk) {
        (Ok(a), Ok(b)) => {
            let first = a.iter().zip(b).position(|(x, y)| x != y);
            assert!(a == b, "{}: {} and {} bytes, first difference at {first:?}", path.display(), a.len(), b.len());
        }
        _ => assert_eq!(reference.as_ref().err(), bulk.as_ref().err(), "{}", path.display()),
    }
    bulk
}

const LAYOUTS: [Layout; 3] = [Layout::Plain, Layout::Normals, Layout::Rich];

/// The dragon of `name` in `scenes/`, as the scene loader reads it.
fn dragon(name: &str) -> (Vec<glam::Vec3>, Vec<[u32; 3]>) {
    read_ply_mesh(&root().join("scenes").join(name), &ReadLimits::with_memory(1 << 30), true).unwrap()
}

#[test]
fn runs_give_the_reference_on_the_dragons_the_shared_scenes_and_the_corpus() {
    let limits = ReadLimits::with_memory(4 << 30);
    let mut dragons = 0;
    // The shared scenes are those of a checkout beside this one, where there is one.
    for dir in [root().join("scenes"), root().join("../shared/scenes")] {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            if path.to_string_lossy().ends_with(".ply.gz") || path.to_string_lossy().ends_with(".ply") {
                let bytes = agree(&path, &limits).unwrap_or_else(|e| panic!("{e}"));
                assert!(bytes.len() > 100_000, "{}: {} bytes", path.display(), bytes.len());
                dragons += 1;
            }
        }
    }
    assert!(dragons >= 4, "{dragons} PLY files in scenes/");
    let tests = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests");
    let (mut corpus, mut read) = (0, 0);
    for dir in ["malformed", "fuzz_regressions", "data"] {
        let Ok(entries) = std::fs::read_dir(tests.join(dir)) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            if path.to_string_lossy().contains(".ply") {
                read += usize::from(agree(&path, &limits).is_ok());
                corpus += 1;
            }
        }
    }
    assert!(corpus >= 15, "{corpus} PLY files in the corpus");
    assert!(read < corpus, "every file of the malformed corpus read");
}

#[test]
fn runs_give_the_reference_in_every_layout() {
    let limits = ReadLimits::with_memory(4 << 30);
    let (positions, triangles) = dragon("dragon_vrip_res2.ply.gz");
    let dir = tempfile::tempdir().unwrap();
    let mut sizes = Vec::new();
    for format in FORMATS {
        for layout in LAYOUTS {
            let path = dir.path().join(format!("{format}-{layout:?}.ply"));
            std::fs::write(&path, write_ply(&positions, &triangles, format, layout)).unwrap();
            let bytes = agree(&path, &limits).unwrap_or_else(|e| panic!("{format} {layout:?}: {e}"));
            sizes.push((format, layout, bytes.len()));
        }
    }
    // Every encoding of a layout holds the same values, so the same number of bytes.
    for (k, &(format, layout, size)) in sizes.iter().enumerate() {
        assert_eq!(size, sizes[k % LAYOUTS.len()].2, "{format} {layout:?}");
    }
}

/// A small dragon in every format and layout, with its header's length.
fn small_dragons() -> Vec<(String, Vec<u8>, usize)> {
    let (positions, triangles) = dragon("dragon_vrip_res4.ply.gz");
    small_files(&positions, &triangles, &LAYOUTS)
}

#[test]
fn truncated_lying_and_corrupt_files_fail_as_before() {
    let limits = ReadLimits::with_memory(1 << 30);
    let dir = tempfile::tempdir().unwrap();
    let mut failures = 0;
    for (name, bytes, header) in small_dragons() {
        failures += damaged(dir.path(), &name, &bytes, header, |path| agree(path, &limits).is_err());
    }
    assert!(failures > 9 * 97, "{failures} failures");
}

#[test]
fn binary_runs_give_way_to_polygons_bad_counts_bad_indices_and_bad_coordinates_as_before() {
    let limits = ReadLimits::with_memory(1 << 30);
    let (positions, triangles) = dragon("dragon_vrip_res4.ply.gz");
    let (nv, nf) = (positions.len(), triangles.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("plain.ply");
    let mut refused = 0;
    for format in ["binary_little_endian", "binary_big_endian"] {
        let bytes = write_ply(&positions, &triangles, format, Layout::Plain);
        let header = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let word = |v: u32| if format == "binary_big_endian" { v.to_be_bytes() } else { v.to_le_bytes() };
        let face = |k: usize| header + nv * 12 + k * 13;
        // (byte offset, bytes written there, whether the file still reads): a face's
        // count of 4, of 2 and of 0 (the faces after it misread), an index of -1 and of
        // the vertex count, a NaN and an infinite coordinate, in the middle and at the end.
        let edits: Vec<(usize, Vec<u8>)> = vec![
            (face(nf / 2), vec![4]),
            (face(nf / 3), vec![2]),
            (face(nf / 4), vec![0]),
            (face(nf / 2) + 5, word(u32::MAX).to_vec()),
            (face(nf - 1) + 9, word(nv as u32).to_vec()),
            (header + 12 * (nv / 2) + 4, word(f32::NAN.to_bits()).to_vec()),
            (header + 12 * (nv - 1) + 8, word(f32::INFINITY.to_bits()).to_vec()),
        ];
        for (at, patch) in edits {
            let mut bad = bytes.clone();
            bad[at..at + patch.len()].copy_from_slice(&patch);
            std::fs::write(&path, &bad).unwrap();
            let message = agree(&path, &limits).map(|_| ()).unwrap_err();
            assert!(message.contains("plain.ply"), "{format}: {message}");
            refused += 1;
        }
        // A quad every 1000 faces, read whole.
        let mut quads = bytes[..face(0)].to_vec();
        for (k, t) in triangles.iter().enumerate() {
            let quad = k % 1000 == 999 && k + 1 < nf;
            quads.push(if quad { 4 } else { 3 });
            for &i in t.iter().chain(quad.then(|| &triangles[k + 1][0])) {
                quads.extend_from_slice(&word(i));
            }
        }
        std::fs::write(&path, &quads).unwrap();
        agree(&path, &limits).unwrap_or_else(|e| panic!("{format}: {e}"));
    }
    assert_eq!(refused, 14);
}

#[test]
fn over_budget_files_fail_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("budget.ply");
    for (name, bytes, _) in small_dragons() {
        std::fs::write(&path, &bytes).unwrap();
        // Budgets from a fifth to eight times the file's size: refused while the data is
        // read, while the columns grow in either reader, or read.
        let mut refused = 0;
        for k in 1..=40 {
            let budget = bytes.len() as u64 * k / 5;
            refused += usize::from(agree(&path, &ReadLimits::with_memory(budget)).is_err());
        }
        assert!((4..40).contains(&refused), "{name}: {refused} budgets of 40 refused");
    }
}

#[test]
fn over_budget_gzipped_files_fail_as_the_whole_file_does() {
    // The whole read holds the inflated file in a vector grown by doubling, and columns
    // sized by its length; the stream holds a block and columns grown as the data arrives,
    // charging the bytes arrived as if held. Near the need, their margins differ, so one
    // may read what the other refuses: then the refusal is the budget's message.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("budget.ply.gz");
    for (name, bytes, _) in small_dragons().into_iter().filter(|(name, ..)| name.starts_with("binary")) {
        std::fs::write(&path, ply_layouts::gzip(&bytes)).unwrap();
        let read = |budget: u64, bulk: bool| {
            let options = options(ReadLimits::with_memory(budget));
            PlyAsset::read_bits(&path, &options, bulk).map_err(|e| e.to_string())
        };
        let all = read(1 << 30, false).unwrap();
        let budget_message = |m: &String| {
            m.starts_with(&path.display().to_string())
                && m.contains(": the mesh needs more than ")
                && m.ends_with(", the read budget (as set by the caller)")
        };
        let (mut refused, mut read_both) = (0, 0);
        for k in 1..=40 {
            let budget = bytes.len() as u64 * k / 5;
            match (read(budget, false), read(budget, true)) {
                (Ok(a), Ok(b)) => {
                    assert!(a == all && b == all, "{name}: budget {budget}");
                    read_both += 1;
                }
                (Err(a), Err(b)) => {
                    assert_eq!(a, b, "{name}: budget {budget}");
                    refused += 1;
                }
                (Ok(a), Err(e)) | (Err(e), Ok(a)) => {
                    assert!(a == all && budget_message(&e), "{name}: budget {budget}: {e}");
                }
            }
        }
        assert!(refused >= 4 && read_both >= 4, "{name}: {refused} budgets of 40 refused, {read_both} read");
    }
}

#[test]
fn endless_input_fails_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let limits = ReadLimits::with_memory(1 << 20);
    let cases: [(&str, &str, &'static [u8]); 3] = [
        // Faces (0, 0, 0) after 13 vertices (12 copies of the element), far more of them
        // than the header says.
        (
            "binary_little_endian",
            "element vertex 13\nproperty float x\nproperty float y\nproperty float z\n\
             element face 80000\nproperty list uchar int vertex_indices\n",
            &[3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ),
        // A vertex whose list goes on for ever.
        (
            "binary_big_endian",
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
             property list uint uchar v\nelement face 1\nproperty list uchar int vertex_indices\n",
            &[0xff],
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
            let message = PlyAsset::read_bits(&path, &options(limits.clone()), bulk).unwrap_err().to_string();
            drop(std::fs::remove_file(&path));
            writer.join().unwrap();
            messages.push(message);
        }
        assert_eq!(messages[0], messages[1], "case {k}");
        assert!(messages[1].contains(&format!("endless-{k}.ply")), "case {k}: {}", messages[1]);
    }
}

#[test]
fn elements_across_read_blocks_read_and_fail_as_the_whole_file_does() {
    for gzipped in [false, true] {
        elements_across_read_blocks(gzipped);
    }
}

/// A file, plain or gzipped, is read a block of 1 MiB at a time: vertices with lists of
/// up to 3 MiB and 200,000 faces (2.6 MB, a pentagon every 10,000) span several blocks.
fn elements_across_read_blocks(gzipped: bool) {
    // Eight times the file: a list count past the end of the file must not take more.
    let limits = ReadLimits::with_memory(64 << 20);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(if gzipped { "blocks.ply.gz" } else { "blocks.ply" });
    let blobs = [5usize, (3 << 20) + 7, 0, (1 << 20) - 3, 11];
    let faces = 200_000;
    let header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty list int uchar blob\nelement face {faces}\n\
         property list uchar int vertex_indices\nend_header\n",
        blobs.len()
    );
    let mut bytes = header.as_bytes().to_vec();
    let mut counts = Vec::new();
    for (k, &blob) in blobs.iter().enumerate() {
        [k as f32, 0.5, -(k as f32)].iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
        counts.push(bytes.len());
        bytes.extend_from_slice(&(blob as i32).to_le_bytes());
        bytes.extend((0..blob).map(|b| (b % 251) as u8));
    }
    let first_face = bytes.len();
    for f in 0..faces {
        let corners = if f % 10_000 == 9_999 { 5 } else { 3 };
        bytes.push(corners as u8);
        (0..corners).for_each(|c| bytes.extend_from_slice(&(((f + c) % blobs.len()) as i32).to_le_bytes()));
    }
    let read = |bytes: &[u8]| {
        std::fs::write(&path, if gzipped { ply_layouts::gzip(bytes) } else { bytes.to_vec() }).unwrap();
        agree(&path, &limits)
    };
    read(&bytes).unwrap();
    // Cut inside the long lists, between and inside faces, one byte short.
    for k in 1..=40 {
        let end = header.len() + (bytes.len() - header.len()) * k / 41 + k % 7;
        let message = read(&bytes[..end]).unwrap_err();
        assert!(message.contains("blocks.ply") && message.contains("unexpected end of file"), "{end}: {message}");
    }
    assert!(read(&bytes[..bytes.len() - 1]).unwrap_err().contains(&format!("face {} of {faces}", faces - 1)));
    // A list count beyond the end of the file, a negative one, data after the last face.
    let patched = |at: usize, count: i32| {
        let mut bad = bytes.clone();
        bad[at..at + 4].copy_from_slice(&count.to_le_bytes());
        read(&bad).unwrap_err()
    };
    assert!(patched(counts[1], i32::MAX).contains("unexpected end of file in vertex 1 of 5"));
    assert!(patched(counts[3], -5).contains("vertex 3 of 5: list blob has -5 items"));
    let extra = read(&[&bytes[..], &[3, 0, 0, 0, 0]].concat()).unwrap_err();
    assert!(extra.contains(&format!("data after the last element at byte {}", bytes.len() - header.len())), "{extra}");
    assert!(first_face > 4 << 20, "the vertices span four blocks");
}
