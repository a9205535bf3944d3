//! Wavefront OBJ through `tobj`: polygons triangulated as fans, every object and group
//! merged, points and lines ignored, materials ignored (a missing, empty or malformed
//! material library never stops a load). The file is streamed (`.obj.gz` decompressed on
//! the way) a line at a time past a reader that prepares each line for `tobj` and checks
//! it first, so that every error names its line: it reads bytes, not text (a name or a
//! comment in any encoding is no error: names are not needed), skips a UTF-8 byte-order
//! mark, refuses UTF-16 in one line, joins lines continued with `\`, cuts comments off
//! the end of lines with data, checks each `v`,
//! `vt`, `vn` and `f` line as `tobj` will read it (and the face indices where `tobj`
//! resolves them, when an object ends), reports a non-finite vertex with its number and
//! line, and charges the memory each line will take to the read budget before `tobj`
//! sees it (`tobj` holds the whole file's elements until it returns).

use super::input::{Input, Meter, ReadLimits, UTF16_MESSAGE, size_text};
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
/// since `tobj` refuses a file where some vertices have one and others not; a texture
/// coordinate of one number is given its v, 0.
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
        // `vt u` (v and w are optional): `tobj` wants two numbers.
        Some("vt") if text.split_whitespace().count() == 2 => {
            let u = words.next().unwrap_or_default();
            let end = u.as_ptr() as usize - text.as_ptr() as usize + u.len();
            line.truncate(end);
            line.extend_from_slice(b" 0\n");
            return true;
        }
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

/// What the face indices of an OBJ file refer to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Element {
    Vertex,
    TexCoord,
    Normal,
}

impl Element {
    const ALL: [Element; 3] = [Element::Vertex, Element::TexCoord, Element::Normal];

    /// "vertex", "texture coordinate", "normal".
    pub(crate) fn name(self) -> &'static str {
        match self {
            Element::Vertex => "vertex",
            Element::TexCoord => "texture coordinate",
            Element::Normal => "normal",
        }
    }

    /// "vertices", "texture coordinates", "normals".
    pub(crate) fn plural(self) -> &'static str {
        match self {
            Element::Vertex => "vertices",
            Element::TexCoord => "texture coordinates",
            Element::Normal => "normals",
        }
    }
}

/// If `line` (with its ending) is continued on the next (its last character before the
/// ending is `\`), where that `\` is.
pub(crate) fn continued_at(line: &[u8]) -> Option<usize> {
    let end = line.len() - line.iter().rev().take_while(|&&b| b == b'\n' || b == b'\r').count();
    (end > 0 && line[end - 1] == b'\\').then_some(end - 1)
}

/// Checks the numbers of a `v`, `vt` or `vn` line (`words` after its keyword) as `tobj`
/// reads them: a vertex's x, y, z, then a w (non-zero) or a colour (r g b, not read) or
/// nothing; a texture coordinate's u (then v and w, optional); a normal's three.
pub(crate) fn check_numbers(keyword: &str, words: &[&str]) -> std::result::Result<(), ObjLineError> {
    let number = |w: &str, what: &'static str| match w.parse::<f32>() {
        Ok(_) => Ok(()),
        Err(_) => Err(ObjLineError::NotANumber { word: super::input::one_line(w), what }),
    };
    match keyword {
        "v" => {
            let n = words.len();
            if n < 3 {
                return Err(ObjLineError::PositionNumbers(n));
            }
            if !matches!(n, 3 | 4 | 6) {
                return Err(ObjLineError::VertexNumbers(n));
            }
            words[..3].iter().try_for_each(|w| number(w, "a vertex position coordinate"))?;
            if n == 4 {
                number(words[3], "a vertex's w")?;
                if words[3].parse::<f32>() == Ok(0.0) {
                    return Err(ObjLineError::AtInfinity);
                }
            }
        }
        "vt" => {
            if words.is_empty() {
                return Err(ObjLineError::NoTexCoordNumbers);
            }
            words.iter().take(2).try_for_each(|w| number(w, "a texture coordinate"))?;
        }
        "vn" => {
            if words.len() < 3 {
                return Err(ObjLineError::NormalNumbers(words.len()));
            }
            words[..3].iter().try_for_each(|w| number(w, "a normal"))?;
        }
        _ => {}
    }
    Ok(())
}

/// One index of a face corner, 1-based or (negative) relative to the elements so far:
/// `Err` when it is not an integer.
fn corner_index(part: &str, corner: &str) -> std::result::Result<i64, ObjLineError> {
    part.parse::<i64>().map_err(|_| ObjLineError::NotAnIndex {
        corner: super::input::one_line(corner),
        part: super::input::one_line(part),
    })
}

/// What is wrong with one line of an OBJ file, as the scene loader checks it before
/// `tobj` reads it (the loader adds the line number and the file).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub(crate) enum ObjLineError {
    /// A word of a `v`, `vt` or `vn` line that is no number, and what it stands for.
    #[error("'{word}' is not a number ({what})")]
    NotANumber { word: String, what: &'static str },
    /// A vertex with fewer than three coordinates.
    #[error("a vertex position needs 3 numbers, found {0}")]
    PositionNumbers(usize),
    /// A vertex of neither 3, 4 nor 6 numbers.
    #[error("a vertex has x y z, then a w or a color (r g b) or nothing; found {0} numbers")]
    VertexNumbers(usize),
    /// A vertex whose w is zero.
    #[error("a vertex with w = 0 (at infinity)")]
    AtInfinity,
    /// A `vt` line with no number.
    #[error("a texture coordinate needs 1 to 3 numbers, found none")]
    NoTexCoordNumbers,
    /// A normal with fewer than three numbers.
    #[error("a normal needs 3 numbers, found {0}")]
    NormalNumbers(usize),
    /// A face corner's part that is no integer.
    #[error("the face corner '{corner}' has '{part}', not an index")]
    NotAnIndex { corner: String, part: String },
    /// A face corner without a vertex index.
    #[error("the face corner '{corner}' names no vertex")]
    NoVertex { corner: String },
    /// A face corner of more than three parts.
    #[error("the face corner '{corner}' has more than v/vt/vn")]
    TooManyParts { corner: String },
    /// A face index that names no element: `count` of them `at` (" before it", or where
    /// the object ends).
    #[error("{}", out_of_bounds(*element, *index, *count, at))]
    OutOfBounds { element: Element, index: i64, count: u64, at: String },
}

/// The face indices of one element since its object began (where `tobj` resolves them):
/// the largest 1-based one and its line, and the first that reaches before the first
/// element (zero, or relative past the start) with its line.
#[derive(Clone, Copy, Default)]
struct PendingIndices {
    largest: u64,
    largest_line: u64,
    /// The index, its line and the count of elements before that line.
    before_start: Option<(i64, u64, u64)>,
}

/// An OBJ file as `tobj` reads it, a line at a time: blank and comment lines dropped (and
/// counted against the limits' allowance for them), comments after data cut off, lines
/// continued with `\` joined, bytes
/// that are not UTF-8 replaced (they can only be in names, which are not needed, or make a
/// number invalid), every line checked (see [`check_numbers`], the face indices when their
/// object ends) and then left as [`keep_geometry`] leaves it; every `v` line checked for a
/// non-finite coordinate, and the memory each line will take charged to the meter before
/// `tobj` sees it. A limit exceeded or a line in error ends the stream with an error,
/// which the loader reports instead of `tobj`'s.
struct ObjLines<'a> {
    input: Input,
    meter: &'a mut Meter,
    path: &'a Path,
    /// The current line, served from `pos` on.
    line: Vec<u8>,
    pos: usize,
    /// The line number of the current line (of its first line, when continued).
    line_number: u64,
    /// `v`, `vt` and `vn` lines so far.
    counts: [u64; 3],
    /// Face indices not yet resolved, per element.
    pending: [PendingIndices; 3],
    /// Bytes of blank and comment lines, and of the others.
    idle: u64,
    data: u64,
    /// "vertex k (line l) has a non-finite coordinate (...)" for the first such vertex.
    first_non_finite: Option<String>,
    /// A limit exceeded.
    error: Option<Error>,
    /// The first line in error.
    line_error: Option<Error>,
}

impl<'a> ObjLines<'a> {
    fn new(input: Input, meter: &'a mut Meter, path: &'a Path) -> Self {
        ObjLines {
            input,
            meter,
            path,
            line: Vec::new(),
            pos: 0,
            line_number: 0,
            counts: [0; 3],
            pending: [PendingIndices::default(); 3],
            idle: 0,
            data: 0,
            first_non_finite: None,
            error: None,
            line_error: None,
        }
    }

    /// `v` lines read so far.
    #[cfg(test)]
    fn vertices(&self) -> u64 {
        self.counts[Element::Vertex as usize]
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
        self.input.skip_text_mark()?;
        loop {
            self.line.clear();
            self.pos = 0;
            self.skip_blank()?;
            let n = self.input.read_line(&mut self.line)? as u64;
            if n == 0 {
                // The end of the last object: its face indices are resolved.
                return self.resolve_pending(None);
            }
            self.line_number = self.input.line_number();
            if self.line[0] == b'#' {
                self.idle += n;
                self.check_idle()?;
                continue;
            }
            self.data += n;
            while let Some(at) = continued_at(&self.line) {
                self.line.truncate(at);
                self.line.push(b' ');
                let more = self.input.read_line(&mut self.line)? as u64;
                self.data += more;
                let longest = self.input.limits().line_bytes();
                if self.line.len() > longest {
                    let message = format!(
                        "line {}, continued with '\\', is longer than {}, the longest line a text file may have",
                        self.line_number,
                        size_text(longest as u64)
                    );
                    return Err(self.stop(Error::scene(self.path, message)));
                }
                if more == 0 {
                    break;
                }
            }
            self.check_idle()?;
            if memchr::memchr(0, &self.line).is_some() {
                let message = if self.line_number == 1 || self.line[0] == 0 {
                    format!("line {}: a NUL byte: {UTF16_MESSAGE}", self.line_number)
                } else {
                    format!("line {}: invalid OBJ: a NUL byte", self.line_number)
                };
                return Err(self.stop_at_line(message));
            }
            if let Some(at) = memchr::memchr(b'#', &self.line) {
                // A comment after the data.
                self.line.truncate(at);
                self.line.push(b'\n');
            }
            if std::str::from_utf8(&self.line).is_err() {
                // Names in other encodings: not needed, and `tobj` reads only UTF-8.
                self.line = String::from_utf8_lossy(&self.line).into_owned().into_bytes();
            }
            let line = std::mem::take(&mut self.line);
            let checked = self.check_line(std::str::from_utf8(&line).unwrap_or_default());
            self.line = line;
            checked?;
            if keep_geometry(&mut self.line) {
                return Ok(());
            }
        }
    }

    /// Checks the line `text` (the current line) and charges what `tobj` will hold for it.
    fn check_line(&mut self, text: &str) -> io::Result<()> {
        let mut words = text.split_whitespace();
        let keyword = words.next().unwrap_or("");
        let number = self.line_number;
        let fail = |e: ObjLineError| format!("line {number}: invalid OBJ: {e}");
        match keyword {
            "v" | "vt" | "vn" => {
                let numbers: Vec<&str> = words.collect();
                if let Err(e) = check_numbers(keyword, &numbers) {
                    return Err(self.stop_at_line(fail(e)));
                }
                let element = match keyword {
                    "v" => Element::Vertex,
                    "vt" => Element::TexCoord,
                    _ => Element::Normal,
                };
                self.counts[element as usize] += 1;
                if element == Element::Vertex
                    && self.first_non_finite.is_none()
                    && let Some(c) = parse_vertex_line(text).and_then(non_finite_coordinate)
                {
                    self.first_non_finite = Some(format!(
                        "vertex {} (line {}) has a non-finite coordinate ({c})",
                        self.counts[0], self.line_number
                    ));
                }
            }
            "f" => {
                if let Err(e) = self.check_face(words) {
                    return Err(self.stop_at_line(fail(e)));
                }
            }
            // An object or a group ends the one before: `tobj` resolves its faces' indices.
            "o" | "g" => self.resolve_pending(Some(self.line_number))?,
            _ => {}
        }
        if let Err(e) = self.meter.charge(self.path, line_bytes(text)) {
            return Err(self.stop(e));
        }
        Ok(())
    }

    /// Checks the corners of a face (`corners`: the words after `f`) as `tobj` parses
    /// them, and, for a face of three corners or more (fewer make no surface, and `tobj`
    /// leaves their indices alone), keeps its indices to resolve where its object ends.
    fn check_face<'t>(
        &mut self,
        corners: impl Iterator<Item = &'t str> + Clone,
    ) -> std::result::Result<(), ObjLineError> {
        let surface = corners.clone().count() >= 3;
        for corner in corners {
            let mut parts = corner.split('/');
            for (k, element) in Element::ALL.into_iter().enumerate() {
                let part = match parts.next() {
                    Some(p) if !p.is_empty() => p,
                    _ if k == 0 => {
                        return Err(ObjLineError::NoVertex { corner: super::input::one_line(corner) });
                    }
                    _ => continue,
                };
                let i = corner_index(part, corner)?;
                if !surface {
                    continue;
                }
                let count = self.counts[element as usize];
                let pending = &mut self.pending[element as usize];
                if i > 0 {
                    if i as u64 > pending.largest {
                        (pending.largest, pending.largest_line) = (i as u64, self.line_number);
                    }
                } else if i == 0 || i.unsigned_abs() > count {
                    if element == Element::Vertex {
                        return Err(ObjLineError::OutOfBounds { element, index: i, count, at: " before it".into() });
                    }
                    pending.before_start.get_or_insert((i, self.line_number, count));
                }
            }
            if parts.next().is_some() {
                return Err(ObjLineError::TooManyParts { corner: super::input::one_line(corner) });
            }
        }
        Ok(())
    }

    /// Resolves the face indices of the object that ends at line `end` (at the end of the
    /// file for `None`) as `tobj` does there: every vertex index must name a vertex read
    /// by then, and every texture coordinate or normal index one of those, if the file
    /// has any by then (`tobj` ignores them otherwise).
    fn resolve_pending(&mut self, end: Option<u64>) -> io::Result<()> {
        let pending = std::mem::take(&mut self.pending);
        for element in Element::ALL {
            let count = self.counts[element as usize];
            let p = pending[element as usize];
            if element != Element::Vertex && count == 0 {
                continue;
            }
            let at = match end {
                Some(line) => format!(" by line {line}, where its object ends"),
                None => String::new(),
            };
            let error = if let Some((i, line, then)) = p.before_start {
                Some((line, out_of_bounds(element, i, then, " before it")))
            } else if p.largest > count {
                Some((p.largest_line, out_of_bounds(element, p.largest as i64, count, &at)))
            } else {
                None
            };
            if let Some((line, message)) = error {
                return Err(self.stop_at_line(format!("line {line}: invalid OBJ: {message}")));
            }
        }
        Ok(())
    }

    /// Ends the stream with `e`, a limit exceeded, which the loader reports.
    fn stop(&mut self, e: Error) -> io::Error {
        let message = e.message();
        self.error.get_or_insert(e);
        io::Error::other(message)
    }

    /// Ends the stream at a line in error, `message` (which names it).
    fn stop_at_line(&mut self, message: String) -> io::Error {
        self.line_error.get_or_insert(Error::scene(self.path, message.clone()));
        io::Error::other(message)
    }
}

/// "face vertex index out of bounds (9, with 3 vertices)".
fn out_of_bounds(element: Element, index: i64, count: u64, at: &str) -> String {
    let (name, plural) = (element.name(), element.plural());
    if index == 0 {
        return format!("face {name} index out of bounds (0: OBJ counts from 1)");
    }
    format!("face {name} index out of bounds ({index}, with {count} {plural}{at})")
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
    // The first problem in the file: a non-finite vertex comes before the line that stopped it.
    if let Some(message) = lines.first_non_finite.take() {
        return Err(Error::scene(path, message));
    }
    if let Some(e) = lines.line_error.take() {
        return Err(e);
    }
    let line = lines.line_number;
    let (models, _) = loaded.map_err(|e| Error::scene(path, format!("line {line}: invalid OBJ: {e}")))?;

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
    input.skip_text_mark().ok()?;
    let mut line = Vec::new();
    let mut number = 0;
    loop {
        line.clear();
        if input.read_line(&mut line).ok()? == 0 {
            return None;
        }
        let line_number = input.line_number() as usize;
        if line.iter().find(|b| !b.is_ascii_whitespace()) != Some(&b'#') {
            while let Some(at) = continued_at(&line) {
                line.truncate(at);
                line.push(b' ');
                if input.read_line(&mut line).ok()? == 0 {
                    break;
                }
            }
        }
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
                assert_eq!(lines.vertices(), 5, "reads of {chunk}");
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
    fn the_file_is_read_as_tobj_resolves_it_whatever_its_names_and_line_ends() {
        let plain = load_files(&[("m.obj", &format!("{SQUARE}f 1 2 3 4\n"))]).unwrap();
        // A face may name a vertex below it in its object; texture coordinates and normals a
        // file has none of are not resolved; `vt u` is a coordinate; a comment may follow data.
        for text in [
            "f 1 2 3 4\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n".to_string(),
            format!("{SQUARE}f 1/9/9 2/9/9 3/9/9 4/9/9\n"),
            format!("{SQUARE}vt 0.5\nf 1/1 2/1 3/-1 4/1 # a quad\n"),
            format!("\u{feff}{SQUARE}f 1 2 \\\r\n 3 4\r\n"),
        ] {
            let mesh = load_files(&[("m.obj", &text)]).unwrap_or_else(|e| panic!("{text:?}: {e}"));
            assert_eq!(
                (mesh.positions, mesh.triangles),
                (plain.positions.clone(), plain.triangles.clone()),
                "{text:?}"
            );
        }
    }

    #[test]
    fn errors_name_the_line_tobj_would_fail_at() {
        for (text, want) in [
            // The object ends before the vertex its face names.
            (
                format!("v 0 0 0\nf 1 2 3\ng next\n{SQUARE}"),
                "line 2: invalid OBJ: face vertex index out of bounds (3, with 1 vertices by line 3",
            ),
            (
                format!("{SQUARE}vt 0 0\nf 1/2 2/1 3/1\n"),
                "line 6: invalid OBJ: face texture coordinate index out of bounds (2, with 1 texture coordinates)",
            ),
            (
                format!("{SQUARE}f 1//-1 2 3\nvn 0 0 1\n"),
                "line 5: invalid OBJ: face normal index out of bounds (-1, with 0 normals before it)",
            ),
            (
                format!("{SQUARE}f 1 2 -5\n"),
                "line 5: invalid OBJ: face vertex index out of bounds (-5, with 4 vertices before it)",
            ),
            (format!("# c\n\n{SQUARE}vn 0 1\n"), "line 7: invalid OBJ: a normal needs 3 numbers, found 2"),
            (format!("{SQUARE}v 1 2 3 0\n"), "line 5: invalid OBJ: a vertex with w = 0"),
            ("v 1 \\\n2 3\nv x 0 0\n".to_string(), "line 3: invalid OBJ: 'x' is not a number"),
        ] {
            let e = load_files(&[("m.obj", &text)]).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
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
