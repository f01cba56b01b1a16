//! Handle frames inferred from a box bar, a cylinder bar on standoffs and a tilted mesh hull, each
//! against the frame composed by hand from the numbers written into the object; the shipped objects'
//! handle links against the handle frames their files declare; and the refusals.

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::*;
use crate::model::kinematics::{Collision, Shape};
use crate::model::scene::{BUILTIN_OBJECTS, BUILTIN_ROBOTS};

/// A carcass, a door hinged on its +y edge at (0, 0.2, 0.8) about −z whose leaf's front is its
/// frame's x = 0 plane (the leaf spans y ∈ [−0.4, 0] behind it), and a link `grip` fixed at
/// (−0.061, −0.32, 0.05) in the door frame carrying `grip` collisions.
fn door(leaf: &str, grip: &str) -> String {
    format!(
        r#"<robot name="cabinet">
  <link name="body"><collision><origin xyz="0.25 0 0.5"/><geometry><box size="0.45 0.44 1.0"/></geometry></collision></link>
  <link name="door">{leaf}</link>
  <link name="grip">{grip}</link>
  <joint name="hinge" type="revolute"><parent link="body"/><child link="door"/><origin xyz="0 0.2 0.8"/>
    <axis xyz="0 0 -1"/><limit lower="0" upper="1.5" effort="10" velocity="1"/></joint>
  <joint name="grip_mount" type="fixed"><parent link="door"/><child link="grip"/><origin xyz="-0.061 -0.32 0.05"/></joint>
</robot>"#
    )
}

const LEAF: &str = r#"<collision><origin xyz="0.009 -0.2 0"/><geometry><box size="0.018 0.4 0.6"/></geometry></collision>"#;

fn scene(object: &str, pose: &[f64]) -> Scene {
    Scene::from_urdf_strings(BUILTIN_ROBOTS[0].1, object, Some(pose)).expect("the test object loads")
}

/// The pose of columns `x`, `z × x`, `z` at `origin`.
fn frame(origin: Vector3<f64>, x: Vector3<f64>, z: Vector3<f64>) -> Isometry3<f64> {
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, z.cross(&x), z]));
    Isometry3::from_parts(Translation3::from(origin), UnitQuaternion::from_rotation_matrix(&rotation))
}

fn assert_close(got: &Isometry3<f64>, expected: &Isometry3<f64>, tolerance: f64) {
    let difference: Matrix4<f64> = got.to_homogeneous() - expected.to_homogeneous();
    assert!(difference.abs().max() < tolerance, "got {got}, expected {expected}");
}

#[test]
fn a_box_bar_on_a_door_gets_its_centre_z_into_the_leaf_and_the_finger_on_the_hinge_side() {
    let grip = r#"<collision><origin xyz="0.02 0 0"/><geometry><box size="0.02 0.02 0.2"/></geometry></collision>"#;
    let s = scene(&door(LEAF, grip), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let found = handle_frame(&s, "grip").unwrap();
    assert_eq!(found.link, s.object.link_id("grip").unwrap());
    // the grip frame is the door's, turned by nothing: x up (a vertical bar), y = x̂ × ẑ = −ŷ points
    // away from the hinge (at +y), so the finger on −y comes in from the hinge's side
    assert_close(
        &found.offset,
        &frame(Vector3::new(0.02, 0.0, 0.0), Vector3::z(), Vector3::x()),
        1e-12,
    );
    assert_eq!(found.offset, infer_handle_frame(&s, "grip").unwrap());
}

#[test]
fn a_cylinder_bar_on_standoffs_is_grasped_on_its_axis_with_y_up() {
    let drawer = r#"<robot name="chest">
  <link name="body"><collision><origin xyz="0.25 0 0.5"/><geometry><box size="0.45 0.44 1.0"/></geometry></collision></link>
  <link name="tray"><collision><origin xyz="0.009 0 0"/><geometry><box size="0.018 0.4 0.15"/></geometry></collision></link>
  <link name="grip">
    <collision><origin rpy="1.5707963267948966 0 0"/><geometry><cylinder radius="0.008" length="0.24"/></geometry></collision>
    <collision><origin xyz="0.0305 -0.1 0"/><geometry><box size="0.061 0.01 0.01"/></geometry></collision>
    <collision><origin xyz="0.0305 0.1 0"/><geometry><box size="0.061 0.01 0.01"/></geometry></collision>
  </link>
  <joint name="slide" type="prismatic"><parent link="body"/><child link="tray"/><origin xyz="0 0 0.6"/>
    <axis xyz="-1 0 0"/><limit lower="0" upper="0.35" effort="10" velocity="1"/></joint>
  <joint name="grip_mount" type="fixed"><parent link="tray"/><child link="grip"/><origin xyz="-0.061 0.05 0"/></joint>
</robot>"#;
    let s = scene(drawer, &[1.2, 0.3, 0.05, 0.0, 0.0, 0.4]);
    // the bar's axis runs along the grip frame's y, 0.061 in front of the tray (at x = 0.061):
    // x along the bar, y = z × x = x̂ × ŷ = ẑ up
    let expected = frame(Vector3::zeros(), Vector3::y(), Vector3::x());
    assert_close(&handle_frame(&s, "grip").unwrap().offset, &expected, 1e-12);
}

#[test]
fn a_tilted_u_handle_meshed_as_one_hull_is_grasped_at_its_bar() {
    // a bar 0.01 thick and 0.16 long on legs reaching the leaf (0.061 behind the bar's axis), as one
    // convex hull (a slab), leaning 30° in the leaf's plane; the cabinet turned and moved
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), 30f64.to_radians());
    let corners: Vec<Point3<f64>> = [-0.005, 0.061]
        .iter()
        .flat_map(|&x| {
            [-0.005, 0.005]
                .iter()
                .flat_map(move |&y| [-0.08, 0.08].map(|z| Point3::new(x, y, z)))
        })
        .map(|p| tilt * p)
        .collect();
    let (low, high) = corners.iter().fold(
        (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)),
        |(low, high), p| (low.inf(&p.coords), high.sup(&p.coords)),
    );
    let centre = 0.5 * (low + high);
    let mut s = scene(&door(LEAF, ""), &[2.0, -1.0, 0.1, 0.0, 0.0, 0.7]);
    let grip = s.object.link_id("grip").unwrap();
    s.object.links[grip].collisions.push(Collision {
        name: None,
        shape: Shape::Hull {
            points: corners.iter().map(|p| p - centre).collect(),
            half_extents: 0.5 * (high - low),
        },
        origin: Isometry3::translation(centre.x, centre.y, centre.z),
    });
    // x along the tilted bar, (0, −sin 30°, cos 30°): y = x̂ × x = (0, −cos 30°, −sin 30°) has the
    // hinge (at +y) on its −y side
    let along = tilt * Vector3::z();
    let expected = frame(Vector3::zeros(), along, Vector3::x());
    // the outline's points count once to 12 decimals: a turned bar's axis is that close
    assert_close(&handle_frame(&s, "grip").unwrap().offset, &expected, 1e-9);
}

#[test]
fn the_shipped_handle_links_give_the_handle_frames_their_files_declare() {
    for (object, _) in BUILTIN_OBJECTS {
        let s = Scene::load("royalpanda", object, None).unwrap();
        let closed: Vec<f64> = s.object_limits().iter().map(|l| l.lower).collect();
        let declared = s.object_fk(&closed, "handle").unwrap().inverse() * s.object_fk(&closed, "handle_frame").unwrap();
        assert_close(&infer_handle_frame(&s, "handle").unwrap(), &declared, 1e-12);
        let named = handle_frame(&s, "handle_frame").unwrap();
        assert_eq!(named.link, s.object.link_id("handle_frame").unwrap());
        assert_eq!(
            named.offset,
            Isometry3::identity(),
            "{object}: a frame without geometry is the handle frame"
        );
    }
}

fn refusal(s: &Scene, link: &str) -> String {
    infer_handle_frame(s, link).unwrap_err().to_string()
}

#[test]
fn a_knob_an_unmounted_handle_and_a_link_without_geometry_are_refused_saying_why() {
    let knob = r#"<collision><origin rpy="0 1.5707963267948966 0"/><geometry><cylinder radius="0.015" length="0.03"/></geometry></collision>"#;
    let message = refusal(&scene(&door(LEAF, knob), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), "grip");
    assert!(
        message.contains("a knob, not a bar") && message.contains("30 × 30 mm"),
        "{message}"
    );
    assert!(message.contains("What works: a bar at least 2 times"), "{message}");

    let bar = r#"<collision><geometry><box size="0.01 0.01 0.17"/></geometry></collision>"#;
    let message = refusal(&scene(&door("", bar), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), "grip");
    assert!(
        message.contains("no moving collision geometry besides the handle's own"),
        "{message}"
    );

    let buried = r#"<collision><origin xyz="0.07 0 0"/><geometry><box size="0.01 0.01 0.17"/></geometry></collision>"#;
    let message = refusal(&scene(&door(LEAF, buried), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), "grip");
    assert!(message.contains("lies inside the collision geometry of 'door'"), "{message}");

    let s = scene(&door(LEAF, bar), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let unknown = handle_frame(&s, "pull").unwrap_err();
    assert!(matches!(unknown, SabreError::UnknownFrame { .. }), "{unknown}");
    assert!(
        unknown
            .to_string()
            .contains("links with collision geometry: body, door, grip"),
        "{unknown}"
    );
    let empty = scene(&door(LEAF, ""), &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert!(refusal(&empty, "grip").contains("has no collision geometry to infer a handle from"));
    assert_eq!(handle_frame(&empty, "grip").unwrap().offset, Isometry3::identity());
}

#[test]
fn the_front_outline_of_a_turned_rectangle_with_inner_and_collinear_points_is_that_rectangle() {
    let turn = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3);
    let mut points: Vec<Point3<f64>> = [
        (-0.1, -0.02),
        (0.1, -0.02),
        (0.1, 0.02),
        (-0.1, 0.02),
        (0.0, 0.02),
        (0.03, 0.0),
    ]
    .iter()
    .map(|&(a, b)| turn * Point3::new(a, b, 0.0))
    .collect();
    points.extend(points.clone().iter().map(|p| p + Vector3::new(0.0, 0.0, 0.05)));
    let (axis, length, thickness) = front_outline(&points, &Vector3::z());
    assert!(
        (length - 0.2).abs() < 1e-12 && (thickness - 0.04).abs() < 1e-12,
        "{length} × {thickness}"
    );
    assert!((axis.dot(&(turn * Vector3::x())).abs() - 1.0).abs() < 1e-12, "{axis}");
}
