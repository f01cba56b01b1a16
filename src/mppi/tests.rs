//! The sampler's update, its handling of failed rollouts and guides, and the time shift of kept samples.

use super::*;
use crate::cost::Term;
use crate::sim::rollout::tests::NON_FINITE_COMMAND;
use crate::sim::test_scene::{probe_and_drawer, state};
use crate::sim::RolloutConfig;

/// A sampler over the probe scene with `rollouts` samples, 8 steps, no smoothing.
fn sampler(rollouts: usize) -> Mppi {
    let model = Arc::new(RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model"));
    let mut config = MppiConfig::paper_defaults(2);
    config.rollouts = rollouts;
    config.horizon = 8.0 * model.dt();
    config.smoothing_window = 0;
    config.threads = Some(2);
    Mppi::new(model, config).expect("sampler")
}

/// A sampler of three (α = 0.5, g_max = 0.1, h = 2) whose batch is the nominal (zero), the zero
/// sequence and a guide, updated once with costs (1, 1, 0); and the guide.
fn updated_once_with_a_guide() -> (Mppi, Vec<f64>) {
    let mut mppi = sampler(3);
    mppi.config.step_size = 0.5;
    mppi.config.gradient_clip = 0.1;
    mppi.config.h = 2.0;
    let k = mppi.horizon_steps();
    let guide: Vec<f64> = (0..2 * k).map(|e| [0.05, 0.5, -0.05, -0.5][e % 4]).collect();
    mppi.set_guides(&guide).unwrap();
    mppi.sample(0.0);
    mppi.update(&[1.0, 1.0, 0.0]).unwrap();
    (mppi, guide)
}

#[test]
fn update_moves_the_nominal_by_the_clipped_weighted_step() {
    let (mppi, guide) = updated_once_with_a_guide();
    // (55): costs (1, 1, 0) weigh (e⁻², e⁻², 1) / (1 + 2e⁻²); only the guide differs from μ = 0.
    let w = 1.0 / (1.0 + 2.0 * (-2.0f64).exp());
    for (m, g) in mppi.nominal().iter().zip(&guide) {
        let expected = 0.5 * (w * g).clamp(-0.1, 0.1);
        assert!((m - expected).abs() < 1e-15, "{m} vs {expected}");
    }
}

#[test]
fn a_second_update_weighs_the_same_batch_again() {
    let (mut mppi, guide) = updated_once_with_a_guide();
    let first = mppi.nominal().to_vec();
    mppi.update(&[1.0, 1.0, 0.0]).unwrap();
    // The batch is still (0, 0, guide) with weights (w₀, w₀, w) summing to 1: the step is
    // clip(w g − μ₁) with μ₁ the first update's mean.
    let w = 1.0 / (1.0 + 2.0 * (-2.0f64).exp());
    for ((m, m1), g) in mppi.nominal().iter().zip(&first).zip(&guide) {
        let expected = m1 + 0.5 * (w * g - m1).clamp(-0.1, 0.1);
        assert!((m - expected).abs() < 1e-15, "{m} vs {expected}");
    }
}

#[test]
fn iteration_with_a_failed_rollout_weighs_it_zero_and_keeps_a_finite_nominal() {
    let mut mppi = sampler(6);
    let k = mppi.horizon_steps();
    let mut guide = vec![0.2; 2 * k];
    guide[2 * 2] = NON_FINITE_COMMAND;
    mppi.set_guides(&guide).unwrap();
    let cost = Cost::new(vec![Term::Posture {
        target: vec![0.5, 0.0],
        weights: vec![1.0, 1.0],
    }]);
    let x0 = state([0.0, 0.0], [0.0, 0.0], 0.0, 0.0);
    let stats = mppi.iterate(&x0, 0.0, &cost).unwrap().clone();
    assert_eq!(stats.failed_rollouts, 1);
    assert_eq!(mppi.weights()[2], 0.0);
    assert!(mppi.nominal().iter().all(|v| v.is_finite()));
    assert!(mppi.nominal().iter().any(|&v| v != 0.0));
}

#[test]
fn shifting_by_whole_and_fractional_steps() {
    let mut seq = vec![0.0, 1.0, 2.0, 3.0];
    let mut scratch = Vec::new();
    shift(&mut seq, 1, 1.0, &mut scratch);
    assert_eq!(seq, vec![1.0, 2.0, 3.0, 3.0]);
    shift(&mut seq, 1, 0.5, &mut scratch);
    assert_eq!(seq, vec![1.5, 2.5, 3.0, 3.0]);
}

/// Two iterations of a sampler of `rollouts` on `threads` from the probe scene's rest state (the
/// second batch keeps samples of the first): the policy and the last batch.
fn two_iterations(rollouts: usize, threads: usize, noise_interval: usize) -> (Vec<f64>, Vec<f64>) {
    let mut mppi = sampler(rollouts);
    mppi.config.threads = Some(threads);
    mppi.config.noise_interval = noise_interval;
    let cost = Cost::new(vec![Term::Posture {
        target: vec![0.5, 0.0],
        weights: vec![1.0, 1.0],
    }]);
    let x0 = state([0.0, 0.0], [0.0, 0.0], 0.0, 0.0);
    for t in [0.0, 0.013] {
        mppi.iterate(&x0, t, &cost).unwrap();
    }
    (mppi.nominal().to_vec(), mppi.previous.clone())
}

#[test]
fn the_batch_rolled_out_by_iterate_is_the_one_sample_builds_on_any_thread_count() {
    for interval in [1, 3] {
        let (policy, batch) = two_iterations(12, 1, interval);
        assert_eq!(
            two_iterations(12, 2, interval),
            (policy.clone(), batch.clone()),
            "interval {interval}"
        );
        let mut mppi = sampler(12);
        mppi.config.noise_interval = interval;
        let cost = Cost::new(vec![Term::Posture {
            target: vec![0.5, 0.0],
            weights: vec![1.0, 1.0],
        }]);
        let x0 = state([0.0, 0.0], [0.0, 0.0], 0.0, 0.0);
        for t in [0.0, 0.013] {
            mppi.sample(t);
            let rolled = mppi.rollout(&x0, &cost).unwrap();
            mppi.update(&rolled.costs).unwrap();
        }
        assert_eq!(mppi.nominal(), &policy[..], "interval {interval}");
        assert_eq!(mppi.previous, batch, "interval {interval}");
    }
}

/// The fresh rows' noise (sample − nominal) / σ of a sampler of `rollouts` around a zero
/// nominal, far inside the input bounds: one K × nu row each, for `batches` batches.
fn fresh_noise(rollouts: usize, noise_interval: usize, batches: usize) -> Vec<Vec<f64>> {
    let mut mppi = sampler(rollouts);
    mppi.config.noise_interval = noise_interval;
    mppi.config.keep_fraction = 0.0;
    mppi.std = vec![1e-3; 2];
    let row = mppi.horizon_steps() * 2;
    let mut rows = Vec::new();
    for b in 0..batches {
        let samples = mppi.sample(b as f64 * 0.01).to_vec();
        rows.extend(
            samples[2 * row..]
                .chunks(row)
                .map(|r| r.iter().map(|v| v / 1e-3).collect::<Vec<f64>>()),
        );
    }
    rows
}

#[test]
fn fresh_rows_are_independent_standard_normal_noise_across_rows_and_batches() {
    let rows = fresh_noise(202, 1, 2);
    let values: Vec<f64> = rows.iter().flatten().copied().collect();
    let count = values.len() as f64;
    let mean = values.iter().sum::<f64>() / count;
    let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count;
    // 6400 standard normal values: the mean's deviation is 0.0125, the variance's 0.018.
    assert!(mean.abs() < 0.05, "mean {mean}");
    assert!((variance - 1.0).abs() < 0.08, "variance {variance}");
    // Row i of one batch against row i of the next and against row i + 1 of the same batch:
    // correlations of 16 values, averaged over 200 pairs each, about 0 within 0.02.
    let correlation = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / a.len() as f64;
    let fresh = rows.len() / 2;
    let across_batches: f64 = (0..fresh).map(|i| correlation(&rows[i], &rows[fresh + i])).sum::<f64>() / fresh as f64;
    let across_rows: f64 = (0..fresh - 1).map(|i| correlation(&rows[i], &rows[i + 1])).sum::<f64>() / (fresh - 1) as f64;
    assert!(across_batches.abs() < 0.1, "across batches {across_batches}");
    assert!(across_rows.abs() < 0.1, "across rows {across_rows}");
    assert!(rows[0] != rows[fresh] && rows[0] != rows[1]);
}

#[test]
fn noise_between_knots_is_their_linear_interpolation() {
    for row in fresh_noise(5, 3, 1) {
        let steps: Vec<&[f64]> = row.chunks(2).collect();
        for s in [1, 2, 4, 5] {
            let (knot, a) = (s / 3 * 3, (s % 3) as f64 / 3.0);
            let (here, next) = (steps[knot], steps[knot + 3]);
            for ((&value, &h), &n) in steps[s].iter().zip(here).zip(next) {
                let expected = (1.0 - a) * h + a * n;
                assert!((value - expected).abs() < 1e-9, "step {s}: {value} vs {expected}");
            }
        }
    }
}
