//! The MPPI-style sampler (paper Sec. III-A and V): Gaussian policy, cost-scale-invariant weights, clipped
//! gradient step, nominal and zero sequences always sampled, best samples reused, receding horizon, smoothing.

mod batch;
mod config;
pub mod guide;
mod limits;
pub mod smoothing;
pub mod weights;

use std::sync::Arc;
use std::time::Instant;

use crate::cost::Cost;
use crate::error::{ensure_finite, Result, SabreError};
use crate::model::LimitBound;
use crate::sim::{RolloutBatch, RolloutModel, MAX_BATCH_ELEMENTS};
pub use batch::interpolate;
use batch::{shift, stream_key, RowPlan};
pub use config::MppiConfig;
pub use guide::{servo_guide, servo_guides, ServoGuideConfig, ServoGuidePlan};
pub use smoothing::SavitzkyGolay;
pub use weights::{effective_sample_size, weights, LikelihoodMapping};

/// Statistics of the last iteration.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IterationStats {
    pub iteration: u64,
    /// Wall time of sampling, rollouts and update (s).
    pub iteration_time: f64,
    /// Wall time of the rollouts with their cost (s); in [`Mppi::iterate`] each worker also builds
    /// the rows it rolls out, and their time is here.
    pub rollout_time: f64,
    /// Steps of the batch that went through Rapier's pipeline (the rest were skipped as quiescent).
    pub engine_steps: u64,
    /// Time spent inside those steps, summed over the workers (s): the physics engine's own share
    /// of `rollout_time × threads`.
    pub engine_time: f64,
    pub cost_min: f64,
    pub cost_mean: f64,
    pub cost_max: f64,
    /// Cost of the unperturbed nominal sequence (sample 0).
    pub nominal_cost: f64,
    pub effective_sample_size: f64,
    pub failed_rollouts: usize,
}

/// The sampler and its policy (the nominal input sequence).
pub struct Mppi {
    model: Arc<RolloutModel>,
    config: MppiConfig,
    k: usize,
    nu: usize,
    dt: f64,
    lower: Vec<f64>,
    upper: Vec<f64>,
    std: Vec<f64>,
    /// Multiplies Σ for the fresh samples (a task's noise schedule); 1 = the configured Σ.
    noise_scale: f64,
    nominal: Vec<f64>,
    /// Time at which nominal[0] applies.
    nominal_t0: f64,
    samples: Vec<f64>,
    previous: Vec<f64>,
    previous_weights: Vec<f64>,
    previous_t0: f64,
    have_previous: bool,
    /// The last update moved the batch to `previous` (a swap); it is the current batch until the
    /// next `sample`.
    batch_in_previous: bool,
    /// Task-proposed sequences for the next batch only (M × K × nu), and guides planned for it
    /// that the rollouts' workers integrate (after those).
    guides: Vec<f64>,
    guide_plan: Option<Arc<ServoGuidePlan>>,
    weights: Vec<f64>,
    smoother: Option<SavitzkyGolay>,
    /// The random streams' key (from the seed) and the number of batches drawn since it was set:
    /// row i of batch b draws from stream b at the i-th offset.
    key: [u8; 32],
    batches: u64,
    /// The next batch's kept rows of `previous`, best first, and its fresh samples' deviations.
    kept: Vec<usize>,
    scaled_std: Vec<f64>,
    stats: IterationStats,
    scratch: Vec<f64>,
    /// The rollouts of [`Self::iterate`], reused from one iteration to the next.
    batch: RolloutBatch,
    /// The joint-limit bound the nominal holds, and the joint positions the batch was rolled out from.
    limit_bound: Option<LimitBound>,
    start: Vec<f64>,
}

/// The longest horizon in steps: the Savitzky–Golay smoother holds a K × K matrix.
pub const MAX_HORIZON_STEPS: usize = 10_000;

impl Mppi {
    pub fn new(model: Arc<RolloutModel>, config: MppiConfig) -> Result<Self> {
        let scene = model.scene().clone();
        let nu = scene.nu();
        let dt = model.dt();
        if config.rollouts < 3 {
            return Err(SabreError::invalid(
                "rollouts",
                "needs at least 3 (nominal, zero and one sample)",
            ));
        }
        if !(config.horizon.is_finite() && config.horizon >= dt) {
            return Err(SabreError::invalid("horizon", format!("must be at least one step ({dt} s)")));
        }
        if config.sigma.len() != nu {
            return Err(SabreError::shape(
                "sigma",
                format!("({nu},)"),
                format!("({},)", config.sigma.len()),
            ));
        }
        ensure_finite("sigma", &config.sigma)?;
        if config.sigma.iter().any(|&s| s < 0.0) {
            return Err(SabreError::invalid("sigma", "variances must be non-negative"));
        }
        for (name, v) in [
            ("h", config.h),
            ("step_size", config.step_size),
            ("gradient_clip", config.gradient_clip),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SabreError::invalid(name, format!("must be positive and finite, got {v}")));
            }
        }
        if !(0.0..=1.0).contains(&config.keep_fraction) {
            return Err(SabreError::invalid("keep_fraction", "must be within [0, 1]"));
        }
        // The horizon and batch come from the caller: check the sizes they imply before allocating,
        // so that an absurd configuration is an error and not an allocation failure that aborts.
        let steps = (config.horizon / dt).round();
        let n = config.rollouts;
        let nx = scene.nx();
        let k = steps as usize;
        if steps > MAX_HORIZON_STEPS as f64 {
            return Err(SabreError::invalid(
                "horizon",
                format!(
                    "{} s at dt {dt:e} s is {steps:e} steps; at most {MAX_HORIZON_STEPS} (the smoother is K × K)",
                    config.horizon
                ),
            ));
        }
        let fits = n
            .checked_mul(k + 1)
            .and_then(|v| v.checked_mul(nx.max(nu).max(6)))
            .is_some_and(|v| v <= MAX_BATCH_ELEMENTS);
        if !fits {
            return Err(SabreError::invalid(
                "rollouts × horizon",
                format!(
                    "{n} rollouts of {k} steps ({} s at dt {dt:e} s) exceed the batch limit of {MAX_BATCH_ELEMENTS} values",
                    config.horizon
                ),
            ));
        }
        let limits = scene.robot_limits();
        let mut bound: Vec<f64> = limits.iter().map(|l| l.velocity).collect();
        if let Some(limit) = &config.input_limit {
            if limit.len() != nu {
                return Err(SabreError::shape(
                    "input_limit",
                    format!("({nu},)"),
                    format!("({},)", limit.len()),
                ));
            }
            if limit.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(SabreError::invalid("input_limit", "bounds must be positive and finite"));
            }
            for (b, l) in bound.iter_mut().zip(limit) {
                *b = b.min(*l);
            }
        }
        let limit_bound = config.limit_bound.map(|c| LimitBound::new(&scene, &c)).transpose()?;
        let smoother =
            (config.smoothing_window > 1).then(|| SavitzkyGolay::new(k, config.smoothing_window, config.smoothing_order));
        Ok(Self {
            lower: bound.iter().map(|b| -b).collect(),
            upper: bound,
            std: config.sigma.iter().map(|v| v.sqrt()).collect(),
            noise_scale: 1.0,
            nominal: vec![0.0; k * nu],
            nominal_t0: 0.0,
            samples: vec![0.0; n * k * nu],
            previous: vec![0.0; n * k * nu],
            previous_weights: vec![0.0; n],
            previous_t0: 0.0,
            have_previous: false,
            batch_in_previous: false,
            guides: Vec::new(),
            guide_plan: None,
            weights: vec![0.0; n],
            smoother,
            key: stream_key(config.seed),
            batches: 0,
            kept: Vec::new(),
            scaled_std: Vec::new(),
            stats: IterationStats::default(),
            scratch: Vec::new(),
            batch: RolloutBatch::default(),
            limit_bound,
            start: Vec::new(),
            model,
            config,
            k,
            nu,
            dt,
        })
    }

    pub fn config(&self) -> &MppiConfig {
        &self.config
    }
    pub fn horizon_steps(&self) -> usize {
        self.k
    }
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn model(&self) -> &Arc<RolloutModel> {
        &self.model
    }
    pub fn stats(&self) -> &IterationStats {
        &self.stats
    }
    /// The policy mean, K × nu, row-major; row 0 applies at [`Self::nominal_t0`].
    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }
    /// The plan to hand the cascade: the nominal held to the configured joint-limit bound
    /// ([`MppiConfig::limit_bound`]) along its kinematics from the state the last batch was rolled out
    /// from, one plan step late; the nominal itself without a bound or before the first rollout. The
    /// sampler's own nominal (its mean for the next batch) stays as the update left it.
    pub fn bounded_nominal(&self) -> Vec<f64> {
        let mut plan = self.nominal.clone();
        if let Some(bound) = self.limit_bound.as_ref().filter(|_| self.start.len() == self.nu) {
            limits::bound_sequence(bound, &self.start, self.dt, &mut plan);
        }
        plan
    }
    pub fn nominal_t0(&self) -> f64 {
        self.nominal_t0
    }
    /// The port dissipation −τ_extᵀu (W) at each of the K steps of the nominal's rollout from `x`,
    /// on the calling thread: what the plan predicts for the tank's refill.
    pub fn predicted_dissipation(&self, x: &[f64]) -> Result<Vec<f64>> {
        let nu = self.nu;
        let batch = self.model.rollout(x, &self.nominal, 1, self.k, Some(1))?;
        Ok(batch
            .tau_ext
            .chunks(nu)
            .zip(self.nominal.chunks(nu))
            .map(|(tau, u)| -tau.iter().zip(u).map(|(t, v)| t * v).sum::<f64>())
            .collect())
    }
    /// The normalised weights of the last iteration's samples (N).
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Clears the policy and the sample memory; the random stream restarts from `seed`.
    pub fn reset(&mut self, seed: u64, t0: f64) {
        self.nominal.fill(0.0);
        self.nominal_t0 = t0;
        self.recall_batch();
        self.have_previous = false;
        self.clear_guides();
        self.key = stream_key(seed);
        self.batches = 0;
        self.config.seed = seed;
        self.noise_scale = 1.0;
        self.stats = IterationStats::default();
        self.start.clear();
    }

    /// Scales the sampling covariance to `scale` · Σ from the next batch on (a task's noise
    /// schedule: explore widely far from the goal, finely near it).
    pub fn set_noise_scale(&mut self, scale: f64) -> Result<()> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(SabreError::invalid(
                "noise_scale",
                format!("must be positive and finite, got {scale}"),
            ));
        }
        self.noise_scale = scale;
        Ok(())
    }

    pub fn noise_scale(&self) -> f64 {
        self.noise_scale
    }

    /// Puts `guides` (M × K × nu, row 0 applying at the time of the next [`Self::sample`]) into
    /// the next batch after the nominal and the zero sequence, in place of as many kept or fresh
    /// samples. They are rolled out and weighted like every other sample, so a bad guide costs
    /// nothing but its slot; they are used once. This is how a task proposes what it knows (a
    /// path along a moving handle, a servo step toward a pose) without bypassing the sampler.
    pub fn set_guides(&mut self, guides: &[f64]) -> Result<()> {
        let row = self.k * self.nu;
        let slots = self.config.rollouts - 2;
        if !guides.len().is_multiple_of(row) || guides.len() / row > slots {
            return Err(SabreError::shape(
                "guides",
                format!("(M, {}, {}) with M <= {slots}", self.k, self.nu),
                format!("{} elements", guides.len()),
            ));
        }
        ensure_finite("guides", guides)?;
        self.guides.clear();
        self.guides.extend_from_slice(guides);
        Ok(())
    }

    /// Puts the guides of `plan` into the next batch after those of [`Self::set_guides`], as many
    /// as the batch has slots for; each is integrated by the worker that rolls its row out, in
    /// parallel with the other rollouts. Used once, like [`Self::set_guides`].
    pub fn set_guide_plan(&mut self, plan: Arc<ServoGuidePlan>) -> Result<()> {
        if !plan.is_empty() && (plan.steps() != self.k || plan.width() != self.nu) {
            return Err(SabreError::shape(
                "guide plan",
                format!("(M, {}, {})", self.k, self.nu),
                format!("({}, {}, {})", plan.len(), plan.steps(), plan.width()),
            ));
        }
        self.guide_plan = Some(plan);
        Ok(())
    }

    fn clear_guides(&mut self) {
        self.guides.clear();
        self.guide_plan = None;
    }

    /// Replaces the policy mean (e.g. with a filtered sequence), K × nu starting at time `t0`.
    pub fn set_nominal(&mut self, nominal: &[f64], t0: f64) -> Result<()> {
        if nominal.len() != self.nominal.len() {
            return Err(SabreError::shape(
                "nominal",
                format!("({}, {})", self.k, self.nu),
                format!("{} elements", nominal.len()),
            ));
        }
        ensure_finite("nominal", nominal)?;
        self.nominal.copy_from_slice(nominal);
        self.nominal_t0 = t0;
        Ok(())
    }

    /// The commanded velocity at time `t`, linearly interpolated between the nominal's steps.
    pub fn reference(&self, t: f64, out: &mut [f64]) {
        interpolate(&self.nominal, self.nu, (t - self.nominal_t0) / self.dt, out);
    }

    /// Receding horizon: the nominal now starts at `t`.
    fn shift_to(&mut self, t: f64) {
        let steps = (t - self.nominal_t0) / self.dt;
        shift(&mut self.nominal, self.nu, steps, &mut self.scratch);
        self.nominal_t0 = t;
    }

    fn project(&self, u: &mut [f64]) {
        for step in u.chunks_exact_mut(self.nu) {
            for ((v, &lo), &hi) in step.iter_mut().zip(&self.lower).zip(&self.upper) {
                *v = v.clamp(lo, hi);
            }
        }
    }

    /// Moves the nominal to `t` and chooses what the next batch's rows hold: the nominal, zero,
    /// the guides, the best previous samples shifted to `t`, fresh samples (see [`RowPlan`]).
    fn plan_batch(&mut self, t: f64) {
        // Every row of the batch is written anew: whatever `samples` holds is scratch.
        self.batch_in_previous = false;
        self.shift_to(t);
        let n = self.config.rollouts;
        let filled = 2 + self.guides.len() / (self.k * self.nu) + self.planned_guides();
        self.kept.clear();
        if self.have_previous {
            let keep = ((self.config.keep_fraction * n as f64).floor() as usize).min(n - filled);
            let weights = &self.previous_weights;
            self.kept.extend((0..n).filter(|&i| weights[i] > 0.0));
            // Highest weight first; ties by index keep the choice deterministic.
            self.kept.sort_by(|&a, &b| weights[b].total_cmp(&weights[a]).then(a.cmp(&b)));
            self.kept.truncate(keep);
        }
        let std_scale = self.noise_scale.sqrt();
        self.scaled_std.clear();
        self.scaled_std.extend(self.std.iter().map(|s| std_scale * s));
        self.batches += 1;
    }

    /// How many of the planned guides the next batch takes: those the given ones leave room for.
    fn planned_guides(&self) -> usize {
        let room = self.config.rollouts - 2 - self.guides.len() / (self.k * self.nu);
        self.guide_plan.as_ref().map_or(0, |plan| plan.len().min(room))
    }

    /// The rows of the batch chosen by the last [`Self::plan_batch`].
    fn row_plan(&self) -> RowPlan<'_> {
        RowPlan {
            nu: self.nu,
            nominal: &self.nominal,
            guides: &self.guides,
            planned: self.guide_plan.as_deref().map(|plan| (plan, self.planned_guides())),
            previous: &self.previous,
            kept: &self.kept,
            kept_shift: (self.nominal_t0 - self.previous_t0) / self.dt,
            std: &self.scaled_std,
            interval: self.config.noise_interval.max(1),
            lower: &self.lower,
            upper: &self.upper,
            key: self.key,
            batch: self.batches,
        }
    }

    /// Builds every row of the planned batch here; the guides are used.
    fn fill_batch(&mut self) {
        let mut samples = std::mem::take(&mut self.samples);
        let plan = self.row_plan();
        for (i, row) in samples.chunks_exact_mut(self.k * self.nu).enumerate() {
            plan.fill(i, row);
        }
        self.samples = samples;
        self.clear_guides();
    }

    /// Builds the batch for time `t`: nominal, zero, the guides, the best previous samples
    /// shifted, fresh samples. The same batch as [`Self::iterate`] rolls out at `t`.
    pub fn sample(&mut self, t: f64) -> &[f64] {
        self.plan_batch(t);
        self.fill_batch();
        &self.samples
    }

    /// Rolls the current batch out from `x` with `cost`; records its timing in [`Self::stats`].
    pub fn rollout(&mut self, x: &[f64], cost: &Cost) -> Result<RolloutBatch> {
        self.recall_batch();
        let mut batch = RolloutBatch::default();
        let start = Instant::now();
        let (n, k, threads) = (self.config.rollouts, self.k, self.config.threads);
        self.model
            .rollout_into(x, &self.samples, n, k, threads, Some(cost), &mut batch)?;
        self.record_rollouts(start, &batch, x);
        Ok(batch)
    }

    fn record_rollouts(&mut self, start: Instant, batch: &RolloutBatch, x: &[f64]) {
        self.stats.rollout_time = start.elapsed().as_secs_f64();
        (self.stats.engine_steps, self.stats.engine_time) = batch.engine_totals();
        self.start.clear();
        self.start.extend_from_slice(&x[..self.nu]);
    }

    /// Plans the batch for `t` and rolls it out from `x` with `cost`, each row built by the worker
    /// that rolls it out.
    fn sample_and_rollout(&mut self, x: &[f64], t: f64, cost: &Cost, batch: &mut RolloutBatch) -> Result<()> {
        self.plan_batch(t);
        let start = Instant::now();
        let (n, k, threads) = (self.config.rollouts, self.k, self.config.threads);
        let mut samples = std::mem::take(&mut self.samples);
        let plan = self.row_plan();
        let fill = |i: usize, row: &mut [f64]| plan.fill(i, row);
        let result = self
            .model
            .rollout_filled_into(x, &mut samples, &fill, n, k, threads, Some(cost), false, batch);
        self.samples = samples;
        if result.is_err() {
            // Rows that no worker reached are built here, so that the batch is whole.
            self.fill_batch();
            return result;
        }
        self.clear_guides();
        self.record_rollouts(start, batch, x);
        Ok(())
    }

    /// Moves the current batch back into `samples` if the last update swapped it out (a second
    /// update or rollout of the same batch).
    fn recall_batch(&mut self) {
        if self.batch_in_previous {
            std::mem::swap(&mut self.previous, &mut self.samples);
            self.batch_in_previous = false;
        }
    }

    /// Weights the samples by `costs` and moves the policy: μ_k += α clip(Σ_l w_l ε_k^l, ±g_max) (14, 54),
    /// then smooths and projects it. Keeps the batch for reuse in the next iteration.
    pub fn update(&mut self, costs: &[f64]) -> Result<()> {
        let (n, k, nu) = (self.config.rollouts, self.k, self.nu);
        if costs.len() != n {
            return Err(SabreError::shape("costs", format!("({n},)"), format!("({},)", costs.len())));
        }
        self.recall_batch();
        let mut w = std::mem::take(&mut self.weights);
        weights(costs, LikelihoodMapping::Invariant { h: self.config.h }, &mut w);
        let row = k * nu;
        let total: f64 = w.iter().sum();
        if total > 0.0 {
            let clip = self.config.gradient_clip;
            let mut gradient = vec![0.0; row];
            for (l, &wl) in w.iter().enumerate() {
                if wl == 0.0 {
                    continue;
                }
                let sample = &self.samples[l * row..(l + 1) * row];
                for ((g, &u), &m) in gradient.iter_mut().zip(sample).zip(&self.nominal) {
                    *g += wl * (u - m);
                }
            }
            for (m, g) in self.nominal.iter_mut().zip(&gradient) {
                *m += self.config.step_size * g.clamp(-clip, clip);
            }
            if let Some(smoother) = &self.smoother {
                let mut smoothed = vec![0.0; row];
                smoother.apply(&self.nominal, nu, &mut smoothed);
                self.nominal = smoothed;
            }
            let mut nominal = std::mem::take(&mut self.nominal);
            self.project(&mut nominal);
            self.nominal = nominal;
        }
        let finite: Vec<f64> = costs.iter().copied().filter(|c| c.is_finite()).collect();
        self.stats.cost_min = finite.iter().copied().fold(f64::INFINITY, f64::min);
        self.stats.cost_max = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        self.stats.cost_mean = if finite.is_empty() {
            f64::NAN
        } else {
            finite.iter().sum::<f64>() / finite.len() as f64
        };
        self.stats.nominal_cost = costs[0];
        self.stats.effective_sample_size = effective_sample_size(&w);
        self.stats.failed_rollouts = n - finite.len();
        // The batch becomes the previous one by a swap, not a copy (an N × K × nu array every
        // iteration): the next `sample` writes every row of the batch anew.
        std::mem::swap(&mut self.previous, &mut self.samples);
        self.batch_in_previous = true;
        self.previous_weights.copy_from_slice(&w);
        self.previous_t0 = self.nominal_t0;
        self.have_previous = true;
        self.weights = w;
        self.stats.iteration += 1;
        Ok(())
    }

    /// One planning iteration from the measured state `x` at time `t`.
    pub fn iterate(&mut self, x: &[f64], t: f64, cost: &Cost) -> Result<&IterationStats> {
        if !t.is_finite() {
            return Err(SabreError::invalid("t", "must be finite"));
        }
        let start = Instant::now();
        let mut batch = std::mem::take(&mut self.batch);
        let result = self
            .sample_and_rollout(x, t, cost, &mut batch)
            .and_then(|()| self.update(&batch.costs));
        self.batch = batch;
        result?;
        self.stats.iteration_time = start.elapsed().as_secs_f64();
        Ok(&self.stats)
    }
}

#[cfg(test)]
mod tests;
