//! The engine as a whole: a session answers many requests without rebuilding anything and
//! gives the same films as fresh sessions; checkpoints written by format version 1 still
//! resume to the same bits; the Rust/WGSL layout table agrees with naga field by field; and
//! the library's modules form no cycle.

mod common;
use aorender::gpu::layout::{Access, BINDINGS, STRUCTS, constants, node_binding, primitive_binding, wgsl_header};
use aorender::gpu::shaders::{GeometryChunks, Traversal, compose};
use aorender::{
    Accumulation, BvhLayout, BvhOptions, Control, Device, DeviceKind, Hemisphere, ImageRequest, Probe, Sampler, Scene,
    Session,
};
use common::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A small aobench view.
fn aobench(spp: u32) -> Scene {
    let mut scene = Scene::default_scene();
    (scene.settings.width, scene.settings.height, scene.settings.spp) = (40, 30, spp);
    scene
}

/// The devices to check: the CPU reference, and the adapter when there is one.
fn devices() -> Vec<Device> {
    let mut devices = vec![Device::cpu()];
    if gpu_available() {
        devices.push(Device::gpu(None).expect("adapter"));
    }
    devices
}

/// One session, many requests: every sampling setting changed in turn (spp, seed,
/// hemisphere, sampler, max distance, image size, camera and sample range), each film
/// identical, bit for bit, to a fresh session's film of the same request; probes on the
/// same session equal a fresh session's too. Nothing is rebuilt between requests: the
/// session's setup (BVH build and upload) is the one it was made with.
#[test]
fn one_session_answers_many_requests_like_fresh_sessions() {
    for device in devices() {
        let scene = aobench(12);
        let session = Session::new(&device, scene.clone(), &BvhOptions::default()).expect("session");
        let setup = format!("{:?}", session.setup());
        let base = session.default_request();
        let mut requests = vec![base.clone()];
        let mut with = |f: &dyn Fn(&mut ImageRequest)| {
            let mut r = base.clone();
            f(&mut r);
            requests.push(r);
        };
        with(&|r| r.settings.spp = 20);
        with(&|r| r.settings.sampling.seed = 7);
        with(&|r| r.settings.sampling.hemisphere = Hemisphere::Uniform);
        with(&|r| r.settings.sampling.sampler = Sampler::Sobol);
        with(&|r| r.settings.sampling.sampler = Sampler::Stratified);
        with(&|r| r.settings.sampling.max_distance = Some(0.5));
        with(&|r| (r.settings.width, r.settings.height) = (17, 9));
        with(&|r| r.camera.eye.x += 0.25);
        with(&|r| r.samples = Some(3..9));
        for request in &requests {
            let reused = session.render(request).expect("render").complete(&mut Control::default()).expect("run");
            let fresh = Session::new(&device, scene.clone(), &BvhOptions::default())
                .expect("session")
                .render(request)
                .expect("render")
                .complete(&mut Control::default())
                .expect("run");
            let what = format!("{} {:?}", device.info().name, request);
            assert!(reused.film.image_mean() > 0.0, "{what}: empty image");
            assert_eq!(reused.film.sum, fresh.film.sum, "{what}");
            assert_eq!(reused.film.sum_sq, fresh.film.sum_sq, "{what}");
            assert_eq!(
                reused.stats.samples_per_pixel,
                request.samples.clone().map_or(request.settings.spp, |r| r.len() as u32)
            );
        }
        assert_eq!(format!("{:?}", session.setup()), setup, "the session's setup changed");
        let probes = [Probe::new(glam::Vec3::new(0.0, -0.5, -2.0), glam::Vec3::Y).unwrap()];
        let a = session.probe(&probes, 300, &base.settings).expect("probe");
        let b = Session::new(&device, scene.clone(), &BvhOptions::default())
            .expect("session")
            .probe(&probes, 300, &base.settings)
            .expect("probe");
        assert_eq!(a.values, b.values, "{}", device.info().name);
    }
}

/// Sessions made together on several devices share one BVH build (their setups report
/// the same build) and render what separate sessions render, bit for bit.
#[test]
fn sessions_on_several_devices_share_the_build() {
    let devices: Vec<Device> = devices().into_iter().chain([Device::cpu()]).collect();
    let scene = aobench(8);
    let sessions = Session::on_devices(&devices, scene.clone(), &BvhOptions::default()).expect("sessions");
    assert_eq!(sessions.len(), devices.len());
    let build = sessions[0].setup().bvh_build_seconds - sessions[0].setup().bvh_convert_seconds;
    for (session, device) in sessions.iter().zip(&devices) {
        let setup = session.setup();
        // The same measured build (up to the rounding of taking the conversion back out).
        let own = setup.bvh_build_seconds - setup.bvh_convert_seconds;
        assert!((own - build).abs() <= 1e-12, "{}: a build of {own} s, not {build} s", device.info().name);
        let request = session.default_request();
        let shared = session.render(&request).unwrap().complete(&mut Control::default()).unwrap();
        let alone = Session::new(device, scene.clone(), &BvhOptions::default()).unwrap();
        let alone = alone.render(&request).unwrap().complete(&mut Control::default()).unwrap();
        assert_eq!(shared.film.sum, alone.film.sum, "{}", device.info().name);
    }
}

/// A request the session cannot render is refused with the setting named, before any work.
#[test]
fn invalid_requests_name_the_setting() {
    let session = Session::new(&Device::cpu(), aobench(4), &BvhOptions::default()).unwrap();
    let mut r = session.default_request();
    r.samples = Some(2..9);
    let e = session.render(&r).err().expect("a range past the samples per pixel").to_string();
    assert!(e.contains("sample range 2..9") && e.contains("4 samples per pixel"), "{e}");
    let mut r = session.default_request();
    r.settings.width = 0;
    assert!(session.render(&r).err().expect("a zero width").to_string().contains("image size must be positive"));
    let mut r = session.default_request();
    r.camera.look_at = r.camera.eye;
    assert!(session.render(&r).err().expect("a degenerate camera").to_string().contains("the same point"));
    let bad =
        Probe { position: glam::Vec3::ZERO, normal: glam::Vec3::ZERO, error: 0.0, surface_normal: glam::Vec3::ZERO };
    let e = session.probe(&[Probe::new(glam::Vec3::ONE, glam::Vec3::Z).unwrap(), bad], 16, &r.settings).unwrap_err();
    assert_eq!(e.to_string(), "probe 1: zero normal");
    // A normal of any length is the direction it gives.
    let unit = Probe::new(glam::Vec3::new(0.0, -0.5, -2.0), glam::Vec3::Y).unwrap();
    let long = Probe { normal: glam::Vec3::new(0.0, 3.0, 0.0), ..unit };
    let a = session.probe(&[unit], 64, &r.settings).unwrap();
    let b = session.probe(&[long], 64, &r.settings).unwrap();
    assert_eq!(a.values, b.values);
}

/// Checkpoints of format version 1, written before the engine was reorganised
/// (`tests/fixtures/README.md`), are read and continued to the bits of an uninterrupted
/// render of that version: on the CPU reference always, on the GPU where the adapter is
/// the one that wrote it (another adapter's arithmetic differs in the last bits).
#[test]
fn version_1_checkpoints_resume_to_the_same_bits() {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
    let dir = temp_dir();
    for kind in [DeviceKind::Cpu, DeviceKind::Gpu] {
        if kind == DeviceKind::Gpu && !gpu_available() {
            continue;
        }
        let name = kind.name();
        let saved = Accumulation::read(&fixtures.join(format!("checkpoint-v1-{name}.ck"))).expect("fixture reads");
        let device = Device::open(kind, None).expect("device");
        if device.info().name != saved.adapter() {
            eprintln!("SKIPPED: the {name} fixture was written on {}, not {}", saved.adapter(), device.info().name);
            continue;
        }
        assert!(
            0 < saved.samples() && saved.samples() < 600 && saved.partial().is_some(),
            "{name}: a block in progress"
        );
        let mut scene = Scene::default_scene();
        let s = &mut scene.settings;
        (s.width, s.height, s.spp, s.sampling.hemisphere, s.sampling.sampler, s.sampling.seed) =
            (64, 48, 600, Hemisphere::Uniform, Sampler::Stratified, 7);
        let session = Session::new(&device, scene, &BvhOptions::default()).expect("session");
        let mut render = session.render(&session.default_request()).expect("render");
        render.resume(saved).expect("the fixture resumes");
        let out = render.complete(&mut Control::default()).expect("run");
        assert_eq!(out.stats.samples_per_pixel, 600);
        let path = dir.path().join(format!("{name}.pfm"));
        aorender::output::write_image(&out.film, &path).unwrap();
        let expected = std::fs::read(fixtures.join(format!("checkpoint-v1-{name}-full.pfm"))).unwrap();
        assert!(std::fs::read(&path).unwrap() == expected, "{name}: the resumed film differs from the stored one");
    }
}

/// naga's layout of every generated struct: its size and each field's offset equal the
/// Rust mirror's, and the fields are the same, in the same order.
#[test]
fn every_shared_struct_has_the_rust_layout_in_wgsl() {
    let source = wgsl_header();
    let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).expect("layout");
    for layout in STRUCTS {
        let (handle, ty) = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some(layout.wgsl_name))
            .unwrap_or_else(|| panic!("WGSL struct {} not generated", layout.wgsl_name));
        let naga::TypeInner::Struct { members, .. } = &ty.inner else { panic!("{} is not a struct", layout.wgsl_name) };
        assert_eq!(layouter[handle].size as usize, layout.size, "size of {}", layout.wgsl_name);
        let wgsl: Vec<(String, usize)> =
            members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize)).collect();
        let rust: Vec<(String, usize)> = layout.fields.iter().map(|f| (f.name.to_string(), f.offset)).collect();
        assert_eq!(wgsl, rust, "fields and offsets of {}", layout.wgsl_name);
    }
}

/// The constants the shaders see are the Rust values, bit for bit, and none is defined
/// again by hand in a shader file.
#[test]
fn shared_constants_are_defined_once() {
    let source = wgsl_header();
    let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
    let mut names = BTreeSet::new();
    for c in constants() {
        let (name, expected) = match c {
            aorender::gpu::layout::Constant::U32(n, v) => (n, naga::Literal::U32(v)),
            aorender::gpu::layout::Constant::F32(n, v) => (n, naga::Literal::F32(v)),
        };
        assert!(names.insert(name), "{name} listed twice");
        let (_, constant) = module
            .constants
            .iter()
            .find(|(_, k)| k.name.as_deref() == Some(name))
            .unwrap_or_else(|| panic!("{name} not generated"));
        let naga::Expression::Literal(value) = module.global_expressions[constant.init] else {
            panic!("{name} is not a literal");
        };
        let same = match (value, expected) {
            (naga::Literal::F32(a), naga::Literal::F32(b)) => a.to_bits() == b.to_bits(),
            (a, b) => a == b,
        };
        assert!(same, "{name}: WGSL {value:?}, Rust {expected:?}");
    }
    let shaders = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    for entry in std::fs::read_dir(&shaders).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        for name in &names {
            assert!(
                !text.contains(&format!("const {name}:")),
                "{} defines {name} again: it is generated from Rust",
                path.display()
            );
        }
        for layout in STRUCTS {
            assert!(
                !text.contains(&format!("struct {} {{", layout.wgsl_name)),
                "{} declares struct {} again: it is generated from Rust",
                path.display(),
                layout.wgsl_name
            );
        }
    }
}

/// The composed kernel binds exactly the table's fixed bindings (number, name, access) and
/// the geometry's.
#[test]
fn the_kernel_binds_what_the_table_lists() {
    for layout in [BvhLayout::Bvh2, BvhLayout::Cwbvh] {
        let source =
            compose("ao.wgsl", layout, Traversal::PerLane, GeometryChunks::SINGLE, layout.stack_size(), true).unwrap();
        let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| panic!("{}", e.emit_to_string(&source)));
        let bound: BTreeMap<u32, (String, naga::AddressSpace)> = module
            .global_variables
            .iter()
            .filter_map(|(_, g)| g.binding.as_ref().map(|b| (b.binding, (g.name.clone().unwrap_or_default(), g.space))))
            .collect();
        for b in BINDINGS {
            let (name, space) = bound.get(&b.index).unwrap_or_else(|| panic!("binding {} is not bound", b.index));
            assert_eq!(name, b.name, "binding {}", b.index);
            let access = match space {
                naga::AddressSpace::Storage { access } => *access,
                other => panic!("binding {} is in {other:?}", b.index),
            };
            assert_eq!(
                access.contains(naga::StorageAccess::STORE),
                b.access == Access::ReadWrite,
                "binding {}",
                b.index
            );
        }
        let geometry = [node_binding(0), primitive_binding(0)];
        assert_eq!(bound.len(), BINDINGS.len() + geometry.len(), "{layout:?}: {bound:?}");
        assert!(geometry.iter().all(|g| bound.contains_key(g)));
    }
}

/// The library's modules, file by file, and the modules each names (`use crate::…`,
/// `use super::…`, `crate::…` paths in code, and a parent's uses of its children), test
/// modules aside.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    fn files(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                files(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let mut paths = Vec::new();
    files(src, &mut paths);
    let mut modules: BTreeMap<String, String> = BTreeMap::new();
    for path in paths {
        let rel = path.strip_prefix(src).unwrap().with_extension("");
        let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
        if matches!(parts.last().map(String::as_str), Some("mod" | "lib")) {
            parts.pop();
        }
        let text = std::fs::read_to_string(&path).unwrap();
        // Test modules and comments are not part of the data flow.
        let text = text.split("#[cfg(test)]\nmod tests").next().unwrap().to_string();
        let code: String = text.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
        modules.insert(parts.join("::"), code);
    }
    // The longest prefix of `path` (already absolute) that is a module.
    let resolve = |path: &[String]| -> Option<String> {
        (0..=path.len()).rev().map(|k| path[..k].join("::")).find(|m| modules.contains_key(m))
    };
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (module, code) in &modules {
        let here: Vec<String> = if module.is_empty() { vec![] } else { module.split("::").map(String::from).collect() };
        let mut add = |target: Option<String>| {
            if let Some(t) = target.filter(|t| t != module) {
                edges.entry(module.clone()).or_default().insert(t);
            }
        };
        let bytes = code.as_bytes();
        let mut i = 0;
        while i < code.len() {
            let rest = &code[i..];
            let start = ["crate::", "super::", "self::"].iter().find(|p| rest.starts_with(**p));
            let preceded =
                i > 0 && (bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_' || bytes[i - 1] == b':');
            let Some(_) = start.filter(|_| !preceded) else {
                i += rest.chars().next().map_or(1, char::len_utf8);
                continue;
            };
            // The path's segments up to a use tree, then the tree's items.
            let end = rest.find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':')).unwrap_or(rest.len());
            let mut segments: Vec<String> =
                rest[..end].split("::").filter(|s| !s.is_empty()).map(String::from).collect();
            let mut base: Vec<String> = match segments.first().map(String::as_str) {
                Some("crate") => vec![],
                Some("super") => here[..here.len().saturating_sub(1)].to_vec(),
                _ => here.clone(),
            };
            segments.remove(0);
            while segments.first().map(String::as_str) == Some("super") {
                base.pop();
                segments.remove(0);
            }
            base.extend(segments);
            if rest[end..].starts_with('{') {
                let close = rest[end..].find('}').map_or(rest.len(), |c| end + c);
                for item in rest[end + 1..close].split(',') {
                    let item = item.split(" as ").next().unwrap().trim();
                    let first = item.split("::").next().unwrap_or("");
                    if first.is_empty() {
                        continue;
                    }
                    let mut path = base.clone();
                    if first != "self" {
                        path.push(first.to_string());
                    }
                    add(resolve(&path));
                }
                i += close;
            } else {
                add(resolve(&base));
                i += end;
            }
        }
        // A parent naming a child module in code (`child::item`).
        for child in modules.keys().filter(|c| {
            c.strip_prefix(module.as_str())
                .map(|r| r.trim_start_matches("::"))
                .is_some_and(|r| !r.is_empty() && !r.contains("::"))
                && (module.is_empty() || c.starts_with(&format!("{module}::")))
        }) {
            let name = child.rsplit("::").next().unwrap();
            let uses = code.match_indices(&format!("{name}::")).any(|(at, _)| {
                at == 0 || !(bytes[at - 1].is_ascii_alphanumeric() || bytes[at - 1] == b'_' || bytes[at - 1] == b':')
            });
            if uses {
                add(Some(child.clone()));
            }
        }
    }
    edges
}

/// No module of the library imports one that imports it back, directly or through
/// others: the data flows one way (scene → BVH → device → passes → accumulation →
/// outputs). The edges are printed for the record.
#[test]
fn the_library_modules_form_no_cycle() {
    let edges = module_graph(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"));
    assert!(edges.len() > 20, "only {} modules with imports found", edges.len());
    for (from, to) in &edges {
        eprintln!(
            "{} -> {}",
            if from.is_empty() { "(lib)" } else { from },
            to.iter().cloned().collect::<Vec<_>>().join(", ")
        );
    }
    let mut cycles = Vec::new();
    for (from, targets) in &edges {
        for to in targets {
            // Does `to` reach `from`?
            let mut seen = BTreeSet::new();
            let mut stack = vec![to.clone()];
            while let Some(m) = stack.pop() {
                if m == *from {
                    cycles.push(format!("{from} -> {to}"));
                    break;
                }
                if seen.insert(m.clone()) {
                    stack.extend(edges.get(&m).into_iter().flatten().cloned());
                }
            }
        }
    }
    assert!(cycles.is_empty(), "edges on cycles:\n{}", cycles.join("\n"));
    // The steps of the flow, and that each depends only on earlier ones.
    let top = |m: &str| m.split("::").next().unwrap().to_string();
    let depends = |a: &str, b: &str| edges.iter().any(|(f, t)| top(f) == a && t.iter().any(|m| top(m) == b));
    for (later, earlier) in
        [("bvh", "scene"), ("device", "bvh"), ("render", "device"), ("render", "accumulation"), ("session", "render")]
    {
        assert!(depends(later, earlier), "{later} does not use {earlier}");
        assert!(!depends(earlier, later), "{earlier} uses {later}");
    }
}

/// The checkpoint format and the accumulation read the kinds their samples were made with
/// (device, BVH layout and preset, the options a scene is prepared with) from the module
/// that describes them, which depends on no other: the file format imports neither the
/// device nor the BVH code, and the accumulation not the device's.
#[test]
fn the_checkpoint_format_imports_no_device_code() {
    let edges = module_graph(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"));
    let top = |m: &str| m.split("::").next().unwrap().to_string();
    let imports = |module: &str| edges.get(module).into_iter().flatten().map(|m| top(m)).collect::<BTreeSet<_>>();
    let format = imports("output::checkpoint");
    assert!(format.contains("kinds"), "the checkpoint format does not read the kinds: {format:?}");
    for layer in ["device", "bvh", "gpu", "cpu"] {
        assert!(!format.contains(layer), "the checkpoint format imports {layer}: {format:?}");
    }
    let accumulation = imports("accumulation");
    assert!(accumulation.contains("kinds"), "the accumulation does not read the kinds: {accumulation:?}");
    for layer in ["device", "bvh", "cpu"] {
        assert!(!accumulation.contains(layer), "the accumulation imports {layer}: {accumulation:?}");
    }
    assert!(imports("kinds").is_empty(), "kinds imports {:?}", imports("kinds"));
    for user in ["bvh", "device", "gpu"] {
        assert!(edges.iter().any(|(f, t)| top(f) == user && t.contains("kinds")), "{user} does not use kinds");
    }
}
