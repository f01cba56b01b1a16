//! The nominal sequence held to the hard joint-limit bound the cascade applies: integrated on the
//! kinematics from the state it was planned from, each step's command clamped into the bound there.

use crate::model::LimitBound;

/// Clamps each step of `sequence` (K × nu, nu = the bound's joints, row-major) into `bound`'s box at
/// the joint positions the sequence reaches from `q0` (q advancing by u·dt per step of `dt`), so that
/// the plan the cascade receives stops inside the margins on the kinematics as the cascade's bound
/// would have it, one plan step late. Returns whether any value changed.
pub(crate) fn bound_sequence(bound: &LimitBound, q0: &[f64], dt: f64, sequence: &mut [f64]) -> bool {
    let nu = bound.len();
    let mut q = q0.to_vec();
    let mut changed = false;
    for step in sequence.chunks_exact_mut(nu) {
        changed |= bound.clamp(&q, dt, step);
        for (q, u) in q.iter_mut().zip(step.iter()) {
            *q += u * dt;
        }
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{LimitBoundConfig, Scene};

    #[test]
    fn a_sequence_pushing_out_stops_inside_the_margin_and_one_moving_inward_is_kept() {
        let scene = Scene::load("royalpanda", "shelf", None).expect("built-in scene loads");
        let config = LimitBoundConfig::default();
        let bound = LimitBound::new(&scene, &config).unwrap();
        let (nq, dt, k) = (scene.nq(), 0.02, 150);
        let limits = scene.robot_limits();
        let q0 = scene.home_configuration();
        let mut outward = vec![0.0; k * nq];
        for step in outward.chunks_exact_mut(nq) {
            step[8] = 2.0; // panda_joint6 at 2 rad/s toward its upper limit for 3 s
            step[6] = -1.5; // panda_joint4 toward its lower one
        }
        let mut bounded = outward.clone();
        assert!(bound_sequence(&bound, &q0, dt, &mut bounded));
        let mut q = q0.clone();
        for step in bounded.chunks_exact(nq) {
            for i in 0..nq {
                q[i] += step[i] * dt;
                assert!(
                    q[i] <= limits[i].upper - config.margin + 1e-12 && q[i] >= limits[i].lower + config.margin - 1e-12,
                    "joint {i} at {} past its margin",
                    q[i]
                );
            }
        }
        // both joints got to their margins and stopped there
        assert!((q[8] - (limits[8].upper - config.margin)).abs() < 1e-3, "{}", q[8]);
        assert!((q[6] - (limits[6].lower + config.margin)).abs() < 1e-3, "{}", q[6]);
        // moving inward only: nothing to clamp
        let mut inward: Vec<f64> = outward.iter().map(|u| -0.1 * u).collect();
        let copy = inward.clone();
        assert!(!bound_sequence(&bound, &q0, dt, &mut inward));
        assert_eq!(inward, copy);
    }
}
