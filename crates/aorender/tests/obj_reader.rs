//! The OBJ reader against `tobj`, the reader the scene loader used before it: for every
//! OBJ file of the repository (`scenes/`, the tests' own) and of the shared scenes beside
//! it (`../shared/scenes`, skipped by name when that folder is absent), a mesh made from
//! the dragon with every index form, truncations of a real file, and malformed lines, the
//! new reader gives the same triangles bit for bit, in the same order, in blocks of any
//! size, or refuses what `tobj` refused. `tobj` is given the lines as the old loader gave
//! them: material lines, polylines and empty faces dropped, comments cut, a vertex colour
//! cut off and a lone texture coordinate `u` given its v.

use aorender::scene::{ReadLimits, read_obj_triangles};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Triangles as the bits of their corners' coordinates.
type Bits = Vec<[[u32; 3]; 3]>;

/// The lines of `bytes` as the old loader handed them to `tobj`.
fn prepared(bytes: &[u8]) -> String {
    let mut out = String::new();
    for line in String::from_utf8_lossy(bytes).lines() {
        let line = line.split('#').next().unwrap_or_default();
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["mtllib" | "usemtl" | "l", ..] | ["f"] => continue,
            ["vt", u] => out += &format!("vt {u} 0"),
            ["v", x, y, z, _, _, _] => out += &format!("v {x} {y} {z}"),
            _ => out += line,
        }
        out.push('\n');
    }
    out
}

/// `tobj`'s triangles of `bytes`, polygons triangulated, every object merged in order.
fn tobj_triangles(bytes: &[u8]) -> Result<Bits, String> {
    let options = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    let text = prepared(bytes);
    let (models, _) =
        tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| Ok(Default::default())).map_err(|e| e.to_string())?;
    let mut out = Vec::new();
    for model in models {
        let m = model.mesh;
        let corner = |i: u32| {
            let k = i as usize * 3;
            [m.positions[k], m.positions[k + 1], m.positions[k + 2]].map(f32::to_bits)
        };
        out.extend(m.indices.chunks_exact(3).map(|t| [corner(t[0]), corner(t[1]), corner(t[2])]));
    }
    Ok(out)
}

/// The new reader's triangles of `path` in blocks of `block_bytes`.
fn new_triangles(path: &Path, block_bytes: usize) -> Result<Bits, String> {
    let limits = ReadLimits::with_memory(1 << 32);
    let triangles = read_obj_triangles(path, &limits, block_bytes).map_err(|e| e.to_string())?;
    Ok(triangles.iter().map(|t| t.map(|p| p.to_array().map(f32::to_bits))).collect())
}

/// The new reader gives `tobj`'s triangles of the file at `path`, in one block and in
/// small ones.
fn same_as_tobj(path: &Path) -> usize {
    let bytes = std::fs::read(path).unwrap();
    let want = tobj_triangles(&bytes).unwrap_or_else(|e| panic!("{}: tobj: {e}", path.display()));
    for block_bytes in [1 << 20, 4096] {
        let got = new_triangles(path, block_bytes).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(got.len(), want.len(), "{} in blocks of {block_bytes}", path.display());
        assert!(got == want, "{} in blocks of {block_bytes}: other triangles", path.display());
    }
    want.len()
}

/// Every `.obj` file under `dir` (not gzipped: `tobj` reads text).
fn obj_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "obj"))
        .collect();
    files.sort();
    files
}

#[test]
fn every_obj_file_reads_as_tobj_read_it() {
    let mut checked = Vec::new();
    for path in obj_files(&repo().join("scenes")) {
        checked.push((same_as_tobj(&path), path));
    }
    let shared = repo().join("../shared/scenes");
    if shared.is_dir() {
        for path in obj_files(&shared) {
            checked.push((same_as_tobj(&path), path));
        }
    } else {
        eprintln!("{} is absent: its scenes are not compared", shared.display());
    }
    // The tests' own files that tobj reads.
    for dir in ["crates/aorender/tests/malformed", "crates/aorender/tests/fuzz_regressions"] {
        for path in obj_files(&repo().join(dir)) {
            let bytes = std::fs::read(&path).unwrap();
            match tobj_triangles(&bytes) {
                Ok(_) => checked.push((same_as_tobj(&path), path)),
                Err(_) => assert!(new_triangles(&path, 1 << 20).is_err(), "{} was read", path.display()),
            }
        }
    }
    let names: Vec<String> = checked.iter().map(|(_, p)| p.file_name().unwrap().to_string_lossy().into()).collect();
    assert!(names.iter().any(|n| n == "bunny.obj") && names.iter().any(|n| n == "teapot.obj"), "{names:?}");
    let bunny = checked.iter().find(|(_, p)| p.ends_with("bunny.obj")).unwrap();
    assert_eq!(bunny.0, 69_451);
}

/// The dragon (202,520 triangles) written as OBJ in groups, with every corner form
/// (positive and relative indices, texture coordinates and normals), quads and comments:
/// many blocks of every size.
#[test]
fn a_large_mesh_with_every_index_form_reads_as_tobj_read_it() {
    let dragon = repo().join("scenes/dragon_vrip_res2.ply.gz");
    let (positions, triangles) =
        aorender::scene::read_ply_mesh(&dragon, &ReadLimits::with_memory(1 << 32), true).unwrap();
    let mut text = String::from("# the dragon\nmtllib dragon.mtl\n");
    let mut written = 0;
    for (k, t) in triangles.iter().enumerate() {
        // Each triangle's vertices are written before it, once, so relative indices vary.
        while written <= t.iter().copied().max().unwrap() as usize {
            let p = positions[written];
            text += &format!("v {} {} {}\nvt {} {}\nvn 0 0 1\n", p.x, p.y, p.z, p.x, p.y);
            written += 1;
        }
        if k % 5000 == 0 {
            text += &format!("g part{k}\nusemtl m{}\ns {}\n", k % 3, k % 2);
        }
        let n = written as i64;
        let [a, b, c] = t.map(|v| v as i64 + 1);
        text += &match k % 5 {
            0 => format!("f {a} {b} {c}\n"),
            1 => format!("f {} {} {}\n", a - n - 1, b - n - 1, c - n - 1),
            2 => format!("f {a}/{a} {b}/{b} {c}/{} # a comment\n", c - n - 1),
            3 => format!("f {a}//{a} {b}//{} {c}//{c}\r\n", b - n - 1),
            _ => format!("f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c} {c}/{c}/{c}\n"),
        };
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dragon.obj");
    std::fs::write(&path, &text).unwrap();
    assert!(text.len() > 8 << 20, "{} bytes", text.len());
    assert!(same_as_tobj(&path) > 200_000);
}

/// A real file cut short anywhere: both readers take the same, or both refuse it.
#[test]
fn truncated_files_read_or_fail_as_tobj_did() {
    let bytes = std::fs::read(repo().join("scenes/teapot.obj")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.obj");
    let mut refused = 0;
    for end in (1..bytes.len()).step_by(997).chain([bytes.len() - 1, bytes.len() / 2 + 3]) {
        std::fs::write(&path, &bytes[..end]).unwrap();
        let (want, got) = (tobj_triangles(&bytes[..end]), new_triangles(&path, 4096));
        match (&want, &got) {
            (Ok(w), Ok(g)) => assert!(w == g, "cut at {end}: other triangles"),
            (Err(_), Err(e)) => {
                assert!(e.contains("invalid OBJ"), "cut at {end}: {e}");
                refused += 1;
            }
            _ => panic!("cut at {end}: tobj {:?}, the reader {:?}", want.map(|t| t.len()), got.map(|t| t.len())),
        }
    }
    assert!(refused > 0, "no cut was refused");
}

/// Malformed lines `tobj` refused are refused, naming the line.
#[test]
fn malformed_files_are_refused_as_tobj_refused_them() {
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.obj");
    for (text, line) in [
        (format!("{tri}v 1 2\n"), 4),
        (format!("{tri}v 1 x 3\n"), 4),
        (format!("{tri}v 1 2 3 0\n"), 4),
        (format!("{tri}v 1 2 3 4 5\n"), 4),
        (format!("{tri}vn 0 1\n"), 4),
        (format!("{tri}vn 0 1 z\n"), 4),
        (format!("{tri}vt x 1\n"), 4),
        (format!("{tri}f 1 2 x\n"), 4),
        (format!("{tri}f 1 2 3.5\n"), 4),
        (format!("{tri}f 1 2 4\n"), 4),
        (format!("{tri}f 1 2 -4\n"), 4),
        (format!("{tri}f 1 2 0\n"), 4),
        (format!("{tri}f 1/1/1/1 2 3\n"), 4),
        (format!("{tri}vt 0 0\nf 1/2 2/1 3/1\n"), 5),
        (format!("{tri}vn 0 0 1\nf 1//2 2//1 3//1\n"), 5),
    ] {
        assert!(tobj_triangles(text.as_bytes()).is_err(), "tobj read {text:?}");
        std::fs::write(&path, &text).unwrap();
        let e = new_triangles(&path, 1 << 20).unwrap_err();
        assert!(e.contains(&format!("bad.obj: line {line}: invalid OBJ: ")), "{text:?}: {e}");
    }
}
