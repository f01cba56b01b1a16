//! `_core.CommandGate`, the arm's and base's command streams through their rate limiters with the
//! gate that makes them follow targets or ramp to zero and its watchdog; `_core.JointMerge`, a
//! robot's joint states merged by name from several publishers with a staleness per joint. The
//! bridge's per-tick logic (`sabre.ros.commands`, `sabre.ros.inputs`) runs on these.

use std::sync::Mutex;

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::convert::{lock, vector};
use super::error::run;
use super::rate_limit::PyRateLimiter;
use crate::control::command_stream::{Command, CommandGate, CommandShaper};
use crate::control::joint_merge::JointMerge;
use crate::error::SabreError;

/// One command as Python sees it: the arm's (na,) and the base's (3,) when it is due, else None.
type PyCommand<'py> = (Bound<'py, PyArray1<f64>>, Option<Bound<'py, PyArray1<f64>>>);

fn py_command<'py>(py: Python<'py>, command: &Command) -> PyCommand<'py> {
    let base = command.base_due.then(|| PyArray1::from_slice(py, &command.base));
    (PyArray1::from_slice(py, &command.arm), base)
}

fn target(name: &str, values: Option<Bound<'_, PyAny>>) -> PyResult<Option<Vec<f64>>> {
    values.map(|v| vector(name, &v)).transpose()
}

/// The arm's command stream (a step per call) and the base's (a step every `base_every`-th call),
/// each through its rate limiter, and the gate on them: a tick follows its targets or, without,
/// steps a ramp to zero; once no tick came for `state_timeout` s, the watchdog gives the ramp's
/// steps, one per period (the arm limiter's dt), starting at most one period after the timeout.
#[pyclass(name = "CommandGate", module = "sabre._core", frozen)]
pub struct PyCommandGate {
    inner: Mutex<CommandGate>,
}

impl PyCommandGate {
    /// The gate with its streams' state, a copy for another core object to own.
    pub(crate) fn gate(&self) -> CommandGate {
        lock(&self.inner).clone()
    }
}

#[pymethods]
impl PyCommandGate {
    /// The gate on copies of `arm` and `base` (None: a fixed base) in their current state; the
    /// base steps every `base_every`-th call; `state_timeout` (s) not negative, inf: no watchdog.
    #[new]
    fn new(
        arm: PyRef<'_, PyRateLimiter>,
        base: Option<PyRef<'_, PyRateLimiter>>,
        base_every: usize,
        state_timeout: f64,
    ) -> PyResult<Self> {
        let shaper = CommandShaper::new(arm.limiter(), base.map(|b| b.limiter()), base_every);
        let inner = run(|| CommandGate::new(shaper, state_timeout))?;
        Ok(Self {
            inner: Mutex::new(inner),
        })
    }

    /// A gate with a copy of these streams in their current state, its own clock (no tick yet)
    /// and `state_timeout`.
    fn with_state_timeout(&self, state_timeout: f64) -> PyResult<Self> {
        let shaper = lock(&self.inner).shaper().clone();
        let inner = run(|| CommandGate::new(shaper, state_timeout))?;
        Ok(Self {
            inner: Mutex::new(inner),
        })
    }

    /// The command answering a tick at `now`: (arm (na,), base (3,) or None when not due).
    /// `arm` None: a step of the ramp to zero; `base` None: the base's last target.
    #[pyo3(signature = (now, arm=None, base=None))]
    fn on_tick<'py>(
        &self,
        py: Python<'py>,
        now: f64,
        arm: Option<Bound<'py, PyAny>>,
        base: Option<Bound<'py, PyAny>>,
    ) -> PyResult<PyCommand<'py>> {
        let (arm, base) = (target("arm", arm)?, target("base", base)?);
        let mut gate = lock(&self.inner);
        let command = run(|| gate.on_tick(now, arm.as_deref(), base.as_deref()))?;
        Ok(py_command(py, command))
    }

    /// One step of the streams outside the gate's clock (a shutdown's ramp once the watchdog
    /// stopped), with the targets of :meth:`on_tick`.
    #[pyo3(signature = (arm=None, base=None))]
    fn step<'py>(
        &self,
        py: Python<'py>,
        arm: Option<Bound<'py, PyAny>>,
        base: Option<Bound<'py, PyAny>>,
    ) -> PyResult<PyCommand<'py>> {
        let (arm, base) = (target("arm", arm)?, target("base", base)?);
        let mut gate = lock(&self.inner);
        let mut command = gate.shaper().command();
        run(|| gate.shaper_mut().step(arm.as_deref(), base.as_deref(), &mut command))?;
        Ok(py_command(py, &command))
    }

    /// The ramp steps due at `now` because no tick came for `state_timeout`, at most `limit`.
    #[pyo3(signature = (now, limit=10))]
    fn watchdog<'py>(&self, py: Python<'py>, now: f64, limit: usize) -> Vec<PyCommand<'py>> {
        let mut steps = Vec::new();
        lock(&self.inner).watchdog(now, limit, &mut steps);
        steps.iter().map(|c| py_command(py, c)).collect()
    }

    /// Seconds from `now` until the watchdog has something to do.
    fn next_look(&self, now: f64) -> f64 {
        lock(&self.inner).next_look(now)
    }

    /// Both streams at rest, the base's target zero and due on the next step (the clock stays).
    fn reset(&self) {
        lock(&self.inner).shaper_mut().reset();
    }

    #[getter]
    fn at_rest(&self) -> bool {
        lock(&self.inner).shaper().at_rest()
    }
    /// A bound on the arm steps a ramp to rest takes.
    #[getter]
    fn steps_to_rest(&self) -> usize {
        lock(&self.inner).shaper().steps_to_rest()
    }
    #[getter]
    fn base_every(&self) -> usize {
        lock(&self.inner).shaper().base_every()
    }
    #[getter]
    fn period(&self) -> f64 {
        lock(&self.inner).period()
    }
    #[getter]
    fn state_timeout(&self) -> f64 {
        lock(&self.inner).state_timeout()
    }
    /// When the last tick came (-inf before the first).
    #[getter]
    fn last_tick(&self) -> f64 {
        lock(&self.inner).last_tick()
    }
    /// When the last command was due.
    #[getter]
    fn last_command(&self) -> f64 {
        lock(&self.inner).last_command()
    }
    /// When the watchdog found the ticks stopped (None while they come).
    #[getter]
    fn stale_since(&self) -> Option<f64> {
        lock(&self.inner).stale_since()
    }
    #[getter]
    fn stale_events(&self) -> usize {
        lock(&self.inner).stale_events()
    }
    /// A copy of the arm's limiter (bounds and state).
    #[getter]
    fn arm(&self) -> PyRateLimiter {
        lock(&self.inner).shaper().arm().clone().into()
    }
    /// A copy of the base's limiter, None for a fixed base.
    #[getter]
    fn base(&self) -> Option<PyRateLimiter> {
        lock(&self.inner).shaper().base().cloned().map(Into::into)
    }

    fn __repr__(&self) -> String {
        let gate = lock(&self.inner);
        let shaper = gate.shaper();
        format!(
            "CommandGate(arm={}, base={}, base_every={}, state_timeout={})",
            shaper.arm().len(),
            shaper.base().map_or("None".to_string(), |b| b.len().to_string()),
            shaper.base_every(),
            gate.state_timeout()
        )
    }
}

/// Indices from a NumPy integer array or a sequence of ints (not negative).
fn indices(values: &Bound<'_, PyAny>) -> PyResult<Vec<usize>> {
    let signed: Vec<isize> = match values.cast::<PyArrayDyn<isize>>() {
        Ok(array) if array.ndim() == 1 => array.readonly().as_array().iter().copied().collect(),
        _ => values.extract()?,
    };
    signed
        .into_iter()
        .map(|i| usize::try_from(i).map_err(|_| SabreError::invalid("joint indices", format!("{i} is negative")).into()))
        .collect()
}

/// The newest position and velocity of each of a robot's joints (`names`, in this order), merged
/// from every message that names them, with the time each arrived; a message naming every one of
/// `tick_joints` drives a tick; a joint older than its timeout (s, one per joint) is stale.
#[pyclass(name = "JointMerge", module = "sabre._core", frozen)]
pub struct PyJointMerge {
    inner: Mutex<JointMerge>,
}

impl PyJointMerge {
    /// The merge with its joints' values, a copy for another core object to own.
    pub(crate) fn merge(&self) -> JointMerge {
        lock(&self.inner).clone()
    }
}

#[pymethods]
impl PyJointMerge {
    /// Distinct `names`, `tick_joints` among them, `timeouts` (n,) not negative (inf: never stale).
    #[new]
    fn new(names: Vec<String>, tick_joints: Vec<String>, timeouts: Bound<'_, PyAny>) -> PyResult<Self> {
        let timeouts = vector("timeouts", &timeouts)?;
        let inner = run(|| JointMerge::new(names, &tick_joints, timeouts))?;
        Ok(Self {
            inner: Mutex::new(inner),
        })
    }

    /// Takes a joint-state message's known joints (an empty `velocity`: zeros), arrived at
    /// `received`; returns whether it drives a tick. Mismatched lengths or a non-finite value
    /// for a known joint raise and change nothing.
    fn update(
        &self,
        names: Vec<String>,
        position: Bound<'_, PyAny>,
        velocity: Bound<'_, PyAny>,
        received: f64,
    ) -> PyResult<bool> {
        let (position, velocity) = (vector("position", &position)?, vector("velocity", &velocity)?);
        let mut merge = lock(&self.inner);
        run(|| merge.update(&names, &position, &velocity, received))
    }

    /// Whether a message naming `names` drives a tick.
    fn drives_tick(&self, names: Vec<String>) -> bool {
        lock(&self.inner).drives_tick(&names)
    }

    /// (indices into a message naming `names` of the joints known here, their indices in this
    /// merge's order, whether it drives a tick).
    #[allow(clippy::type_complexity)]
    fn route<'py>(
        &self,
        py: Python<'py>,
        names: Vec<String>,
    ) -> (Bound<'py, PyArray1<isize>>, Bound<'py, PyArray1<isize>>, bool) {
        let mut merge = lock(&self.inner);
        let route = merge.route(&names);
        let signed = |v: &[usize]| PyArray1::from_iter(py, v.iter().map(|&i| i as isize));
        (
            signed(route.message_indices()),
            signed(route.joint_indices()),
            route.drives_tick(),
        )
    }

    /// Sets the joints at `indices` (this merge's order) to `position` and `velocity`, arrived at
    /// `received`; a bad index, length or value raises and changes nothing.
    fn set(
        &self,
        indices: Bound<'_, PyAny>,
        position: Bound<'_, PyAny>,
        velocity: Bound<'_, PyAny>,
        received: f64,
    ) -> PyResult<()> {
        let index = self::indices(&indices)?;
        let (position, velocity) = (vector("position", &position)?, vector("velocity", &velocity)?);
        let mut merge = lock(&self.inner);
        run(|| merge.set(&index, &position, &velocity, received))
    }

    /// Whether every joint is within its timeout at `now`.
    fn fresh(&self, now: f64) -> bool {
        lock(&self.inner).fresh(now)
    }

    /// The joints older than their timeout at `now` (never received: stale unless the timeout is
    /// infinite).
    fn stale(&self, now: f64) -> Vec<String> {
        lock(&self.inner).stale(now).map(str::to_owned).collect()
    }

    #[getter]
    fn names(&self) -> Vec<String> {
        lock(&self.inner).names().to_vec()
    }
    /// The tick joints' indices in this merge's order.
    #[getter]
    fn tick_joints(&self) -> Vec<usize> {
        lock(&self.inner).tick_joints().to_vec()
    }
    /// (n,), a copy.
    #[getter]
    fn timeouts<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).timeouts())
    }
    /// (n,), a copy.
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).position())
    }
    /// (n,), a copy.
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).velocity())
    }
    /// (n,) when each joint's newest value arrived (-inf: never), a copy.
    #[getter]
    fn received<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).received())
    }

    fn __repr__(&self) -> String {
        let merge = lock(&self.inner);
        format!(
            "JointMerge(names={:?}, tick_joints={})",
            merge.names(),
            merge.tick_joints().len()
        )
    }
}
