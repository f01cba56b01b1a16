//! The reduced path against Rapier's pipeline and the quiet case.

use std::sync::Arc;

use super::ReducedWorld;
use crate::model::scene::Scene;
use crate::sim::test_scene::{probe_and_drawer, reduced_config, servo_config, state, world_at, DT};

fn reduced_at(scene: &Arc<Scene>, x: &[f64]) -> ReducedWorld {
    let mut world = ReducedWorld::new(scene.clone(), &reduced_config()).expect("reduced world");
    world.set_state(x);
    world
}

/// Against the Rapier path on the same pushes: the drawer ends where Rapier's pipeline puts it
/// (within 1 mm after 0.3 s of pushing) and the robot feels the same force.
#[test]
fn the_drawer_moves_as_in_rapiers_pipeline() {
    let scene = probe_and_drawer();
    let x0 = state([0.62, 0.3], [0.3, 0.0], 0.0, 0.0);
    let mut reduced = reduced_at(&scene, &x0);
    let mut rapier = world_at(&scene, &servo_config(0.0, false), &x0);
    let (mut a, mut b) = (x0.clone(), x0.clone());
    let (mut impulse_a, mut impulse_b) = (0.0, 0.0);
    for _ in 0..20 {
        reduced.step_once(&[0.3, 0.2], &mut a);
        rapier.step_once(&[0.3, 0.2], &mut b);
        impulse_a += reduced.interaction().tau_ext[0] * DT;
        impulse_b += rapier.interaction().tau_ext[0] * DT;
    }
    assert!(b[4] > 0.05, "Rapier's drawer opened: {}", b[4]);
    assert!((a[4] - b[4]).abs() < 1e-3, "drawer {} vs {}", a[4], b[4]);
    assert!(
        (impulse_a - impulse_b).abs() < 0.05 * impulse_b.abs(),
        "{impulse_a} vs {impulse_b}"
    );
}

#[test]
fn nothing_touches_a_robot_far_from_the_object() {
    let scene = probe_and_drawer();
    let x0 = state([-0.5, 0.0], [0.0, 0.0], 0.2, 0.0);
    let mut world = reduced_at(&scene, &x0);
    let mut x = x0.clone();
    for _ in 0..10 {
        world.step_once(&[0.1, 0.5], &mut x);
        assert!(!world.interaction().contact && world.contacts().is_empty());
        assert_eq!(world.interaction().tau_ext, vec![0.0; 2]);
    }
    // Held by its dry friction, the drawer stays put.
    assert_eq!(x[4], 0.2);
}

/// An object with more movable joints than the reduced solve takes is refused when the world is
/// built, naming the limit and the path that takes it.
#[test]
fn an_object_with_too_many_joints_is_refused_by_name() {
    let joints = super::MAX_OBJECT_DOFS + 1;
    let mut urdf = String::from(r#"<robot name="chain"><link name="l0"/>"#);
    for i in 1..=joints {
        urdf += &format!(
            r#"<link name="l{i}"><inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
            <joint name="j{i}" type="revolute"><parent link="l{}"/><child link="l{i}"/><axis xyz="0 0 1"/>
            <limit lower="-1" upper="1" effort="10" velocity="1"/></joint>"#,
            i - 1
        );
    }
    urdf += "</robot>";
    let scene = Arc::new(
        Scene::from_urdf_strings(
            crate::sim::test_scene::ROBOT,
            &urdf,
            Some(&crate::sim::test_scene::OBJECT_POSE),
        )
        .expect("test scene"),
    );
    match ReducedWorld::new(scene, &reduced_config()) {
        Err(crate::SabreError::InvalidValue { what, detail }) => {
            assert_eq!(what, "contact_model");
            assert!(
                detail.contains(&joints.to_string()) && detail.contains("'rapier'"),
                "{detail}"
            );
        }
        Err(other) => panic!("another error: {other}"),
        Ok(_) => panic!("a world of {joints} object joints was built"),
    }
}
