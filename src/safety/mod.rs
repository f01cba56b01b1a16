//! Safety and passivity (Sec. III-B/C, IV-B/C): ZBF constraints, the FILTER-QP, its sequential form and the energy tank.
//!
//! Every constraint is a zeroing barrier h(q) ≥ 0 turned into a row affine in the command
//! u = q̇*: ∂h/∂q · u + δ ≥ −γ (h − Δ) (19, Remark 1), with a slack δ ≥ 0 per row penalised by the
//! class's Γ. Input limits are hard bounds. Pure Rust; the Python bindings live in `crate::python`.

mod active_set;
pub mod config;
mod constraints;
pub mod filter;
mod output;
mod qp;
pub mod sequential;
pub mod tank;
mod task_metric;

pub use config::{ConstraintClass, PerClass, SafetyConfig, MAX_OBSTACLE_SLOTS, TASK_ANGULAR_LENGTH};
pub use constraints::Obstacle;
pub use filter::SafetyFilter;
pub use output::{FilterOutput, FilterStats, FilterStatus, QpMatrices, SolveMethod};
pub use sequential::SequenceOutput;
pub use tank::{EnergyTank, RefillConfig};
