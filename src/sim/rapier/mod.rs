//! Rapier's contact path: one robot and one articulated object in Rapier's whole pipeline (the
//! plant, and the rollout model's reference contact path). This file holds its types (configuration,
//! layout, mutable physics state) and the conversions the other files share. What each part of the
//! world does lives beside it: `build` (construction), `servo` (driving the robot and setting or
//! reading the state), `step` (one step, the quiescence test that skips it, and its evaluation) and
//! `contacts` (τ_ext, the wrist wrench and contact reports from Rapier's contact pairs).

mod build;
mod contacts;
mod servo;
mod step;

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Vector3};
use rapier3d_f64::prelude::*;

use crate::model::dynamics::DynamicsWorkspace;
use crate::model::kinematics::Frames;
use crate::model::scene::Scene;
use crate::sim::engine_clock::EngineClock;
use crate::sim::interaction::Interaction;
use crate::sim::quiescence::Quiescence;
use crate::sim::servo::{ServoLimits, ServoState};

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
    KinematicServo {
        bandwidth: f64,
        integral_gain: f64,
        integral_limit: f64,
        skip_quiescent: bool,
    },
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
    /// Acceleration, velocity and position bounds of the robot's joints.
    servo_limits: ServoLimits,
    robot_handle: Option<MultibodyJointHandle>,
    object_handle: MultibodyJointHandle,
    robot_dofs: Vec<DofRef>,
    object_dofs: Vec<DofRef>,
    effort_limits: Vec<f64>,
    /// Robot links whose contact forces the wrist force-torque sensor measures.
    pub sensor_links: Vec<bool>,
    pub sensor_link: usize,
    /// The quiescence test's geometry and the object's dry friction.
    quiescence: Quiescence,
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
    /// The robot when it is a kinematic servo; for the multibody servo only its command is used.
    servo: ServoState,
    /// Interaction measured in the last step.
    last: Interaction,
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
