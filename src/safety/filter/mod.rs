//! FILTER-QP (41): rows, exact screening, Clarabel solve, fallback, result and statistics.
//!
//! Each call evaluates every ZBF row, then solves the smallest QP with the same solution:
//! - if the command projected onto the input limits already meets every row, it *is* the QP's
//!   solution (δ = 0; the objective's unconstrained minimiser over the box), and no solver runs;
//! - else the previous call's active set is re-solved as a small linear system and accepted if it
//!   meets every optimality condition (`active_set`), which is the common case at 1 kHz;
//! - rows that every candidate optimum meets can never bind and are left out: the optimum lies in
//!   the input box and within a distance of u_ref bounded by the cost of the projected command
//!   (see `screen`); the rest go into the smallest of a few pre-built Clarabel problems with that
//!   many dense row slots (2, 4, 8, 16), or into the full problem (every row, its own sparsity)
//!   when more remain.
//!
//! Every Clarabel problem is built once at construction with a fixed pattern and updated in place.
//! `SafetyConfig::screening = false` skips all three shortcuts and always solves the full problem
//! with Clarabel (same solution, slower).

use std::sync::Arc;
use std::time::Instant;

use clarabel::solver::SolverStatus;

use super::active_set::ActiveSet;
use super::config::{ConstraintClass, SafetyConfig};
use super::constraints::{Obstacle, Rows};
use super::output::{FilterOutput, FilterStats, FilterStatus, QpMatrices, SolveMethod};
use super::qp::{SlotQp, EMPTY};
use super::task_metric::TaskMetric;
use crate::error::{ensure_finite, ensure_len, Result, SabreError};
use crate::model::scene::Scene;
use crate::model::LimitBound;

mod hold;
mod obstacles;

/// Row-slot counts of the pre-built reduced problems, smallest first.
const REDUCED_SIZES: [usize; 4] = [2, 4, 8, 16];

/// The CBF safety filter (FILTER-QP, eq. 41) for one scene.
pub struct SafetyFilter {
    scene: Arc<Scene>,
    config: SafetyConfig,
    rows: Rows,
    row_penalty: Vec<f64>,
    obstacles: Vec<Option<Obstacle>>,
    next_obstacle_id: u64,
    velocity_limits: Vec<f64>,
    /// Hard position limits (lower, upper) of every robot joint, from the URDF.
    position_limits: Vec<(f64, f64)>,
    /// Every row in its own slot with its own sparsity.
    full: SlotQp,
    /// Dense slots for the rows that survive screening (only sizes below the full row count).
    reduced: Vec<SlotQp>,
    /// Rows that can bind in this call, and the slot assignment handed to the solver.
    candidates: Vec<usize>,
    assignment: Vec<usize>,
    active_set: ActiveSet,
    /// The task metric of this call, when either task weight is set.
    metric: Option<TaskMetric>,
    /// Whether the current call is a step of the Sequential FILTER-QP.
    pub(crate) in_sequence: bool,
    output: FilterOutput,
    stats: FilterStats,
}

/// Writes the rows of `assignment` and the metric into a QP.
fn load(
    qp: &mut SlotQp,
    assignment: &[usize],
    rows: &Rows,
    penalty: &[f64],
    u_ref: &[f64],
    metric: Option<&TaskMetric>,
) -> Result<()> {
    qp.load(
        assignment,
        &rows.coef,
        &rows.bound,
        penalty,
        u_ref,
        metric.map(|m| m.m.as_slice()),
    )
}

impl SafetyFilter {
    pub fn new(scene: Arc<Scene>, config: SafetyConfig) -> Result<Self> {
        config.validate()?;
        // The cascade applies the bound; its margins are checked against the robot here already.
        LimitBound::new(&scene, &config.limit_bound)?;
        let nq = scene.nq();
        let limits = scene.robot_limits();
        let velocity_limits: Vec<f64> = limits.iter().map(|l| l.velocity).collect();
        if let Some(j) = velocity_limits.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(SabreError::invalid(
                "robot velocity limits",
                format!(
                    "joint {j} has velocity limit {}; the filter needs finite positive input limits",
                    velocity_limits[j]
                ),
            ));
        }
        let weighted = config.task_weight > 0.0 || config.sequential_task_weight > 0.0;
        // An empty name is the scene's tool frame; a robot without one gets the plain metric.
        let task_link = if config.task_frame.is_empty() {
            scene.roles.tool_frame
        } else {
            Some(scene.robot.link_id(&config.task_frame).ok_or_else(|| {
                SabreError::invalid(
                    "task_frame",
                    format!(
                        "the robot has no frame '{}' for the task metric (set task_weight = 0 or name one of: {})",
                        config.task_frame,
                        scene.robot.link_names().join(", ")
                    ),
                )
            })?)
        };
        let metric = if let (true, Some(link)) = (weighted, task_link) {
            Some(TaskMetric {
                link,
                weight: config.task_weight,
                sequential_weight: config.sequential_task_weight,
                active: false,
                m: (0..nq * nq).map(|k| if k % (nq + 1) == 0 { 1.0 } else { 0.0 }).collect(),
                smallest: 1.0,
            })
        } else {
            None
        };
        let weighted = metric.is_some();
        let rows = Rows::new(scene.clone(), &config);
        let r = rows.len();
        let row_penalty: Vec<f64> = rows.rows.iter().map(|row| config.penalty.get(row.class)).collect();
        let full_cols = rows.rows.iter().map(|row| row.cols.clone()).collect();
        let full = SlotQp::new(nq, full_cols, &row_penalty, &velocity_limits, false, weighted, &config)?;
        let mut reduced = Vec::new();
        for &size in REDUCED_SIZES.iter().filter(|&&size| size < r) {
            let dense = vec![(0..nq).collect::<Vec<_>>(); size];
            reduced.push(SlotQp::new(
                nq,
                dense,
                &vec![1.0; size],
                &velocity_limits,
                true,
                weighted,
                &config,
            )?);
        }
        let output = FilterOutput {
            u: vec![0.0; nq],
            slack: vec![0.0; r],
            class_slack: [0.0; ConstraintClass::COUNT],
            barrier: vec![0.0; r],
            active: Vec::with_capacity(r + nq),
            ..FilterOutput::default()
        };
        let mut obstacles = Vec::with_capacity(config.max_obstacles);
        obstacles.resize(config.max_obstacles, None);
        Ok(Self {
            scene,
            rows,
            row_penalty,
            obstacles,
            next_obstacle_id: 0,
            velocity_limits,
            position_limits: limits.iter().map(|l| (l.lower, l.upper)).collect(),
            full,
            reduced,
            candidates: Vec::with_capacity(r),
            assignment: Vec::with_capacity(r),
            active_set: ActiveSet::new(nq),
            metric,
            in_sequence: false,
            output,
            stats: FilterStats::default(),
            config,
        })
    }

    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }
    pub fn config(&self) -> &SafetyConfig {
        &self.config
    }
    pub fn stats(&self) -> &FilterStats {
        &self.stats
    }
    pub fn reset_stats(&mut self) {
        self.stats = FilterStats::default();
    }
    /// Makes the next call ignore the previous call's active set (it then runs the interior-point
    /// solver unless the projected command is safe). Never needed for correctness, since a
    /// remembered active set is only used after it passes every optimality check; for benchmarks.
    pub fn forget_active_set(&mut self) {
        self.active_set.forget();
    }
    /// The output of the last call.
    pub fn output(&self) -> &FilterOutput {
        &self.output
    }
    /// Number of soft (ZBF) rows R.
    pub fn num_rows(&self) -> usize {
        self.rows.len()
    }
    /// Class of row r.
    pub fn row_class(&self, r: usize) -> ConstraintClass {
        self.rows.rows[r].class
    }
    /// The input limits (velocity limits from the URDF) the filter enforces as hard bounds.
    pub fn input_limits(&self) -> &[f64] {
        &self.velocity_limits
    }
    /// Name of entry `i` of [`FilterOutput::active`]: a row name for i < R, else `input_limit:<joint>`.
    pub fn constraint_name(&self, i: usize) -> String {
        let r = self.rows.len();
        if i < r {
            self.rows.name(i, &self.obstacles)
        } else {
            let s = &self.scene.robot;
            format!("input_limit:{}", s.joints[s.active_joints[i - r]].name)
        }
    }
    /// Names of all R rows, in order.
    pub fn row_names(&self) -> Vec<String> {
        (0..self.rows.len()).map(|r| self.rows.name(r, &self.obstacles)).collect()
    }

    // -- the filter ---------------------------------------------------------------------------

    fn check_inputs(&self, x: &[f64], u_ref: Option<&[f64]>, passivity: Option<(&[f64], f64)>) -> Result<()> {
        let nq = self.scene.nq();
        self.scene.check_state(x)?;
        if let Some(u_ref) = u_ref {
            ensure_len("u_ref", u_ref, nq)?;
            ensure_finite("u_ref", u_ref)?;
        }
        if let Some((tau, energy)) = passivity {
            ensure_len("tau_ext", tau, nq)?;
            ensure_finite("tau_ext", tau)?;
            ensure_finite("tank_energy", &[energy])?;
        }
        Ok(())
    }

    /// The rows at q and, with a task metric, the metric of this call.
    fn evaluate(&mut self, q: &[f64], passivity: Option<(&[f64], f64)>) {
        self.rows.evaluate(q, &self.obstacles, passivity);
        let in_sequence = self.in_sequence;
        if let Some(m) = &mut self.metric {
            m.update(&self.scene, q, in_sequence);
        }
    }

    /// Finds the rows that can bind (`candidates`) and whether the box projection of u_ref,
    /// already in `output.u`, meets every row.
    ///
    /// A row can be left out when every candidate optimum meets it. Optima lie in the input box
    /// and, because the projection ū with slacks δ̄_r = max(0, b_r − a_r ū) is feasible with cost
    /// F̄ = ½‖ū − u_ref‖² + ½ΣΓ_r δ̄_r², also in the ball ‖u − u_ref‖ ≤ ρ = √(2F̄). So a row with
    /// b_r ≤ max(−Σ_j |a_rj| v_j, a_r·u_ref − ρ‖a_r‖) is met by every optimum and cannot bind.
    fn screen(&mut self, u_ref: &[f64]) -> bool {
        let nq = self.scene.nq();
        // With a task metric the cost is measured in M, whose smallest eigenvalue μ ≤ 1 bounds
        // ‖u − u_ref‖ ≤ ‖u − u_ref‖_M / √μ: the ball below grows by 1/√μ.
        let mut cost = match self.metric.as_ref().filter(|m| m.active) {
            Some(m) => m.half_norm2(&self.output.u, u_ref),
            None => self.output.u.iter().zip(u_ref).map(|(u, r)| 0.5 * (u - r) * (u - r)).sum(),
        };
        let mut projection_feasible = true;
        for r in 0..self.rows.len() {
            if self.rows.live[r] {
                let a = &self.rows.coef[r * nq..(r + 1) * nq];
                let deficit = self.rows.bound[r] - a.iter().zip(&self.output.u).map(|(a, u)| a * u).sum::<f64>();
                if deficit > 0.0 {
                    cost += 0.5 * self.row_penalty[r] * deficit * deficit;
                    projection_feasible = false;
                }
            }
        }
        let radius = (2.0 * cost / self.metric.as_ref().map_or(1.0, |m| m.smallest)).sqrt();
        self.candidates.clear();
        for r in 0..self.rows.len() {
            if !self.rows.live[r] {
                continue;
            }
            let a = &self.rows.coef[r * nq..(r + 1) * nq];
            let b = self.rows.bound[r];
            let (mut box_lowest, mut at_ref, mut norm2) = (0.0, 0.0, 0.0);
            for j in 0..nq {
                box_lowest -= a[j].abs() * self.velocity_limits[j];
                at_ref += a[j] * u_ref[j];
                norm2 += a[j] * a[j];
            }
            let lowest = f64::max(box_lowest, at_ref - radius * norm2.sqrt());
            // Left out only with a clear margin, so rounding never drops a row that could bind.
            if b > lowest - 1e-9 * (1.0 + b.abs() + lowest.abs()) {
                self.candidates.push(r);
            }
        }
        projection_feasible
    }

    /// Chooses the problem for this call, loads it and solves it; returns the index of the reduced
    /// problem used (None = full), the solver status and the iteration count.
    fn solve(&mut self, u_ref: &[f64]) -> Result<(Option<usize>, SolverStatus, u32)> {
        let pick = if self.config.screening {
            self.reduced.iter().position(|qp| qp.slots() >= self.candidates.len())
        } else {
            None
        };
        self.assignment.clear();
        let qp = match pick {
            Some(i) => {
                self.assignment.extend_from_slice(&self.candidates);
                self.assignment.resize(self.reduced[i].slots(), EMPTY);
                &mut self.reduced[i]
            }
            None => {
                // Every row in its own slot; rows switched off this call hold 0·ũ + δ ≥ −1.
                self.assignment.extend(0..self.rows.len());
                &mut self.full
            }
        };
        load(
            qp,
            &self.assignment,
            &self.rows,
            &self.row_penalty,
            u_ref,
            self.metric.as_ref(),
        )?;
        let (status, iterations) = qp.solve();
        Ok((pick, status, iterations))
    }

    /// Filters `u_ref` (nq) at state `x` (nx). `passivity` = (τ_ext (nq), tank energy S) switches
    /// the passivity row on for this call (if the class is enabled; otherwise it is ignored).
    /// Returns the filter's output buffer.
    ///
    /// Bad input (wrong lengths, NaN) is an error; a solver failure is not: it yields the safe
    /// stop u = 0 with status [`FilterStatus::Fallback`]. A command is never passed through unfiltered.
    pub fn filter(&mut self, x: &[f64], u_ref: &[f64], passivity: Option<(&[f64], f64)>) -> Result<&FilterOutput> {
        self.filter_within(x, u_ref, passivity, None)
    }

    /// [`Self::filter`], then every component of the command clipped into `within` = (lower,
    /// upper) (nq each, lower ≤ 0 ≤ upper: the cascade's joint-limit bound) by the hard-limit guard,
    /// which keeps the passivity row's power as it does for the URDF limits. Errors: a box of the
    /// wrong length or one that does not contain 0, besides [`Self::filter`]'s.
    pub fn filter_within(
        &mut self,
        x: &[f64],
        u_ref: &[f64],
        passivity: Option<(&[f64], f64)>,
        within: Option<(&[f64], &[f64])>,
    ) -> Result<&FilterOutput> {
        let start = Instant::now();
        self.check_inputs(x, Some(u_ref), passivity)?;
        self.check_box(within)?;
        let nq = self.scene.nq();
        let r = self.rows.len();
        self.evaluate(&x[..nq], passivity);
        let weighted = self.metric.as_ref().is_some_and(|m| m.active);
        let mut clipped = false;
        for ((u, r), v) in self.output.u.iter_mut().zip(u_ref).zip(&self.velocity_limits) {
            *u = r.clamp(-v, *v);
            clipped |= *u != *r;
        }
        self.output.slack.fill(0.0);
        // Clipping to the box is the closest command in the Euclidean metric only; with a task
        // metric it is the QP's solution only if nothing was clipped.
        let projection_feasible = self.screen(u_ref) && !(clipped && weighted);
        // Multipliers and bound distances above this count as active when remembering a solution.
        const REMEMBER: f64 = 1e-6;
        if self.config.screening && projection_feasible {
            // The box projection of u_ref minimises the objective over the box and meets every
            // row with δ = 0: it is the QP's solution.
            let out = &mut self.output;
            out.status = FilterStatus::Solved;
            out.solver_status = SolverStatus::Solved;
            out.method = SolveMethod::Projection;
            out.iterations = 0;
            out.qp_rows = 0;
            self.active_set.remember(
                &self.rows,
                &self.row_penalty,
                &out.slack,
                &out.u,
                &self.velocity_limits,
                REMEMBER,
            );
        } else if let Some(k) = (self.config.screening && !weighted)
            .then(|| {
                self.active_set.try_solve(
                    &self.rows,
                    &self.row_penalty,
                    &self.velocity_limits,
                    u_ref,
                    &mut self.output.u,
                    &mut self.output.slack,
                )
            })
            .flatten()
        {
            let out = &mut self.output;
            out.status = FilterStatus::Solved;
            out.solver_status = SolverStatus::Solved;
            out.method = SolveMethod::ActiveSet;
            out.iterations = 0;
            out.qp_rows = k;
        } else {
            let (pick, status, iterations) = self.solve(u_ref)?;
            let qp = match pick {
                Some(i) => &self.reduced[i],
                None => &self.full,
            };
            let x = qp.primal();
            let out = &mut self.output;
            out.solver_status = status;
            out.method = SolveMethod::InteriorPoint;
            out.iterations = iterations;
            out.qp_rows = self.assignment.iter().filter(|&&a| a != EMPTY).count();
            self.stats.interior_point_calls += 1;
            let converged =
                matches!(status, SolverStatus::Solved | SolverStatus::AlmostSolved) && x.iter().all(|v| v.is_finite());
            if converged {
                out.status = if status == SolverStatus::Solved {
                    FilterStatus::Solved
                } else {
                    FilterStatus::AlmostSolved
                };
                // Interior-point iterates sit within the tolerance of the bounds; clip so the input
                // limits hold exactly.
                for ((u, &value), &limit) in out.u.iter_mut().zip(&x[..nq]).zip(&self.velocity_limits) {
                    *u = value.clamp(-limit, limit);
                }
                for (s, &row) in self.assignment.iter().enumerate() {
                    if row != EMPTY {
                        out.slack[row] = x[nq + s].max(0.0);
                    }
                }
                self.active_set.remember(
                    &self.rows,
                    &self.row_penalty,
                    &out.slack,
                    &out.u,
                    &self.velocity_limits,
                    REMEMBER,
                );
            } else {
                out.status = FilterStatus::Fallback;
                out.u.fill(0.0);
                // The slack the safe stop needs: the deficit of each live row at u = 0.
                for ri in 0..r {
                    out.slack[ri] = if self.rows.live[ri] {
                        self.rows.bound[ri].max(0.0)
                    } else {
                        0.0
                    };
                }
                self.active_set.forget();
            }
        }
        self.hold_hard_limits(&x[..nq], within);
        let out = &mut self.output;
        out.barrier.copy_from_slice(&self.rows.barrier);
        out.active.clear();
        out.class_slack = [0.0; ConstraintClass::COUNT];
        let tol = self.config.active_tolerance;
        for ri in 0..r {
            if !self.rows.live[ri] {
                continue;
            }
            let a = &self.rows.coef[ri * nq..(ri + 1) * nq];
            let b = self.rows.bound[ri];
            let lhs: f64 = a.iter().zip(&out.u).map(|(a, u)| a * u).sum::<f64>() + out.slack[ri];
            if lhs - b <= tol * (1.0 + b.abs()) || out.slack[ri] > tol {
                out.active.push(ri);
            }
            let c = self.rows.rows[ri].class.index();
            out.class_slack[c] = out.class_slack[c].max(out.slack[ri]);
        }
        for j in 0..nq {
            let v = self.velocity_limits[j];
            if out.u[j].abs() >= v - tol * (1.0 + v) {
                out.active.push(r + j);
            }
        }
        let elapsed = start.elapsed().as_secs_f64();
        out.solve_time = elapsed;
        let s = &mut self.stats;
        s.calls += 1;
        s.fallbacks += u64::from(out.status == FilterStatus::Fallback);
        s.total_time += elapsed;
        s.max_time = s.max_time.max(elapsed);
        s.total_iterations += u64::from(out.iterations);
        Ok(&self.output)
    }

    /// The ZBF rows at x: (∂h/∂q per row, R × nq row-major; bounds b, R; barrier values h, R), so
    /// that a·u ≥ b is each row's condition without slack. Rows switched off in this call have
    /// zero gradient, b = −1 and h = NaN. Does not touch the solver.
    pub fn constraint_rows(&mut self, x: &[f64], passivity: Option<(&[f64], f64)>) -> Result<(&[f64], &[f64], &[f64])> {
        self.check_inputs(x, None, passivity)?;
        let nq = self.scene.nq();
        self.rows.evaluate(&x[..nq], &self.obstacles, passivity);
        Ok((&self.rows.coef, &self.rows.bound, &self.rows.barrier))
    }

    /// The full QP (every row) for these inputs, densely, in Clarabel's form; [`Self::filter`]
    /// solves this problem or an exactly equivalent smaller one (see the module notes).
    pub fn qp_matrices(&mut self, x: &[f64], u_ref: &[f64], passivity: Option<(&[f64], f64)>) -> Result<QpMatrices> {
        self.check_inputs(x, Some(u_ref), passivity)?;
        let nq = self.scene.nq();
        self.evaluate(&x[..nq], passivity);
        self.assignment.clear();
        self.assignment.extend(0..self.rows.len());
        load(
            &mut self.full,
            &self.assignment,
            &self.rows,
            &self.row_penalty,
            u_ref,
            self.metric.as_ref(),
        )?;
        let (n, m, p, q, a, b) = self.full.dense();
        Ok(QpMatrices {
            n,
            m,
            nu: nq,
            p,
            q,
            a,
            b,
        })
    }
}
