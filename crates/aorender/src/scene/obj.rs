//! Wavefront OBJ through `tobj`: polygons triangulated as fans, every object and group
//! merged, points and lines ignored, materials ignored (a missing, empty or malformed
//! material library never stops a load). The file is streamed (`.obj.gz` decompressed on
//! the way) past a scanner that checks each `v` line as `tobj` reads it, so a non-finite
//! vertex is reported with its number and line from the same single pass.

use super::input::Input;
use super::mesh::{IndexedMesh, VertexNames, vertex_index};
// Re-exported for the OBJ bake, which checks `v` lines as this loader does.
pub(crate) use super::types::non_finite_coordinate;
use crate::error::{Error, Result};
use glam::Vec3;
use std::io::{self, BufRead, BufReader, Read};
use std::path::Path;

/// The position of a `v` line as `tobj` parses it (`f32::from_str`, which accepts "nan"
/// and "inf"; a homogeneous `w` divided out); `None` for other lines and for `v` lines
/// `tobj` will refuse itself.
pub(crate) fn parse_vertex_line(line: &str) -> Option<Vec3> {
    let mut words = line.split_whitespace();
    if words.next() != Some("v") {
        return None;
    }
    let mut xyz = [0.0f32; 3];
    for c in &mut xyz {
        *c = words.next()?.parse().ok()?;
    }
    let [x, y, z] = xyz;
    let rest: Vec<&str> = words.collect();
    let w = match rest.as_slice() {
        [w] => w.parse::<f32>().unwrap_or(1.0),
        _ => 1.0,
    };
    Some(if w == 1.0 { Vec3::new(x, y, z) } else { Vec3::new(x / w, y / w, z / w) })
}

/// Passes the bytes of an OBJ stream through unchanged while reading its `v` lines.
struct VertexScanner<R> {
    inner: R,
    /// The current, unfinished line.
    line: Vec<u8>,
    line_number: usize,
    vertices: usize,
    /// "vertex k (line l) has a non-finite coordinate (...)" for the first such vertex.
    first_non_finite: Option<String>,
}

impl<R> VertexScanner<R> {
    fn new(inner: R) -> Self {
        VertexScanner { inner, line: Vec::new(), line_number: 0, vertices: 0, first_non_finite: None }
    }

    fn scan(&mut self, mut bytes: &[u8]) {
        while let Some(end) = bytes.iter().position(|&b| b == b'\n') {
            self.line.extend_from_slice(&bytes[..end]);
            self.end_line();
            bytes = &bytes[end + 1..];
        }
        self.line.extend_from_slice(bytes);
    }

    fn end_line(&mut self) {
        self.line_number += 1;
        if let Some(p) = parse_vertex_line(&String::from_utf8_lossy(&self.line)) {
            self.vertices += 1;
            if self.first_non_finite.is_none()
                && let Some(c) = non_finite_coordinate(p)
            {
                self.first_non_finite = Some(format!(
                    "vertex {} (line {}) has a non-finite coordinate ({c})",
                    self.vertices, self.line_number
                ));
            }
        }
        self.line.clear();
    }
}

impl<R: Read> Read for VertexScanner<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = self.inner.read(buf)?;
        if n == 0 {
            if !self.line.is_empty() {
                self.end_line();
            }
        } else {
            self.scan(&buf[..n]);
        }
        Ok(n)
    }
}

/// Cuts from `line` what `tobj` must not see: material lines (`mtllib`, `usemtl`:
/// materials are not AO's business, and `tobj` refuses a `usemtl` without a name) and
/// polylines (`l`, which `tobj` would triangulate when they have three points or more)
/// and empty faces become empty; a vertex's colour (`v x y z r g b`) is cut off, since `tobj` refuses a
/// file where some vertices have one and others not.
fn keep_geometry(line: &mut Vec<u8>) {
    let Ok(text) = std::str::from_utf8(line) else {
        // `tobj` refuses the line itself.
        return;
    };
    let mut words = text.split_whitespace();
    let keep = match words.next() {
        Some("mtllib" | "usemtl" | "l") => 0,
        // A face of no corners, which `tobj` refuses, has no surface either.
        Some("f") if words.next().is_none() => 0,
        Some("v") if text.split_whitespace().count() == 7 => {
            let z = words.nth(2).unwrap_or_default();
            z.as_ptr() as usize - text.as_ptr() as usize + z.len()
        }
        _ => return,
    };
    // An empty line, not nothing: nothing would end the stream.
    line.truncate(keep);
    line.push(b'\n');
}

/// The lines of an OBJ stream as [`keep_geometry`] leaves them.
struct GeometryLines<B> {
    inner: B,
    /// The current line, served from `pos` on.
    line: Vec<u8>,
    pos: usize,
}

impl<B> GeometryLines<B> {
    fn new(inner: B) -> Self {
        GeometryLines { inner, line: Vec::new(), pos: 0 }
    }
}

impl<B: BufRead> BufRead for GeometryLines<B> {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        if self.pos == self.line.len() {
            self.line.clear();
            self.pos = 0;
            self.inner.read_until(b'\n', &mut self.line)?;
            keep_geometry(&mut self.line);
        }
        Ok(&self.line[self.pos..])
    }

    fn consume(&mut self, amount: usize) {
        self.pos = (self.pos + amount).min(self.line.len());
    }
}

impl<B: BufRead> Read for GeometryLines<B> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(buf.len());
        buf[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

/// Reads an OBJ file (`.obj` or `.obj.gz`); rejects a vertex with a NaN or infinite
/// coordinate, naming it by its number (from 1, as faces count) and line.
pub(crate) fn load_obj(path: &Path) -> Result<IndexedMesh> {
    let mut scanner = VertexScanner::new(Input::open(path)?);
    let options = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    // Materials are not part of an AO scene: material lines never reach `tobj`, and the
    // material loader (never called then) would load nothing.
    let loaded =
        tobj::load_obj_buf(&mut GeometryLines::new(BufReader::new(&mut scanner)), &options, |_| Ok(Default::default()));
    if let Some(message) = scanner.inner.stream_error() {
        return Err(Error::scene(path, message));
    }
    if let Some(message) = scanner.first_non_finite.take() {
        return Err(Error::scene(path, message));
    }
    let (models, _) = loaded.map_err(|e| Error::scene(path, format!("invalid OBJ: {e}")))?;

    let mut mesh = IndexedMesh { names: VertexNames::Obj(path.to_path_buf()), ..Default::default() };
    for model in models {
        let m = model.mesh;
        let base = mesh.positions.len();
        let count = m.positions.len() / 3;
        mesh.positions.extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        for f in m.indices.chunks_exact(3) {
            let mut t = [0u32; 3];
            for (v, &i) in t.iter_mut().zip(f) {
                if i as usize >= count {
                    return Err(Error::scene(
                        path,
                        format!("face index {i} is out of range in object '{}'", model.name),
                    ));
                }
                *v = vertex_index(base, i as usize).ok_or_else(|| Error::scene(path, "more than 2^32 vertices"))?;
            }
            mesh.triangles.push(t);
        }
    }
    Ok(mesh)
}

/// The number (from 1) and line of the first `v` line of `path` whose position is
/// bit-identical to `position`: the name of a `tobj` vertex in error messages.
pub(super) fn find_vertex(path: &Path, position: Vec3) -> Option<(usize, usize)> {
    let mut input = Input::open(path).ok()?;
    let mut line = Vec::new();
    let (mut number, mut line_number) = (0, 0);
    loop {
        line.clear();
        if input.read_until(b'\n', &mut line).ok()? == 0 {
            return None;
        }
        line_number += 1;
        if let Some(p) = parse_vertex_line(&String::from_utf8_lossy(&line)) {
            number += 1;
            if p.to_array().map(f32::to_bits) == position.to_array().map(f32::to_bits) {
                return Some((number, line_number));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `v` line of `text` with its line number.
    fn scan_vertices(text: &str) -> Vec<(usize, Vec3)> {
        let mut out = Vec::new();
        for (i, line) in text.lines().enumerate() {
            if let Some(p) = parse_vertex_line(line) {
                out.push((i + 1, p));
            }
        }
        out
    }

    #[test]
    fn vertices_are_parsed_as_tobj_reads_them() {
        let text = "# c\nv 1 2 3\nvn 0 0 1\n  v 2 4 6 2\nv 1 2 3 0.5 0.5 0.5\nv nan 0 0\nv 0 -inf 1\nv x\n";
        let v = scan_vertices(text);
        let expect = [(2, Vec3::new(1.0, 2.0, 3.0)), (4, Vec3::new(1.0, 2.0, 3.0)), (5, Vec3::new(1.0, 2.0, 3.0))];
        assert_eq!(v.len(), 5);
        for (got, want) in v.iter().zip(expect) {
            assert_eq!(*got, want);
        }
        assert!(v[3].1.x.is_nan() && v[3].0 == 6);
        assert_eq!(non_finite_coordinate(v[4].1).as_deref(), Some("y = -inf"));
    }

    #[test]
    fn the_scanner_finds_the_first_non_finite_vertex_across_reads() {
        let text = b"v 0 0 0\r\nv 1 0 0\nvt 0 nan\nv 0 1 0\nv 0 nan 0\nv inf 0 0";
        // Reads of one to seven bytes split lines anywhere.
        for chunk in 1..8 {
            let mut scanner = VertexScanner::new(&text[..]);
            let mut buf = vec![0; chunk];
            while scanner.read(&mut buf).unwrap() > 0 {}
            assert_eq!(scanner.vertices, 5, "reads of {chunk}");
            assert_eq!(
                scanner.first_non_finite.as_deref(),
                Some("vertex 4 (line 5) has a non-finite coordinate (y = NaN)"),
                "reads of {chunk}"
            );
        }
    }

    /// Writes `files` (name, text) into a new directory and loads the first as OBJ.
    fn load_files(files: &[(&str, &str)]) -> Result<IndexedMesh> {
        let dir = tempfile::tempdir().unwrap();
        for (name, text) in files {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        load_obj(&dir.path().join(files[0].0))
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn a_missing_material_library_is_ignored() {
        let mesh = load_files(&[("m.obj", &format!("mtllib none.mtl\n{SQUARE}usemtl red\nf 1 2 3 4\n"))]).unwrap();
        assert_eq!(mesh.triangles.len(), 2);
    }

    #[test]
    fn a_material_with_an_empty_name_is_ignored() {
        let obj = format!("mtllib m.mtl\n{SQUARE}usemtl\nf 1 2 3\nusemtl  \r\nf 1 3 4\n");
        let mesh = load_files(&[("m.obj", &obj), ("m.mtl", "newmtl\nKd 1 0 0\n")]).unwrap();
        assert_eq!(mesh.triangles.len(), 2);
    }

    #[test]
    fn a_malformed_material_library_is_ignored() {
        let obj = format!("mtllib m.mtl\n{SQUARE}usemtl a\nf 1 2 3 4\n");
        let mtl = "newmtl a\nKd red green\nNs\nmap_Kd\n\u{0}\u{ff}";
        let mesh = load_files(&[("m.obj", &obj), ("m.mtl", mtl)]).unwrap();
        assert_eq!(mesh.triangles.len(), 2);
    }

    #[test]
    fn polylines_and_points_make_no_triangles() {
        let mesh =
            load_files(&[("m.obj", &format!("{SQUARE}l 1 2 3 4\nf 1 2\np 1 2 3\nf\nf 1 2 3\n  l 1 2 3"))]).unwrap();
        assert_eq!(mesh.triangles.len(), 1);
    }

    #[test]
    fn vertex_colours_are_ignored() {
        let text = "v 0 0 0\nv 1 0 0 0.5 0.5 0.5\r\nv 0 1 0 1 0 0\nf 1 2 3\n";
        let mesh = load_files(&[("m.obj", text)]).unwrap();
        assert_eq!(mesh.positions, [Vec3::ZERO, Vec3::X, Vec3::Y]);
        assert_eq!(mesh.triangles, [[0, 1, 2]]);
    }

    #[test]
    fn broken_geometry_is_still_refused() {
        for (text, want) in [
            (format!("{SQUARE}usemtl\nf 1 2 5\n"), "out of bounds"),
            (format!("{SQUARE}f 1 2 x\n"), "face"),
            ("v 0 0\n".to_string(), "position"),
            (format!("{SQUARE}v 0 0 0 1 1\nf 1 2 3\n"), "color"),
            (format!("{SQUARE}v 0 0 0 1 1 1 1\nf 1 2 3\n"), "color"),
        ] {
            let e = load_files(&[("m.obj", &text)]).unwrap_err().to_string();
            assert!(e.to_lowercase().contains(want), "{text:?}: {e}");
        }
    }
}
