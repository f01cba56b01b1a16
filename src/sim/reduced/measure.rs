//! What a step of the reduced world reports: τ_ext and the wrist wrench of its contact forces,
//! the contact points for diagnosis, and a step's cost from the world's own frames.

use nalgebra::{Isometry3, Point3, Vector3};

use super::{ReducedLayout, WorldState};
use crate::sim::evaluator::{StepEvaluator, StepView};
use crate::sim::interaction::ContactReport;

impl WorldState {
    /// τ_ext = Σ J_cᵀ f_c (35) and the wrist wrench of the last step's contact forces, taken at the
    /// configuration the step ended in (each contact point carried along with its link).
    pub(super) fn measure_interaction(&mut self, layout: &ReducedLayout) {
        self.last.contact = false;
        self.last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        self.last.wrench = [0.0; 6];
        if self.touches.is_empty() {
            return;
        }
        let frames = &mut self.robot.frames;
        self.scene.robot.update_frames(&Isometry3::identity(), &self.servo.q, frames);
        let inv_dt = 1.0 / layout.config.dt;
        // The contacts on one link act on the joints as one wrench about the link's origin: one
        // Jacobian per touched link instead of one per contact point.
        self.link_wrenches.clear();
        for (touch, impulse) in self.touches.iter().zip(&self.impulses) {
            if *impulse == Vector3::zeros() {
                continue;
            }
            self.last.contact = true;
            let force = impulse * inv_dt;
            let pose = frames.poses[touch.robot_link];
            let point = pose * touch.local_point;
            let moment = (point.coords - pose.translation.vector).cross(&force);
            match self.link_wrenches.iter_mut().find(|(link, _, _)| *link == touch.robot_link) {
                Some((_, f, m)) => {
                    *f += force;
                    *m += moment;
                }
                None => self.link_wrenches.push((touch.robot_link, force, moment)),
            }
            if layout.sensor_links[touch.robot_link] {
                let sensor = frames.poses[layout.sensor_link].translation.vector;
                let torque = (point.coords - sensor).cross(&force);
                for (w, v) in self
                    .last
                    .wrench
                    .iter_mut()
                    .zip([force.x, force.y, force.z, torque.x, torque.y, torque.z])
                {
                    *w += v;
                }
            }
        }
        for (link, force, moment) in &self.link_wrenches {
            let origin = Point3::from(frames.poses[*link].translation.vector);
            self.scene
                .robot
                .frames_add_wrench_torques(frames, *link, &origin, force, moment, &mut self.last.tau_ext);
        }
    }

    /// [`ReducedWorld::contacts`].
    pub(super) fn contacts(&self, layout: &ReducedLayout) -> Vec<ContactReport> {
        let frames_q = &self.servo.q;
        let poses = self.scene.robot.link_poses(&Isometry3::identity(), frames_q);
        let inv_dt = 1.0 / layout.config.dt;
        self.touches
            .iter()
            .zip(&self.impulses)
            .filter(|(_, impulse)| **impulse != Vector3::zeros())
            .map(|(touch, impulse)| {
                let p = poses[touch.robot_link] * touch.local_point;
                let f = impulse * inv_dt;
                ContactReport {
                    robot_link: touch.robot_link,
                    object_link: touch.object_link,
                    point: [p.x, p.y, p.z],
                    force: [f.x, f.y, f.z],
                }
            })
            .collect()
    }

    /// [`ReducedWorld::evaluate_step`].
    pub(super) fn evaluate_step(&mut self, layout: &ReducedLayout, evaluator: &dyn StepEvaluator, x: &[f64], u: &[f64]) -> f64 {
        let (nq, no) = (layout.nq, layout.no);
        self.scene
            .robot
            .update_frames(&Isometry3::identity(), &x[..nq], &mut self.robot.frames);
        if evaluator.needs_object_frames() {
            self.scene
                .object
                .update_frames(&self.scene.object_pose, &x[2 * nq..2 * nq + no], &mut self.object.frames);
        }
        evaluator.evaluate(
            &self.scene,
            &StepView {
                x,
                u,
                tau_ext: &self.last.tau_ext,
                contact: self.last.contact,
                robot: &self.robot.frames,
                object: &self.object.frames,
            },
        )
    }
}
