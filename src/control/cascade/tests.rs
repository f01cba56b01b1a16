//! The cascade's tick against its stages run by hand, the plan hand-over, and τ_ext's conditioning.

use std::sync::{Arc, Mutex};

use super::*;
use crate::control::tau_ext::ExternalTorque;
use crate::control::LowLevelConfig;
use crate::low_pass::blend;
use crate::model::scene::Scene;
use crate::safety::{RefillConfig, SafetyConfig};

fn scene() -> Arc<Scene> {
    Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene loads"))
}

fn controller(scene: &Arc<Scene>) -> LowLevelController {
    LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap()
}

fn shared<T>(value: T) -> Shared<T> {
    Arc::new(Mutex::new(value))
}

/// A cascade of a default low-level controller, reading τ_ext as given.
fn cascade(scene: &Arc<Scene>, filter: Option<SafetyFilter>, tank: Option<EnergyTank>) -> Cascade {
    let tau = ExternalTorque::new(scene.nq(), None, None, None).unwrap();
    Cascade::new(shared(controller(scene)), filter.map(shared), tank.map(shared), tau).unwrap()
}

/// A reference (K × nq) whose every row moves each joint a little, different per row.
fn moving_reference(nq: usize, k: usize) -> Vec<f64> {
    (0..k * nq)
        .map(|i| 0.05 * ((i % nq) as f64 - 4.0) + 0.01 * (i / nq) as f64)
        .collect()
}

fn reference_at(plan: &Plan, t: f64) -> Vec<f64> {
    let mut out = vec![0.0; plan.nu()];
    plan.reference_at(t, &mut out);
    out
}

#[test]
fn a_tick_without_filter_or_tank_is_the_torque_of_the_interpolated_reference() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let plan = Arc::new(Plan::new(moving_reference(nq, 5), nq, 0.2, 0.015).unwrap());
    let mut by_hand = controller(&scene);
    let mut c = cascade(&scene, None, None);
    c.hand_over(plan.clone(), None).unwrap();
    // Two ticks: the second one has the reference's feed-forward from the first.
    for t in [0.2071, 0.2082] {
        let out = c.tick_measured(&x, &vec![0.3; nq], t, 0.001).unwrap().clone();
        let reference = reference_at(&plan, t);
        assert_ne!(reference, reference_at(&plan, 0.2), "between grid points");
        assert_eq!(out.reference, reference);
        assert_eq!(out.command, reference);
        assert_eq!(out.torque, by_hand.torque(&x, &reference).unwrap());
        assert_eq!((out.tank_energy, out.status, out.status_name()), (None, None, "unfiltered"));
    }
    assert_eq!(c.ticks(), 2);
}

#[test]
fn a_tick_uses_the_plans_gain_floor_else_the_controllers_own() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let own = LowLevelConfig {
        gain_inertia_floor: 0.02,
        ..LowLevelConfig::default()
    };
    let reference = moving_reference(nq, 2);
    let t = 0.004;
    let mut torques = Vec::new();
    for floor in [None, Some(0.5)] {
        let mut plan = Plan::new(reference.clone(), nq, 0.0, 0.01).unwrap();
        if let Some(f) = floor {
            plan = plan.with_gain_inertia_floor(f).unwrap();
        }
        let low = shared(LowLevelController::new(scene.clone(), 0.001, own.clone()).unwrap());
        let mut by_hand = LowLevelController::new(scene.clone(), 0.001, own.clone()).unwrap();
        let tau = ExternalTorque::new(nq, None, None, None).unwrap();
        let mut c = Cascade::new(low.clone(), None, None, tau).unwrap();
        c.hand_over(Arc::new(plan.clone()), None).unwrap();
        let out = c.tick_measured(&x, &vec![0.0; nq], t, 0.001).unwrap().clone();
        let mut expected = vec![0.0; nq];
        by_hand
            .torque_into(&x, &reference_at(&plan, t), floor.unwrap_or(0.02), &mut expected)
            .unwrap();
        assert_eq!(out.torque, expected);
        assert_eq!(lock(&low).config().gain_inertia_floor, 0.02, "the plan's floor is not kept");
        torques.push(out.torque);
    }
    assert_ne!(torques[0], torques[1], "the light wrist joints feel the plan's floor");
}

#[test]
fn a_tick_refills_and_steps_the_tank_as_by_hand() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let reference = moving_reference(nq, 4);
    // τ_ext = −0.5 u_ref: the robot pushes, dissipating 0.5 |u_ref|², which the plan predicts.
    let predicted: Vec<f64> = reference
        .chunks(nq)
        .map(|r| 0.5 * r.iter().map(|v| v * v).sum::<f64>())
        .collect();
    let plan = Plan::new(reference, nq, 0.0, 0.01)
        .unwrap()
        .with_predicted_dissipation(predicted)
        .unwrap();
    let new_tank = || {
        let mut tank = EnergyTank::new(3.0, 2.0, None, false).unwrap();
        tank.set_refill(Some(RefillConfig::default())).unwrap();
        tank
    };
    let mut by_hand = new_tank();
    let mut c = cascade(&scene, None, Some(new_tank()));
    c.hand_over(Arc::new(plan.clone()), None).unwrap();
    let dt = 0.002;
    for step in 0..20 {
        let t = 0.0013 + step as f64 * dt;
        let u_ref = reference_at(&plan, t);
        let tau_ext: Vec<f64> = u_ref.iter().map(|u| -0.5 * u).collect();
        let energy = c.tick_measured(&x, &tau_ext, t, dt).unwrap().tank_energy;
        by_hand
            .refill(
                plan.predicted_dissipation_at(t).unwrap(),
                -EnergyTank::power(&tau_ext, &u_ref),
                dt,
            )
            .unwrap();
        let expected = by_hand.step(&tau_ext, &u_ref, dt).unwrap();
        assert_eq!(energy, Some(expected), "step {step}");
    }
    assert!(by_hand.refilled() > 0.0, "the refill ran");
    assert!(by_hand.energy() < 3.0, "the tank drained");
    let tank = lock(c.tank().unwrap());
    assert_eq!((tank.energy(), tank.refilled()), (by_hand.energy(), by_hand.refilled()));
}

#[test]
fn a_tick_checks_its_inputs_before_changing_anything() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let plan = Arc::new(Plan::new(moving_reference(nq, 3), nq, 0.0, 0.01).unwrap());
    let filter = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let tank = EnergyTank::new(10.0, 2.0, None, true).unwrap();
    let mut c = cascade(&scene, Some(filter), Some(tank));
    let tau = vec![0.0; nq];
    let shape = |r: Result<&TickOutput>| matches!(r, Err(SabreError::Shape { .. }));
    let invalid = |r: Result<&TickOutput>| matches!(r, Err(SabreError::InvalidValue { .. }));
    assert!(invalid(c.tick_measured(&x, &tau, 0.0, 0.001)), "no plan yet");
    c.hand_over(plan, None).unwrap();
    let mut nan_tau = tau.clone();
    nan_tau[1] = f64::NAN;
    let other = Arc::new(Plan::new(vec![0.0; 3 * (nq - 1)], nq - 1, 0.0, 0.01).unwrap());
    assert!(matches!(c.hand_over(other, None), Err(SabreError::Shape { .. })));
    assert!(shape(c.tick_measured(&x[1..], &tau, 0.0, 0.001)));
    assert!(shape(c.tick_measured(&x, &tau[1..], 0.0, 0.001)));
    assert!(invalid(c.tick_measured(&x, &nan_tau, 0.0, 0.001)));
    assert!(invalid(c.tick_measured(&x, &tau, f64::NAN, 0.001)));
    for dt in [0.0, -0.001, f64::INFINITY] {
        assert!(invalid(c.tick_measured(&x, &tau, 0.0, dt)), "dt = {dt}");
    }
    assert_eq!(c.tau_ext().readings(), 0, "no bad tick took a reading");
    let out = c.tick_measured(&x, &tau, 0.0, 0.001).unwrap();
    assert_eq!(out.status_name(), "solved");
    assert_eq!(out.tank_energy, Some(10.0));
    assert_eq!(
        lock(c.filter().unwrap()).stats().calls,
        1,
        "only the good tick reached the filter"
    );
    assert_eq!(
        lock(c.tank().unwrap()).history().len(),
        2,
        "only the good tick stepped the tank"
    );
    assert_eq!(c.tau_ext().readings(), 1, "the good tick took its reading");
}

#[test]
fn a_cascade_rejects_a_filter_built_for_another_robot() {
    let probe = crate::sim::test_scene::probe_and_drawer();
    let filter = SafetyFilter::new(scene(), SafetyConfig::default()).unwrap();
    let tau = ExternalTorque::new(probe.nq(), None, None, None).unwrap();
    let made = Cascade::new(shared(controller(&probe)), Some(shared(filter)), None, tau);
    assert!(matches!(made, Err(SabreError::InvalidValue { .. })));
}

#[test]
fn a_plan_handed_over_for_later_takes_over_at_its_time_and_a_newer_one_replaces_it() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let constant = |v: f64| Arc::new(Plan::new(vec![v; 2 * nq], nq, 0.0, 0.01).unwrap());
    let mut c = cascade(&scene, None, None);
    assert_eq!(c.in_force(), None);
    let first = c.hand_over(constant(0.1), Some(5.0)).unwrap();
    assert_eq!(
        (c.in_force(), c.pending()),
        (Some(first), None),
        "the first plan is in force at once"
    );
    let second = c.hand_over(constant(0.2), Some(0.003)).unwrap();
    let third = c.hand_over(constant(0.3), Some(0.004)).unwrap();
    assert_eq!(c.pending(), Some((third, 0.004)), "the newer waiting plan dropped the older");
    assert!(second < third);
    let tau = vec![0.0; nq];
    let mut seen = Vec::new();
    // a clock that sums its steps lands a rounding error short of 0.004
    let mut t = 0.0;
    for _ in 0..6 {
        seen.push(c.tick_measured(&x, &tau, t, 0.001).unwrap().reference[0]);
        t += 0.001 * (1.0 - 1e-12);
    }
    // a constant plan, interpolated: equal to its value within rounding
    let expected = [0.1, 0.1, 0.1, 0.1, 0.3, 0.3];
    assert!(seen.iter().zip(expected).all(|(s, e)| (s - e).abs() < 1e-12), "{seen:?}");
    assert_eq!((c.in_force(), c.pending()), (Some(third), None));
    c.reset();
    assert_eq!((c.in_force(), c.pending(), c.ticks()), (None, None, 0));
}

#[test]
fn tau_ext_is_low_passed_over_the_ticks_steps_and_counted_stale_past_its_timeout() {
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let tau = ExternalTorque::new(nq, Some(5.0), Some(0.01), None).unwrap();
    let tank = EnergyTank::new(10.0, 0.0, None, false).unwrap();
    let mut c = Cascade::new(shared(controller(&scene)), None, Some(shared(tank)), tau).unwrap();
    let u = 0.2;
    c.hand_over(Arc::new(Plan::new(vec![u; nq], nq, 0.0, 0.01).unwrap()), None)
        .unwrap();
    let reading = vec![1.0; nq];
    c.tau_ext_mut().set_torque(&reading, 3.0, 0.0).unwrap();
    // The tank's step integrates dt τ̂ᵀu: read τ̂ back from its energy.
    let mut energy = 10.0;
    let mut conditioned = |c: &mut Cascade, now: f64, dt: f64| {
        let e = c.tick(&x, now, dt, now).unwrap().tank_energy.unwrap();
        let tau_hat = (e - energy) / (dt * u * nq as f64);
        energy = e;
        tau_hat
    };
    assert!(
        (conditioned(&mut c, 0.0, 0.001) - 1.0).abs() < 1e-9,
        "the first reading passes through"
    );
    assert!(
        (conditioned(&mut c, 0.004, 0.004) - 1.0).abs() < 1e-9,
        "a constant reading stays"
    );
    let a = blend(5.0, 0.002);
    // past the timeout the reading counts as zero, through the low-pass
    let stale = conditioned(&mut c, 0.012, 0.002);
    assert!((stale - (1.0 - a)).abs() < 1e-9, "{stale} vs {}", 1.0 - a);
    assert_eq!(c.tau_ext().stale_count(), 1);
    assert_eq!(c.tau_ext().force(), 3.0);
    assert!(matches!(
        c.tau_ext_mut().set_torque(&reading, -1.0, 0.0),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(ExternalTorque::new(nq, Some(f64::NAN), None, None).is_err());
    assert!(ExternalTorque::new(nq, None, Some(-1.0), None).is_err());
}

#[test]
fn a_shaped_tick_needs_a_shaping_and_then_steps_the_gate_toward_the_ticks_command() {
    use crate::control::command_stream::{CommandGate, CommandShaper};
    use crate::control::{CommandShaping, RateLimiter};
    let scene = scene();
    let (nq, x) = (scene.nq(), scene.default_state());
    let mut c = cascade(&scene, None, None);
    c.hand_over(Arc::new(Plan::new(moving_reference(nq, 3), nq, 0.0, 0.01).unwrap()), None)
        .unwrap();
    assert!(matches!(
        c.tick_shaped(&x, 0.0, 0.001, 0.0),
        Err(SabreError::InvalidValue { .. })
    ));
    assert_eq!(c.ticks(), 0, "refused before the tick");
    let arm: Vec<usize> = (3..nq).collect();
    let loose = |n: usize| RateLimiter::new(vec![10.0; n], vec![1e6; n], vec![1e9; n], 0.001).unwrap();
    let gate = CommandGate::new(CommandShaper::new(loose(arm.len()), Some(loose(3)), 1), 0.05).unwrap();
    c.set_shaping(CommandShaping::new(gate, arm.clone(), Some([0, 1, 2]), nq).unwrap())
        .unwrap();
    let command = c.tick_shaped(&x, 0.004, 0.001, 0.004).unwrap().clone();
    let ticked = c.output().command.clone();
    assert!(arm.iter().zip(&command.arm).all(|(&i, a)| (ticked[i] - a).abs() < 1e-9));
    assert_eq!(c.ticks(), 1);
}

#[test]
fn the_tank_books_tau_ext_against_the_filtered_command_not_the_reference() {
    let scene = scene();
    let nq = scene.nq();
    let j4 = scene
        .robot
        .active_joint_names()
        .iter()
        .position(|n| n == "panda_joint4")
        .expect("the Panda's fourth joint");
    let mut x = scene.default_state();
    x[j4] = scene.robot_limits()[j4].upper - 0.02;
    // 1 rad/s into the limit 20 mrad away: the filter brakes it
    let mut reference = vec![0.0; 2 * nq];
    reference[j4] = 1.0;
    reference[nq + j4] = 1.0;
    let filter = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let tank = EnergyTank::new(10.0, 0.0, None, false).unwrap();
    let mut by_hand = EnergyTank::new(10.0, 0.0, None, false).unwrap();
    let mut c = cascade(&scene, Some(filter), Some(tank));
    c.hand_over(Arc::new(Plan::new(reference, nq, 0.0, 0.01).unwrap()), None)
        .unwrap();
    let tau: Vec<f64> = (0..nq).map(|i| if i == j4 { 5.0 } else { 0.3 }).collect();
    let out = c.tick_measured(&x, &tau, 0.0, 0.001).unwrap().clone();
    assert!(
        out.reference[j4] - out.command[j4] > 0.1,
        "the filter braked: {} → {}",
        out.reference[j4],
        out.command[j4]
    );
    assert_eq!(out.tank_energy, Some(by_hand.step(&tau, &out.command, 0.001).unwrap()));
}
