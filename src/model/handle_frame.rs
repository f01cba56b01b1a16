//! The handle frame of an object: the named frame itself, or one inferred from the named link's
//! collision geometry and the articulation.
//!
//! The handle frame has its origin at the bar's centre, x along the bar, z into the panel the handle
//! is mounted on (the hand approaches along −z from open space) and y = z × x. A frame without
//! collision geometry (the shipped objects' `handle_frame`) is the handle frame itself; for a link
//! with geometry (boxes, cylinders, capsules, spheres, meshes as their convex hulls, several pieces)
//! the frame is inferred with the object closed (its joints at their lower limits):
//!
//! - the handle is the union of the link's collision shapes; its centre, for a start, the centre of
//!   their bounding box;
//! - the panel is the surface of the moving geometry of other links nearest to that centre (a door
//!   leaf, a drawer front, in whatever pieces): z points from the centre to its nearest point;
//! - seen from the front (along z), the handle's outline has a smallest bounding rectangle: the bar
//!   runs along its long side (x up to sign) and is as thick as the short side. An outline less than
//!   [`BAR_ASPECT`] times as long as it is thick is a knob, which the hook finger cannot catch;
//! - the bar is the part of the handle farthest from the panel (standoffs and a U handle's legs stand
//!   between): its centre lies half its thickness behind the handle's front face, midway along and
//!   across the part of the handle within one thickness of that face;
//! - for a bar within 45° of vertical, x points so that the finger, which hooks from the frame's −y
//!   side, comes in from the hinge's side when the part turns about a vertical hinge (a door: the
//!   side of the free edge may hold the neighbouring door and its handle, the hinge's side is the
//!   door's own), and x points up on anything else (a drawer); for any other bar, so that y = z × x
//!   points up.

use std::f64::consts::{FRAC_1_SQRT_2, FRAC_PI_2, PI};

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};

use super::collision_shape::closest_point;
use super::kinematics::{Collision, Shape};
use super::scene::Scene;
use crate::error::{Result, SabreError};

/// A bar is at least this many times as long as it is thick, seen from the front.
pub const BAR_ASPECT: f64 = 2.0;

/// Points per circle where round primitives (cylinders, capsules, spheres) are sampled: the extent of
/// a sampled circle is short of the true one by at most 1 − cos(π/64), 0.12 % of its radius, and
/// exact along the primitive's own x and y axes (64 is a multiple of 4).
const ROUND_SAMPLES: usize = 64;
/// Circles of latitude, poles included, where spheres and a capsule's caps are sampled.
const LATITUDES: usize = 9;

/// The handle frame of an object: a link of the object and the frame's fixed pose in that link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandleFrame {
    /// The link, as an index of the scene's object tree.
    pub link: usize,
    /// The handle frame in the link's frame.
    pub offset: Isometry3<f64>,
}

/// The handle frame named by `handle`: an object frame without collision geometry is the handle
/// frame itself; a link with geometry gets the inferred frame ([`infer_handle_frame`]).
pub fn handle_frame(scene: &Scene, handle: &str) -> Result<HandleFrame> {
    let link = scene.object.link_id(handle).ok_or_else(|| unknown(scene, handle))?;
    let offset = if scene.object.links[link].collisions.is_empty() {
        Isometry3::identity()
    } else {
        infer(scene, link)?
    };
    Ok(HandleFrame { link, offset })
}

/// The handle frame inferred from the collision geometry of object link `link`, in that link's
/// frame (see the module's rules).
///
/// Errors: `UnknownFrame` for a name the object lacks (listing its frames and the links with
/// geometry); `InvalidValue` for a link without collision geometry, without moving geometry of
/// another link to approach it from, or shaped as a knob rather than a bar (saying what works).
pub fn infer_handle_frame(scene: &Scene, link: &str) -> Result<Isometry3<f64>> {
    let id = scene.object.link_id(link).ok_or_else(|| unknown(scene, link))?;
    if scene.object.links[id].collisions.is_empty() {
        return Err(SabreError::invalid(
            format!("object link '{link}'"),
            format!(
                "has no collision geometry to infer a handle from; links with geometry: {}",
                geometry_links(scene)
            ),
        ));
    }
    infer(scene, id)
}

/// The object's links with collision geometry, sorted by name, comma-separated.
fn geometry_links(scene: &Scene) -> String {
    let mut names: Vec<&str> = scene
        .object
        .links
        .iter()
        .filter(|l| !l.collisions.is_empty())
        .map(|l| l.name.as_str())
        .collect();
    names.sort_unstable();
    names.join(", ")
}

fn unknown(scene: &Scene, name: &str) -> SabreError {
    SabreError::UnknownFrame {
        name: name.to_string(),
        available: format!(
            "{}; links with collision geometry: {}",
            scene.object.link_names().join(", "),
            geometry_links(scene)
        ),
    }
}

/// The handle frame of object link `link`, which has collision geometry.
fn infer(scene: &Scene, link: usize) -> Result<Isometry3<f64>> {
    let name = &scene.object.links[link].name;
    let closed: Vec<f64> = scene.object_limits().iter().map(|l| l.lower).collect();
    let poses = scene.object.link_poses(&scene.object_pose, &closed);
    let points: Vec<Point3<f64>> = scene.object.links[link]
        .collisions
        .iter()
        .flat_map(shape_points)
        .map(|p| poses[link] * p)
        .collect();
    let (low, high) = points.iter().fold(
        (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)),
        |(low, high), p| (low.inf(&p.coords), high.sup(&p.coords)),
    );
    let z = surface_behind(scene, link, &poses, &Point3::from(0.5 * (low + high)))?;
    let (axis, length, thickness) = front_outline(&points, &z);
    if length < BAR_ASPECT * thickness {
        return Err(SabreError::invalid(
            format!("handle '{name}'"),
            format!(
                "a knob, not a bar: seen from the front it measures {:.0} × {:.0} mm, with no long axis for the hook \
                 finger to catch. What works: a bar at least {BAR_ASPECT} times as long as it is thick (a pull bar, a \
                 U handle); or name as the handle a link without collision geometry whose frame is the handle frame \
                 (origin where the finger hooks, x along the bar, z into the door)",
                1000.0 * length,
                1000.0 * thickness
            ),
        ));
    }
    let side = z.cross(&axis);
    // how far each point stands out from the panel
    let out = |p: &Point3<f64>| -p.coords.dot(&z);
    let front_out = points.iter().map(out).fold(f64::NEG_INFINITY, f64::max);
    let front: Vec<&Point3<f64>> = points.iter().filter(|p| out(p) >= front_out - thickness - 1e-9).collect();
    let middle = |direction: &Vector3<f64>| {
        let (low, high) = front.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(low, high), p| {
            let v = p.coords.dot(direction);
            (low.min(v), high.max(v))
        });
        0.5 * (low + high)
    };
    let centre = middle(&axis) * axis + middle(&side) * side - (front_out - 0.5 * thickness) * z;
    let x = bar_direction(&axis, &z, hinge_to(scene, link, &closed, &poses, &Point3::from(centre)));
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, z.cross(&x), z]));
    let world = Isometry3::from_parts(Translation3::from(centre), UnitQuaternion::from_rotation_matrix(&rotation));
    Ok(poses[link].inverse() * world)
}

/// Points in the link frame whose convex hull is the collision primitive (round ones sampled).
pub(crate) fn shape_points(collision: &Collision) -> Vec<Point3<f64>> {
    let circle = |radius: f64, z: f64| {
        (0..ROUND_SAMPLES).map(move |k| {
            let angle = 2.0 * PI * k as f64 / ROUND_SAMPLES as f64;
            Point3::new(radius * angle.cos(), radius * angle.sin(), z)
        })
    };
    let sphere = |radius: f64, z: f64| {
        (0..LATITUDES).flat_map(move |i| {
            let latitude = -FRAC_PI_2 + i as f64 * PI / (LATITUDES - 1) as f64;
            circle(radius * latitude.cos(), z + radius * latitude.sin())
        })
    };
    let local: Vec<Point3<f64>> = match collision.shape {
        Shape::Box { half_extents: h } => (0..8)
            .map(|k| {
                let sign = |bit: usize| if k & (4 >> bit) == 0 { -1.0 } else { 1.0 };
                Point3::new(sign(0) * h.x, sign(1) * h.y, sign(2) * h.z)
            })
            .collect(),
        Shape::Hull { ref points, .. } => points.to_vec(),
        Shape::Sphere { radius } => sphere(radius, 0.0).collect(),
        Shape::Cylinder { radius, half_length } => circle(radius, -half_length).chain(circle(radius, half_length)).collect(),
        Shape::Capsule { radius, half_length } => circle(radius, -half_length)
            .chain(circle(radius, half_length))
            .chain(sphere(radius, -half_length))
            .chain(sphere(radius, half_length))
            .collect(),
    };
    local.into_iter().map(|p| collision.origin * p).collect()
}

/// Unit direction from `centre` to the nearest point of the moving collision geometry of the
/// object's other links: into the panel the handle is mounted on.
fn surface_behind(scene: &Scene, link: usize, poses: &[Isometry3<f64>], centre: &Point3<f64>) -> Result<Vector3<f64>> {
    let tree = &scene.object;
    let name = &tree.links[link].name;
    let mut best: Option<(f64, Point3<f64>, usize)> = None;
    for (other, (part, pose)) in tree.links.iter().zip(poses).enumerate() {
        if other == link || tree.ancestor_active_joints(other).is_empty() {
            continue;
        }
        for c in &part.collisions {
            let nearest = closest_point(&c.shape, &(pose * c.origin), centre);
            let gap = (nearest - centre).norm();
            if best.is_none_or(|(smallest, ..)| gap < smallest) {
                best = Some((gap, nearest, other));
            }
        }
    }
    let Some((gap, nearest, other)) = best else {
        return Err(SabreError::invalid(
            format!("handle '{name}'"),
            "no moving collision geometry besides the handle's own to approach it from; the handle must be its own \
             link, fixed to a moving part (a door leaf or drawer front) that has collision geometry",
        ));
    };
    if gap < 1e-6 {
        return Err(SabreError::invalid(
            format!("handle '{name}'"),
            format!(
                "its centre lies inside the collision geometry of '{}'; cannot tell which side of that part the hand \
                 approaches from",
                tree.links[other].name
            ),
        ));
    }
    Ok((nearest - centre) / gap)
}

/// (unit bar axis ⊥ `normal`, length, thickness): the long side of the smallest-area rectangle
/// around `points` seen along `normal`, and the rectangle's two sides (m).
fn front_outline(points: &[Point3<f64>], normal: &Vector3<f64>) -> (Vector3<f64>, f64, f64) {
    let seed = Vector3::ith(
        (0..3).fold(0, |i, k| if normal[k].abs() < normal[i].abs() { k } else { i }),
        1.0,
    );
    let u = (seed - seed.dot(normal) * normal).normalize();
    let v = normal.cross(&u);
    let hull = hull_2d(points.iter().map(|p| Vector2::new(p.coords.dot(&u), p.coords.dot(&v))));
    if hull.len() < 2 {
        return (u, 0.0, 0.0);
    }
    let extent = |direction: &Vector2<f64>| {
        let (low, high) = hull.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(low, high), p| {
            let s = p.dot(direction);
            (low.min(s), high.max(s))
        });
        high - low
    };
    // (area, long side, length, thickness) of the best rectangle so far: one side on a hull edge
    let mut best: Option<(f64, Vector2<f64>, f64, f64)> = None;
    for (k, start) in hull.iter().enumerate() {
        let edge = hull[(k + 1) % hull.len()] - start;
        let norm = edge.norm();
        if norm <= 1e-12 {
            continue;
        }
        let along = edge / norm;
        let across = Vector2::new(-along.y, along.x);
        let (a, b) = (extent(&along), extent(&across));
        if best.is_none_or(|(area, ..)| a * b < area - 1e-15) {
            best = Some((a * b, if a >= b { along } else { across }, a.max(b), a.min(b)));
        }
    }
    match best {
        Some((_, axis, length, thickness)) => (axis.x * u + axis.y * v, length, thickness),
        None => (u, 0.0, 0.0),
    }
}

/// The convex hull of 2-D points, counter-clockwise (Andrew's monotone chain); points equal to 12
/// decimals count once.
fn hull_2d(points: impl Iterator<Item = Vector2<f64>>) -> Vec<Vector2<f64>> {
    // + 0.0 makes −0 into 0, which the lexicographic order below must see as one value
    let round = |v: f64| (v * 1e12).round_ties_even() / 1e12 + 0.0;
    let mut unique: Vec<Vector2<f64>> = points.map(|p| Vector2::new(round(p.x), round(p.y))).collect();
    unique.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    unique.dedup();
    if unique.len() < 3 {
        return unique;
    }
    // twice the signed area of the triangle a, b, c: positive for a left turn
    let turn = |a: &Vector2<f64>, b: &Vector2<f64>, c: &Vector2<f64>| (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
    let half = |rows: &mut dyn Iterator<Item = &Vector2<f64>>| {
        let mut chain: Vec<Vector2<f64>> = Vec::new();
        for p in rows {
            while chain.len() >= 2 && turn(&chain[chain.len() - 2], &chain[chain.len() - 1], p) <= 0.0 {
                chain.pop();
            }
            chain.push(*p);
        }
        chain.pop();
        chain
    };
    let mut hull = half(&mut unique.iter());
    hull.extend(half(&mut unique.iter().rev()));
    hull
}

/// Unit horizontal direction from the hinge axis to `centre` (a point of `link`) when the object's
/// joints, opening from `closed` toward their upper limits, turn `link` about an axis within 45° of
/// vertical; None otherwise (a drawer, a flap).
fn hinge_to(scene: &Scene, link: usize, closed: &[f64], poses: &[Isometry3<f64>], centre: &Point3<f64>) -> Option<Vector3<f64>> {
    let tree = &scene.object;
    let mut jacobian = vec![0.0; 6 * tree.nq()];
    tree.point_jacobian_into(poses, link, centre, &mut jacobian);
    let (mut velocity, mut omega) = (Vector3::zeros(), Vector3::zeros());
    for ((column, limits), lower) in jacobian.chunks_exact(6).zip(scene.object_limits()).zip(closed) {
        let rate = limits.upper - lower;
        velocity += rate * Vector3::new(column[0], column[1], column[2]);
        omega += rate * Vector3::new(column[3], column[4], column[5]);
    }
    let up = Vector3::z();
    if omega.norm() < 1e-9 || omega.dot(&up).abs() < FRAC_1_SQRT_2 * omega.norm() {
        return None;
    }
    // v = ω × r with r ⊥ ω from the axis to the point: r = −ω × v / |ω|²
    let mut lever = -omega.cross(&velocity) / omega.norm_squared();
    lever -= lever.dot(&up) * up;
    let norm = lever.norm();
    (norm > 1e-9).then(|| lever / norm)
}

/// The handle frame's x: `axis` or its opposite (see the module's rules). The finger hooks from the
/// frame's −y side; on a door turning about a vertical hinge that side faces the hinge.
fn bar_direction(axis: &Vector3<f64>, z: &Vector3<f64>, from_hinge: Option<Vector3<f64>>) -> Vector3<f64> {
    let up = Vector3::z();
    let keep = if axis.dot(&up).abs() >= FRAC_1_SQRT_2 {
        match from_hinge {
            Some(from_hinge) => z.cross(axis).dot(&from_hinge) > 0.0,
            None => axis.dot(&up) > 0.0,
        }
    } else {
        z.cross(axis).dot(&up) >= 0.0
    };
    if keep {
        *axis
    } else {
        -axis
    }
}

#[cfg(test)]
mod tests;
