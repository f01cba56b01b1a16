//! `_core.LowLevelController`: the dynamics-compensated PI joint-velocity controller (53) of the
//! plant, with its config object, and the inner loop that drives the plant with it (constant
//! tracking, and following a reference with the optional safety stage); `_core.Plan` and
//! `_core.InnerLoop`, the inner loop's tick on a measured state (one call per 1 kHz step).

use std::sync::Mutex;

use numpy::{IntoPyArray, PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyType};

use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::safety::{PyEnergyTank, PySafetyFilter};
use super::scene::PyScene;
use super::sim::PyPlant;
use crate::control::{
    follow_reference_safe, InnerLoop, InnerSafety, LowLevelConfig, LowLevelController, Plan, TickOutput, TrackTrace,
};
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
    inner: Plan,
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
            Ok(Self { inner: plan })
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

/// The inner loop's tick: the reference, the command after the filter, the torques (nq,), the
/// tank's energy (None without a tank) and the filter's status ("unfiltered" without a filter).
type Tick<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Option<f64>,
    &'static str,
);

/// The inner loop on a measured state: the low-level controller with the optional FILTER-QP and
/// energy tank, the very objects given (their state is shared with every other holder).
#[pyclass(name = "InnerLoop", module = "sabre._core", frozen)]
pub struct PyInnerLoop {
    low_level: Py<PyLowLevelController>,
    filter: Option<Py<PySafetyFilter>>,
    tank: Option<Py<PyEnergyTank>>,
    nx: usize,
    nq: usize,
    /// The tick's buffers, reused from call to call.
    output: Mutex<TickOutput>,
}

#[pymethods]
impl PyInnerLoop {
    /// The inner loop of `low_level`, with `filter` (built for the same robot) and `tank` if given.
    #[new]
    #[pyo3(signature = (low_level, filter=None, tank=None))]
    fn new(
        low_level: Bound<'_, PyLowLevelController>,
        filter: Option<Bound<'_, PySafetyFilter>>,
        tank: Option<Bound<'_, PyEnergyTank>>,
    ) -> PyResult<Self> {
        let (nx, nq) = {
            // The same check as every tick's, once here so that a mismatch fails at construction.
            let mut controller = lock(&low_level.get().inner);
            let filter = match &filter {
                Some(f) => Some(f.try_borrow()?),
                None => None,
            };
            let mut filter_guard = filter.as_ref().map(|f| lock(&f.inner));
            run(|| InnerLoop::new(&mut controller, filter_guard.as_deref_mut(), None).map(|_| ()))?;
            let scene = controller.scene();
            (scene.nx(), scene.nq())
        };
        Ok(Self {
            low_level: low_level.unbind(),
            filter: filter.map(Bound::unbind),
            tank: tank.map(Bound::unbind),
            nx,
            nq,
            output: Mutex::new(TickOutput::new(nq, nq)),
        })
    }

    #[getter]
    fn low_level(&self, py: Python<'_>) -> Py<PyLowLevelController> {
        self.low_level.clone_ref(py)
    }
    #[getter]
    fn filter(&self, py: Python<'_>) -> Option<Py<PySafetyFilter>> {
        self.filter.as_ref().map(|f| f.clone_ref(py))
    }
    #[getter]
    fn tank(&self, py: Python<'_>) -> Option<Py<PyEnergyTank>> {
        self.tank.as_ref().map(|t| t.clone_ref(py))
    }

    /// One tick at the measured state x (nx,) and external torques tau_ext (nq,) at time t,
    /// integrating the tank over dt (s): the plan's reference at t → FILTER-QP (with the passivity
    /// row when there is a tank) → the tank's refill and step → the low-level torque with the
    /// plan's gain inertia floor, else the controller's own. Returns (reference (nu,), command
    /// (nu,), torque (nq,), tank energy or None, filter status or "unfiltered").
    ///
    /// Keeps the GIL: a tick takes tens of µs, and the 1 kHz caller needs the GIL again right
    /// after it; releasing it would let a planner thread's Python work delay the tick's return.
    fn tick<'py>(
        &self,
        py: Python<'py>,
        plan: &PyPlan,
        x: PyReadonlyArrayDyn<'py, f64>,
        tau_ext: PyReadonlyArrayDyn<'py, f64>,
        t: f64,
        dt: f64,
    ) -> PyResult<Tick<'py>> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let tau_ext = run(|| view("tau_ext", &tau_ext, &[self.nq as isize]))?;
        self.tick_slices(py, plan, x, tau_ext, t, dt, |out| {
            (
                PyArray1::from_slice(py, &out.reference),
                PyArray1::from_slice(py, &out.command),
                PyArray1::from_slice(py, &out.torque),
                out.tank_energy,
                out.status_name(),
            )
        })
    }
}

impl PyInnerLoop {
    /// One tick on plain slices (see `tick`), handing its output to `then`: the bridge's tick runs
    /// the inner loop this way between its own stages.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn tick_slices<R>(
        &self,
        py: Python<'_>,
        plan: &PyPlan,
        x: &[f64],
        tau_ext: &[f64],
        t: f64,
        dt: f64,
        then: impl FnOnce(&TickOutput) -> R,
    ) -> PyResult<R> {
        let filter = match &self.filter {
            Some(f) => Some(f.bind(py).try_borrow()?),
            None => None,
        };
        let tank = match &self.tank {
            Some(t) => Some(t.bind(py).try_borrow()?),
            None => None,
        };
        let mut out = lock(&self.output);
        {
            // Controller, filter, tank: the lock order of every call.
            let mut controller = lock(&self.low_level.get().inner);
            let mut filter = filter.as_ref().map(|f| lock(&f.inner));
            let mut tank = tank.as_ref().map(|t| lock(&t.inner));
            run(|| {
                InnerLoop::new(&mut controller, filter.as_deref_mut(), tank.as_deref_mut())?.tick(
                    &plan.inner,
                    x,
                    tau_ext,
                    t,
                    dt,
                    &mut out,
                )
            })?;
        }
        Ok(then(&out))
    }
}
