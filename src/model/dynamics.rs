//! Joint-space mass matrix and gravity torques of a kinematic tree (composite-rigid-body algorithm),
//! potential and mechanical energy.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, Vector3};

use super::kinematics::{Frames, JointKind, KinematicTree};

/// Gravitational acceleration of the world frame (m/s²), z up: the one value every model of the
/// robot and object (plant, rollouts, low-level controller, dynamics queries) is built with.
pub const GRAVITY: Vector3<f64> = Vector3::new(0.0, 0.0, -9.81);

/// Reusable buffers for [`joint_space_terms`]; `frames` holds the link poses of the last call.
#[derive(Debug, Default, Clone)]
pub struct DynamicsWorkspace {
    pub frames: Frames,
    /// Per rigid body of the tree, the inertia of everything its joint moves (see [`Composite`]).
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
    // Through the slice: nalgebra's own fill walks a dynamic matrix element by element.
    mass_matrix.as_mut_slice().fill(0.0);
    if gravity_torque.len() != n {
        gravity_torque.resize_vertically_mut(n, 0.0);
    }
    gravity_torque.as_mut_slice().fill(0.0);
    tree.update_frames(root_pose, q, &mut ws.frames);
    let frames = &ws.frames;
    ws.composites.clear();
    // One inertia per rigid body a movable joint carries; a link that no movable joint moves (a
    // cabinet's carcass) adds nothing to M or g.
    let bodies = tree.rigid_bodies();
    ws.composites.extend(bodies.iter().map(|body| match &body.inertial {
        Some(inertial) => {
            let pose = frames.poses[body.link];
            let c = (pose * Point3::from(inertial.com)).coords;
            let r = pose.rotation.to_rotation_matrix();
            let inertia_com = r.matrix() * inertial.inertia * r.matrix().transpose();
            Composite {
                mass: inertial.mass,
                first_moment: c * inertial.mass,
                inertia: inertia_com + (Matrix3::identity() * c.norm_squared() - c * c.transpose()) * inertial.mass,
            }
        }
        None => Composite::ZERO,
    }));
    // Parents come before their children: summed from the leaves up, each body's entry becomes the
    // inertia of everything its joint moves.
    for (index, body) in bodies.iter().enumerate().rev() {
        if let Some(parent) = body.parent {
            let below = ws.composites[index];
            let above = &mut ws.composites[parent];
            above.mass += below.mass;
            above.first_moment += below.first_moment;
            above.inertia += below.inertia;
        }
    }
    for (moved, body) in ws.composites.iter().zip(bodies) {
        let j = body.joint;
        let b = tree.joints[j].q_index.expect("movable");
        let (omega_b, v_b) = joint_twist(tree, frames, j);
        let (angular, linear) = moved.momentum(&omega_b, &v_b);
        // Gravity's wrench on the moved bodies about the origin: (h × a_g, m a_g).
        gravity_torque[b] = -(omega_b.dot(&moved.first_moment.cross(gravity)) + v_b.dot(&(gravity * moved.mass)));
        for &i in tree.ancestor_active_joints(body.link) {
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

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, Vector3};

    use super::{joint_space_terms, DynamicsWorkspace};
    use crate::model::kinematics::{Inertial, KinematicTree};
    use crate::model::scene::Scene;

    fn mass_matrix(tree: &KinematicTree, q: &[f64]) -> DMatrix<f64> {
        let (mut m, mut g) = (DMatrix::zeros(0, 0), DVector::zeros(0));
        let gravity = Vector3::new(0.0, 0.0, -9.81);
        joint_space_terms(
            tree,
            &Isometry3::identity(),
            q,
            &gravity,
            &mut DynamicsWorkspace::default(),
            &mut m,
            &mut g,
        );
        m
    }

    /// m J_vᵀ J_v + J_ωᵀ I_world J_ω of one body on `link`: its share of M, from the geometric
    /// Jacobian at its centre of mass (no composite inertia involved).
    fn body_share(tree: &KinematicTree, q: &[f64], link: usize, inertial: &Inertial) -> DMatrix<f64> {
        let n = tree.nq();
        let poses = tree.link_poses(&Isometry3::identity(), q);
        let com = poses[link] * Point3::from(inertial.com);
        let mut jacobian = vec![0.0; 6 * n];
        tree.point_jacobian_into(&poses, link, &com, &mut jacobian);
        let j = DMatrix::from_column_slice(6, n, &jacobian);
        let (jv, jw) = (j.rows(0, 3), j.rows(3, 3));
        let r = poses[link].rotation.to_rotation_matrix();
        let i_world = DMatrix::from_iterator(3, 3, (r.matrix() * inertial.inertia * r.matrix().transpose()).iter().copied());
        jv.transpose() * jv * inertial.mass + jw.transpose() * i_world * jw
    }

    #[test]
    fn an_inertial_set_on_a_link_adds_its_body_to_the_mass_matrix() {
        let scene = Scene::load("royalpanda", "shelf", None).expect("built-in scene");
        let mut tree = scene.robot.clone();
        let q: Vec<f64> = (0..tree.nq()).map(|i| 0.3 * (i as f64 + 1.0).sin()).collect();
        let before = mass_matrix(&tree, &q);
        // The tool's grasp frame hangs on fixed joints below the last arm joint: its body is
        // summed with the hand's.
        let link = tree.link_id("grasp").expect("the hook's grasp frame");
        assert!(
            tree.rigid_bodies().iter().all(|b| b.link != link),
            "grasp is not a joint's child"
        );
        let added = Inertial {
            mass: 1.7,
            com: Vector3::new(0.03, -0.02, 0.05),
            inertia: Matrix3::new(0.02, 0.001, 0.0, 0.001, 0.03, -0.002, 0.0, -0.002, 0.01),
        };
        let old = tree.links[link].inertial;
        let expected = match &old {
            Some(o) => &before - body_share(&tree, &q, link, o) + body_share(&tree, &q, link, &added),
            None => &before + body_share(&tree, &q, link, &added),
        };
        tree.set_inertial(link, Some(added));
        let after = mass_matrix(&tree, &q);
        assert!((&after - &expected).abs().max() < 1e-12, "M = {after}\nexpected {expected}");
        tree.set_inertial(link, old);
        assert!((mass_matrix(&tree, &q) - &before).abs().max() < 1e-12);
    }

    #[test]
    fn the_objects_mass_matrix_is_the_sum_of_its_links_shares() {
        for object in ["shelf", "drawer", "dishwasher", "microwave"] {
            let scene = Scene::load("royalpanda", object, None).expect("built-in scene");
            let tree = &scene.object;
            let q = vec![0.4; tree.nq()];
            let expected = tree
                .links
                .iter()
                .enumerate()
                .filter_map(|(link, l)| l.inertial().map(|i| body_share(tree, &q, link, i)))
                .fold(DMatrix::zeros(tree.nq(), tree.nq()), |a, b| a + b);
            let m = mass_matrix(tree, &q);
            assert!(
                (&m - &expected).abs().max() < 1e-12 * (1.0 + expected.abs().max()),
                "{object}: M = {m}\nexpected {expected}"
            );
        }
    }

    /// M(q) from the links' own Jacobian shares, independent of the composite-body algorithm.
    fn summed_mass_matrix(tree: &KinematicTree, q: &[f64]) -> DMatrix<f64> {
        let n = tree.nq();
        tree.links
            .iter()
            .enumerate()
            .filter_map(|(link, l)| l.inertial().map(|i| body_share(tree, q, link, i)))
            .fold(DMatrix::zeros(n, n), |a, b| a + b)
    }

    #[test]
    fn the_mass_matrix_does_not_change_with_the_coordinates_named_invariant_and_does_with_the_others() {
        let royal = Scene::load("royalpanda", "shelf", None).expect("built-in scene");
        // The same arm on a fixed base: its base joints fixed where they are.
        let base: Vec<(usize, f64)> = royal.robot.active_joints[..3].iter().map(|&j| (j, 0.3)).collect();
        let arm = royal.robot.with_joints_fixed(&base, "test").expect("arm on a fixed base");
        let cabinet = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/objects/examples/double_cabinet.urdf"),
        )
        .expect("example object");
        let doors = KinematicTree::from_description(
            crate::model::urdf::parse_urdf("double_cabinet", &cabinet)
                .expect("example object")
                .description,
        );
        // From the descriptions: a mobile base's x and y (prismatic, at the root) and nothing from
        // its yaw on; a fixed arm's first joint; a door's hinge; two doors on one carcass, neither
        // of which carries the other.
        let expected: Vec<(&KinematicTree, Vec<bool>)> = vec![
            (&royal.robot, [vec![true, true], vec![false; 8]].concat()),
            (&arm, [vec![true], vec![false; 6]].concat()),
            (&royal.object, vec![true]),
            (&doors, vec![false, false]),
        ];
        for (tree, flags) in &expected {
            assert_eq!(tree.mass_invariant_coordinates(), flags.as_slice(), "{}", tree.name);
            let n = tree.nq();
            for trial in 0..4 {
                let q: Vec<f64> = (0..n).map(|i| 0.5 * ((i * 7 + trial * 3) as f64 + 0.4).sin()).collect();
                let m = summed_mass_matrix(tree, &q);
                let scale = 1.0 + m.abs().max();
                for (c, &invariant) in flags.iter().enumerate() {
                    let mut moved = q.clone();
                    moved[c] += 0.7;
                    let change = (summed_mass_matrix(tree, &moved) - &m).abs().max();
                    if invariant {
                        assert!(
                            change < 1e-12 * scale,
                            "{}: M changed by {change} with coordinate {c}",
                            tree.name
                        );
                    }
                }
            }
        }
        // The robots' other coordinates do move M (the rule leaves none out that it could name).
        for tree in [&royal.robot, &arm] {
            let flags = tree.mass_invariant_coordinates();
            let q: Vec<f64> = (0..tree.nq()).map(|i| 0.5 * (i as f64 + 0.4).sin()).collect();
            let m = summed_mass_matrix(tree, &q);
            // The last joint of an arm turns only the hand about its own axis: M changes little
            // but it changes.
            for c in (0..tree.nq()).filter(|&c| !flags[c]) {
                let mut moved = q.clone();
                moved[c] += 0.7;
                assert!(
                    (summed_mass_matrix(tree, &moved) - &m).abs().max() > 1e-9,
                    "{}: coordinate {c}",
                    tree.name
                );
            }
        }
    }
}
