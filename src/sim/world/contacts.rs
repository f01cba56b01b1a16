//! Contact measurement: solver impulses of robot–object contacts turned into forces, τ_ext = Σ J_cᵀ f_c
//! (35), the wrist wrench and the contact flag of each step, and per-point contact reports.

use nalgebra::{Isometry3, Point3, Vector3};
use rapier3d_f64::prelude::*;

use super::{vec_from_rapier, ContactReport, Interaction, SimWorld, OWNER_OBJECT, OWNER_ROBOT};

impl SimWorld {
    /// Every robot–object contact point that carried force in the last step, with the force on
    /// the robot; for diagnosing what the robot touches (allocates, not for the hot path).
    pub fn contacts(&self) -> Vec<ContactReport> {
        let mut out = Vec::new();
        let inv_dt = 1.0 / self.params.dt;
        for pair in self.state.narrow_phase.contact_pairs() {
            let (Some(c1), Some(c2)) = (
                self.state.colliders.get(pair.collider1),
                self.state.colliders.get(pair.collider2),
            ) else {
                continue;
            };
            let owner = |c: &Collider| c.user_data & !0xffff_ffff_ffff_ffff;
            let index = |c: &Collider| (c.user_data & 0xffff_ffff) as usize;
            let (robot_link, object_link, robot_is_first) = match (owner(c1), owner(c2)) {
                (OWNER_ROBOT, OWNER_OBJECT) => (index(c1), index(c2), true),
                (OWNER_OBJECT, OWNER_ROBOT) => (index(c2), index(c1), false),
                _ => continue,
            };
            for manifold in pair.solver_manifolds() {
                for sc in manifold.data.solver_contacts.iter() {
                    let Some((p, force)) = Self::contact_force(manifold, sc, &self.state.bodies, robot_is_first, inv_dt) else {
                        continue;
                    };
                    out.push(ContactReport {
                        robot_link,
                        object_link,
                        point: [p.x, p.y, p.z],
                        force: [force.x, force.y, force.z],
                    });
                }
            }
        }
        out
    }

    /// Point and force on the robot of one solver contact, or None if it carried no impulse.
    fn contact_force(
        manifold: &ContactManifold,
        sc: &SolverContact,
        bodies: &RigidBodySet,
        robot_is_first: bool,
        inv_dt: f64,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let contact_index = (sc.contact_id[0] & !NEW_CONTACT_BIT) as usize;
        let point = manifold.points.get(contact_index)?;
        let normal_impulse = point.data.impulse;
        let tangent_impulse = point.data.warmstart_tangent_world;
        if normal_impulse <= 0.0 && tangent_impulse.length_squared() == 0.0 {
            return None;
        }
        // The normal points from the first collider to the second; the normal impulse pushes the
        // first collider back along −normal.
        let on_first = -(manifold.data.normal * normal_impulse) + tangent_impulse;
        let impulse = if robot_is_first { on_first } else { -on_first };
        let (p1, p2) = manifold.data.solver_contact_world_points(sc, bodies);
        Some((vec_from_rapier((p1 + p2) * 0.5), vec_from_rapier(impulse * inv_dt)))
    }

    pub(super) fn measure_interaction(&mut self) {
        let nq = self.layout.nq;
        let mut last = std::mem::replace(
            &mut self.state.last,
            Interaction {
                contact: false,
                tau_ext: Vec::new(),
                wrench: [0.0; 6],
            },
        );
        last.contact = false;
        last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        last.wrench = [0.0; 6];
        let inv_dt = 1.0 / self.params.dt;
        let mut poses_ready = false;
        for pair in self.state.narrow_phase.contact_pairs() {
            let (Some(c1), Some(c2)) = (
                self.state.colliders.get(pair.collider1),
                self.state.colliders.get(pair.collider2),
            ) else {
                continue;
            };
            let owner = |c: &Collider| c.user_data & !0xffff_ffff_ffff_ffff;
            // The robot may be either side of the pair; forces are taken as acting on the robot.
            let (robot_link, robot_is_first) = match (owner(c1), owner(c2)) {
                (OWNER_ROBOT, OWNER_OBJECT) => ((c1.user_data & 0xffff_ffff) as usize, true),
                (OWNER_OBJECT, OWNER_ROBOT) => ((c2.user_data & 0xffff_ffff) as usize, false),
                _ => continue,
            };
            for manifold in pair.solver_manifolds() {
                for sc in manifold.data.solver_contacts.iter() {
                    let Some((p, force)) = Self::contact_force(manifold, sc, &self.state.bodies, robot_is_first, inv_dt) else {
                        continue;
                    };
                    last.contact = true;
                    if !poses_ready {
                        let mut q = std::mem::take(&mut self.scratch);
                        q.resize(nq, 0.0);
                        self.read_robot_q(&mut q);
                        self.scene
                            .robot
                            .update_frames(&Isometry3::identity(), &q, &mut self.dynamics.frames);
                        self.scratch = q;
                        poses_ready = true;
                    }
                    let point = Point3::from(p);
                    let frames = &self.dynamics.frames;
                    self.scene
                        .robot
                        .frames_jacobian_into(frames, robot_link, &point, &mut self.jacobian);
                    for (c, t) in last.tau_ext.iter_mut().enumerate() {
                        let col = &self.jacobian[6 * c..6 * c + 3];
                        *t += col[0] * force.x + col[1] * force.y + col[2] * force.z;
                    }
                    if self.layout.sensor_links[robot_link] {
                        let sensor = frames.poses[self.layout.sensor_link].translation.vector;
                        let torque = (p - sensor).cross(&force);
                        for (w, v) in last
                            .wrench
                            .iter_mut()
                            .zip([force.x, force.y, force.z, torque.x, torque.y, torque.z])
                        {
                            *w += v;
                        }
                    }
                }
            }
        }
        self.state.last = last;
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Vector3};

    use crate::sim::test_scene::{probe_and_drawer, servo_config, state, world_at};

    /// The arm's ball pushed into the drawer's front along +x for a few steps; returns the world
    /// after a step that reported contact and the state after it.
    fn pressed() -> (crate::sim::SimWorld, Vec<f64>) {
        let scene = probe_and_drawer();
        // Ball centre at 0.9 + 0.3 cos 0.3 ≈ 0.887 with a 0.05 radius, the face at 0.95, pushing
        // at 0.3 m/s along x while turning: contact off the arm's axis, with a moment about z.
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        let mut world = world_at(&scene, &servo_config(0.0, false), &x0);
        let mut x = x0.clone();
        for _ in 0..6 {
            world.step_once(&[0.3, 0.2], &mut x);
        }
        assert!(world.interaction().contact, "no contact after six steps");
        (world, x)
    }

    #[test]
    fn wrench_force_is_the_sum_of_reported_contact_forces() {
        let (world, _) = pressed();
        let reports = world.contacts();
        assert!(!reports.is_empty());
        let total: Vector3<f64> = reports.iter().map(|c| Vector3::from(c.force)).sum();
        let wrench = world.interaction().wrench;
        assert!(total.norm() > 1e-3, "contact carries force");
        assert!((Vector3::new(wrench[0], wrench[1], wrench[2]) - total).norm() < 1e-9 * total.norm().max(1.0));
        // The sensor is the arm's origin (its last joint's child): torque Σ (p − o) × f.
        let origin = world.scene().fk(&world.state.robot_q, "arm").unwrap().translation.vector;
        let torque: Vector3<f64> = reports
            .iter()
            .map(|c| (Vector3::from(c.point) - origin).cross(&Vector3::from(c.force)))
            .sum();
        assert!((Vector3::new(wrench[3], wrench[4], wrench[5]) - torque).norm() < 1e-9 * torque.norm().max(1.0));
    }

    #[test]
    fn tau_ext_is_the_jacobian_transpose_of_the_contact_forces() {
        let (world, x) = pressed();
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

    #[test]
    fn object_takes_the_opposite_of_the_force_on_the_robot() {
        // Newton's third law seen from the drawer: its momentum changes by the force that the
        // contacts put on it, −Σ f (f on the robot), less its 0.5 N dry friction while it slides.
        let scene = probe_and_drawer();
        let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
        let mut world = world_at(&scene, &servo_config(0.0, false), &x0);
        let (mut x, mut engine) = (x0.clone(), x0.clone());
        let mass = 2.0;
        let mut pushed = 0;
        for _ in 0..12 {
            world.read_state(&mut engine);
            let before = engine[5];
            world.step_once(&[0.3, 0.2], &mut x);
            world.read_state(&mut engine);
            let force_on_robot: Vector3<f64> = world.contacts().iter().map(|c| Vector3::from(c.force)).sum();
            if force_on_robot.norm() == 0.0 {
                continue;
            }
            pushed += 1;
            assert!(engine[5] > 0.0, "the drawer slides open");
            let momentum_rate = mass * (engine[5] - before) / world.dt();
            let expected = -force_on_robot.x - 0.5;
            assert!(
                (momentum_rate - expected).abs() < 1e-6 * expected.abs().max(1.0),
                "{momentum_rate} vs {expected}"
            );
        }
        assert!(pushed >= 10, "pushed in {pushed} steps");
    }
}
