//! The filter's hard-limit guard: after the QP, no component of the command drives a joint further
//! beyond its URDF limit, nor past a box of allowed commands a caller gives (the cascade's joint-limit
//! bound), and the passivity row keeps what the QP's command achieved.

use super::SafetyFilter;
use crate::error::{ensure_len, Result, SabreError};
use crate::safety::config::ConstraintClass;

impl SafetyFilter {
    /// Checks a box of allowed commands: nq entries each, lower[i] ≤ 0 ≤ upper[i] (so that scaling a
    /// command toward the safe stop u = 0 never leaves it).
    pub(super) fn check_box(&self, within: Option<(&[f64], &[f64])>) -> Result<()> {
        let Some((lower, upper)) = within else { return Ok(()) };
        let nq = self.scene.nq();
        ensure_len("lower", lower, nq)?;
        ensure_len("upper", upper, nq)?;
        if let Some(i) = (0..nq).find(|&i| !(lower[i] <= 0.0 && upper[i] >= 0.0)) {
            return Err(SabreError::invalid(
                "within",
                format!(
                    "joint {i}'s allowed commands [{}, {}] must contain 0 (the safe stop)",
                    lower[i], upper[i]
                ),
            ));
        }
        Ok(())
    }

    /// The hard-limit guard: the joint-limit rows are ZBFs with slack, so a command that saturates
    /// many inputs may still move a joint that is already at or beyond its URDF limit further out
    /// (Remark 1 bounds the violation by the slack the penalty allows, it does not forbid it).
    /// Such a component is set to zero, and every component is clipped into `within` (lower ≤ 0 ≤
    /// upper per joint) when given. If that lowers τ_extᵀu below both the passivity row's bound and
    /// what the QP's command achieved (or below zero, when the tank is under its floor), the whole
    /// command is scaled toward the safe stop u = 0 until it achieves that again: every component
    /// stays within its clip, which contains 0, and u = 0 moves no energy through the port
    /// (Ṡ = τ_extᵀ·0 = 0), which meets the row whenever the tank is at or above its floor. The
    /// reported slacks are those of the final command.
    pub(super) fn hold_hard_limits(&mut self, q: &[f64], within: Option<(&[f64], &[f64])>) {
        let nq = q.len();
        let out = &mut self.output;
        let before = out.u.clone();
        let mut changed = false;
        for (j, (&(lower, upper), &qj)) in self.position_limits.iter().zip(q).enumerate() {
            let (mut lo, mut hi) = within.map_or((f64::NEG_INFINITY, f64::INFINITY), |(l, h)| (l[j], h[j]));
            if qj >= upper {
                hi = hi.min(0.0);
            }
            if qj <= lower {
                lo = lo.max(0.0);
            }
            let held = out.u[j].clamp(lo, hi);
            if held != out.u[j] {
                out.u[j] = held;
                changed = true;
            }
        }
        if !changed {
            return;
        }
        let dot = |a: &[f64], u: &[f64]| a.iter().zip(u).map(|(a, u)| a * u).sum::<f64>();
        for ri in 0..self.rows.len() {
            if !self.rows.live[ri] || self.rows.rows[ri].class != ConstraintClass::Passivity {
                continue;
            }
            let a = &self.rows.coef[ri * nq..(ri + 1) * nq];
            let wanted = self.rows.bound[ri].min(dot(a, &before)).min(0.0);
            let achieved = dot(a, &out.u);
            if achieved < wanted {
                let scale = (wanted / achieved).clamp(0.0, 1.0);
                out.u.iter_mut().for_each(|u| *u *= scale);
            }
        }
        for ri in 0..self.rows.len() {
            if self.rows.live[ri] {
                let a = &self.rows.coef[ri * nq..(ri + 1) * nq];
                out.slack[ri] = (self.rows.bound[ri] - dot(a, &out.u)).max(0.0);
            }
        }
        self.stats.hard_limit_holds += 1;
    }
}
