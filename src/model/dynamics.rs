//! Joint-space mass matrix and gravity torques of a kinematic tree, assembled from link Jacobians.

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Vector3};

use super::kinematics::{Frames, KinematicTree};

/// Reusable buffers for [`joint_space_terms`]; `frames` holds the link poses of the last call.
#[derive(Debug, Default, Clone)]
pub struct DynamicsWorkspace {
    pub frames: Frames,
    jacobian: Vec<f64>,
    columns: Vec<usize>,
}

/// M(q) = Σ_links (m J_vᵀ J_v + J_ωᵀ I_world J_ω) with J taken at each link's centre of mass, and
/// g(q) = −Σ_links m J_vᵀ a_g, the torque that holds the tree still against gravity `a_g`.
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
    mass_matrix.resize_mut(n, n, 0.0);
    mass_matrix.fill(0.0);
    gravity_torque.resize_vertically_mut(n, 0.0);
    gravity_torque.fill(0.0);
    tree.update_frames(root_pose, q, &mut ws.frames);
    ws.jacobian.resize(6 * n, 0.0);
    for (link, l) in tree.links.iter().enumerate() {
        let Some(inertial) = &l.inertial else { continue };
        if tree.ancestor_active_joints(link).is_empty() {
            continue;
        }
        let pose = ws.frames.poses[link];
        let com = pose * Point3::from(inertial.com);
        tree.frames_jacobian_into(&ws.frames, link, &com, &mut ws.jacobian);
        let r = pose.rotation.to_rotation_matrix();
        let inertia_world = r.matrix() * inertial.inertia * r.matrix().transpose();
        ws.columns.clear();
        ws.columns.extend(
            tree.ancestor_active_joints(link)
                .iter()
                .map(|&j| tree.joints[j].q_index.expect("movable")),
        );
        let cols = &ws.columns;
        for &a in cols {
            let ja = &ws.jacobian[6 * a..6 * a + 6];
            let va = Vector3::new(ja[0], ja[1], ja[2]);
            let wa = Vector3::new(ja[3], ja[4], ja[5]);
            gravity_torque[a] -= inertial.mass * va.dot(gravity);
            let iwa = inertia_world * wa;
            for &b in cols {
                let jb = &ws.jacobian[6 * b..6 * b + 6];
                let vb = Vector3::new(jb[0], jb[1], jb[2]);
                let wb = Vector3::new(jb[3], jb[4], jb[5]);
                mass_matrix[(a, b)] += inertial.mass * va.dot(&vb) + iwa.dot(&wb);
            }
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
