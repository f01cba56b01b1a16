//! Driving the robot: the kinematic servo's integration, the velocity command, joint torques, the
//! object lock, and setting or reading the state x = [q, q̇, o, ȯ] (proxies placed at the robot's
//! forward kinematics).

use nalgebra::Isometry3;
use rapier3d_f64::prelude::*;

use super::{pose_to_rapier, DofRef, RobotDrive, SimWorld};
use crate::sim::servo::ServoGains;

impl SimWorld {
    /// Rate-limits the kinematic servo's commands (see
    /// [`crate::sim::servo::ServoLimits::cap_acceleration`]);
    /// before the world is copied (its copies share the layout). Errors: a bad bound, or a world
    /// already copied.
    pub fn cap_servo_acceleration(&mut self, caps: &[f64]) -> crate::error::Result<()> {
        let dt = self.dt();
        std::sync::Arc::get_mut(&mut self.layout)
            .ok_or_else(|| crate::error::SabreError::invalid("command_acceleration", "set before the world is copied"))?
            .servo_limits
            .cap_acceleration(caps, dt)
    }

    fn set_tree_state(
        multibodies: &mut MultibodyJointSet,
        bodies: &mut RigidBodySet,
        handle: MultibodyJointHandle,
        dofs: &[DofRef],
        q: &[f64],
        qd: &[f64],
        displacement: &mut Vec<f64>,
    ) {
        let (mb, _) = multibodies.get_mut(handle).expect("multibody");
        displacement.clear();
        displacement.resize(mb.ndofs(), 0.0);
        for (i, d) in dofs.iter().enumerate() {
            let current = d.value(mb);
            displacement[d.dof] = q[i] - current;
        }
        mb.apply_displacements(displacement);
        {
            let mut v = mb.generalized_velocity_mut();
            v.fill(0.0);
            for (i, d) in dofs.iter().enumerate() {
                v[d.dof] = qd[i];
            }
        }
        mb.forward_kinematics(bodies, false);
        mb.update_rigid_bodies(bodies, true);
    }

    /// Places robot and object at state x = [q, q̇, o, ȯ] (x must be validated by the caller).
    pub fn set_state(&mut self, x: &[f64]) {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let layout = self.layout.clone();
        match layout.robot_handle {
            Some(handle) => Self::set_tree_state(
                &mut self.state.multibody_joints,
                &mut self.state.bodies,
                handle,
                &layout.robot_dofs,
                &x[..nq],
                &x[nq..2 * nq],
                &mut self.scratch,
            ),
            None => {
                self.state.servo.reset(&x[..nq], &x[nq..2 * nq]);
                self.place_proxies();
            }
        }
        Self::set_tree_state(
            &mut self.state.multibody_joints,
            &mut self.state.bodies,
            layout.object_handle,
            &layout.object_dofs,
            &x[2 * nq..2 * nq + no],
            &x[2 * nq + no..],
            &mut self.scratch,
        );
        self.state.servo.command.iter_mut().for_each(|v| *v = 0.0);
        self.state.last.contact = false;
        self.state.last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        self.state.last.wrench = [0.0; 6];
    }

    /// Places every proxy body at the forward kinematics of the servo's configuration with the
    /// velocity that its joint velocities give it.
    fn place_proxies(&mut self) {
        let frames = &mut self.dynamics.frames;
        let qd = &self.state.servo.qd;
        self.scene
            .robot
            .update_frames(&Isometry3::identity(), &self.state.servo.q, frames);
        for &(link, body, com) in &self.layout.proxies {
            let pose = frames.poses[link];
            let com_world = pose * com;
            self.scene
                .robot
                .frames_jacobian_into(frames, link, &com_world, &mut self.jacobian);
            let mut twist = [0.0; 6];
            for (c, &v) in qd.iter().enumerate() {
                for (r, t) in twist.iter_mut().enumerate() {
                    *t += self.jacobian[6 * c + r] * v;
                }
            }
            let rb = &mut self.state.bodies[body];
            rb.set_position(pose_to_rapier(&pose), true);
            rb.set_linvel(Vector::new(twist[0], twist[1], twist[2]), true);
            rb.set_angvel(Vector::new(twist[3], twist[4], twist[5]), true);
        }
    }

    /// Writes the current state into `x` (length nx): the engine's own velocities, which for the
    /// object in a servo world are not its motion (see [`Self::step_once`], which reports that).
    pub fn read_state(&self, x: &mut [f64]) {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let mbs = &self.state.multibody_joints;
        match self.layout.robot_handle {
            Some(handle) => {
                let (robot, _) = mbs.get(handle).expect("robot");
                let rv = robot.generalized_velocity();
                for (i, d) in self.layout.robot_dofs.iter().enumerate() {
                    x[i] = d.value(robot);
                    x[nq + i] = rv[d.dof];
                }
            }
            None => {
                x[..nq].copy_from_slice(&self.state.servo.q);
                x[nq..2 * nq].copy_from_slice(&self.state.servo.qd);
            }
        }
        let (object, _) = mbs.get(self.layout.object_handle).expect("object");
        let ov = object.generalized_velocity();
        for (i, d) in self.layout.object_dofs.iter().enumerate() {
            x[2 * nq + i] = d.value(object);
            x[2 * nq + no + i] = ov[d.dof];
        }
    }

    /// Sets the joint velocity command of the next step for the servo drives, projected onto the
    /// joint velocity limits.
    pub fn set_velocity_command(&mut self, u: &[f64]) {
        let layout = self.layout.clone();
        self.state.servo.set_command(u, &layout.servo_limits);
        if let (Some(handle), RobotDrive::MultibodyServo { bandwidth }) = (layout.robot_handle, layout.drive) {
            let (mb, _) = self.state.multibody_joints.get_mut(handle).expect("robot");
            for (i, d) in layout.robot_dofs.iter().enumerate() {
                if let Some(link) = mb.link_mut(d.link_id) {
                    link.joint
                        .data
                        .set_motor_velocity(d.axis, self.state.servo.command[i], bandwidth);
                }
            }
        }
    }

    /// Applies joint torques (clamped to the effort limits) for the next step as equal and opposite
    /// wrenches on each joint's child and parent bodies, which Rapier maps to exactly τ_i on that joint.
    pub fn apply_joint_torques(&mut self, tau: &[f64], applied: &mut [f64]) {
        let Some(handle) = self.layout.robot_handle else { return };
        let bodies = &mut self.state.bodies;
        for (_, rb) in bodies.iter_mut() {
            rb.reset_forces(false);
            rb.reset_torques(false);
        }
        let (mb, _) = self.state.multibody_joints.get(handle).expect("robot");
        for (i, d) in self.layout.robot_dofs.iter().enumerate() {
            let limit = self.layout.effort_limits[i];
            let t = tau[i].clamp(-limit, limit);
            applied[i] = t;
            if t == 0.0 {
                continue;
            }
            let link = mb.link(d.link_id).expect("link");
            let frame = *link.local_to_world() * link.joint().data.local_frame2;
            let axis = frame.rotation * Vector::X;
            let origin = frame.translation;
            match d.axis {
                JointAxis::AngX => {
                    bodies[d.child_body].add_torque(axis * t, true);
                    bodies[d.parent_body].add_torque(-axis * t, true);
                }
                _ => {
                    bodies[d.child_body].add_force_at_point(axis * t, origin, true);
                    bodies[d.parent_body].add_force_at_point(-axis * t, origin, true);
                }
            }
        }
    }

    /// Locks (or releases) the object's joints in place: a stuck door or drawer. The joint's limits
    /// collapse onto its current value (a hard constraint that transmits any force), then return.
    pub fn hold_object(&mut self, hold: bool) {
        let object_limits = self.scene.object_limits();
        let (mb, _) = self
            .state
            .multibody_joints
            .get_mut(self.layout.object_handle)
            .expect("object");
        for (i, d) in self.layout.object_dofs.iter().enumerate() {
            let value = d.value(mb);
            if let Some(link) = mb.link_mut(d.link_id) {
                let limits = if hold {
                    [value, value]
                } else {
                    [object_limits[i].lower, object_limits[i].upper]
                };
                link.joint.data.set_limits(d.axis, limits);
            }
        }
        if hold {
            let mut v = mb.generalized_velocity_mut();
            for d in &self.layout.object_dofs {
                v[d.dof] = 0.0;
            }
        }
    }

    /// One step of the kinematic servo (see [`ServoState::advance`]); the proxies start the step
    /// where the robot is, moving as it will move during the step.
    pub(super) fn advance_kinematic_robot(&mut self, gains: &ServoGains) {
        let layout = self.layout.clone();
        self.state.servo.advance(
            gains,
            &layout.servo_limits,
            &self.scene,
            &self.state.last.tau_ext,
            self.params.dt,
            &mut self.dynamics,
            &mut self.mass_matrix,
            &mut self.gravity_torque,
        );
        self.place_proxies();
        self.state.servo.commit();
    }

    pub(super) fn read_robot_q(&self, q: &mut [f64]) {
        match self.layout.robot_handle {
            Some(handle) => {
                let (robot, _) = self.state.multibody_joints.get(handle).expect("robot");
                for (i, d) in self.layout.robot_dofs.iter().enumerate() {
                    q[i] = d.value(robot);
                }
            }
            None => q.copy_from_slice(&self.state.servo.q),
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::sim::test_scene::{probe_and_drawer, servo_config, state, world_at, BANDWIDTH, DT};

    /// Runs `steps` steps under the constant command `u` from `x0`; returns the state after each.
    fn run(integral_gain: f64, x0: &[f64], u: [f64; 2], steps: usize) -> Vec<Vec<f64>> {
        let scene = probe_and_drawer();
        let mut world = world_at(&scene, &servo_config(integral_gain, false), x0);
        let mut x = x0.to_vec();
        (0..steps)
            .map(|_| {
                world.step_once(&u, &mut x);
                x.clone()
            })
            .collect()
    }

    #[test]
    fn free_motion_follows_the_semi_implicit_servo_law() {
        let (gain, u) = (400.0, [0.5, 0.8]);
        let x0 = state([-0.5, 0.0], [0.0, 0.0], 0.0, 0.0);
        let states = run(gain, &x0, u, 10);
        // q̇' = (q̇ + dt (Λ u + Λ_I I)) / (1 + dt Λ), q' = q + dt q̇', I' = I + dt (u − q̇').
        let (mut q, mut qd, mut integral) = ([-0.5, 0.0], [0.0, 0.0], [0.0, 0.0]);
        for x in &states {
            for j in 0..2 {
                qd[j] = (qd[j] + DT * (BANDWIDTH * u[j] + gain * integral[j])) / (1.0 + DT * BANDWIDTH);
                q[j] += DT * qd[j];
                integral[j] += DT * (u[j] - qd[j]);
                assert!(
                    (x[j] - q[j]).abs() < 1e-12 && (x[2 + j] - qd[j]).abs() < 1e-12,
                    "joint {j}: {x:?} vs {q:?}, {qd:?}"
                );
            }
        }
    }

    #[test]
    fn integral_action_settles_at_zero_lag() {
        let u = [0.0, 0.2];
        let x0 = state([-0.5, -1.0], [0.0, 0.0], 0.0, 0.0);
        let steps = 300;
        let travelled = u[1] * DT * steps as f64;
        let with = run(400.0, &x0, u, steps);
        let lag = -1.0 + travelled - with.last().unwrap()[1];
        assert!(lag.abs() < 1e-9, "lag {lag}");
        // Without it a first-order lag stays behind by Σ_k (u − q̇_k) dt = u/Λ.
        let without = run(0.0, &x0, u, steps);
        let lag = -1.0 + travelled - without.last().unwrap()[1];
        assert!((lag - u[1] / BANDWIDTH).abs() < 1e-9, "lag {lag}");
    }

    #[test]
    fn position_limit_clamps_and_stops_the_joint() {
        let states = run(400.0, &state([-0.95, 0.0], [0.0, 0.0], 0.0, 0.0), [-1.0, 0.0], 20);
        assert!(states.iter().all(|x| x[0] >= -1.0));
        let last = states.last().unwrap();
        assert_eq!((last[0], last[2]), (-1.0, 0.0));
    }

    #[test]
    fn velocity_limit_clamps_command_and_servo() {
        // The turn joint's limit is 2 rad/s; the integral's catch-up would push past it.
        let states = run(400.0, &state([-0.5, -2.9], [0.0, 0.0], 0.0, 0.0), [0.0, 10.0], 60);
        assert!(states.iter().all(|x| x[3] <= 2.0));
        assert_eq!(states.last().unwrap()[3], 2.0);
    }
}
