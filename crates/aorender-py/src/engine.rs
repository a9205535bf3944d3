//! What every call shares: devices opened once per process, the sampling keywords, the
//! engine's errors as Python exceptions, and work run with the GIL released that a
//! KeyboardInterrupt stops after the current pass.

use aorender::{
    Control, Device, DeviceKind, Hemisphere, Progress, Sampler, Sampling, Sky, SkyModel, SkyNormalise, SkySampling,
};
use pyo3::exceptions::{PyMemoryError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

/// The engine's error as a Python exception with its one-line message: bad settings and
/// points are ValueError, unreadable or unwritable files OSError, a film past the memory
/// budget MemoryError, the device's failures RuntimeError.
pub fn to_py(e: aorender::Error) -> PyErr {
    use aorender::Error as E;
    let message = e.to_string();
    match e {
        E::Settings { .. } | E::Probe { .. } => PyValueError::new_err(message),
        E::Scene { .. } | E::Output { .. } => PyOSError::new_err(message),
        E::FilmBudget { .. } => PyMemoryError::new_err(message),
        _ => PyRuntimeError::new_err(message),
    }
}

/// Devices already opened, by the name they were asked for: opening an adapter compiles
/// its pipelines, so it happens once per process.
static DEVICES: Mutex<Vec<(String, Device)>> = Mutex::new(Vec::new());

/// Opens (or finds already open) the device `name` names: `auto` (the best GPU adapter,
/// else the CPU reference), `gpu`, `cpu`, or a substring of an adapter's name.
pub fn device(py: Python<'_>, name: &str) -> PyResult<Device> {
    let name = name.trim();
    if name.is_empty() {
        return Err(PyValueError::new_err("device must be 'auto', 'gpu', 'cpu' or part of an adapter's name"));
    }
    let key = name.to_ascii_lowercase();
    py.allow_threads(|| {
        let mut devices = DEVICES.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, d)) = devices.iter().find(|(k, _)| *k == key) {
            return Ok(d.clone());
        }
        let device = match key.as_str() {
            "auto" => Device::gpu(None).unwrap_or_else(|_| Device::cpu()),
            "gpu" => Device::open(DeviceKind::Gpu, None)?,
            "cpu" => Device::cpu(),
            _ => Device::gpu(Some(name))?,
        };
        devices.push((key, device.clone()));
        Ok(device)
    })
    .map_err(to_py)
}

/// The sampling the keyword arguments every call takes ask for.
pub fn sampling(
    hemisphere: &str,
    sampler: &str,
    seed: u32,
    max_distance: Option<f64>,
    replicate: Option<u32>,
    sky: Option<&Bound<'_, PyAny>>,
) -> PyResult<Sampling> {
    let names =
        |all: &mut dyn Iterator<Item = &'static str>| all.map(|n| format!("'{n}'")).collect::<Vec<_>>().join(", ");
    let h = Hemisphere::from_name(hemisphere).ok_or_else(|| {
        PyValueError::new_err(format!(
            "unknown hemisphere '{hemisphere}': expected one of {}",
            names(&mut Hemisphere::ALL.iter().map(|h| h.name()))
        ))
    })?;
    let s = Sampler::from_name(sampler).ok_or_else(|| {
        PyValueError::new_err(format!(
            "unknown sampler '{sampler}': expected one of {}",
            names(&mut Sampler::ALL.iter().map(|s| s.name()))
        ))
    })?;
    if let Some(d) = max_distance
        && (d.is_nan() || d < 0.0)
    {
        return Err(PyValueError::new_err(format!("max_distance must be zero or positive, got {d}")));
    }
    let max_distance = max_distance.map(|d| d as f32);
    let sampling = Sampling { hemisphere: h, sampler: s, seed, max_distance, replicate, sky: parse_sky(sky)? };
    sampling.validate().map_err(to_py)?;
    Ok(sampling)
}

/// The `sky` keyword: None (classic AO), a sky's name ("uniform", "overcast"), or a dict
/// with "model" and any of "up" (3 numbers, +Y by default), "ground_albedo", "sampling"
/// and "normalise", named as on the command line.
pub fn parse_sky(sky: Option<&Bound<'_, PyAny>>) -> PyResult<Sky> {
    let Some(sky) = sky.filter(|s| !s.is_none()) else {
        return Ok(Sky::default());
    };
    fn named<T>(what: &str, name: &str, from_name: fn(&str) -> Option<T>, all: &[&str]) -> PyResult<T> {
        from_name(name).ok_or_else(|| {
            let all: Vec<String> = all.iter().map(|n| format!("'{n}'")).collect();
            PyValueError::new_err(format!("unknown {what} '{name}': expected one of {}", all.join(", ")))
        })
    }
    let models = SkyModel::ALL.map(SkyModel::name);
    if let Ok(name) = sky.extract::<String>() {
        let model = named("sky", &name, SkyModel::from_name, &models)?;
        return Ok(Sky { model, ..Sky::default() });
    }
    let dict = sky.downcast::<PyDict>().map_err(|_| {
        PyValueError::new_err(
            "sky must be None, a sky's name or a dict with 'model', 'up', 'ground_albedo', 'sampling', 'normalise'",
        )
    })?;
    let mut out = Sky::default();
    for (key, value) in dict.iter() {
        let key: String = key.extract()?;
        let text =
            || value.extract::<String>().map_err(|_| PyValueError::new_err(format!("sky['{key}'] must be a string")));
        match key.as_str() {
            "model" => out.model = named("sky", &text()?, SkyModel::from_name, &models)?,
            "sampling" => {
                out.sampling =
                    named("sky sampling", &text()?, SkySampling::from_name, &SkySampling::ALL.map(SkySampling::name))?
            }
            "normalise" => {
                out.normalise = named(
                    "sky normalisation",
                    &text()?,
                    SkyNormalise::from_name,
                    &SkyNormalise::ALL.map(SkyNormalise::name),
                )?
            }
            "up" => {
                let [x, y, z]: [f32; 3] =
                    value.extract().map_err(|_| PyValueError::new_err("sky['up'] must be three numbers (x, y, z)"))?;
                out.up = glam::Vec3::new(x, y, z);
            }
            "ground_albedo" => {
                out.ground_albedo =
                    value.extract().map_err(|_| PyValueError::new_err("sky['ground_albedo'] must be a number"))?
            }
            _ => return Err(PyValueError::new_err(format!("unknown sky key '{key}'"))),
        }
    }
    Ok(out)
}

/// Runs `work` with the GIL released, under a [`Control`] whose progress callback takes
/// the GIL back after every pass to run Python's signal handlers: a KeyboardInterrupt (or
/// any exception a handler raises) sets the stop flag, the pass loop ends after that
/// pass, and the exception is raised here once `work` has returned.
pub fn interruptible<T: Send>(
    py: Python<'_>,
    work: impl for<'c, 'd> FnOnce(&'c mut Control<'d>) -> aorender::Result<T> + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    let (result, raised) = py.allow_threads(|| {
        let mut raised: Option<PyErr> = None;
        let result = {
            let mut check = |_: &Progress| {
                if raised.is_none()
                    && let Err(e) = Python::with_gil(|py| py.check_signals())
                {
                    raised = Some(e);
                    stop.store(true, Ordering::Relaxed);
                }
            };
            let mut control = Control { stop: Some(&stop), progress: Some(&mut check), ..Control::default() };
            work(&mut control)
        };
        (result, raised)
    });
    if let Some(e) = raised {
        return Err(e);
    }
    result.map_err(to_py)
}
