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
