//! Sessions in threads, as Python users run them and as the test harness runs tests:
//! several threads at once, each opening and dropping GPU devices of its own, building
//! sessions on them and on a shared device, rendering through one shared session, and
//! writing images, many times over. Every film must be its device's reference, bit for
//! bit, and the process must not crash (NVIDIA's driver corrupted its heap when devices
//! were opened on several threads at once: `gpu::context`'s process-wide lock).

mod common;
use aorender::{BvhOptions, Device, Film, Hemisphere, Probe, Scene, Session};
use common::*;
use std::sync::Barrier;

const THREADS: usize = 4;
const ROUNDS: usize = 16;

fn small_scene() -> Scene {
    let mut scene = Scene::default_scene();
    let s = &mut scene.settings;
    (s.width, s.height, s.spp, s.sampling.hemisphere, s.sampling.seed) = (32, 24, 16, Hemisphere::Uniform, 3);
    scene
}

fn render(session: &Session) -> Film {
    render_request(session, &session.default_request())
}

/// What each device renders, from sessions made on the main thread before any other starts.
struct Reference {
    film: Film,
    probes: Vec<aorender::ProbeValue>,
}

fn reference(session: &Session, probes: &[Probe]) -> Reference {
    let probed = session.probe(probes, 256, &session.scene().settings).unwrap_or_else(|e| panic!("{e}"));
    Reference { film: render(session), probes: probed.values }
}

#[test]
fn sessions_in_threads_render_their_devices_films() {
    let scene = small_scene();
    let probes = vec![
        Probe::new(glam::Vec3::new(0.0, -0.5, -2.0), glam::Vec3::Y).unwrap(),
        Probe::new(glam::Vec3::new(1.0, -0.5, -3.0), glam::Vec3::Y).unwrap(),
    ];
    let cpu_shared = session(&scene, &Config::cpu());
    let cpu = reference(&cpu_shared, &probes);
    let gpu = gpu_available().then(|| {
        let shared = Session::new(&gpu_device(), scene.clone(), &BvhOptions::default()).unwrap();
        let r = reference(&shared, &probes);
        (shared, r)
    });
    let dir = temp_dir();
    let start = Barrier::new(THREADS);
    std::thread::scope(|threads| {
        for t in 0..THREADS {
            let (scene, probes, cpu, gpu, cpu_shared, dir, start) =
                (&scene, &probes, &cpu, &gpu, &cpu_shared, dir.path(), &start);
            threads.spawn(move || {
                start.wait();
                for round in 0..ROUNDS {
                    let what = format!("thread {t}, round {round}");
                    // The CPU reference: the shared session, and one of this thread's.
                    assert_eq!(render(cpu_shared), cpu.film, "{what}: shared CPU session");
                    let own = Session::new(&Device::cpu(), scene.clone(), &BvhOptions::default()).unwrap();
                    assert_eq!(render(&own), cpu.film, "{what}: CPU session of its own");
                    let Some((shared, gpu)) = gpu else { continue };
                    // The shared GPU session, its film written to a file of this thread's.
                    let film = render(shared);
                    assert_eq!(film, gpu.film, "{what}: shared GPU session");
                    aorender::output::write_image(&film, &dir.join(format!("{t}.pfm"))).unwrap();
                    let probed = shared.probe(probes, 256, &scene.settings).unwrap_or_else(|e| panic!("{e}"));
                    assert_eq!(probed.values, gpu.probes, "{what}: probes on the shared GPU session");
                    // A session of its own on the shared device, and every other round a
                    // device of its own too, opened and dropped while the others render.
                    let device = if round % 2 == 0 { Device::gpu(None).unwrap() } else { gpu_device() };
                    let own = Session::new(&device, scene.clone(), &BvhOptions::default()).unwrap();
                    assert_eq!(render(&own), gpu.film, "{what}: GPU session of its own");
                }
            });
        }
    });
    if gpu.is_some() {
        let written = std::fs::read(dir.path().join("0.pfm")).unwrap();
        for t in 1..THREADS {
            assert_eq!(std::fs::read(dir.path().join(format!("{t}.pfm"))).unwrap(), written, "thread {t}'s image");
        }
    }
}
