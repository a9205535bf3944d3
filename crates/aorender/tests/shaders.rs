//! Every WGSL file parses and validates with naga (composed with its imports), and the
//! host structs match the WGSL structs' sizes.

use aorender::bvh::{BvhLayout, GpuNode, GpuPrimitive};
use aorender::gpu::layout::{DispatchUniforms, FrameUniforms, GpuPlane, GpuProbePoint, wgsl_bindings};
use aorender::gpu::shaders::{GeometryChunks, GeometryStorage, Traversal, batch_file, compose_with, geometry_files};
use obvhs::cwbvh::node::CwBvhNode;
use std::collections::BTreeMap;

fn shader_files() -> BTreeMap<String, String> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut files = BTreeMap::new();
    for entry in std::fs::read_dir(&dir).expect("shaders/ exists") {
        let path = entry.expect("directory entry").path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            files.insert(name, std::fs::read_to_string(&path).expect("readable shader"));
        }
    }
    files
}

/// Parses and validates `name` with its imports; `trace.wgsl` stands for `traversal`, and
/// the generated geometry bindings are those of `traversal`'s layout split as `chunks`.
fn validate_chunked(
    name: &str,
    traversal: &str,
    chunks: GeometryChunks,
    files: &BTreeMap<String, String>,
) -> naga::Module {
    let layout = if traversal.starts_with("trace_cwbvh") { BvhLayout::Cwbvh } else { BvhLayout::Bvh2 };
    // With batch_max from subgroup operations and without; the cooperative traversal needs them.
    let cooperative = traversal == "trace_cwbvh_group.wgsl" || name == "trace_cwbvh_group.wgsl";
    let variants: &[bool] = if cooperative { &[true] } else { &[true, false] };
    let mut modules = variants.iter().map(|&subgroups| {
        let [nodes, primitives] = geometry_files(layout, chunks, layout.stack_size());
        let generated = [nodes, primitives, batch_file(subgroups), ("resources.wgsl", wgsl_bindings())];
        let lookup = |n: &str| {
            if let Some((_, text)) = generated.iter().find(|(f, _)| *f == n) {
                return Some(text.as_str());
            }
            files.get(if n == "trace.wgsl" { traversal } else { n }).map(|s| s.as_str())
        };
        let source = compose_with(name, &lookup).unwrap_or_else(|e| panic!("{name}: {e}"));
        let module =
            naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&source)));
        let capabilities = if subgroups {
            naga::valid::Capabilities::all()
        } else {
            naga::valid::Capabilities::all() - naga::valid::Capabilities::SUBGROUP
        };
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities)
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name} (subgroups: {subgroups}): {}", e.emit_to_string(&source)));
        module
    });
    let module = modules.next().expect("one variant");
    modules.for_each(drop);
    module
}

fn validate_with(name: &str, traversal: &str, files: &BTreeMap<String, String>) -> naga::Module {
    validate_chunked(name, traversal, GeometryChunks::SINGLE, files)
}

fn validate(name: &str, files: &BTreeMap<String, String>) -> naga::Module {
    // Each traversal file with its own node type.
    let traversal = match name {
        "trace_cwbvh.wgsl" | "trace_cwbvh_group.wgsl" => name,
        "cwbvh.wgsl" => "trace_cwbvh.wgsl",
        _ => "trace.wgsl",
    };
    validate_with(name, traversal, files)
}

#[test]
fn every_shader_file_validates() {
    let files = shader_files();
    assert!(!files.is_empty(), "no .wgsl files found in shaders/");
    for name in files.keys() {
        validate(name, &files);
    }
    // The kernel as the renderer composes it for each layout, with the geometry in one
    // binding each and split into chunks.
    let split = GeometryChunks {
        node_chunks: 3,
        nodes_per_chunk: 1000,
        primitive_chunks: 2,
        primitives_per_chunk: 700,
        ..GeometryChunks::SINGLE
    };
    let textures =
        |chunks: GeometryChunks| GeometryChunks { storage: GeometryStorage::Textures, row_texels: 600, ..chunks };
    for (layout, traversal) in [
        (BvhLayout::Bvh2, Traversal::PerLane),
        (BvhLayout::Cwbvh, Traversal::PerLane),
        (BvhLayout::Cwbvh, Traversal::Cooperative),
    ] {
        for chunks in [GeometryChunks::SINGLE, split, textures(GeometryChunks::SINGLE), textures(split)] {
            let module =
                validate_chunked("ao.wgsl", aorender::gpu::shaders::traversal_file(layout, traversal), chunks, &files);
            let bound = module.global_variables.iter().filter(|(_, g)| g.binding.is_some()).count() as u32;
            assert_eq!(
                bound,
                aorender::gpu::layout::OTHER_STORAGE_BINDINGS + chunks.node_chunks + chunks.primitive_chunks,
                "{layout:?} {chunks:?}"
            );
        }
    }
}

#[test]
fn compiled_in_shaders_are_the_files_on_disk() {
    let files = shader_files();
    let compiled: BTreeMap<String, String> =
        aorender::gpu::shaders::FILES.iter().map(|(n, t)| (n.to_string(), t.to_string())).collect();
    assert_eq!(files, compiled, "src/gpu/shaders.rs FILES must list every file in shaders/");
}

#[test]
fn host_structs_match_wgsl_layout() {
    let files = shader_files();
    let module = validate("ao.wgsl", &files);
    let cw_module = validate_with("ao.wgsl", "trace_cwbvh.wgsl", &files);
    assert_eq!(wgsl_size(&cw_module, "CwNode") as usize, std::mem::size_of::<CwBvhNode>());
    let size_of = |name: &str| wgsl_size(&module, name);
    let scene = aorender::Scene::default_scene();
    assert_eq!(size_of("Frame") as usize, size_of_val(&FrameUniforms::image(&scene.camera, &scene.settings, 0, 0, 0)));
    assert_eq!(size_of("Dispatch") as usize, std::mem::size_of::<DispatchUniforms>());
    assert_eq!(size_of("Node") as usize, std::mem::size_of::<GpuNode>());
    assert_eq!(size_of("Primitive") as usize, std::mem::size_of::<GpuPrimitive>());
    assert_eq!(size_of("Plane") as usize, std::mem::size_of::<GpuPlane>());
    assert_eq!(size_of("ProbePoint") as usize, std::mem::size_of::<GpuProbePoint>());
    // Geometry textures hold each element in whole texels, and a row in whole elements.
    for (layout, node_size) in [(BvhLayout::Bvh2, size_of("Node")), (BvhLayout::Cwbvh, wgsl_size(&cw_module, "CwNode"))]
    {
        let (node_texels, prim_texels) = aorender::gpu::shaders::element_texels(layout);
        assert_eq!(16 * node_texels, node_size, "{layout:?}");
        assert_eq!(16 * prim_texels, size_of("Primitive"));
        for texels in [node_texels, prim_texels] {
            assert_eq!(aorender::gpu::shaders::ROW_TEXEL_MULTIPLE % texels, 0);
        }
    }
}

/// The kernel binds no uniform buffer (see shaders/bindings.wgsl): lavapipe would
/// recompile it at every dispatch.
#[test]
fn kernel_binds_no_uniform_buffer() {
    let files = shader_files();
    for layout in [BvhLayout::Bvh2, BvhLayout::Cwbvh] {
        let module =
            validate_with("ao.wgsl", aorender::gpu::shaders::traversal_file(layout, Traversal::PerLane), &files);
        let bound: Vec<_> = module.global_variables.iter().filter(|(_, g)| g.binding.is_some()).collect();
        assert!(bound.len() >= 8, "{} bindings found", bound.len());
        for (_, g) in bound {
            assert!(
                !matches!(g.space, naga::AddressSpace::Uniform | naga::AddressSpace::Immediate),
                "binding {:?} ({:?}) is in the {:?} address space",
                g.binding,
                g.name,
                g.space
            );
        }
    }
}

/// naga's size of the WGSL struct `name`.
fn wgsl_size(module: &naga::Module, name: &str) -> u32 {
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).expect("layout");
    let (handle, _) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("WGSL struct {name} not found"));
    layouter[handle].size
}
