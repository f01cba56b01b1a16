//! Kinematics, Jacobians and joint-space dynamics terms of the built-in scene,
//! each checked against an independent reference: hand-computed Panda geometry, finite differences
//! of forward kinematics, and kinetic/potential energies computed from inertials read directly from
//! the URDF file (not through sabre's loader).

use std::collections::HashMap;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sabre::model::dynamics::{joint_space_terms, mechanical_energy, potential_energy, DynamicsWorkspace};
use sabre::model::Scene;

const ROBOT_URDF: &str = include_str!("../assets/robots/royalpanda.urdf");
const GRAVITY: f64 = 9.81;
/// Where panda_link0 sits on base_link (the arm mount), from the spec of the robot.
const MOUNT: [f64; 3] = [0.295, 0.005, 0.445];

fn scene() -> Scene {
    Scene::load("royalpanda", "shelf", None).expect("built-in scene loads")
}

fn v3(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

fn pos(p: &Isometry3<f64>) -> Vector3<f64> {
    p.translation.vector
}

fn rot(p: &Isometry3<f64>) -> Matrix3<f64> {
    *p.rotation.to_rotation_matrix().matrix()
}

fn rz(a: f64) -> Matrix3<f64> {
    *Rotation3::from_axis_angle(&Vector3::z_axis(), a).matrix()
}

fn assert_vec_close(what: &str, got: &Vector3<f64>, want: &Vector3<f64>, tol: f64) {
    let err = (got - want).norm();
    assert!(err <= tol, "{what}: got {got:?}, expected {want:?} (error {err:e} > {tol:e})");
}

fn assert_mat_close(what: &str, got: &Matrix3<f64>, want: &Matrix3<f64>, tol: f64) {
    let err = (got - want).abs().max();
    assert!(err <= tol, "{what}: got {got}, expected {want} (max error {err:e} > {tol:e})");
}

/// Index of each named joint in q, from the scene's own ordering (checked separately below).
fn qi(scene: &Scene, joint: &str) -> usize {
    scene
        .robot
        .active_joint_names()
        .iter()
        .position(|n| n == joint)
        .unwrap_or_else(|| panic!("joint {joint} not found"))
}

/// A random configuration strictly inside the joint limits (base translation kept within ±2 m).
fn random_q(scene: &Scene, rng: &mut ChaCha8Rng) -> Vec<f64> {
    scene
        .robot_limits()
        .iter()
        .map(|l| {
            let lo = l.lower.max(-2.0) + 0.05;
            let hi = l.upper.min(2.0) - 0.05;
            rng.random_range(lo..hi)
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Hand-computed poses
// ---------------------------------------------------------------------------------------------

#[test]
fn joint_order_is_base_then_arm() {
    let s = scene();
    let want: Vec<String> = ["base_x", "base_y", "base_yaw"]
        .iter()
        .map(|s| s.to_string())
        .chain((1..=7).map(|i| format!("panda_joint{i}")))
        .collect();
    assert_eq!(s.robot.active_joint_names(), want);
    assert_eq!(s.nq(), 10);
    assert_eq!(s.no(), 1);
    assert_eq!(s.nx(), 22);
}

#[test]
fn zero_configuration_matches_hand_computed_panda_geometry() {
    let s = scene();
    let q = vec![0.0; 10];
    let m = Vector3::from(MOUNT);
    // Manufacturer offsets: d1 = 0.333, d3 = 0.316, a4 = 0.0825, d5 = 0.384, a7 = 0.088, d_flange = 0.107.
    // At q = 0 the Panda is stretched straight up with the elbow and wrist offsets along +x.
    let expected: [(&str, Vector3<f64>); 9] = [
        ("panda_link0", v3(0.0, 0.0, 0.0)),
        ("panda_link1", v3(0.0, 0.0, 0.333)),
        ("panda_link2", v3(0.0, 0.0, 0.333)),
        ("panda_link3", v3(0.0, 0.0, 0.333 + 0.316)),
        ("panda_link4", v3(0.0825, 0.0, 0.333 + 0.316)),
        ("panda_link5", v3(0.0, 0.0, 0.333 + 0.316 + 0.384)),
        ("panda_link6", v3(0.0, 0.0, 0.333 + 0.316 + 0.384)),
        ("panda_link7", v3(0.088, 0.0, 0.333 + 0.316 + 0.384)),
        ("panda_link8", v3(0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107)),
    ];
    for (frame, p) in expected {
        let pose = s.fk(&q, frame).unwrap();
        assert_vec_close(frame, &pos(&pose), &(m + p), 1e-9);
    }
    // The famous Panda zero-pose flange position (0.088, 0, 0.926) above the arm base.
    assert_vec_close(
        "flange",
        &(pos(&s.fk(&q, "panda_link8").unwrap()) - m),
        &v3(0.088, 0.0, 0.926),
        1e-9,
    );

    // Orientations at q = 0: links 1, 3, 5 are aligned with the world; 2, 4, 6 are rotated +-90 deg
    // about x; link 7 and the flange (link 8) point down (rotation of pi about x).
    let rx = |a: f64| *Rotation3::from_axis_angle(&Vector3::x_axis(), a).matrix();
    let half = std::f64::consts::FRAC_PI_2;
    for (frame, r) in [
        ("base_link", Matrix3::identity()),
        ("panda_link0", Matrix3::identity()),
        ("panda_link1", Matrix3::identity()),
        ("panda_link2", rx(-half)),
        ("panda_link3", Matrix3::identity()),
        ("panda_link4", rx(half)),
        ("panda_link5", Matrix3::identity()),
        ("panda_link6", rx(half)),
        ("panda_link7", rx(std::f64::consts::PI)),
        ("panda_link8", rx(std::f64::consts::PI)),
    ] {
        assert_mat_close(frame, &rot(&s.fk(&q, frame).unwrap()), &r, 1e-9);
    }

    // grasp: 0.095 m along the hand z (= flange z, pointing down) and 0.015 m along the hand y;
    // the hand is turned -45 deg about the flange z, so hand y = R8 (sin 45, cos 45, 0) = (c, -c, 0).
    let c = std::f64::consts::FRAC_1_SQRT_2;
    let flange = pos(&s.fk(&q, "panda_link8").unwrap());
    let grasp = s.fk(&q, "grasp").unwrap();
    assert_vec_close(
        "grasp position",
        &pos(&grasp),
        &(flange + 0.015 * v3(c, -c, 0.0) + 0.095 * v3(0.0, 0.0, -1.0)),
        1e-9,
    );
    let hand_y = rot(&grasp).column(1).into_owned();
    assert_vec_close("grasp y axis", &hand_y, &v3(c, -c, 0.0), 1e-9);
    let hand_z = rot(&grasp).column(2).into_owned();
    assert_vec_close("grasp z axis", &hand_z, &v3(0.0, 0.0, -1.0), 1e-9);
}

#[test]
fn single_arm_joints_move_links_as_hand_computed() {
    let s = scene();
    let m = Vector3::from(MOUNT);
    // joint 1 (vertical axis through the arm base) by +90 deg swings the elbow offset from +x to +y.
    let mut q = vec![0.0; 10];
    q[qi(&s, "panda_joint1")] = std::f64::consts::FRAC_PI_2;
    assert_vec_close(
        "link4 after joint1",
        &pos(&s.fk(&q, "panda_link4").unwrap()),
        &(m + v3(0.0, 0.0825, 0.649)),
        1e-9,
    );
    assert_vec_close(
        "link7 after joint1",
        &pos(&s.fk(&q, "panda_link7").unwrap()),
        &(m + v3(0.0, 0.088, 1.033)),
        1e-9,
    );

    // joint 2 rotates about the world +y axis through the shoulder (0, 0, 0.333):
    // the upper arm (length 0.316) tilts forward by the joint angle.
    for theta in [0.3_f64, -0.7, 1.2] {
        let mut q = vec![0.0; 10];
        q[qi(&s, "panda_joint2")] = theta;
        let want = m + v3(0.0, 0.0, 0.333) + 0.316 * v3(theta.sin(), 0.0, theta.cos());
        assert_vec_close("link3 after joint2", &pos(&s.fk(&q, "panda_link3").unwrap()), &want, 1e-9);
    }

    // joint 4 rotates about the world -y axis through the elbow (0.0825, 0, 0.649): the forearm
    // (link5 sits 0.384 up and 0.0825 back from the elbow) rotates in the x-z plane.
    let theta = -1.0;
    let mut q = vec![0.0; 10];
    q[qi(&s, "panda_joint4")] = theta;
    let elbow = v3(0.0825, 0.0, 0.649);
    let rel = v3(-0.0825, 0.0, 0.384);
    // rotation by theta about -y = rotation by -theta about +y
    let ry = *Rotation3::from_axis_angle(&Vector3::y_axis(), -theta).matrix();
    assert_vec_close(
        "link5 after joint4",
        &pos(&s.fk(&q, "panda_link5").unwrap()),
        &(m + elbow + ry * rel),
        1e-9,
    );
}

#[test]
fn base_joints_translate_and_rotate_every_frame() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (ix, iy, iyaw) = (qi(&s, "base_x"), qi(&s, "base_y"), qi(&s, "base_yaw"));
    let frames = [
        "base_link",
        "panda_link0",
        "panda_link3",
        "panda_link8",
        "panda_hand",
        "grasp",
        "hook_finger",
    ];
    for _ in 0..3 {
        let mut q0 = random_q(&s, &mut rng);
        q0[ix] = 0.0;
        q0[iy] = 0.0;
        q0[iyaw] = 0.0;
        let (dx, dy, yaw) = (
            rng.random_range(-3.0..3.0),
            rng.random_range(-3.0..3.0),
            rng.random_range(-3.0..3.0),
        );

        let mut qt = q0.clone();
        qt[ix] = dx;
        qt[iy] = dy;
        let mut qr = q0.clone();
        qr[iyaw] = yaw;
        let mut qb = q0.clone();
        qb[ix] = dx;
        qb[iy] = dy;
        qb[iyaw] = yaw;

        for frame in frames {
            let p0 = s.fk(&q0, frame).unwrap();
            // pure translation: same orientation, position shifted by (dx, dy, 0)
            let pt = s.fk(&qt, frame).unwrap();
            assert_vec_close(frame, &pos(&pt), &(pos(&p0) + v3(dx, dy, 0.0)), 1e-9);
            assert_mat_close(frame, &rot(&pt), &rot(&p0), 1e-12);
            // pure yaw: rotation about the world z axis through the origin
            let pr = s.fk(&qr, frame).unwrap();
            assert_vec_close(frame, &pos(&pr), &(rz(yaw) * pos(&p0)), 1e-9);
            assert_mat_close(frame, &rot(&pr), &(rz(yaw) * rot(&p0)), 1e-9);
            // both: yaw about the (translated) base origin
            let pb = s.fk(&qb, frame).unwrap();
            assert_vec_close(frame, &pos(&pb), &(v3(dx, dy, 0.0) + rz(yaw) * pos(&p0)), 1e-9);
            assert_mat_close(frame, &rot(&pb), &(rz(yaw) * rot(&p0)), 1e-9);
            // the height never depends on the base joints
            assert!((pos(&pb).z - pos(&p0).z).abs() < 1e-12);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Jacobian against finite differences of fk
// ---------------------------------------------------------------------------------------------

/// 6 × nq Jacobian by central differences of fk: linear rows dp/dq, angular rows vee(dR/dq Rᵀ).
fn fd_jacobian(s: &Scene, q: &[f64], frame: &str) -> DMatrix<f64> {
    let h = 1e-6;
    let n = q.len();
    let r0 = rot(&s.fk(q, frame).unwrap());
    let mut j = DMatrix::zeros(6, n);
    for c in 0..n {
        let mut qp = q.to_vec();
        let mut qm = q.to_vec();
        qp[c] += h;
        qm[c] -= h;
        let (pp, pm) = (s.fk(&qp, frame).unwrap(), s.fk(&qm, frame).unwrap());
        let dp = (pos(&pp) - pos(&pm)) / (2.0 * h);
        let w = (rot(&pp) - rot(&pm)) / (2.0 * h) * r0.transpose();
        // w is skew-symmetric up to O(h²): [ω]x = [[0, -wz, wy], [wz, 0, -wx], [-wy, wx, 0]]
        let omega = v3(w[(2, 1)] - w[(1, 2)], w[(0, 2)] - w[(2, 0)], w[(1, 0)] - w[(0, 1)]) / 2.0;
        for r in 0..3 {
            j[(r, c)] = dp[r];
            j[(3 + r, c)] = omega[r];
        }
    }
    j
}

#[test]
fn jacobian_matches_finite_differences_of_fk() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let frames = [
        "grasp",
        "hook_finger",
        "panda_hand",
        "panda_link8",
        "panda_link4",
        "panda_link2",
        "base_link",
        "world",
    ];
    for _ in 0..6 {
        let q = random_q(&s, &mut rng);
        for frame in frames {
            let j = s.jacobian(&q, frame).unwrap();
            assert_eq!(j.shape(), (6, 10), "{frame}");
            let fd = fd_jacobian(&s, &q, frame);
            let err = (&j - &fd).abs().max();
            assert!(
                err < 1e-6,
                "{frame} at q = {q:?}: Jacobian differs from finite differences by {err:e}\nanalytic {j}\nfd {fd}"
            );
        }
    }
}

/// The twist of a frame's origin, its linear Jacobian and the joint torques of a wrench on it,
/// formed without the full Jacobian, against the finite-difference Jacobian: J q̇, J_v and Jᵀ (f, m).
#[test]
fn twist_linear_jacobian_and_wrench_torques_are_the_finite_difference_jacobian_products() {
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut frames = sabre::model::kinematics::Frames::default();
    for _ in 0..4 {
        let q = random_q(&s, &mut rng);
        let qd: Vec<f64> = (0..q.len()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let (force, moment) = (v3(3.0, -1.0, 2.0), v3(-0.5, 0.2, 0.7));
        s.robot.update_frames(&Isometry3::identity(), &q, &mut frames);
        for frame in ["grasp", "panda_link4", "base_link", "world"] {
            let link = s.robot.link_id(frame).unwrap();
            let origin = Point3::from(frames.poses[link].translation.vector);
            let fd = fd_jacobian(&s, &q, frame);
            let twist = &fd * DVector::from_column_slice(&qd);
            let (v, w) = s.robot.frames_point_velocity(&frames, link, &origin, &qd);
            assert_vec_close(frame, &v, &v3(twist[0], twist[1], twist[2]), 1e-6);
            assert_vec_close(frame, &w, &v3(twist[3], twist[4], twist[5]), 1e-6);
            let mut linear = vec![f64::NAN; 3 * q.len()];
            s.robot.frames_linear_jacobian_into(&frames, link, &origin, &mut linear);
            for c in 0..q.len() {
                let want = v3(fd[(0, c)], fd[(1, c)], fd[(2, c)]);
                assert_vec_close(frame, &v3(linear[3 * c], linear[3 * c + 1], linear[3 * c + 2]), &want, 1e-6);
            }
            let wrench = DVector::from_column_slice(&[force.x, force.y, force.z, moment.x, moment.y, moment.z]);
            let want = fd.transpose() * wrench;
            let mut tau = vec![1.0; q.len()];
            s.robot
                .frames_add_wrench_torques(&frames, link, &origin, &force, &moment, &mut tau);
            for (c, (got, want)) in tau.iter().zip(want.iter()).enumerate() {
                assert!((got - 1.0 - want).abs() < 1e-6, "{frame}, joint {c}: {} vs {want}", got - 1.0);
            }
        }
    }
}

#[test]
fn jacobian_of_base_joints_is_world_aligned() {
    // base_x and base_y are world-aligned prismatic joints; base_yaw is a rotation about world z.
    let s = scene();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let q = random_q(&s, &mut rng);
    let j = s.jacobian(&q, "grasp").unwrap();
    let p = pos(&s.fk(&q, "grasp").unwrap());
    let base = v3(q[0], q[1], 0.0);
    let col = |c: usize| DVector::from_iterator(6, j.column(c).iter().copied());
    assert!((col(0) - DVector::from_column_slice(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0])).norm() < 1e-12);
    assert!((col(1) - DVector::from_column_slice(&[0.0, 1.0, 0.0, 0.0, 0.0, 0.0])).norm() < 1e-12);
    let lin = Vector3::z().cross(&(p - base));
    let want = DVector::from_column_slice(&[lin.x, lin.y, lin.z, 0.0, 0.0, 1.0]);
    assert!((col(2) - &want).norm() < 1e-9, "yaw column {} vs {}", col(2), want);
}

// ---------------------------------------------------------------------------------------------
// Dynamics terms against energies computed from the URDF's inertials
// ---------------------------------------------------------------------------------------------

struct RefInertial {
    mass: f64,
    com: Vector3<f64>,
    /// Inertia about the centre of mass, in the link frame.
    inertia: Matrix3<f64>,
}

fn floats(text: &str) -> Vec<f64> {
    text.split_whitespace().map(|t| t.parse().unwrap()).collect()
}

/// Inertials of every link, read from the URDF text with a plain XML parser.
fn reference_inertials() -> HashMap<String, RefInertial> {
    let doc = roxmltree::Document::parse(ROBOT_URDF).unwrap();
    let mut out = HashMap::new();
    for link in doc.root_element().children().filter(|n| n.has_tag_name("link")) {
        let Some(inertial) = link.children().find(|n| n.has_tag_name("inertial")) else {
            continue;
        };
        let child = |tag: &str| inertial.children().find(|n| n.has_tag_name(tag)).unwrap();
        let origin = child("origin");
        let rpy = floats(origin.attribute("rpy").unwrap_or("0 0 0"));
        assert!(
            rpy.iter().all(|v| *v == 0.0),
            "the reference assumes unrotated inertial frames"
        );
        let xyz = floats(origin.attribute("xyz").unwrap_or("0 0 0"));
        let mass: f64 = child("mass").attribute("value").unwrap().parse().unwrap();
        let i = child("inertia");
        let a = |k: &str| -> f64 { i.attribute(k).unwrap().parse().unwrap() };
        let inertia = Matrix3::new(
            a("ixx"),
            a("ixy"),
            a("ixz"),
            a("ixy"),
            a("iyy"),
            a("iyz"),
            a("ixz"),
            a("iyz"),
            a("izz"),
        );
        out.insert(
            link.attribute("name").unwrap().to_string(),
            RefInertial {
                mass,
                com: v3(xyz[0], xyz[1], xyz[2]),
                inertia,
            },
        );
    }
    assert!(
        out.len() >= 13,
        "expected inertials for the base links, the Panda links, the hand and the hook"
    );
    out
}

/// Σ ½ m |v_com|² + ½ ωᵀ I_world ω, with v_com and ω from central differences of link poses along q̇.
fn reference_kinetic_energy(s: &Scene, inertials: &HashMap<String, RefInertial>, q: &[f64], qd: &[f64]) -> f64 {
    let h = 1e-6;
    let qp: Vec<f64> = q.iter().zip(qd).map(|(a, b)| a + h * b).collect();
    let qm: Vec<f64> = q.iter().zip(qd).map(|(a, b)| a - h * b).collect();
    let mut ke = 0.0;
    for (name, inertial) in inertials {
        let p0 = s.fk(q, name).unwrap();
        let pp = s.fk(&qp, name).unwrap();
        let pm = s.fk(&qm, name).unwrap();
        let com = |p: &Isometry3<f64>| (p * Point3::from(inertial.com)).coords;
        let v = (com(&pp) - com(&pm)) / (2.0 * h);
        let r0 = rot(&p0);
        let w = (rot(&pp) - rot(&pm)) / (2.0 * h) * r0.transpose();
        let omega = v3(w[(2, 1)] - w[(1, 2)], w[(0, 2)] - w[(2, 0)], w[(1, 0)] - w[(0, 1)]) / 2.0;
        let i_world = r0 * inertial.inertia * r0.transpose();
        ke += 0.5 * inertial.mass * v.norm_squared() + 0.5 * omega.dot(&(i_world * omega));
    }
    ke
}

fn reference_potential_energy(s: &Scene, inertials: &HashMap<String, RefInertial>, q: &[f64]) -> f64 {
    inertials
        .iter()
        .map(|(name, i)| {
            let p = s.fk(q, name).unwrap();
            i.mass * GRAVITY * (p * Point3::from(i.com)).z
        })
        .sum()
}

fn terms(s: &Scene, q: &[f64]) -> (DMatrix<f64>, DVector<f64>) {
    let mut ws = DynamicsWorkspace::default();
    let mut m = DMatrix::zeros(0, 0);
    let mut g = DVector::zeros(0);
    joint_space_terms(
        &s.robot,
        &Isometry3::identity(),
        q,
        &v3(0.0, 0.0, -GRAVITY),
        &mut ws,
        &mut m,
        &mut g,
    );
    (m, g)
}

#[test]
fn mass_matrix_is_symmetric_positive_definite_and_matches_kinetic_energy() {
    let s = scene();
    let inertials = reference_inertials();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let n = s.nq();
    for trial in 0..3 {
        let q = random_q(&s, &mut rng);
        let (m, _) = terms(&s, &q);
        assert_eq!(m.shape(), (n, n));
        let asym = (&m - m.transpose()).abs().max();
        assert!(asym < 1e-10, "M not symmetric: {asym:e}");
        let eig = m.clone().symmetric_eigen().eigenvalues;
        assert!(eig.min() > 1e-6, "M not positive definite, eigenvalues {eig}");

        // Polarization: M_ii = 2 T(e_i), M_ij = T(e_i + e_j) − T(e_i) − T(e_j), with T the
        // independently computed kinetic energy. This reconstructs every entry of M.
        let t = |qd: &[f64]| reference_kinetic_energy(&s, &inertials, &q, qd);
        let unit = |i: usize| {
            let mut v = vec![0.0; n];
            v[i] = 1.0;
            v
        };
        let ti: Vec<f64> = (0..n).map(|i| t(&unit(i))).collect();
        let mut m_ref = DMatrix::zeros(n, n);
        for i in 0..n {
            m_ref[(i, i)] = 2.0 * ti[i];
            for jj in 0..i {
                let mut v = unit(i);
                v[jj] = 1.0;
                let mij = t(&v) - ti[i] - ti[jj];
                m_ref[(i, jj)] = mij;
                m_ref[(jj, i)] = mij;
            }
        }
        for i in 0..n {
            for jj in 0..n {
                let (a, b) = (m[(i, jj)], m_ref[(i, jj)]);
                assert!(
                    (a - b).abs() < 1e-6 * (1.0 + b.abs()),
                    "trial {trial}: M[{i},{jj}] = {a} but the kinetic energy gives {b}\nM = {m}\nreference = {m_ref}"
                );
            }
        }

        // A random velocity: ½ q̇ᵀ M q̇ equals the kinetic energy; mechanical_energy adds the potential.
        let qd: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let v = DVector::from_column_slice(&qd);
        let ke = 0.5 * v.dot(&(&m * &v));
        let ke_ref = t(&qd);
        assert!(
            (ke - ke_ref).abs() < 1e-7 * (1.0 + ke_ref),
            "½ q̇ᵀMq̇ = {ke}, kinetic energy = {ke_ref}"
        );
        let e = mechanical_energy(&s.robot, &Isometry3::identity(), &q, &qd, &v3(0.0, 0.0, -GRAVITY));
        let e_ref = ke_ref + reference_potential_energy(&s, &inertials, &q);
        assert!(
            (e - e_ref).abs() < 1e-7 * (1.0 + e_ref.abs()),
            "mechanical energy {e} vs {e_ref}"
        );
    }
}

#[test]
fn potential_energy_matches_urdf_inertials_and_gravity_torque_is_its_gradient() {
    let s = scene();
    let inertials = reference_inertials();
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let gravity = v3(0.0, 0.0, -GRAVITY);
    let h = 1e-6;
    for _ in 0..4 {
        let q = random_q(&s, &mut rng);
        let v = potential_energy(&s.robot, &Isometry3::identity(), &q, &gravity);
        let v_ref = reference_potential_energy(&s, &inertials, &q);
        assert!(
            (v - v_ref).abs() < 1e-9 * (1.0 + v_ref.abs()),
            "potential energy {v} vs {v_ref}"
        );

        let (_, g) = terms(&s, &q);
        assert_eq!(g.len(), s.nq());
        for i in 0..s.nq() {
            let mut qp = q.clone();
            let mut qm = q.clone();
            qp[i] += h;
            qm[i] -= h;
            let grad =
                (reference_potential_energy(&s, &inertials, &qp) - reference_potential_energy(&s, &inertials, &qm)) / (2.0 * h);
            let grad_core = (potential_energy(&s.robot, &Isometry3::identity(), &qp, &gravity)
                - potential_energy(&s.robot, &Isometry3::identity(), &qm, &gravity))
                / (2.0 * h);
            assert!(
                (g[i] - grad).abs() < 1e-5 * (1.0 + grad.abs()),
                "g[{i}] = {} but dV/dq = {grad}",
                g[i]
            );
            assert!(
                (g[i] - grad_core).abs() < 1e-5 * (1.0 + grad.abs()),
                "g[{i}] = {} but d potential_energy/dq = {grad_core}",
                g[i]
            );
        }
        // base translation and yaw never change the potential energy
        for i in 0..3 {
            assert!(
                g[i].abs() < 1e-9,
                "g[{i}] = {} should vanish (base joints are horizontal)",
                g[i]
            );
        }
    }
    // A known value: with the arm stretched up at q = 0, no joint has a gravity torque except
    // through horizontal centre-of-mass offsets; joint 1 (vertical axis) never does.
    let (_, g) = terms(&s, &[0.0; 10]);
    assert!(g[qi(&s, "panda_joint1")].abs() < 1e-9);
}

// ---------------------------------------------------------------------------------------------
// URDF loader errors
// ---------------------------------------------------------------------------------------------
