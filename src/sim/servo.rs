//! The rollout model's joint velocity servo (57) with the integral action of the plant's controller
//! (53), integrated in joint space: its gains, its limits and its state. Both contact paths of the
//! rollout model (Rapier's pipeline and the reduced solve) drive the robot with it.

use nalgebra::{DMatrix, DVector, Isometry3, Vector3};

use crate::error::{Result, SabreError};
use crate::model::dynamics::{joint_space_terms, DynamicsWorkspace};
use crate::model::scene::Scene;

/// Gains of q̈ = Λ (u − q̇) + Λ_I ∫(u − q̇) + M(q)⁻¹ τ_ext.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoGains {
    /// Λ (1/s).
    pub bandwidth: f64,
    /// Λ_I (1/s²).
    pub integral_gain: f64,
    /// Bound on the accumulated velocity error (rad or m).
    pub integral_limit: f64,
}

/// Checks a world's step and its servo's bandwidth (None: a world without the servo), shared by
/// both contact paths' constructors.
pub fn validate_step(dt: f64, bandwidth: Option<f64>) -> Result<()> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(SabreError::invalid("dt", format!("must be positive and finite, got {dt}")));
    }
    match bandwidth {
        Some(b) if !(b.is_finite() && b > 0.0) => {
            Err(SabreError::invalid("servo bandwidth", format!("must be positive, got {b}")))
        }
        _ => Ok(()),
    }
}

/// Per-joint bounds of the servo, fixed for a scene.
#[derive(Debug, Clone)]
pub struct ServoLimits {
    /// Largest joint acceleration the servo can produce: effort / M_ii at the home configuration.
    pub acceleration: Vec<f64>,
    pub velocity: Vec<f64>,
    pub position: Vec<(f64, f64)>,
    /// Per joint: whether the mass matrix changes as it moves, the joints whose motion calls for a
    /// new factor (a mobile base's x and y do not).
    pub moves_mass: Vec<bool>,
    /// Per joint, the most the command may change in a step (see [`Self::cap_acceleration`]); None:
    /// the command is taken as given.
    pub command_step: Option<Vec<f64>>,
}

impl ServoLimits {
    pub fn new(scene: &Scene) -> Result<Self> {
        let (mass_matrix, _) = scene.mass_matrix_and_gravity(&scene.home_configuration())?;
        let limits = scene.robot_limits();
        Ok(Self {
            acceleration: limits
                .iter()
                .enumerate()
                .map(|(i, l)| l.effort / mass_matrix[(i, i)].max(1e-9))
                .collect(),
            velocity: limits.iter().map(|l| l.velocity).collect(),
            position: limits.iter().map(|l| (l.lower, l.upper)).collect(),
            moves_mass: scene.robot.mass_invariant_coordinates().iter().map(|&i| !i).collect(),
            command_step: None,
        })
    }
}

impl ServoLimits {
    /// Rate-limits the servo's command as a robot's command path does (a trajectory's or a stream's
    /// acceleration bound, a base driver's ramp): each step the command moves from the last by at
    /// most `caps` (nq, positive; rad/s² or m/s²) times `dt`, the world's step. The servo tracks
    /// that command with its bandwidth and effort, and contacts push the joints as before.
    pub fn cap_acceleration(&mut self, caps: &[f64], dt: f64) -> Result<()> {
        if caps.len() != self.acceleration.len() {
            return Err(SabreError::invalid(
                "command_acceleration",
                format!(
                    "needs one bound per robot joint ({}), got {}",
                    self.acceleration.len(),
                    caps.len()
                ),
            ));
        }
        if let Some(bad) = caps.iter().find(|a| a.is_nan() || **a <= 0.0) {
            return Err(SabreError::invalid(
                "command_acceleration",
                format!("bounds must be positive, got {bad}"),
            ));
        }
        self.command_step = Some(caps.iter().map(|a| a * dt).collect());
        Ok(())
    }
}

/// The servo's state: configuration, velocity, accumulated lag, the command of the next step and
/// the factorised mass matrix of the contact term.
#[derive(Clone, Debug)]
pub struct ServoState {
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    /// Accumulated velocity error of the integral term.
    pub integral: Vec<f64>,
    /// Velocity command of the next step, projected onto the velocity limits.
    pub command: Vec<f64>,
    /// The configuration at the end of the step being taken (see [`Self::advance`]).
    q_next: Vec<f64>,
    /// The Cholesky factor L of the robot's mass matrix for the contact term (nq × nq, column-major
    /// as nalgebra keeps it, lower triangle; empty until computed) and the configuration it was
    /// computed at (recomputed once the robot has moved on). Kept in a plain buffer: the two substitutions per step on it
    /// cost a fraction of nalgebra's dynamically sized ones, and a copy of the state reuses it.
    mass_factor: Vec<f64>,
    mass_factor_q: Vec<f64>,
    /// M⁻¹ τ_ext of the step being taken.
    contact_acceleration: Vec<f64>,
}

/// M(q) varies slowly; refactorising it only after a joint it depends on moved by this much (rad or
/// m) keeps the contact term within a few percent at a fraction of the cost.
const MASS_REFRESH: f64 = 0.02;

impl ServoState {
    pub fn new(nq: usize) -> Self {
        Self {
            q: vec![0.0; nq],
            qd: vec![0.0; nq],
            integral: vec![0.0; nq],
            command: vec![0.0; nq],
            q_next: Vec::with_capacity(nq),
            mass_factor: Vec::with_capacity(nq * nq),
            mass_factor_q: Vec::new(),
            contact_acceleration: vec![0.0; nq],
        }
    }

    /// Places the servo at (q, q̇) with no accumulated lag and no cached mass matrix, its command at
    /// q̇ (where a rate-limited command path is when the robot moves at q̇).
    pub fn reset(&mut self, q: &[f64], qd: &[f64]) {
        self.q.copy_from_slice(q);
        self.qd.copy_from_slice(qd);
        self.integral.iter_mut().for_each(|v| *v = 0.0);
        self.command.copy_from_slice(qd);
        self.mass_factor.clear();
    }

    /// Sets the command of the next step, projected onto the joint velocity limits and, with a
    /// command path's bound ([`ServoLimits::cap_acceleration`]), moved toward `u` by at most its step.
    pub fn set_command(&mut self, u: &[f64], limits: &ServoLimits) {
        for (i, (&v, &limit)) in u.iter().zip(&limits.velocity).enumerate() {
            let v = v.clamp(-limit, limit);
            self.command[i] = match &limits.command_step {
                Some(step) => v.clamp(self.command[i] - step[i], self.command[i] + step[i]),
                None => v,
            };
        }
    }

    /// One step of semi-implicit Euler of q̈ = Λ (u − q̇) + Λ_I ∫(u − q̇) + M⁻¹ τ_ext: updates q̇ and
    /// the lag and computes the configuration at the end of the step, which [`Self::commit`] makes
    /// current. In between, `q` is still the step's start, where the contact bodies are placed.
    /// `dynamics`, `mass_matrix` and `gravity_torque` are the caller's scratch buffers: what they
    /// hold on return is unspecified.
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &mut self,
        gains: &ServoGains,
        limits: &ServoLimits,
        scene: &Scene,
        tau_ext: &[f64],
        dt: f64,
        dynamics: &mut DynamicsWorkspace,
        mass_matrix: &mut DMatrix<f64>,
        gravity_torque: &mut DVector<f64>,
    ) {
        let nq = self.q.len();
        let in_contact = tau_ext.iter().any(|&t| t != 0.0);
        let stale = self.mass_factor.is_empty()
            || self
                .mass_factor_q
                .iter()
                .zip(&self.q)
                .zip(&limits.moves_mass)
                .any(|((a, b), &moves)| moves && (a - b).abs() > MASS_REFRESH);
        if in_contact && stale {
            joint_space_terms(
                &scene.robot,
                &Isometry3::identity(),
                &self.q,
                &Vector3::zeros(),
                dynamics,
                mass_matrix,
                gravity_torque,
            );
            self.mass_factor.clear();
            // The factorisation works in the mass matrix's own buffer, which goes back for the
            // next refresh (its contents are rebuilt there).
            let matrix = std::mem::replace(mass_matrix, DMatrix::zeros(0, 0));
            if let Some(factor) = matrix.cholesky() {
                let l = factor.l_dirty();
                self.mass_factor.extend_from_slice(l.as_slice());
                *mass_matrix = factor.unpack_dirty();
            }
            self.mass_factor_q.clone_from(&self.q);
        }
        let contact = in_contact && !self.mass_factor.is_empty();
        if contact {
            solve_factored(&self.mass_factor, tau_ext, &mut self.contact_acceleration);
        }
        self.q_next.clear();
        for i in 0..nq {
            let qd = self.qd[i];
            let external = if contact { self.contact_acceleration[i] } else { 0.0 };
            // The integral is the position lag behind the integrated command, ∫u dt − (q − q₀),
            // booked with the same velocity that moves q so that it settles at zero lag exactly.
            let integral = self.integral[i];
            let drive = gains.bandwidth * self.command[i] + gains.integral_gain * integral + external;
            let target = (qd + dt * drive) / (1.0 + dt * gains.bandwidth);
            let max_change = limits.acceleration[i] * dt;
            let saturated = (target - qd).abs() > max_change;
            let velocity_limit = limits.velocity[i];
            let unclamped = qd + (target - qd).clamp(-max_change, max_change);
            let mut qd_next = unclamped.clamp(-velocity_limit, velocity_limit);
            let saturated = saturated || qd_next != unclamped;
            let (lower, upper) = limits.position[i];
            let mut next = self.q[i] + dt * qd_next;
            let at_limit = next < lower || next > upper;
            if at_limit {
                next = next.clamp(lower, upper);
                qd_next = (next - self.q[i]) / dt;
            }
            // Anti-windup: a joint that is saturated or at a limit does not accumulate lag it
            // cannot act on.
            if !saturated && !at_limit {
                let lag = integral + dt * self.command[i] - (next - self.q[i]);
                self.integral[i] = lag.clamp(-gains.integral_limit, gains.integral_limit);
            }
            self.q_next.push(next);
            self.qd[i] = qd_next;
        }
    }

    /// Makes the configuration computed by [`Self::advance`] current.
    pub fn commit(&mut self) {
        std::mem::swap(&mut self.q, &mut self.q_next);
    }
}

/// x = (L Lᵀ)⁻¹ b for the lower-triangular factor L (n × n, column-major; the upper triangle is
/// not read): forward substitution for L y = b column by column, then back substitution for
/// Lᵀ x = y, each reading L's columns in order.
fn solve_factored(l: &[f64], b: &[f64], x: &mut [f64]) {
    let n = b.len();
    x[..n].copy_from_slice(b);
    for j in 0..n {
        let column = &l[j * n..(j + 1) * n];
        let y = x[j] / column[j];
        x[j] = y;
        for (xk, lk) in x[j + 1..n].iter_mut().zip(&column[j + 1..]) {
            *xk -= lk * y;
        }
    }
    for i in (0..n).rev() {
        let column = &l[i * n..(i + 1) * n];
        let partial: f64 = column[i + 1..].iter().zip(&x[i + 1..n]).map(|(a, b)| a * b).sum();
        x[i] = (x[i] - partial) / column[i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_factored_solve_inverts_the_mass_matrix() {
        // A symmetric positive definite matrix, its factor by nalgebra, and b = M x for a known x.
        let a = DMatrix::from_fn(4, 4, |r, c| ((r * 4 + c) as f64 * 0.37).sin());
        let m = &a * a.transpose() + DMatrix::identity(4, 4);
        let l = m.clone().cholesky().expect("positive definite").l();
        let l = l.as_slice().to_vec();
        let expected = DVector::from_vec(vec![0.3, -1.2, 2.0, 0.7]);
        let b = &m * &expected;
        let mut x = vec![0.0; 4];
        solve_factored(&l, b.as_slice(), &mut x);
        for (got, want) in x.iter().zip(expected.iter()) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
    }

    #[test]
    fn moving_only_the_base_keeps_the_factor_and_its_contact_term_stays_exact() {
        let scene = Scene::load("royalpanda", "shelf", None).expect("built-in scene");
        let limits = ServoLimits::new(&scene).expect("limits");
        let gains = ServoGains {
            bandwidth: 30.0,
            integral_gain: 0.0,
            integral_limit: 1.0,
        };
        let nq = scene.nq();
        let tau: Vec<f64> = (0..nq).map(|i| 0.5 + 0.1 * i as f64).collect();
        let (mut ws, mut m, mut g) = (DynamicsWorkspace::default(), DMatrix::zeros(0, 0), DVector::zeros(0));
        let mut servo = ServoState::new(nq);
        let home = scene.home_configuration();
        servo.reset(&home, &vec![0.0; nq]);
        let mut step = |servo: &mut ServoState, q: &[f64]| {
            servo.q.copy_from_slice(q);
            servo.advance(&gains, &limits, &scene, &tau, 0.01, &mut ws, &mut m, &mut g);
            servo.mass_factor_q.clone()
        };
        assert_eq!(step(&mut servo, &home), home, "the first contact step factorises");
        // The base driven 0.8 m away: no new factor, and the contact term is still M(q)⁻¹ τ at
        // the new configuration.
        let mut driven = home.clone();
        driven[0] += 0.5;
        driven[1] -= 0.6;
        assert_eq!(step(&mut servo, &driven), home, "x and y do not call for a new factor");
        let (m_driven, _) = scene.mass_matrix_and_gravity(&driven).expect("M");
        let expected = m_driven.lu().solve(&DVector::from_column_slice(&tau)).expect("invertible");
        for (got, want) in servo.contact_acceleration.iter().zip(expected.iter()) {
            assert!((got - want).abs() <= 1e-9 * (1.0 + want.abs()), "{got} vs {want}");
        }
        // The base's yaw and an arm joint past the threshold do.
        for joint in [2, 5] {
            let mut turned = driven.clone();
            turned[joint] += 2.0 * MASS_REFRESH;
            assert_eq!(step(&mut servo, &turned), turned, "joint {joint} calls for a new factor");
            driven = turned;
        }
    }

    fn rejected(dt: f64, bandwidth: Option<f64>) -> Option<String> {
        match validate_step(dt, bandwidth) {
            Err(SabreError::InvalidValue { what, .. }) => Some(what),
            Err(other) => panic!("not an invalid value: {other}"),
            Ok(()) => None,
        }
    }

    #[test]
    fn a_step_or_bandwidth_that_is_not_positive_and_finite_is_an_invalid_value_naming_it() {
        for dt in [0.0, -0.015, f64::NAN, f64::INFINITY] {
            assert_eq!(rejected(dt, Some(30.0)).as_deref(), Some("dt"), "dt = {dt}");
        }
        for b in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                rejected(0.015, Some(b)).as_deref(),
                Some("servo bandwidth"),
                "bandwidth = {b}"
            );
        }
        assert_eq!(rejected(0.015, Some(30.0)), None);
        assert_eq!(rejected(0.015, None), None);
    }
}
