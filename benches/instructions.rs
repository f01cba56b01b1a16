//! A fixed amount of planning work to count instructions under callgrind: planning iterations of
//! the closed loop's recorded open phase on the shelf (the `open_phase` case of the planning
//! bench), each from the same planner state.
//!
//!     cargo bench --bench instructions --no-run   # prints the binary's path
//!     valgrind --tool=callgrind --toggle-collect='*Mppi*iterate*' --toggle-collect='*rollout_into*' \
//!         target/release/deps/instructions-<hash> 3 [rollouts] [threads]
//!
//! Arguments: iterations (5), rollouts (40), threads (1). It prints the wall time per iteration
//! and a checksum of the last iteration's result (mean and least cost, the nominal plan's sum),
//! which a change meant to leave the numbers alone keeps to the bit.

#[path = "common/open_phase.rs"]
mod open_phase;

use std::sync::Arc;
use std::time::Instant;

use open_phase::open_phase;
use sabre::model::Scene;
use sabre::mppi::{Mppi, MppiConfig};
use sabre::sim::{RolloutConfig, RolloutModel};

fn main() {
    // `cargo bench` passes its own flags (--bench); the numbers are ours.
    let numbers: Vec<usize> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .map(|a| a.parse().expect("iterations, rollouts and threads are counts"))
        .collect();
    let iterations = numbers.first().copied().unwrap_or(5);
    let rollouts = numbers.get(1).copied().unwrap_or(40);
    let threads = numbers.get(2).copied().unwrap_or(1);
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let model = Arc::new(RolloutModel::new(scene.clone(), RolloutConfig::default()).expect("model"));
    let open = open_phase(&scene);
    let mut config = MppiConfig::paper_defaults(scene.nu());
    config.threads = Some(threads);
    config.rollouts = rollouts;
    let seed = config.seed;
    let mut mppi = Mppi::new(model, config).expect("sampler");
    let start = Instant::now();
    for _ in 0..iterations {
        mppi.reset(seed, open.nominal_t0);
        mppi.set_nominal(&open.nominal, open.nominal_t0).expect("plan");
        mppi.set_noise_scale(open.noise_scale).expect("noise scale");
        mppi.set_guides(&open.guides).expect("guides");
        mppi.iterate(&open.x0, open.t, &open.cost).expect("iteration");
    }
    let elapsed = start.elapsed().as_secs_f64();
    let stats = mppi.stats();
    let nominal: f64 = mppi.nominal().iter().sum();
    println!(
        "{iterations} iterations of N = {rollouts} on {threads} thread(s): {:.2} ms each",
        1e3 * elapsed / iterations.max(1) as f64
    );
    println!("checksum {:?} {:?} {:?}", stats.cost_mean, stats.cost_min, nominal);
}
