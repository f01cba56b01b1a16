//! Conversions at the boundary: checked float64 views of NumPy arrays, arrays out, poses as 4 × 4
//! matrices, vectors from arrays or sequences, and locking the core objects the Python classes own.

use std::sync::{Mutex, MutexGuard};

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion};
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::error::run;
use crate::error::{ensure_finite, SabreError};

/// The object behind `mutex`, also after a panic in another call poisoned it: every core object
/// checks its inputs before it mutates, so a panic leaves it in a usable state.
pub(crate) fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A contiguous float64 view of an array with the expected shape (-1 = any size).
pub(crate) fn view<'a>(name: &str, array: &'a PyReadonlyArrayDyn<'_, f64>, shape: &[isize]) -> crate::Result<&'a [f64]> {
    let got = array.shape();
    let matches = got.len() == shape.len() && got.iter().zip(shape).all(|(&g, &e)| e < 0 || g as isize == e);
    if !matches {
        let fmt = |s: Vec<String>| format!("({})", s.join(", "));
        return Err(SabreError::shape(
            name,
            fmt(shape
                .iter()
                .map(|&e| if e < 0 { "·".into() } else { e.to_string() })
                .collect()),
            fmt(got.iter().map(|g| g.to_string()).collect()),
        ));
    }
    // rust-numpy also hands out Fortran-ordered memory as a slice; only C order matches our layout.
    if !array.is_c_contiguous() {
        return Err(SabreError::invalid(
            name,
            "array must be C-contiguous (use numpy.ascontiguousarray)",
        ));
    }
    array
        .as_slice()
        .map_err(|_| SabreError::invalid(name, "array must be C-contiguous"))
}

/// A float64 array of `shape` holding `data` in row-major order.
pub(crate) fn array<'py>(py: Python<'py>, data: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    PyArray1::from_vec(py, data).reshape(shape.to_vec())
}

/// The homogeneous matrix of a pose, row-major (16 entries).
pub(crate) fn matrix_entries(pose: &Isometry3<f64>) -> [f64; 16] {
    let mut out = [0.0; 16];
    out.copy_from_slice(pose.to_homogeneous().transpose().as_slice());
    out
}

/// A (4, 4) array of a pose.
pub(crate) fn pose_array<'py>(py: Python<'py>, pose: &Isometry3<f64>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    array(py, matrix_entries(pose).to_vec(), &[4, 4])
}

/// An (M, 4, 4) array of M poses.
pub(crate) fn poses_array<'py>(py: Python<'py>, poses: &[Isometry3<f64>]) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let data = poses.iter().flat_map(matrix_entries).collect();
    array(py, data, &[poses.len(), 4, 4])
}

/// The pose of a row-major homogeneous matrix (16 entries) whose rotation block is a rotation.
pub(crate) fn isometry(name: &str, m: &[f64]) -> crate::Result<Isometry3<f64>> {
    if m.len() != 16 {
        return Err(SabreError::shape(name, "(4, 4)", format!("{} elements", m.len())));
    }
    ensure_finite(name, m)?;
    let mat = Matrix4::from_row_slice(m);
    let rot = Matrix3::from(mat.fixed_view::<3, 3>(0, 0));
    if (rot.transpose() * rot - Matrix3::identity()).norm() > 1e-6 || (rot.determinant() - 1.0).abs() > 1e-6 {
        return Err(SabreError::invalid(name, "rotation block is not a rotation matrix"));
    }
    // The block is a rotation to 1e-6: read it directly (Shepperd's method) and normalise, instead of
    // nalgebra's iterative projection onto the rotations, which cost more than the servo guide
    // whose targets it read.
    let quaternion = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rot));
    Ok(Isometry3::from_parts(
        Translation3::new(m[3], m[7], m[11]),
        UnitQuaternion::new_normalize(quaternion.into_inner()),
    ))
}

/// A float64 vector from a NumPy array (any layout, one dimension) or any sequence of numbers.
pub(super) fn vector(name: &str, values: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    if let Ok(array) = values.cast::<PyArrayDyn<f64>>() {
        let array = array.readonly();
        let view = array.as_array();
        if view.ndim() != 1 {
            return run(|| Err(SabreError::shape(name, "(n,)", format!("{:?}", view.shape()))));
        }
        return Ok(view.iter().copied().collect());
    }
    values.extract::<Vec<f64>>()
}
