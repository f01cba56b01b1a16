//! The rigid bodies of a kinematic tree: what each movable joint carries with no other movable
//! joint between, summed into one inertial in the joint's child frame, from the tree's links and joints.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use super::description::{Inertial, Joint, JointKind, Link};

/// The links a movable joint carries with no other movable joint between, as one rigid body: the
/// joint's child link and its inertial (mass, centre of mass and inertia about it, in that link's
/// frame) summed over those links (None: they carry no mass).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidBody {
    /// The movable joint and its child link.
    pub joint: usize,
    pub link: usize,
    /// The rigid body the joint's parent link belongs to (its index in the tree's rigid bodies,
    /// `KinematicTree::rigid_bodies`), None when no movable joint moves the parent.
    pub parent: Option<usize>,
    pub inertial: Option<Inertial>,
}

/// One [`RigidBody`] per movable joint of the tree of `links` and `joints` (with their q indices set),
/// parents before children; `topological_joints` orders the joints parents first.
pub(super) fn sum_rigid_bodies(links: &[Link], joints: &[Joint], topological_joints: &[usize]) -> Vec<RigidBody> {
    // Each link's rigid body (index into the result) and its pose in the frame of that body's
    // link; the joints between are fixed, so that pose is constant.
    let mut in_body: Vec<Option<(usize, Isometry3<f64>)>> = vec![None; links.len()];
    let mut bodies = Vec::new();
    for &j in topological_joints {
        let joint = &joints[j];
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
        let members: Vec<(Isometry3<f64>, &Inertial)> = links
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

/// For each of the `nq` coordinates of the tree of `joints` and its rigid `bodies`, whether the
/// joint-space inertia M(q) is independent of it (the root held in place). A joint qualifies when every other rigid body is its ancestor or its
/// descendant, so that its motion moves all that it moves as one rigid whole, and when that motion
/// leaves every other Jacobian column as it was: it is the first movable joint (a rotation or
/// translation of the whole mechanism, under which every term Jᵢᵀ I Jⱼ keeps its value), or it and
/// every movable joint before it translate (their columns are fixed directions, and translation
/// leaves the later columns, axis × (p − o), unchanged). A mobile base's x and y are such joints,
/// its yaw is not (it turns the arm's columns against the base's fixed ones); a door's or a
/// drawer's single joint is one.
pub(super) fn mass_invariant_coordinates(joints: &[Joint], nq: usize, bodies: &[RigidBody]) -> Vec<bool> {
    let mut invariant = vec![false; nq];
    // Rigid bodies come parents first: each body's chain of ancestors, as indices into `bodies`.
    let ancestors = |mut b: usize| {
        let mut chain = Vec::new();
        while let Some(p) = bodies[b].parent {
            chain.push(p);
            b = p;
        }
        chain
    };
    let chains: Vec<Vec<usize>> = (0..bodies.len()).map(ancestors).collect();
    for (b, body) in bodies.iter().enumerate() {
        let leads = (0..bodies.len()).all(|o| o == b || chains[b].contains(&o) || chains[o].contains(&b));
        let translates = |i: usize| joints[bodies[i].joint].kind == JointKind::Prismatic;
        let first = chains[b].is_empty();
        if leads && (first || (translates(b) && chains[b].iter().all(|&a| translates(a)))) {
            if let Some(column) = joints[body.joint].q_index {
                invariant[column] = true;
            }
        }
    }
    invariant
}
