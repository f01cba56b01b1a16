//! What a proxy is made of, for both contact paths: the rigid bodies that fixed joints merge a
//! tree's links into, and the robot's effective mass at a point, which a proxy carries.

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Vector3};

use crate::model::dynamics::{joint_space_terms, DynamicsWorkspace};
use crate::model::kinematics::{JointKind, KinematicTree};

/// For each link: the link that owns its rigid body (fixed joints merge links) and its pose in that body.
pub(crate) fn body_groups(tree: &KinematicTree) -> (Vec<usize>, Vec<Isometry3<f64>>) {
    let n = tree.links.len();
    let mut group: Vec<usize> = (0..n).collect();
    let mut offset = vec![Isometry3::identity(); n];
    for &j in &tree.topological_joints {
        let joint = &tree.joints[j];
        if joint.kind == JointKind::Fixed {
            group[joint.child] = group[joint.parent];
            offset[joint.child] = offset[joint.parent] * joint.origin;
        }
    }
    (group, offset)
}

/// Smallest effective mass of the robot felt at `point` (link frame) of `link`: 1 / λ_max(J_v M⁻¹ J_vᵀ).
pub(crate) fn effective_mass(tree: &KinematicTree, q: &[f64], link: usize, point: &Point3<f64>) -> f64 {
    let n = tree.nq();
    let mut ws = DynamicsWorkspace::default();
    let mut m = DMatrix::zeros(n, n);
    let mut g = DVector::zeros(n);
    joint_space_terms(tree, &Isometry3::identity(), q, &Vector3::zeros(), &mut ws, &mut m, &mut g);
    let poses = tree.link_poses(&Isometry3::identity(), q);
    let mut jac = vec![0.0; 6 * n];
    tree.point_jacobian_into(&poses, link, &(poses[link] * point), &mut jac);
    let jv = DMatrix::from_fn(3, n, |r, c| jac[6 * c + r]);
    let Some(chol) = m.cholesky() else { return 1.0 };
    let a = &jv * chol.solve(&jv.transpose());
    let largest = a.symmetric_eigenvalues().max();
    if largest > 0.0 {
        (1.0 / largest).clamp(0.1, 1e3)
    } else {
        1.0
    }
}
