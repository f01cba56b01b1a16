//! Contact measurement: solver impulses of robot–object contacts turned into forces, τ_ext = Σ J_cᵀ f_c
//! (35), the wrist wrench and the contact flag of each step, and per-point contact reports.

use nalgebra::{Isometry3, Point3, Vector3};
use rapier3d_f64::prelude::*;

use super::{vec_from_rapier, SimWorld, OWNER_OBJECT, OWNER_ROBOT};
use crate::sim::interaction::{ContactReport, Interaction};

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
