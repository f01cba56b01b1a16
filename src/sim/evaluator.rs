//! The per-step evaluator interface: what a rollout hands to whatever scores its steps (the cost of
//! the sampling-based controller), so that the simulation does not depend on what is scored.

use crate::error::Result;
use crate::model::kinematics::Frames;
use crate::model::scene::Scene;

/// What an evaluator sees of one rollout step.
pub struct StepView<'a> {
    /// State after the step, [q, q̇, o, ȯ].
    pub x: &'a [f64],
    /// Command applied during the step.
    pub u: &'a [f64],
    /// τ_ext measured in the step (35).
    pub tau_ext: &'a [f64],
    /// Whether the robot touched the object in the step.
    pub contact: bool,
    /// Robot link poses at the step's q.
    pub robot: &'a Frames,
    /// Object link poses at the step's o (current only if [`StepEvaluator::needs_object_frames`]).
    pub object: &'a Frames,
}

/// Scores each step of a rollout; the rollout sums the scores inside its worker.
pub trait StepEvaluator: Sync {
    /// Checks the evaluator against the scene before a batch runs.
    fn validate(&self, scene: &Scene) -> Result<()>;
    /// Whether [`Self::evaluate`] reads the object's link poses (they are computed only then).
    fn needs_object_frames(&self) -> bool;
    /// The score of one step.
    fn evaluate(&self, scene: &Scene, view: &StepView) -> f64;
}
