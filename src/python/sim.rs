//! `_core.RolloutModel` (batched rollouts of the reduced-order model (57)) and `_core.Plant` (the
//! full-dynamics stand-in for the robot), with their config objects.

use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::convert::{array, lock, view};
use super::error::{run, run_detached};
use super::scene::PyScene;
use crate::sim::{ContactModel, Plant, PlantConfig, RolloutConfig, RolloutModel};

/// Settings of the rollout model; `RolloutConfig()` holds the core's defaults.
#[pyclass(name = "RolloutConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyRolloutConfig {
    /// Step of the rollout model (s).
    dt: f64,
    /// Closed-loop bandwidth Λ (1/s) of the joint velocity servo (57).
    servo_bandwidth: f64,
    /// Integral gain Λ_I (1/s²) of the servo and the bound on its accumulated error.
    servo_integral_gain: f64,
    servo_integral_limit: f64,
    /// Coulomb friction coefficient of robot–object contacts.
    contact_friction: f64,
    /// Solver iterations per step (Rapier's substeps, or the reduced solve's sweeps).
    solver_iterations: usize,
    /// Simulate the servo with Rapier's multibody solver instead of the joint-space servo.
    multibody_robot: bool,
    /// Skip the physics step while the object is statically held and out of reach.
    skip_quiescent_steps: bool,
    /// "reduced" (contacts solved in sabre) or "rapier" (Rapier's pipeline, the reference).
    contact_model: String,
    /// Per robot joint, the largest acceleration its command path gives (None: the effort's alone).
    command_acceleration: Option<Vec<f64>>,
}

impl From<RolloutConfig> for PyRolloutConfig {
    fn from(c: RolloutConfig) -> Self {
        Self {
            dt: c.dt,
            servo_bandwidth: c.servo_bandwidth,
            servo_integral_gain: c.servo_integral_gain,
            servo_integral_limit: c.servo_integral_limit,
            contact_friction: c.contact_friction,
            solver_iterations: c.solver_iterations,
            multibody_robot: c.multibody_robot,
            skip_quiescent_steps: c.skip_quiescent_steps,
            contact_model: c.contact_model.name().to_string(),
            command_acceleration: c.command_acceleration,
        }
    }
}

impl TryFrom<&PyRolloutConfig> for RolloutConfig {
    type Error = crate::SabreError;

    fn try_from(c: &PyRolloutConfig) -> crate::Result<Self> {
        let contact_model = ContactModel::from_name(&c.contact_model)?;
        Ok(Self {
            dt: c.dt,
            servo_bandwidth: c.servo_bandwidth,
            servo_integral_gain: c.servo_integral_gain,
            servo_integral_limit: c.servo_integral_limit,
            contact_friction: c.contact_friction,
            solver_iterations: c.solver_iterations,
            multibody_robot: c.multibody_robot,
            skip_quiescent_steps: c.skip_quiescent_steps,
            contact_model,
            command_acceleration: c.command_acceleration.clone(),
        })
    }
}

#[pymethods]
impl PyRolloutConfig {
    #[new]
    fn new() -> Self {
        RolloutConfig::default().into()
    }
}

/// Settings of the plant; `PlantConfig()` holds the core's defaults.
#[pyclass(name = "PlantConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyPlantConfig {
    /// Plant step (s).
    dt: f64,
    /// Coulomb friction coefficient of robot–object contacts.
    contact_friction: f64,
    /// Rapier solver iterations per step.
    solver_iterations: usize,
    /// Bandwidth (Hz) of the external-torque measurement; None: the raw per-step torques.
    tau_ext_cutoff: Option<f64>,
}

impl From<PlantConfig> for PyPlantConfig {
    fn from(c: PlantConfig) -> Self {
        Self {
            dt: c.dt,
            contact_friction: c.contact_friction,
            solver_iterations: c.solver_iterations,
            tau_ext_cutoff: c.tau_ext_cutoff,
        }
    }
}

impl From<&PyPlantConfig> for PlantConfig {
    fn from(c: &PyPlantConfig) -> Self {
        Self {
            dt: c.dt,
            contact_friction: c.contact_friction,
            solver_iterations: c.solver_iterations,
            tau_ext_cutoff: c.tau_ext_cutoff,
        }
    }
}

#[pymethods]
impl PyPlantConfig {
    #[new]
    fn new() -> Self {
        PlantConfig::default().into()
    }
}

/// N rollouts of K steps: states (N, K+1, nx), tau_ext (N, K, nq), wrench (N, K, 6), contact
/// (N, K), failed (N,), engine_steps (N,), engine_time (N,).
#[pyclass(name = "RolloutResult", module = "sabre._core", frozen)]
pub struct PyRolloutResult {
    #[pyo3(get)]
    states: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    tau_ext: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    wrench: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    contact: Py<PyArrayDyn<bool>>,
    #[pyo3(get)]
    failed: Py<PyArrayDyn<bool>>,
    #[pyo3(get)]
    engine_steps: Py<PyArrayDyn<u64>>,
    #[pyo3(get)]
    engine_time: Py<PyArrayDyn<f64>>,
}

#[pyclass(name = "RolloutModel", module = "sabre._core", frozen)]
pub struct PyRolloutModel {
    pub(crate) inner: Arc<RolloutModel>,
}

#[pymethods]
impl PyRolloutModel {
    #[new]
    fn new(scene: &PyScene, config: &PyRolloutConfig) -> PyResult<Self> {
        run(|| RolloutModel::new(scene.inner.clone(), RolloutConfig::try_from(config)?)).map(|m| Self { inner: Arc::new(m) })
    }

    #[getter]
    fn dt(&self) -> f64 {
        self.inner.dt()
    }

    /// Rolls N input sequences U (N, K, nu) out from x0 (nx,) without the GIL.
    #[pyo3(signature = (x0, u, threads=None))]
    fn rollout<'py>(
        &self,
        py: Python<'py>,
        x0: PyReadonlyArrayDyn<'py, f64>,
        u: PyReadonlyArrayDyn<'py, f64>,
        threads: Option<usize>,
    ) -> PyResult<PyRolloutResult> {
        let scene = self.inner.scene();
        let (nx, nq) = (scene.nx() as isize, scene.nq() as isize);
        let x0 = run(|| view("x0", &x0, &[nx]))?;
        let u_shape = u.shape().to_vec();
        let u = run(|| view("U", &u, &[-1, -1, nq]))?;
        let (n, k) = (u_shape[0], u_shape[1]);
        let model = self.inner.clone();
        let batch = run_detached(py, move || model.rollout(x0, u, n, k, threads))?;
        let (nx, nq) = (batch.nx, batch.nq);
        Ok(PyRolloutResult {
            states: array(py, batch.states, &[n, k + 1, nx])?.unbind(),
            tau_ext: array(py, batch.tau_ext, &[n, k, nq])?.unbind(),
            wrench: array(py, batch.wrench, &[n, k, 6])?.unbind(),
            contact: batch.contact.into_pyarray(py).reshape(vec![n, k])?.unbind(),
            failed: batch.failed.into_pyarray(py).reshape(vec![n])?.unbind(),
            engine_steps: batch.engine_steps.into_pyarray(py).reshape(vec![n])?.unbind(),
            engine_time: array(py, batch.engine_time, &[n])?.unbind(),
        })
    }
}

/// A contact point: (robot link, object link, point (3,), force on the robot (3,)).
type ContactRow = (String, String, [f64; 3], [f64; 3]);

#[pyclass(name = "Plant", module = "sabre._core")]
pub struct PyPlant {
    pub(crate) inner: Mutex<Plant>,
}

impl PyPlant {
    pub(crate) fn with<T>(&self, f: impl FnOnce(&mut Plant) -> crate::Result<T>) -> PyResult<T> {
        let mut plant = lock(&self.inner);
        run(|| f(&mut plant))
    }
}

#[pymethods]
impl PyPlant {
    #[new]
    fn new(scene: &PyScene, config: &PyPlantConfig) -> PyResult<Self> {
        let config = PlantConfig::from(config);
        run(|| Plant::new(scene.inner.clone(), config)).map(|p| Self { inner: Mutex::new(p) })
    }

    fn reset(&self, x0: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        self.with(|p| {
            let nx = p.scene().nx() as isize;
            p.reset(view("x0", &x0, &[nx])?)
        })
    }

    fn step(&self, py: Python<'_>, tau: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        let tau = self.with(|p| Ok(view("tau", &tau, &[p.scene().nq() as isize])?.to_vec()))?;
        let plant = &self.inner;
        run_detached(py, || lock(plant).step(&tau))
    }

    #[getter]
    fn state(&self) -> PyResult<Vec<f64>> {
        self.with(|p| Ok(p.state().to_vec()))
    }
    #[getter]
    fn wrench(&self) -> PyResult<Vec<f64>> {
        self.with(|p| Ok(p.interaction().wrench.to_vec()))
    }
    #[getter]
    fn tau_ext(&self) -> PyResult<Vec<f64>> {
        self.with(|p| Ok(p.interaction().tau_ext.clone()))
    }
    #[getter]
    fn measured_tau_ext(&self) -> PyResult<Vec<f64>> {
        self.with(|p| Ok(p.measured_tau_ext().to_vec()))
    }
    #[getter]
    fn contact(&self) -> PyResult<bool> {
        self.with(|p| Ok(p.interaction().contact))
    }
    /// Contact points of the last step: (robot link, object link, point (3,), force on the robot (3,)).
    fn contacts(&self) -> PyResult<Vec<ContactRow>> {
        self.with(|p| {
            let scene = p.scene();
            Ok(p.contacts()
                .into_iter()
                .map(|c| {
                    (
                        scene.robot.links[c.robot_link].name.clone(),
                        scene.object.links[c.object_link].name.clone(),
                        c.point,
                        c.force,
                    )
                })
                .collect())
        })
    }
    #[getter]
    fn applied_torque(&self) -> PyResult<Vec<f64>> {
        self.with(|p| Ok(p.applied_torque().to_vec()))
    }
    #[getter]
    fn time(&self) -> PyResult<f64> {
        self.with(|p| Ok(p.time()))
    }
    #[getter]
    fn dt(&self) -> PyResult<f64> {
        self.with(|p| Ok(p.dt()))
    }
    #[getter]
    fn object_held(&self) -> PyResult<bool> {
        self.with(|p| Ok(p.object_held()))
    }
    fn hold_object(&self, flag: bool) -> PyResult<()> {
        self.with(|p| {
            p.hold_object(flag);
            Ok(())
        })
    }
    fn object_energy(&self) -> PyResult<f64> {
        self.with(|p| Ok(p.object_energy()))
    }
    fn push(&self, dv: Vec<f64>) -> PyResult<()> {
        self.with(|p| p.push(&dv))
    }
}
