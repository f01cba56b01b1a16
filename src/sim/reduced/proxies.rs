//! The reduced path's proxies: the rigid bodies fixed joints merge the robot's contact links into,
//! each with the robot's effective mass at its centre of mass.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use super::geometry::Collider;
use crate::model::kinematics::KinematicTree;
use crate::model::scene::Scene;
use crate::sim::proxy::{body_groups, effective_mass};

/// A proxy: the rigid body of robot links joined by fixed joints that carries contact geometry,
/// with the robot's effective mass at its centre of mass.
#[derive(Debug, Clone)]
pub(super) struct ProxyBody {
    /// The link whose frame the body lives in (the first link of its fixed group).
    pub link: usize,
    /// Centre of mass in that frame.
    pub com: Point3<f64>,
    pub inv_mass: f64,
    /// Inverse inertia about the centre of mass, in that frame.
    pub inv_inertia: Matrix3<f64>,
}

/// Mass, centre of mass and inertia (about that centre, in the frame of `body`) of the links of
/// `tree` that fixed joints join into `body`.
fn group_mass(tree: &KinematicTree, group: &[usize], offset: &[Isometry3<f64>], body: usize) -> (f64, Point3<f64>, Matrix3<f64>) {
    let parts: Vec<(f64, Point3<f64>, Matrix3<f64>)> = tree
        .links
        .iter()
        .enumerate()
        .filter(|&(link, _)| group[link] == body)
        .filter_map(|(link, l)| {
            let inertial = l.inertial()?;
            let r = offset[link].rotation.to_rotation_matrix();
            Some((
                inertial.mass,
                offset[link] * Point3::from(inertial.com),
                r.matrix() * inertial.inertia * r.matrix().transpose(),
            ))
        })
        .collect();
    let mass: f64 = parts.iter().map(|p| p.0).sum();
    if mass <= 0.0 {
        // Massless links still need an invertible inertia.
        return (1e-3, Point3::origin(), Matrix3::identity() * 1e-6);
    }
    let com = Point3::from(parts.iter().map(|(m, c, _)| c.coords * *m).sum::<Vector3<f64>>() / mass);
    let inertia = parts
        .iter()
        .map(|(m, c, i)| {
            let d = c - com;
            i + (Matrix3::identity() * d.norm_squared() - d * d.transpose()) * *m
        })
        .sum();
    (mass, com, inertia)
}

/// The proxies of the links `include` accepts, and for each of those links' primitives (in
/// [`Collider::of_tree`] order) the proxy it belongs to.
pub(super) fn proxy_bodies(scene: &Scene, colliders: &[Collider]) -> (Vec<ProxyBody>, Vec<usize>) {
    let tree = &scene.robot;
    let (group, offset) = body_groups(tree);
    let q0 = &scene.default_state()[..scene.nq()];
    let mut bodies: Vec<ProxyBody> = Vec::new();
    let owner = colliders
        .iter()
        .map(|c| {
            let body = group[c.link];
            if let Some(i) = bodies.iter().position(|b| b.link == body) {
                return i;
            }
            let (mass, com, inertia) = group_mass(tree, &group, &offset, body);
            let effective = effective_mass(tree, q0, body, &com);
            let scale = effective / mass;
            bodies.push(ProxyBody {
                link: body,
                com,
                inv_mass: 1.0 / effective,
                inv_inertia: (inertia * scale).try_inverse().unwrap_or_else(Matrix3::zeros),
            });
            bodies.len() - 1
        })
        .collect();
    (bodies, owner)
}
