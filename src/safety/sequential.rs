//! Sequential FILTER-QP (Algorithm 1): filter a whole input sequence step by step along its rollout.

use super::filter::SafetyFilter;
use super::output::FilterStatus;
use crate::error::{ensure_finite, Result, SabreError};
use crate::sim::{RolloutModel, RolloutWorld};

/// A filtered sequence and the rollout it produces.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SequenceOutput {
    /// Number of steps K.
    pub k: usize,
    /// Filtered inputs, K × nq row-major.
    pub u: Vec<f64>,
    /// States x_0 … x_K of the rollout under the filtered inputs, (K+1) × nx.
    pub states: Vec<f64>,
    /// Filter status of each step.
    pub status: Vec<FilterStatus>,
    /// Largest slack of each step over all rows.
    pub max_slack: Vec<f64>,
    pub fallbacks: usize,
}

impl SafetyFilter {
    /// Algorithm 1: for k = 0 … K−1, filter u_k at x_k (no passivity row: as in the paper,
    /// passivity is enforced with measured wrenches in the inner loop only), then advance the
    /// rollout model one step with the filtered command to get x_{k+1}. `u` is K × nq row-major.
    /// Uses a pooled world of `model`.
    pub fn filter_sequence(&mut self, model: &RolloutModel, x0: &[f64], u: &[f64]) -> Result<SequenceOutput> {
        let mut out = SequenceOutput::default();
        model.with_world(x0, |world| self.filter_sequence_in(world, x0, u, &mut out))?;
        Ok(out)
    }

    /// [`Self::filter_sequence`] in a caller-held world, already placed at x0 (see
    /// [`RolloutModel::reset_world`]); `out` is overwritten and its buffers reused.
    pub fn filter_sequence_in(
        &mut self,
        world: &mut RolloutWorld,
        x0: &[f64],
        u: &[f64],
        out: &mut SequenceOutput,
    ) -> Result<()> {
        let scene = self.scene().clone();
        let (nq, nx) = (scene.nq(), scene.nx());
        let other = world.scene();
        if other.nq() != nq || other.nx() != nx || other.robot.name != scene.robot.name {
            return Err(SabreError::invalid(
                "rollout model",
                "simulates a different scene than the filter's",
            ));
        }
        scene.check_state(x0)?;
        if u.is_empty() || !u.len().is_multiple_of(nq) {
            return Err(SabreError::shape("U", format!("(K, {nq})"), format!("{} elements", u.len())));
        }
        ensure_finite("U", u)?;
        let k = u.len() / nq;
        out.k = k;
        out.u.clear();
        out.u.resize(k * nq, 0.0);
        out.states.clear();
        out.states.resize((k + 1) * nx, 0.0);
        out.states[..nx].copy_from_slice(x0);
        out.status.clear();
        out.max_slack.clear();
        out.fallbacks = 0;
        self.in_sequence = true;
        let result = self.run_sequence(world, u, out);
        self.in_sequence = false;
        result
    }

    fn run_sequence(&mut self, world: &mut RolloutWorld, u: &[f64], out: &mut SequenceOutput) -> Result<()> {
        let (nq, nx, k) = (self.scene().nq(), self.scene().nx(), out.k);
        for step in 0..k {
            let (done, rest) = out.states.split_at_mut((step + 1) * nx);
            let x = &done[step * nx..];
            let filtered = self.filter(x, &u[step * nq..(step + 1) * nq], None)?;
            out.u[step * nq..(step + 1) * nq].copy_from_slice(&filtered.u);
            out.status.push(filtered.status);
            out.max_slack.push(filtered.slack.iter().copied().fold(0.0, f64::max));
            out.fallbacks += usize::from(filtered.status == FilterStatus::Fallback);
            let next = &mut rest[..nx];
            world.step_once(&out.u[step * nq..(step + 1) * nq], next);
            if let Some(i) = next.iter().position(|v| !v.is_finite()) {
                return Err(SabreError::Simulation(format!(
                    "rollout state entry {i} became non-finite at step {step} of the sequential filter"
                )));
            }
        }
        Ok(())
    }
}
