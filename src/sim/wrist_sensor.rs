//! The wrist force-torque sensor: the link it sits on and the robot links whose contact forces it
//! measures, for both contact paths.

use crate::model::scene::Scene;

/// The link carrying the wrist force-torque sensor (the scene's wrist-sensor role) and, per robot
/// link, whether the sensor measures the forces on it (the link is at or beyond it).
pub(crate) fn wrist_sensor(scene: &Scene) -> (usize, Vec<bool>) {
    let sensor_link = scene.roles.wrist_sensor;
    let beyond = (0..scene.robot.links.len())
        .map(|l| {
            let mut cur = Some(l);
            while let Some(c) = cur {
                if c == sensor_link {
                    return true;
                }
                cur = scene.robot.links[c].parent_joint.map(|j| scene.robot.joints[j].parent);
            }
            false
        })
        .collect();
    (sensor_link, beyond)
}
