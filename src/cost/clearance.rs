//! The base-clearance term's geometry: sample points on the object's moving parts (in clusters
//! with bounding spheres) and the robot base's footprint.

use nalgebra::{Isometry3, Point3, Vector3};

use crate::model::scene::Scene;

/// The sample points of a base-clearance term (object link, point in its frame), in clusters
/// of neighbours on one link, each with a bounding sphere: a step skips the clusters that cannot
/// reach the footprint's band or cylinder, which on most steps is all of them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ClearancePoints {
    clusters: Vec<PointCluster>,
}

#[derive(Debug, Clone, PartialEq)]
struct PointCluster {
    link: usize,
    centre: Point3<f64>,
    radius: f64,
    points: Vec<Point3<f64>>,
}

/// Points per cluster: consecutive points of [`moving_object_points`]'s grid lie close together.
const CLUSTER_POINTS: usize = 16;

/// How far inside a bound a cluster must be to be skipped, so that rounding between the
/// cluster's centre and its points never drops a point that counts.
const CLUSTER_SLACK: f64 = 1e-9;

impl ClearancePoints {
    /// Clusters `points` (object link, point in its frame) in their order.
    pub fn new(points: &[(usize, Point3<f64>)]) -> Self {
        let mut clusters = Vec::new();
        let mut start = 0;
        while start < points.len() {
            let link = points[start].0;
            let mut end = start + 1;
            while end < points.len() && points[end].0 == link && end - start < CLUSTER_POINTS {
                end += 1;
            }
            let members: Vec<Point3<f64>> = points[start..end].iter().map(|(_, p)| *p).collect();
            let centre = Point3::from(members.iter().map(|p| p.coords).sum::<Vector3<f64>>() / members.len() as f64);
            let radius = members.iter().map(|p| (p - centre).norm()).fold(0.0, f64::max);
            clusters.push(PointCluster {
                link,
                centre,
                radius,
                points: members,
            });
            start = end;
        }
        Self { clusters }
    }

    /// The object link of each cluster.
    pub(super) fn links(&self) -> impl Iterator<Item = usize> + '_ {
        self.clusters.iter().map(|c| c.link)
    }

    /// max over the points inside the height band [bottom, top] above `base` of radius − their
    /// horizontal distance from `base`; −∞ without such a point. A cluster whose sphere lies
    /// outside the band or the cylinder is skipped: none of its points can be in the band or
    /// give more than 0 there, and the term only charges a positive maximum.
    pub(super) fn deepest(&self, object: &[Isometry3<f64>], base: &Vector3<f64>, radius: f64, bottom: f64, top: f64) -> f64 {
        let mut deepest = f64::NEG_INFINITY;
        for cluster in &self.clusters {
            let pose = &object[cluster.link];
            let c = pose * cluster.centre;
            let reach = cluster.radius + CLUSTER_SLACK;
            let height = c.z - base.z;
            if height + reach < bottom || height - reach > top {
                continue;
            }
            if ((c.x - base.x).powi(2) + (c.y - base.y).powi(2)).sqrt() - reach > radius {
                continue;
            }
            // One rotation matrix per cluster turns its points with fewer products than the
            // quaternion does point by point.
            let rotation = pose.rotation.to_rotation_matrix();
            for local in &cluster.points {
                let p = rotation * local + pose.translation.vector;
                let height = p.z - base.z;
                if height >= bottom && height <= top {
                    deepest = deepest.max(radius - ((p.x - base.x).powi(2) + (p.y - base.y).powi(2)).sqrt());
                }
            }
        }
        deepest
    }
}

/// Points spread over the collision primitives of the object's moving links (in their link frames),
/// at most `spacing` apart along each axis of each primitive's bounding box.
pub fn moving_object_points(scene: &Scene, spacing: f64) -> Vec<(usize, Point3<f64>)> {
    let tree = &scene.object;
    let mut out = Vec::new();
    for (link, l) in tree.links.iter().enumerate() {
        if tree.ancestor_active_joints(link).is_empty() {
            continue;
        }
        for c in &l.collisions {
            let half = c.shape.half_extents();
            // Vertices of a grid over the bounding box: corners and edges, where a box first meets
            // the footprint, are always among the points.
            let cells = grid_cells(half, spacing).map(|c| c as usize);
            for i in 0..=cells.x {
                for j in 0..=cells.y {
                    for k in 0..=cells.z {
                        let at = |n: usize, of: usize, h: f64| -h + 2.0 * h * n as f64 / of as f64;
                        let local = Point3::new(at(i, cells.x, half.x), at(j, cells.y, half.y), at(k, cells.z, half.z));
                        out.push((link, c.origin * local));
                    }
                }
            }
        }
    }
    out
}

/// Cells per axis of the sampling grid over a primitive with these half extents.
fn grid_cells(half: Vector3<f64>, spacing: f64) -> Vector3<f64> {
    half.map(|h| (2.0 * h / spacing).ceil().max(1.0))
}

/// How many points [`moving_object_points`] would return, as a float so that it cannot overflow.
pub fn moving_object_point_count(scene: &Scene, spacing: f64) -> f64 {
    let tree = &scene.object;
    let mut count = 0.0;
    for (link, l) in tree.links.iter().enumerate() {
        if tree.ancestor_active_joints(link).is_empty() {
            continue;
        }
        for c in &l.collisions {
            count += grid_cells(c.shape.half_extents(), spacing).map(|n| n + 1.0).product();
        }
    }
    count
}

/// The most points a base-clearance term samples: each is tested in every step of every rollout.
pub const MAX_CLEARANCE_POINTS: usize = 100_000;

/// (radius, bottom, top) of the vertical cylinder about a robot link's origin that bounds its
/// collision primitives, heights relative to the link origin; None if it has none.
pub fn link_footprint(scene: &Scene, link: usize) -> Option<(f64, f64, f64)> {
    use crate::model::kinematics::Shape;
    let l = scene.robot.links.get(link)?;
    let mut bound: Option<(f64, f64, f64)> = None;
    for c in &l.collisions {
        let half = c.shape.half_extents();
        // Corners of the primitive's bounding box; an upright round primitive's own radius is tighter.
        let upright = c.origin.rotation.angle() < 1e-9;
        let round = upright && matches!(c.shape, Shape::Cylinder { .. } | Shape::Capsule { .. } | Shape::Sphere { .. });
        for corner in 0..8 {
            let sign = |bit: usize| if corner & bit == 0 { -1.0 } else { 1.0 };
            let p = c.origin * Point3::new(sign(1) * half.x, sign(2) * half.y, sign(4) * half.z);
            let r = if round {
                c.origin.translation.vector.xy().norm() + half.x
            } else {
                p.coords.xy().norm()
            };
            bound = Some(match bound {
                None => (r, p.z, p.z),
                Some((rr, lo, hi)) => (rr.max(r), lo.min(p.z), hi.max(p.z)),
            });
        }
    }
    bound
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Point3, Vector3};

    use super::ClearancePoints;

    #[test]
    fn clustered_clearance_points_give_every_point_s_deepest_penetration() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Two links' grids of points (as moving_object_points lays them out), then random link poses
        // and bases: the clusters' answer against the plain maximum over every point.
        let mut points = Vec::new();
        for link in [1usize, 2] {
            for i in 0..7 {
                for j in 0..3 {
                    for k in 0..9 {
                        points.push((link, Point3::new(0.1 * i as f64, 0.02 * j as f64, 0.1 * k as f64 - 0.4)));
                    }
                }
            }
        }
        let clusters = ClearancePoints::new(&points);
        let (radius, bottom, top) = (0.35, -0.1, 0.5);
        let mut charged = 0;
        for _ in 0..2000 {
            let mut pose = || {
                Isometry3::new(
                    Vector3::new(
                        rng.random_range(-0.6..0.6),
                        rng.random_range(-0.6..0.6),
                        rng.random_range(-0.3..0.6),
                    ),
                    Vector3::new(
                        rng.random_range(-3.0..3.0),
                        rng.random_range(-3.0..3.0),
                        rng.random_range(-3.0..3.0),
                    ),
                )
            };
            let object = [Isometry3::identity(), pose(), pose()];
            let base = Vector3::new(rng.random_range(-0.8..0.8), rng.random_range(-0.8..0.8), 0.0);
            let mut expected = f64::NEG_INFINITY;
            for (link, local) in &points {
                let p = object[*link] * local;
                let height = p.z - base.z;
                if height >= bottom && height <= top {
                    expected = expected.max(radius - ((p.x - base.x).powi(2) + (p.y - base.y).powi(2)).sqrt());
                }
            }
            let got = clusters.deepest(&object, &base, radius, bottom, top);
            if expected > 0.0 {
                charged += 1;
                // The clusters turn their points by a rotation matrix, the reference by the
                // quaternion: the same depth up to rounding.
                assert!(
                    (got - expected).abs() < 1e-12,
                    "a penetrating point's depth: {got}, expected {expected}"
                );
            } else {
                assert!(got <= 0.0, "{got} where no point penetrates ({expected})");
            }
        }
        assert!(charged > 100 && charged < 1900, "both cases drawn: {charged} of 2000 charged");
    }
}
