//! The reduced-order rollout model and its data-parallel batch rollouts (rayon, one world per worker).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::{Arc, Mutex};

use rayon::iter::Either;
use rayon::prelude::*;

use super::evaluator::StepEvaluator;
use super::rapier::{RobotColliders, RobotDrive, SimWorld, WorldConfig};
use super::reduced::{ReducedConfig, ReducedWorld};
use super::rollout_world::RolloutWorld;
use super::servo::ServoGains;
use crate::error::{ensure_finite, Result, SabreError};
use crate::interrupt::Cancel;
use crate::model::scene::Scene;
use pool::pool;
pub use pool::{default_threads, MAX_CACHED_POOLS, MAX_THREADS};

mod pool;

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
        }
    }
}

/// Results of N rollouts of K steps, row-major in (N, K[+1], ·).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RolloutBatch {
    pub n: usize,
    pub k: usize,
    pub nx: usize,
    pub nq: usize,
    /// (N, K+1, nx); entry 0 of each rollout is x0.
    pub states: Vec<f64>,
    /// (N, K, nq)
    pub tau_ext: Vec<f64>,
    /// (N, K, 6)
    pub wrench: Vec<f64>,
    /// (N, K)
    pub contact: Vec<bool>,
    /// (N,) rollouts whose physics failed; their outputs are NaN from the failing step on.
    pub failed: Vec<bool>,
    /// (N,) accumulated cost of each rollout (zero without a cost; +∞ for failed rollouts).
    pub costs: Vec<f64>,
    /// (N,) steps of each rollout that went through Rapier's pipeline; the others were skipped
    /// because nothing could move the object (see [`RolloutConfig::skip_quiescent_steps`]).
    pub engine_steps: Vec<u64>,
    /// (N,) wall time each rollout spent inside Rapier's pipeline (s); the rest of its time is the
    /// servo, the contact measurement and the cost.
    pub engine_time: Vec<f64>,
}

impl RolloutBatch {
    /// Sizes the batch for `n` rollouts of `k` steps, keeping its buffers' memory: a planner that
    /// reuses one batch allocates (and the OS maps and zeroes) nothing per iteration. The states,
    /// τ_ext, wrenches and contacts are left as they were (every rollout writes all of its own);
    /// the per-rollout flags and totals start from zero.
    fn prepare(&mut self, n: usize, k: usize, nx: usize, nq: usize) -> Result<()> {
        fn fit<T: Clone>(v: &mut Vec<T>, len: usize, fill: T) -> Result<()> {
            if len > v.len() {
                v.try_reserve_exact(len - v.len())
                    .map_err(|_| SabreError::Simulation(format!("cannot allocate {len} values for the rollout outputs")))?;
            }
            v.resize(len, fill);
            Ok(())
        }
        (self.n, self.k, self.nx, self.nq) = (n, k, nx, nq);
        fit(&mut self.states, n * (k + 1) * nx, 0.0)?;
        fit(&mut self.tau_ext, n * k * nq, 0.0)?;
        fit(&mut self.wrench, n * k * 6, 0.0)?;
        fit(&mut self.contact, n * k, false)?;
        for (v, fill) in [(&mut self.costs, 0.0), (&mut self.engine_time, 0.0)] {
            fit(v, n, fill)?;
            v.fill(fill);
        }
        fit(&mut self.failed, n, false)?;
        self.failed.fill(false);
        fit(&mut self.engine_steps, n, 0)?;
        self.engine_steps.fill(0);
        Ok(())
    }

    /// Steps through Rapier's pipeline and the time spent in them, summed over the batch. The time
    /// adds up every worker's: divide by the thread count for its share of the wall time.
    pub fn engine_totals(&self) -> (u64, f64) {
        (self.engine_steps.iter().sum(), self.engine_time.iter().sum())
    }
}

/// Batch rollouts of the reduced-order model from one initial state.
pub struct RolloutModel {
    scene: Arc<Scene>,
    config: RolloutConfig,
    template: RolloutWorld,
    /// Worlds handed to workers; each is restored from `template` before every rollout.
    worlds: Mutex<Vec<RolloutWorld>>,
    /// A world per worker of the pool running a batch (by rayon's thread index): a worker keeps the
    /// world it used last, whose memory is still in its core's caches, instead of one another core
    /// left on the shared stack.
    by_worker: Vec<Mutex<Option<RolloutWorld>>>,
    /// Per joint (robot, then object) the speed beyond which a rollout has diverged.
    speed_bounds: Vec<f64>,
}

/// A single rollout of at most this many steps runs on the calling thread (see `rollout_into`).
const INLINE_STEPS: usize = 512;

/// Upper bound on the values in one output array of a batch (2^28 doubles = 2 GiB).
pub const MAX_BATCH_ELEMENTS: usize = 1 << 28;

/// A batch's inputs: given, or written row by row by the worker that rolls the row out.
enum Inputs<'a> {
    Given(&'a [f64]),
    Filled(&'a mut [f64], &'a (dyn Fn(usize, &mut [f64]) + Sync)),
}

struct RolloutSlices<'a> {
    states: &'a mut [f64],
    tau_ext: &'a mut [f64],
    wrench: &'a mut [f64],
    contact: &'a mut [bool],
    cost: &'a mut f64,
}

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
        let template = match config.contact_model {
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
        Ok(Self {
            speed_bounds: super::joint_speed_bounds(&scene).into_iter().map(|j| j.2).collect(),
            scene,
            config,
            template,
            worlds: Mutex::new(Vec::new()),
            by_worker: (0..MAX_THREADS).map(|_| Mutex::new(None)).collect(),
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

    /// The calling worker's own world (see `by_worker`), else one from the shared stack.
    fn checkout_for_worker(&self) -> RolloutWorld {
        let slot = rayon::current_thread_index().and_then(|i| self.by_worker.get(i));
        let own = slot.and_then(|m| m.lock().unwrap_or_else(|e| e.into_inner()).take());
        own.unwrap_or_else(|| self.checkout())
    }

    fn checkin_for_worker(&self, world: RolloutWorld) {
        match rayon::current_thread_index().and_then(|i| self.by_worker.get(i)) {
            Some(m) => {
                let mut slot = m.lock().unwrap_or_else(|e| e.into_inner());
                match slot.as_ref() {
                    None => *slot = Some(world),
                    Some(_) => self.checkin(world),
                }
            }
            None => self.checkin(world),
        }
    }

    /// Simulates one input sequence `u` (K × nu) from `x0`; returns the step at which the physics
    /// produced non-finite numbers, if it did.
    fn rollout_one(
        &self,
        world: &mut RolloutWorld,
        x0: &[f64],
        u: &[f64],
        cost: Option<&dyn StepEvaluator>,
        out: RolloutSlices,
        cancel: &Cancel,
    ) -> Option<usize> {
        let nx = self.scene.nx();
        let nq = self.scene.nq();
        let k = out.contact.len();
        world.restore_from(&self.template);
        world.set_state(x0);
        out.states[..nx].copy_from_slice(x0);
        *out.cost = 0.0;
        for step in 0..k {
            if cancel.is_set() {
                return Some(step);
            }
            let u_step = &u[step * nq..(step + 1) * nq];
            let x = &mut out.states[(step + 1) * nx..(step + 2) * nx];
            world.step_once(u_step, x);
            #[cfg(test)]
            tests::inject_failure(u_step, x);
            // Non-finite numbers, or a joint faster than anything the actuators or the object can
            // do: the integration diverged and the rest of this rollout means nothing.
            if x.iter().any(|v| !v.is_finite()) || super::diverged_joint(x, nq, self.scene.no(), &self.speed_bounds).is_some() {
                return Some(step);
            }
            if let Some(cost) = cost {
                *out.cost += world.evaluate_step(cost, x, u_step);
            }
            let interaction = world.interaction();
            out.tau_ext[step * nq..(step + 1) * nq].copy_from_slice(&interaction.tau_ext);
            out.wrench[step * 6..(step + 1) * 6].copy_from_slice(&interaction.wrench);
            out.contact[step] = interaction.contact;
        }
        None
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
        self.rollout_rows(x0, Inputs::Given(u), n, k, threads, cost, batch)
    }

    /// [`Self::rollout_into`] of inputs that `fill(i, row)` writes into row i of `u` (K × nu) on
    /// the worker that rolls that row out, just before. `fill` must write finite values within the
    /// joint velocity limits: the rows are not checked. Rows are filled only if rolled out: after
    /// an error, some may not be.
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
        batch: &mut RolloutBatch,
    ) -> Result<()> {
        self.check_inputs(u, n, k)?;
        self.rollout_rows(x0, Inputs::Filled(u, fill), n, k, threads, cost, batch)
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
        batch.prepare(n, k, nx, nq)?;
        if n == 0 || k == 0 {
            for i in 0..n {
                batch.states[i * nx..(i + 1) * nx].copy_from_slice(x0);
            }
            return Ok(());
        }
        if let Some(cost) = cost {
            cost.validate(&self.scene)?;
        }
        let cancel = Cancel::default();
        let work = |u_i: &[f64],
                    states: &mut [f64],
                    tau: &mut [f64],
                    wrench: &mut [f64],
                    contact: &mut [bool],
                    (failed, total): (&mut bool, &mut f64),
                    (engine_steps, engine_time): (&mut u64, &mut f64)| {
            let mut world = self.checkout_for_worker();
            let clock = world.engine_clock();
            let slices = RolloutSlices {
                states: &mut *states,
                tau_ext: &mut *tau,
                wrench: &mut *wrench,
                contact: &mut *contact,
                cost: &mut *total,
            };
            // A panic inside the physics engine must not cross into the caller: that rollout is
            // marked failed from its first step and its world, possibly inconsistent, is dropped.
            let failed_at = match catch_unwind(AssertUnwindSafe(|| {
                self.rollout_one(&mut world, x0, u_i, cost, slices, &cancel)
            })) {
                Ok(result) => {
                    let after = world.engine_clock();
                    *engine_steps = after.steps - clock.steps;
                    *engine_time = after.seconds - clock.seconds;
                    self.checkin_for_worker(world);
                    result
                }
                Err(_) => Some(0),
            };
            if let Some(step) = failed_at {
                *failed = true;
                *total = f64::INFINITY;
                states[(step + 1) * nx..].fill(f64::NAN);
                tau[step * nq..].fill(f64::NAN);
                wrench[step * 6..].fill(f64::NAN);
                contact[step..].fill(false);
            }
        };
        if n == 1 && k <= INLINE_STEPS {
            // One short rollout (a task's probe, every planning iteration) costs less than handing
            // it to the pool and back, and ends too soon to need watching for Ctrl-C.
            let b = &mut *batch;
            let (failed, costs) = (&mut b.failed[0], &mut b.costs[0]);
            let (steps, time) = (&mut b.engine_steps[0], &mut b.engine_time[0]);
            let u = match inputs {
                Inputs::Given(u) => u,
                Inputs::Filled(u, fill) => {
                    fill(0, u);
                    &*u
                }
            };
            work(
                u,
                &mut b.states,
                &mut b.tau_ext,
                &mut b.wrench,
                &mut b.contact,
                (failed, costs),
                (steps, time),
            );
            return Ok(());
        }
        let rows = match inputs {
            Inputs::Given(u) => Either::Left(u.par_chunks(k * nq)),
            Inputs::Filled(u, fill) => Either::Right(u.par_chunks_mut(k * nq).enumerate().map(move |(i, row)| {
                fill(i, row);
                &*row
            })),
        };
        let run = || {
            rows.zip(batch.states.par_chunks_mut((k + 1) * nx))
                .zip(batch.tau_ext.par_chunks_mut(k * nq))
                .zip(batch.wrench.par_chunks_mut(k * 6))
                .zip(batch.contact.par_chunks_mut(k))
                .zip(batch.failed.par_iter_mut().zip(batch.costs.par_iter_mut()))
                .zip(batch.engine_steps.par_iter_mut().zip(batch.engine_time.par_iter_mut()))
                // One rollout per job: rollouts in contact cost several times those in free space,
                // and rayon's default halving can leave a worker idle behind a chunk of expensive ones.
                .with_max_len(1)
                .for_each(|((((((u_i, s), t), w), c), f), e)| work(u_i, s, t, w, c, f, e));
        };
        let pool = pool(threads)?;
        crate::interrupt::run_watched_on(&pool, &cancel, run)?;
        Ok(())
    }
}

#[cfg(test)]
pub(crate) mod tests;
