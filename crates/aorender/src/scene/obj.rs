//! Wavefront OBJ, read by one parser for the scene and for the bake: positions (a
//! homogeneous `w` divided out, a vertex colour read past), texture coordinates, normals
//! and faces in every index form (`v`, `v/vt`, `v//vn`, `v/vt/vn`, negative indices
//! counting back from the line). Polygons are split as fans (v0, v(k-1), vk), every
//! object and group merged, points (`p`, faces of fewer than three corners) and lines
//! (`l`) ignored, and so are materials, smoothing groups and names: no file but the input
//! is read.
//!
//! Indices follow the format's numbering ("Object Files (.obj)", Wavefront's Advanced
//! Visualizer manual, appendix B1, "Referencing vertex data"): the vertices of the file are
//! numbered from 1 in the order they appear, through the whole file, whatever objects and
//! groups lie between; a negative index counts back from the line it is on. So a positive
//! index may name a vertex defined further down, and one past the file's last vertex is
//! out of bounds. Texture coordinate and normal indices are checked only when the file has
//! some of them (they are ignored otherwise).
//!
//! The text is read bytes first (`.obj.gz` decompressed), in rounds of blocks that end at
//! line ends; each round's blocks are parsed on rayon's threads into their own buffers,
//! then taken in order, relative indices resolved from the counts before each block. A
//! line is bytes, not text: a name or a comment in any encoding is no error; a UTF-8
//! byte-order mark is skipped and UTF-16 refused in one line; lines continued with `\`
//! are joined, a comment after data cut off. Numbers are parsed by `fast-float2`, which
//! rounds as `str::parse::<f32>` does (words outside its plain grammar, such as `inf`,
//! go to `str::parse`). The memory the text and what is read from it take is charged to
//! the read budget as they grow, blank and comment lines may not outgrow the data lines
//! (see [`ReadLimits::idle_bytes`]), and a line is at most the longest a text file may
//! have. When something is wrong, the text read so far is parsed again from its start, in
//! order, for the first problem: its error names the line.

use super::input::{Input, Meter, ReadLimits, UTF16_MESSAGE, size_text, vec_bytes};
use super::mesh::{IndexedMesh, VertexNames};
pub(crate) use super::types::non_finite_coordinate;
use crate::error::{Error, Result};
use glam::{Vec2, Vec3};
use std::path::Path;

/// Bytes of lines one block (one rayon task) parses: large enough that a task's work
/// dwarfs handing it out, small enough that a round of them holds little.
const BLOCK_BYTES: usize = 1 << 20;

/// Blocks per thread in a round of reading and parsing.
const BLOCKS_PER_THREAD: usize = 4;

/// Most bytes of parsed data one byte of text makes (a corner `1 ` of two bytes: its
/// vertex, texture coordinate and normal indices, 12 bytes): charged for a round before
/// it is parsed, so that its buffers stay within the budget.
const PARSED_BYTES_PER_BYTE: u64 = 6;
/// The same without texture coordinates and normals (a corner `-1 `: its vertex index
/// and its place among the relative ones, 12 bytes).
const SCENE_BYTES_PER_BYTE: u64 = 4;

/// What a read keeps besides the positions and the faces.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Keep {
    /// The text itself (the bake writes it back).
    pub text: bool,
    /// Texture coordinates and normals, and the indices of each corner's.
    pub attributes: bool,
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
    fn name(self) -> &'static str {
        match self {
            Element::Vertex => "vertex",
            Element::TexCoord => "texture coordinate",
            Element::Normal => "normal",
        }
    }

    /// "vertices", "texture coordinates", "normals".
    fn plural(self) -> &'static str {
        match self {
            Element::Vertex => "vertices",
            Element::TexCoord => "texture coordinates",
            Element::Normal => "normals",
        }
    }
}

/// An OBJ file as read: every `v` line's position, and what [`Keep`] asked for.
#[derive(Debug, Default)]
pub(crate) struct ObjData {
    /// The text (decompressed, without a byte-order mark), when kept.
    pub text: Vec<u8>,
    /// Every `v` line's position, in the file's order.
    pub positions: Vec<Vec3>,
    /// Every `vt` line's u and v (a missing v is 0, a w ignored), when kept.
    pub uvs: Vec<Vec2>,
    /// Every `vn` line's normal, when kept.
    pub normals: Vec<Vec3>,
    /// The file's `vt` and `vn` lines.
    pub texcoord_count: u64,
    pub normal_count: u64,
    /// Face `f` (a face of three corners or more, in the file's order) has the corners
    /// `face_indices[face_starts[f] .. face_starts[f + 1]]`; starts with 0.
    pub face_starts: Vec<u32>,
    /// Each corner's vertex, from 0.
    pub face_indices: Vec<u32>,
    /// Each corner's texture coordinate and normal, from 0 (`u32::MAX` for none), when kept.
    pub corner_uvs: Vec<u32>,
    pub corner_normals: Vec<u32>,
}

impl ObjData {
    /// The bytes its vectors hold.
    fn bytes(&self) -> u64 {
        vec_bytes(&self.text)
            + vec_bytes(&self.positions)
            + vec_bytes(&self.uvs)
            + vec_bytes(&self.normals)
            + vec_bytes(&self.face_starts)
            + vec_bytes(&self.face_indices)
            + vec_bytes(&self.corner_uvs)
            + vec_bytes(&self.corner_normals)
    }
}

/// What is wrong with one line of an OBJ file (the reader adds the line and the file).
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
    /// A face index that names no element: `count` of them (`before` the line, or in the file).
    #[error("{}", out_of_bounds(*element, *index, *count, *before))]
    OutOfBounds { element: Element, index: i64, count: u64, before: bool },
}

/// "face vertex index out of bounds (9, with 3 vertices)".
fn out_of_bounds(element: Element, index: i64, count: u64, before: bool) -> String {
    let (name, plural) = (element.name(), element.plural());
    if index == 0 {
        return format!("face {name} index out of bounds (0: OBJ counts from 1)");
    }
    let at = if before { " before it" } else { "" };
    format!("face {name} index out of bounds ({index}, with {count} {plural}{at})")
}

/// A problem found on a line, with the line (from 1, counted in the text parsed).
#[derive(Clone, Debug, PartialEq)]
enum Problem {
    /// "line N: invalid OBJ: …".
    Line(ObjLineError),
    /// A physical line longer than the longest line a text file may have.
    Long,
    /// A line continued with `\` longer than that, joined.
    LongContinued,
    /// A NUL byte: UTF-16 text when it starts the file or a line.
    Nul { starts: bool },
    /// A vertex with a coordinate not finite (its number from 1, and the coordinate).
    NonFinite { vertex: u64, coordinate: String },
    /// Blank and comment lines past their allowance.
    Idle,
}

impl Problem {
    /// The message for this problem at line `line` of a file read within `limits`.
    fn message(&self, line: u64, limits: &ReadLimits) -> String {
        let longest = size_text(limits.line_bytes() as u64);
        match self {
            Problem::Line(e) => format!("line {line}: invalid OBJ: {e}"),
            Problem::Long => format!("line {line} is longer than {longest}, the longest line a text file may have"),
            Problem::LongContinued => {
                format!(
                    "line {line}, continued with '\\', is longer than {longest}, the longest line a text file may have"
                )
            }
            Problem::Nul { starts: true } => format!("line {line}: a NUL byte: {UTF16_MESSAGE}"),
            Problem::Nul { starts: false } => format!("line {line}: invalid OBJ: a NUL byte"),
            Problem::NonFinite { vertex, coordinate } => {
                format!("vertex {vertex} (line {line}) has a non-finite coordinate ({coordinate})")
            }
            Problem::Idle => limits.idle_message(line),
        }
    }
}

/// A word as a number, rounded to the nearest `f32` as `str::parse::<f32>` rounds it.
/// Words of the plain decimal grammar go through `fast-float2`; others (`inf`, `NaN`, and
/// what is no number) through `str::parse`, so that the two accept the same words.
pub(crate) fn parse_f32(word: &str) -> Option<f32> {
    let plain = word.bytes().all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E'));
    if plain { fast_float2::parse::<f32, _>(word).ok() } else { word.parse().ok() }
}

/// A face index as `str::parse::<i64>` reads it (an optional sign, then digits).
fn parse_index(part: &str) -> Option<i64> {
    let b = part.as_bytes();
    let (negative, digits) = match b.first() {
        Some(b'-') => (true, &b[1..]),
        Some(b'+') => (false, &b[1..]),
        _ => (false, b),
    };
    if digits.is_empty() || digits.len() > 18 || !digits.iter().all(u8::is_ascii_digit) {
        // Longer numbers may overflow: `str::parse` says.
        return part.parse().ok();
    }
    let magnitude = digits.iter().fold(0i64, |v, &d| v * 10 + i64::from(d - b'0'));
    Some(if negative { -magnitude } else { magnitude })
}

/// White space as `str::split_whitespace` sees it in ASCII text.
fn is_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | b'\r' | 0x0B | 0x0C)
}

/// The words of a line, split as `str::split_whitespace` splits them: byte by byte for
/// ASCII text, by Unicode white space otherwise.
enum Words<'a> {
    Ascii { text: &'a str, at: usize },
    Unicode(std::str::SplitWhitespace<'a>),
}

impl<'a> Words<'a> {
    fn new(text: &'a str) -> Words<'a> {
        if text.is_ascii() { Words::Ascii { text, at: 0 } } else { Words::Unicode(text.split_whitespace()) }
    }
}

impl<'a> Iterator for Words<'a> {
    type Item = &'a str;

    fn next(&mut self) -> Option<&'a str> {
        match self {
            Words::Ascii { text, at } => {
                let b = text.as_bytes();
                let mut i = *at;
                while i < b.len() && is_space(b[i]) {
                    i += 1;
                }
                if i == b.len() {
                    *at = i;
                    return None;
                }
                let start = i;
                while i < b.len() && !is_space(b[i]) {
                    i += 1;
                }
                *at = i;
                Some(&text[start..i])
            }
            Words::Unicode(words) => words.next(),
        }
    }
}

/// If `line` (with its ending) is continued on the next (its last character before the
/// ending is `\`), where that `\` is.
pub(crate) fn continued_at(line: &[u8]) -> Option<usize> {
    let end = line.len() - line.iter().rev().take_while(|&&b| b == b'\n' || b == b'\r').count();
    (end > 0 && line[end - 1] == b'\\').then_some(end - 1)
}

/// The first byte that is not a blank (` `, tab, carriage return) of a line.
fn first_data(line: &[u8]) -> Option<usize> {
    line.iter().position(|&b| !matches!(b, b' ' | b'\t' | b'\r' | b'\n'))
}

/// A relative index of a block, resolved once the counts before the block are known.
#[derive(Clone, Copy, Debug)]
struct Relative {
    /// Where its index goes in the block's corner array of its element (the element in
    /// the top two bits: a block holds far fewer than 2^30 corners).
    slot: u32,
    /// The block's count of the element before its line, plus the (negative) index;
    /// `i32::MIN` for any that reach further back than a file within the budget can hold.
    local: i32,
}

impl Relative {
    fn new(element: Element, slot: usize, local: i64) -> Relative {
        let local = i32::try_from(local).unwrap_or(i32::MIN);
        Relative { slot: (element as u32) << 30 | slot as u32, local }
    }

    fn element(self) -> Element {
        Element::ALL[(self.slot >> 30) as usize]
    }

    fn slot(self) -> usize {
        (self.slot & ((1 << 30) - 1)) as usize
    }
}

/// What the checks of a parse from the start of the text need to know of the whole.
#[derive(Clone, Copy, Debug)]
struct Whole {
    /// Each element's count in the text parsed.
    counts: [u64; 3],
    /// Whether the text was read to its end (positive indices are checked against the
    /// counts only then).
    complete: bool,
    /// Bytes of blank and comment lines allowed beyond those of data lines.
    idle_allowance: u64,
}

/// One block's lines parsed.
#[derive(Debug, Default)]
struct Block {
    /// Physical lines (line ends, and a last line without one).
    lines: u64,
    /// `v` lines.
    vertices: u64,
    positions: Vec<Vec3>,
    uvs: Vec<Vec2>,
    texcoords: u64,
    normals: Vec<Vec3>,
    normal_count: u64,
    /// Corners of each face of three corners or more.
    face_sizes: Vec<u32>,
    corners: Vec<u32>,
    corner_uvs: Vec<u32>,
    corner_normals: Vec<u32>,
    relative: Vec<Relative>,
    /// The largest positive index of each element.
    largest: [u64; 3],
    /// A texture coordinate or normal index of 0 (an error when the file has some).
    zero: [bool; 3],
    /// Bytes of blank and comment lines, of data lines, and the most the first ran ahead
    /// of the second after any line of the block.
    idle: u64,
    data: u64,
    most_ahead: i64,
    /// The first problem (and its line in the block), where the parse stopped.
    problem: Option<(u64, Problem)>,
}

/// Parses a block's lines, `text`, keeping the attributes when `attributes`. With `whole`,
/// the block is the text from its start, and every check of the whole file is made on the
/// way (relative indices against the counts so far, positive ones against the file's,
/// the blank lines' allowance): the first problem is the file's first.
fn parse_block(text: &[u8], attributes: bool, longest: usize, whole: Option<&Whole>) -> Block {
    let mut block = Block::default();
    let mut joined = Vec::new();
    let has_nul = memchr::memchr(0, text).is_some();
    let mut rest = text;
    while !rest.is_empty() {
        let end = memchr::memchr(b'\n', rest).map_or(rest.len(), |e| e + 1);
        let (physical, next) = rest.split_at(end);
        rest = next;
        block.lines += 1;
        let number = block.lines;
        if physical.len() > longest {
            block.problem = Some((number, Problem::Long));
            return block;
        }
        // Blank and comment lines, and the blanks before data.
        let start = first_data(physical);
        let is_comment = start.is_none_or(|s| physical[s] == b'#');
        let mut line = physical;
        if !is_comment && continued_at(physical).is_some() {
            joined.clear();
            let mut piece = physical;
            while let Some(at) = continued_at(piece) {
                joined.extend_from_slice(&piece[..at]);
                joined.push(b' ');
                if rest.is_empty() {
                    break;
                }
                let end = memchr::memchr(b'\n', rest).map_or(rest.len(), |e| e + 1);
                (piece, rest) = rest.split_at(end);
                block.lines += 1;
                if piece.len() > longest {
                    block.problem = Some((block.lines, Problem::Long));
                    return block;
                }
                if continued_at(piece).is_none() {
                    joined.extend_from_slice(piece);
                }
                if joined.len() > longest {
                    block.problem = Some((number, Problem::LongContinued));
                    return block;
                }
            }
            line = &joined;
        }
        match start {
            Some(s) if !is_comment => {
                block.idle += s as u64;
                block.data += (line.len() - s) as u64;
            }
            _ => block.idle += line.len() as u64,
        }
        let ahead = block.idle as i64 - block.data as i64;
        block.most_ahead = block.most_ahead.max(ahead);
        if let Some(w) = whole
            && ahead > w.idle_allowance as i64
        {
            block.problem = Some((number, Problem::Idle));
            return block;
        }
        if is_comment {
            continue;
        }
        if has_nul && memchr::memchr(0, line).is_some() {
            let starts = number == 1 || line[start.unwrap_or(0)] == 0;
            block.problem = Some((number, Problem::Nul { starts }));
            return block;
        }
        // A comment after the data is not part of it.
        let line = memchr::memchr(b'#', line).map_or(line, |at| &line[..at]);
        let lossy;
        let text = match std::str::from_utf8(line) {
            Ok(text) => text,
            Err(_) => {
                // Names in other encodings: not needed; a number with such bytes is no number.
                lossy = String::from_utf8_lossy(line);
                &lossy
            }
        };
        if let Err(problem) = parse_line(text, &mut block, attributes, whole) {
            block.problem = Some((number, problem));
            return block;
        }
    }
    block
}

/// Parses one line (a comment cut off) onto `block`.
fn parse_line(
    text: &str,
    block: &mut Block,
    attributes: bool,
    whole: Option<&Whole>,
) -> std::result::Result<(), Problem> {
    let mut words = Words::new(text);
    let line_error = |e: ObjLineError| Problem::Line(e);
    match words.next() {
        Some("v") => {
            let mut numbers = [""; 4];
            let mut n = 0;
            for word in words {
                if n < numbers.len() {
                    numbers[n] = word;
                }
                n += 1;
            }
            if n < 3 {
                return Err(line_error(ObjLineError::PositionNumbers(n)));
            }
            if !matches!(n, 3 | 4 | 6) {
                return Err(line_error(ObjLineError::VertexNumbers(n)));
            }
            let number = |w: &str, what: &'static str| {
                parse_f32(w)
                    .ok_or_else(|| line_error(ObjLineError::NotANumber { word: super::input::one_line(w), what }))
            };
            let what = "a vertex position coordinate";
            let mut p = Vec3::new(number(numbers[0], what)?, number(numbers[1], what)?, number(numbers[2], what)?);
            if n == 4 {
                let w = number(numbers[3], "a vertex's w")?;
                if w == 0.0 {
                    return Err(line_error(ObjLineError::AtInfinity));
                }
                if w != 1.0 {
                    p = Vec3::new(p.x / w, p.y / w, p.z / w);
                }
            }
            if let Some(coordinate) = non_finite_coordinate(p) {
                return Err(Problem::NonFinite { vertex: block.vertices + 1, coordinate });
            }
            block.vertices += 1;
            // A parse from the start only looks for problems: it keeps nothing.
            if whole.is_none() {
                block.positions.push(p);
            }
        }
        Some("vt") => {
            let what = "a texture coordinate";
            let u = words.next().ok_or(line_error(ObjLineError::NoTexCoordNumbers))?;
            let number = |w: &str| {
                parse_f32(w)
                    .ok_or_else(|| line_error(ObjLineError::NotANumber { word: super::input::one_line(w), what }))
            };
            let u = number(u)?;
            let v = match words.next() {
                Some(v) => number(v)?,
                None => 0.0,
            };
            block.texcoords += 1;
            if attributes && whole.is_none() {
                block.uvs.push(Vec2::new(u, v));
            }
        }
        Some("vn") => {
            let mut n = [0.0f32; 3];
            let mut found = 0;
            let mut bad = None;
            for word in words {
                if found < 3 && bad.is_none() {
                    match parse_f32(word) {
                        Some(c) => n[found] = c,
                        None => bad = Some(word),
                    }
                }
                found += 1;
            }
            if found < 3 {
                return Err(line_error(ObjLineError::NormalNumbers(found)));
            }
            if let Some(word) = bad {
                let word = super::input::one_line(word);
                return Err(line_error(ObjLineError::NotANumber { word, what: "a normal" }));
            }
            block.normal_count += 1;
            if attributes && whole.is_none() {
                block.normals.push(Vec3::from_array(n));
            }
        }
        Some("f") => parse_face(text, words, block, attributes, whole).map_err(line_error)?,
        _ => {}
    }
    Ok(())
}

/// Parses the corners of a face (`corners`, the words after `f`) onto `block`; a face of
/// fewer than three corners has its indices checked as words, not resolved.
fn parse_face<'t>(
    text: &str,
    corners: Words<'t>,
    block: &mut Block,
    attributes: bool,
    whole: Option<&Whole>,
) -> std::result::Result<(), ObjLineError> {
    let surface = Words::new(text).nth(3).is_some();
    let start = block.corners.len();
    for corner in corners {
        let mut parts = corner.split('/');
        let mut resolved = [u32::MAX; 3];
        for (k, element) in Element::ALL.into_iter().enumerate() {
            let part = match parts.next() {
                Some(p) if !p.is_empty() => p,
                _ if k == 0 => return Err(ObjLineError::NoVertex { corner: super::input::one_line(corner) }),
                _ => continue,
            };
            let i = parse_index(part).ok_or_else(|| ObjLineError::NotAnIndex {
                corner: super::input::one_line(corner),
                part: super::input::one_line(part),
            })?;
            if surface {
                resolved[k] = block.resolve(element, i, whole)?;
            }
        }
        if parts.next().is_some() {
            return Err(ObjLineError::TooManyParts { corner: super::input::one_line(corner) });
        }
        if surface && whole.is_none() {
            block.corners.push(resolved[0]);
            if attributes {
                block.corner_uvs.push(resolved[1]);
                block.corner_normals.push(resolved[2]);
            }
        }
    }
    if surface && whole.is_none() {
        let size = block.corners.len() - start;
        block.face_sizes.push(u32::try_from(size).unwrap_or(u32::MAX));
    }
    Ok(())
}

impl Block {
    fn count(&self, element: Element) -> u64 {
        match element {
            Element::Vertex => self.vertices,
            Element::TexCoord => self.texcoords,
            Element::Normal => self.normal_count,
        }
    }

    /// The index `i` of `element` from 0 (`u32::MAX` where it is resolved later, or past
    /// 32 bits, which is more than any file here has), checked as far as the block can.
    fn resolve(&mut self, element: Element, i: i64, whole: Option<&Whole>) -> std::result::Result<u32, ObjLineError> {
        let e = element as usize;
        let count = self.count(element);
        // Texture coordinate and normal indices count only when the file has some.
        let checked = element == Element::Vertex || whole.is_some_and(|w| w.counts[e] > 0);
        let fail = |before| Err(ObjLineError::OutOfBounds { element, index: i, count, before });
        if i > 0 {
            let index = i.unsigned_abs();
            self.largest[e] = self.largest[e].max(index);
            if let Some(w) = whole
                && checked
                && w.complete
                && index > w.counts[e]
            {
                return Err(ObjLineError::OutOfBounds { element, index: i, count: w.counts[e], before: false });
            }
            return Ok(u32::try_from(index - 1).unwrap_or(u32::MAX));
        }
        if i == 0 {
            if checked && (whole.is_some() || element == Element::Vertex) {
                return fail(false);
            }
            self.zero[e] = true;
            return Ok(u32::MAX);
        }
        if whole.is_some() {
            if i.unsigned_abs() > count {
                return if checked { fail(true) } else { Ok(u32::MAX) };
            }
            return Ok((count - i.unsigned_abs()) as u32);
        }
        let slot = match element {
            Element::Vertex => self.corners.len(),
            Element::TexCoord => self.corner_uvs.len(),
            Element::Normal => self.corner_normals.len(),
        };
        self.relative.push(Relative::new(element, slot, count as i64 + i));
        Ok(u32::MAX)
    }

    /// The bytes its vectors hold.
    fn bytes(&self) -> u64 {
        vec_bytes(&self.positions)
            + vec_bytes(&self.uvs)
            + vec_bytes(&self.normals)
            + vec_bytes(&self.face_sizes)
            + vec_bytes(&self.corners)
            + vec_bytes(&self.corner_uvs)
            + vec_bytes(&self.corner_normals)
            + vec_bytes(&self.relative)
    }
}

/// Where `text` may be cut into blocks: after the last line end (from `from` on) whose
/// line is not continued with `\`, at most `most` bytes in when there is one there.
fn cut(text: &[u8], most: usize) -> Option<usize> {
    let mut end = most.min(text.len());
    loop {
        let at = memchr::memrchr(b'\n', &text[..end])?;
        let line_start = memchr::memrchr(b'\n', &text[..at]).map_or(0, |s| s + 1);
        if continued_at(&text[line_start..=at]).is_none() {
            return Some(at + 1);
        }
        end = at;
    }
}

/// Room for `add` more elements in `v`, its growth charged to `meter` first: doubling,
/// within what is left of the budget.
fn reserve<T>(v: &mut Vec<T>, add: usize, meter: &mut Meter, path: &Path) -> Result<()> {
    let need = v.len().saturating_add(add);
    if need <= v.capacity() {
        return Ok(());
    }
    let size = std::mem::size_of::<T>().max(1);
    let fits = usize::try_from(meter.left() / size as u64).unwrap_or(usize::MAX);
    let want = v.capacity().saturating_mul(2).min(v.capacity().saturating_add(fits)).max(need);
    let grow = want - v.capacity();
    meter.charge(path, (grow * size) as u64)?;
    v.try_reserve_exact(want - v.len()).map_err(|_| meter.refused(path, (grow * size) as u64))
}

/// Takes `block` into `data`, its growth charged to `meter`: its relative indices
/// resolved from the counts before it. Returns false when a vertex index reaches before
/// the first vertex (a texture coordinate or normal index that does is marked in `bad`).
fn append(data: &mut ObjData, mut block: Block, bad: &mut [bool; 3], meter: &mut Meter, path: &Path) -> Result<bool> {
    let before = [data.positions.len() as u64, data.texcoord_count, data.normal_count];
    let mut ok = true;
    for r in &block.relative {
        let element = r.element();
        let e = element as usize;
        let index = before[e] as i64 + i64::from(r.local);
        let value = if index < 0 || r.local == i32::MIN {
            bad[e] = true;
            ok &= element != Element::Vertex;
            u32::MAX
        } else {
            u32::try_from(index).unwrap_or(u32::MAX)
        };
        let slots = match element {
            Element::Vertex => &mut block.corners,
            Element::TexCoord => &mut block.corner_uvs,
            Element::Normal => &mut block.corner_normals,
        };
        // Without the attributes kept, only whether a texture coordinate or normal index
        // reaches before the first counts.
        if let Some(slot) = slots.get_mut(r.slot()) {
            *slot = value;
        }
    }
    reserve(&mut data.positions, block.positions.len(), meter, path)?;
    reserve(&mut data.uvs, block.uvs.len(), meter, path)?;
    reserve(&mut data.normals, block.normals.len(), meter, path)?;
    reserve(&mut data.face_starts, block.face_sizes.len() + 1, meter, path)?;
    reserve(&mut data.face_indices, block.corners.len(), meter, path)?;
    reserve(&mut data.corner_uvs, block.corner_uvs.len(), meter, path)?;
    reserve(&mut data.corner_normals, block.corner_normals.len(), meter, path)?;
    let mut corner = data.face_indices.len() as u64;
    if data.face_starts.is_empty() {
        data.face_starts.push(0);
    }
    for size in &block.face_sizes {
        corner += u64::from(*size);
        data.face_starts.push(u32::try_from(corner).unwrap_or(u32::MAX));
    }
    data.positions.append(&mut block.positions);
    data.uvs.append(&mut block.uvs);
    data.normals.append(&mut block.normals);
    data.texcoord_count += block.texcoords;
    data.normal_count += block.normal_count;
    data.face_indices.append(&mut block.corners);
    data.corner_uvs.append(&mut block.corner_uvs);
    data.corner_normals.append(&mut block.corner_normals);
    Ok(ok)
}

/// What the parallel parse found that makes the text need a parse from its start.
#[derive(Debug, Default)]
struct Findings {
    /// Something is wrong (a problem in a block, a relative vertex index before the first,
    /// the blank lines past their allowance).
    wrong: bool,
    largest: [u64; 3],
    zero: [bool; 3],
    before_first: [bool; 3],
    /// Bytes of blank and comment lines, and of data lines, so far.
    idle: u64,
    data: u64,
}

/// Reads an OBJ file (`.obj` or `.obj.gz`) within `meter`'s budget, keeping what `keep`
/// asks for; every check of the format is made (see the module's documentation).
pub(crate) fn read_obj(path: &Path, meter: &mut Meter, keep: Keep) -> Result<ObjData> {
    read_obj_in_blocks(path, meter, keep, BLOCK_BYTES)
}

/// [`read_obj`] with blocks of `block_bytes` (tests use small ones).
pub(crate) fn read_obj_in_blocks(path: &Path, meter: &mut Meter, keep: Keep, block_bytes: usize) -> Result<ObjData> {
    use rayon::prelude::*;
    let limits = meter.limits().clone();
    let longest = limits.line_bytes();
    let mut input = Input::open(path, &limits)?;
    if input.skip_text_mark().is_err() {
        return Err(Error::scene(path, input.stream_error().unwrap_or(UTF16_MESSAGE).to_string()));
    }
    let base = meter.used();
    let threads = rayon::current_num_threads().max(1);
    let factor = if keep.attributes { PARSED_BYTES_PER_BYTE } else { SCENE_BYTES_PER_BYTE };
    let mut data = ObjData::default();
    let mut found = Findings::default();
    // The text read so far (kept: an error is found by parsing it again), and where its
    // unparsed part starts.
    let mut text: Vec<u8> = Vec::new();
    let mut parsed = 0;
    let mut read_error = None;
    loop {
        meter.hold(path, base + data.bytes() + vec_bytes(&text))?;
        // A round's parsed data must fit in what is left of the budget.
        let round =
            (block_bytes * threads * BLOCKS_PER_THREAD).min((meter.left() / (factor + 1)) as usize).max(1 << 16);
        let before = text.len();
        if let Err(e) = input.read_into(path, &mut text, meter, 1, round as u64) {
            read_error = Some(e);
        }
        let at_end = read_error.is_some() || text.len() == before;
        // Whole lines only, unless the file ends; a line without an end too long to wait
        // for is parsed as it is, and refused.
        let unparsed = &text[parsed..];
        let end = if at_end && read_error.is_none() {
            unparsed.len()
        } else {
            match cut(unparsed, usize::MAX) {
                Some(end) => end,
                None if unparsed.len() > 4 * longest + 4 => {
                    // One line longer than any may be, even joined: the parse from the start finds it.
                    parsed = text.len();
                    found.wrong = true;
                    break;
                }
                None => 0,
            }
        };
        let mut blocks = Vec::new();
        let mut rest = &unparsed[..end];
        while !rest.is_empty() {
            let n = if rest.len() <= block_bytes { rest.len() } else { cut(rest, block_bytes).unwrap_or(rest.len()) };
            blocks.push(&rest[..n]);
            rest = &rest[n..];
        }
        if let Err(e) = meter.charge(path, (end as u64).saturating_mul(factor)) {
            // Past the budget: the parse from the start says whether a line before failed.
            (read_error, found.wrong, parsed) = (Some(e), true, parsed + end);
            break;
        }
        let parse = |b: &&[u8]| parse_block(b, keep.attributes, longest, None);
        let results: Vec<Block> =
            if blocks.len() > 1 { blocks.par_iter().map(parse).collect() } else { blocks.iter().map(parse).collect() };
        let held = base + data.bytes() + vec_bytes(&text);
        meter.hold(path, held + results.iter().map(Block::bytes).sum::<u64>())?;
        for block in results {
            let ahead = found.idle as i64 - found.data as i64;
            found.wrong |= ahead + block.most_ahead > limits.idle_bytes() as i64 || block.problem.is_some();
            found.idle += block.idle;
            found.data += block.data;
            for e in 0..3 {
                found.largest[e] = found.largest[e].max(block.largest[e]);
                found.zero[e] |= block.zero[e];
            }
            found.wrong |= !append(&mut data, block, &mut found.before_first, meter, path)?;
            if found.wrong {
                break;
            }
        }
        parsed += end;
        meter.hold(path, base + data.bytes() + vec_bytes(&text))?;
        if found.wrong || at_end {
            break;
        }
    }
    // Positive indices are checked against the file's counts once it is read to its end;
    // a problem on the way stops the read there, as a reader a line at a time stops.
    let complete = !found.wrong && read_error.is_none();
    let counts = [data.positions.len() as u64, data.texcoord_count, data.normal_count];
    for element in Element::ALL {
        let e = element as usize;
        let checked = element == Element::Vertex || counts[e] > 0;
        let past = complete && found.largest[e] > counts[e];
        found.wrong |= checked && (past || found.zero[e] || found.before_first[e]);
    }
    if found.wrong {
        // The first problem in the file: the text parsed again from its start, in order.
        let whole = Whole { counts, complete, idle_allowance: limits.idle_bytes() };
        let block = parse_block(&text[..parsed], false, longest, Some(&whole));
        return Err(match (block.problem, read_error) {
            (Some((line, problem)), _) => Error::scene(path, problem.message(line, &limits)),
            (None, Some(e)) => e,
            (None, None) => Error::scene(path, "invalid OBJ"),
        });
    }
    if let Some(e) = read_error {
        return Err(e);
    }
    if u32::try_from(data.positions.len()).is_err() || u32::try_from(data.face_indices.len()).is_err() {
        return Err(Error::scene(path, "more than 2^32 vertices or face corners"));
    }
    if data.face_starts.is_empty() {
        data.face_starts.push(0);
    }
    if keep.attributes {
        if data.texcoord_count == 0 {
            data.corner_uvs.iter_mut().for_each(|c| *c = u32::MAX);
        }
        if data.normal_count == 0 {
            data.corner_normals.iter_mut().for_each(|c| *c = u32::MAX);
        }
    }
    if keep.text {
        data.text = text;
    } else {
        meter.release(vec_bytes(&text));
    }
    Ok(data)
}

/// The mesh the scene traces from an OBJ file's vertices and faces: the vertices some face
/// uses, in the file's order (as `tobj` kept them, a vertex no face uses is not placed),
/// and each face split as a fan (v0, v(k-1), vk), as `tobj` split polygons.
pub(crate) fn scene_mesh(path: &Path, positions: &[Vec3], face_starts: &[u32], face_indices: &[u32]) -> IndexedMesh {
    let mut number = vec![u32::MAX; positions.len()];
    for &v in face_indices {
        number[v as usize] = 0;
    }
    let mut used = Vec::with_capacity(number.iter().filter(|&&n| n == 0).count());
    for (k, n) in number.iter_mut().enumerate() {
        if *n == 0 {
            *n = used.len() as u32;
            used.push(positions[k]);
        }
    }
    let faces = face_starts.windows(2);
    let count: usize = faces.clone().map(|w| (w[1] - w[0]) as usize - 2).sum();
    let mut triangles = Vec::with_capacity(count);
    for w in faces {
        let c = &face_indices[w[0] as usize..w[1] as usize];
        triangles.extend((2..c.len()).map(|k| [c[0], c[k - 1], c[k]].map(|v| number[v as usize])));
    }
    IndexedMesh { positions: used, triangles, names: VertexNames::Obj(path.to_path_buf()), ..Default::default() }
}

/// The bytes [`scene_mesh`] holds at most while it makes the mesh of these faces from
/// `vertices` positions.
fn scene_mesh_bytes(vertices: usize, face_starts: &[u32]) -> u64 {
    let corners = u64::from(face_starts.last().copied().unwrap_or(0));
    let faces = face_starts.len().saturating_sub(1) as u64;
    vertices as u64 * (4 + 12) + (corners - 2 * faces) * 12
}

/// Reads an OBJ file (`.obj` or `.obj.gz`) as the scene's mesh within `meter`'s budget.
pub(crate) fn load_obj(path: &Path, meter: &mut Meter) -> Result<IndexedMesh> {
    let held = meter.used();
    let data = read_obj(path, meter, Keep::default())?;
    meter.charge(path, scene_mesh_bytes(data.positions.len(), &data.face_starts))?;
    let mesh = scene_mesh(path, &data.positions, &data.face_starts, &data.face_indices);
    meter.set_used(held + vec_bytes(&mesh.positions) + vec_bytes(&mesh.triangles));
    Ok(mesh)
}

/// The triangles of an OBJ file as the scene loader reads them (each a triple of
/// positions), within `limits`, parsed in blocks of `block_bytes`.
#[cfg(feature = "testing")]
pub fn read_obj_triangles(path: &Path, limits: &ReadLimits, block_bytes: usize) -> Result<Vec<[Vec3; 3]>> {
    let mut meter = Meter::new(limits, "the mesh");
    let data = read_obj_in_blocks(path, &mut meter, Keep::default(), block_bytes)?;
    let mesh = scene_mesh(path, &data.positions, &data.face_starts, &data.face_indices);
    Ok(mesh.triangles.iter().map(|t| t.map(|v| mesh.positions[v as usize])).collect())
}

/// The position of a `v` line as the reader parses it; `None` for other lines and for
/// `v` lines it refuses.
pub(crate) fn parse_vertex_line(line: &str) -> Option<Vec3> {
    let mut words = Words::new(line);
    if words.next() != Some("v") {
        return None;
    }
    let mut xyz = [0.0f32; 3];
    for c in &mut xyz {
        *c = parse_f32(words.next()?)?;
    }
    let [x, y, z] = xyz;
    let rest: Vec<&str> = words.collect();
    let w = match rest.as_slice() {
        [w] => parse_f32(w).unwrap_or(1.0),
        _ => 1.0,
    };
    Some(if w == 1.0 { Vec3::new(x, y, z) } else { Vec3::new(x / w, y / w, z / w) })
}

/// The number (from 1) and line of the first `v` line of `path` whose position is
/// bit-identical to `position`: the name of a vertex in error messages (the scene's mesh
/// keeps only the vertices its faces use). Only a regular file is read again (a pipe
/// would wait for a writer), within the default limits.
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
        let text = String::from_utf8_lossy(&line);
        let text = text.split('#').next().unwrap_or_default();
        if let Some(p) = parse_vertex_line(text) {
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

    /// Writes `files` (name, text) into a new directory and loads the first as OBJ.
    fn load_files(files: &[(&str, &str)]) -> Result<IndexedMesh> {
        let dir = tempfile::tempdir().unwrap();
        for (name, text) in files {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        let mut meter = Meter::new(&ReadLimits::with_memory(1 << 30), "the mesh");
        load_obj(&dir.path().join(files[0].0), &mut meter)
    }

    /// The triangles of `text` as position bits, read in blocks of `block_bytes`, or the error.
    fn triangles(text: &[u8], block_bytes: usize) -> std::result::Result<Vec<[[u32; 3]; 3]>, String> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        std::fs::write(&path, text).unwrap();
        let mut meter = Meter::new(&ReadLimits::with_memory(1 << 30), "the mesh");
        let data = read_obj_in_blocks(&path, &mut meter, Keep::default(), block_bytes).map_err(|e| {
            let e = e.to_string();
            e.split_once("m.obj: ").map_or(e.clone(), |(_, m)| m.to_string())
        })?;
        let mesh = scene_mesh(&path, &data.positions, &data.face_starts, &data.face_indices);
        Ok(mesh.triangles.iter().map(|t| t.map(|v| mesh.positions[v as usize].to_array().map(f32::to_bits))).collect())
    }

    const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    #[test]
    fn vertices_are_parsed_as_str_parse_reads_them() {
        let text = "# c\nv 1 2 3\nvn 0 0 1\n  v 2 4 6 2\nv 1 2 3 0.5 0.5 0.5\nv nan 0 0\nv 0 -inf 1\nv x\n";
        let v: Vec<Vec3> = text.lines().filter_map(parse_vertex_line).collect();
        assert_eq!(v.len(), 5);
        assert_eq!(v[..3], [Vec3::new(1.0, 2.0, 3.0); 3]);
        assert!(v[3].x.is_nan());
        assert_eq!(non_finite_coordinate(v[4]).as_deref(), Some("y = -inf"));
    }

    /// Every word of up to five characters of digits, signs, points and exponents, and the
    /// words of infinity and NaN: `parse_f32` accepts what `str::parse::<f32>` accepts,
    /// and gives the same bits.
    #[test]
    fn numbers_parse_to_the_bits_of_str_parse() {
        let alphabet = b"019.-+eE";
        let mut words: Vec<String> = ["inf", "-inf", "+infinity", "NaN", "nan", "1e39", "-1e-46", "3.4028236e38"]
            .iter()
            .map(|w| w.to_string())
            .collect();
        let mut current = vec![String::new()];
        for _ in 0..5 {
            let mut next = Vec::new();
            for w in &current {
                for &c in alphabet {
                    next.push(format!("{w}{}", c as char));
                }
            }
            words.extend(next.iter().cloned());
            current = next;
        }
        words.extend(["0.1", "16777217", "1.00000005960464477539", "7.038531e-26", "0.000001"].map(String::from));
        for w in &words {
            let want = w.parse::<f32>().ok().map(f32::to_bits);
            let got = parse_f32(w).map(f32::to_bits);
            let nan = |b: Option<u32>| b.is_some_and(|b| f32::from_bits(b).is_nan());
            assert!(got == want || (nan(got) && nan(want)), "{w:?}: {got:?} != {want:?}");
        }
        for w in ["1", "-1", "+7", "0", "-0", "123456789012345678", "1234567890123456789012", "1.5", "", "-", "x"] {
            assert_eq!(parse_index(w), w.parse::<i64>().ok(), "{w:?}");
        }
    }

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
    fn vertex_colours_are_ignored_and_unused_vertices_left_out() {
        let text = "v 0 0 0\nv 1 0 0 0.5 0.5 0.5\r\nv 9 9 9\nv 0 1 0 1 0 0\nf 1 2 4\n";
        let mesh = load_files(&[("m.obj", text)]).unwrap();
        assert_eq!(mesh.positions, [Vec3::ZERO, Vec3::X, Vec3::Y]);
        assert_eq!(mesh.triangles, [[0, 1, 2]]);
    }

    #[test]
    fn the_file_is_read_as_tobj_resolves_it_whatever_its_names_and_line_ends() {
        let plain = load_files(&[("m.obj", &format!("{SQUARE}f 1 2 3 4\n"))]).unwrap();
        // A face may name a vertex below it; texture coordinates and normals a file has
        // none of are not resolved; `vt u` is a coordinate; a comment may follow data.
        for text in [
            "f 1 2 3 4\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n".to_string(),
            format!("{SQUARE}f 1/9/9 2/9/9 3/9/9 4/9/9\n"),
            format!("{SQUARE}vt 0.5\nf 1/1 2/1 3/-1 4/1 # a quad\n"),
            format!("\u{feff}{SQUARE}f 1 2 \\\r\n 3 4\r\n"),
            format!("{SQUARE}f\u{2003}1 2\u{a0}3 4 # \u{e9}\n"),
        ] {
            let mesh = load_files(&[("m.obj", &text)]).unwrap_or_else(|e| panic!("{text:?}: {e}"));
            assert_eq!(
                (mesh.positions, mesh.triangles),
                (plain.positions.clone(), plain.triangles.clone()),
                "{text:?}"
            );
        }
    }

    /// Positive indices number the file's vertices from its first, through every object
    /// and group (the format's numbering): a face may name a vertex a later object
    /// defines; one past the file's last vertex is out of bounds, named at its line.
    #[test]
    fn a_face_may_name_a_vertex_any_later_object_defines() {
        let late = b"v 0 0 0\nv 1 0 0\nf 1 2 3\no next\nv 0 1 0\nf 1 2 3\n";
        let t = triangles(late, 1 << 20).unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t[0], t[1]);
        assert_eq!(t[0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]].map(|p| p.map(f32::to_bits)));
        let past = b"v 0 0 0\nv 1 0 0\nf 1 2 3\nf 1 2 4\no next\nv 0 1 0\n";
        assert_eq!(
            triangles(past, 1 << 20).unwrap_err(),
            "line 4: invalid OBJ: face vertex index out of bounds (4, with 3 vertices)"
        );
    }

    #[test]
    fn errors_name_the_first_line_in_error() {
        for (text, want) in [
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
            (
                format!("{SQUARE}f 1 2 0\n"),
                "line 5: invalid OBJ: face vertex index out of bounds (0: OBJ counts from 1)",
            ),
            (format!("# c\n\n{SQUARE}vn 0 1\n"), "line 7: invalid OBJ: a normal needs 3 numbers, found 2"),
            (format!("{SQUARE}v 1 2 3 0\n"), "line 5: invalid OBJ: a vertex with w = 0 (at infinity)"),
            (
                "v 1 \\\n2 3\nv x 0 0\n".to_string(),
                "line 3: invalid OBJ: 'x' is not a number (a vertex position coordinate)",
            ),
            (format!("{SQUARE}v 0 nan 0\nf 1 2 x\n"), "vertex 5 (line 5) has a non-finite coordinate (y = NaN)"),
            (format!("{SQUARE}f 1 2 x\nv 0 nan 0\n"), "line 5: invalid OBJ: the face corner 'x' has 'x', not an index"),
            (format!("{SQUARE}f 1 2 9\nf 1 2 3 x\n"), "line 6: invalid OBJ: the face corner 'x' has 'x', not an index"),
            (
                format!("{SQUARE}f 1 2 9\nf 1 2 3\n"),
                "line 5: invalid OBJ: face vertex index out of bounds (9, with 4 vertices)",
            ),
            (format!("{SQUARE}v 0 0\u{0}0\n"), "line 5: invalid OBJ: a NUL byte"),
            (
                format!("{SQUARE}f 1/1/1/1 2 3\n"),
                "line 5: invalid OBJ: the face corner '1/1/1/1' has more than v/vt/vn",
            ),
            (format!("{SQUARE}f /1 2 3\n"), "line 5: invalid OBJ: the face corner '/1' names no vertex"),
            (
                format!("{SQUARE}v 0 0 0 1 1\n"),
                "line 5: invalid OBJ: a vertex has x y z, then a w or a color (r g b) or nothing; found 5 numbers",
            ),
            (format!("{SQUARE}vt\n"), "line 5: invalid OBJ: a texture coordinate needs 1 to 3 numbers, found none"),
        ] {
            // In one block, and in blocks of a few lines: the same first error.
            for block_bytes in [1 << 20, 16, 1] {
                let e = triangles(text.as_bytes(), block_bytes).unwrap_err();
                assert_eq!(e, want, "{text:?} in blocks of {block_bytes}");
            }
        }
    }

    /// A file of many blocks: relative indices and faces that reach back across blocks,
    /// continued lines, comments and every corner form read as in one block.
    #[test]
    fn blocks_of_any_size_read_the_same_mesh() {
        let mut text = String::from("# grid\nmtllib g.mtl\n");
        let n = 40;
        for i in 0..n {
            for j in 0..n {
                text += &format!("v {} {} {}\n", i as f32 * 0.1, j as f32 * 0.3, ((i * j) % 7) as f32 / 3.0);
            }
            if i > 0 {
                text += &format!("o row{i}\nvt 0.{i} 0.5\nvn 0 0 1\n");
                for j in 1..n {
                    let (a, b) = ((i - 1) * n + j, i * n + j);
                    match j % 4 {
                        0 => text += &format!("f {a} {} {} {b}\n", a + 1, b + 1),
                        1 => text += &format!("f -{} -{} -{} # relative\n", n * 2 - j + 1, n * 2 - j, n - j + 1),
                        2 => text += &format!("f {a}/1/1 {}/-1/-1 \\\n {}/1/1\n", a + 1, b + 1),
                        _ => text += &format!("f {a}//1 {b}//-1 {}//1 {}//1 {a}//1\r\n", b + 1, a + 1),
                    }
                }
            }
        }
        let one = triangles(text.as_bytes(), 1 << 20).unwrap();
        assert!(one.len() > 3 * n * n / 2, "{} triangles", one.len());
        for block_bytes in [7, 64, 1000, 4096] {
            assert!(triangles(text.as_bytes(), block_bytes).unwrap() == one, "blocks of {block_bytes}");
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
