//! Loading scenes: minimal descriptions load; malformed XML, missing meshes, two roots, joints to
//! unknown links, sabre pairs naming unknown spheres and other invalid documents are each a URDF
//! error that names what is wrong; bad arguments give their own error variants; collision spheres
//! face obstacles unless the description says otherwise.

use sabre::model::Scene;
use sabre::SabreError;

const ROBOT_OK: &str = r#"<?xml version="1.0"?>
<robot name="bot">
  <link name="base"/>
  <link name="arm">
    <inertial><origin xyz="0 0 0.1"/><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><box size="0.1 0.1 0.2"/></geometry></collision>
  </link>
  <joint name="j" type="revolute">
    <parent link="base"/><child link="arm"/>
    <axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="10"/>
  </joint>
  <sabre>
    <sphere name="s1" link="arm" xyz="0 0 0.1" radius="0.05"/>
    <sphere name="s0" link="base" radius="0.05"/>
    <pair a="s1" b="s0"/>
  </sabre>
</robot>"#;

const OBJECT_OK: &str = r#"<?xml version="1.0"?>
<robot name="thing">
  <link name="cabinet"/>
  <link name="door">
    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><box size="0.02 0.3 0.5"/></geometry></collision>
  </link>
  <link name="handle_frame"/>
  <joint name="articulation" type="revolute">
    <parent link="cabinet"/><child link="door"/>
    <axis xyz="0 0 -1"/>
    <limit lower="0" upper="1.5" velocity="1" effort="10"/>
  </joint>
  <joint name="hf" type="fixed"><parent link="door"/><child link="handle_frame"/><origin xyz="-0.05 -0.2 0"/></joint>
</robot>"#;

fn load(robot: &str, object: &str) -> Result<Scene, SabreError> {
    Scene::from_urdf_strings(robot, object, None)
}

fn expect_urdf_error(label: &str, robot: &str, object: &str, needle: &str) {
    match load(robot, object) {
        Err(SabreError::Urdf { detail, .. }) => {
            assert!(
                detail.to_lowercase().contains(&needle.to_lowercase()),
                "{label}: URDF error does not mention '{needle}': {detail}"
            )
        }
        Err(other) => panic!("{label}: expected SabreError::Urdf, got {other:?}"),
        Ok(_) => panic!("{label}: loaded without error"),
    }
}

#[test]
fn minimal_urdfs_load() {
    let s = load(ROBOT_OK, OBJECT_OK).expect("baseline URDFs are valid");
    assert_eq!(s.nq(), 1);
    assert_eq!(s.no(), 1);
    assert_eq!(s.sphere_pairs.len(), 1);
    // default object pose: x = 1 m
    let hf = s.object_fk(&[0.0], "handle_frame").unwrap();
    let at = hf.translation.vector;
    assert!(
        (at - nalgebra::Vector3::new(0.95, -0.2, 0.0)).norm() < 1e-12,
        "handle_frame at {at}"
    );
}

#[test]
fn malformed_xml_is_a_urdf_error() {
    expect_urdf_error("truncated", &ROBOT_OK[..ROBOT_OK.len() - 20], OBJECT_OK, "");
    expect_urdf_error(
        "mismatched tag",
        "<robot name='x'><link name='a'></joint></robot>",
        OBJECT_OK,
        "xml",
    );
    expect_urdf_error("empty", "", OBJECT_OK, "");
    expect_urdf_error("not xml", "this is not a URDF", OBJECT_OK, "");
    expect_urdf_error("object malformed", ROBOT_OK, "<robot name='o'><link name='a'>", "");
}

#[test]
fn a_mesh_that_cannot_be_found_is_a_urdf_error_naming_it() {
    let robot = ROBOT_OK.replace(r#"<box size="0.1 0.1 0.2"/>"#, r#"<mesh filename="package://bot/arm.stl"/>"#);
    assert_ne!(robot, ROBOT_OK);
    expect_urdf_error("mesh in robot", &robot, OBJECT_OK, "mesh 'package://bot/arm.stl' not found");
    let object = OBJECT_OK.replace(
        r#"<box size="0.02 0.3 0.5"/>"#,
        r#"<mesh filename="door.dae" scale="1 1 1"/>"#,
    );
    expect_urdf_error("mesh in object", ROBOT_OK, &object, "mesh 'door.dae' not found");
}

#[test]
fn two_root_links_is_a_urdf_error() {
    let robot = ROBOT_OK.replace(r#"<link name="base"/>"#, r#"<link name="base"/><link name="stray"/>"#);
    expect_urdf_error("two roots", &robot, OBJECT_OK, "root");
}

#[test]
fn joint_to_unknown_link_is_a_urdf_error() {
    let robot = ROBOT_OK.replace(r#"<child link="arm"/>"#, r#"<child link="nowhere"/>"#);
    expect_urdf_error("unknown child", &robot, OBJECT_OK, "nowhere");
    let robot = ROBOT_OK.replace(r#"<parent link="base"/>"#, r#"<parent link="ghost"/>"#);
    expect_urdf_error("unknown parent", &robot, OBJECT_OK, "ghost");
}

#[test]
fn sabre_pair_with_unknown_sphere_is_a_urdf_error() {
    let robot = ROBOT_OK.replace(r#"<pair a="s1" b="s0"/>"#, r#"<pair a="s1" b="elbow"/>"#);
    expect_urdf_error("unknown sphere", &robot, OBJECT_OK, "elbow");
    let robot = ROBOT_OK.replace(r#"link="base" radius"#, r#"link="nolink" radius"#);
    expect_urdf_error("sphere on unknown link", &robot, OBJECT_OK, "nolink");
}

#[test]
fn other_invalid_urdfs_are_urdf_errors() {
    let floating = ROBOT_OK.replace(r#"type="revolute""#, r#"type="floating""#);
    expect_urdf_error("floating joint", &floating, OBJECT_OK, "floating");
    let duplicate = ROBOT_OK.replace(r#"<link name="base"/>"#, r#"<link name="base"/><link name="base"/>"#);
    expect_urdf_error("duplicate link", &duplicate, OBJECT_OK, "duplicate");
    let zero_axis = ROBOT_OK.replace(r#"<axis xyz="0 0 1"/>"#, r#"<axis xyz="0 0 0"/>"#);
    expect_urdf_error("zero axis", &zero_axis, OBJECT_OK, "axis");
    let negative_mass = ROBOT_OK.replace(r#"<mass value="1"/>"#, r#"<mass value="-1"/>"#);
    expect_urdf_error("negative mass", &negative_mass, OBJECT_OK, "mass");
    let bad_box = ROBOT_OK.replace(r#"<box size="0.1 0.1 0.2"/>"#, r#"<box size="0.1 0 0.2"/>"#);
    expect_urdf_error("zero box", &bad_box, OBJECT_OK, "box");
    let unknown_ext = ROBOT_OK.replace("<sabre>", "<sabre><gizmo/>");
    expect_urdf_error("unknown sabre element", &unknown_ext, OBJECT_OK, "gizmo");
    let fixed_object = OBJECT_OK.replace(r#"type="revolute""#, r#"type="fixed""#);
    expect_urdf_error("object without movable joint", ROBOT_OK, &fixed_object, "movable");
    let continuous_object = OBJECT_OK.replace(r#"type="revolute""#, r#"type="continuous""#);
    expect_urdf_error("object joint without limits", ROBOT_OK, &continuous_object, "limit");
    // Two links that are each other's parent: one has two parents or there is no root.
    let cycle = ROBOT_OK.replace(
        "</robot>",
        r#"<joint name="back" type="fixed"><parent link="arm"/><child link="base"/></joint></robot>"#,
    );
    assert!(matches!(load(&cycle, OBJECT_OK), Err(SabreError::Urdf { .. })), "cycle");
}

#[test]
fn bad_arguments_give_the_matching_error_variant() {
    assert!(matches!(
        Scene::load("robby", "shelf", None),
        Err(SabreError::UnknownAsset { .. })
    ));
    match Scene::load("royalpanda", "fridge", None) {
        Err(SabreError::UnknownAsset { available, .. }) => {
            for name in ["shelf", "microwave", "dishwasher", "drawer"] {
                assert!(available.contains(name), "available list misses {name}: {available}");
            }
        }
        other => panic!("expected UnknownAsset, got {other:?}"),
    }
    assert!(matches!(
        Scene::load("royalpanda", "shelf", Some(&[1.0, 0.0, 0.0])),
        Err(SabreError::Shape { .. })
    ));
    assert!(matches!(
        Scene::load("royalpanda", "shelf", Some(&[1.0, 0.0, 0.0, 0.0, f64::NAN, 0.0])),
        Err(SabreError::InvalidValue { .. })
    ));
    let s = Scene::load("royalpanda", "shelf", None).expect("built-in scene");
    assert!(matches!(s.fk(&[0.0; 9], "grasp"), Err(SabreError::Shape { .. })));
    assert!(matches!(s.fk(&[0.0; 11], "grasp"), Err(SabreError::Shape { .. })));
    assert!(matches!(s.jacobian(&[0.0; 3], "grasp"), Err(SabreError::Shape { .. })));
    let mut q = [0.0; 10];
    q[4] = f64::INFINITY;
    assert!(matches!(s.fk(&q, "grasp"), Err(SabreError::InvalidValue { .. })));
    q[4] = f64::NAN;
    assert!(matches!(s.jacobian(&q, "grasp"), Err(SabreError::InvalidValue { .. })));
    assert!(matches!(s.fk(&[0.0; 10], "gripper"), Err(SabreError::UnknownFrame { .. })));
    assert!(matches!(
        s.jacobian(&[0.0; 10], "handle_frame"),
        Err(SabreError::UnknownFrame { .. })
    ));
    assert!(matches!(s.object_fk(&[0.0], "grasp"), Err(SabreError::UnknownFrame { .. })));
    assert!(matches!(
        s.object_fk(&[0.0, 0.0], "handle_frame"),
        Err(SabreError::Shape { .. })
    ));
    assert!(matches!(
        s.object_fk(&[f64::NAN], "handle_frame"),
        Err(SabreError::InvalidValue { .. })
    ));
}

#[test]
fn spheres_face_obstacles_unless_marked_otherwise() {
    let s = load(ROBOT_OK, OBJECT_OK).expect("baseline URDFs are valid");
    assert!(s.spheres.iter().all(|sp| sp.obstacles));
    let robot = ROBOT_OK.replace(
        r#"xyz="0 0 0.1" radius="0.05"/>"#,
        r#"xyz="0 0 0.1" radius="0.05" obstacles="false"/>"#,
    );
    let s = load(&robot, OBJECT_OK).expect("obstacles is a valid attribute");
    let s1 = s.spheres.iter().find(|sp| sp.name == "s1").unwrap();
    assert!(!s1.obstacles && s.spheres.iter().filter(|sp| sp.obstacles).count() == s.spheres.len() - 1);
    let robot = ROBOT_OK.replace(
        r#"xyz="0 0 0.1" radius="0.05"/>"#,
        r#"xyz="0 0 0.1" radius="0.05" obstacles="maybe"/>"#,
    );
    expect_urdf_error("obstacles maybe", &robot, OBJECT_OK, "obstacles");
}
