//! The scene: one robot, one articulated object placed in the world, the state layout and built-in assets.

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Translation3, UnitQuaternion};

use super::assembly::{assemble as assemble_robot, RobotRoles};
use super::dynamics::{joint_space_terms, DynamicsWorkspace, GRAVITY};
use super::generated;
use super::inertials::{assume_missing, AssumedInertial, DEFAULT_DENSITY};
use super::kinematics::{Frames, JointKind, JointLimits, KinematicTree};
use super::roles::RoleDecls;
use super::safety_geometry::{check_extension, declared_geometry};
pub use super::safety_geometry::{ArmReach, GeometryOrigin, Sphere};
use super::urdf::{parse_urdf, ParsedUrdf};
use crate::error::{ensure_coordinates, ensure_finite, ensure_len, Result, SabreError};

/// Built-in robots, compiled into the library so that installed wheels need no data files.
pub const BUILTIN_ROBOTS: &[(&str, &str)] = &[("royalpanda", include_str!("../../../assets/robots/royalpanda.urdf"))];

/// Built-in articulated objects.
pub const BUILTIN_OBJECTS: &[(&str, &str)] = &[
    ("shelf", include_str!("../../../assets/objects/shelf.urdf")),
    ("microwave", include_str!("../../../assets/objects/microwave.urdf")),
    ("dishwasher", include_str!("../../../assets/objects/dishwasher.urdf")),
    ("drawer", include_str!("../../../assets/objects/drawer.urdf")),
];

/// Where an object stands when the caller gives no pose: its front faces the robot's default base
/// pose (origin, looking along +x) with the handle within arm's reach.
pub const DEFAULT_OBJECT_POSE: [f64; 6] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];

/// Default placement of each built-in object; low objects stand a little further away so the
/// opening part clears the robot's base.
pub fn default_object_pose(object: &str) -> [f64; 6] {
    match object {
        "dishwasher" | "drawer" => [1.2, 0.0, 0.0, 0.0, 0.0, 0.0],
        _ => DEFAULT_OBJECT_POSE,
    }
}

/// Robot, object and their placement; all kinematic queries go through here.
#[derive(Debug, Clone)]
pub struct Scene {
    pub robot: KinematicTree,
    pub object: KinematicTree,
    /// Pose of the object's root link in the world.
    pub object_pose: Isometry3<f64>,
    pub spheres: Vec<Sphere>,
    pub sphere_pairs: Vec<(usize, usize)>,
    /// Robot links whose colliders touch the object in the reduced-order rollout model.
    pub rollout_contact_links: Vec<usize>,
    pub arm_reach: Option<ArmReach>,
    /// What the robot's parts are for: tool frame, base, postures, held joints, wrist sensor.
    pub roles: RobotRoles,
    /// Where the spheres, pairs, contact links and reach came from.
    pub geometry_origin: GeometryOrigin,
    pub robot_source: String,
    pub object_source: String,
    /// Density (kg/m³) of moving object parts whose file gives no inertial (see [`super::inertials`]).
    pub density: f64,
    /// The inertials of moving object links that were filled in from collision geometry.
    pub assumed_inertials: Vec<AssumedInertial>,
}

/// (x, y, z, roll, pitch, yaw) to an isometry; roll-pitch-yaw as in URDF.
pub fn pose_from_xyzrpy(p: &[f64]) -> Result<Isometry3<f64>> {
    ensure_len("obj_pose", p, 6)?;
    ensure_finite("obj_pose", p)?;
    Ok(Isometry3::from_parts(
        Translation3::new(p[0], p[1], p[2]),
        UnitQuaternion::from_euler_angles(p[3], p[4], p[5]),
    ))
}

/// The URDF text of a built-in robot or object by name.
pub fn builtin<'a>(kind: &str, table: &'a [(&str, &str)], name: &str) -> Result<&'a str> {
    table
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
        .ok_or_else(|| SabreError::UnknownAsset {
            kind: kind.to_string(),
            name: name.to_string(),
            available: table.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
        })
}

/// The URDF text of a built-in asset: `kind` is "robot" or "object", `name` one of that table's names.
pub fn builtin_urdf(kind: &str, name: &str) -> Result<&'static str> {
    match kind {
        "robot" => builtin(kind, BUILTIN_ROBOTS, name),
        "object" => builtin(kind, BUILTIN_OBJECTS, name),
        _ => Err(SabreError::invalid(
            "kind",
            format!("must be \"robot\" or \"object\", got {kind:?}"),
        )),
    }
}

impl Scene {
    /// Scene from built-in assets by name.
    pub fn load(robot: &str, object: &str, object_pose: Option<&[f64]>) -> Result<Self> {
        let robot_text = builtin("robot", BUILTIN_ROBOTS, robot)?;
        let object_text = builtin("object", BUILTIN_OBJECTS, object)?;
        let robot = parse_urdf(robot, robot_text)?;
        let default_pose = default_object_pose(object);
        let obj = parse_urdf(object, object_text)?;
        Self::from_parts(robot, obj, Some(object_pose.unwrap_or(&default_pose)), &RoleDecls::default())
    }

    /// Scene from URDF files on disk.
    pub fn from_urdf_files(robot: &std::path::Path, object: &std::path::Path, object_pose: Option<&[f64]>) -> Result<Self> {
        let robot = super::urdf::load_urdf_file(robot)?;
        let obj = super::urdf::load_urdf_file(object)?;
        Self::from_parts(robot, obj, object_pose, &RoleDecls::default())
    }

    /// Scene from URDF text (robot, object).
    pub fn from_urdf_strings(robot: &str, object: &str, object_pose: Option<&[f64]>) -> Result<Self> {
        Self::from_parts(
            parse_urdf("robot", robot)?,
            parse_urdf("object", object)?,
            object_pose,
            &RoleDecls::default(),
        )
    }

    /// Scene from parsed URDFs, with `options` over the roles the robot's `<sabre>` block declares
    /// (the tool to attach, its control frame, held joints, the base, postures).
    ///
    /// Safety geometry: a robot whose block declares none (no sphere, pair, rollout_contact or
    /// arm_reach element) gets all of it generated (`super::generated`); one that declares any gets
    /// exactly what it declares.
    pub fn from_parts(robot: ParsedUrdf, obj: ParsedUrdf, object_pose: Option<&[f64]>, options: &RoleDecls) -> Result<Self> {
        let object_pose = pose_from_xyzrpy(object_pose.unwrap_or(&DEFAULT_OBJECT_POSE))?;
        let ext = robot.extension;
        let source = robot.description.name.clone();
        let robot = KinematicTree::from_description(robot.description);
        let object = KinematicTree::from_description(obj.description);
        let (tree, roles) = assemble_robot(robot, &ext.roles.overridden_by(options), &source)?;
        check_extension(&source, &tree, &ext)?;
        if tree.nq() == 0 {
            return Err(SabreError::urdf(&tree.name, "the robot has no movable joint"));
        }
        if object.nq() == 0 {
            return Err(SabreError::urdf(&object.name, "the object has no movable joint"));
        }
        if let Some(link) = tree
            .links
            .iter()
            .find(|l| l.declared_inertial.is_some_and(|d| d.mass.is_some()))
        {
            return Err(SabreError::urdf(
                &tree.name,
                format!("robot link '{}' declares a mass but no inertia tensor", link.name),
            ));
        }
        for &j in &object.active_joints {
            let l = object.joints[j].limits;
            if !(l.lower.is_finite() && l.upper.is_finite()) {
                return Err(SabreError::urdf(
                    &object.name,
                    format!("object joint '{}' needs finite position limits", object.joints[j].name),
                ));
            }
        }
        let declared =
            !(ext.spheres.is_empty() && ext.pairs.is_empty() && ext.rollout_contact_links.is_empty() && ext.arm_reach.is_none());
        let (spheres, sphere_pairs, rollout_contact_links, arm_reach) = if declared {
            declared_geometry(&tree, &ext)
        } else {
            let spheres = generated::cover_spheres(&tree);
            let pairs = generated::collision_pairs(&tree, &spheres, &[&roles.home, &roles.start]);
            let contact = generated::contact_links(&tree, roles.tool_frame);
            let reach = generated::arm_reach(&tree, &roles);
            (spheres, pairs, contact, reach)
        };
        Self {
            robot_source: tree.name.clone(),
            object_source: object.name.clone(),
            robot: tree,
            object,
            object_pose,
            spheres,
            sphere_pairs,
            rollout_contact_links,
            arm_reach,
            roles,
            geometry_origin: GeometryOrigin(if declared { "declared" } else { "generated" }),
            density: DEFAULT_DENSITY,
            assumed_inertials: Vec::new(),
        }
        .with_density(DEFAULT_DENSITY)
    }

    /// The scene with the inertials its object file leaves out filled in from collision geometry
    /// at `density` (kg/m³), for every link a movable joint moves ([`super::inertials`]).
    pub fn with_density(mut self, density: f64) -> Result<Self> {
        for assumed in &self.assumed_inertials {
            let link = self.object.link_id(&assumed.link).expect("an object link");
            self.object.set_inertial(link, None);
        }
        self.assumed_inertials = assume_missing(&mut self.object, density, &self.object_source)?;
        self.density = density;
        Ok(self)
    }

    /// The scene with one movable object joint: `joint`, or the one that moves the link `handle`
    /// (either is required when the object has several), is kept and every other movable joint is
    /// fixed at its `hold` value (default 0 within its limits).
    pub fn with_object_joint(mut self, joint: Option<&str>, hold: &[(String, f64)], handle: Option<&str>) -> Result<Self> {
        let keep = match handle {
            Some(handle) => Some(self.joint_moving_handle(handle, joint)?),
            None => joint.map(str::to_string),
        };
        match keep {
            Some(keep) => {
                self.object = self.object.with_single_joint(&keep, hold, &self.object_source)?;
            }
            None if !hold.is_empty() => {
                return Err(SabreError::urdf(
                    &self.object_source,
                    "`hold` needs `joint` or `handle`: what says which joint stays movable",
                ));
            }
            None => {}
        }
        let density = self.density;
        self.with_density(density)
    }

    /// The movable object joints that move the object link or frame `frame`, root first.
    pub fn object_joints_moving(&self, frame: &str) -> Result<Vec<String>> {
        let link = self.object.require_link(frame)?;
        Ok(self
            .object
            .ancestor_active_joints(link)
            .iter()
            .map(|&j| self.object.joints[j].name.clone())
            .collect())
    }

    /// The joint to open for the handle link `handle`: the one movable joint that moves it, or
    /// `joint` when it is one of several that do.
    fn joint_moving_handle(&self, handle: &str, joint: Option<&str>) -> Result<String> {
        let movers = self.object_joints_moving(handle)?;
        let source = &self.object_source;
        let movable = self.object.active_joint_names().join(", ");
        match (movers.as_slice(), joint) {
            ([], _) => Err(SabreError::urdf(
                source,
                format!("handle '{handle}' is on a part no joint moves; the movable joints are: {movable}"),
            )),
            (_, Some(joint)) if movers.iter().any(|m| m == joint) => Ok(joint.to_string()),
            (_, Some(joint)) => Err(SabreError::urdf(
                source,
                format!(
                    "joint '{joint}' does not move handle '{handle}'; it is moved by: {}",
                    movers.join(", ")
                ),
            )),
            ([only], None) => Ok(only.clone()),
            (_, None) => Err(SabreError::urdf(
                source,
                format!(
                    "handle '{handle}' is moved by several joints: {}; name the one to open with `joint`",
                    movers.join(", ")
                ),
            )),
        }
    }

    pub fn nq(&self) -> usize {
        self.robot.nq()
    }
    pub fn no(&self) -> usize {
        self.object.nq()
    }
    /// State x = [q, q̇, o, ȯ].
    pub fn nx(&self) -> usize {
        2 * (self.nq() + self.no())
    }
    /// Input u = commanded robot joint velocities q̇*.
    pub fn nu(&self) -> usize {
        self.nq()
    }

    pub fn robot_limits(&self) -> Vec<JointLimits> {
        self.robot.active_limits()
    }
    pub fn object_limits(&self) -> Vec<JointLimits> {
        self.object.active_limits()
    }

    /// The home configuration at rest, object closed.
    pub fn default_state(&self) -> Vec<f64> {
        let mut x = vec![0.0; self.nx()];
        let home = self.home_configuration();
        x[..self.nq()].copy_from_slice(&home);
        let no = self.no();
        let off = 2 * self.nq();
        for (i, l) in self.object_limits().iter().enumerate() {
            x[off + i] = 0.0_f64.clamp(l.lower, l.upper);
        }
        debug_assert_eq!(off + 2 * no, x.len());
        x
    }

    /// The robot's home configuration (nq): the declared `<home>` values, else 0 where it lies
    /// within a joint's limits, else the middle of finite limits.
    pub fn home_configuration(&self) -> Vec<f64> {
        self.roles.home.clone()
    }

    /// The robot's start configuration (nq): the declared `<start>` values over the home configuration.
    pub fn start_configuration(&self) -> Vec<f64> {
        self.roles.start.clone()
    }

    /// The robot's working configuration (nq): the declared `<work>` values over the home configuration.
    pub fn work_configuration(&self) -> Vec<f64> {
        self.roles.work.clone()
    }

    /// The control frame's link name, if the robot has one.
    pub fn tool_frame_name(&self) -> Option<&str> {
        self.roles.tool_frame.map(|l| self.robot.links[l].name.as_str())
    }

    fn check_q(&self, q: &[f64]) -> Result<()> {
        ensure_len("q", q, self.nq())?;
        ensure_coordinates("q", q)
    }

    fn check_o(&self, o: &[f64]) -> Result<()> {
        ensure_len("o", o, self.no())?;
        ensure_coordinates("o", o)
    }

    /// World pose of a robot link or frame.
    pub fn fk(&self, q: &[f64], frame: &str) -> Result<Isometry3<f64>> {
        self.check_q(q)?;
        let link = self.robot.require_link(frame)?;
        Ok(self.robot.link_poses(&Isometry3::identity(), q)[link])
    }

    /// Geometric Jacobian (6 × nq, world frame, linear rows first) of a robot frame's origin.
    pub fn jacobian(&self, q: &[f64], frame: &str) -> Result<DMatrix<f64>> {
        self.check_q(q)?;
        let link = self.robot.require_link(frame)?;
        Ok(self.robot.frame_jacobian(&Isometry3::identity(), q, link))
    }

    /// World pose of an object link or frame (e.g. `handle_frame`) at object configuration `o`.
    pub fn object_fk(&self, o: &[f64], frame: &str) -> Result<Isometry3<f64>> {
        self.check_o(o)?;
        let link = self.object.require_link(frame)?;
        Ok(self.object.link_poses(&self.object_pose, o)[link])
    }

    /// World poses of a robot frame for M configurations `q` (M × nq, row-major).
    pub fn fk_many(&self, q: &[f64], frame: &str) -> Result<Vec<Isometry3<f64>>> {
        poses_many(&self.robot, &Isometry3::identity(), "q", q, frame)
    }

    /// World poses of an object frame for M object configurations `o` (M × no, row-major).
    pub fn object_fk_many(&self, o: &[f64], frame: &str) -> Result<Vec<Isometry3<f64>>> {
        poses_many(&self.object, &self.object_pose, "o", o, frame)
    }

    /// Joint-space mass matrix M(q) (nq × nq) and gravity torque g(q) (nq) of the robot under
    /// [`GRAVITY`], the terms of the low-level controller (53).
    pub fn mass_matrix_and_gravity(&self, q: &[f64]) -> Result<(DMatrix<f64>, DVector<f64>)> {
        self.check_q(q)?;
        let nq = self.nq();
        let mut workspace = DynamicsWorkspace::default();
        let mut mass_matrix = DMatrix::zeros(nq, nq);
        let mut gravity_torque = DVector::zeros(nq);
        joint_space_terms(
            &self.robot,
            &Isometry3::identity(),
            q,
            &GRAVITY,
            &mut workspace,
            &mut mass_matrix,
            &mut gravity_torque,
        );
        Ok((mass_matrix, gravity_torque))
    }

    /// World centre of each self-collision sphere.
    pub fn sphere_centers(&self, poses: &[Isometry3<f64>]) -> Vec<Point3<f64>> {
        self.spheres.iter().map(|s| poses[s.link] * Point3::from(s.center)).collect()
    }

    /// Validates a full state vector.
    pub fn check_state(&self, x: &[f64]) -> Result<()> {
        ensure_len("x", x, self.nx())?;
        ensure_coordinates("x", x)
    }

    /// True if the object's single movable joint is a hinge.
    pub fn object_is_revolute(&self) -> bool {
        self.object
            .active_joints
            .iter()
            .all(|&j| self.object.joints[j].kind == JointKind::Revolute)
    }
}

/// World poses of one frame of `tree` (rooted at `root`) for every row of `values` (rows of
/// `tree.nq()` entries, named `name` in errors).
fn poses_many(
    tree: &KinematicTree,
    root: &Isometry3<f64>,
    name: &str,
    values: &[f64],
    frame: &str,
) -> Result<Vec<Isometry3<f64>>> {
    let n = tree.nq();
    if n == 0 || !values.len().is_multiple_of(n) {
        return Err(SabreError::shape(
            name,
            format!("(·, {n})"),
            format!("{} elements", values.len()),
        ));
    }
    ensure_coordinates(name, values)?;
    let link = tree.require_link(frame)?;
    let mut frames = Frames::default();
    Ok(values
        .chunks_exact(n)
        .map(|row| {
            tree.update_frames(root, row, &mut frames);
            frames.poses[link]
        })
        .collect())
}

#[cfg(test)]
mod tests;
