//! Baking into PLY files: the whole file read (every header line, element and property,
//! in order, each value in its own type), and written back with the AO added as MeshLab
//! reads it: `quality` on the vertex (or face) element, optionally `quality_std_error`,
//! the bent normal `bnx bny bnz` and a grey `red green blue` (on the same element). A
//! property of the file with one of these names is replaced in place, colours keeping
//! their type.
//!
//! The header goes through the scene loader's reader ([`read_header`]); the data is read
//! here, ascii tokens accepted and converted exactly as the loader's crate does (so the
//! positions are the loader's, bit for bit). Output is binary little-endian, or ascii
//! when the input was.
//!
//! A texture bake writes the map beside the file; generated texture coordinates go in as
//! MeshLab's face `texcoord` lists (`u v` per corner), so the vertices stay as they are.

use super::asset::{
    Asset, AssetMesh, BakeAt, BakedValues, GeneratedUvs, TextureMap, UvSet, WriteOptions, write_maps_beside,
};
use crate::error::{Error, Result};
use crate::output::{write_output_with, write_rows};
use crate::scene::input::is_gzip as is_gzip_name;
use crate::scene::input::{Input, LoadOptions, Meter, advise_huge_pages, huge_vec, vec_bytes};
use crate::scene::mesh::{IndexedMesh, VertexNames};
use crate::scene::ply::{HeaderLine, PlyHeader, index_list_name, non_finite_coordinate, read_header};
use crate::scene::ply_data::{Ty, ascii_int};
use glam::Vec3;
use ply_rs_bw::ply::{ElementDef, Encoding, PropertyType, ScalarType};
use std::io::{Read, Write};
use std::path::Path;

/// Rows of an element one rayon task writes out at a time: about a megabyte of ascii
/// vertices, enough that a task's work dwarfs handing it out.
const WRITE_BLOCK_ROWS: usize = 1 << 14;

/// A value of one of PLY's scalar types.
trait Scalar: Copy + std::str::FromStr + Into<f64> {
    /// Bytes in binary encodings.
    const SIZE: usize;

    /// The value at `data[*pos..]`, advancing `pos`; `None` when too few bytes are left.
    fn read(data: &[u8], pos: &mut usize, big_endian: bool) -> Option<Self>;

    /// The value at the start of `bytes` (at least [`Scalar::SIZE`] of them), in the byte
    /// order `BIG` says.
    fn at<const BIG: bool>(bytes: &[u8]) -> Self;

    /// Appends the value's little-endian bytes.
    fn put_le(self, out: &mut Vec<u8>);

    /// Appends the value as ascii text that reads back as the same value.
    fn put_ascii(self, out: &mut Vec<u8>);
}

macro_rules! scalar {
    ($t:ty, $ascii:expr) => {
        impl Scalar for $t {
            const SIZE: usize = std::mem::size_of::<$t>();

            fn read(data: &[u8], pos: &mut usize, big_endian: bool) -> Option<Self> {
                let bytes: [u8; std::mem::size_of::<$t>()] = data.get(*pos..*pos + Self::SIZE)?.try_into().ok()?;
                *pos += Self::SIZE;
                Some(if big_endian { <$t>::from_be_bytes(bytes) } else { <$t>::from_le_bytes(bytes) })
            }

            #[inline(always)]
            fn at<const BIG: bool>(bytes: &[u8]) -> Self {
                let mut b = [0u8; std::mem::size_of::<$t>()];
                b.copy_from_slice(&bytes[..Self::SIZE]);
                if BIG { <$t>::from_be_bytes(b) } else { <$t>::from_le_bytes(b) }
            }

            fn put_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }

            fn put_ascii(self, out: &mut Vec<u8>) {
                let ascii: fn($t, &mut Vec<u8>) = $ascii;
                ascii(self, out)
            }
        }
    };
}

fn put_display(v: impl std::fmt::Display, out: &mut Vec<u8>) {
    // Writing to a Vec cannot fail.
    let _ = write!(out, "{v}");
}

scalar!(i8, put_display);
scalar!(u8, put_display);
scalar!(i16, put_display);
scalar!(u16, put_display);
scalar!(i32, put_display);
scalar!(u32, put_display);
/// A float as the shortest digits that read back as the same value: `{}`, or `{:e}` for
/// magnitudes whose `{}` would run to many zeros.
fn put_float<T: std::fmt::Display + std::fmt::LowerExp + Into<f64> + Copy>(v: T, out: &mut Vec<u8>) {
    let magnitude = to_f64(v).abs();
    if magnitude != 0.0 && !(1e-5..1e16).contains(&magnitude) {
        let _ = write!(out, "{v:e}");
    } else {
        put_display(v, out);
    }
}

// Infinities (an ascii value beyond the type's range reads as one) are written as such a
// value, since PLY readers take no `inf`.
scalar!(f32, |v, out| match v {
    f32::INFINITY => out.extend_from_slice(b"1e39"),
    f32::NEG_INFINITY => out.extend_from_slice(b"-1e39"),
    v if v.is_nan() => out.extend_from_slice(b"nan"),
    v => put_float(v, out),
});
scalar!(f64, |v, out| match v {
    f64::INFINITY => out.extend_from_slice(b"1e309"),
    f64::NEG_INFINITY => out.extend_from_slice(b"-1e309"),
    v if v.is_nan() => out.extend_from_slice(b"nan"),
    v => put_float(v, out),
});

/// `v` as an `f64`: exact for every PLY type.
fn to_f64<T: Into<f64>>(v: T) -> f64 {
    v.into()
}

/// The values of one property over all elements (the items of all lists, for a list), in
/// the property's own type.
#[derive(Clone, Debug, PartialEq)]
enum Values {
    Char(Vec<i8>),
    UChar(Vec<u8>),
    Short(Vec<i16>),
    UShort(Vec<u16>),
    Int(Vec<i32>),
    UInt(Vec<u32>),
    Float(Vec<f32>),
    Double(Vec<f64>),
}

/// Runs `$body` with `$v` bound to the vector inside `$values`, whatever its type.
macro_rules! with_values {
    ($values:expr, $v:ident => $body:expr) => {
        match $values {
            Values::Char($v) => $body,
            Values::UChar($v) => $body,
            Values::Short($v) => $body,
            Values::UShort($v) => $body,
            Values::Int($v) => $body,
            Values::UInt($v) => $body,
            Values::Float($v) => $body,
            Values::Double($v) => $body,
        }
    };
}

impl Values {
    /// No values of type `t`, with room for `capacity`.
    fn new(t: &ScalarType, capacity: usize) -> Values {
        match t {
            ScalarType::Char => Values::Char(huge_vec(capacity)),
            ScalarType::UChar => Values::UChar(huge_vec(capacity)),
            ScalarType::Short => Values::Short(huge_vec(capacity)),
            ScalarType::UShort => Values::UShort(huge_vec(capacity)),
            ScalarType::Int => Values::Int(huge_vec(capacity)),
            ScalarType::UInt => Values::UInt(huge_vec(capacity)),
            ScalarType::Float => Values::Float(huge_vec(capacity)),
            ScalarType::Double => Values::Double(huge_vec(capacity)),
        }
    }

    fn scalar_type(&self) -> ScalarType {
        match self {
            Values::Char(_) => ScalarType::Char,
            Values::UChar(_) => ScalarType::UChar,
            Values::Short(_) => ScalarType::Short,
            Values::UShort(_) => ScalarType::UShort,
            Values::Int(_) => ScalarType::Int,
            Values::UInt(_) => ScalarType::UInt,
            Values::Float(_) => ScalarType::Float,
            Values::Double(_) => ScalarType::Double,
        }
    }

    fn len(&self) -> usize {
        with_values!(self, v => v.len())
    }

    /// Appends `more`, values of the same type.
    fn append(&mut self, more: Values) {
        match (self, more) {
            (Values::Char(v), Values::Char(m)) => v.extend(m),
            (Values::UChar(v), Values::UChar(m)) => v.extend(m),
            (Values::Short(v), Values::Short(m)) => v.extend(m),
            (Values::UShort(v), Values::UShort(m)) => v.extend(m),
            (Values::Int(v), Values::Int(m)) => v.extend(m),
            (Values::UInt(v), Values::UInt(m)) => v.extend(m),
            (Values::Float(v), Values::Float(m)) => v.extend(m),
            (Values::Double(v), Values::Double(m)) => v.extend(m),
            _ => unreachable!("a block's columns have their column's types"),
        }
    }

    /// The bytes its vector holds.
    fn bytes(&self) -> u64 {
        with_values!(self, v => vec_bytes(v))
    }

    /// Appends the binary value at `data[*pos..]`; `None` when too few bytes are left.
    fn push_binary(&mut self, data: &[u8], pos: &mut usize, big_endian: bool) -> Option<()> {
        with_values!(self, v => v.push(Scalar::read(data, pos, big_endian)?));
        Some(())
    }

    /// Appends the value of an ascii token (already checked to be a number), parsed as
    /// ply-rs parses it, `str::parse` into the property's type: floats by `fast-float2`
    /// (correctly rounded too, so the same bits), plain integers by the scene loader's
    /// digit loop, anything else by `str::parse` itself; all by `str::parse` unless `fast`
    /// (the reference the fast parsers are compared with).
    fn push_token(&mut self, token: &str, fast: bool) -> std::result::Result<(), TokenError> {
        let t = self.scalar_type();
        let invalid = || TokenError { token: token.to_string(), type_name: type_name(&t) };
        if !fast {
            with_values!(self, v => v.push(token.parse().map_err(|_| invalid())?));
            return Ok(());
        }
        let ty = Ty::of(&t);
        macro_rules! integer {
            ($v:expr) => {{
                // `ascii_int` keeps to the type's range, so the conversion cannot fail.
                let fast = ascii_int(token.as_bytes(), ty).and_then(|i| i.try_into().ok());
                $v.push(fast.map_or_else(|| token.parse().map_err(|_| invalid()), Ok)?)
            }};
        }
        match self {
            Values::Char(v) => integer!(v),
            Values::UChar(v) => integer!(v),
            Values::Short(v) => integer!(v),
            Values::UShort(v) => integer!(v),
            Values::Int(v) => integer!(v),
            Values::UInt(v) => integer!(v),
            Values::Float(v) => v.push(fast_float2::parse(token).or_else(|_| token.parse()).map_err(|_| invalid())?),
            Values::Double(v) => v.push(fast_float2::parse(token).or_else(|_| token.parse()).map_err(|_| invalid())?),
        }
        Ok(())
    }

    /// Makes room for exactly `additional` more values.
    fn reserve(&mut self, additional: usize) {
        with_values!(self, v => {
            v.reserve_exact(additional);
            advise_huge_pages(v);
        })
    }

    /// Room for more values without growing.
    fn spare(&self) -> usize {
        with_values!(self, v => v.capacity() - v.len())
    }

    /// Appends the `items` values at byte `offset` of each element of `block` (whole
    /// binary elements of `stride` bytes), in the byte order `big` says.
    fn extend_from_elements(&mut self, block: &[u8], stride: usize, offset: usize, items: usize, big: bool) {
        with_values!(self, v => if big {
            gather::<_, true>(v, block, stride, offset, items)
        } else {
            gather::<_, false>(v, block, stride, offset, items)
        })
    }

    /// Value `i` as `f32`, converted as the scene loader converts coordinates (the
    /// nearest value; every integer of PLY's types is exact as an `f64`).
    fn f32(&self, i: usize) -> f32 {
        with_values!(self, v => to_f64(v[i]) as f32)
    }

    /// Value `i` as an integer; `None` for the floating-point types.
    fn integer(&self, i: usize) -> Option<i64> {
        match self {
            Values::Float(_) | Values::Double(_) => None,
            // Exact: PLY's integers are at most 32 bits.
            other => Some(other.f64(i) as i64),
        }
    }

    fn f64(&self, i: usize) -> f64 {
        with_values!(self, v => to_f64(v[i]))
    }

    fn put_le(&self, i: usize, out: &mut Vec<u8>) {
        with_values!(self, v => v[i].put_le(out))
    }

    fn put_ascii(&self, i: usize, out: &mut Vec<u8>) {
        with_values!(self, v => v[i].put_ascii(out))
    }
}

/// Appends the `items` values at byte `offset` of each element of `block` to `v`.
#[inline]
fn gather<T: Scalar, const BIG: bool>(v: &mut Vec<T>, block: &[u8], stride: usize, offset: usize, items: usize) {
    let elements = block.chunks_exact(stride);
    match items {
        // An exact-size iterator: `extend` writes in place, without a check per value.
        1 => v.extend(elements.map(|e| T::at::<BIG>(&e[offset..]))),
        2 => gather_n::<T, BIG, 2>(v, elements, offset),
        3 => gather_n::<T, BIG, 3>(v, elements, offset),
        4 => gather_n::<T, BIG, 4>(v, elements, offset),
        _ => {
            let end = offset + items * T::SIZE;
            v.extend(elements.flat_map(|e| e[offset..end].chunks_exact(T::SIZE).map(T::at::<BIG>)));
        }
    }
}

/// [`gather`] of `N` values an element (a triangle's indices, a pair of coordinates),
/// decoded as fixed-size arrays.
#[inline]
fn gather_n<T: Scalar, const BIG: bool, const N: usize>(
    v: &mut Vec<T>,
    elements: std::slice::ChunksExact<u8>,
    offset: usize,
) {
    v.reserve(elements.len() * N);
    for e in elements {
        let e = &e[offset..offset + N * T::SIZE];
        v.extend_from_slice(&std::array::from_fn::<T, N, _>(|k| T::at::<BIG>(&e[k * T::SIZE..])));
    }
}

/// An ascii token that does not parse as its property's type.
#[derive(Debug, thiserror::Error)]
#[error("'{token}' is not a valid {type_name}")]
struct TokenError {
    token: String,
    /// The property's PLY type.
    type_name: &'static str,
}

/// One property of an element, with its values for every element.
#[derive(Clone, Debug, PartialEq)]
struct Column {
    name: String,
    /// For a list property: the count's type, and where the items of each element start
    /// in `values` (one entry more than there are elements).
    list: Option<(ScalarType, Starts)>,
    /// Its values, empty (of their type) where the mesh holds them (`held`).
    values: Values,
    held: Held,
}

/// Where a column's values are held.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Held {
    /// In the column.
    Own,
    /// In the mesh's positions, as coordinate `k` (a `float` x, y or z: the same bits).
    Axis(usize),
    /// In the mesh's corners (an `int` or `uint` vertex index list: the same bits).
    Corners,
}

/// Where the items of each element's list start in its column's values, one entry more
/// than there are elements: lists of one length throughout (a triangle mesh's faces) as
/// that length alone, without memory; any other as every entry.
#[derive(Clone, Debug)]
enum Starts {
    /// `len` entries, entry `k` at `k * items` (`items` unknown while there is one entry);
    /// the entries take `room` entries' memory once they differ.
    Uniform {
        items: Option<usize>,
        len: usize,
        room: usize,
    },
    Explicit(Vec<usize>),
}

impl Starts {
    /// The first entry (0), room for `room` entries.
    fn with_room(room: usize) -> Starts {
        Starts::Uniform { items: None, len: 1, room }
    }

    fn len(&self) -> usize {
        match self {
            Starts::Uniform { len, .. } => *len,
            Starts::Explicit(v) => v.len(),
        }
    }

    /// Entry `k`.
    #[inline]
    fn get(&self, k: usize) -> usize {
        match self {
            Starts::Uniform { items, .. } => k * items.unwrap_or(0),
            Starts::Explicit(v) => v[k],
        }
    }

    fn last(&self) -> usize {
        self.get(self.len() - 1)
    }

    fn iter(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.len()).map(|k| self.get(k))
    }

    /// The bytes it holds.
    fn bytes(&self) -> u64 {
        match self {
            Starts::Uniform { .. } => 0,
            Starts::Explicit(v) => vec_bytes(v),
        }
    }

    /// Lists of `items` items it can take without taking memory.
    fn room_for(&self, items: usize) -> usize {
        match self {
            Starts::Uniform { items: None, .. } => usize::MAX,
            Starts::Uniform { items: Some(n), .. } => {
                if *n == items {
                    usize::MAX
                } else {
                    0
                }
            }
            Starts::Explicit(v) => v.capacity() - v.len(),
        }
    }

    /// Appends the entry `end` (the end of one more list).
    fn push(&mut self, end: usize) {
        self.extend(1, end - self.last());
    }

    /// Appends `n` lists of `items` items each.
    fn extend(&mut self, n: usize, items: usize) {
        if let Starts::Uniform { items: uniform, len, room } = self {
            match uniform {
                Some(k) if *k != items => {
                    let mut v = huge_vec((*room).max(*len));
                    v.extend((0..*len).map(|i| i * *k));
                    *self = Starts::Explicit(v);
                }
                _ => {
                    *uniform = Some(items);
                    *len += n;
                    return;
                }
            }
        }
        if let Starts::Explicit(v) = self {
            let first = v.last().copied().unwrap_or(0);
            v.extend((1..=n).map(|k| first + k * items));
        }
    }
}

impl PartialEq for Starts {
    fn eq(&self, other: &Starts) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}

impl From<Vec<usize>> for Starts {
    fn from(v: Vec<usize>) -> Starts {
        Starts::Explicit(v)
    }
}

impl Column {
    /// A scalar `float` property.
    fn float(name: &str, values: Vec<f32>) -> Column {
        Column { name: name.to_string(), list: None, values: Values::Float(values), held: Held::Own }
    }

    /// The bytes it holds.
    fn bytes(&self) -> u64 {
        self.values.bytes() + self.list.as_ref().map_or(0, |(_, starts)| starts.bytes())
    }

    /// The items of element `i`'s list (all of `values` for a scalar property).
    fn items(&self, i: usize) -> std::ops::Range<usize> {
        match &self.list {
            Some((_, starts)) => starts.get(i)..starts.get(i + 1),
            None => i..i + 1,
        }
    }

    /// How many values it has (in the mesh, where the mesh holds them).
    #[cfg(feature = "testing")]
    fn len(&self, mesh: &AssetMesh) -> usize {
        match self.held {
            Held::Own => self.values.len(),
            Held::Axis(_) => mesh.positions.len(),
            Held::Corners => mesh.face_indices.len(),
        }
    }

    /// Appends value `i` in binary little-endian.
    fn put_le(&self, i: usize, mesh: &AssetMesh, out: &mut Vec<u8>) {
        match self.held {
            Held::Own => self.values.put_le(i, out),
            Held::Axis(k) => mesh.positions[i][k].put_le(out),
            // An `int` index is below 2^31: the same bytes as the `uint`.
            Held::Corners => mesh.face_indices[i].put_le(out),
        }
    }

    /// Appends value `i` as ascii text.
    fn put_ascii(&self, i: usize, mesh: &AssetMesh, out: &mut Vec<u8>) {
        match self.held {
            Held::Own => self.values.put_ascii(i, out),
            Held::Axis(k) => mesh.positions[i][k].put_ascii(out),
            // An `int` index is below 2^31: the same digits as the `uint`.
            Held::Corners => mesh.face_indices[i].put_ascii(out),
        }
    }

    /// The property's header line, without its line break.
    fn header_line(&self) -> String {
        match &self.list {
            Some((count, _)) => {
                format!("property list {} {} {}", type_name(count), type_name(&self.values.scalar_type()), self.name)
            }
            None => format!("property {} {}", type_name(&self.values.scalar_type()), self.name),
        }
    }
}

/// A type's name as the PLY specification spells it.
fn type_name(t: &ScalarType) -> &'static str {
    match t {
        ScalarType::Char => "char",
        ScalarType::UChar => "uchar",
        ScalarType::Short => "short",
        ScalarType::UShort => "ushort",
        ScalarType::Int => "int",
        ScalarType::UInt => "uint",
        ScalarType::Float => "float",
        ScalarType::Double => "double",
    }
}

fn scalar_bytes(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// An element with all its values.
#[derive(Clone, Debug, PartialEq)]
struct Element {
    name: String,
    count: usize,
    columns: Vec<Column>,
}

/// A PLY file read for baking: its one mesh, and the whole file to write it back.
pub struct PlyAsset {
    meshes: Vec<AssetMesh>,
    header: PlyHeader,
    elements: Vec<Element>,
}

impl PlyAsset {
    /// [`PlyAsset::read_with`] within the read budget of [`LoadOptions::from_env`].
    #[cfg(test)]
    pub fn read(path: &Path) -> Result<PlyAsset> {
        PlyAsset::read_with(path, &LoadOptions::from_env()?)
    }

    /// Reads `path` (`.ply` or `.ply.gz`, any of the three encodings) for baking: the
    /// file's data and its columns must fit in the read budget of `options`.
    pub fn read_with(path: &Path, options: &LoadOptions) -> Result<PlyAsset> {
        PlyAsset::read_in(path, options, true)
    }

    /// [`PlyAsset::read_with`], binary data through the bulk runs and ascii numbers through
    /// the fast parsers where `bulk` is set, else one element and one `str::parse` at a
    /// time (the reference they are compared with).
    fn read_in(path: &Path, options: &LoadOptions, bulk: bool) -> Result<PlyAsset> {
        let mut meter = Meter::new(&options.limits, "the mesh");
        let mut input = Input::open(path, &options.limits)?;
        let header = read_header(path, &mut input)?;
        check_header(path, &header)?;
        let elements = match header.encoding {
            Encoding::Ascii => {
                read_ascii(path, &header.elements, &input.read_all(path, &mut meter)?, &mut meter, bulk)?
            }
            encoding => {
                let big_endian = encoding == Encoding::BinaryBigEndian;
                let mut data = if bulk && input.is_plain_file() {
                    Window::blocks(path, &mut input, &mut meter)?
                } else if bulk && input.is_gzip() {
                    Window::stream(&mut input, &meter)
                } else {
                    Window::whole(input.read_all(path, &mut meter)?)
                };
                read_binary(path, &header.elements, &mut data, big_endian, &mut meter, bulk)?
            }
        };
        let label = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        let mesh = mesh(path, &header, &elements, label)?;
        let mut elements = elements;
        let face = header.element("face").ok_or_else(|| Error::scene(path, "no face element"))?;
        hand_to_mesh(&mut elements, &mesh, &index_list_name(path, face)?);
        Ok(PlyAsset { meshes: vec![mesh], header, elements })
    }

    /// [`PlyAsset::read_with`] one element and one `str::parse` at a time: the reference
    /// the binary runs and fast ascii parsers are compared with.
    #[cfg(feature = "testing")]
    pub fn read_reference(path: &Path, options: &LoadOptions) -> Result<PlyAsset> {
        PlyAsset::read_in(path, options, false)
    }

    /// Everything read from `path` for a bake, as bytes to compare (every element's
    /// columns, in their own types and little-endian, and the mesh, as bits): through the
    /// binary runs and fast ascii parsers where `bulk` is set, else one element and one
    /// `str::parse` at a time, their reference.
    #[cfg(feature = "testing")]
    pub fn read_bits(path: &Path, options: &LoadOptions, bulk: bool) -> Result<Vec<u8>> {
        let asset = PlyAsset::read_in(path, options, bulk)?;
        let mut out = Vec::new();
        let words = |out: &mut Vec<u8>, words: &mut dyn Iterator<Item = u32>| {
            words.for_each(|w| out.extend_from_slice(&w.to_le_bytes()))
        };
        for element in &asset.elements {
            out.extend_from_slice(format!("{} {}\n", element.name, element.count).as_bytes());
            for column in &element.columns {
                out.extend_from_slice(column.header_line().as_bytes());
                if let Some((_, starts)) = &column.list {
                    starts.iter().for_each(|s| out.extend_from_slice(&(s as u64).to_le_bytes()));
                }
                (0..column.len(&asset.meshes[0])).for_each(|i| column.put_le(i, &asset.meshes[0], &mut out));
            }
        }
        let mesh = &asset.meshes[0];
        let vec3 = |v: &Vec3| v.to_array().map(f32::to_bits);
        words(&mut out, &mut mesh.positions.iter().flat_map(vec3));
        words(&mut out, &mut mesh.normals.iter().flatten().flat_map(vec3));
        words(&mut out, &mut mesh.face_starts.iter().chain(&mesh.face_indices).copied());
        for set in &mesh.uv_sets {
            words(&mut out, &mut set.corners.iter().flat_map(|c| c.to_array().map(f32::to_bits)));
        }
        Ok(out)
    }

    /// The mesh the scene loader reads from the file: its faces as fans, vertices
    /// numbered from 0, the header's warnings.
    pub(crate) fn scene_mesh(&self) -> IndexedMesh {
        let warnings = self.header.warnings.clone();
        super::asset::fan_mesh(&self.meshes[0], VertexNames::FromZero, warnings)
    }
}

/// What the mesh needs of the header, checked as the scene loader checks it, and every
/// list's count an integer type.
fn check_header(path: &Path, header: &PlyHeader) -> Result<()> {
    let vertex = header.element("vertex").ok_or_else(|| Error::scene(path, "no vertex element"))?;
    for axis in ["x", "y", "z"] {
        match vertex.properties.get(axis).map(|p| &p.data_type) {
            Some(PropertyType::Scalar(_)) => {}
            Some(t) => return Err(Error::scene(path, format!("vertex property {axis} must be a number, not {t:?}"))),
            None => return Err(Error::scene(path, format!("the vertex element has no {axis} property"))),
        }
    }
    let face = header.element("face").ok_or_else(|| Error::scene(path, "no face element"))?;
    index_list_name(path, face)?;
    for element in &header.elements {
        for (name, p) in &element.properties {
            if let PropertyType::List(ScalarType::Float | ScalarType::Double, _) = p.data_type {
                let message = format!("{} property {name}: a list's count must have an integer type", element.name);
                return Err(Error::scene(path, message));
            }
        }
    }
    Ok(())
}

/// Empty columns for `def`'s properties, with room for `capacity` elements.
fn columns(def: &ElementDef, capacity: usize) -> Vec<Column> {
    columns_with(def, capacity, capacity)
}

/// [`columns`], with room for `list_items` items in each list.
fn columns_with(def: &ElementDef, capacity: usize, list_items: usize) -> Vec<Column> {
    def.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => {
                Column { name: p.name.clone(), list: None, values: Values::new(t, capacity), held: Held::Own }
            }
            PropertyType::List(count, item) => {
                let starts = Starts::with_room(capacity + 1);
                Column {
                    name: p.name.clone(),
                    list: Some((count.clone(), starts)),
                    values: Values::new(item, list_items),
                    held: Held::Own,
                }
            }
        })
        .collect()
}

/// How many elements of `def` to reserve room for: its count, but no more than
/// `remaining` bytes could hold at `min_bytes` each.
fn capacity(def: &ElementDef, remaining: usize, min_bytes: usize) -> usize {
    def.count.min(remaining / min_bytes.max(1))
}

fn end_of_file(path: &Path, def: &ElementDef, i: usize) -> Error {
    Error::scene(path, format!("unexpected end of file in {} {i} of {}", def.name, def.count))
}

/// The bytes the columns of `elements` (read) and `columns` (being read) hold.
fn columns_bytes(elements: &[Element], columns: &[Column]) -> u64 {
    elements.iter().flat_map(|e| &e.columns).chain(columns).map(Column::bytes).sum()
}

/// Reads the data of a binary file; the columns, as they grow, are charged to `meter` (on
/// top of what it holds already: the data). With `bulk`, runs of elements of the same
/// shape are taken a column at a time ([`binary_run`]); every other element, and all of
/// them without it, one at a time ([`read_binary_element`]): the reference the runs are
/// compared with. Both charge the same bytes before each element, so they fail alike.
fn read_binary(
    path: &Path,
    defs: &[ElementDef],
    data: &mut Window,
    big_endian: bool,
    meter: &mut Meter,
    bulk: bool,
) -> Result<Vec<Element>> {
    let base = meter.used();
    let mut elements = Vec::with_capacity(defs.len());
    for def in defs {
        let min_bytes: usize = def
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(t) | PropertyType::List(t, _) => scalar_bytes(t),
            })
            .sum();
        // A list's items are reserved by its first element (`read_binary_element`).
        let mut columns = columns_with(def, capacity(def, data.remaining(), min_bytes), 0);
        // Elements without properties take no bytes.
        let count = if columns.is_empty() { 0 } else { def.count };
        let mut i = 0;
        while i < count {
            if bulk {
                data.fill(path, READ_BLOCK_BYTES / 2)?;
            }
            // What the columns hold changes only when one grows, which a run never does:
            // one charge before a run is the charge before each of its elements.
            meter.hold(path, base + data.arrived() + columns_bytes(&elements, &columns))?;
            let mut pos = 0;
            let taken = if bulk { binary_run(&mut columns, data.rest(), &mut pos, count - i, big_endian) } else { 0 };
            if taken == 0 {
                data.fill_element(path, def, i, &columns, big_endian)?;
                let unread = data.unread();
                read_binary_element(path, def, i, &mut columns, data.rest(), unread, &mut pos, big_endian)?;
                i += 1;
            }
            data.take(pos);
            i += taken;
        }
        elements.push(Element { name: def.name.clone(), count: def.count, columns });
    }
    data.fill(path, 1)?;
    if !data.rest().is_empty() {
        return Err(extra_data(path, data.position()));
    }
    Ok(elements)
}

/// Bytes of a binary file read at a time into a [`Window`]: large enough that a read
/// costs little next to decoding it, small enough to stay in the CPU's caches.
const READ_BLOCK_BYTES: usize = 1 << 20;

/// The data of a binary file, as [`read_binary`] takes it: all of it in memory, or a
/// file read a block at a time into a buffer that is reused, so that the file is neither
/// copied whole nor faulted into new memory (the columns are what the read keeps). The
/// blocks are charged as if the whole file were held, as the whole read charges it: a
/// plain file's length before the read, a gzipped file's bytes as they arrive (its length
/// is not known before).
struct Window<'a> {
    /// Where the rest of the data comes from; `None` when `buf` holds all of it.
    input: Option<&'a mut Input>,
    buf: Vec<u8>,
    /// The bytes not taken yet: `buf[start..end]`.
    start: usize,
    end: usize,
    /// Bytes of the data before `buf[0]`.
    base: usize,
    /// Bytes the input has yet to deliver, as its length tells; `None` for a stream whose
    /// length is not known (gzipped), which nothing is sized by before it arrives.
    unread: Option<usize>,
    /// For a stream: the most bytes the budget holds, and the message of a read past it.
    budget: Option<(u64, String)>,
}

impl<'a> Window<'a> {
    /// All the data, read.
    fn whole(data: Vec<u8>) -> Window<'a> {
        let end = data.len();
        Window { input: None, buf: data, start: 0, end, base: 0, unread: Some(0), budget: None }
    }

    /// The rest of `input` (a plain regular file within the input cap, see
    /// [`Input::is_plain_file`]), read as it is taken; its length is charged to `meter`
    /// first, as [`Input::read_all`] charges it.
    fn blocks(path: &Path, input: &'a mut Input, meter: &mut Meter) -> Result<Window<'a>> {
        let len = input.remaining_bound();
        if len > 0 {
            meter.charge(path, len)?;
        }
        let unread = usize::try_from(len).unwrap_or(usize::MAX);
        let buf = vec![0; READ_BLOCK_BYTES.min(unread)];
        Ok(Window { input: Some(input), buf, start: 0, end: 0, base: 0, unread: Some(unread), budget: None })
    }

    /// The rest of `input`, of a length not known before it is read (a gzipped file),
    /// read as it is taken: memory is taken for what has arrived, never for what a
    /// header says will come. Data past what `meter` has left is refused as the whole
    /// read refuses it, with the meter's message.
    fn stream(input: &'a mut Input, meter: &Meter) -> Window<'a> {
        let budget = Some((meter.left(), meter.exceeded_message()));
        Window { input: Some(input), buf: vec![0; READ_BLOCK_BYTES], start: 0, end: 0, base: 0, unread: None, budget }
    }

    /// Bytes read from a stream so far, to be charged as if held; 0 for the other kinds,
    /// charged before the read.
    fn arrived(&self) -> u64 {
        match self.unread {
            None => (self.base + self.end) as u64,
            Some(_) => 0,
        }
    }

    /// Bytes known to follow those at hand: `None` for a stream.
    fn unread(&self) -> Option<usize> {
        self.unread.map(|unread| if self.input.is_some() { unread } else { 0 })
    }

    /// The data not taken yet that is at hand.
    fn rest(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// Takes the first `n` bytes of [`Window::rest`].
    fn take(&mut self, n: usize) {
        self.start += n;
    }

    /// The offset in the data of the first byte not taken.
    fn position(&self) -> usize {
        self.base + self.start
    }

    /// The bytes of data not taken yet, at hand or still to read (at hand alone for a
    /// stream).
    fn remaining(&self) -> usize {
        (self.end - self.start).saturating_add(self.unread().unwrap_or(0))
    }

    /// Reads more of the input when fewer than `want` bytes are at hand: as much as the
    /// buffer holds (at least `want`, the buffer growing where it must), or to the end.
    fn fill(&mut self, path: &Path, want: usize) -> Result<()> {
        let Some(input) = self.input.as_deref_mut() else {
            return Ok(());
        };
        let held = self.end - self.start;
        if held >= want {
            return Ok(());
        }
        self.buf.copy_within(self.start..self.end, 0);
        self.base += self.start;
        (self.start, self.end) = (0, held);
        if want > self.buf.len() {
            // No more than the file holds: a lying count cannot make it grow further. A
            // stream's buffer at most doubles, so that it holds no more than twice what
            // has arrived.
            let most = match self.unread {
                Some(unread) => held.saturating_add(unread),
                None => self.buf.len().saturating_mul(2),
            };
            let grow = want.min(most).max(self.buf.len());
            self.buf.resize(grow, 0);
        }
        // A stream stops one byte past the budget, where the whole read fails on it.
        let to = match &self.budget {
            Some((most, _)) => {
                let past = usize::try_from(most.saturating_add(1)).unwrap_or(usize::MAX);
                self.buf.len().min(past.saturating_sub(self.base))
            }
            None => self.buf.len(),
        };
        while self.end < to {
            match input.read(&mut self.buf[self.end..to]) {
                Ok(0) => {
                    self.input = None;
                    break;
                }
                Ok(n) => {
                    self.end += n;
                    self.unread = self.unread.map(|unread| unread.saturating_sub(n));
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(Error::scene(path, input.stream_error().map_or_else(|| e.to_string(), str::to_string)));
                }
            }
        }
        match &self.budget {
            Some((most, refusal)) if self.arrived() > *most => Err(Error::scene(path, refusal.clone())),
            _ => Ok(()),
        }
    }

    /// Reads until element `i` of `def` (of `columns`' shape) is at hand whole, or fails
    /// as [`read_binary_element`] would on all the data where the data ends inside it.
    fn fill_element(
        &mut self,
        path: &Path,
        def: &ElementDef,
        i: usize,
        columns: &[Column],
        big_endian: bool,
    ) -> Result<()> {
        while self.input.is_some() {
            let Err(need) = element_bytes(columns, self.rest(), big_endian) else {
                break;
            };
            if self.unread.is_some() && need > self.remaining() {
                return Err(end_of_file(path, def, i));
            }
            self.fill(path, need)?;
        }
        Ok(())
    }
}

/// The bytes of the binary element of `columns`' shape at the start of `bytes`: `Ok` with
/// its length where they hold it whole, or with 0 where a list count is negative (which
/// [`read_binary_element`] reports); `Err` with the bytes it takes at least, where they
/// fall short.
fn element_bytes(columns: &[Column], bytes: &[u8], big_endian: bool) -> std::result::Result<usize, usize> {
    let mut at = 0usize;
    for column in columns {
        let size = scalar_bytes(&column.values.scalar_type());
        let Some((count_type, _)) = &column.list else {
            at = at.saturating_add(size);
            continue;
        };
        let t = Ty::of(count_type);
        let end = at.saturating_add(t.size());
        let Some(n) = bytes.get(at..).and_then(|b| count_at(b, t, big_endian)) else {
            return Err(end);
        };
        let Ok(n) = usize::try_from(n) else {
            return Ok(0);
        };
        at = end.saturating_add(n.saturating_mul(size));
    }
    if bytes.len() < at { Err(at) } else { Ok(at) }
}

/// Reads element `i` of `def` at `data[*pos..]` onto `columns`, one value at a time;
/// `unread` more bytes of data follow `data` (`None`: a stream, of which `data` holds the
/// element whole or all that is left). A list that outgrows its column makes room for the
/// elements left; in a stream, a column grows by at least what it holds, so that it is
/// copied a few times in all.
#[allow(clippy::too_many_arguments)]
fn read_binary_element(
    path: &Path,
    def: &ElementDef,
    i: usize,
    columns: &mut [Column],
    data: &[u8],
    unread: Option<usize>,
    pos: &mut usize,
    big_endian: bool,
) -> Result<()> {
    for column in columns {
        let Some((count_type, starts)) = &mut column.list else {
            if unread.is_none() && column.values.spare() == 0 {
                let len = column.values.len();
                column.values.reserve(len.max(4096).min(def.count.saturating_sub(i)).max(1));
            }
            column.values.push_binary(data, pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
            continue;
        };
        let mut n = Values::new(count_type, 1);
        n.push_binary(data, pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
        let n = n.integer(0).unwrap_or(0);
        let item_bytes = scalar_bytes(&column.values.scalar_type());
        let left = (data.len() - *pos).saturating_add(unread.unwrap_or(0));
        let Some(n) = usize::try_from(n).ok().filter(|n| n.saturating_mul(item_bytes) <= left) else {
            return Err(if n < 0 {
                let message = format!("{} {i} of {}: list {} has {n} items", def.name, def.count, column.name);
                Error::scene(path, message)
            } else {
                end_of_file(path, def, i)
            });
        };
        if column.values.spare() < n {
            // Room for the elements left at this one's length, as far as the data left
            // could hold them: the items of most files' lists in one allocation.
            let most = match unread {
                Some(_) => left / item_bytes,
                None => (left / item_bytes).max(column.values.len()),
            };
            column.values.reserve(def.count.saturating_sub(i).saturating_mul(n).min(most).max(n));
        }
        for _ in 0..n {
            column.values.push_binary(data, pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
        }
        starts.push(column.values.len());
    }
    Ok(())
}

/// A binary list count of integer type `t` at the start of `bytes`; `None` when `bytes`
/// is too short.
#[inline(always)]
fn count_at(bytes: &[u8], t: Ty, big_endian: bool) -> Option<i64> {
    (bytes.len() >= t.size()).then(|| t.i64_at(bytes, big_endian))
}

/// Takes the whole elements at `data[*pos..]`, at most `most`, while each has the list
/// lengths of the first and no column must grow to hold them (so that what the columns
/// hold is what was charged before them); each column is filled in one pass over the
/// elements, the byte order converted as each value is taken. The number of elements
/// taken: none where the first is cut off or has a negative list length, which the
/// element-at-a-time reader then reports.
fn binary_run(columns: &mut [Column], data: &[u8], pos: &mut usize, most: usize, big_endian: bool) -> usize {
    let rest = &data[*pos..];
    // Each column's byte offset and item count in the first element, and each list's
    // count: its offset, type and value.
    let mut shape = Vec::with_capacity(columns.len());
    let mut lists = Vec::new();
    let mut at = 0usize;
    for column in columns.iter() {
        let size = scalar_bytes(&column.values.scalar_type());
        let Some((count_type, _)) = &column.list else {
            shape.push((at, 1));
            at += size;
            continue;
        };
        let count_type = Ty::of(count_type);
        let Some(n) = rest.get(at..).and_then(|b| count_at(b, count_type, big_endian)) else {
            return 0;
        };
        let Ok(n) = usize::try_from(n) else {
            return 0;
        };
        lists.push((at, count_type, n as i64));
        at += count_type.size();
        shape.push((at, n));
        at = at.saturating_add(n.saturating_mul(size));
    }
    let stride = at;
    if stride == 0 || stride > rest.len() {
        return 0;
    }
    let mut n = most.min(rest.len() / stride);
    for (column, &(_, items)) in columns.iter().zip(&shape) {
        n = n.min(column.values.spare().checked_div(items).unwrap_or(usize::MAX));
        if let Some((_, starts)) = &column.list {
            n = n.min(starts.room_for(items));
        }
    }
    if !lists.is_empty() {
        let same = |e: &[u8]| lists.iter().all(|&(offset, t, n)| count_at(&e[offset..], t, big_endian) == Some(n));
        n = rest[..n * stride].chunks_exact(stride).position(|e| !same(e)).unwrap_or(n);
    }
    if n == 0 {
        return 0;
    }
    let block = &rest[..n * stride];
    for (column, &(offset, items)) in columns.iter_mut().zip(&shape) {
        column.values.extend_from_elements(block, stride, offset, items, big_endian);
        if let Some((_, starts)) = &mut column.list {
            starts.extend(n, items);
        }
    }
    *pos += n * stride;
    n
}

fn extra_data(path: &Path, at: usize) -> Error {
    Error::scene(
        path,
        format!(
            "data after the last element at byte {at} of the data: the header's element counts do not match the file"
        ),
    )
}

/// A number as ply-rs's ascii grammar takes it: `[-+]?[0-9]+(\.[0-9]+)?([eE][-+]?[0-9]+)?`.
fn is_number(token: &[u8]) -> bool {
    fn digits(t: &[u8], mut i: usize) -> usize {
        while t.get(i).is_some_and(u8::is_ascii_digit) {
            i += 1;
        }
        i
    }
    let mut i = usize::from(matches!(token.first(), Some(b'-' | b'+')));
    let start = i;
    i = digits(token, i);
    if i == start {
        return false;
    }
    if token.get(i) == Some(&b'.') {
        let end = digits(token, i + 1);
        if end == i + 1 {
            return false;
        }
        i = end;
    }
    if matches!(token.get(i), Some(b'e' | b'E')) {
        i += 1 + usize::from(matches!(token.get(i + 1), Some(b'-' | b'+')));
        let end = digits(token, i);
        if end == i {
            return false;
        }
        i = end;
    }
    i == token.len()
}

/// Bytes of ASCII lines one rayon task parses at a time: large enough that a task's
/// work dwarfs handing it out, small enough that a round of them holds little.
const ASCII_BLOCK_BYTES: usize = 1 << 20;

/// Reads the data of an ascii file: one line per element, as ply-rs reads it (values
/// beyond the element's properties are ignored, as it ignores them). The lines are
/// parsed in blocks on rayon's threads, a round of one block per thread at a time, and
/// taken in order: an error is the first line's in the file, as a line-at-a-time read
/// reports it, and what the columns hold is charged to `meter` after each block.
fn read_ascii(path: &Path, defs: &[ElementDef], data: &[u8], meter: &mut Meter, fast: bool) -> Result<Vec<Element>> {
    use rayon::prelude::*;
    let base = meter.used();
    let longest = meter.limits().line_bytes();
    let threads = rayon::current_num_threads().max(1);
    let mut rest = data;
    let mut elements = Vec::with_capacity(defs.len());
    for def in defs {
        // Every value takes at least a digit and a separator.
        let min_bytes = 2 * def.properties.len();
        let mut columns = columns(def, capacity(def, rest.len(), min_bytes));
        let mut i = 0;
        while i < def.count {
            if rest.is_empty() {
                return Err(end_of_file(path, def, i));
            }
            meter.hold(path, base + columns_bytes(&elements, &columns))?;
            // A round: up to one block of whole lines per thread, each block (its first
            // element's number, its lines).
            let mut blocks: Vec<(usize, Vec<&[u8]>)> = Vec::with_capacity(threads);
            while blocks.len() < threads && i < def.count && !rest.is_empty() {
                let (first, mut bytes, mut lines) = (i, 0, Vec::new());
                while bytes < ASCII_BLOCK_BYTES && i < def.count && !rest.is_empty() {
                    let end = memchr::memchr(b'\n', rest).map_or(rest.len(), |e| e + 1);
                    let (line, next) = rest.split_at(end);
                    rest = next;
                    bytes += line.len();
                    let line = line.strip_suffix(b"\n").unwrap_or(line);
                    lines.push(line.strip_suffix(b"\r").unwrap_or(line));
                    i += 1;
                }
                blocks.push((first, lines));
            }
            let parsed: Vec<Result<Vec<Column>>> = blocks
                .par_iter()
                .map(|(first, lines)| {
                    let mut block = columns_like(&columns, lines.len());
                    let mut tokens = Vec::new();
                    for (k, line) in lines.iter().enumerate() {
                        let i = first + k;
                        let at = |message: AsciiLineError| {
                            Error::scene(path, format!("{} {i} of {}: {message}", def.name, def.count))
                        };
                        read_ascii_line(line, longest, &mut block, &mut tokens, fast).map_err(at)?;
                    }
                    Ok(block)
                })
                .collect();
            for block in parsed {
                append_columns(&mut columns, block?);
                meter.hold(path, base + columns_bytes(&elements, &columns))?;
            }
        }
        elements.push(Element { name: def.name.clone(), count: def.count, columns });
    }
    if let Some(at) = rest.iter().position(|b| !b.is_ascii_whitespace()) {
        return Err(extra_data(path, data.len() - rest.len() + at));
    }
    Ok(elements)
}

/// What is wrong with one ascii element's line.
#[derive(Debug, thiserror::Error)]
enum AsciiLineError {
    #[error("its line is longer than {0}, the longest line a text file may have")]
    TooLong(String),
    #[error("'{0}' is not a number")]
    NotANumber(String),
    #[error("fewer values than its properties need")]
    Short,
    #[error("list {column}: '{count}' is not a count")]
    NotACount { column: String, count: String },
    #[error(transparent)]
    Token(#[from] TokenError),
}

/// Parses one ascii element's `line` (at most `longest` bytes) onto `columns`, the values
/// by the fast parsers where `fast` is set (see [`Values::push_token`]); `tokens` is
/// scratch.
fn read_ascii_line<'l>(
    line: &'l [u8],
    longest: usize,
    columns: &mut [Column],
    tokens: &mut Vec<&'l str>,
    fast: bool,
) -> std::result::Result<(), AsciiLineError> {
    if line.len() > longest {
        return Err(AsciiLineError::TooLong(crate::scene::input::size_text(longest as u64)));
    }
    tokens.clear();
    for token in line.split(|&b| b == b' ' || b == b'\t').filter(|t| !t.is_empty()) {
        if !is_number(token) {
            let text = String::from_utf8_lossy(token);
            return Err(AsciiLineError::NotANumber(crate::scene::input::one_line(&text)));
        }
        // A number is ascii.
        tokens.push(std::str::from_utf8(token).unwrap_or_default());
    }
    let mut next_token = tokens.iter();
    let mut take = || next_token.next().ok_or(AsciiLineError::Short);
    for column in columns {
        let Some((_, starts)) = &mut column.list else {
            column.values.push_token(take()?, fast)?;
            continue;
        };
        let n = take()?;
        let n: usize =
            n.parse().map_err(|_| AsciiLineError::NotACount { column: column.name.clone(), count: n.to_string() })?;
        for _ in 0..n {
            column.values.push_token(take()?, fast)?;
        }
        starts.push(column.values.len());
    }
    Ok(())
}

/// Empty columns of the names and types of `columns`, with room for `capacity` elements.
fn columns_like(columns: &[Column], capacity: usize) -> Vec<Column> {
    let like = |c: &Column| Column {
        name: c.name.clone(),
        list: c.list.as_ref().map(|(count, _)| (count.clone(), Starts::with_room(1))),
        values: Values::new(&c.values.scalar_type(), capacity),
        held: Held::Own,
    };
    columns.iter().map(like).collect()
}

/// Appends the elements of `block` (columns made by [`columns_like`] of `columns`) to
/// `columns`.
fn append_columns(columns: &mut [Column], block: Vec<Column>) {
    for (column, part) in columns.iter_mut().zip(block) {
        let offset = column.values.len();
        if let (Some((_, starts)), Some((_, more))) = (&mut column.list, &part.list) {
            more.iter().skip(1).for_each(|s| starts.push(s + offset));
        }
        column.values.append(part.values);
    }
}

/// The column named `name` of `element`.
fn column<'a>(element: &'a Element, name: &str) -> Option<&'a Column> {
    element.columns.iter().find(|c| c.name == name)
}

/// The scalar columns named `names`, when all exist.
fn scalar_columns<'a, const N: usize>(element: &'a Element, names: [&str; N]) -> Option<[&'a Column; N]> {
    let mut found = [None; N];
    for (slot, name) in found.iter_mut().zip(names) {
        *slot = Some(column(element, name).filter(|c| c.list.is_none())?);
    }
    Some(found.map(|c| c.expect("every slot was filled")))
}

/// Empties the columns whose values `mesh` holds with the same bits, so that a file's
/// positions and corners are held once, by the mesh, and written back from it: a `float`
/// x, y or z, and an `int` or `uint` vertex index list (`index_list`). Each is compared
/// with the mesh first, and kept where it differs.
fn hand_to_mesh(elements: &mut [Element], mesh: &AssetMesh, index_list: &str) {
    for element in elements.iter_mut() {
        for column in &mut element.columns {
            let held = match (element.name.as_str(), column.name.as_str(), &column.values, &column.list) {
                ("vertex", axis @ ("x" | "y" | "z"), Values::Float(v), None) => {
                    let k = ["x", "y", "z"].iter().position(|a| a == &axis).expect("one of the three");
                    let same = v.len() == mesh.positions.len()
                        && v.iter().zip(&mesh.positions).all(|(a, p)| a.to_bits() == p[k].to_bits());
                    same.then_some(Held::Axis(k))
                }
                ("face", name, Values::UInt(v), Some(_)) if name == index_list => {
                    (v[..] == mesh.face_indices[..]).then_some(Held::Corners)
                }
                ("face", name, Values::Int(v), Some(_)) if name == index_list => {
                    let same = v.len() == mesh.face_indices.len()
                        && v.iter().zip(&mesh.face_indices).all(|(&a, &b)| a as u32 == b && a >= 0);
                    same.then_some(Held::Corners)
                }
                _ => None,
            };
            if let Some(held) = held {
                column.values = Values::new(&column.values.scalar_type(), 0);
                column.held = held;
            }
        }
    }
}

/// The mesh of the file: positions and faces checked as the scene loader checks them.
fn mesh(path: &Path, header: &PlyHeader, elements: &[Element], label: String) -> Result<AssetMesh> {
    let find = |name: &str| elements.iter().find(|e| e.name == name);
    let (Some(vertex), Some(face)) = (find("vertex"), find("face")) else {
        return Err(Error::scene(path, "no vertex or no face element"));
    };
    let xyz = scalar_columns(vertex, ["x", "y", "z"]).ok_or_else(|| Error::scene(path, "no x, y or z"))?;
    let positions = match xyz.map(|c| &c.values) {
        [Values::Float(x), Values::Float(y), Values::Float(z)] => float_positions(path, x, y, z)?,
        _ => positions(path, vertex.count, |i| Vec3::from(xyz.map(|c| c.values.f32(i))))?,
    };
    let normals = scalar_columns(vertex, ["nx", "ny", "nz"]).map(|n| match n.map(|c| &c.values) {
        [Values::Float(x), Values::Float(y), Values::Float(z)] => {
            (0..vertex.count).map(|i| Vec3::new(x[i], y[i], z[i])).collect()
        }
        _ => (0..vertex.count).map(|i| Vec3::from(n.map(|c| c.values.f32(i)))).collect(),
    });

    let face_def = header.element("face").ok_or_else(|| Error::scene(path, "no face element"))?;
    let list = column(face, &index_list_name(path, face_def)?).ok_or_else(|| Error::scene(path, "no face list"))?;
    let scalar_starts: Starts;
    let starts = match &list.list {
        Some((_, starts)) => starts,
        None => {
            scalar_starts = Starts::Uniform { items: Some(1), len: face.count + 1, room: 0 };
            &scalar_starts
        }
    };
    let n = vertex.count;
    let (face_starts, face_indices) = match &list.values {
        Values::Char(v) => corners(path, starts, v, n, i64::from),
        Values::UChar(v) => corners(path, starts, v, n, i64::from),
        Values::Short(v) => corners(path, starts, v, n, i64::from),
        Values::UShort(v) => corners(path, starts, v, n, i64::from),
        Values::Int(v) => corners(path, starts, v, n, i64::from),
        Values::UInt(v) => corners(path, starts, v, n, i64::from),
        // Not an index.
        Values::Float(v) => corners(path, starts, v, n, |_| -1),
        Values::Double(v) => corners(path, starts, v, n, |_| -1),
    }?;
    // Per-corner texture coordinates (MeshLab's face `texcoord` list, u v per corner), else
    // per-vertex ones under the names the common writers use.
    let wedge = column(face, "texcoord").filter(|c| c.list.is_some()).map(|c| {
        let mut corners = Vec::with_capacity(face_indices.len());
        for f in 0..face.count {
            let n = (face_starts[f + 1] - face_starts[f]) as usize;
            let items: Vec<usize> = c.items(f).collect();
            for k in 0..n {
                corners.push(match (items.get(2 * k), items.get(2 * k + 1)) {
                    (Some(&a), Some(&b)) if items.len() == 2 * n => glam::Vec2::new(c.values.f32(a), c.values.f32(b)),
                    _ => glam::Vec2::NAN,
                });
            }
        }
        vec![UvSet { set: 0, corners }]
    });
    let uv_sets = wedge
        .or_else(|| {
            [["s", "t"], ["u", "v"], ["texture_u", "texture_v"], ["texture_s", "texture_t"]]
                .into_iter()
                .find_map(|names| scalar_columns(vertex, names))
                .map(|[u, v]| {
                    let corners = face_indices
                        .iter()
                        .map(|&i| glam::Vec2::new(u.values.f32(i as usize), v.values.f32(i as usize)));
                    vec![UvSet { set: 0, corners: corners.collect() }]
                })
        })
        .unwrap_or_default();
    Ok(AssetMesh {
        label,
        positions,
        normals,
        face_starts,
        face_indices,
        to_file: glam::Mat3::IDENTITY,
        uv_sets,
        uv_v_down: false,
        material: None,
        repeating_sets: Vec::new(),
    })
}

/// The positions of `float` columns, checked to be finite in one pass over the columns
/// first; the first non-finite one is reported by [`positions`].
fn float_positions(path: &Path, x: &[f32], y: &[f32], z: &[f32]) -> Result<Vec<Vec3>> {
    let count = x.len().min(y.len()).min(z.len());
    let (x, y, z) = (&x[..count], &y[..count], &z[..count]);
    // Branch-free, so that it vectorises: a value is finite when its exponent is not all ones.
    let finite = |v: &[f32]| v.iter().fold(true, |all, c| all & c.is_finite());
    if !(finite(x) & finite(y) & finite(z)) {
        return positions(path, count, |i| Vec3::new(x[i], y[i], z[i]));
    }
    let mut positions = huge_vec(count);
    positions.extend(x.iter().zip(y).zip(z).map(|((&x, &y), &z)| Vec3::new(x, y, z)));
    Ok(positions)
}

/// The positions `at(0..count)`, each checked to be finite.
fn positions(path: &Path, count: usize, at: impl Fn(usize) -> Vec3) -> Result<Vec<Vec3>> {
    let mut positions = Vec::with_capacity(count);
    for i in 0..count {
        let p = at(i);
        if !p.is_finite()
            && let Some(c) = non_finite_coordinate(p)
        {
            return Err(Error::scene(path, format!("vertex {i} has a non-finite coordinate ({c})")));
        }
        positions.push(p);
    }
    Ok(positions)
}

/// The faces of an index list (face `i`'s indices `values[starts[i]..starts[i + 1]]`, each
/// as `index` reads it), checked as the scene loader checks them: at least 3 corners,
/// each naming one of the `vertex_count` vertices. The faces' starts and their corners.
fn corners<T: Copy>(
    path: &Path,
    starts: &Starts,
    values: &[T],
    vertex_count: usize,
    index: impl Fn(T) -> i64,
) -> Result<(Vec<u32>, Vec<u32>)> {
    if let Some(faces) = valid_corners(starts, values, vertex_count, &index) {
        return Ok(faces);
    }
    let starts: Vec<usize> = starts.iter().collect();
    let faces = starts.len() - 1;
    let mut face_starts = Vec::with_capacity(faces + 1);
    let mut face_indices = Vec::with_capacity(values.len());
    face_starts.push(0);
    for (i, items) in starts.windows(2).enumerate() {
        let items = &values[items[0]..items[1]];
        if items.len() < 3 {
            let n = items.len();
            return Err(Error::scene(path, format!("face {i} has {n} vertices; a face needs at least 3")));
        }
        for &item in items {
            let v = index(item);
            let Some(v) = usize::try_from(v).ok().filter(|&v| v < vertex_count).and_then(|v| u32::try_from(v).ok())
            else {
                let message =
                    format!("face {i}: vertex index {v} is out of range (the file has {vertex_count} vertices)");
                return Err(Error::scene(path, message));
            };
            face_indices.push(v);
        }
        let end = u32::try_from(face_indices.len())
            .map_err(|_| Error::scene(path, "more than 4294967295 face corners: too many for a mesh"))?;
        face_starts.push(end);
    }
    Ok((face_starts, face_indices))
}

/// [`corners`] where every face is valid, checked a column at a time (passes without
/// branches, which vectorise) before the faces are built; `None` where one is not, for
/// [`corners`] to find and report it.
fn valid_corners<T: Copy>(
    starts: &Starts,
    values: &[T],
    vertex_count: usize,
    index: impl Fn(T) -> i64,
) -> Option<(Vec<u32>, Vec<u32>)> {
    let corners = starts.last();
    let values = values.get(..corners)?;
    let bound = u64::try_from(vertex_count).ok()?.min(1 << 32);
    // A negative index, as `u64`, is beyond any bound.
    let in_range = values.iter().fold(true, |all, &v| all & ((index(v) as u64) < bound));
    let polygons = match starts {
        Starts::Uniform { items, .. } => items.is_none_or(|n| n >= 3),
        Starts::Explicit(v) => v.windows(2).fold(true, |all, w| all & (w[1].wrapping_sub(w[0]) >= 3)),
    };
    if !(in_range && polygons && u32::try_from(corners).is_ok()) {
        return None;
    }
    let (mut face_starts, mut face_indices) = (huge_vec(starts.len()), huge_vec(corners));
    face_indices.extend(values.iter().map(|&v| index(v) as u32));
    match starts {
        Starts::Uniform { items, len, .. } => {
            let n = items.unwrap_or(0) as u32;
            face_starts.extend((0..*len as u32).map(|k| k * n));
        }
        Starts::Explicit(v) => face_starts.extend(v.iter().map(|&s| s as u32)),
    }
    Some((face_starts, face_indices))
}

/// AO as a grey colour channel in type `t`: 0 to 1 for the floating-point types, 0 to 255
/// for the integers (saturated to the type's range).
fn grey(t: &ScalarType, ao: &[f32]) -> Values {
    let level = |a: f32| (255.0 * a.clamp(0.0, 1.0)).round();
    match t {
        ScalarType::Char => Values::Char(ao.iter().map(|&a| level(a) as i8).collect()),
        ScalarType::UChar => Values::UChar(ao.iter().map(|&a| level(a) as u8).collect()),
        ScalarType::Short => Values::Short(ao.iter().map(|&a| level(a) as i16).collect()),
        ScalarType::UShort => Values::UShort(ao.iter().map(|&a| level(a) as u16).collect()),
        ScalarType::Int => Values::Int(ao.iter().map(|&a| level(a) as i32).collect()),
        ScalarType::UInt => Values::UInt(ao.iter().map(|&a| level(a) as u32).collect()),
        ScalarType::Float => Values::Float(ao.iter().map(|&a| a.clamp(0.0, 1.0)).collect()),
        ScalarType::Double => Values::Double(ao.iter().map(|&a| f64::from(a.clamp(0.0, 1.0))).collect()),
    }
}

impl PlyAsset {
    /// The properties the bake adds to `element`, each replacing the element's own
    /// property of that name; with notes on those replaced.
    fn added_columns(
        &self,
        element: &Element,
        values: &BakedValues,
        options: &WriteOptions,
    ) -> std::result::Result<(Vec<Column>, Vec<String>), String> {
        let n = element.count;
        let check = |what: &str, len: usize| {
            if len == n { Ok(()) } else { Err(format!("{len} {what} values for the {n} elements '{}'", element.name)) }
        };
        check("AO", values.ao.len())?;
        let mut added = vec![Column::float("quality", values.ao.clone())];
        if options.std_error {
            check("standard error", values.std_error.len())?;
            added.push(Column::float("quality_std_error", values.std_error.clone()));
        }
        if let Some(bent) = &values.bent_normals {
            check("bent normal", bent.len())?;
            for (axis, name) in ["bnx", "bny", "bnz"].into_iter().enumerate() {
                added.push(Column::float(name, bent.iter().map(|b| b[axis]).collect()));
            }
        }
        let mut notes = Vec::new();
        let mut kept_colours = Vec::new();
        if options.colors {
            for name in ["red", "green", "blue"] {
                let own = column(element, name).filter(|c| c.list.is_none());
                let t = own.map_or(ScalarType::UChar, |c| c.values.scalar_type());
                if own.is_some() {
                    kept_colours.push(format!("{name} ({})", type_name(&t)));
                }
                added.push(Column {
                    name: name.to_string(),
                    list: None,
                    values: grey(&t, &values.ao),
                    held: Held::Own,
                });
            }
        }
        for a in &added {
            let Some(own) = column(element, &a.name) else { continue };
            if ["red", "green", "blue"].contains(&a.name.as_str()) && own.list.is_none() {
                continue;
            }
            let was = match &own.list {
                Some(_) => "a list".to_string(),
                None => format!("of type {}", type_name(&own.values.scalar_type())),
            };
            notes.push(format!(
                "the {} element's own '{}' property ({was}) was replaced by the bake's",
                element.name, a.name
            ));
        }
        if !kept_colours.is_empty() {
            notes.push(format!(
                "the {} element's own colour {} was overwritten with the AO as grey, its type kept",
                element.name,
                kept_colours.join(", ")
            ));
        }
        Ok((added, notes))
    }
}

impl Asset for PlyAsset {
    fn meshes(&self) -> &[AssetMesh] {
        &self.meshes
    }

    fn write(&self, path: &Path, values: &[BakedValues], options: &WriteOptions) -> Result<Vec<String>> {
        let [values] = values else {
            return Err(Error::output(path, format!("a PLY file has 1 mesh, but {} were baked", values.len())));
        };
        let target_name = match options.at {
            BakeAt::Vertices => "vertex",
            BakeAt::Faces => "face",
        };
        let Some(target) = self.elements.iter().position(|e| e.name == target_name) else {
            return Err(Error::output(path, format!("the file has no {target_name} element")));
        };
        let element = &self.elements[target];
        let (added, notes) = self.added_columns(element, values, options).map_err(|m| Error::output(path, m))?;
        self.write_added(path, target, &added, notes)
    }

    /// Writes the map beside the file (`STEM_ao.png`) and the file with the generated
    /// coordinates, when there are some, as MeshLab's face `texcoord` lists (u v per
    /// corner, the first convention the loader reads); else the file as it was.
    fn write_textures(&self, path: &Path, maps: &[TextureMap], uvs: Option<&GeneratedUvs>) -> Result<Vec<String>> {
        let uvs = uvs.and_then(|g| g.meshes.first());
        let Some(face) = self.elements.iter().position(|e| e.name == "face") else {
            return Err(Error::output(path, "the file has no face element"));
        };
        let mut added = Vec::new();
        if let Some(uvs) = uvs {
            if !self.meshes[0].uv_sets.is_empty() {
                return Err(Error::output(path, "the file has texture coordinates of its own: PLY holds one set"));
            }
            let mesh = &self.meshes[0];
            let starts: Vec<usize> = mesh.face_starts.iter().map(|&s| 2 * s as usize).collect();
            let values = uvs.corners.iter().flat_map(|&k| uvs.uvs[k as usize].to_array()).collect();
            added.push(Column {
                name: "texcoord".to_string(),
                list: Some((ScalarType::UChar, Starts::from(starts))),
                values: Values::Float(values),
                held: Held::Own,
            });
        }
        write_maps_beside(path, maps)?;
        self.write_added(path, face, &added, Vec::new())
    }
}

impl PlyAsset {
    /// Writes the file with the columns `added` on element `target`, each replacing the
    /// element's own property of its name in place, the others after its last property.
    fn write_added(&self, path: &Path, target: usize, added: &[Column], mut notes: Vec<String>) -> Result<Vec<String>> {
        let element = &self.elements[target];
        // The columns written, element by element: the bake's replace the file's own of
        // the same name in place; the others follow the element's last property.
        let mut plan: Vec<Vec<&Column>> = self.elements.iter().map(|e| e.columns.iter().collect()).collect();
        for a in added {
            match plan[target].iter().position(|c| c.name == a.name) {
                Some(i) => plan[target][i] = a,
                None => plan[target].push(a),
            }
        }
        let own_count = element.columns.len();

        let ascii = self.header.encoding == Encoding::Ascii;
        let mut head = Vec::new();
        head.extend_from_slice(b"ply\n");
        let property_line = |head: &mut Vec<u8>, c: &Column| {
            head.extend_from_slice(c.header_line().as_bytes());
            head.push(b'\n');
        };
        let target_last_line = self
            .header
            .lines
            .iter()
            .rposition(|l| matches!(l, HeaderLine::Element(e) | HeaderLine::Property(e, _) if *e == target));
        for (k, line) in self.header.lines.iter().enumerate() {
            match line {
                HeaderLine::Format => {
                    let encoding = if ascii { "ascii" } else { "binary_little_endian" };
                    let version = self.header.version;
                    let _ = writeln!(head, "format {encoding} {}.{}", version.major, version.minor);
                }
                HeaderLine::Text(text) => {
                    head.extend_from_slice(text);
                    head.push(b'\n');
                }
                HeaderLine::Unknown(number, text) => {
                    head.extend_from_slice(b"comment ");
                    head.extend_from_slice(text);
                    head.push(b'\n');
                    notes.push(format!("header line {number}, free text without 'comment', is written as a comment"));
                }
                HeaderLine::Element(e) => {
                    let _ = writeln!(head, "element {} {}", self.elements[*e].name, self.elements[*e].count);
                }
                HeaderLine::Property(e, p) => property_line(&mut head, plan[*e][*p]),
            }
            if Some(k) == target_last_line {
                for c in &plan[target][own_count..] {
                    property_line(&mut head, c);
                }
            }
        }
        head.extend_from_slice(b"end_header\n");

        let gzip = is_gzip_name(path);
        let (elements, mesh) = (&self.elements, &self.meshes[0]);
        let body = |out: &mut dyn Write| -> std::io::Result<()> {
            out.write_all(&head)?;
            for (element, columns) in elements.iter().zip(&plan) {
                let rows = if !ascii && columns.is_empty() { 0 } else { element.count };
                if ascii {
                    write_rows(out, rows, WRITE_BLOCK_ROWS, &|i, text| {
                        put_ascii_row(columns, mesh, i, text);
                        Ok(())
                    })?;
                } else {
                    write_rows(out, rows, WRITE_BLOCK_ROWS, &|i, text| put_binary_row(columns, mesh, i, text))?;
                }
            }
            Ok(())
        };
        write_output_with(path, &mut |w| {
            if gzip {
                let mut encoder = crate::output::gzip::GzipWriter::new(w)?;
                body(&mut encoder)?;
                encoder.finish().map(|_| ())
            } else {
                body(w)
            }
        })?;
        Ok(notes)
    }
}

/// Appends element `i` of `columns` (the values some hold in `mesh`) as one ascii line.
fn put_ascii_row(columns: &[&Column], mesh: &AssetMesh, i: usize, out: &mut Vec<u8>) {
    for (k, c) in columns.iter().enumerate() {
        if k > 0 {
            out.push(b' ');
        }
        let items = c.items(i);
        if c.list.is_some() {
            put_display(items.len(), out);
            if !items.is_empty() {
                out.push(b' ');
            }
        }
        for (j, item) in items.enumerate() {
            if j > 0 {
                out.push(b' ');
            }
            c.put_ascii(item, mesh, out);
        }
    }
    out.push(b'\n');
}

/// Appends element `i` of `columns` (the values some hold in `mesh`) in binary little-endian.
fn put_binary_row(columns: &[&Column], mesh: &AssetMesh, i: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
    for c in columns {
        let items = c.items(i);
        if let Some((count_type, _)) = &c.list {
            let n = items.len();
            let too_long =
                || std::io::Error::other(format!("list {} of {n} items is too long for its count type", c.name));
            match count_type {
                ScalarType::Char => i8::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::UChar => u8::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::Short => i16::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::UShort => u16::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::Int => i32::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::UInt => u32::try_from(n).map_err(|_| too_long())?.put_le(out),
                ScalarType::Float | ScalarType::Double => return Err(too_long()),
            }
        }
        for item in items {
            c.put_le(item, mesh, out);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{Addable, DefaultElement, Ply, Property, PropertyDef, Version};
    use ply_rs_bw::writer::Writer;
    use std::path::PathBuf;

    fn scenes() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
    }

    fn scalar(t: ScalarType) -> PropertyType {
        PropertyType::Scalar(t)
    }

    fn list(count: ScalarType, item: ScalarType) -> PropertyType {
        PropertyType::List(count, item)
    }

    /// Adds element `name` with `properties` and `rows` (values in the properties' order).
    fn add(ply: &mut Ply<DefaultElement>, name: &str, properties: &[(&str, PropertyType)], rows: Vec<Vec<Property>>) {
        let mut def = ElementDef::new(name.to_string());
        for (p, t) in properties {
            def.properties.add(PropertyDef::new(p.to_string(), t.clone()));
        }
        def.count = rows.len();
        ply.header.elements.add(def);
        let rows = rows
            .into_iter()
            .map(|row| {
                assert_eq!(row.len(), properties.len());
                let mut e = DefaultElement::new();
                for ((p, _), v) in properties.iter().zip(row) {
                    e.insert(p.to_string(), v);
                }
                e
            })
            .collect();
        ply.payload.insert(name.to_string(), rows);
    }

    const XYZ: [[f32; 3]; 5] =
        [[0.1, -0.0, 0.0], [1.0 / 3.0, 0.0, -2.5e-7], [1.0, 12345.678, 0.0], [0.0, 1.0, 1e-38], [0.5, 0.5, 1.0]];
    const FACES: [&[i32]; 2] = [&[0, 1, 4], &[0, 1, 2, 3]];

    /// A pyramid's apex and base quadrilateral with normals, extra vertex properties of
    /// several types, and `edge` and `material` elements between every type of PLY.
    fn fixture(encoding: Encoding) -> Ply<DefaultElement> {
        use Property as P;
        use ScalarType as T;
        let mut ply = Ply::<DefaultElement>::new();
        ply.header.encoding = encoding;
        ply.header.version = Version { major: 1, minor: 0 };
        ply.header.comments = vec!["made by the bake's tests".into(), "  spaced   comment".into()];
        ply.header.obj_infos = vec!["num_cols 5".into()];
        let vertex_rows = (0..5)
            .map(|i| {
                let [x, y, z] = XYZ[i];
                vec![
                    P::Float(x),
                    P::Float(y),
                    P::Float(z),
                    P::Float(0.0),
                    P::Float(-(i as f32) * 0.7),
                    P::Float(1.0),
                    P::Double(1.0 / (i as f64 + 7.0)),
                    P::UChar(200 + i as u8),
                    P::ListFloat(vec![0.25; i]),
                ]
            })
            .collect();
        add(
            &mut ply,
            "vertex",
            &[
                ("x", scalar(T::Float)),
                ("y", scalar(T::Float)),
                ("z", scalar(T::Float)),
                ("nx", scalar(T::Float)),
                ("ny", scalar(T::Float)),
                ("nz", scalar(T::Float)),
                ("confidence", scalar(T::Double)),
                ("flags", scalar(T::UChar)),
                ("uv", list(T::UChar, T::Float)),
            ],
            vertex_rows,
        );
        let face_rows = FACES
            .iter()
            .enumerate()
            .map(|(i, f)| vec![P::ListInt(f.to_vec()), P::Short(-300 - i as i16), P::Char(-5)])
            .collect();
        add(
            &mut ply,
            "face",
            &[("vertex_indices", list(T::UChar, T::Int)), ("flags", scalar(T::Short)), ("material", scalar(T::Char))],
            face_rows,
        );
        add(
            &mut ply,
            "edge",
            &[("vertex1", scalar(T::Int)), ("vertex2", scalar(T::UInt)), ("crease", scalar(T::UShort))],
            vec![
                vec![P::Int(0), P::UInt(4_000_000_000), P::UShort(65_535)],
                vec![P::Int(-2_000_000_000), P::UInt(2), P::UShort(0)],
            ],
        );
        add(
            &mut ply,
            "material",
            &[
                ("name", list(T::UInt, T::UChar)),
                ("weights", list(T::UShort, T::Double)),
                ("ids", list(T::Char, T::UInt)),
                ("offsets", list(T::Short, T::Char)),
                ("shorts", list(T::Int, T::Short)),
                ("ushorts", list(T::UChar, T::UShort)),
                ("ints", list(T::UChar, T::Int)),
                ("power", scalar(T::Double)),
            ],
            vec![vec![
                P::ListUChar(b"steel".to_vec()),
                P::ListDouble(vec![0.1, -1e300, 5e-324]),
                P::ListUInt(vec![]),
                P::ListChar(vec![-128, 127]),
                P::ListShort(vec![-32768]),
                P::ListUShort(vec![65535, 1]),
                P::ListInt(vec![i32::MIN, i32::MAX]),
                P::Double(std::f64::consts::PI),
            ]],
        );
        ply
    }

    /// `ply` encoded by ply-rs's own writer.
    fn encode(ply: &mut Ply<DefaultElement>) -> Vec<u8> {
        let mut bytes = Vec::new();
        Writer::new().write_ply(&mut bytes, ply).unwrap();
        bytes
    }

    /// `bytes` read by ply-rs's generic reader: independent of the reader under test.
    fn parse(bytes: &[u8]) -> Ply<DefaultElement> {
        Parser::<DefaultElement>::new().read_ply(&mut &bytes[..]).unwrap()
    }

    fn gzip(bytes: &[u8]) -> Vec<u8> {
        let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        encoder.write_all(bytes).unwrap();
        encoder.finish().unwrap()
    }

    fn gunzip(bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(bytes), &mut out).unwrap();
        out
    }

    /// The header of a PLY file's bytes, as text.
    fn header_text(bytes: &[u8]) -> String {
        let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        String::from_utf8(bytes[..end].to_vec()).unwrap()
    }

    /// Asserts that `written` holds every comment, obj_info, element and property of
    /// `original` in order, with the same types and values bit for bit, except for the
    /// properties `replaced` of element `target`; returns the names it has besides.
    fn assert_preserved(
        original: &Ply<DefaultElement>,
        written: &Ply<DefaultElement>,
        target: &str,
        replaced: &[&str],
    ) -> Vec<String> {
        assert_eq!(written.header.comments, original.header.comments);
        assert_eq!(written.header.obj_infos, original.header.obj_infos);
        let names = |p: &Ply<DefaultElement>| p.header.elements.keys().cloned().collect::<Vec<_>>();
        assert_eq!(names(written), names(original));
        let mut added = Vec::new();
        for (name, def) in &original.header.elements {
            let out_def = &written.header.elements[name];
            assert_eq!(out_def.count, def.count, "{name}");
            let kept: Vec<&String> =
                def.properties.keys().filter(|p| name != target || !replaced.contains(&p.as_str())).collect();
            let out_kept: Vec<&String> =
                out_def.properties.keys().filter(|p| def.properties.contains_key(*p)).collect();
            assert_eq!(out_def.properties.keys().take(def.properties.len()).collect::<Vec<_>>(), {
                def.properties.keys().collect::<Vec<_>>()
            });
            for p in kept {
                assert_eq!(out_def.properties[p], def.properties[p], "{name} {p}");
                for (i, (a, b)) in original.payload[name].iter().zip(&written.payload[name]).enumerate() {
                    // Debug text tells -0.0 from 0.0 and names the type: bit for bit.
                    assert_eq!(format!("{:?}", b[p]), format!("{:?}", a[p]), "{name} {i} {p}");
                }
            }
            assert!(out_kept.len() == def.properties.len());
            if name == target {
                added.extend(out_def.properties.keys().skip(def.properties.len()).cloned());
            } else {
                assert_eq!(out_def.properties.len(), def.properties.len(), "{name} gained properties");
            }
        }
        added
    }

    fn baked(n: usize, bent: bool) -> BakedValues {
        BakedValues {
            ao: (0..n).map(|i| [0.0, 1.0, 0.123_456_79, -0.5, 2.0][i % 5]).collect(),
            std_error: (0..n).map(|i| 1e-3 * i as f32 + 1.0 / 3.0).collect(),
            bent_normals: bent.then(|| (0..n).map(|i| Vec3::new(0.1 * i as f32, -0.6, 0.8)).collect()),
        }
    }

    fn float_column(ply: &Ply<DefaultElement>, element: &str, name: &str) -> Vec<f32> {
        ply.payload[element]
            .iter()
            .map(|e| match e[name] {
                Property::Float(v) => v,
                ref other => panic!("{element} {name} is {other:?}"),
            })
            .collect()
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    const ALL: WriteOptions = WriteOptions { at: BakeAt::Vertices, std_error: true, colors: true };

    /// Texture coordinates per corner: from vertex `s t` (or `u v`…), or from MeshLab's
    /// face `texcoord` lists, which win.
    #[test]
    fn texture_coordinates_are_read_per_corner() {
        let dir = tempfile::tempdir().unwrap();
        let header = |vertex: &str, face: &str| {
            format!(
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n{vertex}\
                 element face 1\nproperty list uchar int vertex_indices\n{face}end_header\n"
            )
        };
        for (names, list) in [("s t", false), ("u v", false), ("texture_u texture_v", false), ("s t", true)] {
            let vertex: String = names.split(' ').map(|n| format!("property float {n}\n")).collect();
            let face = if list { "property list uchar float texcoord\n" } else { "" };
            let mut text = header(&vertex, face);
            text += "0 0 0 0.1 0.2\n1 0 0 0.3 0.4\n0 1 0 0.5 0.6\n3 2 0 1";
            text += if list { " 6 0.7 0.8 0.9 1.0 0.0 0.25\n" } else { "\n" };
            let path = dir.path().join("uv.ply");
            std::fs::write(&path, text).unwrap();
            let asset = PlyAsset::read(&path).unwrap();
            let mesh = &asset.meshes()[0];
            let corners: Vec<[f32; 2]> = mesh.uv_set(0).unwrap().corners.iter().map(|c| c.to_array()).collect();
            let expected =
                if list { [[0.7, 0.8], [0.9, 1.0], [0.0, 0.25]] } else { [[0.5, 0.6], [0.1, 0.2], [0.3, 0.4]] };
            assert_eq!(corners, expected, "{names} {list}");
            assert!(!mesh.uv_v_down);
        }
    }

    #[test]
    fn every_encoding_round_trips_with_the_bake_added() {
        let dir = tempfile::tempdir().unwrap();
        for encoding in [Encoding::Ascii, Encoding::BinaryLittleEndian, Encoding::BinaryBigEndian] {
            let bytes = encode(&mut fixture(encoding));
            let original = parse(&bytes);
            for gz in [false, true] {
                let input = dir.path().join(if gz { "in.ply.gz" } else { "in.ply" });
                std::fs::write(&input, if gz { gzip(&bytes) } else { bytes.clone() }).unwrap();
                let asset = PlyAsset::read(&input).unwrap_or_else(|e| panic!("{encoding:?}: {e}"));

                let [mesh] = asset.meshes() else { panic!("one mesh") };
                assert_eq!(mesh.label, input.file_name().unwrap().to_str().unwrap());
                let want: Vec<Vec3> = XYZ.iter().map(|&p| Vec3::from(p)).collect();
                assert_eq!(mesh.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>(), {
                    want.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>()
                });
                let normals = mesh.normals.as_ref().expect("the fixture has normals");
                assert_eq!(normals[2], Vec3::new(0.0, -1.4, 1.0));
                assert_eq!((mesh.face_count(), mesh.face(0), mesh.face(1)), (2, &[0, 1, 4][..], &[0, 1, 2, 3][..]));

                let output = dir.path().join("out.ply");
                let values = baked(5, true);
                let notes = asset.write(&output, std::slice::from_ref(&values), &ALL).unwrap();
                assert!(notes.is_empty(), "{notes:?}");
                let out = std::fs::read(&output).unwrap();
                let format = if encoding == Encoding::Ascii { "ascii" } else { "binary_little_endian" };

                // The header: the original's lines, in order, with the new properties
                // after the vertex element's last.
                let mut want_header = header_text(&bytes)
                    .replace("binary_big_endian", "binary_little_endian")
                    .replace("property list uchar float uv\n", "property list uchar float uv\nNEW");
                let new = "property float quality\nproperty float quality_std_error\nproperty float bnx\n\
                           property float bny\nproperty float bnz\nproperty uchar red\nproperty uchar green\n\
                           property uchar blue\n";
                want_header = want_header.replace("NEW", new);
                assert_eq!(header_text(&out), want_header);
                assert!(header_text(&out).contains(&format!("format {format} 1.0\n")));

                let written = parse(&out);
                let added = assert_preserved(&original, &written, "vertex", &[]);
                assert_eq!(added, ["quality", "quality_std_error", "bnx", "bny", "bnz", "red", "green", "blue"]);
                assert_eq!(bits(&float_column(&written, "vertex", "quality")), bits(&values.ao));
                assert_eq!(bits(&float_column(&written, "vertex", "quality_std_error")), bits(&values.std_error));
                let bent = values.bent_normals.as_ref().unwrap();
                for (axis, name) in ["bnx", "bny", "bnz"].into_iter().enumerate() {
                    let want: Vec<f32> = bent.iter().map(|b| b[axis]).collect();
                    assert_eq!(bits(&float_column(&written, "vertex", name)), bits(&want));
                }
                for name in ["red", "green", "blue"] {
                    let grey: Vec<Property> = written.payload["vertex"].iter().map(|e| e[name].clone()).collect();
                    let want = [0, 255, 31, 0, 255].map(Property::UChar);
                    assert_eq!(grey, want, "{name}");
                }
                // The asset reads its own output back to the same mesh.
                let again = PlyAsset::read(&output).unwrap();
                assert_eq!(again.meshes()[0].positions, mesh.positions);
                assert_eq!(again.meshes()[0].face_indices, mesh.face_indices);
            }
        }
    }

    #[test]
    fn faces_mode_writes_quality_on_the_face_element() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode(&mut fixture(Encoding::BinaryLittleEndian));
        let original = parse(&bytes);
        let input = dir.path().join("in.ply");
        std::fs::write(&input, bytes).unwrap();
        let asset = PlyAsset::read(&input).unwrap();
        let output = dir.path().join("faces.ply");
        let values = baked(2, false);
        let options = WriteOptions { at: BakeAt::Faces, std_error: true, colors: false };
        asset.write(&output, std::slice::from_ref(&values), &options).unwrap();
        let written = parse(&std::fs::read(&output).unwrap());
        assert_eq!(assert_preserved(&original, &written, "face", &[]), ["quality", "quality_std_error"]);
        assert_eq!(bits(&float_column(&written, "face", "quality")), bits(&values.ao));
        assert_eq!(bits(&float_column(&written, "face", "quality_std_error")), bits(&values.std_error));
        // Per-vertex values do not fit the faces.
        let message = asset.write(&output, &[baked(5, false)], &options).unwrap_err().to_string();
        assert!(message.contains("faces.ply: 5 AO values for the 2 elements 'face'"), "{message}");
    }

    #[test]
    fn an_existing_quality_and_colour_are_replaced_in_place_with_notes() {
        use Property as P;
        let dir = tempfile::tempdir().unwrap();
        let mut original = Ply::<DefaultElement>::new();
        original.header.encoding = Encoding::Ascii;
        let rows = XYZ
            .iter()
            .map(|&[x, y, z]| {
                let c = P::Float(0.25);
                vec![P::Float(x), P::Float(y), P::Float(z), P::Double(7.5), c.clone(), c.clone(), c, P::UChar(9)]
            })
            .collect();
        let t = |t| scalar(t);
        let props = [
            ("x", t(ScalarType::Float)),
            ("y", t(ScalarType::Float)),
            ("z", t(ScalarType::Float)),
            ("quality", t(ScalarType::Double)),
            ("red", t(ScalarType::Float)),
            ("green", t(ScalarType::Float)),
            ("blue", t(ScalarType::Float)),
            ("alpha", t(ScalarType::UChar)),
        ];
        add(&mut original, "vertex", &props, rows);
        let faces = FACES.iter().map(|f| vec![P::ListInt(f.to_vec())]).collect();
        add(&mut original, "face", &[("vertex_indices", list(ScalarType::UChar, ScalarType::Int))], faces);
        let input = dir.path().join("coloured.ply");
        std::fs::write(&input, encode(&mut original)).unwrap();
        let asset = PlyAsset::read(&input).unwrap();
        assert_eq!(asset.meshes()[0].normals, None);

        let output = dir.path().join("out.ply");
        let values = baked(5, false);
        let options = WriteOptions { at: BakeAt::Vertices, std_error: false, colors: true };
        let notes = asset.write(&output, std::slice::from_ref(&values), &options).unwrap();
        assert_eq!(
            notes,
            [
                "the vertex element's own 'quality' property (of type double) was replaced by the bake's",
                "the vertex element's own colour red (float), green (float), blue (float) was overwritten with the AO \
                 as grey, its type kept"
            ]
        );
        let out = std::fs::read(&output).unwrap();
        assert!(header_text(&out).contains(
            "property float x\nproperty float y\nproperty float z\nproperty float quality\nproperty float red\n\
             property float green\nproperty float blue\nproperty uchar alpha\nelement face 2\n"
        ));
        let written = parse(&out);
        let added = assert_preserved(&original, &written, "vertex", &["quality", "red", "green", "blue"]);
        assert!(added.is_empty(), "{added:?}");
        assert_eq!(bits(&float_column(&written, "vertex", "quality")), bits(&values.ao));
        let grey: Vec<f32> = values.ao.iter().map(|a| a.clamp(0.0, 1.0)).collect();
        assert_eq!(float_column(&written, "vertex", "green"), grey);
    }

    #[test]
    fn a_gz_output_is_gzipped() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode(&mut fixture(Encoding::Ascii));
        let original = parse(&bytes);
        let input = dir.path().join("in.ply");
        std::fs::write(&input, bytes).unwrap();
        let output = dir.path().join("out.ply.gz");
        let values = baked(5, false);
        PlyAsset::read(&input)
            .unwrap()
            .write(&output, std::slice::from_ref(&values), &WriteOptions::default())
            .unwrap();
        let out = std::fs::read(&output).unwrap();
        assert_eq!(out[..2], [0x1f, 0x8b]);
        let written = parse(&gunzip(&out));
        assert_eq!(assert_preserved(&original, &written, "vertex", &[]), ["quality"]);
        assert_eq!(bits(&float_column(&written, "vertex", "quality")), bits(&values.ao));
        // Only the output is left in the directory: the write went through a temporary file.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }

    #[test]
    fn a_free_text_header_line_is_read_and_written_back_as_a_comment() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("blender.ply");
        let text = "ply\nformat ascii 1.0\nCreated by Blender3D 247 - www.blender.org\nelement vertex 3\n\
                    property float x\ncomment between properties\nproperty float y\nproperty float z\n\
                    obj_info after the vertex element\nelement face 1\nproperty list uchar uint vertex_index\n\
                    end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        std::fs::write(&input, text).unwrap();
        let asset = PlyAsset::read(&input).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(asset.meshes()[0].face_indices, [0, 1, 2]);
        let output = dir.path().join("out.ply");
        let values = BakedValues { ao: vec![0.5, 0.25, 1.0], ..Default::default() };
        let notes = asset.write(&output, &[values], &WriteOptions::default()).unwrap();
        assert_eq!(notes, ["header line 3, free text without 'comment', is written as a comment"]);
        let want = "ply\nformat ascii 1.0\ncomment Created by Blender3D 247 - www.blender.org\nelement vertex 3\n\
                    property float x\ncomment between properties\nproperty float y\nproperty float z\n\
                    property float quality\nobj_info after the vertex element\nelement face 1\n\
                    property list uchar uint vertex_index\nend_header\n0 0 0 0.5\n1 0 0 0.25\n0 1 0 1\n3 0 1 2\n";
        assert_eq!(std::fs::read_to_string(&output).unwrap(), want);
    }

    #[test]
    fn positions_are_the_scene_loaders_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        // Values near the limits of each type, ascii spellings of every form the grammar
        // takes, doubles that round, integers beyond f32's exact range.
        let ascii = dir.path().join("exotic.ply");
        std::fs::write(
            &ascii,
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty int y\nproperty float z\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n\
             0.1 16777217 1e-45\n-1.00000001 -2147483648 3.4028235e38\n+2.5E+3 2147483647 0.30000001192092896\n\
             1e-320 0 -0\n4 0 1 2 3\n",
        )
        .unwrap();
        let mut files = vec![ascii];
        for name in
            ["dragon_vrip_res4.ply.gz", "dragon_vrip_res3.ply.gz", "dragon_vrip_res2.ply.gz", "dragon_vrip.ply.gz"]
        {
            files.push(scenes().join(name));
        }
        for path in files {
            let start = std::time::Instant::now();
            let asset = PlyAsset::read(&path).unwrap_or_else(|e| panic!("{e}"));
            let read = start.elapsed();
            let loaded = crate::scene::ply::load_ply(&path, &mut Meter::unlimited()).unwrap();
            let mesh = &asset.meshes()[0];
            let as_bits = |p: &[Vec3]| p.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
            assert!(as_bits(&mesh.positions) == as_bits(&loaded.positions), "{}", path.display());
            // The loader's triangles are fans of the asset's faces.
            let fans: Vec<[u32; 3]> = (0..mesh.face_count())
                .flat_map(|f| {
                    let c = mesh.face(f);
                    (1..c.len() - 1).map(move |k| [c[0], c[k], c[k + 1]])
                })
                .collect();
            assert!(fans == loaded.triangles, "{}", path.display());
            eprintln!(
                "{}: {} vertices, {} faces read in {read:.2?}",
                path.display(),
                mesh.positions.len(),
                mesh.face_count()
            );
        }
    }

    #[test]
    fn the_full_dragon_is_written_back_identically() {
        let dir = tempfile::tempdir().unwrap();
        let path = scenes().join("dragon_vrip.ply.gz");
        let asset = PlyAsset::read(&path).unwrap_or_else(|e| panic!("{e}"));
        let n = asset.meshes()[0].positions.len();
        let start = std::time::Instant::now();
        let output = dir.path().join("dragon.ply");
        asset.write(&output, &[baked(n, false)], &WriteOptions::default()).unwrap();
        eprintln!("dragon written in {:.2?}", start.elapsed());
        let again = PlyAsset::read(&output).unwrap();
        assert_eq!(again.elements[0].columns[..3], asset.elements[0].columns[..]);
        assert_eq!(again.elements[1..], asset.elements[1..]);
        // The positions and corners, which the columns leave to the mesh.
        let (a, b) = (&again.meshes()[0], &asset.meshes()[0]);
        let bits = |m: &AssetMesh| m.positions.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(a), bits(b));
        assert_eq!((&a.face_starts, &a.face_indices), (&b.face_starts, &b.face_indices));
    }

    /// A file's `float` x, y and z and its `int` vertex index list are held once, by the
    /// mesh (the round trips above write them back from it); a column of another type, or
    /// one whose bits differ from the mesh's, keeps its values.
    #[test]
    fn positions_and_corners_are_held_once_by_the_mesh() {
        let dir = tempfile::tempdir().unwrap();
        for encoding in [Encoding::Ascii, Encoding::BinaryLittleEndian, Encoding::BinaryBigEndian] {
            let input = dir.path().join("in.ply");
            std::fs::write(&input, encode(&mut fixture(encoding))).unwrap();
            let asset = PlyAsset::read(&input).unwrap();
            let held: Vec<(&str, &str, Held, usize)> = asset
                .elements
                .iter()
                .flat_map(|e| e.columns.iter().map(move |c| (e.name.as_str(), c.name.as_str(), c.held, c.values.len())))
                .filter(|c| c.2 != Held::Own)
                .collect();
            let want = [
                ("vertex", "x", Held::Axis(0), 0),
                ("vertex", "y", Held::Axis(1), 0),
                ("vertex", "z", Held::Axis(2), 0),
                ("face", "vertex_indices", Held::Corners, 0),
            ];
            assert_eq!(held, want, "{encoding:?}");
        }

        let scalar = |name: &str, values: Values| Column { name: name.into(), list: None, values, held: Held::Own };
        let mesh = AssetMesh {
            positions: vec![Vec3::new(1.0, 2.0, 0.0), Vec3::new(-1.0, 0.5, 3.0), Vec3::new(0.0, 0.0, 1.0)],
            face_starts: vec![0, 3],
            face_indices: vec![0, 1, 2],
            ..AssetMesh::default()
        };
        let corners = |values: Values| Column {
            name: "vertex_indices".into(),
            list: Some((ScalarType::UChar, Starts::from(vec![0, 3]))),
            values,
            held: Held::Own,
        };
        let element = |name: &str, count: usize, columns: Vec<Column>| Element { name: name.into(), count, columns };
        let mut elements = vec![
            // y a double, z's first value -0.0 where the mesh has 0.0.
            element(
                "vertex",
                3,
                vec![
                    scalar("x", Values::Float(vec![1.0, -1.0, 0.0])),
                    scalar("y", Values::Double(vec![2.0, 0.5, 0.0])),
                    scalar("z", Values::Float(vec![-0.0, 3.0, 1.0])),
                ],
            ),
            element("face", 1, vec![corners(Values::UInt(vec![0, 1, 2]))]),
        ];
        let before = elements.clone();
        hand_to_mesh(&mut elements, &mesh, "vertex_indices");
        let held: Vec<Held> = elements.iter().flat_map(|e| e.columns.iter().map(|c| c.held)).collect();
        assert_eq!(held, [Held::Axis(0), Held::Own, Held::Own, Held::Corners]);
        assert_eq!(elements[0].columns[1..], before[0].columns[1..], "the columns kept are unchanged");
        // An index list of another type, or of other values, keeps its values.
        for values in [Values::UShort(vec![0, 1, 2]), Values::Int(vec![0, 2, 1]), Values::Int(vec![0, 1])] {
            let mut elements = vec![element("face", 1, vec![corners(values)])];
            hand_to_mesh(&mut elements, &mesh, "vertex_indices");
            assert_eq!(elements[0].columns[0].held, Held::Own);
        }
    }

    /// `text` written to `name` and read: the error's message.
    fn error_of(dir: &Path, name: &str, bytes: &[u8]) -> String {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        match std::panic::catch_unwind(|| PlyAsset::read(&path)) {
            Err(_) => panic!("{name}: panicked"),
            Ok(Ok(_)) => panic!("{name}: read"),
            Ok(Err(e)) => e.to_string(),
        }
    }

    #[test]
    fn bad_files_are_one_line_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let head = |format: &str, vertices: usize, extra: &str| {
            format!(
                "ply\nformat {format} 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\n{extra}\
                 element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            )
        };
        let with_z = "property float z\n";
        let le = |values: &[f32], face: &[i32]| {
            let mut b = Vec::new();
            values.iter().for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
            b.push(face.len() as u8);
            face.iter().for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
            b
        };
        let binary = |vertices: usize, data: Vec<u8>| {
            [head("binary_little_endian", vertices, with_z).into_bytes(), data].concat()
        };
        let ascii = |body: &str| format!("{}{body}", head("ascii", 3, with_z)).into_bytes();
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("empty.ply", Vec::new(), "not a PLY file"),
            ("no_end.ply", b"ply\nformat ascii 1.0\nelement vertex 1\n".to_vec(), "ends before 'end_header'"),
            ("no_z.ply", head("ascii", 1, "").into_bytes(), "the vertex element has no z property"),
            ("truncated.ply", binary(3, le(&[0.0; 7], &[])), "unexpected end of file in vertex 2 of 3"),
            ("short_face.ply", binary(3, le(&[0.0; 9], &[0, 1])), "face 0 has 2 vertices"),
            ("range.ply", binary(3, le(&[0.0; 9], &[0, 1, 3])), "face 0: vertex index 3 is out of range"),
            ("negative.ply", binary(3, le(&[0.0; 9], &[0, -1, 2])), "face 0: vertex index -1 is out of range"),
            ("long_list.ply", binary(3, [le(&[0.0; 9], &[]), vec![0; 3]].concat()), "data after the last element"),
            ("short_list.ply", binary(3, le(&[0.0; 9], &[0, 1]).into_iter().enumerate().map(|(i, b)| if i == 36 { 3 } else { b }).collect()), "unexpected end of file in face 0"),
            ("extra.ply", binary(3, [le(&[0.0; 9], &[0, 1, 2]), vec![0]].concat()), "data after the last element"),
            ("nan.ply", binary(3, le(&[0.0, f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], &[0, 1, 2])), "vertex 0 has a non-finite coordinate (y = NaN)"),
            ("word.ply", ascii("0 0 0\n1 x 0\n0 1 0\n3 0 1 2\n"), "vertex 1 of 3: 'x' is not a number"),
            ("dot.ply", ascii("0 0 0\n1 .5 0\n0 1 0\n3 0 1 2\n"), "vertex 1 of 3: '.5' is not a number"),
            ("few.ply", ascii("0 0 0\n1 0\n0 1 0\n3 0 1 2\n"), "vertex 1 of 3: fewer values than its properties need"),
            ("int.ply", ascii("0 0 0\n1 0 0\n0 1 0\n3 0 1.0 2\n"), "face 0 of 1: '1.0' is not a valid int"),
            ("cut.ply", ascii("0 0 0\n1 0 0\n"), "unexpected end of file in vertex 2 of 3"),
            ("more.ply", ascii("0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n7\n"), "data after the last element"),
            ("list_x.ply", head("ascii", 0, "property list uchar float z\n").into_bytes(), "vertex property z must be a number"),
            ("float_count.ply", head("ascii", 0, "property float z\nproperty list float int w\n").into_bytes(), "a list's count must have an integer type"),
            ("no_face.ply", b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec(), "no face element"),
            ("bad.ply.gz", b"\x1f\x8b\x08\x00garbage".to_vec(), "invalid or truncated gzip data"),
        ];
        for (name, bytes, expect) in cases {
            let message = error_of(dir.path(), name, &bytes);
            assert!(message.contains(name) && message.contains(expect), "{name}: '{message}' lacks '{expect}'");
            assert!(!message.contains('\n'), "{name}: {message}");
        }
        // The scene loader's corpus of malformed files: errors too.
        let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/malformed");
        let mut seen = 0;
        for entry in std::fs::read_dir(&corpus).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if name.starts_with("ply_") {
                let message = error_of(dir.path(), &name, &std::fs::read(&path).unwrap());
                assert!(message.contains(&name) && !message.contains('\n'), "{name}: {message}");
                seen += 1;
            }
        }
        assert!(seen >= 10, "the corpus has {seen} PLY files");
    }

    /// An ASCII file of many blocks (`ASCII_BLOCK_BYTES` of lines each): a vertex
    /// `float x y z` and `uchar` grey, a face list of triangles and quads.
    fn many_blocks(vertices: usize) -> (String, Vec<[f32; 3]>, Vec<Vec<i32>>) {
        let points: Vec<[f32; 3]> =
            (0..vertices).map(|i| [i as f32 * 0.001, (i % 97) as f32 / 7.0, -(i as f32).sqrt()]).collect();
        let faces: Vec<Vec<i32>> = (0..vertices as i32 - 3)
            .map(|i| if i % 5 == 0 { vec![i, i + 1, i + 2, i + 3] } else { vec![i, i + 2, i + 1] })
            .collect();
        let mut text = format!(
            "ply\nformat ascii 1.0\nelement vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n\
             property uchar grey\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
            faces.len()
        );
        for (i, p) in points.iter().enumerate() {
            text += &format!("{} {} {} {}\n", p[0], p[1], p[2], i % 256);
        }
        for f in &faces {
            text += &format!("{} {}\n", f.len(), f.iter().map(i32::to_string).collect::<Vec<_>>().join(" "));
        }
        (text, points, faces)
    }

    #[test]
    fn ascii_blocks_are_read_in_order_and_fail_at_the_first_bad_line() {
        let n = 200_000;
        let (text, points, faces) = many_blocks(n);
        assert!(text.len() > 4 * ASCII_BLOCK_BYTES, "{} bytes", text.len());
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("blocks.ply");
        std::fs::write(&path, &text).unwrap();
        let asset = PlyAsset::read(&path).unwrap();
        let mesh = &asset.meshes()[0];
        let want: Vec<Vec3> = points.iter().map(|&p| Vec3::from(p)).collect();
        assert!(
            mesh.positions
                .iter()
                .zip(&want)
                .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits))
        );
        assert_eq!(mesh.positions.len(), n);
        assert_eq!(mesh.face_count(), faces.len());
        for (f, face) in faces.iter().enumerate() {
            assert_eq!(mesh.face(f).iter().map(|&v| v as i32).collect::<Vec<_>>(), *face, "face {f}");
        }
        let grey = column(&asset.elements[0], "grey").unwrap();
        assert!((0..n).all(|i| grey.values.integer(i) == Some((i % 256) as i64)));
        // Bad lines in several blocks: the first in the file is reported.
        let lines: Vec<&str> = text.lines().collect();
        let header = lines.iter().position(|l| *l == "end_header").unwrap() + 1;
        let edit = |edits: &[(usize, &str)]| {
            let mut l = lines.clone();
            for &(k, line) in edits {
                l[header + k] = line;
            }
            l.join("\n") + "\n"
        };
        let cases = [
            (edit(&[(150_000, "1 2 x 4"), (190_000, "y")]), "vertex 150000 of 200000: 'x' is not a number"),
            (edit(&[(199_999, "1 2")]), "vertex 199999 of 200000: fewer values than its properties need"),
            (
                edit(&[(n + 120_000, "3 0 1.5 2"), (n + 130_000, "z")]),
                "face 120000 of 199997: '1.5' is not a valid int",
            ),
            (lines[..header + n + 50_000].join("\n") + "\n", "unexpected end of file in face 50000 of 199997"),
        ];
        for (k, (text, expect)) in cases.into_iter().enumerate() {
            let message = error_of(dir.path(), &format!("bad{k}.ply"), text.as_bytes());
            assert!(message.ends_with(expect), "{k}: '{message}' does not end with '{expect}'");
        }
    }
}
