//! `_core.ObjectStateEstimator`: the object's coordinate and rate from the hand pose while the hand
//! holds the handle (`crate::control::object_estimate`).

use std::sync::Mutex;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::convert::{isometry, lock, pose_array, view};
use super::error::run;
use super::scene::PyScene;
use crate::control::object_estimate::{ObjectEstimatorConfig, ObjectStateEstimator};

/// One estimate as Python receives it: (position, velocity, hooked, residual).
type EstimateRow = (f64, f64, bool, f64);

/// The object-state estimator of a scene's single-joint object; `update` once per measured
/// joint state. Keyword arguments left out take the core's defaults.
#[pyclass(name = "ObjectStateEstimator", module = "sabre._core", frozen)]
pub struct PyObjectStateEstimator {
    inner: Mutex<ObjectStateEstimator>,
}

impl PyObjectStateEstimator {
    /// A copy of the core estimator, for a Rust loop that takes it over.
    pub(crate) fn inner(&self) -> ObjectStateEstimator {
        lock(&self.inner).clone()
    }
}

#[pymethods]
impl PyObjectStateEstimator {
    /// An estimator at `initial` (None: the lower limit), the hand at the robot frame `hand_frame`,
    /// the handle at `handle_offset` (4, 4) in the object frame `handle_frame`.
    #[new]
    #[pyo3(signature = (
        scene, hand_frame, handle_frame, handle_offset, initial=None, *,
        hook_distance=None, release_distance=None, slide_distance=None, contact_force=None, release_time=None,
        rate_cutoff=None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        scene: &PyScene,
        hand_frame: &str,
        handle_frame: &str,
        handle_offset: PyReadonlyArrayDyn<'_, f64>,
        initial: Option<f64>,
        hook_distance: Option<f64>,
        release_distance: Option<f64>,
        slide_distance: Option<f64>,
        contact_force: Option<f64>,
        release_time: Option<f64>,
        rate_cutoff: Option<f64>,
    ) -> PyResult<Self> {
        let defaults = ObjectEstimatorConfig::default();
        let config = ObjectEstimatorConfig {
            hook_distance: hook_distance.unwrap_or(defaults.hook_distance),
            release_distance: release_distance.unwrap_or(defaults.release_distance),
            slide_distance: slide_distance.unwrap_or(defaults.slide_distance),
            contact_force: contact_force.unwrap_or(defaults.contact_force),
            release_time: release_time.unwrap_or(defaults.release_time),
            rate_cutoff: rate_cutoff.unwrap_or(defaults.rate_cutoff),
        };
        run(|| {
            let offset = isometry("handle_offset", view("handle_offset", &handle_offset, &[4, 4])?)?;
            ObjectStateEstimator::new(scene.inner.clone(), hand_frame, handle_frame, offset, initial, config)
        })
        .map(|inner| Self {
            inner: Mutex::new(inner),
        })
    }

    /// (position, velocity, hooked, residual) at time `t` (s) from the joint positions `q` (nq,)
    /// and the wrist force magnitude `force` (N); the estimate is unchanged when an input is refused.
    #[pyo3(signature = (q, t, force=f64::INFINITY, may_hook=true))]
    fn update(&self, q: PyReadonlyArrayDyn<'_, f64>, t: f64, force: f64, may_hook: bool) -> PyResult<EstimateRow> {
        let mut estimator = lock(&self.inner);
        let nq = estimator.scene().nq() as isize;
        let e = run(|| estimator.update(view("q", &q, &[nq])?, t, force, may_hook))?;
        Ok((e.position, e.velocity, e.hooked, e.residual))
    }

    /// Starts over at `position` (clipped to the limits), not hooked, at rest, with no time seen.
    fn reset_to(&self, position: f64) -> PyResult<()> {
        run(|| lock(&self.inner).reset_to(position))
    }

    /// An independent copy, in the same state.
    fn __copy__(&self) -> Self {
        Self {
            inner: Mutex::new(self.inner()),
        }
    }

    #[getter]
    fn hooked(&self) -> bool {
        lock(&self.inner).hooked()
    }
    #[getter]
    fn position(&self) -> f64 {
        lock(&self.inner).position()
    }
    #[getter]
    fn velocity(&self) -> f64 {
        lock(&self.inner).velocity()
    }
    #[getter]
    fn residual(&self) -> f64 {
        lock(&self.inner).residual()
    }
    /// The hook point (x, y, z) in the handle frame while hooked, else None.
    #[getter]
    fn hook_point(&self) -> Option<[f64; 3]> {
        lock(&self.inner).hook_point().map(|p| [p.x, p.y, p.z])
    }
    #[getter]
    fn hand_frame(&self) -> String {
        lock(&self.inner).hand_frame().to_string()
    }
    #[getter]
    fn handle_frame(&self) -> String {
        lock(&self.inner).handle_frame().to_string()
    }
    #[getter]
    fn handle_offset<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let offset = *lock(&self.inner).handle_offset();
        pose_array(py, &offset)
    }
    #[getter]
    fn hook_distance(&self) -> f64 {
        lock(&self.inner).config().hook_distance
    }
    #[getter]
    fn release_distance(&self) -> f64 {
        lock(&self.inner).config().release_distance
    }
    #[getter]
    fn slide_distance(&self) -> f64 {
        lock(&self.inner).config().slide_distance
    }
    #[getter]
    fn contact_force(&self) -> f64 {
        lock(&self.inner).config().contact_force
    }
    #[getter]
    fn release_time(&self) -> f64 {
        lock(&self.inner).config().release_time
    }
    #[getter]
    fn rate_cutoff(&self) -> f64 {
        lock(&self.inner).config().rate_cutoff
    }

    fn __repr__(&self) -> String {
        let e = lock(&self.inner);
        format!(
            "ObjectStateEstimator(hand_frame={:?}, handle_frame={:?}, position={}, hooked={})",
            e.hand_frame(),
            e.handle_frame(),
            e.position(),
            e.hooked()
        )
    }
}
