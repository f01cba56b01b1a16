//! The bridge's tick: one arm joint state in, as rmw delivers it serialized, and one command out,
//! serialized for the arm's and the base's command topics. Between them: the joint states merged
//! by name, the object's state (the estimator from the hand pose, or the newest on its topic), the
//! cascade's tick ([`Cascade::tick`], which conditions τ_ext) on the step between two states' stamps,
//! and the rate-limited command gate.

use crate::bridge::messages::{self, Stamp};
use crate::control::cascade::Cascade;
use crate::control::command_stream::{Command, CommandGate};
use crate::control::joint_merge::JointMerge;
use crate::control::object_estimate::{ObjectEstimate, ObjectStateEstimator};
use crate::error::{ensure_finite, ensure_len, Result, SabreError};

/// How a tick's joints map onto the commands and how time and τ_ext are read.
#[derive(Debug, Clone)]
pub struct BridgeLayout {
    /// sabre's joints the arm command carries, in its order.
    pub arm_index: Vec<usize>,
    /// sabre's base x, y and yaw joints (None: a fixed base, no base command).
    pub base_index: Option<[usize; 3]>,
    /// The longest step (s) the tank integrates over between two states.
    pub max_tick_dt: f64,
    /// The base command as TwistStamped in `cmd_vel_frame` (else Twist).
    pub cmd_vel_stamped: bool,
    pub cmd_vel_frame: String,
    /// The arm joints' names for an echo of each arm command as a JointState (velocities, the
    /// answered state's stamp) for a robot whose command interface drops `data_offset`; None: no echo.
    pub echo_names: Option<Vec<String>>,
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

/// The serialized commands of one step: the arm's, and the base's when one is due.
#[derive(Debug, Clone, Default)]
pub struct Answer {
    pub arm: Vec<u8>,
    pub base: Option<Vec<u8>>,
    pub echo: Option<Vec<u8>>,
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
    gate: CommandGate,
    estimator: Option<ObjectStateEstimator>,
    nq: usize,
    object: (Vec<f64>, Vec<f64>),
    last_stamp: Option<f64>,
    origin: Option<f64>,
    last_t: Option<f64>,
    stamp: Stamp,
    x: Vec<f64>,
    arm_target: Vec<f64>,
    base_target: Vec<f64>,
    estimate: Option<ObjectEstimate>,
    counts: BridgeCounts,
}

impl BridgeTick {
    /// A tick on `joints` (sabre's joints by the robot's names, the arm's driving the ticks) with
    /// `gate`, and the object from `estimator` or, without one, `object` (o, ȯ) until [`Self::set_object`].
    pub fn new(
        layout: BridgeLayout,
        joints: JointMerge,
        gate: CommandGate,
        estimator: Option<ObjectStateEstimator>,
        object: (Vec<f64>, Vec<f64>),
    ) -> Result<Self> {
        let nq = joints.names().len();
        let na = gate.shaper().arm().len();
        if layout.arm_index.len() != na || layout.arm_index.iter().any(|&i| i >= nq) {
            return Err(SabreError::invalid(
                "arm_index",
                format!("needs {na} distinct joints of {nq}, got {:?}", layout.arm_index),
            ));
        }
        if layout.base_index.is_some() != gate.shaper().base().is_some()
            || layout.base_index.is_some_and(|b| b.iter().any(|&i| i >= nq))
        {
            return Err(SabreError::invalid(
                "base_index",
                "a base command needs the base's three joints and a base limiter, a fixed base neither",
            ));
        }
        ensure_len("object velocity", &object.1, object.0.len())?;
        ensure_finite("object", &object.0)?;
        ensure_finite("object velocity", &object.1)?;
        let nx = 2 * nq + 2 * object.0.len();
        Ok(Self {
            layout,
            joints,
            gate,
            estimator,
            nq,
            object,
            last_stamp: None,
            origin: None,
            last_t: None,
            stamp: Stamp::default(),
            x: vec![0.0; nx],
            arm_target: vec![0.0; na],
            base_target: vec![0.0; 3],
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
            if t_abs <= last {
                self.counts.rejected += 1;
                let error = SabreError::invalid("joint state", format!("stamp {t_abs:.6} is not after the previous one"));
                return Received::Rejected { error, ticks: true };
            }
        }
        self.last_stamp = Some(t_abs);
        let origin = *self.origin.get_or_insert(t_abs);
        Received::Tick {
            t: t_abs - origin,
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
    /// one command period for the first).
    fn step_to(&mut self, t: f64) -> f64 {
        let dt = match self.last_t {
            Some(last) => (t - last).min(self.layout.max_tick_dt),
            // the first state the inner loop sees: one command period
            None => self.gate.period(),
        };
        self.last_t = Some(t);
        dt
    }

    /// Notes that a state was observed without ticking the inner loop (the tank's step starts there).
    pub fn skip(&mut self, t: f64) {
        self.last_t = Some(t);
    }

    /// Answers the newest state, at its time `t` (received at `received`, s monotonic), with the
    /// cascade's plan in force: the state (see [`Self::state`]), the cascade's tick over the step
    /// since the previous state, and the gate's step toward its command (nq, in sabre's joints; the
    /// base's in world rates, turned into the base frame here). Without a plan, or with one older
    /// than `max_plan_age` s at t, only the state is taken and nothing is sent.
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
        let dt = self.step_to(t);
        let command = &cascade.tick(&self.x, t, dt, received)?.command;
        for (target, &i) in self.arm_target.iter_mut().zip(&self.layout.arm_index) {
            *target = command[i];
        }
        if let Some([ix, iy, iyaw]) = self.layout.base_index {
            // world rates → the base frame's twist (vx, vy, ωz)
            let yaw = self.joints.position()[iyaw];
            let (c, s) = (yaw.cos(), yaw.sin());
            let (vx, vy) = (command[ix], command[iy]);
            self.base_target
                .copy_from_slice(&[c * vx + s * vy, -s * vx + c * vy, command[iyaw]]);
        }
        let base_target = self.layout.base_index.map(|_| self.base_target.as_slice());
        let out = self.gate.on_tick(received, Some(&self.arm_target), base_target)?.clone();
        self.counts.followed += 1;
        self.answer(&out, Some(self.stamp)).map(Followed::Answered)
    }

    /// A step of the ramp to zero answering the newest state (or a rejected one).
    pub fn stop(&mut self, received: f64) -> Result<Answer> {
        let out = self.gate.on_tick(received, None, None)?.clone();
        self.answer(&out, Some(self.stamp))
    }

    fn answer(&mut self, command: &Command, answers: Option<Stamp>) -> Result<Answer> {
        self.counts.ticks += u64::from(answers.is_some());
        self.encode(command, answers, answers.unwrap_or_default())
    }

    /// Serializes one step: the arm command carries the answered state's stamp's nanoseconds in
    /// `layout.data_offset` (a velocity controller ignores it; a robot can match it to the state),
    /// 0 for a step that answers none; a stamped base command carries `stamp`.
    fn encode(&mut self, command: &Command, answers: Option<Stamp>, stamp: Stamp) -> Result<Answer> {
        let mut out = Answer::default();
        messages::encode_float64_array(&mut out.arm, &command.arm, answers.map_or(0, |s| s.nanosec))?;
        if command.base_due && self.layout.base_index.is_some() {
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
        if let Some(names) = &self.layout.echo_names {
            let mut echo = Vec::new();
            messages::encode_joint_state(&mut echo, stamp, "", names, &[], &command.arm, &[])?;
            out.echo = Some(echo);
        }
        self.counts.answered += 1;
        Ok(out)
    }

    /// The ramp steps due at `now` (s, monotonic) because no state came for the state timeout
    /// (at most `limit`), stamped `stamp`.
    pub fn watchdog(&mut self, now: f64, limit: usize, stamp: Stamp) -> Result<Vec<Answer>> {
        let mut steps = Vec::new();
        self.gate.watchdog(now, limit, &mut steps);
        steps.iter().map(|c| self.encode(c, None, stamp)).collect()
    }

    /// One step of the ramp to zero outside the ticks (a shutdown's), None once at rest.
    pub fn ramp_step(&mut self, stamp: Stamp) -> Result<Option<Answer>> {
        if self.gate.shaper().at_rest() {
            return Ok(None);
        }
        let mut command = self.gate.shaper().command();
        self.gate.shaper_mut().step(None, None, &mut command)?;
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
    pub fn gate(&self) -> &CommandGate {
        &self.gate
    }
    pub fn counts(&self) -> &BridgeCounts {
        &self.counts
    }
    /// The object's coordinate as the controller knows it (estimated or received).
    pub fn opening(&self) -> f64 {
        self.object.0.first().copied().unwrap_or(f64::NAN)
    }
}
