//! `_core.Cascade`: the control cascade's inner loop (`crate::control::Cascade`) on the very low-level
//! controller, FILTER-QP and tank objects given (their state is shared with every other holder).

use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArray1, PyArrayMethods, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::bridge::PyCommandGate;
use super::control::{PyLowLevelController, PyPlan};
use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::safety::{PyEnergyTank, PyLimitBoundConfig, PySafetyFilter};
use super::sim::PyPlant;
use crate::control::segment::SegmentShape;
use crate::control::trajectory_stream::{
    TrajectoryConfig, TRAJECTORY_FILTER_STEP, TRAJECTORY_KNOT, TRAJECTORY_LEAD, TRAJECTORY_PERIOD, TRAJECTORY_TIME_CONSTANT,
    TRAJECTORY_TOLERATED_GAP,
};
use crate::control::{Cascade, CommandShaping, ExternalTorque, Shared, TrackTrace, WrenchFrames};

/// A tick's output: the reference, the command after the filter, the torques (nq,), the tank's energy
/// (None without a tank) and the filter's status ("unfiltered" without a filter).
type Tick<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Option<f64>,
    &'static str,
);

/// The cascade's inner loop: the plan in force, τ_ext conditioned, the optional FILTER-QP and energy
/// tank, the low-level controller (see `sabre.realtime` and `sabre.closed_loop`, which tick it).
#[pyclass(name = "Cascade", module = "sabre._core", frozen)]
pub struct PyCascade {
    pub(crate) inner: Shared<Cascade>,
    low_level: Py<PyLowLevelController>,
    filter: Option<Py<PySafetyFilter>>,
    tank: Option<Py<PyEnergyTank>>,
    nx: usize,
    nq: usize,
}

#[pymethods]
impl PyCascade {
    /// The cascade of `low_level` with `filter` (built for the same robot) and `tank` if given; τ_ext
    /// low-passed at `tau_ext_cutoff` Hz (None or 0: as read), counted as none once older than
    /// `tau_ext_timeout` s (None: never), wrist wrenches read through `wrench_frames` (world frame, the
    /// sensor frame for an empty header, the moment's point frame or ""); every command held to the hard
    /// joint-limit bound of `limit_bound` (None: the filter's, the defaults without a filter).
    #[new]
    #[pyo3(signature = (
        low_level, filter=None, tank=None, tau_ext_cutoff=None, tau_ext_timeout=None, wrench_frames=None, limit_bound=None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        low_level: Bound<'_, PyLowLevelController>,
        filter: Option<Bound<'_, PySafetyFilter>>,
        tank: Option<Bound<'_, PyEnergyTank>>,
        tau_ext_cutoff: Option<f64>,
        tau_ext_timeout: Option<f64>,
        wrench_frames: Option<(String, String, String)>,
        limit_bound: Option<PyLimitBoundConfig>,
    ) -> PyResult<Self> {
        let shared = low_level.get().inner.clone();
        let scene = lock(&shared).scene().clone();
        let cascade = run(|| {
            let frames = wrench_frames
                .map(|(world, default, point)| WrenchFrames::new(scene.clone(), &world, &default, &point))
                .transpose()?;
            let tau = ExternalTorque::new(scene.nq(), tau_ext_cutoff, tau_ext_timeout, frames)?;
            let mut cascade = Cascade::new(
                shared,
                filter.as_ref().map(|f| f.borrow().inner.clone()),
                tank.as_ref().map(|t| t.borrow().inner.clone()),
                tau,
            )?;
            if let Some(bound) = &limit_bound {
                cascade.set_limit_bound(&bound.to_core())?;
            }
            Ok(cascade)
        })?;
        Ok(Self {
            inner: Arc::new(Mutex::new(cascade)),
            low_level: low_level.unbind(),
            filter: filter.map(Bound::unbind),
            tank: tank.map(Bound::unbind),
            nx: scene.nx(),
            nq: scene.nq(),
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

    /// Hands over `plan`; returns the number it is known by (`in_force`). It takes over at the first
    /// tick at time `at` (s) or later; None, or no plan in force yet: at once. A plan still waiting
    /// for its time is dropped.
    #[pyo3(signature = (plan, at=None))]
    fn hand_over(&self, plan: &PyPlan, at: Option<f64>) -> PyResult<u64> {
        run(|| lock(&self.inner).hand_over(plan.inner.clone(), at))
    }

    /// The number of the plan in force at time t (s), after one handed over for t or earlier takes
    /// over; None before the first.
    fn plan_at(&self, t: f64) -> Option<u64> {
        let mut cascade = lock(&self.inner);
        cascade.plan_at(t);
        cascade.in_force()
    }

    /// The number of the plan in force (None before the first).
    #[getter]
    fn in_force(&self) -> Option<u64> {
        lock(&self.inner).in_force()
    }

    /// (number, time) of the plan waiting for its time, or None.
    #[getter]
    fn pending(&self) -> Option<(u64, f64)> {
        lock(&self.inner).pending()
    }

    /// Shapes the commands for a robot's command interface from now on (a copy of `gate`): the arm
    /// command carries sabre's joints `arm_index`, the base's twist the joints `base_index` (x, y, yaw;
    /// None: a fixed base). The ROS 2 bridge's tick runs the shaping.
    #[pyo3(signature = (gate, arm_index, base_index=None))]
    fn set_shaping(&self, gate: &PyCommandGate, arm_index: Vec<usize>, base_index: Option<[usize; 3]>) -> PyResult<()> {
        run(|| {
            let shaping = CommandShaping::new(gate.gate(), arm_index, base_index, self.nq)?;
            lock(&self.inner).set_shaping(shaping)
        })
    }

    /// Streams the arm's commands as trajectory segments for a joint_trajectory_controller from now on
    /// (after `set_shaping`, whose arm joints they carry; the base keeps its stream): per arm joint the
    /// segments' `velocity`, `acceleration` and `jerk` bounds and JTC's `position_gain` (1/s), a
    /// segment every `period` s spliced `lead` s after its stamp, following the filtered plan for
    /// `tolerated_gap` + `period` before its stop, filtered every `filter_step` s on knots `knot` s
    /// apart with the velocity's time constant `time_constant`. The targets take JTC's feedback
    /// k_p (q_d − q) off, so that the robot executes the filtered command.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (velocity, acceleration, jerk, position_gain, period=TRAJECTORY_PERIOD, lead=TRAJECTORY_LEAD, tolerated_gap=TRAJECTORY_TOLERATED_GAP, filter_step=TRAJECTORY_FILTER_STEP, knot=TRAJECTORY_KNOT, time_constant=TRAJECTORY_TIME_CONSTANT))]
    fn set_trajectory(
        &self,
        velocity: Vec<f64>,
        acceleration: Vec<f64>,
        jerk: Vec<f64>,
        position_gain: Vec<f64>,
        period: f64,
        lead: f64,
        tolerated_gap: f64,
        filter_step: f64,
        knot: f64,
        time_constant: f64,
    ) -> PyResult<()> {
        run(|| {
            let config = TrajectoryConfig {
                shape: SegmentShape::new(velocity, acceleration, jerk, knot, time_constant)?,
                period,
                lead,
                tolerated_gap,
                filter_step,
                position_gain,
            };
            lock(&self.inner).set_trajectory(config)
        })
    }

    /// The trajectory stream's counts as a dict (published, stops, refused, fallbacks), None when the
    /// arm's commands are not segments.
    #[getter]
    fn trajectory_counts<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let cascade = lock(&self.inner);
        let Some(stream) = cascade.trajectory() else {
            return Ok(None);
        };
        let c = stream.counts();
        let d = PyDict::new(py);
        d.set_item("published", c.published)?;
        d.set_item("stops", c.stops)?;
        d.set_item("refused", c.refused)?;
        d.set_item("fallbacks", c.fallbacks)?;
        Ok(Some(d))
    }

    /// Forgets the plans and the low-level controller's integral (the τ_ext readings stay).
    fn reset(&self) {
        lock(&self.inner).reset();
    }

    /// Ticks since construction or the last reset.
    #[getter]
    fn ticks(&self) -> u64 {
        lock(&self.inner).ticks()
    }

    /// Ticks since construction or the last reset whose command the joint-limit bound changed.
    #[getter]
    fn limit_holds(&self) -> u64 {
        lock(&self.inner).limit_holds()
    }

    /// One tick at the measured state x (nx,) and external torques tau_ext (nq,) at time t, integrating
    /// over dt (s): the plan in force at t → FILTER-QP (with the passivity row when there is a tank) →
    /// the tank's refill and step → the low-level torque with the plan's gain inertia floor, else the
    /// controller's own. Returns (reference (nu,), command (nu,), torque (nq,), tank energy or None,
    /// filter status or "unfiltered").
    ///
    /// Keeps the GIL: a tick takes tens of µs, and the 1 kHz caller needs the GIL again right after
    /// it; releasing it would let a planner thread's Python work delay the tick's return.
    fn tick<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        tau_ext: PyReadonlyArrayDyn<'py, f64>,
        t: f64,
        dt: f64,
    ) -> PyResult<Tick<'py>> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let tau_ext = run(|| view("tau_ext", &tau_ext, &[self.nq as isize]))?;
        let mut cascade = lock(&self.inner);
        let out = run(|| cascade.tick_measured(x, tau_ext, t, dt))?;
        Ok((
            PyArray1::from_slice(py, &out.reference),
            PyArray1::from_slice(py, &out.command),
            PyArray1::from_slice(py, &out.torque),
            out.tank_energy,
            out.status_name(),
        ))
    }

    /// The cascade driving `plant` for `steps` plant steps (each a tick at the plant's state, τ_ext
    /// measurement and time, then the plant step with its torques); returns the trace of every
    /// `record_every`-th step as a dict: time, state, reference, wrench, tau_ext, tau_ext_measured,
    /// contact, and with a filter filtered (M, nq) and filter_status (list of str), with a tank
    /// tank_energy (M,).
    #[pyo3(signature = (plant, steps, record_every=1))]
    fn follow<'py>(&self, py: Python<'py>, plant: &PyPlant, steps: usize, record_every: usize) -> PyResult<Bound<'py, PyDict>> {
        let (plant, cascade) = (&plant.inner, &self.inner);
        let (has_filter, has_tank) = (self.filter.is_some(), self.tank.is_some());
        let trace = run_detached(py, || {
            // Always plant, then cascade (and its stages): one lock order for every call.
            let mut plant = lock(plant);
            let mut cascade = lock(cascade);
            let mut trace = TrackTrace::default();
            cascade.follow(&mut plant, steps, record_every, &mut trace)?;
            Ok(trace)
        })?;
        trace_dict(py, trace, self.nx, self.nq, has_filter, has_tank)
    }

    /// The newest τ_ext (nq,) and the wrist force's magnitude (N; inf: torques only), arrived at
    /// `received` (s, the ticks' clock).
    fn set_external_torque(&self, tau: PyReadonlyArrayDyn<'_, f64>, force: f64, received: f64) -> PyResult<()> {
        run(|| {
            let tau = view("tau_ext", &tau, &[self.nq as isize])?;
            lock(&self.inner).tau_ext_mut().set_torque(tau, force, received)
        })
    }

    /// The newest τ_ext (nq,) as received (before the low-pass).
    #[getter]
    fn tau_ext<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).tau_ext().raw())
    }

    /// (readings received, ticks that found the newest one older than the timeout).
    #[getter]
    fn tau_ext_counts(&self) -> (u64, u64) {
        let cascade = lock(&self.inner);
        (cascade.tau_ext().readings(), cascade.tau_ext().stale_count())
    }
}

/// The dict of a trace of M recorded steps (see [`PyCascade::follow`]).
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
