//! What the safety tests share: the shelf scene, filters with obstacles scattered around the robot,
//! random states near or beyond the limits and commands beyond them, the rows copied out of a
//! filter, and FILTER-QP solved without Clarabel by accelerated projected gradient.

// Each test crate that includes this module uses only some of it.
#![allow(dead_code)]

use std::sync::Arc;

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use sabre::model::Scene;
use sabre::safety::{SafetyConfig, SafetyFilter};

pub fn scene() -> Arc<Scene> {
    Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene"))
}

pub fn joint(scene: &Scene, name: &str) -> usize {
    scene
        .robot
        .active_joint_names()
        .iter()
        .position(|n| n == name)
        .expect("joint exists")
}

/// A filter with eight obstacles scattered around the robot's workspace.
pub fn filter_with_obstacles(scene: &Arc<Scene>, config: SafetyConfig, rng: &mut ChaCha8Rng) -> SafetyFilter {
    let mut f = SafetyFilter::new(scene.clone(), config).expect("filter");
    for _ in 0..8 {
        let c = [
            rng.random_range(-0.5..1.5),
            rng.random_range(-1.0..1.0),
            rng.random_range(0.2..1.5),
        ];
        f.add_obstacle(c, rng.random_range(0.05..0.3)).expect("slot free");
    }
    f
}

/// A state with a third of the coordinates near or beyond a limit (joint limits; base within
/// [−2.3, 2.3]², so sometimes outside the [−2, 2]² box), random velocities.
pub fn random_state(scene: &Scene, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let mut x = scene.default_state();
    let nq = scene.nq();
    for (j, l) in scene.robot_limits().iter().enumerate() {
        let (lo, hi) = if j < 2 {
            (-2.2, 2.2)
        } else {
            (l.lower.max(-6.0), l.upper.min(6.0))
        };
        x[j] = if rng.random_bool(0.33) {
            // Near a limit, up to 0.05 beyond it.
            if rng.random_bool(0.5) {
                lo + rng.random_range(-0.05..0.1)
            } else {
                hi - rng.random_range(-0.05..0.1)
            }
        } else {
            rng.random_range(lo..hi)
        };
        x[nq + j] = rng.random_range(-0.5..0.5);
    }
    x
}

pub fn random_command(scene: &Scene, rng: &mut ChaCha8Rng) -> Vec<f64> {
    // Up to 1.5× the velocity limits: the filter must also bring over-limit commands in.
    scene
        .robot_limits()
        .iter()
        .map(|l| rng.random_range(-1.5..1.5) * l.velocity)
        .collect()
}

pub fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Rows at x, copied out of the filter: (a R × nq, b, h).
pub fn rows(f: &mut SafetyFilter, x: &[f64], passivity: Option<(&[f64], f64)>) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (a, b, h) = f.constraint_rows(x, passivity).expect("rows");
    (a.to_vec(), b.to_vec(), h.to_vec())
}

pub fn penalties(f: &SafetyFilter) -> Vec<f64> {
    (0..f.num_rows()).map(|r| f.config().penalty.get(f.row_class(r))).collect()
}

/// The FILTER-QP without Clarabel: min over the input box of ½‖u − u_ref‖² + ½ Σ Γ_r max(0, b_r − a_r u)²
/// (the slack eliminated), a smooth strongly convex problem, solved by accelerated projected
/// gradient with adaptive restart. Rows that no admissible u can violate (b_r ≤ −Σ|a_r|v) add
/// nothing to the objective on the box and are left out of the step-size bound.
pub fn projected_gradient(a: &[f64], b: &[f64], gamma: &[f64], v: &[f64], u_ref: &[f64]) -> Vec<f64> {
    let nq = v.len();
    let row = |r: usize| &a[r * nq..(r + 1) * nq];
    let relevant: Vec<usize> = (0..b.len())
        .filter(|&r| b[r] > -dot(&row(r).iter().map(|x| x.abs()).collect::<Vec<_>>(), v))
        .collect();
    let lipschitz = 1.0 + relevant.iter().map(|&r| gamma[r] * dot(row(r), row(r))).sum::<f64>();
    let project = |u: &mut Vec<f64>| u.iter_mut().zip(v).for_each(|(x, l)| *x = x.clamp(-l, *l));
    let gradient = |u: &[f64]| {
        let mut g: Vec<f64> = u.iter().zip(u_ref).map(|(x, r)| x - r).collect();
        for &r in &relevant {
            let deficit = b[r] - dot(row(r), u);
            if deficit > 0.0 {
                g.iter_mut().zip(row(r)).for_each(|(gi, ai)| *gi -= gamma[r] * deficit * ai);
            }
        }
        g
    };
    let mut u = u_ref.to_vec();
    project(&mut u);
    let mut y = u.clone();
    let mut t = 1.0_f64;
    for _ in 0..60_000 {
        let g = gradient(&y);
        let mut next: Vec<f64> = y.iter().zip(&g).map(|(yi, gi)| yi - gi / lipschitz).collect();
        project(&mut next);
        // Restart the momentum when it points uphill (O'Donoghue & Candès): linear convergence.
        let uphill: f64 = y.iter().zip(&next).zip(&u).map(|((yi, ni), ui)| (yi - ni) * (ni - ui)).sum();
        if uphill > 0.0 {
            t = 1.0;
        }
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        y = next.iter().zip(&u).map(|(n, o)| n + (t - 1.0) / t_next * (n - o)).collect();
        u = next;
        t = t_next;
    }
    u
}
