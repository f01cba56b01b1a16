//! Trajectory segments spliced every publication into the simulated robot's joint_trajectory
//! controller, sampled at 1 kHz off the knots: the command the arm sees stays within Franka's
//! velocity, acceleration and jerk checks when deliveries take up to the splice's lead and when
//! publications stop for up to the follow horizon; past the horizon the arm comes to rest.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::bridge::jtc::TrajectoryFollower;
use sabre::bridge::messages::{Stamp, TrajectoryPoint, TrajectoryValue};
use sabre::bridge::reflexes::FrankaReflexes;
use sabre::control::segment::{KnotState, Segment, SegmentShape};

const VELOCITY: [f64; 7] = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
const ACCELERATION: [f64; 7] = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0];
const JERK: [f64; 7] = [7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0];
/// The wall clock's offset from the ticks' clock (s).
const WALL: f64 = 1_000.0;
const PERIOD: f64 = 0.01;
const LEAD: f64 = 0.004;
const KNOT: f64 = 0.002;
const FOLLOW: usize = 60; // knots: 120 ms

fn names() -> Vec<String> {
    (1..=7).map(|i| format!("panda_joint{i}")).collect()
}

fn shape() -> SegmentShape {
    let scaled = |l: &[f64; 7], s: f64| l.iter().map(|x| x * s).collect();
    SegmentShape::new(
        VELOCITY.to_vec(),
        scaled(&ACCELERATION, 0.2),
        scaled(&JERK, 0.5),
        KNOT,
        5.0 * KNOT,
    )
    .unwrap()
}

fn message(seg: &Segment, splice: f64) -> TrajectoryValue {
    TrajectoryValue {
        stamp: Stamp::from_seconds(splice + WALL),
        joint_names: names(),
        points: seg
            .times
            .iter()
            .zip(&seg.states)
            .map(|(&t, s)| TrajectoryPoint {
                time_from_start: t,
                positions: s.q.clone(),
                velocities: s.v.clone(),
                accelerations: Vec::new(),
            })
            .collect(),
    }
}

/// Runs `seconds` of publications every PERIOD (none while `stalled(t)`), each delivered after a
/// delay `delay(rng)`, against the robot at 1 kHz; the reflex tripped, if any, and the last command.
fn run(seconds: f64, stalled: impl Fn(f64) -> bool, delay: impl Fn(&mut ChaCha8Rng) -> f64) -> (Option<String>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let shape = shape();
    let mut robot = TrajectoryFollower::new(names(), vec![0.0; 7]).unwrap();
    let mut reflexes = FrankaReflexes::new(0.001, &VELOCITY, &ACCELERATION, &JERK).unwrap();
    // what the controller sent last, from when (its belief of what the robot follows)
    let mut sent: Option<(f64, Segment)> = None;
    let mut in_flight: Vec<(f64, TrajectoryValue)> = Vec::new();
    let mut target = vec![0.0; 7];
    let q0 = vec![0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.8];
    let mut q = q0.clone();
    let mut command = vec![0.0; 7];
    let phase = 0.000_37; // the robot's cycles fall between the knots
    let steps = (seconds / 0.001) as usize;
    for k in 0..steps {
        let t = k as f64 * 0.001 + phase;
        let publication = (t / PERIOD).floor() * PERIOD;
        if (publication - (t - 0.001)).abs() < 1e-12 || (t - 0.001 < publication && publication <= t) {
            if (publication / 0.1).fract() < 1e-9 {
                target = (0..7).map(|j| rng.random_range(-1.0..1.0) * VELOCITY[j]).collect();
            }
            if !stalled(publication) {
                // the splice on the grid of the segment in force, `LEAD` after the publication
                let (start, splice) = match &sent {
                    Some((from, seg)) => {
                        let splice = from + ((publication + LEAD - from) / KNOT).ceil() * KNOT;
                        (seg.sample(splice - from), splice)
                    }
                    None => (KnotState::rest(&q0), publication + LEAD),
                };
                let seg = Segment::build(&shape, &start, &vec![target.clone(); FOLLOW]).unwrap();
                in_flight.push((publication + delay(&mut rng), message(&seg, splice)));
                sent = Some((splice, seg));
            }
        }
        in_flight.retain(|(arrival, m)| {
            if *arrival <= t {
                robot.receive(m, t, t + WALL).unwrap();
            }
            *arrival > t
        });
        command = robot.command(t, &q).to_vec();
        for (qj, vj) in q.iter_mut().zip(&command) {
            *qj += vj * 0.001;
        }
        if let Some(e) = reflexes.check(&command) {
            return (Some(format!("t = {t:.4}: {e}")), command);
        }
    }
    (None, command)
}

#[test]
fn deliveries_within_the_lead_splice_within_frankas_checks() {
    let (tripped, _) = run(6.0, |_| false, |rng| rng.random_range(0.0..LEAD));
    assert!(tripped.is_none(), "{tripped:?}");
}

#[test]
fn publications_that_stop_for_up_to_the_follow_horizon_are_ridden_out() {
    // the controller is not scheduled for 40–100 ms, several times
    let stalls = [(0.5, 0.04), (1.2, 0.1), (2.05, 0.07), (3.3, 0.1)];
    let stalled = |t: f64| stalls.iter().any(|&(at, length)| t >= at && t < at + length);
    let (tripped, _) = run(4.0, stalled, |rng| rng.random_range(0.0..LEAD));
    assert!(tripped.is_none(), "{tripped:?}");
}

#[test]
fn when_publications_end_the_arm_stops_at_rest_within_the_checks() {
    let (tripped, last) = run(8.0, |t| t >= 1.0, |_| 0.001);
    assert!(tripped.is_none(), "{tripped:?}");
    assert!(last.iter().all(|v| v.abs() < 1e-9), "at rest: {last:?}");
}
