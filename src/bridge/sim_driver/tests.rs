//! The simulated robot's driver side: commands, answers, states, reflexes, middleware endpoints.

use super::*;

fn layout(per_message: bool) -> SimDriverLayout {
    SimDriverLayout {
        nq: 5,
        arm_index: vec![3, 4],
        base_index: Some([0, 1, 2]),
        command_timeout: 0.05,
        period: 0.001,
        names: vec!["j1".into(), "j2".into(), "finger".into()],
        held: vec![0.04],
        position_noise: 0.0,
        velocity_noise: 0.0,
        noise_seed: 0,
        per_message,
        recent_states: 4,
        trajectory_gains: None,
    }
}

fn command(v: &[f64], answers: u32) -> Vec<u8> {
    let mut out = Vec::new();
    messages::encode_float64_array(&mut out, v, answers).unwrap();
    out
}

#[test]
fn a_command_answers_its_state_and_is_the_reference_until_it_is_stale() {
    let mut d = SimDriver::new(layout(true), None).unwrap();
    let raw = d
        .publish_state(&[0.0, 0.0, 0.0, 0.1, 0.2], &[0.0, 0.0, 0.0, 0.3, 0.4], 5_000_000_123)
        .unwrap()
        .unwrap()
        .to_vec();
    let state = messages::decode_joint_state(&raw).unwrap();
    assert_eq!(state.position, vec![0.1, 0.2, 0.04]);
    assert_eq!(state.velocity, vec![0.3, 0.4, 0.0]);
    d.receive_arm(&command(&[0.5, -0.5], 123), 10.0, 5.0004);
    let c = d.counts();
    assert_eq!((c.echoes, c.first_answered, c.late_echoes), (1, Some(0), 0));
    let latency = d.take_latencies();
    assert!((latency[0] - (5.0004 - 5.000_000_123)).abs() < 1e-12, "{latency:?}");
    assert_eq!(
        d.reference(10.01, 0.0, &[0.0; 5], false).unwrap(),
        &[0.0, 0.0, 0.0, 0.5, -0.5]
    );
    assert_eq!(
        d.reference(10.06, 0.0, &[0.0; 5], false).unwrap(),
        &[0.0; 5],
        "older than the timeout: stopped"
    );
    assert_eq!(d.stops().len(), 1);
    assert!((d.stops()[0] - 0.06).abs() < 1e-12);
    // an answer 2 ms after its state: two periods, late (though well within the command timeout)
    d.publish_state(&[0.0; 5], &[0.0; 5], 6_000_000_007).unwrap();
    d.receive_arm(&command(&[0.5, -0.5], 7), 11.0, 6.002);
    assert_eq!((d.counts().echoes, d.counts().late_echoes), (2, 1));
}

/// A subscription's queue: each message with the middleware's reception time (ns), then a failure.
struct Queue(VecDeque<(Vec<u8>, i64)>, Option<(Vec<u8>, i64)>, bool);

impl MessageSource for Queue {
    fn take(&mut self) -> Result<Option<(&[u8], i64)>> {
        if self.0.is_empty() && self.2 {
            return Err(SabreError::Simulation("the middleware failed".into()));
        }
        self.1 = self.0.pop_front();
        Ok(self.1.as_ref().map(|(b, t)| (b.as_slice(), *t)))
    }
}

#[test]
fn every_waiting_command_is_taken_in_order_and_dated_by_the_middleware() {
    let mut d = SimDriver::new(layout(false), None).unwrap();
    d.publish_state(&[0.0; 5], &[0.0; 5], 7_000_000_050).unwrap();
    let queue = [(command(&[0.1, 0.1], 0), 0), (command(&[0.3, 0.2], 50), 7_000_300_000)];
    d.connect(Some(Box::new(Queue(queue.into(), None, false))), None);
    assert_eq!(d.take_arm_commands(9.0, 7.5).unwrap(), 2);
    assert_eq!(d.take_arm_commands(9.0, 7.5).unwrap(), 0, "nothing is taken twice");
    assert_eq!(d.counts().arm_commands, 2);
    assert!(
        (d.step_max[0] - 0.2).abs() < 1e-12 && (d.step_max[1] - 0.1).abs() < 1e-12,
        "in order: {:?}",
        d.step_max
    );
    assert_eq!(d.reference(9.0, 0.0, &[0.0; 5], false).unwrap(), &[0.0, 0.0, 0.0, 0.3, 0.2]);
    // the answer's round trip ends at the middleware's reception, not at the later take (7.5 s)
    let latency = d.take_latencies();
    assert!((latency[0] - (7.0003 - 7.000_000_050)).abs() < 1e-9, "{latency:?}");

    d.connect(Some(Box::new(Queue(VecDeque::new(), None, true))), None);
    assert!(d.take_arm_commands(9.0, 7.5).is_err(), "a failing middleware is reported");
}

#[test]
fn the_base_command_is_turned_into_world_rates() {
    let twist = |linear: [f64; 3], angular: [f64; 3]| {
        let mut out = Vec::new();
        messages::encode_twist(&mut out, linear, angular, None, "").unwrap();
        out
    };
    let mut d = SimDriver::new(layout(true), None).unwrap();
    assert!(d.receive_base(&twist([1.0, 0.0, 0.0], [0.0, 0.0, 0.3]), false, 1.0));
    let u = d
        .reference(1.0, std::f64::consts::FRAC_PI_2, &[0.0; 5], false)
        .unwrap()
        .to_vec();
    assert!(u[0].abs() < 1e-12 && (u[1] - 1.0).abs() < 1e-12 && u[2] == 0.3, "{u:?}");
    // forward and sideways at any heading: the base frame's velocity rotated into the world's
    assert!(d.receive_base(&twist([0.4, -0.7, 0.0], [0.0, 0.0, -0.2]), false, 1.0));
    for yaw in [-2.5, 0.3, 1.9] {
        let world = nalgebra::Rotation2::new(yaw) * nalgebra::Vector2::new(0.4, -0.7);
        let u = d.reference(1.0, yaw, &[0.0; 5], false).unwrap().to_vec();
        assert!(
            (u[0] - world.x).abs() < 1e-12 && (u[1] - world.y).abs() < 1e-12 && u[2] == -0.2,
            "{u:?}"
        );
    }
    assert!(!d.receive_base(&twist([f64::NAN, 0.0, 0.0], [0.0; 3]), false, 1.0));
    assert!(
        !d.receive_base(&twist([1.0, 0.0, 0.0], [0.0; 3]), true, 1.0),
        "not a TwistStamped"
    );
    assert_eq!((d.counts().rejected_commands, d.counts().base_commands), (2, 2));
}

#[test]
fn bad_commands_are_refused_and_counted_and_never_become_the_reference() {
    let mut d = SimDriver::new(layout(true), None).unwrap();
    d.receive_arm(&command(&[0.1], 0), 1.0, 1.0);
    d.receive_arm(&command(&[0.1, f64::NAN], 0), 1.0, 1.0);
    d.receive_arm(b"not cdr", 1.0, 1.0);
    assert_eq!(d.counts().rejected_commands, 3);
    assert_eq!(d.take_events().rejected.len(), 3);
    assert_eq!(d.reference(1.0, 0.0, &[0.0; 5], false).unwrap(), &[0.0; 5]);
}

#[test]
fn a_jump_trips_the_reflex_and_the_arm_stays_stopped() {
    let reflexes = || FrankaReflexes::new(0.001, &[2.0; 2], &[10.0; 2], &[5000.0; 2]).unwrap();
    let mut d = SimDriver::new(layout(true), Some(reflexes())).unwrap();
    d.receive_arm(&command(&[0.0, 0.0], 0), 1.0, 1.0);
    d.receive_arm(&command(&[0.5, 0.0], 0), 1.001, 1.001);
    assert_eq!(d.take_events().reflexes.len(), 1);
    assert_eq!(
        d.reference(1.001, 0.0, &[0.0; 5], false).unwrap()[3],
        0.0,
        "aborted: the arm's reference is zero"
    );
    d.receive_arm(&command(&[0.0, 0.0], 0), 1.2, 1.2);
    assert!(
        d.reflexes().unwrap().aborted().is_some(),
        "an abort needs the user's recovery"
    );
    // a stream that restarts from rest after a stop is checked from rest
    let mut d = SimDriver::new(layout(true), Some(reflexes())).unwrap();
    d.receive_arm(&command(&[0.004, 0.0], 0), 1.0, 1.0);
    d.receive_arm(&command(&[0.0, 0.0], 0), 1.2, 1.2);
    d.receive_arm(&command(&[0.004, 0.0], 0), 1.201, 1.201);
    assert!(d.take_events().reflexes.is_empty(), "4 rad/s² from rest, jerk 4000 rad/s³");
    // per cycle: the command in effect is checked at every tick
    let mut d = SimDriver::new(layout(false), Some(reflexes())).unwrap();
    d.receive_arm(&command(&[0.5, 0.0], 0), 1.0, 1.0);
    assert!(d.take_events().reflexes.is_empty(), "not checked on reception");
    d.reference(1.0, 0.0, &[0.0; 5], false).unwrap();
    assert_eq!(d.take_events().reflexes.len(), 1);
}

#[test]
fn only_the_recent_states_are_matched() {
    let mut d = SimDriver::new(layout(true), None).unwrap();
    for k in 0..6 {
        d.publish_state(&[0.0; 5], &[0.0; 5], 1_000_000_000 + k).unwrap();
    }
    // four kept (states 2 to 5): the answers to states 0 and 1 are not matched, to 2 and 5 they are
    for answered in [0, 1, 2, 5] {
        d.receive_arm(&command(&[0.0, 0.0], answered), 1.0, 1.0);
    }
    assert_eq!((d.counts().unmatched_echoes, d.counts().echoes), (2, 2));
    assert_eq!((d.counts().first_answered, d.counts().last_answered), (Some(2), Some(5)));
}

#[test]
fn positions_and_velocities_get_their_own_noise_and_the_held_joints_none() {
    let (position_noise, velocity_noise) = (1e-3, 1e-1);
    let mut d = SimDriver::new(
        SimDriverLayout {
            position_noise,
            velocity_noise,
            noise_seed: 3,
            ..layout(true)
        },
        None,
    )
    .unwrap();
    let (q, dq) = ([0.0, 0.0, 0.0, 0.7, -0.2], [0.0, 0.0, 0.0, 0.1, 0.3]);
    let (mut position, mut velocity) = (Vec::new(), Vec::new());
    for k in 0..500 {
        let raw = d.publish_state(&q, &dq, 1_000_000_000 + k).unwrap().unwrap().to_vec();
        let state = messages::decode_joint_state(&raw).unwrap();
        assert_eq!((state.position[2], state.velocity[2]), (0.04, 0.0), "the finger is held");
        position.extend(state.position[..2].iter().zip(&q[3..]).map(|(p, q)| p - q));
        velocity.extend(state.velocity[..2].iter().zip(&dq[3..]).map(|(v, dq)| v - dq));
    }
    // the sample deviation of 1000 normal draws lies within 10 % of the given one (about 4 σ)
    let deviation = |e: &[f64]| (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
    assert!(
        (deviation(&position) / position_noise - 1.0).abs() < 0.1,
        "{}",
        deviation(&position)
    );
    assert!(
        (deviation(&velocity) / velocity_noise - 1.0).abs() < 0.1,
        "{}",
        deviation(&velocity)
    );
}
