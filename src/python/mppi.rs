//! `_core.Planner` and its `MppiConfig`, the likelihood mappings, and the servo guides with their settings and plans.

use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{array, isometry, lock, view};
use super::cost::PyCost;
use super::error::{run, run_detached};
use super::safety::PyLimitBoundConfig;
use super::scene::PyScene;
use super::sim::PyRolloutModel;
use crate::cost::Cost;
use crate::error::SabreError;
use crate::mppi::{IterationStats, LikelihoodMapping, Mppi, MppiConfig, ServoGuideConfig, ServoGuidePlan};

/// Sampler settings (Table I); `MppiConfig()` holds the core's defaults. `sigma=None` is the
/// Table I covariance for the scene's inputs ([`MppiConfig::paper_defaults`]).
#[pyclass(name = "MppiConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyMppiConfig {
    /// Rollouts N per iteration.
    rollouts: usize,
    /// Horizon T (s).
    horizon: f64,
    /// Diagonal of Σ (variances), one per input; None: Table I for the scene.
    sigma: Option<Vec<f64>>,
    /// Sharpness h of the likelihood mapping (55).
    h: f64,
    /// Step size α of the update (14).
    step_size: f64,
    /// Element-wise gradient clip g_max (54).
    gradient_clip: f64,
    /// Share of the previous batch kept and shifted in time.
    keep_fraction: f64,
    /// Savitzky–Golay window (samples) and order; a window of 0 or 1 turns smoothing off.
    smoothing_window: usize,
    smoothing_order: usize,
    /// Noise drawn every `noise_interval` steps and interpolated in between (1: white noise).
    noise_interval: usize,
    seed: u64,
    /// Rollout worker threads (None: all cores).
    threads: Option<usize>,
    /// Symmetric bound on each commanded input; None: the joint velocity limits.
    input_limit: Option<Vec<f64>>,
    /// The cascade's joint-limit bound, held by the plan handed to it (`bounded_nominal`); None: not held.
    limit_bound: Option<PyLimitBoundConfig>,
}

impl PyMppiConfig {
    fn to_core(&self, nu: usize) -> MppiConfig {
        MppiConfig {
            rollouts: self.rollouts,
            horizon: self.horizon,
            sigma: self.sigma.clone().unwrap_or_else(|| MppiConfig::paper_defaults(nu).sigma),
            h: self.h,
            step_size: self.step_size,
            gradient_clip: self.gradient_clip,
            keep_fraction: self.keep_fraction,
            smoothing_window: self.smoothing_window,
            smoothing_order: self.smoothing_order,
            noise_interval: self.noise_interval,
            seed: self.seed,
            threads: self.threads,
            input_limit: self.input_limit.clone(),
            limit_bound: self.limit_bound.as_ref().map(PyLimitBoundConfig::to_core),
        }
    }
}

#[pymethods]
impl PyMppiConfig {
    #[new]
    fn new() -> Self {
        let c = MppiConfig::paper_defaults(0);
        Self {
            rollouts: c.rollouts,
            horizon: c.horizon,
            sigma: None,
            h: c.h,
            step_size: c.step_size,
            gradient_clip: c.gradient_clip,
            keep_fraction: c.keep_fraction,
            smoothing_window: c.smoothing_window,
            smoothing_order: c.smoothing_order,
            noise_interval: c.noise_interval,
            seed: c.seed,
            threads: c.threads,
            input_limit: c.input_limit,
            limit_bound: None,
        }
    }

    /// The Table I covariance diagonal for `nu` inputs (what `sigma=None` stands for).
    #[staticmethod]
    fn paper_sigma(nu: usize) -> Vec<f64> {
        MppiConfig::paper_defaults(nu).sigma
    }
}

/// Settings of the resolved-rate servo guide; `ServoGuideConfig()` holds the core's defaults.
#[pyclass(name = "ServoGuideConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyServoGuideConfig {
    /// Proportional gain on the pose error (1/s).
    gain: f64,
    /// Caps on the commanded Cartesian rate: linear (m/s) and angular (rad/s).
    max_linear: f64,
    max_angular: f64,
    /// Per-joint speed limit (nq), tightened to the URDF limits; None: the URDF limits.
    velocity_limit: Option<Vec<f64>>,
    /// Damping λ of the least-squares inverse.
    damping: f64,
    /// Distance (rad or m) inside each joint limit at which a joint is held.
    joint_margin: f64,
    /// Weigh joints heading toward a limit by how close they are (weighted least norm).
    limit_weighting: bool,
}

impl PyServoGuideConfig {
    fn to_core(&self, nq: usize) -> crate::Result<ServoGuideConfig> {
        if let Some(limit) = &self.velocity_limit {
            if limit.len() != nq {
                return Err(SabreError::shape(
                    "velocity_limit",
                    format!("({nq})"),
                    format!("({})", limit.len()),
                ));
            }
        }
        Ok(ServoGuideConfig {
            gain: self.gain,
            max_linear: self.max_linear,
            max_angular: self.max_angular,
            velocity_limit: self.velocity_limit.clone(),
            damping: self.damping,
            joint_margin: self.joint_margin,
            limit_weighting: self.limit_weighting,
        })
    }
}

#[pymethods]
impl PyServoGuideConfig {
    #[new]
    fn new() -> Self {
        let c = ServoGuideConfig::default();
        Self {
            gain: c.gain,
            max_linear: c.max_linear,
            max_angular: c.max_angular,
            velocity_limit: c.velocity_limit,
            damping: c.damping,
            joint_margin: c.joint_margin,
            limit_weighting: c.limit_weighting,
        }
    }
}

/// Joint velocities (K, nu) servoing `frame` of `scene`'s robot along target poses (K+1, 4, 4)
/// from q0 (nq,): the resolved-rate guide of `sabre.guides.servo_guide` with the gains of `config`.
#[pyfunction]
pub fn servo_guide<'py>(
    py: Python<'py>,
    scene: &PyScene,
    q0: PyReadonlyArrayDyn<'py, f64>,
    targets: PyReadonlyArrayDyn<'py, f64>,
    dt: f64,
    frame: &str,
    config: &PyServoGuideConfig,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let nq = scene.inner.nq();
    let (out, steps) = run(|| {
        let q0 = view("q0", &q0, &[nq as isize])?;
        let targets = view("targets", &targets, &[-1, 4, 4])?;
        let poses = targets
            .chunks(16)
            .map(|m| isometry("targets", m))
            .collect::<crate::Result<Vec<_>>>()?;
        let config = config.to_core(nq)?;
        let out = crate::mppi::servo_guide(&scene.inner, q0, &poses, dt, frame, &config)?;
        Ok((out, poses.len().saturating_sub(1)))
    })?;
    array(py, out, &[steps, nq])
}

/// The servo guides of `sabre.guides.servo_guides`, checked now and integrated where they are used:
/// `sabre.guides.servo_guide_plan`.
#[pyfunction]
pub fn servo_guide_plan<'py>(
    scene: &PyScene,
    q0: PyReadonlyArrayDyn<'py, f64>,
    targets: PyReadonlyArrayDyn<'py, f64>,
    dt: f64,
    frame: &str,
    configs: Vec<PyRef<'py, PyServoGuideConfig>>,
) -> PyResult<PyServoGuidePlan> {
    let nq = scene.inner.nq();
    let q0 = run(|| view("q0", &q0, &[nq as isize]))?;
    let sequences = run(|| {
        let poses = view("targets", &targets, &[-1, -1, 4, 4])?;
        let per_sequence = 16 * targets.shape()[1];
        poses
            .chunks(per_sequence.max(1))
            .map(|sequence| sequence.chunks(16).map(|m| isometry("targets", m)).collect())
            .collect::<crate::Result<Vec<Vec<_>>>>()
    })?;
    let configs = run(|| configs.iter().map(|c| c.to_core(nq)).collect::<crate::Result<Vec<_>>>())?;
    let plan = run(|| ServoGuidePlan::new(scene.inner.clone(), q0, &sequences, dt, frame, &configs))?;
    Ok(PyServoGuidePlan::new(plan, targets.shape()[1].saturating_sub(1)))
}

/// Servo guides checked and ready to integrate: a planner given one (`Planner.set_guide_plan`)
/// has each rollout worker integrate the guide of the row it rolls out.
#[pyclass(name = "ServoGuidePlan", module = "sabre._core", frozen)]
pub struct PyServoGuidePlan {
    pub(crate) inner: Arc<ServoGuidePlan>,
    /// K, also of a plan of no guides.
    steps: usize,
}

impl PyServoGuidePlan {
    pub(crate) fn new(plan: ServoGuidePlan, steps: usize) -> Self {
        Self {
            inner: Arc::new(plan),
            steps,
        }
    }
}

#[pymethods]
impl PyServoGuidePlan {
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// (M, K, nu) of the guides.
    #[getter]
    fn shape(&self) -> (usize, usize, usize) {
        (self.inner.len(), self.steps, self.inner.width())
    }

    /// Every guide, (M, K, nu), integrated here (without the GIL).
    fn evaluate<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let plan = self.inner.clone();
        let out = run_detached(py, move || Ok(plan.evaluate()))?;
        let (m, k, nu) = self.shape();
        array(py, out, &[m, k, nu])
    }

    fn __repr__(&self) -> String {
        let (m, k, nu) = self.shape();
        format!("ServoGuidePlan({m} guides of {k} steps × {nu})")
    }
}

#[pyclass(name = "Planner", module = "sabre._core")]
pub struct PyPlanner {
    inner: Mutex<Mppi>,
    cost: Mutex<Arc<Cost>>,
}

fn stats_dict<'py>(py: Python<'py>, s: &IterationStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("iteration", s.iteration)?;
    d.set_item("iteration_time", s.iteration_time)?;
    d.set_item("rollout_time", s.rollout_time)?;
    d.set_item("engine_steps", s.engine_steps)?;
    d.set_item("engine_time", s.engine_time)?;
    d.set_item("cost_min", s.cost_min)?;
    d.set_item("cost_mean", s.cost_mean)?;
    d.set_item("cost_max", s.cost_max)?;
    d.set_item("nominal_cost", s.nominal_cost)?;
    d.set_item("effective_sample_size", s.effective_sample_size)?;
    d.set_item("failed_rollouts", s.failed_rollouts)?;
    Ok(d)
}

#[pymethods]
impl PyPlanner {
    /// The sampler of the paper (Sec. V) for `model` and `cost`, set up by `config`.
    #[new]
    fn new(model: &PyRolloutModel, cost: &PyCost, config: &PyMppiConfig) -> PyResult<Self> {
        let config = config.to_core(model.inner.scene().nu());
        let planner = run(|| {
            cost.inner.validate(model.inner.scene())?;
            Mppi::new(model.inner.clone(), config)
        })?;
        Ok(Self {
            inner: Mutex::new(planner),
            cost: Mutex::new(cost.inner.clone()),
        })
    }

    #[getter]
    fn noise_scale(&self) -> f64 {
        lock(&self.inner).noise_scale()
    }

    #[setter]
    fn set_noise_scale(&self, scale: f64) -> PyResult<()> {
        let mut planner = lock(&self.inner);
        run(|| planner.set_noise_scale(scale))
    }

    fn set_cost(&self, cost: &PyCost) -> PyResult<()> {
        let planner = lock(&self.inner);
        run(|| cost.inner.validate(planner.model().scene()))?;
        *lock(&self.cost) = cost.inner.clone();
        Ok(())
    }

    fn reset(&self, seed: u64, t0: f64) {
        lock(&self.inner).reset(seed, t0);
    }

    /// One planning iteration (sample, roll out, update) without the GIL; returns its statistics.
    fn iterate<'py>(&self, py: Python<'py>, x: PyReadonlyArrayDyn<'py, f64>, t: f64) -> PyResult<Bound<'py, PyDict>> {
        let cost = lock(&self.cost).clone();
        let inner = &self.inner;
        let x = run(|| view("x", &x, &[-1]))?;
        let stats = run_detached(py, || lock(inner).iterate(x, t, &cost).cloned())?;
        stats_dict(py, &stats)
    }

    /// Builds the batch for time t and returns it, (N, K, nu).
    fn sample<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut planner = lock(&self.inner);
        let (n, k, nu) = (
            planner.config().rollouts,
            planner.horizon_steps(),
            planner.model().scene().nu(),
        );
        let samples = planner.sample(t).to_vec();
        array(py, samples, &[n, k, nu])
    }

    /// Rolls the current batch out from x; returns (costs, states, tau_ext, wrench, contact).
    #[allow(clippy::type_complexity)]
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<(
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<bool>>,
    )> {
        let cost = lock(&self.cost).clone();
        let inner = &self.inner;
        let x = run(|| view("x", &x, &[-1]))?;
        let batch = run_detached(py, || lock(inner).rollout(x, &cost))?;
        let (n, k, nx, nq) = (batch.n, batch.k, batch.nx, batch.nq);
        Ok((
            array(py, batch.costs, &[n])?,
            array(py, batch.states, &[n, k + 1, nx])?,
            array(py, batch.tau_ext, &[n, k, nq])?,
            array(py, batch.wrench, &[n, k, 6])?,
            batch.contact.into_pyarray(py).reshape(vec![n, k])?,
        ))
    }

    /// Weights the current batch by `costs` (N,) and updates the policy.
    fn update<'py>(&self, py: Python<'py>, costs: PyReadonlyArrayDyn<'py, f64>) -> PyResult<Bound<'py, PyDict>> {
        let mut planner = lock(&self.inner);
        let n = planner.config().rollouts as isize;
        let costs = run(|| view("costs", &costs, &[n]))?;
        let stats = run(|| planner.update(costs).map(|_| planner.stats().clone()))?;
        stats_dict(py, &stats)
    }

    /// The commanded input (nu,) at time t, interpolated along the nominal.
    fn reference(&self, t: f64) -> PyResult<Vec<f64>> {
        if !t.is_finite() {
            return Err(SabreError::invalid("t", "must be finite").into());
        }
        let planner = lock(&self.inner);
        let mut out = vec![0.0; planner.model().scene().nu()];
        planner.reference(t, &mut out);
        Ok(out)
    }

    #[getter]
    fn nominal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let planner = lock(&self.inner);
        let (k, nu) = (planner.horizon_steps(), planner.model().scene().nu());
        array(py, planner.nominal().to_vec(), &[k, nu])
    }

    /// The plan to hand the cascade (K, nu): the nominal held to the joint-limit bound along its
    /// kinematics from the state the last batch was rolled out from.
    #[getter]
    fn bounded_nominal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let planner = lock(&self.inner);
        let (k, nu) = (planner.horizon_steps(), planner.model().scene().nu());
        array(py, planner.bounded_nominal(), &[k, nu])
    }

    /// −τ_extᵀu (W) at each step of the nominal's rollout from x (K,), for the tank's refill.
    fn predicted_dissipation<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let inner = &self.inner;
        let x = run(|| view("x", &x, &[-1]))?;
        let dissipation = run_detached(py, || lock(inner).predicted_dissipation(x))?;
        let k = dissipation.len();
        array(py, dissipation, &[k])
    }

    #[getter]
    fn nominal_t0(&self) -> f64 {
        lock(&self.inner).nominal_t0()
    }

    /// Sequences (M, K, nu) placed in the next batch after the nominal and the zero sequence.
    fn set_guides(&self, guides: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        let mut planner = lock(&self.inner);
        let (k, nu) = (planner.horizon_steps() as isize, planner.model().scene().nu() as isize);
        let guides = run(|| view("guides", &guides, &[-1, k, nu]))?;
        run(|| planner.set_guides(guides))
    }

    /// Guides placed in the next batch after those of `set_guides`, as many as it has slots for,
    /// each integrated by the worker that rolls it out.
    fn set_guide_plan(&self, plan: &PyServoGuidePlan) -> PyResult<()> {
        run(|| lock(&self.inner).set_guide_plan(plan.inner.clone()))
    }

    fn set_nominal(&self, nominal: PyReadonlyArrayDyn<'_, f64>, t0: f64) -> PyResult<()> {
        let mut planner = lock(&self.inner);
        let (k, nu) = (planner.horizon_steps() as isize, planner.model().scene().nu() as isize);
        let nominal = run(|| view("nominal", &nominal, &[k, nu]))?;
        run(|| planner.set_nominal(nominal, t0))
    }

    #[getter]
    fn weights(&self) -> Vec<f64> {
        lock(&self.inner).weights().to_vec()
    }

    #[getter]
    fn horizon_steps(&self) -> usize {
        lock(&self.inner).horizon_steps()
    }

    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        stats_dict(py, lock(&self.inner).stats())
    }
}

/// Normalised weights of a cost vector under one likelihood mapping ("naive", "baseline",
/// "invariant" (55)).
#[pyfunction]
pub fn likelihood_weights(costs: Vec<f64>, mapping: &str, parameter: f64) -> PyResult<Vec<f64>> {
    if !(parameter.is_finite() && parameter > 0.0) {
        return Err(SabreError::invalid("parameter", format!("λ or h must be positive and finite, got {parameter}")).into());
    }
    let mapping = match mapping {
        "naive" => LikelihoodMapping::Naive { lambda: parameter },
        "baseline" => LikelihoodMapping::Baseline { lambda: parameter },
        "invariant" => LikelihoodMapping::Invariant { h: parameter },
        other => {
            return Err(SabreError::invalid("mapping", format!("unknown mapping '{other}' (naive, baseline, invariant)")).into())
        }
    };
    let mut out = Vec::new();
    crate::mppi::weights(&costs, mapping, &mut out);
    Ok(out)
}
