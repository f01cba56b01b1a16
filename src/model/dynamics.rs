//! Joint-space mass matrix and gravity torques of a kinematic tree (composite-rigid-body algorithm),
//! potential and mechanical energy.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, Vector3};

use super::kinematics::{Frames, JointKind, KinematicTree};

/// Reusable buffers for [`joint_space_terms`]; `frames` holds the link poses of the last call.
#[derive(Debug, Default, Clone)]
pub struct DynamicsWorkspace {
    pub frames: Frames,
    /// Per link, the inertia of the subtree it carries (see [`Composite`]).
    composites: Vec<Composite>,
}

/// The inertia of a set of bodies about the world origin, in the world frame: mass m, first moment
/// h = Σ m c, and J = Σ (I_c + m (|c|² 1 − c cᵀ)). Sets add by adding these.
#[derive(Debug, Clone, Copy)]
struct Composite {
    mass: f64,
    first_moment: Vector3<f64>,
    inertia: Matrix3<f64>,
}

impl Composite {
    const ZERO: Composite = Composite {
        mass: 0.0,
        first_moment: Vector3::new(0.0, 0.0, 0.0),
        inertia: Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    };

    /// Angular momentum about the world origin and linear momentum of the set moving with the
    /// twist (ω, v), v being the velocity of the point at the world origin.
    fn momentum(&self, omega: &Vector3<f64>, v: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
        (
            self.inertia * omega + self.first_moment.cross(v),
            v * self.mass + omega.cross(&self.first_moment),
        )
    }
}

/// The twist (ω, velocity of the world origin) a unit rate of movable joint `j` gives its child.
fn joint_twist(tree: &KinematicTree, frames: &Frames, j: usize) -> (Vector3<f64>, Vector3<f64>) {
    let (axis, origin) = (frames.axis(j), frames.origin(j));
    match tree.joints[j].kind {
        JointKind::Revolute => (axis, origin.coords.cross(&axis)),
        _ => (Vector3::zeros(), axis),
    }
}

/// M(q), the joint-space mass matrix (kinetic energy ½ q̇ᵀ M q̇ of every link), and g(q) = −Σ_links
/// m J_vᵀ a_g, the torque that holds the tree still against gravity `a_g`, by the composite-rigid-
/// body algorithm: with S_j the twist of joint j and I_j the inertia of everything joint j moves,
/// M_ij = S_iᵀ I_j S_j for i at or above j, and g_j = −S_jᵀ (gravity's wrench on I_j).
pub fn joint_space_terms(
    tree: &KinematicTree,
    root_pose: &Isometry3<f64>,
    q: &[f64],
    gravity: &Vector3<f64>,
    ws: &mut DynamicsWorkspace,
    mass_matrix: &mut DMatrix<f64>,
    gravity_torque: &mut DVector<f64>,
) {
    let n = tree.nq();
    // nalgebra's resize moves the data into a new allocation even at the same size.
    if mass_matrix.shape() != (n, n) {
        mass_matrix.resize_mut(n, n, 0.0);
    }
    mass_matrix.fill(0.0);
    if gravity_torque.len() != n {
        gravity_torque.resize_vertically_mut(n, 0.0);
    }
    gravity_torque.fill(0.0);
    tree.update_frames(root_pose, q, &mut ws.frames);
    let frames = &ws.frames;
    ws.composites.clear();
    // A link that no movable joint moves (a cabinet's carcass) adds nothing to M or g.
    ws.composites
        .extend(tree.links.iter().enumerate().map(|(link, l)| match &l.inertial {
            Some(inertial) if !tree.ancestor_active_joints(link).is_empty() => {
                let pose = frames.poses[link];
                let c = (pose * Point3::from(inertial.com)).coords;
                let r = pose.rotation.to_rotation_matrix();
                let inertia_com = r.matrix() * inertial.inertia * r.matrix().transpose();
                Composite {
                    mass: inertial.mass,
                    first_moment: c * inertial.mass,
                    inertia: inertia_com + (Matrix3::identity() * c.norm_squared() - c * c.transpose()) * inertial.mass,
                }
            }
            _ => Composite::ZERO,
        }));
    // Children come after their parents in topological order: summed from the leaves up, each
    // link's entry becomes the inertia of the subtree it carries.
    for &j in tree.topological_joints.iter().rev() {
        let (parent, child) = (tree.joints[j].parent, tree.joints[j].child);
        if tree.ancestor_active_joints(parent).is_empty() {
            continue;
        }
        let below = ws.composites[child];
        let above = &mut ws.composites[parent];
        above.mass += below.mass;
        above.first_moment += below.first_moment;
        above.inertia += below.inertia;
    }
    for &j in &tree.active_joints {
        let joint = &tree.joints[j];
        let b = joint.q_index.expect("movable");
        let moved = &ws.composites[joint.child];
        let (omega_b, v_b) = joint_twist(tree, frames, j);
        let (angular, linear) = moved.momentum(&omega_b, &v_b);
        // Gravity's wrench on the moved bodies about the origin: (h × a_g, m a_g).
        gravity_torque[b] = -(omega_b.dot(&moved.first_moment.cross(gravity)) + v_b.dot(&(gravity * moved.mass)));
        for &i in tree.ancestor_active_joints(joint.child) {
            let a = tree.joints[i].q_index.expect("movable");
            let (omega_a, v_a) = joint_twist(tree, frames, i);
            let m = omega_a.dot(&angular) + v_a.dot(&linear);
            mass_matrix[(a, b)] = m;
            mass_matrix[(b, a)] = m;
        }
    }
}

/// Gravitational potential energy Σ m (−a_g · p_com) of the tree's links.
pub fn potential_energy(tree: &KinematicTree, root_pose: &Isometry3<f64>, q: &[f64], gravity: &Vector3<f64>) -> f64 {
    let poses = tree.link_poses(root_pose, q);
    tree.links
        .iter()
        .zip(poses.iter())
        .filter_map(|(l, pose)| {
            l.inertial
                .map(|i| -i.mass * gravity.dot(&(pose * Point3::from(i.com)).coords))
        })
        .sum()
}

/// Kinetic plus potential energy at configuration q and velocity q̇.
pub fn mechanical_energy(tree: &KinematicTree, root_pose: &Isometry3<f64>, q: &[f64], qd: &[f64], gravity: &Vector3<f64>) -> f64 {
    let mut ws = DynamicsWorkspace::default();
    let mut m = DMatrix::zeros(0, 0);
    let mut g = DVector::zeros(0);
    joint_space_terms(tree, root_pose, q, gravity, &mut ws, &mut m, &mut g);
    let v = DVector::from_column_slice(qd);
    0.5 * v.dot(&(&m * &v)) + potential_energy(tree, root_pose, q, gravity)
}

/// Gravity torque g(q) alone (the torque that holds the tree still), without the mass matrix.
pub fn gravity_torque(tree: &KinematicTree, root_pose: &Isometry3<f64>, q: &[f64], gravity: &Vector3<f64>) -> Vec<f64> {
    let poses = tree.link_poses(root_pose, q);
    let mut out = vec![0.0; tree.nq()];
    let mut jac = vec![0.0; 6 * tree.nq()];
    for (link, l) in tree.links.iter().enumerate() {
        let Some(inertial) = &l.inertial else { continue };
        let com = poses[link] * Point3::from(inertial.com);
        tree.point_jacobian_into(&poses, link, &com, &mut jac);
        for (c, g) in out.iter_mut().enumerate() {
            *g -= inertial.mass * (jac[6 * c] * gravity.x + jac[6 * c + 1] * gravity.y + jac[6 * c + 2] * gravity.z);
        }
    }
    out
}
