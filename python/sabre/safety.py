"""Safety and passivity: the CBF safety filter (FILTER-QP, paper eq. 41), its sequential form and the energy tank.

Every constraint is a zeroing barrier h(q) ≥ 0 turned into a row affine in the command u = q̇*:
``∂h/∂q · u + δ ≥ −γ (h − Δ)`` (19, Remark 1) with a slack δ ≥ 0 per row, penalised by its class's
Γ; the joint velocity limits are hard bounds. The QP runs in Rust (Clarabel), with the GIL released.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from . import _core
from ._validate import as_count, as_finite, as_float_array, as_non_negative, as_positive, core_config, readonly
from .errors import InvalidValueError
from .safety_records import ConstraintRows, FilterResult, FilterStats, QPMatrices, SequenceResult
from .scene import Scene
from .sim import RolloutModel

__all__ = [
    "CLASSES",
    "SafetyConfig",
    "SafetyFilter",
    "FilterResult",
    "SequenceResult",
    "FilterStats",
    "ConstraintRows",
    "QPMatrices",
    "EnergyTank",
    "TankRefill",
    "Obstacle",
]

# The core's defaults, the one source of every default below.
_SAFETY = _core.SafetyConfig()
_x_min, _x_max, _y_min, _y_max = _SAFETY.base_box
_DEFAULT_BASE_BOX = (_x_min, _x_max, _y_min, _y_max)
_LIMIT_BOUND = _core.LimitBoundConfig()
_TANK = _core.EnergyTankConfig()
_REFILL = _core.TankRefillConfig()

#: Constraint classes, in the order the core uses.
CLASSES: tuple[str, ...] = tuple(_core.SafetyConfig.classes())

#: ZBF rate γ (1/s) of the kinematic classes; passivity's rate is ``passivity_alpha``.
DEFAULT_GAMMA = MappingProxyType(dict(zip(CLASSES[:-1], _SAFETY.gamma[:-1])))
#: Slack penalties Γ (paper Table I: joint limits 10, self-collision 100, Cartesian 100, passivity 100).
DEFAULT_PENALTY = MappingProxyType(dict(zip(CLASSES, _SAFETY.penalty)))
#: Margins Δ (Remark 1) in the units of each class's h: rad, m², m², m, m².
DEFAULT_MARGIN = MappingProxyType(dict(zip(CLASSES[:-1], _SAFETY.margin[:-1])))


def _vector(name: str, value: object, n: int) -> np.ndarray:
    """`value` as a float64 (n,) array; ready-made arrays pass untouched (the core checks their
    values and raises the same errors), anything else goes through the full conversion."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (n,) and value.flags.c_contiguous:
        return value
    return as_float_array(name, value, (n,))


def _merged(name: str, given: Mapping[str, object], defaults: Mapping[str, object], allowed: Sequence[str]) -> dict:
    if not isinstance(given, Mapping):
        raise InvalidValueError(f"{name}: expected a mapping from constraint class to value, got {type(given).__name__}")
    unknown = set(given) - set(allowed)
    if unknown:
        raise InvalidValueError(f"{name}: unknown constraint class(es) {sorted(unknown)}; known: {list(allowed)}")
    return {**defaults, **given}


@dataclass(frozen=True)
class SafetyConfig:
    """Settings of :class:`SafetyFilter`, validated on construction.

    The mappings take overrides by class name (see :data:`CLASSES`); missing classes keep their
    defaults (:data:`DEFAULT_GAMMA`, :data:`DEFAULT_PENALTY`, :data:`DEFAULT_MARGIN`, from the
    core). ``gamma``: ZBF rate γ (1/s) — a joint approaches its limit no faster than γ × its
    distance. ``penalty``: slack penalty Γ (Table I). ``margin``: Δ of Remark 1 in the units of
    that class's h (rad for joint limits, m for the base box, m² for self-collision, arm reach and
    obstacles); the defaults keep the slack that the
    penalties allow inside the true limits. ``enabled``: classes without rows. ``base_box``:
    (x_min, x_max, y_min, y_max) in m on a holonomic base's x and y, or None for no box (a
    fixed-base robot never has base-box rows). ``passivity_alpha``: α of (56)
    (1/s; the paper's 1 avoids chattering). ``tank_floor``: ε (J). ``max_obstacles``: obstacle
    slots (fixed QP structure). ``max_iterations``, ``tolerance``: Clarabel's bounds.
    ``screening``: take the exact shortcuts (projected command, remembered active set, rows that
    cannot bind left out); off, every call runs Clarabel on the full QP. Same solution either way.
    ``task_weight``, ``sequential_task_weight`` (λ in 1/m², beyond the paper): the QP measures
    the change of the command in the metric M = (I + λJ_wᵀJ_w) / (1 + λσ²_max(J_w)), J_w the
    Jacobian of ``task_frame`` (None: the scene's tool frame; a robot without one gets the plain
    metric) with its angular rows scaled by ℓ = 0.1 m, so that a constraint is
    met by moving what keeps the hand on its path (the base, the elbow) before the hand itself,
    and no correction costs more than in the paper's ‖ũ − u‖² (41), which λ = 0 gives.
    ``task_weight`` applies to :meth:`SafetyFilter.filter` (default 0: the paper's, in the 1 kHz
    loop), ``sequential_task_weight`` to :meth:`SafetyFilter.filter_sequence`, whose output
    becomes the plan (default 100: a plan pushed off the handle's path loses the handle).

    ``limit_margin`` (rad), ``prismatic_limit_margin`` (m), ``limit_deceleration`` (rad/s², m/s²):
    the hard joint-limit bound (beyond the paper) that the inner loop's cascade applies to every
    command after the filter, in every variant, and a controller to the plan it hands over: a joint's
    command toward a limit is at most the speed from which a stop ends this margin inside the URDF
    limit, starting a control period late (for the ROS 2 bridge, also after its state timeout) and
    braking at the deceleration of the command's rate limiter (the bridge's) or, for a plant the
    cascade drives directly, at ``limit_deceleration``. A joint
    within the margin moves inward only. A margin larger than half a joint's range is refused when
    the config meets a robot (:class:`SafetyFilter`, the cascade).
    """

    gamma: Mapping[str, float] = field(default_factory=dict)
    penalty: Mapping[str, float] = field(default_factory=dict)
    margin: Mapping[str, float] = field(default_factory=dict)
    enabled: Mapping[str, bool] = field(default_factory=dict)
    base_box: tuple[float, float, float, float] | None = _DEFAULT_BASE_BOX
    passivity_alpha: float = _SAFETY.gamma[-1]
    tank_floor: float = _SAFETY.tank_floor
    max_obstacles: int = _SAFETY.max_obstacles
    max_iterations: int = _SAFETY.max_iterations
    tolerance: float = _SAFETY.tolerance
    screening: bool = _SAFETY.screening
    task_weight: float = _SAFETY.task_weight
    sequential_task_weight: float = _SAFETY.sequential_task_weight
    task_frame: str | None = None
    limit_margin: float = _LIMIT_BOUND.margin
    prismatic_limit_margin: float = _LIMIT_BOUND.prismatic_margin
    limit_deceleration: float = _LIMIT_BOUND.deceleration

    def __post_init__(self) -> None:
        kinematic = CLASSES[:-1]
        if "passivity" in self.gamma:
            raise InvalidValueError("gamma: the passivity rate is passivity_alpha")
        if "passivity" in self.margin:
            raise InvalidValueError("margin: passivity has no margin (the tank floor is its margin)")
        gamma = _merged("gamma", self.gamma, DEFAULT_GAMMA, kinematic)
        penalty = _merged("penalty", self.penalty, DEFAULT_PENALTY, CLASSES)
        margin = _merged("margin", self.margin, DEFAULT_MARGIN, kinematic)
        enabled = _merged("enabled", self.enabled, dict(zip(CLASSES, _SAFETY.enabled)), CLASSES)
        for c in kinematic:
            gamma[c] = as_positive(f"gamma[{c}]", gamma[c])
            margin[c] = as_non_negative(f"margin[{c}]", margin[c])
        for c in CLASSES:
            penalty[c] = as_positive(f"penalty[{c}]", penalty[c])
            if not isinstance(enabled[c], (bool, np.bool_)):
                raise InvalidValueError(f"enabled[{c}]: expected a bool, got {enabled[c]!r}")
            enabled[c] = bool(enabled[c])
        box = self.base_box
        if box is None:
            enabled["base_box"] = False
        else:
            box = tuple(as_float_array("base_box", box, (4,)).tolist())
            if not (box[0] < box[1] and box[2] < box[3]):
                raise InvalidValueError(f"base_box: needs x_min < x_max and y_min < y_max, got {box}")
            object.__setattr__(self, "base_box", box)
        object.__setattr__(self, "gamma", MappingProxyType(gamma))
        object.__setattr__(self, "penalty", MappingProxyType(penalty))
        object.__setattr__(self, "margin", MappingProxyType(margin))
        object.__setattr__(self, "enabled", MappingProxyType(enabled))
        object.__setattr__(self, "passivity_alpha", as_positive("passivity_alpha", self.passivity_alpha))
        object.__setattr__(self, "tank_floor", as_non_negative("tank_floor", self.tank_floor))
        as_count("max_obstacles", self.max_obstacles, 0, 64)
        as_count("max_iterations", self.max_iterations, 1, 10_000)
        tolerance = as_positive("tolerance", self.tolerance)
        if tolerance >= 1.0:
            raise InvalidValueError(f"tolerance: must be below 1, got {tolerance}")
        if not isinstance(self.screening, (bool, np.bool_)):
            raise InvalidValueError(f"screening: expected a bool, got {self.screening!r}")
        object.__setattr__(self, "task_weight", as_non_negative("task_weight", self.task_weight))
        object.__setattr__(self, "sequential_task_weight", as_non_negative("sequential_task_weight", self.sequential_task_weight))
        if self.task_frame is not None and not isinstance(self.task_frame, str):
            raise InvalidValueError(f"task_frame: expected a frame name or None, got {self.task_frame!r}")
        for name in ("limit_margin", "prismatic_limit_margin"):
            object.__setattr__(self, name, as_non_negative(name, getattr(self, name)))
        object.__setattr__(self, "limit_deceleration", as_positive("limit_deceleration", self.limit_deceleration))

    def _limit_bound(self) -> _core.LimitBoundConfig:
        """The hard joint-limit bound's settings as the core's config object."""
        return core_config(
            _core.LimitBoundConfig,
            margin=self.limit_margin,
            prismatic_margin=self.prismatic_limit_margin,
            deceleration=self.limit_deceleration,
        )

    def _core_config(self) -> _core.SafetyConfig:
        """The settings as the core's config object; without a base box its class is disabled
        and the box keeps the core's default."""
        fields = {
            "gamma": [self.gamma[c] for c in CLASSES[:-1]] + [self.passivity_alpha],
            "penalty": [self.penalty[c] for c in CLASSES],
            "margin": [self.margin[c] for c in CLASSES[:-1]] + [_SAFETY.margin[-1]],
            "enabled": [self.enabled[c] for c in CLASSES],
            "tank_floor": self.tank_floor,
            "max_obstacles": self.max_obstacles,
            "max_iterations": self.max_iterations,
            "tolerance": self.tolerance,
            "screening": bool(self.screening),
            "task_weight": self.task_weight,
            "sequential_task_weight": self.sequential_task_weight,
            "task_frame": self.task_frame or "",
            "limit_bound": self._limit_bound(),
        }
        if self.base_box is not None:
            fields["base_box"] = list(self.base_box)
        return core_config(_core.SafetyConfig, **fields)


@dataclass(frozen=True)
class Obstacle:
    """A sphere obstacle of a :class:`SafetyFilter`: its id, world centre (m) and radius (m)."""

    id: int
    center: tuple[float, float, float]
    radius: float


class SafetyFilter:
    """The CBF safety filter of the paper (FILTER-QP, eq. 41) for one scene.

    Rows: joint limits (37) on every joint with finite limits, self-collision (39) on the scene's
    sphere pairs, arm reach (40), base box, sphere obstacles (added at run time) against every
    robot sphere, and the passivity row (56) ``τ_extᵀu + δ ≥ −α (S − ε)`` when ``tau_ext`` and
    ``tank_energy`` are given. The QP is built once and updated in place; if the solver fails the
    result is the safe stop u = 0 with ``status == "fallback"`` (counted in :attr:`stats`).

    Each call takes the cheapest exact route to the QP's solution: the command clipped to the
    input limits when it already meets every row; else the previous call's active set, re-solved
    and accepted only if it meets every optimality condition; else Clarabel on the rows that can
    bind. ``SafetyConfig(screening=False)`` always runs Clarabel on the full problem.
    """

    def __init__(self, scene: Scene, config: SafetyConfig | None = None) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        config = SafetyConfig() if config is None else config
        if not isinstance(config, SafetyConfig):
            raise TypeError(f"config must be a sabre.SafetyConfig, got {type(config).__name__}")
        self.scene = scene
        self.config = config
        self._core = _core.SafetyFilter(scene._core, config._core_config())

    def _passivity(
        self, tau_ext: Sequence[float] | np.ndarray | None, tank_energy: float | None
    ) -> tuple[np.ndarray | None, float | None]:
        if (tau_ext is None) != (tank_energy is None):
            raise InvalidValueError("passivity: give both tau_ext and tank_energy, or neither")
        if tau_ext is None or tank_energy is None:
            return None, None
        tau = _vector("tau_ext", tau_ext, self.scene.nq)
        return tau, as_finite("tank_energy", tank_energy)

    def filter(
        self,
        x: Sequence[float] | np.ndarray,
        u_ref: Sequence[float] | np.ndarray,
        tau_ext: Sequence[float] | np.ndarray | None = None,
        tank_energy: float | None = None,
    ) -> FilterResult:
        """Filters the command u_ref (nq,) at state x (nx,); with τ_ext (nq,) and the tank energy S
        the passivity row is on (only in the inner loop, as in the paper)."""
        x = _vector("x", x, self.scene.nx)
        u_ref = _vector("u_ref", u_ref, self.scene.nq)
        tau, energy = self._passivity(tau_ext, tank_energy)
        r = self._core.filter(x, u_ref, tau, energy)
        return FilterResult(
            u=readonly(r.u),
            slack=readonly(r.slack),
            class_slack=MappingProxyType(dict(r.class_slack)),
            barrier=readonly(r.barrier),
            active=tuple(r.active),
            status=r.status,
            solver_status=r.solver_status,
            solve_time=r.solve_time,
            iterations=r.iterations,
            qp_rows=r.qp_rows,
            method=r.method,
        )

    def filter_sequence(self, x0: Sequence[float] | np.ndarray, U: np.ndarray, model: RolloutModel) -> SequenceResult:
        """Sequential FILTER-QP (Algorithm 1): filters U (K, nq) step by step while rolling it out
        from x0 in ``model`` (no passivity row: the paper enforces passivity in the inner loop)."""
        if not isinstance(model, RolloutModel):
            raise TypeError(f"model must be a sabre.RolloutModel, got {type(model).__name__}")
        x0 = as_float_array("x0", x0, (self.scene.nx,))
        U = as_float_array("U", U, (None, self.scene.nq))
        if U.shape[0] == 0:
            raise InvalidValueError("U: needs at least one step")
        u, states, status, fallbacks = self._core.filter_sequence(x0, U, model._core)
        return SequenceResult(U=readonly(u), states=readonly(states), status=tuple(status), fallbacks=int(fallbacks))

    # -- obstacles --------------------------------------------------------------------------
    def add_obstacle(self, center: Sequence[float] | np.ndarray, radius: float) -> int:
        """Adds a sphere obstacle (world centre (3,), radius in m); returns its id."""
        center = as_float_array("center", center, (3,))
        return self._core.add_obstacle(center.tolist(), as_positive("radius", radius))

    def move_obstacle(self, obstacle_id: int, center: Sequence[float] | np.ndarray) -> None:
        """Moves obstacle ``obstacle_id`` to the world centre (3,) in m. Raises InvalidValueError for an unknown id."""
        self._core.move_obstacle(as_count("obstacle_id", obstacle_id, 0), as_float_array("center", center, (3,)).tolist())

    def remove_obstacle(self, obstacle_id: int) -> None:
        """Removes obstacle ``obstacle_id``; its slot turns off. Raises InvalidValueError for an unknown id."""
        self._core.remove_obstacle(as_count("obstacle_id", obstacle_id, 0))

    @property
    def obstacles(self) -> list[Obstacle]:
        """The sphere obstacles in place, in id order."""
        return [Obstacle(int(i), (c[0], c[1], c[2]), float(r)) for i, c, r in self._core.obstacles]

    # -- inspection -------------------------------------------------------------------------
    @property
    def row_names(self) -> list[str]:
        """Names of the R rows, in the order of ``FilterResult.slack`` and ``barrier``."""
        return self._core.row_names

    @property
    def input_limits(self) -> np.ndarray:
        """(nq,) joint velocity limits, the hard input bounds."""
        return np.asarray(self._core.input_limits, dtype=np.float64)

    @property
    def stats(self) -> FilterStats:
        """Call, fallback and solver counters since construction or :meth:`reset_stats`."""
        return FilterStats(**dict(self._core.stats))

    def reset_stats(self) -> None:
        """Sets every counter of :attr:`stats` to zero."""
        self._core.reset_stats()

    def forget_active_set(self) -> None:
        """The next call ignores the previous active set (never needed for correctness: a
        remembered active set is used only after it passes every optimality check)."""
        self._core.forget_active_set()

    def constraint_rows(
        self,
        x: Sequence[float] | np.ndarray,
        tau_ext: Sequence[float] | np.ndarray | None = None,
        tank_energy: float | None = None,
    ) -> ConstraintRows:
        """The R rows of FILTER-QP at state x (nx,); with τ_ext (nq,, N·m) and the tank energy
        (J) the passivity row is on.

        Raises:
            ShapeError: x or tau_ext of the wrong length.
            InvalidValueError: non-finite input, or only one of tau_ext and tank_energy given.
        """
        x = as_float_array("x", x, (self.scene.nx,))
        tau, energy = self._passivity(tau_ext, tank_energy)
        a, b, h = self._core.constraint_rows(x, tau, energy)
        return ConstraintRows(a=readonly(a), b=readonly(b), h=readonly(h))

    def qp_matrices(
        self,
        x: Sequence[float] | np.ndarray,
        u_ref: Sequence[float] | np.ndarray,
        tau_ext: Sequence[float] | np.ndarray | None = None,
        tank_energy: float | None = None,
    ) -> QPMatrices:
        """The full QP at state x (nx,) for the command u_ref (nq,), as dense arrays, for
        cross-checks with other solvers (arguments as for :meth:`filter`).

        Raises:
            ShapeError: an argument of the wrong length.
            InvalidValueError: non-finite input, or only one of tau_ext and tank_energy given.
        """
        x = as_float_array("x", x, (self.scene.nx,))
        u_ref = as_float_array("u_ref", u_ref, (self.scene.nq,))
        tau, energy = self._passivity(tau_ext, tank_energy)
        d = dict(self._core.qp_matrices(x, u_ref, tau, energy))
        return QPMatrices(P=readonly(d["P"]), q=readonly(d["q"]), A=readonly(d["A"]), b=readonly(d["b"]), nu=int(d["nu"]))

    def __repr__(self) -> str:
        return f"SafetyFilter({self.scene!r}, rows={len(self.row_names)})"


@dataclass(frozen=True)
class TankRefill:
    """Refill of the energy tank by the energy the current plan is predicted to need (beyond the paper).

    A fixed S(0) runs out on a long task: opening the shelf costs about 4 J per radian, and every
    contact before the open phase spends more. With a refill, while the plant does what the rollout
    model predicted, the inner loop adds the port dissipation −τ_extᵀu (49) that the model predicts
    along the rollout of the current plan to the tank, at most ``max_rate`` (W) and never above
    S(0). Both the measured −τ̂ᵀu of the step's reference and the predicted value pass a first-order
    low-pass of ``time_constant`` (s) and must agree within ``tolerance`` (W) +
    ``relative_tolerance``·|predicted|: a stall the model did not predict (a held door: the model
    lets it move, the plant's wrench grows) stops the refill, and the passivity row (56) bounds the
    wrench as in the paper.
    """

    max_rate: float = _REFILL.max_rate
    tolerance: float = _REFILL.tolerance
    relative_tolerance: float = _REFILL.relative_tolerance
    time_constant: float = _REFILL.time_constant

    def __post_init__(self) -> None:
        for name in ("max_rate", "tolerance", "relative_tolerance"):
            as_non_negative(name, getattr(self, name))
        as_positive("time_constant", self.time_constant)

    def _core_config(self) -> _core.TankRefillConfig:
        return core_config(
            _core.TankRefillConfig,
            max_rate=float(self.max_rate),
            tolerance=float(self.tolerance),
            relative_tolerance=float(self.relative_tolerance),
            time_constant=float(self.time_constant),
        )


class EnergyTank:
    """The virtual energy tank (paper Sec. III-C, IV-C): S(0) = ``initial``, floor ε = ``floor``.

    ``step(tau_ext, u, dt)`` integrates Ṡ = τ_extᵀu (49) with explicit Euler: τ_ext is the external
    torque on the robot, so the power the robot pushes into the environment, −τ_extᵀu, drains the
    tank, and work done on the robot refills it (up to ``ceiling``, if given). The energy is never
    clamped at the floor; keeping it there is the passivity row's job. ``history`` holds S(0) and
    every step's energy when ``record_history``. With ``refill`` (:class:`TankRefill`) the inner
    loop also refills it while the plant follows the plan's prediction.
    """

    def __init__(
        self,
        initial: float = _TANK.initial,
        floor: float = _TANK.floor,
        *,
        ceiling: float | None = _TANK.ceiling,
        record_history: bool = _TANK.record_history,
        refill: TankRefill | None = None,
    ) -> None:
        config = core_config(
            _core.EnergyTankConfig,
            initial=as_finite("initial", initial),
            floor=as_finite("floor", floor),
            ceiling=None if ceiling is None else as_finite("ceiling", ceiling),
            record_history=bool(record_history),
        )
        if refill is not None and not isinstance(refill, TankRefill):
            raise InvalidValueError(f"refill must be a sabre.TankRefill or None, got {type(refill).__name__}")
        self._core = _core.EnergyTank(config)
        self._refill = refill
        if refill is not None:
            self._core.set_refill(refill._core_config())

    @property
    def refill_config(self) -> TankRefill | None:
        """The refill's settings, or None without a refill."""
        return self._refill

    def refill(self, predicted: float, measured: float, dt: float) -> float:
        """One refill step (see :class:`TankRefill`) from the predicted and measured port dissipation
        −τ_extᵀu (W) over dt (s); returns the energy added (J), 0 without a refill."""
        return self._core.refill(as_finite("predicted", predicted), as_finite("measured", measured), as_positive("dt", dt))

    @property
    def refilled(self) -> float:
        """Energy (J) the refill added since the last reset."""
        return self._core.refilled

    def step(self, tau_ext: Sequence[float] | np.ndarray, u: Sequence[float] | np.ndarray, dt: float) -> float:
        """Integrates Ṡ = τ_extᵀu (49) over dt (s) with τ_ext (nq,) in N·m and u (nq,) the command; returns S (J)."""
        tau = as_float_array("tau_ext", tau_ext, (None,))
        u = as_float_array("u", u, (tau.shape[0],))
        return self._core.step(tau, u, as_positive("dt", dt))

    def reset(self) -> None:
        """Puts the energy back to :attr:`initial` and clears the history."""
        self._core.reset()

    @property
    def energy(self) -> float:
        """Current energy S (J)."""
        return self._core.energy

    @property
    def initial(self) -> float:
        """S(0) (J)."""
        return self._core.initial

    @property
    def floor(self) -> float:
        """The floor ε (J) the passivity row keeps S above."""
        return self._core.floor

    @property
    def ceiling(self) -> float | None:
        """Upper bound of S (J), or None."""
        return self._core.ceiling

    @property
    def residual(self) -> float:
        """S − ε: the energy the passivity row still lets the robot dissipate."""
        return self._core.residual

    @property
    def history(self) -> np.ndarray:
        """(steps + 1,) S(0) and the energy after every step (J); empty without ``record_history``."""
        return readonly(self._core.history)

    def __repr__(self) -> str:
        return f"EnergyTank(energy={self.energy:.3f}, floor={self.floor})"
