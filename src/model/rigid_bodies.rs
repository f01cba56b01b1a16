//! The rigid bodies of a kinematic tree: what each movable joint carries with no other movable
//! joint between, summed into one inertial in the joint's child frame.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use super::kinematics::{Inertial, KinematicTree};

/// The links a movable joint carries with no other movable joint between, as one rigid body: the
/// joint's child link and its inertial (mass, centre of mass and inertia about it, in that link's
/// frame) summed over those links (None: they carry no mass).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidBody {
    /// The movable joint and its child link.
    pub joint: usize,
    pub link: usize,
    /// The rigid body the joint's parent link belongs to (its index in
    /// [`KinematicTree::rigid_bodies`]), None when no movable joint moves the parent.
    pub parent: Option<usize>,
    pub inertial: Option<Inertial>,
}

/// One [`RigidBody`] per movable joint of `tree`, parents before children.
pub(super) fn sum_rigid_bodies(tree: &KinematicTree) -> Vec<RigidBody> {
    // Each link's rigid body (index into the result) and its pose in the frame of that body's
    // link; the joints between are fixed, so that pose is constant.
    let mut in_body: Vec<Option<(usize, Isometry3<f64>)>> = vec![None; tree.links.len()];
    let mut bodies = Vec::new();
    for &j in &tree.topological_joints {
        let joint = &tree.joints[j];
        in_body[joint.child] = if joint.q_index.is_some() {
            bodies.push(RigidBody {
                joint: j,
                link: joint.child,
                parent: in_body[joint.parent].map(|(body, _)| body),
                inertial: None,
            });
            Some((bodies.len() - 1, Isometry3::identity()))
        } else {
            in_body[joint.parent].map(|(body, pose)| (body, pose * joint.origin))
        };
    }
    for (index, body) in bodies.iter_mut().enumerate() {
        let members: Vec<(Isometry3<f64>, &Inertial)> = tree
            .links
            .iter()
            .zip(&in_body)
            .filter_map(|(l, placed)| match (l.inertial.as_ref(), placed) {
                (Some(inertial), Some((b, pose))) if *b == index => Some((*pose, inertial)),
                _ => None,
            })
            .collect();
        if members.is_empty() {
            continue;
        }
        let mass: f64 = members.iter().map(|(_, i)| i.mass).sum();
        let com = if mass > 0.0 {
            members
                .iter()
                .map(|(pose, i)| (pose * Point3::from(i.com)).coords * i.mass)
                .sum::<Vector3<f64>>()
                / mass
        } else {
            Vector3::zeros()
        };
        // Each member's inertia turned into the body frame and moved to the common centre of
        // mass (parallel axes).
        let inertia = members
            .iter()
            .map(|(pose, i)| {
                let r = pose.rotation.to_rotation_matrix();
                let d = (pose * Point3::from(i.com)).coords - com;
                r.matrix() * i.inertia * r.matrix().transpose()
                    + (Matrix3::identity() * d.norm_squared() - d * d.transpose()) * i.mass
            })
            .sum();
        body.inertial = Some(Inertial { mass, com, inertia });
    }
    bodies
}
