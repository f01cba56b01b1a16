//! `_core.LowPass` and `_core.low_pass_blend`: the core's first-order low-pass (`crate::low_pass`), the one
//! every τ_ext reading and estimated rate goes through, for a plant or a filter written in Python.

use std::sync::Mutex;

use numpy::{PyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{lock, view};
use super::error::run;
use crate::error::SabreError;
use crate::low_pass::{blend, LowPass};

/// The blend 1 − e^(−2π f_c dt) of a first-order low-pass at `cutoff` Hz over a step of `dt` s.
#[pyfunction]
pub fn low_pass_blend(cutoff: f64, dt: f64) -> PyResult<f64> {
    run(|| {
        if !(cutoff.is_finite() && cutoff >= 0.0 && dt.is_finite() && dt >= 0.0) {
            return Err(SabreError::invalid(
                "low-pass",
                format!("cutoff (Hz) and dt (s) must be finite and ≥ 0, got {cutoff} and {dt}"),
            ));
        }
        Ok(blend(cutoff, dt))
    })
}

/// A first-order low-pass on n values at `cutoff` Hz (None or ≤ 0: none): the first sample passes
/// through, each later one is blended in over its measured step.
#[pyclass(name = "LowPass", module = "sabre._core", frozen)]
pub struct PyLowPass {
    inner: Mutex<LowPass>,
    n: usize,
}

#[pymethods]
impl PyLowPass {
    #[new]
    #[pyo3(signature = (n, cutoff=None))]
    fn new(n: usize, cutoff: Option<f64>) -> PyResult<Self> {
        run(|| match cutoff {
            Some(c) if c.is_nan() || c.is_infinite() => Err(SabreError::invalid(
                "cutoff",
                format!("must be finite (Hz; None or ≤ 0: none), got {c}"),
            )),
            _ => Ok(Self {
                inner: Mutex::new(LowPass::new(n, cutoff)),
                n,
            }),
        })
    }

    /// The cutoff (Hz), None without one.
    #[getter]
    fn cutoff(&self) -> Option<f64> {
        lock(&self.inner).cutoff()
    }

    /// Blends `sample` (n,) in over the step `dt` (s) and returns the filtered value (n,).
    fn update<'py>(&self, py: Python<'py>, sample: PyReadonlyArrayDyn<'py, f64>, dt: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let sample = run(|| view("sample", &sample, &[self.n as isize]))?;
        run(|| {
            if sample.iter().any(|v| !v.is_finite()) || dt.is_nan() {
                return Err(SabreError::invalid("sample", "needs finite values and a step"));
            }
            Ok(())
        })?;
        Ok(PyArray1::from_slice(py, lock(&self.inner).update(sample, dt)))
    }

    /// The filtered value (n,) (zeros before the first sample).
    #[getter]
    fn value<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).value())
    }

    /// Forgets the samples: the next one passes through.
    fn reset(&self) {
        lock(&self.inner).reset();
    }
}
