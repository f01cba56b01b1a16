//! The energy tank, Sequential FILTER-QP, the filtered inner loop, the obstacle slots, constraint
//! classes and the task metric, checked against closed-form tank energies, simulated rollouts and
//! the optimality conditions of the weighted problem.
#![allow(clippy::needless_range_loop)] // index loops name the joint in each failure message

mod safety_fixtures;

use std::sync::{Arc, Mutex};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::control::{Cascade, ExternalTorque, LowLevelConfig, LowLevelController, Plan, TrackTrace};
use sabre::model::Scene;
use sabre::safety::{ConstraintClass, EnergyTank, FilterStatus, SafetyConfig, SafetyFilter};
use sabre::sim::{Plant, PlantConfig, RolloutConfig, RolloutModel};
use sabre::SabreError;
use safety_fixtures::*;

#[test]
fn passivity_row_stops_dissipation_at_the_tank_floor() {
    let scene = scene();
    let mut config = SafetyConfig::default();
    // With Γ_pass = 1e6 the row's slack, λ/Γ, is negligible: at S = ε the filter must leave no
    // dissipation. With the default Γ = 100 a slack of λ/100 remains, bounded by the tests above.
    config.penalty.set(ConstraintClass::Passivity, 1e6);
    let mut f = SafetyFilter::new(scene.clone(), config).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let x = scene.default_state();
    for _ in 0..50 {
        let tau: Vec<f64> = (0..10).map(|_| rng.random_range(-10.0..10.0)).collect();
        // A command that pushes against τ_ext: −τᵀu > 0 (dissipating).
        let u_ref: Vec<f64> = tau.iter().map(|t| -0.05 * t.signum()).collect();
        assert!(-dot(&tau, &u_ref) > 0.0);
        let out = f.filter(&x, &u_ref, Some((&tau, 2.0))).unwrap().clone();
        let dissipated = -dot(&tau, &out.u);
        assert!(dissipated <= 1e-4, "P_diss = {dissipated} at the floor");
        assert!(out.active.iter().any(|&i| f.constraint_name(i) == "passivity"));
        // Above the floor the same command may dissipate up to α (S − ε) = 1 W.
        let out = f.filter(&x, &u_ref, Some((&tau, 3.0))).unwrap();
        assert!(-dot(&tau, &out.u) <= 1.0 + 1e-4);
    }
    // Without τ_ext the row is off.
    let out = f.filter(&x, &[0.05; 10], None).unwrap();
    assert!(out.barrier.last().unwrap().is_nan());
}

#[test]
fn tank_integrates_constant_power_exactly_and_respects_its_ceiling() {
    let mut tank = EnergyTank::new(10.0, 2.0, None, true).unwrap();
    let tau = [2.0, -1.0, 0.5];
    let u = [-0.2, 0.1, 0.2]; // τᵀu = −0.4 W: the robot dissipates, the tank drains
    for _ in 0..1000 {
        tank.step(&tau, &u, 1e-3).unwrap();
    }
    assert!((tank.energy() - (10.0 - 0.4)).abs() < 1e-12, "{}", tank.energy());
    let h = tank.history();
    assert_eq!(h.len(), 1001);
    for (k, s) in h.iter().enumerate() {
        assert!((s - (10.0 - 0.4 * k as f64 * 1e-3)).abs() < 1e-12);
    }
    assert!((tank.residual() - 7.6).abs() < 1e-12);
    // Power from the environment refills up to the ceiling.
    let mut capped = EnergyTank::new(10.0, 2.0, Some(10.5), false).unwrap();
    for _ in 0..2000 {
        capped.step(&[1.0], &[1.0], 1e-3).unwrap();
    }
    assert_eq!(capped.energy(), 10.5);
    assert!(capped.history().is_empty());
    capped.reset();
    assert_eq!(capped.energy(), 10.0);
    assert!(matches!(
        tank.step(&[1.0, f64::NAN, 0.0], &u, 1e-3),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(matches!(tank.step(&[1.0], &u, 1e-3), Err(SabreError::Shape { .. })));
    assert!(tank.step(&tau, &u, 0.0).is_err());
    assert!(EnergyTank::new(1.0, 2.0, None, false).is_err());
    assert!(EnergyTank::new(10.0, 2.0, Some(5.0), false).is_err());
}

#[test]
fn solver_failure_falls_back_to_the_safe_stop_and_is_counted() {
    let scene = scene();
    // One interior-point iteration cannot converge: every solver call must take the fallback.
    let config = SafetyConfig {
        max_iterations: 1,
        ..SafetyConfig::default()
    };
    let mut f = SafetyFilter::new(scene.clone(), config).unwrap();
    let mut x = scene.default_state();
    let j4 = joint(&scene, "panda_joint4");
    x[j4] = -0.08; // 1 cm from the upper limit
    let mut u_ref = vec![0.0; 10];
    u_ref[j4] = 2.0;
    let out = f.filter(&x, &u_ref, None).unwrap();
    assert_eq!(out.status, FilterStatus::Fallback);
    assert!(out.u.iter().all(|&u| u == 0.0));
    assert!(out.qp_rows > 0);
    assert_eq!(f.stats().fallbacks, 1);
    // A command the projection already makes safe needs no solver, so it cannot fail.
    let out = f.filter(&scene.default_state(), &[0.01; 10], None).unwrap();
    assert_eq!(out.status, FilterStatus::Solved);
    assert_eq!(f.stats().fallbacks, 1);
    assert_eq!(f.stats().calls, 2);
}

#[test]
fn joint_limit_is_approached_no_faster_than_the_barrier_allows() {
    let scene = scene();
    let mut f = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let j4 = joint(&scene, "panda_joint4");
    let upper = scene.robot_limits()[j4].upper;
    let mut x = scene.default_state();
    x[j4] = upper - 0.05;
    let mut u_ref = vec![0.0; 10];
    u_ref[j4] = 2.0;
    let out = f.filter(&x, &u_ref, None).unwrap().clone();
    assert!(out.u[j4] < 2.0 && out.u[j4] > 0.0, "{}", out.u[j4]);
    let name = f.constraint_name(out.active[0]);
    assert_eq!(name, "joint_limit:panda_joint4");
    assert!(out.class_slack[ConstraintClass::JointLimits.index()] > 0.0);
    // Beyond the limit the filter drives the joint back in.
    x[j4] = upper + 0.02;
    let out = f.filter(&x, &u_ref, None).unwrap();
    assert!(out.u[j4] < 0.0, "{}", out.u[j4]);
}

#[test]
fn sequential_filter_keeps_the_rollout_inside_limits_the_raw_sequence_violates() {
    let scene = scene();
    let model = RolloutModel::new(scene.clone(), RolloutConfig::default()).unwrap();
    let mut f = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let (nq, nx, k) = (scene.nq(), scene.nx(), 66);
    let j4 = joint(&scene, "panda_joint4");
    let upper = scene.robot_limits()[j4].upper;
    let mut x0 = scene.default_state();
    x0[j4] = upper - 0.4;
    x0[0] = 1.6; // base 0.4 m from the box edge
    let mut u = vec![0.0; k * nq];
    for step in 0..k {
        u[step * nq + j4] = 1.5; // 1.5 rad/s for 1 s: 1.1 rad past the limit
        u[step * nq] = 0.8; // 0.8 m/s for 1 s: 0.4 m past the box
    }
    let raw = model.rollout(&x0, &u, 1, k, Some(1)).unwrap();
    let raw_q4 = (0..=k).map(|s| raw.states[s * nx + j4]).fold(f64::MIN, f64::max);
    let raw_x = (0..=k).map(|s| raw.states[s * nx]).fold(f64::MIN, f64::max);
    // The model's joints stop hard at their limits; unfiltered, joint 4 runs into the stop.
    assert!(raw_q4 >= upper - 1e-9, "{raw_q4}");
    assert!(raw_x > 2.0, "{raw_x}");
    let out = f.filter_sequence(&model, &x0, &u).unwrap();
    assert_eq!(out.k, k);
    assert_eq!(out.fallbacks, 0);
    assert_eq!(&out.states[..nx], &x0[..]);
    for s in 0..=k {
        let q4 = out.states[s * nx + j4];
        let bx = out.states[s * nx];
        assert!(q4 < upper - 1e-3, "step {s}: q4 = {q4}, limit {upper}");
        assert!(bx <= 2.0, "step {s}: base x = {bx}");
    }
    // Far from the limits the filtered sequence is the raw one.
    let filtered_first = out.u[j4];
    assert!((filtered_first - 1.5).abs() < 1e-6, "{filtered_first}");
    // The filtered states are exactly a rollout of the filtered inputs.
    let replay = model.rollout(&x0, &out.u, 1, k, Some(1)).unwrap();
    for (a, b) in replay.states.iter().zip(&out.states) {
        assert!((a - b).abs() < 1e-12);
    }
}

#[test]
fn inner_loop_filters_every_step_and_keeps_the_tank() {
    let scene = scene();
    let mut plant = Plant::new(scene.clone(), PlantConfig::default()).unwrap();
    let controller = LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap();
    let filter = Arc::new(Mutex::new(SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap()));
    let tank = Arc::new(Mutex::new(EnergyTank::new(10.0, 2.0, None, true).unwrap()));
    let tau = ExternalTorque::new(scene.nq(), None, None, None).unwrap();
    let mut cascade = Cascade::new(
        Arc::new(Mutex::new(controller)),
        Some(filter.clone()),
        Some(tank.clone()),
        tau,
    )
    .unwrap();
    let (nq, nx) = (scene.nq(), scene.nx());
    let j4 = joint(&scene, "panda_joint4");
    let upper = scene.robot_limits()[j4].upper;
    let mut x0 = scene.default_state();
    x0[j4] = upper - 0.15;
    plant.reset(&x0).unwrap();
    let mut reference = vec![0.0; 10 * nq];
    for k in 0..10 {
        reference[k * nq + j4] = 1.0;
    }
    let mut trace = TrackTrace::default();
    let steps = 400;
    cascade
        .hand_over(Arc::new(Plan::new(reference, nq, 0.0, 0.015).unwrap()), None)
        .unwrap();
    cascade.follow(&mut plant, steps, 1, &mut trace).unwrap();
    let (filter, tank) = (filter.lock().unwrap(), tank.lock().unwrap());
    assert_eq!(trace.filtered.len(), steps * nq);
    assert_eq!(trace.tank_energy.len(), steps);
    assert_eq!(trace.filter_status.len(), steps);
    assert_eq!(filter.stats().calls, steps as u64);
    assert!(trace.filter_status.iter().all(|s| *s != FilterStatus::Fallback));
    // The reference asks for 1 rad/s into the limit for 0.4 s; the filtered command brakes.
    let last = &trace.filtered[(steps - 1) * nq..];
    assert!(last[j4] < 0.2, "{}", last[j4]);
    for s in 0..steps {
        assert!(trace.state[s * nx + j4] < upper, "step {s}");
    }
    // No contact, no exchange with the tank.
    assert!(trace.tank_energy.iter().all(|&e| (e - 10.0).abs() < 1e-9));
    assert_eq!(tank.history().len(), steps + 1);
}

#[test]
fn obstacles_are_added_moved_and_removed_in_fixed_slots() {
    let scene = scene();
    let mut f = SafetyFilter::new(
        scene.clone(),
        SafetyConfig {
            max_obstacles: 2,
            ..SafetyConfig::default()
        },
    )
    .unwrap();
    let rows_before = f.num_rows();
    let a = f.add_obstacle([1.0, 0.0, 1.0], 0.1).unwrap();
    let b = f.add_obstacle([0.0, 1.0, 1.0], 0.1).unwrap();
    assert!(matches!(
        f.add_obstacle([0.0, 0.0, 0.0], 0.1),
        Err(SabreError::InvalidValue { .. })
    ));
    assert_eq!(f.num_rows(), rows_before, "slots are part of the fixed structure");
    let x = scene.default_state();
    let index = |f: &SafetyFilter, name: &str| f.row_names().iter().position(|n| n == name).unwrap();
    let (_, _, h) = rows(&mut f, &x, None);
    let ra = index(&f, &format!("obstacle:{a}:panda_hand"));
    let before = h[ra];
    f.move_obstacle(a, [3.0, 0.0, 1.0]).unwrap();
    let (_, _, h) = rows(&mut f, &x, None);
    assert!(h[ra] > before);
    f.remove_obstacle(a).unwrap();
    let (_, _, h) = rows(&mut f, &x, None);
    assert!(h[ra].is_nan(), "an empty slot has no barrier");
    assert!(f.remove_obstacle(a).is_err());
    assert!(f.move_obstacle(a, [0.0; 3]).is_err());
    assert_eq!(f.obstacles().map(|o| o.id).collect::<Vec<_>>(), vec![b]);
    let c = f.add_obstacle([2.0, 2.0, 1.0], 0.3).unwrap();
    assert!(c > b, "ids are never reused");
    assert!(f.add_obstacle([0.0, 0.0, f64::NAN], 0.1).is_err());
    assert!(f.add_obstacle([0.0, 0.0, 0.0], -0.1).is_err());
}

#[test]
fn classes_can_be_switched_off_and_bad_input_is_an_error() {
    let scene = scene();
    let mut config = SafetyConfig::default();
    config.enabled.set(ConstraintClass::Obstacles, false);
    config.enabled.set(ConstraintClass::BaseBox, false);
    let mut f = SafetyFilter::new(scene.clone(), config).unwrap();
    let names = f.row_names();
    assert!(
        !names.iter().any(|n| n.starts_with("obstacle") || n.starts_with("base_box")),
        "{names:?}"
    );
    assert_eq!(names.len(), 10 + 3 + 1 + 1);
    assert!(f.add_obstacle([0.0; 3], 0.1).is_err());
    let x = scene.default_state();
    assert!(matches!(f.filter(&x[..5], &[0.0; 10], None), Err(SabreError::Shape { .. })));
    assert!(matches!(f.filter(&x, &[0.0; 9], None), Err(SabreError::Shape { .. })));
    let mut bad = x.clone();
    bad[3] = f64::NAN;
    assert!(matches!(
        f.filter(&bad, &[0.0; 10], None),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(matches!(
        f.filter(&x, &[f64::INFINITY; 10], None),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(matches!(
        f.filter(&x, &[0.0; 10], Some((&[0.0; 3], 5.0))),
        Err(SabreError::Shape { .. })
    ));
    assert!(matches!(
        f.filter(&x, &[0.0; 10], Some((&[0.0; 10], f64::NAN))),
        Err(SabreError::InvalidValue { .. })
    ));
    assert_eq!(f.stats().calls, 0, "rejected calls are not counted");
    let mut config = SafetyConfig::default();
    config.gamma.set(ConstraintClass::JointLimits, -1.0);
    assert!(SafetyFilter::new(scene.clone(), config).is_err());
    assert!(SafetyFilter::new(
        scene.clone(),
        SafetyConfig {
            base_box: [1.0, -1.0, -2.0, 2.0],
            ..SafetyConfig::default()
        }
    )
    .is_err());
    let model = RolloutModel::new(scene.clone(), RolloutConfig::default()).unwrap();
    assert!(f.filter_sequence(&model, &x, &[0.0; 15]).is_err());
    assert!(f.filter_sequence(&model, &x, &[]).is_err());
}

/// M = (I + λJ_wᵀJ_w) / (1 + λσ²_max(J_w)) of the grasp frame, computed here from the scene's Jacobian.
fn task_metric(scene: &Scene, q: &[f64], weight: f64) -> nalgebra::DMatrix<f64> {
    let mut j = scene.jacobian(q, "grasp").unwrap();
    for r in 3..6 {
        for c in 0..scene.nq() {
            j[(r, c)] *= sabre::safety::TASK_ANGULAR_LENGTH;
        }
    }
    let sigma2 = (&j * j.transpose()).symmetric_eigenvalues().max();
    (nalgebra::DMatrix::identity(scene.nq(), scene.nq()) + weight * j.transpose() * &j) / (1.0 + weight * sigma2)
}

#[test]
fn task_metric_solutions_meet_the_weighted_optimality_conditions() {
    let scene = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let config = SafetyConfig {
        task_weight: 100.0,
        ..SafetyConfig::default()
    };
    for screening in [false, true] {
        let mut f = filter_with_obstacles(
            &scene,
            SafetyConfig {
                screening,
                ..config.clone()
            },
            &mut rng,
        );
        let nq = scene.nq();
        let v = f.input_limits().to_vec();
        let gamma = penalties(&f);
        for trial in 0..40 {
            let x = random_state(&scene, &mut rng);
            let u_ref = random_command(&scene, &mut rng);
            let holds = f.stats().hard_limit_holds;
            let out = f.filter(&x, &u_ref, None).unwrap().clone();
            assert_ne!(out.status, FilterStatus::Fallback);
            if f.stats().hard_limit_holds > holds {
                continue; // the hard-limit guard changed the QP's command after the fact
            }
            let (a, b, _) = rows(&mut f, &x, None);
            let m = task_metric(&scene, &x[..nq], 100.0);
            // Stationarity in the metric: g = M(u − u_ref) − Σ λ_r a_r, λ_r = Γ_r δ_r.
            let d = nalgebra::DVector::from_iterator(nq, out.u.iter().zip(&u_ref).map(|(u, r)| u - r));
            let mut g: Vec<f64> = (&m * d).iter().copied().collect();
            for r in 0..b.len() {
                let lambda = gamma[r] * out.slack[r];
                let row = &a[r * nq..(r + 1) * nq];
                assert!(dot(row, &out.u) + out.slack[r] >= b[r] - 1e-6, "trial {trial}: row {r}");
                g.iter_mut().zip(row).for_each(|(gi, ai)| *gi -= lambda * ai);
            }
            for j in 0..nq {
                // The metric's small eigenvalues (1 / (1 + λσ²)) leave interior-point iterates up to
                // ~1e-4 inside a bound they press against.
                let tol = 1e-4;
                if out.u[j] >= v[j] - 1e-4 {
                    assert!(
                        g[j] <= tol,
                        "trial {trial} (screening {screening}): upper bound of {j}: {}",
                        g[j]
                    );
                } else if out.u[j] <= -v[j] + 1e-4 {
                    assert!(
                        g[j] >= -tol,
                        "trial {trial} (screening {screening}): lower bound of {j}: {}",
                        g[j]
                    );
                } else {
                    assert!(
                        g[j].abs() <= tol,
                        "trial {trial} (screening {screening}, {:?} {:?}, rows {}): stationarity of {j}: {} at u {} of {}",
                        out.method,
                        out.status,
                        out.qp_rows,
                        g[j],
                        out.u[j],
                        v[j]
                    );
                }
            }
        }
    }
}

#[test]
fn task_metric_meets_a_constraint_by_moving_the_hand_less() {
    // Joint 4 pressed against its limit while the command also moves the hand: the paper's metric
    // takes the correction out of joint 4 alone; the task metric moves other joints too, so that the
    // hand's velocity changes less, and both meet the row.
    let scene = scene();
    let nq = scene.nq();
    let j4 = joint(&scene, "panda_joint4");
    let mut x = scene.default_state();
    x[j4] = scene.robot_limits()[j4].upper - 0.01;
    let mut u_ref = vec![0.0; nq];
    u_ref[j4] = 1.0;
    u_ref[0] = 0.2;
    let jac = scene.jacobian(&x[..nq], "grasp").unwrap();
    let hand_change = |u: &[f64]| {
        let d = nalgebra::DVector::from_iterator(nq, u.iter().zip(&u_ref).map(|(a, b)| a - b));
        (jac.rows(0, 3) * d).norm()
    };
    let mut results = Vec::new();
    for weight in [0.0, 100.0] {
        let mut f = SafetyFilter::new(
            scene.clone(),
            SafetyConfig {
                task_weight: weight,
                ..SafetyConfig::default()
            },
        )
        .unwrap();
        let out = f.filter(&x, &u_ref, None).unwrap().clone();
        assert!(
            out.active.iter().any(|&i| f.constraint_name(i) == "joint_limit:panda_joint4"),
            "{weight}"
        );
        assert!(out.u[j4] < 0.5, "weight {weight}: joint 4 still driven at {}", out.u[j4]);
        results.push(hand_change(&out.u));
    }
    assert!(
        results[1] < 0.5 * results[0],
        "hand velocity change: paper {} vs task metric {}",
        results[0],
        results[1]
    );
}

#[test]
fn the_sequence_uses_its_own_task_weight_and_single_calls_theirs() {
    let scene = scene();
    let paper = SafetyConfig {
        sequential_task_weight: 0.0,
        ..SafetyConfig::default()
    };
    assert_eq!(SafetyConfig::default().task_weight, 0.0);
    assert!(SafetyConfig::default().sequential_task_weight > 0.0);
    let model = RolloutModel::new(scene.clone(), RolloutConfig::default()).unwrap();
    let nq = scene.nq();
    let j4 = joint(&scene, "panda_joint4");
    let mut x0 = scene.default_state();
    x0[j4] = scene.robot_limits()[j4].upper - 0.01;
    let mut u = vec![0.0; 3 * nq];
    for s in 0..3 {
        u[s * nq + j4] = 1.0;
        u[s * nq] = 0.2;
    }
    let mut weighted = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let mut plain = SafetyFilter::new(scene.clone(), paper).unwrap();
    // Single calls: both the paper's metric, the same command.
    let a = weighted.filter(&x0, &u[..nq], None).unwrap().u.clone();
    let b = plain.filter(&x0, &u[..nq], None).unwrap().u.clone();
    assert!(a.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-9));
    // In a sequence the default weights the first step differently.
    let sa = weighted.filter_sequence(&model, &x0, &u).unwrap();
    let sb = plain.filter_sequence(&model, &x0, &u).unwrap();
    let first = (0..nq).map(|j| (sa.u[j] - sb.u[j]).abs()).fold(0.0, f64::max);
    assert!(first > 1e-3, "{first}");
    // and the single calls afterwards are the paper's again
    let c = weighted.filter(&x0, &u[..nq], None).unwrap().u.clone();
    assert!(c.iter().zip(&b).all(|(p, q)| (p - q).abs() < 1e-9));
}
