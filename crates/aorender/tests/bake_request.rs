//! The bake as a library request (`Bake`, `Session::bake`): planned without a device,
//! traced on a session, its shards merged into the values of the bake in one piece, bit
//! for bit.

use aorender::bake::{Bake, BakeRequest};
use aorender::output::FilePlan;
use aorender::{Accumulation, BvhOptions, Control, Device, DeviceKind, Scene, Session};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A unit cube as an OBJ file in `dir`.
fn cube(dir: &Path) -> PathBuf {
    let mut obj = String::new();
    for i in 0..8 {
        obj += &format!("v {} {} {}\n", i & 1, (i >> 1) & 1, (i >> 2) & 1);
    }
    // Outward quads, counter-clockwise seen from outside.
    for f in ["1 3 4 2", "5 6 8 7", "1 2 6 5", "3 7 8 4", "1 5 7 3", "2 4 8 6"] {
        obj += &format!("f {f}\n");
    }
    let path = dir.join("cube.obj");
    std::fs::write(&path, obj).unwrap();
    path
}

fn planned(scene: &Scene, input: &Path, request: &BakeRequest) -> Bake {
    let mut files = FilePlan::new();
    files.scene(input);
    Bake::new(scene, input, request, &mut files).unwrap()
}

#[test]
fn a_request_bakes_a_convex_mesh_to_exactly_one_and_writes_nothing_without_an_output() {
    let dir = tempfile::tempdir().unwrap();
    let input = cube(dir.path());
    let scene = Scene::load(&input).unwrap();
    let bake = planned(&scene, &input, &BakeRequest::new(64));
    assert_eq!(bake.probes().len(), 8);
    let session = Session::new(&Device::open(DeviceKind::Cpu, None).unwrap(), scene, &BvhOptions::default()).unwrap();
    let trace = session.bake(&bake, None, &mut Control::default()).unwrap();
    assert_eq!(trace.samples, 64);
    let baked = bake.finish(trace).unwrap();
    let ao: Vec<f32> = baked.values.iter().flat_map(|v| v.ao.clone()).collect();
    assert_eq!(ao, vec![1.0; 8]);
    let written = bake.write(&baked, 64).unwrap();
    assert!(written.files.is_empty());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "only the input is there");
}

#[test]
fn shards_merged_give_the_values_of_the_bake_in_one_piece() {
    let input = repo().join("scenes/bunny.obj");
    let scene = Scene::load(&input).unwrap();
    let device = Device::open(DeviceKind::Cpu, None).unwrap();
    let samples = 8;
    let whole_request = BakeRequest { one_film: true, ..BakeRequest::new(samples) };
    let whole = planned(&scene, &input, &whole_request);
    let expected = whole.expected(&scene, DeviceKind::Cpu, &BvhOptions::default()).unwrap();
    let session = Session::new(&device, scene.clone(), &BvhOptions::default()).unwrap();
    let one_piece = whole.finish(session.bake(&whole, None, &mut Control::default()).unwrap()).unwrap();

    let mut shards = Vec::new();
    for (k, range) in [0..3, 3..samples].into_iter().enumerate() {
        let request = BakeRequest { sample_range: Some(range), ..whole_request.clone() };
        let shard = planned(&scene, &input, &request);
        let saved: Mutex<Option<Accumulation>> = Mutex::new(None);
        let mut save = |acc: &Accumulation| {
            *saved.lock().unwrap() = Some(acc.clone());
            Ok(())
        };
        let mut control = Control { save: Some(&mut save), ..Control::default() };
        let part = shard.finish(session.bake(&shard, None, &mut control).unwrap()).unwrap();
        // One shard alone is not the bake.
        assert_ne!(part.values, one_piece.values);
        shards.push((PathBuf::from(format!("shard-{k}")), saved.into_inner().unwrap().unwrap()));
    }
    let merged = whole.finish(whole.merge(&shards, &expected).unwrap()).unwrap();
    assert_eq!(merged.values, one_piece.values);
    assert_eq!(merged.mean_ao.to_bits(), one_piece.mean_ao.to_bits());
    // Not every sample: refused, naming the first shard.
    let error = whole.merge(&shards[..1], &expected).err().unwrap().to_string();
    assert!(error.starts_with("shard-0: the shards hold samples 0..3, not all 0..8"), "{error}");
}
