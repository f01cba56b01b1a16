//! `_core.LowLevelController`: the dynamics-compensated PI joint-velocity controller (53) of the
//! plant, with its config object, and the inner loop that drives the plant with it (constant
//! tracking, and following a reference with the optional safety stage).

use std::sync::Mutex;

use numpy::{IntoPyArray, PyArrayMethods, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::safety::{PyEnergyTank, PySafetyFilter};
use super::scene::PyScene;
use super::sim::PyPlant;
use crate::control::{follow_reference_safe, InnerSafety, LowLevelConfig, LowLevelController, TrackTrace};

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

    /// Runs `steps` steps of `plant`, each with torques from this controller tracking `u_ref`.
    fn track(&self, py: Python<'_>, plant: &PyPlant, u_ref: PyReadonlyArrayDyn<'_, f64>, steps: usize) -> PyResult<()> {
        let u_ref = plant.with(|p| Ok(view("u_ref", &u_ref, &[p.scene().nq() as isize])?.to_vec()))?;
        let (plant, controller) = (&plant.inner, &self.inner);
        run_detached(py, || {
            // Always plant, then controller: one lock order for every call.
            let mut plant = lock(plant);
            let mut controller = lock(controller);
            let mut poll = crate::interrupt::Poll::new();
            for _ in 0..steps {
                poll.check()?;
                let tau = controller.torque(plant.state(), &u_ref)?;
                plant.step(&tau)?;
            }
            Ok(())
        })
    }

    /// Follows a reference sequence (K, nq) starting at t0 with steps dt for `steps` steps of
    /// `plant` under this controller, with the optional inner safety stage (FILTER-QP (41) with the
    /// passivity row (56), the tank (49), or both); returns the trace of every `record_every`-th
    /// step as a dict: time, state, reference, wrench, tau_ext, tau_ext_measured, contact, and with a
    /// filter filtered (M, nq) and filter_status (list of str), with a tank tank_energy (M,).
    /// `predicted_dissipation` (K,), on the reference's time grid, feeds a tank's refill.
    #[pyo3(signature = (plant, reference, t0, dt, steps, record_every=1, safety=None, tank=None, predicted_dissipation=None))]
    #[allow(clippy::too_many_arguments)]
    fn follow<'py>(
        &self,
        py: Python<'py>,
        plant: &PyPlant,
        reference: PyReadonlyArrayDyn<'py, f64>,
        t0: f64,
        dt: f64,
        steps: usize,
        record_every: usize,
        safety: Option<&PySafetyFilter>,
        tank: Option<&PyEnergyTank>,
        predicted_dissipation: Option<PyReadonlyArrayDyn<'py, f64>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (nx, nq) = plant.with(|p| Ok((p.scene().nx(), p.scene().nq())))?;
        let reference = run(|| view("reference", &reference, &[-1, nq as isize]))?;
        let predicted = match &predicted_dissipation {
            Some(p) => Some(run(|| view("predicted_dissipation", p, &[-1]))?),
            None => None,
        };
        let (plant, controller) = (&plant.inner, &self.inner);
        let (has_filter, has_tank) = (safety.is_some(), tank.is_some());
        let trace = run_detached(py, || {
            // Always plant, controller, filter, tank: one lock order for every call.
            let mut plant = lock(plant);
            let mut controller = lock(controller);
            let mut filter = safety.map(|f| lock(&f.inner));
            let mut tank = tank.map(|t| lock(&t.inner));
            let stage = InnerSafety {
                filter: filter.as_deref_mut(),
                tank: tank.as_deref_mut(),
                predicted_dissipation: predicted,
            };
            let mut trace = TrackTrace::default();
            follow_reference_safe(
                &mut plant,
                &mut controller,
                reference,
                t0,
                dt,
                steps,
                record_every,
                &mut trace,
                Some(stage),
            )?;
            Ok(trace)
        })?;
        trace_dict(py, trace, nx, nq, has_filter, has_tank)
    }
}

/// The dict of a trace of M recorded steps (see [`PyLowLevelController::follow`]).
fn trace_dict(
    py: Python<'_>,
    trace: TrackTrace,
    nx: usize,
    nq: usize,
    has_filter: bool,
    has_tank: bool,
) -> PyResult<Bound<'_, PyDict>> {
    let m = trace.time.len();
    let d = PyDict::new(py);
    d.set_item("time", array(py, trace.time, &[m])?)?;
    d.set_item("state", array(py, trace.state, &[m, nx])?)?;
    d.set_item("reference", array(py, trace.reference, &[m, nq])?)?;
    d.set_item("wrench", array(py, trace.wrench, &[m, 6])?)?;
    d.set_item("tau_ext", array(py, trace.tau_ext, &[m, nq])?)?;
    d.set_item("tau_ext_measured", array(py, trace.tau_ext_measured, &[m, nq])?)?;
    d.set_item("contact", trace.contact.into_pyarray(py).reshape(vec![m])?)?;
    if has_filter {
        d.set_item("filtered", array(py, trace.filtered, &[m, nq])?)?;
        d.set_item(
            "filter_status",
            trace.filter_status.iter().map(|s| s.name()).collect::<Vec<_>>(),
        )?;
    }
    if has_tank {
        d.set_item("tank_energy", array(py, trace.tank_energy, &[m])?)?;
    }
    Ok(d)
}
