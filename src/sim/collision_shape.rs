//! The collision shape of a URDF primitive as parry holds it, which both contact paths collide.

use nalgebra::{Isometry3, Vector3};
use rapier3d_f64::prelude::{SharedShape, Vector};

use crate::model::kinematics::Shape;

/// The parry shape of a collision primitive and the rotation that takes it to the URDF's axes
/// (Rapier's and parry's cylinders run along y, URDF's along z).
pub(crate) fn shared_shape(shape: &Shape) -> (SharedShape, Isometry3<f64>) {
    match *shape {
        Shape::Box { half_extents: h } => (SharedShape::cuboid(h.x, h.y, h.z), Isometry3::identity()),
        Shape::Sphere { radius } => (SharedShape::ball(radius), Isometry3::identity()),
        Shape::Cylinder { radius, half_length } => (
            SharedShape::cylinder(half_length, radius),
            Isometry3::rotation(Vector3::x() * std::f64::consts::FRAC_PI_2),
        ),
        Shape::Capsule { radius, half_length } => (SharedShape::capsule_z(half_length, radius), Isometry3::identity()),
        Shape::Hull {
            ref points,
            half_extents,
        } => {
            let vertices: Vec<Vector> = points.iter().map(|p| Vector::new(p.x, p.y, p.z)).collect();
            // The URDF loader only keeps hulls with volume; a box of the same extents is the fallback
            // should parry still refuse one.
            let hull = SharedShape::convex_hull(&vertices)
                .unwrap_or_else(|| SharedShape::cuboid(half_extents.x, half_extents.y, half_extents.z));
            (hull, Isometry3::identity())
        }
    }
}
