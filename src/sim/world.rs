//! Builds a Rapier world (robot and object as reduced-coordinate multibodies) from a scene, sets and reads
//! the state x = [q, q̇, o, ȯ], and turns solver contact impulses into τ_ext, the wrist wrench and a contact flag.

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{DMatrix, DVector, Isometry3, Point3, UnitQuaternion, Vector3};
use rapier3d_f64::prelude::*;

use crate::error::{Result, SabreError};
use crate::model::dynamics::{joint_space_terms, DynamicsWorkspace};
use crate::cost::{Cost, StepView};
use crate::model::kinematics::{Frames, JointKind, KinematicTree, Shape};
use crate::model::scene::Scene;

/// Which robot colliders exist in the world.
#[derive(Debug, Clone, PartialEq)]
pub enum RobotColliders {
    /// Every collision primitive of the robot (the plant).
    All,
    /// Only these links' primitives (the reduced-order rollout model: hand, hook, forearm).
    Links(Vec<usize>),
}

/// How the robot's joints are driven.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RobotDrive {
    /// The closed loop of (57) integrated in joint space, with the integral action of the plant's
    /// controller (53): q̈ = Λ (u − q̇) + Λ_I ∫(u − q̇) + M(q)⁻¹ τ_ext, each joint's acceleration bounded
    /// by effort / inertia; gravity and Coriolis terms are compensated by the servo, as in (57). Each contact body of the robot is a free Rapier body ("proxy") carrying
    /// the robot's effective mass at that body: every step it is placed at its forward-kinematics pose
    /// with its forward-kinematics velocity, Rapier's contact solver resolves its contacts with the
    /// dynamic object (so forces stay bounded by the robot's inertia, also in jams), and the contact
    /// forces act back on the joints through τ_ext on the next step.
    KinematicServo { bandwidth: f64, integral_gain: f64, integral_limit: f64, skip_quiescent: bool },
    /// The same closed loop simulated by Rapier's multibody solver: implicit velocity motors per
    /// joint (torque-limited), robot links without gravity. Higher fidelity, several times slower.
    MultibodyServo { bandwidth: f64 },
    /// Joint torques applied by the caller; gravity acts on the robot (the plant).
    Torque,
}

impl RobotDrive {
    fn bandwidth(&self) -> Option<f64> {
        match *self {
            RobotDrive::KinematicServo { bandwidth, .. } | RobotDrive::MultibodyServo { bandwidth } => Some(bandwidth),
            RobotDrive::Torque => None,
        }
    }
}

/// Physics settings shared by the rollout model and the plant.
#[derive(Debug, Clone, PartialEq)]
pub struct WorldConfig {
    pub dt: f64,
    pub colliders: RobotColliders,
    pub drive: RobotDrive,
    /// Coulomb friction coefficient between robot and object surfaces; low, as the paper advises,
    /// so that plans rely on geometry (hooking) rather than on friction that is hard to know.
    pub contact_friction: f64,
    pub solver_iterations: usize,
}

const ROBOT_GROUP: Group = Group::GROUP_1;
const OBJECT_GROUP: Group = Group::GROUP_2;
const OWNER_ROBOT: u128 = 1 << 64;
const OWNER_OBJECT: u128 = 2 << 64;

/// One movable joint as Rapier sees it.
#[derive(Debug, Clone, Copy)]
struct DofRef {
    link_id: usize,
    dof: usize,
    /// Index in the joint's 6-vector of coordinates (0 = linear x, 3 = angular x).
    coord: usize,
    axis: JointAxis,
    parent_body: RigidBodyHandle,
    child_body: RigidBodyHandle,
}

impl DofRef {
    /// This coordinate's current value in multibody `mb`.
    fn value(&self, mb: &Multibody) -> f64 {
        mb.link(self.link_id).expect("link").joint().coords()[self.coord]
    }
}

/// Static facts about a built world, shared by every copy of it.
#[derive(Debug)]
pub struct WorldLayout {
    pub nq: usize,
    pub no: usize,
    drive: RobotDrive,
    /// Proxy bodies of the robot (kinematic servo): link owning the body, the body, its centre of
    /// mass in the link frame.
    proxies: Vec<(usize, RigidBodyHandle, Point3<f64>)>,
    /// Largest joint acceleration the servo can produce: effort / M_ii at the home configuration.
    acceleration_limits: Vec<f64>,
    position_limits: Vec<(f64, f64)>,
    robot_handle: Option<MultibodyJointHandle>,
    object_handle: MultibodyJointHandle,
    robot_dofs: Vec<DofRef>,
    object_dofs: Vec<DofRef>,
    velocity_limits: Vec<f64>,
    effort_limits: Vec<f64>,
    /// Robot links whose contact forces the wrist force-torque sensor measures.
    pub sensor_links: Vec<bool>,
    pub sensor_link: usize,
    /// Bounding spheres (link, centre in the link frame, radius) of the robot's contact geometry
    /// and of the object's links, for the quiescence test.
    robot_spheres: Vec<(usize, Point3<f64>, f64)>,
    /// Object collision primitives (link, pose in the link frame, shape).
    object_shapes: Vec<(usize, Isometry3<f64>, Shape)>,
    object_friction: Vec<f64>,
}

/// Radius of a sphere about the primitive's centre that contains it.
fn bounding_radius(shape: &Shape) -> f64 {
    match *shape {
        Shape::Box { half_extents } => half_extents.norm(),
        Shape::Sphere { radius } => radius,
        Shape::Cylinder { radius, half_length } => (radius * radius + half_length * half_length).sqrt(),
        Shape::Capsule { radius, half_length } => radius + half_length,
    }
}

/// Distance from `point` to a primitive placed at `pose` (exact for boxes and spheres, through the
/// bounding sphere otherwise; never more than the true distance).
fn distance_to_shape(pose: &Isometry3<f64>, shape: &Shape, point: &Point3<f64>) -> f64 {
    let local = pose.inverse_transform_point(point);
    match *shape {
        Shape::Box { half_extents } => {
            let outside = Vector3::new(
                (local.x.abs() - half_extents.x).max(0.0),
                (local.y.abs() - half_extents.y).max(0.0),
                (local.z.abs() - half_extents.z).max(0.0),
            );
            outside.norm()
        }
        _ => (local.coords.norm() - bounding_radius(shape)).max(0.0),
    }
}

/// One bounding sphere per link with collision geometry (of the links `include` accepts).
fn link_spheres(tree: &KinematicTree, include: &dyn Fn(usize) -> bool) -> Vec<(usize, Point3<f64>, f64)> {
    let mut out = Vec::new();
    for (link, l) in tree.links.iter().enumerate() {
        if l.collisions.is_empty() || !include(link) {
            continue;
        }
        let centers: Vec<Point3<f64>> = l.collisions.iter().map(|c| Point3::from(c.origin.translation.vector)).collect();
        let center = Point3::from(centers.iter().map(|c| c.coords).sum::<Vector3<f64>>() / centers.len() as f64);
        let radius = l
            .collisions
            .iter()
            .zip(&centers)
            .map(|(c, p)| (p - center).norm() + bounding_radius(&c.shape))
            .fold(0.0, f64::max);
        out.push((link, center, radius));
    }
    out
}

/// Per-step interaction readings.
#[derive(Debug, Clone, PartialEq)]
pub struct Interaction {
    /// Any contact between the robot and the object (or its cabinet) carried force in this step.
    pub contact: bool,
    /// τ_ext = Σ J_cᵀ f_c over contacts on the robot, f_c the force acting on the robot (35).
    pub tau_ext: Vec<f64>,
    /// Force (world frame) and torque about the sensor origin (world frame) acting on the robot
    /// links at and beyond the wrist sensor.
    pub wrench: [f64; 6],
}

/// One robot–object contact point that carried force in the last step.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactReport {
    /// Index of the robot link (in the robot tree) whose collider touches.
    pub robot_link: usize,
    /// Index of the object link (in the object tree) whose collider touches.
    pub object_link: usize,
    /// Contact point, world frame (m).
    pub point: [f64; 3],
    /// Force acting on the robot at the point, world frame (N).
    pub force: [f64; 3],
}

/// The mutable Rapier state; cloning it is how a world is reset to a pristine snapshot.
#[derive(Clone)]
struct PhysicsState {
    islands: IslandManager,
    broad_phase: BroadPhaseBvh,
    narrow_phase: NarrowPhase,
    bodies: RigidBodySet,
    colliders: ColliderSet,
    impulse_joints: ImpulseJointSet,
    multibody_joints: MultibodyJointSet,
    soft_bodies: SoftBodySet,
    ccd_solver: CCDSolver,
    /// Robot configuration and velocity when the robot is a kinematic servo (else unused).
    robot_q: Vec<f64>,
    robot_qd: Vec<f64>,
    /// Accumulated velocity error of the servo's integral term.
    robot_integral: Vec<f64>,
    /// Velocity command of the next step (servo drives).
    command: Vec<f64>,
    /// Interaction measured in the last step.
    last: Interaction,
    /// Factorised robot mass matrix for the contact term of the kinematic servo, and the
    /// configuration it was computed at (recomputed once the robot has moved on).
    mass_factor: Option<nalgebra::linalg::Cholesky<f64, nalgebra::Dyn>>,
    mass_factor_q: Vec<f64>,
}

/// A Rapier world holding one robot and one articulated object.
pub struct SimWorld {
    state: PhysicsState,
    pipeline: PhysicsPipeline,
    params: IntegrationParameters,
    gravity: Vector,
    pub layout: Arc<WorldLayout>,
    scene: Arc<Scene>,
    jacobian: Vec<f64>,
    /// Scratch buffer (joint displacements, next configuration, state) reused every step.
    scratch: Vec<f64>,
    /// Object coordinates at the start of the step (see `step_once`).
    object_coords: Vec<f64>,
    dynamics: DynamicsWorkspace,
    /// Object link poses for cost evaluation (a cache keyed by the configuration). The robot's
    /// are `dynamics.frames`: one step places the proxies, takes contact Jacobians and evaluates the
    /// cost at the same configuration, so one cache computes them once.
    object_frames: Frames,
    mass_matrix: DMatrix<f64>,
    gravity_torque: DVector<f64>,
    engine: EngineClock,
}

/// Work done inside Rapier's `PhysicsPipeline::step` by one world since it was built: what the
/// physics engine itself costs, apart from sabre's servo, interaction and cost work around it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EngineClock {
    /// Steps that went through the pipeline (steps skipped as quiescent are not counted).
    pub steps: u64,
    /// Wall time spent inside those steps (s).
    pub seconds: f64,
}

impl Clone for SimWorld {
    fn clone(&self) -> Self {
        Self {
            state: self.state.clone(),
            pipeline: PhysicsPipeline::new(),
            params: self.params,
            gravity: self.gravity,
            layout: self.layout.clone(),
            scene: self.scene.clone(),
            jacobian: self.jacobian.clone(),
            scratch: self.scratch.clone(),
            object_coords: self.object_coords.clone(),
            dynamics: self.dynamics.clone(),
            object_frames: self.object_frames.clone(),
            mass_matrix: self.mass_matrix.clone(),
            gravity_torque: self.gravity_torque.clone(),
            engine: self.engine,
        }
    }
}

fn vec_to_rapier(v: &Vector3<f64>) -> Vector {
    Vector::new(v.x, v.y, v.z)
}

fn vec_from_rapier(v: Vector) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

fn pose_to_rapier(iso: &Isometry3<f64>) -> Pose {
    Pose::from(*iso)
}

/// Rotation that maps the x axis onto `axis` (Rapier joints move along or about their local x).
fn align_x_to(axis: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(&Vector3::x(), axis)
        .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI))
}

/// For each link: the link that owns its rigid body (fixed joints merge links) and its pose in that body.
fn body_groups(tree: &KinematicTree) -> (Vec<usize>, Vec<Isometry3<f64>>) {
    let n = tree.links.len();
    let mut group: Vec<usize> = (0..n).collect();
    let mut offset = vec![Isometry3::identity(); n];
    for &j in &tree.topological_joints {
        let joint = &tree.joints[j];
        if joint.kind == JointKind::Fixed {
            group[joint.child] = group[joint.parent];
            offset[joint.child] = offset[joint.parent] * joint.origin;
        }
    }
    (group, offset)
}

fn mass_properties(tree: &KinematicTree, group: &[usize], offset: &[Isometry3<f64>], body: usize) -> MassProperties {
    let mut total = MassProperties::default();
    for (link, l) in tree.links.iter().enumerate() {
        if group[link] != body {
            continue;
        }
        if let Some(inertial) = &l.inertial {
            let m = inertial.inertia;
            let local = MassProperties::with_inertia_matrix(
                vec_to_rapier(&inertial.com),
                inertial.mass,
                Matrix::from_cols_array(&[m[(0, 0)], m[(1, 0)], m[(2, 0)], m[(0, 1)], m[(1, 1)], m[(2, 1)], m[(0, 2)], m[(1, 2)], m[(2, 2)]]),
            );
            total += local.transform_by(&pose_to_rapier(&offset[link]));
        }
    }
    if total.mass() <= 0.0 {
        // Massless intermediate links (virtual base axes) still need an invertible inertia.
        total = MassProperties::new(Vector::ZERO, 1e-3, Vector::splat(1e-6));
    }
    total
}

fn collider_for(shape: &Shape) -> (ColliderBuilder, Isometry3<f64>) {
    match *shape {
        Shape::Box { half_extents: h } => (ColliderBuilder::cuboid(h.x, h.y, h.z), Isometry3::identity()),
        Shape::Sphere { radius } => (ColliderBuilder::ball(radius), Isometry3::identity()),
        // URDF cylinders run along z, Rapier's along y: rotate y onto z.
        Shape::Cylinder { radius, half_length } => (
            ColliderBuilder::cylinder(half_length, radius),
            Isometry3::rotation(Vector3::x() * std::f64::consts::FRAC_PI_2),
        ),
        Shape::Capsule { radius, half_length } => (ColliderBuilder::capsule_z(half_length, radius), Isometry3::identity()),
    }
}

/// Smallest effective mass of the robot felt at `point` (link frame) of `link`: 1 / λ_max(J_v M⁻¹ J_vᵀ).
fn effective_mass(tree: &KinematicTree, q: &[f64], link: usize, point: &Point3<f64>) -> f64 {
    let n = tree.nq();
    let mut ws = DynamicsWorkspace::default();
    let mut m = DMatrix::zeros(n, n);
    let mut g = DVector::zeros(n);
    joint_space_terms(tree, &Isometry3::identity(), q, &Vector3::zeros(), &mut ws, &mut m, &mut g);
    let poses = tree.link_poses(&Isometry3::identity(), q);
    let mut jac = vec![0.0; 6 * n];
    tree.point_jacobian_into(&poses, link, &(poses[link] * point), &mut jac);
    let jv = DMatrix::from_fn(3, n, |r, c| jac[6 * c + r]);
    let Some(chol) = m.cholesky() else { return 1.0 };
    let a = &jv * chol.solve(&jv.transpose());
    let largest = a.symmetric_eigenvalues().max();
    if largest > 0.0 {
        (1.0 / largest).clamp(0.1, 1e3)
    } else {
        1.0
    }
}

struct BuiltTree {
    bodies: Vec<Option<RigidBodyHandle>>,
    dofs: Vec<DofRef>,
    first_joint: Option<MultibodyJointHandle>,
}

#[allow(clippy::too_many_arguments)]
fn build_tree(
    state: &mut PhysicsState,
    tree: &KinematicTree,
    root_pose: &Isometry3<f64>,
    q0: &[f64],
    include_collider: &dyn Fn(usize) -> bool,
    membership: (Group, Group, u128),
    friction: f64,
    gravity_scale: f64,
    drive: Option<&RobotDrive>,
) -> Result<BuiltTree> {
    let (group, offset) = body_groups(tree);
    let poses = tree.link_poses(root_pose, q0);
    let n = tree.links.len();
    let mut bodies: Vec<Option<RigidBodyHandle>> = vec![None; n];
    let kinematic = matches!(drive, Some(RobotDrive::KinematicServo { .. }));
    for link in 0..n {
        if group[link] != link {
            continue;
        }
        if kinematic {
            // Only bodies that carry contact geometry exist, as free proxies with the robot's
            // effective mass at that body.
            let has_colliders = (0..n).any(|l| group[l] == link && include_collider(l) && !tree.links[l].collisions.is_empty());
            if has_colliders {
                let own = mass_properties(tree, &group, &offset, link);
                let effective = effective_mass(tree, q0, link, &Point3::from(vec_from_rapier(own.local_com)));
                let scale = effective / own.mass().max(1e-9);
                let mprops = MassProperties::with_principal_inertia_frame(
                    own.local_com,
                    effective,
                    own.principal_inertia() * scale,
                    own.principal_inertia_local_frame,
                );
                let rb = RigidBodyBuilder::dynamic()
                    .additional_mass_properties(mprops)
                    .gravity_scale(0.0)
                    .can_sleep(false)
                    .pose(pose_to_rapier(&poses[link]))
                    .build();
                bodies[link] = Some(state.bodies.insert(rb));
            }
            continue;
        }
        let builder = if link == tree.root {
            RigidBodyBuilder::fixed()
        } else {
            RigidBodyBuilder::dynamic()
                .additional_mass_properties(mass_properties(tree, &group, &offset, link))
                .gravity_scale(gravity_scale)
                .can_sleep(false)
        };
        bodies[link] = Some(state.bodies.insert(builder.pose(pose_to_rapier(&poses[link])).build()));
    }
    for (link, l) in tree.links.iter().enumerate() {
        if !include_collider(link) {
            continue;
        }
        let Some(body) = bodies[group[link]] else { continue };
        for c in &l.collisions {
            let (builder, shape_frame) = collider_for(&c.shape);
            let collider = builder
                .position(pose_to_rapier(&(offset[link] * c.origin * shape_frame)))
                .density(0.0)
                .friction(friction)
                .restitution(0.0)
                .collision_groups(InteractionGroups::new(membership.0, membership.1, InteractionTestMode::And))
                .user_data(membership.2 | link as u128)
                .build();
            state.colliders.insert_with_parent(collider, body, &mut state.bodies);
        }
    }
    let mut dofs = Vec::with_capacity(tree.nq());
    let mut first_joint = None;
    let mut handles = Vec::with_capacity(tree.nq());
    if kinematic {
        return Ok(BuiltTree {
            bodies,
            dofs,
            first_joint,
        });
    }
    for &j in &tree.topological_joints {
        let joint = &tree.joints[j];
        if joint.kind == JointKind::Fixed {
            continue;
        }
        let align = align_x_to(&joint.axis);
        let frame1 = offset[joint.parent] * joint.origin * Isometry3::from_parts(Default::default(), align);
        let frame2 = Isometry3::from_parts(Default::default(), align);
        let (locked, axis, coord) = match joint.kind {
            JointKind::Revolute => (JointAxesMask::LOCKED_REVOLUTE_AXES, JointAxis::AngX, 3),
            _ => (JointAxesMask::LOCKED_PRISMATIC_AXES, JointAxis::LinX, 0),
        };
        let mut builder = GenericJointBuilder::new(locked)
            .local_frame1(pose_to_rapier(&frame1))
            .local_frame2(pose_to_rapier(&frame2))
            .contacts_enabled(false);
        if joint.limits.lower.is_finite() && joint.limits.upper.is_finite() {
            builder = builder.limits(axis, [joint.limits.lower, joint.limits.upper]);
        }
        if let Some(RobotDrive::MultibodyServo { bandwidth }) = drive {
            builder = builder
                .motor_model(axis, MotorModel::AccelerationBased)
                .motor_velocity(axis, 0.0, *bandwidth)
                .motor_max_force(axis, joint.limits.effort);
        }
        let parent_body = bodies[group[joint.parent]].expect("parent body");
        let child_body = bodies[joint.child].expect("child body");
        let handle = state
            .multibody_joints
            .insert(parent_body, child_body, builder.build(), true)
            .ok_or_else(|| SabreError::Simulation(format!("Rapier rejected joint '{}'", joint.name)))?;
        first_joint.get_or_insert(handle);
        handles.push((j, handle, axis, coord, parent_body, child_body));
    }
    // Link ids are final only once every joint of the multibody is inserted, and a fixed root's
    // six free coordinates are dropped only by the first forward-kinematics pass.
    if let Some(h) = first_joint {
        let (mb, _) = state.multibody_joints.get_mut(h).expect("inserted");
        mb.forward_kinematics(&state.bodies, true);
    }
    let mut by_q: Vec<Option<DofRef>> = vec![None; tree.nq()];
    for (j, handle, axis, coord, parent_body, child_body) in handles {
        let (mb, link_id) = state.multibody_joints.get(handle).expect("inserted");
        let q_index = tree.joints[j].q_index.expect("movable");
        by_q[q_index] = Some(DofRef {
            link_id,
            dof: mb.link(link_id).expect("link").assembly_id(),
            coord,
            axis,
            parent_body,
            child_body,
        });
    }
    dofs.extend(by_q.into_iter().map(|d| d.expect("every coordinate has a joint")));
    if let Some(h) = first_joint {
        let (mb, _) = state.multibody_joints.get_mut(h).expect("inserted");
        let damping = mb.damping_mut();
        damping.fill(0.0);
        for (qi, d) in dofs.iter().enumerate() {
            damping[d.dof] = tree.joints[tree.active_joints[qi]].damping;
        }
        let frictions = mb.frictions_mut();
        frictions.fill(0.0);
        for (qi, d) in dofs.iter().enumerate() {
            frictions[d.dof] = tree.joints[tree.active_joints[qi]].friction;
        }
    }
    Ok(BuiltTree {
        bodies,
        dofs,
        first_joint,
    })
}

impl SimWorld {
    /// Builds the world once; copies of it are reset, never rebuilt.
    pub fn new(scene: Arc<Scene>, config: &WorldConfig) -> Result<Self> {
        if !(config.dt.is_finite() && config.dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be positive and finite, got {}", config.dt)));
        }
        if let Some(bandwidth) = config.drive.bandwidth() {
            if !(bandwidth.is_finite() && bandwidth > 0.0) {
                return Err(SabreError::invalid("servo bandwidth", format!("must be positive, got {bandwidth}")));
            }
        }
        let nq = scene.nq();
        let mut state = PhysicsState {
            islands: IslandManager::new(),
            broad_phase: BroadPhaseBvh::new(),
            narrow_phase: NarrowPhase::new(),
            bodies: RigidBodySet::new(),
            colliders: ColliderSet::new(),
            impulse_joints: ImpulseJointSet::new(),
            multibody_joints: MultibodyJointSet::new(),
            soft_bodies: SoftBodySet::new(),
            ccd_solver: CCDSolver::new(),
            robot_q: vec![0.0; nq],
            robot_qd: vec![0.0; nq],
            robot_integral: vec![0.0; nq],
            command: vec![0.0; nq],
            last: Interaction {
                contact: false,
                tau_ext: vec![0.0; nq],
                wrench: [0.0; 6],
            },
            mass_factor: None,
            mass_factor_q: Vec::new(),
        };
        let x0 = scene.default_state();
        let no = scene.no();
        let robot_links: Vec<bool> = match &config.colliders {
            RobotColliders::All => vec![true; scene.robot.links.len()],
            RobotColliders::Links(links) => {
                let mut v = vec![false; scene.robot.links.len()];
                links.iter().for_each(|&l| v[l] = true);
                v
            }
        };
        let (drive, gravity_scale) = match config.drive {
            RobotDrive::KinematicServo { .. } | RobotDrive::MultibodyServo { .. } => (Some(&config.drive), 0.0),
            RobotDrive::Torque => (None, 1.0),
        };
        let robot = build_tree(
            &mut state,
            &scene.robot,
            &Isometry3::identity(),
            &x0[..nq],
            &|l| robot_links[l],
            (ROBOT_GROUP, OBJECT_GROUP, OWNER_ROBOT),
            config.contact_friction,
            gravity_scale,
            drive,
        )?;
        let object = build_tree(
            &mut state,
            &scene.object,
            &scene.object_pose,
            &x0[2 * nq..2 * nq + no],
            &|_| true,
            (OBJECT_GROUP, ROBOT_GROUP, OWNER_OBJECT),
            config.contact_friction,
            1.0,
            None,
        )?;
        let proxies = robot
            .bodies
            .iter()
            .enumerate()
            .filter_map(|(link, b)| b.map(|b| (link, b)))
            .filter(|_| matches!(config.drive, RobotDrive::KinematicServo { .. }))
            .map(|(link, b)| (link, b, Point3::from(vec_from_rapier(state.bodies[b].local_center_of_mass()))))
            .collect();
        let mut dynamics = DynamicsWorkspace::default();
        let mut mass_matrix = DMatrix::zeros(nq, nq);
        let mut gravity_torque = DVector::zeros(nq);
        joint_space_terms(
            &scene.robot,
            &Isometry3::identity(),
            &scene.home_configuration(),
            &Vector3::zeros(),
            &mut dynamics,
            &mut mass_matrix,
            &mut gravity_torque,
        );

        let sensor_link = scene
            .robot
            .link_id("panda_link8")
            .unwrap_or_else(|| scene.robot.joints[*scene.robot.active_joints.last().expect("nq > 0")].child);
        let sensor_links = (0..scene.robot.links.len())
            .map(|l| {
                let mut cur = Some(l);
                while let Some(c) = cur {
                    if c == sensor_link {
                        return true;
                    }
                    cur = scene.robot.links[c].parent_joint.map(|j| scene.robot.joints[j].parent);
                }
                false
            })
            .collect();
        let limits = scene.robot_limits();
        let robot_spheres = link_spheres(&scene.robot, &|l| robot_links[l]);
        let object_shapes = scene
            .object
            .links
            .iter()
            .enumerate()
            .flat_map(|(link, l)| l.collisions.iter().map(move |c| (link, c.origin, c.shape)))
            .collect();
        let object_friction = scene.object.active_joints.iter().map(|&j| scene.object.joints[j].friction).collect();
        let layout = WorldLayout {
            robot_spheres,
            object_shapes,
            object_friction,
            nq,
            no,
            drive: config.drive,
            proxies,
            acceleration_limits: limits
                .iter()
                .enumerate()
                .map(|(i, l)| l.effort / mass_matrix[(i, i)].max(1e-9))
                .collect(),
            position_limits: limits.iter().map(|l| (l.lower, l.upper)).collect(),
            robot_handle: robot.first_joint,
            object_handle: object.first_joint.expect("object has joints"),
            robot_dofs: robot.dofs,
            object_dofs: object.dofs,
            velocity_limits: limits.iter().map(|l| l.velocity).collect(),
            effort_limits: limits.iter().map(|l| l.effort).collect(),
            sensor_links,
            sensor_link,
        };
        let mut params = IntegrationParameters::default();
        params.dt = config.dt;
        params.num_solver_iterations = config.solver_iterations.max(1);
        // Proxies are re-placed every step; recycled manifolds would keep contacts from the
        // pose before the jump (seen as forces across centimetre gaps).
        // Recycled manifolds keep a contact's normal and separation while bodies move less than
        // 5 cm: far too coarse for a 1 cm bar and a 16 mm hook (a finger passing beside the bar
        // keeps "touching" it long after), and wrong for proxies that are re-placed every step.
        params.contact_recycling = false;
        if matches!(config.drive, RobotDrive::KinematicServo { .. }) {
            // Proxies re-enter a little of what they pushed every step; a stiffer, less damped contact
            // than Rapier's default (30 Hz, ζ = 10) resolves that within a step or two at dt = 15 ms,
            // so a hooked handle is held instead of slipping off the 16 mm tip.
            params.contact_softness.natural_frequency = 60.0;
            params.contact_softness.damping_ratio = 1.0;
            // Contacts are predicted 1 cm ahead (Rapier's default is 2 cm): a hand moving below
            // 0.6 m/s covers less than that in a 15 ms step, and fewer speculative pairs are solved.
            params.normalized_prediction_distance = 0.01;
        }
        let mut world = Self {
            state,
            pipeline: PhysicsPipeline::new(),
            params,
            gravity: Vector::new(0.0, 0.0, -9.81),
            layout: Arc::new(layout),
            jacobian: vec![0.0; 6 * nq],
            scratch: Vec::new(),
            object_coords: Vec::new(),
            dynamics,
            object_frames: Default::default(),
            mass_matrix,
            gravity_torque,
            engine: EngineClock::default(),
            scene,
        };
        world.set_state(&x0);
        Ok(world)
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub fn dt(&self) -> f64 {
        self.params.dt
    }

    /// Restores every piece of Rapier state (bodies, contacts, warm starts, broad phase) from `snapshot`.
    /// The result depends only on the snapshot, never on what this world simulated before.
    pub fn restore_from(&mut self, snapshot: &SimWorld) {
        self.state.clone_from(&snapshot.state);
    }

    fn set_tree_state(
        multibodies: &mut MultibodyJointSet,
        bodies: &mut RigidBodySet,
        handle: MultibodyJointHandle,
        dofs: &[DofRef],
        q: &[f64],
        qd: &[f64],
        displacement: &mut Vec<f64>,
    ) {
        let (mb, _) = multibodies.get_mut(handle).expect("multibody");
        displacement.clear();
        displacement.resize(mb.ndofs(), 0.0);
        for (i, d) in dofs.iter().enumerate() {
            let current = d.value(mb);
            displacement[d.dof] = q[i] - current;
        }
        mb.apply_displacements(displacement);
        {
            let mut v = mb.generalized_velocity_mut();
            v.fill(0.0);
            for (i, d) in dofs.iter().enumerate() {
                v[d.dof] = qd[i];
            }
        }
        mb.forward_kinematics(bodies, false);
        mb.update_rigid_bodies(bodies, true);
    }

    /// Places robot and object at state x = [q, q̇, o, ȯ] (x must be validated by the caller).
    pub fn set_state(&mut self, x: &[f64]) {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let layout = self.layout.clone();
        match layout.robot_handle {
            Some(handle) => Self::set_tree_state(
                &mut self.state.multibody_joints,
                &mut self.state.bodies,
                handle,
                &layout.robot_dofs,
                &x[..nq],
                &x[nq..2 * nq],
                &mut self.scratch,
            ),
            None => {
                self.state.robot_q.copy_from_slice(&x[..nq]);
                self.state.robot_qd.copy_from_slice(&x[nq..2 * nq]);
                self.state.robot_integral.iter_mut().for_each(|v| *v = 0.0);
                self.state.mass_factor = None;
                let qd = self.state.robot_qd.clone();
                self.place_proxies(&qd);
            }
        }
        Self::set_tree_state(
            &mut self.state.multibody_joints,
            &mut self.state.bodies,
            layout.object_handle,
            &layout.object_dofs,
            &x[2 * nq..2 * nq + no],
            &x[2 * nq + no..],
            &mut self.scratch,
        );
        self.state.command.iter_mut().for_each(|v| *v = 0.0);
        self.state.last.contact = false;
        self.state.last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        self.state.last.wrench = [0.0; 6];
    }

    /// Places every proxy body at the forward kinematics of `robot_q` with the velocity that the
    /// joint velocities `qd` give it.
    fn place_proxies(&mut self, qd: &[f64]) {
        let frames = &mut self.dynamics.frames;
        self.scene.robot.update_frames(&Isometry3::identity(), &self.state.robot_q, frames);
        for &(link, body, com) in &self.layout.proxies {
            let pose = frames.poses[link];
            let com_world = pose * com;
            self.scene.robot.frames_jacobian_into(frames, link, &com_world, &mut self.jacobian);
            let mut twist = [0.0; 6];
            for (c, &v) in qd.iter().enumerate() {
                for (r, t) in twist.iter_mut().enumerate() {
                    *t += self.jacobian[6 * c + r] * v;
                }
            }
            let rb = &mut self.state.bodies[body];
            rb.set_position(pose_to_rapier(&pose), true);
            rb.set_linvel(Vector::new(twist[0], twist[1], twist[2]), true);
            rb.set_angvel(Vector::new(twist[3], twist[4], twist[5]), true);
        }
    }

    /// Writes the current state into `x` (length nx): the engine's own velocities, which for the
    /// object in a servo world are not its motion (see [`Self::step_once`], which reports that).
    pub fn read_state(&self, x: &mut [f64]) {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let mbs = &self.state.multibody_joints;
        match self.layout.robot_handle {
            Some(handle) => {
                let (robot, _) = mbs.get(handle).expect("robot");
                let rv = robot.generalized_velocity();
                for (i, d) in self.layout.robot_dofs.iter().enumerate() {
                    x[i] = d.value(robot);
                    x[nq + i] = rv[d.dof];
                }
            }
            None => {
                x[..nq].copy_from_slice(&self.state.robot_q);
                x[nq..2 * nq].copy_from_slice(&self.state.robot_qd);
            }
        }
        let (object, _) = mbs.get(self.layout.object_handle).expect("object");
        let ov = object.generalized_velocity();
        for (i, d) in self.layout.object_dofs.iter().enumerate() {
            x[2 * nq + i] = d.value(object);
            x[2 * nq + no + i] = ov[d.dof];
        }
    }

    /// Sets the joint velocity command of the next step for the servo drives, projected onto the
    /// joint velocity limits.
    pub fn set_velocity_command(&mut self, u: &[f64]) {
        let layout = self.layout.clone();
        for (i, c) in self.state.command.iter_mut().enumerate() {
            let limit = layout.velocity_limits[i];
            *c = u[i].clamp(-limit, limit);
        }
        if let (Some(handle), RobotDrive::MultibodyServo { bandwidth }) = (layout.robot_handle, layout.drive) {
            let (mb, _) = self.state.multibody_joints.get_mut(handle).expect("robot");
            for (i, d) in layout.robot_dofs.iter().enumerate() {
                if let Some(link) = mb.link_mut(d.link_id) {
                    link.joint.data.set_motor_velocity(d.axis, self.state.command[i], bandwidth);
                }
            }
        }
    }

    /// Applies joint torques (clamped to the effort limits) for the next step as equal and opposite
    /// wrenches on each joint's child and parent bodies, which Rapier maps to exactly τ_i on that joint.
    pub fn apply_joint_torques(&mut self, tau: &[f64], applied: &mut [f64]) {
        let Some(handle) = self.layout.robot_handle else { return };
        let bodies = &mut self.state.bodies;
        for (_, rb) in bodies.iter_mut() {
            rb.reset_forces(false);
            rb.reset_torques(false);
        }
        let (mb, _) = self.state.multibody_joints.get(handle).expect("robot");
        for (i, d) in self.layout.robot_dofs.iter().enumerate() {
            let limit = self.layout.effort_limits[i];
            let t = tau[i].clamp(-limit, limit);
            applied[i] = t;
            if t == 0.0 {
                continue;
            }
            let link = mb.link(d.link_id).expect("link");
            let frame = *link.local_to_world() * link.joint().data.local_frame2;
            let axis = frame.rotation * Vector::X;
            let origin = frame.translation;
            match d.axis {
                JointAxis::AngX => {
                    bodies[d.child_body].add_torque(axis * t, true);
                    bodies[d.parent_body].add_torque(-axis * t, true);
                }
                _ => {
                    bodies[d.child_body].add_force_at_point(axis * t, origin, true);
                    bodies[d.parent_body].add_force_at_point(-axis * t, origin, true);
                }
            }
        }
    }

    /// Locks (or releases) the object's joints in place: a stuck door or drawer. The joint's limits
    /// collapse onto its current value (a hard constraint that transmits any force), then return.
    pub fn hold_object(&mut self, hold: bool) {
        let object_limits = self.scene.object_limits();
        let (mb, _) = self.state.multibody_joints.get_mut(self.layout.object_handle).expect("object");
        for (i, d) in self.layout.object_dofs.iter().enumerate() {
            let value = d.value(mb);
            if let Some(link) = mb.link_mut(d.link_id) {
                let limits = if hold { [value, value] } else { [object_limits[i].lower, object_limits[i].upper] };
                link.joint.data.set_limits(d.axis, limits);
            }
        }
        if hold {
            let mut v = mb.generalized_velocity_mut();
            for d in &self.layout.object_dofs {
                v[d.dof] = 0.0;
            }
        }
    }

    /// One step of the kinematic servo: semi-implicit Euler of q̈ = Λ (u − q̇) + Λ_I ∫(u − q̇) + M⁻¹ τ_ext.
    fn advance_kinematic_robot(&mut self, bandwidth: f64, integral_gain: f64, integral_limit: f64) {
        let dt = self.params.dt;
        let nq = self.layout.nq;
        let in_contact = self.state.last.tau_ext.iter().any(|&t| t != 0.0);
        // M(q) varies slowly; refactorising it only after a joint moved by MASS_REFRESH keeps the
        // contact term within a few percent at a fraction of the cost.
        const MASS_REFRESH: f64 = 0.02;
        let stale = self.state.mass_factor.is_none()
            || self
                .state
                .mass_factor_q
                .iter()
                .zip(&self.state.robot_q)
                .any(|(a, b)| (a - b).abs() > MASS_REFRESH);
        if in_contact && stale {
            joint_space_terms(
                &self.scene.robot,
                &Isometry3::identity(),
                &self.state.robot_q,
                &Vector3::zeros(),
                &mut self.dynamics,
                &mut self.mass_matrix,
                &mut self.gravity_torque,
            );
            self.state.mass_factor = self.mass_matrix.clone().cholesky();
            self.state.mass_factor_q.clone_from(&self.state.robot_q);
        }
        let contact_acceleration = match (&self.state.mass_factor, in_contact) {
            (Some(factor), true) => Some(factor.solve(&DVector::from_column_slice(&self.state.last.tau_ext))),
            _ => None,
        };
        let mut q_next = std::mem::take(&mut self.scratch);
        q_next.clear();
        for i in 0..nq {
            let qd = self.state.robot_qd[i];
            let external = contact_acceleration.as_ref().map_or(0.0, |a| a[i]);
            // The integral is the position lag behind the integrated command, ∫u dt − (q − q₀),
            // booked with the same velocity that moves q so that it settles at zero lag exactly.
            let integral = self.state.robot_integral[i];
            let drive = bandwidth * self.state.command[i] + integral_gain * integral + external;
            let target = (qd + dt * drive) / (1.0 + dt * bandwidth);
            let max_change = self.layout.acceleration_limits[i] * dt;
            let saturated = (target - qd).abs() > max_change;
            let velocity_limit = self.layout.velocity_limits[i];
            let unclamped = qd + (target - qd).clamp(-max_change, max_change);
            let mut qd_next = unclamped.clamp(-velocity_limit, velocity_limit);
            let saturated = saturated || qd_next != unclamped;
            let (lower, upper) = self.layout.position_limits[i];
            let mut next = self.state.robot_q[i] + dt * qd_next;
            let at_limit = next < lower || next > upper;
            if at_limit {
                next = next.clamp(lower, upper);
                qd_next = (next - self.state.robot_q[i]) / dt;
            }
            // Anti-windup: a joint that is saturated or at a limit does not accumulate lag it
            // cannot act on.
            if !saturated && !at_limit {
                let lag = integral + dt * self.state.command[i] - (next - self.state.robot_q[i]);
                self.state.robot_integral[i] = lag.clamp(-integral_limit, integral_limit);
            }
            q_next.push(next);
            self.state.robot_qd[i] = qd_next;
        }
        // The proxies start the step where the robot is, moving as it will move during the step.
        let qd = self.state.robot_qd.clone();
        self.place_proxies(&qd);
        self.state.robot_q.copy_from_slice(&q_next);
        self.scratch = q_next;
    }

    /// Advances the physics by one step of length dt under the current command, then measures
    /// the interaction of that step.
    pub fn step(&mut self) {
        if let RobotDrive::KinematicServo {
            bandwidth,
            integral_gain,
            integral_limit,
            skip_quiescent,
        } = self.layout.drive
        {
            self.advance_kinematic_robot(bandwidth, integral_gain, integral_limit);
            if skip_quiescent && self.quiescent() {
                // Nothing can touch the object and it is held at rest: the physics step would leave
                // it exactly where it is, as Rapier's island sleeping would. Skip it.
                let last = &mut self.state.last;
                last.contact = false;
                last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
                last.wrench = [0.0; 6];
                return;
            }
        }
        let s = &mut self.state;
        let started = Instant::now();
        self.pipeline.step(
            self.gravity,
            &self.params,
            &mut s.islands,
            &mut s.broad_phase,
            &mut s.narrow_phase,
            &mut s.bodies,
            &mut s.colliders,
            &mut s.impulse_joints,
            &mut s.multibody_joints,
            &mut s.soft_bodies,
            &mut s.ccd_solver,
            &(),
            &(),
        );
        self.engine.steps += 1;
        self.engine.seconds += started.elapsed().as_secs_f64();
        self.measure_interaction();
    }

    /// Steps taken and time spent inside Rapier's pipeline by this world so far (the clock is
    /// not part of the simulated state: [`Self::restore_from`] and [`Self::set_state`] keep it).
    pub fn engine_clock(&self) -> EngineClock {
        self.engine
    }

    /// One step under the velocity command `u` (projected onto the velocity limits); writes the
    /// state after the step into `x` (nx). For the servo drives of the rollout model.
    ///
    /// The object's velocity in `x` is the rate at which it moved over the step. With 15 ms steps
    /// the proxies are placed a little inside what they push, and Rapier moves the object out by
    /// position correction, a velocity it discards after the step; the joint's dry-friction row then
    /// leaves a velocity of the wrong sign (a door pulled open at 0.18 rad/s read −0.07 rad/s, with 1
    /// to 8 solver iterations alike; without dry friction the two agree). The engine keeps its own
    /// velocity: writing the displacement rate back changes the contact dynamics (the door coasts
    /// between steps) and with them the closed loop, whose plans were validated without it.
    pub fn step_once(&mut self, u: &[f64], x: &mut [f64]) {
        self.set_velocity_command(u);
        self.record_object_coords();
        self.step();
        self.read_state(x);
        let (nq, no) = (self.layout.nq, self.layout.no);
        let dt = self.params.dt;
        for (i, before) in self.object_coords.iter().enumerate() {
            x[2 * nq + no + i] = (x[2 * nq + i] - before) / dt;
        }
    }

    fn record_object_coords(&mut self) {
        let (mb, _) = self.state.multibody_joints.get(self.layout.object_handle).expect("object");
        self.object_coords.clear();
        for d in &self.layout.object_dofs {
            self.object_coords.push(d.value(mb));
        }
    }

    /// True when the object is at rest and statically held (dry friction at least its gravity
    /// torque, or gravity pressing it onto a limit), and no robot contact body can reach any object
    /// link within this step (bounding spheres, with the contact prediction distance and each
    /// body's travel as margin). The robot frames must be those of the step's start (placed proxies).
    fn quiescent(&mut self) -> bool {
        let (nq, no) = (self.layout.nq, self.layout.no);
        let mut x = std::mem::take(&mut self.scratch);
        x.resize(2 * (nq + no), 0.0);
        self.read_state(&mut x);
        let o = &x[2 * nq..2 * nq + no];
        let od = &x[2 * nq + no..];
        let at_rest = od.iter().all(|v| v.abs() < 1e-9);
        let mut quiet = at_rest;
        if quiet {
            // Rest is kept only if no generalized force beats the dry friction, or a limit takes it.
            let g = crate::model::dynamics::gravity_torque(&self.scene.object, &self.scene.object_pose, o, &Vector3::new(0.0, 0.0, -9.81));
            let limits = self.scene.object_limits();
            for i in 0..no {
                // g is the torque that holds the object still; gravity itself pushes with −g.
                let push = -g[i];
                let held_by_friction = push.abs() <= self.layout.object_friction[i];
                let on_lower = o[i] <= limits[i].lower + 1e-6 && push <= 0.0;
                let on_upper = o[i] >= limits[i].upper - 1e-6 && push >= 0.0;
                if !(held_by_friction || on_lower || on_upper) {
                    quiet = false;
                }
            }
        }
        if quiet {
            let frames = &self.dynamics.frames; // robot frames at the step's start (place_proxies)
            let object_poses = self.scene.object.link_poses(&self.scene.object_pose, o);
            let dt = self.params.dt;
            let margin = self.params.normalized_prediction_distance * self.params.length_unit + 0.02;
            for &(link, center, radius) in &self.layout.robot_spheres {
                let c = frames.poses[link] * center;
                let nearest = self
                    .layout
                    .object_shapes
                    .iter()
                    .map(|(olink, origin, shape)| distance_to_shape(&(object_poses[*olink] * origin), shape, &c))
                    .fold(f64::INFINITY, f64::min);
                if nearest >= radius + margin {
                    // Travel bound of this body over the step: its link's linear speed at the
                    // centre (only needed when the static clearance does not already decide).
                    let mut jac = std::mem::take(&mut self.jacobian);
                    self.scene.robot.frames_jacobian_into(frames, link, &c, &mut jac);
                    let mut v = Vector3::zeros();
                    for (col, &rate) in self.state.robot_qd.iter().enumerate() {
                        v += Vector3::new(jac[6 * col], jac[6 * col + 1], jac[6 * col + 2]) * rate;
                    }
                    self.jacobian = jac;
                    if nearest >= radius + v.norm() * dt + margin {
                        continue;
                    }
                }
                quiet = false;
                break;
            }
        }
        self.scratch = x;
        quiet
    }

    /// Interaction measured in the last step.
    pub fn interaction(&self) -> &Interaction {
        &self.state.last
    }

    /// Every robot–object contact point that carried force in the last step, with the force on
    /// the robot; for diagnosing what the robot touches (allocates, not for the hot path).
    pub fn contacts(&self) -> Vec<ContactReport> {
        let mut out = Vec::new();
        let inv_dt = 1.0 / self.params.dt;
        for pair in self.state.narrow_phase.contact_pairs() {
            let (Some(c1), Some(c2)) = (self.state.colliders.get(pair.collider1), self.state.colliders.get(pair.collider2)) else {
                continue;
            };
            let owner = |c: &Collider| c.user_data & !0xffff_ffff_ffff_ffff;
            let index = |c: &Collider| (c.user_data & 0xffff_ffff) as usize;
            let (robot_link, object_link, robot_is_first) = match (owner(c1), owner(c2)) {
                (OWNER_ROBOT, OWNER_OBJECT) => (index(c1), index(c2), true),
                (OWNER_OBJECT, OWNER_ROBOT) => (index(c2), index(c1), false),
                _ => continue,
            };
            for manifold in pair.solver_manifolds() {
                for sc in manifold.data.solver_contacts.iter() {
                    let Some((p, force)) = Self::contact_force(manifold, sc, &self.state.bodies, robot_is_first, inv_dt) else {
                        continue;
                    };
                    out.push(ContactReport {
                        robot_link,
                        object_link,
                        point: [p.x, p.y, p.z],
                        force: [force.x, force.y, force.z],
                    });
                }
            }
        }
        out
    }

    /// Point and force on the robot of one solver contact, or None if it carried no impulse.
    fn contact_force(
        manifold: &ContactManifold,
        sc: &SolverContact,
        bodies: &RigidBodySet,
        robot_is_first: bool,
        inv_dt: f64,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let contact_index = (sc.contact_id[0] & !NEW_CONTACT_BIT) as usize;
        let point = manifold.points.get(contact_index)?;
        let normal_impulse = point.data.impulse;
        let tangent_impulse = point.data.warmstart_tangent_world;
        if normal_impulse <= 0.0 && tangent_impulse.length_squared() == 0.0 {
            return None;
        }
        // The normal points from the first collider to the second; the normal impulse pushes the
        // first collider back along −normal.
        let on_first = -(manifold.data.normal * normal_impulse) + tangent_impulse;
        let impulse = if robot_is_first { on_first } else { -on_first };
        let (p1, p2) = manifold.data.solver_contact_world_points(sc, bodies);
        Some((vec_from_rapier((p1 + p2) * 0.5), vec_from_rapier(impulse * inv_dt)))
    }

    fn measure_interaction(&mut self) {
        let nq = self.layout.nq;
        let mut last = std::mem::replace(
            &mut self.state.last,
            Interaction {
                contact: false,
                tau_ext: Vec::new(),
                wrench: [0.0; 6],
            },
        );
        last.contact = false;
        last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        last.wrench = [0.0; 6];
        let inv_dt = 1.0 / self.params.dt;
        let mut poses_ready = false;
        for pair in self.state.narrow_phase.contact_pairs() {
            let (Some(c1), Some(c2)) = (self.state.colliders.get(pair.collider1), self.state.colliders.get(pair.collider2)) else {
                continue;
            };
            let owner = |c: &Collider| c.user_data & !0xffff_ffff_ffff_ffff;
            // The robot may be either side of the pair; forces are taken as acting on the robot.
            let (robot_link, robot_is_first) = match (owner(c1), owner(c2)) {
                (OWNER_ROBOT, OWNER_OBJECT) => ((c1.user_data & 0xffff_ffff) as usize, true),
                (OWNER_OBJECT, OWNER_ROBOT) => ((c2.user_data & 0xffff_ffff) as usize, false),
                _ => continue,
            };
            for manifold in pair.solver_manifolds() {
                for sc in manifold.data.solver_contacts.iter() {
                    let Some((p, force)) = Self::contact_force(manifold, sc, &self.state.bodies, robot_is_first, inv_dt) else {
                        continue;
                    };
                    last.contact = true;
                    if !poses_ready {
                        let mut q = std::mem::take(&mut self.scratch);
                        q.resize(nq, 0.0);
                        self.read_robot_q(&mut q);
                        self.scene.robot.update_frames(&Isometry3::identity(), &q, &mut self.dynamics.frames);
                        self.scratch = q;
                        poses_ready = true;
                    }
                    let point = Point3::from(p);
                    let frames = &self.dynamics.frames;
                    self.scene.robot.frames_jacobian_into(frames, robot_link, &point, &mut self.jacobian);
                    for (c, t) in last.tau_ext.iter_mut().enumerate() {
                        let col = &self.jacobian[6 * c..6 * c + 3];
                        *t += col[0] * force.x + col[1] * force.y + col[2] * force.z;
                    }
                    if self.layout.sensor_links[robot_link] {
                        let sensor = frames.poses[self.layout.sensor_link].translation.vector;
                        let torque = (p - sensor).cross(&force);
                        for (w, v) in last.wrench.iter_mut().zip([force.x, force.y, force.z, torque.x, torque.y, torque.z]) {
                            *w += v;
                        }
                    }
                }
            }
        }
        self.state.last = last;
    }

    /// Cost of the last step, which led to state `x` under command `u`.
    pub fn step_cost(&mut self, cost: &Cost, x: &[f64], u: &[f64]) -> f64 {
        let interaction = &self.state.last;
        let (nq, no) = (self.layout.nq, self.layout.no);
        let robot_frames = &mut self.dynamics.frames;
        let object_frames = &mut self.object_frames;
        self.scene.robot.update_frames(&Isometry3::identity(), &x[..nq], robot_frames);
        if cost.needs_object_frames() {
            self.scene.object.update_frames(&self.scene.object_pose, &x[2 * nq..2 * nq + no], object_frames);
        }
        cost.step(
            &self.scene,
            &StepView {
                x,
                u,
                tau_ext: &interaction.tau_ext,
                contact: interaction.contact,
                robot: robot_frames,
                object: object_frames,
            },
        )
    }

    fn read_robot_q(&self, q: &mut [f64]) {
        match self.layout.robot_handle {
            Some(handle) => {
                let (robot, _) = self.state.multibody_joints.get(handle).expect("robot");
                for (i, d) in self.layout.robot_dofs.iter().enumerate() {
                    q[i] = d.value(robot);
                }
            }
            None => q.copy_from_slice(&self.state.robot_q),
        }
    }
}
