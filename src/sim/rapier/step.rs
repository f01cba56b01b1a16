//! One step of a world (servo, quiescence test, Rapier's pipeline, interaction measurement), the
//! single-command step of the rollout model, the engine clock, and the per-step evaluation that
//! reads the world's cached frames.

use std::time::Instant;

use nalgebra::Isometry3;

use super::{RobotDrive, SimWorld};
use crate::model::scene::Scene;
use crate::sim::engine_clock::EngineClock;
use crate::sim::evaluator::{StepEvaluator, StepView};
use crate::sim::interaction::Interaction;
use crate::sim::servo::ServoGains;

impl SimWorld {
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub fn dt(&self) -> f64 {
        self.params.dt
    }

    /// Restores every piece of Rapier state (bodies, contacts, warm starts, broad phase) from `snapshot`.
    /// The result depends only on the snapshot, never on what this world simulated before.
    pub fn restore_from(&mut self, snapshot: &SimWorld) {
        self.state.clone_from(&snapshot.state);
    }

    /// Advances the physics by one step of length dt under the current command, then measures
    /// the interaction of that step.
    pub fn step(&mut self) {
        if let RobotDrive::KinematicServo {
            bandwidth,
            integral_gain,
            integral_limit,
            skip_quiescent,
        } = self.layout.drive
        {
            self.advance_kinematic_robot(&ServoGains {
                bandwidth,
                integral_gain,
                integral_limit,
            });
            if skip_quiescent && self.quiescent() {
                // Nothing can touch the object and it is held at rest: the physics step would leave
                // it exactly where it is, as Rapier's island sleeping would. Skip it.
                let last = &mut self.state.last;
                last.contact = false;
                last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
                last.wrench = [0.0; 6];
                return;
            }
        }
        let s = &mut self.state;
        let started = Instant::now();
        self.pipeline.step(
            self.gravity,
            &self.params,
            &mut s.islands,
            &mut s.broad_phase,
            &mut s.narrow_phase,
            &mut s.bodies,
            &mut s.colliders,
            &mut s.impulse_joints,
            &mut s.multibody_joints,
            &mut s.soft_bodies,
            &mut s.ccd_solver,
            &(),
            &(),
        );
        self.engine.steps += 1;
        self.engine.seconds += started.elapsed().as_secs_f64();
        self.measure_interaction();
    }

    /// Steps taken and time spent inside Rapier's pipeline by this world so far (the clock is
    /// not part of the simulated state: [`Self::restore_from`] and [`Self::set_state`] keep it).
    pub fn engine_clock(&self) -> EngineClock {
        self.engine
    }

    /// One step under the velocity command `u` (projected onto the velocity limits); writes the
    /// state after the step into `x` (nx). For the servo drives of the rollout model.
    ///
    /// The object's velocity in `x` is the rate at which it moved over the step. The proxies are
    /// placed a little inside what they push, and Rapier moves the object out by position
    /// correction, a velocity it discards after the step, so the engine's own velocity of a pushed
    /// object under dry friction can even have the wrong sign. The engine keeps that velocity:
    /// writing the displacement rate back would change the contact dynamics (the object would
    /// coast between steps) and with them the closed loop the rollouts model.
    pub fn step_once(&mut self, u: &[f64], x: &mut [f64]) {
        self.set_velocity_command(u);
        self.record_object_coords();
        self.step();
        self.read_state(x);
        let (nq, no) = (self.layout.nq, self.layout.no);
        let dt = self.params.dt;
        for (i, before) in self.object_coords.iter().enumerate() {
            x[2 * nq + no + i] = (x[2 * nq + i] - before) / dt;
        }
    }

    fn record_object_coords(&mut self) {
        let (mb, _) = self.state.multibody_joints.get(self.layout.object_handle).expect("object");
        self.object_coords.clear();
        for d in &self.layout.object_dofs {
            self.object_coords.push(d.value(mb));
        }
    }

    /// Interaction measured in the last step.
    pub fn interaction(&self) -> &Interaction {
        &self.state.last
    }

    /// `evaluator`'s value of the last step, which led to state `x` under command `u`. The robot's
    /// link poses are computed once here into the world's frame cache (and the object's when the
    /// evaluator reads them), the same cache the servo and the contact measurement use.
    pub fn evaluate_step(&mut self, evaluator: &dyn StepEvaluator, x: &[f64], u: &[f64]) -> f64 {
        let interaction = &self.state.last;
        let (nq, no) = (self.layout.nq, self.layout.no);
        let robot_frames = &mut self.dynamics.frames;
        let object_frames = &mut self.object_frames;
        self.scene.robot.update_frames(&Isometry3::identity(), &x[..nq], robot_frames);
        if evaluator.needs_object_frames() {
            self.scene
                .object
                .update_frames(&self.scene.object_pose, &x[2 * nq..2 * nq + no], object_frames);
        }
        evaluator.evaluate(
            &self.scene,
            &StepView {
                x,
                u,
                tau_ext: &interaction.tau_ext,
                contact: interaction.contact,
                robot: robot_frames,
                object: object_frames,
            },
        )
    }
}

impl SimWorld {
    /// [`Quiescence::holds`] for this world's state, with the contact prediction distance and 2 cm
    /// as margin. The robot frames must be those of the step's start (placed proxies).
    fn quiescent(&mut self) -> bool {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let mut x = std::mem::take(&mut self.scratch);
        x.resize(2 * (nq + no), 0.0);
        self.read_state(&mut x);
        let margin = self.params.normalized_prediction_distance * self.params.length_unit + 0.02;
        let quiet = self.layout.quiescence.holds(
            &self.scene,
            &self.dynamics.frames,
            &self.state.servo.qd,
            &x[2 * nq..2 * nq + no],
            &x[2 * nq + no..],
            self.params.dt,
            margin,
            &mut self.jacobian,
            &mut 0,
        );
        self.scratch = x;
        quiet
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use nalgebra::Isometry3;

    use crate::error::Result;
    use crate::model::scene::Scene;
    use crate::sim::evaluator::{StepEvaluator, StepView};
    use crate::sim::test_scene::{probe_and_drawer, servo_config, state, world_at};

    /// What the recorder saw of one step: the arm's and the handle's poses, τ_ext, the contact flag.
    type Seen = (Isometry3<f64>, Isometry3<f64>, Vec<f64>, bool);

    /// Records what it is shown.
    struct Recorder {
        seen: Mutex<Vec<Seen>>,
    }

    impl StepEvaluator for Recorder {
        fn validate(&self, _: &Scene) -> Result<()> {
            Ok(())
        }
        fn needs_object_frames(&self) -> bool {
            true
        }
        fn evaluate(&self, scene: &Scene, view: &StepView) -> f64 {
            let arm = view.robot.poses[scene.robot.link_id("arm").unwrap()];
            let handle = view.object.poses[scene.object.link_id("handle").unwrap()];
            self.seen
                .lock()
                .unwrap()
                .push((arm, handle, view.tau_ext.to_vec(), view.contact));
            1.5
        }
    }

    #[test]
    fn evaluator_sees_the_frames_and_interaction_of_the_step() {
        let scene = probe_and_drawer();
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        let mut world = world_at(&scene, &servo_config(0.0, false), &x0);
        let recorder = Recorder {
            seen: Mutex::new(Vec::new()),
        };
        let mut x = x0.clone();
        let mut touched = false;
        for _ in 0..6 {
            world.step_once(&[0.3, 0.2], &mut x);
            assert_eq!(world.evaluate_step(&recorder, &x, &[0.3, 0.2]), 1.5);
            let (arm, handle, tau, contact) = recorder.seen.lock().unwrap().pop().unwrap();
            let fk_arm = scene.fk(&x[..2], "arm").unwrap();
            let fk_handle = scene.object_fk(&x[4..5], "handle").unwrap();
            assert!((arm.to_homogeneous() - fk_arm.to_homogeneous()).norm() < 1e-12);
            assert!((handle.to_homogeneous() - fk_handle.to_homogeneous()).norm() < 1e-12);
            assert_eq!(
                (tau, contact),
                (world.interaction().tau_ext.clone(), world.interaction().contact)
            );
            touched |= contact;
        }
        assert!(touched);
    }

    #[test]
    fn step_once_reports_the_object_displacement_rate() {
        let scene = probe_and_drawer();
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        let mut world = world_at(&scene, &servo_config(0.0, false), &x0);
        let mut x = x0.clone();
        for _ in 0..6 {
            let before = x[4];
            world.step_once(&[0.3, 0.2], &mut x);
            assert_eq!(x[5], (x[4] - before) / world.dt());
        }
        assert!(x[4] > 0.0, "the drawer was pushed open");
    }

    #[test]
    fn engine_clock_counts_pipeline_steps_only() {
        let scene = probe_and_drawer();
        let far = state([-0.5, 0.0], [0.0, 0.0], 0.0, 0.0);
        let mut x = far.clone();
        let mut skipping = world_at(&scene, &servo_config(0.0, true), &far);
        let mut stepping = world_at(&scene, &servo_config(0.0, false), &far);
        for _ in 0..3 {
            skipping.step_once(&[0.0, 0.0], &mut x);
            stepping.step_once(&[0.0, 0.0], &mut x);
        }
        assert_eq!((skipping.engine_clock().steps, stepping.engine_clock().steps), (0, 3));
    }
}
