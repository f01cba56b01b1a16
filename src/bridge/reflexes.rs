//! The Franka arm's checks of a joint-velocity command stream, emulated for the simulated robot:
//! every control cycle the command in effect must keep the joint velocity, acceleration and jerk
//! limits, the latter two as difference quotients over the cycle; a violation aborts the motion
//! (libfranka's discontinuity reflexes), and the arm ignores commands until recovered.

use crate::error::{Result, SabreError};

/// Relative slack on each limit (libfranka's checks allow the limit itself, within rounding).
pub const LIMIT_TOLERANCE: f64 = 1e-6;

#[derive(Debug, Clone)]
pub struct FrankaReflexes {
    dt: f64,
    /// Velocity, acceleration and jerk limits with their slack.
    limits: [Vec<f64>; 3],
    v: Vec<f64>,
    a: Vec<f64>,
    aborted: Option<String>,
    aborts: usize,
}

const REFLEXES: [(&str, &str); 3] = [
    ("velocity", "velocity_limits_violation"),
    ("acceleration", "velocity_discontinuity"),
    ("jerk", "acceleration_discontinuity"),
];

impl FrankaReflexes {
    /// Checks at cycles of `dt` s against per-joint `velocity`, `acceleration` and `jerk` limits.
    pub fn new(dt: f64, velocity: &[f64], acceleration: &[f64], jerk: &[f64]) -> Result<Self> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be positive and finite, got {dt}")));
        }
        let n = velocity.len();
        for (name, limits) in [("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk)] {
            if limits.len() != n || n == 0 {
                return Err(SabreError::invalid(
                    name,
                    format!("need one limit per joint ({n}), got {}", limits.len()),
                ));
            }
            if !limits.iter().all(|l| l.is_finite() && *l > 0.0) {
                return Err(SabreError::invalid(name, "limits must be positive and finite"));
            }
        }
        let slack = |l: &[f64]| l.iter().map(|v| v * (1.0 + LIMIT_TOLERANCE)).collect();
        Ok(Self {
            dt,
            limits: [slack(velocity), slack(acceleration), slack(jerk)],
            v: vec![0.0; n],
            a: vec![0.0; n],
            aborted: None,
            aborts: 0,
        })
    }

    pub fn joints(&self) -> usize {
        self.v.len()
    }

    /// The violation that aborted the motion, until [`Self::recover`].
    pub fn aborted(&self) -> Option<&str> {
        self.aborted.as_deref()
    }

    pub fn aborts(&self) -> usize {
        self.aborts
    }

    /// Clears an abort; the next check starts from rest.
    pub fn recover(&mut self) {
        self.aborted = None;
        self.v.iter_mut().for_each(|v| *v = 0.0);
        self.a.iter_mut().for_each(|a| *a = 0.0);
    }

    /// Takes `v` as the command in effect without checking it (the robot's own stop).
    pub fn follow(&mut self, v: &[f64]) {
        for ((p, a), &v) in self.v.iter_mut().zip(&mut self.a).zip(v) {
            *a = (v - *p) / self.dt;
            *p = v;
        }
    }

    /// The reflex `v` (the command in effect this cycle) trips, if any (then aborted).
    pub fn check(&mut self, v: &[f64]) -> Option<&str> {
        if self.aborted.is_some() || v.len() != self.v.len() {
            return None;
        }
        let mut violation: Option<(usize, usize, f64)> = None;
        for (i, (&v, (previous_v, previous_a))) in v.iter().zip(self.v.iter_mut().zip(&mut self.a)).enumerate() {
            let a = (v - *previous_v) / self.dt;
            let jerk = (a - *previous_a) / self.dt;
            *previous_v = v;
            *previous_a = a;
            for (kind, value) in [v, a, jerk].into_iter().enumerate() {
                // velocity before acceleration before jerk, then the lowest joint: the first reported;
                // NaN is never within a limit
                let within = value.abs() <= self.limits[kind][i];
                if !within && violation.is_none_or(|(k, _, _)| kind < k) {
                    violation = Some((kind, i, value));
                }
            }
        }
        let (kind, i, value) = violation?;
        let (name, reflex) = REFLEXES[kind];
        self.aborted = Some(format!(
            "joint_motion_generator_{reflex}: joint {} commanded {name} {value:.4} beyond {:.4}",
            i + 1,
            self.limits[kind][i]
        ));
        self.aborts += 1;
        self.aborted.as_deref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm() -> FrankaReflexes {
        FrankaReflexes::new(0.001, &[2.0; 3], &[10.0; 3], &[5000.0; 3]).unwrap()
    }

    #[test]
    fn a_step_beyond_the_acceleration_limit_aborts_once_until_recovered() {
        let mut r = arm();
        assert!(r.check(&[0.0; 3]).is_none());
        let error = r.check(&[0.0, 0.011, 0.0]).unwrap().to_string(); // 11 rad/s² in one cycle
        assert!(
            error.contains("velocity_discontinuity") && error.contains("joint 2"),
            "{error}"
        );
        assert!(r.check(&[0.0; 3]).is_none() && r.aborted().is_some() && r.aborts() == 1);
        r.recover();
        assert!(r.aborted().is_none() && r.check(&[0.0; 3]).is_none());
    }

    #[test]
    fn a_ramp_within_the_limits_passes_and_its_jerk_is_checked_at_the_ramps_start() {
        let mut r = arm();
        // 4 rad/s² from rest: the jerk of the first cycle is 4000 rad/s³ (< 5000)
        for k in 1..=400 {
            assert!(r.check(&[0.004 * k as f64, 0.0, 0.0]).is_none(), "{:?}", r.aborted());
        }
        let mut r = arm();
        // 6 rad/s² from rest: 6000 rad/s³ in the first cycle
        assert!(r.check(&[0.006, 0.0, 0.0]).unwrap().contains("acceleration_discontinuity"));
        // 5 rad/s² from rest: the jerk limit itself, within rounding
        assert!(arm().check(&[0.005, 0.0, 0.0]).is_none());
    }

    #[test]
    fn an_acceleration_reached_within_the_jerk_limit_and_held_is_no_jerk() {
        // 4 then 8 rad/s² (4000 rad/s³ each cycle), then 8 rad/s² held: its jerk is zero
        let mut stream = vec![0.0, 0.004, 0.012];
        while stream.len() < 200 {
            stream.push(stream[stream.len() - 1] + 0.008);
        }
        let dt = 0.001;
        let a: Vec<f64> = stream.windows(2).map(|w| (w[1] - w[0]) / dt).collect();
        let jerk: Vec<f64> = a.windows(2).map(|w| (w[1] - w[0]) / dt).collect();
        assert!(stream.iter().all(|v| v.abs() < 2.0) && a.iter().all(|a| a.abs() < 10.0 + 1e-9));
        assert!(jerk.iter().all(|j| j.abs() < 5000.0 * (1.0 - 1e-6)) && jerk.iter().skip(2).all(|j| j.abs() < 1e-6));
        let mut r = arm();
        for (k, v) in stream.iter().enumerate() {
            assert!(r.check(&[0.0, *v, 0.0]).is_none(), "cycle {k}: {:?}", r.aborted());
        }
    }

    #[test]
    fn a_velocity_beyond_its_limit_is_reported_before_the_step_that_reached_it() {
        let mut r = arm();
        r.follow(&[2.0, 0.0, 0.0]);
        r.follow(&[2.0, 0.0, 0.0]);
        assert!(r.check(&[2.0, 0.0, 0.0]).is_none(), "the limit itself passes");
        let error = r.check(&[2.001, 0.0, 0.0]).unwrap().to_string();
        assert!(error.contains("velocity_limits_violation"), "{error}");
        assert!(arm().check(&[f64::NAN, 0.0, 0.0]).is_some(), "NaN is never within a limit");
    }

    #[test]
    fn limits_that_are_missing_or_not_positive_are_refused() {
        assert!(FrankaReflexes::new(0.001, &[1.0; 3], &[1.0; 2], &[1.0; 3]).is_err());
        assert!(FrankaReflexes::new(0.001, &[1.0; 3], &[1.0; 3], &[0.0; 3]).is_err());
        assert!(FrankaReflexes::new(0.0, &[1.0; 3], &[1.0; 3], &[1.0; 3]).is_err());
    }
}
