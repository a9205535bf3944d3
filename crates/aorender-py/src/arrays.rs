//! numpy arrays in: every input checked (shape, dtype, finiteness, index range) and
//! converted before any work starts, whatever its dtype and memory order.

use glam::{DVec3, Vec3};
use numpy::{Element, PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// `x` as a numpy array (numpy converts lists and other sequences).
fn as_array<'py>(py: Python<'py>, x: &Bound<'py, PyAny>, name: &str) -> PyResult<(Bound<'py, PyAny>, String)> {
    let arr = py.import("numpy")?.call_method1("asarray", (x,))?;
    let kind: String = arr.getattr("dtype")?.getattr("kind")?.extract()?;
    let shape: Vec<usize> = arr.getattr("shape")?.extract()?;
    if shape.len() != 2 || shape[1] != 3 {
        let shape: Vec<String> = shape.iter().map(usize::to_string).collect();
        return Err(PyValueError::new_err(format!("{name} must be an (n, 3) array, got shape ({})", shape.join(", "))));
    }
    if shape[0] == 0 {
        return Err(PyValueError::new_err(format!("{name} is empty: an (n, 3) array with n ≥ 1 is needed")));
    }
    Ok((arr, kind))
}

/// A C-contiguous copy (or view) of `arr` with elements of type `T`, as a flat vector.
fn contiguous<'py, T: Element + Copy>(py: Python<'py>, arr: &Bound<'py, PyAny>, dtype: &str) -> PyResult<Vec<T>> {
    let arr = py.import("numpy")?.call_method1("ascontiguousarray", (arr, dtype))?;
    let arr = arr.downcast_into::<PyArray2<T>>()?;
    let ro = arr.readonly();
    Ok(ro.as_slice()?.to_vec())
}

/// An (n, 3) array of any real dtype as n points in f32: non-finite values, and values
/// that do not fit in f32, are refused naming the row.
pub fn vec3s(py: Python<'_>, x: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Vec3>> {
    // Less zero is exact: each coordinate is rounded once, from f64 to f32.
    relative_vec3s(py, x, name, DVec3::ZERO)
}

/// An (n, 3) array of real numbers as points relative to `origin`: each subtracted in
/// f64 and rounded once to f32 (points far from the origin keep their accuracy near it).
pub fn relative_vec3s(py: Python<'_>, x: &Bound<'_, PyAny>, name: &str, origin: DVec3) -> PyResult<Vec<Vec3>> {
    let (arr, kind) = as_array(py, x, name)?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyValueError::new_err(format!("{name} must hold real numbers, got dtype kind '{kind}'")));
    }
    let flat: Vec<f64> = contiguous(py, &arr, "float64")?;
    flat.chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let v = (DVec3::new(c[0], c[1], c[2]) - origin).as_vec3();
            if v.is_finite() {
                Ok(v)
            } else if c.iter().all(|x| x.is_finite()) {
                Err(PyValueError::new_err(format!("{name}[{i}] = {c:?} does not fit in 32-bit floats")))
            } else {
                Err(PyValueError::new_err(format!("{name}[{i}] has a non-finite coordinate: {c:?}")))
            }
        })
        .collect()
}

/// An (m, 3) array of any integer dtype as triangles of vertex indices below `vertices`.
pub fn faces(py: Python<'_>, x: &Bound<'_, PyAny>, name: &str, vertices: usize) -> PyResult<Vec<[u32; 3]>> {
    let (arr, kind) = as_array(py, x, name)?;
    let flat: Vec<i128> = match kind.as_str() {
        "i" => contiguous::<i64>(py, &arr, "int64")?.into_iter().map(i128::from).collect(),
        "u" => contiguous::<u64>(py, &arr, "uint64")?.into_iter().map(i128::from).collect(),
        _ => {
            return Err(PyValueError::new_err(format!(
                "{name} must be an integer array of vertex indices, got dtype kind '{kind}'"
            )));
        }
    };
    flat.chunks_exact(3)
        .enumerate()
        .map(|(i, c)| {
            let mut t = [0u32; 3];
            for (k, &index) in c.iter().enumerate() {
                if index < 0 || index >= vertices as i128 {
                    return Err(PyValueError::new_err(format!(
                        "{name}[{i}] = {c:?}: index {index} is out of range for {vertices} vertices"
                    )));
                }
                t[k] = index as u32;
            }
            Ok(t)
        })
        .collect()
}

/// A float64 array of `values`.
pub fn out<'py>(py: Python<'py>, values: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_vec(py, values)
}
