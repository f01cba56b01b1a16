//! PyO3 bindings (`sabre._core`): thin wrappers over the core, error mapping, GIL release, no panics across.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use numpy::{IntoPyArray, PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyModule;

use crate::control::{follow_reference, follow_reference_safe, InnerSafety, LowLevelConfig, LowLevelController, TrackTrace};
use crate::cost::{Cost, PoseTarget, Term};
use crate::mppi::{LikelihoodMapping, Mppi, MppiConfig};
use crate::error::SabreError;
use crate::model::scene::Scene;
use crate::safety::{ConstraintClass, EnergyTank, FilterOutput, PerClass, SafetyConfig, SafetyFilter};
use crate::sim::{Plant, PlantConfig, RolloutConfig, RolloutModel};

/// Maps a core error to the matching class of `sabre.errors` (falling back to builtins if the
/// Python package is not importable, e.g. when `_core` is used on its own).
fn to_pyerr(error: SabreError) -> PyErr {
    let class = match &error {
        SabreError::Shape { .. } => "ShapeError",
        SabreError::InvalidValue { .. } => "InvalidValueError",
        SabreError::UnknownAsset { .. } => "UnknownAssetError",
        SabreError::Urdf { .. } => "UrdfError",
        SabreError::UnknownFrame { .. } => "UnknownFrameError",
        SabreError::Simulation(_) => "SimulationError",
    };
    let message = error.to_string();
    Python::attach(|py| {
        let class = py
            .import("sabre.errors")
            .and_then(|m| m.getattr(class))
            .and_then(|c| c.call1((message.clone(),)));
        match class {
            Ok(instance) => PyErr::from_value(instance),
            Err(_) => match error {
                SabreError::Simulation(_) => PyRuntimeError::new_err(message),
                _ => PyValueError::new_err(message),
            },
        }
    })
}

/// Runs `f` without the GIL and turns both errors and panics into Python exceptions.
fn run_detached<T: Send, F: FnOnce() -> crate::Result<T> + Send>(py: Python<'_>, f: F) -> PyResult<T> {
    let outcome = py.detach(|| catch_unwind(AssertUnwindSafe(f)));
    settle(outcome)
}

/// Same as [`run_detached`] for cheap calls that keep the GIL.
fn run<T, F: FnOnce() -> crate::Result<T>>(f: F) -> PyResult<T> {
    settle(catch_unwind(AssertUnwindSafe(f)))
}

fn settle<T>(outcome: std::thread::Result<crate::Result<T>>) -> PyResult<T> {
    match outcome {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(error)) => Err(to_pyerr(error)),
        Err(panic) => {
            let detail = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(to_pyerr(SabreError::Simulation(format!("internal error: {detail}"))))
        }
    }
}

/// A contiguous float64 view of an array with the expected shape (-1 = any size).
fn view<'a>(name: &str, array: &'a PyReadonlyArrayDyn<'_, f64>, shape: &[isize]) -> crate::Result<&'a [f64]> {
    let got = array.shape();
    let matches = got.len() == shape.len() && got.iter().zip(shape).all(|(&g, &e)| e < 0 || g as isize == e);
    if !matches {
        let fmt = |s: Vec<String>| format!("({})", s.join(", "));
        return Err(SabreError::shape(
            name,
            fmt(shape.iter().map(|&e| if e < 0 { "·".into() } else { e.to_string() }).collect()),
            fmt(got.iter().map(|g| g.to_string()).collect()),
        ));
    }
    // rust-numpy also hands out Fortran-ordered memory as a slice; only C order matches our layout.
    if !array.is_c_contiguous() {
        return Err(SabreError::invalid(name, "array must be C-contiguous (use numpy.ascontiguousarray)"));
    }
    array
        .as_slice()
        .map_err(|_| SabreError::invalid(name, "array must be C-contiguous"))
}

fn array<'py>(py: Python<'py>, data: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    PyArray1::from_vec(py, data).reshape(shape.to_vec())
}

#[pyclass(name = "Scene", module = "sabre._core", frozen)]
pub struct PyScene {
    inner: Arc<Scene>,
}

#[pymethods]
impl PyScene {
    #[staticmethod]
    #[pyo3(signature = (robot, obj, obj_pose=None))]
    fn load(robot: &str, obj: &str, obj_pose: Option<Vec<f64>>) -> PyResult<Self> {
        run(|| Scene::load(robot, obj, obj_pose.as_deref())).map(|s| Self { inner: Arc::new(s) })
    }

    #[staticmethod]
    #[pyo3(signature = (robot_path, obj_path, obj_pose=None))]
    fn from_urdf(robot_path: PathBuf, obj_path: PathBuf, obj_pose: Option<Vec<f64>>) -> PyResult<Self> {
        run(|| Scene::from_urdf_files(&robot_path, &obj_path, obj_pose.as_deref())).map(|s| Self { inner: Arc::new(s) })
    }

    #[staticmethod]
    #[pyo3(signature = (robot_urdf, obj_urdf, obj_pose=None))]
    fn from_urdf_strings(robot_urdf: &str, obj_urdf: &str, obj_pose: Option<Vec<f64>>) -> PyResult<Self> {
        run(|| Scene::from_urdf_strings(robot_urdf, obj_urdf, obj_pose.as_deref())).map(|s| Self { inner: Arc::new(s) })
    }

    #[getter]
    fn nq(&self) -> usize {
        self.inner.nq()
    }
    #[getter]
    fn no(&self) -> usize {
        self.inner.no()
    }
    #[getter]
    fn nx(&self) -> usize {
        self.inner.nx()
    }
    #[getter]
    fn nu(&self) -> usize {
        self.inner.nu()
    }
    #[getter]
    fn robot_name(&self) -> String {
        self.inner.robot.name.clone()
    }
    #[getter]
    fn object_name(&self) -> String {
        self.inner.object.name.clone()
    }
    #[getter]
    fn joint_names(&self) -> Vec<String> {
        self.inner.robot.active_joint_names()
    }
    #[getter]
    fn frame_names(&self) -> Vec<String> {
        self.inner.robot.link_names()
    }
    #[getter]
    fn object_joint_names(&self) -> Vec<String> {
        self.inner.object.active_joint_names()
    }
    #[getter]
    fn object_frame_names(&self) -> Vec<String> {
        self.inner.object.link_names()
    }
    /// Robot joint limits as (lower, upper, velocity, effort) arrays of length nq.
    fn robot_limits(&self) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let l = self.inner.robot_limits();
        (
            l.iter().map(|v| v.lower).collect(),
            l.iter().map(|v| v.upper).collect(),
            l.iter().map(|v| v.velocity).collect(),
            l.iter().map(|v| v.effort).collect(),
        )
    }
    /// Object joint limits as (lower, upper) arrays of length no.
    fn object_limits(&self) -> (Vec<f64>, Vec<f64>) {
        let l = self.inner.object_limits();
        (l.iter().map(|v| v.lower).collect(), l.iter().map(|v| v.upper).collect())
    }
    /// Object damping and dry friction per object joint.
    fn object_dynamics(&self) -> (Vec<f64>, Vec<f64>) {
        let o = &self.inner.object;
        (
            o.active_joints.iter().map(|&j| o.joints[j].damping).collect(),
            o.active_joints.iter().map(|&j| o.joints[j].friction).collect(),
        )
    }
    fn object_joint_is_revolute(&self) -> bool {
        self.inner.object_is_revolute()
    }
    /// Object pose in the world as a 4 × 4 matrix.
    fn object_pose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        array(py, self.inner.object_pose.to_homogeneous().transpose().as_slice().to_vec(), &[4, 4])
    }
    fn default_state(&self) -> Vec<f64> {
        self.inner.default_state()
    }
    fn home_configuration(&self) -> Vec<f64> {
        self.inner.home_configuration()
    }
    fn rollout_contact_links(&self) -> Vec<String> {
        self.inner.rollout_contact_links.iter().map(|&l| self.inner.robot.links[l].name.clone()).collect()
    }
    /// Self-collision spheres as (name, link, centre xyz, radius) and the checked pairs (by name).
    fn self_collision(&self) -> (Vec<(String, String, [f64; 3], f64)>, Vec<(String, String)>) {
        let s = &self.inner;
        (
            s.spheres
                .iter()
                .map(|sp| (sp.name.clone(), s.robot.links[sp.link].name.clone(), [sp.center.x, sp.center.y, sp.center.z], sp.radius))
                .collect(),
            s.sphere_pairs.iter().map(|&(a, b)| (s.spheres[a].name.clone(), s.spheres[b].name.clone())).collect(),
        )
    }
    /// (base link, frame, max) of the planar arm-reach limit, if declared.
    fn arm_reach(&self) -> Option<(String, String, f64)> {
        let s = &self.inner;
        s.arm_reach
            .as_ref()
            .map(|a| (s.robot.links[a.base_link].name.clone(), s.robot.links[a.frame_link].name.clone(), a.max))
    }

    fn fk<'py>(&self, py: Python<'py>, q: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq() as isize;
        let pose = run(|| self.inner.fk(view("q", &q, &[nq])?, frame))?;
        array(py, pose.to_homogeneous().transpose().as_slice().to_vec(), &[4, 4])
    }

    /// World poses (M, 4, 4) of a robot frame for M configurations (M, nq).
    fn fk_many<'py>(&self, py: Python<'py>, q: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_many(py, &self.inner.robot, &nalgebra::Isometry3::identity(), "q", &q, frame)
    }

    fn jacobian<'py>(&self, py: Python<'py>, q: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq() as isize;
        let j = run(|| self.inner.jacobian(view("q", &q, &[nq])?, frame))?;
        array(py, j.transpose().as_slice().to_vec(), &[6, self.inner.nq()])
    }

    /// Joint velocities (K, nu) servoing `frame` along target poses (K+1, 4, 4) from q0 (nq,):
    /// the resolved-rate guide of `sabre.guides.servo_guide`.
    #[pyo3(signature = (q0, targets, dt, frame, gain, max_linear, max_angular, velocity_limit, damping, joint_margin))]
    #[allow(clippy::too_many_arguments)]
    fn servo_guide<'py>(
        &self,
        py: Python<'py>,
        q0: PyReadonlyArrayDyn<'py, f64>,
        targets: PyReadonlyArrayDyn<'py, f64>,
        dt: f64,
        frame: &str,
        gain: f64,
        max_linear: f64,
        max_angular: f64,
        velocity_limit: Option<PyReadonlyArrayDyn<'py, f64>>,
        damping: f64,
        joint_margin: f64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let nq = self.inner.nq();
        let (out, steps) = run(|| {
            let q0 = view("q0", &q0, &[nq as isize])?;
            let targets = view("targets", &targets, &[-1, 4, 4])?;
            let poses: Vec<nalgebra::Isometry3<f64>> = targets.chunks(16).map(|m| isometry("targets", m)).collect::<crate::Result<_>>()?;
            let velocity_limit = match &velocity_limit {
                Some(v) => Some(view("velocity_limit", v, &[nq as isize])?.to_vec()),
                None => None,
            };
            let config = crate::mppi::ServoGuideConfig { gain, max_linear, max_angular, velocity_limit, damping, joint_margin };
            let out = crate::mppi::servo_guide(&self.inner, q0, &poses, dt, frame, &config)?;
            Ok((out, poses.len().saturating_sub(1)))
        })?;
        array(py, out, &[steps, nq])
    }

    /// World poses (M, 4, 4) of an object frame for M object configurations (M, no).
    fn object_fk_many<'py>(&self, py: Python<'py>, o: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        poses_many(py, &self.inner.object, &self.inner.object_pose, "o", &o, frame)
    }

    fn object_fk<'py>(&self, py: Python<'py>, o: PyReadonlyArrayDyn<'py, f64>, frame: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let no = self.inner.no() as isize;
        let pose = run(|| self.inner.object_fk(view("o", &o, &[no])?, frame))?;
        array(py, pose.to_homogeneous().transpose().as_slice().to_vec(), &[4, 4])
    }

    /// Joint-space mass matrix (nq × nq) and gravity torque (nq) of the robot at q.
    fn mass_matrix_and_gravity<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let nq = self.inner.nq();
        let (m, g) = run(|| {
            let q = view("q", &q, &[nq as isize])?;
            crate::error::ensure_finite("q", q)?;
            let mut ws = crate::model::dynamics::DynamicsWorkspace::default();
            let mut m = nalgebra::DMatrix::zeros(nq, nq);
            let mut g = nalgebra::DVector::zeros(nq);
            crate::model::dynamics::joint_space_terms(
                &self.inner.robot,
                &nalgebra::Isometry3::identity(),
                q,
                &nalgebra::Vector3::new(0.0, 0.0, -9.81),
                &mut ws,
                &mut m,
                &mut g,
            );
            Ok((m, g))
        })?;
        Ok((array(py, m.transpose().as_slice().to_vec(), &[nq, nq])?, array(py, g.as_slice().to_vec(), &[nq])?))
    }
}

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
    inner: Arc<RolloutModel>,
}

#[pymethods]
impl PyRolloutModel {
    #[new]
    #[pyo3(signature = (scene, dt=0.015, servo_bandwidth=40.0, servo_integral_gain=400.0, servo_integral_limit=0.1, contact_friction=0.2, solver_iterations=1, multibody_robot=false, skip_quiescent_steps=true))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        scene: &PyScene,
        dt: f64,
        servo_bandwidth: f64,
        servo_integral_gain: f64,
        servo_integral_limit: f64,
        contact_friction: f64,
        solver_iterations: usize,
        multibody_robot: bool,
        skip_quiescent_steps: bool,
    ) -> PyResult<Self> {
        let config = RolloutConfig {
            skip_quiescent_steps,
            dt,
            servo_bandwidth,
            servo_integral_gain,
            servo_integral_limit,
            multibody_robot,
            contact_friction,
            solver_iterations,
        };
        run(|| RolloutModel::new(scene.inner.clone(), config)).map(|m| Self { inner: Arc::new(m) })
    }

    #[getter]
    fn dt(&self) -> f64 {
        self.inner.dt()
    }

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

#[pyclass(name = "Plant", module = "sabre._core")]
pub struct PyPlant {
    inner: Mutex<Plant>,
}

impl PyPlant {
    fn with<T>(&self, f: impl FnOnce(&mut Plant) -> crate::Result<T>) -> PyResult<T> {
        let mut plant = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        run(|| f(&mut plant))
    }
}

#[pymethods]
impl PyPlant {
    #[new]
    #[pyo3(signature = (scene, dt=0.001, contact_friction=0.2, solver_iterations=4, tau_ext_cutoff=Some(crate::sim::DEFAULT_TAU_EXT_CUTOFF)))]
    fn new(scene: &PyScene, dt: f64, contact_friction: f64, solver_iterations: usize, tau_ext_cutoff: Option<f64>) -> PyResult<Self> {
        let config = PlantConfig {
            dt,
            contact_friction,
            solver_iterations,
            tau_ext_cutoff,
        };
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
        run_detached(py, || plant.lock().unwrap_or_else(|e| e.into_inner()).step(&tau))
    }

    /// Runs `steps` plant steps, each with torques from the low-level controller tracking `u_ref`.
    fn track(&self, py: Python<'_>, controller: &PyLowLevelController, u_ref: PyReadonlyArrayDyn<'_, f64>, steps: usize) -> PyResult<()> {
        let u_ref = self.with(|p| Ok(view("u_ref", &u_ref, &[p.scene().nq() as isize])?.to_vec()))?;
        let plant = &self.inner;
        let controller = &controller.inner;
        run_detached(py, || {
            let mut plant = plant.lock().unwrap_or_else(|e| e.into_inner());
            let mut controller = controller.lock().unwrap_or_else(|e| e.into_inner());
            for _ in 0..steps {
                let tau = controller.torque(plant.state(), &u_ref)?;
                plant.step(&tau)?;
            }
            Ok(())
        })
    }

    /// Follows a reference sequence (K, nq) starting at t0 with steps dt for `steps` plant steps under
    /// the low-level controller; returns the trace of every `record_every`-th step as
    /// (time, state, reference, wrench, tau_ext, contact).
    #[pyo3(signature = (controller, reference, t0, dt, steps, record_every=1))]
    #[allow(clippy::too_many_arguments, clippy::type_complexity)]
    fn follow<'py>(
        &self,
        py: Python<'py>,
        controller: &PyLowLevelController,
        reference: PyReadonlyArrayDyn<'py, f64>,
        t0: f64,
        dt: f64,
        steps: usize,
        record_every: usize,
    ) -> PyResult<(
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<f64>>,
        Bound<'py, PyArrayDyn<bool>>,
    )> {
        let (nx, nq) = self.with(|p| Ok((p.scene().nx(), p.scene().nq())))?;
        let reference = run(|| view("reference", &reference, &[-1, nq as isize]))?;
        let plant = &self.inner;
        let controller = &controller.inner;
        let trace = run_detached(py, || {
            let mut plant = plant.lock().unwrap_or_else(|e| e.into_inner());
            let mut controller = controller.lock().unwrap_or_else(|e| e.into_inner());
            let mut trace = TrackTrace::default();
            follow_reference(&mut plant, &mut controller, reference, t0, dt, steps, record_every, &mut trace)?;
            Ok(trace)
        })?;
        let m = trace.time.len();
        Ok((
            array(py, trace.time, &[m])?,
            array(py, trace.state, &[m, nx])?,
            array(py, trace.reference, &[m, nq])?,
            array(py, trace.wrench, &[m, 6])?,
            array(py, trace.tau_ext, &[m, nq])?,
            trace.contact.into_pyarray(py).reshape(vec![m])?,
        ))
    }

    /// [`Self::follow`] with the optional inner safety stage (filter, tank, or both); returns the
    /// trace as a dict: time, state, reference, wrench, tau_ext, contact, and with a filter
    /// filtered (M, nq) and filter_status (list of str), with a tank tank_energy (M,).
    #[pyo3(signature = (controller, reference, t0, dt, steps, record_every=1, safety=None, tank=None))]
    #[allow(clippy::too_many_arguments)]
    fn follow_safe<'py>(
        &self,
        py: Python<'py>,
        controller: &PyLowLevelController,
        reference: PyReadonlyArrayDyn<'py, f64>,
        t0: f64,
        dt: f64,
        steps: usize,
        record_every: usize,
        safety: Option<&PySafetyFilter>,
        tank: Option<&PyEnergyTank>,
    ) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let (nx, nq) = self.with(|p| Ok((p.scene().nx(), p.scene().nq())))?;
        let reference = run(|| view("reference", &reference, &[-1, nq as isize]))?;
        let plant = &self.inner;
        let controller = &controller.inner;
        let (has_filter, has_tank) = (safety.is_some(), tank.is_some());
        let trace = run_detached(py, || {
            let mut plant = plant.lock().unwrap_or_else(|e| e.into_inner());
            let mut controller = controller.lock().unwrap_or_else(|e| e.into_inner());
            let mut filter = safety.map(|f| f.inner.lock().unwrap_or_else(|e| e.into_inner()));
            let mut tank = tank.map(|t| t.inner.lock().unwrap_or_else(|e| e.into_inner()));
            let stage = InnerSafety {
                filter: filter.as_deref_mut(),
                tank: tank.as_deref_mut(),
            };
            let mut trace = TrackTrace::default();
            follow_reference_safe(&mut plant, &mut controller, reference, t0, dt, steps, record_every, &mut trace, Some(stage))?;
            Ok(trace)
        })?;
        let m = trace.time.len();
        let d = pyo3::types::PyDict::new(py);
        d.set_item("time", array(py, trace.time, &[m])?)?;
        d.set_item("state", array(py, trace.state, &[m, nx])?)?;
        d.set_item("reference", array(py, trace.reference, &[m, nq])?)?;
        d.set_item("wrench", array(py, trace.wrench, &[m, 6])?)?;
        d.set_item("tau_ext", array(py, trace.tau_ext, &[m, nq])?)?;
        d.set_item("tau_ext_measured", array(py, trace.tau_ext_measured, &[m, nq])?)?;
        d.set_item("contact", trace.contact.into_pyarray(py).reshape(vec![m])?)?;
        if has_filter {
            d.set_item("filtered", array(py, trace.filtered, &[m, nq])?)?;
            d.set_item("filter_status", trace.filter_status.iter().map(|s| s.name()).collect::<Vec<_>>())?;
        }
        if has_tank {
            d.set_item("tank_energy", array(py, trace.tank_energy, &[m])?)?;
        }
        Ok(d)
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
    fn contacts(&self) -> PyResult<Vec<(String, String, [f64; 3], [f64; 3])>> {
        self.with(|p| {
            let scene = p.scene();
            Ok(p
                .contacts()
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
}

#[pyclass(name = "LowLevelController", module = "sabre._core")]
pub struct PyLowLevelController {
    inner: Mutex<LowLevelController>,
}

#[pymethods]
impl PyLowLevelController {
    #[new]
    #[pyo3(signature = (scene, dt=0.001, bandwidth=40.0, integral_gain=400.0, integral_limit=0.1, gain_inertia_floor=0.0))]
    fn new(scene: &PyScene, dt: f64, bandwidth: f64, integral_gain: f64, integral_limit: f64, gain_inertia_floor: f64) -> PyResult<Self> {
        let config = LowLevelConfig {
            bandwidth,
            integral_gain,
            integral_limit,
            gain_inertia_floor,
        };
        run(|| LowLevelController::new(scene.inner.clone(), dt, config)).map(|c| Self { inner: Mutex::new(c) })
    }

    fn reset(&self) {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).reset();
    }

    #[getter]
    fn gain_inertia_floor(&self) -> f64 {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).config().gain_inertia_floor
    }

    #[setter]
    fn set_gain_inertia_floor(&self, floor: f64) -> PyResult<()> {
        let mut c = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        run(|| c.set_gain_inertia_floor(floor))
    }

    fn torque(&self, x: PyReadonlyArrayDyn<'_, f64>, u_ref: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<f64>> {
        let mut c = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        run(|| c.torque(view("x", &x, &[-1])?, view("u_ref", &u_ref, &[-1])?))
    }
}

fn per_class<T: Copy>(name: &str, values: Vec<T>) -> crate::Result<PerClass<T>> {
    let n = ConstraintClass::COUNT;
    <[T; ConstraintClass::COUNT]>::try_from(values)
        .map(PerClass)
        .map_err(|v| SabreError::shape(name, format!("({n},)"), format!("({},)", v.len())))
}

/// (τ_ext, S) for the passivity row: both or neither.
fn passivity_inputs<'a>(nq: usize, tau_ext: &'a Option<PyReadonlyArrayDyn<'_, f64>>, tank_energy: Option<f64>) -> crate::Result<Option<(&'a [f64], f64)>> {
    match (tau_ext, tank_energy) {
        (Some(tau), Some(energy)) => Ok(Some((view("tau_ext", tau, &[nq as isize])?, energy))),
        (None, None) => Ok(None),
        _ => Err(SabreError::invalid("passivity", "give both tau_ext and tank_energy, or neither")),
    }
}

#[pyclass(name = "FilterResult", module = "sabre._core", frozen)]
pub struct PyFilterResult {
    #[pyo3(get)]
    u: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    slack: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    barrier: Py<PyArrayDyn<f64>>,
    #[pyo3(get)]
    class_slack: Py<pyo3::types::PyDict>,
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
    let class_slack = pyo3::types::PyDict::new(py);
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
    inner: Mutex<SafetyFilter>,
    nq: usize,
    nx: usize,
}

impl PySafetyFilter {
    fn lock(&self) -> std::sync::MutexGuard<'_, SafetyFilter> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl PySafetyFilter {
    /// Per-class lists follow ConstraintClass order: joint_limits, self_collision, arm_reach,
    /// base_box, obstacles, passivity (gamma's passivity entry is α).
    #[new]
    #[pyo3(signature = (scene, gamma, penalty, margin, enabled, base_box, tank_floor, max_obstacles, max_iterations, tolerance, screening))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        scene: &PyScene,
        gamma: Vec<f64>,
        penalty: Vec<f64>,
        margin: Vec<f64>,
        enabled: Vec<bool>,
        base_box: [f64; 4],
        tank_floor: f64,
        max_obstacles: usize,
        max_iterations: u32,
        tolerance: f64,
        screening: bool,
    ) -> PyResult<Self> {
        run(|| {
            let config = SafetyConfig {
                gamma: per_class("gamma", gamma)?,
                penalty: per_class("penalty", penalty)?,
                margin: per_class("margin", margin)?,
                enabled: per_class("enabled", enabled)?,
                base_box,
                tank_floor,
                max_obstacles,
                max_iterations,
                tolerance,
                screening,
                ..SafetyConfig::default()
            };
            let filter = SafetyFilter::new(scene.inner.clone(), config)?;
            Ok(Self { inner: Mutex::new(filter), nq: scene.inner.nq(), nx: scene.inner.nx() })
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
            let mut f = inner.lock().unwrap_or_else(|e| e.into_inner());
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
        let out = run_detached(py, move || inner.lock().unwrap_or_else(|e| e.into_inner()).filter_sequence(&model, x0, u))?;
        Ok((
            array(py, out.u, &[out.k, self.nq])?,
            array(py, out.states, &[out.k + 1, self.nx])?,
            out.status.iter().map(|s| s.name().to_string()).collect(),
            out.fallbacks,
        ))
    }

    fn add_obstacle(&self, center: [f64; 3], radius: f64) -> PyResult<u64> {
        run(|| self.lock().add_obstacle(center, radius))
    }
    fn move_obstacle(&self, id: u64, center: [f64; 3]) -> PyResult<()> {
        run(|| self.lock().move_obstacle(id, center))
    }
    fn remove_obstacle(&self, id: u64) -> PyResult<()> {
        run(|| self.lock().remove_obstacle(id))
    }
    /// (id, centre, radius) of each obstacle present.
    #[getter]
    fn obstacles(&self) -> Vec<(u64, [f64; 3], f64)> {
        self.lock().obstacles().map(|o| (o.id, [o.center.x, o.center.y, o.center.z], o.radius)).collect()
    }
    #[getter]
    fn row_names(&self) -> Vec<String> {
        self.lock().row_names()
    }
    #[getter]
    fn input_limits(&self) -> Vec<f64> {
        self.lock().input_limits().to_vec()
    }
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let s = *self.lock().stats();
        let d = pyo3::types::PyDict::new(py);
        d.set_item("calls", s.calls)?;
        d.set_item("fallbacks", s.fallbacks)?;
        d.set_item("mean_solve_time", s.mean_time())?;
        d.set_item("max_solve_time", s.max_time)?;
        d.set_item("total_iterations", s.total_iterations)?;
        d.set_item("interior_point_calls", s.interior_point_calls)?;
        Ok(d)
    }
    fn reset_stats(&self) {
        self.lock().reset_stats();
    }
    fn forget_active_set(&self) {
        self.lock().forget_active_set();
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
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>)> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let passivity = run(|| passivity_inputs(self.nq, &tau_ext, tank_energy))?;
        let mut f = self.lock();
        let (a, b, h) = run(|| f.constraint_rows(x, passivity).map(|(a, b, h)| (a.to_vec(), b.to_vec(), h.to_vec())))?;
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
    ) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let x = run(|| view("x", &x, &[self.nx as isize]))?;
        let u_ref = run(|| view("u_ref", &u_ref, &[self.nq as isize]))?;
        let passivity = run(|| passivity_inputs(self.nq, &tau_ext, tank_energy))?;
        let qp = run(|| self.lock().qp_matrices(x, u_ref, passivity))?;
        let d = pyo3::types::PyDict::new(py);
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
    inner: Mutex<EnergyTank>,
}

impl PyEnergyTank {
    fn lock(&self) -> std::sync::MutexGuard<'_, EnergyTank> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl PyEnergyTank {
    #[new]
    #[pyo3(signature = (initial=10.0, floor=2.0, ceiling=None, record_history=true))]
    fn new(initial: f64, floor: f64, ceiling: Option<f64>, record_history: bool) -> PyResult<Self> {
        run(|| EnergyTank::new(initial, floor, ceiling, record_history)).map(|t| Self { inner: Mutex::new(t) })
    }
    /// One Euler step S += dt τ_extᵀu; returns the new energy.
    fn step(&self, tau_ext: PyReadonlyArrayDyn<'_, f64>, u: PyReadonlyArrayDyn<'_, f64>, dt: f64) -> PyResult<f64> {
        let tau = run(|| view("tau_ext", &tau_ext, &[-1]))?;
        let u = run(|| view("u", &u, &[-1]))?;
        run(|| self.lock().step(tau, u, dt))
    }
    fn reset(&self) {
        self.lock().reset();
    }
    #[getter]
    fn energy(&self) -> f64 {
        self.lock().energy()
    }
    #[getter]
    fn initial(&self) -> f64 {
        self.lock().initial()
    }
    #[getter]
    fn floor(&self) -> f64 {
        self.lock().floor()
    }
    #[getter]
    fn ceiling(&self) -> Option<f64> {
        self.lock().ceiling()
    }
    #[getter]
    fn residual(&self) -> f64 {
        self.lock().residual()
    }
    #[getter]
    fn history<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let h = self.lock().history().to_vec();
        let n = h.len();
        array(py, h, &[n])
    }
}

/// World poses (M, 4, 4) of one frame of `tree` (root at `root`) for M configurations (M, n).
fn poses_many<'py>(
    py: Python<'py>,
    tree: &crate::model::KinematicTree,
    root: &nalgebra::Isometry3<f64>,
    name: &str,
    values: &PyReadonlyArrayDyn<'py, f64>,
    frame: &str,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let n = tree.nq();
    let m = values.shape().first().copied().unwrap_or(0);
    let poses = run(|| {
        let values = view(name, values, &[-1, n as isize])?;
        crate::error::ensure_finite(name, values)?;
        let link = tree.require_link(frame)?;
        let mut frames = crate::model::kinematics::Frames::default();
        let mut out = Vec::with_capacity(m * 16);
        for i in 0..m {
            tree.update_frames(root, &values[i * n..(i + 1) * n], &mut frames);
            out.extend_from_slice(frames.poses[link].to_homogeneous().transpose().as_slice());
        }
        Ok(out)
    })?;
    array(py, poses, &[m, 4, 4])
}

fn isometry(name: &str, m: &[f64]) -> crate::Result<nalgebra::Isometry3<f64>> {
    if m.len() != 16 {
        return Err(SabreError::shape(name, "(4, 4)", format!("{} elements", m.len())));
    }
    crate::error::ensure_finite(name, m)?;
    let mat = nalgebra::Matrix4::from_row_slice(m);
    let rot = nalgebra::Matrix3::from(mat.fixed_view::<3, 3>(0, 0));
    if (rot.transpose() * rot - nalgebra::Matrix3::identity()).norm() > 1e-6 || (rot.determinant() - 1.0).abs() > 1e-6 {
        return Err(SabreError::invalid(name, "rotation block is not a rotation matrix"));
    }
    let rotation = nalgebra::UnitQuaternion::from_matrix(&rot);
    Ok(nalgebra::Isometry3::from_parts(nalgebra::Translation3::new(m[3], m[7], m[11]), rotation))
}

fn spec_error(detail: impl Into<String>) -> SabreError {
    SabreError::invalid("cost term", detail)
}

fn floats(spec: &Bound<'_, PyAny>, key: &str) -> crate::Result<Vec<f64>> {
    spec.get_item(key)
        .and_then(|v| v.extract::<Vec<f64>>())
        .map_err(|e| spec_error(format!("'{key}': {e}")))
}

fn float(spec: &Bound<'_, PyAny>, key: &str) -> crate::Result<f64> {
    let v = spec.get_item(key).and_then(|v| v.extract::<f64>()).map_err(|e| spec_error(format!("'{key}': {e}")))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(spec_error(format!("'{key}' must be finite, got {v}")))
    }
}

fn text(spec: &Bound<'_, PyAny>, key: &str) -> crate::Result<String> {
    spec.get_item(key).and_then(|v| v.extract::<String>()).map_err(|e| spec_error(format!("'{key}': {e}")))
}

/// Turns one term specification (a dict made by `sabre.costs`) into a core term.
fn term_from_spec(scene: &Scene, spec: &Bound<'_, PyAny>) -> crate::Result<Term> {
    let kind = text(spec, "kind")?;
    Ok(match kind.as_str() {
        "pose" => {
            let link = scene.robot.require_link(&text(spec, "frame")?)?;
            let w = floats(spec, "weights")?;
            if w.len() != 6 {
                return Err(spec_error("pose weights need 6 entries (linear, then angular)"));
            }
            let pose = isometry("pose target", &floats(spec, "target")?)?;
            let target = match spec.get_item("object_frame").ok().and_then(|v| v.extract::<Option<String>>().ok()).flatten() {
                Some(name) => {
                    let lead = spec.get_item("lead").ok().and_then(|v| v.extract::<f64>().ok()).unwrap_or(0.0);
                    let lead_limit = spec.get_item("lead_limit").ok().and_then(|v| v.extract::<f64>().ok()).unwrap_or(f64::INFINITY);
                    if !lead.is_finite() || lead_limit.is_nan() {
                        return Err(spec_error("pose lead must be finite and lead_limit a number"));
                    }
                    PoseTarget::ObjectLink { link: scene.object.require_link(&name)?, offset: pose, lead, lead_limit }
                }
                None => PoseTarget::World(pose),
            };
            Term::TargetPose { link, target, weights: [w[0], w[1], w[2], w[3], w[4], w[5]] }
        }
        "contact" => Term::Contact { weight: float(spec, "weight")? },
        "joint_limits" => Term::JointLimits {
            weight: float(spec, "weight")?,
            weight_slope: float(spec, "weight_slope")?,
            lower: floats(spec, "lower")?,
            upper: floats(spec, "upper")?,
        },
        "arm_reach" => Term::ArmReach {
            base_link: scene.robot.require_link(&text(spec, "base")?)?,
            frame_link: scene.robot.require_link(&text(spec, "frame")?)?,
            r_max: float(spec, "r_max")?,
            weight: float(spec, "weight")?,
            weight_slope: float(spec, "weight_slope")?,
        },
        "self_collision" => Term::SelfCollision {
            pairs: scene.sphere_pairs.clone(),
            weight: float(spec, "weight")?,
            weight_slope: float(spec, "weight_slope")?,
        },
        "posture" => Term::Posture { target: floats(spec, "target")?, weights: floats(spec, "weights")? },
        "object" => Term::ObjectState { target: floats(spec, "target")?, weights: floats(spec, "weights")? },
        "power" => Term::Power { weight: float(spec, "weight")?, p_max: float(spec, "p_max")? },
        "base_box" => {
            let (lo, hi) = (floats(spec, "lower")?, floats(spec, "upper")?);
            if lo.len() != 2 || hi.len() != 2 {
                return Err(spec_error("base box bounds need 2 entries (x, y)"));
            }
            Term::BaseBox { lower: [lo[0], lo[1]], upper: [hi[0], hi[1]], weight: float(spec, "weight")?, weight_slope: float(spec, "weight_slope")? }
        }
        "obstacles" => {
            let centers = floats(spec, "centers")?;
            let radii = floats(spec, "radii")?;
            if centers.len() != 3 * radii.len() {
                return Err(spec_error("obstacles need 3 centre coordinates per radius"));
            }
            Term::Obstacles {
                spheres: radii.iter().enumerate().map(|(i, &r)| (nalgebra::Point3::new(centers[3 * i], centers[3 * i + 1], centers[3 * i + 2]), r)).collect(),
                weight: float(spec, "weight")?,
                weight_slope: float(spec, "weight_slope")?,
            }
        }
        "base_clearance" => {
            let base_link = scene.robot.require_link(&text(spec, "link")?)?;
            let footprint = spec.get_item("footprint").ok().and_then(|v| v.extract::<Option<[f64; 3]>>().ok()).flatten().map(|f| (f[0], f[1], f[2]));
            crate::cost::base_clearance(scene, base_link, footprint, float(spec, "margin")?, float(spec, "spacing")?, float(spec, "weight")?, float(spec, "weight_slope")?)?
        }
        other => return Err(spec_error(format!("unknown kind '{other}'"))),
    })
}

#[pyclass(name = "Cost", module = "sabre._core", frozen)]
pub struct PyCost {
    inner: Arc<Cost>,
}

#[pymethods]
impl PyCost {
    /// A cost compiled from term specifications (dicts with a "kind" key, made by `sabre.costs`).
    #[new]
    fn new(scene: &PyScene, terms: Vec<Bound<'_, PyAny>>) -> PyResult<Self> {
        run(|| {
            let terms = terms.iter().map(|t| term_from_spec(&scene.inner, t)).collect::<crate::Result<Vec<_>>>()?;
            let cost = Cost::new(terms);
            cost.validate(&scene.inner)?;
            Ok(Self { inner: Arc::new(cost) })
        })
    }

    #[getter]
    fn num_terms(&self) -> usize {
        self.inner.terms.len()
    }
}

#[pyclass(name = "Planner", module = "sabre._core")]
pub struct PyPlanner {
    inner: Mutex<Mppi>,
    cost: Mutex<Arc<Cost>>,
}

fn stats_dict<'py>(py: Python<'py>, s: &crate::mppi::IterationStats) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let d = pyo3::types::PyDict::new(py);
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
    #[new]
    #[pyo3(signature = (model, cost, rollouts, horizon, sigma, h, step_size, gradient_clip, keep_fraction, smoothing_window, smoothing_order, seed, threads=None, noise_interval=1, input_limit=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        model: &PyRolloutModel,
        cost: &PyCost,
        rollouts: usize,
        horizon: f64,
        sigma: Vec<f64>,
        h: f64,
        step_size: f64,
        gradient_clip: f64,
        keep_fraction: f64,
        smoothing_window: usize,
        smoothing_order: usize,
        seed: u64,
        threads: Option<usize>,
        noise_interval: usize,
        input_limit: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        let config = MppiConfig {
            noise_interval,
            input_limit,
            rollouts,
            horizon,
            sigma,
            h,
            step_size,
            gradient_clip,
            keep_fraction,
            smoothing_window,
            smoothing_order,
            seed,
            threads,
        };
        run(|| {
            cost.inner.validate(model.inner.scene())?;
            Mppi::new(model.inner.clone(), config)
        })
        .map(|m| Self { inner: Mutex::new(m), cost: Mutex::new(cost.inner.clone()) })
    }

    #[getter]
    fn noise_scale(&self) -> f64 {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).noise_scale()
    }

    #[setter]
    fn set_noise_scale(&self, scale: f64) -> PyResult<()> {
        let mut planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        run(|| planner.set_noise_scale(scale))
    }

    fn set_cost(&self, cost: &PyCost) -> PyResult<()> {
        let planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        run(|| cost.inner.validate(planner.model().scene()))?;
        *self.cost.lock().unwrap_or_else(|e| e.into_inner()) = cost.inner.clone();
        Ok(())
    }

    fn reset(&self, seed: u64, t0: f64) {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).reset(seed, t0);
    }

    /// One planning iteration (sample, roll out, update) without the GIL; returns its statistics.
    fn iterate<'py>(&self, py: Python<'py>, x: PyReadonlyArrayDyn<'py, f64>, t: f64) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let cost = self.cost.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let inner = &self.inner;
        let x = run(|| view("x", &x, &[-1]))?;
        let stats = run_detached(py, || {
            let mut planner = inner.lock().unwrap_or_else(|e| e.into_inner());
            planner.iterate(x, t, &cost).cloned()
        })?;
        stats_dict(py, &stats)
    }

    /// Builds the batch for time t and returns it, (N, K, nu).
    fn sample<'py>(&self, py: Python<'py>, t: f64) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (n, k, nu) = (planner.config().rollouts, planner.horizon_steps(), planner.model().scene().nu());
        let samples = planner.sample(t).to_vec();
        array(py, samples, &[n, k, nu])
    }

    /// Rolls the current batch out from x; returns (costs, states, tau_ext, wrench, contact).
    #[allow(clippy::type_complexity)]
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<(Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<bool>>)> {
        let cost = self.cost.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let inner = &self.inner;
        let x = run(|| view("x", &x, &[-1]))?;
        let batch = run_detached(py, || inner.lock().unwrap_or_else(|e| e.into_inner()).rollout(x, &cost))?;
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
    fn update<'py>(&self, py: Python<'py>, costs: PyReadonlyArrayDyn<'py, f64>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let mut planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let n = planner.config().rollouts as isize;
        let costs = run(|| view("costs", &costs, &[n]))?;
        let stats = run(|| planner.update(costs).map(|_| planner.stats().clone()))?;
        stats_dict(py, &stats)
    }

    fn reference(&self, t: f64) -> PyResult<Vec<f64>> {
        if !t.is_finite() {
            return Err(to_pyerr(SabreError::invalid("t", "must be finite")));
        }
        let planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let mut out = vec![0.0; planner.model().scene().nu()];
        planner.reference(t, &mut out);
        Ok(out)
    }

    #[getter]
    fn nominal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (k, nu) = (planner.horizon_steps(), planner.model().scene().nu());
        array(py, planner.nominal().to_vec(), &[k, nu])
    }

    #[getter]
    fn nominal_t0(&self) -> f64 {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).nominal_t0()
    }

    /// Sequences (M, K, nu) placed in the next batch after the nominal and the zero sequence.
    fn set_guides(&self, guides: PyReadonlyArrayDyn<'_, f64>) -> PyResult<()> {
        let mut planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (k, nu) = (planner.horizon_steps() as isize, planner.model().scene().nu() as isize);
        let guides = run(|| view("guides", &guides, &[-1, k, nu]))?;
        run(|| planner.set_guides(guides))
    }

    fn set_nominal(&self, nominal: PyReadonlyArrayDyn<'_, f64>, t0: f64) -> PyResult<()> {
        let mut planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (k, nu) = (planner.horizon_steps() as isize, planner.model().scene().nu() as isize);
        let nominal = run(|| view("nominal", &nominal, &[k, nu]))?;
        run(|| planner.set_nominal(nominal, t0))
    }

    #[getter]
    fn weights(&self) -> Vec<f64> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).weights().to_vec()
    }

    #[getter]
    fn horizon_steps(&self) -> usize {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).horizon_steps()
    }

    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let planner = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        stats_dict(py, planner.stats())
    }
}

/// Normalised weights of a cost vector under one likelihood mapping ("naive", "baseline", "invariant").
#[pyfunction]
fn likelihood_weights(costs: Vec<f64>, mapping: &str, parameter: f64) -> PyResult<Vec<f64>> {
    let mapping = match mapping {
        "naive" => LikelihoodMapping::Naive { lambda: parameter },
        "baseline" => LikelihoodMapping::Baseline { lambda: parameter },
        "invariant" => LikelihoodMapping::Invariant { h: parameter },
        other => return Err(to_pyerr(SabreError::invalid("mapping", format!("unknown mapping '{other}' (naive, baseline, invariant)")))),
    };
    let mut out = Vec::new();
    crate::mppi::weights(&costs, mapping, &mut out);
    Ok(out)
}

/// Number of worker threads used when `threads=None`.
#[pyfunction]
fn default_threads() -> usize {
    crate::sim::default_threads()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyScene>()?;
    m.add_class::<PyRolloutModel>()?;
    m.add_class::<PyRolloutResult>()?;
    m.add_class::<PyPlant>()?;
    m.add_class::<PyLowLevelController>()?;
    m.add_class::<PyCost>()?;
    m.add_class::<PyPlanner>()?;
    m.add_class::<PySafetyFilter>()?;
    m.add_class::<PyFilterResult>()?;
    m.add_class::<PyEnergyTank>()?;
    m.add_function(wrap_pyfunction!(default_threads, m)?)?;
    m.add_function(wrap_pyfunction!(likelihood_weights, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DEFAULT_TAU_EXT_CUTOFF", crate::sim::DEFAULT_TAU_EXT_CUTOFF)?;
    Ok(())
}
