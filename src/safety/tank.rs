//! The virtual energy tank (Sec. III-C, IV-C): S integrates the power port (q̇*, τ_ext), Ṡ = τ_extᵀ u (49).

use crate::error::{ensure_finite, ensure_len, Result, SabreError};

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
        };
        tank.reset();
        Ok(tank)
    }

    /// Back to the initial energy; the history restarts with S(0).
    pub fn reset(&mut self) {
        self.energy = self.initial;
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
