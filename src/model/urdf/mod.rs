//! URDF (via urdf-rs) to kinematic trees, plus sabre's `<sabre>` extension block (via roxmltree).

use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use super::inertials::{inertial_elements, with_complete_inertials, DeclaredInertial};
use super::kinematics::{Collision, Inertial, Joint, JointKind, JointLimits, KinematicTree, Link, Shape};
use crate::error::{Result, SabreError};

/// A collision sphere rigidly attached to a robot link, for the self-collision pairs that name it
/// and, unless `obstacles="false"`, against run-time sphere obstacles. A self-collision sphere may
/// be larger than its link to encode a minimum distance between two links; against an obstacle a
/// sphere only needs to cover the link's geometry, so such a link gets a second, obstacle-only
/// sphere (one in no pair).
#[derive(Debug, Clone, PartialEq)]
pub struct SphereDecl {
    pub name: String,
    pub link: String,
    pub center: Vector3<f64>,
    pub radius: f64,
    pub obstacles: bool,
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
    /// The tool, control frame, held joints, base and postures it declares.
    pub roles: super::roles::RoleDecls,
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

/// A physical inertia tensor: symmetric positive definite, and its principal moments obey the
/// triangle inequality (no rigid body has one moment larger than the other two together).
pub(super) fn check_inertia(source: &str, link: &str, inertia: &Matrix3<f64>) -> Result<()> {
    let moments = inertia.symmetric_eigenvalues();
    let scale = moments.abs().max().max(f64::MIN_POSITIVE);
    let tolerance = 1e-9 * scale;
    let positive = moments.iter().all(|&m| m > 0.0);
    let (a, b, c) = (moments[0], moments[1], moments[2]);
    let triangle = a <= b + c + tolerance && b <= a + c + tolerance && c <= a + b + tolerance;
    if positive && triangle {
        Ok(())
    } else {
        Err(SabreError::urdf(
            source,
            format!("link '{link}' has a non-physical inertia (principal moments {a:.6e}, {b:.6e}, {c:.6e}): it must be positive definite and each moment at most the sum of the other two"),
        ))
    }
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

fn parse_f64(source: &str, node: &roxmltree::Node, attr: &str) -> Result<f64> {
    let text = node.attribute(attr).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!("<sabre><{}> needs attribute '{attr}'", node.tag_name().name()),
        )
    })?;
    text.trim().parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
        SabreError::urdf(
            source,
            format!(
                "<sabre><{}> attribute '{attr}'='{text}' is not a finite number",
                node.tag_name().name()
            ),
        )
    })
}

fn parse_xyz(source: &str, node: &roxmltree::Node) -> Result<Vector3<f64>> {
    let Some(text) = node.attribute("xyz") else {
        return Ok(Vector3::zeros());
    };
    let values: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    if values.len() != 3 || values.iter().any(|v: &f64| !v.is_finite()) {
        return Err(SabreError::urdf(
            source,
            format!("<sabre> xyz='{text}' must be three finite numbers"),
        ));
    }
    Ok(Vector3::new(values[0], values[1], values[2]))
}

fn parse_extension(source: &str, doc: &roxmltree::Document) -> Result<SabreExtension> {
    let mut ext = SabreExtension::default();
    let Some(block) = doc.root_element().children().find(|n| n.has_tag_name("sabre")) else {
        return Ok(ext);
    };
    for node in block.children().filter(|n| n.is_element()) {
        let attr = |name: &str| {
            node.attribute(name).map(str::to_string).ok_or_else(|| {
                SabreError::urdf(
                    source,
                    format!("<sabre><{}> needs attribute '{name}'", node.tag_name().name()),
                )
            })
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
                let obstacles = match node.attribute("obstacles").map(str::trim) {
                    None | Some("true") => true,
                    Some("false") => false,
                    Some(other) => {
                        return Err(SabreError::urdf(
                            source,
                            format!("<sabre><sphere> attribute 'obstacles'='{other}' must be true or false"),
                        ))
                    }
                };
                ext.spheres.push(SphereDecl {
                    name: attr("name")?,
                    link: attr("link")?,
                    center: parse_xyz(source, &node)?,
                    radius,
                    obstacles,
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
            other => {
                if !super::roles::parse_role(source, &node, &mut ext.roles)? {
                    return Err(SabreError::urdf(source, format!("unknown element <sabre><{other}>")));
                }
            }
        }
    }
    Ok(ext)
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
    let names: std::collections::HashMap<&str, usize> =
        robot.links.iter().enumerate().map(|(i, l)| (l.name.as_str(), i)).collect();
    let lookup = |name: &str| names.get(name).copied();
    let joints = robot
        .joints
        .iter()
        .map(|j| convert_joint(source, j, &lookup))
        .collect::<Result<Vec<_>>>()?;
    let tree = KinematicTree::new(robot.name.clone(), links, joints, source)?;
    Ok(ParsedUrdf { tree, extension })
}

/// Checks that every link and sphere the `<sabre>` block names exists in `tree` (the robot with its
/// tool attached).
pub fn check_extension(source: &str, tree: &KinematicTree, extension: &SabreExtension) -> Result<()> {
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
                return Err(SabreError::urdf(
                    source,
                    format!("<sabre><pair> refers to unknown sphere '{s}'"),
                ));
            }
        }
    }
    Ok(())
}

/// Reads and parses a URDF file.
pub fn load_urdf_file(path: &std::path::Path) -> Result<ParsedUrdf> {
    let source = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| SabreError::urdf(&source, format!("cannot read file: {e}")))?;
    parse_urdf(&source, &text)
}

#[cfg(test)]
mod tests;
