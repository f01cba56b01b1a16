//! What a FILTER-QP call returns: its status, how it was solved, the filtered command, the
//! running statistics, and the QP in matrix form for checks against other solvers.

use clarabel::solver::SolverStatus;

use super::config::ConstraintClass;

/// How a call ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FilterStatus {
    /// Clarabel converged to the requested tolerance.
    #[default]
    Solved,
    /// Clarabel converged to its reduced tolerance; the solution is used (clipped to the input limits).
    AlmostSolved,
    /// Clarabel did not converge (iteration limit, numerical trouble): the output is the safe stop
    /// u = 0, which meets the input limits; counted in [`FilterStats::fallbacks`].
    Fallback,
}

impl FilterStatus {
    pub fn name(self) -> &'static str {
        match self {
            FilterStatus::Solved => "solved",
            FilterStatus::AlmostSolved => "almost_solved",
            FilterStatus::Fallback => "fallback",
        }
    }
}

/// How a call found its command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SolveMethod {
    /// The command projected onto the input limits met every row.
    #[default]
    Projection,
    /// The previous active set, re-solved and checked against every optimality condition.
    ActiveSet,
    /// Clarabel's interior-point method (also when it failed and the call fell back).
    InteriorPoint,
}

impl SolveMethod {
    pub fn name(self) -> &'static str {
        match self {
            SolveMethod::Projection => "projection",
            SolveMethod::ActiveSet => "active_set",
            SolveMethod::InteriorPoint => "interior_point",
        }
    }
}

/// The outcome of one call; owned by the filter and overwritten by the next call.
#[derive(Debug, Clone, Default)]
pub struct FilterOutput {
    /// Filtered command ũ (nq), always within the input limits.
    pub u: Vec<f64>,
    /// Slack δ_r ≥ 0 of each row (R): how far the row's ZBF condition is relaxed.
    pub slack: Vec<f64>,
    /// Largest slack of each class, in [`ConstraintClass::ALL`] order (0 for classes without rows).
    pub class_slack: [f64; ConstraintClass::COUNT],
    /// Barrier value h of each row (without the margin); NaN for rows switched off in this call.
    pub barrier: Vec<f64>,
    /// Active constraints: row indices r < R, or R + j for the input limit of joint j.
    pub active: Vec<usize>,
    pub status: FilterStatus,
    /// Clarabel's own verdict (also for fallbacks).
    pub solver_status: SolverStatus,
    /// Wall time of the whole call (rows, update, solve, post-processing), seconds.
    pub solve_time: f64,
    pub iterations: u32,
    /// Rows in the QP that was solved (0: the projected command met every row, no solver ran;
    /// for the active-set method the number of active rows).
    pub qp_rows: usize,
    pub method: SolveMethod,
}

/// Running statistics of a filter.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterStats {
    pub calls: u64,
    pub fallbacks: u64,
    pub total_time: f64,
    pub max_time: f64,
    pub total_iterations: u64,
    /// Calls that ran Clarabel.
    pub interior_point_calls: u64,
    /// Calls whose command the hard-limit guard changed (a joint at or beyond its URDF limit was
    /// commanded further out).
    pub hard_limit_holds: u64,
}

impl FilterStats {
    pub fn mean_time(&self) -> f64 {
        if self.calls == 0 {
            0.0
        } else {
            self.total_time / self.calls as f64
        }
    }
}

/// The QP data in Clarabel's form, for inspection and for cross-checking with other solvers:
/// minimise ½xᵀPx + qᵀx subject to A x ≤ b, with x = [ũ; δ].
#[derive(Debug, Clone, PartialEq)]
pub struct QpMatrices {
    pub n: usize,
    pub m: usize,
    pub nu: usize,
    /// Dense row-major n × n, m × n.
    pub p: Vec<f64>,
    pub q: Vec<f64>,
    pub a: Vec<f64>,
    pub b: Vec<f64>,
}
