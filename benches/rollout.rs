//! Criterion bench of the rollout kernel on the shelf scene, both contact paths (the reduced one and
//! Rapier's pipeline): a batch of N = 40 rollouts × K = 66 steps on 1 and 2 threads, one step in
//! contact, and a world's reset.
//!
//! Batch throughput is reported in elements per second, one element being one simulation step of one
//! rollout. Two batches: free motion (seeded random joint velocities from the default state) and in
//! contact (the hook on the shelf handle, pulling; state and commands from
//! `benches/data/shelf_hooked.json`). The step is the first of that pull, from a freshly reset world;
//! the reset is what every rollout does before its first step (restore the pristine world, place it).

use std::sync::Arc;

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::model::Scene;
use sabre::sim::{ContactModel, RolloutConfig, RolloutModel};

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

const MODELS: [(&str, ContactModel); 2] = [("reduced", ContactModel::Reduced), ("rapier", ContactModel::Rapier)];

fn model(scene: &Arc<Scene>, contact_model: ContactModel) -> RolloutModel {
    RolloutModel::new(
        scene.clone(),
        RolloutConfig {
            contact_model,
            ..RolloutConfig::default()
        },
    )
    .expect("rollout model")
}

fn rollout(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let mut group = c.benchmark_group("rollout_shelf_40x66");
    group.throughput(Throughput::Elements((N * K) as u64));
    group.sample_size(30);
    for (label, contact_model) in MODELS {
        let model = model(&scene, contact_model);
        for (name, x0, u) in batches(&scene) {
            for threads in [1usize, 2] {
                group.bench_with_input(
                    BenchmarkId::new(format!("{name}/{label}"), format!("{threads}_threads")),
                    &threads,
                    |b, &threads| b.iter(|| model.rollout(&x0, &u, N, K, Some(threads)).expect("rollout")),
                );
            }
        }
    }
    group.finish();
}

fn step_and_reset(c: &mut Criterion) {
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"));
    let (_, x_hooked, u) = batches(&scene).pop().expect("the in-contact batch");
    let first = &u[..scene.nq()];
    let mut group = c.benchmark_group("world_shelf");
    for (label, contact_model) in MODELS {
        let model = model(&scene, contact_model);
        let mut world = model.new_world();
        let mut x = x_hooked.clone();
        group.bench_function(BenchmarkId::new("step_in_contact", label), |b| {
            b.iter_batched_ref(
                || {
                    let mut w = world.clone();
                    model.reset_world(&mut w, &x_hooked).expect("reset");
                    w
                },
                |w| w.step_once(first, &mut x),
                BatchSize::SmallInput,
            )
        });
        group.bench_function(BenchmarkId::new("reset", label), |b| {
            b.iter(|| model.reset_world(&mut world, &x_hooked).expect("reset"))
        });
    }
    group.finish();
}

criterion_group!(benches, rollout, step_and_reset);
criterion_main!(benches);
