//! The reduced-order rollout model and its data-parallel batch rollouts (rows handed out to the
//! calling thread and a rayon pool, longest first; one world per worker).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::evaluator::StepEvaluator;
use super::rapier::{RobotColliders, RobotDrive, SimWorld, WorldConfig};
use super::reduced::{ReducedConfig, ReducedWorld};
use super::rollout_world::RolloutWorld;
use super::servo::ServoGains;
use crate::error::{ensure_finite, Result, SabreError};
use crate::interrupt::Cancel;
use crate::model::scene::Scene;
pub use batch::RolloutBatch;
use pool::run_on_slots;
pub use pool::{default_threads, MAX_CACHED_POOLS, MAX_THREADS};
use rows::{Inputs, Row, RowInput, Rows, ScratchTrajectory, Stop, Trajectory};

mod batch;
mod pool;
mod rows;

/// How the rollout model resolves the contacts between the robot's contact bodies and the object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContactModel {
    /// Contacts from parry's manifolds and one small soft-contact solve in sabre against the
    /// object's joint coordinates ([`ReducedWorld`]).
    Reduced,
    /// Rapier's whole pipeline (broad and narrow phase, islands, the object as a multibody): the
    /// reference the reduced path is validated against, several times slower in contact.
    Rapier,
}

impl ContactModel {
    /// Every contact path, the default first.
    pub const ALL: [ContactModel; 2] = [ContactModel::Reduced, ContactModel::Rapier];

    /// The path's name in configurations: "reduced" or "rapier".
    pub fn name(self) -> &'static str {
        match self {
            ContactModel::Reduced => "reduced",
            ContactModel::Rapier => "rapier",
        }
    }

    /// The path of that name; an invalid value naming the choices otherwise.
    pub fn from_name(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name).ok_or_else(|| {
            let names: Vec<_> = Self::ALL.iter().map(|m| format!("'{}'", m.name())).collect();
            SabreError::invalid("contact_model", format!("must be one of {}, got '{name}'", names.join(", ")))
        })
    }
}

/// Settings of the rollout model.
#[derive(Debug, Clone, PartialEq)]
pub struct RolloutConfig {
    /// Step of the rollout model (the paper uses 0.015 s).
    pub dt: f64,
    /// Closed-loop bandwidth (1/s) of the joint velocity servo (57): a first-order lag 1/bandwidth.
    pub servo_bandwidth: f64,
    /// Integral gain Λ_I (1/s²) of the servo and the bound on its accumulated error (rad or m); the
    /// same PI structure as the plant's low-level controller, so contact loads are held, not yielded to.
    pub servo_integral_gain: f64,
    pub servo_integral_limit: f64,
    /// Simulate the servo loop with Rapier's multibody solver instead of the joint-space kinematic
    /// servo: higher fidelity to robot compliance in contact, several times slower.
    pub multibody_robot: bool,
    /// Skip the physics step while the object is statically held and out of the robot's reach
    /// (its state cannot change then); off, every step goes through Rapier.
    pub skip_quiescent_steps: bool,
    pub contact_friction: f64,
    /// Solver iterations per step: substeps of Rapier's TGS solver on the Rapier path, sweeps of
    /// the position-correcting solve on the reduced path. Both warm-start each contact from its
    /// impulse of the previous step, and one iteration holds a hooked handle at 15 ms steps; each
    /// further one adds to the cost of every contact step.
    pub solver_iterations: usize,
    /// Which contact path the model steps (the multibody robot needs [`ContactModel::Rapier`]).
    pub contact_model: ContactModel,
    /// Per robot joint, the largest acceleration (rad/s² or m/s²) the robot's command path gives it
    /// (a trajectory's or a command stream's bound, a base driver's ramp): the servo tracks the
    /// commands rate-limited at it; None: as given (a plant driven directly). A plan from a model
    /// faster than the command path asks one joint group for what it cannot follow while another
    /// follows at once.
    pub command_acceleration: Option<Vec<f64>>,
}

impl Default for RolloutConfig {
    fn default() -> Self {
        Self {
            dt: 0.015,
            servo_bandwidth: 40.0,
            servo_integral_gain: 400.0,
            servo_integral_limit: 0.1,
            multibody_robot: false,
            skip_quiescent_steps: true,
            contact_friction: 0.2,
            solver_iterations: 1,
            contact_model: ContactModel::Reduced,
            command_acceleration: None,
        }
    }
}

/// Batch rollouts of the reduced-order model from one initial state.
pub struct RolloutModel {
    scene: Arc<Scene>,
    config: RolloutConfig,
    template: RolloutWorld,
    /// Worlds handed to workers; each is restored from `template` before every rollout.
    worlds: Mutex<Vec<RolloutWorld>>,
    /// A world per worker slot of a batch (slot 0: the calling thread): a worker keeps the world it
    /// used last, whose memory is still in its core's caches, instead of one another core left on
    /// the shared stack.
    by_slot: Vec<Mutex<Option<RolloutWorld>>>,
    /// Each row's wall time (s) in the last batch of more than one row (see `row_order`).
    row_seconds: Mutex<Vec<f64>>,
    /// Per joint (robot, then object) the speed beyond which a rollout has diverged.
    speed_bounds: Vec<f64>,
}

/// Upper bound on the values in one output array of a batch (2^28 doubles = 2 GiB).
pub const MAX_BATCH_ELEMENTS: usize = 1 << 28;

impl RolloutModel {
    pub fn new(scene: Arc<Scene>, config: RolloutConfig) -> Result<Self> {
        if config.solver_iterations == 0 {
            return Err(SabreError::invalid("solver_iterations", "must be at least 1"));
        }
        for (name, v) in [
            ("contact_friction", config.contact_friction),
            ("servo_integral_gain", config.servo_integral_gain),
            ("servo_integral_limit", config.servo_integral_limit),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SabreError::invalid(name, format!("must be finite and non-negative, got {v}")));
            }
        }
        let mut template = match config.contact_model {
            ContactModel::Rapier => {
                let world_config = WorldConfig {
                    dt: config.dt,
                    colliders: RobotColliders::Links(scene.rollout_contact_links.clone()),
                    drive: if config.multibody_robot {
                        RobotDrive::MultibodyServo {
                            bandwidth: config.servo_bandwidth,
                        }
                    } else {
                        RobotDrive::KinematicServo {
                            bandwidth: config.servo_bandwidth,
                            integral_gain: config.servo_integral_gain,
                            integral_limit: config.servo_integral_limit,
                            skip_quiescent: config.skip_quiescent_steps,
                        }
                    },
                    contact_friction: config.contact_friction,
                    solver_iterations: config.solver_iterations,
                };
                RolloutWorld::Rapier(Box::new(SimWorld::new(scene.clone(), &world_config)?))
            }
            ContactModel::Reduced if config.multibody_robot => {
                return Err(SabreError::invalid(
                    "multibody_robot",
                    "the multibody robot is simulated by Rapier's pipeline: it needs contact_model 'rapier'",
                ))
            }
            ContactModel::Reduced => RolloutWorld::Reduced(Box::new(ReducedWorld::new(
                scene.clone(),
                &ReducedConfig {
                    dt: config.dt,
                    gains: ServoGains {
                        bandwidth: config.servo_bandwidth,
                        integral_gain: config.servo_integral_gain,
                        integral_limit: config.servo_integral_limit,
                    },
                    skip_quiescent: config.skip_quiescent_steps,
                    contact_friction: config.contact_friction,
                    iterations: config.solver_iterations,
                },
            )?)),
        };
        if let Some(caps) = &config.command_acceleration {
            template.cap_servo_acceleration(caps)?;
        }
        Ok(Self {
            speed_bounds: super::divergence::joint_speed_bounds(&scene)
                .into_iter()
                .map(|j| j.2)
                .collect(),
            scene,
            config,
            template,
            worlds: Mutex::new(Vec::new()),
            by_slot: (0..MAX_THREADS).map(|_| Mutex::new(None)).collect(),
            row_seconds: Mutex::new(Vec::new()),
        })
    }

    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    pub fn config(&self) -> &RolloutConfig {
        &self.config
    }

    pub fn dt(&self) -> f64 {
        self.config.dt
    }

    /// A fresh world of this model (a copy of its pristine template) for stepping one command at a
    /// time: place it with [`Self::reset_world`], advance it with [`RolloutWorld::step_once`].
    pub fn new_world(&self) -> RolloutWorld {
        self.template.clone()
    }

    /// Puts `world`, one of this model's, at state x0 with no contact history and a fresh servo.
    pub fn reset_world(&self, world: &mut RolloutWorld, x0: &[f64]) -> Result<()> {
        if !world.same_model(&self.template) {
            return Err(SabreError::invalid("world", "belongs to a different rollout model"));
        }
        self.scene.check_state(x0)?;
        world.restore_from(&self.template);
        world.set_state(x0);
        Ok(())
    }

    /// Runs `f` on a world of the pool that the batch rollouts use, placed at x0, and returns the
    /// world to the pool; repeated single-world work (Sequential FILTER-QP) builds no new world.
    /// A world whose user panicked is dropped, not returned.
    pub fn with_world<T>(&self, x0: &[f64], f: impl FnOnce(&mut RolloutWorld) -> Result<T>) -> Result<T> {
        let mut world = self.checkout();
        let result = self.reset_world(&mut world, x0).and_then(|_| f(&mut world));
        self.checkin(world);
        result
    }

    fn checkout(&self) -> RolloutWorld {
        let popped = self.worlds.lock().unwrap_or_else(|e| e.into_inner()).pop();
        popped.unwrap_or_else(|| self.template.clone())
    }

    fn checkin(&self, world: RolloutWorld) {
        self.worlds.lock().unwrap_or_else(|e| e.into_inner()).push(world);
    }

    /// The worker slot's own world (see `by_slot`), else one from the shared stack (another batch
    /// running at the same time holds it).
    fn checkout_for_slot(&self, slot: usize) -> RolloutWorld {
        let own = self
            .by_slot
            .get(slot)
            .and_then(|m| m.lock().unwrap_or_else(|e| e.into_inner()).take());
        own.unwrap_or_else(|| self.checkout())
    }

    fn checkin_for_slot(&self, slot: usize, world: RolloutWorld) {
        match self.by_slot.get(slot) {
            Some(m) => {
                let mut own = m.lock().unwrap_or_else(|e| e.into_inner());
                match own.as_ref() {
                    None => *own = Some(world),
                    Some(_) => self.checkin(world),
                }
            }
            None => self.checkin(world),
        }
    }

    /// Simulates one input sequence `u` (K × nu) from `x0`; returns the summed cost and the step
    /// at which the physics produced non-finite numbers, if it did.
    fn rollout_one(
        &self,
        world: &mut RolloutWorld,
        x0: &[f64],
        u: &[f64],
        cost: Option<&dyn StepEvaluator>,
        out: &mut Trajectory,
        stop: &mut Stop,
    ) -> (f64, Option<usize>) {
        let nx = self.scene.nx();
        let nq = self.scene.nq();
        let k = out.contact.len();
        world.restore_from(&self.template);
        world.set_state(x0);
        out.states[..nx].copy_from_slice(x0);
        let mut total = 0.0;
        for step in 0..k {
            if stop.now() {
                return (total, Some(step));
            }
            let u_step = &u[step * nq..(step + 1) * nq];
            let x = &mut out.states[(step + 1) * nx..(step + 2) * nx];
            world.step_once(u_step, x);
            #[cfg(test)]
            tests::inject_failure(u_step, x);
            // Non-finite numbers, or a joint faster than anything the actuators or the object can
            // do: the integration diverged and the rest of this rollout means nothing.
            if x.iter().any(|v| !v.is_finite())
                || super::divergence::diverged_joint(x, nq, self.scene.no(), &self.speed_bounds).is_some()
            {
                return (total, Some(step));
            }
            if let Some(cost) = cost {
                total += world.evaluate_step(cost, x, u_step);
            }
            let interaction = world.interaction();
            out.tau_ext[step * nq..(step + 1) * nq].copy_from_slice(&interaction.tau_ext);
            out.wrench[step * 6..(step + 1) * 6].copy_from_slice(&interaction.wrench);
            out.contact[step] = interaction.contact;
        }
        (total, None)
    }

    /// Runs N rollouts of K steps from `x0` (nx) with inputs `u` (N × K × nu, row-major).
    /// Inputs are projected onto the joint velocity limits. The result does not depend on `threads`.
    pub fn rollout(&self, x0: &[f64], u: &[f64], n: usize, k: usize, threads: Option<usize>) -> Result<RolloutBatch> {
        self.rollout_with_cost(x0, u, n, k, threads, None)
    }

    /// [`Self::rollout`] that also sums `cost`'s score of every step over each rollout, inside the workers.
    pub fn rollout_with_cost(
        &self,
        x0: &[f64],
        u: &[f64],
        n: usize,
        k: usize,
        threads: Option<usize>,
        cost: Option<&dyn StepEvaluator>,
    ) -> Result<RolloutBatch> {
        let mut batch = RolloutBatch::default();
        self.rollout_into(x0, u, n, k, threads, cost, &mut batch)?;
        Ok(batch)
    }

    /// [`Self::rollout_with_cost`] into `batch`, whose memory is reused (see [`RolloutBatch::prepare`]).
    #[allow(clippy::too_many_arguments)]
    pub fn rollout_into(
        &self,
        x0: &[f64],
        u: &[f64],
        n: usize,
        k: usize,
        threads: Option<usize>,
        cost: Option<&dyn StepEvaluator>,
        batch: &mut RolloutBatch,
    ) -> Result<()> {
        self.check_inputs(u, n, k)?;
        ensure_finite("U", u)?;
        self.rollout_rows(x0, Inputs::Given(u), n, k, threads, cost, true, batch)
    }

    /// [`Self::rollout_into`] of inputs that `fill(i, row)` writes into row i of `u` (K × nu) on
    /// the worker that rolls that row out, just before. `fill` must write finite values within the
    /// joint velocity limits: the rows are not checked. Rows are filled only if rolled out: after
    /// an error, some may not be. Without `trajectories`, the batch keeps each rollout's cost and
    /// flags but not its states, τ_ext, wrenches and contacts: a planner that only weighs the
    /// costs leaves the batch's trajectories (megabytes at a few hundred rollouts) unwritten, and
    /// each worker's one rollout of them in its cache.
    #[allow(clippy::too_many_arguments)]
    pub fn rollout_filled_into(
        &self,
        x0: &[f64],
        u: &mut [f64],
        fill: &(dyn Fn(usize, &mut [f64]) + Sync),
        n: usize,
        k: usize,
        threads: Option<usize>,
        cost: Option<&dyn StepEvaluator>,
        trajectories: bool,
        batch: &mut RolloutBatch,
    ) -> Result<()> {
        self.check_inputs(u, n, k)?;
        self.rollout_rows(x0, Inputs::Filled(u, fill), n, k, threads, cost, trajectories, batch)
    }

    fn check_inputs(&self, u: &[f64], n: usize, k: usize) -> Result<()> {
        let nq = self.scene.nq();
        if u.len() != n * k * nq {
            return Err(SabreError::shape(
                "U",
                format!("({n}, {k}, {nq})"),
                format!("{} elements", u.len()),
            ));
        }
        Ok(())
    }

    #[allow(clippy::too_many_arguments)]
    fn rollout_rows(
        &self,
        x0: &[f64],
        inputs: Inputs,
        n: usize,
        k: usize,
        threads: Option<usize>,
        cost: Option<&dyn StepEvaluator>,
        trajectories: bool,
        batch: &mut RolloutBatch,
    ) -> Result<()> {
        let nx = self.scene.nx();
        let nq = self.scene.nq();
        self.scene.check_state(x0)?;
        let threads = threads.unwrap_or_else(default_threads);
        if !(1..=MAX_THREADS).contains(&threads) {
            return Err(SabreError::invalid(
                "threads",
                format!("must be between 1 and {MAX_THREADS}, got {threads}"),
            ));
        }
        // Sizes come from the caller: check them before allocating, so that an absurd batch is an
        // error and not an allocation failure that aborts the process.
        let elements = n
            .checked_mul(k + 1)
            .and_then(|v| v.checked_mul(nx.max(nq).max(6)))
            .filter(|&v| v <= MAX_BATCH_ELEMENTS)
            .ok_or_else(|| {
                SabreError::invalid(
                    "U",
                    format!("a batch of {n} rollouts × {k} steps is too large (limit {MAX_BATCH_ELEMENTS} values per output)"),
                )
            })?;
        debug_assert!(elements >= n * k);
        batch.prepare(n, k, nx, nq, trajectories)?;
        if n == 0 || k == 0 {
            for state in batch.states.chunks_exact_mut(nx) {
                state.copy_from_slice(x0);
            }
            return Ok(());
        }
        if let Some(cost) = cost {
            cost.validate(&self.scene)?;
        }
        let rows = Rows::split(inputs, n, k, nq, nx, batch);
        let order = self.row_order(n);
        let next = AtomicUsize::new(0);
        let cancel = Cancel::default();
        let row_seconds: Vec<AtomicU64> = (0..n).map(|_| AtomicU64::new(0)).collect();
        let work = |slot: usize| {
            // The caller's slot also asks the embedding's watcher (Ctrl-C); the others see `cancel`.
            let mut stop = Stop::new(&cancel, slot == 0);
            let mut world = None;
            let mut scratch = ScratchTrajectory::default();
            while !stop.now() {
                let j = next.fetch_add(1, Ordering::Relaxed);
                let Some(&i) = order.get(j) else { break };
                let Some(row) = rows.take(i) else { continue };
                let started = Instant::now();
                let w = world.get_or_insert_with(|| self.checkout_for_slot(slot));
                if !self.rollout_row(w, x0, row, cost, &mut scratch, &mut stop) {
                    world = None;
                }
                row_seconds[i].store(started.elapsed().as_secs_f64().to_bits(), Ordering::Relaxed);
            }
            if let Some(w) = world {
                self.checkin_for_slot(slot, w);
            }
        };
        run_on_slots(threads.min(n), &work)?;
        if cancel.is_set() {
            return Err(SabreError::Interrupted);
        }
        if n > 1 {
            self.remember_row_seconds(row_seconds.iter().map(|s| f64::from_bits(s.load(Ordering::Relaxed))));
        }
        Ok(())
    }

    /// Rolls one row out in `world` (its trajectory into `scratch` when the batch keeps none);
    /// false if the physics panicked (the row is marked failed from its first step and the world,
    /// possibly inconsistent, must be dropped).
    fn rollout_row(
        &self,
        world: &mut RolloutWorld,
        x0: &[f64],
        row: Row,
        cost: Option<&dyn StepEvaluator>,
        scratch: &mut ScratchTrajectory,
        stop: &mut Stop,
    ) -> bool {
        let (nx, nq) = (self.scene.nx(), self.scene.nq());
        let Row {
            input,
            trajectory,
            cost: total,
            failed,
            steps,
            time,
        } = row;
        let u: &[f64] = match input {
            RowInput::Given(u) => u,
            RowInput::Filled(u, i, fill) => {
                fill(i, u);
                u
            }
        };
        let k = u.len() / nq;
        let mut out = trajectory.unwrap_or_else(|| scratch.slices(k, nx, nq));
        let clock = world.engine_clock();
        // A panic inside the physics engine must not cross into the caller.
        let (failed_at, sound) = match catch_unwind(AssertUnwindSafe(|| self.rollout_one(world, x0, u, cost, &mut out, stop))) {
            Ok((sum, result)) => {
                let after = world.engine_clock();
                *steps = after.steps - clock.steps;
                *time = after.seconds - clock.seconds;
                *total = sum;
                (result, true)
            }
            Err(_) => (Some(0), false),
        };
        if let Some(step) = failed_at {
            *failed = true;
            *total = f64::INFINITY;
            out.states[(step + 1) * nx..].fill(f64::NAN);
            out.tau_ext[step * nq..].fill(f64::NAN);
            out.wrench[step * 6..].fill(f64::NAN);
            out.contact[step..].fill(false);
        }
        sound
    }

    /// The order in which a batch of `n` rows is handed out: the rows that took longest in the
    /// last batch of that size first, so that the cheap ones fill in at the end and the threads
    /// finish together (rollouts in contact cost several times those in free space, and a row's
    /// role in a planner's batch — nominal, guide, kept sample — changes little between batches).
    fn row_order(&self, n: usize) -> Vec<usize> {
        let mut order: Vec<usize> = (0..n).collect();
        let last = self.row_seconds.lock().unwrap_or_else(|e| e.into_inner());
        if last.len() == n {
            order.sort_by(|&a, &b| last[b].total_cmp(&last[a]));
        }
        order
    }

    fn remember_row_seconds(&self, seconds: impl Iterator<Item = f64>) {
        let mut last = self.row_seconds.lock().unwrap_or_else(|e| e.into_inner());
        last.clear();
        last.extend(seconds);
    }
}

#[cfg(test)]
pub(crate) mod tests;
