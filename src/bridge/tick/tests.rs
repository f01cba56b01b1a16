//! The bridge's tick against the cascade ticked by hand: which states tick, the step each integrates
//! over, what its answers carry, and when it does not follow the plan.

use std::sync::{Arc, Mutex};

use super::*;
use crate::control::command_stream::{CommandGate, CommandShaper};
use crate::control::{ExternalTorque, LowLevelConfig, LowLevelController, Plan, RateLimiter};
use crate::model::scene::Scene;
use crate::safety::EnergyTank;

const NQ: usize = 10;
/// The royalpanda's base joints (x, y, yaw) and its arm's.
const BASE: [usize; 3] = [0, 1, 2];
const MAX_TICK_DT: f64 = 0.005;
const STATE_TIMEOUT: f64 = 0.05;
const BASE_TIMEOUT: f64 = 0.2;

fn names() -> Vec<String> {
    (0..NQ).map(|i| format!("joint_{i}")).collect()
}

fn layout() -> BridgeLayout {
    BridgeLayout {
        max_tick_dt: MAX_TICK_DT,
        cmd_vel_stamped: true,
        cmd_vel_frame: "base_link".into(),
        echo_names: None,
        trajectory: None,
    }
}

/// A tick on the robot's joints (the arm's drive the ticks; the base's go stale after BASE_TIMEOUT),
/// the object at o = 0 at rest.
fn bridge_tick() -> BridgeTick {
    let names = names();
    let arm: Vec<String> = names[3..].to_vec();
    let timeouts = (0..NQ).map(|i| if i < 3 { BASE_TIMEOUT } else { STATE_TIMEOUT }).collect();
    let joints = JointMerge::new(names, &arm, timeouts).unwrap();
    BridgeTick::new(layout(), joints, None, (vec![0.0], vec![0.0])).unwrap()
}

/// A cascade with a tank and a τ_ext that works on the command, so that the tank's energy records the
/// step each tick integrated over, shaping through a 1 kHz gate (the base every 20th step).
fn cascade(scene: &Arc<Scene>, plan: Option<&Arc<Plan>>) -> Cascade {
    let low = LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap();
    let tank = EnergyTank::new(5.0, 1.0, None, false).unwrap();
    let tau = ExternalTorque::new(NQ, None, None, None).unwrap();
    let mut c = Cascade::new(Arc::new(Mutex::new(low)), None, Some(Arc::new(Mutex::new(tank))), tau).unwrap();
    let arm = RateLimiter::new(vec![2.0; 7], vec![10.0; 7], vec![5000.0; 7], 0.001).unwrap();
    let base = RateLimiter::new(vec![1.0; 3], vec![1.0; 3], vec![10.0; 3], 0.02).unwrap();
    let gate = CommandGate::new(CommandShaper::new(arm, Some(base), 20), STATE_TIMEOUT).unwrap();
    c.set_shaping(CommandShaping::new(gate, (3..NQ).collect(), Some(BASE), NQ).unwrap())
        .unwrap();
    c.tau_ext_mut().set_torque(&[0.4; NQ], f64::INFINITY, 0.0).unwrap();
    if let Some(plan) = plan {
        c.hand_over(plan.clone(), None).unwrap();
    }
    c
}

/// A plan from t = 0 over 0.2 s whose every joint moves, the base too.
fn plan() -> Arc<Plan> {
    let reference = (0..20 * NQ)
        .map(|i| 0.3 + 0.02 * (i % NQ) as f64 + 0.01 * (i / NQ) as f64)
        .collect();
    Arc::new(Plan::new(reference, NQ, 0.0, 0.01).unwrap())
}

fn state(stamp: f64, names: &[String], q: &[f64]) -> Vec<u8> {
    let mut out = Vec::new();
    let qd: Vec<f64> = q.iter().map(|v| 0.1 * v).collect();
    messages::encode_joint_state(&mut out, Stamp::from_seconds(stamp), "", names, q, &qd, &[]).unwrap();
    out
}

/// Within every joint's limits (panda_joint4, index 6, lives in [−3.07, −0.07] rad).
fn configuration() -> Vec<f64> {
    (0..NQ).map(|i| if i == 6 { -1.0 } else { 0.05 * i as f64 }).collect()
}

fn tick_at(received: &Received) -> (f64, bool) {
    match received {
        Received::Tick { t, fresh } => (*t, *fresh),
        other => panic!("not a tick: {other:?}"),
    }
}

#[test]
fn each_stamp_ticks_once_and_a_joint_past_its_timeout_makes_the_tick_stale() {
    let mut tick = bridge_tick();
    let (names, q) = (names(), configuration());
    assert_eq!(tick_at(&tick.receive(&state(100.0, &names, &q), 0.0)), (0.0, true));
    // the same stamp again, then an earlier one: refused, and still answered (they name the arm)
    for (stamp, received) in [(100.0, 0.001), (99.999, 0.002)] {
        match tick.receive(&state(stamp, &names, &q), received) {
            Received::Rejected { ticks: true, .. } => {}
            other => panic!("stamp {stamp}: {other:?}"),
        }
    }
    assert_eq!(tick.counts().rejected, 2);
    // the arm's joints alone: the base's were received at 0 s and go stale BASE_TIMEOUT later
    let (arm_names, arm_q) = (&names[3..], &q[3..]);
    let (t, fresh) = tick_at(&tick.receive(&state(100.1, arm_names, arm_q), 0.1));
    assert!((t - 0.1).abs() < 1e-9 && fresh);
    let (t, fresh) = tick_at(&tick.receive(&state(100.25, arm_names, arm_q), BASE_TIMEOUT + 0.05));
    assert!((t - 0.25).abs() < 1e-9 && !fresh, "the base's joints are past their timeout");
    assert_eq!(tick.receive(&state(100.3, &names[..3], &q[..3]), 0.3), Received::Merged);
}

#[test]
fn a_followed_state_is_the_cascades_shaped_tick_over_the_step_since_the_previous_capped() {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).unwrap());
    let plan = plan();
    let (mut c, mut by_hand) = (cascade(&scene, Some(&plan)), cascade(&scene, Some(&plan)));
    let mut tick = bridge_tick();
    let (names, q) = (names(), configuration());
    let qd: Vec<f64> = q.iter().map(|v| 0.1 * v).collect();
    let x: Vec<f64> = q.iter().chain(&qd).chain(&[0.0, 0.0]).copied().collect();
    // the first state: one command period; then 1 ms; then 40 ms, capped at MAX_TICK_DT
    let mut previous: Option<f64> = None;
    for stamp in [100.0, 100.001, 100.041] {
        let received = stamp - 99.0;
        let (t, fresh) = tick_at(&tick.receive(&state(stamp, &names, &q), received));
        assert!(fresh);
        let dt = previous.map_or(0.001, |p| (t - p).min(MAX_TICK_DT));
        previous = Some(t);
        let Followed::Answered(answer) = tick.follow(&mut c, t, received, false, 0.1).unwrap() else {
            panic!("at {t}: not answered")
        };
        assert_eq!(tick.x(), &x[..]);
        let expected = by_hand.tick_shaped(&x, t, dt, received).unwrap().clone();
        assert_eq!(c.output().tank_energy, by_hand.output().tank_energy, "at {t}: another step");
        let (arm, answers) = messages::decode_float64_array(answer.arm.as_ref().unwrap()).unwrap();
        assert_eq!((arm, answers), (expected.arm.clone(), Stamp::from_seconds(stamp).nanosec));
        assert_eq!(answer.base.is_some(), expected.base_due);
        if let Some(base) = answer.base {
            let twist = messages::decode_twist(&base, true).unwrap();
            assert_eq!([twist.linear[0], twist.linear[1], twist.angular[2]], expected.base[..]);
            assert_eq!(twist.stamp, Some(Stamp::from_seconds(stamp)), "a stamped base command");
        }
    }
    assert_eq!(tick.counts().followed, 3);
    assert!(c.output().tank_energy != Some(5.0), "the tank did integrate");
}

#[test]
fn an_old_plan_is_not_followed_and_steps_that_answer_no_state_carry_no_stamp() {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).unwrap());
    let (names, q) = (names(), configuration());
    let mut tick = bridge_tick();
    let mut c = cascade(&scene, None);
    let (t, _) = tick_at(&tick.receive(&state(100.0, &names, &q), 1.0));
    assert!(matches!(tick.follow(&mut c, t, 1.0, false, 0.05).unwrap(), Followed::NoPlan));
    c.hand_over(plan(), None).unwrap();
    let (t, _) = tick_at(&tick.receive(&state(100.01, &names, &q), 1.01));
    assert!(matches!(
        tick.follow(&mut c, t, 1.01, false, 0.05).unwrap(),
        Followed::Answered(_)
    ));
    // the plan starts at 0 s: 60 ms old at 0.06 s, older than the 50 ms allowed
    let (t, _) = tick_at(&tick.receive(&state(100.06, &names, &q), 1.06));
    assert!(matches!(
        tick.follow(&mut c, t, 1.06, false, 0.05).unwrap(),
        Followed::StalePlan
    ));
    // a ramp step answering that state carries its stamp
    let (arm, answers) = messages::decode_float64_array(tick.stop(&mut c, 1.06).unwrap().arm.as_ref().unwrap()).unwrap();
    assert_eq!(answers, Stamp::from_seconds(100.06).nanosec);
    assert!(arm.iter().all(|v| *v != 0.0), "a ramp step, not a step to zero: {arm:?}");
    // no state for longer than the timeout: the watchdog's steps answer none (0), the base's stamped
    let stamp = Stamp { sec: 7, nanosec: 9 };
    let steps = tick.watchdog(&mut c, 1.06 + STATE_TIMEOUT + 0.0105, 100, stamp).unwrap();
    assert!(!steps.is_empty());
    for step in &steps {
        assert_eq!(messages::decode_float64_array(step.arm.as_ref().unwrap()).unwrap().1, 0);
        if let Some(base) = &step.base {
            assert_eq!(messages::decode_twist(base, true).unwrap().stamp, Some(stamp));
        }
    }
    let mut rest = 0;
    while let Some(step) = tick.ramp_step(&mut c, stamp).unwrap() {
        assert_eq!(messages::decode_float64_array(step.arm.as_ref().unwrap()).unwrap().1, 0);
        rest += 1;
        assert!(rest <= 10_000, "the shutdown's ramp does not come to rest");
    }
    let gate = shaping_of(&c).unwrap().gate();
    assert!(gate.shaper().at_rest() && gate.stale_events() == 1);
}

#[test]
fn a_cascade_without_command_shaping_is_refused() {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).unwrap());
    let low = LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap();
    let tau = ExternalTorque::new(NQ, None, None, None).unwrap();
    let mut c = Cascade::new(Arc::new(Mutex::new(low)), None, None, tau).unwrap();
    c.hand_over(plan(), None).unwrap();
    let mut tick = bridge_tick();
    let (t, _) = tick_at(&tick.receive(&state(100.0, &names(), &configuration()), 0.0));
    let error = tick.follow(&mut c, t, 0.0, false, 0.1).unwrap_err();
    assert_eq!(error.to_string(), shapes_no_commands().to_string());
    assert!(tick.stop(&mut c, 0.0).is_err() && tick.ramp_step(&mut c, Stamp::default()).is_err());
}
