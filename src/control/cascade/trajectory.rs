//! The cascade's tick for an arm on a joint_trajectory_controller: the tank booked against the velocity
//! the robot executes (the segment in force, v_d + k_p (q_d − q)), and when a segment is due the
//! Sequential FILTER-QP (Algorithm 1) along it, each step filtered at the state the segment will be in
//! with the passivity row (56) fed by the energy the segment predicts, the hard joint-limit bound at
//! that state, and the base's command from the same filtered steps through its own stream. The
//! segment's targets are the filtered commands less the robot's feedback on the desired positions'
//! lead (see [`TrajectoryConfig::position_gain`]): the robot executes what the filter passed.

use super::{lock, Cascade};
use crate::control::plan::Plan;
use crate::control::segment::{Segment, SegmentBuilder};
use crate::control::shaping::CommandShaping;
use crate::control::trajectory_stream::{FilteredSteps, TrajectoryConfig, TrajectoryStream, TrajectoryTick};
use crate::error::{Result, SabreError};
use crate::model::LimitBound;
use crate::safety::{EnergyTank, FilterStatus};

fn no_trajectory() -> SabreError {
    SabreError::invalid(
        "trajectory",
        "this cascade streams no trajectory: give it a trajectory stream first",
    )
}

impl Cascade {
    /// Streams the arm's commands as trajectory segments from now on ([`Self::tick_trajectory`]); the
    /// cascade must shape commands already ([`Self::set_shaping`]: its arm joints are the segments',
    /// its base stream the base's). The arm's joint-limit bound then brakes as a segment does.
    pub fn set_trajectory(&mut self, config: TrajectoryConfig) -> Result<()> {
        let shaping = self.shaping.as_ref().ok_or_else(super::super::shaping::shapes_no_commands)?;
        if shaping.arm_index().len() != config.shape.joints() {
            return Err(SabreError::invalid(
                "trajectory",
                format!(
                    "its segments carry {} joints, the arm command {}",
                    config.shape.joints(),
                    shaping.arm_index().len()
                ),
            ));
        }
        let stream = TrajectoryStream::new(config)?;
        let mut limits = self.limits.clone();
        brake_as_segment(&mut limits, &stream, shaping.arm_index())?;
        (self.limits, self.trajectory) = (limits, Some(stream));
        Ok(())
    }

    /// The trajectory stream, when the arm's commands are segments.
    pub fn trajectory(&self) -> Option<&TrajectoryStream> {
        self.trajectory.as_ref()
    }

    /// Re-applies the segments' braking to `limits` for the arm joints `arm` (after the bound or the
    /// shaping changed). Errors: an arm of another size than the segments'.
    pub(super) fn rebrake_trajectory(&self, limits: &mut LimitBound, arm: &[usize]) -> Result<()> {
        match &self.trajectory {
            Some(stream) if stream.config().shape.joints() != arm.len() => Err(SabreError::invalid(
                "command shaping",
                format!(
                    "its arm has {} joints, the trajectory's segments {}",
                    arm.len(),
                    stream.config().shape.joints()
                ),
            )),
            Some(stream) => brake_as_segment(limits, stream, arm),
            None => Ok(()),
        }
    }

    /// One tick at the measured state `x` at time `t` (the stamps' clock, as the segments are stamped)
    /// over `dt`, τ_ext conditioned for `now`: the tank's refill and step (49) with τ_ext and the
    /// velocity the robot executes, the segment's v_d + k_p (q_d − q) for the arm and the base stream's
    /// command; then, when a segment is due, the next one (see the module; one that would leave the
    /// joint limits' margin is not sent, the one in force goes on); then the base stream's step toward
    /// the filtered step in force. Errors: no trajectory stream, or the checks of [`Self::tick`].
    pub fn tick_trajectory(&mut self, x: &[f64], t: f64, dt: f64, now: f64) -> Result<TrajectoryTick> {
        if self.trajectory.is_none() {
            return Err(no_trajectory());
        }
        self.check_tick(x, t, dt)?;
        let plan = self
            .plan_at(t)
            .cloned()
            .ok_or_else(|| SabreError::invalid("plan", "no plan yet"))?;
        let tau_ext = self.tau_ext.condition(now, dt).to_vec();
        plan.reference_at(t, &mut self.out.reference);
        self.executed(x, t);
        self.out.tank_energy = match self.tank.as_deref() {
            Some(tank) => {
                let mut tank = lock(tank);
                if let Some(predicted) = plan.predicted_dissipation_at(t).filter(|_| tank.refill_config().is_some()) {
                    let measured = -EnergyTank::power(&tau_ext, &self.out.reference);
                    tank.refill(predicted, measured, dt)?;
                }
                Some(tank.step(&tau_ext, &self.out.command, dt)?)
            }
            None => None,
        };
        let stream = self.trajectory.as_ref().expect("checked above");
        let segment = if stream.due(t) {
            self.next_segment(x, t, &plan, &tau_ext)?
        } else {
            None
        };
        // the base's stream follows the filtered step for now, the one the arm's segment executes now
        // (its stream has no lead); none yet: as it goes; past the last: at rest, as the segment ends
        let mut target = self.out.command.clone();
        let steps = &self.filtered_steps;
        let started = steps.times.first().is_some_and(|&t0| t0 <= t);
        if let (true, Some(base)) = (started, self.shaping.as_ref().and_then(|s| s.base_index())) {
            let k = steps.times.partition_point(|&tk| tk <= t) - 1;
            let ended = t >= steps.times[k] + self.trajectory.as_ref().expect("checked above").config().filter_step;
            let ended = ended && k + 1 == steps.times.len();
            for i in base {
                target[i] = if ended { 0.0 } else { steps.rows[k * self.nq + i] };
            }
        }
        let shaping = self.shaping.as_mut().expect("set with the stream");
        let command = shaping.follow(now, &target, x)?.clone();
        self.ticks += 1;
        Ok(TrajectoryTick { command, segment })
    }

    /// The stop to publish at `t` with the base stream's ramp step at `now`: the segment in force up
    /// to the splice, then a stop to rest (None when the last segment sent already stops, or none was
    /// sent). Errors: no trajectory stream.
    pub fn stop_trajectory(&mut self, t: f64, now: f64) -> Result<TrajectoryTick> {
        let stream = self.trajectory.as_mut().ok_or_else(no_trajectory)?;
        let segment = stream.stop(t)?.cloned();
        self.filtered_steps = FilteredSteps::default();
        let shaping = self.shaping.as_mut().ok_or_else(super::super::shaping::shapes_no_commands)?;
        let command = shaping.stop(now)?.clone();
        Ok(TrajectoryTick { command, segment })
    }

    /// The stop segment alone at `t`, outside the ticks (a shutdown's); see [`Self::stop_trajectory`].
    pub fn stop_segment(&mut self, t: f64) -> Result<Option<Segment>> {
        let stream = self.trajectory.as_mut().ok_or_else(no_trajectory)?;
        self.filtered_steps = FilteredSteps::default();
        Ok(stream.stop(t)?.cloned())
    }

    /// The velocity the robot executes at `t` into `out.command` (nq): the arm's v_d + k_p (q_d − q)
    /// of the segment in force (0 before the first), the base's the base stream's command in world
    /// rates.
    fn executed(&mut self, x: &[f64], t: f64) {
        let stream = self.trajectory.as_ref().expect("checked by the caller");
        let shaping = self.shaping.as_ref().expect("set with the stream");
        let command = &mut self.out.command;
        command.iter_mut().for_each(|c| *c = 0.0);
        if let Some(d) = stream.desired_at(t) {
            let gains = &stream.config().position_gain;
            for (k, &i) in shaping.arm_index().iter().enumerate() {
                command[i] = d.v[k] + gains[k] * (d.q[k] - x[i]);
            }
        }
        if let (Some([ix, iy, iyaw]), Some(base)) = (shaping.base_index(), shaping.gate().shaper().base()) {
            let (b, (c, s)) = (base.velocity(), (x[iyaw].cos(), x[iyaw].sin()));
            command[ix] = c * b[0] - s * b[1];
            command[iy] = s * b[0] + c * b[1];
            command[iyaw] = b[2];
        }
    }

    /// Algorithm 1 along the next segment (see the module), committed to the stream when its knots
    /// keep the joint limits' margin; None (the one in force goes on) otherwise.
    fn next_segment(&mut self, x: &[f64], t: f64, plan: &Plan, tau_ext: &[f64]) -> Result<Option<Segment>> {
        let (nq, nx) = (self.nq, self.nx);
        let stream = self.trajectory.as_ref().expect("checked by the caller");
        let shaping = self.shaping.as_ref().expect("set with the stream");
        let arm = shaping.arm_index().to_vec();
        let config = stream.config().clone();
        let q_arm: Vec<f64> = arm.iter().map(|&i| x[i]).collect();
        let (splice, start) = stream.splice(t, &q_arm);
        // the desired positions' lead over the measured ones, which the robot's feedback adds to v_d
        let lead: Vec<f64> = match stream.desired_at(t) {
            Some(d) => arm.iter().enumerate().map(|(k, &i)| d.q[k] - x[i]).collect(),
            None => vec![0.0; arm.len()],
        };
        let mut builder = SegmentBuilder::new(&config.shape, &start)?;
        let mut xk = x.to_vec();
        let mut reference = vec![0.0; nq];
        let (mut lower, mut upper) = (vec![0.0; nq], vec![0.0; nq]);
        let mut target = vec![0.0; arm.len()];
        let mut energy = self.tank.as_deref().map(|t| lock(t).energy());
        let mut filter = self.filter.as_deref().map(lock);
        let step = config.filter_step;
        let mut steps = FilteredSteps::default();
        // the base's velocity where the segment starts: the filtered step it executes until the
        // splice, or before any its stream's command (world rates)
        let mut base_velocity = self.out.command.clone();
        let kept = &self.filtered_steps;
        if let Some(k) = kept.times.partition_point(|&tk| tk < splice).checked_sub(1) {
            base_velocity.copy_from_slice(&kept.rows[k * nq..(k + 1) * nq]);
        }
        // the tank where the segment starts: what the steps executed until the splice spend first
        if let Some(e) = energy.as_mut() {
            for (k, &tk) in kept.times.iter().enumerate() {
                let overlap = (tk + config.filter_step).min(splice) - tk.max(t);
                if overlap > 0.0 {
                    *e += overlap * EnergyTank::power(tau_ext, &kept.rows[k * nq..(k + 1) * nq]);
                }
            }
        }
        let mut reach = Reach::of(&config, shaping, step);
        let mut fallbacks = 0;
        let mut first_status = None;
        let mut solve = || -> Result<()> {
            for k in 0..config.steps() {
                let tk = splice + k as f64 * step;
                // where the arm will be: the segment's positions less the desired positions' lead
                // over the measured ones, which the robot's feedback takes back at k_p (kept whole
                // with k_p = 0: a feedforward arm that was held back stays behind its segment)
                let s = builder.state();
                for (j, &i) in arm.iter().enumerate() {
                    let k_p = config.position_gain[j];
                    let behind = lead[j] * (-k_p * (tk - t)).exp();
                    xk[i] = s.q[j] - behind;
                    xk[nq + i] = s.v[j] + k_p * behind;
                }
                plan.reference_at(tk, &mut reference);
                self.limits.velocity_box(&xk[..nq], step, &mut lower, &mut upper);
                reach.narrow(&arm, &builder.state().v, &base_velocity, &mut lower, &mut upper);
                let u: &[f64] = match filter.as_deref_mut() {
                    Some(f) => {
                        let passivity = energy.map(|e| (tau_ext, e));
                        let out = f.filter_within(&xk[..nx], &reference, passivity, Some((&lower, &upper)))?;
                        fallbacks += u64::from(out.status == FilterStatus::Fallback);
                        first_status.get_or_insert(out.status);
                        &out.u
                    }
                    None => {
                        for (i, r) in reference.iter_mut().enumerate() {
                            *r = r.clamp(lower[i], upper[i]);
                        }
                        &reference
                    }
                };
                if let Some(e) = energy.as_mut() {
                    *e += step * EnergyTank::power(tau_ext, u);
                }
                steps.times.push(tk);
                steps.rows.extend_from_slice(u);
                for (j, &i) in arm.iter().enumerate() {
                    let k_p = config.position_gain[j];
                    target[j] = u[i] - k_p * lead[j] * (-k_p * (tk - t)).exp();
                }
                reach.advance(&base_velocity, u);
                for i in (0..nq).filter(|i| !arm.contains(i)) {
                    xk[i] += u[i] * step;
                    xk[nq + i] = u[i];
                    base_velocity[i] = u[i];
                }
                for _ in 0..config.knots_per_step() {
                    builder.push(&target)?;
                }
            }
            Ok(())
        };
        let solved = solve();
        drop(filter);
        solved?;
        let new = builder.finish()?;
        // the status reported for the ticks until the next segment: its first step's
        self.out.status = first_status;
        let stream = self.trajectory.as_mut().expect("checked by the caller");
        stream.counts_mut().fallbacks += fallbacks;
        if !keeps_margin(&self.limits, &arm, &new, t - splice, &lead, &config.position_gain) {
            stream.skip(t);
            return Ok(None);
        }
        // the steps in force until the splice stay (the base executes them while the arm still
        // follows the segment they came with), then the new ones; those before now are done
        let kept = &self.filtered_steps;
        let from = kept.times.partition_point(|&tk| tk <= t).saturating_sub(1);
        let to = kept.times.partition_point(|&tk| tk < splice).max(from);
        let mut merged = FilteredSteps {
            times: kept.times[from..to].to_vec(),
            rows: kept.rows[from * nq..to * nq].to_vec(),
        };
        merged.times.extend_from_slice(&steps.times);
        merged.rows.extend_from_slice(&steps.rows);
        self.filtered_steps = merged;
        stream.commit(t, splice, new, false).map(|s| Some(s.clone()))
    }
}

/// The velocities the command path can reach within one filter step: the segment's joints at its
/// acceleration bound from the segment's velocity, the base's from the base's command at the
/// acceleration its stream reaches by then (its jerk bound raises it from the acceleration of the step
/// before, up to its acceleration bound). The filter chooses within them, so that the velocity the
/// robot executes (which the tank books) is the one the passivity row passed, not a lagging approach to it.
struct Reach {
    step: f64,
    /// Per arm joint (the segment's order): the velocity change (rad/s) one filter step allows.
    arm: Vec<f64>,
    /// The base's joints (x, y, yaw), their world rates' acceleration and jerk bounds (the base
    /// frame's smaller linear bound over √2 for x and y: reachable at any heading), and the
    /// acceleration each has reached.
    base: Option<BaseReach>,
}

struct BaseReach {
    index: [usize; 3],
    acceleration: [f64; 3],
    jerk: [f64; 3],
    reached: [f64; 3],
}

impl Reach {
    fn of(config: &TrajectoryConfig, shaping: &CommandShaping, step: f64) -> Self {
        let arm = config.shape.acceleration.iter().map(|a| a * step).collect();
        let base = shaping
            .base_index()
            .zip(shaping.gate().shaper().base())
            .map(|(index, limiter)| {
                let (a, j, now) = (limiter.a_max(), limiter.j_max(), limiter.acceleration());
                let linear = |b: &[f64]| b[0].min(b[1]) / std::f64::consts::SQRT_2;
                let planar = now[0].hypot(now[1]);
                BaseReach {
                    index,
                    acceleration: [linear(a), linear(a), a[2]],
                    jerk: [linear(j), linear(j), j[2]],
                    reached: [planar, planar, now[2].abs()],
                }
            });
        Self { step, arm, base }
    }

    /// After a filter step from the base's world rates `from` to `to` (nq): the acceleration the
    /// base's stream has reached.
    fn advance(&mut self, from: &[f64], to: &[f64]) {
        if let Some(b) = self.base.as_mut() {
            for (k, &i) in b.index.iter().enumerate() {
                b.reached[k] = ((to[i] - from[i]) / self.step).abs().min(b.acceleration[k]);
            }
        }
    }

    /// Narrows the box [`lower`, `upper`] (nq, holding 0) to what is reachable from the segment's
    /// velocities `arm_velocity` (the joints `arm`) and the base's `base_velocity` (nq, world rates),
    /// widened to hold 0: a stop stays the filter's safe choice, and the stream brakes toward it.
    fn narrow(&self, arm: &[usize], arm_velocity: &[f64], base_velocity: &[f64], lower: &mut [f64], upper: &mut [f64]) {
        let mut meet = |i: usize, v: f64, r: f64| {
            lower[i] = lower[i].max((v - r).min(0.0));
            upper[i] = upper[i].min((v + r).max(0.0));
        };
        for (j, &i) in arm.iter().enumerate() {
            meet(i, arm_velocity[j], self.arm[j]);
        }
        if let Some(b) = &self.base {
            for (k, &i) in b.index.iter().enumerate() {
                let a = (b.reached[k] + b.jerk[k] * self.step).min(b.acceleration[k]);
                meet(i, base_velocity[i], a * self.step);
            }
        }
    }
}

/// Whether every knot of `segment` (the arm's joints `arm`, times from `start` s before the tick)
/// puts the arm within the bound's inner limits, give or take half the smaller margin (the knots of a
/// stop the bound allowed end about there), or at least no further out than where the segment starts
/// (a joint the world pushed into the margin may stay or move inward): the knot's position less the
/// desired positions' `lead` over the measured ones, which the robot's feedback takes back at `gain`.
fn keeps_margin(limits: &LimitBound, arm: &[usize], segment: &Segment, start: f64, lead: &[f64], gain: &[f64]) -> bool {
    let (lower, upper) = limits.inner_limits();
    let config = limits.config();
    let slack = 0.5 * config.margin.min(config.prismatic_margin);
    let at = |k: usize, j: usize| segment.states[k].q[j] - lead[j] * (-gain[j] * (segment.times[k] - start)).exp();
    arm.iter().enumerate().all(|(j, &i)| {
        let first = at(0, j);
        let (low, high) = ((lower[i] - slack).min(first), (upper[i] + slack).max(first));
        (0..segment.times.len()).all(|k| (low..=high).contains(&at(k, j)))
    })
}

/// The arm's joints brake as a segment does: at its acceleration and jerk bounds, after the filter
/// step the command holds, the velocity's time constant it lags by and a knot's rounding.
fn brake_as_segment(limits: &mut LimitBound, stream: &TrajectoryStream, arm: &[usize]) -> Result<()> {
    let config = stream.config();
    let shape = &config.shape;
    let delay = config.filter_step + shape.time_constant + 2.0 * shape.knot;
    for (k, &i) in arm.iter().enumerate() {
        limits.set_braking(i, shape.acceleration[k], shape.jerk[k], delay)?;
    }
    Ok(())
}
