//! Every cost term by value: on the probe scene (a cart sliding along x at height 0.5 with an arm
//! turning about z, a drawer whose front is at x = 1 + o), each term against numbers worked out by
//! hand from that geometry, on both sides of its switch, with and without its slope weight.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3, Vector6};

use super::*;
use crate::model::kinematics::Frames;
use crate::sim::test_scene::{probe_and_drawer, state};

/// One step's inputs to the cost: q, o, u, τ_ext and the contact flag.
struct Step {
    q: [f64; 2],
    o: f64,
    u: [f64; 2],
    tau_ext: [f64; 2],
    contact: bool,
}

impl Default for Step {
    fn default() -> Self {
        Self {
            q: [0.0, 0.0],
            o: 0.0,
            u: [0.0, 0.0],
            tau_ext: [0.0, 0.0],
            contact: false,
        }
    }
}

/// The value of `term` alone at `step`, robot and object frames from the scene's kinematics.
fn value(term: Term, step: Step) -> f64 {
    value_in(probe_and_drawer(), term, step)
}

fn value_in(scene: std::sync::Arc<Scene>, term: Term, step: Step) -> f64 {
    let cost = Cost::new(vec![term]);
    cost.validate(&scene).expect("valid term");
    let x = state(step.q, [0.0, 0.0], step.o, 0.0);
    let mut robot = Frames::default();
    let mut object = Frames::default();
    scene.robot.update_frames(&Isometry3::identity(), &x[..2], &mut robot);
    scene.object.update_frames(&scene.object_pose, &x[4..5], &mut object);
    let view = StepView {
        x: &x,
        u: &step.u,
        tau_ext: &step.tau_ext,
        contact: step.contact,
        robot: &robot,
        object: &object,
    };
    cost.step(&scene, &view)
}

fn robot_link(name: &str) -> usize {
    probe_and_drawer().robot.link_id(name).expect("link")
}

fn object_link(name: &str) -> usize {
    probe_and_drawer().object.link_id(name).expect("link")
}

fn assert_close(actual: f64, expected: f64) {
    assert!(
        (actual - expected).abs() <= 1e-12 * expected.abs().max(1.0),
        "got {actual}, expected {expected}"
    );
}

const POSE_WEIGHTS: [f64; 6] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];

#[test]
fn target_pose_world_translation_is_weighted_squared_offset() {
    // The arm is at (0.2, 0, 0.5), unrotated; the target 0.1 further along x and 0.2 along y.
    let target = PoseTarget::World(Isometry3::translation(0.3, 0.2, 0.5));
    let term = Term::TargetPose {
        link: robot_link("arm"),
        target,
        weights: POSE_WEIGHTS,
    };
    assert_close(
        value(
            term,
            Step {
                q: [0.2, 0.0],
                ..Default::default()
            },
        ),
        1.0 * 0.01 + 2.0 * 0.04,
    );
}

#[test]
fn target_pose_world_rotation_is_weighted_squared_angle() {
    // Arm turned by 0.5 rad about z, target at the same place turned by 0.2: log = (0, 0, 0, 0, 0, −0.3).
    let target = PoseTarget::World(Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.5),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2),
    ));
    let term = Term::TargetPose {
        link: robot_link("arm"),
        target,
        weights: POSE_WEIGHTS,
    };
    assert_close(
        value(
            term,
            Step {
                q: [0.0, 0.5],
                ..Default::default()
            },
        ),
        6.0 * 0.09,
    );
}

#[test]
fn target_pose_object_link_follows_the_object() {
    // Handle at x = 1 + o − 0.05 = 1.05 for o = 0.1; arm at 0.5: offset 0.55 along x.
    let target = PoseTarget::ObjectLink {
        link: object_link("handle"),
        offset: Isometry3::identity(),
        lead: 0.0,
        lead_limit: 1.0,
    };
    let term = Term::TargetPose {
        link: robot_link("arm"),
        target,
        weights: POSE_WEIGHTS,
    };
    assert_close(
        value(
            term,
            Step {
                q: [0.5, 0.0],
                o: 0.1,
                ..Default::default()
            },
        ),
        1.0 * 0.55 * 0.55,
    );
}

#[test]
fn target_pose_object_link_with_offset_is_taken_in_the_link_frame() {
    let offset = Isometry3::translation(0.0, 0.3, 0.0);
    let target = PoseTarget::ObjectLink {
        link: object_link("handle"),
        offset,
        lead: 0.0,
        lead_limit: 1.0,
    };
    let term = Term::TargetPose {
        link: robot_link("arm"),
        target,
        weights: POSE_WEIGHTS,
    };
    // Target (0.95, 0.3, 0.5) from the arm at (0.5, 0, 0.5): (0.45, 0.3, 0).
    assert_close(
        value(
            term,
            Step {
                q: [0.5, 0.0],
                o: 0.0,
                ..Default::default()
            },
        ),
        1.0 * 0.45 * 0.45 + 2.0 * 0.09,
    );
}

fn lead_term(lead: f64, lead_limit: f64) -> Term {
    let target = PoseTarget::ObjectLink {
        link: object_link("handle"),
        offset: Isometry3::identity(),
        lead,
        lead_limit,
    };
    Term::TargetPose {
        link: robot_link("arm"),
        target,
        weights: POSE_WEIGHTS,
    }
}

#[test]
fn target_pose_lead_takes_the_object_ahead() {
    // o = 0.1 led by 0.2 to 0.3 (below the cap 0.5): handle at 1.25, arm at 0.5.
    assert_close(
        value(
            lead_term(0.2, 0.5),
            Step {
                q: [0.5, 0.0],
                o: 0.1,
                ..Default::default()
            },
        ),
        0.75 * 0.75,
    );
}

#[test]
fn target_pose_lead_is_capped_at_lead_limit() {
    // o = 0.4 led by 0.2 would reach 0.6; the cap holds it at 0.5: handle at 1.45.
    assert_close(
        value(
            lead_term(0.2, 0.5),
            Step {
                q: [0.5, 0.0],
                o: 0.4,
                ..Default::default()
            },
        ),
        0.95 * 0.95,
    );
}

#[test]
fn target_pose_lead_leaves_an_object_already_past_the_cap() {
    // o = 0.7 is past the cap 0.5: the target stays with the object, handle at 1.65.
    assert_close(
        value(
            lead_term(0.2, 0.5),
            Step {
                q: [0.5, 0.0],
                o: 0.7,
                ..Default::default()
            },
        ),
        1.15 * 1.15,
    );
}

#[test]
fn contact_charges_its_weight_only_in_contact() {
    assert_close(
        value(
            Term::Contact { weight: 7.0 },
            Step {
                contact: true,
                ..Default::default()
            },
        ),
        7.0,
    );
    assert_eq!(
        value(
            Term::Contact { weight: 7.0 },
            Step {
                contact: false,
                ..Default::default()
            }
        ),
        0.0
    );
}

fn joint_limits(weight: f64, weight_slope: f64) -> Term {
    Term::JointLimits {
        weight,
        weight_slope,
        lower: vec![-1.0, -3.0],
        upper: vec![1.0, 3.0],
    }
}

#[test]
fn joint_limits_inside_cost_nothing() {
    assert_eq!(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [0.5, -2.0],
                ..Default::default()
            }
        ),
        0.0
    );
    assert_eq!(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [1.0, -3.0],
                ..Default::default()
            }
        ),
        0.0
    );
}

#[test]
fn joint_limits_one_violation_is_weight_plus_slope_times_square() {
    assert_close(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [1.2, 0.0],
                ..Default::default()
            },
        ),
        10.0 + 100.0 * 0.04,
    );
    assert_close(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [0.0, -3.3],
                ..Default::default()
            },
        ),
        10.0 + 100.0 * 0.09,
    );
}

#[test]
fn joint_limits_switch_on_just_past_the_limit() {
    assert_close(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [1.0 + 1e-9, 0.0],
                ..Default::default()
            },
        ),
        10.0 + 100.0 * 1e-18,
    );
}

#[test]
fn joint_limits_both_sides_violated_add_up() {
    // Joint 0 below its lower limit by 0.5, joint 1 above its upper limit by 0.5.
    assert_close(
        value(
            joint_limits(10.0, 100.0),
            Step {
                q: [-1.5, 3.5],
                ..Default::default()
            },
        ),
        2.0 * 10.0 + 100.0 * 0.5,
    );
}

#[test]
fn joint_limits_without_slope_charge_the_weight_alone() {
    assert_close(
        value(
            joint_limits(10.0, 0.0),
            Step {
                q: [1.2, 0.0],
                ..Default::default()
            },
        ),
        10.0,
    );
}

mod bodies;
