//! The control cascade's inner loop, one tick for every clock and plant: the plan in force (handed over by
//! the planner, taking over at its time), τ_ext conditioned, the FILTER-QP (41) with the tank's passivity row
//! (56) and the hard joint-limit bound ([`LimitBound`]), the tank's refill and step (49), the low-level
//! torque (53), and for a robot's command interface the command shaping ([`CommandShaping`]). `run_episode`,
//! the deployment loop and the ROS bridge's velocity stream all tick through [`Cascade::tick`];
//! [`Cascade::follow`] runs it on the Rust plant. An arm on a joint_trajectory_controller ticks through
//! [`Cascade::tick_trajectory`] instead (the `trajectory` child module).

use std::sync::{Arc, Mutex, MutexGuard};

use super::command_stream::Command;
use super::low_level::LowLevelController;
use super::plan::Plan;
use super::shaping::CommandShaping;
use super::tau_ext::ExternalTorque;
use super::trajectory_stream::{FilteredSteps, TrajectoryStream};
use crate::error::{ensure_finite, ensure_len, Result, SabreError};
use crate::model::{LimitBound, LimitBoundConfig};
use crate::safety::{EnergyTank, FilterStatus, SafetyFilter};

/// A stage the cascade shares with another holder: the planner reads the tank's energy and edits the
/// filter's obstacles, a user tunes the low-level controller between ticks.
pub type Shared<T> = Arc<Mutex<T>>;

/// The object behind `mutex`, also after a panic in another holder poisoned it: every stage checks its
/// inputs before it mutates, so a panic leaves it usable.
pub fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A plan handed over for time t_a takes over at the first tick at t ≥ t_a − this (s): simulated clocks
/// that sum their steps land a rounding error short of t_a.
pub const TAKEOVER_TOLERANCE: f64 = 1e-7;

/// What one tick produced; the buffers are reused from tick to tick.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TickOutput {
    /// The plan's reference at the tick's time (nu).
    pub reference: Vec<f64>,
    /// The command after the filter and the joint-limit bound (nu): the bounded reference without a
    /// filter.
    pub command: Vec<f64>,
    /// The low-level controller's joint torques tracking the command (nq).
    pub torque: Vec<f64>,
    /// The tank's energy after the tick (J); None without a tank.
    pub tank_energy: Option<f64>,
    /// The filter's status; None without a filter.
    pub status: Option<FilterStatus>,
}

impl TickOutput {
    /// Buffers for a robot with nu inputs and nq joints.
    pub fn new(nu: usize, nq: usize) -> Self {
        Self {
            reference: vec![0.0; nu],
            command: vec![0.0; nu],
            torque: vec![0.0; nq],
            tank_energy: None,
            status: None,
        }
    }

    /// The filter status's name, or "unfiltered" without a filter.
    pub fn status_name(&self) -> &'static str {
        self.status.map_or("unfiltered", FilterStatus::name)
    }
}

/// Samples recorded while [`Cascade::follow`] drives the plant (one row per recorded plant step).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrackTrace {
    pub time: Vec<f64>,
    /// nx per row.
    pub state: Vec<f64>,
    /// nq per row: the interpolated velocity reference of that step.
    pub reference: Vec<f64>,
    /// 6 per row.
    pub wrench: Vec<f64>,
    /// nq per row: the simulator's contact τ_ext of the step.
    pub tau_ext: Vec<f64>,
    /// nq per row: the plant's τ_ext measurement after the step (`Plant::measured_tau_ext`).
    pub tau_ext_measured: Vec<f64>,
    pub contact: Vec<bool>,
    /// With a filter only (else empty): nq per row, the filtered (and bounded) command that the
    /// low-level controller tracked in that step.
    pub filtered: Vec<f64>,
    /// With a tank only: tank energy after the step.
    pub tank_energy: Vec<f64>,
    /// With a filter only: the filter's status in that step.
    pub filter_status: Vec<FilterStatus>,
}

/// A plan handed to the cascade, with the number it was handed over under.
#[derive(Debug, Clone)]
struct Handed {
    plan: Arc<Plan>,
    serial: u64,
}

/// The inner loop of the cascade (see the module). Its stages are shared (see [`Shared`]); it owns the
/// plans it was handed, the τ_ext conditioning and the tick's buffers.
pub struct Cascade {
    low_level: Shared<LowLevelController>,
    filter: Option<Shared<SafetyFilter>>,
    tank: Option<Shared<EnergyTank>>,
    tau_ext: ExternalTorque,
    shaping: Option<CommandShaping>,
    limits: LimitBound,
    /// The commands the bound allows this tick, per joint (lower ≤ 0 ≤ upper), and the positions it
    /// bounds them from.
    allowed: (Vec<f64>, Vec<f64>),
    steered: Vec<f64>,
    limit_holds: u64,
    plan: Option<Handed>,
    pending: Option<(Handed, f64)>,
    handed: u64,
    nx: usize,
    nq: usize,
    out: TickOutput,
    ticks: u64,
    trajectory: Option<TrajectoryStream>,
    filtered_steps: FilteredSteps,
}

impl Cascade {
    /// The cascade of `low_level` with the optional FILTER-QP `filter` (built for the same robot) and
    /// energy `tank`, reading τ_ext through `tau_ext` (see [`ExternalTorque`]). Its joint-limit bound
    /// has the filter's settings ([`crate::safety::SafetyConfig::limit_bound`]), the defaults without
    /// one ([`Self::set_limit_bound`] changes them).
    pub fn new(
        low_level: Shared<LowLevelController>,
        filter: Option<Shared<SafetyFilter>>,
        tank: Option<Shared<EnergyTank>>,
        tau_ext: ExternalTorque,
    ) -> Result<Self> {
        let scene = lock(&low_level).scene().clone();
        let (nx, nq) = (scene.nx(), scene.nq());
        let mut bound = LimitBoundConfig::default();
        if let Some(f) = &filter {
            let f = lock(f);
            if f.scene().nq() != nq || f.scene().nx() != nx {
                return Err(SabreError::invalid(
                    "safety filter",
                    "was built for a different scene than the low-level controller's",
                ));
            }
            bound = f.config().limit_bound;
        }
        let mut limits = LimitBound::new(&scene, &bound)?;
        brake_within_low_level(&mut limits, &lock(&low_level))?;
        if tau_ext.raw().len() != nq {
            return Err(SabreError::invalid(
                "tau_ext",
                format!("reads {} joints, the robot has {nq}", tau_ext.raw().len()),
            ));
        }
        Ok(Self {
            low_level,
            filter,
            tank,
            tau_ext,
            shaping: None,
            limits,
            allowed: (vec![0.0; nq], vec![0.0; nq]),
            steered: vec![0.0; nq],
            limit_holds: 0,
            plan: None,
            pending: None,
            handed: 0,
            nx,
            nq,
            out: TickOutput::new(nq, nq),
            ticks: 0,
            trajectory: None,
            filtered_steps: Default::default(),
        })
    }

    pub fn low_level(&self) -> &Shared<LowLevelController> {
        &self.low_level
    }
    pub fn filter(&self) -> Option<&Shared<SafetyFilter>> {
        self.filter.as_ref()
    }
    pub fn tank(&self) -> Option<&Shared<EnergyTank>> {
        self.tank.as_ref()
    }
    pub fn tau_ext(&self) -> &ExternalTorque {
        &self.tau_ext
    }
    /// The τ_ext readings, to hand it a new one ([`ExternalTorque::set_torque`], [`ExternalTorque::set_wrench`]).
    pub fn tau_ext_mut(&mut self) -> &mut ExternalTorque {
        &mut self.tau_ext
    }
    /// Shapes the commands for a robot's command interface from now on ([`Self::tick_shaped`]); the
    /// shaping must be for this cascade's robot.
    pub fn set_shaping(&mut self, shaping: CommandShaping) -> Result<()> {
        let base = shaping.base_index();
        let widest = shaping.arm_index().iter().chain(base.iter().flatten()).max();
        if widest.is_some_and(|&i| i >= self.nq) {
            return Err(SabreError::invalid(
                "command shaping",
                format!("names joints past the robot's {}", self.nq),
            ));
        }
        let mut limits = self.limits.clone();
        limits.clear_braking();
        brake_within_low_level(&mut limits, &lock(&self.low_level))?;
        brake_as_shaped(&mut limits, &shaping)?;
        self.rebrake_trajectory(&mut limits, shaping.arm_index())?;
        (self.limits, self.shaping) = (limits, Some(shaping));
        Ok(())
    }

    /// The joint-limit bound's settings from now on (the margins checked against the robot); a shaped
    /// joint keeps braking as its limiter does.
    pub fn set_limit_bound(&mut self, config: &LimitBoundConfig) -> Result<()> {
        let scene = lock(&self.low_level).scene().clone();
        let mut limits = LimitBound::new(&scene, config)?;
        brake_within_low_level(&mut limits, &lock(&self.low_level))?;
        if let Some(shaping) = &self.shaping {
            brake_as_shaped(&mut limits, shaping)?;
            self.rebrake_trajectory(&mut limits, shaping.arm_index())?;
        }
        self.limits = limits;
        Ok(())
    }
    /// The joint-limit bound every command passes after the filter.
    pub fn limit_bound(&self) -> &LimitBound {
        &self.limits
    }
    /// Ticks whose command the joint-limit bound (or the filter's hard-limit guard) changed.
    pub fn limit_holds(&self) -> u64 {
        self.limit_holds
    }
    pub fn shaping(&self) -> Option<&CommandShaping> {
        self.shaping.as_ref()
    }
    pub fn shaping_mut(&mut self) -> Option<&mut CommandShaping> {
        self.shaping.as_mut()
    }
    pub fn nx(&self) -> usize {
        self.nx
    }
    pub fn nq(&self) -> usize {
        self.nq
    }
    /// Ticks since construction or the last [`Self::reset`].
    pub fn ticks(&self) -> u64 {
        self.ticks
    }
    /// The last tick's output.
    pub fn output(&self) -> &TickOutput {
        &self.out
    }

    // The plan in force ---------------------------------------------------------------------------

    /// Hands over `plan`; returns the number it is known by from now on ([`Self::in_force`]). It takes
    /// over at the first tick at time `at` (s) or later; None, or no plan in force yet: at once. A plan
    /// still waiting for its time is dropped.
    pub fn hand_over(&mut self, plan: Arc<Plan>, at: Option<f64>) -> Result<u64> {
        if plan.nu() != self.nq {
            return Err(SabreError::shape(
                "plan",
                format!("(K, {})", self.nq),
                format!("({}, {})", plan.steps(), plan.nu()),
            ));
        }
        if let Some(at) = at.filter(|a| !a.is_finite()) {
            return Err(SabreError::invalid("at", format!("must be finite, got {at}")));
        }
        self.handed += 1;
        let handed = Handed {
            plan,
            serial: self.handed,
        };
        match at {
            Some(at) if self.plan.is_some() => self.pending = Some((handed, at)),
            _ => (self.plan, self.pending) = (Some(handed), None),
        }
        Ok(self.handed)
    }

    /// The plan in force at time `t` (s), after one handed over for t or earlier takes over; None
    /// before the first.
    pub fn plan_at(&mut self, t: f64) -> Option<&Arc<Plan>> {
        if self.pending.as_ref().is_some_and(|(_, at)| t >= at - TAKEOVER_TOLERANCE) {
            self.plan = self.pending.take().map(|(handed, _)| handed);
        }
        self.plan.as_ref().map(|h| &h.plan)
    }

    /// The number of the plan in force (as [`Self::hand_over`] returned it), None before the first.
    pub fn in_force(&self) -> Option<u64> {
        self.plan.as_ref().map(|h| h.serial)
    }

    /// The number of the plan waiting for its time, and the time.
    pub fn pending(&self) -> Option<(u64, f64)> {
        self.pending.as_ref().map(|(h, at)| (h.serial, *at))
    }

    /// Forgets the plans and the low-level controller's integral: the next tick needs a new plan. The
    /// τ_ext readings are the world's and stay (a robot's wrench stream does not restart with the
    /// planner); [`ExternalTorque::reset`] forgets them.
    pub fn reset(&mut self) {
        self.plan = None;
        self.pending = None;
        lock(&self.low_level).reset();
        self.ticks = 0;
        self.limit_holds = 0;
    }

    // The tick ------------------------------------------------------------------------------------

    /// One tick with `tau_ext` (nq) measured now: [`ExternalTorque::set_torque`] at time `t` (contact
    /// assumed), then [`Self::tick`] at `t`. Every input is checked before anything changes.
    pub fn tick_measured(&mut self, x: &[f64], tau_ext: &[f64], t: f64, dt: f64) -> Result<&TickOutput> {
        ensure_len("tau_ext", tau_ext, self.nq)?;
        ensure_finite("tau_ext", tau_ext)?;
        self.check_tick(x, t, dt)?;
        self.tau_ext.set_torque(tau_ext, f64::INFINITY, t)?;
        self.tick(x, t, dt, t)
    }

    /// The checks every tick makes before anything changes: the state as the model reads it, the times,
    /// a plan to follow.
    fn check_tick(&self, x: &[f64], t: f64, dt: f64) -> Result<()> {
        lock(&self.low_level).scene().check_state(x)?;
        if !t.is_finite() {
            return Err(SabreError::invalid("t", format!("must be finite, got {t}")));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be finite and positive, got {dt}")));
        }
        if self.plan.is_none() && self.pending.is_none() {
            return Err(SabreError::invalid(
                "plan",
                "no plan yet: hand one over before the first tick",
            ));
        }
        Ok(())
    }

    /// One inner-loop step at the measured state `x` (nx) at time `t`, integrating over `dt` (s), with
    /// τ_ext conditioned for `now` (the readings' clock): the plan in force at t, its reference at t →
    /// FILTER-QP, with the passivity row (56) fed by τ_ext and the tank's energy when there is a tank,
    /// and the joint-limit bound at x's positions (a joint's stop at its deceleration, one tick of `dt`
    /// late or as its limiter's stream allows, ends a margin inside its limit; applied by the filter's
    /// hard-limit guard, which keeps the passivity row's power, or as a clip without a filter) → the
    /// tank's refill (when it has one configured and the plan a predicted dissipation) → the tank step
    /// (49) with τ_ext and the filtered command → the low-level torque (53) with the plan's gain inertia
    /// floor, else the controller's own.
    ///
    /// The tank is integrated with the same measurement the passivity row saw and the command the
    /// filter returned, S ← S + dt τ̂ᵀu, as a controller on a real robot must (it cannot know the
    /// next reading): a row met without slack then keeps S above its floor in discrete time.
    /// Errors: bad inputs or no plan yet, before any stage changes state.
    pub fn tick(&mut self, x: &[f64], t: f64, dt: f64, now: f64) -> Result<&TickOutput> {
        self.check_tick(x, t, dt)?;
        let Some(plan) = self.plan_at(t).cloned() else {
            return Err(SabreError::invalid(
                "plan",
                "no plan yet: hand one over before the first tick",
            ));
        };
        let tau_ext = self.tau_ext.condition(now, dt);
        let out = &mut self.out;
        plan.reference_at(t, &mut out.reference);
        let mut controller = lock(&self.low_level);
        let mut filter = self.filter.as_deref().map(lock);
        let mut tank = self.tank.as_deref().map(lock);
        steered_positions(&self.limits, &controller, &x[..self.nq], &mut self.steered);
        let (lower, upper) = (&mut self.allowed.0, &mut self.allowed.1);
        self.limits.velocity_box(&self.steered, dt, lower, upper);
        let held = match filter.as_deref_mut() {
            Some(filter) => {
                let passivity = tank.as_ref().map(|tank| (tau_ext, tank.energy()));
                let holds = filter.stats().hard_limit_holds;
                let filtered = filter.filter_within(x, &out.reference, passivity, Some((lower, upper)))?;
                out.command.copy_from_slice(&filtered.u);
                out.status = Some(filtered.status);
                filter.stats().hard_limit_holds > holds
            }
            None => {
                let mut held = false;
                for (i, (c, &r)) in out.command.iter_mut().zip(&out.reference).enumerate() {
                    *c = r.clamp(lower[i], upper[i]);
                    held |= *c != r;
                }
                out.status = None;
                held
            }
        };
        self.limit_holds += u64::from(held);
        let (inner_lower, inner_upper) = self.limits.inner_limits();
        for (i, &q) in x[..self.nq].iter().enumerate().filter(|&(i, _)| !self.limits.shaped(i)) {
            controller.clamp_position_error(i, inner_lower[i] - q, inner_upper[i] - q);
        }
        out.tank_energy = match tank.as_deref_mut() {
            Some(tank) => {
                if let Some(predicted) = plan.predicted_dissipation_at(t).filter(|_| tank.refill_config().is_some()) {
                    // Against the reference, not the filtered command: the test is whether the world
                    // pushes back as the model predicted, whatever the passivity row let through.
                    let measured = -EnergyTank::power(tau_ext, &out.reference);
                    tank.refill(predicted, measured, dt)?;
                }
                Some(tank.step(tau_ext, &out.command, dt)?)
            }
            None => None,
        };
        let floor = plan.gain_inertia_floor().unwrap_or(controller.config().gain_inertia_floor);
        controller.torque_into(x, &out.command, floor, &mut out.torque)?;
        self.ticks += 1;
        Ok(&self.out)
    }

    /// [`Self::tick`], then the command shaping's step at `now` toward the tick's command (see
    /// [`CommandShaping::follow`]). Errors: no shaping (before anything changes), or the tick's.
    pub fn tick_shaped(&mut self, x: &[f64], t: f64, dt: f64, now: f64) -> Result<&Command> {
        if self.shaping.is_none() {
            return Err(super::shaping::shapes_no_commands());
        }
        self.tick(x, t, dt, now)?;
        let shaping = self.shaping.as_mut().expect("checked above");
        shaping.follow(now, &self.out.command, x)?;
        // A limiter still braking from above the bound (after a stale state's ramp) must keep braking.
        if beyond_bound(shaping, &self.allowed, x) {
            shaping.gate_mut().forbid_hold();
        }
        Ok(shaping.gate().command())
    }

    /// The cascade driving `plant` for `steps` plant steps: each a [`Self::tick`] at the plant's state,
    /// its τ_ext measurement and time, integrating over the plant's step, then the plant step with the
    /// tick's torques; records every `record_every`-th step into `trace` (0: none). A plan taking over
    /// is checked first for a gain inertia floor the plant's step can keep stable. A filter fallback
    /// (u = 0) is tracked like any other command and recorded.
    pub fn follow(
        &mut self,
        plant: &mut crate::sim::Plant,
        steps: usize,
        record_every: usize,
        trace: &mut TrackTrace,
    ) -> Result<()> {
        if plant.scene().nq() != self.nq || plant.scene().nx() != self.nx {
            return Err(SabreError::invalid(
                "plant",
                "the cascade was built for a different scene than the plant's",
            ));
        }
        let (has_filter, has_tank) = (self.filter.is_some(), self.tank.is_some());
        let plant_dt = plant.dt();
        let mut checked = None;
        let mut poll = crate::interrupt::Poll::new();
        for step in 0..steps {
            poll.check()?;
            let t = plant.time();
            if let Some(plan) = self.plan_at(t).cloned() {
                if checked != self.in_force() {
                    let controller = lock(&self.low_level);
                    controller.check_stable(
                        plan.gain_inertia_floor().unwrap_or(controller.config().gain_inertia_floor),
                        plant_dt,
                    )?;
                    checked = self.in_force();
                }
            }
            self.tau_ext.set_torque(plant.measured_tau_ext(), f64::INFINITY, t)?;
            self.tick(plant.state(), t, plant_dt, t)?;
            plant.step(&self.out.torque)?;
            if record_every > 0 && step % record_every == 0 {
                let out = &self.out;
                trace.time.push(plant.time());
                trace.state.extend_from_slice(plant.state());
                trace.reference.extend_from_slice(&out.reference);
                let i = plant.interaction();
                trace.wrench.extend_from_slice(&i.wrench);
                trace.tau_ext.extend_from_slice(&i.tau_ext);
                trace.tau_ext_measured.extend_from_slice(plant.measured_tau_ext());
                trace.contact.push(i.contact);
                if has_filter {
                    trace.filtered.extend_from_slice(&out.command);
                    trace.filter_status.push(out.status.unwrap_or_default());
                }
                if has_tank {
                    trace.tank_energy.push(out.tank_energy.unwrap_or(f64::NAN));
                }
            }
        }
        Ok(())
    }
}

/// Whether a stream's output, the velocity its limiter commands now, lies outside the bound's box
/// `allowed` at the state `x` (the base's in world rates).
fn beyond_bound(shaping: &CommandShaping, allowed: &(Vec<f64>, Vec<f64>), x: &[f64]) -> bool {
    let outside = |i: usize, v: f64| {
        let slack = 1e-12 * (1.0 + v.abs());
        v > allowed.1[i] + slack || v < allowed.0[i] - slack
    };
    let shaper = shaping.gate().shaper();
    let arm = shaper.arm().velocity();
    if shaping.arm_index().iter().zip(arm).any(|(&i, &v)| outside(i, v)) {
        return true;
    }
    match (shaping.base_index(), shaper.base()) {
        (Some([ix, iy, iyaw]), Some(base)) => {
            let (b, (c, s)) = (base.velocity(), (x[iyaw].cos(), x[iyaw].sin()));
            outside(ix, c * b[0] - s * b[1]) || outside(iy, s * b[0] + c * b[1]) || outside(iyaw, b[2])
        }
        _ => false,
    }
}

/// The positions the bound keeps inside the margins: a shaped joint's measured one (the robot's own
/// controller follows the command), else where the low-level controller steers it, q plus its
/// position error, which the tick then keeps from pointing past the margin
/// ([`LowLevelController::clamp_position_error`]): a joint that trailed its reference would
/// otherwise catch up past a stop the command ended in time.
fn steered_positions(limits: &LimitBound, controller: &LowLevelController, q: &[f64], out: &mut [f64]) {
    let (lower, upper) = limits.inner_limits();
    let error = controller.position_error();
    for i in 0..q.len() {
        out[i] = if limits.shaped(i) {
            q[i]
        } else {
            q[i] + error[i].clamp((lower[i] - q[i]).min(0.0), (upper[i] - q[i]).max(0.0))
        };
    }
}

/// A low-level controller that rate-limits the command it tracks
/// ([`LowLevelController::set_command_acceleration`]) brakes each joint at most at its bound.
fn brake_within_low_level(limits: &mut LimitBound, low_level: &LowLevelController) -> Result<()> {
    for (i, a) in low_level.command_acceleration().into_iter().flatten().enumerate() {
        limits.cap_deceleration(i, a)?;
    }
    Ok(())
}

/// Joints a shaping's limiters command brake as those limiters do: an arm joint at its limiter's
/// acceleration and jerk bounds, the base's x and y at the smaller of the base limiter's bounds on vx
/// and vy (its streams are in the base's frame, which turns), its yaw at ωz's. From the state a tick
/// measured, the command before runs for one period of its stream; a stop then starts at the next
/// step, or, when no state comes, at the gate's watchdog ramp: the tick's command runs for the state
/// timeout and until the ramp's first step, one period more. The delay is the sum.
fn brake_as_shaped(limits: &mut LimitBound, shaping: &CommandShaping) -> Result<()> {
    let gate = shaping.gate();
    let timeout = gate.state_timeout();
    let delay = |period: f64| if timeout.is_finite() { 2.0 * period + timeout } else { period };
    let arm = gate.shaper().arm();
    for (k, &i) in shaping.arm_index().iter().enumerate() {
        limits.set_braking(i, arm.a_max()[k], arm.j_max()[k], delay(arm.dt()))?;
    }
    if let (Some([ix, iy, iyaw]), Some(base)) = (shaping.base_index(), gate.shaper().base()) {
        let (a, j, period) = (base.a_max(), base.j_max(), base.dt());
        for i in [ix, iy] {
            limits.set_braking(i, a[0].min(a[1]), j[0].min(j[1]), delay(period))?;
        }
        limits.set_braking(iyaw, a[2], j[2], delay(period))?;
    }
    Ok(())
}

mod trajectory;

#[cfg(test)]
mod limit_tests;
#[cfg(test)]
mod tests;
#[cfg(test)]
mod trajectory_tests;
