//! The low-level joint velocity controller (53): the torques that make the robot track a velocity
//! command, with gains scaled by the robot's inertia and a floor for its light joints.

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Isometry3};

use crate::error::{ensure_finite, ensure_len, Result, SabreError};
use crate::model::dynamics::{joint_space_terms, DynamicsWorkspace};
use crate::model::scene::Scene;

/// Gains of the velocity controller.
#[derive(Debug, Clone, PartialEq)]
pub struct LowLevelConfig {
    /// Proportional bandwidth Λ_D (1/s): in free motion the tracking error decays like exp(−Λ_D t).
    pub bandwidth: f64,
    /// Integral gain Λ_I (1/s²) on the accumulated velocity error (position error).
    pub integral_gain: f64,
    /// Bound on the accumulated position error per joint, against wind-up while in contact.
    pub integral_limit: f64,
    /// Smallest joint inertia (kg m²) the PI gains are scaled with. The last wrist joint turns only
    /// the hand (M_ii ≈ 0.007 kg m²), so with K = M Λ alone it resists a load by 0.27 N m per rad/s
    /// and 0.27 N m of integral: a hook pulling on a held door twists it and the finger slides off
    /// the bar. The floor gives such joints the stiffness of a joint of this inertia; heavier joints
    /// keep K = M Λ.
    pub gain_inertia_floor: f64,
}

impl Default for LowLevelConfig {
    fn default() -> Self {
        Self {
            bandwidth: 40.0,
            integral_gain: 400.0,
            integral_limit: 0.1,
            gain_inertia_floor: 0.0,
        }
    }
}

fn check_gain(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(SabreError::invalid(name, format!("must be finite and non-negative, got {v}")))
    }
}

/// τ = M(q) q̈* + (M(q) + A(q)) (Λ_D (q̇* − q̇) + Λ_I ∫(q̇* − q̇)) + g(q),
/// A = diag(max(0, m_floor − M_ii)) (`gain_inertia_floor`).
///
/// This is (53) with K_D = (M + A) Λ_D and K_I = (M + A) Λ_I, so the closed loop has the same
/// first-order velocity response as the rollout model's servo on every joint whose inertia is
/// above the floor. The Coriolis feed-forward C q̇* is neglected
/// (robot velocities are small; it is bounded by the PI terms).
pub struct LowLevelController {
    scene: Arc<Scene>,
    config: LowLevelConfig,
    dt: f64,
    integral: Vec<f64>,
    /// The previous call's reference, for the feed-forward q̈*; only valid while `has_previous`.
    previous_reference: Vec<f64>,
    has_previous: bool,
    workspace: DynamicsWorkspace,
    mass_matrix: DMatrix<f64>,
    gravity_torque: DVector<f64>,
    acceleration: DVector<f64>,
    pi_acceleration: DVector<f64>,
    /// M(q) q̈ of the current call.
    inertial_torque: DVector<f64>,
    /// Per joint, the inertia it feels with every other joint free, 1 / (M⁻¹)_ii, and M_ii, both
    /// where that inertia is smallest among the home and start configurations (for
    /// [`Self::loop_gain`]).
    apparent_inertia: Vec<f64>,
    diagonal_inertia: Vec<f64>,
    /// Per joint, the most the tracked command may change in a call (see
    /// [`Self::set_command_acceleration`]); None: the reference is tracked as given.
    command_step: Option<Vec<f64>>,
    /// The rate-limited command tracked by the last call; only valid while `has_previous`.
    command: Vec<f64>,
}

/// Largest loop gain per plant step a joint may have (see [`LowLevelController::loop_gain`]): above 1
/// each step overshoots the velocity error, above 2 the loop diverges.
pub const MAX_LOOP_GAIN: f64 = 1.0;

/// (1 / (M⁻¹)_ii, M_ii) per joint, at the configuration of the smaller first value among `qs`.
fn apparent_inertias(scene: &Scene, qs: &[Vec<f64>]) -> Result<(Vec<f64>, Vec<f64>)> {
    let nq = scene.nq();
    let (mut apparent, mut diagonal) = (vec![f64::INFINITY; nq], vec![0.0; nq]);
    for q in qs {
        let (m, _) = scene.mass_matrix_and_gravity(q)?;
        let Some(inverse) = m.clone().try_inverse() else { continue };
        for i in 0..nq {
            let felt = 1.0 / inverse[(i, i)].max(f64::MIN_POSITIVE);
            if felt < apparent[i] {
                (apparent[i], diagonal[i]) = (felt, m[(i, i)]);
            }
        }
    }
    Ok((apparent, diagonal))
}

impl LowLevelController {
    pub fn new(scene: Arc<Scene>, dt: f64, config: LowLevelConfig) -> Result<Self> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", "must be positive"));
        }
        for (name, v) in [
            ("bandwidth", config.bandwidth),
            ("integral_gain", config.integral_gain),
            ("integral_limit", config.integral_limit),
            ("gain_inertia_floor", config.gain_inertia_floor),
        ] {
            check_gain(name, v)?;
        }
        let nq = scene.nq();
        let (apparent_inertia, diagonal_inertia) =
            apparent_inertias(&scene, &[scene.home_configuration(), scene.start_configuration()])?;
        Ok(Self {
            apparent_inertia,
            diagonal_inertia,
            scene,
            config,
            dt,
            integral: vec![0.0; nq],
            previous_reference: vec![0.0; nq],
            has_previous: false,
            workspace: DynamicsWorkspace::default(),
            mass_matrix: DMatrix::zeros(nq, nq),
            gravity_torque: DVector::zeros(nq),
            acceleration: DVector::zeros(nq),
            pi_acceleration: DVector::zeros(nq),
            inertial_torque: DVector::zeros(nq),
            command_step: None,
            command: vec![0.0; nq],
        })
    }

    /// Rate-limits the command this controller tracks, as a robot's command path does (a base
    /// driver's ramp, a trajectory's or a stream's acceleration bound): each call moves the tracked
    /// command from the last one toward the reference by at most `caps` (nq, positive; rad/s² or
    /// m/s²) times the control step, starting after a reset from the measured velocity. None: the
    /// reference is tracked as given. The rollout model's servo does the same with
    /// `RolloutConfig::command_acceleration`. Errors: a wrong length or a bound not positive.
    pub fn set_command_acceleration(&mut self, caps: Option<&[f64]>) -> Result<()> {
        let Some(caps) = caps else {
            self.command_step = None;
            return Ok(());
        };
        ensure_len("command_acceleration", caps, self.scene.nq())?;
        if let Some(bad) = caps.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
            return Err(SabreError::invalid(
                "command_acceleration",
                format!("bounds must be finite and positive, got {bad}"),
            ));
        }
        self.command_step = Some(caps.iter().map(|a| a * self.dt).collect());
        Ok(())
    }

    /// The per-joint bounds of [`Self::set_command_acceleration`] (rad/s² or m/s²), if set.
    pub fn command_acceleration(&self) -> Option<Vec<f64>> {
        self.command_step.as_ref().map(|s| s.iter().map(|v| v / self.dt).collect())
    }

    pub fn config(&self) -> &LowLevelConfig {
        &self.config
    }

    /// The scene of the robot this controller drives.
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// Changes the gain inertia floor between ticks (gain scheduling, e.g. per task phase); the
    /// integral state is kept.
    pub fn set_gain_inertia_floor(&mut self, floor: f64) -> Result<()> {
        check_gain("gain_inertia_floor", floor)?;
        self.config.gain_inertia_floor = floor;
        Ok(())
    }

    /// The largest loop gain per step `plant_dt` among the joints with gain inertia floor `floor`,
    /// and the joint that has it: Λ_D dt (1 + A_ii / m_i), the share of a joint's velocity error one
    /// step removes, with m_i = 1 / (M⁻¹)_ii the inertia the joint feels (the M(q) part of the gains
    /// gives Λ_D exactly; the floor's A_ii = max(0, floor − M_ii) adds A_ii / m_i times more).
    pub fn loop_gain(&self, floor: f64, plant_dt: f64) -> (f64, usize) {
        (0..self.apparent_inertia.len())
            .map(|i| {
                let extra = (floor - self.diagonal_inertia[i]).max(0.0) / self.apparent_inertia[i];
                (self.config.bandwidth * plant_dt * (1.0 + extra), i)
            })
            .fold((0.0, 0), |best, g| if g.0 > best.0 { g } else { best })
    }

    /// The largest gain inertia floor (kg m²) whose loop gain stays within [`MAX_LOOP_GAIN`] at plant
    /// step `plant_dt` (0 when the bandwidth alone exceeds it).
    pub fn max_stable_floor(&self, plant_dt: f64) -> f64 {
        let allowed = MAX_LOOP_GAIN / (self.config.bandwidth * plant_dt) - 1.0;
        if allowed < 0.0 {
            return 0.0;
        }
        (0..self.apparent_inertia.len())
            .map(|i| self.diagonal_inertia[i] + allowed * self.apparent_inertia[i])
            .fold(f64::INFINITY, f64::min)
    }

    /// Refuses gains that would make a joint's loop diverge at plant step `plant_dt` (see
    /// [`Self::loop_gain`]), naming the joint and the largest floor that would do.
    pub fn check_stable(&self, floor: f64, plant_dt: f64) -> Result<()> {
        let (gain, joint) = self.loop_gain(floor, plant_dt);
        if gain <= MAX_LOOP_GAIN + 1e-12 {
            return Ok(());
        }
        let name = &self.scene.robot.joints[self.scene.robot.active_joints[joint]].name;
        Err(SabreError::invalid(
            "low-level gains",
            format!(
                "joint '{name}' (inertia {:.3e} kg m² with the others free) would get a loop gain of {gain:.2} per {plant_dt} s \
                 plant step with bandwidth {} 1/s and gain inertia floor {floor} kg m²: above {MAX_LOOP_GAIN} each step \
                 overshoots and above 2 the joint diverges; use a floor of at most {:.4} kg m², a lower bandwidth or a \
                 shorter step",
                self.apparent_inertia[joint],
                self.config.bandwidth,
                self.max_stable_floor(plant_dt)
            ),
        ))
    }

    pub fn reset(&mut self) {
        self.integral.iter_mut().for_each(|v| *v = 0.0);
        self.has_previous = false;
    }

    /// The accumulated velocity error ∫(q̇* − q̇) per joint (rad or m, within ±`integral_limit`): how
    /// far each joint trails the position its velocity reference has integrated to. The integral term
    /// drives it to zero, so the joint still travels this far once the reference stops.
    pub fn position_error(&self) -> &[f64] {
        &self.integral
    }

    /// Clamps joint `joint`'s position error into [lower, upper] (lower ≤ 0 ≤ upper): the position the
    /// controller steers the joint to, q + error, no further than that from where it is.
    pub fn clamp_position_error(&mut self, joint: usize, lower: f64, upper: f64) {
        if let Some(e) = self.integral.get_mut(joint) {
            *e = e.clamp(lower.min(0.0), upper.max(0.0));
        }
    }

    /// Joint torques that make the robot at state `x` track the velocity reference `u_ref`.
    pub fn torque(&mut self, x: &[f64], u_ref: &[f64]) -> Result<Vec<f64>> {
        let mut tau = vec![0.0; self.scene.nq()];
        self.torque_into(x, u_ref, self.config.gain_inertia_floor, &mut tau)?;
        Ok(tau)
    }

    /// [`Self::torque`] into `tau` (nq) with the gain inertia floor `gain_inertia_floor` for this
    /// call instead of the configured one (a plan's phase schedules its own); allocates nothing.
    pub fn torque_into(&mut self, x: &[f64], u_ref: &[f64], gain_inertia_floor: f64, tau: &mut [f64]) -> Result<()> {
        let nq = self.scene.nq();
        self.scene.check_state(x)?;
        ensure_len("u_ref", u_ref, nq)?;
        ensure_finite("u_ref", u_ref)?;
        ensure_len("tau", tau, nq)?;
        check_gain("gain_inertia_floor", gain_inertia_floor)?;
        let q = &x[..nq];
        let qd = &x[nq..2 * nq];
        joint_space_terms(
            &self.scene.robot,
            &Isometry3::identity(),
            q,
            &crate::model::GRAVITY,
            &mut self.workspace,
            &mut self.mass_matrix,
            &mut self.gravity_torque,
        );
        // the command tracked: the reference, or its rate-limited follower from the last call's
        // (from the measured velocity after a reset)
        if let Some(step) = &self.command_step {
            for i in 0..nq {
                let from = if self.has_previous { self.command[i] } else { qd[i] };
                self.command[i] = u_ref[i].clamp(from - step[i], from + step[i]);
            }
        } else {
            self.command.copy_from_slice(u_ref);
        }
        let u_ref = &self.command;
        let c = &self.config;
        for i in 0..nq {
            let error = u_ref[i] - qd[i];
            self.integral[i] = (self.integral[i] + error * self.dt).clamp(-c.integral_limit, c.integral_limit);
            let feedforward = if self.has_previous {
                (u_ref[i] - self.previous_reference[i]) / self.dt
            } else {
                0.0
            };
            self.pi_acceleration[i] = c.bandwidth * error + c.integral_gain * self.integral[i];
            // Summed as (53) is written, the floor's term added separately below,
            // so that a zero floor gives exactly the torque of plain (53).
            self.acceleration[i] = feedforward + c.bandwidth * error + c.integral_gain * self.integral[i];
        }
        self.previous_reference.copy_from_slice(u_ref);
        self.has_previous = true;
        self.mass_matrix.mul_to(&self.acceleration, &mut self.inertial_torque);
        for (i, tau) in tau.iter_mut().enumerate() {
            *tau = self.inertial_torque[i] + self.gravity_torque[i];
            let extra = gain_inertia_floor - self.mass_matrix[(i, i)];
            if extra > 0.0 {
                *tau += extra * self.pi_acceleration[i];
            }
        }
        Ok(())
    }
}
