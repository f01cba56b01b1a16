//! The joint-limit bound in the cascade: a limiter's stop from the bound ends within its distance, and
//! random plans (pushing out hard), e-stops and stale states never carry a joint past its limit, on the
//! kinematics and on the Rust plant.

use std::sync::{Arc, Mutex};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::control::command_stream::{Command, CommandGate, CommandShaper};
use crate::control::{LowLevelConfig, RateLimiter};
use crate::model::limit_bound::{stopping_distance, velocity_bound, Braking};
use crate::model::scene::Scene;
use crate::model::LimitBoundConfig;
use crate::safety::SafetyConfig;
use crate::sim::{Plant, PlantConfig};

pub(super) const DT: f64 = 0.001;
/// Franka's published joint limits.
pub(super) const FRANKA_VELOCITY: [f64; 7] = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
pub(super) const FRANKA_ACCELERATION: [f64; 7] = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0];
pub(super) const FRANKA_JERK: [f64; 7] = [7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0];
/// The robot's joints: base x, y, yaw, then the arm's seven.
pub(super) const ARM: [usize; 7] = [3, 4, 5, 6, 7, 8, 9];
pub(super) const BASE: [usize; 3] = [0, 1, 2];

/// The bridge's default arm limits: Franka's, kept robust to two missed commands at 1 kHz
/// (`sabre.ros.params.robust_arm_limits`).
fn robust_arm() -> (Vec<f64>, Vec<f64>) {
    let a = (0..7)
        .map(|i| FRANKA_ACCELERATION[i].min(0.9 * FRANKA_JERK[i] * DT / 3.0))
        .collect();
    let j = FRANKA_JERK.iter().map(|j| 0.9 * j).collect();
    (a, j)
}

/// The low-level gains of the simulated robot behind the bridge (its `gain_inertia_floor` parameter):
/// without a floor, the last wrist joint (M_ii ≈ 0.007 kg m²) barely resists its neighbours'
/// motion, which then carries it onto its limit whatever its own command.
fn held_wrist() -> LowLevelConfig {
    LowLevelConfig {
        gain_inertia_floor: 0.03,
        ..LowLevelConfig::default()
    }
}

pub(super) fn scene() -> Arc<Scene> {
    Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene loads"))
}

#[test]
fn a_limiter_stop_from_the_bound_ends_within_its_distance_and_within_two_steps_of_it() {
    let (robust_a, robust_j) = robust_arm();
    let base = (vec![1.0, 2.0], vec![10.0, 20.0]);
    for (a, j, dt) in [
        (FRANKA_ACCELERATION.to_vec(), FRANKA_JERK.to_vec(), DT),
        (robust_a, robust_j, DT),
        (base.0, base.1, 0.02),
    ] {
        for i in 0..a.len() {
            let b = Braking {
                deceleration: a[i],
                jerk: j[i],
                delay: dt,
            };
            for fraction in [0.05, 0.2, 0.5, 0.9] {
                let v_max = FRANKA_VELOCITY[i.min(6)];
                // accelerating outward at the limiter's full bound when the stop begins
                let mut limiter = RateLimiter::new(vec![v_max], vec![a[i]], vec![j[i]], dt).unwrap();
                let mut out = [0.0];
                while limiter.velocity()[0] < fraction * v_max {
                    limiter.limit(&[v_max], &mut out).unwrap();
                }
                let (v, accelerating) = (limiter.velocity()[0], limiter.acceleration()[0]);
                // the distance whose bound v is; the command in flight runs one period, then the ramp
                let d = stopping_distance(v, &b);
                assert!((velocity_bound(d, &b) - v).abs() <= 1e-9 * v);
                let mut travel = v * dt;
                while !limiter.at_rest() {
                    limiter.limit(&[0.0], &mut out).unwrap();
                    travel += out[0] * dt;
                }
                let what = format!("a {}, j {}: from {v} at {accelerating}", a[i], j[i]);
                assert!(travel <= d, "{what}: the stop covers {travel} > {d}");
                if accelerating == a[i] {
                    // tight: short of d by at most two steps' travel at the stop's top speed (the
                    // discrete steps turn the acceleration from the first, a step before the continuous stop)
                    let top = v + a[i] * a[i] / (2.0 * j[i]);
                    assert!(d - travel <= 2.0 * top * dt, "{what}: {travel} of {d}");
                }
                // from zero acceleration the same stop is shorter
                limiter.reset(Some(&[v])).unwrap();
                let mut steady = v * dt;
                while !limiter.at_rest() {
                    limiter.limit(&[0.0], &mut out).unwrap();
                    steady += out[0] * dt;
                }
                assert!(
                    steady <= travel,
                    "{what}: {steady} from rest acceleration, {travel} accelerating"
                );
            }
        }
    }
}

/// A plan of six steps of 50 ms from `t0`: each joint of `joints` toward a target at random within
/// ±1.5 × its velocity limit, half of them pushing toward the nearer limit of `q`, the others zero.
/// With `from` (the reference at t0) the plan is one the Rust plant can follow: it starts there, its
/// targets are within the velocity limits and it moves toward them at half Franka's acceleration
/// limits (a plan that swings several joints at once harder than that saturates the Panda's efforts
/// in the simulated dynamics, and the joints it throws about go where no bound on their commands can
/// keep them); one in seven ramps every joint to rest. Without `from` it jumps to its targets.
pub(super) fn random_plan(
    rng: &mut ChaCha8Rng,
    scene: &Scene,
    q: &[f64],
    joints: &[usize],
    t0: f64,
    from: Option<&[f64]>,
) -> Arc<Plan> {
    let (nq, rows, dt) = (scene.nq(), 6, 0.05);
    let limits = scene.robot_limits();
    let mut reference = vec![0.0; rows * nq];
    let rest = from.is_some() && rng.random_bool(1.0 / 7.0);
    for &i in joints {
        let l = limits[i];
        let outward = if l.upper - q[i] < q[i] - l.lower { 1.0 } else { -1.0 };
        let speed = rng.random_range(0.0..if from.is_some() { 1.0 } else { 1.5 }) * l.velocity;
        let target = if rest {
            0.0
        } else if rng.random_bool(0.5) {
            outward * speed
        } else {
            rng.random_range(-1.0..1.0) * speed
        };
        let mut value = from.map_or(target, |start| start[i]);
        let slope = ARM.iter().position(|&a| a == i).map_or(1.0, |k| 0.5 * FRANKA_ACCELERATION[k]);
        for k in 0..rows {
            if from.is_some() && k > 0 {
                value += (target - value).clamp(-slope * dt, slope * dt);
            }
            reference[k * nq + i] = value;
        }
    }
    Arc::new(Plan::new(reference, nq, t0, dt).unwrap())
}

/// A start near the limits: the scene's start posture with panda_joint6 2 mrad inside the margin
/// toward its upper limit (where the scripted pull leaves it) and panda_joint4 near its lower one.
pub(super) fn start(scene: &Scene, margin: f64) -> Vec<f64> {
    let limits = scene.robot_limits();
    let mut x = scene.default_state();
    let q = scene.start_configuration();
    x[..scene.nq()].copy_from_slice(&q);
    x[8] = limits[8].upper - margin - 0.002;
    x[6] = limits[6].lower + 0.1;
    x
}

/// What the cascade's command does next, as a 1 kHz robot: e-stop ticks, stale states (no ticks, the
/// gate's watchdog ramps) or ticks following the plans.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Mode {
    Follow,
    Stop,
    Stale,
}

/// The shaped cascade's commands as joint velocities (nq) in effect on the robot: the arm's every
/// step, the base's twist (in its frame at `yaw`) when due, each held until the next.
fn apply(command: &Command, yaw: f64, in_effect: &mut [f64]) {
    for (k, &i) in ARM.iter().enumerate() {
        in_effect[i] = command.arm[k];
    }
    if command.base_due {
        let (c, s) = (yaw.cos(), yaw.sin());
        let b = &command.base;
        in_effect[BASE[0]] = c * b[0] - s * b[1];
        in_effect[BASE[1]] = s * b[0] + c * b[1];
        in_effect[BASE[2]] = b[2];
    }
}

/// A robot the shaped cascade drives for `seconds`: the kinematics (`plant` None: q advances by the
/// command in effect, which is the one sent a period before) or the Rust plant tracking the command in
/// effect with the low-level controller, as the simulated robot does. Calls `check` with every state.
fn drive_shaped(seed: u64, filtered: bool, mut plant: Option<&mut Plant>, seconds: f64, check: &mut dyn FnMut(&[f64])) {
    let scene = scene();
    let (nq, margin) = (scene.nq(), LimitBoundConfig::default().margin);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (a, j) = robust_arm();
    let arm = RateLimiter::new(FRANKA_VELOCITY.to_vec(), a, j, DT).unwrap();
    let base = RateLimiter::new(vec![1.0; 3], vec![1.0, 1.0, 2.0], vec![10.0, 10.0, 20.0], 0.02).unwrap();
    let gate = CommandGate::new(CommandShaper::new(arm, Some(base), 20), 0.05).unwrap();
    let low = Arc::new(Mutex::new(
        LowLevelController::new(scene.clone(), DT, LowLevelConfig::default()).unwrap(),
    ));
    let filter = filtered.then(|| Arc::new(Mutex::new(SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap())));
    let tau = ExternalTorque::new(nq, None, None, None).unwrap();
    let mut cascade = Cascade::new(low, filter, None, tau).unwrap();
    cascade
        .set_shaping(CommandShaping::new(gate, ARM.to_vec(), Some(BASE), nq).unwrap())
        .unwrap();
    let mut x = start(&scene, margin);
    if let Some(p) = plant.as_deref_mut() {
        p.reset(&x).unwrap();
    }
    let mut tracker = LowLevelController::new(scene.clone(), DT, held_wrist()).unwrap();
    let (mut sent, mut in_effect) = (vec![0.0; nq], vec![0.0; nq]);
    let (mut mode, mut until, mut next_plan) = (Mode::Follow, 0.0, 0.0);
    let mut steps = Vec::new();
    // the base's x and y stay: their streams turn with the base (see docs/design.md)
    let moving: Vec<usize> = ARM.iter().copied().chain([BASE[2]]).collect();
    for k in 0..(seconds / DT).round() as usize {
        let t = k as f64 * DT;
        if t >= until {
            let r: f64 = rng.random();
            mode = if r < 0.7 {
                Mode::Follow
            } else if r < 0.85 {
                Mode::Stop
            } else {
                Mode::Stale
            };
            until = t + rng.random_range(0.02..0.3);
        }
        if t >= next_plan {
            cascade
                .hand_over(random_plan(&mut rng, &scene, &x, &moving, t, None), None)
                .unwrap();
            next_plan = t + rng.random_range(0.05..0.4);
        }
        let yaw = x[BASE[2]];
        match mode {
            Mode::Follow => apply(cascade.tick_shaped(&x, t, DT, t).unwrap(), yaw, &mut sent),
            Mode::Stop => apply(cascade.shaping_mut().unwrap().stop(t).unwrap(), yaw, &mut sent),
            Mode::Stale => {
                cascade.shaping_mut().unwrap().gate_mut().watchdog(t, 10, &mut steps);
                for command in &steps {
                    apply(command, yaw, &mut sent);
                }
            }
        }
        // this step runs the command sent a period ago; the one just sent runs from the next
        match plant.as_deref_mut() {
            None => {
                for (q, v) in x[..nq].iter_mut().zip(&in_effect) {
                    *q += v * DT;
                }
                x[nq..2 * nq].copy_from_slice(&in_effect);
            }
            Some(p) => {
                let tau = tracker.torque(p.state(), &in_effect).unwrap();
                p.step(&tau).unwrap();
                x.copy_from_slice(p.state());
            }
        }
        in_effect.copy_from_slice(&sent);
        check(&x);
    }
}

#[test]
fn shaped_commands_with_e_stops_and_stale_states_stop_every_joint_inside_its_margin() {
    let scene = scene();
    let limits = scene.robot_limits();
    let config = LimitBoundConfig::default();
    for (seed, filtered) in [(1, false), (2, false), (3, true)] {
        let mut closest = f64::INFINITY;
        drive_shaped(seed, filtered, None, 20.0, &mut |x| {
            for &i in ARM.iter().chain([&BASE[2]]) {
                let inside = (limits[i].upper - config.margin - x[i]).min(x[i] - limits[i].lower - config.margin);
                // the start lies 2 mrad inside the margin: that joint may not go further out
                let allowed = if i == 8 { -0.002 } else { 0.0 };
                // the kinematics are exact: only rounding may show
                assert!(
                    inside >= allowed - 1e-9,
                    "seed {seed}: joint {i} at {} is {} past its margin",
                    x[i],
                    -inside
                );
                closest = closest.min(inside - allowed);
            }
        });
        // the plans pushed the joints to their margins
        assert!(closest < 0.005, "seed {seed}: no joint came near its margin ({closest})");
    }
}

/// Asserts that no robot joint of `x` has reached its URDF limit; returns the smallest distance to one.
/// No tolerance: the plant's own limit holds a joint pressed against it a fraction of a milliradian
/// past it, so a joint that got there shows, and one the bound kept off it stays well inside.
pub(super) fn within_limits(scene: &Scene, x: &[f64], what: &str) -> f64 {
    let mut closest = f64::INFINITY;
    for (i, l) in scene.robot_limits().iter().enumerate() {
        let inside = (l.upper - x[i]).min(x[i] - l.lower);
        assert!(
            inside > 0.0,
            "{what}: joint {i} at {} reached its limit ({} past it)",
            x[i],
            -inside
        );
        closest = closest.min(inside);
    }
    closest
}

#[test]
fn shaped_commands_on_the_plant_never_carry_a_joint_past_its_limit() {
    let scene = scene();
    let mut plant = Plant::new(scene.clone(), PlantConfig::default()).unwrap();
    let mut closest = f64::INFINITY;
    drive_shaped(4, false, Some(&mut plant), 8.0, &mut |x| {
        closest = closest.min(within_limits(&scene, x, "shaped, plant"));
    });
    assert!(closest < 0.03, "no joint came near its limit ({closest})");
}

#[test]
fn random_plans_on_the_plant_never_carry_a_joint_past_its_limit() {
    let scene = scene();
    let nq = scene.nq();
    let margin = LimitBoundConfig::default().margin;
    for (seed, filtered) in [(5, false), (6, true)] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut plant = Plant::new(scene.clone(), PlantConfig::default()).unwrap();
        plant.reset(&start(&scene, margin)).unwrap();
        let low = Arc::new(Mutex::new(LowLevelController::new(scene.clone(), DT, held_wrist()).unwrap()));
        let filter = filtered.then(|| Arc::new(Mutex::new(SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap())));
        let tank = filtered.then(|| Arc::new(Mutex::new(EnergyTank::new(10.0, 2.0, None, false).unwrap())));
        let tau = ExternalTorque::new(nq, None, None, None).unwrap();
        let mut cascade = Cascade::new(low, filter, tank, tau).unwrap();
        let mut closest = f64::INFINITY;
        let mut trace = TrackTrace::default();
        for _ in 0..40 {
            let (t, x) = (plant.time(), plant.state().to_vec());
            // the next plan starts where the one in force is at t
            let mut now = vec![0.0; nq];
            if let Some(plan) = cascade.plan_at(t) {
                plan.reference_at(t, &mut now);
            }
            let plan = random_plan(&mut rng, &scene, &x, &ARM, t, Some(&now));
            cascade.hand_over(plan, None).unwrap();
            trace = TrackTrace::default();
            cascade.follow(&mut plant, rng.random_range(50..300), 1, &mut trace).unwrap();
            for x in trace.state.chunks_exact(scene.nx()) {
                closest = closest.min(within_limits(&scene, x, &format!("seed {seed}")));
            }
        }
        assert!(!trace.time.is_empty());
        assert!(closest < 0.03, "seed {seed}: no joint came near its limit ({closest})");
        assert!(cascade.limit_holds() > 0, "seed {seed}: the bound never held a command");
    }
}
