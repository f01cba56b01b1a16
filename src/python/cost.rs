//! `_core.Cost`: the cost terms of Sec. V-E, converted from the specifications `sabre.costs` builds
//! (dicts with a "kind" key and the term's fields).

use std::sync::Arc;

use nalgebra::Point3;
use pyo3::exceptions::{PyKeyError, PyValueError};
use pyo3::prelude::*;

use super::convert::isometry;
use super::error::run;
use super::scene::PyScene;
use crate::cost::{Cost, PoseTarget, Term};
use crate::error::SabreError;
use crate::model::scene::Scene;

/// A float that must be finite.
struct Finite(f64);

impl<'a, 'py> FromPyObject<'a, 'py> for Finite {
    type Error = PyErr;

    fn extract(obj: Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        let value: f64 = obj.extract()?;
        if value.is_finite() {
            Ok(Finite(value))
        } else {
            Err(PyValueError::new_err(format!("must be finite, got {value}")))
        }
    }
}

/// (28): a robot frame's pose against a world pose, or against an object frame (`object_frame`)
/// run ahead by `lead` along the object joint, at most to `lead_limit`.
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct PoseSpec {
    frame: String,
    /// Row-major 4 × 4 matrix.
    target: Vec<f64>,
    object_frame: Option<String>,
    /// Linear, then angular.
    weights: [f64; 6],
    #[pyo3(default = Finite(0.0))]
    lead: Finite,
    #[pyo3(default = f64::INFINITY)]
    lead_limit: f64,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct WeightSpec {
    weight: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct BarrierSpec {
    weight: Finite,
    weight_slope: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct JointLimitsSpec {
    weight: Finite,
    weight_slope: Finite,
    lower: Vec<f64>,
    upper: Vec<f64>,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct ArmReachSpec {
    base: String,
    frame: String,
    r_max: Finite,
    weight: Finite,
    weight_slope: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct TargetSpec {
    target: Vec<f64>,
    weights: Vec<f64>,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct PowerSpec {
    weight: Finite,
    p_max: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct BaseBoxSpec {
    /// (x, y) bounds.
    lower: [f64; 2],
    upper: [f64; 2],
    weight: Finite,
    weight_slope: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct ObstaclesSpec {
    /// 3 centre coordinates per radius.
    centers: Vec<f64>,
    radii: Vec<f64>,
    weight: Finite,
    weight_slope: Finite,
}

#[derive(FromPyObject)]
#[pyo3(from_item_all)]
struct BaseClearanceSpec {
    link: String,
    /// (radius, bottom, top) of the base's footprint cylinder; None: from its collision spheres.
    footprint: Option<[f64; 3]>,
    margin: Finite,
    spacing: Finite,
    weight: Finite,
    weight_slope: Finite,
}

fn spec_error(detail: impl Into<String>) -> SabreError {
    SabreError::invalid("cost term", detail)
}

/// What went wrong extracting a spec: the missing key, or the field and the reason.
fn describe(py: Python<'_>, error: &PyErr) -> String {
    if error.is_instance_of::<PyKeyError>(py) {
        return format!("missing key {}", error.value(py));
    }
    match error.cause(py) {
        Some(cause) => format!("{} ({})", error.value(py), cause.value(py)),
        None => error.value(py).to_string(),
    }
}

/// The fields of a `kind` term as `T`, or an `InvalidValueError` naming the field and the reason.
fn fields<'a, 'py, T: FromPyObject<'a, 'py, Error = PyErr>>(spec: &'a Bound<'py, PyAny>, kind: &str) -> crate::Result<T> {
    spec.extract::<T>()
        .map_err(|error| spec_error(format!("'{kind}': {}", describe(spec.py(), &error))))
}

/// Turns one term specification (a dict made by `sabre.costs`) into a core term.
fn term_from_spec(scene: &Scene, spec: &Bound<'_, PyAny>) -> crate::Result<Term> {
    let kind: String = spec
        .get_item("kind")
        .and_then(|v| v.extract())
        .map_err(|e| spec_error(format!("kind: {}", describe(spec.py(), &e))))?;
    Ok(match kind.as_str() {
        "pose" => {
            let s: PoseSpec = fields(spec, &kind)?;
            if s.lead_limit.is_nan() {
                return Err(spec_error("pose lead must be finite and lead_limit a number"));
            }
            let pose = isometry("pose target", &s.target)?;
            let target = match s.object_frame {
                Some(name) => PoseTarget::ObjectLink {
                    link: scene.object.require_link(&name)?,
                    offset: pose,
                    lead: s.lead.0,
                    lead_limit: s.lead_limit,
                },
                None => PoseTarget::World(pose),
            };
            Term::TargetPose {
                link: scene.robot.require_link(&s.frame)?,
                target,
                weights: s.weights,
            }
        }
        "contact" => Term::Contact {
            weight: fields::<WeightSpec>(spec, &kind)?.weight.0,
        },
        "joint_limits" => {
            let s: JointLimitsSpec = fields(spec, &kind)?;
            Term::JointLimits {
                weight: s.weight.0,
                weight_slope: s.weight_slope.0,
                lower: s.lower,
                upper: s.upper,
            }
        }
        "arm_reach" => {
            let s: ArmReachSpec = fields(spec, &kind)?;
            Term::ArmReach {
                base_link: scene.robot.require_link(&s.base)?,
                frame_link: scene.robot.require_link(&s.frame)?,
                r_max: s.r_max.0,
                weight: s.weight.0,
                weight_slope: s.weight_slope.0,
            }
        }
        "self_collision" => {
            let s: BarrierSpec = fields(spec, &kind)?;
            Term::SelfCollision {
                pairs: scene.sphere_pairs.clone(),
                weight: s.weight.0,
                weight_slope: s.weight_slope.0,
            }
        }
        "posture" => {
            let s: TargetSpec = fields(spec, &kind)?;
            Term::Posture {
                target: s.target,
                weights: s.weights,
            }
        }
        "object" => {
            let s: TargetSpec = fields(spec, &kind)?;
            Term::ObjectState {
                target: s.target,
                weights: s.weights,
            }
        }
        "power" => {
            let s: PowerSpec = fields(spec, &kind)?;
            Term::Power {
                weight: s.weight.0,
                p_max: s.p_max.0,
            }
        }
        "base_box" => {
            let s: BaseBoxSpec = fields(spec, &kind)?;
            if scene.roles.base.is_none() {
                return Err(spec_error(
                    "BaseBox needs a robot with a holonomic base; this robot's base is fixed (it has no base coordinates)",
                ));
            }
            Term::BaseBox {
                lower: s.lower,
                upper: s.upper,
                weight: s.weight.0,
                weight_slope: s.weight_slope.0,
            }
        }
        "obstacles" => {
            let s: ObstaclesSpec = fields(spec, &kind)?;
            if s.centers.len() != 3 * s.radii.len() {
                return Err(spec_error("obstacles need 3 centre coordinates per radius"));
            }
            Term::Obstacles {
                spheres: s
                    .centers
                    .chunks_exact(3)
                    .zip(&s.radii)
                    .map(|(c, &r)| (Point3::new(c[0], c[1], c[2]), r))
                    .collect(),
                weight: s.weight.0,
                weight_slope: s.weight_slope.0,
            }
        }
        "base_clearance" => {
            let s: BaseClearanceSpec = fields(spec, &kind)?;
            let base_link = scene.robot.require_link(&s.link)?;
            let footprint = s.footprint.map(|f| (f[0], f[1], f[2]));
            crate::cost::base_clearance(
                scene,
                base_link,
                footprint,
                s.margin.0,
                s.spacing.0,
                s.weight.0,
                s.weight_slope.0,
            )?
        }
        other => return Err(spec_error(format!("unknown kind '{other}'"))),
    })
}

#[pyclass(name = "Cost", module = "sabre._core", frozen)]
pub struct PyCost {
    pub(crate) inner: Arc<Cost>,
}

#[pymethods]
impl PyCost {
    /// A cost compiled from term specifications (dicts with a "kind" key, made by `sabre.costs`).
    #[new]
    fn new(scene: &PyScene, terms: Vec<Bound<'_, PyAny>>) -> PyResult<Self> {
        run(|| {
            let terms = terms
                .iter()
                .map(|t| term_from_spec(&scene.inner, t))
                .collect::<crate::Result<Vec<_>>>()?;
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
