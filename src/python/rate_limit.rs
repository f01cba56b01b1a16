//! `_core.RateLimiter`: the per-joint velocity, acceleration and jerk limits on a command stream.

use std::sync::Mutex;

use numpy::PyArray1;
use pyo3::prelude::*;

use super::convert::{lock, vector};
use super::error::run;
use crate::control::RateLimiter;

/// Per-joint limits on a stream of velocity commands, one `limit` call per step of `dt`:
/// every output obeys |v| ≤ v_max, |a| ≤ a_max and |Δa| ≤ j_max·dt (a the output's difference
/// quotient), and a held target is reached without overshoot.
#[pyclass(name = "RateLimiter", module = "sabre._core", frozen)]
pub struct PyRateLimiter {
    inner: Mutex<RateLimiter>,
}

impl PyRateLimiter {
    /// The limiter's bounds and state, a copy for another core object to own.
    pub(crate) fn limiter(&self) -> RateLimiter {
        lock(&self.inner).clone()
    }
}

impl From<RateLimiter> for PyRateLimiter {
    fn from(inner: RateLimiter) -> Self {
        Self {
            inner: Mutex::new(inner),
        }
    }
}

#[pymethods]
impl PyRateLimiter {
    /// A limiter at rest for n joints with bounds v_max, a_max, j_max (n,) (positive) at step dt (s).
    #[new]
    fn new(v_max: Bound<'_, PyAny>, a_max: Bound<'_, PyAny>, j_max: Bound<'_, PyAny>, dt: f64) -> PyResult<Self> {
        let (v, a, j) = (vector("v_max", &v_max)?, vector("a_max", &a_max)?, vector("j_max", &j_max)?);
        run(|| RateLimiter::new(v, a, j, dt)).map(|inner| Self {
            inner: Mutex::new(inner),
        })
    }

    /// One step toward `target` (n,): the limited command (n,), which the next step starts from.
    fn limit<'py>(&self, py: Python<'py>, target: Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let target = vector("target", &target)?;
        let mut limiter = lock(&self.inner);
        let mut out = vec![0.0; limiter.len()];
        run(|| limiter.limit(&target, &mut out))?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// Starts again from `velocity` (n,) (None: rest), each entry clipped to ±v_max, with zero
    /// acceleration.
    #[pyo3(signature = (velocity=None))]
    fn reset(&self, velocity: Option<Bound<'_, PyAny>>) -> PyResult<()> {
        let velocity = velocity.map(|v| vector("velocity", &v)).transpose()?;
        let mut limiter = lock(&self.inner);
        run(|| limiter.reset(velocity.as_deref()))
    }

    /// (velocity (n,), acceleration (n,)) of the last output.
    #[getter]
    fn state<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>) {
        let limiter = lock(&self.inner);
        (
            PyArray1::from_slice(py, limiter.velocity()),
            PyArray1::from_slice(py, limiter.acceleration()),
        )
    }
    /// Whether the last output is zero and not changing.
    #[getter]
    fn at_rest(&self) -> bool {
        lock(&self.inner).at_rest()
    }
    /// An upper bound on the steps a ramp to rest takes from the current state.
    #[getter]
    fn steps_to_rest(&self) -> usize {
        lock(&self.inner).steps_to_rest()
    }
    #[getter]
    fn size(&self) -> usize {
        lock(&self.inner).len()
    }
    #[getter]
    fn dt(&self) -> f64 {
        lock(&self.inner).dt()
    }
    #[getter]
    fn v_max<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).v_max())
    }
    #[getter]
    fn a_max<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).a_max())
    }
    #[getter]
    fn j_max<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).j_max())
    }

    fn __repr__(&self) -> String {
        let l = lock(&self.inner);
        format!("RateLimiter(n={}, dt={})", l.len(), l.dt())
    }
}
