//! The dragon written as PLY in the layouts and encodings the PLY readers' tests compare
//! their fast paths on, those files damaged every way a reader meets, and endless PLY
//! input through a pipe.

use std::fmt::Write as _;
use std::io::Write as _;

/// How a test file lays the dragon out.
#[derive(Clone, Copy, Debug)]
pub enum Layout {
    /// `float x y z`, `list uchar int vertex_indices`, as most writers do.
    Plain,
    /// Normals and an RGBA colour per vertex; a quad every 7 faces, `uint` indices.
    Normals,
    /// Doubles, a colour between the coordinates, a list after them, a flag and two lists
    /// in each face (a quad every third), and elements of scalars and of lists the mesh
    /// does not use.
    Rich,
}

/// The dragon (`positions`, `triangles`) written as PLY in `format` and `layout`.
pub fn write_ply(positions: &[glam::Vec3], triangles: &[[u32; 3]], format: &str, layout: Layout) -> Vec<u8> {
    let (nv, nf) = (positions.len(), triangles.len());
    let mut header = format!("ply\nformat {format} 1.0\ncomment PLY reader test\n");
    match layout {
        Layout::Plain => write!(
            header,
            "element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n\
             element face {nf}\nproperty list uchar int vertex_indices\n"
        ),
        Layout::Normals => write!(
            header,
            "element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\n\
             property float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
             property uchar alpha\nelement face {nf}\nproperty list uchar uint vertex_indices\n"
        ),
        Layout::Rich => write!(
            header,
            "element vertex {nv}\nproperty double x\nproperty float y\nproperty uchar red\nproperty double z\n\
             property list uchar float uv\nelement material 2\nproperty float shine\nproperty short id\n\
             element face {nf}\nproperty uchar flags\nproperty list ushort uint vertex_index\n\
             property list char float texcoord\nelement edge 3\nproperty list uint short ends\n"
        ),
    }
    .unwrap();
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    let ascii = format == "ascii";
    let big = format == "binary_big_endian";
    macro_rules! put {
        ($v:expr, $fmt:literal) => {{
            let v = $v;
            if ascii {
                write!(out, $fmt, v).unwrap();
            } else if big {
                out.extend_from_slice(&v.to_be_bytes());
            } else {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }};
    }
    let end = |out: &mut Vec<u8>| {
        if ascii {
            out.push(b'\n');
        }
    };
    for (k, p) in positions.iter().enumerate() {
        match layout {
            Layout::Plain => {
                put!(p.x, "{} ");
                put!(p.y, "{} ");
                put!(p.z, "{}");
            }
            Layout::Normals => {
                put!(p.x, "{} ");
                put!(p.y, "{} ");
                put!(p.z, "{} ");
                // Not unit length, some in exponent form.
                put!(p.y * 3.0, "{:e} ");
                put!(-p.x, "{} ");
                put!(1.0f32 / (k as f32 + 1.0), "{} ");
                for c in [(k % 256) as u8, 7, 255, (k / 256 % 256) as u8] {
                    put!(c, "{} ");
                }
            }
            Layout::Rich => {
                // Some values in exponent form, some doubles that are no f32.
                put!(f64::from(p.x) + 1e-12, "{:e} ");
                put!(p.y, "{}\t");
                put!((k % 256) as u8, "{} ");
                put!(f64::from(p.z), "{} ");
                put!(2u8, "{} ");
                put!(0.5f32, "{} ");
                put!(-0.25f32, "{}");
            }
        }
        end(&mut out);
    }
    if let Layout::Rich = layout {
        for id in [7i16, -3] {
            put!(1.5f32, "{} ");
            put!(id, "{}");
            end(&mut out);
        }
    }
    for (k, t) in triangles.iter().enumerate() {
        match layout {
            Layout::Plain => {
                put!(3u8, "{} ");
                for &i in t {
                    put!(i as i32, "{} ");
                }
            }
            Layout::Normals => {
                // Every seventh face a quad of its triangle and the next one's first corner.
                let quad = k % 7 == 0 && k + 1 < nf;
                put!(if quad { 4u8 } else { 3 }, "{} ");
                for &i in t.iter().chain(quad.then(|| &triangles[k + 1][0])) {
                    put!(i, "{} ");
                }
            }
            Layout::Rich => {
                put!(1u8, "{} ");
                let quad = k % 3 == 0 && k + 1 < nf;
                put!(if quad { 4u16 } else { 3 }, "{} ");
                for &i in t.iter().chain(quad.then(|| &triangles[k + 1][0])) {
                    put!(i, "{} ");
                }
                put!(2i8, "{} ");
                put!(0.75f32, "{} ");
                put!(k as f32, "{}");
            }
        }
        end(&mut out);
    }
    if let Layout::Rich = layout {
        for e in 0..3u32 {
            put!(2u32, "{} ");
            put!(e as i16, "{} ");
            put!(-(e as i16), "{}");
            end(&mut out);
        }
    }
    out
}

/// A pipe that delivers `header` and then `element` for ever, as `name` in `dir`.
pub fn endless(
    dir: &std::path::Path,
    name: &str,
    header: &str,
    element: &'static [u8],
) -> (std::path::PathBuf, std::thread::JoinHandle<()>) {
    let path = dir.join(name);
    let c_path = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid, NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0, "mkfifo");
    let (writer_path, header) = (path.clone(), header.to_string());
    let writer = std::thread::spawn(move || {
        let mut pipe = std::fs::OpenOptions::new().write(true).open(writer_path).unwrap();
        let block: Vec<u8> = element.iter().copied().cycle().take(element.len() * 4096).collect();
        // Until the reader stops reading and closes the pipe.
        if pipe.write_all(header.as_bytes()).is_ok() {
            while pipe.write_all(&block).is_ok() {}
        }
    });
    (path, writer)
}

/// Writes `bytes`, a PLY file (`name`) whose header is its first `header` bytes, damaged
/// every way a reader meets, as `cut.ply` and `cut.ply.gz` in `dir`, and hands each to
/// `refused`, which reads it and says whether the read failed: the data cut at 98 places
/// (in a value, between elements, in a list), each element's count lying either way (which
/// must fail), a byte corrupted in the first vertex, in a late face and near the end
/// (which may read); and gzipped: the stream cut at 42 places (which must fail), each
/// count lying (which must fail), bytes corrupted in the deflate data, its checksum and
/// its length (which may read where the checksum misses it). Returns how many of the cut
/// and lying files were refused.
pub fn damaged(
    dir: &std::path::Path,
    name: &str,
    bytes: &[u8],
    header: usize,
    mut refused: impl FnMut(&std::path::Path) -> bool,
) -> usize {
    let path = dir.join("cut.ply");
    let gz = dir.join("cut.ply.gz");
    let mut failures = 0;
    let data = bytes.len() - header;
    for k in 0..=97 {
        let end = header + data * k / 97 - usize::from(k > 0 && k < 97) * (k % 5);
        std::fs::write(&path, &bytes[..end]).unwrap();
        failures += usize::from(refused(&path));
    }
    let text = String::from_utf8_lossy(&bytes[..header]).to_string();
    for element in ["vertex", "face"] {
        let line = text.lines().find(|l| l.starts_with(&format!("element {element} "))).unwrap();
        let n: usize = line.rsplit(' ').next().unwrap().parse().unwrap();
        for lie in [n - 1, n + 1, n / 2, n * 3] {
            let header = text.replace(line, &format!("element {element} {lie}"));
            let lying = [header.as_bytes(), &bytes[text.len()..]].concat();
            std::fs::write(&path, &lying).unwrap();
            assert!(refused(&path), "{name}: {element} {lie} of {n} read");
            std::fs::write(&gz, gzip(&lying)).unwrap();
            assert!(refused(&gz), "{name}: {element} {lie} of {n} read from a gzipped file");
            failures += 2;
        }
    }
    for (at, byte) in [(header + 2, 0xffu8), (bytes.len() - 30, 0x7f), (bytes.len() - 9, 0x80)] {
        let mut bad = bytes.to_vec();
        bad[at] = byte;
        std::fs::write(&path, &bad).unwrap();
        refused(&path);
    }
    let compressed = gzip(bytes);
    // Cut in the gzip header, all through the deflate data, in the trailer.
    let ends = (0..40).map(|k| 10 + (compressed.len() - 18) * k / 40 + k % 3).chain([5, compressed.len() - 5]);
    for end in ends {
        std::fs::write(&gz, &compressed[..end]).unwrap();
        assert!(refused(&gz), "{name}: a gzip stream cut at byte {end} of {} read", compressed.len());
        failures += 1;
    }
    let len = compressed.len();
    for at in [12, len / 5, len / 2, len * 4 / 5, len - 20, len - 7, len - 2] {
        let mut bad = compressed.clone();
        bad[at] ^= 0x5a;
        std::fs::write(&gz, &bad).unwrap();
        refused(&gz);
    }
    failures
}

/// `bytes` through `gzip -1`.
pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

/// The PLY encodings the readers' tests write every layout in.
pub const FORMATS: [&str; 3] = ["ascii", "binary_little_endian", "binary_big_endian"];

/// The dragon (`positions`, `triangles`) in every format and in each of `layouts`, named
/// `FORMAT-LAYOUT`, each with its header's length.
pub fn small_files(
    positions: &[glam::Vec3],
    triangles: &[[u32; 3]],
    layouts: &[Layout],
) -> Vec<(String, Vec<u8>, usize)> {
    let mut files = Vec::new();
    for format in FORMATS {
        for &layout in layouts {
            let bytes = write_ply(positions, triangles, format, layout);
            let header = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            files.push((format!("{format}-{layout:?}"), bytes, header));
        }
    }
    files
}
