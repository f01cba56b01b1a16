//! Guide sequences for the sampler: a resolved-rate servo of a robot frame along target poses,
//! integrated on the kinematics over the horizon.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix6, Vector6};

use crate::error::{ensure_finite, Result, SabreError};
use crate::model::kinematics::Frames;
use crate::model::scene::Scene;

/// Gains and limits of [`servo_guide`].
#[derive(Debug, Clone, PartialEq)]
pub struct ServoGuideConfig {
    /// Proportional gain on the pose error (1/s).
    pub gain: f64,
    /// Cap on the commanded Cartesian rate: linear (m/s) and angular (rad/s).
    pub max_linear: f64,
    pub max_angular: f64,
    /// Per-joint speed limit, tightened to the URDF limits; None: the URDF limits.
    pub velocity_limit: Option<Vec<f64>>,
    /// Damping λ of the least-squares inverse Jᵀ(JJᵀ + λI)⁻¹.
    pub damping: f64,
    /// Distance (rad or m) inside each joint limit at which a joint is held.
    pub joint_margin: f64,
    /// Weigh joints heading toward a limit by how close they are (weighted least norm), so that
    /// the redundant joints (the base) take over before a joint reaches its margin.
    pub limit_weighting: bool,
}

impl Default for ServoGuideConfig {
    fn default() -> Self {
        Self {
            gain: 2.0,
            max_linear: 0.3,
            max_angular: 0.6,
            velocity_limit: None,
            damping: 1e-3,
            joint_margin: 0.05,
            limit_weighting: true,
        }
    }
}

/// World-frame (linear, rotation vector) displacement taking pose `a` to pose `b`.
fn displacement(a: &Isometry3<f64>, b: &Isometry3<f64>) -> Vector6<f64> {
    let p = b.translation.vector - a.translation.vector;
    let w = (b.rotation * a.rotation.inverse()).scaled_axis();
    Vector6::new(p.x, p.y, p.z, w.x, w.y, w.z)
}

/// Scales the linear and angular halves of `rate` down to their caps.
fn cap_rate(rate: &mut Vector6<f64>, max_linear: f64, max_angular: f64) {
    let linear = rate.fixed_rows::<3>(0).norm();
    if linear > max_linear {
        rate.fixed_rows_mut::<3>(0).scale_mut(max_linear / linear);
    }
    let angular = rate.fixed_rows::<3>(3).norm();
    if angular > max_angular {
        rate.fixed_rows_mut::<3>(3).scale_mut(max_angular / angular);
    }
}

/// K × nu joint velocities (row-major) that servo `frame` along `targets` (K + 1 poses) from `q0`.
///
/// Step k commands v_k = J⁺(ξ_k + gain·e_k): ξ_k the targets' own motion from k to k + 1 (feed
/// forward), e_k the frame's pose error at k, the Cartesian rate capped, J⁺ the damped
/// least-squares inverse, weighted (with `limit_weighting`) by Chan and Dubey's joint-limit
/// gradient so that joints heading for a limit slow down as they near it and the redundant ones
/// take over. A joint that would cross its margin within the step is held there and the others
/// re-solved for the rest of the rate (clamp and re-solve). One common factor brings every joint
/// within its speed limit, keeping the direction. q is integrated with step `dt`: the guide is what the servo
/// would do on the kinematics alone, which is all a sample needs to be.
pub fn servo_guide(
    scene: &Scene,
    q0: &[f64],
    targets: &[Isometry3<f64>],
    dt: f64,
    frame: &str,
    config: &ServoGuideConfig,
) -> Result<Vec<f64>> {
    let guide = ServoGuide::new(scene, q0, targets.to_vec(), dt, frame, config)?;
    let mut out = vec![0.0; guide.steps() * scene.nq()];
    guide.write(scene, &mut out);
    Ok(out)
}

/// One servo guide, checked and ready to integrate (see [`servo_guide`]).
#[derive(Debug, Clone)]
struct ServoGuide {
    q0: Vec<f64>,
    targets: Vec<Isometry3<f64>>,
    dt: f64,
    link: usize,
    config: ServoGuideConfig,
    /// Per joint: the speed limit and the margin-tightened position limits.
    speed: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
}

impl ServoGuide {
    fn new(
        scene: &Scene,
        q0: &[f64],
        targets: Vec<Isometry3<f64>>,
        dt: f64,
        frame: &str,
        config: &ServoGuideConfig,
    ) -> Result<Self> {
        let nq = scene.nq();
        crate::error::ensure_len("q0", q0, nq)?;
        ensure_finite("q0", q0)?;
        if targets.len() < 2 {
            return Err(SabreError::invalid(
                "targets",
                format!("the servo guide needs at least 2 poses (K + 1), got {}", targets.len()),
            ));
        }
        let finite_pose = |t: &Isometry3<f64>| {
            t.translation
                .vector
                .iter()
                .chain(t.rotation.coords.iter())
                .all(|v| v.is_finite())
        };
        if !targets.iter().all(finite_pose) {
            return Err(SabreError::invalid("targets", "must be finite"));
        }
        for (name, value) in [
            ("dt", dt),
            ("max_linear", config.max_linear),
            ("max_angular", config.max_angular),
            ("damping", config.damping),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(SabreError::invalid(name, format!("must be positive and finite, got {value}")));
            }
        }
        if !(config.gain.is_finite() && config.gain >= 0.0 && config.joint_margin.is_finite()) {
            return Err(SabreError::invalid(
                "gain, joint_margin",
                "gain must be non-negative and finite, joint_margin finite",
            ));
        }
        let link = scene.robot.require_link(frame)?;
        let limits = scene.robot_limits();
        let mut speed: Vec<f64> = limits.iter().map(|l| l.velocity).collect();
        if let Some(tighter) = &config.velocity_limit {
            crate::error::ensure_len("velocity_limit", tighter, nq)?;
            ensure_finite("velocity_limit", tighter)?;
            for (s, &t) in speed.iter_mut().zip(tighter) {
                if t <= 0.0 {
                    return Err(SabreError::invalid("velocity_limit", "must be positive"));
                }
                *s = s.min(t);
            }
        }
        Ok(Self {
            q0: q0.to_vec(),
            targets,
            dt,
            link,
            config: config.clone(),
            speed,
            lower: limits.iter().map(|l| l.lower + config.joint_margin).collect(),
            upper: limits.iter().map(|l| l.upper - config.joint_margin).collect(),
        })
    }

    fn steps(&self) -> usize {
        self.targets.len() - 1
    }

    /// Integrates the guide on `scene` (the one it was checked on) into `out` (K × nq).
    fn write(&self, scene: &Scene, out: &mut [f64]) {
        let nq = self.q0.len();
        let (config, dt) = (&self.config, self.dt);
        let limits = scene.robot_limits();
        let mut q = self.q0.clone();
        let mut frames = Frames::default();
        let mut jacobian = vec![0.0; 6 * nq];
        let mut columns = vec![Vector6::zeros(); nq];
        let mut solver = HeldSolver {
            lower: self.lower.clone(),
            upper: self.upper.clone(),
            dt,
            damping: config.damping,
            free: vec![true; nq],
            held: vec![0.0; nq],
        };
        let unit = vec![1.0; nq];
        let mut weights = vec![1.0; nq];
        let mut v = vec![0.0; nq];
        let targets = &self.targets;
        for k in 0..self.steps() {
            scene.robot.update_frames(&Isometry3::identity(), &q, &mut frames);
            let pose = frames.poses[self.link];
            scene
                .robot
                .frames_jacobian_into(&frames, self.link, &pose.translation.vector.into(), &mut jacobian);
            for (c, column) in columns.iter_mut().enumerate() {
                *column = Vector6::from_column_slice(&jacobian[6 * c..6 * c + 6]);
            }
            let mut rate = displacement(&targets[k], &targets[k + 1]) / dt + config.gain * displacement(&pose, &targets[k]);
            cap_rate(&mut rate, config.max_linear, config.max_angular);

            solver.solve(&columns, &rate, &unit, &q, &mut v);
            if config.limit_weighting {
                let mut weighted = false;
                for c in 0..nq {
                    weights[c] = limit_weight(q[c], limits[c].lower, limits[c].upper, v[c]);
                    weighted |= weights[c] > 1.0;
                }
                if weighted {
                    solver.solve(&columns, &rate, &weights, &q, &mut v);
                }
            }
            let over = v.iter().zip(&self.speed).map(|(vi, s)| vi.abs() / s).fold(0.0, f64::max);
            if over > 1.0 {
                v.iter_mut().for_each(|vi| *vi /= over);
            }
            out[k * nq..(k + 1) * nq].copy_from_slice(&v);
            for (qi, vi) in q.iter_mut().zip(&v) {
                *qi += dt * vi;
            }
        }
    }
}

/// [`servo_guide`] along several target sequences from the same `q0`, each with its own config:
/// M × K × nu joint velocities (row-major), guide m servoing along `targets[m]`. Every sequence has
/// the same length K + 1.
pub fn servo_guides(
    scene: &Scene,
    q0: &[f64],
    targets: &[Vec<Isometry3<f64>>],
    dt: f64,
    frame: &str,
    configs: &[ServoGuideConfig],
) -> Result<Vec<f64>> {
    let guides = checked_guides(scene, q0, targets, dt, frame, configs)?;
    let row = guides.first().map_or(0, ServoGuide::steps) * scene.nq();
    let mut out = vec![0.0; guides.len() * row];
    for (guide, chunk) in guides.iter().zip(out.chunks_exact_mut(row.max(1))) {
        guide.write(scene, chunk);
    }
    Ok(out)
}

/// The guides of [`servo_guides`], checked.
fn checked_guides(
    scene: &Scene,
    q0: &[f64],
    targets: &[Vec<Isometry3<f64>>],
    dt: f64,
    frame: &str,
    configs: &[ServoGuideConfig],
) -> Result<Vec<ServoGuide>> {
    if targets.len() != configs.len() {
        return Err(SabreError::invalid(
            "configs",
            format!(
                "one per target sequence: {} sequences, {} configs",
                targets.len(),
                configs.len()
            ),
        ));
    }
    if let Some(first) = targets.first() {
        if let Some(other) = targets.iter().find(|t| t.len() != first.len()) {
            return Err(SabreError::invalid(
                "targets",
                format!("every sequence has the same length: {} and {}", first.len(), other.len()),
            ));
        }
    }
    targets
        .iter()
        .zip(configs)
        .map(|(sequence, config)| ServoGuide::new(scene, q0, sequence.clone(), dt, frame, config))
        .collect()
}

/// The servo guides of [`servo_guides`], checked when the plan is made and integrated one by one
/// where they are used: a planner's rollout workers each build the guide of the row they roll out,
/// in parallel with the others' rollouts, instead of the caller building them all first.
#[derive(Debug, Clone)]
pub struct ServoGuidePlan {
    scene: Arc<Scene>,
    guides: Vec<ServoGuide>,
    steps: usize,
}

impl ServoGuidePlan {
    /// One guide per target sequence (every sequence K + 1 poses long), guide m with `configs[m]`.
    pub fn new(
        scene: Arc<Scene>,
        q0: &[f64],
        targets: &[Vec<Isometry3<f64>>],
        dt: f64,
        frame: &str,
        configs: &[ServoGuideConfig],
    ) -> Result<Self> {
        let guides = checked_guides(&scene, q0, targets, dt, frame, configs)?;
        let steps = guides.first().map_or(0, ServoGuide::steps);
        Ok(Self { scene, guides, steps })
    }

    /// A plan of no guides.
    pub fn empty(scene: Arc<Scene>) -> Self {
        Self {
            scene,
            guides: Vec::new(),
            steps: 0,
        }
    }

    /// The number of guides M.
    pub fn len(&self) -> usize {
        self.guides.len()
    }

    pub fn is_empty(&self) -> bool {
        self.guides.is_empty()
    }

    /// Steps K of every guide.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Joint velocities per step: the robot's nq.
    pub fn width(&self) -> usize {
        self.scene.nq()
    }

    /// Integrates guide `m` into `out` (K × nq).
    pub fn write(&self, m: usize, out: &mut [f64]) {
        self.guides[m].write(&self.scene, out);
    }

    /// Every guide, M × K × nq (row-major).
    pub fn evaluate(&self) -> Vec<f64> {
        let row = self.steps * self.width();
        let mut out = vec![0.0; self.len() * row];
        for (m, chunk) in out.chunks_exact_mut(row.max(1)).enumerate().take(self.len()) {
            self.write(m, chunk);
        }
        out
    }
}

/// The joint-rate solve of [`servo_guide`] with its joint margins and scratch.
struct HeldSolver {
    lower: Vec<f64>,
    upper: Vec<f64>,
    dt: f64,
    damping: f64,
    free: Vec<bool>,
    held: Vec<f64>,
}

impl HeldSolver {
    /// v = W⁻¹Jᵀ(JW⁻¹Jᵀ + λI)⁻¹ rate (W = diag(weights)), with the joints that would cross their
    /// margin within the step held there and the others re-solved for the rest of the rate (clamp
    /// and re-solve), so that, for example, the base takes over from an arm joint at its limit.
    fn solve(&mut self, columns: &[Vector6<f64>], rate: &Vector6<f64>, weights: &[f64], q: &[f64], v: &mut [f64]) {
        let nq = q.len();
        self.free.fill(true);
        self.held.fill(0.0);
        // Each pass holds at least one more joint, so nq + 1 passes always settle; in practice two.
        for _ in 0..=nq {
            let mut gram = Matrix6::identity() * self.damping;
            let mut remaining = *rate;
            for (col, ((&free, &held), &weight)) in columns.iter().zip(self.free.iter().zip(&self.held).zip(weights)) {
                if free {
                    // The Gram matrix is symmetric: its lower triangle is all the factorisation reads.
                    gram.syger(1.0 / weight, col, col, 1.0);
                } else {
                    remaining -= col * held;
                }
            }
            let y = match gram.cholesky() {
                Some(chol) => chol.solve(&remaining),
                None => Vector6::zeros(),
            };
            let mut stopped = false;
            for c in 0..nq {
                if !self.free[c] {
                    v[c] = self.held[c];
                    continue;
                }
                v[c] = columns[c].dot(&y) / weights[c];
                let next = q[c] + self.dt * v[c];
                if next > self.upper[c] && v[c] > 0.0 {
                    self.held[c] = (self.upper[c] - q[c]).max(0.0) / self.dt;
                } else if next < self.lower[c] && v[c] < 0.0 {
                    self.held[c] = (self.lower[c] - q[c]).min(0.0) / self.dt;
                } else {
                    continue;
                }
                self.free[c] = false;
                stopped = true;
            }
            if !stopped {
                break;
            }
        }
    }
}

/// Chan and Dubey's weight 1 + |∂H/∂q| of a joint at q in [lower, upper] moving at rate v, with
/// H = (upper − lower)² / (4 (upper − q)(q − lower)): large near a limit the joint heads for, 1
/// when it heads for the middle, for an unlimited joint, or at rest.
fn limit_weight(q: f64, lower: f64, upper: f64, v: f64) -> f64 {
    let range = upper - lower;
    if !range.is_finite() || range <= 0.0 {
        return 1.0;
    }
    let to_upper = (upper - q).max(1e-6);
    let from_lower = (q - lower).max(1e-6);
    let gradient = range * range * (2.0 * q - upper - lower) / (4.0 * to_upper * to_upper * from_lower * from_lower);
    if gradient * v > 0.0 {
        1.0 + gradient.abs()
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::limit_weight;

    /// H(q) = (u − l)² / (4 (u − q)(q − l)), whose gradient the weight adds to 1.
    fn h(q: f64, l: f64, u: f64) -> f64 {
        (u - l) * (u - l) / (4.0 * (u - q) * (q - l))
    }

    #[test]
    fn the_weight_is_one_plus_the_gradient_toward_the_limit() {
        let (l, u) = (-1.5, 0.5);
        for q in [-1.4, -1.0, -0.3, 0.0, 0.45] {
            let fd = (h(q + 1e-6, l, u) - h(q - 1e-6, l, u)) / 2e-6;
            let toward = fd.signum();
            let w = limit_weight(q, l, u, toward);
            assert!(
                (w - (1.0 + fd.abs())).abs() < 1e-5 * (1.0 + fd.abs()),
                "q {q}: {w} vs 1 + {fd}"
            );
            assert_eq!(limit_weight(q, l, u, -toward), 1.0, "heading for the middle at q {q}");
            assert_eq!(limit_weight(q, l, u, 0.0), 1.0);
        }
        assert_eq!(limit_weight(0.3, f64::NEG_INFINITY, f64::INFINITY, 1.0), 1.0);
    }
}
