//! The control cascade; for now the low-level joint velocity controller that drives the plant.

pub mod low_level;

pub use low_level::{follow_reference, LowLevelConfig, LowLevelController, TrackTrace};
