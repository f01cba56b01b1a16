//! Criterion bench of the safety filter: one FILTER-QP call with the full constraint set, and one 1 kHz inner-loop tick.
//!
//! Constraint set: 10 joint limits, 3 self-collision pairs, arm reach, base box (x, y), 8 sphere
//! obstacles against 5 robot spheres (40 rows) and the passivity row: 57 ZBF rows + 20 input bounds.
//! States:
//! - `free`: the home posture, obstacles around but clear, a moderate command, full tank: the
//!   projected command meets every row (the common case away from limits; no solver runs);
//! - `binding_cold`: the paper's start posture (elbow near its limit, hand near the base), base 5 cm
//!   inside the box edge, an obstacle 3.5 cm in front of the hand, the tank 0.1 J above its floor with a
//!   contact torque, and a command that presses into all of them (self-collision, obstacle and
//!   passivity rows bind); no remembered active set, so Clarabel solves the screened problem;
//! - `binding_warm`: the same call again: the previous active set is re-solved and verified (the
//!   common case at 1 kHz);
//! - `binding_full_qp`: the same with every shortcut off (Clarabel solves all 57 rows).
//!
//! The tick runs `Cascade::follow` for one plant step (interpolation, filter with the tank,
//! low-level controller, plant step, tank update) with the `binding` posture and command.

use std::sync::{Arc, Mutex};

use criterion::{criterion_group, criterion_main, Criterion};
use sabre::control::{Cascade, ExternalTorque, LowLevelConfig, LowLevelController, Plan, TrackTrace};
use sabre::model::Scene;
use sabre::safety::{EnergyTank, SafetyConfig, SafetyFilter};
use sabre::sim::{Plant, PlantConfig};

struct Case {
    x: Vec<f64>,
    u: Vec<f64>,
    tau: Vec<f64>,
    energy: f64,
}

fn index(scene: &Scene, name: &str) -> usize {
    scene
        .robot
        .active_joint_names()
        .iter()
        .position(|n| n == name)
        .expect("joint")
}

fn filter(scene: &Arc<Scene>, screening: bool) -> SafetyFilter {
    let mut f = SafetyFilter::new(
        scene.clone(),
        SafetyConfig {
            screening,
            ..SafetyConfig::default()
        },
    )
    .expect("filter");
    // One obstacle 3.5 cm in front of the binding posture's hand, seven scattered around the workspace.
    f.add_obstacle([2.62, 0.005, 0.885], 0.08).expect("slot");
    for i in 0..7 {
        let a = i as f64 * 0.9;
        f.add_obstacle([1.2 * a.cos(), 1.2 * a.sin(), 0.3 + 0.15 * i as f64], 0.1)
            .expect("slot");
    }
    f
}

fn cases(scene: &Scene) -> (Case, Case) {
    let nq = scene.nq();
    let free = Case {
        x: scene.default_state(),
        u: vec![0.1, -0.1, 0.05, 0.2, -0.2, 0.1, 0.1, -0.1, 0.2, 0.1],
        tau: vec![0.0; nq],
        energy: 10.0,
    };
    let mut x = scene.default_state();
    for (name, value) in [("panda_joint2", -1.6), ("panda_joint4", -2.95), ("panda_joint6", 1.6)] {
        x[index(scene, name)] = value;
    }
    x[0] = 1.95;
    let mut u = vec![0.0; nq];
    u[0] = 0.8;
    u[index(scene, "panda_joint4")] = -1.5;
    u[index(scene, "panda_joint2")] = -0.8;
    u[index(scene, "panda_joint6")] = 0.5;
    let tau: Vec<f64> = (0..nq).map(|j| if j < 3 { 0.0 } else { -3.0 }).collect();
    (free, Case { x, u, tau, energy: 2.1 })
}

fn filter_qp(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let (free, binding) = cases(&scene);
    let mut group = c.benchmark_group("filter_qp_57_rows");
    group.sample_size(50);
    let cases = [
        ("free", &free, true, false),
        ("binding_cold", &binding, true, true),
        ("binding_warm", &binding, true, false),
        ("binding_full_qp", &binding, false, false),
    ];
    for (name, case, screening, cold) in cases {
        let mut f = filter(&scene, screening);
        let call = |f: &mut SafetyFilter| {
            if cold {
                f.forget_active_set();
            }
            f.filter(&case.x, &case.u, Some((&case.tau, case.energy))).expect("filter").u[0]
        };
        call(&mut f);
        call(&mut f);
        let out = f.output().clone();
        let active: Vec<String> = out.active.iter().map(|&i| f.constraint_name(i)).collect();
        eprintln!(
            "{name}: {:?}, {} rows, {} iterations, {:?}, active {active:?}",
            out.method, out.qp_rows, out.iterations, out.status
        );
        group.bench_function(name, |b| b.iter(|| call(&mut f)));
    }
    group.finish();
}

fn inner_tick(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let (_, binding) = cases(&scene);
    let mut plant = Plant::new(scene.clone(), PlantConfig::default()).expect("plant");
    let controller = Arc::new(Mutex::new(
        LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).expect("controller"),
    ));
    let f = Arc::new(Mutex::new(filter(&scene, true)));
    let tank = Arc::new(Mutex::new(EnergyTank::new(10.0, 2.0, None, false).expect("tank")));
    plant.reset(&binding.x).expect("reset");
    // A reference of 66 steps (15 ms) pressing into the limits; past its end it holds its last value.
    let reference: Vec<f64> = (0..66).flat_map(|_| binding.u.iter().copied()).collect();
    let plan = Arc::new(Plan::new(reference, scene.nq(), 0.0, 0.015).expect("plan"));
    let tau = || ExternalTorque::new(scene.nq(), None, None, None).expect("tau_ext");
    let mut full = Cascade::new(controller.clone(), Some(f.clone()), Some(tank), tau()).expect("cascade");
    let mut bare = Cascade::new(controller, None, None, tau()).expect("cascade");
    full.hand_over(plan.clone(), None).expect("plan");
    bare.hand_over(plan, None).expect("plan");
    let mut trace = TrackTrace::default();
    let mut group = c.benchmark_group("inner_loop");
    group.sample_size(50);
    group.bench_function("tick_filter_tank_controller_plant", |b| {
        b.iter(|| full.follow(&mut plant, 1, 0, &mut trace).expect("tick"))
    });
    group.bench_function("tick_controller_plant_only", |b| {
        b.iter(|| bare.follow(&mut plant, 1, 0, &mut trace).expect("tick"))
    });
    group.finish();
    let s = *f.lock().expect("filter").stats();
    eprintln!(
        "filter during the ticks: {} calls, {} with Clarabel, {} fallbacks, mean {:.1} µs",
        s.calls,
        s.interior_point_calls,
        s.fallbacks,
        1e6 * s.mean_time()
    );
}

criterion_group!(benches, filter_qp, inner_tick);
criterion_main!(benches);
