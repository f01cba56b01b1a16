//! Exact warm start of the FILTER-QP: re-solve the previous call's active set and accept it only if it meets every optimality condition.
//!
//! At 1 kHz the binding constraints rarely change from one call to the next. For a guessed active
//! set — soft rows R_A pressed with multipliers λ_r = Γ_r δ_r > 0, and joints B held at an input
//! bound — the optimality conditions of the FILTER-QP are linear:
//! u_F = u_ref,F + Σ_r λ_r a_r,F on the free joints, u_B = ±v_B, and a_r·u + λ_r/Γ_r = b_r, i.e.
//! (A_F A_Fᵀ + diag(1/Γ)) λ = b − A_F u_ref,F − A_B u_B (symmetric positive definite, k × k).
//! The result is the QP's solution exactly when λ ≥ 0, every other row holds with δ = 0, the free
//! joints are within their bounds and the bound multipliers have the right sign (the QP is convex,
//! so these KKT conditions are sufficient). Otherwise the caller runs the interior-point solver.

use super::constraints::Rows;

/// Largest active set (rows) solved directly; beyond it the interior-point solver is as quick.
const MAX_ROWS: usize = 16;

pub(crate) struct ActiveSet {
    nq: usize,
    valid: bool,
    rows: Vec<usize>,
    /// Per joint: +1 at the upper bound, −1 at the lower bound, 0 free.
    bounds: Vec<i8>,
    matrix: Vec<f64>,
    lambda: Vec<f64>,
    u: Vec<f64>,
}

impl ActiveSet {
    pub fn new(nq: usize) -> Self {
        Self {
            nq,
            valid: false,
            rows: Vec::with_capacity(MAX_ROWS),
            bounds: vec![0; nq],
            matrix: vec![0.0; MAX_ROWS * MAX_ROWS],
            lambda: vec![0.0; MAX_ROWS],
            u: vec![0.0; nq],
        }
    }

    pub fn forget(&mut self) {
        self.valid = false;
    }

    /// Remembers the active set of a solution: rows whose multiplier Γδ exceeds `threshold`, joints
    /// within `threshold` of a bound.
    pub fn remember(&mut self, rows: &Rows, penalty: &[f64], slack: &[f64], u: &[f64], limits: &[f64], threshold: f64) {
        self.rows.clear();
        for r in 0..rows.len() {
            if rows.live[r] && penalty[r] * slack[r] > threshold {
                if self.rows.len() == MAX_ROWS {
                    self.valid = false;
                    return;
                }
                self.rows.push(r);
            }
        }
        for j in 0..self.nq {
            self.bounds[j] = if u[j] >= limits[j] - threshold {
                1
            } else if u[j] <= -limits[j] + threshold {
                -1
            } else {
                0
            };
        }
        self.valid = true;
    }

    /// Solves the remembered active set for `u_ref`; on success writes the command and the slacks
    /// (zero off the active set) and returns the number of active rows.
    pub fn try_solve(
        &mut self,
        rows: &Rows,
        penalty: &[f64],
        limits: &[f64],
        u_ref: &[f64],
        u_out: &mut [f64],
        slack_out: &mut [f64],
    ) -> Option<usize> {
        if !self.valid {
            return None;
        }
        let (nq, k) = (self.nq, self.rows.len());
        let row = |r: usize| &rows.coef[r * nq..(r + 1) * nq];
        for (i, &ri) in self.rows.iter().enumerate() {
            if !rows.live[ri] {
                return None;
            }
            let (ai, mut rhs) = (row(ri), rows.bound[ri]);
            for j in 0..nq {
                rhs -= ai[j]
                    * match self.bounds[j] {
                        0 => u_ref[j],
                        s => f64::from(s) * limits[j],
                    };
            }
            self.lambda[i] = rhs;
            for (l, &rl) in self.rows.iter().enumerate().take(i + 1) {
                let al = row(rl);
                let mut m: f64 = (0..nq).filter(|&j| self.bounds[j] == 0).map(|j| ai[j] * al[j]).sum();
                if l == i {
                    m += 1.0 / penalty[ri];
                }
                self.matrix[i * MAX_ROWS + l] = m;
            }
        }
        if !cholesky_solve(&mut self.matrix, k, &mut self.lambda[..k]) {
            return None;
        }
        const TOL: f64 = 1e-10;
        if self.lambda[..k].iter().any(|&l| l < -TOL) {
            return None;
        }
        for j in 0..nq {
            let pull: f64 = self.rows.iter().zip(&self.lambda).map(|(&r, l)| l * row(r)[j]).sum();
            match self.bounds[j] {
                0 => {
                    self.u[j] = u_ref[j] + pull;
                    if self.u[j].abs() > limits[j] * (1.0 + TOL) {
                        return None;
                    }
                }
                s => {
                    self.u[j] = f64::from(s) * limits[j];
                    // Bound multiplier μ = s (u_ref + Σλa − u) must be non-negative.
                    if f64::from(s) * (u_ref[j] + pull - self.u[j]) < -TOL * (1.0 + limits[j]) {
                        return None;
                    }
                }
            }
        }
        for r in 0..rows.len() {
            if !rows.live[r] || self.rows.contains(&r) {
                continue;
            }
            let b = rows.bound[r];
            let lhs: f64 = row(r).iter().zip(&self.u).map(|(a, u)| a * u).sum();
            if lhs < b - TOL * (1.0 + b.abs()) {
                return None;
            }
        }
        u_out.copy_from_slice(&self.u);
        slack_out.fill(0.0);
        for (i, &r) in self.rows.iter().enumerate() {
            slack_out[r] = self.lambda[i].max(0.0) / penalty[r];
        }
        Some(k)
    }
}

/// Solves M x = b in place for symmetric positive definite M (lower triangle in `m`, row stride
/// MAX_ROWS, k × k); false if M is not numerically positive definite.
fn cholesky_solve(m: &mut [f64], k: usize, b: &mut [f64]) -> bool {
    for i in 0..k {
        for j in 0..=i {
            let mut s = m[i * MAX_ROWS + j];
            for p in 0..j {
                s -= m[i * MAX_ROWS + p] * m[j * MAX_ROWS + p];
            }
            if i == j {
                if s <= 1e-14 {
                    return false;
                }
                m[i * MAX_ROWS + i] = s.sqrt();
            } else {
                m[i * MAX_ROWS + j] = s / m[j * MAX_ROWS + j];
            }
        }
    }
    for i in 0..k {
        let mut s = b[i];
        for p in 0..i {
            s -= m[i * MAX_ROWS + p] * b[p];
        }
        b[i] = s / m[i * MAX_ROWS + i];
    }
    for i in (0..k).rev() {
        let mut s = b[i];
        for p in i + 1..k {
            s -= m[p * MAX_ROWS + i] * b[p];
        }
        b[i] = s / m[i * MAX_ROWS + i];
    }
    true
}
