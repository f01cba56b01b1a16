//! Cost terms of the sampling-based controller (paper Sec. IV-A, eqs. 29–36), evaluated per rollout step.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3, Vector6};

use crate::error::{Result, SabreError};
use crate::model::scene::Scene;
use crate::sim::StepEvaluator;
pub use crate::sim::StepView;

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

/// The sample points of a [`Term::BaseClearance`] (object link, point in its frame), in clusters
/// of neighbours on one link, each with a bounding sphere: a step skips the clusters that cannot
/// reach the footprint's band or cylinder, which on most steps is all of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClearancePoints {
    clusters: Vec<PointCluster>,
}

#[derive(Debug, Clone, PartialEq)]
struct PointCluster {
    link: usize,
    centre: Point3<f64>,
    radius: f64,
    points: Vec<Point3<f64>>,
}

/// Points per cluster: consecutive points of [`moving_object_points`]'s grid lie close together.
const CLUSTER_POINTS: usize = 16;

/// How far inside a bound a cluster must be to be skipped, so that rounding between the
/// cluster's centre and its points never drops a point that counts.
const CLUSTER_SLACK: f64 = 1e-9;

impl ClearancePoints {
    /// Clusters `points` (object link, point in its frame) in their order.
    pub fn new(points: &[(usize, Point3<f64>)]) -> Self {
        let mut clusters = Vec::new();
        let mut start = 0;
        while start < points.len() {
            let link = points[start].0;
            let mut end = start + 1;
            while end < points.len() && points[end].0 == link && end - start < CLUSTER_POINTS {
                end += 1;
            }
            let members: Vec<Point3<f64>> = points[start..end].iter().map(|(_, p)| *p).collect();
            let centre = Point3::from(members.iter().map(|p| p.coords).sum::<Vector3<f64>>() / members.len() as f64);
            let radius = members.iter().map(|p| (p - centre).norm()).fold(0.0, f64::max);
            clusters.push(PointCluster {
                link,
                centre,
                radius,
                points: members,
            });
            start = end;
        }
        Self { clusters }
    }

    /// The object link of each cluster.
    fn links(&self) -> impl Iterator<Item = usize> + '_ {
        self.clusters.iter().map(|c| c.link)
    }

    /// max over the points inside the height band [bottom, top] above `base` of radius − their
    /// horizontal distance from `base`; −∞ without such a point. A cluster whose sphere lies
    /// outside the band or the cylinder is skipped: none of its points can be in the band or
    /// give more than 0 there, and the term only charges a positive maximum.
    fn deepest(&self, object: &[Isometry3<f64>], base: &Vector3<f64>, radius: f64, bottom: f64, top: f64) -> f64 {
        let mut deepest = f64::NEG_INFINITY;
        for cluster in &self.clusters {
            let pose = &object[cluster.link];
            let c = pose * cluster.centre;
            let reach = cluster.radius + CLUSTER_SLACK;
            let height = c.z - base.z;
            if height + reach < bottom || height - reach > top {
                continue;
            }
            if ((c.x - base.x).powi(2) + (c.y - base.y).powi(2)).sqrt() - reach > radius {
                continue;
            }
            for local in &cluster.points {
                let p = pose * local;
                let height = p.z - base.z;
                if height >= bottom && height <= top {
                    deepest = deepest.max(radius - ((p.x - base.x).powi(2) + (p.y - base.y).powi(2)).sqrt());
                }
            }
        }
        deepest
    }
}

/// Points spread over the collision primitives of the object's moving links (in their link frames),
/// at most `spacing` apart along each axis of each primitive's bounding box.
pub fn moving_object_points(scene: &Scene, spacing: f64) -> Vec<(usize, Point3<f64>)> {
    let tree = &scene.object;
    let mut out = Vec::new();
    for (link, l) in tree.links.iter().enumerate() {
        if tree.ancestor_active_joints(link).is_empty() {
            continue;
        }
        for c in &l.collisions {
            let half = c.shape.half_extents();
            // Vertices of a grid over the bounding box: corners and edges, where a box first meets
            // the footprint, are always among the points.
            let cells = grid_cells(half, spacing).map(|c| c as usize);
            for i in 0..=cells.x {
                for j in 0..=cells.y {
                    for k in 0..=cells.z {
                        let at = |n: usize, of: usize, h: f64| -h + 2.0 * h * n as f64 / of as f64;
                        let local = Point3::new(at(i, cells.x, half.x), at(j, cells.y, half.y), at(k, cells.z, half.z));
                        out.push((link, c.origin * local));
                    }
                }
            }
        }
    }
    out
}

/// Cells per axis of the sampling grid over a primitive with these half extents.
fn grid_cells(half: Vector3<f64>, spacing: f64) -> Vector3<f64> {
    half.map(|h| (2.0 * h / spacing).ceil().max(1.0))
}

/// How many points [`moving_object_points`] would return, as a float so that it cannot overflow.
pub fn moving_object_point_count(scene: &Scene, spacing: f64) -> f64 {
    let tree = &scene.object;
    let mut count = 0.0;
    for (link, l) in tree.links.iter().enumerate() {
        if tree.ancestor_active_joints(link).is_empty() {
            continue;
        }
        for c in &l.collisions {
            count += grid_cells(c.shape.half_extents(), spacing).map(|n| n + 1.0).product();
        }
    }
    count
}

/// The most points a [`Term::BaseClearance`] samples: each is tested in every step of every rollout.
pub const MAX_CLEARANCE_POINTS: usize = 100_000;

/// (radius, bottom, top) of the vertical cylinder about a robot link's origin that bounds its
/// collision primitives, heights relative to the link origin; None if it has none.
pub fn link_footprint(scene: &Scene, link: usize) -> Option<(f64, f64, f64)> {
    use crate::model::kinematics::Shape;
    let l = scene.robot.links.get(link)?;
    let mut bound: Option<(f64, f64, f64)> = None;
    for c in &l.collisions {
        let half = c.shape.half_extents();
        // Corners of the primitive's bounding box; an upright round primitive's own radius is tighter.
        let upright = c.origin.rotation.angle() < 1e-9;
        let round = upright && matches!(c.shape, Shape::Cylinder { .. } | Shape::Capsule { .. } | Shape::Sphere { .. });
        for corner in 0..8 {
            let sign = |bit: usize| if corner & bit == 0 { -1.0 } else { 1.0 };
            let p = c.origin * Point3::new(sign(1) * half.x, sign(2) * half.y, sign(4) * half.z);
            let r = if round {
                c.origin.translation.vector.xy().norm() + half.x
            } else {
                p.coords.xy().norm()
            };
            bound = Some(match bound {
                None => (r, p.z, p.z),
                Some((rr, lo, hi)) => (rr.max(r), lo.min(p.z), hi.max(p.z)),
            });
        }
    }
    bound
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
