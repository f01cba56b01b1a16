//! What a world measured of the robot touching the object in its last step, for both contact
//! paths: the interaction readings (contact flag, τ_ext, wrist wrench) and per-point contact reports.

/// Per-step interaction readings.
#[derive(Debug, Clone, PartialEq)]
pub struct Interaction {
    /// Any contact between the robot and the object (or its cabinet) carried force in this step.
    pub contact: bool,
    /// τ_ext = Σ J_cᵀ f_c over contacts on the robot, f_c the force acting on the robot (35).
    pub tau_ext: Vec<f64>,
    /// Force (world frame) and torque about the sensor origin (world frame) acting on the robot
    /// links at and beyond the wrist sensor.
    pub wrench: [f64; 6],
}

/// One robot–object contact point that carried force in the last step.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactReport {
    /// Index of the robot link (in the robot tree) whose collider touches.
    pub robot_link: usize,
    /// Index of the object link (in the object tree) whose collider touches.
    pub object_link: usize,
    /// Contact point, world frame (m).
    pub point: [f64; 3],
    /// Force acting on the robot at the point, world frame (N).
    pub force: [f64; 3],
}
