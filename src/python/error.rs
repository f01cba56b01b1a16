//! The error boundary of the bindings: core errors as `sabre.errors` exceptions, panics caught.

use std::panic::{catch_unwind, AssertUnwindSafe};

use pyo3::prelude::*;

use crate::error::SabreError;

// The classes are defined once, in Python (`python/sabre/errors.py`); the bindings raise those.
pyo3::import_exception!(sabre.errors, ShapeError);
pyo3::import_exception!(sabre.errors, InvalidValueError);
pyo3::import_exception!(sabre.errors, UnknownAssetError);
pyo3::import_exception!(sabre.errors, UrdfError);
pyo3::import_exception!(sabre.errors, UnknownFrameError);
pyo3::import_exception!(sabre.errors, SimulationError);

impl From<SabreError> for PyErr {
    fn from(error: SabreError) -> Self {
        let message = error.to_string();
        match error {
            SabreError::Shape { .. } => ShapeError::new_err(message),
            SabreError::InvalidValue { .. } => InvalidValueError::new_err(message),
            SabreError::UnknownAsset { .. } => UnknownAssetError::new_err(message),
            SabreError::Urdf { .. } => UrdfError::new_err(message),
            SabreError::UnknownFrame { .. } => UnknownFrameError::new_err(message),
            SabreError::Simulation(_) => SimulationError::new_err(message),
        }
    }
}

/// Runs `f` without the GIL; errors and panics come back as Python exceptions.
pub(crate) fn run_detached<T: Send, F: FnOnce() -> crate::Result<T> + Send>(py: Python<'_>, f: F) -> PyResult<T> {
    settle(py.detach(|| catch_unwind(AssertUnwindSafe(f))))
}

/// [`run_detached`] for cheap calls that keep the GIL.
pub(crate) fn run<T, F: FnOnce() -> crate::Result<T>>(f: F) -> PyResult<T> {
    settle(catch_unwind(AssertUnwindSafe(f)))
}

/// A panic in the core becomes a `SimulationError` naming it, so it never unwinds into Python.
fn settle<T>(outcome: std::thread::Result<crate::Result<T>>) -> PyResult<T> {
    match outcome {
        Ok(result) => result.map_err(PyErr::from),
        Err(panic) => {
            let detail = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(SabreError::Simulation(format!("internal error: {detail}")).into())
        }
    }
}
