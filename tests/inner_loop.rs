//! The cascade driving the plant (`Cascade::follow`) is the cascade's tick, once per plant step,
//! followed by the plant step: the same states, commands, statuses and tank energies, bit for bit.

use std::sync::{Arc, Mutex};

use sabre::control::{Cascade, ExternalTorque, LowLevelConfig, LowLevelController, Plan, Shared, TrackTrace};
use sabre::model::Scene;
use sabre::safety::{EnergyTank, FilterStatus, RefillConfig, SafetyConfig, SafetyFilter};
use sabre::sim::{Plant, PlantConfig};

const STEPS: usize = 600;
/// The mobile base's x joint.
const BASE_X: usize = 0;
const PLAN_DT: f64 = 0.015;

fn shared<T>(value: T) -> Shared<T> {
    Arc::new(Mutex::new(value))
}

/// Everything one run of the cascade owns: the plant and the cascade, with its filter and tank.
struct Rig {
    plant: Plant,
    cascade: Cascade,
    filter: Shared<SafetyFilter>,
    tank: Shared<EnergyTank>,
}

fn rig(scene: &Arc<Scene>, x0: &[f64]) -> Rig {
    let mut plant = Plant::new(scene.clone(), PlantConfig::default()).unwrap();
    plant.reset(x0).unwrap();
    let mut tank = EnergyTank::new(10.0, 2.0, Some(12.0), false).unwrap();
    tank.set_refill(Some(RefillConfig::default())).unwrap();
    let (filter, tank) = (
        shared(SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap()),
        shared(tank),
    );
    let controller = shared(LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap());
    let tau = ExternalTorque::new(scene.nq(), None, None, None).unwrap();
    let cascade = Cascade::new(controller, Some(filter.clone()), Some(tank.clone()), tau).unwrap();
    Rig {
        plant,
        cascade,
        filter,
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

    let plan = Arc::new(
        Plan::new(reference, nq, t0, PLAN_DT)
            .unwrap()
            .with_predicted_dissipation(predicted)
            .unwrap(),
    );
    let mut followed = rig(&scene, &x0);
    followed.cascade.hand_over(plan.clone(), None).unwrap();
    let mut trace = TrackTrace::default();
    followed.cascade.follow(&mut followed.plant, STEPS, 1, &mut trace).unwrap();

    let mut ticked = rig(&scene, &x0);
    ticked.cascade.hand_over(plan, None).unwrap();
    let plant = &mut ticked.plant;
    let (mut states, mut commands, mut energies, mut statuses) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..STEPS {
        let tau_ext = plant.measured_tau_ext().to_vec();
        let out = ticked
            .cascade
            .tick_measured(plant.state(), &tau_ext, plant.time(), plant.dt())
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
    let refilled = |rig: &Rig| rig.tank.lock().unwrap().refilled();
    assert_eq!(refilled(&followed), refilled(&ticked));
    assert_eq!(followed.filter.lock().unwrap().stats().calls, STEPS as u64);
    // The run exercised what it claims to: contact, a tank drained and refilled, a filter that
    // held the base back.
    assert!(trace.contact.iter().any(|&c| c));
    assert!(energies[STEPS - 1] < 9.0, "{}", energies[STEPS - 1]);
    assert!(refilled(&ticked) > 0.1, "{}", refilled(&ticked));
    assert!((0..STEPS).any(|s| commands[s * nq + BASE_X] < 0.2));
    assert!(statuses.iter().all(|s| *s != FilterStatus::Fallback));
}
