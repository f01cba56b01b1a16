//! Guide sequences for the sampler: a resolved-rate servo of a robot frame along target poses,
//! integrated on the kinematics over the horizon.

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
/// least-squares inverse. A joint that would cross its margin within the step is held there and
/// the others re-solved for the rest of the rate (clamp and re-solve), so that, for example, the
/// base takes over from an arm joint at its limit. One common factor brings every joint within its
/// speed limit, keeping the direction. q is integrated with step `dt`: the guide is what the servo
/// would do on the kinematics alone, which is all a sample needs to be.
pub fn servo_guide(
    scene: &Scene,
    q0: &[f64],
    targets: &[Isometry3<f64>],
    dt: f64,
    frame: &str,
    config: &ServoGuideConfig,
) -> Result<Vec<f64>> {
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
    let lower: Vec<f64> = limits.iter().map(|l| l.lower + config.joint_margin).collect();
    let upper: Vec<f64> = limits.iter().map(|l| l.upper - config.joint_margin).collect();

    let steps = targets.len() - 1;
    let mut out = vec![0.0; steps * nq];
    let mut q = q0.to_vec();
    let mut frames = Frames::default();
    let mut jacobian = vec![0.0; 6 * nq];
    let mut free = vec![true; nq];
    let mut held = vec![0.0; nq];
    let mut v = vec![0.0; nq];
    for k in 0..steps {
        scene.robot.update_frames(&Isometry3::identity(), &q, &mut frames);
        let pose = frames.poses[link];
        scene
            .robot
            .frames_jacobian_into(&frames, link, &pose.translation.vector.into(), &mut jacobian);
        let column = |c: usize| Vector6::from_column_slice(&jacobian[6 * c..6 * c + 6]);
        let mut rate = displacement(&targets[k], &targets[k + 1]) / dt + config.gain * displacement(&pose, &targets[k]);
        cap_rate(&mut rate, config.max_linear, config.max_angular);

        free.fill(true);
        held.fill(0.0);
        // Each pass holds at least one more joint, so nq + 1 passes always settle; in practice two.
        for _ in 0..=nq {
            let mut gram = Matrix6::identity() * config.damping;
            let mut remaining = rate;
            for c in 0..nq {
                let col = column(c);
                if free[c] {
                    gram += col * col.transpose();
                } else {
                    remaining -= col * held[c];
                }
            }
            let y = match gram.cholesky() {
                Some(chol) => chol.solve(&remaining),
                None => Vector6::zeros(),
            };
            let mut stopped = false;
            for c in 0..nq {
                if !free[c] {
                    v[c] = held[c];
                    continue;
                }
                v[c] = column(c).dot(&y);
                let next = q[c] + dt * v[c];
                if next > upper[c] && v[c] > 0.0 {
                    held[c] = (upper[c] - q[c]).max(0.0) / dt;
                } else if next < lower[c] && v[c] < 0.0 {
                    held[c] = (lower[c] - q[c]).min(0.0) / dt;
                } else {
                    continue;
                }
                free[c] = false;
                stopped = true;
            }
            if !stopped {
                break;
            }
        }
        let over = v.iter().zip(&speed).map(|(vi, s)| vi.abs() / s).fold(0.0, f64::max);
        if over > 1.0 {
            v.iter_mut().for_each(|vi| *vi /= over);
        }
        out[k * nq..(k + 1) * nq].copy_from_slice(&v);
        for (qi, vi) in q.iter_mut().zip(&v) {
            *qi += dt * vi;
        }
    }
    Ok(out)
}
