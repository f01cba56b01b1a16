//! `_core.LowLevelController`: the dynamics-compensated PI joint-velocity controller (53) of the
//! plant, with its config object and constant-velocity tracking; `_core.Plan`, a plan as the cascade
//! follows it (the cascade itself: `cascade.rs`).

use std::sync::{Arc, Mutex};

use numpy::{PyArray1, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyType;

use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::scene::PyScene;
use super::sim::PyPlant;
use crate::control::{LowLevelConfig, LowLevelController, Plan, Shared};
use crate::error::SabreError;

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

#[pyclass(name = "LowLevelController", module = "sabre._core", frozen)]
pub struct PyLowLevelController {
    pub(crate) inner: Shared<LowLevelController>,
}

#[pymethods]
impl PyLowLevelController {
    /// The controller for the robot of `scene` at control step `dt` (s).
    #[new]
    fn new(scene: &PyScene, dt: f64, config: &PyLowLevelConfig) -> PyResult<Self> {
        let config = LowLevelConfig::from(config);
        run(|| LowLevelController::new(scene.inner.clone(), dt, config)).map(|c| Self {
            inner: Arc::new(Mutex::new(c)),
        })
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

    /// Per joint, the bound (rad/s² or m/s²) at which the tracked command follows the reference; None: as given.
    #[getter]
    fn command_acceleration(&self) -> Option<Vec<f64>> {
        lock(&self.inner).command_acceleration()
    }

    #[setter]
    fn set_command_acceleration(&self, caps: Option<Vec<f64>>) -> PyResult<()> {
        let mut controller = lock(&self.inner);
        run(|| controller.set_command_acceleration(caps.as_deref()))
    }

    /// The largest gain inertia floor (kg m²) that keeps every joint's loop stable at plant step `plant_dt` (s).
    fn max_stable_floor(&self, plant_dt: f64) -> f64 {
        lock(&self.inner).max_stable_floor(plant_dt)
    }

    /// (largest loop gain per plant step `plant_dt`, the joint with it) at gain inertia floor `floor`.
    fn loop_gain(&self, floor: f64, plant_dt: f64) -> (f64, String) {
        let controller = lock(&self.inner);
        let (gain, joint) = controller.loop_gain(floor, plant_dt);
        let scene = controller.scene();
        (gain, scene.robot.joints[scene.robot.active_joints[joint]].name.clone())
    }

    /// Joint torques (nq) that make the robot at state x (nx,) track the velocities u_ref (nq,).
    fn torque(&self, x: PyReadonlyArrayDyn<'_, f64>, u_ref: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<f64>> {
        let mut controller = lock(&self.inner);
        run(|| controller.torque(view("x", &x, &[-1])?, view("u_ref", &u_ref, &[-1])?))
    }

    /// Runs `steps` steps of `plant`, each with torques from this controller tracking `u_ref`.
    fn track(&self, py: Python<'_>, plant: &PyPlant, u_ref: PyReadonlyArrayDyn<'_, f64>, steps: usize) -> PyResult<()> {
        let u_ref = plant.with(|p| Ok(view("u_ref", &u_ref, &[p.scene().nq() as isize])?.to_vec()))?;
        let (plant, controller) = (&plant.inner, &self.inner);
        run_detached(py, || {
            // Always plant, then controller: one lock order for every call.
            let mut plant = lock(plant);
            let mut controller = lock(controller);
            controller.check_stable(controller.config().gain_inertia_floor, plant.dt())?;
            let mut poll = crate::interrupt::Poll::new();
            for _ in 0..steps {
                poll.check()?;
                let tau = controller.torque(plant.state(), &u_ref)?;
                plant.step(&tau)?;
            }
            Ok(())
        })
    }
}

/// A finite time, else the error naming it.
fn finite_time(t: f64) -> crate::Result<f64> {
    if t.is_finite() {
        Ok(t)
    } else {
        Err(SabreError::invalid("t", format!("must be finite, got {t}")))
    }
}

/// The entries of an `ndim`-dimensional array in row-major order, whatever its memory layout.
fn copied(name: &str, values: &PyReadonlyArrayDyn<'_, f64>, expected: &str, ndim: usize) -> crate::Result<Vec<f64>> {
    let values = values.as_array();
    if values.ndim() != ndim {
        return Err(SabreError::shape(name, expected, format!("{:?}", values.shape())));
    }
    Ok(values.iter().copied().collect())
}

/// A plan as the inner loop follows it: reference (K, nu) with row k at t0 + k·dt, the predicted
/// port dissipation (K,) on the same grid and the gain inertia floor of its task phase, both
/// optional. Immutable: its arrays are returned as copies.
#[pyclass(name = "Plan", module = "sabre._core", frozen, eq)]
#[derive(PartialEq)]
pub struct PyPlan {
    pub(crate) inner: Arc<Plan>,
}

#[pymethods]
impl PyPlan {
    #[new]
    #[pyo3(signature = (reference, t0, dt, predicted_dissipation=None, gain_inertia_floor=None))]
    fn new(
        reference: PyReadonlyArrayDyn<'_, f64>,
        t0: f64,
        dt: f64,
        predicted_dissipation: Option<PyReadonlyArrayDyn<'_, f64>>,
        gain_inertia_floor: Option<f64>,
    ) -> PyResult<Self> {
        run(|| {
            let rows = copied("reference", &reference, "(K, nu)", 2)?;
            let mut plan = Plan::new(rows, reference.shape()[1], t0, dt)?;
            if let Some(p) = &predicted_dissipation {
                plan = plan.with_predicted_dissipation(copied("predicted_dissipation", p, "(K,)", 1)?)?;
            }
            if let Some(floor) = gain_inertia_floor {
                plan = plan.with_gain_inertia_floor(floor)?;
            }
            Ok(Self { inner: Arc::new(plan) })
        })
    }

    /// (K, nu), a copy.
    #[getter]
    fn reference<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let p = &self.inner;
        array(py, p.reference().to_vec(), &[p.steps(), p.nu()])
    }
    #[getter]
    fn nu(&self) -> usize {
        self.inner.nu()
    }
    /// K, the number of grid points.
    #[getter]
    fn steps(&self) -> usize {
        self.inner.steps()
    }
    #[getter]
    fn t0(&self) -> f64 {
        self.inner.t0()
    }
    #[getter]
    fn dt(&self) -> f64 {
        self.inner.dt()
    }
    /// (K,), a copy; None without one.
    #[getter]
    fn predicted_dissipation<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        self.inner
            .predicted_dissipation()
            .map(|p| array(py, p.to_vec(), &[p.len()]))
            .transpose()
    }
    #[getter]
    fn gain_inertia_floor(&self) -> Option<f64> {
        self.inner.gain_inertia_floor()
    }

    /// (nu,) the reference at time t: linear between grid points, held at both ends.
    fn reference_at<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let t = run(|| finite_time(t))?;
        let mut out = vec![0.0; self.inner.nu()];
        self.inner.reference_at(t, &mut out);
        Ok(PyArray1::from_vec(py, out))
    }

    /// The predicted port dissipation (W) at time t, interpolated as the reference; None without one.
    fn predicted_dissipation_at(&self, t: f64) -> PyResult<Option<f64>> {
        let t = run(|| finite_time(t))?;
        Ok(self.inner.predicted_dissipation_at(t))
    }

    /// Pickles as its constructor's arguments (plans cross into planner processes and back).
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(
        Bound<'py, PyType>,
        (
            Bound<'py, PyArrayDyn<f64>>,
            f64,
            f64,
            Option<Bound<'py, PyArrayDyn<f64>>>,
            Option<f64>,
        ),
    )> {
        let py = slf.py();
        let plan = slf.get();
        let args = (
            plan.reference(py)?,
            plan.t0(),
            plan.dt(),
            plan.predicted_dissipation(py)?,
            plan.gain_inertia_floor(),
        );
        Ok((slf.get_type(), args))
    }

    fn __repr__(&self) -> String {
        let p = &self.inner;
        format!(
            "Plan(steps={}, nu={}, t0={}, dt={}, predicted_dissipation={}, gain_inertia_floor={:?})",
            p.steps(),
            p.nu(),
            p.t0(),
            p.dt(),
            if p.predicted_dissipation().is_some() { "(K,)" } else { "None" },
            p.gain_inertia_floor(),
        )
    }
}
