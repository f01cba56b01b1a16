//! The sampler's settings, with the paper's Table I as defaults.

use crate::model::LimitBoundConfig;

/// Sampler settings; the defaults are the paper's Table I.
#[derive(Debug, Clone, PartialEq)]
pub struct MppiConfig {
    /// Number of rollouts N per iteration.
    pub rollouts: usize,
    /// Horizon T in seconds; K = round(T / dt) steps of the rollout model.
    pub horizon: f64,
    /// Diagonal of the sampling covariance Σ (variances, one per input).
    pub sigma: Vec<f64>,
    /// Sharpness h of the invariant likelihood mapping (55).
    pub h: f64,
    /// Step size α of the update (14).
    pub step_size: f64,
    /// Element-wise clip g_max of the gradient estimate (54).
    pub gradient_clip: f64,
    /// Fraction of the previous batch kept (the best by weight) and shifted in time.
    pub keep_fraction: f64,
    /// Savitzky–Golay window (samples) and polynomial order; a window of 0 or 1 turns smoothing off.
    pub smoothing_window: usize,
    pub smoothing_order: usize,
    /// Noise is drawn every `noise_interval` steps and linearly interpolated in between (1: white
    /// noise, the paper's sampler). Longer intervals explore joint positions much further per
    /// rollout for the same per-step variance.
    pub noise_interval: usize,
    pub seed: u64,
    /// Rollout worker threads (None: all cores).
    pub threads: Option<usize>,
    /// Symmetric bound on each commanded input (|u_i| ≤ limit_i), tighter than the joint velocity
    /// limits if given; None uses the scene's velocity limits.
    pub input_limit: Option<Vec<f64>>,
    /// The cascade's hard joint-limit bound, held by the plan handed to it
    /// ([`super::Mppi::bounded_nominal`]); None: not held.
    pub limit_bound: Option<LimitBoundConfig>,
}

impl MppiConfig {
    /// Table I defaults for `nu` inputs: Σ = 0.5 on the three base inputs, 1.0 on the arm joints.
    pub fn paper_defaults(nu: usize) -> Self {
        Self {
            rollouts: 40,
            horizon: 1.0,
            sigma: (0..nu).map(|i| if i < 3 { 0.5 } else { 1.0 }).collect(),
            h: 10.0,
            step_size: 1.0,
            gradient_clip: 0.2,
            keep_fraction: 0.3,
            smoothing_window: 30,
            smoothing_order: 3,
            noise_interval: 1,
            input_limit: None,
            limit_bound: None,
            seed: 0,
            threads: None,
        }
    }
}
