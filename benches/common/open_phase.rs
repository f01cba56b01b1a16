//! The closed loop's recorded re-plan in the open phase (`benches/data/shelf_open_phase.json`,
//! written by `benches/capture_open_phase.py`), shared by the planning benches: its state, plan,
//! guides, noise scale and the cost `OpenObject.cost(scene, "open")` compiles to.

use nalgebra::{Isometry3, Matrix4};
use sabre::cost::{base_clearance, Cost, PoseTarget, Term};
use sabre::model::Scene;

/// The numbers of a JSON value (nested arrays flattened row by row).
pub fn floats(v: &serde_json::Value) -> Vec<f64> {
    match v {
        serde_json::Value::Array(items) => items.iter().flat_map(floats).collect(),
        other => vec![other.as_f64().expect("a number")],
    }
}

/// A re-plan of the closed loop in the open phase: where it starts and the cost the task gave it.
pub struct OpenPhase {
    pub x0: Vec<f64>,
    pub t: f64,
    pub nominal: Vec<f64>,
    pub nominal_t0: f64,
    pub noise_scale: f64,
    pub guides: Vec<f64>,
    pub cost: Cost,
}

/// `benches/data/shelf_open_phase.json` with the cost `OpenObject.cost(scene, "open")` compiles to,
/// built from the task parameters recorded with it (the terms of the planning bench's `open_cost`, plus arm reach and
/// base clearance, with the task's tilted grasp).
pub fn open_phase(scene: &Scene) -> OpenPhase {
    let data: serde_json::Value = serde_json::from_str(include_str!("../data/shelf_open_phase.json"))
        .expect("benches/data/shelf_open_phase.json is valid JSON");
    let offset = Matrix4::from_row_slice(&floats(&data["grasp_offset"]));
    let offset: Isometry3<f64> = nalgebra::try_convert(offset).expect("grasp offset is a rigid transform");
    let safety = &data["safety"];
    let value = |v: &serde_json::Value| v.as_f64().expect("a number");
    let limits = scene.robot_limits();
    let base_link = scene
        .robot
        .link_id(safety["base_link"].as_str().expect("base link name"))
        .expect("base link");
    let reach = scene.arm_reach.as_ref().expect("the robot declares its arm reach");
    let terms = vec![
        Term::TargetPose {
            link: scene.robot.link_id("grasp").expect("grasp frame"),
            target: PoseTarget::ObjectLink {
                link: scene.object.link_id("handle_frame").expect("handle frame"),
                offset,
                lead: value(&data["lead"]),
                lead_limit: value(&data["lead_limit"]),
            },
            weights: floats(&data["pose_weights"]).try_into().expect("six pose weights"),
        },
        Term::ObjectState {
            target: floats(&data["object_target"]),
            weights: vec![value(&data["object_weight"])],
        },
        Term::JointLimits {
            weight: value(&safety["joint_limit"]),
            weight_slope: value(&safety["joint_limit_slope"]),
            lower: limits.iter().map(|l| l.lower).collect(),
            upper: limits.iter().map(|l| l.upper).collect(),
        },
        Term::SelfCollision {
            pairs: scene.sphere_pairs.clone(),
            weight: value(&safety["self_collision"]),
            weight_slope: value(&safety["self_collision_slope"]),
        },
        Term::Power {
            weight: value(&safety["power"]),
            p_max: value(&safety["p_max"]),
        },
        Term::ArmReach {
            base_link: reach.base_link,
            frame_link: reach.frame_link,
            r_max: reach.max,
            weight: value(&safety["reach"]),
            weight_slope: value(&safety["reach_slope"]),
        },
        base_clearance(
            scene,
            base_link,
            None,
            value(&data["base_clearance_margin"]),
            value(&data["base_clearance_spacing"]),
            value(&safety["base_clearance"]),
            value(&safety["base_clearance_slope"]),
        )
        .expect("base clearance"),
    ];
    OpenPhase {
        x0: floats(&data["x0"]),
        t: value(&data["t"]),
        nominal: floats(&data["nominal"]),
        nominal_t0: value(&data["nominal_t0"]),
        noise_scale: value(&data["noise_scale"]),
        guides: floats(&data["guides"]),
        cost: Cost::new(terms),
    }
}
