//! The cascade's trajectory stream against the simulated robot's joint_trajectory_controller (the
//! bridge's own emulation, fed the serialized messages), sampled at 1 kHz as Franka checks it: random
//! plans pushing toward the limits, e-stops, stalls of the controller up to the tolerated gap and
//! deliveries up to the lead late pass every check and keep every joint inside its limits; a stream
//! that ends brings the arm to rest; the tank, booked against the executed velocity, keeps the
//! passivity row.

use std::sync::{Arc, Mutex};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::limit_tests::{random_plan, scene, start, ARM, BASE, DT, FRANKA_ACCELERATION, FRANKA_JERK, FRANKA_VELOCITY};
use super::*;
use crate::bridge::jtc::TrajectoryFollower;
use crate::bridge::messages::{decode_joint_trajectory, Stamp};
use crate::bridge::reflexes::FrankaReflexes;
use crate::bridge::tick::encode_segment;
use crate::control::command_stream::{CommandGate, CommandShaper};
use crate::control::segment::{Segment, SegmentShape};
use crate::control::trajectory_stream::TrajectoryConfig;
use crate::control::{LowLevelConfig, RateLimiter};
use crate::model::{LimitBoundConfig, Scene};
use crate::safety::SafetyConfig;

/// The robot's clock's offset from the ticks' (s): stamps are on the robot's clock.
const WALL: f64 = 1_000.0;

fn names() -> Vec<String> {
    (1..=7).map(|i| format!("panda_joint{i}")).collect()
}

fn config(tolerated_gap: f64, lead: f64, gain: f64) -> TrajectoryConfig {
    let half = |l: &[f64; 7]| l.iter().map(|x| 0.5 * x).collect();
    TrajectoryConfig {
        shape: SegmentShape::new(
            FRANKA_VELOCITY.iter().map(|v| 0.9 * v).collect(),
            half(&FRANKA_ACCELERATION),
            half(&FRANKA_JERK),
            0.002,
            0.01,
        )
        .unwrap(),
        period: 0.01,
        lead,
        tolerated_gap,
        filter_step: 0.01,
        position_gain: vec![gain; 7],
    }
}

/// The cascade on `scene` streaming segments per `trajectory`: Franka's arm stream and a Ridgeback-like
/// base stream, the default low-level controller, the FILTER-QP when `filtered`, and `tank`.
fn streaming(scene: &Arc<Scene>, filtered: bool, tank: Option<EnergyTank>, trajectory: TrajectoryConfig) -> Cascade {
    let arm = RateLimiter::new(
        FRANKA_VELOCITY.to_vec(),
        FRANKA_ACCELERATION.to_vec(),
        FRANKA_JERK.to_vec(),
        DT,
    )
    .unwrap();
    let base = RateLimiter::new(vec![1.0; 3], vec![1.0, 1.0, 2.0], vec![10.0, 10.0, 20.0], 0.02).unwrap();
    let gate = CommandGate::new(CommandShaper::new(arm, Some(base), 20), 0.05).unwrap();
    let low = Arc::new(Mutex::new(
        LowLevelController::new(scene.clone(), DT, LowLevelConfig::default()).unwrap(),
    ));
    let filter = filtered.then(|| Arc::new(Mutex::new(SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap())));
    let tau = ExternalTorque::new(scene.nq(), None, None, None).unwrap();
    let mut cascade = Cascade::new(low, filter, tank.map(|t| Arc::new(Mutex::new(t))), tau).unwrap();
    cascade
        .set_shaping(CommandShaping::new(gate, ARM.to_vec(), Some(BASE), scene.nq()).unwrap())
        .unwrap();
    cascade.set_trajectory(trajectory).unwrap();
    cascade
}

/// A segment published at `from` (ticks' clock) as the robot receives it.
fn message(segment: &Segment, from: f64) -> Vec<u8> {
    let mut out = Vec::new();
    encode_segment(&mut out, segment, Stamp::from_seconds(from + WALL), &names(), false).unwrap();
    out
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Mode {
    Follow,
    Stop,
    /// The controller is not scheduled: no tick, no publication.
    Stall,
}

/// What a run saw: the first reflex, the smallest distance of a joint to its URDF limit, the arm's
/// last velocity command, segments published.
struct Outcome {
    reflex: Option<String>,
    closest: f64,
    last: Vec<f64>,
    published: u64,
    /// The largest acceleration of the command in effect over the segments' bound.
    accel: f64,
}

/// The cascade (with the FILTER-QP when `filtered`) streaming segments to the robot for `seconds`,
/// modes drawn by `modes` (time → None: draw at random), deliveries `delay` late; the arm moves by
/// its JTC's velocity command (position gain `gain`), the base by its stream.
fn drive(
    seed: u64,
    (filtered, gain): (bool, f64),
    seconds: f64,
    lead: f64,
    modes: &dyn Fn(f64) -> Option<Mode>,
    delay: &dyn Fn(&mut ChaCha8Rng) -> f64,
) -> Outcome {
    let scene = scene();
    let nq = scene.nq();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let tank = EnergyTank::new(10.0, 2.0, None, false).unwrap();
    let mut cascade = streaming(&scene, filtered, Some(tank), config(0.1, lead, gain));
    let mut robot = TrajectoryFollower::new(names(), vec![gain; 7]).unwrap();
    let mut reflexes = FrankaReflexes::new(DT, &FRANKA_VELOCITY, &FRANKA_ACCELERATION, &FRANKA_JERK).unwrap();
    let limits = scene.robot_limits();
    let mut x = start(&scene, LimitBoundConfig::default().margin);
    let (mut in_flight, mut base_in_effect) = (Vec::<(f64, Vec<u8>)>::new(), [0.0; 3]);
    let (mut mode, mut until, mut next_plan) = (Mode::Follow, 0.0, 0.0);
    let moving: Vec<usize> = ARM.iter().copied().chain([BASE[2]]).collect();
    let mut outcome = Outcome {
        reflex: None,
        closest: f64::INFINITY,
        last: vec![],
        published: 0,
        accel: 0.0,
    };
    // the robot's cycles fall between the controller's ticks
    let phase = 0.000_37;
    for k in 0..(seconds / DT).round() as usize {
        let t = k as f64 * DT;
        if t >= until {
            mode = modes(t).unwrap_or_else(|| match rng.random::<f64>() {
                r if r < 0.75 => Mode::Follow,
                r if r < 0.85 => Mode::Stop,
                _ => Mode::Stall,
            });
            let longest = if mode == Mode::Stall { 0.1 } else { 0.3 };
            until = t + rng.random_range(0.02..longest);
        }
        if t >= next_plan {
            cascade
                .hand_over(random_plan(&mut rng, &scene, &x, &moving, t, None), None)
                .unwrap();
            next_plan = t + rng.random_range(0.05..0.4);
        }
        let tick = match mode {
            Mode::Follow => Some(cascade.tick_trajectory(&x, t, DT, t).unwrap()),
            Mode::Stop => Some(cascade.stop_trajectory(t, t).unwrap()),
            Mode::Stall => None,
        };
        if let Some(tick) = tick {
            if let Some(segment) = &tick.segment {
                // one publisher's messages on a reliable topic arrive in order
                let after = in_flight.last().map_or(t, |(arrival, _)| *arrival);
                in_flight.push(((t + delay(&mut rng)).max(after), message(segment, t)));
            }
            if tick.command.base_due {
                base_in_effect.copy_from_slice(&tick.command.base);
            }
        }
        // the robot's cycle: deliveries, then its command
        let now = t + phase;
        for (_, raw) in in_flight.iter().filter(|(arrival, _)| *arrival <= now) {
            robot
                .receive(&decode_joint_trajectory(raw).unwrap(), now, now + WALL)
                .unwrap();
        }
        in_flight.retain(|(arrival, _)| *arrival > now);
        let q: Vec<f64> = ARM.iter().map(|&i| x[i]).collect();
        let command = robot.command(now, &q).to_vec();
        if let Some(e) = reflexes.check(&command) {
            outcome.reflex.get_or_insert(format!("t = {t:.3}: {e}"));
        }
        if !outcome.last.is_empty() {
            for j in 0..7 {
                let a = (command[j] - outcome.last[j]) / DT;
                outcome.accel = outcome.accel.max(a.abs() / (0.5 * FRANKA_ACCELERATION[j]));
            }
        }
        for (k, &i) in ARM.iter().enumerate() {
            x[i] += command[k] * DT;
            x[nq + i] = command[k];
        }
        let yaw = x[BASE[2]];
        let b = base_in_effect;
        x[BASE[0]] += (yaw.cos() * b[0] - yaw.sin() * b[1]) * DT;
        x[BASE[1]] += (yaw.sin() * b[0] + yaw.cos() * b[1]) * DT;
        x[BASE[2]] += b[2] * DT;
        for &i in &ARM {
            outcome.closest = outcome.closest.min(x[i] - limits[i].lower).min(limits[i].upper - x[i]);
        }
        outcome.last = command;
    }
    outcome.published = cascade.trajectory().unwrap().counts().published;
    outcome
}

#[test]
fn random_plans_e_stops_and_stalls_up_to_the_tolerated_gap_pass_frankas_checks_inside_the_limits() {
    // feedforward (JTC's gains zero) and with a position gain, whose feedback the segments take off
    for (seed, filtered, gain) in [(1, true, 0.0), (2, false, 10.0), (3, true, 10.0)] {
        let lead = 0.03;
        let out = drive(seed, (filtered, gain), 6.0, lead, &|_| None, &|rng| {
            rng.random_range(0.0..lead)
        });
        assert!(out.reflex.is_none(), "seed {seed}: {:?}", out.reflex);
        assert!(out.closest > 0.0, "seed {seed}: a joint {} past its limit", -out.closest);
        assert!(out.published > 100, "seed {seed}: {} segments", out.published);
        if gain == 0.0 {
            // the command in effect is the segments' velocity: their own acceleration bound holds at
            // every cycle, splices and stops included
            assert!(out.accel <= 1.0 + 1e-9, "seed {seed}: {} of the bound", out.accel);
        }
    }
}

#[test]
fn a_stream_that_ends_brings_the_arm_to_rest_within_the_checks() {
    let follow_then_stall = |t: f64| Some(if t < 1.5 { Mode::Follow } else { Mode::Stall });
    let out = drive(4, (true, 10.0), 3.0, 0.03, &follow_then_stall, &|_| 0.002);
    assert!(out.reflex.is_none(), "{:?}", out.reflex);
    assert!(out.last.iter().all(|v| v.abs() < 1e-6), "at rest: {:?}", out.last);
}

/// The tank is booked against the velocity the robot executes; the filter picks only commands the
/// streams reach within a filter step, so the passivity row (56) it met is the one the tank sees. The
/// world pushes the base along y (energy the filter could take in by letting the base yield, faster
/// than its stream accelerates) while every arm joint is held against a plan that drives it.
#[test]
fn the_tank_booked_against_the_executed_velocity_stays_above_its_floor() {
    let scene = scene();
    let nq = scene.nq();
    let (floor, initial) = (2.0, 6.0);
    let tank = EnergyTank::new(initial, floor, None, false).unwrap();
    let mut cascade = streaming(&scene, true, Some(tank), config(0.1, 0.03, 0.0));
    let mut robot = TrajectoryFollower::new(names(), vec![0.0; 7]).unwrap();
    let mut x = scene.default_state();
    x[..nq].copy_from_slice(&scene.start_configuration());
    // each arm joint driven at 0.2 rad/s toward the middle of its range, and held back by 10 N m
    let limits = scene.robot_limits();
    let (mut reference, mut resisting) = (vec![0.0; nq], vec![0.0; nq]);
    for &i in &ARM {
        let inward = if x[i] < 0.5 * (limits[i].lower + limits[i].upper) {
            1.0
        } else {
            -1.0
        };
        reference[i] = 0.2 * inward;
        resisting[i] = -10.0 * inward;
    }
    resisting[BASE[1]] = 200.0;
    let plan = Arc::new(Plan::new(reference.repeat(40), nq, 0.0, 0.05).unwrap());
    cascade.hand_over(plan, None).unwrap();
    let (mut base_in_effect, mut lowest, mut excess) = ([0.0; 3], initial, f64::NEG_INFINITY);
    let mut in_flight = Vec::<(f64, Vec<u8>)>::new();
    for k in 0..3000 {
        let t = k as f64 * DT;
        cascade.tau_ext_mut().set_torque(&resisting, f64::INFINITY, t).unwrap();
        let tick = cascade.tick_trajectory(&x, t, DT, t).unwrap();
        if let Some(segment) = &tick.segment {
            in_flight.push((t + 0.01, message(segment, t)));
        }
        if tick.command.base_due {
            base_in_effect.copy_from_slice(&tick.command.base);
        }
        let energy = cascade.output().tank_energy.unwrap();
        lowest = lowest.min(energy);
        // the executed velocity's power against the row's bound −α (S − ε), α = 1/s
        let power: f64 = (0..nq).map(|i| resisting[i] * x[nq + i]).sum();
        excess = excess.max(-(energy - floor) - power);
        for (_, raw) in in_flight.iter().filter(|(arrival, _)| *arrival <= t) {
            robot.receive(&decode_joint_trajectory(raw).unwrap(), t, t + WALL).unwrap();
        }
        in_flight.retain(|(arrival, _)| *arrival > t);
        let q: Vec<f64> = ARM.iter().map(|&i| x[i]).collect();
        let command = robot.command(t, &q).to_vec();
        for (j, &i) in ARM.iter().enumerate() {
            x[i] += command[j] * DT;
            x[nq + i] = command[j];
        }
        let yaw = x[BASE[2]];
        let b = base_in_effect;
        x[BASE[0]] += (yaw.cos() * b[0] - yaw.sin() * b[1]) * DT;
        x[BASE[1]] += (yaw.sin() * b[0] + yaw.cos() * b[1]) * DT;
        x[BASE[2]] += b[2] * DT;
        x[nq + BASE[0]] = yaw.cos() * b[0] - yaw.sin() * b[1];
        x[nq + BASE[1]] = yaw.sin() * b[0] + yaw.cos() * b[1];
        x[nq + BASE[2]] = b[2];
    }
    // the plan spends the tank (the test is not idle), never below its floor, and the power the robot
    // executes keeps the row's bound but for the segments' lag behind a filtered step
    assert!(
        excess < 0.5,
        "the executed power exceeded the passivity row's bound by {excess} W"
    );
    assert!(
        lowest > floor - 0.02,
        "the tank fell to {lowest} J, below its floor {floor} J"
    );
    assert!(lowest < initial - 1.0, "the tank only fell to {lowest} J");
}

/// The lag (s) at which `executed` best matches `planned` shifted later, searched over ±0.1 s at the
/// samples' step `dt` (least squares over the samples both cover).
fn best_lag(planned: &[f64], executed: &[f64], dt: f64) -> f64 {
    let span = (0.1 / dt).round() as i64;
    let n = planned.len() as i64;
    let misfit = |lag: i64| -> f64 {
        let pairs = (span..n - span).map(|k| (executed[k as usize] - planned[(k - lag) as usize]).powi(2));
        pairs.sum::<f64>()
    };
    let best = (-span..=span).min_by(|&a, &b| misfit(a).total_cmp(&misfit(b))).unwrap();
    best as f64 * dt
}

/// The base and the arm execute the plan on one time axis: a filtered step is executed by the base
/// when the arm executes the segment's knots for the same time, not a segment's lead earlier (the
/// base's stream has no lead). A slow sinusoid in the plan for the base's x rate and for every arm
/// joint; the lag of each executed velocity behind the plan, from their best least-squares match.
#[test]
fn the_base_and_the_arm_execute_the_plan_at_the_same_time() {
    let scene = scene();
    let nq = scene.nq();
    let lead = 0.05;
    let mut cascade = streaming(&scene, false, None, config(0.1, lead, 0.0));
    let mut robot = TrajectoryFollower::new(names(), vec![0.0; 7]).unwrap();
    let mut x = scene.default_state();
    x[..nq].copy_from_slice(&scene.start_configuration());
    x[BASE[2]] = 0.0;
    let (step, seconds) = (0.01, 4.0);
    let wave = |t: f64| 0.08 * (std::f64::consts::TAU * 0.5 * t).sin();
    let rows: Vec<f64> = (0..=(seconds / step) as usize + 10)
        .flat_map(|k| {
            let mut row = vec![0.0; nq];
            row[BASE[0]] = wave(k as f64 * step);
            for &i in &ARM {
                row[i] = 0.5 * wave(k as f64 * step);
            }
            row
        })
        .collect();
    cascade
        .hand_over(Arc::new(Plan::new(rows, nq, 0.0, step).unwrap()), None)
        .unwrap();
    let (mut base_in_effect, mut in_flight) = ([0.0; 3], Vec::<(f64, Vec<u8>)>::new());
    let (mut planned, mut base_executed, mut arm_executed) = (vec![], vec![], vec![]);
    for k in 0..(seconds / DT) as usize {
        let t = k as f64 * DT;
        let tick = cascade.tick_trajectory(&x, t, DT, t).unwrap();
        if let Some(segment) = &tick.segment {
            in_flight.push((t, message(segment, t)));
        }
        if tick.command.base_due {
            base_in_effect.copy_from_slice(&tick.command.base);
        }
        for (_, raw) in in_flight.iter().filter(|(arrival, _)| *arrival <= t) {
            robot.receive(&decode_joint_trajectory(raw).unwrap(), t, t + WALL).unwrap();
        }
        in_flight.clear();
        let q: Vec<f64> = ARM.iter().map(|&i| x[i]).collect();
        let command = robot.command(t, &q).to_vec();
        for (j, &i) in ARM.iter().enumerate() {
            x[i] += command[j] * DT;
        }
        // the base turns not (yaw 0, no yaw rate in the plan): its frame's x rate is the world's
        x[BASE[0]] += base_in_effect[0] * DT;
        planned.push(wave(t));
        base_executed.push(base_in_effect[0]);
        arm_executed.push(2.0 * command[0]);
    }
    let (base_lag, arm_lag) = (best_lag(&planned, &base_executed, DT), best_lag(&planned, &arm_executed, DT));
    assert!(
        base_lag >= 0.0 && arm_lag >= 0.0,
        "executed before its time: base {base_lag} s, arm {arm_lag} s"
    );
    assert!(
        (base_lag - arm_lag).abs() <= 0.4 * lead,
        "the base executes the plan {base_lag} s after its time, the arm {arm_lag} s (lead {lead} s)"
    );
}
