//! `_core.HandleGeometry`, `_core.OpenObjectRules` and their `OpenObjectConfig`: the open-object
//! task's per-iteration logic for `sabre.tasks.OpenObject`.

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{array, isometry, pose_array, poses_array, view};
use super::error::{run, run_detached};
use super::mppi::PyServoGuidePlan;
use super::scene::PyScene;
use crate::task::{HandleGeometry, OpenObjectConfig, OpenObjectRules, OpenPhase, ReleaseMove};

/// The Python class of the settings, field for field the core's [`OpenObjectConfig`] (documented there).
macro_rules! open_object_config {
    ($($field:ident: $ty:ty),* $(,)?) => {
        /// Settings of the open-object task's per-iteration logic; `OpenObjectConfig()` holds the
        /// core's defaults.
        #[pyclass(name = "OpenObjectConfig", module = "sabre._core", get_all, set_all)]
        #[derive(Clone)]
        pub struct PyOpenObjectConfig {
            $($field: $ty),*
        }

        impl From<OpenObjectConfig> for PyOpenObjectConfig {
            fn from(c: OpenObjectConfig) -> Self {
                Self { $($field: c.$field),* }
            }
        }

        impl From<&PyOpenObjectConfig> for OpenObjectConfig {
            fn from(c: &PyOpenObjectConfig) -> Self {
                Self { $($field: c.$field.clone()),* }
            }
        }
    };
}

open_object_config!(
    pregrasp_offset: [f64; 3],
    insert_offset: [f64; 3],
    hook_offset: [f64; 3],
    open_offset: [f64; 3],
    pitch: f64,
    fit_clearance: Option<f64>,
    switch_position: f64,
    switch_angle: f64,
    hook_tolerance: f64,
    along_tolerance: f64,
    insert_depth_tolerance: Option<f64>,
    blocked_depth: Option<f64>,
    blocked_speed: f64,
    backout: Option<f64>,
    drag_speed: f64,
    drag_distance: f64,
    stall_depth: Option<f64>,
    open_speeds: Vec<f64>,
    slip_distance: f64,
    slip_lateral: f64,
    hold_speed: f64,
    hold_pull: f64,
    success_fraction: f64,
    release_speed: f64,
    release_distance: f64,
    release_rate: f64,
    probe: f64,
    runaway_speed: f64,
    noise_distance: f64,
    noise_floor: f64,
    noise_open: f64,
    guide_speed: f64,
    fine_speed: f64,
    guide_gain: f64,
);

#[pymethods]
impl PyOpenObjectConfig {
    #[new]
    fn new() -> Self {
        OpenObjectConfig::default().into()
    }
}

/// The handle frame of a scene's object and the robot's control frame (see [`HandleGeometry`]).
#[pyclass(name = "HandleGeometry", module = "sabre._core", frozen)]
pub struct PyHandleGeometry {
    inner: HandleGeometry,
}

impl PyHandleGeometry {
    fn state<'a>(&self, x: &'a PyReadonlyArrayDyn<'_, f64>) -> PyResult<&'a [f64]> {
        let nx = self.inner.scene().nx() as isize;
        let x = run(|| view("x", x, &[nx]))?;
        run(|| self.inner.check_state(x))?;
        Ok(x)
    }
}

#[pymethods]
impl PyHandleGeometry {
    /// The handle frame named by `handle` (an object frame, or a link whose handle frame is inferred
    /// from its collision geometry) and the robot frame `tool_frame`.
    #[new]
    fn new(scene: &PyScene, handle: &str, tool_frame: &str) -> PyResult<Self> {
        let inner = run(|| HandleGeometry::new(scene.inner.clone(), handle, tool_frame))?;
        Ok(Self { inner })
    }

    /// (4, 4) world pose of the handle at object configuration o (no,).
    fn handle_pose<'py>(&self, py: Python<'py>, o: PyReadonlyArrayDyn<'py, f64>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let no = self.inner.scene().no() as isize;
        let o = run(|| view("o", &o, &[no]))?;
        run(|| crate::error::ensure_coordinates("o", o))?;
        pose_array(py, &self.inner.handle_pose(o))
    }

    /// (M, 4, 4) world poses of the handle at M object configurations o (M, no).
    fn handle_poses<'py>(&self, py: Python<'py>, o: PyReadonlyArrayDyn<'py, f64>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let no = self.inner.scene().no();
        let o = run(|| view("o", &o, &[-1, no as isize]))?;
        run(|| crate::error::ensure_coordinates("o", o))?;
        let poses: Vec<_> = o.chunks(no.max(1)).map(|row| self.inner.handle_pose(row)).collect();
        poses_array(py, &poses)
    }

    /// (4, 4) pose in the handle frame of a grasp target at `xyz` (m), pointing `pitch` (rad) below the normal.
    fn grasp_offset<'py>(&self, py: Python<'py>, xyz: [f64; 3], pitch: f64) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let offset = run(|| self.inner.grasp_offset(xyz, pitch))?;
        pose_array(py, &offset)
    }

    /// (distance (m), angle (rad)) of the grasp frame from the target `offset` (4, 4) at state x.
    fn approach_error(&self, x: PyReadonlyArrayDyn<'_, f64>, offset: PyReadonlyArrayDyn<'_, f64>) -> PyResult<(f64, f64)> {
        let offset = run(|| isometry("offset", view("offset", &offset, &[4, 4])?))?;
        Ok(self.inner.at(self.state(&x)?).approach_error(&offset))
    }

    /// (across, along) distance (m) of the grasp frame from the target `offset` at state x.
    fn pocket_error(&self, x: PyReadonlyArrayDyn<'_, f64>, offset: PyReadonlyArrayDyn<'_, f64>) -> PyResult<(f64, f64)> {
        let offset = run(|| isometry("offset", view("offset", &offset, &[4, 4])?))?;
        Ok(self.inner.at(self.state(&x)?).pocket_error(&offset))
    }

    /// Signed distance (m) along the handle's z from the target `offset` at state x.
    fn depth_error(&self, x: PyReadonlyArrayDyn<'_, f64>, offset: PyReadonlyArrayDyn<'_, f64>) -> PyResult<f64> {
        let offset = run(|| isometry("offset", view("offset", &offset, &[4, 4])?))?;
        Ok(self.inner.at(self.state(&x)?).depth_error(&offset))
    }

    /// Sideways position (m) of the grasp frame along the handle's y at state x, from `sideways`.
    fn lateral_error(&self, x: PyReadonlyArrayDyn<'_, f64>, sideways: f64) -> PyResult<f64> {
        Ok(self.inner.at(self.state(&x)?).lateral_error(sideways))
    }

    /// Distance (m) the handle moves per unit of opening at opening o (the object's first joint).
    fn travel(&self, o: f64) -> PyResult<f64> {
        run(|| crate::error::ensure_coordinates("o", &[o]))?;
        let mut at: Vec<f64> = self.inner.scene().object_limits().iter().map(|l| l.lower).collect();
        at[0] = o;
        Ok(self.inner.travel(&at))
    }

    /// Speed (m/s) of the handle in the opening direction at state x.
    fn speed(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<f64> {
        Ok(self.inner.speed(self.state(&x)?))
    }

    /// Distance (m) of the handle at state x from where it is with the object closed.
    fn distance_from_closed(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<f64> {
        Ok(self.inner.distance_from_closed(self.state(&x)?))
    }

    /// (3,) unit direction in which the hand backs off when releasing at state x.
    fn release_direction(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<f64>> {
        Ok(self.inner.release_direction(self.state(&x)?).iter().copied().collect())
    }

    /// (steps + 1, 4, 4) grasp-frame targets that let go of the handle (see the core's `release_path`).
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (x, steps, dt, *, entry_side, entry_depth, hooked_within, speed, distance))]
    fn release_path<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        steps: usize,
        dt: f64,
        entry_side: f64,
        entry_depth: f64,
        hooked_within: f64,
        speed: f64,
        distance: f64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let motion = ReleaseMove {
            entry_side,
            entry_depth,
            hooked_within,
            speed,
            distance,
        };
        let x = self.state(&x)?;
        let path = run(|| self.inner.release_path(x, steps, dt, &motion))?;
        poses_array(py, &path)
    }
}

/// The open-object task's per-iteration logic on one scene (see [`OpenObjectRules`]).
#[pyclass(name = "OpenObjectRules", module = "sabre._core", frozen)]
pub struct PyOpenObjectRules {
    inner: OpenObjectRules,
}

impl PyOpenObjectRules {
    fn state<'a>(&self, x: &'a PyReadonlyArrayDyn<'_, f64>) -> PyResult<&'a [f64]> {
        let nx = self.inner.geometry().scene().nx() as isize;
        run(|| view("x", x, &[nx]))
    }

    fn guides_array<'py>(
        &self,
        py: Python<'py>,
        guides: Vec<f64>,
        count: usize,
        steps: usize,
    ) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        if count == 0 {
            return Ok(None);
        }
        let nu = self.inner.geometry().scene().nu();
        array(py, guides, &[count, steps, nu]).map(Some)
    }
}

#[pymethods]
impl PyOpenObjectRules {
    /// The logic on `geometry`'s scene with `config`, opening to `target_opening` (rad or m), the
    /// opening guides running toward `object_setpoint`.
    #[new]
    fn new(
        geometry: &PyHandleGeometry,
        config: &PyOpenObjectConfig,
        target_opening: f64,
        object_setpoint: f64,
    ) -> PyResult<Self> {
        let inner = run(|| OpenObjectRules::new(geometry.inner.clone(), config.into(), target_opening, object_setpoint))?;
        Ok(Self { inner })
    }

    /// (4, 4) the grasp target of `phase` in the handle frame, as fitted to the handle (release: the
    /// open phase's).
    fn offset<'py>(&self, py: Python<'py>, phase: &str) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let phase = run(|| OpenPhase::from_name(phase))?;
        pose_array(py, self.inner.offset(phase))
    }

    /// The targets fitted to the handle's measured geometry and what was measured (handle frame, m
    /// and rad), or None (the fit is off, or no bar stands at the handle frame).
    fn fit<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, pyo3::types::PyDict>>> {
        let Some(f) = self.inner.fit() else {
            return Ok(None);
        };
        let c = &f.clearance;
        let out = pyo3::types::PyDict::new(py);
        out.set_item("pitch", f.pitch)?;
        out.set_item("pregrasp", f.pregrasp.to_vec())?;
        out.set_item("insert", f.insert.to_vec())?;
        out.set_item("hook", f.hook.to_vec())?;
        out.set_item("open", f.open.to_vec())?;
        out.set_item("tip_behind", f.tip_behind)?;
        out.set_item("gap", f.gap)?;
        out.set_item("need", f.need)?;
        out.set_item("bar_along", c.along.to_vec())?;
        out.set_item("bar_across", c.across.to_vec())?;
        out.set_item("bar_front", c.front)?;
        out.set_item("bar_back", c.back)?;
        out.set_item("widest_gap", c.widest_gap())?;
        Ok(Some(out))
    }

    /// The phase to plan in from state x, coming from `phase`.
    fn next_phase(&self, py: Python<'_>, x: PyReadonlyArrayDyn<'_, f64>, phase: &str) -> PyResult<&'static str> {
        let phase = run(|| OpenPhase::from_name(phase))?;
        let x = self.state(&x)?;
        Ok(run_detached(py, || self.inner.next_phase(x, phase))?.name())
    }

    /// Factor on the sampling covariance in `phase` at state x.
    fn noise_scale(&self, x: PyReadonlyArrayDyn<'_, f64>, phase: &str) -> PyResult<f64> {
        let phase = run(|| OpenPhase::from_name(phase))?;
        let x = self.state(&x)?;
        run(|| self.inner.noise_scale(x, phase))
    }

    /// Guides (M, steps, nu) for `phase` from state x, or None.
    fn guides<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        phase: &str,
        steps: usize,
        dt: f64,
    ) -> PyResult<Option<Bound<'py, PyArrayDyn<f64>>>> {
        let phase = run(|| OpenPhase::from_name(phase))?;
        let x = self.state(&x)?;
        let (guides, count) = run_detached(py, || self.inner.guides(x, phase, steps, dt))?;
        self.guides_array(py, guides, count, steps)
    }

    /// The guides of `guides` as a plan, integrated where they are used.
    fn guide_plan(&self, x: PyReadonlyArrayDyn<'_, f64>, phase: &str, steps: usize, dt: f64) -> PyResult<PyServoGuidePlan> {
        let phase = run(|| OpenPhase::from_name(phase))?;
        let x = self.state(&x)?;
        let plan = run(|| self.inner.guide_plan(x, phase, steps, dt))?;
        Ok(PyServoGuidePlan::new(plan, steps))
    }

    fn success(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<bool> {
        let x = self.state(&x)?;
        run(|| self.inner.success(x))
    }

    fn self_opening(&self, py: Python<'_>, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<bool> {
        let x = self.state(&x)?;
        run_detached(py, || self.inner.self_opening(x))
    }

    fn pulling(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<bool> {
        let x = self.state(&x)?;
        run(|| self.inner.pulling(x))
    }

    fn backed_out(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<bool> {
        let x = self.state(&x)?;
        run(|| self.inner.backed_out(x))
    }

    fn running_ahead(&self, x: PyReadonlyArrayDyn<'_, f64>) -> PyResult<bool> {
        let x = self.state(&x)?;
        run(|| self.inner.running_ahead(x))
    }

    /// (steps + 1, 4, 4) grasp-frame targets of the release from state x.
    fn release_path<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArrayDyn<'py, f64>,
        steps: usize,
        dt: f64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let x = self.state(&x)?;
        let path = run(|| self.inner.release_path(x, steps, dt))?;
        poses_array(py, &path)
    }
}
