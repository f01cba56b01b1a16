//! Simulation: the reduced-order rollout model (batch, parallel; its contacts through Rapier's
//! pipeline or the reduced path solved in sabre) and the full-dynamics plant on Rapier.

pub mod divergence;
pub mod engine_clock;
pub mod evaluator;
pub mod interaction;
pub mod plant;
pub(crate) mod proxy;
pub mod quiescence;
pub mod rapier;
pub mod reduced;
pub mod rollout;
pub mod rollout_world;
pub mod servo;
#[cfg(test)]
pub(crate) mod test_scene;
pub(crate) mod wrist_sensor;

pub use divergence::{diverged_joint, joint_speed_bounds, DIVERGENCE_VELOCITY_FACTOR, MAX_OBJECT_SPEED};
pub use engine_clock::EngineClock;
pub use evaluator::{StepEvaluator, StepView};
pub use interaction::{ContactReport, Interaction};
pub use plant::{Plant, PlantConfig, DEFAULT_TAU_EXT_CUTOFF};
pub use rapier::SimWorld;
pub use reduced::{ReducedConfig, ReducedWorld};
pub use rollout::{default_threads, ContactModel, RolloutBatch, RolloutConfig, RolloutModel, MAX_BATCH_ELEMENTS};
pub use rollout_world::RolloutWorld;
