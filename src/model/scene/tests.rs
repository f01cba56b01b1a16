//! Scenes from the built-in descriptions: one door of a two-door cabinet held, forward kinematics
//! of many configurations and its refusals, gravity torque as the gradient of the potential energy.

use super::*;
use crate::model::dynamics::potential_energy;

fn scene() -> Scene {
    Scene::load("royalpanda", "shelf", None).expect("built-in scene loads")
}

const DOUBLE_CABINET: &str = include_str!("../../../assets/objects/examples/double_cabinet.urdf");

#[test]
fn one_joint_of_a_two_door_cabinet_stays_movable_and_the_other_is_held() {
    let robot = BUILTIN_ROBOTS[0].1;
    let both = Scene::from_urdf_strings(robot, DOUBLE_CABINET, None).unwrap();
    assert_eq!(both.object.active_joint_names(), ["left_hinge", "right_hinge"]);
    let held = vec![("right_hinge".to_string(), 0.5)];
    let left = Scene::from_urdf_strings(robot, DOUBLE_CABINET, None)
        .unwrap()
        .with_object_joint(Some("left_hinge"), &held, None)
        .unwrap();
    assert_eq!(left.no(), 1);
    assert_eq!(left.object.active_joint_names(), ["left_hinge"]);
    for o in [0.0, 0.7, 1.5] {
        for frame in ["left_pull", "right_pull", "right_door"] {
            let reduced = left.object_fk(&[o], frame).unwrap();
            let full = both.object_fk(&[o, 0.5], frame).unwrap();
            assert!(
                (reduced.to_homogeneous() - full.to_homogeneous()).norm() < 1e-12,
                "{frame} at {o}"
            );
        }
    }
    // Without a value the other door is held closed (0 lies within its limits).
    let closed = Scene::from_urdf_strings(robot, DOUBLE_CABINET, None)
        .unwrap()
        .with_object_joint(Some("right_hinge"), &[], None)
        .unwrap();
    let full = both.object_fk(&[0.0, 0.3], "left_pull").unwrap();
    assert!((closed.object_fk(&[0.3], "left_pull").unwrap().to_homogeneous() - full.to_homogeneous()).norm() < 1e-12);
}

#[test]
fn a_bad_joint_choice_names_the_candidates() {
    let robot = BUILTIN_ROBOTS[0].1;
    let build = |joint: Option<&str>, hold: &[(String, f64)]| {
        Scene::from_urdf_strings(robot, DOUBLE_CABINET, None)
            .unwrap()
            .with_object_joint(joint, hold, None)
            .unwrap_err()
            .to_string()
    };
    assert!(build(Some("door"), &[]).contains("left_hinge, right_hinge"));
    assert!(build(Some("left_hinge"), &[("left_hinge".into(), 0.1)]).contains("right_hinge"));
    assert!(build(Some("left_hinge"), &[("right_hinge".into(), 2.0)]).contains("outside its limits"));
    assert!(build(None, &[("right_hinge".into(), 0.1)]).contains("needs `joint`"));
}

#[test]
fn fk_many_equals_fk_of_each_row() {
    let s = scene();
    let home = s.home_configuration();
    let rows: Vec<f64> = (0..3)
        .flat_map(|k| {
            home.iter()
                .enumerate()
                .map(move |(i, v)| v + 0.1 * k as f64 * (i as f64).sin())
        })
        .collect();
    let poses = s.fk_many(&rows, "grasp").unwrap();
    assert_eq!(poses.len(), 3);
    for (row, pose) in rows.chunks(s.nq()).zip(&poses) {
        assert_eq!(*pose, s.fk(row, "grasp").unwrap());
    }
    let o = [0.1, 0.4];
    let object_poses = s.object_fk_many(&o, "handle_frame").unwrap();
    for (value, pose) in o.iter().zip(&object_poses) {
        assert_eq!(*pose, s.object_fk(&[*value], "handle_frame").unwrap());
    }
}

#[test]
fn fk_many_rejects_ragged_non_finite_and_unknown_input() {
    let s = scene();
    let mut rows = s.home_configuration();
    rows.push(0.0);
    assert!(matches!(s.fk_many(&rows, "grasp"), Err(SabreError::Shape { .. })));
    rows.pop();
    rows[2] = f64::NAN;
    assert!(matches!(s.fk_many(&rows, "grasp"), Err(SabreError::InvalidValue { .. })));
    assert!(matches!(
        s.fk_many(&s.home_configuration(), "gripper"),
        Err(SabreError::UnknownFrame { .. })
    ));
}

#[test]
fn gravity_torque_is_the_gradient_of_the_potential_energy() {
    let s = scene();
    let q: Vec<f64> = s
        .home_configuration()
        .iter()
        .enumerate()
        .map(|(i, v)| v + 0.05 * i as f64)
        .collect();
    let (m, g) = s.mass_matrix_and_gravity(&q).unwrap();
    assert_eq!((m.nrows(), m.ncols(), g.len()), (s.nq(), s.nq(), s.nq()));
    assert!((&m - m.transpose()).norm() < 1e-12, "M(q) is symmetric");
    let root = Isometry3::identity();
    let h = 1e-6;
    for i in 0..s.nq() {
        let (mut up, mut down) = (q.clone(), q.clone());
        up[i] += h;
        down[i] -= h;
        let gradient = (potential_energy(&s.robot, &root, &up, &crate::model::GRAVITY)
            - potential_energy(&s.robot, &root, &down, &crate::model::GRAVITY))
            / (2.0 * h);
        assert!(
            (g[i] - gradient).abs() < 1e-5 * (1.0 + gradient.abs()),
            "joint {i}: g = {}, dV/dq = {gradient}",
            g[i]
        );
    }
}
