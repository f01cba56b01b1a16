//! A per-joint rate limiter on velocity commands: velocity, acceleration and jerk bounds that a
//! robot's command interface enforces (a Franka's 1 kHz interface aborts a motion whose commanded
//! velocity jumps past them), with a braking look-ahead so that a held target is reached without
//! overshoot.

use crate::error::{ensure_finite, ensure_len, Result, SabreError};

/// Limits a stream of velocity targets, one call per control step of `dt`, so that every output
/// v_k obeys, per joint i,
/// |v_k| ≤ v_max, |a_k| ≤ a_max and |a_k − a_{k−1}| ≤ j_max·dt with a_k = (v_k − v_{k−1})/dt.
///
/// Each step chooses the acceleration nearest the one that closes the gap to the target fastest,
/// within the jerk and acceleration bounds and below the largest acceleration from which braking
/// at full jerk still ends at (not past) the target; the same look-ahead toward ±v_max keeps the
/// velocity bound. A target held long enough is therefore reached exactly and without overshoot,
/// and a target of zero is a ramp to rest. Targets outside ±v_max are clipped to it first.
#[derive(Debug, Clone, PartialEq)]
pub struct RateLimiter {
    v_max: Vec<f64>,
    a_max: Vec<f64>,
    j_max: Vec<f64>,
    dt: f64,
    velocity: Vec<f64>,
    acceleration: Vec<f64>,
}

/// The largest acceleration a ≥ 0 from which ramping down to zero in steps of `jerk_step`
/// (= j·dt) adds at most `budget`·dt of velocity, counting a's own step: with a = m·J + r
/// (0 ≤ r ≤ J) the ramp a, a − J, …, r adds dt·((m + 1)·r + J·m(m + 1)/2).
fn braking_cap(budget: f64, jerk_step: f64) -> f64 {
    if budget <= 0.0 {
        return 0.0;
    }
    let x = budget / jerk_step;
    let mut m = (((8.0 * x + 1.0).sqrt() - 1.0) / 2.0).floor().max(0.0);
    // The closed form's rounding: m is the largest integer with J·m(m + 1)/2 ≤ budget.
    while jerk_step * (m + 1.0) * (m + 2.0) / 2.0 <= budget {
        m += 1.0;
    }
    while m > 0.0 && jerk_step * m * (m + 1.0) / 2.0 > budget {
        m -= 1.0;
    }
    let r = ((budget - jerk_step * m * (m + 1.0) / 2.0) / (m + 1.0)).clamp(0.0, jerk_step);
    m * jerk_step + r
}

impl RateLimiter {
    /// A limiter for `v_max.len()` joints with bounds `v_max`, `a_max`, `j_max` (finite, positive,
    /// of equal length) at step `dt` (s, finite, positive), at rest.
    pub fn new(v_max: Vec<f64>, a_max: Vec<f64>, j_max: Vec<f64>, dt: f64) -> Result<Self> {
        let n = v_max.len();
        if n == 0 {
            return Err(SabreError::shape("v_max", "(n,) with n ≥ 1", "0 elements"));
        }
        for (name, values) in [("v_max", &v_max), ("a_max", &a_max), ("j_max", &j_max)] {
            ensure_len(name, values, n)?;
            ensure_finite(name, values)?;
            if let Some(i) = values.iter().position(|&v| v <= 0.0) {
                return Err(SabreError::invalid(
                    name,
                    format!("entry {i} is {}: bounds must be positive", values[i]),
                ));
            }
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be finite and positive, got {dt}")));
        }
        Ok(Self {
            v_max,
            a_max,
            j_max,
            dt,
            velocity: vec![0.0; n],
            acceleration: vec![0.0; n],
        })
    }

    pub fn len(&self) -> usize {
        self.v_max.len()
    }
    pub fn is_empty(&self) -> bool {
        self.v_max.is_empty()
    }
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn v_max(&self) -> &[f64] {
        &self.v_max
    }
    pub fn a_max(&self) -> &[f64] {
        &self.a_max
    }
    pub fn j_max(&self) -> &[f64] {
        &self.j_max
    }
    /// The last output (the velocity the joints were last commanded).
    pub fn velocity(&self) -> &[f64] {
        &self.velocity
    }
    /// The last output's acceleration (its difference from the one before, over dt).
    pub fn acceleration(&self) -> &[f64] {
        &self.acceleration
    }
    /// Whether the last output is zero and not changing.
    pub fn at_rest(&self) -> bool {
        self.velocity.iter().chain(&self.acceleration).all(|&v| v == 0.0)
    }

    /// Starts again from `velocity` (None: rest) with zero acceleration; each entry is clipped to
    /// ±v_max.
    pub fn reset(&mut self, velocity: Option<&[f64]>) -> Result<()> {
        match velocity {
            None => self.velocity.fill(0.0),
            Some(v) => {
                ensure_len("velocity", v, self.len())?;
                ensure_finite("velocity", v)?;
                for ((out, &v), &limit) in self.velocity.iter_mut().zip(v).zip(&self.v_max) {
                    *out = v.clamp(-limit, limit);
                }
            }
        }
        self.acceleration.fill(0.0);
        Ok(())
    }

    /// One step toward `target` (n, finite): writes the limited command into `out` (n) and keeps it
    /// as the state of the next step.
    pub fn limit(&mut self, target: &[f64], out: &mut [f64]) -> Result<()> {
        let n = self.len();
        ensure_len("target", target, n)?;
        ensure_len("out", out, n)?;
        ensure_finite("target", target)?;
        let dt = self.dt;
        for i in 0..n {
            let (v, a) = (self.velocity[i], self.acceleration[i]);
            let (v_max, a_max, jerk_step) = (self.v_max[i], self.a_max[i], self.j_max[i] * dt);
            let goal = target[i].clamp(-v_max, v_max);
            let toward = if goal >= v {
                braking_cap((goal - v) / dt, jerk_step)
            } else {
                -braking_cap((v - goal) / dt, jerk_step)
            };
            // The same look-ahead toward both velocity bounds keeps every later output within them.
            let within = toward.clamp(
                -braking_cap((v_max + v) / dt, jerk_step),
                braking_cap((v_max - v) / dt, jerk_step),
            );
            let next_a = within.clamp((a - jerk_step).max(-a_max), (a + jerk_step).min(a_max));
            let mut next_v = (v + next_a * dt).clamp(-v_max, v_max);
            if (next_v - goal).abs() <= 4.0 * f64::EPSILON * goal.abs().max(1.0) {
                next_v = goal; // arrived: no rounding residue left to creep on
            }
            self.velocity[i] = next_v;
            self.acceleration[i] = next_a;
            out[i] = next_v;
        }
        Ok(())
    }

    /// How many steps a ramp to rest from the current state takes at most (every joint at full
    /// jerk, then full braking): a bound for a caller that must wait until the joints are at rest.
    pub fn steps_to_rest(&self) -> usize {
        let dt = self.dt;
        (0..self.len())
            .map(|i| {
                let (v, a) = (self.velocity[i].abs(), self.acceleration[i].abs());
                let (a_max, j) = (self.a_max[i], self.j_max[i]);
                // reverse the acceleration, brake at a_max, release it: each at most this long
                let ramp = 2.0 * (a + a_max) / j;
                let brake = v / a_max + a * a / (a_max * j);
                ((ramp + brake) / dt).ceil() as usize + 2
            })
            .max()
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// Franka's published joint limits (velocity, acceleration, jerk) at its 1 kHz step.
    fn franka() -> RateLimiter {
        RateLimiter::new(
            vec![2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61],
            vec![15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0],
            vec![7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0],
            0.001,
        )
        .unwrap()
    }

    /// Asserts the three bounds on one output, given the two before it.
    fn check_bounds(lim: &RateLimiter, previous: &[f64], before: &[f64], out: &[f64]) {
        let dt = lim.dt();
        for i in 0..lim.len() {
            let tol = 1e-9;
            assert!(out[i].abs() <= lim.v_max()[i] + tol, "velocity {} of joint {i}", out[i]);
            let a = (out[i] - previous[i]) / dt;
            let a_before = (previous[i] - before[i]) / dt;
            assert!(
                a.abs() <= lim.a_max()[i] * (1.0 + 1e-9) + 1e-6,
                "acceleration {a} of joint {i}"
            );
            let jerk = (a - a_before) / dt;
            assert!(jerk.abs() <= lim.j_max()[i] * (1.0 + 1e-6) + 1e-3, "jerk {jerk} of joint {i}");
        }
    }

    #[test]
    fn braking_cap_is_the_largest_acceleration_whose_ramp_fits_the_budget() {
        let j = 7.5;
        for budget in [0.0, 1e-9, 3.0, 7.5, 7.6, 22.5, 100.0, 12345.6] {
            let a = braking_cap(budget, j);
            let ramp = |a: f64| {
                let (mut sum, mut x) = (0.0, a);
                while x > 0.0 {
                    sum += x;
                    x -= j;
                }
                sum
            };
            assert!(ramp(a) <= budget * (1.0 + 1e-12) + 1e-12, "budget {budget}: a {a}");
            assert!(
                ramp(a + 1e-6) > budget || a == 0.0 && budget == 0.0,
                "budget {budget}: a {a} is not the largest"
            );
        }
    }

    #[test]
    fn random_targets_keep_every_output_within_the_bounds() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut lim = franka();
        let n = lim.len();
        let (mut before, mut previous) = (vec![0.0; n], vec![0.0; n]);
        let mut out = vec![0.0; n];
        let mut target = vec![0.0; n];
        for step in 0..20_000 {
            // targets jump at random, beyond the velocity bound too, and sometimes every step
            if step % 37 == 0 || rng.random_bool(0.05) {
                for t in target.iter_mut() {
                    *t = rng.random_range(-4.0..4.0);
                }
            }
            lim.limit(&target, &mut out).unwrap();
            check_bounds(&lim, &previous, &before, &out);
            before.clone_from(&previous);
            previous.clone_from(&out);
        }
    }

    #[test]
    fn a_held_target_is_reached_exactly_and_never_overshot() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut lim = franka();
        let n = lim.len();
        let mut out = vec![0.0; n];
        for _ in 0..200 {
            // from wherever the last target left the joints (at rest at that target)
            let start = lim.velocity().to_vec();
            let target: Vec<f64> = (0..n).map(|_| rng.random_range(-3.0..3.0)).collect();
            let goal: Vec<f64> = target.iter().zip(lim.v_max()).map(|(t, v)| t.clamp(-v, *v)).collect();
            let bound = lim.steps_to_rest() + 2000;
            let mut reached = false;
            for _ in 0..bound {
                lim.limit(&target, &mut out).unwrap();
                for i in 0..n {
                    let (lo, hi) = if goal[i] >= start[i] {
                        (start[i], goal[i])
                    } else {
                        (goal[i], start[i])
                    };
                    assert!(
                        out[i] >= lo - 1e-9 && out[i] <= hi + 1e-9,
                        "joint {i}: {} outside [{lo}, {hi}]",
                        out[i]
                    );
                }
                if out.iter().zip(&goal).all(|(o, g)| (o - g).abs() <= 1e-12) {
                    reached = true;
                    break;
                }
            }
            assert!(reached, "target {goal:?} not reached: {out:?}");
            // reached with zero acceleration: the next step stays there
            lim.limit(&target, &mut out).unwrap();
            assert!(out.iter().zip(&goal).all(|(o, g)| (o - g).abs() <= 1e-12));
            assert!(lim.acceleration().iter().all(|a| a.abs() <= 1e-9));
        }
    }

    #[test]
    fn a_stop_from_full_speed_and_acceleration_is_a_ramp_that_ends_at_rest() {
        let mut lim = franka();
        let n = lim.len();
        let mut out = vec![0.0; n];
        let up: Vec<f64> = lim.v_max().to_vec();
        for _ in 0..50 {
            lim.limit(&up, &mut out).unwrap(); // accelerating hard
        }
        assert!(lim.acceleration().iter().all(|a| *a > 0.0));
        let bound = lim.steps_to_rest();
        let (mut before, mut previous) = (lim.velocity().to_vec(), lim.velocity().to_vec());
        let mut steps = 0;
        while !lim.at_rest() {
            lim.limit(&vec![0.0; n], &mut out).unwrap();
            check_bounds(&lim, &previous, &before, &out);
            // never reverses: a stop does not swing past zero
            assert!(out.iter().all(|o| *o >= -1e-12), "{out:?}");
            before.clone_from(&previous);
            previous.clone_from(&out);
            steps += 1;
            assert!(steps <= bound, "not at rest within steps_to_rest = {bound}");
        }
        assert!(out.iter().all(|v| *v == 0.0));
    }

    #[test]
    fn reset_clips_to_the_velocity_bound_and_bad_input_is_rejected() {
        let mut lim = franka();
        lim.reset(Some(&[5.0, -5.0, 0.1, 0.0, 0.0, 0.0, 0.0])).unwrap();
        assert_eq!(&lim.velocity()[..3], &[2.175, -2.175, 0.1]);
        assert!(lim.acceleration().iter().all(|a| *a == 0.0));
        let mut out = vec![0.0; 7];
        assert!(lim.limit(&[0.0; 6], &mut out).is_err());
        assert!(lim.limit(&[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], &mut out).is_err());
        assert!(RateLimiter::new(vec![1.0], vec![0.0], vec![1.0], 0.001).is_err());
        assert!(RateLimiter::new(vec![1.0], vec![1.0], vec![1.0, 2.0], 0.001).is_err());
        assert!(RateLimiter::new(vec![1.0], vec![1.0], vec![1.0], 0.0).is_err());
        lim.reset(None).unwrap();
        assert!(lim.at_rest());
    }
}
