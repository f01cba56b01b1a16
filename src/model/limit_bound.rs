//! The hard joint-limit bound: the fastest command toward a joint limit from which a stop at the
//! command's deceleration (and jerk), starting after the command's delay, still ends a margin inside
//! the limit.

use super::kinematics::JointKind;
use super::scene::Scene;
use crate::error::{Result, SabreError};

/// Settings of [`LimitBound`]. Lengths in rad for revolute joints and m for prismatic ones.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LimitBoundConfig {
    /// Distance (rad) a revolute joint's stop must end inside its URDF limit.
    pub margin: f64,
    /// Distance (m) a prismatic joint's stop must end inside its URDF limit.
    pub prismatic_margin: f64,
    /// The deceleration (rad/s², m/s² for prismatic joints) a stop may use on a joint whose
    /// command no rate limiter shapes (a torque-controlled plant's, which can brake as hard as its
    /// effort limits allow); a shaped joint brakes at its limiter's bound instead.
    pub deceleration: f64,
}

impl Default for LimitBoundConfig {
    /// 0.02 rad covers what a stop computed from the measured position cannot see: the plant lags
    /// its command (a torque-controlled joint trails its velocity reference while it brakes), the
    /// joint state is a measurement, and the limiter's discrete steps differ from the continuous
    /// stop the bound is solved for. Prismatic joints are a mobile base's x and y here, whose
    /// wheels and driver follow a twist less tightly than an arm joint follows its command, and
    /// whose command streams turn with the base (see `docs/design.md`): 0.05 m. The deceleration
    /// 7.5 rad/s² is Franka's smallest joint bound (panda_joint2's), which the simulated Panda's
    /// efforts reach against gravity where a larger one leaves the shoulder falling while it brakes.
    fn default() -> Self {
        Self {
            margin: 0.02,
            prismatic_margin: 0.05,
            deceleration: 7.5,
        }
    }
}

impl LimitBoundConfig {
    /// Checks the numbers on their own (see [`LimitBound::new`] for the check against a robot).
    pub fn validate(&self) -> Result<()> {
        for (name, m) in [
            ("limit_margin", self.margin),
            ("prismatic_limit_margin", self.prismatic_margin),
        ] {
            if !(m.is_finite() && m >= 0.0) {
                return Err(SabreError::invalid(name, format!("must be finite and non-negative, got {m}")));
            }
        }
        let a = self.deceleration;
        if !(a.is_finite() && a > 0.0) {
            return Err(SabreError::invalid(
                "limit_deceleration",
                format!("must be finite and positive, got {a}"),
            ));
        }
        Ok(())
    }
}

/// How one joint's command can be stopped: at most `deceleration` (> 0), its rate of change at most
/// `jerk` (> 0; infinite: unbounded), starting `delay` s late (≥ 0: the command already sent runs
/// for one control period before the next one can change it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Braking {
    pub deceleration: f64,
    pub jerk: f64,
    pub delay: f64,
}

/// The distance a joint moving at `v` ≥ 0 covers until it stands, braking as `b` allows, from any
/// acceleration within ±a: s(v) = v·τ + v²/(2a) + 2v·a/j + (17/24)·a³/j².
///
/// From zero acceleration, the deceleration ramps up at j to a, holds, and ramps down at j; that
/// velocity profile is point-symmetric about its middle, so the stop covers v·T/2 with
/// T = v/a + a/j: v²/(2a) + v·a/(2j). A limiter may still be accelerating outward at a when its stop
/// begins: its acceleration first ramps down to zero (a/j, covering v·a/j + a³/(3j²) and gaining
/// a²/(2j) of speed), then the stop from zero acceleration at v + a²/(2j) follows; expanded, that is
/// the formula, which bounds a stop from any acceleration within ±a. Without a jerk bound both extra
/// terms vanish; the delay τ adds v·τ.
pub fn stopping_distance(v: f64, b: &Braking) -> f64 {
    let (a, r) = (b.deceleration, b.deceleration / b.jerk);
    v * b.delay + v * v / (2.0 * a) + 2.0 * v * r + JERK_REST * a * r * r
}

/// The coefficient of a³/j² in [`stopping_distance`]: 1/3 + 1/8 + 1/4.
const JERK_REST: f64 = 17.0 / 24.0;

/// The largest speed toward a limit `d` away whose stop ([`stopping_distance`]) ends at or before
/// it; 0 when not even a stop from rest fits (d ≤ (17/24)·a³/j²), unbounded for an infinite d.
///
/// s(v) = d is v²/(2a) + c·v − e = 0 with c = τ + 2a/j, e = d − (17/24)·a³/j²; its positive root,
/// written without the cancellation of −c + √(c² + 2e/a): v = 2e / (c + √(c² + 2e/a)).
pub fn velocity_bound(d: f64, b: &Braking) -> f64 {
    if d.is_infinite() && d > 0.0 {
        return f64::INFINITY;
    }
    let (a, r) = (b.deceleration, b.deceleration / b.jerk);
    let e = d - JERK_REST * a * r * r;
    if e.is_nan() || e <= 0.0 {
        return 0.0;
    }
    let c = b.delay + 2.0 * r;
    2.0 * e / (c + (c * c + 2.0 * e / a).sqrt())
}

/// Per joint, how its command is stopped: as set, or, with `delay` None, at the config's
/// deceleration without a jerk bound after one tick of the caller's step.
#[derive(Debug, Clone, Copy, PartialEq)]
struct JointBraking {
    deceleration: f64,
    jerk: f64,
    delay: Option<f64>,
}

/// The hard joint-limit bound of one robot: at position q, joint i's command toward its upper limit
/// is at most [`velocity_bound`] of its distance to (upper − margin), toward its lower limit likewise.
/// A joint at or past (limit − margin) may still move inward, never further out. Coordinates without
/// finite limits are not bounded.
#[derive(Debug, Clone, PartialEq)]
pub struct LimitBound {
    config: LimitBoundConfig,
    /// The limits moved inward by the margin (±∞ for a coordinate without limits).
    lower: Vec<f64>,
    upper: Vec<f64>,
    braking: Vec<JointBraking>,
}

impl LimitBound {
    /// The bound of `scene`'s robot. Errors: a config [`LimitBoundConfig::validate`] refuses, or a
    /// margin larger than half a joint's range (nothing would be left to move in).
    pub fn new(scene: &Scene, config: &LimitBoundConfig) -> Result<Self> {
        config.validate()?;
        let robot = &scene.robot;
        let limits = scene.robot_limits();
        let (mut lower, mut upper) = (Vec::with_capacity(limits.len()), Vec::with_capacity(limits.len()));
        for (i, l) in limits.iter().enumerate() {
            let joint = &robot.joints[robot.active_joints[i]];
            let (margin, name, unit) = match joint.kind {
                JointKind::Prismatic => (config.prismatic_margin, "prismatic_limit_margin", "m"),
                _ => (config.margin, "limit_margin", "rad"),
            };
            if !(l.lower.is_finite() && l.upper.is_finite()) {
                lower.push(f64::NEG_INFINITY);
                upper.push(f64::INFINITY);
                continue;
            }
            if 2.0 * margin > l.upper - l.lower {
                return Err(SabreError::invalid(
                    name,
                    format!(
                        "{margin} {unit} is more than half of joint '{}'s range [{}, {}]",
                        joint.name, l.lower, l.upper
                    ),
                ));
            }
            lower.push(l.lower + margin);
            upper.push(l.upper - margin);
        }
        let plain = JointBraking {
            deceleration: config.deceleration,
            jerk: f64::INFINITY,
            delay: None,
        };
        Ok(Self {
            config: *config,
            braking: vec![plain; lower.len()],
            lower,
            upper,
        })
    }

    pub fn config(&self) -> &LimitBoundConfig {
        &self.config
    }
    pub fn len(&self) -> usize {
        self.lower.len()
    }
    pub fn is_empty(&self) -> bool {
        self.lower.is_empty()
    }
    /// The limits moved inward by the margins (±∞ for coordinates without limits).
    pub fn inner_limits(&self) -> (&[f64], &[f64]) {
        (&self.lower, &self.upper)
    }

    /// Joint `joint`'s command is shaped by a rate limiter with these bounds: its stop brakes at
    /// `deceleration` with `jerk` (infinite: none) and starts `delay` s late (> 0: at least the
    /// limiter's step, longer when a stop can start later than the next step).
    pub fn set_braking(&mut self, joint: usize, deceleration: f64, jerk: f64, delay: f64) -> Result<()> {
        if joint >= self.len() {
            return Err(SabreError::invalid(
                "joint",
                format!("{joint} is past the robot's {} joints", self.len()),
            ));
        }
        for (name, v) in [("deceleration", deceleration), ("jerk", jerk), ("delay", delay)] {
            if v.is_nan() || v <= 0.0 || (name != "jerk" && v.is_infinite()) {
                return Err(SabreError::invalid(name, format!("must be positive, got {v}")));
            }
        }
        self.braking[joint] = JointBraking {
            deceleration,
            jerk,
            delay: Some(delay),
        };
        Ok(())
    }

    /// Joint `joint`'s stop brakes at most at `deceleration` (its controller rate-limits the command
    /// it tracks; positive), whatever else its braking is. Errors: a joint past the robot's, a bound
    /// not positive.
    pub fn cap_deceleration(&mut self, joint: usize, deceleration: f64) -> Result<()> {
        if joint >= self.len() {
            return Err(SabreError::invalid(
                "joint",
                format!("{joint} is past the robot's {} joints", self.len()),
            ));
        }
        if !(deceleration.is_finite() && deceleration > 0.0) {
            return Err(SabreError::invalid(
                "deceleration",
                format!("must be finite and positive, got {deceleration}"),
            ));
        }
        let b = &mut self.braking[joint];
        b.deceleration = b.deceleration.min(deceleration);
        Ok(())
    }

    /// Every joint back to the config's deceleration, no jerk bound and the caller's step.
    pub fn clear_braking(&mut self) {
        let deceleration = self.config.deceleration;
        for b in &mut self.braking {
            *b = JointBraking {
                deceleration,
                jerk: f64::INFINITY,
                delay: None,
            };
        }
    }

    /// Whether joint `i`'s command is shaped by a rate limiter ([`Self::set_braking`]).
    pub fn shaped(&self, i: usize) -> bool {
        self.braking[i].delay.is_some()
    }

    /// Joint `i`'s braking when the caller ticks every `dt` s.
    pub fn braking(&self, i: usize, dt: f64) -> Braking {
        let b = &self.braking[i];
        Braking {
            deceleration: b.deceleration,
            jerk: b.jerk,
            delay: b.delay.unwrap_or(dt),
        }
    }

    /// The commands allowed at positions `q` (the robot's joints) for a caller ticking every `dt`
    /// s: joint i's command within [lower[i], upper[i]], lower[i] ≤ 0 ≤ upper[i].
    pub fn velocity_box(&self, q: &[f64], dt: f64, lower: &mut [f64], upper: &mut [f64]) {
        for i in 0..self.len() {
            let b = self.braking(i, dt);
            upper[i] = velocity_bound(self.upper[i] - q[i], &b);
            lower[i] = -velocity_bound(q[i] - self.lower[i], &b);
        }
    }

    /// Clamps `u` (a command of the robot's joints) into [`Self::velocity_box`] at `q`; returns
    /// whether any component changed.
    pub fn clamp(&self, q: &[f64], dt: f64, u: &mut [f64]) -> bool {
        let mut changed = false;
        for (i, u) in u.iter_mut().enumerate().take(self.len()) {
            let b = self.braking(i, dt);
            let hi = velocity_bound(self.upper[i] - q[i], &b);
            let lo = -velocity_bound(q[i] - self.lower[i], &b);
            let held = u.clamp(lo, hi);
            changed |= held != *u;
            *u = held;
        }
        changed
    }
}

#[cfg(test)]
mod tests;
