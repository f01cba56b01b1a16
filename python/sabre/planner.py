"""The sampling-based controller (paper Sec. IV-A): its settings, one planning iteration at a time, and the
sampler's likelihood weights (55).

``Controller`` wraps the Rust sampler (one planning iteration per :meth:`Controller.update`, GIL
released) and a :class:`~sabre.tasks.Task` (phases, costs, switching). ``ControllerConfig`` holds every Table I
parameter and the variant (:data:`VARIANTS`); ``IterationStats`` reports one iteration. The closed loop on the
plant is :func:`sabre.run_episode`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._validate import (
    as_array,
    as_count,
    as_finite,
    as_float_array,
    as_non_negative,
    as_positive,
    as_state_vector,
    core_config,
)
from .costs import Batch, CompiledCost
from .errors import InvalidValueError, ShapeError
from .inner_loop import PlanSnapshot
from .safety import EnergyTank, SafetyConfig, SafetyFilter, TankRefill
from .scene import Scene
from .sim import CONTACT_MODELS, MAX_THREADS, RolloutModel
from .tasks import Task

__all__ = ["ControllerConfig", "Controller", "IterationStats", "likelihood_weights", "VARIANTS"]

#: Controller variants Π_N, Π_I, Π_O, Π_IO (paper Sec. VI): N no filter, I inner FILTER-QP with the tank, O sequential
#: FILTER-QP in the outer loop, IO both.
VARIANTS = ("N", "I", "O", "IO")

# The core's defaults, the one source of every default below.
_MPPI = _core.MppiConfig()
_ROLLOUT = _core.RolloutConfig()
_TANK = _core.EnergyTankConfig()


@dataclass(frozen=True)
class ControllerConfig:
    """Every Table I parameter of the sampler, with the paper's defaults, plus seed and threads.

    The defaults are the core's (Table I).
    rollouts: N samples per iteration (≥ 3). horizon: T (s). dt: rollout step (s); K = T / dt
    steps. sigma: diagonal of Σ (variances, (rad/s)² or (m/s)²), one entry per input; None gives
    Table I's Σ for the scene's inputs (:meth:`sigma_for`). h: sharpness of the likelihood mapping
    (55). step_size: ρ = α (14). gradient_clip: g_max (54). keep_fraction: share of the best
    previous samples reused ("caching"), in [0, 1]. smoothing_window, smoothing_order: the
    Savitzky–Golay filter of the nominal (window in steps; 0 or 1: off). seed: the random stream. threads: rollout
    workers (None: every core; results are identical for any count). tank_initial: S(0) (J).

    Raises:
        InvalidValueError: any value outside its range (checked on construction).
    """

    rollouts: int = _MPPI.rollouts
    horizon: float = _MPPI.horizon
    dt: float = _ROLLOUT.dt
    sigma: tuple[float, ...] | None = None
    h: float = _MPPI.h
    step_size: float = _MPPI.step_size
    gradient_clip: float = _MPPI.gradient_clip
    keep_fraction: float = _MPPI.keep_fraction
    smoothing_window: int = _MPPI.smoothing_window
    smoothing_order: int = _MPPI.smoothing_order
    #: noise drawn every `noise_interval` rollout steps and interpolated (1 = white, as in the paper).
    noise_interval: int = _MPPI.noise_interval
    seed: int = _MPPI.seed
    threads: int | None = _MPPI.threads
    #: Symmetric bound |u_i| ≤ input_limit_i on the commanded velocities (one entry per input, or
    #: None for the joint velocity limits). Samples are projected onto it.
    input_limit: tuple[float, ...] | None = None
    #: Rollout-model settings (the closed loop the sampler predicts with).
    servo_bandwidth: float = _ROLLOUT.servo_bandwidth
    contact_friction: float = _ROLLOUT.contact_friction
    #: how the rollout model resolves contacts (:data:`sabre.CONTACT_MODELS`): "reduced" or "rapier".
    contact_model: str = _ROLLOUT.contact_model
    #: per joint (nq), the largest acceleration (rad/s² or m/s²) the robot's command path gives it:
    #: the rollout model's servo tracks its commands rate-limited at it (:class:`sabre.RolloutModel`);
    #: None: as given (a plant driven directly). The ROS 2 bridge sets it from its command limits.
    command_acceleration: tuple[float, ...] | None = None
    #: "N" (no filter), "I" (1 kHz FILTER-QP with the energy tank), "O" (Sequential FILTER-QP on
    #: the optimised sequence, which warm-starts the next round) or "IO" (both).
    variant: str = "N"
    #: constraints, slack penalties and passivity settings of both filters, and the hard joint-limit
    #: bound of the inner loop and the nominal plan (None: the defaults).
    safety: SafetyConfig | None = None
    #: energy tank: S(0) (J); its floor ε is ``safety.tank_floor``.
    tank_initial: float = _TANK.initial
    #: refill of the inner loop's tank (variants I, IO) by the plan's predicted dissipation while the
    #: plant agrees with the prediction (:class:`~sabre.TankRefill`); None: the paper's fixed budget.
    tank_refill: TankRefill | None = field(default_factory=TankRefill)

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise InvalidValueError(f"variant must be one of {VARIANTS}, got {self.variant!r}")
        if self.contact_model not in CONTACT_MODELS:
            raise InvalidValueError(f"contact_model must be one of {CONTACT_MODELS}, got {self.contact_model!r}")
        if self.safety is not None and not isinstance(self.safety, SafetyConfig):
            raise InvalidValueError(f"safety must be a sabre.SafetyConfig, got {type(self.safety).__name__}")
        as_positive("tank_initial", self.tank_initial)
        if self.tank_refill is not None and not isinstance(self.tank_refill, TankRefill):
            raise InvalidValueError(f"tank_refill must be a sabre.TankRefill or None, got {type(self.tank_refill).__name__}")
        as_count("rollouts", self.rollouts, 3)
        as_positive("horizon", self.horizon)
        as_positive("dt", self.dt)
        if self.horizon < self.dt:
            raise InvalidValueError(f"horizon ({self.horizon} s) is shorter than one step ({self.dt} s)")
        for name in ("h", "step_size", "gradient_clip", "servo_bandwidth"):
            as_positive(name, getattr(self, name))
        if not 0.0 <= self.keep_fraction <= 1.0:
            raise InvalidValueError(f"keep_fraction must be within [0, 1], got {self.keep_fraction}")
        as_count("smoothing_window", self.smoothing_window, 0)
        as_count("smoothing_order", self.smoothing_order, 0)
        as_count("noise_interval", self.noise_interval, 1)
        as_count("seed", self.seed, 0)
        if self.threads is not None:
            as_count("threads", self.threads, 1, MAX_THREADS)
        if self.input_limit is not None:
            limit = np.asarray(self.input_limit, dtype=float)
            if limit.ndim != 1 or np.any(~np.isfinite(limit)) or np.any(limit <= 0):
                raise InvalidValueError("input_limit must be a sequence of positive, finite bounds")
        if self.command_acceleration is not None:
            a = np.asarray(self.command_acceleration, dtype=float)
            if a.ndim != 1 or np.any(~np.isfinite(a)) or np.any(a <= 0):
                raise InvalidValueError("command_acceleration must be a sequence of positive, finite bounds")
        if self.sigma is not None:
            sigma = np.asarray(self.sigma, dtype=float)
            if sigma.ndim != 1 or np.any(~np.isfinite(sigma)) or np.any(sigma < 0):
                raise InvalidValueError("sigma must be a sequence of finite, non-negative variances")

    @property
    def safety_config(self) -> SafetyConfig:
        """The filters' settings: ``safety``, or the defaults when None."""
        return SafetyConfig() if self.safety is None else self.safety

    @property
    def inner_filter(self) -> bool:
        """Whether the variant runs the 1 kHz FILTER-QP with the tank (I, IO)."""
        return "I" in self.variant

    @property
    def outer_filter(self) -> bool:
        """Whether the variant runs the sequential FILTER-QP on each plan (O, IO)."""
        return "O" in self.variant

    @property
    def horizon_steps(self) -> int:
        """K, the number of rollout steps in the horizon."""
        return int(round(self.horizon / self.dt))

    def sigma_for(self, nu: int) -> list[float]:
        """The diagonal of Σ for ``nu`` inputs. Raises InvalidValueError if ``sigma`` has another length."""
        if self.sigma is None:
            return list(_core.MppiConfig.paper_sigma(nu))
        if len(self.sigma) != nu:
            raise InvalidValueError(f"sigma has {len(self.sigma)} entries, the scene has nu = {nu} inputs")
        return [float(s) for s in self.sigma]


@dataclass(frozen=True)
class IterationStats:
    """Statistics of one planning iteration (:meth:`Controller.update`).

    Attributes:
        iteration: iterations since the last reset, this one included.
        iteration_time: wall time of the whole iteration (s): sampling, rollouts, cost, update, the
            task's guides and, with the outer filter, the sequential FILTER-QP.
        rollout_time: wall time of the parallel rollouts and their cost (s); with every cost term in
            the core, each worker also draws the samples it rolls out, and their time is here.
        engine_steps: rollout steps, summed over the rollouts, that went through the contact step
            (contact detection and solve, or Rapier's pipeline with ``contact_model="rapier"``); the
            others were skipped as quiescent, see :class:`sabre.RolloutModel`.
        engine_time: time spent in those steps (s), summed over the workers, so
            ``engine_time / (rollout_time * threads)`` is the contact physics' share of the rollouts.
        cost_min, cost_mean, cost_max: smallest, mean and largest finite rollout cost of the batch
            (dimensionless, the task's cost).
        nominal_cost: cost of the nominal (the sequence the reference follows) after the update.
        effective_sample_size: 1 / Σ w_i² of the normalised sample weights (55), between 1 and N.
        failed_rollouts: rollouts whose physics diverged (weighted zero).
        phase: the task phase the iteration planned for.
        noise_scale: factor on Σ the task asked for (:meth:`sabre.tasks.Task.noise_scale`).
        guide_time: wall time of the task's guides (s), included in ``iteration_time``; of a guide
            plan (:meth:`sabre.tasks.Task.guide_plan`) only its making: the rollout workers
            integrate its guides, within ``rollout_time``.
        sequential_time: wall time of the sequential FILTER-QP (s, Algorithm 1), included in
            ``iteration_time``; None without the outer filter (variants N, I).
        sequential_fallbacks: steps of the sequential filter that fell back to the safe stop; None
            without the outer filter.

    Timings vary from run to run; every other field is deterministic for a seed.
    """

    iteration: int
    iteration_time: float
    rollout_time: float
    engine_steps: int
    engine_time: float
    cost_min: float
    cost_mean: float
    cost_max: float
    nominal_cost: float
    effective_sample_size: float
    failed_rollouts: int
    phase: str
    noise_scale: float
    guide_time: float
    sequential_time: float | None = None
    sequential_fallbacks: int | None = None


class Controller:
    """Sampling-based controller (paper Sec. IV-A) for ``scene`` pursuing ``task``.

    update(x, t): one planning iteration from the measured state. reference(t): the commanded joint
    velocity at time t (linear interpolation of the nominal). nominal: the current input sequence
    (K, nu) starting at ``nominal_t0``. stats: statistics of the last iteration
    (:class:`IterationStats`). The variant's filters (:attr:`outer_filter`, :attr:`inner_filter`)
    and energy tank (:attr:`tank`) are built from ``config`` (default: :class:`ControllerConfig`).

    Raises:
        TypeError: scene or task of the wrong type.
        InvalidValueError: ``config.sigma`` of another length than nu.
        ShapeError: ``config.input_limit`` of another length than nu.
    """

    def __init__(self, scene: Scene, task: Task, config: ControllerConfig | None = None) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        if not isinstance(task, Task):
            raise TypeError(f"task must be a sabre.tasks.Task, got {type(task).__name__}")
        self.scene = scene
        self.task = task
        self.config = config or ControllerConfig()
        #: keep the last iteration's rollouts: ``last_samples`` = (states (N, K+1, nx), costs (N,))
        self.keep_samples = False
        self.last_samples: tuple[np.ndarray, np.ndarray] | None = None
        c = self.config
        #: How often :meth:`set_scene` replaced the scene.
        self.scene_changes = 0
        self.phase = task.initial_phase()
        self._build(scene, c.seed)
        self._stats: IterationStats | None = None
        self.phase_history: list[tuple[float, str]] = [(0.0, self.phase)]
        safety = c.safety_config
        #: Sequential FILTER-QP of the outer loop (variants O, IO), else None.
        self.outer_filter = SafetyFilter(scene, safety) if c.outer_filter else None
        #: FILTER-QP of the 1 kHz inner loop with the passivity row (variants I, IO), else None.
        self.inner_filter = SafetyFilter(scene, safety) if c.inner_filter else None
        #: The energy tank of the inner loop; without the inner filter it only keeps the books.
        self.tank = EnergyTank(c.tank_initial, safety.tank_floor, refill=c.tank_refill if c.inner_filter else None)
        self._predicted_dissipation: np.ndarray | None = None

    def _build(self, scene: Scene, seed: int) -> None:
        """The rollout model, the phases' costs and the sampler for ``scene``."""
        c = self.config
        # The task's check first: what it says about a scene (files swapped, a joint to pick) is
        # more to the point than the rollout model's limits.
        self.task.check(scene)
        model = RolloutModel(
            scene,
            c.dt,
            servo_bandwidth=c.servo_bandwidth,
            contact_friction=c.contact_friction,
            contact_model=c.contact_model,
            command_acceleration=c.command_acceleration,
        )
        compiled: dict[str, CompiledCost] = {}
        for phase in self.task.phases:  # a phase the scene cannot serve fails here, not mid-episode
            compiled[phase] = self.task.cost(scene, phase).compile(scene)
        planner_config = core_config(
            _core.MppiConfig,
            rollouts=c.rollouts,
            horizon=c.horizon,
            sigma=c.sigma_for(scene.nu),
            h=c.h,
            step_size=c.step_size,
            gradient_clip=c.gradient_clip,
            keep_fraction=c.keep_fraction,
            smoothing_window=c.smoothing_window,
            smoothing_order=c.smoothing_order,
            seed=seed,
            threads=c.threads,
            noise_interval=c.noise_interval,
            input_limit=None if c.input_limit is None else [float(v) for v in c.input_limit],
            # the plan handed to the cascade keeps its hard joint-limit bound along the kinematics
            limit_bound=c.safety_config._limit_bound(),
        )
        self.scene, self.model, self._compiled = scene, model, compiled
        self._cost = compiled[self.phase]
        self._planner = _core.Planner(model._core, self._cost.core, planner_config)

    def set_scene(self, scene: Scene) -> None:
        """Plans with ``scene`` from now on, the plan in force continuing: the rollout model and the
        phases' costs are built for it, the nominal, phase, filters and tank carry over. For an object
        whose model changes while it is opened (:class:`sabre.EstimatedObject`); the robot must be the
        same (its joints and state layout).

        Raises:
            TypeError: scene is no :class:`~sabre.Scene`.
            InvalidValueError: a scene of another robot or state layout, or one the task refuses.
        """
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        if scene.joint_names != self.scene.joint_names or scene.nx != self.scene.nx:
            raise InvalidValueError(
                f"set_scene: the new scene's robot ({scene.nq} joints, nx {scene.nx}) is not the controller's "
                f"({self.scene.nq} joints, nx {self.scene.nx})"
            )
        nominal, t0 = np.array(self.nominal), self.nominal_t0
        self.scene_changes += 1
        self._build(scene, self.config.seed + self.scene_changes)
        self._planner.set_nominal(np.ascontiguousarray(nominal), t0)

    def _compile(self, phase: str) -> CompiledCost:
        if phase not in self._compiled:
            self._compiled[phase] = self.task.cost(self.scene, phase).compile(self.scene)
        return self._compiled[phase]

    def refresh_cost(self) -> None:
        """Builds the current phase's cost again from the task: for a task whose cost depends on
        where the phase began (:class:`sabre.tasks.OpenObject`'s hold)."""
        self._compiled.pop(self.phase, None)
        self._cost = self._compile(self.phase)
        self._planner.set_cost(self._cost.core)

    def reset(self, seed: int | None = None, t0: float = 0.0) -> None:
        """Forgets the policy, the filters' remembered active sets and the tank's energy, and restarts
        the random stream (default: the configured seed): an episode re-run after reset repeats exactly."""
        self._planner.reset(self.config.seed if seed is None else as_count("seed", seed, 0), as_finite("t0", t0))
        self.phase = self.task.initial_phase()
        self._cost = self._compile(self.phase)
        self._planner.set_cost(self._cost.core)
        self.phase_history = [(float(t0), self.phase)]
        self.tank.reset()
        self._predicted_dissipation = None
        for f in (self.outer_filter, self.inner_filter):
            if f is not None:
                f.reset_stats()
                f.forget_active_set()

    @property
    def filters(self) -> tuple[SafetyFilter, ...]:
        """The safety filters of the variant (outer first), empty for N."""
        return tuple(f for f in (self.outer_filter, self.inner_filter) if f is not None)

    def add_obstacle(self, center: Sequence[float] | np.ndarray, radius: float) -> int | None:
        """Adds a sphere obstacle to the filters of this variant (the same id in each); None
        for variant N, which has no filter (give the sampler an ``Obstacles`` cost term too)."""
        ids = {f.add_obstacle(center, radius) for f in self.filters}
        if len(ids) > 1:
            raise InvalidValueError(
                "the inner and outer filters disagree on obstacle ids; manage them through the controller only"
            )
        return ids.pop() if ids else None

    def move_obstacle(self, obstacle_id: int, center: Sequence[float] | np.ndarray) -> None:
        """Moves an obstacle (world centre (3,), m) in every filter of the variant."""
        for f in self.filters:
            f.move_obstacle(obstacle_id, center)

    def remove_obstacle(self, obstacle_id: int) -> None:
        """Removes an obstacle from every filter of the variant."""
        for f in self.filters:
            f.remove_obstacle(obstacle_id)

    def set_nominal(self, U: np.ndarray, t0: float) -> None:
        """Replaces the nominal sequence with U (K, nu), row 0 applying at t0 (s): to start from a
        plan saved earlier (:attr:`nominal`, :attr:`nominal_t0`) instead of from rest.

        Raises:
            ShapeError: U is not (K, nu) with the configured horizon.
            InvalidValueError: non-finite U or t0.
        """
        U = as_float_array("U", U, (self.config.horizon_steps, self.scene.nu))
        self._planner.set_nominal(np.ascontiguousarray(U), as_finite("t0", t0))

    @property
    def phase_since(self) -> float:
        """When (s) the controller entered its current phase."""
        return self.phase_history[-1][0]

    def set_phase(self, phase: str, t: float = 0.0) -> None:
        """Switches the task phase by hand (the task's own rule keeps running afterwards)."""
        if phase not in self.task.phases:
            raise InvalidValueError(f"unknown phase {phase!r}; phases: {self.task.phases}")
        if phase != self.phase:
            self.phase = phase
            self._cost = self._compile(phase)
            self._planner.set_cost(self._cost.core)
            self.phase_history.append((float(t), phase))

    def update(
        self, x: Sequence[float] | np.ndarray, t: float, *, observed: Sequence[float] | np.ndarray | None = None
    ) -> IterationStats:
        """One planning iteration from the state x (nx,) at time t (s); returns its statistics.

        Runs the task's phase switch and ``on_step``, samples around the nominal, rolls out, weighs
        and updates the nominal (and, with the outer filter, filters it along its rollout). When x is
        a prediction (:meth:`predict`), ``observed`` (nx,) is the measured state it was predicted from:
        the phase switch reads it, since the phases' tests are contact events (a slip, a stalled hook)
        that the rollout model's reduced contact predicts less well than the robot measures them.

        Raises:
            ShapeError: x is not (nx,), or the task's guides are not (M, K, nu).
            InvalidValueError: non-finite x or t, an unknown phase or a bad noise scale from the task.
        """
        x = as_state_vector("x", x, self.scene.nx)
        t = float(t)
        if not math.isfinite(t):
            raise InvalidValueError("t must be finite")
        seen = x if observed is None else as_state_vector("observed", observed, self.scene.nx)
        phase = self.task.next_phase(self.scene, seen, t, self.phase)
        if phase not in self.task.phases:
            raise InvalidValueError(f"task returned unknown phase {phase!r}; phases: {self.task.phases}")
        self.set_phase(phase, t)
        self.task.on_step(self.scene, x, t, self)
        scale = float(self.task.noise_scale(self.scene, x, self.phase))
        if not (math.isfinite(scale) and scale > 0.0):
            raise InvalidValueError(f"task.noise_scale returned {scale}; it must be positive and finite")
        self._planner.noise_scale = scale
        start = time.perf_counter()
        steps, dt = self.config.horizon_steps, self.config.dt
        plan = self.task.guide_plan(self.scene, x, self.phase, steps, dt)
        guides = self.task.guides(self.scene, x, self.phase, steps, dt) if plan is None else None
        if plan is not None:
            if not isinstance(plan, _core.ServoGuidePlan):
                raise InvalidValueError(
                    f"task.guide_plan: expected a sabre.guides.ServoGuidePlan or None, got {type(plan).__name__}"
                )
            self._planner.set_guide_plan(plan)
        elif guides is not None and len(guides):
            guides = np.asarray(guides, dtype=np.float64)
            if guides.ndim != 3 or guides.shape[1:] != (self.config.horizon_steps, self.scene.nu):
                raise ShapeError(f"task.guides: expected (M, {self.config.horizon_steps}, {self.scene.nu}), got {guides.shape}")
            self._planner.set_guides(np.ascontiguousarray(guides[: self.config.rollouts - 2]))
        guide_time = time.perf_counter() - start
        in_core = not self._cost.python_terms and not self.keep_samples
        if in_core:
            stats = self._planner.iterate(x, t)
        else:
            inputs = self._planner.sample(t)
            costs, states, tau_ext, _wrench, contact = self._planner.evaluate(x)
            q = self.scene.split_state(states).q
            frames = {name: self.scene.fk_many(q, name) for name in self._cost.frames_needed}
            batch = Batch(states, inputs, tau_ext, contact, self.config.dt, frames)
            for term in self._cost.python_terms:
                costs = costs + term.evaluate(self.scene, batch)
            stats = self._planner.update(costs)
            stats["iteration_time"] = time.perf_counter() - start
            if self.keep_samples:
                self.last_samples = (states, np.asarray(costs, dtype=np.float64))
        if self.outer_filter is not None:
            # Algorithm 1: filter the optimised sequence step by step along its rollout; the
            # filtered sequence is the reference and the next round's nominal.
            start = time.perf_counter()
            seq = self.outer_filter.filter_sequence(x, self.nominal, self.model)
            self._planner.set_nominal(np.ascontiguousarray(seq.U), self.nominal_t0)
            stats["sequential_time"] = time.perf_counter() - start
            stats["sequential_fallbacks"] = seq.fallbacks
            stats["iteration_time"] += stats["sequential_time"]
        if self.tank.refill_config is not None:
            start = time.perf_counter()
            self._predicted_dissipation = self._predict_dissipation(x)
            stats["iteration_time"] += time.perf_counter() - start
        stats["guide_time"] = guide_time
        # The core times its own iteration; the Python path above already counts the guides.
        stats["iteration_time"] += guide_time if in_core else 0.0
        stats["phase"] = self.phase
        stats["noise_scale"] = scale
        self._stats = IterationStats(**stats)
        return self._stats

    def predict(self, x: Sequence[float] | np.ndarray, t: float, delay: float) -> tuple[np.ndarray, float]:
        """The state the rollout model predicts ``delay`` s after the measured state x (nx,) at
        time t under the current plan (:meth:`reference`), on the planning grid: k =
        round(delay / dt) steps ahead, so the prediction is for t + k·dt. Returns (state, time).

        A real-time planner plans from it, with its own iteration time as the delay: its plan
        takes over only once computed, and the robot has meanwhile followed the previous plan, so
        a plan made from the measured state would start from where the robot no longer is. Gives
        (x, t) back for k = 0, before the first :meth:`update` and where the rollout fails.

        Raises:
            ShapeError: x is not (nx,).
            InvalidValueError: non-finite x or t, negative or non-finite delay.
        """
        x = as_float_array("x", x, (self.scene.nx,))
        t = as_finite("t", t)
        steps = int(round(as_non_negative("delay", delay) / self.config.dt))
        if steps == 0 or self._stats is None:
            return x, t
        dt = self.config.dt
        inputs = np.stack([self.reference(t + j * dt) for j in range(steps)])
        result = self.model.rollout(x, inputs[None], threads=1)
        if result.failed[0]:
            return x, t
        return np.array(result.states[0, steps]), t + steps * dt

    def _predict_dissipation(self, x: np.ndarray) -> np.ndarray:
        """−τ_extᵀu (W) at each step of the current plan's rollout from x (K,), for the tank's refill (in the core)."""
        return self._planner.predicted_dissipation(x)

    @property
    def predicted_dissipation(self) -> np.ndarray | None:
        """(K,) the port dissipation −τ_extᵀu (W) the rollout model predicts along the current plan, on
        the grid of :attr:`nominal` (row k at ``nominal_t0 + k·dt``); None without a tank refill or
        before the first :meth:`update`."""
        return self._predicted_dissipation

    def predicted_dissipation_at(self, t: float) -> float | None:
        """The predicted port dissipation (W) at time t, interpolated on the grid of :attr:`nominal` as
        :meth:`reference` is (held at both ends); None where :attr:`predicted_dissipation` is None."""
        predicted = self._predicted_dissipation
        if predicted is None:
            return None
        s = min(max((as_finite("t", t) - self.nominal_t0) / self.config.dt, 0.0), float(len(predicted) - 1))
        i = int(s)
        j = min(i + 1, len(predicted) - 1)
        return float((1.0 - (s - i)) * predicted[i] + (s - i) * predicted[j])

    def snapshot(self) -> PlanSnapshot:
        """The current plan as a value the inner loop follows (:class:`~sabre.PlanSnapshot`): a copy of
        :attr:`nominal` from :attr:`nominal_t0`, held to the inner loop's hard joint-limit bound along its
        kinematics from the state it was planned from (``safety``'s ``limit_margin``; a joint that would
        come within it is slowed, one plan step late, as the cascade would), the predicted dissipation,
        the task's gain inertia floor for the phase, and the last iteration's phase, time, count and
        nominal cost. Later updates leave it as it is."""
        stats = self._stats
        return PlanSnapshot.of(
            self._planner.bounded_nominal,
            self.nominal_t0,
            self.config.dt,
            predicted=self._predicted_dissipation,
            gain_inertia_floor=self.task.gain_inertia_floor(self.phase),
            phase=self.phase,
            iteration_time=float("nan") if stats is None else stats.iteration_time,
            iterations=0 if stats is None else stats.iteration,
            nominal_cost=float("nan") if stats is None else stats.nominal_cost,
        )

    def reference(self, t: float) -> np.ndarray:
        """(nu,) commanded joint velocity at time t."""
        return np.asarray(self._planner.reference(float(t)), dtype=np.float64)

    @property
    def nominal(self) -> np.ndarray:
        """(K, nu) current input sequence; row k applies at nominal_t0 + k·dt."""
        return self._planner.nominal

    @property
    def nominal_t0(self) -> float:
        """Time (s) at which row 0 of :attr:`nominal` applies."""
        return self._planner.nominal_t0

    @property
    def stats(self) -> IterationStats | None:
        """Statistics of the last planning iteration; None before the first :meth:`update`."""
        return self._stats


def _real_costs(costs: Sequence[float] | np.ndarray) -> np.ndarray:
    """A flat float64 cost vector (NaN and ±inf allowed: they weigh zero); complex or non-numeric refused."""
    array = as_array("costs", costs).reshape(-1)
    if array.dtype.kind not in "fiu":
        raise ShapeError(f"costs: expected real numbers, got dtype {array.dtype}")
    return array.astype(np.float64)


def likelihood_weights(costs: Sequence[float] | np.ndarray, mapping: str = "invariant", parameter: float = 10.0) -> np.ndarray:
    """Normalised sample weights of a cost vector (paper Fig. 3).

    mapping: "naive" exp(−λJ), "baseline" exp(−λ(J − J_min)), or "invariant" (55)
    exp(−h (J − J_min)/(J_max − J_min)); `parameter` is λ or h (positive). Non-finite costs weigh
    zero; where a mapping underflows or overflows for every cost (the naive one at large costs, the
    point of Fig. 3) all weights are zero, which the sampler treats as "keep the nominal".
    """
    costs = _real_costs(costs)
    weights = _core.likelihood_weights(costs.tolist(), str(mapping), as_positive("parameter", parameter))
    return np.asarray(weights, dtype=np.float64)
