//! Criterion bench of the rollout kernel: the shelf scene, N = 40 rollouts × K = 66 steps, 1 and 2 threads.
//!
//! Throughput is reported in elements per second, one element being one simulation step of one rollout.
//! Two batches: free motion (seeded random joint velocities from the default state) and in contact (the
//! hook on the shelf handle, pulling; state and commands from `benches/data/shelf_hooked.json`).

use std::sync::Arc;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::model::Scene;
use sabre::sim::{RolloutConfig, RolloutModel};

const N: usize = 40;
const K: usize = 66;

fn batches(scene: &Scene) -> Vec<(&'static str, Vec<f64>, Vec<f64>)> {
    let nq = scene.nq();
    let limits = scene.robot_limits();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let free: Vec<f64> = (0..N * K * nq)
        .map(|i| {
            let v: f64 = rng.random_range(-0.3..0.3);
            v.clamp(-limits[i % nq].velocity, limits[i % nq].velocity)
        })
        .collect();

    let data: serde_json::Value =
        serde_json::from_str(include_str!("data/shelf_hooked.json")).expect("benches/data/shelf_hooked.json is valid JSON");
    let x_hooked: Vec<f64> = data["x0"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let nominal: Vec<f64> = data["U"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|row| {
            row.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect::<Vec<_>>()
        })
        .collect();
    let contact: Vec<f64> = (0..N)
        .flat_map(|_| nominal.iter().map(|&u| u + rng.random_range(-0.02..0.02)).collect::<Vec<_>>())
        .collect();
    vec![
        ("free_motion", scene.default_state(), free),
        ("in_contact", x_hooked, contact),
    ]
}

fn rollout(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let model = RolloutModel::new(scene.clone(), RolloutConfig::default()).expect("rollout model");
    let mut group = c.benchmark_group("rollout_shelf_40x66");
    group.throughput(Throughput::Elements((N * K) as u64));
    group.sample_size(30);
    for (name, x0, u) in batches(&scene) {
        for threads in [1usize, 2] {
            group.bench_with_input(
                BenchmarkId::new(name, format!("{threads}_threads")),
                &threads,
                |b, &threads| b.iter(|| model.rollout(&x0, &u, N, K, Some(threads)).expect("rollout")),
            );
        }
    }
    group.finish();
}

criterion_group!(benches, rollout);
criterion_main!(benches);
