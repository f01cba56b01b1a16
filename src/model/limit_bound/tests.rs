//! The bound against stops integrated step by step, and its checks against a robot's limits.

use super::*;
use crate::model::scene::Scene;

/// Distance covered by a stop from `v` that first runs at v for `b.delay`, then, from an outward
/// acceleration of a, brakes as fast as the jerk and deceleration bounds allow: the acceleration ramps
/// down through zero to −a at the jerk bound, holds, and ramps back so that the velocity ends at zero
/// (a stop too short to reach −a peaks lower). Integrated in steps of at most `h`, each phase in
/// whole steps with its jerk constant.
fn integrated_stop(v: f64, b: &Braking, h: f64) -> f64 {
    let (a, j) = (b.deceleration, b.jerk);
    let mut phases = Vec::new();
    let (mut vel, mut acc) = (v, -a);
    if j.is_finite() {
        // from +a to zero acceleration, gaining a²/(2j), then the stop from zero acceleration
        acc = a;
        phases.push((a / j, -j));
        let top = v + a * a / (2.0 * j);
        let peak = a.min((top * j).sqrt());
        let ramp = peak / j;
        phases.extend([(ramp, -j), ((top - peak * ramp) / peak, 0.0), (ramp, j)]);
    } else {
        phases.push((v / a, 0.0));
    }
    let mut x = v * b.delay;
    for (duration, jerk) in phases {
        if duration <= 0.0 {
            continue;
        }
        let n = (duration / h).ceil();
        let step = duration / n;
        for _ in 0..n as usize {
            x += vel * step + 0.5 * acc * step * step + jerk * step * step * step / 6.0;
            vel += acc * step + 0.5 * jerk * step * step;
            acc += jerk * step;
        }
    }
    assert!(vel.abs() <= 1e-9 * (1.0 + v), "the stop ends at {vel}, not at rest");
    x
}

fn cases() -> Vec<Braking> {
    let mut out = Vec::new();
    for (deceleration, jerk) in [
        (7.5, 3750.0),
        (15.0, 7500.0),
        (1.125, 3375.0),
        (15.0, f64::INFINITY),
        (1.0, 10.0),
    ] {
        for delay in [0.0, 0.001, 0.02] {
            out.push(Braking {
                deceleration,
                jerk,
                delay,
            });
        }
    }
    out
}

#[test]
fn a_stop_from_the_bound_ends_at_the_distance_and_a_little_more_speed_overshoots() {
    for b in cases() {
        for d in [1e-4, 0.003, 0.05, 0.3, 2.0] {
            let v = velocity_bound(d, &b);
            if v == 0.0 {
                // not even a stop from rest at full outward acceleration fits
                assert!(stopping_distance(0.0, &b) >= d, "{b:?} at {d}");
                continue;
            }
            let h = 1e-6 * (1.0 + v / b.deceleration);
            let stop = integrated_stop(v, &b, h);
            assert!(
                stop <= d * (1.0 + 1e-6) + 1e-12,
                "{b:?}: a stop from {v} covers {stop}, more than {d}"
            );
            // A stop too short to reach −a covers less than s(v); one that reaches it exactly s(v).
            let trapezoid = b.jerk.is_infinite() || v >= b.deceleration * b.deceleration / (2.0 * b.jerk);
            if trapezoid {
                assert!((stop - d).abs() <= 1e-6 * d, "{b:?}: {stop} against {d}");
            }
            let faster = v * (1.0 + 1e-3);
            let over = integrated_stop(faster, &b, h);
            if trapezoid {
                assert!(over > d, "{b:?}: 0.1 % more than {v} still stops within {d} ({over})");
            }
            assert!(stopping_distance(faster, &b) > d);
        }
    }
}

#[test]
fn the_bound_inverts_the_stopping_distance_and_grows_with_the_distance() {
    for b in cases() {
        let mut previous = 0.0;
        for k in 1..200 {
            let d = 1e-5 * 1.1_f64.powi(k);
            let v = velocity_bound(d, &b);
            if d <= stopping_distance(0.0, &b) {
                assert_eq!(v, 0.0, "{b:?} at {d}");
                continue;
            }
            assert!((stopping_distance(v, &b) - d).abs() <= 1e-12 * (1.0 + d), "{b:?} at {d}");
            assert!(v > previous, "{b:?}: not increasing at {d}");
            previous = v;
        }
        assert_eq!(velocity_bound(0.0, &b), 0.0);
        assert_eq!(velocity_bound(-0.1, &b), 0.0);
        assert_eq!(velocity_bound(f64::INFINITY, &b), f64::INFINITY);
    }
    // No delay and no jerk bound: the textbook √(2ad).
    let plain = Braking {
        deceleration: 2.0,
        jerk: f64::INFINITY,
        delay: 0.0,
    };
    assert!((velocity_bound(0.25, &plain) - 1.0).abs() < 1e-15);
}

fn scene() -> Scene {
    Scene::load("royalpanda", "shelf", None).expect("built-in scene loads")
}

#[test]
fn the_box_lets_a_joint_past_its_margin_move_inward_only() {
    let scene = scene();
    let config = LimitBoundConfig::default();
    let bound = LimitBound::new(&scene, &config).unwrap();
    let limits = scene.robot_limits();
    let nq = scene.nq();
    let j6 = 8; // panda_joint6
    let mut q = scene.home_configuration();
    let (mut lo, mut hi) = (vec![0.0; nq], vec![0.0; nq]);
    for (offset, outward_allowed) in [(0.5, true), (0.02, false), (0.01, false), (-0.01, false)] {
        q[j6] = limits[j6].upper - offset;
        bound.velocity_box(&q, 0.001, &mut lo, &mut hi);
        assert_eq!(hi[j6] > 0.0, outward_allowed, "{offset} inside the limit: {}", hi[j6]);
        assert!(lo[j6] < 0.0, "inward stays allowed {offset} inside");
        let mut u = vec![0.0; nq];
        u[j6] = 10.0;
        assert!(bound.clamp(&q, 0.001, &mut u));
        assert_eq!(u[j6], hi[j6]);
    }
    // At 0.5 rad: the default deceleration and one 1 ms step allow about √(2a·0.48).
    q[j6] = limits[j6].upper - 0.5;
    bound.velocity_box(&q, 0.001, &mut lo, &mut hi);
    let expected = velocity_bound(0.48, &bound.braking(j6, 0.001));
    assert_eq!(hi[j6], expected);
    assert!((expected - (2.0 * config.deceleration * 0.48).sqrt()).abs() < 0.02);
    // The base's x and y are prismatic: their margin is the prismatic one.
    let (inner_lo, inner_hi) = bound.inner_limits();
    assert_eq!(inner_hi[0], limits[0].upper - config.prismatic_margin);
    assert_eq!(inner_lo[j6], limits[j6].lower + config.margin);
}

#[test]
fn bad_settings_are_refused_with_their_name() {
    let scene = scene();
    let refused = |config: LimitBoundConfig, name: &str| match LimitBound::new(&scene, &config) {
        Err(SabreError::InvalidValue { what, .. }) => assert_eq!(what, name, "{config:?}"),
        other => panic!("{config:?} gave {other:?}"),
    };
    let base = LimitBoundConfig::default();
    refused(LimitBoundConfig { margin: -0.01, ..base }, "limit_margin");
    refused(
        LimitBoundConfig {
            margin: f64::NAN,
            ..base
        },
        "limit_margin",
    );
    refused(
        LimitBoundConfig {
            prismatic_margin: f64::INFINITY,
            ..base
        },
        "prismatic_limit_margin",
    );
    refused(
        LimitBoundConfig {
            deceleration: 0.0,
            ..base
        },
        "limit_deceleration",
    );
    refused(
        LimitBoundConfig {
            deceleration: f64::NAN,
            ..base
        },
        "limit_deceleration",
    );
    // panda_joint6's range is 3.77 rad, panda_joint4's 3.0: half of that is the most a margin may take
    refused(LimitBoundConfig { margin: 1.51, ..base }, "limit_margin");
    refused(
        LimitBoundConfig {
            prismatic_margin: 10.5,
            ..base
        },
        "prismatic_limit_margin",
    );
    assert!(LimitBound::new(&scene, &LimitBoundConfig { margin: 1.5, ..base }).is_ok());
    let mut bound = LimitBound::new(&scene, &base).unwrap();
    assert!(bound.set_braking(scene.nq(), 1.0, 1.0, 0.001).is_err());
    assert!(bound.set_braking(3, 0.0, 1.0, 0.001).is_err());
    assert!(bound.set_braking(3, 1.0, f64::NAN, 0.001).is_err());
    assert!(bound.set_braking(3, 1.0, f64::INFINITY, 0.001).is_ok());
    assert!(bound.set_braking(3, 1.0, 1.0, f64::INFINITY).is_err());
    assert_eq!(bound.braking(3, 0.004).delay, 0.001);
    bound.clear_braking();
    assert_eq!(bound.braking(3, 0.004).delay, 0.004);
}
