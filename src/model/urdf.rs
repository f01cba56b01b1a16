//! URDF (via urdf-rs) to kinematic trees, plus sabre's `<sabre>` extension block (via roxmltree).

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::kinematics::{Collision, Inertial, Joint, JointKind, JointLimits, KinematicTree, Link, Shape};
use crate::error::{Result, SabreError};

/// A self-collision sphere rigidly attached to a robot link.
#[derive(Debug, Clone, PartialEq)]
pub struct SphereDecl {
    pub name: String,
    pub link: String,
    pub center: Vector3<f64>,
    pub radius: f64,
}

/// Planar reach limit of a frame relative to the arm base (paper eqs. 32 and 40).
#[derive(Debug, Clone, PartialEq)]
pub struct ArmReachDecl {
    pub base: String,
    pub frame: String,
    pub max: f64,
}

/// Contents of the optional `<sabre>` block of a robot URDF.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SabreExtension {
    pub rollout_contact_links: Vec<String>,
    pub spheres: Vec<SphereDecl>,
    pub pairs: Vec<(String, String)>,
    pub arm_reach: Option<ArmReachDecl>,
}

/// A parsed URDF: its kinematic tree and sabre's extension block.
#[derive(Debug, Clone)]
pub struct ParsedUrdf {
    pub tree: KinematicTree,
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

fn convert_shape(source: &str, link: &str, geometry: &urdf_rs::Geometry) -> Result<Shape> {
    let positive = |what: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(SabreError::urdf(source, format!("link '{link}': {what} must be positive and finite, got {v}")))
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
        urdf_rs::Geometry::Mesh { filename, .. } => {
            return Err(SabreError::urdf(
                source,
                format!("link '{link}' uses mesh '{filename}': sabre simulates primitives only (box, sphere, cylinder, capsule)"),
            ))
        }
    })
}

fn convert_link(source: &str, link: &urdf_rs::Link) -> Result<Link> {
    let inertial = if link.inertial.mass.value > 0.0 {
        let i = &link.inertial.inertia;
        let values = [link.inertial.mass.value, i.ixx, i.ixy, i.ixz, i.iyy, i.iyz, i.izz];
        finite_or_err(source, &format!("inertial of link '{}'", link.name), &values)?;
        let origin = origin_pose(&link.inertial.origin);
        let local = Matrix3::new(i.ixx, i.ixy, i.ixz, i.ixy, i.iyy, i.iyz, i.ixz, i.iyz, i.izz);
        let r = origin.rotation.to_rotation_matrix();
        Some(Inertial {
            mass: link.inertial.mass.value,
            com: origin.translation.vector,
            inertia: r.matrix() * local * r.matrix().transpose(),
        })
    } else if link.inertial.mass.value < 0.0 || !link.inertial.mass.value.is_finite() {
        return Err(SabreError::urdf(
            source,
            format!("link '{}' has invalid mass {}", link.name, link.inertial.mass.value),
        ));
    } else {
        None
    };
    let mut collisions = Vec::with_capacity(link.collision.len());
    for c in &link.collision {
        finite_or_err(source, &format!("collision origin of link '{}'", link.name), &[c.origin.xyz[0], c.origin.xyz[1], c.origin.xyz[2], c.origin.rpy[0], c.origin.rpy[1], c.origin.rpy[2]])?;
        collisions.push(Collision {
            name: c.name.clone(),
            shape: convert_shape(source, &link.name, &c.geometry)?,
            origin: origin_pose(&c.origin),
        });
    }
    Ok(Link {
        name: link.name.clone(),
        parent_joint: None,
        inertial,
        collisions,
    })
}

fn convert_joint(source: &str, joint: &urdf_rs::Joint, link_id: &dyn Fn(&str) -> Option<usize>) -> Result<Joint> {
    let kind = match joint.joint_type {
        urdf_rs::JointType::Fixed => JointKind::Fixed,
        urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => JointKind::Revolute,
        urdf_rs::JointType::Prismatic => JointKind::Prismatic,
        ref other => {
            return Err(SabreError::urdf(
                source,
                format!("joint '{}' has unsupported type {other:?} (use fixed, revolute, continuous or prismatic)", joint.name),
            ))
        }
    };
    let find = |name: &str| {
        link_id(name).ok_or_else(|| SabreError::urdf(source, format!("joint '{}' refers to unknown link '{name}'", joint.name)))
    };
    let parent = find(&joint.parent.link)?;
    let child = find(&joint.child.link)?;
    let o = &joint.origin;
    finite_or_err(source, &format!("origin of joint '{}'", joint.name), &[o.xyz[0], o.xyz[1], o.xyz[2], o.rpy[0], o.rpy[1], o.rpy[2]])?;
    let axis = vec3(&joint.axis.xyz);
    let axis = if kind == JointKind::Fixed {
        Vector3::x()
    } else {
        let norm = axis.norm();
        if !norm.is_finite() || norm < 1e-9 {
            return Err(SabreError::urdf(source, format!("joint '{}' has a zero or non-finite axis", joint.name)));
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
    if (kind != JointKind::Fixed && !(lower < upper)) || lower.is_nan() || upper.is_nan() {
        return Err(SabreError::urdf(source, format!("joint '{}' has lower limit {lower} not below upper {upper}", joint.name)));
    }
    let velocity = if l.velocity > 0.0 { l.velocity } else { f64::INFINITY };
    let effort = if l.effort > 0.0 { l.effort } else { f64::INFINITY };
    let (damping, friction) = joint.dynamics.as_ref().map_or((0.0, 0.0), |d| (d.damping, d.friction));
    if !(damping >= 0.0 && friction >= 0.0) {
        return Err(SabreError::urdf(source, format!("joint '{}' has negative or non-finite dynamics", joint.name)));
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

fn parse_f64(source: &str, node: &roxmltree::Node, attr: &str) -> Result<f64> {
    let text = node
        .attribute(attr)
        .ok_or_else(|| SabreError::urdf(source, format!("<sabre><{}> needs attribute '{attr}'", node.tag_name().name())))?;
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| SabreError::urdf(source, format!("<sabre><{}> attribute '{attr}'='{text}' is not a finite number", node.tag_name().name())))
}

fn parse_xyz(source: &str, node: &roxmltree::Node) -> Result<Vector3<f64>> {
    let Some(text) = node.attribute("xyz") else {
        return Ok(Vector3::zeros());
    };
    let values: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    if values.len() != 3 || values.iter().any(|v: &f64| !v.is_finite()) {
        return Err(SabreError::urdf(source, format!("<sabre> xyz='{text}' must be three finite numbers")));
    }
    Ok(Vector3::new(values[0], values[1], values[2]))
}

fn parse_extension(source: &str, text: &str) -> Result<SabreExtension> {
    let doc = roxmltree::Document::parse(text).map_err(|e| SabreError::urdf(source, format!("malformed XML: {e}")))?;
    let mut ext = SabreExtension::default();
    let Some(block) = doc.root_element().children().find(|n| n.has_tag_name("sabre")) else {
        return Ok(ext);
    };
    for node in block.children().filter(|n| n.is_element()) {
        let attr = |name: &str| {
            node.attribute(name)
                .map(str::to_string)
                .ok_or_else(|| SabreError::urdf(source, format!("<sabre><{}> needs attribute '{name}'", node.tag_name().name())))
        };
        match node.tag_name().name() {
            "rollout_contact" => ext
                .rollout_contact_links
                .extend(attr("links")?.split_whitespace().map(str::to_string)),
            "sphere" => {
                let radius = parse_f64(source, &node, "radius")?;
                if radius <= 0.0 {
                    return Err(SabreError::urdf(source, "<sabre><sphere> radius must be positive"));
                }
                ext.spheres.push(SphereDecl {
                    name: attr("name")?,
                    link: attr("link")?,
                    center: parse_xyz(source, &node)?,
                    radius,
                });
            }
            "pair" => ext.pairs.push((attr("a")?, attr("b")?)),
            "arm_reach" => {
                ext.arm_reach = Some(ArmReachDecl {
                    base: attr("base")?,
                    frame: attr("frame")?,
                    max: parse_f64(source, &node, "max")?,
                })
            }
            other => return Err(SabreError::urdf(source, format!("unknown element <sabre><{other}>"))),
        }
    }
    Ok(ext)
}

/// Parses URDF text; `source` names it in error messages (a path or a built-in asset name).
pub fn parse_urdf(source: &str, text: &str) -> Result<ParsedUrdf> {
    // roxmltree first: it reports malformed XML with a position, which urdf-rs does not.
    let extension = parse_extension(source, text)?;
    let robot = urdf_rs::read_from_string(text).map_err(|e| SabreError::urdf(source, e.to_string()))?;
    if robot.links.is_empty() {
        return Err(SabreError::urdf(source, "no <link> elements"));
    }
    let links = robot
        .links
        .iter()
        .map(|l| convert_link(source, l))
        .collect::<Result<Vec<_>>>()?;
    let names: std::collections::HashMap<&str, usize> = robot.links.iter().enumerate().map(|(i, l)| (l.name.as_str(), i)).collect();
    let lookup = |name: &str| names.get(name).copied();
    let joints = robot
        .joints
        .iter()
        .map(|j| convert_joint(source, j, &lookup))
        .collect::<Result<Vec<_>>>()?;
    let tree = KinematicTree::new(robot.name.clone(), links, joints, source)?;
    for name in extension
        .rollout_contact_links
        .iter()
        .chain(extension.spheres.iter().map(|s| &s.link))
        .chain(extension.arm_reach.iter().flat_map(|a| [&a.base, &a.frame]))
    {
        if tree.link_id(name).is_none() {
            return Err(SabreError::urdf(source, format!("<sabre> refers to unknown link '{name}'")));
        }
    }
    for (a, b) in &extension.pairs {
        for s in [a, b] {
            if !extension.spheres.iter().any(|sp| &sp.name == s) {
                return Err(SabreError::urdf(source, format!("<sabre><pair> refers to unknown sphere '{s}'")));
            }
        }
    }
    Ok(ParsedUrdf { tree, extension })
}

/// Reads and parses a URDF file.
pub fn load_urdf_file(path: &std::path::Path) -> Result<ParsedUrdf> {
    let source = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| SabreError::urdf(&source, format!("cannot read file: {e}")))?;
    parse_urdf(&source, &text)
}
