//! What a robot bridge commands on each control step: the arm's and the base's velocity command
//! streams through their rate limiters ([`CommandShaper`]), and the gate that decides when they
//! follow the targets and when they ramp to zero, with a watchdog for the time no state arrives
//! ([`CommandGate`]). Time comes in as an argument, so that the stop logic runs on any clock.

use super::rate_limit::RateLimiter;
use crate::error::{ensure_finite, ensure_len, Result, SabreError};

/// One step of the command streams: the arm's velocities, and the base's twist (vx, vy, ωz in the
/// base frame) when `base_due` (a base command is due this step; never without a base).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Command {
    pub arm: Vec<f64>,
    /// The base's command when `base_due`; otherwise its previous content, not to be sent.
    pub base: Vec<f64>,
    pub base_due: bool,
}

/// The arm's and the base's command streams through their rate limiters: the arm steps every
/// call, the base every `base_every`-th call (its limiter's `dt` is that step); a robot without a
/// base has the arm's stream only.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandShaper {
    arm: RateLimiter,
    base: Option<RateLimiter>,
    base_every: usize,
    calls: usize,
    base_target: Vec<f64>,
    zero_arm: Vec<f64>,
}

impl CommandShaper {
    /// The streams of `arm` and `base` (None: a fixed base), both from their limiters' current
    /// state; the base steps every `base_every`-th call (0 counts as 1: every call).
    pub fn new(arm: RateLimiter, base: Option<RateLimiter>, base_every: usize) -> Self {
        let base_target = vec![0.0; base.as_ref().map_or(0, RateLimiter::len)];
        let zero_arm = vec![0.0; arm.len()];
        Self {
            arm,
            base,
            base_every: base_every.max(1),
            calls: 0,
            base_target,
            zero_arm,
        }
    }

    pub fn arm(&self) -> &RateLimiter {
        &self.arm
    }
    pub fn base(&self) -> Option<&RateLimiter> {
        self.base.as_ref()
    }
    pub fn base_every(&self) -> usize {
        self.base_every
    }
    /// The arm's step (s): one call of [`Self::step`].
    pub fn period(&self) -> f64 {
        self.arm.dt()
    }

    /// A command sized for these streams, for [`Self::step`] to fill.
    pub fn command(&self) -> Command {
        Command {
            arm: vec![0.0; self.arm.len()],
            base: vec![0.0; self.base_target.len()],
            base_due: false,
        }
    }

    /// One step toward the targets into `out` (resized to fit; no allocation once it fits):
    /// `arm` None ramps both streams to zero; `base` None keeps the base's last target (a base
    /// target without a base is ignored). A target of the wrong length or with a non-finite
    /// entry is an error, and then nothing changes.
    pub fn step(&mut self, arm: Option<&[f64]>, base: Option<&[f64]>, out: &mut Command) -> Result<()> {
        if let Some(target) = arm {
            ensure_len("arm target", target, self.arm.len())?;
            ensure_finite("arm target", target)?;
        }
        let base = base.filter(|_| arm.is_some() && self.base.is_some());
        if let Some(target) = base {
            ensure_len("base target", target, self.base_target.len())?;
            ensure_finite("base target", target)?;
        }
        match (arm, base) {
            (None, _) => self.base_target.fill(0.0),
            (Some(_), Some(target)) => self.base_target.copy_from_slice(target),
            (Some(_), None) => {}
        }
        out.arm.resize(self.arm.len(), 0.0);
        out.base.resize(self.base_target.len(), 0.0);
        self.arm.limit(arm.unwrap_or(&self.zero_arm), &mut out.arm)?;
        out.base_due = false;
        if let Some(limiter) = self.base.as_mut() {
            if self.calls.is_multiple_of(self.base_every) {
                limiter.limit(&self.base_target, &mut out.base)?;
                out.base_due = true;
            }
        }
        self.calls += 1;
        Ok(())
    }

    /// Whether both streams' last outputs are zero and not changing.
    pub fn at_rest(&self) -> bool {
        self.arm.at_rest() && self.base.as_ref().is_none_or(RateLimiter::at_rest)
    }

    /// A bound on the arm steps a ramp to rest takes (the base's counted in arm steps).
    pub fn steps_to_rest(&self) -> usize {
        let base = self.base.as_ref().map_or(0, |b| b.steps_to_rest() * self.base_every);
        self.arm.steps_to_rest().max(base)
    }

    /// Both streams at rest, the base's target zero and due on the next step.
    pub fn reset(&mut self) {
        // A reset to rest (None) cannot fail: only a given velocity is checked.
        let _ = self.arm.reset(None);
        if let Some(base) = self.base.as_mut() {
            let _ = base.reset(None);
        }
        self.calls = 0;
        self.base_target.fill(0.0);
    }
}

/// How early (s) a ramp step still counts as due: the rounding of `now − period` never holds a
/// due step back to the next look.
const DUE_SLACK: f64 = 1e-9;

/// Decides what a bridge commands on each tick (a state that arrived) and, between ticks, on each
/// look of its watchdog.
///
/// A tick with targets follows them through the shaper; a tick without (a reason to stop holds:
/// e-stop, not active, stale joint, rejected message, stale plan, stopped planner) is one step of
/// a ramp to zero. When no tick has come for `state_timeout` s, [`Self::watchdog`] gives the
/// ramp's steps that are due, one per `period` s counted from the last command, until the streams
/// are at rest: the ramp starts at most one period after the timeout and never steps. A tick's
/// command that may not be held that long ([`Self::forbid_hold`]) ramps once two periods pass
/// without a tick instead, with every step due since the last command. Before the first tick
/// nothing was commanded and the watchdog has nothing to ramp.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandGate {
    shaper: CommandShaper,
    state_timeout: f64,
    period: f64,
    last_tick: f64,
    last_command: f64,
    stale_since: Option<f64>,
    stale_events: usize,
    may_hold: bool,
    command: Command,
}

impl CommandGate {
    /// The gate of `shaper`, whose arm step is the period; `state_timeout` (s) not negative,
    /// infinite for a gate whose watchdog never ramps.
    pub fn new(shaper: CommandShaper, state_timeout: f64) -> Result<Self> {
        if state_timeout.is_nan() || state_timeout < 0.0 {
            return Err(SabreError::invalid(
                "state_timeout",
                format!("must be a duration (s, not negative), got {state_timeout}"),
            ));
        }
        let command = shaper.command();
        Ok(Self {
            period: shaper.period(),
            shaper,
            state_timeout,
            last_tick: f64::NEG_INFINITY,
            last_command: f64::NEG_INFINITY,
            stale_since: None,
            stale_events: 0,
            may_hold: true,
            command,
        })
    }

    pub fn shaper(&self) -> &CommandShaper {
        &self.shaper
    }
    /// The shaper, for steps outside the gate's clock (a shutdown's ramp once the watchdog stops).
    pub fn shaper_mut(&mut self) -> &mut CommandShaper {
        &mut self.shaper
    }
    pub fn state_timeout(&self) -> f64 {
        self.state_timeout
    }
    /// The arm's step (s), one ramp step per period.
    pub fn period(&self) -> f64 {
        self.period
    }
    /// When the last tick came (−∞ before the first).
    pub fn last_tick(&self) -> f64 {
        self.last_tick
    }
    /// When the last command was due (a tick's, or a ramp step's on the period grid).
    pub fn last_command(&self) -> f64 {
        self.last_command
    }
    /// When the watchdog found the ticks stopped (None while they come).
    pub fn stale_since(&self) -> Option<f64> {
        self.stale_since
    }
    /// How many times the ticks stopped for `state_timeout`.
    pub fn stale_events(&self) -> usize {
        self.stale_events
    }
    /// The last tick's command.
    pub fn command(&self) -> &Command {
        &self.command
    }
    /// Whether the last tick's command may be held for `state_timeout` when no tick follows.
    pub fn may_hold(&self) -> bool {
        self.may_hold
    }

    /// The last tick's command may not be held for `state_timeout` (a stop that waited that long
    /// would end past a joint's limit): once two periods pass without a tick, the watchdog ramps,
    /// with every step due since the last command, so that the streams keep braking on their
    /// period grid. The next tick allows holding again.
    pub fn forbid_hold(&mut self) {
        self.may_hold = false;
    }

    /// The command answering a tick at `now` (`arm` None: a ramp step toward zero; `base` None:
    /// the base's last target). A bad target is an error, and then nothing changes.
    pub fn on_tick(&mut self, now: f64, arm: Option<&[f64]>, base: Option<&[f64]>) -> Result<&Command> {
        self.shaper.step(arm, base, &mut self.command)?;
        self.last_tick = now;
        self.last_command = now;
        self.stale_since = None;
        self.may_hold = true;
        Ok(&self.command)
    }

    /// The ramp step due at `now` because no tick came for `state_timeout` (none when `limit` is 0),
    /// into `out`: its length becomes the number of steps, and a command already in it is reused.
    /// One step per look, a period after the last command at the earliest: a late look slows the
    /// ramp and never steepens it (a robot that missed cycles would see the steps it caught up on
    /// arrive in one cycle).
    pub fn watchdog(&mut self, now: f64, limit: usize, out: &mut Vec<Command>) {
        let mut count = 0;
        if limit > 0 && self.ramp_due(now) && !self.shaper.at_rest() && now - self.last_command >= self.period - DUE_SLACK {
            if out.is_empty() {
                out.push(self.shaper.command());
            }
            self.last_command = now.max(self.last_command + self.period);
            // Neither target is given, so the step cannot fail.
            let _ = self.shaper.step(None, None, &mut out[0]);
            count = 1;
        }
        out.truncate(count);
    }

    /// Whether the ticks stopped for `state_timeout` after at least one came (for a command that
    /// may not be held, for two periods: its ramp steps from the last command on); the first look
    /// that finds them stopped for the timeout counts the event and, for a held command, sets the
    /// ramp's first step one period after the last command, or at `now` if that is past.
    fn ramp_due(&mut self, now: f64) -> bool {
        if self.last_tick == f64::NEG_INFINITY {
            return false;
        }
        let quiet = now - self.last_tick;
        if quiet <= self.state_timeout {
            return !self.may_hold && quiet >= 2.0 * self.period - DUE_SLACK;
        }
        if self.stale_since.is_none() {
            self.stale_since = Some(now);
            self.stale_events += 1;
            if self.may_hold {
                self.last_command = self.last_command.max(now - self.period);
            }
        }
        true
    }

    /// Seconds from `now` until the watchdog has something to do (a caller's sleep).
    pub fn next_look(&self, now: f64) -> f64 {
        if self.last_tick == f64::NEG_INFINITY {
            self.state_timeout
        } else if !self.may_hold && !self.shaper.at_rest() {
            let due = (self.last_tick + 2.0 * self.period).max(self.last_command + self.period);
            (due - now).max(0.0)
        } else if now - self.last_tick <= self.state_timeout {
            // just past the timeout, so that the look finds the ticks stopped
            self.last_tick + self.state_timeout - now + 1e-4
        } else if self.shaper.at_rest() {
            self.state_timeout
        } else {
            (self.last_command + self.period - now).max(0.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DT: f64 = 0.001;
    const A_MAX: [f64; 2] = [10.0, 6.0];
    const J_MAX: [f64; 2] = [1000.0, 800.0];

    fn arm() -> RateLimiter {
        RateLimiter::new(vec![1.0, 1.5], A_MAX.to_vec(), J_MAX.to_vec(), DT).unwrap()
    }

    fn base(every: usize) -> RateLimiter {
        RateLimiter::new(vec![1.0; 3], vec![2.0; 3], vec![50.0; 3], DT * every as f64).unwrap()
    }

    fn gate() -> CommandGate {
        CommandGate::new(CommandShaper::new(arm(), Some(base(20)), 20), 0.05).unwrap()
    }

    /// Asserts that a stream of arm commands, one per `DT`, keeps the acceleration and jerk bounds:
    /// no step anywhere in it.
    fn assert_no_step(stream: &[Vec<f64>]) {
        for k in 2..stream.len() {
            for i in 0..2 {
                let a = (stream[k][i] - stream[k - 1][i]) / DT;
                let before = (stream[k - 1][i] - stream[k - 2][i]) / DT;
                assert!(a.abs() <= A_MAX[i] * (1.0 + 1e-9) + 1e-6, "step {k}: acceleration {a}");
                let jerk = (a - before) / DT;
                assert!(jerk.abs() <= J_MAX[i] * (1.0 + 1e-6) + 1e-3, "step {k}: jerk {jerk}");
            }
        }
    }

    /// Ticks at 1 kHz toward `target` from t = 0.001 to `ticks`·0.001; returns the arm's stream
    /// from rest.
    fn follow(gate: &mut CommandGate, target: &[f64], ticks: usize) -> Vec<Vec<f64>> {
        let mut stream = vec![vec![0.0; 2]];
        for k in 1..=ticks {
            let command = gate.on_tick(k as f64 * DT, Some(target), Some(&[0.3, 0.0, 0.1])).unwrap();
            stream.push(command.arm.clone());
        }
        stream
    }

    #[test]
    fn the_shaper_steps_the_base_every_kth_call_toward_its_last_target() {
        let every = 4;
        let mut shaper = CommandShaper::new(arm(), Some(base(every)), every);
        let mut reference = base(every);
        let mut out = shaper.command();
        let mut expected = vec![0.0; 3];
        let mut target = [0.0; 3];
        for call in 0..40 {
            // a new base target every 3rd call, none given otherwise (the last one holds)
            let given = [0.1 * call as f64, -0.5, 0.2];
            let base_target = (call % 3 == 0).then_some(&given[..]);
            if let Some(t) = base_target {
                target.copy_from_slice(t);
            }
            let arm_target = if call < 30 { Some(&[0.5, 0.5][..]) } else { None };
            if arm_target.is_none() {
                target = [0.0; 3]; // no arm target: both streams ramp to zero
            }
            shaper.step(arm_target, base_target, &mut out).unwrap();
            assert_eq!(out.base_due, call % every == 0, "call {call}");
            if out.base_due {
                reference.limit(&target, &mut expected).unwrap();
                assert_eq!(out.base, expected, "call {call}");
            }
        }
        assert_eq!(shaper.base().unwrap(), &reference);
        let mut fixed = CommandShaper::new(arm(), None, 20);
        let mut out = fixed.command();
        for _ in 0..50 {
            fixed.step(Some(&[0.2, 0.2]), Some(&[1.0, 0.0, 0.0]), &mut out).unwrap();
            assert!(!out.base_due && out.base.is_empty());
        }
    }

    #[test]
    fn the_shaper_bounds_its_ramp_to_rest_and_resets_to_rest() {
        let mut shaper = CommandShaper::new(arm(), Some(base(20)), 20);
        let mut out = Command::default();
        for _ in 0..200 {
            shaper.step(Some(&[1.0, -1.5]), Some(&[1.0, 1.0, 1.0]), &mut out).unwrap();
        }
        let bound = shaper.steps_to_rest();
        assert!(bound >= shaper.base().unwrap().steps_to_rest() * 20);
        let mut steps = 0;
        while !shaper.at_rest() {
            shaper.step(None, None, &mut out).unwrap();
            steps += 1;
            assert!(steps <= bound, "not at rest within steps_to_rest = {bound}");
        }
        assert!(out.arm.iter().chain(&out.base).all(|v| *v == 0.0));
        shaper.step(Some(&[1.0, -1.5]), Some(&[1.0, 1.0, 1.0]), &mut out).unwrap();
        shaper.reset();
        assert!(shaper.at_rest());
        assert_eq!(shaper, CommandShaper::new(arm(), Some(base(20)), 20));
    }

    #[test]
    fn the_gate_ramps_within_one_period_of_the_timeout_and_never_steps() {
        let mut gate = gate();
        let mut steps = Vec::new();
        gate.watchdog(10.0, 10, &mut steps);
        assert!(
            steps.is_empty() && gate.stale_events() == 0,
            "nothing commanded yet: nothing to ramp"
        );
        assert_eq!(gate.next_look(10.0), 0.05);
        let mut stream = follow(&mut gate, &[0.8, -1.2], 300);
        let last_tick = 0.3;
        let bound = gate.shaper().steps_to_rest();
        gate.watchdog(last_tick + 0.05, 10, &mut steps);
        assert!(steps.is_empty() && gate.stale_events() == 0);
        assert!((gate.next_look(last_tick + 0.02) - (0.03 + 1e-4)).abs() < 1e-12);
        let mut times = Vec::new();
        let mut now = last_tick + 0.0503;
        while now < last_tick + 1.0 {
            // an irregular watchdog: looks 0.7 periods apart
            gate.watchdog(now, 10, &mut steps);
            assert!(steps.len() <= 1, "one step per look");
            for command in &steps {
                times.push(gate.last_command());
                stream.push(command.arm.clone());
            }
            let wait = gate.next_look(now);
            assert!(wait >= 0.0 && (gate.shaper().at_rest() || wait <= DT + 1e-12));
            now += 0.0007;
        }
        assert_eq!(gate.stale_events(), 1);
        assert_eq!(gate.stale_since(), Some(last_tick + 0.0503));
        assert!(times[0] > last_tick + 0.05 && times[0] <= last_tick + 0.05 + DT + 1e-9);
        // a period apart, or the look after (0.7 periods later) when a look fell just short
        assert!(times
            .windows(2)
            .all(|w| w[1] - w[0] >= DT - 1e-9 && w[1] - w[0] <= DT + 0.0007 + 1e-9));
        assert!(times.len() <= bound, "{} steps, bound {bound}", times.len());
        assert!(gate.shaper().at_rest() && stream.last().unwrap().iter().all(|v| *v == 0.0));
        assert_eq!(gate.next_look(now), 0.05);
        // a tick resumes following from rest, still without a step
        stream.push(gate.on_tick(now, Some(&[0.8, -1.2]), None).unwrap().arm.clone());
        assert_no_step(&stream);
        assert_eq!(gate.stale_since(), None);
    }

    #[test]
    fn a_late_look_takes_one_step_and_the_next_comes_a_period_later() {
        let mut gate = gate();
        follow(&mut gate, &[0.8, -1.2], 300);
        let mut steps = Vec::new();
        let first = 0.3 + 0.0503;
        gate.watchdog(first, 10, &mut steps);
        assert_eq!(steps.len(), 1);
        assert!((gate.last_command() - first).abs() < 1e-12);
        // 10.5 periods late: one step, never the ten that were due (they would reach the robot in one
        // of its cycles); the ramp goes on a period after it
        let late = first + 0.0105;
        let before = gate.command().arm.clone();
        gate.watchdog(late, 10, &mut steps);
        assert_eq!(steps.len(), 1);
        let step = steps[0]
            .arm
            .iter()
            .zip(&before)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(step <= 10.0 * DT + 1e-12, "one step of the ramp (at most A_MAX·DT): {step}");
        gate.watchdog(late, 10, &mut steps);
        assert!(steps.is_empty());
        assert!((gate.next_look(late) - DT).abs() < 1e-9);
        gate.watchdog(late + DT, 0, &mut steps);
        assert!(steps.is_empty(), "limit 0: none");
        assert_eq!(gate.stale_events(), 1);
        // the ticks come back, then stop again: a second event
        gate.on_tick(1.0, None, None).unwrap();
        gate.watchdog(1.0505, 10, &mut steps);
        assert_eq!((gate.stale_events(), steps.len()), (2, 1));
    }

    #[test]
    fn a_command_that_may_not_be_held_ramps_two_periods_after_its_tick_on_the_period_grid() {
        let mut gate = gate();
        let mut stream = follow(&mut gate, &[0.8, -1.2], 300);
        let last_tick = 0.3;
        assert!(gate.may_hold());
        gate.forbid_hold();
        let mut steps = Vec::new();
        gate.watchdog(last_tick + 0.0015, 10, &mut steps);
        assert!(steps.is_empty(), "not before two periods without a tick");
        assert!((gate.next_look(last_tick + 0.0015) - 0.0005).abs() < 1e-12);
        // two periods without a tick: a step (one per look), none of the timeout's hold
        gate.watchdog(last_tick + 0.002, 10, &mut steps);
        assert_eq!(steps.len(), 1);
        assert!((gate.last_command() - (last_tick + 0.002)).abs() < 1e-12);
        assert_eq!(gate.stale_events(), 0, "no stale event before the state timeout");
        let mut now = last_tick + 0.0027;
        while !gate.shaper().at_rest() {
            for command in &steps {
                stream.push(command.arm.clone());
            }
            gate.watchdog(now, 10, &mut steps);
            now += 0.0007;
        }
        assert_no_step(&stream);
        assert_eq!(gate.stale_events(), 1);
        // a tick allows holding again; a stop's ramp step never does
        gate.on_tick(now, Some(&[0.1, 0.1]), None).unwrap();
        assert!(gate.may_hold());
        let mut shaping = crate::control::CommandShaping::new(gate, vec![0, 1], Some([2, 3, 4]), 5).unwrap();
        shaping.stop(now + 0.001).unwrap();
        assert!(!shaping.gate().may_hold());
    }

    #[test]
    fn a_bad_target_changes_nothing() {
        let mut gate = gate();
        follow(&mut gate, &[0.8, -1.2], 10);
        let before = gate.clone();
        assert!(gate.on_tick(1.0, Some(&[0.1]), None).is_err());
        assert!(gate.on_tick(1.0, Some(&[0.1, f64::NAN]), None).is_err());
        assert!(gate.on_tick(1.0, Some(&[0.1, 0.1]), Some(&[0.0, 0.0])).is_err());
        assert_eq!(gate, before);
        // without an arm target the base's is not used, so not checked
        assert!(gate.on_tick(1.0, None, Some(&[f64::NAN])).is_ok());
        assert!(CommandGate::new(CommandShaper::new(arm(), None, 1), f64::NAN).is_err());
        assert!(CommandGate::new(CommandShaper::new(arm(), None, 1), -1.0).is_err());
    }
}
