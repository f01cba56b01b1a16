//! Criterion bench of one planning iteration (sample, 40 × 67-step rollouts with the cost, update) on
//! 1 and 2 threads, on the shelf: the approach-phase cost from the default state (free space); the
//! open-phase cost from the hook on the handle (in contact; `benches/data/shelf_hooked.json`); and
//! the closed loop's own iteration while it pulls the door open (`open_phase`: state, plan, guides,
//! noise and the task's full cost recorded from the `make demo` episode by
//! `benches/capture_open_phase.py`). Every timed iteration starts from the same planner state, so
//! each does the same work: repeated iterations from one state otherwise let the plan drift into
//! harder or softer contact, and the time with it. After each case a line gives, from the planner's
//! statistics, how much of the rollout workers' time went into the contact step.

#[path = "common/open_phase.rs"]
mod open_phase;

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use nalgebra::Isometry3;
use open_phase::{floats, open_phase};
use sabre::cost::{Cost, PoseTarget, Term};
use sabre::model::Scene;
use sabre::mppi::{IterationStats, Mppi, MppiConfig};
use sabre::sim::{RolloutConfig, RolloutModel};

fn approach_cost(scene: &Scene) -> Cost {
    let limits = scene.robot_limits();
    Cost::new(vec![
        Term::TargetPose {
            link: scene.robot.link_id("grasp").expect("grasp frame"),
            target: PoseTarget::ObjectLink {
                link: scene.object.link_id("handle_frame").expect("handle frame"),
                offset: Isometry3::translation(0.0, -0.022, -0.12),
                lead: 0.0,
                lead_limit: f64::INFINITY,
            },
            weights: [100.0; 6],
        },
        Term::Contact { weight: 100.0 },
        Term::JointLimits {
            weight: 1000.0,
            weight_slope: 100.0,
            lower: limits.iter().map(|l| l.lower).collect(),
            upper: limits.iter().map(|l| l.upper).collect(),
        },
        Term::SelfCollision {
            pairs: scene.sphere_pairs.clone(),
            weight: 1000.0,
            weight_slope: 100.0,
        },
        Term::Power {
            weight: 10.0,
            p_max: 0.0,
        },
    ])
}

/// The open phase: pull on the bar from the pocket and drive the door toward 1.18 rad.
fn open_cost(scene: &Scene) -> Cost {
    let mut terms = approach_cost(scene).terms;
    terms[0] = Term::TargetPose {
        link: scene.robot.link_id("grasp").expect("grasp frame"),
        target: PoseTarget::ObjectLink {
            link: scene.object.link_id("handle_frame").expect("handle frame"),
            offset: Isometry3::translation(0.0, 0.003, -0.016),
            lead: 0.0,
            lead_limit: f64::INFINITY,
        },
        weights: [100.0, 10000.0, 1000.0, 1000.0, 1000.0, 1000.0],
    };
    terms[1] = Term::ObjectState {
        target: vec![1.18],
        weights: vec![100.0],
    };
    Cost::new(terms)
}

fn hooked_state() -> Vec<f64> {
    let data: serde_json::Value =
        serde_json::from_str(include_str!("data/shelf_hooked.json")).expect("benches/data/shelf_hooked.json is valid JSON");
    floats(&data["x0"])
}

/// Iterations from the bench state before timing, so the plan is a converged one, not zeros.
const WARM_ITERATIONS: usize = 20;

/// What the timed iterations spent where, from the planner's own statistics: the physics engine's
/// share is the floor below which sabre's work around it cannot take an iteration.
#[derive(Default)]
struct Breakdown {
    iterations: u32,
    iteration: f64,
    rollout: f64,
    engine: f64,
    engine_steps: u64,
}

impl Breakdown {
    fn add(&mut self, stats: &IterationStats) {
        self.iterations += 1;
        self.iteration += stats.iteration_time;
        self.rollout += stats.rollout_time;
        self.engine += stats.engine_time;
        self.engine_steps += stats.engine_steps;
    }

    fn report(&self, case: &str, threads: usize) {
        if self.iterations == 0 || self.engine_steps == 0 {
            println!("{case}/{threads}_threads: every step skipped as quiescent, none through the contact step");
            return;
        }
        let n = f64::from(self.iterations);
        let workers = threads as f64 * self.rollout;
        println!(
            "{case}/{threads}_threads: mean iteration {:.2} ms, rollouts {:.2} ms; contact step {:.1} % of the workers' time \
             ({:.2} ms per worker per iteration, {:.1} µs per contact step, {:.0} contact steps per iteration)",
            1e3 * self.iteration / n,
            1e3 * self.rollout / n,
            100.0 * self.engine / workers,
            1e3 * self.engine / (n * threads as f64),
            1e6 * self.engine / self.engine_steps as f64,
            self.engine_steps as f64 / n,
        );
    }
}

fn planning(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let model = Arc::new(RolloutModel::new(scene.clone(), RolloutConfig::default()).expect("model"));
    let mut group = c.benchmark_group("planning_iteration_shelf_40x67");
    group.sample_size(40);
    for (name, x0, cost) in [
        ("free", scene.default_state(), approach_cost(&scene)),
        ("in_contact", hooked_state(), open_cost(&scene)),
    ] {
        for threads in [1usize, 2] {
            let mut config = MppiConfig::paper_defaults(scene.nu());
            config.threads = Some(threads);
            let seed = config.seed;
            let mut mppi = Mppi::new(model.clone(), config).expect("sampler");
            // The controller's open phase samples with Σ × 0.01 (OpenObject.noise_open).
            if name == "in_contact" {
                mppi.set_noise_scale(0.01).expect("noise scale");
            }
            let noise = mppi.noise_scale();
            let mut t = 0.0;
            for _ in 0..WARM_ITERATIONS {
                t += 0.01;
                mppi.iterate(&x0, t, &cost).expect("warm-up iteration");
            }
            let (plan, plan_t0) = (mppi.nominal().to_vec(), mppi.nominal_t0());
            let mut breakdown = Breakdown::default();
            group.bench_with_input(BenchmarkId::new(name, format!("{threads}_threads")), &threads, |b, _| {
                b.iter_custom(|iterations| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iterations {
                        mppi.reset(seed, plan_t0);
                        mppi.set_nominal(&plan, plan_t0).expect("plan");
                        mppi.set_noise_scale(noise).expect("noise scale");
                        let start = Instant::now();
                        let stats = mppi.iterate(&x0, t + 0.01, &cost).expect("iteration");
                        total += start.elapsed();
                        breakdown.add(stats);
                    }
                    total
                })
            });
            breakdown.report(name, threads);
        }
    }
    let open = open_phase(&scene);
    for threads in [1usize, 2] {
        let mut config = MppiConfig::paper_defaults(scene.nu());
        config.threads = Some(threads);
        let seed = config.seed;
        let mut mppi = Mppi::new(model.clone(), config).expect("sampler");
        let mut breakdown = Breakdown::default();
        group.bench_with_input(
            BenchmarkId::new("open_phase", format!("{threads}_threads")),
            &threads,
            |b, _| {
                b.iter_custom(|iterations| {
                    let mut total = Duration::ZERO;
                    for _ in 0..iterations {
                        mppi.reset(seed, open.nominal_t0);
                        mppi.set_nominal(&open.nominal, open.nominal_t0).expect("plan");
                        mppi.set_noise_scale(open.noise_scale).expect("noise scale");
                        mppi.set_guides(&open.guides).expect("guides");
                        let start = Instant::now();
                        let stats = mppi.iterate(&open.x0, open.t, &open.cost).expect("iteration");
                        total += start.elapsed();
                        breakdown.add(stats);
                    }
                    total
                })
            },
        );
        breakdown.report("open_phase", threads);
    }
    group.finish();
}

criterion_group!(benches, planning);
criterion_main!(benches);
