//! The bridge's tick: one arm joint state in, as rmw delivers it serialized, and one command out,
//! serialized for the arm's and the base's command topics. Between them: the joint states merged
//! by name, the object's state (the estimator from the hand pose, or the newest on its topic), the
//! cascade's tick and its command shaping ([`Cascade::tick_shaped`]: τ_ext conditioned, the rate-limited
//! gate) on the step between two states' stamps; for an arm on a joint_trajectory_controller the
//! cascade's trajectory tick ([`Cascade::tick_trajectory`]) and its segments as JointTrajectory messages
//! stamped with the answered state's stamp.

use crate::bridge::messages::{self, Stamp, TrajectoryPoint};
use crate::control::cascade::Cascade;
use crate::control::command_stream::Command;
use crate::control::joint_merge::JointMerge;
use crate::control::object_estimate::{ObjectEstimate, ObjectStateEstimator};
use crate::control::segment::Segment;
use crate::control::shaping::{shapes_no_commands, CommandShaping};
use crate::error::{ensure_finite, ensure_len, Result, SabreError};

/// How a tick's steps are timed and its commands serialized.
#[derive(Debug, Clone)]
pub struct BridgeLayout {
    /// The longest step (s) the tank integrates over between two states.
    pub max_tick_dt: f64,
    /// The base command as TwistStamped in `cmd_vel_frame` (else Twist).
    pub cmd_vel_stamped: bool,
    pub cmd_vel_frame: String,
    /// The arm joints' names for an echo of each arm command as a JointState (velocities, the
    /// answered state's stamp) for a robot whose command interface drops `data_offset`; None: no echo.
    pub echo_names: Option<Vec<String>>,
    /// The arm on a joint_trajectory_controller: its segments as JointTrajectory messages instead of
    /// the velocity stream (the cascade streams a trajectory, [`Cascade::set_trajectory`]).
    pub trajectory: Option<TrajectoryLayout>,
}

/// How the arm's segments are serialized.
#[derive(Debug, Clone)]
pub struct TrajectoryLayout {
    /// The arm's joint names, in the segments' order.
    pub names: Vec<String>,
    /// Points with accelerations (JTC interpolates them with quintics), else with positions and
    /// velocities (cubics, which reproduce the segments exactly too).
    pub accelerations: bool,
}

/// What a received joint state is.
#[derive(Debug, Clone, PartialEq)]
pub enum Received {
    /// Merged; it does not carry every arm joint (fingers, another driver's joints).
    Merged,
    /// An arm state at time `t` (s since the first), `fresh` when every joint is within its timeout.
    Tick { t: f64, fresh: bool },
    /// Refused (malformed, non-finite, a stamp not after the previous one); `ticks`: it named the
    /// arm's joints, so it still gets an answer (a ramp step).
    Rejected { error: SabreError, ticks: bool },
}

/// The serialized commands of one step: the arm's velocity command (None when the arm takes
/// segments), the base's when one is due, and the arm's next segment when one is due.
#[derive(Debug, Clone, Default)]
pub struct Answer {
    pub arm: Option<Vec<u8>>,
    pub base: Option<Vec<u8>>,
    pub echo: Option<Vec<u8>>,
    pub trajectory: Option<Vec<u8>>,
}

/// Counts the controller reports (τ_ext's are the cascade's: [`crate::control::ExternalTorque`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BridgeCounts {
    pub ticks: u64,
    pub answered: u64,
    pub followed: u64,
    pub rejected: u64,
}

/// How [`BridgeTick::follow`] answered a state.
#[derive(Debug, Clone)]
pub enum Followed {
    /// The cascade's command, shaped and serialized.
    Answered(Answer),
    /// No plan yet: nothing was sent (the caller ramps).
    NoPlan,
    /// The plan in force is older than its horizon: nothing was sent (the caller ramps).
    StalePlan,
}

/// The 1 kHz path's state between two joint states (see the module).
#[derive(Debug, Clone)]
pub struct BridgeTick {
    layout: BridgeLayout,
    joints: JointMerge,
    estimator: Option<ObjectStateEstimator>,
    nq: usize,
    object: (Vec<f64>, Vec<f64>),
    last_stamp: Option<Stamp>,
    origin: Option<Stamp>,
    last_t: Option<f64>,
    stamp: Stamp,
    x: Vec<f64>,
    estimate: Option<ObjectEstimate>,
    counts: BridgeCounts,
}

impl BridgeTick {
    /// A tick on `joints` (sabre's joints by the robot's names, the arm's driving the ticks) with the
    /// object from `estimator` or, without one, `object` (o, ȯ) until [`Self::set_object`].
    pub fn new(
        layout: BridgeLayout,
        joints: JointMerge,
        estimator: Option<ObjectStateEstimator>,
        object: (Vec<f64>, Vec<f64>),
    ) -> Result<Self> {
        let nq = joints.names().len();
        ensure_len("object velocity", &object.1, object.0.len())?;
        ensure_finite("object", &object.0)?;
        ensure_finite("object velocity", &object.1)?;
        let nx = 2 * nq + 2 * object.0.len();
        Ok(Self {
            layout,
            joints,
            estimator,
            nq,
            object,
            last_stamp: None,
            origin: None,
            last_t: None,
            stamp: Stamp::default(),
            x: vec![0.0; nx],
            estimate: None,
            counts: BridgeCounts::default(),
        })
    }

    /// Reads and merges a serialized joint state that arrived at `received` (s, monotonic).
    pub fn receive(&mut self, raw: &[u8], received: f64) -> Received {
        let message = match messages::decode_joint_state(raw) {
            Ok(m) => m,
            Err(error) => {
                self.counts.rejected += 1;
                // unreadable: its names are unknown; an answer keeps the arm's stream going
                return Received::Rejected { error, ticks: true };
            }
        };
        let stamp = message.stamp();
        let t_abs = stamp.seconds();
        // a rejected state is answered under its own stamp too
        self.stamp = stamp;
        let ticks = match self
            .joints
            .update(&message.name, &message.position, &message.velocity, received)
        {
            Ok(ticks) => ticks,
            Err(error) => {
                self.counts.rejected += 1;
                let ticks = self.joints.drives_tick(&message.name);
                return Received::Rejected { error, ticks };
            }
        };
        if !ticks {
            return Received::Merged;
        }
        if let Some(last) = self.last_stamp {
            if stamp.nanoseconds() <= last.nanoseconds() {
                self.counts.rejected += 1;
                let error = SabreError::invalid("joint state", format!("stamp {t_abs:.6} is not after the previous one"));
                return Received::Rejected { error, ticks: true };
            }
        }
        self.last_stamp = Some(stamp);
        // the ticks' time from the first state's stamp, exact to the nanosecond: a segment stamped with
        // a state's stamp starts at exactly that time
        let origin = *self.origin.get_or_insert(stamp);
        Received::Tick {
            t: stamp.seconds_since(&origin),
            fresh: self.joints.fresh(received),
        }
    }

    /// The stamp of the newest state received (its clock's time; a rejected one's too).
    pub fn stamp(&self) -> Stamp {
        self.stamp
    }

    /// The measured state x = (q, q̇, o, ȯ) at time `t` of the newest state: the object's from the
    /// estimator (hooking only when `may_hook`, with the wrist force's magnitude `force` in N;
    /// infinity: torques only, contact assumed) or the newest from its topic.
    pub fn state(&mut self, t: f64, may_hook: bool, force: f64) -> Result<&[f64]> {
        let nq = self.nq;
        let (q, qd) = (self.joints.position(), self.joints.velocity());
        self.x[..nq].copy_from_slice(q);
        self.x[nq..2 * nq].copy_from_slice(qd);
        let no = self.object.0.len();
        if let Some(estimator) = self.estimator.as_mut() {
            let force = if force.is_finite() { force } else { f64::INFINITY };
            let e = estimator.update(q, t, force, may_hook)?;
            self.object.0[0] = e.position;
            self.object.1[0] = e.velocity;
            self.estimate = Some(e);
        }
        self.x[2 * nq..2 * nq + no].copy_from_slice(&self.object.0);
        self.x[2 * nq + no..].copy_from_slice(&self.object.1);
        Ok(&self.x)
    }

    /// The newest measured state (nx), as the last [`Self::state`] left it.
    pub fn x(&self) -> &[f64] {
        &self.x
    }

    /// The estimator's newest estimate (None without an estimator or before the first state).
    pub fn estimate(&self) -> Option<&ObjectEstimate> {
        self.estimate.as_ref()
    }

    /// The step (s) to integrate over to time `t` from the previous state (capped at `max_tick_dt`;
    /// one command period, `period`, for the first).
    fn step_to(&mut self, t: f64, period: f64) -> f64 {
        let dt = match self.last_t {
            Some(last) => (t - last).min(self.layout.max_tick_dt),
            // the first state the inner loop sees: one command period
            None => period,
        };
        self.last_t = Some(t);
        dt
    }

    /// Notes that a state was observed without ticking the inner loop (the tank's step starts there).
    pub fn skip(&mut self, t: f64) {
        self.last_t = Some(t);
    }

    /// Answers the newest state, at its time `t` (received at `received`, s monotonic), with the
    /// cascade's plan in force: the state (see [`Self::state`]), and the cascade's tick over the step
    /// since the previous state with its command shaping ([`Cascade::tick_shaped`]). Without a plan,
    /// or with one older than `max_plan_age` s at t, only the state is taken and nothing is sent.
    /// Errors: a cascade that shapes no commands, or its tick's.
    pub fn follow(
        &mut self,
        cascade: &mut Cascade,
        t: f64,
        received: f64,
        may_hook: bool,
        max_plan_age: f64,
    ) -> Result<Followed> {
        self.state(t, may_hook, cascade.tau_ext().force())?;
        let age = cascade.plan_at(t).map(|plan| t - plan.t0());
        match age {
            None => {
                self.skip(t);
                return Ok(Followed::NoPlan);
            }
            Some(age) if age > max_plan_age => {
                self.skip(t);
                return Ok(Followed::StalePlan);
            }
            Some(_) => {}
        }
        let period = shaping_of(cascade)?.gate().period();
        let dt = self.step_to(t, period);
        self.counts.followed += 1;
        if cascade.trajectory().is_some() {
            let tick = cascade.tick_trajectory(&self.x, t, dt, received)?;
            return self
                .answer(&tick.command, tick.segment.as_ref(), Some(self.stamp))
                .map(Followed::Answered);
        }
        let out = cascade.tick_shaped(&self.x, t, dt, received)?.clone();
        self.answer(&out, None, Some(self.stamp)).map(Followed::Answered)
    }

    /// A step of the cascade's ramp to zero answering the newest state (or a rejected one); an arm
    /// on segments gets its stop segment once, from the newest state's time.
    pub fn stop(&mut self, cascade: &mut Cascade, received: f64) -> Result<Answer> {
        if cascade.trajectory().is_some() {
            let t = self.time_of(self.stamp);
            let tick = cascade.stop_trajectory(t, received)?;
            return self.answer(&tick.command, tick.segment.as_ref(), Some(self.stamp));
        }
        let out = shaping_mut(cascade)?.stop(received)?.clone();
        self.answer(&out, None, Some(self.stamp))
    }

    /// The ticks' time of a stamp on the states' clock (0 before the first state).
    fn time_of(&self, stamp: Stamp) -> f64 {
        self.origin.map_or(0.0, |origin| stamp.seconds_since(&origin))
    }

    fn answer(&mut self, command: &Command, segment: Option<&Segment>, answers: Option<Stamp>) -> Result<Answer> {
        self.counts.ticks += u64::from(answers.is_some());
        let stamp = answers.unwrap_or_default();
        let mut out = self.encode(command, answers, stamp)?;
        if let Some(segment) = segment {
            out.trajectory = Some(self.encode_segment(segment, stamp)?);
        }
        Ok(out)
    }

    /// A segment as a JointTrajectory stamped `stamp` (its start).
    fn encode_segment(&self, segment: &Segment, stamp: Stamp) -> Result<Vec<u8>> {
        let layout = self.layout.trajectory.as_ref().ok_or_else(|| {
            SabreError::invalid(
                "trajectory",
                "the cascade streams segments but the bridge names no trajectory joints",
            )
        })?;
        let mut out = Vec::new();
        encode_segment(&mut out, segment, stamp, &layout.names, layout.accelerations)?;
        Ok(out)
    }

    /// Serializes one step: the arm command carries the answered state's stamp's nanoseconds in
    /// `layout.data_offset` (a velocity controller ignores it; a robot can match it to the state),
    /// 0 for a step that answers none; a stamped base command carries `stamp`.
    fn encode(&mut self, command: &Command, answers: Option<Stamp>, stamp: Stamp) -> Result<Answer> {
        let mut out = Answer::default();
        if self.layout.trajectory.is_none() {
            let mut arm = Vec::new();
            messages::encode_float64_array(&mut arm, &command.arm, answers.map_or(0, |s| s.nanosec))?;
            out.arm = Some(arm);
        }
        if command.base_due {
            let mut base = Vec::new();
            let (b, stamped) = (&command.base, self.layout.cmd_vel_stamped);
            messages::encode_twist(
                &mut base,
                [b[0], b[1], 0.0],
                [0.0, 0.0, b[2]],
                stamped.then_some(stamp),
                &self.layout.cmd_vel_frame,
            )?;
            out.base = Some(base);
        }
        if let Some(names) = self.layout.echo_names.as_ref().filter(|_| self.layout.trajectory.is_none()) {
            let mut echo = Vec::new();
            messages::encode_joint_state(&mut echo, stamp, "", names, &[], &command.arm, &[])?;
            out.echo = Some(echo);
        }
        self.counts.answered += 1;
        Ok(out)
    }

    /// The cascade's ramp steps due at `now` (s, monotonic) because no state came for the state
    /// timeout (at most `limit`), stamped `stamp`.
    pub fn watchdog(&mut self, cascade: &mut Cascade, now: f64, limit: usize, stamp: Stamp) -> Result<Vec<Answer>> {
        let mut steps = Vec::new();
        shaping_mut(cascade)?.gate_mut().watchdog(now, limit, &mut steps);
        steps.iter().map(|c| self.encode(c, None, stamp)).collect()
    }

    /// One step of the cascade's ramp to zero outside the ticks (a shutdown's) stamped `stamp` (the
    /// states' clock), None once at rest; an arm on segments gets its stop segment first, from the
    /// time of `stamp`.
    pub fn ramp_step(&mut self, cascade: &mut Cascade, stamp: Stamp) -> Result<Option<Answer>> {
        if cascade.trajectory().is_some_and(|s| !s.stopped() && s.sent().is_some()) {
            let segment = cascade.stop_segment(self.time_of(stamp))?;
            let command = shaping_of(cascade)?.gate().command().clone();
            let mut out = self.encode(&command, None, stamp)?;
            out.base = None;
            out.trajectory = segment.map(|s| self.encode_segment(&s, stamp)).transpose()?;
            return Ok(Some(out));
        }
        let gate = shaping_mut(cascade)?.gate_mut();
        if gate.shaper().at_rest() {
            return Ok(None);
        }
        let mut command = gate.shaper().command();
        gate.shaper_mut().step(None, None, &mut command)?;
        self.encode(&command, None, stamp).map(Some)
    }

    /// Merges joints from another source (the base's from odometry).
    pub fn set_joints(&mut self, indices: &[usize], position: &[f64], velocity: &[f64], received: f64) -> Result<()> {
        self.joints.set(indices, position, velocity, received)
    }

    /// A serialized wrist wrench (geometry_msgs/WrenchStamped) that arrived at `received`: handed to
    /// the cascade's τ_ext ([`crate::control::ExternalTorque::set_wrench`]) at the newest joint
    /// positions. Errors: a malformed message, or the cascade's; nothing changes then.
    pub fn set_wrench(&self, cascade: &mut Cascade, raw: &[u8], received: f64) -> Result<()> {
        let message = messages::decode_wrench(raw)?;
        cascade
            .tau_ext_mut()
            .set_wrench(self.joints.position(), &message.wrench, &message.frame_id, received)
    }

    /// The object's state from its topic.
    pub fn set_object(&mut self, position: &[f64], velocity: &[f64]) -> Result<()> {
        ensure_len("object position", position, self.object.0.len())?;
        ensure_len("object velocity", velocity, self.object.1.len())?;
        ensure_finite("object position", position)?;
        ensure_finite("object velocity", velocity)?;
        self.object.0.copy_from_slice(position);
        self.object.1.copy_from_slice(velocity);
        Ok(())
    }

    pub fn joints(&self) -> &JointMerge {
        &self.joints
    }
    pub fn counts(&self) -> &BridgeCounts {
        &self.counts
    }
    /// The object's coordinate as the controller knows it (estimated or received).
    pub fn opening(&self) -> f64 {
        self.object.0.first().copied().unwrap_or(f64::NAN)
    }
}

/// Serializes `segment` as a JointTrajectory for the joints `names` stamped `stamp` (its start) into
/// `out`: a point per knot with positions and velocities, and with `accelerations` its accelerations.
pub fn encode_segment(out: &mut Vec<u8>, segment: &Segment, stamp: Stamp, names: &[String], accelerations: bool) -> Result<()> {
    let points: Vec<TrajectoryPoint> = segment
        .times
        .iter()
        .zip(&segment.states)
        .map(|(&t, s)| TrajectoryPoint {
            time_from_start: t,
            positions: s.q.clone(),
            velocities: s.v.clone(),
            accelerations: if accelerations { s.a.clone() } else { Vec::new() },
        })
        .collect();
    messages::encode_joint_trajectory(out, stamp, names, &points)
}

/// The cascade's command shaping, which a bridge's cascade must have.
pub fn shaping_of(cascade: &Cascade) -> Result<&CommandShaping> {
    cascade.shaping().ok_or_else(shapes_no_commands)
}

fn shaping_mut(cascade: &mut Cascade) -> Result<&mut CommandShaping> {
    cascade.shaping_mut().ok_or_else(shapes_no_commands)
}

#[cfg(test)]
mod tests;
