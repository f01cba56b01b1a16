//! The world the rollout model steps: Rapier's pipeline (the reference contact path) or the
//! reduced contact path, behind one interface.

use super::engine_clock::EngineClock;
use super::evaluator::StepEvaluator;
use super::interaction::{ContactReport, Interaction};
use super::rapier::SimWorld;
use super::reduced::ReducedWorld;
use crate::model::scene::Scene;

/// One world of a [`super::RolloutModel`], of the model's contact path.
#[derive(Clone)]
pub enum RolloutWorld {
    /// The robot's contact bodies and the object simulated by Rapier's pipeline.
    Rapier(Box<SimWorld>),
    /// The same bodies against the object's joint coordinates, solved in sabre.
    Reduced(Box<ReducedWorld>),
}

macro_rules! each {
    ($self:expr, $w:ident => $e:expr) => {
        match $self {
            RolloutWorld::Rapier($w) => $e,
            RolloutWorld::Reduced($w) => $e,
        }
    };
}

impl RolloutWorld {
    pub fn scene(&self) -> &Scene {
        each!(self, w => w.scene())
    }

    pub fn dt(&self) -> f64 {
        each!(self, w => w.dt())
    }

    /// Rate-limits the servo's commands as the robot's command path does (see
    /// [`super::servo::ServoLimits::cap_acceleration`]), before the world is copied.
    pub fn cap_servo_acceleration(&mut self, caps: &[f64]) -> crate::error::Result<()> {
        each!(self, w => w.cap_servo_acceleration(caps))
    }

    /// Whether both worlds are copies of one built world (the same model).
    pub fn same_model(&self, other: &RolloutWorld) -> bool {
        match (self, other) {
            (RolloutWorld::Rapier(a), RolloutWorld::Rapier(b)) => std::sync::Arc::ptr_eq(&a.layout, &b.layout),
            (RolloutWorld::Reduced(a), RolloutWorld::Reduced(b)) => a.same_layout(b),
            _ => false,
        }
    }

    /// Restores every piece of simulated state from `snapshot` (a copy of this model's template).
    pub fn restore_from(&mut self, snapshot: &RolloutWorld) {
        match (self, snapshot) {
            (RolloutWorld::Rapier(w), RolloutWorld::Rapier(s)) => w.restore_from(s),
            (RolloutWorld::Reduced(w), RolloutWorld::Reduced(s)) => w.restore_from(s),
            (w, s) => *w = s.clone(),
        }
    }

    /// Places robot and object at state x = [q, q̇, o, ȯ] (validated by the caller).
    pub fn set_state(&mut self, x: &[f64]) {
        each!(self, w => w.set_state(x))
    }

    /// One step under the velocity command `u`; the state after it goes into `x` (nx), the object's
    /// velocity being its displacement rate over the step.
    pub fn step_once(&mut self, u: &[f64], x: &mut [f64]) {
        each!(self, w => w.step_once(u, x))
    }

    /// Writes the current state into `x` (nx), the object's velocity being the one the contact
    /// solve left it (what [`Self::step_once`] reports is its displacement rate).
    pub fn read_state(&self, x: &mut [f64]) {
        each!(self, w => w.read_state(x))
    }

    /// Interaction measured in the last step.
    pub fn interaction(&self) -> &Interaction {
        each!(self, w => w.interaction())
    }

    /// Contact points that carried force in the last step (allocates).
    pub fn contacts(&self) -> Vec<ContactReport> {
        each!(self, w => w.contacts())
    }

    /// Steps through the contact path and the time spent in them since the world was built.
    pub fn engine_clock(&self) -> EngineClock {
        each!(self, w => w.engine_clock())
    }

    /// `evaluator`'s value of the last step, which led to `x` under `u`.
    pub fn evaluate_step(&mut self, evaluator: &dyn StepEvaluator, x: &[f64], u: &[f64]) -> f64 {
        each!(self, w => w.evaluate_step(evaluator, x, u))
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Vector3};

    use super::RolloutWorld;
    use crate::sim::reduced::ReducedWorld;
    use crate::sim::test_scene::{probe_and_drawer, reduced_config, servo_config, state, world_at};

    /// Both contact paths' worlds of the probe and drawer, placed at `x`: Rapier's, then the reduced.
    fn both_at(x: &[f64]) -> [RolloutWorld; 2] {
        let scene = probe_and_drawer();
        let mut reduced = ReducedWorld::new(scene.clone(), &reduced_config()).expect("reduced world");
        reduced.set_state(x);
        [
            RolloutWorld::Rapier(Box::new(world_at(&scene, &servo_config(0.0, false), x))),
            RolloutWorld::Reduced(Box::new(reduced)),
        ]
    }

    /// The arm's ball (radius 0.05, at 0.9 + 0.3 cos 0.3 ≈ 0.887 against the face at 0.95) pushed
    /// into the drawer's front along +x while turning: contact off the arm's axis, with a moment
    /// about z. Each world after six steps, with the state after them.
    fn pressed() -> Vec<(RolloutWorld, Vec<f64>)> {
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        both_at(&x0)
            .into_iter()
            .map(|mut world| {
                let mut x = x0.clone();
                for _ in 0..6 {
                    world.step_once(&[0.3, 0.2], &mut x);
                }
                assert!(world.interaction().contact, "no contact after six steps");
                (world, x)
            })
            .collect()
    }

    #[test]
    fn the_wrench_is_the_sum_of_the_contact_forces_and_their_moments() {
        for (world, x) in pressed() {
            let reports = world.contacts();
            let total: Vector3<f64> = reports.iter().map(|c| Vector3::from(c.force)).sum();
            assert!(total.norm() > 1e-3, "contact carries force");
            let w = world.interaction().wrench;
            assert!((Vector3::new(w[0], w[1], w[2]) - total).norm() < 1e-9 * total.norm().max(1.0));
            // The sensor is the arm's origin (its last joint's child): torque Σ (p − o) × f.
            let origin = world.scene().fk(&x[..2], "arm").unwrap().translation.vector;
            let torque: Vector3<f64> = reports
                .iter()
                .map(|c| (Vector3::from(c.point) - origin).cross(&Vector3::from(c.force)))
                .sum();
            assert!((Vector3::new(w[3], w[4], w[5]) - torque).norm() < 1e-9 * torque.norm().max(1.0));
        }
    }

    #[test]
    fn tau_ext_is_the_jacobian_transpose_of_the_contact_forces() {
        for (world, x) in pressed() {
            let scene = world.scene();
            let arm = scene.robot.link_id("arm").unwrap();
            // Point Jacobian from the arm's frame Jacobian: v_p = v_o + ω × (p − o).
            let jacobian = scene.robot.frame_jacobian(&Isometry3::identity(), &x[..2], arm);
            let origin = scene.fk(&x[..2], "arm").unwrap().translation.vector;
            let mut expected = [0.0; 2];
            for c in world.contacts() {
                let (p, f) = (Vector3::from(c.point), Vector3::from(c.force));
                let moment = (p - origin).cross(&f);
                for (j, e) in expected.iter_mut().enumerate() {
                    let linear = Vector3::new(jacobian[(0, j)], jacobian[(1, j)], jacobian[(2, j)]);
                    let angular = Vector3::new(jacobian[(3, j)], jacobian[(4, j)], jacobian[(5, j)]);
                    *e += linear.dot(&f) + angular.dot(&moment);
                }
            }
            let tau = &world.interaction().tau_ext;
            assert!(
                expected[0].abs() > 1e-3 && expected[1].abs() > 1e-6,
                "both joints loaded: {expected:?}"
            );
            for j in 0..2 {
                assert!(
                    (tau[j] - expected[j]).abs() < 1e-9 * expected[j].abs().max(1.0),
                    "joint {j}: {tau:?} vs {expected:?}"
                );
            }
        }
    }

    /// Newton's third law seen from the drawer (2 kg, 0.5 N of dry friction): its momentum changes
    /// by the force the contacts put on it, −Σ f (f on the robot), less the friction while it slides.
    #[test]
    fn the_object_takes_the_opposite_of_the_force_on_the_robot() {
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        for mut world in both_at(&x0) {
            let (mut x, mut engine) = (x0.clone(), x0.clone());
            let mut pushed = 0;
            for _ in 0..12 {
                world.read_state(&mut engine);
                let before = engine[5];
                world.step_once(&[0.3, 0.2], &mut x);
                world.read_state(&mut engine);
                let force: Vector3<f64> = world.contacts().iter().map(|c| Vector3::from(c.force)).sum();
                if force.norm() == 0.0 {
                    continue;
                }
                pushed += 1;
                assert!(engine[5] > 0.0, "the drawer slides open");
                let momentum_rate = 2.0 * (engine[5] - before) / world.dt();
                let expected = -force.x - 0.5;
                assert!(
                    (momentum_rate - expected).abs() < 1e-6 * expected.abs().max(1.0),
                    "{momentum_rate} vs {expected}"
                );
            }
            assert!(pushed >= 10, "pushed in {pushed} steps");
        }
    }

    #[test]
    fn a_restored_world_repeats_a_fresh_one_bit_for_bit() {
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        for template in both_at(&x0) {
            let run = |world: &mut RolloutWorld| {
                let mut x = x0.clone();
                (0..8)
                    .flat_map(|_| {
                        world.step_once(&[0.3, 0.2], &mut x);
                        x.iter()
                            .chain(&world.interaction().tau_ext)
                            .map(|v| v.to_bits())
                            .collect::<Vec<_>>()
                    })
                    .collect::<Vec<_>>()
            };
            let expected = run(&mut template.clone());
            // A world that has pushed the drawer elsewhere (contacts kept, impulses to warm-start
            // with), restored and placed again.
            let mut used = template.clone();
            let mut x = x0.clone();
            for _ in 0..20 {
                used.step_once(&[1.0, -1.0], &mut x);
            }
            used.restore_from(&template);
            used.set_state(&x0);
            assert_eq!(run(&mut used), expected);
        }
    }
}
