//! Bindings of the simulated robot's driver side (`_core.SimDriver`), Franka's reflexes
//! (`_core.FrankaReflexes`) and the rcl endpoints (the `sabre-rcl` crate) the driver takes from and
//! publishes to without Python (`sabre.ros.direct` looks up their addresses and checks the versions).

use std::sync::Mutex;

use numpy::{PyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use super::convert::{lock, view};
use super::error::{run, run_detached};
use crate::bridge::reflexes::FrankaReflexes;
use crate::bridge::sim_driver::{MessageSink, MessageSource, SimDriver, SimDriverLayout};
use crate::error::{Result, SabreError};
use sabre_rcl::{RclError, RclLibrary, RclPublisher, RclSubscription, FUNCTION_NAMES};

/// The names of the rcl and rcutils functions whose addresses `SimDriver.connect` takes, in order.
#[pyfunction]
pub fn rcl_function_names() -> Vec<&'static str> {
    FUNCTION_NAMES.to_vec()
}

/// The ROS 2 the rcl layouts were checked against when sabre was built: its install prefix and
/// {package: version} of rcl, rcutils and rmw. Raises SabreError when sabre was built without the
/// ROS 2 headers.
#[pyfunction]
pub fn rcl_built_against() -> PyResult<(&'static str, Vec<(&'static str, &'static str)>)> {
    let (prefix, versions) = run(|| sabre_rcl::built_against().map_err(middleware))?;
    Ok((prefix, versions.to_vec()))
}

fn middleware(e: RclError) -> SabreError {
    SabreError::Simulation(e.0)
}

struct Subscription(RclSubscription);
struct Publisher(RclPublisher);

impl MessageSource for Subscription {
    fn take(&mut self) -> Result<Option<(&[u8], i64)>> {
        self.0.take().map_err(middleware)
    }
}

impl MessageSink for Publisher {
    fn publish(&self, bytes: &[u8]) -> Result<()> {
        self.0.publish(bytes).map_err(middleware)
    }
}

/// Franka's velocity, acceleration and jerk checks on the command in effect each cycle of `dt` s.
#[pyclass(name = "FrankaReflexes", module = "sabre._core", frozen)]
pub struct PyFrankaReflexes {
    inner: Mutex<FrankaReflexes>,
}

#[pymethods]
impl PyFrankaReflexes {
    #[new]
    fn new(dt: f64, velocity: Vec<f64>, acceleration: Vec<f64>, jerk: Vec<f64>) -> PyResult<Self> {
        let inner = run(|| FrankaReflexes::new(dt, &velocity, &acceleration, &jerk))?;
        Ok(Self {
            inner: Mutex::new(inner),
        })
    }

    /// The reflex `v` trips (its libfranka error), once; None while within the limits or aborted.
    fn check(&self, v: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Option<String>> {
        let mut r = lock(&self.inner);
        let n = r.joints() as isize;
        let v = run(|| view("v", &v, &[n]))?;
        Ok(r.check(v).map(str::to_string))
    }

    fn follow(&self, v: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        let mut r = lock(&self.inner);
        let n = r.joints() as isize;
        let v = run(|| view("v", &v, &[n]))?;
        r.follow(v);
        Ok(())
    }

    fn recover(&self) {
        lock(&self.inner).recover();
    }

    #[getter]
    fn aborted(&self) -> Option<String> {
        lock(&self.inner).aborted().map(str::to_string)
    }

    #[getter]
    fn aborts(&self) -> usize {
        lock(&self.inner).aborts()
    }
}

/// The simulated robot's 1 kHz side: arm commands received (checked, recorded, against the
/// reflexes, matched to the states they answer), each tick's reference, the joint states published.
#[pyclass(name = "SimDriver", module = "sabre._core", frozen)]
pub struct PySimDriver {
    inner: Mutex<SimDriver>,
    /// The rclpy endpoints the driver calls into, kept alive while it may.
    endpoints: Mutex<Vec<Py<PyAny>>>,
}

#[pymethods]
impl PySimDriver {
    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (nq, arm_index, base_index, command_timeout, period, names, held, position_noise, velocity_noise, noise_seed, per_message, recent_states, reflexes=None, trajectory_gains=None))]
    fn new(
        nq: usize,
        arm_index: Vec<usize>,
        base_index: Option<[usize; 3]>,
        command_timeout: f64,
        period: f64,
        names: Vec<String>,
        held: Vec<f64>,
        position_noise: f64,
        velocity_noise: f64,
        noise_seed: u64,
        per_message: bool,
        recent_states: usize,
        reflexes: Option<&PyFrankaReflexes>,
        trajectory_gains: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        let layout = SimDriverLayout {
            nq,
            arm_index,
            base_index,
            command_timeout,
            period,
            names,
            held,
            position_noise,
            velocity_noise,
            noise_seed,
            per_message,
            recent_states,
            trajectory_gains,
        };
        let reflexes = reflexes.map(|r| lock(&r.inner).clone());
        let inner = run(|| SimDriver::new(layout, reflexes))?;
        Ok(Self {
            inner: Mutex::new(inner),
            endpoints: Mutex::new(Vec::new()),
        })
    }

    /// Takes arm commands from `subscription` and publishes joint states to `publisher` (each an
    /// (rclpy endpoint, address of its rcl handle) pair, or None), through the functions at
    /// `functions` (addresses, in the order of `rcl_function_names()`). The endpoints are kept alive
    /// here; nothing else may take from the subscription.
    fn connect(
        &self,
        functions: [usize; 5],
        subscription: Option<(Py<PyAny>, usize)>,
        publisher: Option<(Py<PyAny>, usize)>,
    ) -> PyResult<()> {
        let (sub_owner, sub_address) = subscription.unzip();
        let (pub_owner, pub_address) = publisher.unzip();
        // SAFETY: the addresses are those of the loaded rcl functions and of the handles of the
        // endpoints kept alive in `endpoints` for as long as this driver lives.
        let (input, output) = run(|| unsafe {
            let library = RclLibrary::from_addresses(functions).map_err(middleware)?;
            let input = sub_address
                .map(|a| RclSubscription::new(library, a).map(|s| Box::new(Subscription(s)) as Box<dyn MessageSource>))
                .transpose()
                .map_err(middleware)?;
            let output = pub_address
                .map(|a| RclPublisher::new(library, a).map(|p| Box::new(Publisher(p)) as Box<dyn MessageSink>))
                .transpose()
                .map_err(middleware)?;
            Ok((input, output))
        })?;
        lock(&self.endpoints).extend(sub_owner.into_iter().chain(pub_owner));
        lock(&self.inner).connect(input, output);
        Ok(())
    }

    /// Stops taking and publishing through rcl (the endpoints may be destroyed after this) and
    /// releases the endpoints.
    fn disconnect(&self) {
        lock(&self.inner).connect(None, None);
        lock(&self.endpoints).clear();
    }

    /// One serialized arm command received at `now` (s, the ticks' clock) and `wall` (s since the epoch).
    fn receive_arm(&self, raw: &[u8], now: f64, wall: f64) {
        lock(&self.inner).receive_arm(raw, now, wall);
    }

    /// The base's serialized command (Twist, or TwistStamped when `stamped`) at `now`; False when
    /// refused (malformed or not finite).
    fn receive_base(&self, raw: &[u8], stamped: bool, now: f64) -> bool {
        lock(&self.inner).receive_base(raw, stamped, now)
    }

    /// Books an answer (a command echo) naming the state stamped with these nanoseconds.
    fn match_answer(&self, nanosec: u32, wall: f64) {
        lock(&self.inner).match_answer(nanosec, wall);
    }

    /// The reference (nq,) of the tick scheduled at `tick_time` with the robot at `q` (nq,) and the
    /// base at `yaw`, after taking the arm commands waiting (received at `now` / `wall`), and
    /// whether anything was refused or tripped meanwhile (see `take_events`). `excused`: a tick
    /// the robot's own loop ran late (catching up), neither checked nor counted as a gap.
    #[pyo3(signature = (tick_time, yaw, now, wall, q, excused=false))]
    #[allow(clippy::too_many_arguments)]
    fn tick<'py>(
        &self,
        py: Python<'py>,
        tick_time: f64,
        yaw: f64,
        now: f64,
        wall: f64,
        q: PyReadonlyArrayDyn<'_, f64>,
        excused: bool,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, bool)> {
        let q = q.as_slice()?;
        let (u, events) = run_detached(py, || {
            let mut d = lock(&self.inner);
            d.take_arm_commands(now, wall)?;
            let u = d.reference(tick_time, yaw, q, excused)?.to_vec();
            Ok((u, d.has_events()))
        })?;
        Ok((PyArray1::from_vec(py, u), events))
    }

    /// The gaps between arm command deliveries the robot saw: counts by length in cycles (index 0
    /// unused; the last bin holds every longer gap).
    fn delivery_gaps<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        PyArray1::from_slice(py, lock(&self.inner).cycles().gaps())
    }

    /// The largest |v|, |Δv|/dt and |Δ²v|/dt² (each (na,)) of the arm's command in effect over the
    /// cycles the robot ran on time.
    fn cycle_maxima<'py>(&self, py: Python<'py>) -> [Bound<'py, PyArray1<f64>>; 3] {
        let d = lock(&self.inner);
        d.cycles().maxima.clone().map(|m| PyArray1::from_vec(py, m))
    }

    /// The arm's joint state with noise from q and dq (nq,) stamped `stamp_ns`: published to the
    /// connected publisher (then None) or returned serialized.
    fn publish_state<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'_, f64>,
        dq: PyReadonlyArrayDyn<'_, f64>,
        stamp_ns: i64,
    ) -> PyResult<Option<Bound<'py, PyBytes>>> {
        let (q, dq) = (q.as_slice()?, dq.as_slice()?);
        let bytes = run_detached(py, || {
            Ok(lock(&self.inner).publish_state(q, dq, stamp_ns)?.map(<[u8]>::to_vec))
        })?;
        Ok(bytes.map(|b| PyBytes::new(py, &b)))
    }

    /// (commands refused: why, reflexes tripped: libfranka's error) since the last call.
    fn take_events(&self) -> (Vec<String>, Vec<String>) {
        let events = lock(&self.inner).take_events();
        (events.rejected, events.reflexes)
    }

    /// The round trips (s) booked since the last call.
    fn take_latencies<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, lock(&self.inner).take_latencies())
    }

    /// Counts: arm_commands, base_commands, rejected_commands, states_published, echoes,
    /// late_echoes, unmatched_echoes, first_answered and last_answered (None before any),
    /// reflex_aborts and reflex_aborted (the abort in effect, or None).
    fn counts<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = lock(&self.inner);
        let c = d.counts();
        let out = PyDict::new(py);
        for (k, v) in [
            ("arm_commands", c.arm_commands),
            ("base_commands", c.base_commands),
            ("rejected_commands", c.rejected_commands),
            ("states_published", c.states_published),
            ("echoes", c.echoes),
            ("late_echoes", c.late_echoes),
            ("unmatched_echoes", c.unmatched_echoes),
        ] {
            out.set_item(k, v)?;
        }
        out.set_item("first_answered", c.first_answered)?;
        out.set_item("last_answered", c.last_answered)?;
        out.set_item("reflex_aborts", d.reflexes().map_or(0, FrankaReflexes::aborts))?;
        out.set_item("reflex_aborted", d.reflexes().and_then(FrankaReflexes::aborted))?;
        Ok(out)
    }

    /// (largest |Δv| between consecutive arm commands, largest |Δ²v|, largest |v|, the command in
    /// effect), each (na,).
    #[allow(clippy::type_complexity)]
    fn arm_record<'py>(
        &self,
        py: Python<'py>,
    ) -> (
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
    ) {
        let d = lock(&self.inner);
        (
            PyArray1::from_slice(py, &d.step_max),
            PyArray1::from_slice(py, &d.step_change_max),
            PyArray1::from_slice(py, &d.speed_max),
            PyArray1::from_slice(py, d.arm_command()),
        )
    }

    /// Delays (s) from a part's last command to its stop, one per stop.
    fn stops(&self) -> Vec<f64> {
        lock(&self.inner).stops().to_vec()
    }
}
