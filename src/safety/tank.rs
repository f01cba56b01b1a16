//! The virtual energy tank (Sec. III-C, IV-C): S integrates the power port (q̇*, τ_ext), Ṡ = τ_extᵀ u (49).

use crate::error::{ensure_finite, ensure_len, Result, SabreError};

/// Refill of the tank by the energy the current plan is predicted to need (beyond the paper).
///
/// A fixed budget runs out on a long task: opening the shelf costs about 4 J per radian and every
/// contact before the open phase spends more. While the plant does what the rollout model
/// predicted, the tank is refilled by the dissipation −τ_extᵀu through the port (49) that the
/// model predicts along the current plan, at most `max_rate`, and never above S(0). Measured
/// (−τ̂ᵀu of the reference) and predicted dissipation each pass a first-order low-pass of
/// `time_constant` and must agree within `tolerance` + `relative_tolerance`·|predicted|: a stall
/// the model did not predict (a held door: the model lets it move, the plant's wrench grows)
/// disagrees, the refill stops, and the passivity row bounds the wrench as in the paper.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefillConfig {
    /// Most power (W) the refill adds.
    pub max_rate: f64,
    /// Absolute agreement band (W) between measured and predicted dissipation.
    pub tolerance: f64,
    /// Agreement band relative to the predicted dissipation.
    pub relative_tolerance: f64,
    /// Time constant (s) of the low-pass on both dissipations.
    pub time_constant: f64,
}

impl Default for RefillConfig {
    fn default() -> Self {
        Self {
            max_rate: 2.0,
            tolerance: 0.2,
            relative_tolerance: 0.5,
            time_constant: 0.1,
        }
    }
}

impl RefillConfig {
    pub fn validate(&self) -> Result<()> {
        for (name, value) in [
            ("refill max_rate", self.max_rate),
            ("refill tolerance", self.tolerance),
            ("refill relative_tolerance", self.relative_tolerance),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SabreError::invalid(
                    name,
                    format!("must be finite and non-negative, got {value}"),
                ));
            }
        }
        if !(self.time_constant.is_finite() && self.time_constant > 0.0) {
            return Err(SabreError::invalid(
                "refill time_constant",
                format!("must be finite and positive, got {}", self.time_constant),
            ));
        }
        Ok(())
    }
}

/// The refill's low-passed dissipations.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct RefillState {
    measured: f64,
    predicted: f64,
    primed: bool,
}

/// Tank energy S with floor ε and optional ceiling.
///
/// Sign: τ_ext is the external torque acting on the robot, so −τ_extᵀu is the power the robot
/// pushes into the environment (P_diss, positive when acting against it); it drains the tank.
/// Power the environment does on the robot refills it. The tank is integrated with explicit Euler
/// at the caller's dt and never clamped at the floor: keeping S ≥ ε is the passivity row's job,
/// and a reading below ε is reported, not hidden.
#[derive(Debug, Clone, PartialEq)]
pub struct EnergyTank {
    initial: f64,
    energy: f64,
    floor: f64,
    /// Energy above this is discarded (the tank "valve" closes), so a long phase in which the
    /// environment feeds the robot cannot store an unbounded budget for later active behaviour.
    ceiling: Option<f64>,
    record: bool,
    history: Vec<f64>,
    refill: Option<RefillConfig>,
    refill_state: RefillState,
    refilled: f64,
}

impl EnergyTank {
    /// A tank holding `initial` J (the paper: 10 J) with floor `floor` (2 J). `ceiling`, if given,
    /// must be at least `initial`. With `record_history` every step's energy is kept (S(0) first).
    pub fn new(initial: f64, floor: f64, ceiling: Option<f64>, record_history: bool) -> Result<Self> {
        if !(floor.is_finite() && floor >= 0.0) {
            return Err(SabreError::invalid(
                "tank floor",
                format!("must be finite and non-negative, got {floor}"),
            ));
        }
        if !(initial.is_finite() && initial >= floor) {
            return Err(SabreError::invalid(
                "tank initial energy",
                format!("must be finite and at least the floor {floor}, got {initial}"),
            ));
        }
        if let Some(c) = ceiling {
            if !(c.is_finite() && c >= initial) {
                return Err(SabreError::invalid(
                    "tank ceiling",
                    format!("must be finite and at least the initial energy {initial}, got {c}"),
                ));
            }
        }
        let mut tank = Self {
            initial,
            energy: initial,
            floor,
            ceiling,
            record: record_history,
            history: Vec::new(),
            refill: None,
            refill_state: RefillState::default(),
            refilled: 0.0,
        };
        tank.reset();
        Ok(tank)
    }

    /// Back to the initial energy; the history restarts with S(0).
    pub fn reset(&mut self) {
        self.energy = self.initial;
        self.refill_state = RefillState::default();
        self.refilled = 0.0;
        self.history.clear();
        if self.record {
            self.history.push(self.initial);
        }
    }

    /// τ_extᵀ u: the power flowing into the tank (negative while the robot dissipates).
    pub fn power(tau_ext: &[f64], u: &[f64]) -> f64 {
        tau_ext.iter().zip(u).map(|(t, v)| t * v).sum()
    }

    /// One Euler step S ← S + dt τ_extᵀ u (then the ceiling); returns the new energy.
    pub fn step(&mut self, tau_ext: &[f64], u: &[f64], dt: f64) -> Result<f64> {
        ensure_len("u", u, tau_ext.len())?;
        ensure_finite("tau_ext", tau_ext)?;
        ensure_finite("u", u)?;
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be finite and positive, got {dt}")));
        }
        let energy = self.energy + dt * Self::power(tau_ext, u);
        if !energy.is_finite() {
            // τ_ext, u and dt are each finite, but their product overflows: no physical exchange.
            return Err(SabreError::invalid(
                "tank step",
                format!(
                    "the energy exchanged over dt = {dt:e} s overflows (τ_extᵀu = {:e}); the tank is unchanged",
                    Self::power(tau_ext, u)
                ),
            ));
        }
        self.energy = energy;
        if let Some(c) = self.ceiling {
            self.energy = self.energy.min(c);
        }
        if self.record {
            self.history.push(self.energy);
        }
        Ok(self.energy)
    }

    /// Turns the refill on (Some) or off (None).
    pub fn set_refill(&mut self, refill: Option<RefillConfig>) -> Result<()> {
        if let Some(r) = &refill {
            r.validate()?;
        }
        self.refill = refill;
        self.refill_state = RefillState::default();
        Ok(())
    }

    pub fn refill_config(&self) -> Option<RefillConfig> {
        self.refill
    }

    /// One refill step (see [`RefillConfig`]): `predicted` and `measured` are the port dissipation
    /// −τ_extᵀu (W) the plan's rollout predicts at this instant and the measured one.
    /// Returns the energy added (J); 0 without a refill configured. Does not touch the history:
    /// the next [`EnergyTank::step`] records the sum.
    pub fn refill(&mut self, predicted: f64, measured: f64, dt: f64) -> Result<f64> {
        let Some(config) = self.refill else {
            return Ok(0.0);
        };
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be finite and positive, got {dt}")));
        }
        if !(predicted.is_finite() && measured.is_finite()) {
            // No prediction to trust (a failed rollout) or a broken reading: no refill this step.
            return Ok(0.0);
        }
        let s = &mut self.refill_state;
        if s.primed {
            let a = dt / (config.time_constant + dt);
            s.measured += a * (measured - s.measured);
            s.predicted += a * (predicted - s.predicted);
        } else {
            *s = RefillState {
                measured,
                predicted,
                primed: true,
            };
        }
        let band = config.tolerance + config.relative_tolerance * s.predicted.abs();
        if (s.measured - s.predicted).abs() > band {
            return Ok(0.0);
        }
        let room = (self.initial - self.energy).max(0.0);
        let added = (dt * s.predicted.clamp(0.0, config.max_rate)).min(room);
        self.energy += added;
        self.refilled += added;
        Ok(added)
    }

    /// Energy (J) the refill has added since the last reset.
    pub fn refilled(&self) -> f64 {
        self.refilled
    }

    pub fn energy(&self) -> f64 {
        self.energy
    }
    pub fn initial(&self) -> f64 {
        self.initial
    }
    pub fn floor(&self) -> f64 {
        self.floor
    }
    pub fn ceiling(&self) -> Option<f64> {
        self.ceiling
    }
    /// E_res = S − ε, the energy the passivity row still lets the robot dissipate.
    pub fn residual(&self) -> f64 {
        self.energy - self.floor
    }
    /// S(0), then the energy after every step (empty without `record_history`).
    pub fn history(&self) -> &[f64] {
        &self.history
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tank(initial: f64) -> EnergyTank {
        let mut t = EnergyTank::new(initial, 2.0, None, true).unwrap();
        t.set_refill(Some(RefillConfig::default())).unwrap();
        t
    }

    #[test]
    fn agreeing_dissipation_refills_at_the_predicted_rate_up_to_the_cap_and_never_above_the_start() {
        let mut t = tank(10.0);
        t.step(&[-1.0], &[1.0], 1.0).unwrap(); // spend 1 J: S = 9
        assert!((t.refill(0.5, 0.5, 0.1).unwrap() - 0.05).abs() < 1e-15);
        let cap = RefillConfig::default().max_rate;
        let mut u = tank(10.0);
        u.step(&[-1.0], &[1.0], 1.0).unwrap();
        u.refill(10.0, 10.0, 0.1).unwrap(); // primes the low-pass at 10 W
        let added = u.refill(10.0, 10.0, 0.1).unwrap();
        assert!((added - 0.1 * cap).abs() < 1e-12, "{added}");
        for _ in 0..100 {
            u.refill(10.0, 10.0, 0.1).unwrap();
        }
        assert_eq!(u.energy(), 10.0);
        assert!((u.refilled() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn disagreement_beyond_the_band_stops_the_refill_after_the_low_pass() {
        let c = RefillConfig::default();
        let mut t = tank(10.0);
        t.step(&[-5.0], &[1.0], 1.0).unwrap();
        t.refill(1.0, 1.0, 0.001).unwrap();
        // Measured jumps to 5 W while 1 W is predicted: band = tolerance + relative · 1 W.
        let band = c.tolerance + c.relative_tolerance;
        let mut steps_until_stop = 0;
        while t.refill(1.0, 5.0, 0.001).unwrap() > 0.0 {
            steps_until_stop += 1;
            assert!(steps_until_stop < 1000);
        }
        // The low-pass crosses the band after −τ ln(1 − band / 4 W).
        let expected = -c.time_constant * (1.0 - band / 4.0).ln() / 0.001;
        assert!(
            (steps_until_stop as f64 - expected).abs() < 2.0,
            "{steps_until_stop} vs {expected}"
        );
        assert_eq!(t.refill(1.0, 5.0, 0.001).unwrap(), 0.0);
    }

    #[test]
    fn no_refill_without_a_config_a_finite_prediction_or_positive_power() {
        let mut plain = EnergyTank::new(10.0, 2.0, None, false).unwrap();
        plain.step(&[-1.0], &[1.0], 1.0).unwrap();
        assert_eq!(plain.refill(1.0, 1.0, 0.1).unwrap(), 0.0);
        let mut t = tank(10.0);
        t.step(&[-1.0], &[1.0], 1.0).unwrap();
        assert_eq!(t.refill(f64::NAN, 1.0, 0.1).unwrap(), 0.0);
        assert_eq!(t.refill(-1.0, -1.0, 0.1).unwrap(), 0.0); // the environment feeds the robot: the port books it
        assert!(t.refill(1.0, 1.0, 0.0).is_err());
        let bad = RefillConfig {
            time_constant: 0.0,
            ..RefillConfig::default()
        };
        assert!(t.set_refill(Some(bad)).is_err());
        t.reset();
        assert_eq!(t.refilled(), 0.0);
    }
}
