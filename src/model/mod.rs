//! Robot and object models: URDF parsing, kinematic trees, rigid-body dynamics terms and the scene.

pub mod dynamics;
pub mod kinematics;
pub mod scene;
pub mod urdf;

pub use kinematics::{JointKind, JointLimits, KinematicTree};
pub use scene::Scene;
