//! Settings of the safety filter: constraint classes and, per class, ZBF rate, slack penalty, margin and switch.

use crate::error::{Result, SabreError};
use crate::model::LimitBoundConfig;

/// The kinds of constraint the filter enforces; each has its own rate γ, penalty Γ, margin Δ and switch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ConstraintClass {
    /// (37) on every joint with finite position limits.
    JointLimits,
    /// (39) on the sphere pairs declared in the robot's `<sabre>` extension.
    SelfCollision,
    /// (40) planar reach of a frame from the arm base.
    ArmReach,
    /// Base position box (Cartesian limits, Sec. VI-A): one row on base x, one on base y.
    BaseBox,
    /// Sphere obstacles added at run time, against every collision sphere of the robot.
    Obstacles,
    /// (56) energy-tank passivity row; its rate γ is the paper's α.
    Passivity,
}

impl ConstraintClass {
    pub const ALL: [ConstraintClass; 6] = [
        ConstraintClass::JointLimits,
        ConstraintClass::SelfCollision,
        ConstraintClass::ArmReach,
        ConstraintClass::BaseBox,
        ConstraintClass::Obstacles,
        ConstraintClass::Passivity,
    ];

    pub const COUNT: usize = 6;

    pub fn index(self) -> usize {
        self as usize
    }

    /// The snake-case name used in row names, Python dictionaries and reports.
    pub fn name(self) -> &'static str {
        match self {
            ConstraintClass::JointLimits => "joint_limits",
            ConstraintClass::SelfCollision => "self_collision",
            ConstraintClass::ArmReach => "arm_reach",
            ConstraintClass::BaseBox => "base_box",
            ConstraintClass::Obstacles => "obstacles",
            ConstraintClass::Passivity => "passivity",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.name() == name)
    }
}

/// One value per constraint class, indexed by [`ConstraintClass`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PerClass<T>(pub [T; ConstraintClass::COUNT]);

impl<T: Copy> PerClass<T> {
    pub fn get(&self, class: ConstraintClass) -> T {
        self.0[class.index()]
    }
    pub fn set(&mut self, class: ConstraintClass, value: T) {
        self.0[class.index()] = value;
    }
}

/// Settings of [`super::SafetyFilter`]. Classes are in [`ConstraintClass::ALL`] order.
///
/// Units: every ZBF row reads ∂h/∂q · u ≥ −γ (h − Δ), so γ is in 1/s and Δ in the units of that
/// class's h: rad for joint limits (h ≈ distance to the nearer limit), m for the base box (same
/// form), m² for self-collision, arm reach and obstacles (h = ½(d² − d_min²) ≈ d_min · clearance),
/// J for passivity (h = S − ε).
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyConfig {
    /// ZBF rate γ (1/s) per class; the passivity entry is α of (56).
    pub gamma: PerClass<f64>,
    /// Slack penalty Γ per class (paper Table I).
    pub penalty: PerClass<f64>,
    /// Conservative margin Δ ≥ 0 per class (Remark 1).
    pub margin: PerClass<f64>,
    /// Which classes get rows; a disabled class has no rows at all (the QP is built without them).
    pub enabled: PerClass<bool>,
    /// Base box [x_min, x_max, y_min, y_max] (m) on the first two coordinates of q (base x, y).
    pub base_box: [f64; 4],
    /// Tank floor ε (J) of the passivity row.
    pub tank_floor: f64,
    /// Number of obstacle slots; the QP has rows for all of them from the start.
    pub max_obstacles: usize,
    /// Interior-point iteration bound of one solve.
    pub max_iterations: u32,
    /// Clarabel's feasibility and duality-gap tolerance.
    pub tolerance: f64,
    /// A row counts as active when its residual or its slack is below / above this.
    pub active_tolerance: f64,
    /// Take the exact shortcuts of `safety::filter` (projection, remembered active set, rows that
    /// cannot bind left out); off, every call runs Clarabel on the full QP. Same solution either way.
    pub screening: bool,
    /// Weight λ (1/m²) of the `task_frame`'s velocity in the metric of a single FILTER-QP call
    /// (beyond the paper): the objective is ½‖ũ − u‖²_M with M = (I + λJ_wᵀJ_w) / (1 + λσ²_max(J_w)),
    /// J_w = [J_v; ℓJ_ω] the frame's Jacobian, ℓ = [`TASK_ANGULAR_LENGTH`]. A correction that keeps
    /// the hand on its path (move the base, fold the elbow) is then cheaper than one that moves the
    /// hand, and none costs more than in the paper's ‖ũ − u‖² (0, the default for `filter`).
    pub task_weight: f64,
    /// λ of the Sequential FILTER-QP (Algorithm 1): the filtered sequence becomes the plan, and a
    /// plan corrected by moving the hand off its path loses the handle.
    pub sequential_task_weight: f64,
    /// The robot frame whose velocity `task_weight` protects; empty: the scene's tool frame (none:
    /// the paper's plain metric).
    pub task_frame: String,
    /// The hard joint-limit bound the cascade applies to every command after the filter (beyond the
    /// paper): margins inside the URDF limits and the deceleration of an unshaped joint's stop.
    pub limit_bound: LimitBoundConfig,
}

/// ℓ (m): a hand turning at 1 rad/s weighs like a hand moving at ℓ m/s in the task metric.
pub const TASK_ANGULAR_LENGTH: f64 = 0.1;

impl Default for SafetyConfig {
    /// γ = 10/s for every kinematic class: a joint approaches its limit no faster than 10 × its
    /// distance to it, so braking from the 2.2 rad/s Panda limit starts ≈ 0.2 rad out, and at the
    /// outer loop's 15 ms step the discrete decay factor 1 − γ dt = 0.85 stays well inside (0, 1).
    /// α = 1/s for passivity (paper Sec. VI-C; 1/dt chatters). Γ from Table I.
    ///
    /// Margins follow Remark 1: the slack must stay below γΔ. A single row pressed by a command
    /// whose deficit at the boundary is a·u_ref takes δ = a·u_ref / (Γ‖a‖² + 1). For a joint
    /// limit (‖a‖ ≈ 1 there, Γ = 10) pushed at the full 2.6 rad/s that is δ ≈ 0.24, so
    /// Δ = 0.03 rad keeps the true limit. For the base box (Γ = 100, 1 m/s) δ ≤ 0.01 and Δ = 0.01 m
    /// is ample; self-collision, reach and obstacles (Γ = 100, h in m²) get Δ = 0.01 m², about
    /// 1–3 cm of clearance for their 0.3–1 m distances.
    fn default() -> Self {
        Self {
            gamma: PerClass([10.0, 10.0, 10.0, 10.0, 10.0, 1.0]),
            penalty: PerClass([10.0, 100.0, 100.0, 100.0, 100.0, 100.0]),
            margin: PerClass([0.03, 0.01, 0.01, 0.01, 0.01, 0.0]),
            enabled: PerClass([true; ConstraintClass::COUNT]),
            base_box: [-2.0, 2.0, -2.0, 2.0],
            tank_floor: 2.0,
            max_obstacles: 8,
            max_iterations: 50,
            tolerance: 1e-8,
            active_tolerance: 1e-6,
            screening: true,
            task_weight: 0.0,
            sequential_task_weight: 100.0,
            task_frame: String::new(),
            limit_bound: LimitBoundConfig::default(),
        }
    }
}

/// Upper bound on obstacle slots: each slot adds one row per robot sphere to every solve.
pub const MAX_OBSTACLE_SLOTS: usize = 64;

impl SafetyConfig {
    /// Checks every number; called by the filter's constructor.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: String, detail: String| Err(SabreError::invalid(what, detail));
        for class in ConstraintClass::ALL {
            let name = class.name();
            let (g, p, m) = (self.gamma.get(class), self.penalty.get(class), self.margin.get(class));
            if !(g.is_finite() && g > 0.0) {
                return bad(format!("gamma[{name}]"), format!("must be finite and positive, got {g}"));
            }
            if !(p.is_finite() && p > 0.0) {
                return bad(format!("penalty[{name}]"), format!("must be finite and positive, got {p}"));
            }
            if !(m.is_finite() && m >= 0.0) {
                return bad(format!("margin[{name}]"), format!("must be finite and non-negative, got {m}"));
            }
        }
        let [x0, x1, y0, y1] = self.base_box;
        if !self.base_box.iter().all(|v| v.is_finite()) || x0 >= x1 || y0 >= y1 {
            return bad(
                "base_box".into(),
                format!("needs finite x_min < x_max and y_min < y_max, got {:?}", self.base_box),
            );
        }
        if !(self.tank_floor.is_finite() && self.tank_floor >= 0.0) {
            return bad(
                "tank_floor".into(),
                format!("must be finite and non-negative, got {}", self.tank_floor),
            );
        }
        if self.max_obstacles > MAX_OBSTACLE_SLOTS {
            return bad(
                "max_obstacles".into(),
                format!("at most {MAX_OBSTACLE_SLOTS}, got {}", self.max_obstacles),
            );
        }
        if self.max_iterations == 0 {
            return bad("max_iterations".into(), "must be at least 1".into());
        }
        for (name, w) in [
            ("task_weight", self.task_weight),
            ("sequential_task_weight", self.sequential_task_weight),
        ] {
            if !(w.is_finite() && w >= 0.0) {
                return bad(name.into(), format!("must be finite and non-negative, got {w}"));
            }
        }
        for (name, v) in [("tolerance", self.tolerance), ("active_tolerance", self.active_tolerance)] {
            if !(v.is_finite() && v > 0.0 && v < 1.0) {
                return bad(name.into(), format!("must be within (0, 1), got {v}"));
            }
        }
        self.limit_bound.validate()
    }
}
