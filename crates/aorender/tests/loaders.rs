//! The mesh loaders: PLY in all three encodings, plain and gzipped, gives the same
//! triangles, with extra elements and properties ignored and polygons as fans; glTF node
//! hierarchies compose TRS and matrices as the specification says, with every triangle
//! primitive mode, quantized and sparse positions, and other modes skipped with a warning;
//! every mesh in `scenes/` loads with its triangle count, a PLY and a GLB with at most two
//! copies of their geometry in memory; GPU and CPU agree on loaded meshes; and every file
//! of the malformed corpus (`tests/malformed/`) is an error naming the file, with no panic
//! and no allocation larger than the file justifies.

mod common;
use aorender::scene::load_mesh;
use aorender::{DeviceKind, Hemisphere, LoadOptions, ReadLimits, Sampler, Scene};
use base64::Engine;
use common::*;
use glam::{Mat4, Vec3};
use serde_json::json;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::Write;
use std::path::Path;

// --- Allocation tracking, per thread, for the loads a test measures -------------------

/// The system allocator, noting on threads that ask for it the largest single allocation
/// and the peak of bytes allocated since tracking started (a reallocation counts its new
/// block before freeing the old one, as a moving reallocation holds both).
struct Tracking;

thread_local! {
    static TRACKING: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    static LIVE: Cell<isize> = const { Cell::new(0) };
    static PEAK: Cell<isize> = const { Cell::new(0) };
}

fn note_alloc(size: usize) {
    let _ = TRACKING.try_with(|t| {
        if t.get() {
            LARGEST.with(|l| l.set(l.get().max(size)));
            let live = LIVE.with(|l| {
                l.set(l.get() + size as isize);
                l.get()
            });
            PEAK.with(|p| p.set(p.get().max(live)));
        }
    });
}

fn note_free(size: usize) {
    let _ = TRACKING.try_with(|t| {
        if t.get() {
            LIVE.with(|l| l.set(l.get() - size as isize));
        }
    });
}

unsafe impl GlobalAlloc for Tracking {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_alloc(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_alloc(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note_free(layout.size());
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_alloc(new_size);
        note_free(layout.size());
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Tracking = Tracking;

/// Runs `f`, returning its result, the largest single allocation it made and the peak of
/// bytes it held at once.
fn measured<T>(f: impl FnOnce() -> T) -> (T, usize, usize) {
    LARGEST.with(|l| l.set(0));
    LIVE.with(|l| l.set(0));
    PEAK.with(|p| p.set(0));
    TRACKING.with(|t| t.set(true));
    let out = f();
    TRACKING.with(|t| t.set(false));
    (out, LARGEST.with(Cell::get), PEAK.with(Cell::get).max(0) as usize)
}

// --- Helpers ------------------------------------------------------------------------

/// The triangles of a mesh file, untransformed.
fn triangles(path: &Path) -> Vec<[Vec3; 3]> {
    match load_mesh(path, 1.0, &Mat4::IDENTITY) {
        Ok(t) => t.iter().map(|t| t.v).collect(),
        Err(e) => panic!("{} does not load: {e}", path.display()),
    }
}

/// The error loading `path` gives.
fn load_error(path: &Path) -> String {
    match Scene::load(path) {
        Ok(_) => panic!("{} loaded", path.display()),
        Err(e) => e.to_string(),
    }
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut encoder = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    encoder.write_all(bytes).unwrap();
    encoder.finish().unwrap()
}

fn assert_close(got: &[[Vec3; 3]], want: &[[Vec3; 3]], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: triangle count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        for k in 0..3 {
            assert!((g[k] - w[k]).abs().max_element() <= 1e-5, "{what}: triangle {i} vertex {k}: {} != {}", g[k], w[k]);
        }
    }
}

// --- PLY ------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq)]
enum Ty {
    Char,
    UChar,
    Short,
    UShort,
    Int,
    UInt,
    Float,
    Double,
}

impl Ty {
    fn name(self) -> &'static str {
        match self {
            Ty::Char => "char",
            Ty::UChar => "uchar",
            Ty::Short => "int16",
            Ty::UShort => "ushort",
            Ty::Int => "int",
            Ty::UInt => "uint32",
            Ty::Float => "float",
            Ty::Double => "float64",
        }
    }

    fn text(self, v: f64) -> String {
        match self {
            Ty::Float => format!("{}", v as f32),
            Ty::Double => format!("{v}"),
            _ => format!("{}", v as i64),
        }
    }

    fn bytes(self, v: f64, big: bool) -> Vec<u8> {
        macro_rules! b {
            ($x:expr) => {
                if big { $x.to_be_bytes().to_vec() } else { $x.to_le_bytes().to_vec() }
            };
        }
        match self {
            Ty::Char => b!(v as i8),
            Ty::UChar => b!(v as u8),
            Ty::Short => b!(v as i16),
            Ty::UShort => b!(v as u16),
            Ty::Int => b!(v as i32),
            Ty::UInt => b!(v as u32),
            Ty::Float => b!(v as f32),
            Ty::Double => b!(v),
        }
    }
}

enum Prop {
    Scalar(Ty, &'static str),
    List(Ty, Ty, &'static str),
}

enum Value {
    One(f64),
    Many(Vec<f64>),
}

struct Element {
    name: &'static str,
    props: Vec<Prop>,
    rows: Vec<Vec<Value>>,
}

#[derive(Clone, Copy, Debug)]
enum Format {
    Ascii,
    Little,
    Big,
}

const FORMATS: [Format; 3] = [Format::Ascii, Format::Little, Format::Big];

/// A PLY file of `elements` in `format`.
fn ply(format: Format, elements: &[Element]) -> Vec<u8> {
    let name = match format {
        Format::Ascii => "ascii",
        Format::Little => "binary_little_endian",
        Format::Big => "binary_big_endian",
    };
    let mut out = format!("ply\nformat {name} 1.0\ncomment written by tests/loaders.rs\n");
    for e in elements {
        out += &format!("element {} {}\n", e.name, e.rows.len());
        for p in &e.props {
            out += &match p {
                Prop::Scalar(t, n) => format!("property {} {n}\n", t.name()),
                Prop::List(c, t, n) => format!("property list {} {} {n}\n", c.name(), t.name()),
            };
        }
    }
    out += "end_header\n";
    let mut bytes = out.into_bytes();
    for e in elements {
        for row in &e.rows {
            let mut words = Vec::new();
            for (p, v) in e.props.iter().zip(row) {
                match (p, v) {
                    (Prop::Scalar(t, _), Value::One(x)) => match format {
                        Format::Ascii => words.push(t.text(*x)),
                        _ => bytes.extend(t.bytes(*x, matches!(format, Format::Big))),
                    },
                    (Prop::List(c, t, _), Value::Many(xs)) => match format {
                        Format::Ascii => {
                            words.push(xs.len().to_string());
                            words.extend(xs.iter().map(|x| t.text(*x)));
                        }
                        _ => {
                            let big = matches!(format, Format::Big);
                            bytes.extend(c.bytes(xs.len() as f64, big));
                            for x in xs {
                                bytes.extend(t.bytes(*x, big));
                            }
                        }
                    },
                    _ => panic!("value does not match property"),
                }
            }
            if let Format::Ascii = format {
                bytes.extend(words.join(" ").into_bytes());
                bytes.push(b'\n');
            }
        }
    }
    bytes
}

/// Six vertices with exact binary values, and a triangle, a quadrilateral and a pentagon.
const VERTICES: [[f64; 3]; 6] =
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.5, 2.0, 0.25], [-0.75, 0.5, 1.5]];
const FACES: [&[u32]; 3] = [&[0, 1, 2], &[0, 2, 3, 5], &[1, 2, 4, 3, 5]];

/// The faces as fans: (v0, v1, v2), (v0, v2, v3), ...
fn fans(vertices: &[[f64; 3]], faces: &[&[u32]]) -> Vec<[Vec3; 3]> {
    let v = |i: u32| Vec3::from(vertices[i as usize].map(|c| c as f32));
    faces.iter().flat_map(|f| (1..f.len() - 1).map(move |k| [v(f[0]), v(f[k]), v(f[k + 1])])).collect()
}

fn vertex_element(props: Vec<Prop>, row: impl Fn([f64; 3]) -> Vec<Value>) -> Element {
    Element { name: "vertex", props, rows: VERTICES.iter().map(|&p| row(p)).collect() }
}

fn face_element(props: Vec<Prop>, row: impl Fn(&[u32]) -> Vec<Value>) -> Element {
    Element { name: "face", props, rows: FACES.iter().map(|f| row(f)).collect() }
}

fn indices(f: &[u32]) -> Value {
    Value::Many(f.iter().map(|&i| i as f64).collect())
}

fn xyz(t: Ty) -> Vec<Prop> {
    vec![Prop::Scalar(t, "x"), Prop::Scalar(t, "y"), Prop::Scalar(t, "z")]
}

fn xyz_values(p: [f64; 3]) -> Vec<Value> {
    p.iter().map(|&c| Value::One(c)).collect()
}

/// Writes `bytes` as `name` and as `name.gz`; returns both paths.
fn write_plain_and_gzipped(dir: &Path, name: &str, bytes: &[u8]) -> [std::path::PathBuf; 2] {
    let plain = dir.join(name);
    let gz = dir.join(format!("{name}.gz"));
    std::fs::write(&plain, bytes).unwrap();
    std::fs::write(&gz, gzip(bytes)).unwrap();
    [plain, gz]
}

#[test]
fn ply_encodings_and_gzip_give_identical_triangles() {
    let dir = temp_dir();
    let want = fans(&VERTICES, &FACES);
    assert_eq!(want.len(), 6, "1 + 2 + 3 triangles from a triangle, a quadrilateral and a pentagon");
    for format in FORMATS {
        let bytes = ply(
            format,
            &[
                vertex_element(xyz(Ty::Float), xyz_values),
                face_element(vec![Prop::List(Ty::UChar, Ty::Int, "vertex_indices")], |f| vec![indices(f)]),
            ],
        );
        for path in write_plain_and_gzipped(dir.path(), &format!("mesh_{format:?}.ply"), &bytes) {
            assert_eq!(triangles(&path), want, "{}", path.display());
        }
    }
    // A bare gzipped mesh is named without its extensions.
    assert_eq!(Scene::load(&dir.path().join("mesh_Ascii.ply.gz")).unwrap().name, "mesh_Ascii");
}

#[test]
fn ply_extra_elements_and_properties_are_ignored() {
    let dir = temp_dir();
    let want = fans(&VERTICES, &FACES);
    for format in FORMATS {
        let vertex = vertex_element(
            vec![
                Prop::Scalar(Ty::Double, "confidence"),
                Prop::Scalar(Ty::Float, "x"),
                Prop::Scalar(Ty::UChar, "red"),
                Prop::Scalar(Ty::Float, "y"),
                Prop::List(Ty::UChar, Ty::Float, "uv"),
                Prop::Scalar(Ty::Float, "z"),
                Prop::Scalar(Ty::Short, "flags"),
            ],
            |p| {
                vec![
                    Value::One(0.25),
                    Value::One(p[0]),
                    Value::One(200.0),
                    Value::One(p[1]),
                    Value::Many(vec![0.5, 0.75]),
                    Value::One(p[2]),
                    Value::One(-7.0),
                ]
            },
        );
        let edge = Element {
            name: "edge",
            props: vec![Prop::Scalar(Ty::Int, "vertex1"), Prop::Scalar(Ty::Int, "vertex2")],
            rows: vec![vec![Value::One(0.0), Value::One(1.0)], vec![Value::One(2.0), Value::One(3.0)]],
        };
        let face = face_element(
            vec![
                Prop::Scalar(Ty::UChar, "kind"),
                Prop::List(Ty::Int, Ty::UInt, "vertex_index"),
                Prop::List(Ty::UChar, Ty::Float, "texcoord"),
            ],
            |f| vec![Value::One(3.0), indices(f), Value::Many(vec![0.0; 2 * f.len()])],
        );
        let material = Element {
            name: "material",
            props: vec![Prop::List(Ty::UChar, Ty::UChar, "name"), Prop::Scalar(Ty::Float, "shininess")],
            rows: vec![vec![Value::Many(vec![104.0, 105.0]), Value::One(0.5)]],
        };
        let empty = Element { name: "empty", props: vec![Prop::Scalar(Ty::Int, "n")], rows: vec![] };
        let bytes = ply(format, &[vertex, edge, face, material, empty]);
        for path in write_plain_and_gzipped(dir.path(), &format!("extras_{format:?}.ply"), &bytes) {
            assert_eq!(triangles(&path), want, "{}", path.display());
        }
    }
}

#[test]
fn ply_big_endian_doubles_and_integer_coordinates() {
    let dir = temp_dir();
    // Doubles that f32 cannot hold exactly load as their nearest f32.
    let doubles: [[f64; 3]; 6] = VERTICES.map(|p| p.map(|c| c * 1.1 + 0.1));
    let want = fans(&doubles, &FACES);
    for format in FORMATS {
        let vertex =
            Element { name: "vertex", props: xyz(Ty::Double), rows: doubles.iter().map(|&p| xyz_values(p)).collect() };
        let face = face_element(vec![Prop::List(Ty::UShort, Ty::Short, "vertex_indices")], |f| vec![indices(f)]);
        let path = dir.path().join(format!("doubles_{format:?}.ply"));
        std::fs::write(&path, ply(format, &[vertex, face])).unwrap();
        assert_eq!(triangles(&path), want, "{}", path.display());
    }
    // Integer coordinates of every integer type.
    let ints: [[f64; 3]; 6] = VERTICES.map(|p| p.map(|c| (c * 4.0).round() + 2.0));
    let want = fans(&ints, &FACES);
    for format in FORMATS {
        let vertex = Element {
            name: "vertex",
            props: vec![Prop::Scalar(Ty::Short, "x"), Prop::Scalar(Ty::UShort, "y"), Prop::Scalar(Ty::Char, "z")],
            rows: ints.iter().map(|&p| xyz_values(p)).collect(),
        };
        let face = face_element(vec![Prop::List(Ty::Char, Ty::UChar, "vertex_indices")], |f| vec![indices(f)]);
        let path = dir.path().join(format!("ints_{format:?}.ply"));
        std::fs::write(&path, ply(format, &[vertex, face])).unwrap();
        assert_eq!(triangles(&path), want, "{}", path.display());
    }
}

#[test]
fn ply_binary_errors_name_the_vertex_or_face() {
    let dir = temp_dir();
    let cases: Vec<(&str, Vec<Element>, &str)> = vec![
        (
            "nan.ply",
            vec![
                Element {
                    name: "vertex",
                    props: xyz(Ty::Double),
                    rows: vec![xyz_values([0.0; 3]), xyz_values([1.0, f64::NAN, 0.0]), xyz_values([0.0, 1.0, 0.0])],
                },
                Element {
                    name: "face",
                    props: vec![Prop::List(Ty::UChar, Ty::Int, "vertex_indices")],
                    rows: vec![vec![indices(&[0, 1, 2])]],
                },
            ],
            "vertex 1 has a non-finite coordinate (y = NaN)",
        ),
        (
            "overflow.ply",
            vec![
                Element {
                    name: "vertex",
                    props: xyz(Ty::Double),
                    rows: vec![xyz_values([0.0; 3]), xyz_values([1.0, 0.0, 0.0]), xyz_values([1e300, 1.0, 0.0])],
                },
                Element {
                    name: "face",
                    props: vec![Prop::List(Ty::UChar, Ty::Int, "vertex_indices")],
                    rows: vec![vec![indices(&[0, 1, 2])]],
                },
            ],
            "vertex 2 has a non-finite coordinate (x = inf)",
        ),
        (
            "negative.ply",
            vec![
                vertex_element(xyz(Ty::Float), xyz_values),
                Element {
                    name: "face",
                    props: vec![Prop::List(Ty::UChar, Ty::Char, "vertex_indices")],
                    rows: vec![vec![indices(&[0, 1, 2])], vec![Value::Many(vec![0.0, -3.0, 2.0])]],
                },
            ],
            "face 1: vertex index -3 is out of range (the file has 6 vertices)",
        ),
        (
            "range.ply",
            vec![
                vertex_element(xyz(Ty::Float), xyz_values),
                Element {
                    name: "face",
                    props: vec![Prop::List(Ty::UChar, Ty::UInt, "vertex_indices")],
                    rows: vec![vec![indices(&[0, 1, 6])]],
                },
            ],
            "face 0: vertex index 6 is out of range (the file has 6 vertices)",
        ),
        (
            "point.ply",
            vec![
                vertex_element(xyz(Ty::Float), xyz_values),
                Element {
                    name: "face",
                    props: vec![Prop::List(Ty::UChar, Ty::Int, "vertex_indices")],
                    rows: vec![vec![indices(&[0, 1, 2])], vec![indices(&[3])]],
                },
            ],
            "face 1 has 1 vertices; a face needs at least 3",
        ),
    ];
    for (name, elements, expect) in cases {
        for format in [Format::Little, Format::Big] {
            let path = dir.path().join(name);
            std::fs::write(&path, ply(format, &elements)).unwrap();
            let message = load_error(&path);
            assert!(message.contains(name) && message.ends_with(expect), "{format:?}: '{message}' lacks '{expect}'");
        }
    }
}

#[test]
fn gzipped_obj_loads_like_obj() {
    let dir = temp_dir();
    let obj =
        "o first\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no second\nv 0 0 2\nv 1 0 2\nv 0 1 2\nf -3 -2 -1\n";
    let [plain, gz] = write_plain_and_gzipped(dir.path(), "two.obj", obj.as_bytes());
    let want = vec![
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)],
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)],
        [Vec3::new(0.0, 0.0, 2.0), Vec3::new(1.0, 0.0, 2.0), Vec3::new(0.0, 1.0, 2.0)],
    ];
    assert_eq!(triangles(&plain), want);
    assert_eq!(triangles(&gz), want);
}

// --- glTF -----------------------------------------------------------------------------

/// A glTF binary buffer being filled, each piece aligned to 4 bytes.
#[derive(Default)]
struct Buffer {
    bytes: Vec<u8>,
    views: Vec<serde_json::Value>,
}

impl Buffer {
    /// Appends `data` as a new buffer view; returns its index.
    fn view(&mut self, data: &[u8]) -> usize {
        while !self.bytes.len().is_multiple_of(4) {
            self.bytes.push(0);
        }
        self.views.push(json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() }));
        self.bytes.extend_from_slice(data);
        self.views.len() - 1
    }
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn position_accessor(view: usize, count: usize) -> serde_json::Value {
    json!({ "bufferView": view, "componentType": 5126, "count": count, "type": "VEC3",
            "min": [-10.0, -10.0, -10.0], "max": [10.0, 10.0, 10.0] })
}

/// The document `doc` with `buffer` as buffer 0, in the container `kind` names:
/// "data" (a data: URI), "file" (a .bin beside it), "glb", and either gzipped (".gz").
fn write_gltf(dir: &Path, stem: &str, kind: &str, mut doc: serde_json::Value, buffer: &Buffer) -> std::path::PathBuf {
    doc["bufferViews"] = json!(buffer.views);
    let length = buffer.bytes.len();
    let (bytes, ext) = match kind.trim_end_matches(".gz") {
        "data" => {
            let data = base64::engine::general_purpose::STANDARD.encode(&buffer.bytes);
            doc["buffers"] =
                json!([{ "byteLength": length, "uri": format!("data:application/octet-stream;base64,{data}") }]);
            (serde_json::to_vec(&doc).unwrap(), "gltf")
        }
        "file" => {
            // A space in the name exercises the URI's percent-decoding.
            std::fs::write(dir.join(format!("{stem} data.bin")), &buffer.bytes).unwrap();
            doc["buffers"] = json!([{ "byteLength": length, "uri": format!("{stem}%20data.bin") }]);
            (serde_json::to_vec(&doc).unwrap(), "gltf")
        }
        _ => {
            doc["buffers"] = json!([{ "byteLength": length }]);
            let mut text = serde_json::to_vec(&doc).unwrap();
            while !text.len().is_multiple_of(4) {
                text.push(b' ');
            }
            let mut bin = buffer.bytes.clone();
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            let total = 12 + 8 + text.len() + 8 + bin.len();
            let mut glb = Vec::new();
            glb.extend(b"glTF");
            glb.extend(2u32.to_le_bytes());
            glb.extend((total as u32).to_le_bytes());
            glb.extend((text.len() as u32).to_le_bytes());
            glb.extend(b"JSON");
            glb.extend(text);
            glb.extend((bin.len() as u32).to_le_bytes());
            glb.extend(b"BIN\0");
            glb.extend(bin);
            (glb, "glb")
        }
    };
    let gz = kind.ends_with(".gz");
    let path = dir.join(format!("{stem}_{}.{ext}{}", kind.trim_end_matches(".gz"), if gz { ".gz" } else { "" }));
    std::fs::write(&path, if gz { gzip(&bytes) } else { bytes }).unwrap();
    path
}

const CONTAINERS: [&str; 5] = ["data", "file", "glb", "glb.gz", "data.gz"];

#[test]
fn gltf_node_hierarchy_composes_trs_and_matrix() {
    let dir = temp_dir();
    let mut buffer = Buffer::default();
    let positions = buffer.view(&f32_bytes(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]));
    let indices = buffer.view(&[0u16, 1, 2].map(u16::to_le_bytes).concat());
    let half = std::f32::consts::FRAC_1_SQRT_2;
    let doc = json!({
        "asset": { "version": "2.0" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [
            // 90° about z: (x, y, z) → (-y, x, z), after the scale and before the translation.
            { "translation": [1.0, 2.0, 3.0], "rotation": [0.0, 0.0, half, half], "scale": [2.0, 2.0, 2.0],
              "mesh": 0, "children": [1] },
            // Column-major: x scaled by 3, then translated by (0, 0, 5).
            { "matrix": [3.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 5.0, 1.0], "mesh": 0 }
        ],
        "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
        "accessors": [
            position_accessor(positions, 3),
            { "bufferView": indices, "componentType": 5123, "count": 3, "type": "SCALAR" }
        ]
    });
    // By hand: the parent maps p to T + R(2p); the child first maps p to (3x, y, z + 5).
    // (1,0,0): parent (1,4,3); child (3,0,5) → (1, 2 + 6, 3 + 10) = (1,8,13).
    // (0,1,0): parent (-1,2,3); child (0,1,5) → (1 - 2, 2, 13) = (-1,2,13).
    // (0,0,1): parent (1,2,5); child (0,0,6) → (1, 2, 3 + 12) = (1,2,15).
    let want = [
        [Vec3::new(1.0, 4.0, 3.0), Vec3::new(-1.0, 2.0, 3.0), Vec3::new(1.0, 2.0, 5.0)],
        [Vec3::new(1.0, 8.0, 13.0), Vec3::new(-1.0, 2.0, 13.0), Vec3::new(1.0, 2.0, 15.0)],
    ];
    for kind in CONTAINERS {
        let path = write_gltf(dir.path(), "hierarchy", kind, doc.clone(), &buffer);
        assert_close(&triangles(&path), &want, kind);
    }
    // The object transform of a scene file applies on top of the hierarchy.
    let path = write_gltf(dir.path(), "hierarchy", "glb", doc, &buffer);
    let moved = load_mesh(&path, 0.5, &Mat4::from_translation(Vec3::new(0.0, 0.0, -3.0))).unwrap();
    let shifted: Vec<[Vec3; 3]> = want.iter().map(|t| t.map(|p| p - Vec3::new(0.0, 0.0, 3.0))).collect();
    assert_close(&moved.iter().map(|t| t.v).collect::<Vec<_>>(), &shifted, "object transform");
    assert!(moved.iter().all(|t| t.albedo == 0.5));
}

#[test]
fn gltf_primitive_modes_and_index_types() {
    let dir = temp_dir();
    let mut buffer = Buffer::default();
    // A unit square in z = 0: 0 (0,0), 1 (1,0), 2 (0,1), 3 (1,1).
    let square = buffer.view(&f32_bytes(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0]));
    let u8s = buffer.view(&[0u8, 1, 2]);
    let u16s = buffer.view(&[1u16, 3, 2].map(u16::to_le_bytes).concat());
    let u32s = buffer.view(&[0u32, 1, 3, 2].map(u32::to_le_bytes).concat());
    let doc = json!({
        "asset": { "version": "2.0" },
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": [
            { "attributes": { "POSITION": 0 }, "indices": 1 },
            { "attributes": { "POSITION": 0 }, "indices": 2, "mode": 4 },
            { "attributes": { "POSITION": 0 }, "mode": 5 },
            { "attributes": { "POSITION": 0 }, "indices": 3, "mode": 6 },
            { "attributes": { "POSITION": 0 }, "mode": 0 },
            { "attributes": { "POSITION": 0 }, "indices": 3, "mode": 1 }
        ] }],
        "accessors": [
            position_accessor(square, 4),
            { "bufferView": u8s, "componentType": 5121, "count": 3, "type": "SCALAR" },
            { "bufferView": u16s, "componentType": 5123, "count": 3, "type": "SCALAR" },
            { "bufferView": u32s, "componentType": 5125, "count": 4, "type": "SCALAR" }
        ]
    });
    let p = |i: usize| [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.0)][i];
    let want = [
        [p(0), p(1), p(2)], // TRIANGLES, u8
        [p(1), p(3), p(2)], // TRIANGLES, u16
        [p(0), p(1), p(2)], // TRIANGLE_STRIP, no indices: (0,1,2), then (2,1,3) keeps the winding
        [p(2), p(1), p(3)],
        [p(0), p(1), p(3)], // TRIANGLE_FAN, u32: (0,1,3), (0,3,2)
        [p(0), p(3), p(2)],
    ];
    let path = write_gltf(dir.path(), "modes", "data", doc, &buffer);
    assert_eq!(triangles(&path), want);
    // The skipped points and lines reach the caller as a warning naming the file, not as
    // output of the library.
    let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    let warning = scene.warnings[0].to_string();
    assert!(warning.contains("modes_data.gltf"), "{warning}");
    assert!(warning.ends_with("skipped 2 primitives that are not triangles: 1 LINES, 1 POINTS"), "{warning}");
}

#[test]
fn gltf_quantized_and_sparse_positions() {
    let dir = temp_dir();
    let mut buffer = Buffer::default();
    // KHR_mesh_quantization: normalized i16 (c / 32767, at least -1) and plain u8.
    let shorts = buffer.view(&[32767i16, 0, -32768, 0, 16384, 0, -12000, 0, 32767].map(i16::to_le_bytes).concat());
    let bytes = buffer.view(&[9u8, 0, 0, 0, 9, 5, 0, 0, 9, 0, 7, 0]);
    // Sparse: vertex 1 of a float triangle replaced; a zero accessor given two vertices.
    let floats = buffer.view(&f32_bytes(&[0.0, 0.0, 0.0, 9.0, 9.0, 9.0, 0.0, 1.0, 0.0]));
    let sparse_index = buffer.view(&[1u8]);
    let sparse_value = buffer.view(&f32_bytes(&[1.0, 0.0, 0.0]));
    let zero_indices = buffer.view(&[1u16, 2].map(u16::to_le_bytes).concat());
    let zero_values = buffer.view(&f32_bytes(&[0.0, 0.0, 4.0, 0.0, 4.0, 0.0]));
    let minmax = json!({ "min": [-10.0, -10.0, -10.0], "max": [10.0, 10.0, 10.0] });
    let mut accessors = vec![
        json!({ "bufferView": shorts, "componentType": 5122, "normalized": true, "count": 3, "type": "VEC3" }),
        json!({ "bufferView": bytes, "byteOffset": 1, "componentType": 5121, "count": 3, "type": "VEC3" }),
        json!({ "bufferView": floats, "componentType": 5126, "count": 3, "type": "VEC3",
                "sparse": { "count": 1, "indices": { "bufferView": sparse_index, "componentType": 5121 },
                            "values": { "bufferView": sparse_value } } }),
        json!({ "componentType": 5126, "count": 3, "type": "VEC3",
                "sparse": { "count": 2, "indices": { "bufferView": zero_indices, "componentType": 5123 },
                            "values": { "bufferView": zero_values } } }),
    ];
    for a in &mut accessors {
        a["min"] = minmax["min"].clone();
        a["max"] = minmax["max"].clone();
    }
    // The u8 accessor starts one byte into its view, one element every 4 bytes.
    buffer.views[bytes]["byteStride"] = json!(4);
    let doc = json!({
        "asset": { "version": "2.0" },
        "extensionsUsed": ["KHR_mesh_quantization"],
        "extensionsRequired": ["KHR_mesh_quantization"],
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0 }],
        "meshes": [{ "primitives": (0..4).map(|a| json!({ "attributes": { "POSITION": a } })).collect::<Vec<_>>() }],
        "accessors": accessors
    });
    let want = [
        [Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 16384.0 / 32767.0, 0.0), Vec3::new(-12000.0 / 32767.0, 0.0, 1.0)],
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(5.0, 0.0, 0.0), Vec3::new(0.0, 7.0, 0.0)],
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 0.0)],
        [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 4.0), Vec3::new(0.0, 4.0, 0.0)],
    ];
    for kind in ["data", "glb"] {
        let path = write_gltf(dir.path(), "quantized", kind, doc.clone(), &buffer);
        assert_eq!(triangles(&path), want, "{kind}");
    }
}

#[test]
fn required_extensions_are_refused_by_name_unless_supported() {
    let dir = temp_dir();
    let mut buffer = Buffer::default();
    let positions = buffer.view(&f32_bytes(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]));
    let doc = |required: &str| {
        json!({
            "asset": { "version": "2.0" },
            "extensionsUsed": [required],
            "extensionsRequired": [required],
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0 }],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 } }] }],
            "accessors": [position_accessor(positions, 3)]
        })
    };
    let path = write_gltf(dir.path(), "unknown", "glb", doc("EXT_made_up_geometry"), &buffer);
    let message = load_error(&path);
    assert!(message.contains("unknown_glb.glb") && message.contains("EXT_made_up_geometry"), "{message}");
    // An extension that changes only materials leaves the geometry as it is.
    let path = write_gltf(dir.path(), "unlit", "glb", doc("KHR_materials_unlit"), &buffer);
    assert_eq!(triangles(&path).len(), 1);
    // The shared Suzanne is Draco-compressed, which no well-kept Rust crate decodes.
    let message = load_error(&repo().join("scenes/suzanne-meshopt.glb"));
    assert!(message.contains("suzanne-meshopt.glb") && message.contains("KHR_draco_mesh_compression"), "{message}");
}

// --- The meshes in scenes/ ------------------------------------------------------------

/// Each mesh of `scenes/` and its triangles after the zero-area ones are dropped: the
/// counts of `scenes/README.md`, except where a comment says why not.
const SCENE_MESHES: [(&str, usize); 7] = [
    ("bunny.obj", 69_451),
    ("teapot.obj", 6_320),
    ("dragon_vrip_res4.ply.gz", 11_102),
    ("dragon_vrip_res3.ply.gz", 47_794),
    ("dragon_vrip_res2.ply.gz", 202_520),
    // 871,414 faces; in 108 of them two distinct vertices have the same coordinates.
    ("dragon_vrip.ply.gz", 871_306),
    // 121,496 through the node hierarchy; 11,154 repeat a vertex index (110,342 do not, the
    // count other tools give) and 6 more have two corners at the same position.
    ("2CylinderEngine.glb", 110_336),
];

#[test]
fn every_mesh_in_scenes_loads_with_its_triangle_count() {
    for (file, kept) in SCENE_MESHES {
        let path = repo().join("scenes").join(file);
        let start = std::time::Instant::now();
        let scene = Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
        eprintln!("{file}: {} triangles in {:.2} s", scene.triangles.len(), start.elapsed().as_secs_f64());
        assert_eq!(scene.triangles.len(), kept, "{file}");
        let b = scene.bounds().expect("bounds");
        assert!((b.max - b.min).min_element() > 0.0, "{file}: flat bounds {b:?}");
    }
}

/// A scene file that places one mesh file several times (read once) gives exactly the
/// triangles of loading each placement on its own, in object order.
#[test]
fn a_mesh_placed_several_times_gives_each_placement() {
    let dir = temp_dir();
    let d = dir.path();
    let mesh = repo().join("scenes").join("dragon_vrip_res4.ply.gz");
    let teapot = repo().join("scenes").join("teapot.obj");
    let placements = [
        Mat4::IDENTITY,
        Mat4::from_scale_rotation_translation(
            Vec3::splat(2.0),
            glam::Quat::from_rotation_y(30f32.to_radians()),
            Vec3::new(1.0, 0.0, -1.0),
        ),
        Mat4::from_translation(Vec3::new(-3.0, 0.5, 0.0)),
    ];
    let object = |file: &Path, m: &Mat4, albedo: f32| {
        let cols = m.to_cols_array_2d();
        let rows: Vec<String> =
            (0..4).map(|r| format!("[{}, {}, {}, {}]", cols[0][r], cols[1][r], cols[2][r], cols[3][r])).collect();
        format!(
            "[[object]]\ntype = \"mesh\"\nfile = \"{}\"\nalbedo = {albedo}\ntransform = {{ matrix = [{}] }}\n\n",
            file.display(),
            rows.join(", ")
        )
    };
    let mut text = String::from(
        "[camera]\ntype = \"perspective\"\neye = [0.0, 1.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 45.0\n\n",
    );
    text += &object(&mesh, &placements[0], 0.5);
    text += &object(&teapot, &placements[0], 0.7);
    text += &object(&mesh, &placements[1], 0.6);
    text += &object(&mesh, &placements[2], 0.8);
    let scene_path = d.join("placed.toml");
    std::fs::write(&scene_path, text).unwrap();
    let scene = Scene::load(&scene_path).unwrap_or_else(|e| panic!("{e}"));

    // The mesh placed three times is kept once, as three instances; the teapot, placed
    // once, is in the world. Flattened, the instances follow it in their order.
    assert_eq!((scene.meshes.len(), scene.instances.len()), (1, 3));
    let flat = scene.flattened().triangles;
    let mut want = load_mesh(&teapot, 0.7, &placements[0]).unwrap();
    want.extend(load_mesh(&mesh, 0.5, &placements[0]).unwrap());
    want.extend(load_mesh(&mesh, 0.6, &placements[1]).unwrap());
    want.extend(load_mesh(&mesh, 0.8, &placements[2]).unwrap());
    assert_eq!(flat.len(), want.len());
    assert!(flat == want, "the placements differ from loading each on its own");
    // The placements are distinct: a cache that reused the first one would repeat it.
    let n = load_mesh(&mesh, 1.0, &Mat4::IDENTITY).unwrap().len();
    let teapot_n = load_mesh(&teapot, 1.0, &Mat4::IDENTITY).unwrap().len();
    assert_ne!(flat[teapot_n].v, flat[teapot_n + n].v);
}

#[test]
fn loading_holds_at_most_two_copies_of_the_geometry() {
    // The indexed mesh (12 bytes a vertex and a triangle) and the triangles returned (40
    // bytes each) may be alive together; for glTF the file's bytes and the indexed mesh
    // are, before the file is dropped. Fixed costs (read buffers, the gzip window) are
    // below 1 MiB.
    const FIXED: usize = 1 << 20;
    for (file, vertices) in [("dragon_vrip_res2.ply.gz", 100_250), ("2CylinderEngine.glb", 0)] {
        let path = repo().join("scenes").join(file);
        let (loaded, largest, peak) = measured(|| load_mesh(&path, 1.0, &Mat4::IDENTITY));
        let t = loaded.unwrap_or_else(|e| panic!("{e}")).len();
        let output = t * std::mem::size_of::<aorender::scene::Triangle>();
        let file_bytes = std::fs::metadata(&path).unwrap().len() as usize;
        // glTF vertices are not counted from the file: bound them by its size.
        let vertex_bytes = if vertices > 0 { 12 * vertices } else { file_bytes };
        let indexed = vertex_bytes + 12 * t;
        let two_copies =
            if file.ends_with(".glb") { (file_bytes + indexed).max(indexed + output) } else { indexed + output };
        eprintln!("{file}: peak {peak} bytes, largest block {largest}, two copies {two_copies}");
        assert!(peak <= two_copies + FIXED, "{file}: peak {peak} bytes > {two_copies} + {FIXED}");
    }
}

/// The read budget bounds what a load holds: a budget the loaders' charges fit in is at
/// least the heap the load really peaks at (less the fixed costs the budget leaves out:
/// read buffers, the gzip window, a line), and not more than three times it. The smallest
/// such budget is found by bisection, for every format, through a scene file that places
/// meshes once and several times.
#[test]
fn the_read_budget_bounds_the_memory_a_load_holds() {
    const FIXED: usize = 2 << 20;
    let dir = temp_dir();
    let scenes = repo().join("scenes");
    let scene_file = dir.path().join("placed.toml");
    let object = |file: &str, x: f32| {
        let path = scenes.join(file);
        format!("[[object]]\ntype = \"mesh\"\nfile = {:?}\ntransform = {{ translate = [{x}, 0.0, 0.0] }}\n\n", path)
    };
    let text = "[camera]\ntype = \"perspective\"\neye = [0.0, 1.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 45.0\n\n"
        .to_string()
        + &object("teapot.obj", 0.0)
        + &object("dragon_vrip_res3.ply.gz", 1.0)
        + &object("dragon_vrip_res3.ply.gz", 2.0)
        + &object("bunny.obj", 3.0);
    std::fs::write(&scene_file, text).unwrap();
    let files = [
        scenes.join("bunny.obj"),
        scenes.join("teapot.obj"),
        scenes.join("dragon_vrip_res2.ply.gz"),
        scenes.join("2CylinderEngine.glb"),
        scene_file,
    ];
    let load = |path: &Path, budget: u64| {
        let options = LoadOptions { limits: ReadLimits::with_memory(budget), allow_external_uris: false };
        Scene::load_with(path, &options)
    };
    for path in &files {
        let name = path.file_name().unwrap().to_string_lossy();
        let (scene, _, peak) = measured(|| load(path, u64::MAX));
        scene.unwrap_or_else(|e| panic!("{e}"));
        // The smallest budget that loads the file: the loaders' charges.
        let (mut low, mut high) = (0u64, 64 * peak as u64);
        while high - low > (peak as u64 / 256).max(1) {
            let mid = (low + high) / 2;
            match load(path, mid) {
                Ok(_) => high = mid,
                Err(e) => {
                    let message = e.to_string();
                    assert!(message.contains("the read budget (as set by the caller)"), "{name}: {message}");
                    low = mid;
                }
            }
        }
        eprintln!("{name}: heap peak {peak} bytes, smallest budget {high} ({:.2} times)", high as f64 / peak as f64);
        assert!(high as usize + FIXED >= peak, "{name}: loads within {high} bytes but holds {peak}");
        assert!(high <= 3 * peak as u64, "{name}: needs a budget of {high} bytes for a load that holds {peak}");
    }
}

#[test]
fn gpu_and_cpu_agree_on_loaded_meshes() {
    if !gpu_available() {
        return;
    }
    for file in ["dragon_vrip_res4.ply.gz", "2CylinderEngine.glb"] {
        let mut scene = Scene::load(&repo().join("scenes").join(file)).unwrap_or_else(|e| panic!("{e}"));
        scene.settings.width = 32;
        scene.settings.height = 32;
        scene.settings.spp = 64;
        scene.settings.sampling.hemisphere = Hemisphere::Cosine;
        scene.settings.sampling.sampler = Sampler::Independent;
        scene.settings.sampling.seed = 1;
        let gpu = render_on(&scene, DeviceKind::Gpu);
        scene.settings.sampling.seed = 2;
        let cpu = render_on(&scene, DeviceKind::Cpu);
        // Independent renders: the image means within 4 combined standard errors.
        let (mg, mc) = (gpu.image_mean(), cpu.image_mean());
        let (sg, sc) = (image_mean_std_error(&gpu), image_mean_std_error(&cpu));
        let sigma = (sg * sg + sc * sc).sqrt();
        eprintln!("{file}: GPU {mg:.5}, CPU {mc:.5}, σ {sigma:.2e}");
        assert!(sigma > 0.0, "{file}: zero variance, the test could not detect a difference");
        assert!(mg > 0.01, "{file}: the mesh is not in view (mean {mg})");
        assert!(
            (mg - mc).abs() <= 4.0 * sigma,
            "{file}: means {mg} (GPU) and {mc} (CPU) differ by more than 4σ = {}",
            4.0 * sigma
        );
    }
}

// --- The malformed corpus ---------------------------------------------------------------

/// Every file of `tests/malformed/` and a part of the error it must give.
const MALFORMED: &[(&str, &str)] = &[
    ("glb_bad_chunk_length.glb", "the GLB JSON chunk declares 100000 bytes but only 404 follow"),
    ("glb_length_past_end.glb", "the GLB header declares 1424 bytes but the file has 424"),
    ("glb_length_too_small.glb", "the GLB header declares 8 bytes, too few for a JSON chunk"),
    ("glb_truncated.glb.gz", "invalid or truncated gzip data"),
    ("glb_version_1.glb", "GLB version 1 is not supported"),
    ("gltf_accessor_out_of_bounds.gltf", "100 elements from byte 0 of buffer view 0 run past its 36 bytes"),
    ("gltf_bad_json.gltf", "invalid glTF JSON"),
    ("gltf_empty_accessor.gltf", "mesh has no triangles"),
    ("gltf_huge_count_without_view.gltf", "accessor 0 declares 4000000000 elements, more than the file's"),
    // The index's value is the file's data: never shown.
    ("gltf_index_out_of_range.gltf", "index 2 is out of range for the 3 vertices of accessor 0"),
    ("gltf_missing_buffer.gltf", "buffer 0: "),
    ("gltf_node_cycle.gltf", "node 0 is reached twice"),
    ("gltf_position_accessor_missing.gltf", "POSITION accessor 7 does not exist"),
    ("gltf_required_extension.gltf", "requires the glTF extension EXT_meshopt_compression"),
    ("gltf_view_outside_buffer.gltf", "buffer view 0 (36 bytes from byte 24) lies outside buffer 0 of 36 bytes"),
    ("obj_face_out_of_range.obj", "invalid OBJ: face vertex index out of bounds"),
    ("obj_truncated.obj.gz", "invalid or truncated gzip data"),
    ("ply_4294967295_vertices.ply", "unexpected end of file in vertex 3 of 4294967295"),
    ("ply_bad_magic.ply", "not a PLY file"),
    ("ply_face_count_too_large.ply", "unexpected end of file in face 2 of 5"),
    ("ply_float_indices.ply", "vertex_indices must be a list of integers"),
    ("ply_huge_face_list.ply", "unexpected end of file in face 0 of 1"),
    ("ply_missing_z.ply", "the vertex element has no z property"),
    ("ply_nan_vertex.ply", "vertex 1 has a non-finite coordinate (y = NaN)"),
    ("ply_negative_vertex_index.ply", "face 1: vertex index -1 is out of range"),
    ("ply_no_faces.ply", "no face element"),
    ("ply_truncated.ply.gz", "invalid or truncated gzip data"),
    ("ply_truncated_ascii.ply", "face 0 of 2"),
    ("ply_truncated_binary.ply", "unexpected end of file in vertex 2 of 4"),
    ("ply_two_vertex_face.ply", "face 0 has 2 vertices"),
    ("ply_vertex_count_too_small.ply", "face 0 has 0 vertices"),
    ("ply_vertex_index_out_of_range.ply", "face 1: vertex index 7 is out of range"),
];

#[test]
fn malformed_files_are_errors_without_panics_or_large_allocations() {
    let dir = crate_dir().join("tests/malformed");
    let mut files: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    files.sort();
    let listed: Vec<&str> = MALFORMED.iter().map(|(f, _)| *f).collect();
    assert_eq!(files, listed, "tests/malformed/ and MALFORMED must list the same files");
    for (file, expect) in MALFORMED {
        let path = dir.join(file);
        let size = std::fs::metadata(&path).unwrap().len() as usize;
        let (result, largest, _) = measured(|| std::panic::catch_unwind(|| Scene::load(&path).map(|_| ())));
        let message = match result {
            Err(_) => panic!("{file}: the loader panicked"),
            Ok(Ok(())) => panic!("{file}: loaded"),
            Ok(Err(e)) => e.to_string(),
        };
        assert!(message.contains(file) && message.contains(expect), "{file}: '{message}' lacks '{expect}'");
        assert!(!message.contains('\n'), "{file}: '{message}' is more than one line");
        // Read buffers (64 KiB), the gzip window and ply-rs's list preallocation (at most
        // 65,536 entries) are fixed costs, and parsing JSON takes a small multiple of its
        // text; beyond them nothing may scale with a count the file's bytes do not back.
        const FIXED: usize = 1 << 20;
        assert!(largest <= FIXED + 64 * size, "{file} ({size} bytes): an allocation of {largest} bytes");
    }
}
