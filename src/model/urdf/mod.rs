//! The URDF reader: URDF text (via urdf-rs) to a description of links and joints, plus sabre's
//! `<sabre>` extension block (via roxmltree); it knows nothing of the model built from them.

mod extension;

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::description::{
    check_inertia, Collision, DeclaredInertial, Description, Inertial, Joint, JointKind, JointLimits, Link, Shape,
};
use crate::error::{Result, SabreError};
use extension::parse_extension;
pub use extension::{ArmReachDecl, SabreExtension, SphereDecl};

/// A parsed URDF: its links and joints and sabre's extension block.
#[derive(Debug, Clone)]
pub struct ParsedUrdf {
    pub description: Description,
    pub extension: SabreExtension,
}

fn vec3(v: &[f64; 3]) -> Vector3<f64> {
    Vector3::new(v[0], v[1], v[2])
}

fn origin_pose(pose: &urdf_rs::Pose) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(vec3(&pose.xyz)),
        // URDF rpy is fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll).
        UnitQuaternion::from_euler_angles(pose.rpy[0], pose.rpy[1], pose.rpy[2]),
    )
}

fn finite_or_err(source: &str, what: &str, values: &[f64]) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SabreError::urdf(source, format!("{what} has a non-finite value: {values:?}")))
    }
}

/// Which children each `<inertial>` element of the document has, by link name: (mass, origin, inertia).
fn inertial_elements(doc: &roxmltree::Document) -> HashMap<String, (bool, bool, bool)> {
    let mut out = HashMap::new();
    for link in doc.root_element().children().filter(|n| n.has_tag_name("link")) {
        let Some(inertial) = link.children().find(|n| n.has_tag_name("inertial")) else {
            continue;
        };
        let has = |tag: &str| inertial.children().any(|n| n.has_tag_name(tag));
        out.insert(
            link.attribute("name").unwrap_or("").to_string(),
            (has("mass"), has("origin"), has("inertia")),
        );
    }
    out
}

/// The URDF text with a zero `<mass>` or `<inertia>` added to every `<inertial>` that lacks one,
/// which the URDF reader requires; the parts added count as left out ([`inertial_elements`]).
fn with_complete_inertials(text: &str, doc: &roxmltree::Document) -> String {
    let mut inserts: Vec<(usize, usize, String)> = Vec::new();
    for node in doc.descendants().filter(|n| n.has_tag_name("inertial")) {
        let has = |tag: &str| node.children().any(|n| n.has_tag_name(tag));
        let mut missing = String::new();
        if !has("mass") {
            missing.push_str(r#"<mass value="0"/>"#);
        }
        if !has("inertia") {
            missing.push_str(r#"<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>"#);
        }
        if missing.is_empty() {
            continue;
        }
        let range = node.range();
        let element = &text[range.clone()];
        if let Some(open) = element.strip_suffix("/>") {
            let open = open.trim_end();
            inserts.push((range.start, range.end, format!("{open}>{missing}</inertial>")));
        } else if let Some(close) = element.rfind("</") {
            inserts.push((range.start + close, range.start + close, missing));
        }
    }
    let mut out = text.to_string();
    for (start, end, replacement) in inserts.into_iter().rev() {
        out.replace_range(start..end, &replacement);
    }
    out
}

/// Deepest element nesting accepted; URDF itself needs about six levels.
pub const MAX_XML_DEPTH: usize = 64;

/// Refuses documents nested deeper than [`MAX_XML_DEPTH`] before any recursive parser sees them.
fn check_depth(source: &str, doc: &roxmltree::Document) -> Result<()> {
    let mut depth = vec![0usize; doc.descendants().count() + 1];
    for node in doc.descendants() {
        let d = node.parent().map_or(0, |p| depth[p.id().get_usize()] + 1);
        depth[node.id().get_usize()] = d;
        if d > MAX_XML_DEPTH {
            return Err(SabreError::urdf(
                source,
                format!("XML nested deeper than {MAX_XML_DEPTH} elements"),
            ));
        }
    }
    Ok(())
}

/// The shapes of a URDF geometry and where each one's centre lies in the geometry's frame: one
/// primitive, centred; or a mesh's convex pieces (one per object of an OBJ file, one for an STL),
/// each a hull centred on its bounding box.
fn convert_shape(source: &str, link: &str, geometry: &urdf_rs::Geometry) -> Result<Vec<(Shape, Vector3<f64>)>> {
    let urdf_rs::Geometry::Mesh { filename, scale } = geometry else {
        return Ok(vec![(convert_primitive(source, link, geometry)?, Vector3::zeros())]);
    };
    let scale = scale.as_ref().map_or([1.0; 3], |s| [s[0], s[1], s[2]]);
    if scale.iter().any(|s| !(s.is_finite() && *s != 0.0)) {
        return Err(SabreError::urdf(
            source,
            format!("link '{link}': mesh scale must be finite and non-zero, got {scale:?}"),
        ));
    }
    let urdf_dir = Path::new(source).is_file().then(|| Path::new(source).parent()).flatten();
    let in_link = |e: String| SabreError::urdf(source, format!("link '{link}': {e}"));
    let path = super::mesh::resolve(filename, urdf_dir).map_err(in_link)?;
    let hulls = super::mesh::load_hulls(&path, scale).map_err(in_link)?;
    Ok(hulls
        .into_iter()
        .map(|hull| {
            let (mut lo, mut hi) = (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY));
            for p in &hull {
                lo = lo.inf(&p.coords);
                hi = hi.sup(&p.coords);
            }
            let centre = (lo + hi) / 2.0;
            let points: Vec<_> = hull.iter().map(|p| p - centre).collect();
            let shape = Shape::Hull {
                points: points.into(),
                half_extents: (hi - lo) / 2.0,
            };
            (shape, centre)
        })
        .collect())
}

fn convert_primitive(source: &str, link: &str, geometry: &urdf_rs::Geometry) -> Result<Shape> {
    let positive = |what: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(SabreError::urdf(
                source,
                format!("link '{link}': {what} must be positive and finite, got {v}"),
            ))
        }
    };
    Ok(match geometry {
        urdf_rs::Geometry::Box { size } => Shape::Box {
            half_extents: Vector3::new(
                positive("box size", size[0])? / 2.0,
                positive("box size", size[1])? / 2.0,
                positive("box size", size[2])? / 2.0,
            ),
        },
        urdf_rs::Geometry::Sphere { radius } => Shape::Sphere {
            radius: positive("sphere radius", *radius)?,
        },
        urdf_rs::Geometry::Cylinder { radius, length } => Shape::Cylinder {
            radius: positive("cylinder radius", *radius)?,
            half_length: positive("cylinder length", *length)? / 2.0,
        },
        urdf_rs::Geometry::Capsule { radius, length } => Shape::Capsule {
            radius: positive("capsule radius", *radius)?,
            half_length: positive("capsule length", *length)? / 2.0,
        },
        urdf_rs::Geometry::Mesh { .. } => unreachable!("meshes are converted by convert_shape"),
    })
}

/// The link's inertial when the file gives all of it, else what the file declares of it: the parts
/// `present` (its `<mass>`, `<origin>` and `<inertia>` elements) says the file wrote, a zero mass or
/// an all-zero inertia counting as left out.
fn link_inertial(
    source: &str,
    link: &urdf_rs::Link,
    present: (bool, bool, bool),
) -> Result<(Option<Inertial>, Option<DeclaredInertial>)> {
    let mass = link.inertial.mass.value;
    let i = &link.inertial.inertia;
    let values = [mass, i.ixx, i.ixy, i.ixz, i.iyy, i.iyz, i.izz];
    finite_or_err(source, &format!("inertial of link '{}'", link.name), &values)?;
    let o = &link.inertial.origin;
    finite_or_err(
        source,
        &format!("inertial origin of link '{}'", link.name),
        &[o.xyz[0], o.xyz[1], o.xyz[2], o.rpy[0], o.rpy[1], o.rpy[2]],
    )?;
    if mass < 0.0 {
        return Err(SabreError::urdf(
            source,
            format!("link '{}' has invalid mass {mass}", link.name),
        ));
    }
    let origin = origin_pose(&link.inertial.origin);
    let local = Matrix3::new(i.ixx, i.ixy, i.ixz, i.ixy, i.iyy, i.iyz, i.ixz, i.iyz, i.izz);
    let r = origin.rotation.to_rotation_matrix();
    let (has_mass, has_origin, has_inertia) = present;
    let inertia = (has_inertia && local != Matrix3::zeros()).then(|| r.matrix() * local * r.matrix().transpose());
    if inertia.is_some() {
        check_inertia(source, &link.name, &local)?;
    }
    let mass = (has_mass && mass > 0.0).then_some(mass);
    if let (Some(mass), Some(inertia)) = (mass, inertia) {
        return Ok((
            Some(Inertial {
                mass,
                com: origin.translation.vector,
                inertia,
            }),
            None,
        ));
    }
    let com = has_origin.then_some(origin.translation.vector);
    Ok((None, Some(DeclaredInertial { mass, com, inertia })))
}

fn convert_link(source: &str, link: &urdf_rs::Link, present: (bool, bool, bool)) -> Result<Link> {
    let (inertial, declared_inertial) = link_inertial(source, link, present)?;
    let mut collisions = Vec::with_capacity(link.collision.len());
    for c in &link.collision {
        finite_or_err(
            source,
            &format!("collision origin of link '{}'", link.name),
            &[
                c.origin.xyz[0],
                c.origin.xyz[1],
                c.origin.xyz[2],
                c.origin.rpy[0],
                c.origin.rpy[1],
                c.origin.rpy[2],
            ],
        )?;
        let origin = origin_pose(&c.origin);
        for (shape, centre) in convert_shape(source, &link.name, &c.geometry)? {
            collisions.push(Collision {
                name: c.name.clone(),
                shape,
                origin: origin * nalgebra::Translation3::from(centre),
            });
        }
    }
    fuse_capsules(&mut collisions);
    Ok(Link {
        name: link.name.clone(),
        parent_joint: None,
        inertial,
        declared_inertial,
        collisions,
        visuals: Vec::new(),
    })
}

/// Standard URDF has no capsule, so tools write one as a cylinder with a sphere of its radius centred
/// on each end cap. The union is exactly the capsule's solid; reading it back as one capsule keeps the
/// contact path on parry's capsule queries instead of a cylinder's GJK and two extra colliders.
fn fuse_capsules(collisions: &mut Vec<Collision>) {
    const POSITION_TOLERANCE: f64 = 1e-6;
    let mut i = 0;
    while i < collisions.len() {
        let (radius, half_length) = match collisions[i].shape {
            Shape::Cylinder { radius, half_length } => (radius, half_length),
            _ => {
                i += 1;
                continue;
            }
        };
        let cap = |sign: f64| collisions[i].origin * nalgebra::Point3::new(0.0, 0.0, sign * half_length);
        let (top, bottom) = (cap(1.0), cap(-1.0));
        let sphere_at = |centre: &nalgebra::Point3<f64>| {
            collisions.iter().position(|c| {
                matches!(c.shape, Shape::Sphere { radius: r } if (r - radius).abs() <= 1e-9 * radius.max(1.0))
                    && (c.origin.translation.vector - centre.coords).norm() <= POSITION_TOLERANCE
            })
        };
        if let (Some(a), Some(b)) = (sphere_at(&top), sphere_at(&bottom)) {
            if a != b {
                collisions[i].shape = Shape::Capsule { radius, half_length };
                let (first, second) = (a.max(b), a.min(b));
                collisions.remove(first);
                collisions.remove(second);
                i -= [first, second].iter().filter(|&&k| k < i).count();
            }
        }
        i += 1;
    }
}

fn convert_joint(source: &str, joint: &urdf_rs::Joint, link_id: &dyn Fn(&str) -> Option<usize>) -> Result<Joint> {
    let kind = match joint.joint_type {
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => JointKind::Revolute,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        ref other => {
            return Err(SabreError::urdf(
                source,
                format!(
                    "joint '{}' has unsupported type {other:?} (use fixed, revolute, continuous or prismatic)",
                    joint.name
                ),
            ))
        }
    };
    let find = |name: &str| {
        link_id(name).ok_or_else(|| SabreError::urdf(source, format!("joint '{}' refers to unknown link '{name}'", joint.name)))
    };
    let parent = find(&joint.parent.link)?;
    let child = find(&joint.child.link)?;
    let o = &joint.origin;
    finite_or_err(
        source,
        &format!("origin of joint '{}'", joint.name),
        &[o.xyz[0], o.xyz[1], o.xyz[2], o.rpy[0], o.rpy[1], o.rpy[2]],
    )?;
    let axis = vec3(&joint.axis.xyz);
    let axis = if kind == JointKind::Fixed {
        Vector3::x()
    } else {
        let norm = axis.norm();
        if !norm.is_finite() || norm < 1e-9 {
            return Err(SabreError::urdf(
                source,
                format!("joint '{}' has a zero or non-finite axis", joint.name),
            ));
        }
        axis / norm
    };
    let continuous = joint.joint_type == urdf_rs::JointType::Continuous;
    let l = &joint.limit;
    let (lower, upper) = if continuous || (l.lower == 0.0 && l.upper == 0.0 && kind != JointKind::Fixed) {
        // No usable position limit: continuous joints and URDF 1.0's "limits omitted" default.
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        (l.lower, l.upper)
    };
    let ordered = lower.partial_cmp(&upper) == Some(std::cmp::Ordering::Less);
    if (kind != JointKind::Fixed && !ordered) || lower.is_nan() || upper.is_nan() {
        return Err(SabreError::urdf(
            source,
            format!("joint '{}' has lower limit {lower} not below upper {upper}", joint.name),
        ));
    }
    // URDF leaves velocity and effort at 0 when a <limit> omits them: no bound. A negative or
    // non-finite bound is a mistake, not "unlimited".
    let bound = |what: &str, v: f64| -> Result<f64> {
        if !v.is_finite() || v < 0.0 {
            Err(SabreError::urdf(
                source,
                format!(
                    "joint '{}' has {what} limit {v}; it must be finite and non-negative (0 or omitted: no limit)",
                    joint.name
                ),
            ))
        } else if v == 0.0 {
            Ok(f64::INFINITY)
        } else {
            Ok(v)
        }
    };
    let velocity = bound("velocity", l.velocity)?;
    let effort = bound("effort", l.effort)?;
    let (damping, friction) = joint.dynamics.as_ref().map_or((0.0, 0.0), |d| (d.damping, d.friction));
    if !(damping.is_finite() && friction.is_finite() && damping >= 0.0 && friction >= 0.0) {
        return Err(SabreError::urdf(
            source,
            format!(
                "joint '{}' has damping {damping} and friction {friction}; both must be finite and non-negative",
                joint.name
            ),
        ));
    }
    Ok(Joint {
        name: joint.name.clone(),
        kind,
        parent,
        child,
        origin: origin_pose(o),
        axis,
        q_index: None,
        limits: JointLimits {
            lower,
            upper,
            velocity,
            effort,
        },
        damping,
        friction,
    })
}

/// Parses URDF text; `source` names it in error messages (a path or a built-in asset name).
pub fn parse_urdf(source: &str, text: &str) -> Result<ParsedUrdf> {
    // roxmltree first: it reports malformed XML with a position, which urdf-rs does not.
    let doc = roxmltree::Document::parse(text).map_err(|e| SabreError::urdf(source, format!("malformed XML: {e}")))?;
    check_depth(source, &doc)?;
    let extension = parse_extension(source, &doc)?;
    let present = inertial_elements(&doc);
    let robot =
        urdf_rs::read_from_string(&with_complete_inertials(text, &doc)).map_err(|e| SabreError::urdf(source, e.to_string()))?;
    if robot.links.is_empty() {
        return Err(SabreError::urdf(source, "no <link> elements"));
    }
    let mut links = robot
        .links
        .iter()
        .map(|l| convert_link(source, l, present.get(&l.name).copied().unwrap_or_default()))
        .collect::<Result<Vec<_>>>()?;
    for (link, urdf_link) in links.iter_mut().zip(&robot.links) {
        link.visuals = super::visual::convert(source, urdf_link, &robot.materials);
    }
    let names: HashMap<&str, usize> = robot.links.iter().enumerate().map(|(i, l)| (l.name.as_str(), i)).collect();
    let lookup = |name: &str| names.get(name).copied();
    let joints = robot
        .joints
        .iter()
        .map(|j| convert_joint(source, j, &lookup))
        .collect::<Result<Vec<_>>>()?;
    let description = Description::new(robot.name.clone(), links, joints, source)?;
    Ok(ParsedUrdf { description, extension })
}

/// Reads and parses a URDF file.
pub fn load_urdf_file(path: &std::path::Path) -> Result<ParsedUrdf> {
    let source = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| SabreError::urdf(&source, format!("cannot read file: {e}")))?;
    parse_urdf(&source, &text)
}

#[cfg(test)]
mod tests;
