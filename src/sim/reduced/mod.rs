//! The rollout model's reduced contact path: the robot's contact bodies (free proxies with the
//! robot's effective mass, driven by the joint velocity servo, as in the Rapier path) against the
//! object's joint coordinates, with contacts from parry's manifolds and one small soft-contact
//! solve in sabre per step; no physics pipeline, broad phase, islands or multibody. Rapier's
//! pipeline ([`crate::sim::SimWorld`]) stays the reference this path is validated against.

mod box_box;
mod geometry;
mod measure;
mod proxies;
mod solver;

use std::sync::Arc;
use std::time::Instant;

use nalgebra::{DMatrix, DVector, Isometry3, Point3, Vector3};

use self::geometry::{Collider, ContactKey, Detector};
use self::proxies::{proxy_bodies, ProxyBody};
use self::solver::{softness, Proxy, Solver, SolverParams, MAX_OBJECT_DOFS};
use super::engine_clock::EngineClock;
use super::evaluator::StepEvaluator;
use super::interaction::{ContactReport, Interaction};
use super::quiescence::Quiescence;
use super::servo::{validate_step, ServoGains, ServoLimits, ServoState};
use super::wrist_sensor::wrist_sensor;
use crate::error::{Result, SabreError};
use crate::model::dynamics::{joint_space_terms, DynamicsWorkspace};
use crate::model::scene::Scene;
use crate::model::GRAVITY;

/// Settings of the reduced contact path.
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedConfig {
    pub dt: f64,
    pub gains: ServoGains,
    /// Skip the contact step while the object is statically held and out of the robot's reach.
    pub skip_quiescent: bool,
    /// Coulomb friction coefficient between robot and object surfaces.
    pub contact_friction: f64,
    /// Sweeps of the position-correcting solve per step.
    pub iterations: usize,
}

/// Contacts are found up to 1 cm before the surfaces meet: a hand moving below 0.6 m/s covers
/// less than that in a 15 ms step (the Rapier path's prediction distance).
const PREDICTION: f64 = 0.01;
/// Contact stiffness: a spring of 60 Hz, critically damped (the Rapier path's contact softness),
/// which resolves what a proxy re-enters every step within a step or two at 15 ms.
const CONTACT_FREQUENCY: f64 = 60.0;
const CONTACT_DAMPING_RATIO: f64 = 1.0;
/// The fastest an overlap is pushed apart (m/s).
const MAX_CORRECTIVE_VELOCITY: f64 = 3.0;
/// Sweeps of the relaxation that leaves the object its velocity without the overlap correction.
const RELAXATION_ITERATIONS: usize = 1;
/// How much further (rad or m) than its free travel over a step a joint limit gets a row: the
/// contacts of one step would have to move the object faster than 3 rad/s or m/s to reach a limit
/// that far.
const LIMIT_REACH: f64 = 0.05;
/// Extra clearance (m) of the quiescence test beyond the prediction distance.
const QUIESCENCE_MARGIN: f64 = 0.02;

/// Static facts about a reduced world, shared by every copy of it.
#[derive(Debug)]
struct ReducedLayout {
    nq: usize,
    no: usize,
    config: ReducedConfig,
    params: SolverParams,
    servo_limits: ServoLimits,
    quiescence: Quiescence,
    proxies: Vec<ProxyBody>,
    robot_colliders: Vec<Collider>,
    /// The proxy of each robot primitive.
    collider_proxy: Vec<usize>,
    object_colliders: Vec<Collider>,
    object_damping: Vec<f64>,
    object_friction: Vec<f64>,
    object_limits: Vec<(f64, f64)>,
    sensor_link: usize,
    sensor_links: Vec<bool>,
}

/// One robot–object contact of the last step: the robot link it touched, the point in that
/// link's frame, and the object link.
#[derive(Debug, Clone, Copy)]
struct Touch {
    robot_link: usize,
    local_point: Point3<f64>,
    object_link: usize,
}

/// A world of the reduced contact path: the robot's servo state and the object's coordinates.
#[derive(Clone)]
pub struct ReducedWorld {
    /// Shared by a world and its copies; read through a borrow in the step, never cloned there
    /// (two workers counting references on one cache line slow each other's steps).
    layout: Arc<ReducedLayout>,
    state: WorldState,
}

/// Everything of a [`ReducedWorld`] a step changes, apart from the layout it reads.
#[derive(Clone)]
struct WorldState {
    scene: Arc<Scene>,
    servo: ServoState,
    o: Vec<f64>,
    od: Vec<f64>,
    last: Interaction,
    /// Contacts of the last step and the impulses they carried (N·s, on the robot, world frame).
    touches: Vec<Touch>,
    impulses: Vec<Vector3<f64>>,
    /// The contact body the quiescence test tries first (the one that failed it last).
    quiescence_first: usize,
    /// The last step's force and moment (about the link's origin) on each touched robot link.
    link_wrenches: Vec<(usize, Vector3<f64>, Vector3<f64>)>,
    /// The last step's impulse of each contact by its key: the next step's warm start.
    warm_start: Vec<(ContactKey, Vector3<f64>)>,
    /// Robot link poses (`robot.frames`) and the servo's mass-matrix buffers.
    robot: DynamicsWorkspace,
    mass_matrix: DMatrix<f64>,
    gravity_torque: DVector<f64>,
    /// Object link poses (`object.frames`) and its joint-space terms.
    object: DynamicsWorkspace,
    object_mass: DMatrix<f64>,
    object_gravity: DVector<f64>,
    inverse_mass: DMatrix<f64>,
    detector: Detector,
    /// The contact solve, sized for one object joint (no padding in its rows) or for up to
    /// [`MAX_OBJECT_DOFS`]; a world uses the one that fits its object.
    solver_one: Solver<1>,
    solver_many: Solver<MAX_OBJECT_DOFS>,
    jacobian: Vec<f64>,
    linear_jacobian: Vec<f64>,
    /// The object's coordinates at the step's start, and its velocity before the contacts act.
    o_before: Vec<f64>,
    free_velocity: Vec<f64>,
    engine: EngineClock,
}

impl ReducedWorld {
    /// Builds the world once; copies of it are reset, never rebuilt.
    pub fn new(scene: Arc<Scene>, config: &ReducedConfig) -> Result<Self> {
        validate_step(config.dt, Some(config.gains.bandwidth))?;
        let (nq, no) = (scene.nq(), scene.no());
        if no > MAX_OBJECT_DOFS {
            return Err(SabreError::invalid(
                "contact_model",
                format!("the reduced contact path takes objects of at most {MAX_OBJECT_DOFS} movable joints, this one has {no}; use 'rapier'"),
            ));
        }
        let mut contact_links = vec![false; scene.robot.links.len()];
        scene.rollout_contact_links.iter().for_each(|&l| contact_links[l] = true);
        let robot_colliders = Collider::of_tree(&scene.robot, &|l| contact_links[l]);
        let (proxies, collider_proxy) = proxy_bodies(&scene, &robot_colliders);
        let object_colliders = Collider::of_tree(&scene.object, &|_| true);
        let object_joints: Vec<_> = scene.object.active_joints.iter().map(|&j| &scene.object.joints[j]).collect();
        let (erp_inv_dt, cfm_factor) = softness(CONTACT_FREQUENCY, CONTACT_DAMPING_RATIO, config.dt);
        let (sensor_link, sensor_links) = wrist_sensor(&scene);
        let layout = ReducedLayout {
            nq,
            no,
            params: SolverParams {
                dt: config.dt,
                erp_inv_dt,
                cfm_factor,
                max_corrective_velocity: MAX_CORRECTIVE_VELOCITY,
                limit_erp_inv_dt: 1.0 / config.dt,
                iterations: config.iterations.max(1),
                relaxation_iterations: RELAXATION_ITERATIONS,
            },
            config: config.clone(),
            servo_limits: ServoLimits::new(&scene)?,
            quiescence: Quiescence::new(&scene, &|l| contact_links[l]),
            proxies,
            robot_colliders,
            collider_proxy,
            object_colliders,
            object_damping: object_joints.iter().map(|j| j.damping).collect(),
            object_friction: object_joints.iter().map(|j| j.friction).collect(),
            object_limits: object_joints.iter().map(|j| (j.limits.lower, j.limits.upper)).collect(),
            sensor_link,
            sensor_links,
        };
        let mut world = Self {
            layout: Arc::new(layout),
            state: WorldState {
                servo: ServoState::new(nq),
                o: vec![0.0; no],
                od: vec![0.0; no],
                last: Interaction {
                    contact: false,
                    tau_ext: vec![0.0; nq],
                    wrench: [0.0; 6],
                },
                touches: Vec::new(),
                impulses: Vec::new(),
                link_wrenches: Vec::new(),
                quiescence_first: 0,
                warm_start: Vec::new(),
                robot: DynamicsWorkspace::default(),
                mass_matrix: DMatrix::zeros(nq, nq),
                gravity_torque: DVector::zeros(nq),
                object: DynamicsWorkspace::default(),
                object_mass: DMatrix::zeros(no, no),
                object_gravity: DVector::zeros(no),
                inverse_mass: DMatrix::zeros(no, no),
                detector: Detector::default(),
                solver_one: Solver::default(),
                solver_many: Solver::default(),
                jacobian: vec![0.0; 6 * nq],
                linear_jacobian: vec![0.0; 3 * no],
                o_before: Vec::with_capacity(no),
                free_velocity: Vec::with_capacity(no),
                engine: EngineClock::default(),
                scene: scene.clone(),
            },
        };
        world.set_state(&scene.default_state());
        Ok(world)
    }

    pub fn scene(&self) -> &Scene {
        &self.state.scene
    }

    pub fn dt(&self) -> f64 {
        self.layout.config.dt
    }

    /// Rate-limits the servo's commands (see [`ServoLimits::cap_acceleration`]); before the
    /// world is copied (its copies share the layout). Errors: a bad bound, or a world already copied.
    pub fn cap_servo_acceleration(&mut self, caps: &[f64]) -> crate::error::Result<()> {
        let dt = self.dt();
        Arc::get_mut(&mut self.layout)
            .ok_or_else(|| crate::error::SabreError::invalid("command_acceleration", "set before the world is copied"))?
            .servo_limits
            .cap_acceleration(caps, dt)
    }

    /// Whether `other` is a copy of this world (built together, sharing one layout).
    pub fn same_layout(&self, other: &ReducedWorld) -> bool {
        Arc::ptr_eq(&self.layout, &other.layout)
    }

    /// Takes the state of `snapshot`; nothing of what this world simulated before remains.
    pub fn restore_from(&mut self, snapshot: &ReducedWorld) {
        self.state.restore_from(&snapshot.state);
    }

    /// Places robot and object at state x = [q, q̇, o, ȯ] (x must be validated by the caller),
    /// with a fresh servo and no contact history.
    pub fn set_state(&mut self, x: &[f64]) {
        self.state.set_state(&self.layout, x);
    }

    /// Writes the current state into `x` (length nx): the object's velocity is the one the solve
    /// left it (see [`Self::step_once`], which reports its displacement rate instead).
    pub fn read_state(&self, x: &mut [f64]) {
        self.state.read_state(&self.layout, x);
    }

    /// One step under the velocity command `u` (projected onto the velocity limits); writes the
    /// state after the step into `x` (nx), the object's velocity being the rate at which it moved
    /// over the step (as in the Rapier path).
    pub fn step_once(&mut self, u: &[f64], x: &mut [f64]) {
        self.state.step_once(&self.layout, u, x);
    }

    /// Advances one step under the current command and measures its interaction.
    pub fn step(&mut self) {
        self.state.step(&self.layout);
    }

    /// Interaction measured in the last step.
    pub fn interaction(&self) -> &Interaction {
        &self.state.last
    }

    /// Every robot–object contact point that carried force in the last step, with the force on
    /// the robot (allocates; for diagnosis).
    pub fn contacts(&self) -> Vec<ContactReport> {
        self.state.contacts(&self.layout)
    }

    /// Steps that went through the contact solve and the time spent in them (detection, solve
    /// and integration), since the world was built.
    pub fn engine_clock(&self) -> EngineClock {
        self.state.engine
    }

    /// `evaluator`'s value of the last step, which led to state `x` under command `u` (frames from
    /// the world's caches, as in the Rapier path).
    pub fn evaluate_step(&mut self, evaluator: &dyn StepEvaluator, x: &[f64], u: &[f64]) -> f64 {
        self.state.evaluate_step(&self.layout, evaluator, x, u)
    }
}

impl WorldState {
    /// [`ReducedWorld::restore_from`].
    fn restore_from(&mut self, snapshot: &WorldState) {
        self.servo.clone_from(&snapshot.servo);
        self.o.clone_from(&snapshot.o);
        self.od.clone_from(&snapshot.od);
        self.last.clone_from(&snapshot.last);
        self.touches.clone_from(&snapshot.touches);
        self.impulses.clone_from(&snapshot.impulses);
        self.warm_start.clone_from(&snapshot.warm_start);
        self.detector.restore_from(&snapshot.detector);
    }

    /// [`ReducedWorld::set_state`].
    fn set_state(&mut self, layout: &ReducedLayout, x: &[f64]) {
        let (nq, no) = (layout.nq, layout.no);
        self.servo.reset(&x[..nq], &x[nq..2 * nq]);
        self.o.copy_from_slice(&x[2 * nq..2 * nq + no]);
        self.od.copy_from_slice(&x[2 * nq + no..2 * (nq + no)]);
        self.clear_interaction();
    }

    fn clear_interaction(&mut self) {
        self.last.contact = false;
        self.last.tau_ext.iter_mut().for_each(|v| *v = 0.0);
        self.last.wrench = [0.0; 6];
        self.touches.clear();
        self.impulses.clear();
        self.warm_start.clear();
        self.detector.reset();
    }

    /// [`ReducedWorld::read_state`].
    fn read_state(&self, layout: &ReducedLayout, x: &mut [f64]) {
        let (nq, no) = (layout.nq, layout.no);
        x[..nq].copy_from_slice(&self.servo.q);
        x[nq..2 * nq].copy_from_slice(&self.servo.qd);
        x[2 * nq..2 * nq + no].copy_from_slice(&self.o);
        x[2 * nq + no..2 * (nq + no)].copy_from_slice(&self.od);
    }

    /// [`ReducedWorld::step_once`].
    fn step_once(&mut self, layout: &ReducedLayout, u: &[f64], x: &mut [f64]) {
        self.servo.set_command(u, &layout.servo_limits);
        self.o_before.clone_from(&self.o);
        self.step(layout);
        self.read_state(layout, x);
        let (nq, no) = (layout.nq, layout.no);
        for (i, b) in self.o_before.iter().enumerate() {
            x[2 * nq + no + i] = (self.o[i] - b) / layout.config.dt;
        }
    }

    /// [`ReducedWorld::step`].
    fn step(&mut self, layout: &ReducedLayout) {
        let dt = layout.config.dt;
        self.servo.advance(
            &layout.config.gains,
            &layout.servo_limits,
            &self.scene,
            &self.last.tau_ext,
            dt,
            &mut self.robot,
            &mut self.mass_matrix,
            &mut self.gravity_torque,
        );
        // The contact bodies start the step where the robot is, moving as it will move in it.
        self.scene
            .robot
            .update_frames(&Isometry3::identity(), &self.servo.q, &mut self.robot.frames);
        if layout.config.skip_quiescent
            && layout.quiescence.holds(
                &self.scene,
                &self.robot.frames,
                &self.servo.qd,
                &self.o,
                &self.od,
                dt,
                PREDICTION + QUIESCENCE_MARGIN,
                &mut self.jacobian,
                &mut self.quiescence_first,
            )
        {
            // Nothing can touch the object and it is held at rest: the step cannot move it.
            self.servo.commit();
            self.clear_interaction();
            return;
        }
        let started = Instant::now();
        self.solve_contacts(layout);
        self.engine.steps += 1;
        self.engine.seconds += started.elapsed().as_secs_f64();
        self.servo.commit();
        self.measure_interaction(layout);
    }

    /// Detection, the solve and the object's integration over one step.
    fn solve_contacts(&mut self, layout: &ReducedLayout) {
        // The solver moves out of the state for the step (its buffers with it) and back.
        if layout.no == 1 {
            let mut solver = std::mem::take(&mut self.solver_one);
            self.solve_contacts_with(layout, &mut solver);
            self.solver_one = solver;
        } else {
            let mut solver = std::mem::take(&mut self.solver_many);
            self.solve_contacts_with(layout, &mut solver);
            self.solver_many = solver;
        }
    }

    fn solve_contacts_with<const N: usize>(&mut self, layout: &ReducedLayout, solver: &mut Solver<N>) {
        let (no, dt) = (layout.no, layout.config.dt);
        let scene = &self.scene;
        joint_space_terms(
            &scene.object,
            &scene.object_pose,
            &self.o,
            &GRAVITY,
            &mut self.object,
            &mut self.object_mass,
            &mut self.object_gravity,
        );
        // Damping is implicit: (M + dt D) ȯ⁺ = M ȯ + dt (−g) with g the torque that holds the
        // object against gravity.
        self.inverse_mass.copy_from(&self.object_mass);
        for i in 0..no {
            self.inverse_mass[(i, i)] += dt * layout.object_damping[i];
        }
        if !self.inverse_mass.try_inverse_mut() {
            self.inverse_mass.fill(0.0);
        }
        let free = &mut self.free_velocity;
        free.clear();
        for a in 0..no {
            let mut v = self.od[a];
            for b in 0..no {
                let force = -self.object_gravity[b] - layout.object_damping[b] * self.od[b];
                v += dt * self.inverse_mass[(a, b)] * force;
            }
            free.push(v);
        }
        // nalgebra's DMatrix is column-major; the solver takes it row-major (it is symmetric).
        solver.begin(free, self.inverse_mass.as_slice());
        let frames = &self.robot.frames;
        for body in &layout.proxies {
            let pose = frames.poses[body.link];
            let com = pose * body.com;
            let (v, w) = scene.robot.frames_point_velocity(frames, body.link, &com, &self.servo.qd);
            let r = pose.rotation.to_rotation_matrix();
            solver.proxies.push(Proxy {
                inv_mass: body.inv_mass,
                inv_inertia: r.matrix() * body.inv_inertia * r.matrix().transpose(),
                com,
                v,
                w,
            });
        }
        self.detector.detect(
            &layout.robot_colliders,
            &layout.object_colliders,
            frames,
            &self.object.frames,
            PREDICTION,
        );
        self.touches.clear();
        for (index, contact) in self.detector.contacts.iter().enumerate() {
            let object_link = layout.object_colliders[contact.object].link;
            if layout.object_colliders[contact.object].moves {
                scene.object.frames_linear_jacobian_into(
                    &self.object.frames,
                    object_link,
                    &contact.point,
                    &mut self.linear_jacobian,
                );
            } else {
                self.linear_jacobian.fill(0.0);
            }
            // A contact that persists mostly keeps its place in the list: look there first.
            let warm = match self.warm_start.get(index) {
                Some((key, impulse)) if *key == contact.key => Some(*impulse),
                _ => self
                    .warm_start
                    .iter()
                    .find(|(key, _)| *key == contact.key)
                    .map(|(_, impulse)| *impulse),
            };
            solver.add_contact(
                &layout.params,
                layout.collider_proxy[contact.robot],
                &contact.point,
                &contact.normal,
                contact.dist,
                &self.linear_jacobian,
                layout.config.contact_friction,
                warm,
            );
            let robot_link = layout.robot_colliders[contact.robot].link;
            self.touches.push(Touch {
                robot_link,
                local_point: frames.poses[robot_link].inverse_transform_point(&contact.point),
                object_link,
            });
        }
        for i in 0..no {
            // A limit further than the step's free travel plus LIMIT_REACH cannot be reached within
            // the step; its row would never bind.
            let (lower, upper) = layout.object_limits[i];
            let reach = self.free_velocity[i].abs() * dt + LIMIT_REACH;
            for (is_lower, distance) in [(true, self.o[i] - lower), (false, upper - self.o[i])] {
                if distance < reach {
                    solver.add_limit(&layout.params, i, is_lower, distance);
                }
            }
            if layout.object_friction[i] > 0.0 {
                solver.add_dry_friction(i, layout.object_friction[i] * dt);
            }
        }
        solver.solve(&layout.params);
        for (o, od) in self.o.iter_mut().zip(solver.object_velocity()) {
            *o += dt * od;
        }
        solver.relax(&layout.params);
        self.od.copy_from_slice(solver.object_velocity());
        self.impulses.clear();
        self.impulses.extend(solver.contact_impulses());
        self.warm_start.clear();
        self.warm_start.extend(
            self.detector
                .contacts
                .iter()
                .zip(&self.impulses)
                .map(|(contact, impulse)| (contact.key, *impulse)),
        );
    }
}

#[cfg(test)]
mod tests;
