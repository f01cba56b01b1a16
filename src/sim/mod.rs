//! Rapier worlds: the reduced-order rollout model (batch, parallel) and the full-dynamics plant.

pub mod evaluator;
pub mod plant;
pub mod rollout;
#[cfg(test)]
pub(crate) mod test_scene;
pub mod world;

pub use evaluator::{StepEvaluator, StepView};
pub use plant::{Plant, PlantConfig, DEFAULT_TAU_EXT_CUTOFF};
pub use rollout::{default_threads, RolloutBatch, RolloutConfig, RolloutModel, MAX_BATCH_ELEMENTS};
pub use world::{EngineClock, Interaction, SimWorld};
