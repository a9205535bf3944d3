//! Wavefront OBJ through `tobj`: polygons triangulated as fans, every object and group
//! merged, points and lines ignored, materials ignored (a missing, empty or malformed
//! material library never stops a load). The file is streamed (`.obj.gz` decompressed on
//! the way) a line at a time past a reader that checks each `v` line as `tobj` reads it,
//! so a non-finite vertex is reported with its number and line from the same single pass,
//! and that charges the memory each line will take to the read budget before `tobj` sees
//! it (`tobj` holds the whole file's elements until it returns).

use super::input::{Input, Meter, ReadLimits};
use super::mesh::{IndexedMesh, VertexNames, vertex_index};
// Re-exported for the OBJ bake, which checks `v` lines as this loader does.
pub(crate) use super::types::non_finite_coordinate;
use crate::error::{Error, Result};
use glam::Vec3;
use std::io::{self, BufRead, Read};
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

/// Bytes of memory `tobj` and this loader hold for one `v` line at most: `tobj`'s
/// coordinates (12 bytes, in a vector that grows by doubling) and the loaded position.
const VERTEX_LINE_BYTES: u64 = 2 * 12 + 12;
/// For one `vt` line (two coordinates kept, doubling) and one `vn` line (three).
const TEXCOORD_LINE_BYTES: u64 = 2 * 8;
const NORMAL_LINE_BYTES: u64 = 2 * 12;
/// For one face: `tobj`'s face record (an enum of up to four corners' three indices,
/// 104 bytes, in a vector that grows by doubling).
const FACE_BYTES: u64 = 2 * 104;
/// For each corner of a polygon of more than four: `tobj` keeps its indices on the heap.
const POLYGON_CORNER_BYTES: u64 = 24;
/// For each corner: the vertex it names may be new to its object's mesh (its position
/// copied, doubling, a hash map entry, and the loaded position): at most this.
const CORNER_VERTEX_BYTES: u64 = 2 * 12 + 40 + 12;
/// For each corner that names a texture coordinate or a normal: the same for those.
const CORNER_TEXCOORD_BYTES: u64 = 2 * 8 + 40;
const CORNER_NORMAL_BYTES: u64 = 2 * 12 + 40;
/// For each corner of each triangle of a face: an index (doubling) into each of the
/// positions, texture coordinates and normals it names.
const TRIANGLE_INDEX_BYTES: u64 = 2 * 4;
/// For each triangle: the loaded mesh's.
const TRIANGLE_BYTES: u64 = 12;
/// For each object or group (`o`, `g`): `tobj`'s model, mesh, name and hash maps.
const OBJECT_BYTES: u64 = 512;

/// The memory `tobj` and this loader hold for a line at most, its words split as `tobj`
/// splits them.
fn line_bytes(line: &str) -> u64 {
    let mut words = line.split_whitespace();
    match words.next().unwrap_or("") {
        "v" => VERTEX_LINE_BYTES,
        "vt" => TEXCOORD_LINE_BYTES,
        "vn" => NORMAL_LINE_BYTES,
        "o" | "g" => OBJECT_BYTES,
        "f" => {
            let (mut corners, mut texcoords, mut normals) = (0u64, 0u64, 0u64);
            for corner in words {
                corners += 1;
                let mut parts = corner.split('/').skip(1);
                texcoords += u64::from(parts.next().is_some_and(|p| !p.is_empty()));
                normals += u64::from(parts.next().is_some_and(|p| !p.is_empty()));
            }
            let triangles = corners.saturating_sub(2);
            let polygon = if corners > 4 { corners * POLYGON_CORNER_BYTES } else { 0 };
            let arrays = 1 + u64::from(texcoords > 0) + u64::from(normals > 0);
            FACE_BYTES
                + polygon
                + corners * CORNER_VERTEX_BYTES
                + texcoords * CORNER_TEXCOORD_BYTES
                + normals * CORNER_NORMAL_BYTES
                + triangles * (3 * arrays * TRIANGLE_INDEX_BYTES + TRIANGLE_BYTES)
        }
        _ => 0,
    }
}

/// Cuts from `line` what `tobj` must not see: material lines (`mtllib`, `usemtl`:
/// materials are not AO's business, and `tobj` refuses a `usemtl` without a name),
/// polylines (`l`, which `tobj` would triangulate when they have three points or more)
/// and empty faces are dropped (`false`); a vertex's colour (`v x y z r g b`) is cut off,
/// since `tobj` refuses a file where some vertices have one and others not.
fn keep_geometry(line: &mut Vec<u8>) -> bool {
    let Ok(text) = std::str::from_utf8(line) else {
        // `tobj` refuses the line itself.
        return true;
    };
    let mut words = text.split_whitespace();
    let keep = match words.next() {
        Some("mtllib" | "usemtl" | "l") => return false,
        // A face of no corners, which `tobj` refuses, has no surface either.
        Some("f") if words.next().is_none() => return false,
        Some("v") if text.split_whitespace().count() == 7 => {
            let z = words.nth(2).unwrap_or_default();
            z.as_ptr() as usize - text.as_ptr() as usize + z.len()
        }
        _ => return true,
    };
    line.truncate(keep);
    line.push(b'\n');
    true
}

/// An OBJ file as `tobj` reads it, a line at a time: blank and comment lines dropped (and
/// counted against the limits' allowance for them), the others as [`keep_geometry`]
/// leaves them; every `v` line checked for a non-finite coordinate, and the memory each
/// line will take charged to the meter before `tobj` sees it. A limit exceeded ends the
/// stream with an error, which the loader reports instead of `tobj`'s.
struct ObjLines<'a> {
    input: Input,
    meter: &'a mut Meter,
    path: &'a Path,
    /// The current line, served from `pos` on.
    line: Vec<u8>,
    pos: usize,
    vertices: usize,
    /// Bytes of blank and comment lines, and of the others.
    idle: u64,
    data: u64,
    /// "vertex k (line l) has a non-finite coordinate (...)" for the first such vertex.
    first_non_finite: Option<String>,
    /// A limit exceeded.
    error: Option<Error>,
}

impl<'a> ObjLines<'a> {
    fn new(input: Input, meter: &'a mut Meter, path: &'a Path) -> Self {
        ObjLines {
            input,
            meter,
            path,
            line: Vec::new(),
            pos: 0,
            vertices: 0,
            idle: 0,
            data: 0,
            first_non_finite: None,
            error: None,
        }
    }

    /// Skips white space up to the next line that has more, counting its line breaks;
    /// runs of blank lines go by a buffer at a time.
    fn skip_blank(&mut self) -> io::Result<()> {
        loop {
            let buf = self.input.fill_buf()?;
            let n = buf.iter().position(|b| !matches!(b, b'\n' | b'\r' | b' ' | b'\t')).unwrap_or(buf.len());
            if n == 0 {
                return Ok(());
            }
            let breaks = memchr::memchr_iter(b'\n', &buf[..n]).count() as u64;
            self.input.consume(n);
            self.input.count_lines(breaks);
            self.idle += n as u64;
            self.check_idle()?;
        }
    }

    /// Fails once the blank and comment lines pass their allowance.
    fn check_idle(&mut self) -> io::Result<()> {
        if self.idle > self.input.limits().idle_bytes().saturating_add(self.data) {
            let message = self.input.limits().idle_message(self.input.line_number());
            return Err(self.stop(Error::scene(self.path, message)));
        }
        Ok(())
    }

    /// Reads the next line `tobj` is to see into `line` (empty at the end of the file).
    fn next_line(&mut self) -> io::Result<()> {
        loop {
            self.line.clear();
            self.pos = 0;
            self.skip_blank()?;
            let n = self.input.read_line(&mut self.line)? as u64;
            if n == 0 {
                return Ok(());
            }
            if self.line[0] == b'#' {
                self.idle += n;
            } else {
                self.data += n;
                let text = String::from_utf8_lossy(&self.line);
                let bytes = line_bytes(&text);
                if let Some(p) = parse_vertex_line(&text) {
                    self.vertices += 1;
                    if self.first_non_finite.is_none()
                        && let Some(c) = non_finite_coordinate(p)
                    {
                        let line = self.input.line_number();
                        self.first_non_finite =
                            Some(format!("vertex {} (line {line}) has a non-finite coordinate ({c})", self.vertices));
                    }
                }
                if let Err(e) = self.meter.charge(self.path, bytes) {
                    return Err(self.stop(e));
                }
            }
            self.check_idle()?;
            if self.line[0] != b'#' && keep_geometry(&mut self.line) {
                return Ok(());
            }
        }
    }

    /// Ends the stream with `e`, which the loader reports.
    fn stop(&mut self, e: Error) -> io::Error {
        let message = e.message();
        self.error.get_or_insert(e);
        io::Error::other(message)
    }
}

impl BufRead for ObjLines<'_> {
    fn fill_buf(&mut self) -> io::Result<&[u8]> {
        if self.pos == self.line.len() {
            self.next_line()?;
        }
        Ok(&self.line[self.pos..])
    }

    fn consume(&mut self, amount: usize) {
        self.pos = (self.pos + amount).min(self.line.len());
    }
}

impl Read for ObjLines<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let available = self.fill_buf()?;
        let n = available.len().min(buf.len());
        buf[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

/// Reads an OBJ file (`.obj` or `.obj.gz`) within `meter`'s budget; rejects a vertex with
/// a NaN or infinite coordinate, naming it by its number (from 1, as faces count) and line.
pub(crate) fn load_obj(path: &Path, meter: &mut Meter) -> Result<IndexedMesh> {
    let input = Input::open(path, meter.limits())?;
    let mut lines = ObjLines::new(input, meter, path);
    let options = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    // Materials are not part of an AO scene: material lines never reach `tobj`, and the
    // material loader (never called then) would load nothing.
    let loaded = tobj::load_obj_buf(&mut lines, &options, |_| Ok(Default::default()));
    if let Some(e) = lines.error.take() {
        return Err(e);
    }
    if let Some(message) = lines.input.stream_error() {
        return Err(Error::scene(path, message));
    }
    if let Some(message) = lines.first_non_finite.take() {
        return Err(Error::scene(path, message));
    }
    let (models, _) = loaded.map_err(|e| Error::scene(path, format!("invalid OBJ: {e}")))?;

    let mut mesh = IndexedMesh { names: VertexNames::Obj(path.to_path_buf()), ..Default::default() };
    // Exact sizes: the loaded mesh takes what the lines were charged for it.
    mesh.positions.reserve_exact(models.iter().map(|m| m.mesh.positions.len() / 3).sum());
    mesh.triangles.reserve_exact(models.iter().map(|m| m.mesh.indices.len() / 3).sum());
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
/// bit-identical to `position`: the name of a `tobj` vertex in error messages. Only a
/// regular file is read again (a pipe would wait for a writer), within the default limits.
pub(super) fn find_vertex(path: &Path, position: Vec3) -> Option<(usize, usize)> {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return None;
    }
    let mut input = Input::open(path, &ReadLimits::from_env().ok()?).ok()?;
    let mut line = Vec::new();
    let (mut number, mut line_number) = (0, 0);
    loop {
        line.clear();
        if input.read_line(&mut line).ok()? == 0 {
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
    fn the_reader_finds_the_first_non_finite_vertex_across_reads() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        // The second file has blank and comment lines, which count as lines.
        for (text, line) in [
            (&b"v 0 0 0\r\nv 1 0 0\nvt 0 nan\nv 0 1 0\nv 0 nan 0\nv inf 0 0"[..], 5),
            (b"\n \r\nv 0 0 0\r\nv 1 0 0\n\t\n# c\nvt 0 nan\nv 0 1 0\nv 0 nan 0\nv inf 0 0", 9),
        ] {
            std::fs::write(&path, text).unwrap();
            // Reads of one to seven bytes split lines anywhere.
            for chunk in 1..8 {
                let limits = ReadLimits::with_memory(1 << 20);
                let mut meter = Meter::new(&limits, "the mesh");
                let mut lines = ObjLines::new(Input::open(&path, &limits).unwrap(), &mut meter, &path);
                let mut buf = vec![0; chunk];
                while lines.read(&mut buf).unwrap() > 0 {}
                assert_eq!(lines.vertices, 5, "reads of {chunk}");
                let want = format!("vertex 4 (line {line}) has a non-finite coordinate (y = NaN)");
                assert_eq!(lines.first_non_finite.as_deref(), Some(want.as_str()), "reads of {chunk}");
            }
        }
    }

    /// Writes `files` (name, text) into a new directory and loads the first as OBJ.
    fn load_files(files: &[(&str, &str)]) -> Result<IndexedMesh> {
        let dir = tempfile::tempdir().unwrap();
        for (name, text) in files {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        let mut meter = Meter::new(&ReadLimits::with_memory(1 << 30), "the mesh");
        load_obj(&dir.path().join(files[0].0), &mut meter)
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
