//! Small scenes for unit tests whose kinematics can be worked out by hand: a robot that slides
//! along x and turns about z, and a drawer in front of it.

use std::sync::Arc;

use super::rapier::{RobotColliders, RobotDrive, SimWorld, WorldConfig};
use super::reduced::ReducedConfig;
use super::servo::ServoGains;
use crate::model::scene::Scene;

/// Robot: `slide` (prismatic along world x, at height 0.5) carries `cart`; `turn` (revolute about
/// z) carries `arm`, whose ball collider of radius 0.05 sits 0.3 m along the arm's x, where the
/// fixed frame `tip` is. Spheres: `root` (radius 0.1) at the world origin raised 0.5, `probe`
/// (radius 0.05) 0.1 m along the arm.
pub const ROBOT: &str = r#"<robot name="probe">
  <link name="world"/>
  <link name="cart">
    <inertial><mass value="5"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
  </link>
  <link name="arm">
    <inertial><origin xyz="0.15 0 0"/><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><origin xyz="0.3 0 0"/><geometry><sphere radius="0.05"/></geometry></collision>
  </link>
  <link name="tip"/>
  <joint name="slide" type="prismatic">
    <parent link="world"/><child link="cart"/><origin xyz="0 0 0.5"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="100" velocity="1"/>
  </joint>
  <joint name="turn" type="revolute">
    <parent link="cart"/><child link="arm"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="50" velocity="2"/>
  </joint>
  <joint name="tip_joint" type="fixed">
    <parent link="arm"/><child link="tip"/><origin xyz="0.3 0 0"/>
  </joint>
  <sabre>
    <sphere name="root" link="world" xyz="0 0 0.5" radius="0.1"/>
    <sphere name="probe" link="arm" xyz="0.1 0 0" radius="0.05"/>
    <pair a="root" b="probe"/>
  </sabre>
</robot>"#;

/// Drawer: `front`, a 0.1 × 0.4 × 0.4 box, slides along the object's x on `pull` (0 to 1 m, dry
/// friction 0.5 N); the fixed frame `handle` sits 0.05 m before it (−x).
pub const DRAWER: &str = r#"<robot name="drawer">
  <link name="cabinet"/>
  <link name="front">
    <inertial><mass value="2"/><inertia ixx="0.05" ixy="0" ixz="0" iyy="0.05" iyz="0" izz="0.05"/></inertial>
    <collision><geometry><box size="0.1 0.4 0.4"/></geometry></collision>
  </link>
  <link name="handle"/>
  <joint name="pull" type="prismatic">
    <parent link="cabinet"/><child link="front"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="1" effort="100" velocity="1"/>
    <dynamics damping="0" friction="0.5"/>
  </joint>
  <joint name="handle_joint" type="fixed">
    <parent link="front"/><child link="handle"/><origin xyz="-0.05 0 0"/>
  </joint>
</robot>"#;

/// Lift: the same box on a frictionless vertical joint (0 to 0.5 m): gravity pulls it down.
pub const LIFT: &str = r#"<robot name="lift">
  <link name="cabinet"/>
  <link name="front">
    <inertial><mass value="2"/><inertia ixx="0.05" ixy="0" ixz="0" iyy="0.05" iyz="0" izz="0.05"/></inertial>
    <collision><geometry><box size="0.1 0.4 0.4"/></geometry></collision>
  </link>
  <joint name="rise" type="prismatic">
    <parent link="cabinet"/><child link="front"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="0.5" effort="100" velocity="1"/>
    <dynamics damping="0" friction="0"/>
  </joint>
</robot>"#;

/// The object's base sits at (1, 0, 0.5), unrotated: the drawer front's centre is at x = 1 + o.
pub const OBJECT_POSE: [f64; 6] = [1.0, 0.0, 0.5, 0.0, 0.0, 0.0];

/// The probe robot with the drawer.
pub fn probe_and_drawer() -> Arc<Scene> {
    Arc::new(Scene::from_urdf_strings(ROBOT, DRAWER, Some(&OBJECT_POSE)).expect("test scene"))
}

/// The probe robot with the lift.
pub fn probe_and_lift() -> Arc<Scene> {
    Arc::new(Scene::from_urdf_strings(ROBOT, LIFT, Some(&OBJECT_POSE)).expect("test scene"))
}

/// State [q, q̇, o, ȯ] of the probe scenes.
pub fn state(q: [f64; 2], qd: [f64; 2], o: f64, od: f64) -> Vec<f64> {
    vec![q[0], q[1], qd[0], qd[1], o, od]
}

/// Step of the test worlds (the rollout model's).
pub const DT: f64 = 0.015;
/// Servo bandwidth Λ of the test worlds (1/s).
pub const BANDWIDTH: f64 = 40.0;

/// A kinematic-servo world configuration with integral gain Λ_I.
pub fn servo_config(integral_gain: f64, skip_quiescent: bool) -> WorldConfig {
    WorldConfig {
        dt: DT,
        colliders: RobotColliders::All,
        drive: RobotDrive::KinematicServo {
            bandwidth: BANDWIDTH,
            integral_gain,
            integral_limit: 0.1,
            skip_quiescent,
        },
        contact_friction: 0.2,
        solver_iterations: 1,
    }
}

/// A world of `scene` under `config`, placed at `x`.
pub fn world_at(scene: &Arc<Scene>, config: &WorldConfig, x: &[f64]) -> SimWorld {
    let mut world = SimWorld::new(scene.clone(), config).expect("test world");
    world.set_state(x);
    world
}

/// The reduced contact path's configuration matching [`servo_config`] without integral action.
pub fn reduced_config() -> ReducedConfig {
    ReducedConfig {
        dt: DT,
        gains: ServoGains {
            bandwidth: BANDWIDTH,
            integral_gain: 0.0,
            integral_limit: 0.1,
        },
        skip_quiescent: false,
        contact_friction: 0.2,
        iterations: 1,
    }
}
