//! The safety filter's FILTER-QP, checked against something independent of Clarabel: the rows' own
//! definition, optimality conditions rebuilt from the returned primal, a projected-gradient solution
//! of the same problem, finite differences of h, and the cost terms' notion of violation.
#![allow(clippy::needless_range_loop)] // index loops name the joint in each failure message

mod safety_fixtures;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::cost::{Cost, StepView, Term};
use sabre::model::kinematics::Frames;
use sabre::model::{LimitBound, LimitBoundConfig};
use sabre::safety::{FilterStatus, SafetyConfig, SafetyFilter, SolveMethod};
use safety_fixtures::*;

#[test]
fn random_states_meet_input_limits_exactly_and_every_row_up_to_its_slack() {
    let scene = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut screened = filter_with_obstacles(&scene, SafetyConfig::default(), &mut rng);
    let mut rng_full = ChaCha8Rng::seed_from_u64(11);
    let mut full = filter_with_obstacles(
        &scene,
        SafetyConfig {
            screening: false,
            ..SafetyConfig::default()
        },
        &mut rng_full,
    );
    let nq = scene.nq();
    let v = screened.input_limits().to_vec();
    let mut solver_calls = 0;
    for _ in 0..400 {
        let x = random_state(&scene, &mut rng);
        let u_ref = random_command(&scene, &mut rng);
        let tau: Vec<f64> = (0..nq).map(|_| rng.random_range(-5.0..5.0)).collect();
        let energy = rng.random_range(1.5..10.0);
        let out = screened.filter(&x, &u_ref, Some((&tau, energy))).expect("filter").clone();
        assert_ne!(out.status, FilterStatus::Fallback, "at {x:?}");
        solver_calls += usize::from(out.qp_rows > 0);
        for j in 0..nq {
            assert!(out.u[j].abs() <= v[j] + 1e-9, "input limit {j}: {} > {}", out.u[j], v[j]);
        }
        let (a, b, _) = rows(&mut screened, &x, Some((&tau, energy)));
        for r in 0..b.len() {
            let lhs = dot(&a[r * nq..(r + 1) * nq], &out.u) + out.slack[r];
            assert!(
                lhs >= b[r] - 1e-6,
                "row {} violated: {lhs} < {}",
                screened.constraint_name(r),
                b[r]
            );
            assert!(out.slack[r] >= 0.0);
        }
        // The full problem (no screening) has the same solution, to the solver's accuracy: about
        // 1e-9 in general, up to ~1e-5 where a bound is active with a vanishing multiplier
        // (degenerate), where interior-point iterates stop short of the bound.
        let reference = full.filter(&x, &u_ref, Some((&tau, energy))).expect("filter");
        for j in 0..nq {
            assert!(
                (reference.u[j] - out.u[j]).abs() < 1e-4,
                "screened and full QP differ in u[{j}]: {} vs {}",
                out.u[j],
                reference.u[j]
            );
        }
    }
    assert!(
        solver_calls > 300,
        "the random states should mostly need the solver, got {solver_calls}"
    );
    assert_eq!(screened.stats().calls, 400);
    assert_eq!(screened.stats().fallbacks, 0);
}

#[test]
fn a_safe_command_far_from_every_limit_comes_back_unchanged() {
    let scene = scene();
    for screening in [false, true] {
        let mut f = SafetyFilter::new(
            scene.clone(),
            SafetyConfig {
                screening,
                ..SafetyConfig::default()
            },
        )
        .unwrap();
        f.add_obstacle([3.0, 3.0, 1.0], 0.2).unwrap();
        let x = scene.default_state();
        let u_ref = [0.1, -0.1, 0.05, 0.2, -0.2, 0.1, 0.1, -0.1, 0.2, 0.1];
        // Small τ_ext and a full tank: the passivity row is far from binding too.
        let tau = [0.1; 10];
        let out = f.filter(&x, &u_ref, Some((&tau, 10.0))).unwrap().clone();
        assert_eq!(out.status, FilterStatus::Solved);
        for j in 0..10 {
            assert!(
                (out.u[j] - u_ref[j]).abs() < 1e-6,
                "screening={screening}: u[{j}] {} vs {}",
                out.u[j],
                u_ref[j]
            );
        }
        assert!(out.active.is_empty(), "screening={screening}: {:?}", out.active);
        assert!(out.slack.iter().all(|&s| s < 1e-6));
        assert_eq!(out.qp_rows, if screening { 0 } else { f.num_rows() });
    }
}

#[test]
fn optimality_conditions_hold_and_match_an_independent_solution() {
    let scene = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut f = filter_with_obstacles(&scene, SafetyConfig::default(), &mut rng);
    let nq = scene.nq();
    let v = f.input_limits().to_vec();
    let gamma = penalties(&f);
    let mut checked = 0;
    for trial in 0..60 {
        let x = random_state(&scene, &mut rng);
        let u_ref = random_command(&scene, &mut rng);
        let tau: Vec<f64> = (0..nq).map(|_| rng.random_range(-5.0..5.0)).collect();
        let energy = rng.random_range(1.5..10.0);
        let out = f.filter(&x, &u_ref, Some((&tau, energy))).unwrap().clone();
        let (a, b, _) = rows(&mut f, &x, Some((&tau, energy)));
        // KKT of min ½‖u − u_ref‖² + ½ΣΓδ² s.t. a_r u + δ_r ≥ b_r, |u| ≤ v, from the primal alone:
        // ∂/∂δ_r gives the multiplier λ_r = Γ_r δ_r ≥ 0; complementarity: λ_r > 0 ⇒ the row is tight;
        // ∂/∂u: g = u − u_ref − Σ λ_r a_r must vanish off the bounds, g ≤ 0 at +v, g ≥ 0 at −v.
        let mut g: Vec<f64> = out.u.iter().zip(&u_ref).map(|(u, r)| u - r).collect();
        for r in 0..b.len() {
            let lambda = gamma[r] * out.slack[r];
            let row = &a[r * nq..(r + 1) * nq];
            let residual = dot(row, &out.u) + out.slack[r] - b[r];
            assert!(
                lambda * residual.abs() < 1e-5,
                "trial {trial}: complementarity of {}: λ {lambda}, residual {residual}",
                f.constraint_name(r)
            );
            g.iter_mut().zip(row).for_each(|(gi, ai)| *gi -= lambda * ai);
        }
        for j in 0..nq {
            // An interior-point solution sits up to ~1e-7 inside a bound it presses against.
            let tol = 1e-5;
            if out.u[j] >= v[j] - 1e-5 {
                assert!(g[j] <= tol, "trial {trial}: stationarity at the upper bound of {j}: {}", g[j]);
            } else if out.u[j] <= -v[j] + 1e-5 {
                assert!(
                    g[j] >= -tol,
                    "trial {trial}: stationarity at the lower bound of {j}: {}",
                    g[j]
                );
            } else {
                assert!(g[j].abs() <= tol, "trial {trial}: stationarity of {j}: {}", g[j]);
            }
        }
        if trial < 25 {
            let independent = projected_gradient(&a, &b, &gamma, &v, &u_ref);
            for j in 0..nq {
                assert!(
                    (independent[j] - out.u[j]).abs() < 1e-4,
                    "trial {trial}: u[{j}] {} vs projected gradient {}",
                    out.u[j],
                    independent[j]
                );
            }
        }
        checked += 1;
    }
    assert_eq!(checked, 60);
}

#[test]
fn warm_active_set_reproduces_the_full_qp_along_a_slow_trajectory() {
    // A 1 kHz-like sequence: the state creeps towards joint 4's limit and the base box edge with
    // an obstacle near the hand, the command keeps pressing. Most calls should take the
    // active-set path, and every call must match the full QP solved by Clarabel.
    let scene = scene();
    let mut fast = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    // The reference solves the full QP with Clarabel to a much tighter tolerance: where a row is
    // about to bind (multiplier and residual both near zero) an interior-point solution is only
    // accurate to about the square root of its tolerance.
    let tight = SafetyConfig {
        screening: false,
        tolerance: 1e-12,
        max_iterations: 200,
        ..SafetyConfig::default()
    };
    let mut full = SafetyFilter::new(scene.clone(), tight).unwrap();
    for f in [&mut fast, &mut full] {
        f.add_obstacle([0.85, 0.0, 0.95], 0.1).unwrap();
    }
    let j4 = joint(&scene, "panda_joint4");
    let upper = scene.robot_limits()[j4].upper;
    let mut x = scene.default_state();
    let mut u_ref = vec![0.0; 10];
    u_ref[0] = 0.9;
    u_ref[j4] = 1.2;
    u_ref[3] = 0.4;
    let tau = [0.0, 0.0, 0.0, -2.0, -2.0, 1.0, 0.5, 0.0, 0.3, 0.0];
    let mut methods = [0usize; 3];
    for k in 0..400 {
        x[0] = 1.80 + 0.0004 * k as f64;
        x[j4] = upper - 0.12 + 0.0002 * k as f64;
        u_ref[5] = 0.3 * (k as f64 * 0.01).sin();
        let energy = 2.5 - 0.001 * k as f64;
        let a = fast.filter(&x, &u_ref, Some((&tau, energy))).unwrap().clone();
        let b = full.filter(&x, &u_ref, Some((&tau, energy))).unwrap();
        assert_ne!(b.status, FilterStatus::Fallback);
        for j in 0..10 {
            assert!(
                (a.u[j] - b.u[j]).abs() < 2e-6,
                "step {k} ({:?}): u[{j}] {} vs full QP {}",
                a.method,
                a.u[j],
                b.u[j]
            );
        }
        for (sa, sb) in a.slack.iter().zip(&b.slack) {
            assert!((sa - sb).abs() < 2e-6, "step {k} ({:?}): slack {sa} vs {sb}", a.method);
        }
        methods[a.method as usize] += 1;
    }
    eprintln!("methods (projection, active set, interior point): {methods:?}");
    let active_set = methods[SolveMethod::ActiveSet as usize];
    assert!(
        active_set > 300,
        "active-set path taken {active_set} times of 400 ({methods:?})"
    );
    assert_eq!(
        fast.stats().interior_point_calls as usize,
        methods[SolveMethod::InteriorPoint as usize]
    );
}

#[test]
fn row_gradients_match_finite_differences_of_the_barriers() {
    let scene = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut f = filter_with_obstacles(&scene, SafetyConfig::default(), &mut rng);
    let nq = scene.nq();
    let eps = 1e-6;
    let mut compared = 0;
    for _ in 0..50 {
        let x = random_state(&scene, &mut rng);
        let dir: Vec<f64> = (0..nq).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (a, _, h) = rows(&mut f, &x, None);
        let shifted = |s: f64| {
            let mut y = x.clone();
            y.iter_mut().zip(&dir).for_each(|(q, d)| *q += s * d);
            y
        };
        let (_, _, h_plus) = rows(&mut f, &shifted(eps), None);
        let (_, _, h_minus) = rows(&mut f, &shifted(-eps), None);
        for r in 0..h.len() {
            if !h[r].is_finite() {
                continue; // rows switched off in this call (passivity without a tank)
            }
            let numeric = (h_plus[r] - h_minus[r]) / (2.0 * eps);
            let analytic = dot(&a[r * nq..(r + 1) * nq], &dir);
            assert!(
                (numeric - analytic).abs() < 1e-6 * (1.0 + analytic.abs()),
                "{}: ḣ {analytic} vs finite difference {numeric}",
                f.constraint_name(r)
            );
            compared += 1;
        }
    }
    // 10 joints + 3 pairs + reach + 2 box + 8 × 5 obstacle rows per state.
    assert_eq!(compared, 50 * 56);
}

#[test]
fn barriers_agree_with_the_sampler_cost_terms() {
    let scene = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let mut f = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
    let (center, radius) = ([0.6, 0.0, 0.8], 0.25);
    let id = f.add_obstacle(center, radius).unwrap();
    let names = f.row_names();
    let reach = scene.arm_reach.clone().unwrap();
    let term = |t: Term| Cost::new(vec![t]);
    let costs = [
        (
            "self_collision:",
            term(Term::SelfCollision {
                pairs: scene.sphere_pairs.clone(),
                weight: 1.0,
                weight_slope: 0.0,
            }),
        ),
        (
            "base_box:",
            term(Term::BaseBox {
                lower: [-2.0, -2.0],
                upper: [2.0, 2.0],
                weight: 1.0,
                weight_slope: 0.0,
            }),
        ),
        (
            "arm_reach",
            term(Term::ArmReach {
                base_link: reach.base_link,
                frame_link: reach.frame_link,
                r_max: reach.max,
                weight: 1.0,
                weight_slope: 0.0,
            }),
        ),
        (
            "obstacle:",
            term(Term::Obstacles {
                spheres: vec![(center.into(), radius)],
                weight: 1.0,
                weight_slope: 0.0,
            }),
        ),
    ];
    assert!(names.iter().any(|n| n == &format!("obstacle:{id}:panda_hand")), "{names:?}");
    let (mut frames, object) = (Frames::default(), Frames::default());
    let mut disagreements = 0;
    for _ in 0..400 {
        let mut x = random_state(&scene, &mut rng);
        x[0] = rng.random_range(-0.4..0.4) + if rng.random_bool(0.5) { 2.0 } else { -2.0 };
        let (_, _, h) = rows(&mut f, &x, None);
        scene
            .robot
            .update_frames(&nalgebra::Isometry3::identity(), &x[..scene.nq()], &mut frames);
        for (prefix, cost) in &costs {
            let view = StepView {
                x: &x,
                u: &[0.0; 10],
                tau_ext: &[0.0; 10],
                contact: false,
                robot: &frames,
                object: &object,
            };
            // The cost counts one unit per violated constraint; the filter's rows of that kind
            // must have exactly as many negative barriers.
            let violated_by_cost = cost.step(&scene, &view).round() as usize;
            let violated_by_rows = names
                .iter()
                .zip(&h)
                .filter(|(n, h)| n.starts_with(prefix) && **h < 0.0)
                .count();
            disagreements += usize::from(violated_by_cost != violated_by_rows);
        }
    }
    assert_eq!(disagreements, 0);
}

#[test]
fn a_box_of_allowed_commands_holds_every_component_and_keeps_the_passivity_rows_power() {
    let scene = scene();
    let (nq, alpha, floor) = (
        scene.nq(),
        SafetyConfig::default().gamma.0[5],
        SafetyConfig::default().tank_floor,
    );
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let bound = LimitBound::new(&scene, &LimitBoundConfig::default()).unwrap();
    let limits = scene.robot_limits();
    let (mut clipped, mut scaled) = (0, 0);
    for trial in 0..200 {
        // two filters with the same obstacles and no history: the same QP, the same command
        let seed = rng.random();
        let mut plain = filter_with_obstacles(&scene, SafetyConfig::default(), &mut ChaCha8Rng::seed_from_u64(seed));
        let mut boxed = filter_with_obstacles(&scene, SafetyConfig::default(), &mut ChaCha8Rng::seed_from_u64(seed));
        let x = random_state(&scene, &mut rng);
        let u_ref = random_command(&scene, &mut rng);
        let tau: Vec<f64> = (0..nq).map(|_| rng.random_range(-5.0..5.0)).collect();
        // at, above and below the tank's floor
        let energy = rng.random_range(1.0..6.0);
        let (mut lo, mut hi) = (vec![0.0; nq], vec![0.0; nq]);
        bound.velocity_box(&x[..nq], 0.001, &mut lo, &mut hi);
        for (l, h) in lo.iter_mut().zip(hi.iter_mut()) {
            // a tighter box now and then, so that many components are clipped at once
            if rng.random_bool(0.3) {
                *l *= rng.random_range(0.0..1.0);
                *h *= rng.random_range(0.0..1.0);
            }
        }
        let holds = plain.stats().hard_limit_holds;
        let free = plain.filter(&x, &u_ref, Some((&tau, energy))).unwrap().u.clone();
        // without the guard's own hold (a joint beyond its URDF limit), this is the QP's command
        let qp = plain.stats().hard_limit_holds == holds;
        let out = boxed
            .filter_within(&x, &u_ref, Some((&tau, energy)), Some((&lo, &hi)))
            .unwrap()
            .clone();
        let mut inside = true;
        for j in 0..nq {
            assert!(
                out.u[j] >= lo[j] && out.u[j] <= hi[j],
                "trial {trial}: joint {j} {} outside [{}, {}]",
                out.u[j],
                lo[j],
                hi[j]
            );
            // and never further beyond a URDF limit
            let beyond = (x[j] >= limits[j].upper && out.u[j] > 0.0) || (x[j] <= limits[j].lower && out.u[j] < 0.0);
            assert!(!beyond, "trial {trial}: joint {j} driven further beyond its limit");
            inside &= free[j] >= lo[j] && free[j] <= hi[j];
        }
        if !qp {
            continue; // the plain filter's guard changed its command: no reference for what follows
        }
        if inside {
            assert_eq!(out.u, free, "trial {trial}: a box the command lies in changes nothing");
            continue;
        }
        clipped += 1;
        // The passivity row τᵀu ≥ −α(S − ε): the boxed command achieves what the free one did or the
        // row asks, whichever is less, and never drains a tank below its floor: u = 0 moves no energy.
        let (b, free_power, power) = (-alpha * (energy - floor), dot(&tau, &free), dot(&tau, &out.u));
        let wanted = b.min(free_power).min(0.0);
        assert!(
            power >= wanted - 1e-9 * (1.0 + wanted.abs()),
            "trial {trial}: τᵀu {power} below {wanted}"
        );
        // the command is the free one clipped into the box, scaled toward the stop if the row needed it
        let clip: Vec<f64> = (0..nq)
            .map(|j| {
                let hi = if x[j] >= limits[j].upper { hi[j].min(0.0) } else { hi[j] };
                let lo = if x[j] <= limits[j].lower { lo[j].max(0.0) } else { lo[j] };
                free[j].clamp(lo, hi)
            })
            .collect();
        let peak = clip.iter().map(|c| c.abs()).fold(0.0, f64::max);
        let k = (0..nq).find(|&j| clip[j].abs() == peak).unwrap();
        let scale = if peak > 0.0 { out.u[k] / clip[k] } else { 0.0 };
        assert!((0.0..=1.0).contains(&scale), "trial {trial}: scale {scale}");
        for j in 0..nq {
            assert!(
                (out.u[j] - scale * clip[j]).abs() <= 1e-12 * (1.0 + peak),
                "trial {trial}: joint {j}"
            );
        }
        scaled += usize::from(scale < 1.0);
        // the reported slacks are those of the final command
        let (a, bounds, _) = rows(&mut boxed, &x, Some((&tau, energy)));
        for r in 0..bounds.len() {
            let deficit = (bounds[r] - dot(&a[r * nq..(r + 1) * nq], &out.u)).max(0.0);
            assert!(
                (out.slack[r] - deficit).abs() <= 1e-9 * (1.0 + deficit),
                "trial {trial}: row {r}"
            );
        }
    }
    assert!(clipped > 50 && scaled > 0, "{clipped} clipped, {scaled} scaled");
}
