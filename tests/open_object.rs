//! The open-object task's core logic against independent references: the handle's travel against
//! the hinge radius and the drawer's unit ratio, the errors against a target placed on the hand,
//! the grasp offset's tilt, the settings' checks, the probe on a door that falls open and the
//! handle named by its link against the handle frame the object declares.

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, Vector3};
use sabre::task::{HandleGeometry, OpenObjectConfig, OpenObjectRules, OpenPhase};
use sabre::Scene;

fn geometry(object: &str) -> HandleGeometry {
    let scene = Arc::new(Scene::load("royalpanda", object, None).expect("built-in scene loads"));
    let tool = scene.tool_frame_name().expect("the robot has a tool frame").to_string();
    HandleGeometry::new(scene, "handle_frame", &tool).expect("the handle frame exists")
}

/// A state with the robot at its start posture moved a little and the object at `opening`.
fn state(scene: &Scene, opening: f64) -> Vec<f64> {
    let mut x = scene.default_state();
    let nq = scene.nq();
    for (i, v) in x[..nq].iter_mut().enumerate() {
        *v += 0.05 * ((i as f64) * 1.7).sin();
    }
    x[2 * nq] = opening;
    x
}

#[test]
fn a_handle_named_by_its_link_moves_as_the_handle_frame_the_object_declares() {
    for object in ["shelf", "drawer", "microwave", "dishwasher"] {
        let scene = Arc::new(Scene::load("royalpanda", object, None).expect("built-in scene loads"));
        let tool = scene.tool_frame_name().expect("the robot has a tool frame").to_string();
        let by_link = HandleGeometry::new(scene.clone(), "handle", &tool).expect("the handle link has geometry");
        let limits = scene.object_limits()[0];
        for fraction in [0.0, 0.4, 1.0] {
            let o = [limits.lower + fraction * (limits.upper - limits.lower)];
            let declared = scene.object_fk(&o, "handle_frame").unwrap().to_homogeneous();
            let inferred = by_link.handle_pose(&o).to_homogeneous();
            assert!(
                (inferred - declared).abs().max() < 1e-12,
                "{object} at {o:?}: {inferred} {declared}"
            );
        }
    }
    let scene = Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene loads"));
    let tool = scene.tool_frame_name().expect("the robot has a tool frame").to_string();
    let missing = HandleGeometry::new(scene, "pull", &tool).unwrap_err().to_string();
    assert!(
        missing.contains("'pull'") && missing.contains("links with collision geometry"),
        "{missing}"
    );
}

#[test]
fn a_drawer_handle_moves_one_metre_per_metre_and_a_door_handle_its_radius_per_radian() {
    let drawer = geometry("drawer");
    let upper = drawer.scene().object_limits()[0].upper;
    for o in [0.0, 0.5 * upper, upper] {
        assert!(
            (drawer.travel(&[o]) - 1.0).abs() < 1e-9,
            "drawer at {o}: {}",
            drawer.travel(&[o])
        );
    }
    let shelf = geometry("shelf");
    let scene = shelf.scene().clone();
    let joint = scene.object.active_joints[0];
    for o in [0.1, 0.6, 1.2] {
        let poses = scene.object.link_poses(&scene.object_pose, &[o]);
        let (axis, origin) = scene.object.joint_axis_world(&poses, joint);
        let handle = shelf.handle_pose(&[o]).translation.vector;
        let radius = (handle - origin.coords).cross(&axis).norm() / axis.norm();
        assert!(
            (shelf.travel(&[o]) - radius).abs() < 1e-6 * radius,
            "door at {o}: {} vs radius {radius}",
            shelf.travel(&[o])
        );
    }
}

#[test]
fn a_target_on_the_hand_has_no_error_and_one_moved_into_the_door_has_the_move_as_depth() {
    let handle = geometry("shelf");
    let scene = handle.scene().clone();
    let x = state(&scene, 0.3);
    let at = handle.at(&x);
    let on_hand = at.handle.inverse() * at.tool;
    let (distance, angle) = at.approach_error(&on_hand);
    assert!(distance < 1e-12 && angle < 1e-6, "{distance} {angle}");
    let (across, along) = at.pocket_error(&on_hand);
    assert!(across < 1e-12 && along < 1e-12);
    assert!(at.lateral_error(on_hand.translation.vector.y).abs() < 1e-12);
    for (shift, depth, across, along) in [
        (Vector3::new(0.0, 0.0, 0.02), -0.02, 0.02, 0.0),
        (Vector3::new(0.0, 0.0, -0.01), 0.01, 0.01, 0.0),
        (Vector3::new(0.03, 0.0, 0.0), 0.0, 0.0, 0.03),
        (Vector3::new(0.0, 0.004, 0.0), 0.0, 0.004, 0.0),
    ] {
        // the target moved by `shift` in the handle frame: the hand is short of it by that much
        let target = Isometry3::from_parts(Translation3::from(on_hand.translation.vector + shift), on_hand.rotation);
        assert!((at.depth_error(&target) - depth).abs() < 1e-12, "{shift:?}");
        let (got_across, got_along) = at.pocket_error(&target);
        assert!(
            (got_across - across).abs() < 1e-12 && (got_along - along).abs() < 1e-12,
            "{shift:?}"
        );
        assert!((at.approach_error(&target).0 - shift.norm()).abs() < 1e-12);
        assert!((at.lateral_error(target.translation.vector.y) + shift.y).abs() < 1e-12);
    }
}

#[test]
fn the_grasp_offset_tilts_the_hand_down_by_the_pitch_about_a_horizontal_handle_axis() {
    for object in ["shelf", "drawer", "microwave", "dishwasher"] {
        let handle = geometry(object);
        let closed = handle.closed_pose();
        for pitch in [0.0, 0.3, -0.4] {
            let offset = handle.grasp_offset([0.01, -0.02, 0.03], pitch).unwrap();
            assert_eq!(offset.translation.vector, Vector3::new(0.01, -0.02, 0.03));
            let z = (closed * offset).rotation * Vector3::z();
            let normal = closed.rotation * Vector3::z();
            assert!((z.angle(&normal) - pitch.abs()).abs() < 1e-9, "{object} {pitch}");
            // the tilt is about a horizontal axis: the hand's z leaves the normal's vertical plane
            // only vertically, and downward
            let horizontal_axis = normal.cross(&z);
            assert!(horizontal_axis.z.abs() < 1e-9, "{object} {pitch}: {horizontal_axis:?}");
            assert!(z.z <= normal.z + 1e-12, "{object} {pitch}: tilted up");
        }
    }
}

#[test]
fn the_release_starts_at_the_hand_and_ends_backed_off_along_the_release_direction() {
    let handle = geometry("dishwasher");
    let scene = handle.scene().clone();
    let x = state(&scene, 0.4);
    let motion = sabre::task::ReleaseMove {
        entry_side: 0.5,
        entry_depth: -0.07,
        hooked_within: 0.0, // never hooked: the hand only backs off
        speed: 0.4,
        distance: 0.3,
    };
    let (steps, dt) = (100, 0.015);
    let path = handle.release_path(&x, steps, dt, &motion).unwrap();
    assert_eq!(path.len(), steps + 1);
    let tool = handle.at(&x).tool;
    assert!((path[0].translation.vector - tool.translation.vector).norm() < 1e-12);
    let direction = handle.release_direction(&x);
    assert!((direction.norm() - 1.0).abs() < 1e-12);
    let moved = path[steps].translation.vector - tool.translation.vector;
    assert!((moved - 0.3 * direction).norm() < 1e-9, "{moved:?}");
    for pair in path.windows(2) {
        let step = (pair[1].translation.vector - pair[0].translation.vector).norm();
        assert!(step <= 0.4 * dt + 1e-12);
    }
    // from a hinged door the hand backs off half away from the door (the grasp frame's −z), half
    // away from the hinge axis (here from the joint's axis, not from the circle the path fits)
    let poses = scene.object.link_poses(&scene.object_pose, &[0.4]);
    let (axis, origin) = scene.object.joint_axis_world(&poses, scene.object.active_joints[0]);
    let axis = axis.normalize();
    let r = tool.translation.vector - origin.coords;
    let radial = (r - r.dot(&axis) * axis).normalize();
    let back = -(tool.rotation * Vector3::z());
    assert!((direction - (back + radial).normalize()).norm() < 1e-6, "{direction:?}");
}

#[test]
fn settings_out_of_range_are_refused_by_name() {
    let bad = [
        OpenObjectConfig {
            slip_distance: -0.1,
            ..Default::default()
        },
        OpenObjectConfig {
            probe: 0.0,
            ..Default::default()
        },
        OpenObjectConfig {
            success_fraction: 1.5,
            ..Default::default()
        },
        OpenObjectConfig {
            open_speeds: vec![0.1, f64::NAN],
            ..Default::default()
        },
        OpenObjectConfig {
            backout: Some(-1.0),
            ..Default::default()
        },
    ];
    for (config, name) in bad
        .into_iter()
        .zip(["slip_distance", "probe", "success_fraction", "open_speeds", "backout"])
    {
        let error = OpenObjectRules::new(geometry("shelf"), config, 1.0, 1.2)
            .err()
            .expect("refused");
        assert!(error.to_string().contains(name), "{error}");
    }
    assert!(OpenPhase::from_name("pull")
        .unwrap_err()
        .to_string()
        .contains("approach, insert, hook, open, release"));
    for phase in OpenPhase::ALL {
        assert_eq!(OpenPhase::from_name(phase.name()).unwrap(), phase);
    }
}

#[test]
fn a_dishwasher_door_past_its_balance_point_opens_by_itself_and_a_closed_one_does_not() {
    let handle = geometry("dishwasher");
    let scene = handle.scene().clone();
    let upper = scene.object_limits()[0].upper;
    let rules = OpenObjectRules::new(handle, OpenObjectConfig::default(), upper, upper).unwrap();
    assert!(!rules.self_opening(&state(&scene, 0.0)).unwrap());
    assert!(rules.self_opening(&state(&scene, 0.7 * upper)).unwrap());
    // from rest: a door swinging back is judged by what it does once let go, not by its speed now
    let mut moving = state(&scene, 0.0);
    moving[2 * scene.nq() + scene.no()] = 1.0;
    assert!(!rules.self_opening(&moving).unwrap());
    // at success the question is not asked
    assert!(!rules.self_opening(&state(&scene, 0.95 * upper)).unwrap());
}

#[test]
fn an_object_that_nothing_sets_in_motion_is_not_probed_and_the_probe_agrees_that_it_stays() {
    let tilted = [0.9, 0.0, 0.0, 0.05, 0.0, 0.0];
    for (object, pose) in [
        ("shelf", None),
        ("drawer", None),
        ("microwave", None),
        ("dishwasher", None),
        ("shelf", Some(&tilted[..])),
    ] {
        let scene = Arc::new(Scene::load("royalpanda", object, pose).expect("built-in scene loads"));
        let tool = scene.tool_frame_name().expect("a tool frame").to_string();
        let handle = HandleGeometry::new(scene.clone(), "handle_frame", &tool).expect("handle");
        let limits = scene.object_limits()[0];
        // success far above every opening tried, so that the probe's own answer is asked for
        let rules = OpenObjectRules::new(handle, OpenObjectConfig::default(), 10.0, 10.0).unwrap();
        let (nq, no) = (scene.nq(), scene.no());
        let mut resting = 0;
        for fraction in [-0.02, 0.0, 0.1, 0.3, 0.5, 0.7, 0.9] {
            let mut x = state(&scene, limits.lower + fraction * (limits.upper - limits.lower));
            x[2 * nq + no] = 0.3; // moving now: the probe starts from rest all the same
            let stays = rules.stays_at_rest(&x).unwrap();
            let probed = rules.probe_opens(&x).unwrap();
            if stays {
                resting += 1;
                assert!(!probed, "{object} {pose:?} at {fraction}: the probe saw it open");
                assert!(!rules.self_opening(&x).unwrap());
            } else {
                assert_eq!(rules.self_opening(&x).unwrap(), probed, "{object} {pose:?} at {fraction}");
            }
            // beyond a limit the limit pushes back: the probe is always run there
            assert!(!(fraction < 0.0 && stays), "{object}: below its lower limit");
        }
        // Level drawers and doors on vertical hinges stay wherever they are; a dishwasher door and
        // a tilted shelf are probed.
        let level = pose.is_none() && object != "dishwasher";
        assert_eq!(resting, if level { 6 } else { 0 }, "{object} {pose:?}");
    }
}
