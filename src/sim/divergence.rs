//! When a simulation has diverged: the speed beyond which each joint's motion is no longer physical.

use crate::model::kinematics::JointLimits;
use crate::model::scene::Scene;

/// A joint moving faster than this multiple of its velocity limit (or, for the object's joints,
/// than [`MAX_OBJECT_SPEED`]) means the integration diverged: no torque within the effort limits
/// produces it.
pub const DIVERGENCE_VELOCITY_FACTOR: f64 = 20.0;

/// The fastest (rad/s or m/s) an object joint may move before the simulation calls it diverged.
pub const MAX_OBJECT_SPEED: f64 = 100.0;

/// (name, position limits, divergence speed bound) of every robot joint, then every object joint.
pub fn joint_speed_bounds(scene: &Scene) -> Vec<(String, JointLimits, f64)> {
    let robot = scene.robot.active_joint_names().into_iter().zip(scene.robot_limits());
    let object = scene.object.active_joint_names().into_iter().zip(scene.object_limits());
    robot
        .map(|(n, l)| (n, l, DIVERGENCE_VELOCITY_FACTOR * l.velocity))
        .chain(object.map(|(n, l)| (n, l, MAX_OBJECT_SPEED)))
        .collect()
}

/// The index (into the joints of [`joint_speed_bounds`]) of the first joint of state `x` moving
/// beyond its bound, if any.
pub fn diverged_joint(x: &[f64], nq: usize, no: usize, bounds: &[f64]) -> Option<usize> {
    let speeds = x[nq..2 * nq].iter().chain(&x[2 * nq + no..2 * (nq + no)]);
    // NaN speeds count as diverged too.
    speeds.zip(bounds).position(|(v, b)| v.abs() > *b || v.is_nan())
}
