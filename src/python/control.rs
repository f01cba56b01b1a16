//! `_core.LowLevelController`: the dynamics-compensated PI joint-velocity controller (53) of the
//! plant, with its config object.

use std::sync::Mutex;

use numpy::PyReadonlyArrayDyn;
use pyo3::prelude::*;

use super::convert::{lock, view};
use super::error::run;
use super::scene::PyScene;
use crate::control::{LowLevelConfig, LowLevelController};

/// Gains of the low-level controller (53); `LowLevelConfig()` holds the core's defaults.
#[pyclass(name = "LowLevelConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyLowLevelConfig {
    /// Proportional bandwidth Λ_D (1/s).
    bandwidth: f64,
    /// Integral gain Λ_I (1/s²).
    integral_gain: f64,
    /// Bound on the accumulated position error per joint.
    integral_limit: f64,
    /// Smallest joint inertia (kg m²) the PI gains are scaled with.
    gain_inertia_floor: f64,
}

#[pymethods]
impl PyLowLevelConfig {
    #[new]
    fn new() -> Self {
        let c = LowLevelConfig::default();
        Self {
            bandwidth: c.bandwidth,
            integral_gain: c.integral_gain,
            integral_limit: c.integral_limit,
            gain_inertia_floor: c.gain_inertia_floor,
        }
    }
}

impl From<&PyLowLevelConfig> for LowLevelConfig {
    fn from(c: &PyLowLevelConfig) -> Self {
        Self {
            bandwidth: c.bandwidth,
            integral_gain: c.integral_gain,
            integral_limit: c.integral_limit,
            gain_inertia_floor: c.gain_inertia_floor,
        }
    }
}

#[pyclass(name = "LowLevelController", module = "sabre._core")]
pub struct PyLowLevelController {
    pub(crate) inner: Mutex<LowLevelController>,
}

#[pymethods]
impl PyLowLevelController {
    /// The controller for the robot of `scene` at control step `dt` (s).
    #[new]
    fn new(scene: &PyScene, dt: f64, config: &PyLowLevelConfig) -> PyResult<Self> {
        let config = LowLevelConfig::from(config);
        run(|| LowLevelController::new(scene.inner.clone(), dt, config)).map(|c| Self { inner: Mutex::new(c) })
    }

    fn reset(&self) {
        lock(&self.inner).reset();
    }

    #[getter]
    fn gain_inertia_floor(&self) -> f64 {
        lock(&self.inner).config().gain_inertia_floor
    }

    #[setter]
    fn set_gain_inertia_floor(&self, floor: f64) -> PyResult<()> {
        let mut controller = lock(&self.inner);
        run(|| controller.set_gain_inertia_floor(floor))
    }

    /// Joint torques (nq) that make the robot at state x (nx,) track the velocities u_ref (nq,).
    fn torque(&self, x: PyReadonlyArrayDyn<'_, f64>, u_ref: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<f64>> {
        let mut controller = lock(&self.inner);
        run(|| controller.torque(view("x", &x, &[-1])?, view("u_ref", &u_ref, &[-1])?))
    }
}
