//! The `aorender` Python module: ambient occlusion at points of a triangle mesh given as
//! numpy arrays, AO images and per-vertex bakes, on the GPU (wgpu) or the CPU reference.
//! The engine is the `aorender` crate; this crate converts and checks the arrays, keeps
//! one session (the BVH built and uploaded) per scene and device, releases the GIL while
//! tracing, and turns the engine's errors into Python exceptions.

mod arrays;
mod engine;
mod scene;

use pyo3::prelude::*;
use scene::PyScene;

/// ambient_occlusion(V, F, P, N, samples=256, *, hemisphere="cosine", sampler="independent",
/// max_distance=None, seed=0, replicate=None, sky=None, surface_tolerance=None, device="auto") -> (ao, std_error)
///
/// Ambient occlusion of the triangle mesh (V, F) at the points P about the normals N.
///
/// V (n, 3) vertex positions, any real dtype; F (m, 3) vertex indices, any integer dtype;
/// P and N (k, 3) points and normals (normals of any non-zero length). Any memory order;
/// values are converted to 32-bit floats, the engine's precision. Returns two float64
/// arrays of k entries: the AO estimate and its standard error.
///
/// AO here is the cosine-weighted visibility, 1 where the hemisphere is fully open (the
/// convention of pbrt's AO integrator):
///
///     AO(p, n) = 1/π ∫ V(p, ω) cos θ dω     over the hemisphere about n,
///
/// V = 1 for a ray that escapes (or travels farther than max_distance). With
/// hemisphere="cosine" each sample is 0 or 1 (directions drawn ∝ cos θ); with "uniform"
/// directions are uniform and each sample is 2 V cos θ — the same AO, a noisier
/// estimator. Either way the value estimates the integral above.
///
/// libigl's igl.embree.ambient_occlusion(V, F, P, N, num_samples) returns something else:
/// the fraction of `num_samples` directions, drawn uniformly over the hemisphere about N
/// (and not weighted by cos θ), whose ray hits the mesh. So 1 − libigl's value is the
/// unweighted uniform visibility 1/(2π) ∫ V dω, which differs from AO above wherever the
/// occlusion is not the same at every angle (near-grazing blockers count more in
/// libigl's). Neither this module's "uniform" nor "cosine" estimates libigl's quantity;
/// compare 1 − igl with this AO only as two related measures (equal for a point that is
/// fully open or fully closed).
///
/// samples: rays per point. sampler: "independent" (the default, as on the command
/// line), "sobol" (scrambled Sobol' points, lower error), "stratified" or "grid".
/// replicate: samples per independently randomised replicate of "sobol" and
/// "stratified" (a power of two up to 256, of four for stratified), from whose spread
/// std_error is estimated; None (the default) keeps one replicate, the best points, and
/// std_error is then the spread of single samples, which overestimates their error (valid
/// as it stands for "independent"). seed: the random numbers' seed; the same seed,
/// samples and device give the same values as `aorender probe --seed`. device: "auto" (the
/// best GPU adapter, else the CPU reference), "gpu", "cpu", or part of an adapter's name.
/// sky: None or "uniform" (the AO above), "overcast" (the CIE overcast sky about +Y), or a
/// dict with "model", "up" (x, y, z), "ground_albedo", "sampling" ("horizon",
/// "control-variate", "weighted") and "normalise" ("horizontal", "surface"), as
/// `aorender render --sky` takes them.
///
/// Each point is taken on the surface it lies on: the nearest triangle within
/// surface_tolerance (a distance; None, the default, is 2**-18 of the largest coordinate
/// of the point and the triangle, about 32 float32 rounding steps) gives it its normal and
/// a bound on its distance, and its rays start that far off the surface, so a point
/// computed inside a triangle (a surface sample) reads the AO just above it, not the dark
/// of just under it. A mesh vertex is taken as exactly on it. Points on no triangle within
/// the tolerance are traced as given, their rays starting exactly at them, and a
/// UserWarning says how many. Where N is not the triangle's normal (interpolated vertex
/// normals), directions about N that would leave below the triangle are mirrored above it.
///
/// The BVH is built on every call: to ask one mesh several times, make a Scene with
/// Scene.from_arrays(V, F) and call its ambient_occlusion. Ctrl-C stops the tracing after
/// the current pass and raises KeyboardInterrupt. Bad input raises ValueError before any
/// work; a device failure raises RuntimeError.
#[pyfunction]
#[pyo3(signature = (V, F, P, N, samples = 256, *, hemisphere = "cosine", sampler = "independent", max_distance = None, seed = 0, replicate = None, sky = None, surface_tolerance = None, device = "auto"))]
#[allow(non_snake_case, clippy::too_many_arguments)]
fn ambient_occlusion<'py>(
    py: Python<'py>,
    V: &Bound<'py, PyAny>,
    F: &Bound<'py, PyAny>,
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
) -> PyResult<scene::Values<'py>> {
    // Every argument checked before the BVH is built.
    let v = arrays::vec3s(py, V, "V")?;
    let f = arrays::faces(py, F, "F", v.len())?;
    let probes = scene::probes(py, P, N, samples, glam::DVec3::ZERO)?;
    let settings = aorender::Settings {
        sampling: engine::sampling(hemisphere, sampler, seed, max_distance, replicate, sky)?,
        ..Default::default()
    };
    let tolerance = scene::tolerance(surface_tolerance)?;
    let scene = PyScene::of_arrays("arrays", v, f)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("V, F: {}", e.value(py))))?;
    scene.probe(py, &probes, samples, &settings, tolerance, device)
}

/// Ambient occlusion on the GPU (wgpu) or a CPU reference: AO at points of a triangle
/// mesh from numpy arrays, AO images, and per-vertex bakes. See `ambient_occlusion` and
/// `Scene`.
#[pymodule]
fn _aorender(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(ambient_occlusion, m)?)?;
    m.add_class::<PyScene>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
