//! The cost terms on the robot's body and its motion by value, on the probe scene of the parent
//! module: arm reach, self-collision, posture, object state, power, the base's box, obstacles.

use super::*;

fn arm_reach(r_max: f64) -> Term {
    Term::ArmReach {
        base_link: robot_link("cart"),
        frame_link: robot_link("tip"),
        r_max,
        weight: 3.0,
        weight_slope: 40.0,
    }
}

#[test]
fn arm_reach_charges_planar_distance_beyond_r_max() {
    // The tip is 0.3 m from the cart in the plane whatever the slide and turn.
    assert_close(
        value(
            arm_reach(0.25),
            Step {
                q: [0.4, 1.0],
                ..Default::default()
            },
        ),
        3.0 + 40.0 * 0.05 * 0.05,
    );
    assert_eq!(
        value(
            arm_reach(0.35),
            Step {
                q: [0.4, 1.0],
                ..Default::default()
            }
        ),
        0.0
    );
}

fn self_collision() -> Term {
    Term::SelfCollision {
        pairs: vec![(0, 1)],
        weight: 5.0,
        weight_slope: 200.0,
    }
}

#[test]
fn self_collision_charges_sphere_overlap() {
    // root (r 0.1) at (0, 0, 0.5); probe (r 0.05) at (s + 0.1, 0, 0.5): d_min = 0.15.
    assert_close(
        value(
            self_collision(),
            Step {
                q: [0.0, 0.0],
                ..Default::default()
            },
        ),
        5.0 + 200.0 * 0.05 * 0.05,
    );
    assert_eq!(
        value(
            self_collision(),
            Step {
                q: [0.1, 0.0],
                ..Default::default()
            }
        ),
        0.0
    );
}

#[test]
fn posture_is_weighted_squared_distance() {
    let term = Term::Posture {
        target: vec![0.5, -1.0],
        weights: vec![2.0, 3.0],
    };
    assert_close(
        value(
            term,
            Step {
                q: [0.2, 1.0],
                ..Default::default()
            },
        ),
        2.0 * 0.09 + 3.0 * 4.0,
    );
}

#[test]
fn object_state_is_weighted_squared_distance() {
    let term = Term::ObjectState {
        target: vec![0.4],
        weights: vec![50.0],
    };
    assert_close(
        value(
            term,
            Step {
                o: 0.1,
                ..Default::default()
            },
        ),
        50.0 * 0.09,
    );
}

#[test]
fn power_charges_dissipated_power_above_p_max() {
    // −τ_extᵀu = −(2·(−3) + (−1)·1) = 7 W.
    let step = || Step {
        u: [-3.0, 1.0],
        tau_ext: [2.0, -1.0],
        ..Default::default()
    };
    assert_close(value(Term::Power { weight: 4.0, p_max: 5.0 }, step()), 4.0 * 2.0);
    assert_eq!(value(Term::Power { weight: 4.0, p_max: 8.0 }, step()), 0.0);
}

#[test]
fn power_does_not_charge_power_put_into_the_robot() {
    // −τ_extᵀu = −7 W: the contact drives the robot along its command.
    let step = Step {
        u: [3.0, -1.0],
        tau_ext: [2.0, -1.0],
        ..Default::default()
    };
    assert_eq!(value(Term::Power { weight: 4.0, p_max: 0.0 }, step), 0.0);
}

fn base_box() -> Term {
    Term::BaseBox {
        lower: [-0.5, -0.5],
        upper: [0.5, 0.5],
        weight: 2.0,
        weight_slope: 30.0,
    }
}

#[test]
fn base_box_charges_each_coordinate_outside() {
    // The box reads the base's x and y coordinates; the probe's slide and turn stand in for them.
    let with_base = || {
        let mut scene = (*probe_and_drawer()).clone();
        scene.roles.base = Some(crate::model::assembly::PlanarBase { x: 0, y: 1, yaw: 1 });
        std::sync::Arc::new(scene)
    };
    assert_eq!(
        value_in(
            with_base(),
            base_box(),
            Step {
                q: [0.5, -0.5],
                ..Default::default()
            }
        ),
        0.0
    );
    assert_close(
        value_in(
            with_base(),
            base_box(),
            Step {
                q: [0.7, 0.0],
                ..Default::default()
            },
        ),
        2.0 + 30.0 * 0.04,
    );
    assert_close(
        value_in(
            with_base(),
            base_box(),
            Step {
                q: [0.3, -0.6],
                ..Default::default()
            },
        ),
        2.0 + 30.0 * 0.01,
    );
    assert_close(
        value_in(
            with_base(),
            base_box(),
            Step {
                q: [-0.6, 0.8],
                ..Default::default()
            },
        ),
        4.0 + 30.0 * (0.01 + 0.09),
    );
}

fn obstacle(center: [f64; 3], radius: f64) -> Term {
    Term::Obstacles {
        spheres: vec![(Point3::from(center), radius)],
        weight: 6.0,
        weight_slope: 100.0,
    }
}

#[test]
fn obstacles_charge_penetration_of_robot_spheres() {
    // Obstacle r 0.1 at (0.1, 0.1, 0.5), q = 0: probe (r 0.05) at (0.1, 0, 0.5) is 0.1 from it,
    // 0.05 deep; root (r 0.1) at (0, 0, 0.5) is √0.02 from it, 0.2 − √0.02 deep.
    let root_depth = 0.2 - 0.02_f64.sqrt();
    assert_close(
        value(obstacle([0.1, 0.1, 0.5], 0.1), Step::default()),
        (6.0 + 100.0 * 0.05 * 0.05) + (6.0 + 100.0 * root_depth * root_depth),
    );
}

#[test]
fn obstacles_skip_spheres_marked_off_for_them() {
    // As above with root marked obstacles="false": only the probe's 0.05 m depth is charged.
    let mut scene = (*probe_and_drawer()).clone();
    scene
        .spheres
        .iter_mut()
        .filter(|s| s.name == "root")
        .for_each(|s| s.obstacles = false);
    assert_close(
        value_in(std::sync::Arc::new(scene), obstacle([0.1, 0.1, 0.5], 0.1), Step::default()),
        6.0 + 100.0 * 0.05 * 0.05,
    );
}

#[test]
fn obstacles_clear_of_every_sphere_cost_nothing() {
    // probe 0.25 away (needs 0.15), root √(0.01 + 0.0625) ≈ 0.27 away (needs 0.2).
    assert_eq!(value(obstacle([0.1, 0.25, 0.5], 0.1), Step::default()), 0.0);
}

fn base_clearance(top: f64) -> Term {
    let front = object_link("front");
    Term::BaseClearance {
        base_link: robot_link("cart"),
        radius: 0.3,
        bottom: -0.1,
        top,
        // The front's centre, and a point 0.15 m closer to the robot and 0.3 m higher.
        points: ClearancePoints::new(&[(front, Point3::new(0.0, 0.0, 0.0)), (front, Point3::new(-0.15, 0.0, 0.3))]),
        weight: 8.0,
        weight_slope: 50.0,
    }
}

#[test]
fn base_clearance_charges_the_deepest_point_in_the_height_band() {
    // Cart at 0.8, front centre at 1.0 (height 0): 0.1 inside the 0.3 footprint; the higher
    // point, 0.05 from the cart, is above the band.
    assert_close(
        value(
            base_clearance(0.1),
            Step {
                q: [0.8, 0.0],
                ..Default::default()
            },
        ),
        8.0 + 50.0 * 0.01,
    );
}

#[test]
fn base_clearance_counts_a_point_once_the_band_reaches_it() {
    assert_close(
        value(
            base_clearance(0.4),
            Step {
                q: [0.8, 0.0],
                ..Default::default()
            },
        ),
        8.0 + 50.0 * 0.25 * 0.25,
    );
}

#[test]
fn base_clearance_is_free_outside_the_footprint() {
    assert_eq!(
        value(
            base_clearance(0.4),
            Step {
                q: [0.4, 0.0],
                ..Default::default()
            }
        ),
        0.0
    );
}

#[test]
fn terms_add_up() {
    let step = || Step {
        q: [1.2, 0.0],
        contact: true,
        ..Default::default()
    };
    let both = Cost::new(vec![Term::Contact { weight: 7.0 }, joint_limits(10.0, 100.0)]);
    let scene = probe_and_drawer();
    let x = state(step().q, [0.0, 0.0], 0.0, 0.0);
    let mut robot = Frames::default();
    scene.robot.update_frames(&Isometry3::identity(), &x[..2], &mut robot);
    let view = StepView {
        x: &x,
        u: &[0.0, 0.0],
        tau_ext: &[0.0, 0.0],
        contact: true,
        robot: &robot,
        object: &Frames::default(),
    };
    assert_close(both.step(&scene, &view), 7.0 + 10.0 + 100.0 * 0.04);
}

fn se3_exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let v = Vector3::new(xi[0], xi[1], xi[2]);
    let w = Vector3::new(xi[3], xi[4], xi[5]);
    let theta = w.norm();
    let k = w.cross_matrix();
    let (a, b) = if theta < 1e-9 {
        (0.5, 1.0 / 6.0)
    } else {
        (
            (1.0 - theta.cos()) / (theta * theta),
            (theta - theta.sin()) / (theta * theta * theta),
        )
    };
    let vmat = Matrix3::identity() + a * k + b * k * k;
    Isometry3::from_parts(Translation3::from(vmat * v), UnitQuaternion::from_scaled_axis(w))
}

#[test]
fn log_inverts_the_exponential() {
    for xi in [
        Vector6::new(0.1, -0.2, 0.3, 0.0, 0.0, 0.0),
        Vector6::new(0.1, -0.2, 0.3, 0.4, -0.5, 0.6),
        Vector6::new(-1.0, 0.5, 0.2, 2.5, 0.3, -0.4),
        Vector6::new(0.0, 0.0, 0.0, 1e-8, 0.0, 0.0),
    ] {
        let back = se3_log(&se3_exp(&xi));
        assert!((back - xi).norm() < 1e-9, "{xi:?} -> {back:?}");
    }
}

#[test]
fn pure_translation_log_is_the_translation() {
    let t = Isometry3::translation(0.3, -0.1, 2.0);
    let xi = se3_log(&t);
    assert!((xi - Vector6::new(0.3, -0.1, 2.0, 0.0, 0.0, 0.0)).norm() < 1e-12);
}
