//! The quiescence test: a step is skipped when the object is held at rest and no robot contact
//! body can reach it within the step; bounding-sphere geometry for that test.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::model::kinematics::{Frames, KinematicTree, Shape};
use crate::model::scene::Scene;

/// Radius of a sphere about the primitive's centre that contains it.
fn bounding_radius(shape: &Shape) -> f64 {
    match *shape {
        Shape::Box { half_extents } => half_extents.norm(),
        Shape::Sphere { radius } => radius,
        Shape::Cylinder { radius, half_length } => (radius * radius + half_length * half_length).sqrt(),
        Shape::Capsule { radius, half_length } => radius + half_length,
        Shape::Hull { half_extents, .. } => half_extents.norm(),
    }
}

/// Distance from `point` to a primitive placed at `pose` (exact for boxes and spheres, through the
/// bounding sphere otherwise; never more than the true distance).
pub(crate) fn distance_to_shape(pose: &Isometry3<f64>, shape: &Shape, point: &Point3<f64>) -> f64 {
    let local = pose.inverse_transform_point(point);
    match *shape {
        Shape::Box { half_extents } => {
            let outside = Vector3::new(
                (local.x.abs() - half_extents.x).max(0.0),
                (local.y.abs() - half_extents.y).max(0.0),
                (local.z.abs() - half_extents.z).max(0.0),
            );
            outside.norm()
        }
        _ => (local.coords.norm() - bounding_radius(shape)).max(0.0),
    }
}

/// One bounding sphere per link with collision geometry (of the links `include` accepts).
pub(crate) fn link_spheres(tree: &KinematicTree, include: &dyn Fn(usize) -> bool) -> Vec<(usize, Point3<f64>, f64)> {
    let mut out = Vec::new();
    for (link, l) in tree.links.iter().enumerate() {
        if l.collisions.is_empty() || !include(link) {
            continue;
        }
        let centers: Vec<Point3<f64>> = l
            .collisions
            .iter()
            .map(|c| Point3::from(c.origin.translation.vector))
            .collect();
        let center = Point3::from(centers.iter().map(|c| c.coords).sum::<Vector3<f64>>() / centers.len() as f64);
        let radius = l
            .collisions
            .iter()
            .zip(&centers)
            .map(|(c, p)| (p - center).norm() + bounding_radius(&c.shape))
            .fold(0.0, f64::max);
        out.push((link, center, radius));
    }
    out
}

/// What the quiescence test needs of a scene: bounding spheres of the robot's contact links, the
/// object's collision primitives and its joints' dry friction.
#[derive(Debug, Clone)]
pub struct Quiescence {
    /// (link, centre in the link frame, radius) of each robot link with contact geometry.
    robot_spheres: Vec<(usize, Point3<f64>, f64)>,
    /// Object collision primitives (link, pose in the link frame, shape).
    object_shapes: Vec<(usize, Isometry3<f64>, Shape)>,
    object_friction: Vec<f64>,
}

impl Quiescence {
    /// The test for `scene` with the robot links that `include` accepts as contact bodies.
    pub fn new(scene: &Scene, include: &dyn Fn(usize) -> bool) -> Self {
        Self {
            robot_spheres: link_spheres(&scene.robot, include),
            object_shapes: scene
                .object
                .links
                .iter()
                .enumerate()
                .flat_map(|(link, l)| l.collisions.iter().map(move |c| (link, c.origin, c.shape.clone())))
                .collect(),
            object_friction: scene
                .object
                .active_joints
                .iter()
                .map(|&j| scene.object.joints[j].friction)
                .collect(),
        }
    }

    /// True when the object (at `o`, moving at `od`) is at rest and statically held (dry friction at
    /// least its gravity torque, or gravity pressing it onto a limit), and no robot contact body can
    /// reach any object link within a step of `dt` (bounding spheres, with `margin` and each body's
    /// travel at the joint velocities `qd`). `frames` are the robot's at the step's start;
    /// `jacobian` is scratch space; `first` is the body to test first, and is left at the one
    /// that failed the test (the caller keeps it from step to step).
    #[allow(clippy::too_many_arguments)]
    pub fn holds(
        &self,
        scene: &Scene,
        frames: &Frames,
        qd: &[f64],
        o: &[f64],
        od: &[f64],
        dt: f64,
        margin: f64,
        jacobian: &mut Vec<f64>,
        first: &mut usize,
    ) -> bool {
        if !od.iter().all(|v| v.abs() < 1e-9) {
            return false;
        }
        // Rest is kept only if no generalized force beats the dry friction, or a limit takes it.
        let g = crate::model::dynamics::gravity_torque(&scene.object, &scene.object_pose, o, &crate::model::GRAVITY);
        let limits = scene.object_limits();
        for (i, &oi) in o.iter().enumerate() {
            // g is the torque that holds the object still; gravity itself pushes with −g.
            let push = -g[i];
            let held_by_friction = push.abs() <= self.object_friction[i];
            let on_lower = (oi - limits[i].lower).abs() <= 1e-6 && push <= 0.0;
            let on_upper = (oi - limits[i].upper).abs() <= 1e-6 && push >= 0.0;
            // Beyond a limit the limit itself moves the object back, whatever holds it.
            let outside = oi < limits[i].lower - 1e-6 || oi > limits[i].upper + 1e-6;
            if outside || !(held_by_friction || on_lower || on_upper) {
                return false;
            }
        }
        let object_poses = scene.object.link_poses(&scene.object_pose, o);
        jacobian.resize(6 * scene.nq(), 0.0);
        // Starting from the body that kept the last step from being skipped: it usually does so
        // again, and the answer does not depend on the order.
        let n = self.robot_spheres.len();
        let start = (*first).min(n.saturating_sub(1));
        for index in (start..n).chain(0..start) {
            let (link, center, radius) = self.robot_spheres[index];
            let c = frames.poses[link] * center;
            // A body in reach of some primitive decides at the first such primitive (in contact,
            // nearly always), before the nearest distance is known.
            let mut nearest = f64::INFINITY;
            for (olink, origin, shape) in &self.object_shapes {
                let distance = distance_to_shape(&(object_poses[*olink] * origin), shape, &c);
                if distance < radius + margin {
                    *first = index;
                    return false;
                }
                nearest = nearest.min(distance);
            }
            // Travel bound of this body over the step: its link's linear speed at the centre (only
            // needed when the static clearance does not already decide).
            scene.robot.frames_jacobian_into(frames, link, &c, jacobian);
            let mut v = Vector3::zeros();
            for (col, &rate) in qd.iter().enumerate() {
                v += Vector3::new(jacobian[6 * col], jacobian[6 * col + 1], jacobian[6 * col + 2]) * rate;
            }
            if nearest < radius + v.norm() * dt + margin {
                *first = index;
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crate::model::scene::Scene;
    use crate::sim::test_scene::{probe_and_drawer, probe_and_lift, servo_config, state, world_at};

    /// Whether one step from `x` under command `u` went through Rapier's pipeline.
    fn engine_ran(scene: &Arc<Scene>, x: Vec<f64>, u: [f64; 2]) -> bool {
        let mut world = world_at(scene, &servo_config(0.0, true), &x);
        let mut out = x.clone();
        world.step_once(&u, &mut out);
        world.engine_clock().steps == 1
    }

    // The drawer's front face is at x = 0.95; the arm's ball (radius 0.05) at x = s + 0.3; a body
    // is clear when its centre is at least radius + margin (0.01 prediction + 0.02) = 0.08 away.

    #[test]
    fn far_still_robot_and_drawer_held_by_friction_skip_the_engine() {
        assert!(!engine_ran(
            &probe_and_drawer(),
            state([-0.5, 0.0], [0.0, 0.0], 0.0, 0.0),
            [0.0, 0.0]
        ));
    }

    #[test]
    fn robot_touching_the_object_runs_the_engine() {
        assert!(engine_ran(
            &probe_and_drawer(),
            state([0.6, 0.0], [0.0, 0.0], 0.0, 0.0),
            [0.0, 0.0]
        ));
    }

    #[test]
    fn robot_whose_travel_can_reach_the_object_runs_the_engine() {
        // 0.085 from the face: clear at rest, but at 1 m/s it covers 0.015 within the step.
        assert!(!engine_ran(
            &probe_and_drawer(),
            state([0.565, 0.0], [0.0, 0.0], 0.0, 0.0),
            [0.0, 0.0]
        ));
        assert!(engine_ran(
            &probe_and_drawer(),
            state([0.565, 0.0], [1.0, 0.0], 0.0, 0.0),
            [1.0, 0.0]
        ));
    }

    #[test]
    fn moving_object_runs_the_engine() {
        assert!(engine_ran(
            &probe_and_drawer(),
            state([-0.5, 0.0], [0.0, 0.0], 0.2, 0.1),
            [0.0, 0.0]
        ));
    }

    #[test]
    fn object_beyond_its_limit_runs_the_engine() {
        // Held by friction and far from the robot, but outside its travel: the limit moves it back.
        let scene = probe_and_drawer();
        let upper = scene.object_limits()[0].upper;
        assert!(engine_ran(
            &scene,
            state([-0.5, 0.0], [0.0, 0.0], upper + 0.3, 0.0),
            [0.0, 0.0]
        ));
        assert!(engine_ran(&scene, state([-0.5, 0.0], [0.0, 0.0], -0.3, 0.0), [0.0, 0.0]));
    }

    #[test]
    fn object_gravity_does_not_hold_runs_the_engine_unless_on_a_limit() {
        let scene = probe_and_lift();
        // Frictionless vertical joint: mid-travel gravity moves it; at the lower limit it rests.
        assert!(engine_ran(&scene, state([-0.5, 0.0], [0.0, 0.0], 0.25, 0.0), [0.0, 0.0]));
        assert!(!engine_ran(&scene, state([-0.5, 0.0], [0.0, 0.0], 0.0, 0.0), [0.0, 0.0]));
    }
}
