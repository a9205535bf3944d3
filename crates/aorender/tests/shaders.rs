//! Every WGSL file parses and validates with naga (composed with its imports), and the
//! host structs match the WGSL structs' sizes.

use aorender::bvh::{BvhLayout, GpuNode, GpuPrimitive};
use aorender::gpu::layout::{DispatchUniforms, FrameUniforms, GpuPlane, GpuProbePoint};
use aorender::gpu::shaders::{
    ELSEWHERE, GeometryChunks, GeometryStorage, Traversal, compose_with, file_path, generated_files,
};
use obvhs::cwbvh::node::CwBvhNode;
use std::collections::BTreeMap;

/// Every `.wgsl` file of `shaders/` and `src/`, by the name the shaders import it by: its
/// file name in `shaders/`, its name in `ELSEWHERE` outside (or its path, where that
/// does not list it).
fn shader_files() -> BTreeMap<String, String> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = BTreeMap::new();
    let mut dirs = vec![root.join("shaders"), root.join("src")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "wgsl") {
                let place = path.strip_prefix(root).unwrap().to_string_lossy().replace('\\', "/");
                let name = match ELSEWHERE.iter().find(|(_, p)| *p == place) {
                    Some((name, _)) => name.to_string(),
                    None => place.strip_prefix("shaders/").unwrap_or(&place).to_string(),
                };
                assert_eq!(file_path(&name), place, "{place}: not where file_path puts it (list it in ELSEWHERE)");
                files.insert(name, std::fs::read_to_string(&path).expect("readable shader"));
            }
        }
    }
    assert!(files.contains_key("ao.wgsl"), "no shaders/ao.wgsl");
    files
}

/// Parses and validates `name` with its imports, the generated files (the chosen
/// traversal, the geometry bindings split as `chunks`) those of `layout` and `traversal`.
fn validate_chunked(
    name: &str,
    layout: BvhLayout,
    traversal: Traversal,
    chunks: GeometryChunks,
    files: &BTreeMap<String, String>,
) -> naga::Module {
    // With batch_max from subgroup operations and without; the cooperative traversal needs them.
    let cooperative = traversal == Traversal::Cooperative || name == "trace_cwbvh_group.wgsl";
    let variants: &[bool] = if cooperative { &[true] } else { &[true, false] };
    let mut modules = variants.iter().map(|&subgroups| {
        let generated = generated_files(layout, traversal, chunks, layout.stack_size(), subgroups);
        let lookup = |n: &str| {
            if let Some((_, text)) = generated.iter().find(|(f, _)| *f == n) {
                return Some(text.as_str());
            }
            files.get(n).map(|s| s.as_str())
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

fn validate_with(
    name: &str,
    layout: BvhLayout,
    traversal: Traversal,
    files: &BTreeMap<String, String>,
) -> naga::Module {
    validate_chunked(name, layout, traversal, GeometryChunks::SINGLE, files)
}

fn validate(name: &str, files: &BTreeMap<String, String>) -> naga::Module {
    // Each traversal file with its own node type.
    let (layout, traversal) = match name {
        "trace_cwbvh.wgsl" | "cwbvh.wgsl" => (BvhLayout::Cwbvh, Traversal::PerLane),
        "trace_cwbvh_group.wgsl" => (BvhLayout::Cwbvh, Traversal::Cooperative),
        _ => (BvhLayout::Bvh2, Traversal::PerLane),
    };
    validate_with(name, layout, traversal, files)
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
            let module = validate_chunked("ao.wgsl", layout, traversal, chunks, &files);
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
    assert_eq!(files, compiled, "src/gpu/shaders.rs FILES must list every file in shaders/ (and ELSEWHERE in src/)");
}

#[test]
fn host_structs_match_wgsl_layout() {
    let files = shader_files();
    let module = validate("ao.wgsl", &files);
    let cw_module = validate_with("ao.wgsl", BvhLayout::Cwbvh, Traversal::PerLane, &files);
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
        let module = validate_with("ao.wgsl", layout, Traversal::PerLane, &files);
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
