//! The servo guide on the built-in robot, checked by integrating its velocities and measuring the
//! grasp frame with forward kinematics: it reaches reachable targets, keeps joints inside their
//! margins (the other joints take over), keeps speeds inside their limits, and rejects bad input.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use sabre::model::Scene;
use sabre::mppi::{servo_guide, servo_guides, ServoGuideConfig};
use sabre::SabreError;

const DT: f64 = 0.015;
const K: usize = 66;

fn scene() -> Scene {
    Scene::load("royalpanda", "shelf", None).expect("built-in scene loads")
}

/// Final configuration after integrating a K × nq guide from q0 with step DT; every intermediate
/// configuration is passed to `visit`.
fn integrate(q0: &[f64], guide: &[f64], mut visit: impl FnMut(&[f64], &[f64])) -> Vec<f64> {
    let nq = q0.len();
    let mut q = q0.to_vec();
    for v in guide.chunks(nq) {
        for (qi, vi) in q.iter_mut().zip(v) {
            *qi += DT * vi;
        }
        visit(&q, v);
    }
    q
}

fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    (
        (a.translation.vector - b.translation.vector).norm(),
        a.rotation.angle_to(&b.rotation),
    )
}

#[test]
fn reaches_a_static_target_within_the_horizon() {
    let scene = scene();
    let q0 = scene.home_configuration();
    let start = scene.fk(&q0, "grasp").unwrap();
    // 15 cm forward and sideways, 5 cm down, turned 0.3 rad about a tilted axis.
    let target = Isometry3::from_parts(Translation3::new(0.1, 0.1, -0.05), UnitQuaternion::identity())
        * start
        * Isometry3::rotation(Vector3::new(0.1, 0.2, 0.2).normalize() * 0.3);
    let config = ServoGuideConfig {
        gain: 4.0,
        max_linear: 0.5,
        max_angular: 1.0,
        ..Default::default()
    };
    let guide = servo_guide(&scene, &q0, &vec![target; K + 1], DT, "grasp", &config).unwrap();
    assert_eq!(guide.len(), K * scene.nq());
    let q = integrate(&q0, &guide, |_, _| {});
    let (dp, da) = pose_error(&scene.fk(&q, "grasp").unwrap(), &target);
    let (dp0, da0) = pose_error(&start, &target);
    // Once the rate cap lets go, the error shrinks by (1 − gain·dt) per step (explicit Euler on ė = −gain·e).
    let decay = (1.0 - config.gain * DT).powi(K as i32);
    assert!(
        dp < 2.0 * decay * dp0 && da < 2.0 * decay * da0,
        "final error {dp} m, {da} rad (from {dp0} m, {da0} rad)"
    );
}

#[test]
fn a_joint_at_its_margin_is_held_and_the_others_take_over() {
    let scene = scene();
    let nq = scene.nq();
    let limits = scene.robot_limits();
    let margin = 0.05;
    let elbow = 6; // panda_joint4, upper limit −0.0698 rad
    let mut q0 = scene.home_configuration();
    q0[elbow] = limits[elbow].upper - margin - 0.01;
    // The target is where the hand would be with the elbow 0.3 rad past its upper margin.
    let mut beyond = q0.clone();
    beyond[elbow] += 0.3;
    let target = scene.fk(&beyond, "grasp").unwrap();
    let config = ServoGuideConfig {
        gain: 4.0,
        max_linear: 0.5,
        max_angular: 1.0,
        joint_margin: margin,
        ..Default::default()
    };
    let guide = servo_guide(&scene, &q0, &vec![target; K + 1], DT, "grasp", &config).unwrap();
    let mut highest = f64::NEG_INFINITY;
    let q = integrate(&q0, &guide, |q, v| {
        highest = highest.max(q[elbow]);
        for (i, l) in limits.iter().enumerate() {
            assert!(
                v[i].abs() <= l.velocity * (1.0 + 1e-12),
                "joint {i} speed {} over {}",
                v[i],
                l.velocity
            );
            assert!(
                q[i] <= l.upper - margin + 1e-9 && q[i] >= l.lower + margin - 1e-9,
                "joint {i} at {} left its margin",
                q[i]
            );
        }
    });
    assert!(highest <= limits[elbow].upper - margin + 1e-9);
    let (dp, da) = pose_error(&scene.fk(&q, "grasp").unwrap(), &target);
    assert!(dp < 5e-3 && da < 2e-2, "redundancy should reach the target: {dp} m, {da} rad");
    // Without the margin rule (and the limit weighting, which slows the elbow before the margin)
    // the same servo would have driven the elbow past it.
    let loose = ServoGuideConfig {
        joint_margin: -1.0,
        limit_weighting: false,
        ..config
    };
    let free = integrate(
        &q0,
        &servo_guide(&scene, &q0, &vec![target; K + 1], DT, "grasp", &loose).unwrap(),
        |_, _| {},
    );
    assert!(
        free[elbow] > limits[elbow].upper - margin,
        "the check above must be able to fail"
    );
    assert_eq!(q.len(), nq);
}

#[test]
fn rates_are_capped_and_speeds_scaled_together() {
    let scene = scene();
    let q0 = scene.home_configuration();
    let start = scene.fk(&q0, "grasp").unwrap();
    let far = Isometry3::from_parts(Translation3::new(1.0, 0.0, 0.0), UnitQuaternion::identity()) * start;
    let slow = ServoGuideConfig {
        max_linear: 0.1,
        ..Default::default()
    };
    let guide = servo_guide(&scene, &q0, &vec![far; K + 1], DT, "grasp", &slow).unwrap();
    let q = integrate(&q0, &guide, |_, _| {});
    // At most 0.1 m/s for K·DT seconds (to first order in the step).
    let moved = (scene.fk(&q, "grasp").unwrap().translation.vector - start.translation.vector).norm();
    let bound = 0.1 * K as f64 * DT;
    assert!(
        moved <= 1.02 * bound && moved >= 0.9 * bound,
        "moved {moved} m, cap allows {bound} m"
    );
    let tight = vec![0.05; scene.nq()];
    let capped = ServoGuideConfig {
        max_linear: 1.0,
        velocity_limit: Some(tight.clone()),
        ..Default::default()
    };
    let guide = servo_guide(&scene, &q0, &vec![far; K + 1], DT, "grasp", &capped).unwrap();
    assert!(guide.iter().all(|v| v.abs() <= 0.05 + 1e-12));
    assert!(
        guide
            .chunks(scene.nq())
            .all(|v| v.iter().any(|x| (x.abs() - 0.05).abs() < 1e-12)),
        "one joint at the cap each step"
    );
}

#[test]
fn bad_input_is_rejected() {
    let scene = scene();
    let q0 = scene.home_configuration();
    let pose = scene.fk(&q0, "grasp").unwrap();
    let config = ServoGuideConfig::default();
    let invalid = |r: sabre::Result<Vec<f64>>| matches!(r, Err(SabreError::InvalidValue { .. }) | Err(SabreError::Shape { .. }));
    assert!(invalid(servo_guide(&scene, &q0, &[pose], DT, "grasp", &config)));
    assert!(invalid(servo_guide(&scene, &q0[..5], &[pose, pose], DT, "grasp", &config)));
    assert!(invalid(servo_guide(&scene, &q0, &[pose, pose], 0.0, "grasp", &config)));
    let mut nan = q0.clone();
    nan[3] = f64::NAN;
    assert!(invalid(servo_guide(&scene, &nan, &[pose, pose], DT, "grasp", &config)));
    let shifted = Isometry3::from_parts(Translation3::new(f64::NAN, 0.0, 0.0), UnitQuaternion::identity());
    assert!(invalid(servo_guide(&scene, &q0, &[pose, shifted], DT, "grasp", &config)));
    let negative = ServoGuideConfig {
        velocity_limit: Some(vec![-1.0; scene.nq()]),
        ..Default::default()
    };
    assert!(invalid(servo_guide(&scene, &q0, &[pose, pose], DT, "grasp", &negative)));
    assert!(matches!(
        servo_guide(&scene, &q0, &[pose, pose], DT, "gripper_of_doom", &config),
        Err(SabreError::UnknownFrame { .. })
    ));
}

#[test]
fn limit_weighting_keeps_a_joint_further_from_its_limit_and_still_reaches() {
    let scene = scene();
    let limits = scene.robot_limits();
    let elbow = 6; // panda_joint4, upper limit −0.0698 rad
    let mut q0 = scene.home_configuration();
    q0[elbow] = limits[elbow].upper - 0.25;
    // The target is where the hand would be with the elbow 0.2 rad nearer its limit.
    let mut toward = q0.clone();
    toward[elbow] += 0.2;
    let target = scene.fk(&toward, "grasp").unwrap();
    let run = |limit_weighting: bool| {
        let config = ServoGuideConfig {
            gain: 4.0,
            max_linear: 0.5,
            max_angular: 1.0,
            limit_weighting,
            ..Default::default()
        };
        let guide = servo_guide(&scene, &q0, &vec![target; K + 1], DT, "grasp", &config).unwrap();
        let mut highest = f64::NEG_INFINITY;
        let q = integrate(&q0, &guide, |q, _| highest = highest.max(q[elbow]));
        (highest, pose_error(&scene.fk(&q, "grasp").unwrap(), &target))
    };
    let (weighted, (dp, da)) = run(true);
    let (plain, _) = run(false);
    // The plain inverse moves the elbow part of the way; weighted, the other joints do most of it.
    assert!(
        weighted - q0[elbow] < 0.5 * (plain - q0[elbow]),
        "toward its limit the weighted elbow moved {} rad, the unweighted {}",
        weighted - q0[elbow],
        plain - q0[elbow]
    );
    assert!(
        dp < 5e-3 && da < 2e-2,
        "the other joints should reach the target: {dp} m, {da} rad"
    );
}

#[test]
fn guides_in_a_batch_are_each_guide_alone() {
    let scene = scene();
    let q0 = scene.home_configuration();
    let start = scene.fk(&q0, "grasp").unwrap();
    let sequences: Vec<Vec<Isometry3<f64>>> = (0..3)
        .map(|m| {
            let offset = Translation3::new(0.05 * m as f64, -0.04, 0.02 * m as f64);
            (0..=K)
                .map(|k| {
                    Isometry3::from_parts(offset, UnitQuaternion::identity())
                        * start
                        * Isometry3::translation(0.0, 0.0, 0.001 * k as f64)
                })
                .collect()
        })
        .collect();
    let configs: Vec<ServoGuideConfig> = (0..3)
        .map(|m| ServoGuideConfig {
            max_linear: 0.1 + 0.1 * m as f64,
            ..Default::default()
        })
        .collect();
    let alone: Vec<f64> = sequences
        .iter()
        .zip(&configs)
        .flat_map(|(t, c)| servo_guide(&scene, &q0, t, DT, "grasp", c).unwrap())
        .collect();
    let together = servo_guides(&scene, &q0, &sequences, DT, "grasp", &configs).unwrap();
    assert_eq!(together, alone);
    let uneven = vec![sequences[0].clone(), sequences[1][..K].to_vec()];
    assert!(matches!(
        servo_guides(&scene, &q0, &uneven, DT, "grasp", &configs[..2]),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(matches!(
        servo_guides(&scene, &q0, &sequences, DT, "grasp", &configs[..2]),
        Err(SabreError::InvalidValue { .. })
    ));
    assert!(servo_guides(&scene, &q0, &[], DT, "grasp", &[]).unwrap().is_empty());
}
