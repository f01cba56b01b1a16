//! `_core.ArticulationEstimator` and `_core.ArticulationConfig`: the articulation of an object without a
//! model, estimated from the hand's path (`crate::control::articulation`).

use std::sync::Mutex;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{array, isometry, lock, view};
use super::error::run;
use crate::control::articulation::{ArticulationConfig, ArticulationEstimate, ArticulationEstimator, ArticulationKind};
use nalgebra::Point3;

/// Settings of the articulation estimator; `ArticulationConfig()` holds the core's defaults.
#[pyclass(name = "ArticulationConfig", module = "sabre._core", get_all, set_all)]
#[derive(Clone)]
pub struct PyArticulationConfig {
    position_noise: f64,
    noise_floor: f64,
    bin_length: f64,
    max_bins: usize,
    axis_std: f64,
    gravity_aligned: bool,
    aligned_within: f64,
    aligned_std: f64,
    radius: (f64, f64),
    min_path: f64,
    decide: f64,
    rate_cutoff: f64,
    rehook_time: f64,
}

impl From<ArticulationConfig> for PyArticulationConfig {
    fn from(c: ArticulationConfig) -> Self {
        Self {
            position_noise: c.position_noise,
            noise_floor: c.noise_floor,
            bin_length: c.bin_length,
            max_bins: c.max_bins,
            axis_std: c.axis_std,
            gravity_aligned: c.gravity_aligned,
            aligned_within: c.aligned_within,
            aligned_std: c.aligned_std,
            radius: c.radius,
            min_path: c.min_path,
            decide: c.decide,
            rate_cutoff: c.rate_cutoff,
            rehook_time: c.rehook_time,
        }
    }
}

impl From<&PyArticulationConfig> for ArticulationConfig {
    fn from(c: &PyArticulationConfig) -> Self {
        Self {
            position_noise: c.position_noise,
            noise_floor: c.noise_floor,
            bin_length: c.bin_length,
            max_bins: c.max_bins,
            axis_std: c.axis_std,
            gravity_aligned: c.gravity_aligned,
            aligned_within: c.aligned_within,
            aligned_std: c.aligned_std,
            radius: c.radius,
            min_path: c.min_path,
            decide: c.decide,
            rate_cutoff: c.rate_cutoff,
            rehook_time: c.rehook_time,
        }
    }
}

#[pymethods]
impl PyArticulationConfig {
    #[new]
    fn new() -> Self {
        ArticulationConfig::default().into()
    }
}

fn kind_name(kind: Option<ArticulationKind>) -> Option<&'static str> {
    kind.map(|k| match k {
        ArticulationKind::Revolute => "revolute",
        ArticulationKind::Prismatic => "prismatic",
    })
}

fn estimate_dict<'py>(py: Python<'py>, e: &ArticulationEstimate) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("kind", kind_name(e.kind))?;
    d.set_item("geometry", kind_name(Some(e.geometry_kind())))?;
    d.set_item("p_revolute", e.p_revolute)?;
    d.set_item("axis", [e.axis.x, e.axis.y, e.axis.z])?;
    d.set_item("point", [e.point.x, e.point.y, e.point.z])?;
    d.set_item("radius", e.radius)?;
    d.set_item("axis_std", e.axis_std)?;
    d.set_item("point_std", e.point_std)?;
    d.set_item("radius_std", e.radius_std)?;
    d.set_item("opening", e.opening)?;
    d.set_item("rate", e.rate)?;
    d.set_item("path_length", e.path_length)?;
    d.set_item("samples", e.samples)?;
    d.set_item("hooked", e.hooked)?;
    Ok(d)
}

/// The estimator of one handle's articulation; `update` once per measured hand position.
#[pyclass(name = "ArticulationEstimator", module = "sabre._core", frozen)]
pub struct PyArticulationEstimator {
    inner: Mutex<ArticulationEstimator>,
}

#[pymethods]
impl PyArticulationEstimator {
    /// An estimator for the handle frame `handle` (4, 4) in the world, a door with prior probability
    /// `p_revolute`.
    #[new]
    #[pyo3(signature = (handle, p_revolute=0.5, config=None))]
    fn new(handle: PyReadonlyArrayDyn<'_, f64>, p_revolute: f64, config: Option<&PyArticulationConfig>) -> PyResult<Self> {
        let config = config.map_or_else(ArticulationConfig::default, ArticulationConfig::from);
        run(|| {
            let handle = isometry("handle", view("handle", &handle, &[4, 4])?)?;
            ArticulationEstimator::new(handle, p_revolute, config)
        })
        .map(|inner| Self {
            inner: Mutex::new(inner),
        })
    }

    /// Takes the hand positions `hand` (T, 3) measured at the times `t` (T,), each hooked or not
    /// (`hooked` (T,): the opening follows the hand) and recorded or not (`record` (T,): the hook
    /// pulls, its path is the handle's); returns the estimate after the last. A refused row leaves the
    /// estimate as the rows before it made it.
    fn update<'py>(
        &self,
        py: Python<'py>,
        t: PyReadonlyArrayDyn<'py, f64>,
        hand: PyReadonlyArrayDyn<'py, f64>,
        hooked: Vec<bool>,
        record: Vec<bool>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let n = hooked.len();
        let mut est = lock(&self.inner);
        let e = run(|| {
            let t = view("t", &t, &[n as isize])?;
            let hand = view("hand", &hand, &[n as isize, 3])?;
            if record.len() != n {
                return Err(crate::SabreError::shape(
                    "record",
                    format!("({n},)"),
                    format!("({},)", record.len()),
                ));
            }
            for (i, (h, r)) in hooked.iter().zip(&record).enumerate() {
                est.update(t[i], Point3::new(hand[3 * i], hand[3 * i + 1], hand[3 * i + 2]), *h, *r)?;
            }
            Ok(*est.estimate())
        })?;
        estimate_dict(py, &e)
    }

    fn estimate<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        estimate_dict(py, lock(&self.inner).estimate())
    }

    /// (M, 5) the binned path the fits see: position (3), weight 1/σ² (1/m²), stretch.
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let points = lock(&self.inner).points();
        let data = points
            .iter()
            .flat_map(|q| [q.p.x, q.p.y, q.p.z, q.w, q.segment as f64])
            .collect();
        array(py, data, &[points.len(), 5])
    }

    /// The opening the hand at `hand` (3,) puts along the current estimate.
    fn opening_at(&self, hand: [f64; 3]) -> f64 {
        lock(&self.inner).opening_at(Point3::from(hand))
    }

    /// Sets where the hand holds the handle with the object closed (world (3,)): the opening's zero.
    fn set_reference(&self, reference: [f64; 3]) -> PyResult<()> {
        run(|| lock(&self.inner).set_reference(Point3::from(reference)))
    }

    #[getter]
    fn reference(&self) -> [f64; 3] {
        lock(&self.inner).reference().coords.into()
    }

    fn reset(&self) {
        lock(&self.inner).reset();
    }

    #[getter]
    fn config(&self) -> PyArticulationConfig {
        (*lock(&self.inner).config()).into()
    }
}
