//! Contact detection of the reduced path: the robot's contact primitives against the object's, a
//! bounding-sphere and box-distance screen, then the contact manifold of the pairs that pass (two
//! boxes by sabre's box–box generator, other pairs by parry's).

use nalgebra::{Isometry3, Point3, Vector3};
use rapier3d_f64::parry::query::{ContactManifold, DefaultQueryDispatcher, PersistentQueryDispatcher};
use rapier3d_f64::parry::shape::{Cuboid, SharedShape, SupportMap};
use rapier3d_f64::prelude::Pose;

use super::box_box::{box_box_manifold, clip_support_faces};
use crate::model::collision_shape::shared_shape;
use crate::model::kinematics::{Frames, KinematicTree, Shape};
use crate::sim::quiescence::distance_to_shape;

/// One collision primitive of a tree, placed in its link's frame.
#[derive(Clone)]
pub(super) struct Collider {
    /// The link (of its tree) the primitive belongs to.
    pub link: usize,
    /// Pose of the parry shape in the link frame.
    pub local: Isometry3<f64>,
    pub shape: SharedShape,
    /// The URDF primitive and its pose in the link frame (a box's parry shape sits at that pose).
    primitive: Shape,
    primitive_pose: Isometry3<f64>,
    /// Radius of a sphere about the primitive's origin that contains it.
    radius: f64,
    /// Whether the parry shape sits at the primitive's own pose (all but cylinders): then one
    /// placement serves both.
    shape_at_primitive: bool,
    /// Whether a movable joint moves the primitive's link.
    pub moves: bool,
}

/// A world-frame axis-aligned box.
#[derive(Debug, Clone, Copy)]
struct Aabb {
    min: Vector3<f64>,
    max: Vector3<f64>,
}

impl Aabb {
    /// The box around `primitive`'s bounding box placed at `pose`.
    #[inline]
    fn around(pose: &Isometry3<f64>, primitive: &Shape) -> Self {
        let extent = pose.rotation.to_rotation_matrix().matrix().abs() * primitive.half_extents();
        let c = pose.translation.vector;
        Self {
            min: c - extent,
            max: c + extent,
        }
    }

    fn within(&self, other: &Aabb, margin: f64) -> bool {
        (0..3).all(|i| self.min[i] <= other.max[i] + margin && other.min[i] <= self.max[i] + margin)
    }

    fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.inf(&other.min),
            max: self.max.sup(&other.max),
        }
    }

    const EMPTY: Aabb = Aabb {
        min: Vector3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY),
        max: Vector3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY),
    };
}

impl std::fmt::Debug for Collider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Collider").field("link", &self.link).finish_non_exhaustive()
    }
}

impl Collider {
    /// Every collision primitive of the links of `tree` that `include` accepts.
    pub fn of_tree(tree: &KinematicTree, include: &dyn Fn(usize) -> bool) -> Vec<Collider> {
        let mut out = Vec::new();
        for (link, l) in tree.links.iter().enumerate() {
            if !include(link) {
                continue;
            }
            for c in &l.collisions {
                let (shape, frame) = shared_shape(&c.shape);
                out.push(Collider {
                    shape_at_primitive: frame == Isometry3::identity(),
                    link,
                    local: c.origin * frame,
                    shape,
                    primitive: c.shape.clone(),
                    primitive_pose: c.origin,
                    radius: c.shape.half_extents().norm(),
                    moves: !tree.ancestor_active_joints(link).is_empty(),
                });
            }
        }
        out
    }
}

/// A contact point between a robot primitive and an object primitive, world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ContactPoint {
    /// Index of the robot primitive (into the robot's colliders) and of the object's.
    pub robot: usize,
    pub object: usize,
    /// Midpoint of the two closest points.
    pub point: Point3<f64>,
    /// Unit normal pointing from the object toward the robot: the direction the object pushes the
    /// robot.
    pub normal: Vector3<f64>,
    /// Signed distance along the normal; negative while the primitives overlap.
    pub dist: f64,
    /// The pair of primitives and of their features (vertex, edge, face) that touch: the same
    /// contact in the next step has the same key, which carries its impulse over as a warm start.
    pub key: ContactKey,
}

/// Identifies a contact from step to step: robot primitive, object primitive, and parry's packed
/// feature ids on each.
pub(super) type ContactKey = (u32, u32, u32, u32);

/// How much deeper (m) two boxes may overlap along the normal of their contact in the previous
/// step than along the shallowest axis before that normal gives way to it.
const AXIS_PERSISTENCE: f64 = 0.002;

/// Separation of two boxes along `axis` (frame of the first, pointing from the first to the
/// second); negative when they overlap along it.
fn separation_along(cuboid1: &Cuboid, cuboid2: &Cuboid, pos12: &Pose, axis: rapier3d_f64::prelude::Vector) -> f64 {
    let toward_first = pos12.rotation.inverse() * -axis;
    let deepest2 = *pos12 * cuboid2.local_support_point(toward_first);
    (deepest2 - cuboid1.local_support_point(axis)).dot(axis)
}

/// For two boxes that touched along `previous` (first frame) in the last step and whose new
/// manifold chose another axis, rebuilds the manifold along `previous` while the boxes overlap no
/// more than [`AXIS_PERSISTENCE`] deeper along it than along the new axis. A box sliding past
/// another's edge from the side then keeps pressing on the side it came from, where the shallowest
/// axis at a corner would flip the contact onto the neighbouring face within one step.
fn keep_axis(
    cuboid1: &Cuboid,
    cuboid2: &Cuboid,
    pos12: &Pose,
    previous: rapier3d_f64::prelude::Vector,
    manifold: &mut ContactManifold<(), ()>,
) {
    let chosen = manifold.local_n1;
    if manifold.points.is_empty() || chosen.dot(previous) > 0.9 {
        return;
    }
    let kept = separation_along(cuboid1, cuboid2, pos12, previous);
    if kept < separation_along(cuboid1, cuboid2, pos12, chosen) - AXIS_PERSISTENCE {
        return;
    }
    clip_support_faces(cuboid1, cuboid2, pos12, previous, manifold);
}

/// The most contact points kept of one manifold.
const MAX_POINTS: usize = 4;

/// Chooses at most [`MAX_POINTS`] of a manifold's `len` points (position in the first shape's
/// frame and signed distance given by `point`) that span its contact patch, as Rapier reduces its
/// manifolds: the deepest, the one furthest from it, and the two furthest on either side of the
/// line through both. Writes their indices into `selected` and returns how many there are.
fn reduce_manifold(
    len: usize,
    point: impl Fn(usize) -> (Vector3<f64>, f64),
    normal: &Vector3<f64>,
    prediction: f64,
    selected: &mut [usize; MAX_POINTS],
) -> usize {
    if len <= MAX_POINTS {
        for (i, s) in selected.iter_mut().enumerate().take(len) {
            *s = i;
        }
        return len;
    }
    let Some(deepest) = (0..len).min_by(|&a, &b| point(a).1.total_cmp(&point(b).1)) else {
        return 0;
    };
    let a = point(deepest).0;
    let furthest = (0..len)
        .filter(|&i| i != deepest && point(i).1 <= prediction)
        .max_by(|&i, &j| (point(i).0 - a).norm_squared().total_cmp(&(point(j).0 - a).norm_squared()));
    selected[0] = deepest;
    let Some(furthest) = furthest else { return 1 };
    selected[1] = furthest;
    let b = point(furthest).0;
    if a == b {
        return 1;
    }
    let side = (b - a).cross(normal);
    let others = || (0..len).filter(|&i| i != deepest && i != furthest && point(i).1 <= prediction);
    let key = |i: &usize| (point(*i).0 - a).dot(&side);
    let (Some(low), Some(high)) = (
        others().min_by(|i, j| key(i).total_cmp(&key(j))),
        others().max_by(|i, j| key(i).total_cmp(&key(j))),
    ) else {
        return 2;
    };
    selected[2] = low;
    if low == high {
        return 3;
    }
    selected[3] = high;
    4
}

/// Reused buffers of the detection.
#[derive(Clone)]
pub(super) struct Detector {
    /// One manifold per (robot primitive, object primitive) pair, kept from step to step: parry
    /// updates a manifold's points in place while the pair's relative pose has moved less than
    /// 1 mm and 1° (its contact coherence, as in Rapier's narrow phase), and builds it anew
    /// otherwise. Emptied when the pair separates and when the world is reset.
    manifolds: Vec<ContactManifold<(), ()>>,
    /// World pose of each object primitive's parry shape and its world box, at the last detection
    /// (those of primitives that do not move are placed once).
    object_poses: Vec<(Isometry3<f64>, Aabb)>,
    /// The box around every object primitive that does not move, and around all of them.
    fixed_bounds: Aabb,
    object_bounds: Aabb,
    /// Per robot primitive, whether any of its pairs keeps a manifold.
    kept: Vec<bool>,
    pub contacts: Vec<ContactPoint>,
}

impl Default for Detector {
    fn default() -> Self {
        Self {
            manifolds: Vec::new(),
            object_poses: Vec::new(),
            fixed_bounds: Aabb::EMPTY,
            object_bounds: Aabb::EMPTY,
            kept: Vec::new(),
            contacts: Vec::new(),
        }
    }
}

fn to_pose(iso: &Isometry3<f64>) -> Pose {
    Pose::from(*iso)
}

impl Detector {
    /// Forgets every kept manifold: the next detection builds each anew. A manifold is replaced, not
    /// cleared: parry's clear keeps the last normal, which seeds the next detection of the pair, so a
    /// reset world would carry the rollout before it into the next (a row's result would depend on
    /// which rows its worker ran before).
    pub fn reset(&mut self) {
        self.manifolds.iter_mut().for_each(|m| *m = ContactManifold::default());
        self.kept.iter_mut().for_each(|k| *k = false);
    }

    /// Takes the kept manifolds of `other`.
    pub fn restore_from(&mut self, other: &Detector) {
        if other.manifolds.iter().all(|m| m.points.is_empty()) {
            self.reset();
        } else {
            self.manifolds.clone_from(&other.manifolds);
            self.kept.clone_from(&other.kept);
        }
    }

    /// Places the object primitives at `object_frames` (the fixed ones only the first time).
    fn place_object(&mut self, object: &[Collider], object_frames: &Frames) {
        let place = |c: &Collider| {
            let link = object_frames.poses[c.link];
            let primitive_pose = link * c.primitive_pose;
            let shape_pose = if c.shape_at_primitive {
                primitive_pose
            } else {
                link * c.local
            };
            (shape_pose, Aabb::around(&primitive_pose, &c.primitive))
        };
        if self.object_poses.len() != object.len() {
            self.object_poses = object.iter().map(place).collect();
            self.fixed_bounds = object
                .iter()
                .zip(&self.object_poses)
                .filter(|(c, _)| !c.moves)
                .fold(Aabb::EMPTY, |b, (_, p)| b.union(&p.1));
        }
        self.object_bounds = self.fixed_bounds;
        for (c, slot) in object.iter().zip(self.object_poses.iter_mut()) {
            if c.moves {
                *slot = place(c);
                self.object_bounds = self.object_bounds.union(&slot.1);
            }
        }
    }

    /// Fills [`Self::contacts`] with every contact point closer than `prediction` between the
    /// `robot` primitives (placed by `robot_frames`) and the `object` primitives (placed by
    /// `object_frames`).
    pub fn detect(
        &mut self,
        robot: &[Collider],
        object: &[Collider],
        robot_frames: &Frames,
        object_frames: &Frames,
        prediction: f64,
    ) {
        self.contacts.clear();
        let pairs = robot.len() * object.len();
        if self.manifolds.len() != pairs {
            self.manifolds.clear();
            self.manifolds.resize_with(pairs, ContactManifold::new);
            self.kept = vec![false; robot.len()];
        }
        self.place_object(object, object_frames);
        for (ri, rc) in robot.iter().enumerate() {
            let link = robot_frames.poses[rc.link];
            let primitive_pose = link * rc.primitive_pose;
            let aabb = Aabb::around(&primitive_pose, &rc.primitive);
            let manifolds = &mut self.manifolds[ri * object.len()..(ri + 1) * object.len()];
            if !aabb.within(&self.object_bounds, prediction) {
                if std::mem::take(&mut self.kept[ri]) {
                    manifolds.iter_mut().for_each(ContactManifold::clear);
                }
                continue;
            }
            let center = Point3::from(primitive_pose.translation.vector);
            let reach = rc.radius + prediction;
            let mut pose_r: Option<Isometry3<f64>> = None;
            let mut kept = false;
            for (oi, oc) in object.iter().enumerate() {
                let manifold = &mut manifolds[oi];
                let (pose_o, aabb_o) = &self.object_poses[oi];
                // The boxes of the long, thin boards of a carcass pass the box screen near a
                // corner; the exact distance from the robot primitive's sphere centre to a box is
                // tight.
                if !aabb.within(aabb_o, prediction)
                    || matches!(oc.primitive, Shape::Box { .. }) && distance_to_shape(pose_o, &oc.primitive, &center) > reach
                {
                    manifold.clear();
                    continue;
                }
                let pose_r = *pose_r.get_or_insert_with(|| {
                    if rc.shape_at_primitive {
                        primitive_pose
                    } else {
                        link * rc.local
                    }
                });
                let pos12 = to_pose(&(pose_r.inverse() * pose_o));
                let previous = (!manifold.points.is_empty()).then_some(manifold.local_n1);
                if let (Some(cuboid1), Some(cuboid2)) = (rc.shape.as_cuboid(), oc.shape.as_cuboid()) {
                    box_box_manifold(cuboid1, cuboid2, &pos12, prediction, manifold);
                    if let Some(previous) = previous {
                        keep_axis(cuboid1, cuboid2, &pos12, previous, manifold);
                    }
                // Every primitive is convex, and parry has a generator for each convex pair.
                } else if DefaultQueryDispatcher
                    .contact_manifold_convex_convex(
                        &pos12,
                        rc.shape.as_ref(),
                        oc.shape.as_ref(),
                        None,
                        None,
                        prediction,
                        manifold,
                    )
                    .is_err()
                {
                    manifold.clear();
                    continue;
                }
                let manifold = &*manifold;
                kept |= !manifold.points.is_empty();
                let n1 = manifold.local_n1;
                let local_normal = Vector3::new(n1.x, n1.y, n1.z);
                let normal = -(pose_r.rotation * local_normal);
                let points = &manifold.points;
                let close = |i: &usize| points[*i].dist <= prediction;
                let mut selected = [usize::MAX; MAX_POINTS];
                let count = reduce_manifold(
                    points.len(),
                    |i| {
                        let p = points[i].local_p1;
                        (Vector3::new(p.x, p.y, p.z), points[i].dist)
                    },
                    &local_normal,
                    prediction,
                    &mut selected,
                );
                for &i in selected[..count].iter().filter(|i| close(i)) {
                    let tracked = &points[i];
                    let (p1, p2) = (tracked.local_p1, tracked.local_p2);
                    let world1 = pose_r * Point3::new(p1.x, p1.y, p1.z);
                    let world2 = pose_o * Point3::new(p2.x, p2.y, p2.z);
                    self.contacts.push(ContactPoint {
                        robot: ri,
                        object: oi,
                        point: nalgebra::center(&world1, &world2),
                        normal,
                        dist: tracked.dist,
                        key: (ri as u32, oi as u32, tracked.fid1.0, tracked.fid2.0),
                    });
                }
            }
            self.kept[ri] = kept;
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Isometry3, Vector3};
    use rapier3d_f64::parry::query::{ContactManifold, DefaultQueryDispatcher, PersistentQueryDispatcher};
    use rapier3d_f64::parry::shape::Cuboid;
    use rapier3d_f64::prelude::Vector;

    use super::{keep_axis, reduce_manifold, to_pose, AXIS_PERSISTENCE};

    /// A finger (shape 1) pressed from +y into a bar's corner, overlapping it by `along_y` in y
    /// and `along_x` in x: the normal a fresh manifold picks, and the one after keeping −y.
    fn corner(along_x: f64, along_y: f64) -> (Vector, Vector, f64) {
        let finger = Cuboid::new(Vector::new(0.01, 0.0045, 0.035));
        let bar = Cuboid::new(Vector::new(0.005, 0.005, 0.085));
        // The bar at the origin; the finger's −y face along_y below the bar's +y face, its −x face
        // along_x left of the bar's +x face.
        let finger_pose = Isometry3::translation(0.005 - along_x + 0.01, 0.005 - along_y + 0.0045, 0.0);
        let pos12 = to_pose(&finger_pose.inverse());
        let mut manifold = ContactManifold::<(), ()>::new();
        DefaultQueryDispatcher
            .contact_manifold_convex_convex(&pos12, &finger, &bar, None, None, 0.01, &mut manifold)
            .expect("boxes are supported");
        let fresh = manifold.local_n1;
        keep_axis(&finger, &bar, &pos12, Vector::new(0.0, -1.0, 0.0), &mut manifold);
        let deepest = manifold.points.iter().map(|p| p.dist).fold(f64::INFINITY, f64::min);
        (fresh, manifold.local_n1, deepest)
    }

    #[test]
    fn a_box_sliding_into_a_corner_keeps_the_face_it_came_from() {
        // 2.4 mm over the side it slides along, 2.6 mm into the face it came from: the fresh
        // manifold flips to the side, the kept one presses on the face, 2.6 mm deep.
        let (fresh, kept, deepest) = corner(0.0024, 0.0026);
        assert!((fresh - Vector::new(-1.0, 0.0, 0.0)).length() < 1e-9, "{fresh:?}");
        assert!((kept - Vector::new(0.0, -1.0, 0.0)).length() < 1e-9, "{kept:?}");
        assert!((deepest + 0.0026).abs() < 1e-9, "{deepest}");
        // Far deeper along the old axis than the new one: the new axis wins.
        let (fresh, kept, _) = corner(0.0024, 0.0026 + AXIS_PERSISTENCE + 0.0005);
        assert_eq!(fresh, kept);
    }

    #[test]
    fn a_manifold_is_reduced_to_the_deepest_point_the_furthest_and_the_two_widest() {
        // Eight points on a 2 × 1 rectangle in the plane z = 0 (normal z), the deepest at a corner.
        let points: Vec<(Vector3<f64>, f64)> = [
            (0.0, 0.0, -0.003),
            (1.0, 0.0, -0.001),
            (2.0, 0.0, -0.001),
            (2.0, 1.0, -0.002),
            (1.0, 1.0, -0.001),
            (0.0, 1.0, -0.001),
            (1.0, 0.4, -0.001),
            (1.0, 0.6, 0.5),
        ]
        .iter()
        .map(|&(x, y, d)| (Vector3::new(x, y, 0.0), d))
        .collect();
        let mut selected = [usize::MAX; 4];
        let count = reduce_manifold(points.len(), |i| points[i], &Vector3::z(), 0.01, &mut selected);
        assert_eq!(count, 4);
        // Deepest (0, 0); furthest from it (2, 1); widest on either side of that diagonal: (2, 0)
        // and (0, 1). The point beyond the prediction distance is never chosen.
        let mut chosen = selected.to_vec();
        chosen[2..].sort_unstable();
        assert_eq!(chosen, vec![0, 3, 2, 5]);
    }
}
