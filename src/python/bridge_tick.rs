//! Binding of the bridge's tick (`_core.BridgeTick`): a ROS node's 1 kHz callback hands it the
//! serialized joint state and publishes the serialized commands it returns, with the cascade's tick
//! run inside the same call.

use std::sync::Mutex;

use numpy::{PyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use super::bridge::PyJointMerge;
use super::cascade::PyCascade;
use super::convert::{lock, view};
use super::error::run;
use super::estimation::PyObjectStateEstimator;
use super::messages::stamp_of;
use super::scene::PyScene;
use crate::bridge::tick::{shaping_of, Answer, BridgeLayout, BridgeTick, Followed, Received, TrajectoryLayout};
use crate::control::command_stream::CommandGate;
use crate::control::{Cascade, Shared, WrenchFrames};

/// (arm velocity command or None, base command or None, command echo or None, arm trajectory
/// segment or None) as bytes to publish.
type Step<'py> = (
    Option<Bound<'py, PyBytes>>,
    Option<Bound<'py, PyBytes>>,
    Option<Bound<'py, PyBytes>>,
    Option<Bound<'py, PyBytes>>,
);

/// What `follow` returns: why nothing was sent ("planning", "plan stale") or None, the step sent (None
/// then), x (nx,), the tank's energy (None without a tank), the filter's status.
type Answered<'py> = (
    Option<&'static str>,
    Option<Step<'py>>,
    Bound<'py, PyArray1<f64>>,
    Option<f64>,
    &'static str,
);

fn step<'py>(py: Python<'py>, answer: &Answer) -> Step<'py> {
    let bytes = |b: &Option<Vec<u8>>| b.as_ref().map(|b| PyBytes::new(py, b));
    (
        bytes(&answer.arm),
        bytes(&answer.base),
        bytes(&answer.echo),
        bytes(&answer.trajectory),
    )
}

/// The controller node's 1 kHz path (see `sabre.ros.controller_loop`): joint states merged by
/// name, the object's state, the cascade's tick with its command shaping (τ_ext conditioned, the
/// rate-limited gate), on serialized messages. Takes copies of the merge and estimator it is built
/// from, and shares the cascade (`_core.Cascade`, given its shaping with `set_shaping`) its deployment
/// loop hands the plans to.
#[pyclass(name = "BridgeTick", module = "sabre._core", frozen)]
pub struct PyBridgeTick {
    inner: Mutex<BridgeTick>,
    cascade: Shared<Cascade>,
}

#[pymethods]
impl PyBridgeTick {
    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (cascade, joints, estimator, object_position, object_velocity, max_tick_dt, cmd_vel_stamped, cmd_vel_frame, echo_names=None, trajectory_names=None, trajectory_accelerations=false))]
    fn new(
        cascade: &PyCascade,
        joints: &PyJointMerge,
        estimator: Option<&PyObjectStateEstimator>,
        object_position: Vec<f64>,
        object_velocity: Vec<f64>,
        max_tick_dt: f64,
        cmd_vel_stamped: bool,
        cmd_vel_frame: String,
        echo_names: Option<Vec<String>>,
        trajectory_names: Option<Vec<String>>,
        trajectory_accelerations: bool,
    ) -> PyResult<Self> {
        let layout = BridgeLayout {
            max_tick_dt,
            cmd_vel_stamped,
            cmd_vel_frame,
            echo_names,
            trajectory: trajectory_names.map(|names| TrajectoryLayout {
                names,
                accelerations: trajectory_accelerations,
            }),
        };
        let tick = run(|| {
            BridgeTick::new(
                layout,
                joints.merge(),
                estimator.map(PyObjectStateEstimator::inner),
                (object_position, object_velocity),
            )
        })?;
        Ok(Self {
            inner: Mutex::new(tick),
            cascade: cascade.inner.clone(),
        })
    }

    /// Reads and merges a serialized joint state that arrived at `received` (s, monotonic):
    /// ("merged", nan, None), ("tick" or "stale", t, None) for an arm state at t (s since the
    /// first; "stale": a joint is past its timeout), or ("rejected" or "rejected-tick", nan,
    /// why) ("rejected-tick": it still gets an answer, a ramp step).
    fn receive(&self, raw: &[u8], received: f64) -> (&'static str, f64, Option<String>) {
        match lock(&self.inner).receive(raw, received) {
            Received::Merged => ("merged", f64::NAN, None),
            Received::Tick { t, fresh } => (if fresh { "tick" } else { "stale" }, t, None),
            Received::Rejected { error, ticks } => (
                if ticks { "rejected-tick" } else { "rejected" },
                f64::NAN,
                Some(error.to_string()),
            ),
        }
    }

    /// Answers the newest state at its time `t` with the cascade's plan in force (the estimator
    /// hooking only when `may_hook`): the state, the cascade's tick and the gate's step. Without a
    /// plan, or with one older than `max_plan_age` s, nothing is sent. Returns (why nothing was sent
    /// ("planning", "plan stale") or None, (arm, base or None, echo or None) bytes or None, x (nx,),
    /// tank energy or None, filter status).
    fn follow<'py>(&self, py: Python<'py>, t: f64, received: f64, may_hook: bool, max_plan_age: f64) -> PyResult<Answered<'py>> {
        // Always the bridge's tick, then the cascade: one lock order for every call.
        let mut tick = lock(&self.inner);
        let mut cascade = lock(&self.cascade);
        let followed = run(|| tick.follow(&mut cascade, t, received, may_hook, max_plan_age))?;
        let x = PyArray1::from_slice(py, tick.x());
        Ok(match followed {
            Followed::Answered(answer) => {
                let out = cascade.output();
                (None, Some(step(py, &answer)), x, out.tank_energy, out.status_name())
            }
            Followed::NoPlan => (Some("planning"), None, x, None, "none"),
            Followed::StalePlan => (Some("plan stale"), None, x, None, "none"),
        })
    }

    /// The state x (nx,) at the newest state's time `t` without a tick (the planner starting): the
    /// planner still sees it.
    fn observe<'py>(&self, py: Python<'py>, t: f64, may_hook: bool) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let mut tick = lock(&self.inner);
        let force = lock(&self.cascade).tau_ext().force();
        let x = run(|| tick.state(t, may_hook, force).map(<[f64]>::to_vec))?;
        tick.skip(t);
        Ok(PyArray1::from_vec(py, x))
    }

    /// A ramp step toward zero answering the newest (or a rejected) state at `received`.
    fn stop<'py>(&self, py: Python<'py>, received: f64) -> PyResult<Step<'py>> {
        let mut tick = lock(&self.inner);
        let answer = run(|| tick.stop(&mut lock(&self.cascade), received))?;
        Ok(step(py, &answer))
    }

    /// The ramp steps due at `now` (s, monotonic) because no state came for the state timeout
    /// (at most `limit`), a stamped base command stamped `stamp_ns`.
    #[pyo3(signature = (now, stamp_ns, limit=10))]
    fn watchdog<'py>(&self, py: Python<'py>, now: f64, stamp_ns: i64, limit: usize) -> PyResult<Vec<Step<'py>>> {
        let mut tick = lock(&self.inner);
        let steps = run(|| tick.watchdog(&mut lock(&self.cascade), now, limit, stamp_of(stamp_ns)))?;
        Ok(steps.iter().map(|a| step(py, a)).collect())
    }

    /// Seconds until the watchdog has something to do.
    fn next_look(&self, now: f64) -> PyResult<f64> {
        self.gate(|g| g.next_look(now))
    }

    /// One step of the ramp to zero outside the ticks (a shutdown's), None once at rest.
    fn ramp_step<'py>(&self, py: Python<'py>, stamp_ns: i64) -> PyResult<Option<Step<'py>>> {
        let mut tick = lock(&self.inner);
        let answer = run(|| tick.ramp_step(&mut lock(&self.cascade), stamp_of(stamp_ns)))?;
        Ok(answer.map(|a| step(py, &a)))
    }

    /// Merges joints (sabre's indices) from another source, the base's from odometry.
    fn set_joints(
        &self,
        indices: Vec<usize>,
        position: PyReadonlyArrayDyn<'_, f64>,
        velocity: PyReadonlyArrayDyn<'_, f64>,
        received: f64,
    ) -> PyResult<()> {
        let n = indices.len() as isize;
        run(|| {
            let (p, v) = (view("position", &position, &[n])?, view("velocity", &velocity, &[n])?);
            lock(&self.inner).set_joints(&indices, p, v, received)
        })
    }

    /// A serialized wrist wrench (WrenchStamped) that arrived at `received` (s, monotonic): the
    /// cascade's τ_ext at the newest joint positions, in the frame its header names.
    fn set_wrench(&self, raw: &[u8], received: f64) -> PyResult<()> {
        let tick = lock(&self.inner);
        let mut cascade = lock(&self.cascade);
        run(|| tick.set_wrench(&mut cascade, raw, received))
    }

    /// The object's (o, ȯ) from its topic.
    fn set_object(&self, position: PyReadonlyArrayDyn<'_, f64>, velocity: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        run(|| lock(&self.inner).set_object(view("position", &position, &[-1])?, view("velocity", &velocity, &[-1])?))
    }

    /// The newest arm state's stamp (s since its clock's epoch).
    #[getter]
    fn stamp(&self) -> f64 {
        lock(&self.inner).stamp().seconds()
    }
    /// The merged joint positions (nq,).
    #[getter]
    fn position<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, lock(&self.inner).joints().position())
    }
    /// The object's estimate (o, ȯ, hooked, residual), None without an estimator or before a state.
    #[getter]
    fn estimate(&self) -> Option<(f64, f64, bool, f64)> {
        lock(&self.inner)
            .estimate()
            .map(|e| (e.position, e.velocity, e.hooked, e.residual))
    }
    /// The object's coordinate as the controller knows it.
    #[getter]
    fn opening(&self) -> f64 {
        lock(&self.inner).opening()
    }
    #[getter]
    fn at_rest(&self) -> PyResult<bool> {
        self.gate(|g| g.shaper().at_rest())
    }
    /// Whether the watchdog is ramping the commands down because no state came.
    #[getter]
    fn ramping_for_stale_state(&self) -> PyResult<bool> {
        self.gate(|g| g.stale_since().is_some())
    }
    #[getter]
    fn stale_events(&self) -> PyResult<usize> {
        self.gate(CommandGate::stale_events)
    }
    #[getter]
    fn period(&self) -> PyResult<f64> {
        self.gate(CommandGate::period)
    }
    #[getter]
    fn state_timeout(&self) -> PyResult<f64> {
        self.gate(CommandGate::state_timeout)
    }
    /// The counts: ticks (states answered), answered (commands sent), followed, rejected,
    /// wrench_stale, wrench_received.
    #[getter]
    fn counts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = lock(&self.inner).counts().clone();
        let (received, stale) = {
            let cascade = lock(&self.cascade);
            (cascade.tau_ext().readings(), cascade.tau_ext().stale_count())
        };
        let d = PyDict::new(py);
        d.set_item("ticks", c.ticks)?;
        d.set_item("answered", c.answered)?;
        d.set_item("followed", c.followed)?;
        d.set_item("rejected", c.rejected)?;
        d.set_item("wrench_stale", stale)?;
        d.set_item("wrench_received", received)?;
        Ok(d)
    }
}

impl PyBridgeTick {
    /// `read` of the cascade's command gate; an error for a cascade that shapes no commands.
    fn gate<R>(&self, read: impl FnOnce(&CommandGate) -> R) -> PyResult<R> {
        let cascade = lock(&self.cascade);
        run(|| shaping_of(&cascade).map(|s| read(s.gate())))
    }
}

/// How a wrist wrench's header frame is read (`sabre.ros.inputs.WrenchFrames` runs it; the tick
/// runs a copy built from the same three frames).
#[pyclass(name = "WrenchFrames", module = "sabre._core", frozen)]
pub struct PyWrenchFrames {
    inner: WrenchFrames,
}

#[pymethods]
impl PyWrenchFrames {
    /// `world_frame` (and "world") name world axes, `default_frame` is an empty header's frame,
    /// `point_frame` ("" : the axes frame's) the moment's point.
    #[new]
    fn new(scene: &PyScene, world_frame: &str, default_frame: &str, point_frame: &str) -> PyResult<Self> {
        run(|| WrenchFrames::new(scene.inner.clone(), world_frame, default_frame, point_frame)).map(|inner| Self { inner })
    }

    /// τ_ext (nq,) = J(q)ᵀ w of a wrist wrench (6,) [f; m] given in the header frame `frame_id`.
    fn tau_ext<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'py, f64>,
        wrench: PyReadonlyArrayDyn<'py, f64>,
        frame_id: &str,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let tau = run(|| {
            let q = view("q", &q, &[-1])?;
            let w = view("wrench", &wrench, &[6])?;
            let w: [f64; 6] = [w[0], w[1], w[2], w[3], w[4], w[5]];
            self.inner.tau_ext(q, &w, frame_id)
        })?;
        Ok(PyArray1::from_vec(py, tau))
    }

    /// (axes frame or None for world axes, moment point frame) of a header's frame id.
    fn resolve(&self, frame_id: &str) -> PyResult<(Option<String>, String)> {
        run(|| {
            self.inner
                .resolve(frame_id)
                .map(|(axes, point)| (axes.map(str::to_owned), point.to_owned()))
        })
    }
}
