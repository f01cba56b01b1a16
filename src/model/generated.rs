//! Safety geometry generated for a robot whose `<sabre>` block does not declare it: collision spheres
//! that cover each link's collision geometry, the self-collision pairs among them, the rollout
//! model's contact links and the arm's planar reach.
//!
//! Spheres: a link's collision surfaces (a hull's faces for a mesh) are sampled at most
//! [`SURFACE_SPACING`] apart, split into up to [`MAX_SPHERES_PER_LINK`] slices along their principal
//! axis, and each slice gets the smallest sphere about its bounding-box centre that holds its samples,
//! grown by the spacing: every surface point lies within the spacing of a sample, so every one is
//! inside a sphere. Pairs: spheres of two links at least [`PAIR_JOINTS`] movable joints apart along
//! the tree (nearer links move together, and the spheres that cover them overlap in ordinary
//! postures where the links themselves do not), which overlap in at least [`RARELY_OVERLAPPING`] of [`PAIR_SAMPLES`] random configurations within the
//! joint limits but not in more than [`ALWAYS_OVERLAPPING`] of them (those are neighbours whose
//! spheres overlap by construction), mostly (in at least [`FAITHFUL_SHARE`] of those samples) while
//! the links' own collision geometry is within [`NEAR`] (spheres that overlap while their links are
//! well apart would only hold the arm back), and not at the home or start posture.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::assembly::RobotRoles;
use super::kinematics::{JointKind, KinematicTree, Shape};
use super::safety_geometry::{ArmReach, Sphere};

/// Largest distance (m) between neighbouring surface samples, and the margin every sphere adds.
pub const SURFACE_SPACING: f64 = 0.005;
/// Most spheres one link gets.
pub const MAX_SPHERES_PER_LINK: usize = 3;
/// Fewest movable joints between the links of a self-collision pair.
pub const PAIR_JOINTS: usize = 3;
/// Distance (m) between two links' collision geometry that counts as meeting.
pub const NEAR: f64 = 0.02;
/// Share of a pair's overlapping samples in which its links must meet for the pair to be kept.
pub const FAITHFUL_SHARE: f64 = 0.5;
/// Random configurations the pairs are chosen on.
pub const PAIR_SAMPLES: usize = 500;
/// A pair overlapping in more than this share of the samples is left out (its spheres overlap in
/// ordinary postures of neighbouring links) ...
pub const ALWAYS_OVERLAPPING: f64 = 0.2;
/// ... and so is one overlapping in less (it can meet only in postures a task hardly visits).
pub const RARELY_OVERLAPPING: f64 = 0.01;
/// The generated reach limit is this share of the arm's longest planar reach.
pub const REACH_SHARE: f64 = 0.9;

fn grid(n: usize) -> impl Iterator<Item = f64> {
    (0..=n).map(move |i| i as f64 / n as f64)
}

fn cells(length: f64) -> usize {
    ((length / SURFACE_SPACING).ceil() as usize).max(1)
}

/// Points on a circle of radius `r` in the plane z = `z`, at most the spacing apart.
fn ring(r: f64, z: f64, out: &mut Vec<Point3<f64>>) {
    let n = cells(std::f64::consts::TAU * r).max(3);
    out.extend((0..n).map(|i| {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        Point3::new(r * a.cos(), r * a.sin(), z)
    }));
}

/// Points on a sphere of radius `r` about (0, 0, `z`), the half with z ≥ 0 (`side` 1), z ≤ 0 (−1) or all (0).
fn sphere_points(r: f64, z: f64, side: f64, out: &mut Vec<Point3<f64>>) {
    let n = cells(std::f64::consts::PI * r).max(2);
    for t in grid(n) {
        let polar = std::f64::consts::PI * t;
        let (s, c) = polar.sin_cos();
        if side * c < -1e-12 {
            continue;
        }
        let start = out.len();
        ring(r * s, r * c, out);
        out[start..].iter_mut().for_each(|p| p.z += z);
    }
}

/// Samples of a triangle's surface: a grid whose cells are at most the spacing across.
fn triangle_points(a: Point3<f64>, b: Point3<f64>, c: Point3<f64>, out: &mut Vec<Point3<f64>>) {
    let longest = (b - a).norm().max((c - b).norm()).max((a - c).norm());
    let n = cells(longest);
    for i in 0..=n {
        for j in 0..=(n - i) {
            out.push(a + (b - a) * (i as f64 / n as f64) + (c - a) * (j as f64 / n as f64));
        }
    }
}

/// Samples (in the shape's own frame) of one collision primitive's surface.
pub fn shape_surface(shape: &Shape) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    match shape {
        Shape::Box { half_extents: h } => {
            for axis in 0..3 {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                for sign in [-1.0, 1.0] {
                    for s in grid(cells(2.0 * h[u])) {
                        for t in grid(cells(2.0 * h[v])) {
                            let mut p = Vector3::zeros();
                            p[axis] = sign * h[axis];
                            p[u] = h[u] * (2.0 * s - 1.0);
                            p[v] = h[v] * (2.0 * t - 1.0);
                            out.push(Point3::from(p));
                        }
                    }
                }
            }
        }
        Shape::Sphere { radius } => sphere_points(*radius, 0.0, 0.0, &mut out),
        Shape::Cylinder { radius, half_length } | Shape::Capsule { radius, half_length } => {
            for t in grid(cells(2.0 * half_length)) {
                ring(*radius, half_length * (2.0 * t - 1.0), &mut out);
            }
            for sign in [-1.0, 1.0] {
                if matches!(shape, Shape::Capsule { .. }) {
                    sphere_points(*radius, sign * half_length, sign, &mut out);
                } else {
                    for t in grid(cells(*radius)) {
                        ring(radius * t, sign * half_length, &mut out);
                    }
                }
            }
        }
        Shape::Hull { points, .. } => {
            let vertices: Vec<_> = points
                .iter()
                .map(|p| rapier3d_f64::parry::math::Vector::new(p.x, p.y, p.z))
                .collect();
            if let Ok((hull, faces)) = rapier3d_f64::parry::transformation::try_convex_hull(&vertices) {
                let at = |i: u32| Point3::new(hull[i as usize].x, hull[i as usize].y, hull[i as usize].z);
                for [a, b, c] in faces {
                    triangle_points(at(a), at(b), at(c), &mut out);
                }
            } else {
                out.extend(points.iter().copied());
            }
        }
    }
    out
}

/// Samples (in the link frame) of every collision surface of `link`.
pub fn link_surface(tree: &KinematicTree, link: usize) -> Vec<Point3<f64>> {
    tree.links[link]
        .collisions
        .iter()
        .flat_map(|c| shape_surface(&c.shape).into_iter().map(move |p| c.origin * p))
        .collect()
}

/// (centre, radius) of up to [`MAX_SPHERES_PER_LINK`] spheres that hold `points` with
/// [`SURFACE_SPACING`] to spare, one per slice along the points' principal axis.
fn cover(points: &[Point3<f64>]) -> Vec<(Point3<f64>, f64)> {
    let n = points.len() as f64;
    let mean = points.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let covariance = points.iter().fold(Matrix3::zeros(), |s, p| {
        let d = p.coords - mean;
        s + d * d.transpose()
    }) / n;
    let eigen = covariance.symmetric_eigen();
    let axis = eigen.eigenvectors.column(eigen.eigenvalues.imax()).into_owned();
    let along: Vec<f64> = points.iter().map(|p| (p.coords - mean).dot(&axis)).collect();
    let (lo, hi) = along
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &t| (a.min(t), b.max(t)));
    let across = points
        .iter()
        .zip(&along)
        .map(|(p, t)| (p.coords - mean - axis * *t).norm())
        .fold(0.0, f64::max);
    let slices = ((hi - lo) / (2.0 * across.max(SURFACE_SPACING)))
        .round()
        .clamp(1.0, MAX_SPHERES_PER_LINK as f64) as usize;
    let width = (hi - lo) / slices as f64;
    let mut out = Vec::with_capacity(slices);
    for k in 0..slices {
        let inside: Vec<&Point3<f64>> = points
            .iter()
            .zip(&along)
            .filter(|(_, &t)| {
                let slice = if width > 0.0 { ((t - lo) / width).floor() as usize } else { 0 };
                slice.min(slices - 1) == k
            })
            .map(|(p, _)| p)
            .collect();
        if inside.is_empty() {
            continue;
        }
        let (min, max) = inside.iter().fold(
            (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)),
            |(a, b), p| (a.inf(&p.coords), b.sup(&p.coords)),
        );
        let centre = Point3::from((min + max) / 2.0);
        let radius = inside.iter().map(|p| (*p - centre).norm()).fold(0.0, f64::max);
        out.push((centre, radius + SURFACE_SPACING));
    }
    out
}

/// Spheres covering the collision geometry of every link that has some.
pub fn cover_spheres(tree: &KinematicTree) -> Vec<Sphere> {
    let mut out = Vec::new();
    for link in 0..tree.links.len() {
        let points = link_surface(tree, link);
        if points.is_empty() {
            continue;
        }
        let spheres = cover(&points);
        let single = spheres.len() == 1;
        for (k, (centre, radius)) in spheres.into_iter().enumerate() {
            let name = &tree.links[link].name;
            out.push(Sphere {
                name: if single { name.clone() } else { format!("{name}_{k}") },
                link,
                center: centre.coords,
                radius,
                obstacles: true,
            });
        }
    }
    out
}

/// For each link, the link that owns its rigid body (fixed joints merge links).
fn bodies(tree: &KinematicTree) -> Vec<usize> {
    let mut group: Vec<usize> = (0..tree.links.len()).collect();
    for &j in &tree.topological_joints {
        let joint = &tree.joints[j];
        if joint.kind == JointKind::Fixed {
            group[joint.child] = group[joint.parent];
        }
    }
    group
}

/// A configuration drawn uniformly within the joint limits (unlimited revolute joints over a turn,
/// unlimited prismatic ones at 0).
fn random_configuration(tree: &KinematicTree, rng: &mut ChaCha8Rng) -> Vec<f64> {
    tree.active_joints
        .iter()
        .map(|&j| {
            let joint = &tree.joints[j];
            let l = joint.limits;
            let (lo, hi) = match (l.lower.is_finite() && l.upper.is_finite(), joint.kind) {
                (true, _) => (l.lower, l.upper),
                (false, JointKind::Revolute) => (-std::f64::consts::PI, std::f64::consts::PI),
                _ => (0.0, 0.0),
            };
            if hi > lo {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        })
        .collect()
}

fn overlapping(tree: &KinematicTree, spheres: &[Sphere], q: &[f64], a: usize, b: usize) -> bool {
    let poses = tree.link_poses(&Isometry3::identity(), q);
    let (sa, sb) = (&spheres[a], &spheres[b]);
    let d = poses[sa.link] * Point3::from(sa.center) - poses[sb.link] * Point3::from(sb.center);
    d.norm() < sa.radius + sb.radius
}

/// Movable joints between two links along the tree: those that move one of them but not the other.
fn joints_between(tree: &KinematicTree, a: usize, b: usize) -> usize {
    let (ja, jb) = (tree.ancestor_active_joints(a), tree.ancestor_active_joints(b));
    ja.iter().filter(|j| !jb.contains(j)).count() + jb.iter().filter(|j| !ja.contains(j)).count()
}

/// The distance between the collision geometry of links `a` and `b` at link poses `poses`.
fn link_distance(tree: &KinematicTree, poses: &[Isometry3<f64>], a: usize, b: usize) -> f64 {
    use rapier3d_f64::parry::math::Pose;
    let shapes = |l: usize| {
        tree.links[l].collisions.iter().map(move |c| {
            let (shape, frame) = crate::model::collision_shape::shared_shape(&c.shape);
            (shape, Pose::from(poses[l] * c.origin * frame))
        })
    };
    let mut nearest = f64::INFINITY;
    for (sa, pa) in shapes(a) {
        for (sb, pb) in shapes(b) {
            if let Ok(d) = rapier3d_f64::parry::query::distance(&pa, &*sa, &pb, &*sb) {
                nearest = nearest.min(d.distance);
            }
        }
    }
    nearest
}

/// Self-collision pairs among `spheres`: see the module documentation.
pub fn collision_pairs(tree: &KinematicTree, spheres: &[Sphere], postures: &[&[f64]]) -> Vec<(usize, usize)> {
    let candidates: Vec<(usize, usize)> = (0..spheres.len())
        .flat_map(|a| (a + 1..spheres.len()).map(move |b| (a, b)))
        .filter(|&(a, b)| joints_between(tree, spheres[a].link, spheres[b].link) >= PAIR_JOINTS)
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let samples: Vec<Vec<f64>> = (0..PAIR_SAMPLES).map(|_| random_configuration(tree, &mut rng)).collect();
    let all_poses: Vec<Vec<Isometry3<f64>>> = samples.iter().map(|q| tree.link_poses(&Isometry3::identity(), q)).collect();
    let mut near: std::collections::HashMap<(usize, usize, usize), bool> = std::collections::HashMap::new();
    candidates
        .into_iter()
        .filter(|&(a, b)| {
            let (sa, sb) = (&spheres[a], &spheres[b]);
            let overlapping_samples: Vec<usize> = (0..all_poses.len())
                .filter(|&k| {
                    let poses = &all_poses[k];
                    let d = poses[sa.link] * Point3::from(sa.center) - poses[sb.link] * Point3::from(sb.center);
                    d.norm() < sa.radius + sb.radius
                })
                .collect();
            let share = overlapping_samples.len() as f64 / PAIR_SAMPLES as f64;
            if !(RARELY_OVERLAPPING..=ALWAYS_OVERLAPPING).contains(&share)
                || postures.iter().any(|q| overlapping(tree, spheres, q, a, b))
            {
                return false;
            }
            let meeting = overlapping_samples
                .iter()
                .filter(|&&k| {
                    *near
                        .entry((k, sa.link, sb.link))
                        .or_insert_with(|| link_distance(tree, &all_poses[k], sa.link, sb.link) < NEAR)
                })
                .count();
            meeting as f64 >= FAITHFUL_SHARE * overlapping_samples.len() as f64
        })
        .collect()
}

/// The links that touch the object in the rollout model: those with collision geometry on the tool
/// frame's rigid body and on the two bodies before it along its chain; without a tool frame, every
/// link with collision geometry.
pub fn contact_links(tree: &KinematicTree, tool_frame: Option<usize>) -> Vec<usize> {
    let with_geometry = |l: &usize| !tree.links[*l].collisions.is_empty();
    let Some(frame) = tool_frame else {
        return (0..tree.links.len()).filter(with_geometry).collect();
    };
    let body = bodies(tree);
    let chain = tree.ancestor_active_joints(frame);
    let mut kept: Vec<usize> = chain.iter().rev().take(3).map(|&j| body[tree.joints[j].child]).collect();
    kept.push(body[frame]);
    (0..tree.links.len())
        .filter(|l| kept.contains(&body[*l]) && with_geometry(l))
        .collect()
}

/// The configuration within the limits near `start` that takes `measure` highest: a hill climb of
/// random steps that shrink as they stop paying off.
fn climb(tree: &KinematicTree, start: Vec<f64>, measure: &dyn Fn(&[f64]) -> f64, rng: &mut ChaCha8Rng) -> f64 {
    let (mut q, mut best, mut step) = (start, 0.0, 0.3);
    best = measure(&q).max(best);
    let limits: Vec<(f64, f64)> = tree.active_limits().iter().map(|l| (l.lower, l.upper)).collect();
    for _ in 0..400 {
        let trial: Vec<f64> = q
            .iter()
            .zip(&limits)
            .map(|(v, (lo, hi))| (v + step * rng.random_range(-1.0..1.0)).clamp(*lo, *hi))
            .collect();
        let value = measure(&trial);
        if value > best {
            (q, best) = (trial, value);
        } else {
            step = (step * 0.97).max(1e-3);
        }
    }
    best
}

/// The planar reach limit of the tool frame from the arm's base link (the parent of the first
/// movable joint on the tool frame's chain that is not a base joint): [`REACH_SHARE`] of the longest
/// planar distance between them, found by a hill climb from the farthest of random configurations.
pub fn arm_reach(tree: &KinematicTree, roles: &RobotRoles) -> Option<ArmReach> {
    let frame = roles.tool_frame?;
    let base_joints = roles.base.map(|b| b.indices()).unwrap_or_default();
    let first = tree
        .ancestor_active_joints(frame)
        .iter()
        .copied()
        .find(|&j| roles.base.is_none() || !base_joints.contains(&tree.joints[j].q_index.expect("movable")))?;
    let base_link = tree.joints[first].parent;
    let measure = |q: &[f64]| {
        let mut q = q.to_vec();
        if let Some(base) = roles.base {
            base.indices().iter().for_each(|&i| q[i] = 0.0);
        }
        let poses = tree.link_poses(&Isometry3::identity(), &q);
        (poses[frame].translation.vector - poses[base_link].translation.vector)
            .xy()
            .norm()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let farthest = (0..PAIR_SAMPLES)
        .map(|_| random_configuration(tree, &mut rng))
        .max_by(|a, b| measure(a).total_cmp(&measure(b)))?;
    let longest = climb(tree, farthest, &measure, &mut rng);
    (longest > 0.0).then_some(ArmReach {
        base_link,
        frame_link: frame,
        max: REACH_SHARE * longest,
    })
}
