//! Rapier worlds: the reduced-order rollout model (batch, parallel) and the full-dynamics plant.

pub mod plant;
pub mod rollout;
pub mod world;

pub use plant::{Plant, PlantConfig, DEFAULT_TAU_EXT_CUTOFF};
pub use rollout::{default_threads, RolloutBatch, RolloutConfig, RolloutModel};
pub use world::{EngineClock, Interaction, SimWorld};
