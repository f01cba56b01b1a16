//! The inner loop driving the plant (`follow_reference_safe`) is the inner-loop tick, once per plant
//! step, followed by the plant step: the same states, commands, statuses and tank energies, bit for bit.

use std::sync::Arc;

use sabre::control::{
    follow_reference_safe, InnerLoop, InnerSafety, LowLevelConfig, LowLevelController, Plan, TickOutput, TrackTrace,
};
use sabre::model::Scene;
use sabre::safety::{EnergyTank, FilterStatus, RefillConfig, SafetyConfig, SafetyFilter};
use sabre::sim::{Plant, PlantConfig};

const STEPS: usize = 600;
/// The mobile base's x joint.
const BASE_X: usize = 0;
const PLAN_DT: f64 = 0.015;

/// Everything one run of the inner loop owns.
struct Rig {
    plant: Plant,
    controller: LowLevelController,
    filter: SafetyFilter,
    tank: EnergyTank,
}

fn rig(scene: &Arc<Scene>, x0: &[f64]) -> Rig {
    let mut plant = Plant::new(scene.clone(), PlantConfig::default()).unwrap();
    plant.reset(x0).unwrap();
    let mut tank = EnergyTank::new(10.0, 2.0, Some(12.0), false).unwrap();
    tank.set_refill(Some(RefillConfig::default())).unwrap();
    Rig {
        plant,
        controller: LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap(),
        filter: SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap(),
        tank,
    }
}

#[test]
fn following_a_plan_is_one_tick_and_one_plant_step_per_step() {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let nq = scene.nq();
    let mut x0 = scene.default_state();
    x0[BASE_X] = 0.3;
    // The base driven into the shelf, the other joints swaying: the contact drains the tank and
    // the passivity row binds.
    let k = 50;
    let reference: Vec<f64> = (0..k * nq)
        .map(|i| match i % nq {
            BASE_X => 0.3,
            j => 0.1 * ((i / nq) as f64 * 0.3 + j as f64).sin(),
        })
        .collect();
    // About the dissipation the push measures, so that the refill runs.
    let predicted: Vec<f64> = (0..k).map(|i| 20.0 + 0.5 * i as f64).collect();
    let t0 = -0.0042;

    let mut followed = rig(&scene, &x0);
    let mut trace = TrackTrace::default();
    follow_reference_safe(
        &mut followed.plant,
        &mut followed.controller,
        &reference,
        t0,
        PLAN_DT,
        STEPS,
        1,
        &mut trace,
        Some(InnerSafety {
            filter: Some(&mut followed.filter),
            tank: Some(&mut followed.tank),
            predicted_dissipation: Some(&predicted),
        }),
    )
    .unwrap();

    let mut ticked = rig(&scene, &x0);
    let plan = Plan::new(reference, nq, t0, PLAN_DT)
        .unwrap()
        .with_predicted_dissipation(predicted)
        .unwrap();
    let plant = &mut ticked.plant;
    let mut inner = InnerLoop::new(&mut ticked.controller, Some(&mut ticked.filter), Some(&mut ticked.tank)).unwrap();
    let mut out = TickOutput::new(nq, nq);
    let (mut states, mut commands, mut energies, mut statuses) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..STEPS {
        let tau_ext = plant.measured_tau_ext().to_vec();
        inner
            .tick(&plan, plant.state(), &tau_ext, plant.time(), plant.dt(), &mut out)
            .unwrap();
        plant.step(&out.torque).unwrap();
        states.extend_from_slice(plant.state());
        commands.extend_from_slice(&out.command);
        energies.push(out.tank_energy.unwrap());
        statuses.push(out.status.unwrap());
    }

    assert_eq!(trace.state, states);
    assert_eq!(trace.filtered, commands);
    assert_eq!(trace.tank_energy, energies);
    assert_eq!(trace.filter_status, statuses);
    assert_eq!(followed.tank.refilled(), ticked.tank.refilled());
    assert_eq!(followed.filter.stats().calls, STEPS as u64);
    // The run exercised what it claims to: contact, a tank drained and refilled, a filter that
    // held the base back.
    assert!(trace.contact.iter().any(|&c| c));
    assert!(energies[STEPS - 1] < 9.0, "{}", energies[STEPS - 1]);
    assert!(ticked.tank.refilled() > 0.1, "{}", ticked.tank.refilled());
    assert!((0..STEPS).any(|s| commands[s * nq + BASE_X] < 0.2));
    assert!(statuses.iter().all(|s| *s != FilterStatus::Fallback));
}
