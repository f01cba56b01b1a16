//! `_core.SafetyFilter` (FILTER-QP (41) and its sequential form, Algorithm 1) and
//! `_core.EnergyTank` (49), with their config objects.

use std::sync::{Arc, Mutex};

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::scene::PyScene;
use super::sim::PyRolloutModel;
use crate::control::Shared;
use crate::error::SabreError;
use crate::model::LimitBoundConfig;
use crate::safety::{ConstraintClass, EnergyTank, FilterOutput, PerClass, RefillConfig, SafetyConfig, SafetyFilter};

/// Settings of the hard joint-limit bound; `LimitBoundConfig()` holds the core's defaults.
#[pyclass(name = "LimitBoundConfig", module = "sabre._core", get_all, set_all, from_py_object)]
#[derive(Clone)]
pub struct PyLimitBoundConfig {
    /// Distance (rad) a revolute joint's stop ends inside its limit.
    margin: f64,
    /// Distance (m) a prismatic joint's stop ends inside its limit.
    prismatic_margin: f64,
    /// Deceleration (rad/s², m/s²) of an unshaped joint's stop.
    deceleration: f64,
}

impl PyLimitBoundConfig {
    pub(crate) fn to_core(&self) -> LimitBoundConfig {
        LimitBoundConfig {
            margin: self.margin,
            prismatic_margin: self.prismatic_margin,
            deceleration: self.deceleration,
        }
    }
    fn of(c: LimitBoundConfig) -> Self {
        Self {
            margin: c.margin,
            prismatic_margin: c.prismatic_margin,
            deceleration: c.deceleration,
        }
    }
}

#[pymethods]
impl PyLimitBoundConfig {
    #[new]
    fn new() -> Self {
        Self::of(LimitBoundConfig::default())
    }
}

/// Settings of the safety filter; `SafetyConfig()` holds the core's defaults. Per-class lists
/// follow the core's class order: joint_limits, self_collision, arm_reach, base_box, obstacles,
/// passivity (gamma's passivity entry is α of (56)).
#[pyclass(name = "SafetyConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PySafetyConfig {
    /// ZBF rate γ (1/s) per class.
    gamma: Vec<f64>,
    /// Slack penalty Γ per class (Table I).
    penalty: Vec<f64>,
    /// Margin Δ ≥ 0 per class (Remark 1).
    margin: Vec<f64>,
    /// Which classes get rows.
    enabled: Vec<bool>,
    /// [x_min, x_max, y_min, y_max] (m) of the base box.
    base_box: [f64; 4],
    /// Tank floor ε (J) of the passivity row.
    tank_floor: f64,
    /// Obstacle slots of the QP.
    max_obstacles: usize,
    /// Interior-point iteration bound of one solve.
    max_iterations: u32,
    /// Clarabel's feasibility and duality-gap tolerance.
    tolerance: f64,
    /// Residual or slack below / above which a row counts as active.
    active_tolerance: f64,
    /// Take the exact shortcuts (projection, remembered active set, rows that cannot bind left out).
    screening: bool,
    /// Weight λ (1/m²) of the task frame's velocity in the metric of `filter`; 0: the paper's ‖ũ − u‖².
    task_weight: f64,
    /// λ of the Sequential FILTER-QP (`filter_sequence`).
    sequential_task_weight: f64,
    /// The robot frame whose velocity the task metric protects.
    task_frame: String,
    /// The cascade's hard joint-limit bound.
    limit_bound: PyLimitBoundConfig,
}

fn per_class<T: Copy>(name: &str, values: &[T]) -> crate::Result<PerClass<T>> {
    let n = ConstraintClass::COUNT;
    <[T; ConstraintClass::COUNT]>::try_from(values)
        .map(PerClass)
        .map_err(|_| SabreError::shape(name, format!("({n},)"), format!("({},)", values.len())))
}

impl PySafetyConfig {
    fn to_core(&self) -> crate::Result<SafetyConfig> {
        Ok(SafetyConfig {
            gamma: per_class("gamma", &self.gamma)?,
            penalty: per_class("penalty", &self.penalty)?,
            margin: per_class("margin", &self.margin)?,
            enabled: per_class("enabled", &self.enabled)?,
            base_box: self.base_box,
            tank_floor: self.tank_floor,
            max_obstacles: self.max_obstacles,
            max_iterations: self.max_iterations,
            tolerance: self.tolerance,
            active_tolerance: self.active_tolerance,
            screening: self.screening,
            task_weight: self.task_weight,
            sequential_task_weight: self.sequential_task_weight,
            task_frame: self.task_frame.clone(),
            limit_bound: self.limit_bound.to_core(),
        })
    }
}

#[pymethods]
impl PySafetyConfig {
    #[new]
    fn new() -> Self {
        let c = SafetyConfig::default();
        Self {
            gamma: c.gamma.0.to_vec(),
            penalty: c.penalty.0.to_vec(),
            margin: c.margin.0.to_vec(),
            enabled: c.enabled.0.to_vec(),
            base_box: c.base_box,
            tank_floor: c.tank_floor,
            max_obstacles: c.max_obstacles,
            max_iterations: c.max_iterations,
            tolerance: c.tolerance,
            active_tolerance: c.active_tolerance,
            screening: c.screening,
            task_weight: c.task_weight,
            sequential_task_weight: c.sequential_task_weight,
            task_frame: c.task_frame,
            limit_bound: PyLimitBoundConfig::of(c.limit_bound),
        }
    }

    /// The constraint class names, in the order of the per-class lists.
    #[staticmethod]
    fn classes() -> Vec<&'static str> {
        ConstraintClass::ALL.iter().map(|c| c.name()).collect()
    }
}

/// Energy the tank starts with (J), the paper's S(0) (Sec. VI-C).
const DEFAULT_TANK_INITIAL: f64 = 10.0;

/// Settings of the energy tank; `EnergyTankConfig()` holds the defaults: S(0) = 10 J and the
/// filter's tank floor ε.
#[pyclass(name = "EnergyTankConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyEnergyTankConfig {
    /// S(0) (J).
    initial: f64,
    /// Floor ε (J).
    floor: f64,
    /// Energy above this is discarded; None: no ceiling.
    ceiling: Option<f64>,
    /// Keep S(0) and every step's energy.
    record_history: bool,
}

#[pymethods]
impl PyEnergyTankConfig {
    #[new]
    fn new() -> Self {
        Self {
            initial: DEFAULT_TANK_INITIAL,
            floor: SafetyConfig::default().tank_floor,
            ceiling: None,
            record_history: true,
        }
    }
}

/// Settings of the tank's refill (beyond the paper); `TankRefillConfig()` holds the defaults.
#[pyclass(name = "TankRefillConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyTankRefillConfig {
    /// Most power (W) the refill adds.
    max_rate: f64,
    /// Absolute agreement band (W) between measured and predicted dissipation.
    tolerance: f64,
    /// Agreement band relative to the predicted dissipation.
    relative_tolerance: f64,
    /// Time constant (s) of the low-pass on both dissipations.
    time_constant: f64,
}

#[pymethods]
impl PyTankRefillConfig {
    #[new]
    fn new() -> Self {
        let d = RefillConfig::default();
        Self {
            max_rate: d.max_rate,
            tolerance: d.tolerance,
            relative_tolerance: d.relative_tolerance,
            time_constant: d.time_constant,
        }
    }
}

impl From<&PyTankRefillConfig> for RefillConfig {
    fn from(c: &PyTankRefillConfig) -> Self {
        Self {
            max_rate: c.max_rate,
            tolerance: c.tolerance,
            relative_tolerance: c.relative_tolerance,
            time_constant: c.time_constant,
        }
    }
}

/// (τ_ext, S) for the passivity row: both or neither.
fn passivity_inputs<'a>(
    nq: usize,
    tau_ext: &'a Option<PyReadonlyArrayDyn<'_, f64>>,
    tank_energy: Option<f64>,
) -> crate::Result<Option<(&'a [f64], f64)>> {
    match (tau_ext, tank_energy) {
        (Some(tau), Some(energy)) => Ok(Some((view("tau_ext", tau, &[nq as isize])?, energy))),
        (None, None) => Ok(None),
        _ => Err(SabreError::invalid(
            "passivity",
            "give both tau_ext and tank_energy, or neither",
        )),
    }
}

/// One FILTER-QP call: u (nq,), slack (R,), barrier (R,), the largest slack per class, the
/// active rows, the status and the solver's report.
#[pyclass(name = "FilterResult", module = "sabre._core", frozen)]
pub struct PyFilterResult {
    #[pyo3(get)]
    u: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    slack: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    barrier: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    class_slack: Py<PyDict>,
    #[pyo3(get)]
    active: Vec<String>,
    #[pyo3(get)]
    status: String,
    #[pyo3(get)]
    solver_status: String,
    #[pyo3(get)]
    solve_time: f64,
    #[pyo3(get)]
    iterations: u32,
    #[pyo3(get)]
    qp_rows: usize,
    #[pyo3(get)]
    method: String,
}

fn filter_result(py: Python<'_>, out: FilterOutput, active: Vec<String>) -> PyResult<PyFilterResult> {
    let class_slack = PyDict::new(py);
    for c in ConstraintClass::ALL {
        class_slack.set_item(c.name(), out.class_slack[c.index()])?;
    }
    let (r, nq) = (out.slack.len(), out.u.len());
    Ok(PyFilterResult {
        u: array(py, out.u, &[nq])?.unbind(),
        slack: array(py, out.slack, &[r])?.unbind(),
        barrier: array(py, out.barrier, &[r])?.unbind(),
        class_slack: class_slack.unbind(),
        active,
        status: out.status.name().to_string(),
        solver_status: format!("{:?}", out.solver_status),
        solve_time: out.solve_time,
        iterations: out.iterations,
        qp_rows: out.qp_rows,
        method: out.method.name().to_string(),
    })
}

#[pyclass(name = "SafetyFilter", module = "sabre._core")]
pub struct PySafetyFilter {
    pub(crate) inner: Shared<SafetyFilter>,
    nq: usize,
    nx: usize,
}

#[pymethods]
impl PySafetyFilter {
    #[new]
    fn new(scene: &PyScene, config: &PySafetyConfig) -> PyResult<Self> {
        run(|| {
            let filter = SafetyFilter::new(scene.inner.clone(), config.to_core()?)?;
            Ok(Self {
                inner: Arc::new(Mutex::new(filter)),
                nq: scene.inner.nq(),
                nx: scene.inner.nx(),
            })
        })
    }

    /// Filters u_ref (nq,) at state x (nx,); with tau_ext (nq,) and tank_energy the passivity row is on.
    #[pyo3(signature = (x, u_ref, tau_ext=None, tank_energy=None))]
    fn filter(
        &self,
        py: Python<'_>,
        x: PyReadonlyArrayDyn<'_, f64>,
        u_ref: PyReadonlyArrayDyn<'_, f64>,
        tau_ext: Option<PyReadonlyArrayDyn<'_, f64>>,
        tank_energy: Option<f64>,
    ) -> PyResult<PyFilterResult> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let u_ref = run(|| view("u_ref", &u_ref, &[self.nq as isize]))?;
        let passivity = run(|| passivity_inputs(self.nq, &tau_ext, tank_energy))?;
        let inner = &self.inner;
        // The output and the names are taken under the same lock as the solve.
        let (out, active) = run_detached(py, || {
            let mut f = lock(inner);
            let out = f.filter(x, u_ref, passivity)?.clone();
            let active = out.active.iter().map(|&i| f.constraint_name(i)).collect();
            Ok((out, active))
        })?;
        filter_result(py, out, active)
    }

    /// Sequential FILTER-QP (Algorithm 1) of U (K, nq) from x0 with the rollout model; returns
    /// (filtered U (K, nq), states (K+1, nx), status per step, fallbacks).
    #[allow(clippy::type_complexity)]
    fn filter_sequence<'py>(
        &self,
        py: Python<'py>,
        x0: PyReadonlyArrayDyn<'py, f64>,
        u: PyReadonlyArrayDyn<'py, f64>,
        model: &PyRolloutModel,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Vec<String>, usize)> {
        let x0 = run(|| view("x0", &x0, &[self.nx as isize]))?;
        let u = run(|| view("U", &u, &[-1, self.nq as isize]))?;
        let inner = &self.inner;
        let model = model.inner.clone();
        let out = run_detached(py, move || lock(inner).filter_sequence(&model, x0, u))?;
        Ok((
            array(py, out.u, &[out.k, self.nq])?,
            array(py, out.states, &[out.k + 1, self.nx])?,
            out.status.iter().map(|s| s.name().to_string()).collect(),
            out.fallbacks,
        ))
    }

    fn add_obstacle(&self, center: [f64; 3], radius: f64) -> PyResult<u64> {
        run(|| lock(&self.inner).add_obstacle(center, radius))
    }
    fn move_obstacle(&self, id: u64, center: [f64; 3]) -> PyResult<()> {
        run(|| lock(&self.inner).move_obstacle(id, center))
    }
    fn remove_obstacle(&self, id: u64) -> PyResult<()> {
        run(|| lock(&self.inner).remove_obstacle(id))
    }
    /// (id, centre, radius) of each obstacle present.
    #[getter]
    fn obstacles(&self) -> Vec<(u64, [f64; 3], f64)> {
        lock(&self.inner)
            .obstacles()
            .map(|o| (o.id, [o.center.x, o.center.y, o.center.z], o.radius))
            .collect()
    }
    #[getter]
    fn row_names(&self) -> Vec<String> {
        lock(&self.inner).row_names()
    }
    #[getter]
    fn input_limits(&self) -> Vec<f64> {
        lock(&self.inner).input_limits().to_vec()
    }
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = *lock(&self.inner).stats();
        let d = PyDict::new(py);
        d.set_item("calls", s.calls)?;
        d.set_item("fallbacks", s.fallbacks)?;
        d.set_item("mean_solve_time", s.mean_time())?;
        d.set_item("max_solve_time", s.max_time)?;
        d.set_item("total_iterations", s.total_iterations)?;
        d.set_item("interior_point_calls", s.interior_point_calls)?;
        d.set_item("hard_limit_holds", s.hard_limit_holds)?;
        Ok(d)
    }
    fn reset_stats(&self) {
        lock(&self.inner).reset_stats();
    }
    fn forget_active_set(&self) {
        lock(&self.inner).forget_active_set();
    }

    /// The rows at x: (a (R, nq), b (R,), h (R,)) with a·u ≥ b each row's condition without slack.
    #[pyo3(signature = (x, tau_ext=None, tank_energy=None))]
    #[allow(clippy::type_complexity)]
    fn constraint_rows<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        tau_ext: Option<PyReadonlyArrayDyn<'py, f64>>,
        tank_energy: Option<f64>,
    ) -> PyResult<(
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
    )> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let passivity = run(|| passivity_inputs(self.nq, &tau_ext, tank_energy))?;
        let mut f = lock(&self.inner);
        let (a, b, h) = run(|| {
            f.constraint_rows(x, passivity)
                .map(|(a, b, h)| (a.to_vec(), b.to_vec(), h.to_vec()))
        })?;
        let r = b.len();
        Ok((array(py, a, &[r, self.nq])?, array(py, b, &[r])?, array(py, h, &[r])?))
    }

    /// The full QP as dense arrays: min ½xᵀPx + qᵀx s.t. A x ≤ b, x = [u; δ]; dict P, q, A, b, nu.
    #[pyo3(signature = (x, u_ref, tau_ext=None, tank_energy=None))]
    fn qp_matrices<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        u_ref: PyReadonlyArrayDyn<'py, f64>,
        tau_ext: Option<PyReadonlyArrayDyn<'py, f64>>,
        tank_energy: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let u_ref = run(|| view("u_ref", &u_ref, &[self.nq as isize]))?;
        let passivity = run(|| passivity_inputs(self.nq, &tau_ext, tank_energy))?;
        let qp = run(|| lock(&self.inner).qp_matrices(x, u_ref, passivity))?;
        let d = PyDict::new(py);
        d.set_item("P", array(py, qp.p, &[qp.n, qp.n])?)?;
        d.set_item("q", array(py, qp.q, &[qp.n])?)?;
        d.set_item("A", array(py, qp.a, &[qp.m, qp.n])?)?;
        d.set_item("b", array(py, qp.b, &[qp.m])?)?;
        d.set_item("nu", qp.nu)?;
        Ok(d)
    }
}

#[pyclass(name = "EnergyTank", module = "sabre._core")]
pub struct PyEnergyTank {
    pub(crate) inner: Shared<EnergyTank>,
}

#[pymethods]
impl PyEnergyTank {
    #[new]
    fn new(config: &PyEnergyTankConfig) -> PyResult<Self> {
        run(|| EnergyTank::new(config.initial, config.floor, config.ceiling, config.record_history)).map(|t| Self {
            inner: Arc::new(Mutex::new(t)),
        })
    }
    /// One Euler step of (49), S += dt τ_extᵀu; returns the new energy.
    fn step(&self, tau_ext: PyReadonlyArrayDyn<'_, f64>, u: PyReadonlyArrayDyn<'_, f64>, dt: f64) -> PyResult<f64> {
        let tau = run(|| view("tau_ext", &tau_ext, &[-1]))?;
        let u = run(|| view("u", &u, &[-1]))?;
        run(|| lock(&self.inner).step(tau, u, dt))
    }
    /// Turns the refill on with `config`, or off with None.
    #[pyo3(signature = (config=None))]
    fn set_refill(&self, config: Option<&PyTankRefillConfig>) -> PyResult<()> {
        run(|| lock(&self.inner).set_refill(config.map(RefillConfig::from)))
    }
    /// One refill step from the predicted and measured dissipation (W); returns the energy added.
    fn refill(&self, predicted: f64, measured: f64, dt: f64) -> PyResult<f64> {
        run(|| lock(&self.inner).refill(predicted, measured, dt))
    }
    #[getter]
    fn refilled(&self) -> f64 {
        lock(&self.inner).refilled()
    }
    #[getter]
    fn refill_enabled(&self) -> bool {
        lock(&self.inner).refill_config().is_some()
    }
    fn reset(&self) {
        lock(&self.inner).reset();
    }
    #[getter]
    fn energy(&self) -> f64 {
        lock(&self.inner).energy()
    }
    #[getter]
    fn initial(&self) -> f64 {
        lock(&self.inner).initial()
    }
    #[getter]
    fn floor(&self) -> f64 {
        lock(&self.inner).floor()
    }
    #[getter]
    fn ceiling(&self) -> Option<f64> {
        lock(&self.inner).ceiling()
    }
    #[getter]
    fn residual(&self) -> f64 {
        lock(&self.inner).residual()
    }
    #[getter]
    fn history<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let h = lock(&self.inner).history().to_vec();
        let n = h.len();
        array(py, h, &[n])
    }
}
