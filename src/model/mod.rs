//! Robot and object models: URDF parsing, kinematic trees, rigid-body dynamics terms and the scene.

pub mod assembly;
pub(crate) mod collision_shape;
pub mod dynamics;
pub mod generated;
pub mod handle_frame;
pub mod inertials;
pub mod kinematics;
pub mod mesh;
mod rigid_bodies;
pub mod roles;
pub mod scene;
pub mod urdf;
pub mod visual;

pub use kinematics::{JointKind, JointLimits, KinematicTree};
pub use scene::Scene;

/// Gravitational acceleration of the world frame (m/s²), z up: the one value every model of the
/// robot and object (plant, rollouts, low-level controller, dynamics queries) is built with.
pub const GRAVITY: nalgebra::Vector3<f64> = nalgebra::Vector3::new(0.0, 0.0, -9.81);
