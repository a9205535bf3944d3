//! Stanford PLY through `ply-rs-bw`: ascii, binary_little_endian and binary_big_endian,
//! plain or gzipped. The `vertex` element's `x`, `y`, `z` (any scalar type) and the `face`
//! element's `vertex_indices` (or `vertex_index`) list (any integer types) are kept;
//! polygons become triangle fans; every other element and property is read and ignored.
//! A header line that starts with none of the header's keywords (free text some writers
//! put in without `comment`) is skipped with a warning.
//!
//! The header is read here ([`read_header`], shared with the bake), the vertices and faces
//! in bulk where their layout allows ([`super::ply_data`]; ASCII ones a block of lines at
//! a time, parsed on rayon's threads), other elements one at a time by the crate; this module owns the storage, so the counts in the header never
//! size an allocation beyond what the rest of the file could hold (see
//! [`Input::remaining_bound`]).

use super::input::{Input, Meter, UTF8_BOM, advise_huge_pages, make_room, one_line};
use super::mesh::{IndexedMesh, VertexNames};
use super::ply_data::{Keep, LIST_ITEM_BYTES, Layout, ascii_axes, ascii_indices, read_binary};
pub(crate) use super::types::non_finite_coordinate;
use crate::error::{Error, Result};
use glam::Vec3;
use ply_rs_bw::parser::{ParseError, Parser};
use ply_rs_bw::ply::{
    ElementDef, Encoding, Property, PropertyAccess, PropertyAccessResult, PropertyDef, PropertyType, ScalarType,
    Version,
};
use std::io::{BufRead, ErrorKind};
use std::path::Path;

/// A header longer than this is refused rather than read into memory.
const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Names of the face element's index list, in order of preference.
const INDEX_LISTS: [&str; 2] = ["vertex_indices", "vertex_index"];

/// The coordinates of one `vertex` element.
#[derive(Default)]
struct PlyVertex {
    p: [f32; 3],
}

/// A scalar property as `f32`: the nearest value (a `double` beyond the `f32` range
/// becomes infinite, and is then refused as non-finite).
fn scalar_as_f32(property: &Property) -> Option<f32> {
    Some(match *property {
        Property::Char(v) => v.into(),
        Property::UChar(v) => v.into(),
        Property::Short(v) => v.into(),
        Property::UShort(v) => v.into(),
        Property::Int(v) => v as f32,
        Property::UInt(v) => v as f32,
        Property::Float(v) => v,
        Property::Double(v) => v as f32,
        _ => return None,
    })
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return PropertyAccessResult::Ignored,
        };
        match scalar_as_f32(&property) {
            Some(v) => {
                self.p[axis] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

/// The vertex indices of one `face` element; negative ones stay negative to be reported.
#[derive(Default)]
struct PlyFace {
    indices: Vec<i64>,
}

impl PropertyAccess for PlyFace {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if !INDEX_LISTS.contains(&name) {
            return PropertyAccessResult::Ignored;
        }
        self.indices = match property {
            Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// An element read only to be skipped.
struct Skipped;

impl PropertyAccess for Skipped {
    fn new() -> Self {
        Skipped
    }
}

fn scalar_bytes(t: &ScalarType) -> u64 {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

fn is_integer(t: &ScalarType) -> bool {
    !matches!(t, ScalarType::Float | ScalarType::Double)
}

/// The fewest bytes one element of `def` can take in the file. The index list of a face
/// counts with three entries: a shorter face is an error. In ascii every value takes at
/// least a digit and a separator.
fn min_element_bytes(def: &ElementDef, encoding: Encoding, index_list: Option<&str>) -> u64 {
    let binary = encoding != Encoding::Ascii;
    let mut bytes = 0;
    for (name, p) in &def.properties {
        let entries = if index_list == Some(name.as_str()) { 3 } else { 0 };
        bytes += match &p.data_type {
            PropertyType::Scalar(t) if binary => scalar_bytes(t),
            PropertyType::List(count, item) if binary => scalar_bytes(count) + entries * scalar_bytes(item),
            PropertyType::Scalar(_) => 2,
            PropertyType::List(..) => 2 + entries * 2,
        };
    }
    bytes.max(1)
}

/// How many elements of `def` to reserve room for: the header's count, but no more than
/// the rest of the input is known to hold (nothing for a pipe or a device, whose data
/// must arrive first) and the budget leaves for elements of `size` bytes.
fn capacity(
    def: &ElementDef,
    input: &Input,
    encoding: Encoding,
    index_list: Option<&str>,
    meter: &Meter,
    size: u64,
) -> usize {
    let fit = (input.known_remaining() / min_element_bytes(def, encoding, index_list)).min(meter.left() / size);
    def.count.min(usize::try_from(fit).unwrap_or(usize::MAX))
}

fn out_of_memory(path: &Path, n: usize, what: &str) -> Error {
    Error::scene(path, format!("not enough memory for {n} {what}"))
}

/// Reserves room for `n` more elements in `v`, charged to `meter` first.
fn reserve<T>(path: &Path, v: &mut Vec<T>, n: usize, meter: &mut Meter, what: &str) -> Result<()> {
    meter.charge(path, (n * std::mem::size_of::<T>()) as u64)?;
    v.try_reserve_exact(n).map_err(|_| out_of_memory(path, n, what))?;
    advise_huge_pages(v);
    Ok(())
}

/// Reads the `def.count` elements of `def`, passing each with its number to `each`. An
/// element's lists may take at most what is left of `meter`'s budget: a binary element is
/// cut off there (an ASCII one is a line, at most the longest line). An ASCII line is read
/// by `fast` where it can (`None`: by the crate, which also says what is wrong with it).
fn read_elements<E: PropertyAccess>(
    path: &Path,
    input: &mut Input,
    encoding: Encoding,
    def: &ElementDef,
    meter: &mut Meter,
    mut fast: impl FnMut(&[u8]) -> Option<E>,
    mut each: impl FnMut(usize, E, &mut Meter) -> Result<()>,
) -> Result<()> {
    if encoding != Encoding::Ascii && def.properties.is_empty() {
        // Elements without properties take no bytes: nothing to read.
        return Ok(());
    }
    let parser = Parser::<E>::new();
    let has_list = def.properties.values().any(|p| matches!(p.data_type, PropertyType::List(..)));
    let mut line = Vec::new();
    for i in 0..def.count {
        let cut = has_list && encoding != Encoding::Ascii;
        if cut {
            input.set_limit(Some(input.consumed().saturating_add(meter.left() / LIST_ITEM_BYTES + 16)));
        }
        let element = match encoding {
            Encoding::Ascii => {
                line.clear();
                match input.read_line(&mut line) {
                    Ok(0) => Err(ParseError::from(std::io::Error::from(ErrorKind::UnexpectedEof))),
                    Ok(_) => match fast(&line) {
                        Some(element) => Ok(element),
                        None => read_ascii_line(&parser, &line, def),
                    },
                    Err(e) => Err(ParseError::from(e)),
                }
            }
            Encoding::BinaryLittleEndian => parser.read_little_endian_element(input, def),
            Encoding::BinaryBigEndian => parser.read_big_endian_element(input, def),
        };
        let cut_off = cut && input.at_limit();
        if cut {
            input.set_limit(None);
        }
        let element = element.map_err(|e| element_error(path, input.stream_error(), def, i, cut_off, meter, &e))?;
        each(i, element, meter)?;
    }
    Ok(())
}

/// An ASCII line of `def` read by the general reader.
fn read_ascii_line<E: PropertyAccess>(
    parser: &Parser<E>,
    line: &[u8],
    def: &ElementDef,
) -> std::result::Result<E, ParseError> {
    match std::str::from_utf8(line) {
        Ok(text) => parser.read_ascii_element(text, def),
        Err(_) => {
            Err(ParseError::from(std::io::Error::new(ErrorKind::InvalidData, "stream did not contain valid UTF-8")))
        }
    }
}

/// The error of element `i` of `def` whose read failed with `e`: the stream's own error
/// when it had one, the budget when its lists were `cut_off` by it.
fn element_error(
    path: &Path,
    stream: Option<&str>,
    def: &ElementDef,
    i: usize,
    cut_off: bool,
    meter: &Meter,
    e: &ParseError,
) -> Error {
    let what = format!("{} {i} of {}", def.name, def.count);
    let message = if let Some(stream) = stream {
        format!("{what}: {stream}")
    } else if cut_off && e.kind() == ErrorKind::UnexpectedEof {
        format!("{what}: its lists: {}", meter.exceeded_message())
    } else if e.kind() == ErrorKind::UnexpectedEof {
        format!("unexpected end of file in {what}")
    } else {
        format!("{what}: {}", one_line(&e.to_string()))
    };
    Error::scene(path, message)
}

/// Bytes and lines of ASCII lines each of rayon's threads parses per block at most: blocks
/// of lines are read in turn, parsed in parallel and taken in order, so that memory stays
/// bounded (a block and what it parses to, however short its lines) whatever the file's
/// counts.
const ASCII_BLOCK_BYTES: usize = 1 << 20;
const ASCII_BLOCK_LINES: usize = 1 << 16;

/// An ASCII element as [`read_ascii_blocks`] gives it.
enum Parsed<T, E> {
    /// Parsed by the fast path.
    Fast(T),
    /// Read by the general reader (a line the fast path does not take as it stands).
    General(E),
}

/// Reads the `def.count` ASCII lines of `def` a block at a time, each block's lines
/// parsed by `fast` on rayon's threads, then passed with their numbers to `each` in
/// order; a line `fast` does not take is read by the general reader, which also says
/// what is wrong with it. Gives what [`read_elements`] gives, error for error: a read that
/// fails (the end of the file, a line too long, the stream's error) is reported after the
/// lines before it are taken.
fn read_ascii_blocks<T: Send, E: PropertyAccess>(
    path: &Path,
    input: &mut Input,
    def: &ElementDef,
    meter: &mut Meter,
    fast: impl Fn(&[u8], &mut Vec<i64>) -> Option<T> + Sync,
    mut each: impl FnMut(usize, Parsed<T, E>, &mut Meter) -> Result<()>,
) -> Result<()> {
    use rayon::prelude::*;
    let parser = Parser::<E>::new();
    let threads = rayon::current_num_threads().max(1);
    let (target, most) = (ASCII_BLOCK_BYTES.saturating_mul(threads), ASCII_BLOCK_LINES.saturating_mul(threads));
    let (mut block, mut ends) = (Vec::new(), vec![0usize]);
    let mut i = 0;
    while i < def.count {
        block.clear();
        ends.truncate(1);
        // The stream's error as it stood before the block's reads, for its lines' messages.
        let earlier = input.stream_error().map(str::to_string);
        let mut failure = None;
        while i + ends.len() - 1 < def.count && block.len() < target && ends.len() - 1 < most {
            // The whole lines in the input's buffer at once; a line that spans buffers, one
            // too long and the end of the data by `read_line`, which words their errors.
            let want = (def.count - i).min(most) - (ends.len() - 1);
            let longest = input.limits().line_bytes();
            let (taken, lines) = match input.fill_buf() {
                Ok(buf) => {
                    let (mut taken, mut lines) = (0, 0);
                    for end in memchr::memchr_iter(b'\n', buf) {
                        if lines == want || end + 1 - taken > longest {
                            break;
                        }
                        block.extend_from_slice(&buf[taken..=end]);
                        ends.push(block.len());
                        (taken, lines) = (end + 1, lines + 1);
                    }
                    (taken, lines)
                }
                Err(_) => (0, 0),
            };
            if lines > 0 {
                input.consume(taken);
                input.count_lines(lines as u64);
                continue;
            }
            match input.read_line(&mut block) {
                Ok(0) => {
                    failure = Some(ParseError::from(std::io::Error::from(ErrorKind::UnexpectedEof)));
                    break;
                }
                Ok(_) => ends.push(block.len()),
                Err(e) => {
                    failure = Some(ParseError::from(e));
                    break;
                }
            }
        }
        let line = |k: usize| &block[ends[k]..ends[k + 1]];
        let parsed: Vec<Option<T>> = (0..ends.len() - 1)
            .into_par_iter()
            .with_min_len(1024)
            .map_init(Vec::new, |scratch, k| fast(line(k), scratch))
            .collect();
        for (k, element) in parsed.into_iter().enumerate() {
            let element = match element {
                Some(t) => Parsed::Fast(t),
                None => match read_ascii_line(&parser, line(k), def) {
                    Ok(e) => Parsed::General(e),
                    Err(e) => return Err(element_error(path, earlier.as_deref(), def, i, false, meter, &e)),
                },
            };
            each(i, element, meter)?;
            i += 1;
        }
        if let Some(e) = failure {
            return Err(element_error(path, input.stream_error(), def, i, false, meter, &e));
        }
    }
    Ok(())
}

/// Skips the elements of `def` without parsing them when they are binary scalars (a fixed
/// number of bytes each), a buffer at a time; `false` (nothing read) for other elements.
fn skip_elements(path: &Path, input: &mut Input, encoding: Encoding, def: &ElementDef) -> Result<bool> {
    let mut size = 0;
    for p in def.properties.values() {
        match &p.data_type {
            PropertyType::Scalar(t) if encoding != Encoding::Ascii => size += scalar_bytes(t),
            _ => return Ok(false),
        }
    }
    let total = (def.count as u64).saturating_mul(size);
    let mut skipped = 0;
    while skipped < total {
        let available = match input.fill_buf() {
            Ok(buf) => buf.len() as u64,
            Err(e) => {
                let what = format!("{} {} of {}", def.name, skipped / size.max(1), def.count);
                let stream = input.stream_error().map_or_else(|| e.to_string(), str::to_string);
                return Err(Error::scene(path, format!("{what}: {stream}")));
            }
        };
        if available == 0 {
            let what = format!("{} {} of {}", def.name, skipped / size.max(1), def.count);
            return Err(Error::scene(path, format!("unexpected end of file in {what}")));
        }
        let n = available.min(total - skipped);
        input.consume(n as usize);
        skipped += n;
    }
    Ok(true)
}

/// One line of a PLY header, in the file's order (for writing the header back).
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum HeaderLine {
    /// The `format` line.
    Format,
    /// A `comment` or `obj_info` line, as it stands (without its line break).
    Text(Vec<u8>),
    /// The `element` line of element `e` of [`PlyHeader::elements`].
    Element(usize),
    /// A `property` line: property `p` of element `e`.
    Property(usize, usize),
    /// A line that is none of the header's keywords (a free-text line some writers, such
    /// as Blender 2.47, put in without `comment`), skipped; its number from 1 and its text.
    Unknown(usize, Vec<u8>),
}

/// A PLY header as [`read_header`] reads it: the elements in order, and every line.
#[derive(Clone, Debug)]
pub(crate) struct PlyHeader {
    /// The data's encoding.
    pub encoding: Encoding,
    /// The `format` line's version.
    pub version: Version,
    /// The elements in the file's order, each with its properties in order; names are
    /// unique among the elements, and among the properties of each.
    pub elements: Vec<ElementDef>,
    /// Every line between `ply` and `end_header`.
    pub lines: Vec<HeaderLine>,
    /// The lines skipped, one message each.
    pub warnings: Vec<String>,
}

impl PlyHeader {
    /// The element named `name`.
    pub(crate) fn element(&self, name: &str) -> Option<&ElementDef> {
        self.elements.iter().find(|e| e.name == name)
    }
}

/// `text` without its line break and trailing blanks.
fn trim_line(text: &[u8]) -> &[u8] {
    let end = text.iter().rposition(|b| !matches!(b, b'\n' | b'\r' | b' ' | b'\t')).map_or(0, |i| i + 1);
    &text[..end]
}

/// A header name (of an element or a property): `[A-Za-z_][A-Za-z0-9_-]*`, as ply-rs's
/// grammar has it.
fn is_name(word: &str) -> bool {
    let mut chars = word.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

/// A scalar type by any of its PLY names.
pub(crate) fn scalar_type(word: &str) -> Option<ScalarType> {
    Some(match word {
        "char" | "int8" => ScalarType::Char,
        "uchar" | "uint8" => ScalarType::UChar,
        "short" | "int16" => ScalarType::Short,
        "ushort" | "uint16" => ScalarType::UShort,
        "int" | "int32" => ScalarType::Int,
        "uint" | "uint32" => ScalarType::UInt,
        "float" | "float32" => ScalarType::Float,
        "double" | "float64" => ScalarType::Double,
        _ => return None,
    })
}

/// What is wrong with a PLY header.
#[derive(Debug, thiserror::Error)]
enum HeaderError {
    /// The file could not be read.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The first line is not `ply`.
    #[error("not a PLY file: the first line is not 'ply'")]
    NotPly,
    /// No `end_header` line.
    #[error("invalid PLY header: the file ends before 'end_header'")]
    Unterminated,
    /// A line that is wrong, with its number and text.
    #[error("invalid PLY header: line {number} '{text}': {why}")]
    Line {
        /// The line's number, from 1.
        number: usize,
        /// The line, on one line.
        text: String,
        /// What is wrong with it.
        why: HeaderLineError,
    },
    /// A header without a `format` line.
    #[error("invalid PLY header: no format line")]
    NoFormat,
}

/// What is wrong with one line of a PLY header.
#[derive(Debug, thiserror::Error)]
enum HeaderLineError {
    #[error("'ply' may only be the first line")]
    SecondPly,
    /// A keyword line with the wrong number of words: its form.
    #[error("expected '{0}'")]
    Form(&'static str),
    #[error("unknown encoding '{0}'")]
    Encoding(String),
    #[error("invalid version '{0}'")]
    Version(String),
    #[error("invalid element name '{0}'")]
    ElementName(String),
    #[error("invalid element count '{0}'")]
    ElementCount(String),
    #[error("unknown type '{0}'")]
    Type(String),
    #[error("invalid property name '{0}'")]
    PropertyName(String),
    #[error("a second, different format line")]
    SecondFormat,
    #[error("a second element named '{0}'")]
    SecondElement(String),
    #[error("a property before any element")]
    PropertyBeforeElement,
    #[error("a second property named '{property}' in element '{element}'")]
    SecondProperty { property: String, element: String },
}

/// One header line's meaning, or what is wrong with it.
fn parse_header_line(words: &[&str]) -> std::result::Result<ParsedLine, HeaderLineError> {
    let arity = |n: usize, form: &'static str| {
        if words.len() == n { Ok(()) } else { Err(HeaderLineError::Form(form)) }
    };
    match words[0] {
        "ply" => Err(HeaderLineError::SecondPly),
        "end_header" => arity(1, "end_header").map(|()| ParsedLine::End),
        "comment" | "obj_info" => Ok(ParsedLine::Text),
        "format" => {
            arity(3, "format ENCODING VERSION")?;
            let encoding = match words[1] {
                "ascii" => Encoding::Ascii,
                "binary_little_endian" => Encoding::BinaryLittleEndian,
                "binary_big_endian" => Encoding::BinaryBigEndian,
                other => return Err(HeaderLineError::Encoding(other.to_string())),
            };
            let version = words[2]
                .split_once('.')
                .filter(|(a, b)| [a, b].iter().all(|s| !s.is_empty() && s.bytes().all(|c| c.is_ascii_digit())))
                .and_then(|(a, b)| Some(Version { major: a.parse().ok()?, minor: b.parse().ok()? }))
                .ok_or_else(|| HeaderLineError::Version(words[2].to_string()))?;
            Ok(ParsedLine::Format(encoding, version))
        }
        "element" => {
            arity(3, "element NAME COUNT")?;
            if !is_name(words[1]) {
                return Err(HeaderLineError::ElementName(words[1].to_string()));
            }
            let count = Some(words[2])
                .filter(|w| w.bytes().all(|c| c.is_ascii_digit()))
                .and_then(|w| w.parse::<usize>().ok())
                .ok_or_else(|| HeaderLineError::ElementCount(words[2].to_string()))?;
            let mut def = ElementDef::new(words[1].to_string());
            def.count = count;
            Ok(ParsedLine::Element(def))
        }
        "property" => {
            let ty = |w: &str| scalar_type(w).ok_or_else(|| HeaderLineError::Type(w.to_string()));
            let data_type = if words.get(1) == Some(&"list") {
                arity(5, "property list COUNT_TYPE ITEM_TYPE NAME")?;
                PropertyType::List(ty(words[2])?, ty(words[3])?)
            } else {
                arity(3, "property TYPE NAME")?;
                PropertyType::Scalar(ty(words[1])?)
            };
            let name = words[words.len() - 1];
            if !is_name(name) {
                return Err(HeaderLineError::PropertyName(name.to_string()));
            }
            Ok(ParsedLine::Property(PropertyDef::new(name.to_string(), data_type)))
        }
        _ => Ok(ParsedLine::Unknown),
    }
}

/// What a header line says.
enum ParsedLine {
    Format(Encoding, Version),
    Text,
    Element(ElementDef),
    Property(PropertyDef),
    End,
    Unknown,
}

/// Reads a PLY header up to and including `end_header`, leaving `input` at the first
/// byte of the data. A line that starts with none of the header's keywords is skipped
/// with a warning; a malformed keyword line is an error.
pub(crate) fn read_header(path: &Path, input: &mut Input) -> Result<PlyHeader> {
    input.set_limit(Some(MAX_HEADER_BYTES));
    let header = read_header_lines(input);
    input.set_limit(None);
    header.map_err(|e| {
        let message = if let Some(stream) = input.stream_error() {
            stream.to_string()
        } else if input.at_limit() {
            format!("the PLY header is longer than {MAX_HEADER_BYTES} bytes")
        } else {
            e.to_string()
        };
        Error::scene(path, message)
    })
}

fn read_header_lines(input: &mut Input) -> std::result::Result<PlyHeader, HeaderError> {
    let mut raw = Vec::new();
    if input.read_until(b'\n', &mut raw)? == 0 || trim_line(raw.strip_prefix(UTF8_BOM).unwrap_or(&raw)) != b"ply" {
        return Err(HeaderError::NotPly);
    }
    let mut format = None;
    let mut elements: Vec<ElementDef> = Vec::new();
    let mut lines = Vec::new();
    let mut warnings = Vec::new();
    for number in 2usize.. {
        raw.clear();
        if input.read_until(b'\n', &mut raw)? == 0 {
            return Err(HeaderError::Unterminated);
        }
        let line = trim_line(&raw);
        let line = &line[line.iter().position(|b| !matches!(b, b' ' | b'\t')).unwrap_or(line.len())..];
        let text = String::from_utf8_lossy(line);
        let words: Vec<&str> = text.split([' ', '\t']).filter(|w| !w.is_empty()).collect();
        let invalid = |why: HeaderLineError| HeaderError::Line { number, text: one_line(&text), why };
        if words.is_empty() {
            warnings.push(format!("skipped the empty line {number} of the PLY header"));
            continue;
        }
        match parse_header_line(&words).map_err(invalid)? {
            ParsedLine::End => break,
            ParsedLine::Text => lines.push(HeaderLine::Text(line.to_vec())),
            ParsedLine::Unknown => {
                warnings.push(format!(
                    "skipped line {number} of the PLY header, which is no PLY keyword line: '{}'",
                    one_line(&text)
                ));
                lines.push(HeaderLine::Unknown(number, line.to_vec()));
            }
            ParsedLine::Format(encoding, version) => {
                if format.is_some_and(|f| f != (encoding, version)) {
                    return Err(invalid(HeaderLineError::SecondFormat));
                }
                format = Some((encoding, version));
                lines.push(HeaderLine::Format);
            }
            ParsedLine::Element(def) => {
                if elements.iter().any(|e| e.name == def.name) {
                    return Err(invalid(HeaderLineError::SecondElement(def.name)));
                }
                lines.push(HeaderLine::Element(elements.len()));
                elements.push(def);
            }
            ParsedLine::Property(def) => {
                let e = elements.len().wrapping_sub(1);
                let Some(element) = elements.last_mut() else {
                    return Err(invalid(HeaderLineError::PropertyBeforeElement));
                };
                if element.properties.contains_key(&def.name) {
                    return Err(invalid(HeaderLineError::SecondProperty {
                        property: def.name,
                        element: element.name.clone(),
                    }));
                }
                lines.push(HeaderLine::Property(e, element.properties.len()));
                element.properties.insert(def.name.clone(), def);
            }
        }
    }
    let (encoding, version) = format.ok_or(HeaderError::NoFormat)?;
    Ok(PlyHeader { encoding, version, elements, lines, warnings })
}

/// The name of the face element's index list, checked to be a list of integers.
pub(crate) fn index_list_name(path: &Path, face: &ElementDef) -> Result<String> {
    let Some((name, def)) = INDEX_LISTS.iter().find_map(|n| face.properties.get_key_value(*n)) else {
        return Err(Error::scene(path, "the face element has no vertex_indices list"));
    };
    match &def.data_type {
        PropertyType::List(count, item) if is_integer(count) && is_integer(item) => Ok(name.clone()),
        t => Err(Error::scene(path, format!("face property {name} must be a list of integers, not {t:?}"))),
    }
}

/// Reads a PLY file (`.ply` or `.ply.gz`) within `meter`'s budget. Vertices and faces are
/// numbered from 0, as the faces' indices count them.
pub(crate) fn load_ply(path: &Path, meter: &mut Meter) -> Result<IndexedMesh> {
    read_ply(path, meter, true)
}

/// The vertices and triangles of a PLY file within `limits`: through the bulk readers
/// (`bulk`), or with the element-at-a-time reader alone, the reference they are compared
/// with.
#[cfg(feature = "testing")]
pub fn read_ply_mesh(path: &Path, limits: &super::input::ReadLimits, bulk: bool) -> Result<(Vec<Vec3>, Vec<[u32; 3]>)> {
    let mesh = read_ply(path, &mut Meter::new(limits, "the mesh"), bulk)?;
    Ok((mesh.positions, mesh.triangles))
}

/// [`load_ply`], through the bulk readers where `fast` is set.
fn read_ply(path: &Path, meter: &mut Meter, fast: bool) -> Result<IndexedMesh> {
    let mut input = Input::open(path, meter.limits())?;
    let header = read_header(path, &mut input)?;
    let encoding = header.encoding;

    let vertex_def = header.element("vertex").ok_or_else(|| Error::scene(path, "no vertex element"))?;
    for axis in ["x", "y", "z"] {
        match vertex_def.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            Some(t) => return Err(Error::scene(path, format!("vertex property {axis} must be a number, not {t:?}"))),
            None => return Err(Error::scene(path, format!("the vertex element has no {axis} property"))),
        }
    }
    let vertex_count = vertex_def.count;
    let face_def = header.element("face").ok_or_else(|| Error::scene(path, "no face element"))?;
    let index_list = index_list_name(path, face_def)?;
    // Every vertex and every face (a triangle at least) is held: a header that declares
    // more than the budget holds, in data the input could deliver, is refused before its
    // data is read (a file too short for its counts is reported where it ends).
    let declared = (vertex_count as u64).saturating_add(face_def.count as u64).saturating_mul(12);
    let data = (vertex_count as u64).saturating_mul(min_element_bytes(vertex_def, encoding, None)).saturating_add(
        (face_def.count as u64).saturating_mul(min_element_bytes(face_def, encoding, Some(&index_list))),
    );
    if declared > meter.left() && input.could_hold(data) {
        let (v, f) = (vertex_count, face_def.count);
        let plural = |n: usize| if n == 1 { "" } else { "s" };
        let message = format!(
            "the header declares {v} vert{} and {f} face{}: {}",
            if v == 1 { "ex" } else { "ices" },
            plural(f),
            meter.exceeded_message()
        );
        return Err(Error::scene(path, message));
    }

    let mut mesh =
        IndexedMesh { names: VertexNames::FromZero, warnings: header.warnings.clone(), ..Default::default() };
    for def in &header.elements {
        match def.name.as_str() {
            "vertex" => {
                let n = capacity(def, &input, encoding, None, meter, 12);
                reserve(path, &mut mesh.positions, n, meter, "vertices")?;
                let positions = &mut mesh.positions;
                match Layout::new(def, encoding, Keep::Axes).filter(|_| fast) {
                    Some(layout) if encoding == Encoding::Ascii => read_ascii_blocks(
                        path,
                        &mut input,
                        def,
                        meter,
                        |line, _| ascii_axes(&layout, line),
                        |i, v: Parsed<[f32; 3], PlyVertex>, meter| {
                            let p = match v {
                                Parsed::Fast(p) => p,
                                Parsed::General(v) => v.p,
                            };
                            push_vertex(path, positions, i, p, meter)
                        },
                    )?,
                    Some(layout) => read_binary(
                        path,
                        &mut input,
                        def,
                        &layout,
                        meter,
                        positions,
                        |positions, i, bytes, most, meter| {
                            let mut k = i;
                            layout.axes_run(bytes, most, |p| {
                                push_vertex(path, positions, k, p, meter)?;
                                k += 1;
                                Ok(())
                            })
                        },
                        |positions, i, element, meter| push_vertex(path, positions, i, layout.axes_of(element), meter),
                    )?,
                    None => read_elements(
                        path,
                        &mut input,
                        encoding,
                        def,
                        meter,
                        |_| None,
                        |i, v: PlyVertex, meter| push_vertex(path, positions, i, v.p, meter),
                    )?,
                }
            }
            "face" => {
                let n = capacity(def, &input, encoding, Some(&index_list), meter, 12);
                reserve(path, &mut mesh.triangles, n, meter, "triangles")?;
                let triangles = &mut mesh.triangles;
                let keep = Keep::IndexList(&index_list, &INDEX_LISTS);
                let push = |triangles: &mut Vec<[u32; 3]>, i, f: PlyFace, meter: &mut Meter| {
                    push_face(path, triangles, vertex_count, i, f.indices.len(), |k| f.indices[k], meter)
                };
                match Layout::new(def, encoding, keep).filter(|_| fast) {
                    Some(layout) if encoding == Encoding::Ascii => read_ascii_blocks(
                        path,
                        &mut input,
                        def,
                        meter,
                        |line, scratch| {
                            // Triangles and quads inline; a longer polygon by the general reader.
                            scratch.clear();
                            let plain = ascii_indices(&layout, line, scratch) && scratch.len() <= 4;
                            plain.then(|| {
                                let mut corners = [0i64; 4];
                                corners[..scratch.len()].copy_from_slice(scratch);
                                (corners, scratch.len())
                            })
                        },
                        |i, f: Parsed<([i64; 4], usize), PlyFace>, meter| match f {
                            Parsed::Fast((corners, n)) => {
                                push_face(path, triangles, vertex_count, i, n, |k| corners[k], meter)
                            }
                            Parsed::General(f) => push(triangles, i, f, meter),
                        },
                    )?,
                    Some(layout) => read_binary(
                        path,
                        &mut input,
                        def,
                        &layout,
                        meter,
                        triangles,
                        |triangles, _, bytes, most, meter| {
                            layout.triangle_run(bytes, most, vertex_count, |t| {
                                make_room(triangles, meter, path)?;
                                triangles.push(t);
                                Ok(())
                            })
                        },
                        |triangles, i, element, meter| {
                            let count = layout.index_count(element);
                            push_face(path, triangles, vertex_count, i, count, |k| layout.index(element, k), meter)
                        },
                    )?,
                    None => read_elements(
                        path,
                        &mut input,
                        encoding,
                        def,
                        meter,
                        |_| None,
                        |i, f, meter| push(triangles, i, f, meter),
                    )?,
                }
            }
            _ if skip_elements(path, &mut input, encoding, def)? => {}
            _ => match Layout::new(def, encoding, Keep::Nothing).filter(|_| fast && encoding != Encoding::Ascii) {
                Some(layout) => read_binary(
                    path,
                    &mut input,
                    def,
                    &layout,
                    meter,
                    &mut (),
                    |_, _, _, _, _| Ok((0, 0)),
                    |_, _, _, _| Ok(()),
                )?,
                None => read_elements(path, &mut input, encoding, def, meter, |_| None, |_, _: Skipped, _| Ok(()))?,
            },
        }
    }
    check_end(path, &mut input, encoding)?;
    Ok(mesh)
}

/// Appends vertex `i` at `p`, refused when a coordinate is not finite.
#[inline(always)]
fn push_vertex(path: &Path, positions: &mut Vec<Vec3>, i: usize, p: [f32; 3], meter: &mut Meter) -> Result<()> {
    let p = Vec3::from(p);
    if !p.is_finite() {
        return Err(non_finite_vertex(path, i, p));
    }
    make_room(positions, meter, path)?;
    positions.push(p);
    Ok(())
}

#[cold]
fn non_finite_vertex(path: &Path, i: usize, p: Vec3) -> Error {
    let c = non_finite_coordinate(p).unwrap_or_default();
    Error::scene(path, format!("vertex {i} has a non-finite coordinate ({c})"))
}

/// Appends face `i`, its `n` vertex indices given by `index`, as a triangle fan; refused
/// when it has fewer than 3 vertices or an index out of range.
#[inline]
fn push_face(
    path: &Path,
    triangles: &mut Vec<[u32; 3]>,
    vertex_count: usize,
    i: usize,
    n: usize,
    index: impl Fn(usize) -> i64,
    meter: &mut Meter,
) -> Result<()> {
    if n < 3 {
        return Err(Error::scene(path, format!("face {i} has {n} vertices; a face needs at least 3")));
    }
    let mut corners = [0u32; 3];
    for slot in 0..n {
        let v = index(slot);
        let valid = usize::try_from(v).ok().filter(|&v| v < vertex_count);
        let Some(v) = valid.and_then(|v| u32::try_from(v).ok()) else {
            return Err(Error::scene(
                path,
                format!("face {i}: vertex index {v} is out of range (the file has {vertex_count} vertices)"),
            ));
        };
        // A fan: (v0, v1, v2), (v0, v2, v3), ...
        match slot {
            0 | 1 => corners[slot] = v,
            _ => {
                corners[2] = v;
                make_room(triangles, meter, path)?;
                triangles.push(corners);
                corners[1] = v;
            }
        }
    }
    Ok(())
}

/// After the last element only white space may follow in ascii, nothing in binary: more
/// data means the header's counts do not match the file. Reading to the end also checks
/// a gzip stream's trailer.
fn check_end(path: &Path, input: &mut Input, encoding: Encoding) -> Result<()> {
    loop {
        let buf = match input.fill_buf() {
            Ok(buf) => buf,
            Err(e) => {
                let message = input.stream_error().map_or_else(|| e.to_string(), str::to_string);
                return Err(Error::scene(path, message));
            }
        };
        if buf.is_empty() {
            return Ok(());
        }
        let extra = match encoding {
            Encoding::Ascii => buf.iter().any(|b| !b.is_ascii_whitespace()),
            _ => true,
        };
        if extra {
            return Err(Error::scene(
                path,
                format!(
                    "data after the last element at byte {} of the data: the header's element counts do not match the file",
                    input.consumed()
                ),
            ));
        }
        let n = buf.len();
        input.consume(n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_full_dragon_has_871414_faces_108_of_them_with_coincident_corners() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/dragon_vrip.ply.gz");
        let mesh = load_ply(&path, &mut Meter::unlimited()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((mesh.positions.len(), mesh.triangles.len()), (437_645, 871_414));
        let p = |i: u32| mesh.positions[i as usize];
        let repeated = mesh.triangles.iter().filter(|t| t[0] == t[1] || t[1] == t[2] || t[0] == t[2]).count();
        let coincident =
            mesh.triangles.iter().filter(|t| p(t[0]) == p(t[1]) || p(t[1]) == p(t[2]) || p(t[0]) == p(t[2])).count();
        assert_eq!((repeated, coincident), (0, 108));
    }

    /// A small ascii PLY (one triangle) with `extra` as its third header line.
    fn ply_with_header_line(extra: &str) -> String {
        format!(
            "ply\nformat ascii 1.0\n{extra}\nelement vertex 3\nproperty float x\nproperty float y\n\
             property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
             0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
        )
    }

    #[test]
    fn a_free_text_header_line_is_skipped_with_a_warning() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("blender.ply");
        std::fs::write(&path, ply_with_header_line("Created by Blender3D 247 - www.blender.org")).unwrap();
        let mesh = load_ply(&path, &mut Meter::unlimited()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(mesh.triangles, [[0, 1, 2]]);
        assert_eq!(
            mesh.warnings,
            [
                "skipped line 3 of the PLY header, which is no PLY keyword line: 'Created by Blender3D 247 - www.blender.org'"
            ]
        );
    }

    #[test]
    fn malformed_keyword_lines_in_the_header_are_still_errors() {
        let dir = tempfile::tempdir().unwrap();
        for (line, expect) in [
            ("element edge", "line 3 'element edge': expected 'element NAME COUNT'"),
            ("element edge -1", "invalid element count '-1'"),
            ("property float w", "line 3 'property float w': a property before any element"),
            ("element vertex 3", "a second element named 'vertex'"),
            ("format binary_little_endian 1.0", "a second, different format line"),
            ("format ascii one", "invalid version 'one'"),
            ("end_header now", "expected 'end_header'"),
        ] {
            let path = dir.path().join("bad.ply");
            std::fs::write(&path, ply_with_header_line(line)).unwrap();
            let message = load_ply(&path, &mut Meter::unlimited()).map(|_| ()).unwrap_err().to_string();
            assert!(message.contains("bad.ply: invalid PLY header") && message.contains(expect), "{line}: {message}");
        }
        let path = dir.path().join("bad.ply");
        let text = ply_with_header_line("comment fine").replace("property float y", "property float32 x");
        std::fs::write(&path, text).unwrap();
        let message = load_ply(&path, &mut Meter::unlimited()).map(|_| ()).unwrap_err().to_string();
        assert!(message.contains("a second property named 'x' in element 'vertex'"), "{message}");
    }

    #[test]
    fn element_sizes_bound_the_reserved_counts() {
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty double x\nproperty float y\n\
                    property float z\nproperty list uchar float uv\nelement face 2\nproperty uchar flags\n\
                    property list uint ushort vertex_indices\nend_header\n";
        let header = ply_rs_bw::parser::Parser::<Skipped>::new()
            .read_header(&mut ply_rs_bw::parser::Reader::new(text.as_bytes()))
            .unwrap();
        let (vertex, face) = (&header.elements["vertex"], &header.elements["face"]);
        assert_eq!(min_element_bytes(vertex, Encoding::BinaryLittleEndian, None), 8 + 4 + 4 + 1);
        assert_eq!(min_element_bytes(face, Encoding::BinaryLittleEndian, Some("vertex_indices")), 1 + 4 + 3 * 2);
        assert_eq!(min_element_bytes(vertex, Encoding::Ascii, None), 4 * 2);
        assert_eq!(min_element_bytes(face, Encoding::Ascii, Some("vertex_indices")), 2 + 2 + 3 * 2);
    }
}
