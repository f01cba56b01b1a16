//! The object-state estimator against the object's own kinematics: fits on a door and a drawer, the
//! hook, both releases, bad input and construction.

use super::*;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

fn scene(object: &str) -> Arc<Scene> {
    let scene = Scene::load("royalpanda", object, None).expect("built-in scene loads");
    assert_eq!(scene.robot.active_joint_names()[..3], ["base_x", "base_y", "base_yaw"]);
    Arc::new(scene)
}

/// An estimator on the shipped handle frame that hooks wherever the hand is (the fits below
/// follow a hook point recorded away from the handle just as well).
fn estimator(scene: &Arc<Scene>, initial: f64, config: ObjectEstimatorConfig) -> ObjectStateEstimator {
    let config = ObjectEstimatorConfig {
        hook_distance: 5.0,
        ..config
    };
    ObjectStateEstimator::new(
        scene.clone(),
        "grasp",
        "handle_frame",
        Isometry3::identity(),
        Some(initial),
        config,
    )
    .unwrap()
}

/// `q` with the robot moved rigidly: turned by `angle` about the vertical line through
/// `pivot` (x, y), then shifted by `shift` (x, y), through the holonomic base's joints.
fn moved(q: &[f64], pivot: [f64; 2], angle: f64, shift: [f64; 2]) -> Vec<f64> {
    let (s, c) = angle.sin_cos();
    let (dx, dy) = (q[0] - pivot[0], q[1] - pivot[1]);
    let mut out = q.to_vec();
    out[0] = pivot[0] + c * dx - s * dy + shift[0];
    out[1] = pivot[1] + s * dx + c * dy + shift[1];
    out[2] += angle;
    out
}

/// The world (x, y) of the object's hinge.
fn hinge(scene: &Scene) -> [f64; 2] {
    let poses = scene.object.link_poses(&scene.object_pose, &[0.0]);
    let (axis, origin) = scene.object.joint_axis_world(&poses, scene.object.active_joints[0]);
    assert!(
        (axis - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12,
        "the shelf's hinge is vertical, opening for o > 0"
    );
    [origin.x, origin.y]
}

#[test]
fn a_drawer_follows_the_hand_that_pulls_it_and_its_rate_is_the_low_passed_difference_quotient() {
    let scene = scene("drawer");
    let config = ObjectEstimatorConfig::default();
    let mut estimator = estimator(&scene, 0.1, config);
    let home = scene.home_configuration();
    assert!(estimator.update(&home, 0.0, 10.0, true).unwrap().hooked);
    // The drawer opens along −x: the base backing off by s opens it by s.
    let dt = 1e-3;
    let speed = |k: usize| if k <= 100 { 0.2 } else { 0.5 };
    let mut opened = 0.0;
    let mut filtered = f64::NAN;
    for k in 1..=200 {
        opened += speed(k) * dt;
        let q = moved(&home, [0.0, 0.0], 0.0, [-opened, 0.0]);
        let e = estimator.update(&q, k as f64 * dt, 10.0, true).unwrap();
        assert!(e.hooked && e.residual < 1e-9, "step {k}: {e:?}");
        assert!(
            (e.position - (0.1 + opened)).abs() < 1e-9,
            "step {k}: {} vs {}",
            e.position,
            0.1 + opened
        );
        let gain = 1.0 - (-2.0 * std::f64::consts::PI * config.rate_cutoff * dt).exp();
        filtered = if k == 1 {
            speed(k)
        } else {
            filtered + gain * (speed(k) - filtered)
        };
        assert!((e.velocity - filtered).abs() < 1e-8, "step {k}: {} vs {filtered}", e.velocity);
    }
    assert!(estimator.velocity() > 0.2 && estimator.velocity() < 0.5);
}

#[test]
fn a_door_follows_the_hand_turning_about_its_hinge() {
    let scene = scene("shelf");
    let mut estimator = estimator(&scene, 0.3, ObjectEstimatorConfig::default());
    let home = scene.home_configuration();
    let pivot = hinge(&scene);
    let at = |o: f64| moved(&home, pivot, 0.3 - o, [0.0, 0.0]);
    assert!(estimator.update(&at(0.3), 0.0, 10.0, true).unwrap().hooked);
    for k in 1..=60 {
        let o = 0.3 + 0.01 * k as f64;
        let e = estimator.update(&at(o), 0.01 * k as f64, 10.0, true).unwrap();
        assert!(e.hooked && e.residual < 1e-9, "step {k}: {e:?}");
        assert!((e.position - o).abs() < 1e-9, "step {k}: {} vs {o}", e.position);
    }
    assert!((estimator.velocity() - 1.0).abs() < 1e-6);
}

#[test]
fn the_fit_recovers_the_coordinate_that_places_the_hook_point_at_the_hand() {
    for (object, start, target) in [("shelf", 0.2, 0.31), ("drawer", 0.05, 0.12)] {
        let scene = scene(object);
        let offset = Isometry3::from_parts(
            Translation3::new(0.01, -0.02, 0.03),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let config = ObjectEstimatorConfig::default();
        let mut estimator =
            ObjectStateEstimator::new(scene.clone(), "grasp", "handle_frame", offset, Some(start), config).unwrap();
        let hook_point = Point3::new(0.02, 0.01, -0.015);
        let hand = |o: f64| scene.object_fk(&[o], "handle_frame").unwrap() * offset * hook_point;
        assert!(estimator.observe(&hand(start), 0.0, 1.0, true).hooked);
        assert!((estimator.hook_point().unwrap() - hook_point).norm() < 1e-12);
        let e = estimator.observe(&hand(target), 0.01, 1.0, true);
        assert!(e.hooked && e.residual < 1e-9, "{object}: {e:?}");
        assert!((e.position - target).abs() < 1e-9, "{object}: {} vs {target}", e.position);
        // on to the upper limit and past it: the fit stops there, the residual the distance left
        let upper = scene.object_limits()[0].upper;
        let (mut o, mut t) = (target, 0.01);
        while o < upper - 0.05 {
            (o, t) = (o + 0.05, t + 0.01);
            let e = estimator.observe(&hand(o), t, 1.0, true);
            assert!(e.hooked && (e.position - o).abs() < 1e-9, "{object}: {} vs {o}", e.position);
        }
        let e = estimator.observe(&hand(upper + 0.01), t + 0.01, 1.0, true);
        assert!(
            e.hooked && e.position == upper && e.residual > 1e-4 && e.residual < 0.04,
            "{object}: {e:?}"
        );
    }
}

#[test]
fn the_hook_needs_permission_proximity_and_contact() {
    let scene = scene("shelf");
    let mut estimator = ObjectStateEstimator::new(
        scene.clone(),
        "grasp",
        "handle_frame",
        Isometry3::identity(),
        None,
        ObjectEstimatorConfig::default(),
    )
    .unwrap();
    let handle = scene.object_fk(&[0.0], "handle_frame").unwrap();
    let near = handle * Point3::new(0.0, 0.0, 0.07);
    let far = handle * Point3::new(0.0, 0.0, 0.09);
    assert!(!estimator.observe(&near, 0.0, 1.0, false).hooked);
    assert!(!estimator.observe(&far, 0.01, 1.0, true).hooked);
    assert!(!estimator.observe(&near, 0.02, 0.1, true).hooked);
    let e = estimator.observe(&near, 0.03, 0.2, true);
    assert!(e.hooked && e.position == 0.0 && e.velocity == 0.0 && e.residual.is_nan());
}

#[test]
fn the_hook_releases_when_the_hand_leaves_the_handle_and_the_estimate_holds_at_rest() {
    let scene = scene("shelf");
    let mut estimator = estimator(&scene, 0.3, ObjectEstimatorConfig::default());
    let home = scene.home_configuration();
    let pivot = hinge(&scene);
    estimator.update(&home, 0.0, 10.0, true).unwrap();
    let before = estimator
        .update(&moved(&home, pivot, -0.05, [0.0, 0.0]), 0.01, 10.0, true)
        .unwrap();
    assert!(before.hooked && before.velocity > 0.0);
    // the shoulder lifts the hand off the handle: no turn of the door puts it back
    let mut away = moved(&home, pivot, -0.05, [0.0, 0.0]);
    away[4] += 0.4;
    let lift = scene.fk(&away, "grasp").unwrap().translation.z - scene.fk(&home, "grasp").unwrap().translation.z;
    assert!(lift.abs() > 0.05, "{lift}");
    // (the lift runs mostly along the vertical bar: the hook slid off its end)
    let e = estimator.update(&away, 0.02, 10.0, true).unwrap();
    assert!(!e.hooked && e.velocity == 0.0 && e.position == before.position, "{e:?}");
    // released, the estimate holds at rest wherever the hand goes (this estimator would hook
    // anywhere, so the task holds it off) …
    for k in 0..5 {
        let wandering = moved(&away, pivot, -0.1 * k as f64, [0.0, 0.0]);
        let e = estimator.update(&wandering, 0.03 + 0.01 * k as f64, 10.0, false).unwrap();
        assert!(!e.hooked && e.velocity == 0.0 && e.position == before.position && e.residual.is_nan());
    }
    // … and a new hook starts from it at rest
    let e = estimator.update(&away, 0.1, 10.0, true).unwrap();
    assert!(e.hooked && e.velocity == 0.0 && e.position == before.position);
}

#[test]
fn the_hook_releases_after_the_force_stays_away_longer_than_release_time_only() {
    let scene = scene("shelf");
    let config = ObjectEstimatorConfig::new(5.0, 0.04, 1.0, 0.5, 5.0).unwrap();
    let mut estimator = estimator(&scene, 0.0, config);
    let q = scene.home_configuration();
    assert!(estimator.update(&q, 0.0, 10.0, true).unwrap().hooked);
    // 0.4 s without force, force back (the timer restarts), then 0.5 s without: still hooked
    let mut t = 0.0;
    for _ in 0..40 {
        t += 0.01;
        assert!(estimator.update(&q, t, 0.0, true).unwrap().hooked);
    }
    assert!(estimator.update(&q, t, 5.0, true).unwrap().hooked);
    let restarted = t;
    for _ in 0..49 {
        t += 0.01;
        assert!(
            estimator.update(&q, t, 0.0, true).unwrap().hooked,
            "{} s without force",
            t - restarted
        );
    }
    assert!(!estimator.update(&q, restarted + 0.51, 0.0, true).unwrap().hooked);
}

#[test]
fn bad_input_is_refused_and_leaves_the_estimate_and_its_clock_as_they_were() {
    let scene = scene("shelf");
    let mut estimator = estimator(&scene, 0.3, ObjectEstimatorConfig::default());
    let home = scene.home_configuration();
    let pivot = hinge(&scene);
    estimator.update(&home, 0.0, 10.0, true).unwrap();
    let good = estimator
        .update(&moved(&home, pivot, -0.01, [0.0, 0.0]), 0.01, 10.0, true)
        .unwrap();
    let mut nan = home.clone();
    nan[4] = f64::NAN;
    let bad: [(&[f64], f64, f64); 6] = [
        (&nan, 0.02, 1.0),
        (&home[1..], 0.02, 1.0),
        (&home, f64::NAN, 1.0),
        (&home, f64::INFINITY, 1.0),
        (&home, 0.02, -1.0),
        (&home, 0.02, f64::NAN),
    ];
    for (k, (q, t, force)) in bad.into_iter().enumerate() {
        let error = estimator.update(q, t, force, true).unwrap_err();
        let expected_shape = k == 1;
        assert_eq!(matches!(error, SabreError::Shape { .. }), expected_shape, "{error}");
        assert_eq!(matches!(error, SabreError::InvalidValue { .. }), !expected_shape, "{error}");
        let now = estimator.estimate();
        assert!(now.hooked && now.position == good.position && now.velocity == good.velocity && now.residual == good.residual);
    }
    // the clock still stands at 0.01: the next step's rate, 2 rad/s, is filtered over 0.01 s
    let e = estimator
        .update(&moved(&home, pivot, -0.03, [0.0, 0.0]), 0.02, 10.0, true)
        .unwrap();
    let gain = 1.0 - (-2.0 * std::f64::consts::PI * 5.0 * 0.01_f64).exp();
    assert!((good.velocity - 1.0).abs() < 1e-6, "{good:?}");
    assert!((e.velocity - (1.0 + gain)).abs() < 1e-6, "{e:?}");
    // a time going backwards counts as no time passed: the position follows, the rate holds
    let back = estimator
        .update(&moved(&home, pivot, -0.04, [0.0, 0.0]), 0.0, 10.0, true)
        .unwrap();
    assert!(back.hooked && (back.position - 0.34).abs() < 1e-9 && back.velocity == e.velocity);
}

#[test]
fn construction_refuses_bad_configs_frames_and_objects() {
    let scene = scene("shelf");
    assert_eq!(ObjectEstimatorConfig::default().validate(), Ok(()));
    for (config, name) in [
        (ObjectEstimatorConfig::new(0.0, 0.04, 0.2, 0.5, 5.0), "hook_distance"),
        (
            ObjectEstimatorConfig::new(0.08, f64::INFINITY, 0.2, 0.5, 5.0),
            "release_distance",
        ),
        (ObjectEstimatorConfig::new(0.08, 0.04, -0.1, 0.5, 5.0), "contact_force"),
        (ObjectEstimatorConfig::new(0.08, 0.04, 0.2, f64::NAN, 5.0), "release_time"),
        (ObjectEstimatorConfig::new(0.08, 0.04, 0.2, 0.5, 0.0), "rate_cutoff"),
    ] {
        assert!(
            matches!(config, Err(SabreError::InvalidValue { ref what, .. }) if what == name),
            "{config:?}"
        );
    }
    let build = |scene: &Arc<Scene>, hand: &str, handle: &str, initial: Option<f64>| {
        ObjectStateEstimator::new(
            scene.clone(),
            hand,
            handle,
            Isometry3::identity(),
            initial,
            ObjectEstimatorConfig::default(),
        )
    };
    assert!(matches!(
        build(&scene, "nowhere", "handle_frame", None),
        Err(SabreError::UnknownFrame { .. })
    ));
    assert!(matches!(
        build(&scene, "grasp", "nowhere", None),
        Err(SabreError::UnknownFrame { .. })
    ));
    assert!(matches!(
        build(&scene, "grasp", "handle_frame", Some(f64::NAN)),
        Err(SabreError::InvalidValue { .. })
    ));
    assert_eq!(build(&scene, "grasp", "handle_frame", Some(7.0)).unwrap().position(), 1.57);
    assert_eq!(build(&scene, "grasp", "handle_frame", None).unwrap().position(), 0.0);
    let cabinet = Scene::from_urdf_strings(
        crate::model::scene::BUILTIN_ROBOTS[0].1,
        include_str!("../../../assets/objects/examples/double_cabinet.urdf"),
        None,
    )
    .unwrap();
    let error = build(&Arc::new(cabinet), "grasp", "left_pull", None).unwrap_err();
    assert!(error.to_string().contains("single-joint"), "{error}");
}

#[test]
fn reset_to_starts_over_at_rest_and_unhooked() {
    let scene = scene("drawer");
    let mut estimator = estimator(&scene, 0.1, ObjectEstimatorConfig::default());
    let home = scene.home_configuration();
    estimator.update(&home, 0.0, 10.0, true).unwrap();
    estimator
        .update(&moved(&home, [0.0, 0.0], 0.0, [-0.01, 0.0]), 0.01, 10.0, true)
        .unwrap();
    assert!(estimator.hooked() && estimator.velocity() > 0.0);
    estimator.reset_to(0.3).unwrap();
    let e = estimator.estimate();
    assert!(!e.hooked && e.position == 0.3 && e.velocity == 0.0 && e.residual.is_nan());
    assert!(estimator.reset_to(f64::NAN).is_err() && estimator.position() == 0.3);
}
