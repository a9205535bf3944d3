//! Baking into PLY files: the whole file read (every header line, element and property,
//! in order, each value in its own type), and written back with the AO added as MeshLab
//! reads it: `quality` on the vertex (or face) element, optionally `quality_std_error`,
//! the bent normal `bnx bny bnz` and a grey `red green blue`.
//!
//! The header goes through the scene loader's reader ([`read_header`]); the data is read
//! here, ascii tokens accepted and converted exactly as the loader's crate does (so the
//! positions are the loader's, bit for bit). Output is binary little-endian, or ascii
//! when the input was.

use super::{Asset, AssetMesh, BakeAt, BakedValues, WriteOptions, is_gzip_name};
use crate::error::{Error, Result};
use crate::output::write_atomically_with;
use crate::scene::input::Input;
use crate::scene::ply::{HeaderLine, PlyHeader, index_list_name, non_finite_coordinate, read_header};
use glam::Vec3;
use ply_rs_bw::ply::{ElementDef, Encoding, PropertyType, ScalarType};
use std::io::Write;
use std::path::Path;

/// Bytes gathered before they are handed to the output stream.
const CHUNK_BYTES: usize = 1 << 20;

/// A value of one of PLY's scalar types.
trait Scalar: Copy + std::str::FromStr + Into<f64> {
    /// Bytes in binary encodings.
    const SIZE: usize;

    /// The value at `data[*pos..]`, advancing `pos`; `None` when too few bytes are left.
    fn read(data: &[u8], pos: &mut usize, big_endian: bool) -> Option<Self>;

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
// `{}` gives the shortest text that reads back as the same value. Infinities (an ascii
// value beyond the type's range reads as one) are written as such a value, since PLY
// readers take no `inf`.
scalar!(f32, |v, out| match v {
    f32::INFINITY => out.extend_from_slice(b"1e39"),
    f32::NEG_INFINITY => out.extend_from_slice(b"-1e39"),
    v if v.is_nan() => out.extend_from_slice(b"nan"),
    v => put_display(v, out),
});
scalar!(f64, |v, out| match v {
    f64::INFINITY => out.extend_from_slice(b"1e309"),
    f64::NEG_INFINITY => out.extend_from_slice(b"-1e309"),
    v if v.is_nan() => out.extend_from_slice(b"nan"),
    v => put_display(v, out),
});

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
            ScalarType::Char => Values::Char(Vec::with_capacity(capacity)),
            ScalarType::UChar => Values::UChar(Vec::with_capacity(capacity)),
            ScalarType::Short => Values::Short(Vec::with_capacity(capacity)),
            ScalarType::UShort => Values::UShort(Vec::with_capacity(capacity)),
            ScalarType::Int => Values::Int(Vec::with_capacity(capacity)),
            ScalarType::UInt => Values::UInt(Vec::with_capacity(capacity)),
            ScalarType::Float => Values::Float(Vec::with_capacity(capacity)),
            ScalarType::Double => Values::Double(Vec::with_capacity(capacity)),
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

    /// Appends the binary value at `data[*pos..]`; `None` when too few bytes are left.
    fn push_binary(&mut self, data: &[u8], pos: &mut usize, big_endian: bool) -> Option<()> {
        with_values!(self, v => v.push(Scalar::read(data, pos, big_endian)?));
        Some(())
    }

    /// Appends the value of an ascii token (already checked to be a number), parsed as
    /// ply-rs parses it: `str::parse` into the property's type.
    fn push_token(&mut self, token: &str) -> std::result::Result<(), String> {
        fn parse<T: std::str::FromStr>(v: &mut Vec<T>, token: &str) -> std::result::Result<(), String> {
            v.push(token.parse().map_err(|_| format!("'{token}' is not a valid {}", std::any::type_name::<T>()))?);
            Ok(())
        }
        with_values!(self, v => parse(v, token))
    }

    /// Value `i` as `f32`, converted as the scene loader converts coordinates (the
    /// nearest value; every integer of PLY's types is exact as an `f64`).
    fn f32(&self, i: usize) -> f32 {
        with_values!(self, v => Into::<f64>::into(v[i]) as f32)
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
        with_values!(self, v => v[i].into())
    }

    fn put_le(&self, i: usize, out: &mut Vec<u8>) {
        with_values!(self, v => v[i].put_le(out))
    }

    fn put_ascii(&self, i: usize, out: &mut Vec<u8>) {
        with_values!(self, v => v[i].put_ascii(out))
    }
}

/// One property of an element, with its values for every element.
#[derive(Clone, Debug, PartialEq)]
struct Column {
    name: String,
    /// For a list property: the count's type, and where the items of each element start
    /// in `values` (one entry more than there are elements).
    list: Option<(ScalarType, Vec<usize>)>,
    values: Values,
}

impl Column {
    /// A scalar `float` property.
    fn float(name: &str, values: Vec<f32>) -> Column {
        Column { name: name.to_string(), list: None, values: Values::Float(values) }
    }

    /// The items of element `i`'s list (all of `values` for a scalar property).
    fn items(&self, i: usize) -> std::ops::Range<usize> {
        match &self.list {
            Some((_, starts)) => starts[i]..starts[i + 1],
            None => i..i + 1,
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
    /// Reads `path` (`.ply` or `.ply.gz`, any of the three encodings) for baking.
    pub fn read(path: &Path) -> Result<PlyAsset> {
        let mut input = Input::open(path)?;
        let header = read_header(path, &mut input)?;
        check_header(path, &header)?;
        let data = input.read_all(path)?;
        let elements = match header.encoding {
            Encoding::Ascii => read_ascii(path, &header.elements, &data)?,
            encoding => read_binary(path, &header.elements, &data, encoding == Encoding::BinaryBigEndian)?,
        };
        drop(data);
        let label = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        let mesh = mesh(path, &header, &elements, label)?;
        Ok(PlyAsset { meshes: vec![mesh], header, elements })
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
    def.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => Column { name: p.name.clone(), list: None, values: Values::new(t, capacity) },
            PropertyType::List(count, item) => {
                let mut starts = Vec::with_capacity(capacity + 1);
                starts.push(0);
                Column {
                    name: p.name.clone(),
                    list: Some((count.clone(), starts)),
                    values: Values::new(item, capacity),
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

/// Reads the data of a binary file.
fn read_binary(path: &Path, defs: &[ElementDef], data: &[u8], big_endian: bool) -> Result<Vec<Element>> {
    let mut pos = 0;
    let mut elements = Vec::with_capacity(defs.len());
    for def in defs {
        let min_bytes: usize = def
            .properties
            .values()
            .map(|p| match &p.data_type {
                PropertyType::Scalar(t) | PropertyType::List(t, _) => scalar_bytes(t),
            })
            .sum();
        let mut columns = columns(def, capacity(def, data.len() - pos, min_bytes));
        // Elements without properties take no bytes.
        let count = if columns.is_empty() { 0 } else { def.count };
        for i in 0..count {
            for column in &mut columns {
                let Some((count_type, starts)) = &mut column.list else {
                    column.values.push_binary(data, &mut pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
                    continue;
                };
                let mut n = Values::new(count_type, 1);
                n.push_binary(data, &mut pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
                let n = n.integer(0).unwrap_or(0);
                let item_bytes = scalar_bytes(&column.values.scalar_type());
                let Some(n) = usize::try_from(n).ok().filter(|n| n.saturating_mul(item_bytes) <= data.len() - pos)
                else {
                    return Err(if n < 0 {
                        let message = format!("{} {i} of {}: list {} has {n} items", def.name, def.count, column.name);
                        Error::scene(path, message)
                    } else {
                        end_of_file(path, def, i)
                    });
                };
                for _ in 0..n {
                    column.values.push_binary(data, &mut pos, big_endian).ok_or_else(|| end_of_file(path, def, i))?;
                }
                starts.push(column.values.len());
            }
        }
        elements.push(Element { name: def.name.clone(), count: def.count, columns });
    }
    if pos != data.len() {
        return Err(extra_data(path, pos));
    }
    Ok(elements)
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

/// Reads the data of an ascii file: one line per element, as ply-rs reads it (values
/// beyond the element's properties are ignored, as it ignores them).
fn read_ascii(path: &Path, defs: &[ElementDef], data: &[u8]) -> Result<Vec<Element>> {
    let mut rest = data;
    let mut tokens: Vec<&str> = Vec::new();
    let mut elements = Vec::with_capacity(defs.len());
    for def in defs {
        // Every value takes at least a digit and a separator.
        let min_bytes = 2 * def.properties.len();
        let mut columns = columns(def, capacity(def, rest.len(), min_bytes));
        for i in 0..def.count {
            if rest.is_empty() {
                return Err(end_of_file(path, def, i));
            }
            let end = rest.iter().position(|&b| b == b'\n').map_or(rest.len(), |e| e + 1);
            let (line, next) = rest.split_at(end);
            rest = next;
            let line = line.strip_suffix(b"\n").unwrap_or(line);
            let line = line.strip_suffix(b"\r").unwrap_or(line);
            let at = |message: String| Error::scene(path, format!("{} {i} of {}: {message}", def.name, def.count));
            tokens.clear();
            for token in line.split(|&b| b == b' ' || b == b'\t').filter(|t| !t.is_empty()) {
                if !is_number(token) {
                    let text = String::from_utf8_lossy(token);
                    return Err(at(format!("'{}' is not a number", crate::scene::input::one_line(&text))));
                }
                // A number is ascii.
                tokens.push(std::str::from_utf8(token).unwrap_or_default());
            }
            let mut next_token = tokens.iter();
            let mut take = || next_token.next().ok_or_else(|| at("fewer values than its properties need".to_string()));
            for column in &mut columns {
                let Some((_, starts)) = &mut column.list else {
                    column.values.push_token(take()?).map_err(at)?;
                    continue;
                };
                let n = take()?;
                let n: usize = n.parse().map_err(|_| at(format!("list {}: '{n}' is not a count", column.name)))?;
                for _ in 0..n {
                    column.values.push_token(take()?).map_err(at)?;
                }
                starts.push(column.values.len());
            }
        }
        elements.push(Element { name: def.name.clone(), count: def.count, columns });
    }
    if let Some(at) = rest.iter().position(|b| !b.is_ascii_whitespace()) {
        return Err(extra_data(path, data.len() - rest.len() + at));
    }
    Ok(elements)
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

/// The mesh of the file: positions and faces checked as the scene loader checks them.
fn mesh(path: &Path, header: &PlyHeader, elements: &[Element], label: String) -> Result<AssetMesh> {
    let find = |name: &str| elements.iter().find(|e| e.name == name);
    let (Some(vertex), Some(face)) = (find("vertex"), find("face")) else {
        return Err(Error::scene(path, "no vertex or no face element"));
    };
    let xyz = scalar_columns(vertex, ["x", "y", "z"]).ok_or_else(|| Error::scene(path, "no x, y or z"))?;
    let mut positions = Vec::with_capacity(vertex.count);
    for i in 0..vertex.count {
        let p = Vec3::from(xyz.map(|c| c.values.f32(i)));
        if let Some(c) = non_finite_coordinate(p) {
            return Err(Error::scene(path, format!("vertex {i} has a non-finite coordinate ({c})")));
        }
        positions.push(p);
    }
    let normals = scalar_columns(vertex, ["nx", "ny", "nz"])
        .map(|n| (0..vertex.count).map(|i| Vec3::from(n.map(|c| c.values.f32(i)))).collect());

    let face_def = header.element("face").ok_or_else(|| Error::scene(path, "no face element"))?;
    let list = column(face, &index_list_name(path, face_def)?).ok_or_else(|| Error::scene(path, "no face list"))?;
    let mut face_starts = Vec::with_capacity(face.count + 1);
    let mut face_indices = Vec::with_capacity(list.values.len());
    face_starts.push(0);
    for i in 0..face.count {
        let items = list.items(i);
        if items.len() < 3 {
            let n = items.len();
            return Err(Error::scene(path, format!("face {i} has {n} vertices; a face needs at least 3")));
        }
        for item in items {
            let v = list.values.integer(item).unwrap_or(-1);
            let Some(v) = usize::try_from(v).ok().filter(|&v| v < vertex.count).and_then(|v| u32::try_from(v).ok())
            else {
                let count = vertex.count;
                let message = format!("face {i}: vertex index {v} is out of range (the file has {count} vertices)");
                return Err(Error::scene(path, message));
            };
            face_indices.push(v);
        }
        let end = u32::try_from(face_indices.len())
            .map_err(|_| Error::scene(path, "more than 4294967295 face corners: too many for a mesh"))?;
        face_starts.push(end);
    }
    Ok(AssetMesh { label, positions, normals, face_starts, face_indices })
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
                added.push(Column { name: name.to_string(), list: None, values: grey(&t, &values.ao) });
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
        let (added, mut notes) = self.added_columns(element, values, options).map_err(|m| Error::output(path, m))?;

        // The columns written, element by element: the bake's replace the file's own of
        // the same name in place; the others follow the element's last property.
        let mut plan: Vec<Vec<&Column>> = self.elements.iter().map(|e| e.columns.iter().collect()).collect();
        for a in &added {
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
        let elements = &self.elements;
        let body = |out: &mut dyn Write| -> std::io::Result<()> {
            out.write_all(&head)?;
            let mut chunk = Vec::with_capacity(CHUNK_BYTES + 4096);
            for (element, columns) in elements.iter().zip(&plan) {
                let rows = if !ascii && columns.is_empty() { 0 } else { element.count };
                for i in 0..rows {
                    if ascii {
                        put_ascii_row(columns, i, &mut chunk);
                    } else {
                        put_binary_row(columns, i, &mut chunk)?;
                    }
                    if chunk.len() >= CHUNK_BYTES {
                        out.write_all(&chunk)?;
                        chunk.clear();
                    }
                }
            }
            out.write_all(&chunk)
        };
        write_atomically_with(path, &mut |w| {
            if gzip {
                let mut encoder = flate2::write::GzEncoder::new(w, flate2::Compression::default());
                body(&mut encoder)?;
                encoder.finish().map(|_| ())
            } else {
                body(w)
            }
        })?;
        Ok(notes)
    }
}

/// Appends element `i` of `columns` as one ascii line.
fn put_ascii_row(columns: &[&Column], i: usize, out: &mut Vec<u8>) {
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
            c.values.put_ascii(item, out);
        }
    }
    out.push(b'\n');
}

/// Appends element `i` of `columns` in binary little-endian.
fn put_binary_row(columns: &[&Column], i: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
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
            c.values.put_le(item, out);
        }
    }
    Ok(())
}
