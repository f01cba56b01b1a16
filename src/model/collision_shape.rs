//! The collision shape of a URDF primitive as parry holds it, which both contact paths collide, and
//! what parry computes on it for the model: mass properties at a density and the nearest surface point.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use rapier3d_f64::parry::mass_properties::MassProperties;
use rapier3d_f64::prelude::{Pose, SharedShape, Vector};

use super::description::{Collision, Inertial, Shape};

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

/// Mass, centre of mass and inertia (about that centre, in the link frame) of a link's collision
/// primitives filled with material of `density` (kg/m³), by parry's mass properties of each solid
/// (a mesh's as the convex polyhedron of its hull); None without geometry. Overlapping primitives
/// count twice.
pub(crate) fn geometry_inertial(collisions: &[Collision], density: f64) -> Option<Inertial> {
    let mut total = MassProperties::default();
    for c in collisions {
        let (shape, frame) = shared_shape(&c.shape);
        total += shape.mass_properties(density).transform_by(&Pose::from(c.origin * frame));
    }
    let mass = total.mass();
    if !(mass.is_finite() && mass > 0.0) {
        return None;
    }
    let com = total.local_com;
    let inertia = total.reconstruct_inertia_matrix().to_cols_array();
    Some(Inertial {
        mass,
        com: Vector3::new(com.x, com.y, com.z),
        inertia: Matrix3::from_column_slice(&inertia),
    })
}

/// The point of the collision primitive `shape`, placed at `pose`, nearest to `point` (on its
/// surface; `point` itself when it lies inside).
pub(crate) fn closest_point(shape: &Shape, pose: &Isometry3<f64>, point: &Point3<f64>) -> Point3<f64> {
    let (parry_shape, frame) = shared_shape(shape);
    let projection = parry_shape.project_point(&Pose::from(pose * frame), Vector::new(point.x, point.y, point.z), true);
    Point3::new(projection.point.x, projection.point.y, projection.point.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn collision(shape: Shape, origin: Isometry3<f64>) -> Collision {
        Collision {
            name: None,
            shape,
            origin,
        }
    }

    #[test]
    fn a_box_and_a_cylinder_have_their_closed_form_mass_and_inertia() {
        let density = 600.0;
        let (a, b, c) = (0.4, 0.02, 0.6);
        let boxed = geometry_inertial(
            &[collision(
                Shape::Box {
                    half_extents: Vector3::new(a / 2.0, b / 2.0, c / 2.0),
                },
                Isometry3::translation(0.1, 0.2, 0.3),
            )],
            density,
        )
        .unwrap();
        let m = density * a * b * c;
        assert!((boxed.mass - m).abs() < 1e-12 * m);
        assert!((boxed.com - Vector3::new(0.1, 0.2, 0.3)).norm() < 1e-12);
        let expected = Matrix3::from_diagonal(&Vector3::new(b * b + c * c, a * a + c * c, a * a + b * b)) * (m / 12.0);
        assert!(
            (boxed.inertia - expected).norm() < 1e-9 * expected.norm(),
            "{}",
            boxed.inertia
        );
        let (r, h) = (0.05, 0.3);
        let cylinder = geometry_inertial(
            &[collision(
                Shape::Cylinder {
                    radius: r,
                    half_length: h / 2.0,
                },
                Isometry3::identity(),
            )],
            density,
        )
        .unwrap();
        let m = density * std::f64::consts::PI * r * r * h;
        assert!((cylinder.mass - m).abs() < 1e-12 * m);
        let across = m * (3.0 * r * r + h * h) / 12.0;
        let expected = Matrix3::from_diagonal(&Vector3::new(across, across, m * r * r / 2.0));
        assert!(
            (cylinder.inertia - expected).norm() < 1e-9 * expected.norm(),
            "{}",
            cylinder.inertia
        );
    }

    #[test]
    fn the_closest_point_of_a_turned_box_lies_on_the_face_in_front_of_the_point() {
        let pose = Isometry3::new(Vector3::new(1.0, 0.0, 0.5), Vector3::z() * 0.3);
        let shape = Shape::Box {
            half_extents: Vector3::new(0.01, 0.2, 0.3),
        };
        let normal = pose.rotation * Vector3::x();
        let point = pose * Point3::new(0.0, 0.05, -0.1) - normal * 0.06;
        let nearest = closest_point(&shape, &pose, &point);
        assert!((nearest - (point + normal * 0.05)).norm() < 1e-12, "{nearest}");
    }
}
