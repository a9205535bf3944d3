//! The fixed cost of a render around its rays: the device opened on a thread of its own
//! while the scene is prepared (`Device::open_beside`, `Session::beside`) renders the
//! same film as one opened first, reports what it took and what of that overlapped, and
//! leaves no thread behind however the caller ends; and the host's round trips to the
//! device are one per pass plus a constant, so that batched passes keep them bounded
//! whatever the samples.

mod common;
use aorender::{
    BvhOptions, Control, Device, DeviceKind, Error, Hemisphere, PassSizing, Ready, RenderOutput, Scene, Session,
};
use common::*;

/// A small aobench view with `spp` samples per pixel.
fn aobench(spp: u32) -> Scene {
    let mut scene = Scene::default_scene();
    let s = &mut scene.settings;
    (s.width, s.height, s.spp, s.sampling.hemisphere) = (40, 30, spp, Hemisphere::Cosine);
    scene
}

/// An opening readied for every image kernel: each statistics kernel and the listing of
/// live pixels compiled and run once over no pixels, which must leave a later render's
/// film as it would be.
const IMAGES: Ready = Ready::Images { target: true, adaptive: true };

/// The session's default image, in passes of `sizing`.
fn render(session: &Session, sizing: PassSizing) -> RenderOutput {
    let mut control = Control { sizing, ..Control::default() };
    session.render(&session.default_request()).expect("request").complete(&mut control).expect("render")
}

/// The tests here. The test harness runs each on a thread named after it, and may start
/// one while another counts; such a thread is not the counting test's to account for.
const TESTS: [&str; 3] = [
    "round_trips_are_one_a_pass_and_a_constant",
    "a_device_opened_beside_the_build_renders_the_same_film",
    "openings_fail_in_one_line_and_leave_no_thread",
];

/// The process's threads now, less the harness's threads of the other tests here (the
/// kernel keeps a thread's name to its first 15 bytes). A thread started unnamed takes its
/// starter's name, so threads named after the counting test are counted.
fn threads() -> usize {
    let me = std::thread::current().name().unwrap_or_default().to_owned();
    let harness = |comm: &str| TESTS.iter().any(|&t| t != me && comm == &t[..t.len().min(15)]);
    std::fs::read_dir("/proc/self/task")
        .expect("the process's threads are listed")
        .filter_map(Result::ok)
        .filter(|task| {
            // A thread gone since the listing is not counted.
            std::fs::read_to_string(task.path().join("comm")).is_ok_and(|comm| !harness(comm.trim_end_matches('\n')))
        })
        .count()
}

/// Whether the process has `before` threads again within ten seconds: the kernel lists a
/// joined thread until it has fully exited, and a dropped thread pool's threads end on
/// their own time, later on a loaded machine. It returns as soon as they are.
fn back_to(before: usize) -> bool {
    (0..1000).any(|_| {
        std::thread::sleep(std::time::Duration::from_millis(10));
        threads() == before
    })
}

/// Held by every test here: each counts the process's threads, which another's devices
/// would change.
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A render whose passes each take every sample it has left (one pass up to 256 samples)
/// waits on the device the same number of times at 16, 64 and 256 samples per pixel: one
/// pass, and a constant rest of three (the exact sums written at the start; Σv and Σv²
/// read back at the end, one round trip each, the status word with the second). In
/// passes of eight samples, the round trips less the passes are the same at 16 and at 64
/// samples (2 and 8 passes): one round trip a pass, nothing that grows with the samples.
/// The CPU reference makes none.
#[test]
fn round_trips_are_one_a_pass_and_a_constant() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if gpu_available() {
        let device = gpu_device();
        let mut counts = Vec::new();
        for spp in [16, 64, 256] {
            let session = Session::new(&device, aobench(spp), &BvhOptions::default()).expect("session");
            let st = render(&session, PassSizing::Fixed(256)).stats;
            assert_eq!(st.passes, 1, "{spp} spp in one pass");
            assert_eq!(st.round_trips, u64::from(st.passes) + 3, "{spp} spp: round trips for {} passes", st.passes);
            counts.push(st.round_trips);
        }
        assert!(counts.iter().all(|&n| n == counts[0]), "round trips by spp 16, 64, 256: {counts:?}");
        let mut rest = Vec::new();
        for (spp, passes) in [(16, 2), (64, 8)] {
            let session = Session::new(&device, aobench(spp), &BvhOptions::default()).expect("session");
            let st = render(&session, PassSizing::Fixed(8)).stats;
            assert_eq!(st.passes, passes, "{spp} spp in passes of 8");
            assert!(st.round_trips >= u64::from(passes), "{spp} spp: {} round trips", st.round_trips);
            rest.push(st.round_trips - u64::from(passes));
        }
        assert_eq!(rest[0], rest[1], "round trips beside the passes at 16 and 64 spp");
        assert_eq!(rest[0], counts[0] - 1, "the same rest as in one pass");
    }
    let session = Session::new(&Device::cpu(), aobench(16), &BvhOptions::default()).expect("session");
    let st = render(&session, PassSizing::Fixed(8)).stats;
    assert_eq!((st.round_trips, session.device().round_trips()), (0, 0), "the CPU reference waits on no device");
}

/// A session on a device opened beside its BVH build renders the film of one on a device
/// opened first, bit for bit, on the CPU reference and on the adapter; the setup says how
/// long the opening took, what of it was waited for (no more than it took) and, on the
/// CPU, that nothing was opened; the statistics' overlap is the rest. Once the session
/// is dropped, the process has the threads it had before the opening: the opening's
/// thread and the device's are gone.
#[test]
fn a_device_opened_beside_the_build_renders_the_same_film() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let kinds: Vec<DeviceKind> =
        if gpu_available() { vec![DeviceKind::Cpu, DeviceKind::Gpu] } else { vec![DeviceKind::Cpu] };
    for kind in kinds {
        let first = Session::new(&Device::open(kind, None).expect("device"), aobench(16), &BvhOptions::default())
            .expect("session");
        let expected = render(&first, PassSizing::Timed);
        let before = threads();
        let mut checked = None;
        let mut opening = Device::open_beside(kind, None, IMAGES);
        assert_eq!(opening.kind(), kind);
        // Ready without waiting once its thread is done (the CPU reference at once).
        let start = std::time::Instant::now();
        while opening.ready().is_none() {
            assert!(kind == DeviceKind::Gpu && start.elapsed().as_secs() < 60, "{kind:?}: never ready");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(opening.ready().map(Device::kind), Some(kind));
        let session = Session::beside(opening, aobench(16), &BvhOptions::default(), |device, scene| {
            checked = Some((device.kind(), scene.settings.width));
            Ok(())
        })
        .expect("session");
        assert_eq!(checked, Some((kind, 40)), "{kind:?}: the check before the upload saw the device and the scene");
        let out = render(&session, PassSizing::Timed);
        assert!(out.film.image_mean() > 0.0, "{kind:?}: empty image");
        assert_eq!(out.film.sum, expected.film.sum, "{kind:?}");
        assert_eq!(out.film.sum_sq, expected.film.sum_sq, "{kind:?}");
        let (setup, st) = (session.setup(), &out.stats);
        let opened = setup.adapter_seconds + setup.adapter_compile_seconds;
        match kind {
            DeviceKind::Cpu => assert_eq!(opened, 0.0, "the CPU reference opens at once"),
            DeviceKind::Gpu => assert!(setup.adapter_seconds > 0.0, "the adapter opened in no time"),
        }
        assert!(
            (0.0..=opened).contains(&setup.adapter_wait_seconds),
            "{kind:?}: waited {} s of an opening of {opened} s",
            setup.adapter_wait_seconds
        );
        assert_eq!(st.adapter_seconds, setup.adapter_seconds, "{kind:?}");
        assert_eq!(st.overlap_seconds, (opened - setup.adapter_wait_seconds).max(0.0), "{kind:?}");
        assert!(st.compile_seconds >= setup.adapter_compile_seconds, "{kind:?}: {st:?}");
        drop(session);
        assert!(back_to(before), "{kind:?}: {} threads before the opening, {} after", before, threads());
    }
}

/// An opening that fails (no adapter of that name) is never ready and fails where it is
/// waited for, with the opening's one-line error, and so does a session built beside it: after the BVH build,
/// before anything is uploaded or checked. A check that fails before the upload is the
/// session's error. An opening dropped unwaited (the caller failed first) joins its
/// thread: none is left running.
#[test]
fn openings_fail_in_one_line_and_leave_no_thread() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = "no adapter is called this";
    let error = |e: Error| e.to_string();
    let mut failing = Device::open_beside(DeviceKind::Gpu, Some(name), Ready::Points);
    std::thread::sleep(std::time::Duration::from_millis(200));
    assert!(failing.ready().is_none(), "a failed opening is ready");
    let message = failing.wait().err().map(error);
    let message = message.expect("no adapter has that name");
    assert!(message.contains(name) && !message.contains('\n'), "{message}");
    let mut checked = false;
    let opening = Device::open_beside(DeviceKind::Gpu, Some(name), Ready::Points);
    let session = Session::beside(opening, aobench(4), &BvhOptions::default(), |_, _| {
        checked = true;
        Ok(())
    });
    assert_eq!(session.err().map(error), Some(message), "the session's error is the opening's");
    assert!(!checked, "a device that did not open was checked");
    let refused = Session::beside(
        Device::open_beside(DeviceKind::Cpu, None, Ready::Points),
        aobench(4),
        &BvhOptions::default(),
        |_, _| Err(Error::settings("refused before the upload")),
    );
    let message = refused.err().map(error).expect("the check's error");
    assert!(message.contains("refused before the upload"), "{message}");
    if gpu_available() {
        // The instance, its driver's threads and rayon's, made before counting.
        drop(Device::open_beside(DeviceKind::Gpu, None, IMAGES).wait().expect("device"));
        let before = threads();
        for _ in 0..3 {
            drop(Device::open_beside(DeviceKind::Gpu, None, IMAGES));
            assert!(back_to(before), "a dropped opening left threads: {before} before, {} after", threads());
        }
    }
}
