//! WGSL sources: the files in `shaders/`, joined by their `//#import` lines, behind a
//! generated header that defines the constants and structs Rust and WGSL share (so each
//! is written once, in Rust: [`super::layout`]), with the bindings and the geometry's
//! accessors generated for the render at hand.

use super::layout::{GROUP_LANES, node_binding, primitive_binding, wgsl_bindings, wgsl_header};
use crate::bvh::BvhLayout;
use crate::error::{Error, Result};

/// Every shader file, by name, compiled into the binary.
pub const FILES: &[(&str, &str)] = &[
    ("ao.wgsl", include_str!("../../shaders/ao.wgsl")),
    ("bindings.wgsl", include_str!("../../shaders/bindings.wgsl")),
    ("cwbvh.wgsl", include_str!("../../shaders/cwbvh.wgsl")),
    ("intersect.wgsl", include_str!("../../shaders/intersect.wgsl")),
    ("per_lane.wgsl", include_str!("../../shaders/per_lane.wgsl")),
    ("sampler.wgsl", include_str!("../../shaders/sampler.wgsl")),
    ("sampling.wgsl", include_str!("../../shaders/sampling.wgsl")),
    ("stats.wgsl", include_str!("../../shaders/stats.wgsl")),
    ("sums.wgsl", include_str!("../../shaders/sums.wgsl")),
    ("trace.wgsl", include_str!("../../shaders/trace.wgsl")),
    ("trace_common.wgsl", include_str!("../../shaders/trace_common.wgsl")),
    ("trace_cwbvh.wgsl", include_str!("../../shaders/trace_cwbvh.wgsl")),
    ("trace_cwbvh_group.wgsl", include_str!("../../shaders/trace_cwbvh_group.wgsl")),
    ("unfused.wgsl", include_str!("../../shaders/unfused.wgsl")),
];

// The traversal and the geometry's storage are named in `kinds`, with the other choices a
// scene is prepared with; what they mean to the kernel is here.
pub use crate::kinds::{GeometryStorage, Traversal};

impl Traversal {
    /// Invocations that trace each ray together.
    pub fn lanes_per_ray(self) -> u32 {
        match self {
            Traversal::PerLane => 1,
            Traversal::Cooperative => GROUP_LANES,
        }
    }
}

/// The traversal file of a BVH layout and traversal; `ao.wgsl` imports `trace.wgsl`,
/// which the composer replaces with this. The cooperative traversal exists for the
/// compressed wide BVH only.
pub fn traversal_file(layout: BvhLayout, traversal: Traversal) -> &'static str {
    match (layout, traversal) {
        (BvhLayout::Bvh2, _) => "trace.wgsl",
        (BvhLayout::Cwbvh, Traversal::PerLane) => "trace_cwbvh.wgsl",
        (BvhLayout::Cwbvh, Traversal::Cooperative) => "trace_cwbvh_group.wgsl",
    }
}

/// The source of `name` with its imports (each once, dependencies first) behind the
/// shared constants. `lookup` maps a file name to its text.
pub fn compose_with<'a>(name: &str, lookup: &dyn Fn(&str) -> Option<&'a str>) -> Result<String> {
    fn visit<'a>(
        name: &str,
        lookup: &dyn Fn(&str) -> Option<&'a str>,
        seen: &mut Vec<String>,
        out: &mut String,
    ) -> Result<()> {
        if seen.iter().any(|s| s == name) {
            return Ok(());
        }
        seen.push(name.to_string());
        let text = lookup(name).ok_or_else(|| Error::Shader(format!("shader file '{name}' not found")))?;
        for line in text.lines() {
            if let Some(dep) = line.trim().strip_prefix("//#import ") {
                visit(dep.trim(), lookup, seen, out)?;
            }
        }
        out.push_str(&format!("// ---- {name}\n"));
        out.push_str(text);
        out.push('\n');
        Ok(())
    }
    let mut out = wgsl_header();
    visit(name, lookup, &mut Vec::new(), &mut out)?;
    Ok(out)
}

impl GeometryStorage {
    /// What suits an adapter of this type: textures on a CPU (lavapipe, where they are
    /// several times faster), storage buffers on a GPU (where the renderer was measured
    /// with them).
    pub fn preferred(device_type: wgpu::DeviceType) -> GeometryStorage {
        match device_type {
            wgpu::DeviceType::Cpu => GeometryStorage::Textures,
            _ => GeometryStorage::Buffers,
        }
    }
}

/// Texels per texture row: a multiple of the texels of every element type (3 for a
/// primitive, 4 for a BVH2 node, 5 for a CWBVH node), so that no element straddles two rows.
pub const ROW_TEXEL_MULTIPLE: u32 = 60;

/// How the BVH nodes and the primitives are split into chunks, each in its own binding
/// (a storage buffer or a texture), so that a scene is not limited to one binding's size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct GeometryChunks {
    /// Buffers or textures.
    pub storage: GeometryStorage,
    /// Bindings holding nodes.
    pub node_chunks: u32,
    /// Nodes in each node binding but the last.
    pub nodes_per_chunk: u32,
    /// Bindings holding primitives.
    pub primitive_chunks: u32,
    /// Primitives in each primitive binding but the last.
    pub primitives_per_chunk: u32,
    /// Texels in a texture row (a multiple of [`ROW_TEXEL_MULTIPLE`]); unused for buffers.
    pub row_texels: u32,
}

impl GeometryChunks {
    /// Everything in one storage buffer each.
    #[cfg(feature = "testing")]
    pub const SINGLE: GeometryChunks = GeometryChunks {
        storage: GeometryStorage::Buffers,
        node_chunks: 1,
        nodes_per_chunk: u32::MAX,
        primitive_chunks: 1,
        primitives_per_chunk: u32::MAX,
        row_texels: 0,
    };
}

/// A geometry element type of the kernel as the texels that hold it.
struct Element {
    /// WGSL type name.
    ty: &'static str,
    /// Texels (16 bytes each) per element.
    texels: u32,
    /// WGSL expression building the element from texels `t0`, `t1`, … (`vec4u` each).
    from_texels: &'static str,
    /// Each texel of an element `@` as a `vec4u` expression, where the traversal reads an
    /// element a texel at a time (`load_node_texel`); empty otherwise.
    texel_fields: &'static [&'static str],
}

const CW_NODE: Element = Element {
    ty: "CwNode",
    texels: 5,
    from_texels: "CwNode(t0, t1, t2, t3, t4)",
    texel_fields: &["@.n0", "@.n1", "@.n2", "@.n3", "@.n4"],
};
const BVH2_NODE: Element = Element {
    ty: "Node",
    texels: 4,
    from_texels: "Node(bitcast<vec3f>(t0.xyz), t0.w, bitcast<vec3f>(t1.xyz), t1.w, \
                  bitcast<vec3f>(t2.xyz), t2.w, bitcast<vec3f>(t3.xyz), t3.w)",
    texel_fields: &[],
};
const PRIMITIVE: Element = Element {
    ty: "Primitive",
    texels: 3,
    from_texels: "Primitive(bitcast<vec4f>(t0), bitcast<vec4f>(t1), bitcast<vec4f>(t2))",
    texel_fields: &[],
};

/// WGSL for `count` chunk bindings of `e` named `name_k`, and `load` returning element
/// i, which lives in chunk i / per_chunk: storage buffers or textures as `chunks` says;
/// for an element read a texel at a time, also `{load}_texel(i, c)`, texel c of element i.
fn chunked_array(
    name: &str,
    e: &Element,
    load: &str,
    count: u32,
    per_chunk: u32,
    binding: fn(u32) -> u32,
    chunks: GeometryChunks,
) -> String {
    let ty = e.ty;
    let mut s = String::new();
    for k in 0..count {
        let b = binding(k);
        s += &match chunks.storage {
            GeometryStorage::Buffers => {
                format!("@group(0) @binding({b}) var<storage, read> {name}_{k}: array<{ty}>;\n")
            }
            GeometryStorage::Textures => {
                format!("@group(0) @binding({b}) var {name}_{k}: texture_storage_2d<rgba32uint, read>;\n")
            }
        };
    }
    let locate = |s: &mut String| {
        *s += &if count == 1 {
            "    let j = i;\n".to_string()
        } else {
            format!("    let chunk = i / {per_chunk}u;\n    let j = i - chunk * {per_chunk}u;\n")
        };
        if chunks.storage == GeometryStorage::Textures {
            let per_row = chunks.row_texels / e.texels;
            *s += &format!("    let y = j / {per_row}u;\n    let x = (j - y * {per_row}u) * {}u;\n", e.texels);
        }
    };
    // `read(k)` as statements ending in a return, in each chunk but the last behind a test.
    let dispatch = |s: &mut String, read: &dyn Fn(u32) -> String| {
        for k in 0..count - 1 {
            *s += &format!("    if (chunk == {k}u) {{\n        {}\n    }}\n", read(k));
        }
        *s += &format!("    {}\n", read(count - 1));
    };
    s += &format!("fn {load}(i: u32) -> {ty} {{\n");
    locate(&mut s);
    // The read of chunk k at index j.
    dispatch(&mut s, &|k| match chunks.storage {
        GeometryStorage::Buffers => format!("return {name}_{k}[j];"),
        GeometryStorage::Textures => {
            let loads: String =
                (0..e.texels).map(|c| format!("let t{c} = textureLoad({name}_{k}, vec2u(x + {c}u, y)); ")).collect();
            format!("{loads}return {};", e.from_texels)
        }
    });
    s += "}\n";
    if !e.texel_fields.is_empty() {
        // Texel c (below e.texels) of element i alone.
        s += &format!("fn {load}_texel(i: u32, c: u32) -> vec4u {{\n");
        locate(&mut s);
        dispatch(&mut s, &|k| match chunks.storage {
            GeometryStorage::Buffers => {
                let texel = |f: &str| f.replace('@', &format!("{name}_{k}[j]"));
                let (last, rest) = e.texel_fields.split_last().expect("texel fields");
                let cases: String =
                    rest.iter().enumerate().map(|(c, f)| format!("case {c}u: {{ return {}; }} ", texel(f))).collect();
                format!("switch c {{ {cases}default: {{ return {}; }} }}", texel(last))
            }
            GeometryStorage::Textures => format!("return textureLoad({name}_{k}, vec2u(x + c, y));"),
        });
        s += "}\n";
    }
    s
}

/// The generated `node_bindings.wgsl` (the node type is the traversal's, and
/// `STACK_SIZE`, the entries of its stack: at least the BVH's depth) and
/// `primitive_bindings.wgsl`.
pub fn geometry_files(layout: BvhLayout, chunks: GeometryChunks, stack_size: u32) -> [(&'static str, String); 2] {
    let node = node_element(layout);
    let header = "// Generated by src/gpu/shaders.rs: the chunk bindings and their accessor.\n";
    [
        (
            "node_bindings.wgsl",
            format!(
                "{header}// Entries of the traversal stack: one per level of the BVH at most.\n\
                 const STACK_SIZE: u32 = {stack_size}u;\n{}",
                chunked_array(
                    "nodes",
                    node,
                    "load_node",
                    chunks.node_chunks,
                    chunks.nodes_per_chunk,
                    node_binding,
                    chunks
                )
            ),
        ),
        (
            "primitive_bindings.wgsl",
            format!(
                "{header}//#import bindings.wgsl\n{}",
                chunked_array(
                    "primitives",
                    &PRIMITIVE,
                    "load_primitive",
                    chunks.primitive_chunks,
                    chunks.primitives_per_chunk,
                    primitive_binding,
                    chunks
                )
            ),
        ),
    ]
}

/// Texels per element of the node type of `layout`, and of a primitive.
#[cfg(feature = "testing")]
pub fn element_texels(layout: BvhLayout) -> (u32, u32) {
    (node_element(layout).texels, PRIMITIVE.texels)
}

/// The node type of `layout`.
fn node_element(layout: BvhLayout) -> &'static Element {
    match layout {
        BvhLayout::Bvh2 => &BVH2_NODE,
        BvhLayout::Cwbvh => &CW_NODE,
    }
}

/// The generated `batch.wgsl`: `batch_max(x)`, the largest `x` among the invocations
/// that call it together in a subgroup, where the device has subgroup operations
/// (`subgroups`); elsewhere `x` itself. lavapipe runs a subgroup as one SIMD batch, whose
/// loop iterations its cap counts together.
pub fn batch_file(subgroups: bool) -> (&'static str, String) {
    let header = "// Generated by src/gpu/shaders.rs: the largest value among the invocations of a batch.\n";
    let body = if subgroups {
        "fn batch_max(x: u32) -> u32 {\n    return subgroupMax(x);\n}\n"
    } else {
        "// The device has no subgroup operations: each invocation stands alone.\n\
         fn batch_max(x: u32) -> u32 {\n    return x;\n}\n"
    };
    ("batch.wgsl", format!("{header}{body}"))
}

/// The composed source of a compiled-in shader file, with the traversal of `layout` as
/// `traversal` says ([`traversal_file`]), its stack of `stack_size` entries, the geometry split as `chunks` says, and `batch_max`
/// from subgroup operations where `subgroups` is set ([`batch_file`]).
///
/// With `AORENDER_SHADER_DIR` set, the files are read from that directory instead of the
/// compiled-in copies (for shader work without rebuilding); a file missing there is an
/// error rather than a silent fallback.
pub fn compose(
    name: &str,
    layout: BvhLayout,
    traversal: Traversal,
    chunks: GeometryChunks,
    stack_size: u32,
    subgroups: bool,
) -> Result<String> {
    let [nodes, primitives] = geometry_files(layout, chunks, stack_size);
    let generated = [nodes, primitives, batch_file(subgroups), ("resources.wgsl", wgsl_bindings())];
    let overridden: Option<Vec<(&str, String)>> = match std::env::var_os(SHADER_DIR_VAR) {
        Some(dir) => Some(
            FILES
                .iter()
                .map(|(f, _)| {
                    let path = std::path::Path::new(&dir).join(f);
                    std::fs::read_to_string(&path)
                        .map(|text| (*f, text))
                        .map_err(|e| Error::Shader(format!("{SHADER_DIR_VAR}: {}: {e}", path.display())))
                })
                .collect::<Result<_>>()?,
        ),
        None => None,
    };
    let lookup = |n: &str| {
        if let Some((_, text)) = generated.iter().find(|(f, _)| *f == n) {
            return Some(text.as_str());
        }
        let n = if n == "trace.wgsl" { traversal_file(layout, traversal) } else { n };
        match &overridden {
            Some(files) => files.iter().find(|(f, _)| *f == n).map(|(_, t)| t.as_str()),
            None => FILES.iter().find(|(f, _)| *f == n).map(|(_, t)| *t),
        }
    };
    compose_with(name, &lookup)
}

/// The environment variable naming a directory to read the shader files from.
pub const SHADER_DIR_VAR: &str = "AORENDER_SHADER_DIR";
