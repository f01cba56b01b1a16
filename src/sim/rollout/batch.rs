//! The results of a batch of rollouts: states, external torques, wrenches, contacts, costs and
//! failures of N rollouts, in buffers a planner reuses from one iteration to the next.

use crate::error::{Result, SabreError};

/// Results of N rollouts of K steps, row-major in (N, K[+1], ·).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RolloutBatch {
    pub n: usize,
    pub k: usize,
    pub nx: usize,
    pub nq: usize,
    /// (N, K+1, nx); entry 0 of each rollout is x0. This and the other trajectories (τ_ext,
    /// wrenches, contacts) are empty when the batch was rolled out for its costs alone.
    pub states: Vec<f64>,
    /// (N, K, nq)
    pub tau_ext: Vec<f64>,
    /// (N, K, 6)
    pub wrench: Vec<f64>,
    /// (N, K)
    pub contact: Vec<bool>,
    /// (N,) rollouts whose physics failed; their outputs are NaN from the failing step on.
    pub failed: Vec<bool>,
    /// (N,) accumulated cost of each rollout (zero without a cost; +∞ for failed rollouts).
    pub costs: Vec<f64>,
    /// (N,) steps of each rollout that went through Rapier's pipeline; the others were skipped
    /// because nothing could move the object (see `RolloutConfig::skip_quiescent_steps`).
    pub engine_steps: Vec<u64>,
    /// (N,) wall time each rollout spent inside Rapier's pipeline (s); the rest of its time is the
    /// servo, the contact measurement and the cost.
    pub engine_time: Vec<f64>,
}

impl RolloutBatch {
    /// Sizes the batch for `n` rollouts of `k` steps, keeping its buffers' memory: a planner that
    /// reuses one batch allocates (and the OS maps and zeroes) nothing per iteration. The states,
    /// τ_ext, wrenches and contacts are left as they were (every rollout writes all of its own),
    /// or emptied without `trajectories`; the per-rollout flags and totals start from zero.
    pub(super) fn prepare(&mut self, n: usize, k: usize, nx: usize, nq: usize, trajectories: bool) -> Result<()> {
        fn fit<T: Clone>(v: &mut Vec<T>, len: usize, fill: T) -> Result<()> {
            if len > v.len() {
                v.try_reserve_exact(len - v.len())
                    .map_err(|_| SabreError::Simulation(format!("cannot allocate {len} values for the rollout outputs")))?;
            }
            v.resize(len, fill);
            Ok(())
        }
        (self.n, self.k, self.nx, self.nq) = (n, k, nx, nq);
        let kept = usize::from(trajectories);
        fit(&mut self.states, kept * n * (k + 1) * nx, 0.0)?;
        fit(&mut self.tau_ext, kept * n * k * nq, 0.0)?;
        fit(&mut self.wrench, kept * n * k * 6, 0.0)?;
        fit(&mut self.contact, kept * n * k, false)?;
        for (v, fill) in [(&mut self.costs, 0.0), (&mut self.engine_time, 0.0)] {
            fit(v, n, fill)?;
            v.fill(fill);
        }
        fit(&mut self.failed, n, false)?;
        self.failed.fill(false);
        fit(&mut self.engine_steps, n, 0)?;
        self.engine_steps.fill(0);
        Ok(())
    }

    /// Steps through Rapier's pipeline and the time spent in them, summed over the batch. The time
    /// adds up every worker's: divide by the thread count for its share of the wall time.
    pub fn engine_totals(&self) -> (u64, f64) {
        (self.engine_steps.iter().sum(), self.engine_time.iter().sum())
    }
}
