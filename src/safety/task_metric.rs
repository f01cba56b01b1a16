//! The FILTER-QP's metric on ũ that keeps a frame's velocity (`SafetyConfig::task_weight`).

use super::config::TASK_ANGULAR_LENGTH;
use crate::model::scene::Scene;

/// The QP's metric on ũ that protects a frame's velocity (`SafetyConfig::task_weight`).
pub(super) struct TaskMetric {
    pub(super) link: usize,
    /// λ of single calls and of calls inside a sequence.
    pub(super) weight: f64,
    pub(super) sequential_weight: f64,
    /// Whether M ≠ I in this call.
    pub(super) active: bool,
    pub(super) m: Vec<f64>,
    /// A lower bound on M's smallest eigenvalue: 1 / (1 + λ σ²_max).
    pub(super) smallest: f64,
}

impl TaskMetric {
    /// M = (I + λ J_wᵀJ_w) / (1 + λ σ²_max(J_w)) with J_w = [J_v; ℓ J_ω]: divided by its largest
    /// eigenvalue, so that no correction costs more than in the paper's ‖ũ − u‖² and the slacks
    /// never become the cheaper way out; the directions that leave the frame still cost least.
    pub(super) fn update(&mut self, scene: &Scene, q: &[f64], in_sequence: bool) {
        let nq = q.len();
        let weight = if in_sequence { self.sequential_weight } else { self.weight };
        let was_active = std::mem::replace(&mut self.active, weight > 0.0);
        if !self.active {
            // The 1 kHz filter's calls land here: write the identity only when leaving a sequence.
            if was_active {
                self.m.fill(0.0);
                (0..nq).for_each(|a| self.m[a * nq + a] = 1.0);
                self.smallest = 1.0;
            }
            return;
        }
        let mut j = scene.robot.frame_jacobian(&nalgebra::Isometry3::identity(), q, self.link);
        for r in 3..6 {
            for c in 0..nq {
                j[(r, c)] *= TASK_ANGULAR_LENGTH;
            }
        }
        let jjt = &j * j.transpose();
        let sigma2 = nalgebra::SymmetricEigen::new(jjt).eigenvalues.max().max(0.0);
        let scale = 1.0 / (1.0 + weight * sigma2);
        self.smallest = scale;
        for a in 0..nq {
            for b in a..nq {
                let jj: f64 = (0..6).map(|r| j[(r, a)] * j[(r, b)]).sum();
                let v = scale * (weight * jj + if a == b { 1.0 } else { 0.0 });
                self.m[a * nq + b] = v;
                self.m[b * nq + a] = v;
            }
        }
    }

    /// ½ (u − v)ᵀ M (u − v).
    pub(super) fn half_norm2(&self, u: &[f64], v: &[f64]) -> f64 {
        let nq = u.len();
        let mut s = 0.0;
        for a in 0..nq {
            for b in 0..nq {
                s += (u[a] - v[a]) * self.m[a * nq + b] * (u[b] - v[b]);
            }
        }
        0.5 * s
    }
}
