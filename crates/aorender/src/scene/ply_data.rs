//! PLY element data read in bulk: binary elements decoded straight from the input's
//! buffer, whole buffers of them at a time (byte order converted as each value is
//! read), the common layouts (`float` coordinates, plain triangles) in runs without
//! measuring each element, and ASCII lines parsed without the general parser's per-value
//! allocations, the numbers by `fast-float2` (on rayon's threads, a block of lines at a
//! time, in `ply.rs`).
//!
//! The fast paths read what `ply-rs-bw` reads and give the same values and the same
//! errors: a binary element is measured first (its lists' counts read), then passed whole
//! to the caller, so that an element cut off by the end of the file, the input cap or the
//! read budget fails where and as the element-at-a-time reader fails. Layouts they do not
//! cover (a coordinate after a list, a float list count, two index lists) and any ASCII
//! line they do not accept as it stands go to that reader.

use super::input::{Input, Meter, one_line};
use crate::error::{Error, Result};
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{ElementDef, Encoding, PropertyAccess, PropertyType, ScalarType};
use std::io::BufRead;
use std::path::Path;

/// Bytes of memory a list item may take while its element is read (see `ply.rs`): a
/// binary element with lists may take at most what is left of the budget over this.
pub(super) const LIST_ITEM_BYTES: u64 = 8 + 8;

/// A scalar type of the file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    /// The type of a header's scalar type.
    pub(crate) fn of(t: &ScalarType) -> Ty {
        match t {
            ScalarType::Char => Ty::I8,
            ScalarType::UChar => Ty::U8,
            ScalarType::Short => Ty::I16,
            ScalarType::UShort => Ty::U16,
            ScalarType::Int => Ty::I32,
            ScalarType::UInt => Ty::U32,
            ScalarType::Float => Ty::F32,
            ScalarType::Double => Ty::F64,
        }
    }

    /// Bytes one value takes in a binary file.
    pub(crate) fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64)
    }

    /// The value at the start of `b` (at least [`Ty::size`] bytes) as `f32`: the nearest
    /// value, as the element-at-a-time reader converts it.
    #[inline(always)]
    fn f32_at(self, b: &[u8], big: bool) -> f32 {
        match self {
            Ty::F32 => f32::from_bits(u32_at(b, big)),
            Ty::F64 => {
                let bytes = b[..8].try_into().unwrap_or([0; 8]);
                (if big { f64::from_be_bytes(bytes) } else { f64::from_le_bytes(bytes) }) as f32
            }
            Ty::I32 => u32_at(b, big) as i32 as f32,
            Ty::U32 => u32_at(b, big) as f32,
            _ => self.i64_at(b, big) as f32,
        }
    }

    /// The integer at the start of `b` (an integer type, at least [`Ty::size`] bytes).
    #[inline(always)]
    pub(crate) fn i64_at(self, b: &[u8], big: bool) -> i64 {
        let u16_at = |b: &[u8]| {
            let bytes = [b[0], b[1]];
            if big { u16::from_be_bytes(bytes) } else { u16::from_le_bytes(bytes) }
        };
        match self {
            Ty::I8 => i64::from(b[0] as i8),
            Ty::U8 => i64::from(b[0]),
            Ty::I16 => i64::from(u16_at(b) as i16),
            Ty::U16 => i64::from(u16_at(b)),
            Ty::I32 => i64::from(u32_at(b, big) as i32),
            Ty::U32 => i64::from(u32_at(b, big)),
            Ty::F32 | Ty::F64 => 0,
        }
    }
}

#[inline(always)]
fn u32_at(b: &[u8], big: bool) -> u32 {
    let bytes = [b[0], b[1], b[2], b[3]];
    if big { u32::from_be_bytes(bytes) } else { u32::from_le_bytes(bytes) }
}

/// One property of an element.
#[derive(Clone, Copy, Debug)]
enum Field {
    Scalar(Ty),
    /// A list: the count's type, the items' type.
    List(Ty, Ty),
}

/// How an element is laid out, and where the values a loader keeps are.
#[derive(Debug)]
pub(super) struct Layout {
    fields: Vec<Field>,
    /// Bytes of an element without lists (in binary).
    stride: Option<usize>,
    big_endian: bool,
    /// The byte offset (in binary) and type of the `x`, `y`, `z` properties, when asked for.
    axes: [(usize, Ty); 3],
    /// The field numbers of `x`, `y`, `z`.
    axis_fields: [usize; 3],
    /// The field number of the index list, when asked for.
    list_field: usize,
    /// The byte offset (in binary) of the index list's count, its count's and items' types.
    list: (usize, Ty, Ty),
}

/// What the loader keeps of an element.
pub(super) enum Keep<'a> {
    /// Nothing: the element is read to be skipped.
    Nothing,
    /// The coordinates `x`, `y`, `z`.
    Axes,
    /// The index list of this name.
    IndexList(&'a str, &'a [&'a str]),
}

impl Layout {
    /// The layout of `def`, or `None` where the fast paths do not cover it: a list count
    /// that is not an integer; coordinates or an index list after a list; an index list
    /// named twice (both names the element-at-a-time reader takes).
    pub(super) fn new(def: &ElementDef, encoding: Encoding, keep: Keep) -> Option<Layout> {
        let mut layout = Layout {
            fields: Vec::with_capacity(def.properties.len()),
            stride: None,
            big_endian: encoding == Encoding::BinaryBigEndian,
            axes: [(0, Ty::F32); 3],
            axis_fields: [usize::MAX; 3],
            list_field: usize::MAX,
            list: (0, Ty::U8, Ty::I32),
        };
        let mut offset = Some(0usize);
        let mut found = 0;
        for (name, p) in &def.properties {
            let field = match &p.data_type {
                PropertyType::Scalar(t) => Field::Scalar(Ty::of(t)),
                PropertyType::List(count, item) => Field::List(Ty::of(count), Ty::of(item)),
            };
            match (&keep, field) {
                (Keep::Axes, Field::Scalar(t)) => {
                    if let Some(axis) = ["x", "y", "z"].iter().position(|a| a == name) {
                        layout.axes[axis] = (offset?, t);
                        layout.axis_fields[axis] = layout.fields.len();
                        found += 1;
                    }
                }
                (Keep::IndexList(index, names), Field::List(count, item)) if names.contains(&name.as_str()) => {
                    if name != index || !count.is_integer() || !item.is_integer() {
                        return None;
                    }
                    layout.list = (offset?, count, item);
                    layout.list_field = layout.fields.len();
                    found += 1;
                }
                (Keep::IndexList(_, names), _) if names.contains(&name.as_str()) => return None,
                _ => {}
            }
            offset = match field {
                Field::Scalar(t) => offset.map(|o| o + t.size()),
                Field::List(count, _) if count.is_integer() => None,
                Field::List(..) => return None,
            };
            layout.fields.push(field);
        }
        let wanted = match keep {
            Keep::Nothing => 0,
            Keep::Axes => 3,
            Keep::IndexList(..) => 1,
        };
        layout.stride = offset;
        (found == wanted).then_some(layout)
    }

    /// The bytes the element at the start of `bytes` takes, as far as they can be told.
    #[inline]
    fn measure(&self, bytes: &[u8]) -> Measure {
        if let Some(stride) = self.stride {
            return if bytes.len() < stride { Measure::Short(stride) } else { Measure::Whole(stride) };
        }
        let mut at = 0usize;
        for field in &self.fields {
            match *field {
                Field::Scalar(t) => at += t.size(),
                Field::List(count, item) => {
                    let end = at + count.size();
                    if bytes.len() < end {
                        return Measure::Short(end);
                    }
                    let n = count.i64_at(&bytes[at..], self.big_endian);
                    let Ok(n) = usize::try_from(n) else {
                        return Measure::Invalid;
                    };
                    at = end.saturating_add(n.saturating_mul(item.size()));
                }
            }
        }
        if bytes.len() < at { Measure::Short(at) } else { Measure::Whole(at) }
    }

    fn has_list(&self) -> bool {
        self.stride.is_none()
    }

    /// The coordinates of a binary element.
    #[inline(always)]
    pub(super) fn axes_of(&self, element: &[u8]) -> [f32; 3] {
        let big = self.big_endian;
        self.axes.map(|(offset, t)| t.f32_at(&element[offset..], big))
    }

    /// The number of entries of a binary element's index list.
    #[inline(always)]
    pub(super) fn index_count(&self, element: &[u8]) -> usize {
        let (offset, count, _) = self.list;
        count.i64_at(&element[offset..], self.big_endian) as usize
    }

    /// Entry `k` of a binary element's index list.
    #[inline(always)]
    pub(super) fn index(&self, element: &[u8], k: usize) -> i64 {
        let (offset, count, item) = self.list;
        item.i64_at(&element[offset + count.size() + k * item.size()..], self.big_endian)
    }
}

impl Layout {
    /// Decodes the coordinates of the whole elements at the start of `bytes`, at most
    /// `most` of them, passing each to `f`; the number decoded and the bytes they took.
    /// Takes every whole element of a layout without lists (`float` coordinates, the
    /// layout most writers use, read with the byte order converted in place), none of a
    /// layout with lists.
    #[inline]
    pub(super) fn axes_run(
        &self,
        bytes: &[u8],
        most: usize,
        mut f: impl FnMut([f32; 3]) -> Result<()>,
    ) -> Result<(usize, usize)> {
        let Some(stride) = self.stride else {
            return Ok((0, 0));
        };
        let n = (bytes.len() / stride).min(most);
        let mut elements = bytes[..n * stride].chunks_exact(stride);
        let offsets = self.axes.map(|(offset, _)| offset);
        let floats = self.axes.iter().all(|&(_, t)| t == Ty::F32);
        let at = |e: &[u8], o: usize| [e[o], e[o + 1], e[o + 2], e[o + 3]];
        match (floats, self.big_endian) {
            (true, false) => elements.try_for_each(|e| f(offsets.map(|o| f32::from_le_bytes(at(e, o)))))?,
            (true, true) => elements.try_for_each(|e| f(offsets.map(|o| f32::from_be_bytes(at(e, o)))))?,
            _ => elements.try_for_each(|e| f(self.axes_of(e)))?,
        }
        Ok((n, n * stride))
    }

    /// Decodes the faces at the start of `bytes` while each is a whole plain triangle: an
    /// element of nothing but a `uchar` count of 3 and `int` or `uint` indices, each below
    /// `vertex_count`; at most `most` of them, each passed to `f`. The number decoded and
    /// the bytes they took: any other face (a polygon, an index out of range, one cut off
    /// by the end of `bytes`) is left to the element-at-a-time path, which also words
    /// its errors.
    #[inline]
    pub(super) fn triangle_run(
        &self,
        bytes: &[u8],
        most: usize,
        vertex_count: usize,
        mut f: impl FnMut([u32; 3]) -> Result<()>,
    ) -> Result<(usize, usize)> {
        const SIZE: usize = 13;
        let plain = self.fields.len() == 1
            && self.list_field == 0
            && matches!(self.list, (0, Ty::U8, Ty::I32 | Ty::U32))
            && i32::try_from(vertex_count).is_ok();
        if !plain {
            return Ok((0, 0));
        }
        // Below `vertex_count` as `u32`: a negative `int` index read as `u32` is at least
        // 2³¹, above any count that fits an `int`.
        let bound = vertex_count as u32;
        let big = self.big_endian;
        let mut n = 0;
        for e in bytes.chunks_exact(SIZE).take(most) {
            let v = [u32_at(&e[1..], big), u32_at(&e[5..], big), u32_at(&e[9..], big)];
            if e[0] != 3 || v[0] >= bound || v[1] >= bound || v[2] >= bound {
                break;
            }
            f(v)?;
            n += 1;
        }
        Ok((n, n * SIZE))
    }
}

/// How much of an element the bytes at hand hold.
enum Measure {
    /// The element takes this many bytes.
    Whole(usize),
    /// It takes at least this many, more than there are.
    Short(usize),
    /// A list count is negative.
    Invalid,
}

/// `vertex 12 of 100`.
fn what(def: &ElementDef, i: usize) -> String {
    format!("{} {i} of {}", def.name, def.count)
}

/// The error of a read of the input that failed while element `i` was read.
fn stream_failure(path: &Path, input: &Input, def: &ElementDef, i: usize, e: &std::io::Error) -> Error {
    let stream = input.stream_error().map_or_else(|| one_line(&e.to_string()), str::to_string);
    Error::scene(path, format!("{}: {stream}", what(def, i)))
}

fn unexpected_end(path: &Path, def: &ElementDef, i: usize) -> Error {
    Error::scene(path, format!("unexpected end of file in {}", what(def, i)))
}

/// The error of element `i` whose lists take more bytes than the budget leaves them.
fn cut_off(path: &Path, def: &ElementDef, i: usize, meter: &Meter) -> Error {
    Error::scene(path, format!("{}: its lists: {}", what(def, i), meter.exceeded_message()))
}

/// The error of element `i` (its `bytes`, as far as they go) that the general reader
/// refuses: its own message, as the element-at-a-time read gives it.
fn invalid(path: &Path, def: &ElementDef, i: usize, bytes: &[u8], big_endian: bool) -> Error {
    struct Skipped;
    impl PropertyAccess for Skipped {
        fn new() -> Self {
            Skipped
        }
    }
    let parser = Parser::<Skipped>::new();
    let mut reader = bytes;
    let result = if big_endian {
        parser.read_big_endian_element(&mut reader, def)
    } else {
        parser.read_little_endian_element(&mut reader, def)
    };
    let message = result.err().map_or_else(|| "invalid element".to_string(), |e| one_line(&e.to_string()));
    Error::scene(path, format!("{}: {message}", what(def, i)))
}

/// The most bytes an element with lists may take: what the budget leaves for its lists
/// (unbounded for an element without lists).
fn room(layout: &Layout, meter: &Meter) -> usize {
    if layout.has_list() {
        usize::try_from((meter.left() / LIST_ITEM_BYTES).saturating_add(16)).unwrap_or(usize::MAX)
    } else {
        usize::MAX
    }
}

/// Reads the `def.count` binary elements of `layout`, in order, into `sink`: runs of
/// them, a block of the input's buffer at a time, by `run` (given the number of the
/// first, the bytes at hand and the most elements it may take; it returns the elements
/// and the bytes it took, which may be none), and every element it leaves, its bytes with
/// its number, by `each`. Whole elements are taken from the input's buffer as it stands;
/// one that spans buffers is gathered first. The input is left just after the last
/// element.
#[allow(clippy::too_many_arguments)]
pub(super) fn read_binary<S>(
    path: &Path,
    input: &mut Input,
    def: &ElementDef,
    layout: &Layout,
    meter: &mut Meter,
    sink: &mut S,
    mut run: impl FnMut(&mut S, usize, &[u8], usize, &mut Meter) -> Result<(usize, usize)>,
    mut each: impl FnMut(&mut S, usize, &[u8], &mut Meter) -> Result<()>,
) -> Result<()> {
    let mut i = 0;
    let mut gathered: Vec<u8> = Vec::new();
    while i < def.count {
        let buf = match input.fill_buf() {
            Ok(buf) => buf,
            Err(e) => return Err(stream_failure(path, input, def, i, &e)),
        };
        if buf.is_empty() {
            return Err(unexpected_end(path, def, i));
        }
        let mut at = 0;
        if let Some(stride) = layout.stride {
            let whole = ((buf.len() / stride) as u64).min((def.count - i) as u64) as usize;
            while at < whole * stride {
                let (n, bytes) = run(sink, i, &buf[at..whole * stride], whole - at / stride, meter)?;
                i += n;
                at += bytes;
                if n == 0 {
                    // `at` is a whole number of elements short of `whole * stride`.
                    each(sink, i, &buf[at..at + stride], meter)?;
                    i += 1;
                    at += stride;
                }
            }
        } else {
            while i < def.count {
                let (n, bytes) = run(sink, i, &buf[at..], def.count - i, meter)?;
                if n > 0 {
                    i += n;
                    at += bytes;
                    continue;
                }
                match layout.measure(&buf[at..]) {
                    Measure::Whole(n) if n > room(layout, meter) => return Err(cut_off(path, def, i, meter)),
                    Measure::Whole(n) => {
                        each(sink, i, &buf[at..at + n], meter)?;
                        at += n;
                        i += 1;
                    }
                    Measure::Short(_) => break,
                    Measure::Invalid => return Err(invalid(path, def, i, &buf[at..], layout.big_endian)),
                }
            }
        }
        let len = buf.len();
        if i == def.count || at == len {
            input.consume(at);
            continue;
        }
        // An element that goes on past the buffer: gathered, no further than its end.
        gathered.clear();
        gathered.extend_from_slice(&buf[at..]);
        input.consume(len);
        let most = room(layout, meter);
        loop {
            match layout.measure(&gathered) {
                Measure::Whole(n) if n > most => return Err(cut_off(path, def, i, meter)),
                Measure::Whole(n) => {
                    each(sink, i, &gathered[..n], meter)?;
                    i += 1;
                    break;
                }
                Measure::Invalid => return Err(invalid(path, def, i, &gathered, layout.big_endian)),
                Measure::Short(need) => {
                    let target = need.min(most);
                    if gathered.len() >= target {
                        return Err(cut_off(path, def, i, meter));
                    }
                    let buf = match input.fill_buf() {
                        Ok(buf) => buf,
                        Err(e) => return Err(stream_failure(path, input, def, i, &e)),
                    };
                    if buf.is_empty() {
                        return Err(unexpected_end(path, def, i));
                    }
                    let take = buf.len().min(target - gathered.len());
                    gathered.extend_from_slice(&buf[..take]);
                    input.consume(take);
                }
            }
        }
    }
    Ok(())
}

/// The tokens of an ASCII data line, one at a time: numbers of the PLY grammar
/// (`[-+]?[0-9]+(.[0-9]+)?([eE][-+]?[0-9]+)?`) separated by spaces or tabs, one line
/// break at most, [`MAX_TOKENS`] at most. A line is plain when every token is such a
/// number ([`Tokens::finish`] checks those left).
struct Tokens<'a> {
    rest: &'a [u8],
    taken: usize,
}

impl<'a> Tokens<'a> {
    fn new(line: &'a [u8]) -> Tokens<'a> {
        let line = line
            .strip_suffix(b"\r\n")
            .or_else(|| line.strip_suffix(b"\n"))
            .or_else(|| line.strip_suffix(b"\r"))
            .unwrap_or(line);
        Tokens { rest: line, taken: 0 }
    }

    /// The next token; `None` at the end of the line, and for a token that is no number
    /// or one past [`MAX_TOKENS`] (the line is then not plain).
    #[inline]
    fn next(&mut self) -> Option<&'a [u8]> {
        let start = self.rest.iter().position(|&b| b != b' ' && b != b'\t')?;
        let rest = &self.rest[start..];
        let end = rest.iter().position(|&b| b == b' ' || b == b'\t').unwrap_or(rest.len());
        let (token, after) = rest.split_at(end);
        self.rest = after;
        self.taken += 1;
        (self.taken <= MAX_TOKENS && is_number(token)).then_some(token)
    }

    /// True when the tokens left are plain too.
    fn finish(mut self) -> bool {
        while self.rest.iter().any(|&b| b != b' ' && b != b'\t') {
            if self.next().is_none() {
                return false;
            }
        }
        true
    }
}

/// `[-+]?[0-9]+(.[0-9]+)?([eE][-+]?[0-9]+)?`, the PLY grammar's number.
fn is_number(token: &[u8]) -> bool {
    fn digits(t: &[u8]) -> usize {
        t.iter().take_while(|b| b.is_ascii_digit()).count()
    }
    let mut t = token.strip_prefix(b"-").or_else(|| token.strip_prefix(b"+")).unwrap_or(token);
    let d = digits(t);
    if d == 0 {
        return false;
    }
    t = &t[d..];
    if let Some(rest) = t.strip_prefix(b".") {
        let d = digits(rest);
        if d == 0 {
            return false;
        }
        t = &rest[d..];
    }
    if let Some(rest) = t.strip_prefix(b"e").or_else(|| t.strip_prefix(b"E")) {
        let rest = rest.strip_prefix(b"-").or_else(|| rest.strip_prefix(b"+")).unwrap_or(rest);
        let d = digits(rest);
        if d == 0 {
            return false;
        }
        t = &rest[d..];
    }
    t.is_empty()
}

/// An integer token as `str::parse` reads it for type `t`, when it is plain digits with
/// an optional `-` (signed types) and in range; `None` for anything else.
pub(crate) fn ascii_int(token: &[u8], t: Ty) -> Option<i64> {
    let (negative, digits) = match token.strip_prefix(b"-") {
        Some(rest) => (true, rest),
        None => (false, token),
    };
    if digits.is_empty() || digits.len() > 18 || !digits.iter().all(u8::is_ascii_digit) {
        return None;
    }
    let magnitude = digits.iter().fold(0i64, |v, &d| v * 10 + i64::from(d - b'0'));
    let v = if negative { -magnitude } else { magnitude };
    let (low, high) = match t {
        Ty::I8 => (i64::from(i8::MIN), i64::from(i8::MAX)),
        Ty::U8 => (0, i64::from(u8::MAX)),
        Ty::I16 => (i64::from(i16::MIN), i64::from(i16::MAX)),
        Ty::U16 => (0, i64::from(u16::MAX)),
        Ty::I32 => (i64::from(i32::MIN), i64::from(i32::MAX)),
        Ty::U32 => (0, i64::from(u32::MAX)),
        Ty::F32 | Ty::F64 => return None,
    };
    // `-0` is refused by unsigned types' `parse`.
    (!(negative && low == 0) && (low..=high).contains(&v)).then_some(v)
}

/// A token of type `t` as `f32`, as the general reader gives it (`str::parse` of the
/// file's type, then the nearest `f32`); `None` where it would not parse.
fn ascii_value(token: &[u8], t: Ty) -> Option<f32> {
    match t {
        Ty::F32 => fast_float2::parse::<f32, _>(token).ok(),
        Ty::F64 => fast_float2::parse::<f64, _>(token).ok().map(|v| v as f32),
        _ => ascii_int(token, t).map(|v| v as f32),
    }
}

/// Checks the tokens of the scalar field `t` as the general reader parses it.
fn ascii_valid(token: &[u8], t: Ty) -> bool {
    // Every number of the grammar parses as a float (overflow gives infinity).
    !t.is_integer() || ascii_int(token, t).is_some()
}

/// Most tokens of a line the fast ASCII path takes (a longer line goes to the general
/// reader).
const MAX_TOKENS: usize = 32;

/// The coordinates of an ASCII vertex line, as the general reader reads them; `None`
/// where the line is not plain (the general reader then reads it, or says what is
/// wrong with it).
pub(super) fn ascii_axes(layout: &Layout, line: &[u8]) -> Option<[f32; 3]> {
    let mut tokens = Tokens::new(line);
    let mut p = [0f32; 3];
    let mut seen = 0;
    for (k, field) in layout.fields.iter().enumerate() {
        match *field {
            Field::Scalar(t) => {
                let token = tokens.next()?;
                if let Some(axis) = layout.axis_fields.iter().position(|&f| f == k) {
                    p[axis] = ascii_value(token, t)?;
                    seen += 1;
                } else if !ascii_valid(token, t) {
                    return None;
                }
            }
            Field::List(count, item) => ascii_list(&mut tokens, count, item, |_| Some(()))?,
        }
    }
    (seen == 3 && tokens.finish()).then_some(p)
}

/// Reads the list whose count is the next token, each item through `item_fn`.
fn ascii_list(tokens: &mut Tokens, count: Ty, item: Ty, mut item_fn: impl FnMut(&[u8]) -> Option<()>) -> Option<()> {
    // The general reader parses a list's count as `usize` whatever its declared type.
    let _ = count;
    let n = ascii_int(tokens.next()?, Ty::U32)?;
    for _ in 0..n {
        let token = tokens.next()?;
        if !ascii_valid(token, item) {
            return None;
        }
        item_fn(token)?;
    }
    Some(())
}

/// The index list of an ASCII face line, appended to `indices`, as the general reader
/// reads it; `false` where the line is not plain.
pub(super) fn ascii_indices(layout: &Layout, line: &[u8], indices: &mut Vec<i64>) -> bool {
    let mut tokens = Tokens::new(line);
    for (k, field) in layout.fields.iter().enumerate() {
        let step = match *field {
            Field::Scalar(t) => tokens.next().filter(|token| ascii_valid(token, t)).map(|_| ()),
            Field::List(count, item) if k == layout.list_field => ascii_list(&mut tokens, count, item, |token| {
                indices.push(ascii_int(token, item)?);
                Some(())
            }),
            Field::List(count, item) => ascii_list(&mut tokens, count, item, |_| Some(())),
        };
        if step.is_none() {
            return false;
        }
    }
    tokens.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(text: &str) -> ply_rs_bw::ply::Header {
        struct Skipped;
        impl PropertyAccess for Skipped {
            fn new() -> Self {
                Skipped
            }
        }
        let mut reader = ply_rs_bw::parser::Reader::new(text.as_bytes());
        Parser::<Skipped>::new().read_header(&mut reader).unwrap()
    }

    #[test]
    fn layouts_with_coordinates_and_index_lists_first_take_the_fast_paths() {
        let h = header(
            "ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\nproperty uchar red\n\
             property float y\nproperty short z\nproperty list uchar float uv\nelement face 1\n\
             property uchar flags\nproperty list ushort uint vertex_index\nproperty list char float t\nend_header\n",
        );
        let (vertex, face) = (&h.elements["vertex"], &h.elements["face"]);
        let layout = Layout::new(vertex, h.encoding, Keep::Axes).unwrap();
        assert_eq!(layout.axes, [(0, Ty::F64), (9, Ty::F32), (13, Ty::I16)]);
        assert_eq!(layout.stride, None);
        let names = ["vertex_indices", "vertex_index"];
        let layout = Layout::new(face, h.encoding, Keep::IndexList("vertex_index", &names)).unwrap();
        assert_eq!(layout.list, (1, Ty::U16, Ty::U32));
        // Flags, 3 big-endian u16-counted u32 indices, an empty list.
        let element = [9, 0, 3, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0, 7, 0];
        assert!(matches!(layout.measure(&element), Measure::Whole(16)));
        assert!(matches!(layout.measure(&element[..14]), Measure::Short(16)));
        assert_eq!((layout.index_count(&element), layout.index(&element, 2)), (3, 7));
        // A coordinate after a list, a float count, two index lists: the general reader's.
        for text in [
            "property list uchar float uv\nproperty float x\nproperty float y\nproperty float z\n",
            "property float x\nproperty float y\nproperty float z\nproperty list float float uv\n",
        ] {
            let h = header(&format!("ply\nformat ascii 1.0\nelement vertex 1\n{text}end_header\n"));
            assert!(Layout::new(&h.elements["vertex"], h.encoding, Keep::Axes).is_none(), "{text}");
        }
        let h = header(
            "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n\
             property list uchar int vertex_index\nend_header\n",
        );
        assert!(Layout::new(&h.elements["face"], h.encoding, Keep::IndexList("vertex_indices", &names)).is_none());
    }

    #[test]
    fn runs_take_plain_elements_and_stop_at_the_first_other() {
        let h = header(
            "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty uchar red\n\
             property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
        );
        let names = ["vertex_indices", "vertex_index"];
        let face = Layout::new(&h.elements["face"], h.encoding, Keep::IndexList("vertex_indices", &names)).unwrap();
        let triangle = |count: u8, v: [i32; 3]| {
            let mut e = vec![count];
            v.iter().for_each(|i| e.extend_from_slice(&i.to_le_bytes()));
            e
        };
        let mut faces = [triangle(3, [0, 1, 2]), triangle(3, [2, 1, 0]), triangle(3, [0, 1, 3])].concat();
        let run = |bytes: &[u8], most: usize| {
            let mut seen = Vec::new();
            let taken = face
                .triangle_run(bytes, most, 4, |t| {
                    seen.push(t);
                    Ok(())
                })
                .unwrap();
            (taken, seen)
        };
        assert_eq!(run(&faces, 9), ((3, 39), vec![[0, 1, 2], [2, 1, 0], [0, 1, 3]]));
        assert_eq!(run(&faces, 2).0, (2, 26));
        assert_eq!(run(&faces[..38], 9).0, (2, 26), "a face cut off");
        faces[26] = 4;
        assert_eq!(run(&faces, 9).0, (2, 26), "a quad");
        for bad in [4, -1] {
            faces[26..].copy_from_slice(&triangle(3, [0, bad, 1]));
            assert_eq!(run(&faces, 9).0, (2, 26), "index {bad}");
        }
        let vertex = Layout::new(&h.elements["vertex"], h.encoding, Keep::Axes).unwrap();
        let mut bytes = Vec::new();
        for k in 0..3u8 {
            let k = f32::from(k);
            [k, 0.5].iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
            bytes.insert(bytes.len() - 4, 7);
            bytes.extend_from_slice(&(-k).to_le_bytes());
        }
        let mut seen = Vec::new();
        assert_eq!(
            vertex
                .axes_run(&bytes[..38], 9, |p| {
                    seen.push(p);
                    Ok(())
                })
                .unwrap(),
            (2, 26)
        );
        assert_eq!(seen, [[0.0, 0.5, -0.0], [1.0, 0.5, -1.0]]);
    }

    #[test]
    fn ascii_numbers_are_taken_as_the_grammar_and_str_parse_take_them() {
        for (token, number) in
            [("1", true), ("-1.5e-3", true), ("+2", true), ("1.", false), (".5", false), ("nan", false)]
        {
            assert_eq!(is_number(token.as_bytes()), number, "{token}");
        }
        assert_eq!(ascii_int(b"255", Ty::U8), Some(255));
        assert_eq!(ascii_int(b"256", Ty::U8), None);
        assert_eq!(ascii_int(b"-0", Ty::U32), None);
        assert_eq!(ascii_int(b"-128", Ty::I8), Some(-128));
        for token in ["0.1", "3.4028236e38", "1e-46", "123456789.123456789", "-0"] {
            assert_eq!(
                ascii_value(token.as_bytes(), Ty::F32).map(f32::to_bits),
                token.parse::<f32>().ok().map(f32::to_bits)
            );
            let double = token.parse::<f64>().ok().map(|v| (v as f32).to_bits());
            assert_eq!(ascii_value(token.as_bytes(), Ty::F64).map(f32::to_bits), double, "{token}");
        }
    }
}
