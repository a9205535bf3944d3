//! `aorender.Scene`: a scene made from arrays or loaded from a file, with one session
//! (the BVH built and uploaded) per device it has been asked on, kept for its lifetime.

use crate::arrays::{faces, out, relative_vec3s, vec3s};
use crate::engine::{device, interruptible, sampling, to_py};
use aorender::bake::{
    AssetMesh, Bake, BakeAt, BakeRequest, GenerateUvs, ReadInputs, TextureOptions, TextureRequest, UvWrap,
    load_for_bake,
};
use aorender::output::{FilePlan, OutputRules};
use aorender::scene::mesh_triangles;
use aorender::{
    BvhOptions, Camera, Control, ImageRequest, LoadOptions, Probe, Projection, ReadLimits, Scene, Session, Settings,
    SurfaceTolerance,
};
use glam::{DVec3, Vec3};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::{PyUserWarning, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// AO values and their standard errors, one per point.
pub type Values<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>);

/// A scene prepared for AO queries, images and bakes.
///
/// Make one with `Scene.from_arrays(V, F)` or `Scene.load(path)`. The BVH is built the
/// first time the scene is used on a device and kept for every later call on that device.
#[pyclass(name = "Scene", module = "aorender", frozen)]
pub struct PyScene {
    scene: Scene,
    /// The mesh a scene made from arrays holds, as a bake reads it.
    arrays: Option<AssetMesh>,
    /// The file a loaded scene came from.
    source: Option<PathBuf>,
    /// The read budget it was loaded within, for the bake's reads of its files.
    limits: ReadLimits,
    /// The mesh files of a loaded scene as its bakes take them, read with the scene: a
    /// bake parses no file again.
    read: ReadInputs,
    /// One session per device, by kind and adapter name.
    sessions: Mutex<Vec<(String, Arc<Session>)>>,
}

impl PyScene {
    /// A scene of the triangles `f` of the vertices `v` (indices checked by the caller).
    pub fn of_arrays(name: &str, v: Vec<Vec3>, f: Vec<[u32; 3]>) -> PyResult<PyScene> {
        let triangles =
            mesh_triangles(Path::new(name), f.iter().map(|t| t.map(|i| v[i as usize])), 1.0).map_err(to_py)?;
        let scene = Scene::from_triangles(name, triangles);
        let mesh = AssetMesh {
            label: name.into(),
            positions: v,
            normals: None,
            face_starts: (0..=f.len() as u32).map(|k| 3 * k).collect(),
            face_indices: f.into_iter().flatten().collect(),
            to_file: glam::Mat3::IDENTITY,
            ..AssetMesh::default()
        };
        let limits = ReadLimits::with_memory(u64::MAX);
        Ok(PyScene {
            scene,
            arrays: Some(mesh),
            source: None,
            limits,
            read: ReadInputs::default(),
            sessions: Mutex::new(Vec::new()),
        })
    }

    /// The session on the device `name` names, made the first time (BVH built and
    /// uploaded with the GIL released).
    pub fn session(&self, py: Python<'_>, name: &str) -> PyResult<Arc<Session>> {
        let device = device(py, name)?;
        let info = device.info();
        let key = format!("{}:{}", device.kind().name(), info.name);
        py.allow_threads(|| {
            // Held while building: a second thread asking for the same device waits for
            // this build rather than making its own.
            let mut sessions = self.sessions.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((_, s)) = sessions.iter().find(|(k, _)| *k == key) {
                return Ok(s.clone());
            }
            let session = Arc::new(Session::new(&device, self.scene.clone(), &BvhOptions::default())?);
            sessions.push((key, session.clone()));
            Ok(session)
        })
        .map_err(to_py)
    }

    /// AO at `probes` (checked by [`probes`]), `samples` rays each, each point put on the
    /// surface it lies on within `tolerance`; a warning counts the points on none.
    pub fn probe<'py>(
        &self,
        py: Python<'py>,
        probes: &[Probe],
        samples: u32,
        settings: &Settings,
        tolerance: SurfaceTolerance,
        device_name: &str,
    ) -> PyResult<Values<'py>> {
        let session = self.session(py, device_name)?;
        let located = py.allow_threads(|| session.locate(probes, tolerance)).map_err(to_py)?;
        if let Some(first) = located.on_surface.iter().position(|&on| !on) {
            let message = format!(
                "{} of {} points (the first is P[{first}]) lie on no surface within the tolerance: their rays start exactly at them (surface_tolerance=D widens it)",
                located.off_surface(),
                probes.len()
            );
            PyErr::warn(py, &py.get_type::<PyUserWarning>(), &std::ffi::CString::new(message)?, 1)?;
        }
        let probes = &located.probes;
        let result = interruptible(py, |control| session.probe_with(probes, samples, settings, control))?;
        let (ao, se) = result.values.iter().map(|v| (v.mean, v.std_error)).unzip();
        Ok((out(py, ao), out(py, se)))
    }
}

/// The `surface_tolerance` keyword: `None` for the default, else a distance, checked.
pub fn tolerance(surface_tolerance: Option<f64>) -> PyResult<SurfaceTolerance> {
    match surface_tolerance {
        None => Ok(SurfaceTolerance::Relative),
        Some(d) => SurfaceTolerance::distance(d as f32).map_err(|_| {
            PyValueError::new_err(format!("surface_tolerance must be a finite distance of at least 0, got {d}"))
        }),
    }
}

/// The points `p` and normals `n` as probes, checked; the points, given in the scene's own
/// coordinates, are taken relative to its `origin` in f64 (they are as given where it is
/// zero).
pub fn probes(
    py: Python<'_>,
    p: &Bound<'_, PyAny>,
    n: &Bound<'_, PyAny>,
    samples: u32,
    origin: DVec3,
) -> PyResult<Vec<Probe>> {
    let positions = if origin == DVec3::ZERO { vec3s(py, p, "P")? } else { relative_vec3s(py, p, "P", origin)? };
    let normals = vec3s(py, n, "N")?;
    if positions.len() != normals.len() {
        return Err(PyValueError::new_err(format!(
            "P and N must have as many rows: P has {}, N has {}",
            positions.len(),
            normals.len()
        )));
    }
    if samples == 0 {
        return Err(PyValueError::new_err("samples must be at least 1"));
    }
    positions
        .into_iter()
        .zip(normals)
        .enumerate()
        .map(|(i, (p, n))| {
            if n == Vec3::ZERO || !n.length().is_finite() {
                return Err(PyValueError::new_err(format!("N[{i}] is not a usable normal: {n}")));
            }
            Probe::new(p, n).map_err(|e| PyValueError::new_err(format!("point {i}: {}", e.message())))
        })
        .collect()
}

/// The camera `dict` asks for, starting from `camera`: keys `eye`, `look_at`, `up`
/// (3-sequences), and `fov` (vertical, degrees) or `ortho_height`.
fn camera_from(dict: &Bound<'_, PyDict>, mut camera: Camera) -> PyResult<Camera> {
    let vec = |v: &Bound<'_, PyAny>, key: &str| -> PyResult<DVec3> {
        let a: [f64; 3] =
            v.extract().map_err(|_| PyValueError::new_err(format!("camera['{key}'] must be three numbers")))?;
        Ok(DVec3::from(a))
    };
    for (key, value) in dict.iter() {
        let key: String = key.extract()?;
        match key.as_str() {
            "eye" => camera.eye = vec(&value, &key)?,
            "look_at" => camera.look_at = vec(&value, &key)?,
            "up" => camera.up = vec(&value, &key)?.as_vec3(),
            "fov" => camera.projection = Projection::Perspective { vfov_deg: value.extract::<f64>()? as f32 },
            "ortho_height" => camera.projection = Projection::Orthographic { height: value.extract::<f64>()? as f32 },
            _ => {
                return Err(PyValueError::new_err(format!(
                    "unknown camera key '{key}': expected eye, look_at, up, fov or ortho_height"
                )));
            }
        }
    }
    if dict.contains("fov")? && dict.contains("ortho_height")? {
        return Err(PyValueError::new_err("camera takes fov (perspective) or ortho_height (orthographic), not both"));
    }
    match camera.projection {
        Projection::Perspective { vfov_deg: f } if !(f > 0.0 && f < 180.0) => {
            Err(PyValueError::new_err(format!("camera fov must be between 0 and 180 degrees, got {f}")))
        }
        Projection::Orthographic { height: h } if !(h > 0.0 && h.is_finite()) => {
            Err(PyValueError::new_err(format!("camera ortho_height must be positive, got {h}")))
        }
        _ => {
            camera.validate().map_err(to_py)?;
            Ok(camera)
        }
    }
}

/// The camera as a dict of the keys `camera_from` reads.
fn camera_dict<'py>(py: Python<'py>, c: &Camera) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("eye", c.eye.to_array())?;
    d.set_item("look_at", c.look_at.to_array())?;
    d.set_item("up", c.up.to_array())?;
    match c.projection {
        Projection::Perspective { vfov_deg } => d.set_item("fov", vfov_deg)?,
        Projection::Orthographic { height } => d.set_item("ortho_height", height)?,
    }
    Ok(d)
}

#[pymethods]
impl PyScene {
    /// Scene.from_arrays(V, F, name="arrays")
    ///
    /// A scene of one triangle mesh: V (n, 3) vertex positions of any real dtype, F (m, 3)
    /// vertex indices of any integer dtype, in any memory order. Triangles of zero area are
    /// dropped (no ray can hit them); a mesh left with none is a ValueError. Albedo 1.
    #[staticmethod]
    #[pyo3(signature = (V, F, name = "arrays"))]
    #[allow(non_snake_case)]
    fn from_arrays(py: Python<'_>, V: &Bound<'_, PyAny>, F: &Bound<'_, PyAny>, name: &str) -> PyResult<PyScene> {
        let v = vec3s(py, V, "V")?;
        let f = faces(py, F, "F", v.len())?;
        PyScene::of_arrays(name, v, f).map_err(|e| {
            // The mesh's own errors name the scene; say which argument holds it.
            PyValueError::new_err(format!("V, F: {}", e.value(py)))
        })
    }

    /// Scene.load(path, *, allow_external_uris=False, read_budget=None)
    ///
    /// A scene file (.toml: meshes, spheres, planes, a camera) or a mesh file (.obj, .ply,
    /// .gltf, .glb, optionally gzipped), read as `aorender render` reads it. Unreadable or
    /// invalid files raise OSError naming the file, and so does a file that needs more
    /// memory than the read budget: `read_budget` bytes, else AORENDER_READ_BUDGET, else
    /// half of the available memory. A glTF file's buffers and images must lie in its
    /// folder unless `allow_external_uris`. What was read of the mesh files is kept for
    /// `bake`, which parses no file again.
    #[staticmethod]
    #[pyo3(signature = (path, *, allow_external_uris = false, read_budget = None))]
    fn load(py: Python<'_>, path: PathBuf, allow_external_uris: bool, read_budget: Option<u64>) -> PyResult<PyScene> {
        let limits = match read_budget {
            Some(0) => return Err(PyValueError::new_err("read_budget must be at least 1 byte")),
            Some(bytes) => ReadLimits::with_memory(bytes),
            None => ReadLimits::from_env().map_err(to_py)?,
        };
        let options = LoadOptions { limits: limits.clone(), allow_external_uris };
        // The mesh files are parsed once, for the scene and for any bake of it.
        let (scene, read) = py.allow_threads(|| load_for_bake(&path, &options)).map_err(to_py)?;
        Ok(PyScene { scene, arrays: None, source: Some(path), limits, read, sessions: Mutex::new(Vec::new()) })
    }

    /// The scene's name (the file's stem, or the name given to from_arrays).
    #[getter]
    fn name(&self) -> String {
        self.scene.name.clone()
    }

    /// Triangles in the world (instanced placements counted).
    #[getter]
    fn triangles(&self) -> usize {
        self.scene.world_triangle_count()
    }

    /// The scene's camera, as a dict of the keys `render` takes.
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        camera_dict(py, &self.scene.camera)
    }

    fn __repr__(&self) -> String {
        format!("Scene({:?}, triangles={})", self.scene.name, self.scene.world_triangle_count())
    }

    /// s.ambient_occlusion(P, N, samples=256, *, hemisphere="cosine", sampler="independent",
    /// max_distance=None, seed=0, replicate=None, surface_tolerance=None, device="auto") -> (ao, std_error)
    ///
    /// AO at the points P (k, 3) about the normals N (k, 3) (any length but zero), with
    /// `samples` rays each: float64 arrays of k values, 1 fully open, and their standard
    /// errors. See `aorender.ambient_occlusion` for the estimator and its arguments.
    #[pyo3(signature = (P, N, samples = 256, *, hemisphere = "cosine", sampler = "independent", max_distance = None, seed = 0, replicate = None, sky = None, surface_tolerance = None, device = "auto"))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn ambient_occlusion<'py>(
        &self,
        py: Python<'py>,
        P: &Bound<'py, PyAny>,
        N: &Bound<'py, PyAny>,
        samples: u32,
        hemisphere: &str,
        sampler: &str,
        max_distance: Option<f64>,
        seed: u32,
        replicate: Option<u32>,
        sky: Option<&Bound<'py, PyAny>>,
        surface_tolerance: Option<f64>,
        device: &str,
    ) -> PyResult<Values<'py>> {
        let probes = probes(py, P, N, samples, self.scene.origin)?;
        let sampling = sampling(hemisphere, sampler, seed, max_distance, replicate, sky)?;
        let settings = Settings { sampling, ..Settings::default() };
        let tolerance = tolerance(surface_tolerance)?;
        self.probe(py, &probes, samples, &settings, tolerance, device)
    }

    /// s.render(width, height, spp, *, camera=None, hemisphere="cosine", sampler="independent",
    /// seed=0, max_distance=None, replicate=None, background=0.0, device="auto") -> (image, stats)
    ///
    /// An AO image as `aorender render` makes it: a float32 array (height, width), row 0
    /// at the top, each pixel the mean of `spp` samples (albedo × AO at the surface its
    /// camera ray hits; `background` where it hits nothing), and the render's figures as
    /// `aorender render --stats` writes them (a dict). `camera` is a dict of any of eye,
    /// look_at, up (3 numbers each) and fov (vertical, degrees) or ortho_height; keys left
    /// out keep the scene's camera (a mesh's, the automatic framing).
    ///
    /// Scale-out, as `aorender render --sample-range` and `aorender merge`:
    /// `sample_range=(start, end)` renders only those sample indices of the `spp` (a
    /// shard) and `checkpoint=PATH` saves its exact sums; `merge=[PATH, ...]` renders
    /// nothing and returns the image of such shards' sums added exactly (all of 0..spp):
    /// the same floats as the render in one piece.
    #[pyo3(signature = (width, height, spp, *, camera = None, hemisphere = "cosine", sampler = "independent", seed = 0, max_distance = None, replicate = None, sky = None, background = 0.0, device = "auto", sample_range = None, checkpoint = None, merge = None))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        width: u32,
        height: u32,
        spp: u32,
        camera: Option<&Bound<'py, PyDict>>,
        hemisphere: &str,
        sampler: &str,
        seed: u32,
        max_distance: Option<f64>,
        replicate: Option<u32>,
        sky: Option<&Bound<'py, PyAny>>,
        background: f64,
        device: &str,
        sample_range: Option<(u32, u32)>,
        checkpoint: Option<PathBuf>,
        merge: Option<Vec<PathBuf>>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let sampling = sampling(hemisphere, sampler, seed, max_distance, replicate, sky)?;
        let settings = Settings { width, height, spp, background: background as f32, sampling };
        settings.validate().map_err(to_py)?;
        let camera = match camera {
            Some(d) => camera_from(d, self.scene.camera)?,
            None => self.scene.camera,
        };
        let (samples, merge) = shard_options(sample_range, spp, checkpoint.is_some(), merge, "renders")?;
        let session = self.session(py, device)?;
        if !merge.is_empty() {
            let kind = session.device().kind();
            let (film, stats) =
                py.allow_threads(|| merged_image(&self.scene, &camera, &settings, kind, &merge, &self.limits))?;
            let pixels: Vec<f32> = film.mean().into_iter().map(|m| m as f32).collect();
            let image = PyArray1::from_vec(py, pixels).reshape([height as usize, width as usize])?;
            let stats = py.import("json")?.call_method1("loads", (stats.to_string(),))?;
            return Ok((image.into_any(), stats));
        }
        let request = ImageRequest { camera, settings, samples };
        let rendered = interruptible(py, |control| {
            let mut render = session.render(&request)?;
            let Some(path) = &checkpoint else {
                render.run(control)?;
                return render.finish();
            };
            saving_to(control, path, |inner| render.run(inner).map(drop))?;
            render.finish()
        })?;
        let pixels: Vec<f32> = rendered.film.mean().into_iter().map(|m| m as f32).collect();
        let image = PyArray1::from_vec(py, pixels).reshape([height as usize, width as usize])?;
        let json = serde_json::to_string(&rendered.stats)
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        let stats = py.import("json")?.call_method1("loads", (json,))?;
        Ok((image.into_any(), stats))
    }

    /// s.bake(samples=256, *, at="vertices", hemisphere="cosine", sampler="independent", seed=0,
    /// max_distance=None, replicate=None, device="auto", output=None, std_error=False, colors=False,
    /// overwrite=False, bent_normals=False, texture=None, uv_set=0, padding=4, bit_depth=8,
    /// texel_points=4, uv_wrap="file", generate_uvs="auto", sample_range=None, checkpoint=None,
    /// merge=None) -> (ao, std_error) or (ao, std_error, bent_normals)
    ///
    /// AO baked at every vertex (about its area-weighted normal, or the file's normal
    /// where it has one) or at every face's centroid (`at="faces"`) of the scene's own
    /// meshes, as `aorender bake` computes it: float64 arrays, one entry per vertex (face)
    /// of each mesh, the meshes in order (a from_arrays scene: the rows of V). A vertex no
    /// face of non-zero area uses gets 1 with standard error 0. With `bent_normals=True` a
    /// third array (n, 3) holds the bent normals (the mean direction of the rays that
    /// escaped, normalised), from the same rays.
    ///
    /// For a loaded scene, `output` writes the files as `aorender bake -o output` does: a
    /// mesh file of the input's format for a mesh file, a directory for a scene file;
    /// `std_error`, `colors` and `bent_normals` add those attributes to it.
    ///
    /// `texture=SIZE` (N or (W, H) texels) bakes into a texture instead, written as
    /// `aorender bake --texture` writes it into `output` (a .png or .exr map, or a glTF/GLB
    /// mesh referencing it; for OBJ and PLY the map beside the mesh); `uv_set`, `padding`,
    /// `bit_depth`, `texel_points`, `uv_wrap` ("file", "refuse", "repeat") and
    /// `generate_uvs` ("auto", "always", "never") are the command's options. It returns
    /// the figures of the texture (a dict) instead of arrays.
    ///
    /// Scale-out: `sample_range=(start, end)` traces only those sample indices of the
    /// `samples` (a shard), and `checkpoint=PATH` saves the shard's exact sums there;
    /// `merge=[PATH, ...]` traces nothing and bakes from such shards, whose sums are added
    /// exactly: the shards of one bake, merged, give the bytes of the bake in one piece.
    #[pyo3(signature = (samples = 256, *, at = "vertices", hemisphere = "cosine", sampler = "independent", seed = 0, max_distance = None, replicate = None, sky = None, device = "auto", output = None, std_error = false, colors = false, overwrite = false, bent_normals = false, texture = None, uv_set = 0, padding = 4, bit_depth = 8, texel_points = 4, uv_wrap = "file", generate_uvs = "auto", sample_range = None, checkpoint = None, merge = None))]
    #[allow(clippy::too_many_arguments)]
    fn bake<'py>(
        &self,
        py: Python<'py>,
        samples: u32,
        at: &str,
        hemisphere: &str,
        sampler: &str,
        seed: u32,
        max_distance: Option<f64>,
        replicate: Option<u32>,
        sky: Option<&Bound<'py, PyAny>>,
        device: &str,
        output: Option<PathBuf>,
        std_error: bool,
        colors: bool,
        overwrite: bool,
        bent_normals: bool,
        texture: Option<&Bound<'py, PyAny>>,
        uv_set: u32,
        padding: u32,
        bit_depth: u8,
        texel_points: u32,
        uv_wrap: &str,
        generate_uvs: &str,
        sample_range: Option<(u32, u32)>,
        checkpoint: Option<PathBuf>,
        merge: Option<Vec<PathBuf>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let sampling = sampling(hemisphere, sampler, seed, max_distance, replicate, sky)?;
        let settings = Settings { sampling, ..Settings::default() };
        let value_error = |e: aorender::Error| PyValueError::new_err(e.to_string());
        let at = match at {
            "vertices" => BakeAt::Vertices,
            "faces" => BakeAt::Faces,
            _ => return Err(PyValueError::new_err(format!("at must be 'vertices' or 'faces', got '{at}'"))),
        };
        if samples == 0 {
            return Err(PyValueError::new_err("samples must be at least 1"));
        }
        let (sample_range, merge) = shard_options(sample_range, samples, checkpoint.is_some(), merge, "bakes")?;
        let texture = match texture {
            Some(size) => Some(texture_request(size, uv_set, padding, bit_depth, texel_points, uv_wrap, generate_uvs)?),
            None => None,
        };
        if texture.is_some() && (std_error || colors || at == BakeAt::Faces) {
            return Err(PyValueError::new_err(
                "std_error, colors and at='faces' are for vertex and face bakes, not texture bakes",
            ));
        }
        let is_texture = texture.is_some();
        let request = BakeRequest {
            at,
            samples,
            sample_range,
            bent_normals,
            std_error,
            colors,
            output: output.clone(),
            output_name: "output".to_string(),
            overwrite,
            texture,
            one_film: checkpoint.is_some() || !merge.is_empty(),
            limits: self.limits.clone(),
            settings: Some(settings),
        };
        // Planned, and every output checked, before any ray.
        let bake = match (&self.arrays, &self.source) {
            (Some(mesh), _) => Bake::of_mesh(&self.scene, mesh, &request).map_err(value_error)?,
            (None, source) => {
                let input = source.clone().unwrap_or_else(|| PathBuf::from(&self.scene.name));
                let mut files = FilePlan::new();
                files.scene(&input);
                for path in &merge {
                    files.input(path, "a checkpoint merge adds");
                }
                if let Some(path) = &checkpoint {
                    files.output_with(path, "checkpoint", OutputRules::default()).map_err(value_error)?;
                }
                if let (Some(path), false) =
                    (&output, input.extension().is_some_and(|e| e.eq_ignore_ascii_case("toml")))
                {
                    let rules = OutputRules { replacing: overwrite.then_some(input.as_path()), new_directories: true };
                    files.output_with(path, "output", rules).map_err(value_error)?;
                }
                py.allow_threads(|| Bake::with_inputs(&self.scene, &self.read, &input, &request, &mut files))
                    .map_err(value_error)?
            }
        };
        let session = self.session(py, device)?;
        let trace = if merge.is_empty() {
            let save_to = checkpoint.clone();
            interruptible(py, |control| {
                let Some(path) = &save_to else {
                    return session.bake(&bake, None, control);
                };
                saving_to(control, path, |inner| session.bake(&bake, None, inner))
            })?
        } else {
            py.allow_threads(|| {
                let mut shards = Vec::with_capacity(merge.len());
                let mut held = 0;
                for path in &merge {
                    let shard = aorender::Accumulation::read_with(path, &self.limits.after(held))?;
                    held += shard.memory_bytes();
                    shards.push((path.clone(), shard));
                }
                let expected = bake.expected(session.scene(), session.device().kind(), &BvhOptions::default())?;
                bake.merge(&shards, &expected)
            })
            .map_err(|e| match e {
                // Shards that are not this bake's, or not all of it: the caller's input.
                aorender::Error::Checkpoint { .. } => PyValueError::new_err(e.to_string()),
                e => to_py(e),
            })?
        };
        let samples_done = trace.samples;
        let baked = py.allow_threads(|| bake.finish(trace)).map_err(to_py)?;
        let written = py.allow_threads(|| bake.write(&baked, samples_done)).map_err(to_py)?;
        for (path, note) in &written.notes {
            PyErr::warn(
                py,
                &py.get_type::<PyUserWarning>(),
                &std::ffi::CString::new(format!("{}: {note}", path.display()))?,
                1,
            )?;
        }
        if is_texture {
            let json = serde_json::to_string(&written.texture)
                .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
            return py.import("json")?.call_method1("loads", (json,));
        }
        let values = &baked.values;
        let ao = values.iter().flat_map(|b| b.ao.iter().map(|&v| v as f64)).collect();
        let se = values.iter().flat_map(|b| b.std_error.iter().map(|&v| v as f64)).collect();
        if !bent_normals {
            return Ok((out(py, ao), out(py, se)).into_pyobject(py)?.into_any());
        }
        let bent: Vec<f64> = values
            .iter()
            .flat_map(|b| b.bent_normals.iter().flatten().flat_map(|n| n.to_array().map(f64::from)))
            .collect();
        let rows = bent.len() / 3;
        let bent = PyArray1::from_vec(py, bent).reshape([rows, 3])?;
        Ok((out(py, ao), out(py, se), bent).into_pyobject(py)?.into_any())
    }
}

/// The texture options of [`PyScene::bake`]: `size` is N or (W, H).
fn texture_request(
    size: &Bound<'_, PyAny>,
    uv_set: u32,
    padding: u32,
    bit_depth: u8,
    points: u32,
    uv_wrap: &str,
    generate_uvs: &str,
) -> PyResult<TextureRequest> {
    let (width, height) = match size.extract::<u32>() {
        Ok(n) => (n, n),
        Err(_) => size
            .extract::<(u32, u32)>()
            .map_err(|_| PyValueError::new_err("texture must be a size in texels: N or (W, H)"))?,
    };
    let wrap = match uv_wrap {
        "file" => UvWrap::File,
        "refuse" => UvWrap::Refuse,
        "repeat" => UvWrap::Repeat,
        _ => {
            return Err(PyValueError::new_err(format!(
                "uv_wrap must be 'file', 'refuse' or 'repeat', got '{uv_wrap}'"
            )));
        }
    };
    let generate_uvs = match generate_uvs {
        "auto" => GenerateUvs::Auto,
        "always" => GenerateUvs::Always,
        "never" => GenerateUvs::Never,
        _ => {
            return Err(PyValueError::new_err(format!(
                "generate_uvs must be 'auto', 'always' or 'never', got '{generate_uvs}'"
            )));
        }
    };
    if bit_depth != 8 && bit_depth != 16 {
        return Err(PyValueError::new_err(format!("bit_depth must be 8 or 16, got {bit_depth}")));
    }
    let options = TextureOptions { width, height, uv_set, points, padding, wrap, seed: 0 };
    options.validate().map_err(|e| PyValueError::new_err(format!("texture: {}", e.message())))?;
    let memory_bytes = aorender::host_memory::memory_available().unwrap_or(u64::MAX);
    Ok(TextureRequest { options, generate_uvs, bit_depth, memory_bytes })
}

/// The film of shards' checkpoints of one image (`scene` seen by `camera` with
/// `settings`), their sums added exactly, and its figures; every sample of 0..spp must be
/// there.
fn merged_image(
    scene: &Scene,
    camera: &Camera,
    settings: &Settings,
    kind: aorender::DeviceKind,
    paths: &[PathBuf],
    limits: &ReadLimits,
) -> PyResult<(aorender::Film, serde_json::Value)> {
    let value_error = |e: aorender::Error| match e {
        aorender::Error::Checkpoint { .. } => PyValueError::new_err(e.to_string()),
        e => to_py(e),
    };
    let mut shards = Vec::with_capacity(paths.len());
    let mut held = 0;
    for path in paths {
        let shard = aorender::Accumulation::read_with(path, &limits.after(held)).map_err(value_error)?;
        held += shard.memory_bytes();
        shards.push((path.clone(), shard));
    }
    let expected =
        aorender::Accumulation::image(scene, camera, settings, 0..settings.spp, kind, &BvhOptions::default());
    let diff = shards[0].1.settings().differences(expected.settings());
    if !diff.is_empty() {
        return Err(PyValueError::new_err(format!(
            "{}: holds samples of another render: {} (checkpoint's value first)",
            shards[0].0.display(),
            diff.join("; ")
        )));
    }
    let merged = aorender::merge(&shards).map_err(value_error)?;
    if merged.first != 0 || merged.end != settings.spp {
        return Err(PyValueError::new_err(format!(
            "{}: the shards hold samples {}..{}, not all 0..{} of spp {}",
            shards[0].0.display(),
            merged.first,
            merged.end,
            settings.spp,
            settings.spp
        )));
    }
    let adapters: Vec<String> = merged.shards.iter().map(|s| s.adapter.clone()).collect();
    let stats = serde_json::json!({
        "samples_per_pixel": merged.end - merged.first,
        "shards": merged.shards.len(),
        "adapter": adapters.join(", "),
    });
    Ok((merged.film, stats))
}

/// A shard's options checked: `sample_range` a non-empty range within 0..`total`, and a
/// merge (which `verb`s from finished shards) without a range or a checkpoint.
fn shard_options(
    sample_range: Option<(u32, u32)>,
    total: u32,
    checkpoint: bool,
    merge: Option<Vec<PathBuf>>,
    verb: &str,
) -> PyResult<(Option<std::ops::Range<u32>>, Vec<PathBuf>)> {
    let range = match sample_range {
        Some((a, b)) if a >= b || b > total => {
            return Err(PyValueError::new_err(format!(
                "sample_range ({a}, {b}) must be a non-empty range of sample indices within 0..{total}"
            )));
        }
        Some((a, b)) => Some(a..b),
        None => None,
    };
    let merge = merge.unwrap_or_default();
    if !merge.is_empty() && (range.is_some() || checkpoint) {
        return Err(PyValueError::new_err(format!(
            "merge {verb} from finished shards: it takes no sample_range or checkpoint"
        )));
    }
    Ok((range, merge))
}

/// Runs `run` with `control`'s stop flag and progress, and the accumulation saved to
/// `path` as the run goes and when it ends (finished or stopped): a shard's checkpoint.
fn saving_to<T>(
    control: &mut Control,
    path: &std::path::Path,
    run: impl FnOnce(&mut Control) -> aorender::Result<T>,
) -> aorender::Result<T> {
    let mut save = |acc: &aorender::Accumulation| acc.write(path);
    let mut outer = control.progress.as_deref_mut();
    let mut progress = |p: &aorender::Progress| {
        if let Some(f) = outer.as_deref_mut() {
            f(p)
        }
    };
    let mut inner =
        Control { stop: control.stop, progress: Some(&mut progress), save: Some(&mut save), ..Control::default() };
    run(&mut inner)
}
