//! A session: a scene prepared once on a device (the BVH built, the geometry uploaded)
//! and then asked for many things — images with any camera and sampling settings,
//! progressively, and AO at given points — without rebuilding or re-uploading anything.
//! Pipelines are compiled once per adapter for each specialisation a request needs.
//!
//! The device holds the scene in its local frame ([`LocalFrame`]): a session moves each
//! request's camera and probe points into it, and everything a caller passes or reads
//! back (the scene, cameras, probes, the hashes of checkpoints) is in the scene's own
//! coordinates: cameras as they are, probe points (like the primitives) relative to
//! [`Scene::origin`], which is zero unless a loader placed the scene far away.

use crate::accumulation::{
    Accumulation, FilmLayout, SampleSettings, geometry_hash, max_image_sample, probes_hash, scene_hash,
};
use crate::device::{Built, BvhOptions, Device, DeviceOpening, Prepared, Setup};
use crate::error::{Error, Result};
use crate::film::value_exponent;
use crate::footprint::background_pixels;
use crate::probe::{Probe, ProbeValue, checked, lanes_for};
use crate::render::{Control, PassTimes, Render, RenderInfo};
use crate::scene::{Camera, LocalFrame, Scene, Settings, round_up};
use crate::surface::{Located, SurfaceIndex, SurfaceTolerance};
use glam::DVec3;
use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// An image to render: a view of the session's scene, its sampling, and which of its
/// sample indices.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRequest {
    /// The camera.
    pub camera: Camera,
    /// Image size and sampling.
    pub settings: Settings,
    /// Sample indices to render, `start..end` with `end` at most the samples per pixel;
    /// `None` is all of them, `0..spp`. The cell samplers still place their cells for
    /// `spp` samples, so disjoint ranges are parts of one render.
    pub samples: Option<Range<u32>>,
}

/// AO estimates at probe points.
#[derive(Clone, Debug)]
pub struct ProbeOutput {
    /// One value per probe, in input order.
    pub values: Vec<ProbeValue>,
    /// AO rays traced.
    pub rays: u64,
    /// Seconds spent tracing (BVH build and setup excluded).
    pub seconds: f64,
    /// Adapter name, or "cpu".
    pub adapter: String,
    /// Seconds to make the request's film and pipeline.
    pub pipeline_seconds: f64,
    /// Of `pipeline_seconds`: seconds compiling pipelines.
    pub compile_seconds: f64,
    /// Seconds of the request beside its film, pipeline and passes: checks, the probes'
    /// hash, the accumulation.
    pub request_seconds: f64,
    /// The passes' seconds and rays, the film's read-back and the host's statistics
    /// (making the values from the sums included).
    pub times: PassTimes,
}

/// A scene prepared on a device, answering requests.
pub struct Session {
    scene: Arc<Scene>,
    /// The frame the devices hold the scene in.
    frame: LocalFrame,
    device: Device,
    options: BvhOptions,
    prepared: Prepared,
    setup: Setup,
    /// The last camera's scene hash (a checkpoint's identity), kept for the next request.
    camera_hash: Mutex<Option<(Camera, [u8; 32])>>,
    /// The geometry's hash, for probe requests.
    geometry_hash: OnceLock<[u8; 32]>,
    /// The surfaces' search structure, made by the first [`Session::locate`].
    surfaces: OnceLock<SurfaceIndex>,
    /// The film budget in bytes, when set for the session; else `host_memory::film_budget`.
    film_budget: Mutex<Option<u64>>,
}

impl Session {
    /// Builds the BVH of `scene` and uploads it to `device`: the work every request then
    /// shares.
    pub fn new(device: &Device, scene: Scene, options: &BvhOptions) -> Result<Session> {
        let mut sessions = Session::on_devices(std::slice::from_ref(device), scene, options)?;
        Ok(sessions.pop().expect("one session per device"))
    }

    /// One session of `scene` on each of `devices` (a GPU and the CPU reference, to compare
    /// them), the BVH built once for all and the scene shared.
    pub fn on_devices(devices: &[Device], scene: Scene, options: &BvhOptions) -> Result<Vec<Session>> {
        let mut scene = scene;
        let start = Instant::now();
        let (frame, prepared) = prepare_in_local_frame(&mut scene, |s| Prepared::new(devices, s, options))?;
        Ok(Session::assemble(devices, scene, frame, prepared, options, start.elapsed().as_secs_f64()))
    }

    /// [`Session::new`] on a device still opening ([`Device::open_beside`]): the BVH is
    /// built while the device opens, and the device is waited for only to upload the
    /// geometry, after `before_upload` has checked it against the scene (an image's film
    /// budget, say: the device's kind of memory is known only once it is open). The
    /// setup says how long the opening took and how much of it was waited for
    /// ([`Setup::adapter_seconds`]).
    pub fn beside(
        opening: DeviceOpening,
        scene: Scene,
        options: &BvhOptions,
        before_upload: impl FnOnce(&Device, &Scene) -> Result<()>,
    ) -> Result<Session> {
        let mut scene = scene;
        let start = Instant::now();
        let kind = opening.kind();
        let mut opened = None;
        let (frame, prepared) = prepare_in_local_frame(&mut scene, |s| {
            let built = Built::new(&[kind], s, options);
            let device = opening.wait()?;
            before_upload(&device.device, s)?;
            let prepared = Prepared::upload(built, std::slice::from_ref(&device.device), s, options);
            opened = Some(device);
            prepared
        })?;
        let opened = opened.expect("opened for the upload");
        let devices = [opened.device];
        let mut sessions = Session::assemble(&devices, scene, frame, prepared, options, 0.0);
        let mut session = sessions.pop().expect("one session");
        // The wait is the opening's, not the session's own setup.
        let setup = &mut session.setup;
        let seconds = start.elapsed().as_secs_f64() - opened.waited_seconds;
        setup.scene_seconds = (seconds - setup.bvh_build_seconds - setup.upload_seconds).max(0.0);
        setup.adapter_seconds = opened.seconds - opened.compile_seconds;
        (setup.adapter_compile_seconds, setup.adapter_wait_seconds) = (opened.compile_seconds, opened.waited_seconds);
        Ok(session)
    }

    /// The sessions of `scene` prepared on `devices`, which took `seconds` in all.
    fn assemble(
        devices: &[Device],
        scene: Scene,
        frame: LocalFrame,
        mut prepared: Vec<(Prepared, Setup)>,
        options: &BvhOptions,
        seconds: f64,
    ) -> Vec<Session> {
        for (_, setup) in &mut prepared {
            setup.scene_seconds = (seconds - setup.bvh_build_seconds - setup.upload_seconds).max(0.0);
        }
        let scene = Arc::new(scene);
        devices
            .iter()
            .zip(prepared)
            .map(|(device, (prepared, setup))| Session {
                scene: scene.clone(),
                frame,
                device: device.clone(),
                options: *options,
                prepared,
                setup,
                camera_hash: Mutex::new(None),
                geometry_hash: OnceLock::new(),
                surfaces: OnceLock::new(),
                film_budget: Mutex::new(None),
            })
            .collect()
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The frame the scene is rendered in: its origin in the scene's coordinates (zero
    /// for a scene near the origin) and how far moving the scene there moved a surface.
    pub fn frame(&self) -> &LocalFrame {
        &self.frame
    }

    /// A probe (checked) in the local frame: its position moved as the scene was, its
    /// offset bound grown by that move's rounding and the scene's (both zero when exact).
    fn local_probe(&self, p: &Probe) -> Probe {
        let (position, rounding) = self.frame.point(p.position);
        let shift = rounding + self.frame.surface_shift as f64;
        let error = if shift == 0.0 { p.error } else { round_up(p.error as f64 + shift) };
        Probe { position, error, ..*p }
    }

    /// `probes` put on the surfaces they lie on: for each point, the nearest surface of
    /// the scene within `tolerance` gives the probe its normal and a bound on the point's
    /// distance to it, by which the AO rays start off it, as a camera hit's do (a point
    /// computed inside a triangle in floating point is rarely exactly on it, and one just
    /// under it reads dark). A triangle's corner (a vertex) is taken as exactly on it and
    /// left as it is; a point on no surface is left as it is and counted
    /// ([`Located::off_surface`]). What `aorender probe` and the Python module do with the
    /// points they are given; the search structure is built by the first call.
    pub fn locate(&self, probes: &[Probe], tolerance: SurfaceTolerance) -> Result<Located> {
        if let SurfaceTolerance::Distance(d) = tolerance {
            SurfaceTolerance::distance(d)?;
        }
        // Checked, but handed on as given: a request normalises a normal once more.
        checked(probes)?;
        let index = self.surfaces.get_or_init(|| SurfaceIndex::new(&self.scene));
        Ok(index.locate(&self.scene, probes, tolerance))
    }

    /// Sets the most host memory, in bytes, a request's film may take (`None`: the
    /// default, `host_memory::film_budget`: three quarters of the memory available, or
    /// what `AORENDER_FILM_BUDGET` says). A request past it is refused with
    /// [`Error::FilmBudget`] before anything is made.
    pub fn set_film_budget(&self, bytes: Option<u64>) {
        *self.film_budget.lock().unwrap_or_else(|e| e.into_inner()) = bytes;
    }

    /// Host bytes the film of an image of `settings` takes at its peak on this session's
    /// device ([`Device::film_bytes`]).
    pub fn image_film_bytes(&self, settings: &Settings) -> u64 {
        let slots = settings.width as u64 * settings.height as u64;
        self.device.film_bytes(slots, settings.sampling.replicate_samples() >= 2)
    }

    /// Fails with [`Error::FilmBudget`] when a film of `slots` slots (`what`, in words)
    /// is past the session's film budget.
    fn check_film_budget(&self, what: String, slots: u64, replicated: bool) -> Result<()> {
        let set = *self.film_budget.lock().unwrap_or_else(|e| e.into_inner());
        self.device.check_film_budget(&self.scene.source(), what, slots, replicated, set)
    }

    /// The device.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// How the scene was prepared: the adapter, the BVH and what it took.
    pub fn setup(&self) -> &Setup {
        &self.setup
    }

    /// The scene's own view: its camera and settings, all sample indices.
    pub fn default_request(&self) -> ImageRequest {
        ImageRequest { camera: self.scene.camera, settings: self.scene.settings.clone(), samples: None }
    }

    /// The scene's hash with `camera` ([`scene_hash`]), computed once per camera.
    fn scene_hash(&self, camera: &Camera) -> [u8; 32] {
        let mut cached = self.camera_hash.lock().unwrap_or_else(|e| e.into_inner());
        match *cached {
            Some((c, hash)) if c == *camera => hash,
            _ => {
                let hash = scene_hash(&self.scene, camera);
                *cached = Some((*camera, hash));
                hash
            }
        }
    }

    /// What every render of this session reports about the scene and its setup.
    /// `round_trips`: the device's count before the request made its film.
    fn info(&self, target_seconds: f64, compile_seconds: f64, request_seconds: f64, round_trips: u64) -> RenderInfo {
        let scene = &self.scene;
        RenderInfo {
            scene: scene.name.clone(),
            triangles: scene.world_triangle_count(),
            instances: scene.instances.len(),
            spheres: scene.spheres.len(),
            planes: scene.planes.len(),
            scene_bytes: scene.geometry_bytes(),
            setup: self.setup.clone(),
            target_seconds,
            compile_seconds,
            request_seconds,
            round_trips_before: round_trips,
        }
    }

    /// Starts an image: checks the request and makes its film on the device (and its
    /// pipeline, the first time this adapter sees its specialisation). Run it with
    /// [`Render::run`].
    pub fn render(&self, request: &ImageRequest) -> Result<Render> {
        let begun = Instant::now();
        let s = &request.settings;
        s.validate()?;
        request.camera.validate()?;
        let range = request.samples.clone().unwrap_or(0..s.spp);
        if range.start >= range.end || range.end > s.spp {
            return Err(Error::settings(format!(
                "sample range {}..{} must be non-empty and end at most at the {} samples per pixel",
                range.start, range.end, s.spp
            )));
        }
        let camera = self.frame.camera(&request.camera, self.scene.origin);
        camera.validate_f32()?;
        let what = format!("a {}x{} image", s.width, s.height);
        self.check_film_budget(what, s.width as u64 * s.height as u64, s.sampling.replicate_samples() >= 2)?;
        let (start, compiled, trips) = (Instant::now(), self.prepared.compile_seconds(), self.device.round_trips());
        let max_value = max_image_sample(&self.scene, s.background, &s.sampling.sky);
        let passes = self.prepared.image(&camera, s, value_exponent(max_value))?;
        let target_seconds = start.elapsed().as_secs_f64();
        let compile_seconds = self.prepared.compile_seconds() - compiled;
        let settings = SampleSettings::image(self.scene_hash(&request.camera), s);
        let mut acc = Accumulation::new(
            settings,
            self.device.kind(),
            self.setup.bvh_layout,
            self.options.quality,
            range.start,
            range.end,
            max_value,
        );
        acc.set_adapter(self.setup.adapter.name.clone());
        // In the scene's stored coordinates, where its primitives are.
        let stored = LocalFrame::IDENTITY.camera(&request.camera, self.scene.origin);
        let (scene, shift, (width, height)) =
            (self.scene.clone(), self.frame.surface_shift as f64, (s.width, s.height));
        let background = Box::new(move || background_pixels(&scene, &stored, width, height, shift));
        let request_seconds = begun.elapsed().as_secs_f64() - target_seconds;
        let info = self.info(target_seconds, compile_seconds, request_seconds, trips);
        Ok(Render::new(passes, acc, info).with_background(background))
    }

    /// AO at `probes` as a render that runs, saves, resumes and merges like an image: one
    /// film slot per probe, sample indices `samples` (all `0..spp` for `None`) of `spp` a
    /// probe, with the hemisphere, sampler, seed and maximum distance of `settings`. Its
    /// accumulation is [`Accumulation::probes`]'s, and [`Accumulation::probe_values`]
    /// reads the estimates off it. With `bent_normals` the film has four slots a probe:
    /// the AO, then the sums of the x, y and z of the directions that escaped, from the
    /// same rays ([`Accumulation::bent_normals`] reads them). What `aorender bake` runs.
    pub fn probe_render(
        &self,
        probes: &[Probe],
        spp: u32,
        samples: Option<Range<u32>>,
        settings: &Settings,
        bent_normals: bool,
    ) -> Result<Render> {
        self.probe_render_from(probes, 0, spp, samples, settings, bent_normals)
    }

    /// [`Session::probe_render`] of a block of a larger set of points that starts at point
    /// `first_point`: probe k takes the sample sequence of point `first_point` + k, so that
    /// blocks traced one after another give the values of the whole set traced at once
    /// (how `aorender bake` bounds the memory of a large texture bake).
    pub fn probe_render_from(
        &self,
        probes: &[Probe],
        first_point: u32,
        spp: u32,
        samples: Option<Range<u32>>,
        settings: &Settings,
        bent_normals: bool,
    ) -> Result<Render> {
        let begun = Instant::now();
        settings.sampling.validate()?;
        if spp == 0 {
            return Err(Error::settings("samples per point must be at least 1"));
        }
        let range = samples.unwrap_or(0..spp);
        if range.start >= range.end || range.end > spp {
            return Err(Error::settings(format!(
                "sample range {}..{} must be non-empty and end at most at the {spp} samples per point",
                range.start, range.end
            )));
        }
        if probes.is_empty() {
            return Err(Error::settings("no points to estimate AO at"));
        }
        let probes = checked(probes)?;
        let slots = if bent_normals { 4 } else { 1 };
        if probes.len() as u64 + u64::from(first_point) > u64::from(u32::MAX) {
            return Err(Error::settings(format!(
                "{} points from point {first_point}: at most 2³² in all",
                probes.len()
            )));
        }
        let what = format!("the film of {} probe points", probes.len());
        self.check_film_budget(what, probes.len() as u64 * slots as u64, settings.sampling.replicate_samples() >= 2)?;
        let (start, compiled, trips) = (Instant::now(), self.prepared.compile_seconds(), self.device.round_trips());
        let e = value_exponent(settings.sampling.sky.max_weight());
        let local = |p: &Probe| self.local_probe(p);
        let passes = self.prepared.probes(&probes, &local, first_point, slots, spp, settings, bent_normals, e)?;
        let target_seconds = start.elapsed().as_secs_f64();
        let compile_seconds = self.prepared.compile_seconds() - compiled;
        let geometry = self.geometry_hash.get_or_init(|| geometry_hash(&self.scene));
        let layout = if bent_normals { FilmLayout::BentProbes } else { FilmLayout::Probes };
        let mut hash = probes_hash(geometry, &probes);
        if first_point > 0 {
            // Another block's samples: a checkpoint of one is not another's.
            let mut h = blake3::Hasher::new();
            h.update(&hash);
            h.update(&first_point.to_le_bytes());
            hash = *h.finalize().as_bytes();
        }
        let points = probes.len() as u32;
        drop(probes);
        let (background, sampling) = (settings.background, &settings.sampling);
        let sample_settings = SampleSettings::new(hash, layout, slots, points, spp, background, sampling);
        let mut acc = Accumulation::new(
            sample_settings,
            self.device.kind(),
            self.setup.bvh_layout,
            self.options.quality,
            range.start,
            range.end,
            settings.sampling.sky.max_weight(),
        );
        acc.set_adapter(self.setup.adapter.name.clone());
        let request_seconds = begun.elapsed().as_secs_f64() - target_seconds;
        Ok(Render::new(passes, acc, self.info(target_seconds, compile_seconds, request_seconds, trips)))
    }

    /// Estimates AO at every probe with `samples` samples each, with the hemisphere,
    /// sampler, seed and maximum distance of `settings` (its image size and samples per
    /// pixel are not used). A probe's normal need not be of unit length; a zero or
    /// non-finite one is an [`Error::Probe`] naming the probe. The probes' samples are
    /// spread over several slots (lanes) each and their sums added exactly.
    pub fn probe(&self, probes: &[Probe], samples: u32, settings: &Settings) -> Result<ProbeOutput> {
        self.probe_with(probes, samples, settings, &mut Control::default())
    }

    /// [`Session::probe`] under `control`: a stop flag, a time limit (the values then
    /// hold fewer samples, as [`ProbeValue::samples`] says; with none, their mean is NaN)
    /// and progress in rounds.
    pub fn probe_with(
        &self,
        probes: &[Probe],
        samples: u32,
        settings: &Settings,
        control: &mut Control,
    ) -> Result<ProbeOutput> {
        let begun = Instant::now();
        settings.sampling.validate()?;
        if samples == 0 {
            return Err(Error::settings("samples per probe must be at least 1"));
        }
        let probes = &checked(probes)?[..];
        let adapter = self.setup.adapter.name.clone();
        if probes.is_empty() {
            let (pipeline_seconds, compile_seconds, times) = (0.0, 0.0, PassTimes::default());
            let request_seconds = begun.elapsed().as_secs_f64();
            return Ok(ProbeOutput {
                values: Vec::new(),
                rays: 0,
                seconds: 0.0,
                adapter,
                pipeline_seconds,
                compile_seconds,
                request_seconds,
                times,
            });
        }
        let lanes = lanes_for(probes.len(), samples);
        let what = format!("the film of {} probe points", probes.len());
        self.check_film_budget(what, probes.len() as u64 * lanes as u64, settings.sampling.replicate_samples() >= 2)?;
        let rounds = samples.div_ceil(lanes);
        let e = value_exponent(settings.sampling.sky.max_weight());
        let (start, compiled, trips) = (Instant::now(), self.prepared.compile_seconds(), self.device.round_trips());
        let local = |p: &Probe| self.local_probe(p);
        let passes = self.prepared.probes(probes, &local, 0, lanes, samples, settings, false, e)?;
        let pipeline_seconds = start.elapsed().as_secs_f64();
        let compile_seconds = self.prepared.compile_seconds() - compiled;
        let geometry = self.geometry_hash.get_or_init(|| geometry_hash(&self.scene));
        let hash = probes_hash(geometry, probes);
        let (points, background) = (probes.len() as u32, settings.background);
        let sample_settings =
            SampleSettings::new(hash, FilmLayout::Probes, lanes, points, samples, background, &settings.sampling);
        let acc = Accumulation::new(
            sample_settings,
            self.device.kind(),
            self.setup.bvh_layout,
            self.options.quality,
            0,
            rounds,
            settings.sampling.sky.max_weight(),
        );
        let request_seconds = begun.elapsed().as_secs_f64() - pipeline_seconds;
        let info = self.info(pipeline_seconds, compile_seconds, request_seconds, trips);
        let mut render = Render::new(passes, acc, info);
        render.run(control)?;
        let acc = render.accumulation()?;
        let start = Instant::now();
        let values = acc.lane_probe_values()?;
        let mut times = render.times();
        times.host_stats_seconds += start.elapsed().as_secs_f64();
        let (rays, seconds) = (acc.ao_rays(), acc.render_seconds());
        Ok(ProbeOutput { values, rays, seconds, adapter, pipeline_seconds, compile_seconds, request_seconds, times })
    }
}

/// Prepares `scene` in its local frame ([`Scene::local_origin`]) with `prepare`, leaving
/// it in its own coordinates. A scene that moves exactly is moved in place and back (both
/// exact), so no second copy is held; one that does not is copied, the copy moved.
fn prepare_in_local_frame(
    scene: &mut Scene,
    prepare: impl FnOnce(&Scene) -> Result<Vec<(Prepared, Setup)>>,
) -> Result<(LocalFrame, Vec<(Prepared, Setup)>)> {
    let origin = scene.local_origin();
    if origin == DVec3::ZERO {
        return Ok((LocalFrame::IDENTITY, prepare(scene)?));
    }
    if scene.moves_exactly(origin) {
        let frame = scene.move_to(origin);
        let prepared = prepare(scene);
        scene.move_to(-origin);
        return Ok((frame, prepared?));
    }
    let mut local = scene.clone();
    let frame = local.move_to(origin);
    Ok((frame, prepare(&local)?))
}
