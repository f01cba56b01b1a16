//! A robot or object as its URDF describes it, as plain data: links, joints, collision shapes and
//! inertials, checked to form one tree, and the check every inertia tensor passes. The URDF reader
//! produces it; a [`super::kinematics::KinematicTree`] is built from it.

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::error::{Result, SabreError};

/// How a joint moves its child link relative to its parent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    Fixed,
    /// Rotation about `axis`; `continuous` URDF joints are revolute without limits.
    Revolute,
    /// Translation along `axis`.
    Prismatic,
}

/// Position, velocity and effort bounds of one actuated joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimits {
    pub lower: f64,
    pub upper: f64,
    pub velocity: f64,
    pub effort: f64,
}

#[derive(Debug, Clone)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    pub parent: usize,
    pub child: usize,
    /// Pose of the joint frame (= child link frame at q = 0) in the parent link frame.
    pub origin: Isometry3<f64>,
    /// Unit axis in the joint frame.
    pub axis: Vector3<f64>,
    /// Index of this joint's coordinate in q, for movable joints.
    pub q_index: Option<usize>,
    pub limits: JointLimits,
    /// Viscous damping (N·s/m or N·m·s/rad) and dry friction (N or N·m) from `<dynamics>`.
    pub damping: f64,
    pub friction: f64,
}

/// A collision primitive; dimensions are half-sizes, long axes along local z as in URDF.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    Box {
        half_extents: Vector3<f64>,
    },
    Sphere {
        radius: f64,
    },
    Cylinder {
        radius: f64,
        half_length: f64,
    },
    Capsule {
        radius: f64,
        half_length: f64,
    },
    /// A mesh's convex hull: its vertices, centred on their bounding box (whose half extents are kept).
    Hull {
        points: std::sync::Arc<[nalgebra::Point3<f64>]>,
        half_extents: Vector3<f64>,
    },
}

impl Shape {
    /// Half extents of the primitive's bounding box in its own frame.
    pub fn half_extents(&self) -> Vector3<f64> {
        match *self {
            Shape::Box { half_extents } => half_extents,
            Shape::Sphere { radius } => Vector3::repeat(radius),
            Shape::Cylinder { radius, half_length } => Vector3::new(radius, radius, half_length),
            Shape::Capsule { radius, half_length } => Vector3::new(radius, radius, half_length + radius),
            Shape::Hull { half_extents, .. } => half_extents,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Collision {
    pub name: Option<String>,
    pub shape: Shape,
    /// Pose of the primitive in its link frame.
    pub origin: Isometry3<f64>,
}

/// Mass, centre of mass and inertia tensor (about the centre of mass, in the link frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertial {
    pub mass: f64,
    pub com: Vector3<f64>,
    pub inertia: Matrix3<f64>,
}

#[derive(Debug, Clone)]
pub struct Link {
    pub name: String,
    /// The joint whose child this link is; `None` for the root.
    pub parent_joint: Option<usize>,
    /// Read through [`Link::inertial`]; changed through `KinematicTree::set_inertial`, which
    /// keeps the tree's rigid bodies in step.
    pub(super) inertial: Option<Inertial>,
    /// What the file declares of an inertial it leaves incomplete or out (None: `inertial` is the
    /// file's); a scene fills the rest in for moving object links (see `super::inertials`).
    pub declared_inertial: Option<DeclaredInertial>,
    pub collisions: Vec<Collision>,
    /// What the link looks like (URDF `<visual>`), for viewers.
    pub visuals: Vec<super::visual::Visual>,
}

impl Link {
    /// The link's mass, centre of mass and inertia, if it has any.
    pub fn inertial(&self) -> Option<&Inertial> {
        self.inertial.as_ref()
    }
}

/// What a link's `<inertial>` declares when it is incomplete: each part the file gives (a mass
/// above zero, an `<origin>`, an inertia tensor that is not all zero), None for each it leaves out.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DeclaredInertial {
    pub mass: Option<f64>,
    pub com: Option<Vector3<f64>>,
    pub inertia: Option<Matrix3<f64>>,
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

/// Links and joints that form one tree: link names unique, every link but the root the child of
/// exactly one joint, every link reached from the root.
#[derive(Debug, Clone)]
pub struct Description {
    pub name: String,
    /// The links, each with its parent joint set.
    pub links: Vec<Link>,
    pub joints: Vec<Joint>,
    pub root: usize,
    /// Joints ordered so that each parent link is placed before its child.
    pub topological_joints: Vec<usize>,
    pub(super) link_index: HashMap<String, usize>,
}

impl Description {
    /// Checks that `links` and `joints` form one tree and orders it; `source` names the file in errors.
    pub fn new(name: String, links: Vec<Link>, joints: Vec<Joint>, source: &str) -> Result<Self> {
        let mut link_index = HashMap::with_capacity(links.len());
        for (i, link) in links.iter().enumerate() {
            if link_index.insert(link.name.clone(), i).is_some() {
                return Err(SabreError::urdf(source, format!("duplicate link '{}'", link.name)));
            }
        }
        let mut links = links;
        for (j, joint) in joints.iter().enumerate() {
            if links[joint.child].parent_joint.is_some() {
                return Err(SabreError::urdf(
                    source,
                    format!("link '{}' has more than one parent joint", links[joint.child].name),
                ));
            }
            links[joint.child].parent_joint = Some(j);
        }
        let roots: Vec<usize> = (0..links.len()).filter(|&i| links[i].parent_joint.is_none()).collect();
        if roots.len() != 1 {
            let names: Vec<&str> = roots.iter().map(|&i| links[i].name.as_str()).collect();
            return Err(SabreError::urdf(
                source,
                format!("expected exactly one root link, found {}: {:?}", roots.len(), names),
            ));
        }
        let root = roots[0];

        // Breadth-first from the root gives a parent-before-child order and detects cycles.
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); links.len()];
        for (j, joint) in joints.iter().enumerate() {
            children[joint.parent].push(j);
        }
        let mut topological_joints = Vec::with_capacity(joints.len());
        let mut frontier = vec![root];
        while let Some(link) = frontier.pop() {
            for &j in &children[link] {
                topological_joints.push(j);
                frontier.push(joints[j].child);
            }
        }
        if topological_joints.len() != joints.len() {
            return Err(SabreError::urdf(source, "the joints do not form a tree rooted at one link"));
        }
        Ok(Self {
            name,
            links,
            joints,
            root,
            topological_joints,
            link_index,
        })
    }
}
