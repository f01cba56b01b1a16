//! The simulated robot's 1 kHz side as its drivers would have it: the arm commands it takes (checked,
//! recorded, held against Franka's reflexes, matched to the state they answer), the joint velocity
//! reference of each plant tick, and the arm's joint states it publishes with measurement noise.

use std::collections::{HashMap, VecDeque};

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::cycles::CycleRecord;
use super::jtc::TrajectoryFollower;
use super::messages::{self, Stamp};
use super::reflexes::FrankaReflexes;
use crate::error::{Result, SabreError};

/// Where the driver takes its arm commands from at each tick: a middleware subscription.
pub trait MessageSource: Send {
    /// The next message waiting (its bytes and the time the middleware received it, ns since the
    /// epoch, 0 when it does not say), or None.
    fn take(&mut self) -> Result<Option<(&[u8], i64)>>;
}

/// Where the driver publishes its joint states: a middleware publisher.
pub trait MessageSink: Send {
    fn publish(&self, bytes: &[u8]) -> Result<()>;
}

/// How the driver is laid out: which of the robot's joints are the arm's and the base's, the
/// joint state it publishes and how its commands are checked.
#[derive(Debug, Clone)]
pub struct SimDriverLayout {
    pub nq: usize,
    pub arm_index: Vec<usize>,
    /// (x, y, yaw) of a holonomic base.
    pub base_index: Option<[usize; 3]>,
    /// A part whose newest command is older than this (s) stops.
    pub command_timeout: f64,
    /// An answer later than this after its state (s) counts as late.
    pub period: f64,
    /// Joint names of the published state: the arm's, then held joints (fingers).
    pub names: Vec<String>,
    /// Positions of the held joints, after the arm's.
    pub held: Vec<f64>,
    /// Standard deviations of the noise on positions and velocities.
    pub position_noise: f64,
    pub velocity_noise: f64,
    pub noise_seed: u64,
    /// Reflexes checked on every command received, a diagnostic (false: on the command in effect
    /// every cycle, as the robot checks it).
    pub per_message: bool,
    /// The arm takes trajectory_msgs/JointTrajectory through JTC's topic interface with these
    /// position gains (1/s, one per arm joint; see [`TrajectoryFollower`]); None: velocity commands.
    pub trajectory_gains: Option<Vec<f64>>,
    /// How many of the newest states an answer is matched against.
    pub recent_states: usize,
}

/// The driver's counts (see `SimRobotNode.summary`).
#[derive(Debug, Clone, Default)]
pub struct DriverCounts {
    pub arm_commands: u64,
    pub base_commands: u64,
    pub rejected_commands: u64,
    pub states_published: u64,
    pub echoes: u64,
    pub late_echoes: u64,
    pub unmatched_echoes: u64,
    pub first_answered: Option<u64>,
    pub last_answered: Option<u64>,
}

/// What happened since the last [`SimDriver::take_events`]: commands refused, reflexes tripped.
#[derive(Debug, Default)]
pub struct DriverEvents {
    pub rejected: Vec<String>,
    pub reflexes: Vec<String>,
}

pub struct SimDriver {
    layout: SimDriverLayout,
    reflexes: Option<FrankaReflexes>,
    arm: Vec<f64>,
    arm_received: f64,
    base: [f64; 3],
    base_received: f64,
    last_command: Option<Vec<f64>>,
    last_step: Option<Vec<f64>>,
    /// Per arm joint: the largest |Δv| between consecutive commands, |Δ²v|, and |v|.
    pub step_max: Vec<f64>,
    pub step_change_max: Vec<f64>,
    pub speed_max: Vec<f64>,
    counts: DriverCounts,
    /// Round trips (s) not yet handed out.
    latencies: Vec<f64>,
    /// Stamps' nanoseconds of the recent states → (index, wall time published, s).
    published: HashMap<u32, (u64, f64)>,
    order: VecDeque<u32>,
    /// Per part (arm, base): stopped, and the delays (s) from a part's last command to its stop.
    stopped: [bool; 2],
    stops: Vec<f64>,
    events: DriverEvents,
    u: Vec<f64>,
    position: Vec<f64>,
    velocity: Vec<f64>,
    rng: ChaCha8Rng,
    message: Vec<u8>,
    arm_input: Option<Box<dyn MessageSource>>,
    state_output: Option<Box<dyn MessageSink>>,
    follower: Option<TrajectoryFollower>,
    /// An arm command accepted since the last cycle.
    delivered: bool,
    cycles: CycleRecord,
    arm_q: Vec<f64>,
}

impl SimDriver {
    pub fn new(layout: SimDriverLayout, reflexes: Option<FrankaReflexes>) -> Result<Self> {
        let na = layout.arm_index.len();
        if let Some(i) = layout
            .arm_index
            .iter()
            .chain(layout.base_index.iter().flatten())
            .find(|&&i| i >= layout.nq)
        {
            return Err(SabreError::invalid("arm_index", format!("joint {i} of {}", layout.nq)));
        }
        if layout.names.len() != na + layout.held.len() {
            return Err(SabreError::invalid(
                "names",
                format!(
                    "need {} (the arm's, then the held joints'), got {}",
                    na + layout.held.len(),
                    layout.names.len()
                ),
            ));
        }
        if reflexes.as_ref().is_some_and(|r| r.joints() != na) {
            return Err(SabreError::invalid(
                "reflexes",
                format!("need one limit per arm joint ({na})"),
            ));
        }
        for (name, v) in [
            ("command_timeout", layout.command_timeout),
            ("period", layout.period),
            ("position_noise", layout.position_noise),
            ("velocity_noise", layout.velocity_noise),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SabreError::invalid(name, format!("must be finite and not negative, got {v}")));
            }
        }
        let mut position = vec![0.0; layout.names.len()];
        position[na..].copy_from_slice(&layout.held);
        let follower = match &layout.trajectory_gains {
            Some(gains) => Some(TrajectoryFollower::new(layout.names[..na].to_vec(), gains.clone())?),
            None => None,
        };
        Ok(Self {
            follower,
            delivered: false,
            cycles: CycleRecord::new(layout.period, na),
            arm_q: vec![0.0; na],
            reflexes,
            arm: vec![0.0; na],
            arm_received: f64::NEG_INFINITY,
            base: [0.0; 3],
            base_received: f64::NEG_INFINITY,
            last_command: None,
            last_step: None,
            step_max: vec![0.0; na],
            step_change_max: vec![0.0; na],
            speed_max: vec![0.0; na],
            counts: DriverCounts::default(),
            latencies: Vec::new(),
            published: HashMap::with_capacity(layout.recent_states + 1),
            order: VecDeque::with_capacity(layout.recent_states + 1),
            stopped: [true; 2],
            stops: Vec::new(),
            events: DriverEvents::default(),
            u: vec![0.0; layout.nq],
            velocity: vec![0.0; layout.names.len()],
            position,
            rng: ChaCha8Rng::seed_from_u64(layout.noise_seed),
            message: Vec::with_capacity(512),
            arm_input: None,
            state_output: None,
            layout,
        })
    }

    /// Takes the arm's commands from `input` (see [`Self::take_arm_commands`]) and publishes the
    /// joint states to `output` instead of handing their bytes back.
    pub fn connect(&mut self, input: Option<Box<dyn MessageSource>>, output: Option<Box<dyn MessageSink>>) {
        self.arm_input = input;
        self.state_output = output;
    }

    pub fn counts(&self) -> &DriverCounts {
        &self.counts
    }

    pub fn reflexes(&self) -> Option<&FrankaReflexes> {
        self.reflexes.as_ref()
    }

    /// The arm command in effect (the newest accepted).
    pub fn arm_command(&self) -> &[f64] {
        &self.arm
    }

    pub fn has_events(&self) -> bool {
        !(self.events.rejected.is_empty() && self.events.reflexes.is_empty())
    }

    pub fn take_events(&mut self) -> DriverEvents {
        std::mem::take(&mut self.events)
    }

    pub fn take_latencies(&mut self) -> Vec<f64> {
        std::mem::take(&mut self.latencies)
    }

    pub fn stops(&self) -> &[f64] {
        &self.stops
    }

    /// One serialized arm command (std_msgs/Float64MultiArray, its data_offset naming the state it
    /// answers) received at `now` (s, the clock of the ticks) and `wall` (s since the epoch).
    pub fn receive_arm(&mut self, raw: &[u8], now: f64, wall: f64) {
        if let Some(follower) = self.follower.as_mut() {
            let taken = messages::decode_joint_trajectory(raw).and_then(|m| follower.receive(&m, now, wall));
            match taken {
                Ok(()) => {
                    self.arm_received = now;
                    self.delivered = true;
                    self.counts.arm_commands += 1;
                }
                Err(e) => self.reject(e.to_string()),
            }
            return;
        }
        let (v, answered) = match messages::decode_float64_array(raw) {
            Ok(decoded) => decoded,
            Err(e) => {
                self.reject(e.to_string());
                return;
            }
        };
        if v.len() != self.arm.len() || !v.iter().all(|x| x.is_finite()) {
            self.reject(format!("need {} finite values, got {}", self.arm.len(), v.len()));
            return;
        }
        self.match_answer(answered, wall);
        if let Some(last) = &self.last_command {
            let step: Vec<f64> = v.iter().zip(last).map(|(a, b)| a - b).collect();
            for (m, s) in self.step_max.iter_mut().zip(&step) {
                *m = m.max(s.abs());
            }
            if let Some(previous) = &self.last_step {
                for ((m, s), p) in self.step_change_max.iter_mut().zip(&step).zip(previous) {
                    *m = m.max((s - p).abs());
                }
            }
            self.last_step = Some(step);
        }
        for (m, x) in self.speed_max.iter_mut().zip(&v) {
            *m = m.max(x.abs());
        }
        if self.layout.per_message {
            if let Some(reflexes) = self.reflexes.as_mut().filter(|r| r.aborted().is_none()) {
                if now - self.arm_received > self.layout.command_timeout && v.iter().all(|&x| x == 0.0) {
                    // a stream that starts again from rest after the arm stopped (a new controller);
                    // one that goes on where it was is checked against its own previous command
                    reflexes.recover();
                }
                if let Some(error) = reflexes.check(&v) {
                    self.events.reflexes.push(error.to_string());
                }
            }
        }
        self.arm.copy_from_slice(&v);
        self.last_command = Some(v);
        self.arm_received = now;
        self.delivered = true;
        self.counts.arm_commands += 1;
    }

    fn reject(&mut self, why: String) {
        self.counts.rejected_commands += 1;
        self.events.rejected.push(why);
    }

    /// The base's serialized command (geometry_msgs/Twist, or TwistStamped when `stamped`; vx, vy
    /// and ω in the base frame) received at `now`; false when refused.
    pub fn receive_base(&mut self, raw: &[u8], stamped: bool, now: f64) -> bool {
        let twist = match messages::decode_twist(raw, stamped) {
            Ok(t) => [t.linear[0], t.linear[1], t.angular[2]],
            Err(e) => {
                self.reject(e.to_string());
                return false;
            }
        };
        if !twist.iter().all(|v| v.is_finite()) {
            self.reject("a base command that is not finite".into());
            return false;
        }
        self.base = twist;
        self.base_received = now;
        self.counts.base_commands += 1;
        true
    }

    /// Takes every arm command waiting on the connected subscription, received at `now`; the
    /// middleware's reception time dates their round trips when it gives one.
    pub fn take_arm_commands(&mut self, now: f64, wall: f64) -> Result<usize> {
        let Some(mut input) = self.arm_input.take() else {
            return Ok(0);
        };
        let mut taken = 0;
        let outcome = loop {
            match input.take() {
                Ok(Some((raw, received_ns))) => {
                    let received = if received_ns > 0 { received_ns as f64 * 1e-9 } else { wall };
                    let received = received.min(wall);
                    // a trajectory's stamp maps onto the ticks' clock from both clocks at the
                    // reception, as JTC maps it onto its own, without the wait for this take
                    let at = if self.follower.is_some() {
                        now - (wall - received)
                    } else {
                        now
                    };
                    self.receive_arm(raw, at, received);
                    taken += 1;
                }
                Ok(None) => break Ok(taken),
                Err(e) => break Err(e),
            }
        };
        self.arm_input = Some(input);
        outcome
    }

    /// Books the answer to the state whose stamp has these nanoseconds, received at `wall`.
    pub fn match_answer(&mut self, nanosec: u32, wall: f64) {
        let Some(&(index, sent)) = self.published.get(&nanosec) else {
            self.counts.unmatched_echoes += 1; // a command sent on its own (watchdog, shutdown ramp)
            return;
        };
        let latency = wall - sent;
        let c = &mut self.counts;
        c.first_answered = Some(c.first_answered.map_or(index, |f| f.min(index)));
        c.last_answered = Some(c.last_answered.map_or(index, |l| l.max(index)));
        c.echoes += 1;
        if latency > self.layout.period {
            c.late_echoes += 1;
        }
        self.latencies.push(latency);
    }

    /// The joint velocity reference (nq,) at a tick's scheduled time `tick_time` with the robot at
    /// `q` (nq,) and the base at `yaw`: the arm's velocity command (zero once older than the
    /// timeout, or none came) or JTC's command on the trajectory in force, zero after a reflex; the
    /// base's command turned into world rates (zero once stale). An `excused` tick is one the
    /// robot's own loop ran late (see [`CycleRecord`]).
    pub fn reference(&mut self, tick_time: f64, yaw: f64, q: &[f64], excused: bool) -> Result<&[f64]> {
        if q.len() != self.layout.nq {
            return Err(SabreError::invalid(
                "q",
                format!("need {} joints, got {}", self.layout.nq, q.len()),
            ));
        }
        self.u.iter_mut().for_each(|v| *v = 0.0);
        let arm_fresh = tick_time - self.arm_received <= self.layout.command_timeout;
        let base_fresh = tick_time - self.base_received <= self.layout.command_timeout;
        for (qa, &i) in self.arm_q.iter_mut().zip(&self.layout.arm_index) {
            *qa = q[i];
        }
        // a stale stream's stop is the simulated driver's timeout, not a command the robot was sent
        let unsent = self.follower.is_none() && !arm_fresh;
        let command: &[f64] = match self.follower.as_mut() {
            Some(follower) => follower.command(tick_time, &self.arm_q),
            None if arm_fresh => &self.arm,
            None => {
                self.arm_q.iter_mut().for_each(|v| *v = 0.0);
                &self.arm_q
            }
        };
        let reflexes = self.reflexes.as_mut().filter(|_| !self.layout.per_message);
        let delivered = std::mem::take(&mut self.delivered);
        if let Some(error) = self.cycles.cycle(command, delivered, excused || unsent, reflexes) {
            self.events.reflexes.push(error);
        }
        if self.reflexes.as_ref().is_none_or(|r| r.aborted().is_none()) {
            for (&i, &v) in self.layout.arm_index.iter().zip(command) {
                self.u[i] = v;
            }
        }
        if let Some(follower) = &self.follower {
            // on the trajectory interface the command in effect is JTC's, reported as the last one
            self.arm.copy_from_slice(follower.last_command());
        }
        let arm_fresh = arm_fresh || self.follower.as_ref().is_some_and(TrajectoryFollower::has_trajectory);
        if let (true, Some([x, y, w])) = (base_fresh, self.layout.base_index) {
            let (s, c) = yaw.sin_cos();
            let [vx, vy, wz] = self.base;
            self.u[x] = c * vx - s * vy;
            self.u[y] = s * vx + c * vy;
            self.u[w] = wz;
        }
        for (part, (fresh, received)) in [(arm_fresh, self.arm_received), (base_fresh, self.base_received)]
            .into_iter()
            .enumerate()
        {
            if !fresh && !self.stopped[part] {
                self.stopped[part] = true;
                self.stops.push(if received.is_finite() { tick_time - received } else { 0.0 });
            } else if fresh {
                self.stopped[part] = false;
            }
        }
        Ok(&self.u)
    }

    /// What the robot saw of the arm's command, cycle by cycle (see [`CycleRecord`]).
    pub fn cycles(&self) -> &CycleRecord {
        &self.cycles
    }

    /// The arm's (and held joints') state with noise, stamped `stamp_ns` (ns since the epoch),
    /// serialized; published to the connected publisher (then None) or handed back.
    pub fn publish_state(&mut self, q: &[f64], dq: &[f64], stamp_ns: i64) -> Result<Option<&[u8]>> {
        if q.len() != self.layout.nq || dq.len() != self.layout.nq {
            return Err(SabreError::invalid("q, dq", format!("need {} joints each", self.layout.nq)));
        }
        for (k, &i) in self.layout.arm_index.iter().enumerate() {
            let noise: f64 = StandardNormal.sample(&mut self.rng);
            self.position[k] = q[i] + self.layout.position_noise * noise;
            let noise: f64 = StandardNormal.sample(&mut self.rng);
            self.velocity[k] = dq[i] + self.layout.velocity_noise * noise;
        }
        let stamp = Stamp {
            sec: stamp_ns.div_euclid(1_000_000_000) as i32,
            nanosec: stamp_ns.rem_euclid(1_000_000_000) as u32,
        };
        self.message.clear();
        messages::encode_joint_state(
            &mut self.message,
            stamp,
            "",
            &self.layout.names,
            &self.position,
            &self.velocity,
            &[],
        )?;
        // booked before publishing: an answer can come before this call returns
        let index = self.counts.states_published;
        if self
            .published
            .insert(stamp.nanosec, (index, stamp_ns as f64 * 1e-9))
            .is_none()
        {
            self.order.push_back(stamp.nanosec);
        }
        while self.order.len() > self.layout.recent_states.max(1) {
            if let Some(old) = self.order.pop_front() {
                self.published.remove(&old);
            }
        }
        self.counts.states_published += 1;
        match &self.state_output {
            Some(output) => {
                output.publish(&self.message)?;
                Ok(None)
            }
            None => Ok(Some(&self.message)),
        }
    }
}

#[cfg(test)]
mod tests;
