//! Cost terms of the sampling-based controller (paper Sec. IV-A, eqs. 29–36), evaluated per rollout step.

use nalgebra::{Isometry3, Matrix3, Point3, Vector6};

use crate::error::{Result, SabreError};
use crate::model::scene::Scene;
use crate::sim::StepEvaluator;

mod clearance;

pub use crate::sim::StepView;
pub use clearance::{link_footprint, moving_object_point_count, moving_object_points, ClearancePoints, MAX_CLEARANCE_POINTS};

/// SE(3) logarithm: the twist ξ = (v, ω) (linear first) with exp(ξ) = T.
pub fn se3_log(t: &Isometry3<f64>) -> Vector6<f64> {
    let omega = t.rotation.scaled_axis();
    let theta = omega.norm();
    let p = t.translation.vector;
    let w = omega.cross_matrix();
    // V⁻¹ = I − ½[ω]× + (1/θ²)(1 − θ sinθ / (2(1 − cosθ)))[ω]×², with its series near θ = 0.
    let coefficient = if theta < 1e-6 {
        1.0 / 12.0 + theta * theta / 720.0
    } else {
        (1.0 - theta * theta.sin() / (2.0 * (1.0 - theta.cos()))) / (theta * theta)
    };
    let v_inv = Matrix3::identity() - 0.5 * w + coefficient * w * w;
    let v = v_inv * p;
    Vector6::new(v.x, v.y, v.z, omega.x, omega.y, omega.z)
}

thread_local! {
    /// Scratch for object poses at a leading configuration (cost evaluation runs on rollout workers).
    static LEAD_POSES: std::cell::RefCell<(Vec<f64>, Vec<Isometry3<f64>>)> = const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
}

/// Where a pose target lives.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseTarget {
    /// A fixed world pose.
    World(Isometry3<f64>),
    /// A pose rigidly attached to an object link (e.g. `handle_frame`), following the object as it
    /// moves. With a non-zero `lead` the link is taken at the object configuration `lead` ahead of
    /// the current one (each joint, capped at `lead_limit` unless already past it): a target that
    /// runs ahead along the articulation's path and so tells the sampler which way to pull.
    ObjectLink {
        link: usize,
        offset: Isometry3<f64>,
        lead: f64,
        lead_limit: f64,
    },
}

/// One cost term with its weights (defaults from the paper's Table I live on the Python side).
#[derive(Debug, Clone, PartialEq)]
pub enum Term {
    /// (29) ‖log(T⁻¹ T*)‖²_W of a robot frame; `weights` is diag(W), linear then angular.
    TargetPose {
        link: usize,
        target: PoseTarget,
        weights: [f64; 6],
    },
    /// (30) w_γ when the robot touches the object in that step.
    Contact { weight: f64 },
    /// (31) per violated joint limit: w_j + w_s · violation².
    JointLimits {
        weight: f64,
        weight_slope: f64,
        lower: Vec<f64>,
        upper: Vec<f64>,
    },
    /// (32) if the planar distance r of `frame` from `base` exceeds r_max: w_r + w_rs (r − r_max)².
    ArmReach {
        base_link: usize,
        frame_link: usize,
        r_max: f64,
        weight: f64,
        weight_slope: f64,
    },
    /// (33) per sphere pair closer than d_min = r_i + r_j: w + w_s (d_min − d)².
    SelfCollision {
        pairs: Vec<(usize, usize)>,
        weight: f64,
        weight_slope: f64,
    },
    /// Σ_i w_i (q_i − q*_i)²: a preferred posture (a task-design hint that moves the sampler out of
    /// folded local minima; weights of zero leave a joint free).
    Posture { target: Vec<f64>, weights: Vec<f64> },
    /// (34) ‖o − o*‖²_{W_o}.
    ObjectState { target: Vec<f64>, weights: Vec<f64> },
    /// (36) w_p · max(0, −τ_extᵀ u − p_max).
    Power { weight: f64, p_max: f64 },
    /// Base position box [x_min, x_max] × [y_min, y_max] (Cartesian limits, Sec. VI-A2) on the
    /// coordinates of the scene's holonomic base: w + w_s · excess².
    BaseBox {
        lower: [f64; 2],
        upper: [f64; 2],
        weight: f64,
        weight_slope: f64,
    },
    /// Sphere obstacles (centre, radius) against the robot's collision spheres: w + w_s · penetration².
    Obstacles {
        spheres: Vec<(Point3<f64>, f64)>,
        weight: f64,
        weight_slope: f64,
    },
    /// The robot base's footprint, a vertical cylinder about `base_link`'s origin (radius, and
    /// heights `bottom`..`top` above it), kept clear of the object's moving parts, which are
    /// represented by `points` (object link, point in the link frame): w + w_s · p², with p the
    /// deepest planar penetration of a point inside the height band. Keeps the base out of the
    /// sweep of a door that opens toward the robot (a dishwasher), which the rollout model, whose
    /// base has no collider, cannot otherwise foresee.
    BaseClearance {
        base_link: usize,
        radius: f64,
        bottom: f64,
        top: f64,
        points: ClearancePoints,
        weight: f64,
        weight_slope: f64,
    },
}

/// The [`Term::BaseClearance`] that keeps `base_link`'s footprint (radius, bottom, top; from its
/// collision primitives when None) plus `margin` clear of the object's moving parts, sampled as
/// points at most `spacing` apart.
pub fn base_clearance(
    scene: &Scene,
    base_link: usize,
    footprint: Option<(f64, f64, f64)>,
    margin: f64,
    spacing: f64,
    weight: f64,
    weight_slope: f64,
) -> Result<Term> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(SabreError::invalid(
            "base clearance spacing",
            format!("must be positive, got {spacing}"),
        ));
    }
    let count = moving_object_point_count(scene, spacing);
    if count > MAX_CLEARANCE_POINTS as f64 {
        return Err(SabreError::invalid(
            "base clearance spacing",
            format!("{spacing} m samples {count:.3e} points on the object's moving parts (limit {MAX_CLEARANCE_POINTS}); use a larger spacing"),
        ));
    }
    let (radius, bottom, top) = match footprint {
        Some(f) => f,
        None => link_footprint(scene, base_link).ok_or_else(|| {
            let name = scene.robot.links.get(base_link).map_or("?", |l| l.name.as_str());
            SabreError::invalid(
                "base clearance",
                format!("link '{name}' has no collision geometry; give its footprint"),
            )
        })?,
    };
    Ok(Term::BaseClearance {
        base_link,
        radius: radius + margin,
        bottom: bottom - margin,
        top: top + margin,
        points: ClearancePoints::new(&moving_object_points(scene, spacing)),
        weight,
        weight_slope,
    })
}

/// A sum of terms, compiled once and evaluated inside the rollout workers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Cost {
    pub terms: Vec<Term>,
}

fn hinge_square(excess: f64, weight: f64, slope: f64) -> f64 {
    if excess > 0.0 {
        weight + slope * excess * excess
    } else {
        0.0
    }
}

impl Cost {
    pub fn new(terms: Vec<Term>) -> Self {
        Self { terms }
    }

    /// Checks every index and number against the scene.
    pub fn validate(&self, scene: &Scene) -> Result<()> {
        let bad = |what: &str, detail: String| Err(SabreError::invalid(what, detail));
        let finite = |what: &str, v: &[f64]| crate::error::ensure_finite(what, v);
        for term in &self.terms {
            match term {
                Term::TargetPose { link, target, weights } => {
                    if *link >= scene.robot.links.len() {
                        return bad("pose cost", format!("robot link index {link} out of range"));
                    }
                    finite("pose cost weights", weights)?;
                    if let PoseTarget::ObjectLink { link, .. } = target {
                        if *link >= scene.object.links.len() {
                            return bad("pose cost", format!("object link index {link} out of range"));
                        }
                    }
                }
                Term::JointLimits {
                    lower,
                    upper,
                    weight,
                    weight_slope,
                } => {
                    if lower.len() != scene.nq() || upper.len() != scene.nq() {
                        return bad("joint limit cost", format!("limits must have nq = {} entries", scene.nq()));
                    }
                    finite("joint limit cost", &[*weight, *weight_slope])?;
                }
                Term::ArmReach {
                    base_link,
                    frame_link,
                    r_max,
                    ..
                } => {
                    if *base_link >= scene.robot.links.len() || *frame_link >= scene.robot.links.len() {
                        return bad("arm reach cost", "link index out of range".into());
                    }
                    finite("arm reach r_max", &[*r_max])?;
                }
                Term::SelfCollision { pairs, .. } => {
                    if pairs
                        .iter()
                        .any(|&(a, b)| a >= scene.spheres.len() || b >= scene.spheres.len())
                    {
                        return bad("self-collision cost", "sphere index out of range".into());
                    }
                }
                Term::Posture { target, weights } => {
                    if target.len() != scene.nq() || weights.len() != scene.nq() {
                        return bad("posture cost", format!("target and weights need nq = {} entries", scene.nq()));
                    }
                    finite("posture target", target)?;
                    finite("posture weights", weights)?;
                }
                Term::ObjectState { target, weights } => {
                    if target.len() != scene.no() || weights.len() != scene.no() {
                        return bad("object cost", format!("target and weights need no = {} entries", scene.no()));
                    }
                    finite("object target", target)?;
                    finite("object weights", weights)?;
                }
                Term::Contact { weight } => finite("contact weight", &[*weight])?,
                Term::Power { weight, p_max } => finite("power cost", &[*weight, *p_max])?,
                Term::BaseBox { lower, upper, .. } => {
                    if scene.roles.base.is_none() {
                        return bad(
                            "base box cost",
                            "the robot's base is fixed: it has no base coordinates".into(),
                        );
                    }
                    finite("base box", &[lower[0], lower[1], upper[0], upper[1]])?
                }
                Term::Obstacles { spheres, .. } => {
                    for (c, r) in spheres {
                        finite("obstacle", &[c.x, c.y, c.z, *r])?;
                    }
                }
                Term::BaseClearance {
                    base_link,
                    radius,
                    bottom,
                    top,
                    points,
                    weight,
                    weight_slope,
                } => {
                    if *base_link >= scene.robot.links.len() || points.links().any(|l| l >= scene.object.links.len()) {
                        return bad("base clearance cost", "link index out of range".into());
                    }
                    finite("base clearance", &[*radius, *bottom, *top, *weight, *weight_slope])?;
                    if *radius < 0.0 || bottom > top {
                        return bad(
                            "base clearance cost",
                            format!("needs radius >= 0 and bottom <= top, got {radius}, {bottom}..{top}"),
                        );
                    }
                }
            }
        }
        Ok(())
    }

    /// Whether any term needs the object's link poses.
    pub fn needs_object_frames(&self) -> bool {
        self.terms.iter().any(|t| {
            matches!(
                t,
                Term::TargetPose {
                    target: PoseTarget::ObjectLink { .. },
                    ..
                } | Term::BaseClearance { .. }
            )
        })
    }

    /// Cost of one step.
    pub fn step(&self, scene: &Scene, view: &StepView) -> f64 {
        let nq = scene.nq();
        let no = scene.no();
        let q = &view.x[..nq];
        let o = &view.x[2 * nq..2 * nq + no];
        let mut total = 0.0;
        for term in &self.terms {
            total += match term {
                Term::TargetPose { link, target, weights } => {
                    let current = view.robot.poses[*link];
                    let desired = match target {
                        PoseTarget::World(t) => *t,
                        PoseTarget::ObjectLink { link, offset, lead, .. } if *lead == 0.0 => view.object.poses[*link] * offset,
                        PoseTarget::ObjectLink {
                            link,
                            offset,
                            lead,
                            lead_limit,
                        } => LEAD_POSES.with(|cell| {
                            let (ahead, poses) = &mut *cell.borrow_mut();
                            ahead.clear();
                            ahead.extend(
                                o.iter()
                                    .map(|&v| if v >= *lead_limit { v } else { (v + lead).min(*lead_limit) }),
                            );
                            scene.object.link_poses_into(&scene.object_pose, ahead, poses);
                            poses[*link] * offset
                        }),
                    };
                    let xi = se3_log(&(current.inverse() * desired));
                    (0..6).map(|i| weights[i] * xi[i] * xi[i]).sum()
                }
                Term::Contact { weight } => {
                    if view.contact {
                        *weight
                    } else {
                        0.0
                    }
                }
                Term::JointLimits {
                    weight,
                    weight_slope,
                    lower,
                    upper,
                } => q
                    .iter()
                    .enumerate()
                    .map(|(i, &v)| {
                        hinge_square(v - upper[i], *weight, *weight_slope) + hinge_square(lower[i] - v, *weight, *weight_slope)
                    })
                    .sum(),
                Term::ArmReach {
                    base_link,
                    frame_link,
                    r_max,
                    weight,
                    weight_slope,
                } => {
                    let d = view.robot.poses[*frame_link].translation.vector - view.robot.poses[*base_link].translation.vector;
                    hinge_square((d.x * d.x + d.y * d.y).sqrt() - r_max, *weight, *weight_slope)
                }
                Term::SelfCollision {
                    pairs,
                    weight,
                    weight_slope,
                } => pairs
                    .iter()
                    .map(|&(a, b)| {
                        let (sa, sb) = (&scene.spheres[a], &scene.spheres[b]);
                        let pa = view.robot.poses[sa.link] * Point3::from(sa.center);
                        let pb = view.robot.poses[sb.link] * Point3::from(sb.center);
                        hinge_square(sa.radius + sb.radius - (pa - pb).norm(), *weight, *weight_slope)
                    })
                    .sum(),
                Term::Posture { target, weights } => q
                    .iter()
                    .zip(target)
                    .zip(weights)
                    .map(|((v, t), w)| w * (v - t) * (v - t))
                    .sum(),
                Term::ObjectState { target, weights } => o
                    .iter()
                    .zip(target)
                    .zip(weights)
                    .map(|((v, t), w)| w * (v - t) * (v - t))
                    .sum(),
                Term::Power { weight, p_max } => {
                    let dissipated: f64 = -view.tau_ext.iter().zip(view.u).map(|(t, u)| t * u).sum::<f64>();
                    weight * (dissipated - p_max).max(0.0)
                }
                Term::BaseBox {
                    lower,
                    upper,
                    weight,
                    weight_slope,
                } => {
                    let base = scene.roles.base.expect("validated: the robot has a holonomic base");
                    [base.x, base.y]
                        .iter()
                        .enumerate()
                        .map(|(i, &coordinate)| {
                            let v = q[coordinate];
                            hinge_square(v - upper[i], *weight, *weight_slope)
                                + hinge_square(lower[i] - v, *weight, *weight_slope)
                        })
                        .sum()
                }
                Term::Obstacles {
                    spheres,
                    weight,
                    weight_slope,
                } => {
                    let mut sum = 0.0;
                    for s in scene.spheres.iter().filter(|s| s.obstacles) {
                        let p = view.robot.poses[s.link] * Point3::from(s.center);
                        for (c, r) in spheres {
                            sum += hinge_square(r + s.radius - (p - c).norm(), *weight, *weight_slope);
                        }
                    }
                    sum
                }
                Term::BaseClearance {
                    base_link,
                    radius,
                    bottom,
                    top,
                    points,
                    weight,
                    weight_slope,
                } => {
                    let base = view.robot.poses[*base_link].translation.vector;
                    let deepest = points.deepest(&view.object.poses, &base, *radius, *bottom, *top);
                    hinge_square(deepest, *weight, *weight_slope)
                }
            };
        }
        total
    }
}

/// The sampler's cost as the rollouts' per-step evaluator.
impl StepEvaluator for Cost {
    fn validate(&self, scene: &Scene) -> Result<()> {
        Cost::validate(self, scene)
    }

    fn needs_object_frames(&self) -> bool {
        Cost::needs_object_frames(self)
    }

    fn evaluate(&self, scene: &Scene, view: &StepView) -> f64 {
        self.step(scene, view)
    }
}

#[cfg(test)]
mod tests;
