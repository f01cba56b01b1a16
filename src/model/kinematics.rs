//! Kinematic trees built from a robot or object description: forward kinematics and geometric Jacobians in f64.

use std::collections::HashMap;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::description::Description;
pub use super::description::{Collision, Inertial, Joint, JointKind, JointLimits, Link, Shape};
pub use super::rigid_bodies::RigidBody;
use super::rigid_bodies::{mass_invariant_coordinates, sum_rigid_bodies};
use crate::error::{Result, SabreError};

/// Link poses and world joint axes of one configuration, reused while the configuration is unchanged.
#[derive(Debug, Clone, Default)]
pub struct Frames {
    pub poses: Vec<Isometry3<f64>>,
    axes: Vec<Vector3<f64>>,
    origins: Vec<Point3<f64>>,
    q: Vec<f64>,
    root: Option<Isometry3<f64>>,
}

impl Frames {
    /// World axis of movable joint `j` at the frames' configuration.
    pub fn axis(&self, j: usize) -> Vector3<f64> {
        self.axes[j]
    }

    /// World origin of movable joint `j`'s frame at the frames' configuration.
    pub fn origin(&self, j: usize) -> Point3<f64> {
        self.origins[j]
    }
}

/// One Jacobian column: the velocity a unit joint rate gives `point` (linear) and the link (angular).
fn fill_column(kind: JointKind, axis: &Vector3<f64>, origin: &Point3<f64>, point: &Point3<f64>, c: &mut [f64]) {
    match kind {
        JointKind::Revolute => {
            let lin = axis.cross(&(point - origin));
            c.copy_from_slice(&[lin.x, lin.y, lin.z, axis.x, axis.y, axis.z]);
        }
        JointKind::Prismatic => c.copy_from_slice(&[axis.x, axis.y, axis.z, 0.0, 0.0, 0.0]),
        JointKind::Fixed => c.fill(0.0),
    }
}

/// A tree of links connected by fixed, revolute and prismatic joints.
#[derive(Debug, Clone)]
pub struct KinematicTree {
    pub name: String,
    pub links: Vec<Link>,
    pub joints: Vec<Joint>,
    /// Joints ordered so that each parent link is placed before its child.
    pub topological_joints: Vec<usize>,
    /// For each coordinate of q, the joint it drives.
    pub active_joints: Vec<usize>,
    pub root: usize,
    link_index: HashMap<String, usize>,
    /// For each link, the movable joints between the root and that link (root first).
    ancestor_active_joints: Vec<Vec<usize>>,
    /// The same joints by their column (q index), with that column: the order in which a
    /// Jacobian-vector product over all columns adds them up.
    ancestor_columns: Vec<Vec<(usize, usize)>>,
    /// One per movable joint (see [`RigidBody`]), parents before children.
    rigid_bodies: Vec<RigidBody>,
    /// Per coordinate: M(q) does not depend on it (see [`Self::mass_invariant_coordinates`]).
    mass_invariant: Vec<bool>,
}

impl KinematicTree {
    /// Assembles a tree; movable joints get q indices in the order they appear in `joints`.
    pub fn new(name: String, links: Vec<Link>, joints: Vec<Joint>, source: &str) -> Result<Self> {
        Ok(Self::from_description(Description::new(name, links, joints, source)?))
    }

    /// The tree a description holds; movable joints get q indices in the order they appear in its joints.
    pub fn from_description(description: Description) -> Self {
        let Description {
            name,
            links,
            mut joints,
            root,
            topological_joints,
            link_index,
        } = description;
        let mut active_joints = Vec::new();
        for (j, joint) in joints.iter_mut().enumerate() {
            if joint.kind != JointKind::Fixed {
                joint.q_index = Some(active_joints.len());
                active_joints.push(j);
            } else {
                joint.q_index = None;
            }
        }

        let mut ancestor_active_joints = vec![Vec::new(); links.len()];
        for &j in &topological_joints {
            let joint = &joints[j];
            let mut chain = ancestor_active_joints[joint.parent].clone();
            if joint.kind != JointKind::Fixed {
                chain.push(j);
            }
            ancestor_active_joints[joint.child] = chain;
        }
        let ancestor_columns = ancestor_active_joints
            .iter()
            .map(|chain| {
                let mut columns: Vec<(usize, usize)> = chain.iter().map(|&j| (j, joints[j].q_index.expect("movable"))).collect();
                columns.sort_by_key(|&(_, column)| column);
                columns
            })
            .collect();

        let mut tree = Self {
            name,
            links,
            joints,
            topological_joints,
            active_joints,
            root,
            link_index,
            ancestor_active_joints,
            ancestor_columns,
            rigid_bodies: Vec::new(),
            mass_invariant: Vec::new(),
        };
        tree.rigid_bodies = sum_rigid_bodies(&tree.links, &tree.joints, &tree.topological_joints);
        tree.mass_invariant = mass_invariant_coordinates(&tree.joints, tree.nq(), &tree.rigid_bodies);
        tree
    }

    /// Sets the inertial of `link` (None: massless).
    pub fn set_inertial(&mut self, link: usize, inertial: Option<Inertial>) {
        self.links[link].inertial = inertial;
        self.rigid_bodies = sum_rigid_bodies(&self.links, &self.joints, &self.topological_joints);
    }

    /// The rigid bodies the movable joints carry: what moves with each of them, summed once so
    /// that the dynamics place one inertia per joint instead of one per link.
    pub fn rigid_bodies(&self) -> &[RigidBody] {
        &self.rigid_bodies
    }

    /// Per coordinate, whether the joint-space inertia M(q) is independent of it with the root
    /// held in place (a mobile base's x and y, a door's hinge): a mass matrix computed at q holds
    /// wherever only these coordinates changed.
    pub fn mass_invariant_coordinates(&self) -> &[bool] {
        &self.mass_invariant
    }

    /// The same tree with one movable joint, `keep`: every other movable joint becomes fixed at its
    /// value in `held` (default 0 clamped into its limits, the closed position of a door or drawer).
    /// A cabinet with two doors is opened one door at a time this way.
    pub fn with_single_joint(&self, keep: &str, held: &[(String, f64)], source: &str) -> Result<Self> {
        let movable = self.active_joint_names();
        if !movable.iter().any(|n| n == keep) {
            return Err(SabreError::urdf(
                source,
                format!("no movable joint '{keep}'; the movable joints are: {}", movable.join(", ")),
            ));
        }
        for (name, value) in held {
            if name == keep || !movable.contains(name) {
                let others: Vec<&str> = movable.iter().filter(|n| *n != keep).map(String::as_str).collect();
                return Err(SabreError::urdf(
                    source,
                    format!("cannot hold '{name}': the joints to hold are: {}", others.join(", ")),
                ));
            }
            let limits = self.joints[self.joints.iter().position(|j| &j.name == name).expect("movable")].limits;
            if !(value.is_finite() && limits.lower <= *value && *value <= limits.upper) {
                return Err(SabreError::urdf(
                    source,
                    format!(
                        "joint '{name}' held at {value}, outside its limits [{}, {}]",
                        limits.lower, limits.upper
                    ),
                ));
            }
        }
        let values: Vec<(usize, f64)> = self
            .active_joints
            .iter()
            .filter(|&&j| self.joints[j].name != keep)
            .map(|&j| {
                let joint = &self.joints[j];
                let value = held
                    .iter()
                    .find(|(n, _)| n == &joint.name)
                    .map_or(0.0_f64.clamp(joint.limits.lower, joint.limits.upper), |(_, v)| *v);
                (j, value)
            })
            .collect();
        self.with_joints_fixed(&values, source)
    }

    /// The same tree with each movable joint of `values` (joint index, value in rad or m) fixed at
    /// its value; link indices are unchanged, q loses those coordinates.
    pub fn with_joints_fixed(&self, values: &[(usize, f64)], source: &str) -> Result<Self> {
        let mut links = self.links.clone();
        for link in &mut links {
            link.parent_joint = None;
        }
        let joints = self
            .joints
            .iter()
            .enumerate()
            .map(|(j, joint)| match values.iter().find(|(k, _)| *k == j) {
                Some(&(_, value)) if joint.kind != JointKind::Fixed => Joint {
                    kind: JointKind::Fixed,
                    origin: joint.origin * Self::joint_motion(joint, value),
                    ..joint.clone()
                },
                _ => joint.clone(),
            })
            .collect();
        Self::new(self.name.clone(), links, joints, source)
    }

    /// Number of generalized coordinates.
    pub fn nq(&self) -> usize {
        self.active_joints.len()
    }

    pub fn link_id(&self, name: &str) -> Option<usize> {
        self.link_index.get(name).copied()
    }

    /// Looks a link up by name, with an error listing the names that exist.
    pub fn require_link(&self, name: &str) -> Result<usize> {
        self.link_id(name).ok_or_else(|| SabreError::UnknownFrame {
            name: name.to_string(),
            available: self.link_names().join(", "),
        })
    }

    pub fn link_names(&self) -> Vec<String> {
        self.links.iter().map(|l| l.name.clone()).collect()
    }

    pub fn active_joint_names(&self) -> Vec<String> {
        self.active_joints.iter().map(|&j| self.joints[j].name.clone()).collect()
    }

    pub fn active_limits(&self) -> Vec<JointLimits> {
        self.active_joints.iter().map(|&j| self.joints[j].limits).collect()
    }

    /// The movable joints that move `link`, root first.
    pub fn ancestor_active_joints(&self, link: usize) -> &[usize] {
        &self.ancestor_active_joints[link]
    }

    /// Motion of a joint's child relative to the joint frame for coordinate value `value`.
    pub fn joint_motion(joint: &Joint, value: f64) -> Isometry3<f64> {
        Self::moved(&Isometry3::identity(), joint, value)
    }

    /// `frame` (a joint's frame in the world) followed by the joint's motion at `value`: the pose
    /// of the joint's child. The axis is a unit vector (the URDF loader normalises it).
    #[inline(always)]
    fn moved(frame: &Isometry3<f64>, joint: &Joint, value: f64) -> Isometry3<f64> {
        match joint.kind {
            JointKind::Fixed => *frame,
            JointKind::Revolute => {
                let turn = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_unchecked(joint.axis), value);
                Isometry3::from_parts(frame.translation, frame.rotation * turn)
            }
            JointKind::Prismatic => Isometry3::from_parts(
                Translation3::from(frame.translation.vector + frame.rotation * (joint.axis * value)),
                frame.rotation,
            ),
        }
    }

    /// World poses of every link, with the root placed at `root_pose`.
    pub fn link_poses_into(&self, root_pose: &Isometry3<f64>, q: &[f64], out: &mut Vec<Isometry3<f64>>) {
        debug_assert_eq!(q.len(), self.nq());
        out.clear();
        out.resize(self.links.len(), Isometry3::identity());
        out[self.root] = *root_pose;
        for &j in &self.topological_joints {
            let joint = &self.joints[j];
            let value = joint.q_index.map_or(0.0, |i| q[i]);
            out[joint.child] = Self::moved(&(out[joint.parent] * joint.origin), joint, value);
        }
    }

    pub fn link_poses(&self, root_pose: &Isometry3<f64>, q: &[f64]) -> Vec<Isometry3<f64>> {
        let mut out = Vec::new();
        self.link_poses_into(root_pose, q, &mut out);
        out
    }

    /// World axis and world origin of a movable joint, given the link poses.
    pub fn joint_axis_world(&self, poses: &[Isometry3<f64>], joint: usize) -> (Vector3<f64>, Point3<f64>) {
        let j = &self.joints[joint];
        let frame = poses[j.parent] * j.origin;
        (frame.rotation * j.axis, Point3::from(frame.translation.vector))
    }

    /// Geometric Jacobian (6 × nq, world frame, linear rows first) of the point `point`
    /// (world coordinates) rigidly attached to `link`; angular rows are the link's angular velocity.
    /// `out` is column-major with 6 rows: `out[6 * c + r]`.
    pub fn point_jacobian_into(&self, poses: &[Isometry3<f64>], link: usize, point: &Point3<f64>, out: &mut [f64]) {
        let n = self.nq();
        debug_assert_eq!(out.len(), 6 * n);
        out.iter_mut().for_each(|v| *v = 0.0);
        for &j in &self.ancestor_active_joints[link] {
            let joint = &self.joints[j];
            let col = joint.q_index.expect("active joint has a coordinate");
            let (axis, origin) = self.joint_axis_world(poses, j);
            fill_column(joint.kind, &axis, &origin, point, &mut out[6 * col..6 * col + 6]);
        }
    }

    /// Brings `frames` to configuration `q` with the root at `root_pose`; free if nothing changed.
    pub fn update_frames(&self, root_pose: &Isometry3<f64>, q: &[f64], frames: &mut Frames) {
        if frames.root.as_ref() == Some(root_pose) && frames.q == q && frames.poses.len() == self.links.len() {
            return;
        }
        // Every link but the root is some joint's child: the loop below writes every pose.
        frames.poses.resize(self.links.len(), Isometry3::identity());
        frames.axes.resize(self.joints.len(), Vector3::zeros());
        frames.origins.resize(self.joints.len(), Point3::origin());
        frames.poses[self.root] = *root_pose;
        for &j in &self.topological_joints {
            let joint = &self.joints[j];
            let parent = &frames.poses[joint.parent];
            // Many joint origins only translate: the rotation product with the identity is left out
            // (its result would be the parent's rotation to the bit).
            let frame = if joint.origin.rotation == UnitQuaternion::identity() {
                Isometry3::from_parts(
                    Translation3::from(parent.translation.vector + parent.rotation * joint.origin.translation.vector),
                    parent.rotation,
                )
            } else {
                parent * joint.origin
            };
            // Only movable joints have an axis anyone asks for (Jacobians, dynamics).
            if let Some(i) = joint.q_index {
                frames.axes[j] = frame.rotation * joint.axis;
                frames.origins[j] = Point3::from(frame.translation.vector);
                frames.poses[joint.child] = Self::moved(&frame, joint, q[i]);
            } else {
                frames.poses[joint.child] = frame;
            }
        }
        frames.q.clear();
        frames.q.extend_from_slice(q);
        frames.root = Some(*root_pose);
    }

    /// [`Self::point_jacobian_into`] from up-to-date [`Frames`].
    pub fn frames_jacobian_into(&self, frames: &Frames, link: usize, point: &Point3<f64>, out: &mut [f64]) {
        debug_assert_eq!(out.len(), 6 * self.nq());
        out.fill(0.0);
        for &j in &self.ancestor_active_joints[link] {
            let joint = &self.joints[j];
            let col = joint.q_index.expect("active joint has a coordinate");
            fill_column(
                joint.kind,
                &frames.axes[j],
                &frames.origins[j],
                point,
                &mut out[6 * col..6 * col + 6],
            );
        }
    }

    /// The linear rows of [`Self::frames_jacobian_into`]: the velocity of `point` on `link` per
    /// unit rate of each joint, as a 3 × nq matrix (column-major).
    pub fn frames_linear_jacobian_into(&self, frames: &Frames, link: usize, point: &Point3<f64>, out: &mut [f64]) {
        debug_assert_eq!(out.len(), 3 * self.nq());
        out.fill(0.0);
        let mut column = [0.0; 6];
        for &(j, c) in &self.ancestor_columns[link] {
            fill_column(self.joints[j].kind, &frames.axes[j], &frames.origins[j], point, &mut column);
            out[3 * c..3 * c + 3].copy_from_slice(&column[..3]);
        }
    }

    /// The twist J(q) q̇ of `point` on `link` from up-to-date [`Frames`]: (linear velocity of the
    /// point, angular velocity of the link), without forming the 6 × nq Jacobian.
    pub fn frames_point_velocity(
        &self,
        frames: &Frames,
        link: usize,
        point: &Point3<f64>,
        qd: &[f64],
    ) -> (Vector3<f64>, Vector3<f64>) {
        let mut twist = [0.0; 6];
        let mut column = [0.0; 6];
        for &(j, c) in &self.ancestor_columns[link] {
            fill_column(self.joints[j].kind, &frames.axes[j], &frames.origins[j], point, &mut column);
            for (t, v) in twist.iter_mut().zip(&column) {
                *t += v * qd[c];
            }
        }
        (
            Vector3::new(twist[0], twist[1], twist[2]),
            Vector3::new(twist[3], twist[4], twist[5]),
        )
    }

    /// Adds the joint torques J(q)ᵀ (force, moment) of a wrench acting at `point` on `link` to `tau`
    /// (nq), from up-to-date [`Frames`], without forming the Jacobian.
    pub fn frames_add_wrench_torques(
        &self,
        frames: &Frames,
        link: usize,
        point: &Point3<f64>,
        force: &Vector3<f64>,
        moment: &Vector3<f64>,
        tau: &mut [f64],
    ) {
        let mut col = [0.0; 6];
        for &(j, c) in &self.ancestor_columns[link] {
            fill_column(self.joints[j].kind, &frames.axes[j], &frames.origins[j], point, &mut col);
            tau[c] += col[0] * force.x
                + col[1] * force.y
                + col[2] * force.z
                + col[3] * moment.x
                + col[4] * moment.y
                + col[5] * moment.z;
        }
    }

    /// Jacobian of the origin of `link`'s frame as a dense 6 × nq matrix.
    pub fn frame_jacobian(&self, root_pose: &Isometry3<f64>, q: &[f64], link: usize) -> nalgebra::DMatrix<f64> {
        let poses = self.link_poses(root_pose, q);
        let point = Point3::from(poses[link].translation.vector);
        let mut data = vec![0.0; 6 * self.nq()];
        self.point_jacobian_into(&poses, link, &point, &mut data);
        nalgebra::DMatrix::from_column_slice(6, self.nq(), &data)
    }
}
