//! ZBF rows of the filter: barrier values h(q), gradients ∂h/∂q and bounds −γ (h − Δ), per constraint (37–40, 56).

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};

use super::config::{ConstraintClass, SafetyConfig};
use crate::model::kinematics::Frames;
use crate::model::scene::Scene;

/// What one row constrains.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum RowKind {
    /// Coordinate `joint` of q between its position limits.
    JointLimit {
        joint: usize,
    },
    /// Entry `pair` of `scene.sphere_pairs`.
    SelfCollision {
        pair: usize,
    },
    ArmReach,
    /// The base's `axis` (0 = x, 1 = y), coordinate `coordinate` of q, inside the base box.
    BaseBox {
        axis: usize,
        coordinate: usize,
    },
    /// Obstacle slot `slot` against robot sphere `sphere`.
    Obstacle {
        slot: usize,
        sphere: usize,
    },
    Passivity,
}

#[derive(Debug, Clone)]
pub(crate) struct Row {
    pub kind: RowKind,
    pub class: ConstraintClass,
    /// Input columns (joint indices) the row can depend on, ascending; fixed for the filter's life
    /// so that the QP keeps one sparsity pattern.
    pub cols: Vec<usize>,
}

/// A sphere obstacle in one slot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Obstacle {
    pub id: u64,
    pub center: Point3<f64>,
    pub radius: f64,
}

/// The rows of one filter and the buffers they are evaluated into (allocated once).
pub(crate) struct Rows {
    scene: Arc<Scene>,
    pub rows: Vec<Row>,
    nq: usize,
    /// Per row: γ, Δ (copied from the config so evaluation needs no lookups).
    gamma: Vec<f64>,
    margin: Vec<f64>,
    base_box: [f64; 4],
    tank_floor: f64,
    /// Dense R × nq, row-major: ∂h/∂q of each row (zero outside its columns).
    pub coef: Vec<f64>,
    /// Lower bound of each row, a·u + δ ≥ b, b = −γ (h − Δ).
    pub bound: Vec<f64>,
    /// The true barrier value h (without the margin); NaN for rows that are switched off this call
    /// (empty obstacle slot, passivity without a tank).
    pub barrier: Vec<f64>,
    /// Whether each row takes part in this call (see `barrier`).
    pub live: Vec<bool>,
    frames: Frames,
    /// World centre and 6 × nq Jacobian (column-major) of each robot sphere.
    sphere_pos: Vec<Point3<f64>>,
    sphere_jac: Vec<f64>,
    /// Origins and Jacobians of the arm-reach frame and its base.
    reach_jac: [Vec<f64>; 2],
}

/// The movable joints (q indices) that move `link`, ascending.
fn link_cols(scene: &Scene, link: usize) -> Vec<usize> {
    let mut cols: Vec<usize> = scene
        .robot
        .ancestor_active_joints(link)
        .iter()
        .map(|&j| scene.robot.joints[j].q_index.expect("active joint"))
        .collect();
    cols.sort_unstable();
    cols
}

fn union(a: &[usize], b: &[usize]) -> Vec<usize> {
    let mut out: Vec<usize> = a.iter().chain(b).copied().collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// h and ∂h/∂q of (q⁺ − q)(q − q⁻)/(q⁺ − q⁻) (37): positive inside, roughly the distance to the
/// nearer limit there, zero on either limit.
fn interval_barrier(q: f64, lower: f64, upper: f64) -> (f64, f64) {
    let width = upper - lower;
    ((upper - q) * (q - lower) / width, (upper + lower - 2.0 * q) / width)
}

impl Rows {
    pub fn new(scene: Arc<Scene>, config: &SafetyConfig) -> Self {
        let nq = scene.nq();
        let on = |c: ConstraintClass| config.enabled.get(c);
        let mut rows = Vec::new();
        if on(ConstraintClass::JointLimits) {
            for (joint, l) in scene.robot_limits().iter().enumerate() {
                // Unlimited coordinates (continuous joints, free base axes) have no barrier.
                if l.lower.is_finite() && l.upper.is_finite() && l.upper > l.lower {
                    rows.push(Row {
                        kind: RowKind::JointLimit { joint },
                        class: ConstraintClass::JointLimits,
                        cols: vec![joint],
                    });
                }
            }
        }
        if on(ConstraintClass::SelfCollision) {
            for (pair, &(a, b)) in scene.sphere_pairs.iter().enumerate() {
                let cols = union(
                    &link_cols(&scene, scene.spheres[a].link),
                    &link_cols(&scene, scene.spheres[b].link),
                );
                rows.push(Row {
                    kind: RowKind::SelfCollision { pair },
                    class: ConstraintClass::SelfCollision,
                    cols,
                });
            }
        }
        if on(ConstraintClass::ArmReach) {
            if let Some(reach) = &scene.arm_reach {
                let cols = union(&link_cols(&scene, reach.frame_link), &link_cols(&scene, reach.base_link));
                rows.push(Row {
                    kind: RowKind::ArmReach,
                    class: ConstraintClass::ArmReach,
                    cols,
                });
            }
        }
        // A fixed-base arm has no base to keep in the box.
        if let (true, Some(base)) = (on(ConstraintClass::BaseBox), scene.roles.base) {
            for (axis, coordinate) in [base.x, base.y].into_iter().enumerate() {
                rows.push(Row {
                    kind: RowKind::BaseBox { axis, coordinate },
                    class: ConstraintClass::BaseBox,
                    cols: vec![coordinate],
                });
            }
        }
        if on(ConstraintClass::Obstacles) {
            for slot in 0..config.max_obstacles {
                for (sphere, s) in scene.spheres.iter().enumerate().filter(|(_, s)| s.obstacles) {
                    rows.push(Row {
                        kind: RowKind::Obstacle { slot, sphere },
                        class: ConstraintClass::Obstacles,
                        cols: link_cols(&scene, s.link),
                    });
                }
            }
        }
        if on(ConstraintClass::Passivity) {
            rows.push(Row {
                kind: RowKind::Passivity,
                class: ConstraintClass::Passivity,
                cols: (0..nq).collect(),
            });
        }
        let r = rows.len();
        let gamma = rows.iter().map(|row| config.gamma.get(row.class)).collect();
        let margin = rows.iter().map(|row| config.margin.get(row.class)).collect();
        let n_spheres = scene.spheres.len();
        Self {
            rows,
            nq,
            gamma,
            margin,
            base_box: config.base_box,
            tank_floor: config.tank_floor,
            coef: vec![0.0; r * nq],
            bound: vec![0.0; r],
            barrier: vec![0.0; r],
            live: vec![false; r],
            frames: Frames::default(),
            sphere_pos: vec![Point3::origin(); n_spheres],
            sphere_jac: vec![0.0; n_spheres * 6 * nq],
            reach_jac: [vec![0.0; 6 * nq], vec![0.0; 6 * nq]],
            scene,
        }
    }

    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Row `r`'s name, e.g. `joint_limit:panda_joint4`, `obstacle:3:panda_hand`.
    pub fn name(&self, r: usize, obstacles: &[Option<Obstacle>]) -> String {
        let s = &self.scene;
        let link_name = |sphere: usize| s.robot.links[s.spheres[sphere].link].name.as_str();
        match self.rows[r].kind {
            RowKind::JointLimit { joint } => format!("joint_limit:{}", s.robot.joints[s.robot.active_joints[joint]].name),
            RowKind::SelfCollision { pair } => {
                let (a, b) = s.sphere_pairs[pair];
                format!("self_collision:{}-{}", link_name(a), link_name(b))
            }
            RowKind::ArmReach => "arm_reach".into(),
            RowKind::BaseBox { axis, .. } => format!("base_box:{}", ["x", "y"][axis]),
            RowKind::Obstacle { slot, sphere } => match obstacles.get(slot).copied().flatten() {
                Some(o) => format!("obstacle:{}:{}", o.id, link_name(sphere)),
                None => format!("obstacle:empty{slot}:{}", link_name(sphere)),
            },
            RowKind::Passivity => "passivity".into(),
        }
    }

    /// Evaluates every row at configuration `q` into `coef`, `bound`, `barrier`, `live`.
    /// `passivity` is (τ_ext, S); without it the passivity row is switched off. A switched-off row
    /// keeps its place with zero coefficients and the bound −1, which 0·u + δ ≥ −1 always meets.
    pub fn evaluate(&mut self, q: &[f64], obstacles: &[Option<Obstacle>], passivity: Option<(&[f64], f64)>) {
        let nq = self.nq;
        let scene = self.scene.clone();
        scene.robot.update_frames(&Isometry3::identity(), q, &mut self.frames);
        let need_spheres = self
            .rows
            .iter()
            .any(|r| matches!(r.kind, RowKind::SelfCollision { .. } | RowKind::Obstacle { .. }));
        if need_spheres {
            for (i, s) in scene.spheres.iter().enumerate() {
                let p = self.frames.poses[s.link] * Point3::from(s.center);
                self.sphere_pos[i] = p;
                scene
                    .robot
                    .frames_jacobian_into(&self.frames, s.link, &p, &mut self.sphere_jac[i * 6 * nq..(i + 1) * 6 * nq]);
            }
        }
        let limits = &scene.robot.joints;
        for r in 0..self.rows.len() {
            let kind = self.rows[r].kind;
            let a = &mut self.coef[r * nq..(r + 1) * nq];
            a.fill(0.0);
            let h = match kind {
                RowKind::JointLimit { joint } => {
                    let l = limits[scene.robot.active_joints[joint]].limits;
                    let (h, dh) = interval_barrier(q[joint], l.lower, l.upper);
                    a[joint] = dh;
                    Some(h)
                }
                RowKind::BaseBox { axis, coordinate } => {
                    let (lo, hi) = (self.base_box[2 * axis], self.base_box[2 * axis + 1]);
                    let (h, dh) = interval_barrier(q[coordinate], lo, hi);
                    a[coordinate] = dh;
                    Some(h)
                }
                RowKind::SelfCollision { pair } => {
                    let (i, j) = scene.sphere_pairs[pair];
                    let d = self.sphere_pos[i] - self.sphere_pos[j];
                    let dc = scene.spheres[i].radius + scene.spheres[j].radius;
                    let (ji, jj) = (&self.sphere_jac[i * 6 * nq..], &self.sphere_jac[j * 6 * nq..]);
                    // ḣ = dᵀ (J_i − J_j) q̇ with the linear point Jacobians (38).
                    for &c in &self.rows[r].cols {
                        let col = |jac: &[f64]| Vector3::new(jac[6 * c], jac[6 * c + 1], jac[6 * c + 2]);
                        a[c] = d.dot(&(col(ji) - col(jj)));
                    }
                    Some(0.5 * (d.norm_squared() - dc * dc))
                }
                RowKind::Obstacle { slot, sphere } => match obstacles.get(slot).copied().flatten() {
                    None => None,
                    Some(o) => {
                        let d = self.sphere_pos[sphere] - o.center;
                        let dc = o.radius + scene.spheres[sphere].radius;
                        let js = &self.sphere_jac[sphere * 6 * nq..];
                        // The obstacle is static within a step: ḣ = dᵀ J_s q̇.
                        for &c in &self.rows[r].cols {
                            a[c] = d.dot(&Vector3::new(js[6 * c], js[6 * c + 1], js[6 * c + 2]));
                        }
                        Some(0.5 * (d.norm_squared() - dc * dc))
                    }
                },
                RowKind::ArmReach => {
                    let reach = scene.arm_reach.as_ref().expect("row exists only with a declaration");
                    let pe = Point3::from(self.frames.poses[reach.frame_link].translation.vector);
                    let pb = Point3::from(self.frames.poses[reach.base_link].translation.vector);
                    let [je, jb] = &mut self.reach_jac;
                    scene.robot.frames_jacobian_into(&self.frames, reach.frame_link, &pe, je);
                    scene.robot.frames_jacobian_into(&self.frames, reach.base_link, &pb, jb);
                    // P = diag(1, 1, 0): only the horizontal offset counts (40).
                    let d = pe - pb;
                    let (dx, dy) = (d.x, d.y);
                    for &c in &self.rows[r].cols {
                        a[c] = -(dx * (je[6 * c] - jb[6 * c]) + dy * (je[6 * c + 1] - jb[6 * c + 1]));
                    }
                    Some(0.5 * (reach.max * reach.max - dx * dx - dy * dy))
                }
                RowKind::Passivity => passivity.map(|(tau, energy)| {
                    // Ṡ = τ_extᵀ u (49); h = S − ε gives τ_extᵀ u ≥ −α (S − ε) = (56).
                    a.copy_from_slice(tau);
                    energy - self.tank_floor
                }),
            };
            match h {
                Some(h) => {
                    self.live[r] = true;
                    self.barrier[r] = h;
                    self.bound[r] = -self.gamma[r] * (h - self.margin[r]);
                }
                None => {
                    self.live[r] = false;
                    self.barrier[r] = f64::NAN;
                    self.bound[r] = -1.0;
                }
            }
        }
    }
}
