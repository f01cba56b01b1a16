//! Robot and object models: URDF parsing, kinematic trees, rigid-body dynamics terms and the scene.

pub mod assembly;
pub(crate) mod collision_shape;
pub mod description;
pub mod dynamics;
pub mod generated;
pub mod handle_frame;
pub mod inertials;
pub mod kinematics;
pub mod limit_bound;
pub mod mesh;
mod rigid_bodies;
pub mod roles;
pub mod safety_geometry;
pub mod scene;
pub mod urdf;
pub mod visual;

pub use dynamics::GRAVITY;
pub use kinematics::{JointKind, JointLimits, KinematicTree};
pub use limit_bound::{LimitBound, LimitBoundConfig};
pub use scene::Scene;
