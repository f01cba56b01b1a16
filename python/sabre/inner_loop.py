"""The inner loop: the low-level joint-velocity controller (53), the 1 kHz loop that makes a plant follow a
planned reference (optionally through the FILTER-QP and the energy tank), and the plan it follows as a value
(:class:`PlanSnapshot`).

Every tick is the core's cascade (``_core.Cascade``, built by :func:`inner_cascade`): :class:`sabre.Plant`
is driven in Rust, a whole stretch of steps per call (:func:`follow_plant`); any other
:class:`~sabre.PlantInterface` is driven step by step from Python with the same tick, so both record the
same :class:`Trace`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._validate import as_accelerations, as_count, as_float_array, as_non_negative, as_positive, core_config, readonly
from .errors import InvalidValueError, ShapeError
from .plants import PlantInterface, as_plant
from .safety import EnergyTank, SafetyConfig, SafetyFilter
from .scene import Scene
from .sim import Plant

__all__ = ["LowLevelController", "Trace", "PlanSnapshot", "inner_cascade", "follow_plant"]

# The core's defaults, the one source of every default below.
_PLANT = _core.PlantConfig()
_LOW_LEVEL = _core.LowLevelConfig()


class LowLevelController:
    """Dynamics-compensated PI joint-velocity controller (53) for the plant.

    τ = M(q) q̈* + (M(q) + A) (Λ_D (q̇* − q̇) + Λ_I ∫(q̇* − q̇)) + g(q): (53) with K_D = (M + A) Λ_D and
    K_I = (M + A) Λ_I, so the plant's free-motion velocity response matches the rollout model's servo
    of the same bandwidth. ∫(q̇* − q̇) is clipped to ±``integral_limit`` (rad) per joint.

    A = diag(max(0, gain_inertia_floor − M_ii)) keeps the gains of light joints from vanishing: the
    last wrist joint turns only the hand (M_ii ≈ 0.007 kg m²), and with K = M Λ alone it would give
    0.27 N m per rad/s and 0.27 N m of integral torque, so a hook pulling on a held door twists the
    hand until the finger slides off the bar. ``gain_inertia_floor=0`` (the default) is plain (53);
    ``"auto"`` chooses one from the robot's dynamics and the step (:attr:`max_stable_floor`); a
    task can ask for a floor per phase (:meth:`sabre.tasks.Task.gain_inertia_floor`). A floor too
    large for the step, one that would make a light joint diverge, is refused when the controller
    drives the plant (:meth:`track`, :meth:`follow`).

    ``command_acceleration`` (nq,) makes the controller the robot's command path too: it tracks a
    command that follows the reference at most that fast per joint (rad/s² or m/s²; a base driver's
    ramp, a trajectory's or a stream's acceleration bound), from the measured velocity after a reset,
    as :class:`sabre.RolloutModel`'s servo does with its own ``command_acceleration``. A cascade
    built on it (:func:`sabre.run_episode`) brakes each joint toward its limits no faster. None (the
    default): the reference is tracked as given.
    """

    def __init__(
        self,
        scene: Scene,
        dt: float = _PLANT.dt,
        *,
        bandwidth: float = _LOW_LEVEL.bandwidth,
        integral_gain: float = _LOW_LEVEL.integral_gain,
        integral_limit: float = _LOW_LEVEL.integral_limit,
        gain_inertia_floor: float | str = _LOW_LEVEL.gain_inertia_floor,
        command_acceleration: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        self.scene = scene
        self.dt = dt = as_positive("dt", dt)
        auto = gain_inertia_floor == "auto"
        config = core_config(
            _core.LowLevelConfig,
            bandwidth=as_positive("bandwidth", bandwidth),
            integral_gain=as_non_negative("integral_gain", integral_gain),
            integral_limit=as_non_negative("integral_limit", integral_limit),
            gain_inertia_floor=0.0 if auto else as_non_negative("gain_inertia_floor", gain_inertia_floor),
        )
        self._core = _core.LowLevelController(scene._core, dt, config)
        if auto:
            self._core.gain_inertia_floor = 0.5 * self.max_stable_floor
        if command_acceleration is not None:
            self._core.command_acceleration = as_accelerations("command_acceleration", command_acceleration, scene.nq)

    @property
    def command_acceleration(self) -> np.ndarray | None:
        """(nq,) the bounds at which the tracked command follows the reference, or None."""
        a = self._core.command_acceleration
        return None if a is None else readonly(np.asarray(a, dtype=float))

    @property
    def max_stable_floor(self) -> float:
        """The largest gain inertia floor (kg m²) at which no joint's loop overshoots at the step ``dt``:
        a joint of inertia m (felt with the others free) and diagonal mass-matrix entry M_jj gets a
        loop gain Λ_D·dt·(1 + max(0, floor − M_jj)/m) per step, at most 1 (above 2 it diverges).
        Driving the plant with a larger floor raises :class:`InvalidValueError` naming the joint.
        ``gain_inertia_floor="auto"`` takes half of it: light joints stiff enough to hold a hook on
        its bar, every joint well within its stable gain."""
        return float(self._core.max_stable_floor(self.dt))

    @property
    def gain_inertia_floor(self) -> float:
        """The floor (kg m²) on the joint inertia the PI gains scale with; settable between ticks
        (the integral is kept), which is how :func:`run_episode` applies a task's per-phase value."""
        return self._core.gain_inertia_floor

    @gain_inertia_floor.setter
    def gain_inertia_floor(self, floor: float) -> None:
        self._core.gain_inertia_floor = as_non_negative("gain_inertia_floor", floor)

    def reset(self) -> None:
        """Clears the integrator and the reference history."""
        self._core.reset()

    def torque(self, x: Sequence[float] | np.ndarray, u_ref: Sequence[float] | np.ndarray) -> np.ndarray:
        """(nq,) joint torques that make the robot at state x (nx,) track the velocities u_ref (nq,)."""
        x = as_float_array("x", x, (self.scene.nx,))
        u_ref = as_float_array("u_ref", u_ref, (self.scene.nq,))
        return np.asarray(self._core.torque(x, u_ref), dtype=np.float64)

    def track(self, plant: PlantInterface, u_ref: Sequence[float] | np.ndarray, steps: int = 1) -> None:
        """Runs ``steps`` plant steps (default 1) with this controller tracking the constant joint
        velocity reference u_ref (nq,) in rad/s (m/s for the prismatic base joints). A velocity plant
        (:attr:`~sabre.PlantInterface.command_interface` ``"velocity"``) gets u_ref itself, its own
        servo tracks it.

        Raises:
            TypeError: plant is not a :class:`~sabre.PlantInterface` (naming what it lacks).
            ShapeError: u_ref is not (nq,). InvalidValueError: non-finite u_ref or negative steps.
        """
        self._check_plant(plant)
        u_ref = as_float_array("u_ref", u_ref, (plant.scene.nq,))
        steps = as_count("steps", steps, 0)
        if isinstance(plant, Plant):
            self._core.track(plant._core, u_ref, steps)
            return
        for _ in range(steps):
            if plant.command_interface == "velocity":
                plant.step(u_ref.copy())
            else:
                plant.step(np.asarray(self._core.torque(_vector("plant.state", plant.state), u_ref), dtype=np.float64))

    def follow(
        self,
        plant: PlantInterface,
        reference: np.ndarray,
        t0: float,
        dt: float,
        steps: int,
        record_every: int = 1,
        *,
        safety: SafetyFilter | None = None,
        tank: EnergyTank | None = None,
        predicted_dissipation: np.ndarray | None = None,
    ) -> Trace:
        """The inner loop for ``steps`` plant steps: the reference sequence (K, nq) of joint
        velocities, sampled every ``dt`` seconds from time ``t0`` (s), is interpolated at the plant's
        time and tracked by this controller (a velocity plant gets the command and tracks it itself).

        Every step's command is held to the hard joint-limit bound (``safety``'s config, else the defaults:
        :class:`~sabre.SafetyConfig`'s ``limit_margin``). With ``safety`` each step's command goes through
        the FILTER-QP (41) first; with ``tank`` too,
        its passivity row (56) uses the plant's last measured τ_ext and the tank's energy, and the
        tank integrates the filtered command over the step against that same reading (49), the one
        the row saw, as a controller on a robot must (it cannot know the next reading).
        A tank without a filter only keeps the books. ``predicted_dissipation`` (K,), on the
        reference's time grid, is the plan's predicted port dissipation −τ_extᵀu (W) that a tank with a refill
        (:class:`~sabre.TankRefill`) is refilled by while the measurement agrees. Records every
        ``record_every``-th step (default: every step).

        :class:`sabre.Plant` runs the whole stretch in Rust; any other :class:`~sabre.PlantInterface`
        is stepped from Python through the same tick, recording the same trace.

        Raises:
            TypeError: plant, safety or tank of the wrong type (a plant: naming what it lacks).
            ShapeError: reference is not (K, nq).
            InvalidValueError: an empty or non-finite reference, a filter built for another scene,
                non-positive dt, negative steps, record_every < 1.
        """
        self._check_plant(plant)
        if safety is not None and not isinstance(safety, SafetyFilter):
            raise TypeError(f"safety must be a sabre.SafetyFilter, got {type(safety).__name__}")
        if tank is not None and not isinstance(tank, EnergyTank):
            raise TypeError(f"tank must be a sabre.EnergyTank, got {type(tank).__name__}")
        if safety is not None and (safety.scene.nq != plant.scene.nq or safety.scene.nx != plant.scene.nx):
            raise InvalidValueError("safety: the filter was built for a different scene than the plant's")
        reference = as_float_array("reference", reference, (None, plant.scene.nq))
        if reference.shape[0] == 0:
            raise InvalidValueError("reference: needs at least one step")
        t0 = float(t0)
        if not np.isfinite(t0):
            raise InvalidValueError(f"t0: must be finite, got {t0}")
        dt = as_positive("dt", dt)
        steps = as_count("steps", steps, 0)
        record_every = as_count("record_every", record_every, 1)
        predicted = (
            None if predicted_dissipation is None else as_float_array("predicted_dissipation", predicted_dissipation, (None,))
        )
        cascade = inner_cascade(self, safety, tank)
        cascade.hand_over(_core.Plan(reference, t0, dt, None if predicted is None or predicted.size == 0 else predicted))
        return follow_plant(cascade, plant, steps, record_every)

    def _check_plant(self, plant: PlantInterface) -> None:
        if not isinstance(plant, Plant):
            as_plant(plant, self.scene)
        elif plant.scene.nq != self.scene.nq:
            raise InvalidValueError("plant: the controller was built for a different scene than the plant's")


def _vector(name: str, value: Any) -> np.ndarray:
    """A plant's reading as the C-contiguous float64 array the core takes (its shape and values are
    checked there)."""
    try:
        return np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name}: cannot be read as a float array ({exc})") from None


class _StepRecord:
    """The rows :func:`follow_plant` records stepping a plant from Python, under the names of the core's trace
    dict."""

    def __init__(self, has_filter: bool, has_tank: bool) -> None:
        names = ["time", "state", "reference", "wrench", "tau_ext", "tau_ext_measured", "contact"]
        names += ["filtered", "filter_status"] if has_filter else []
        names += ["tank_energy"] if has_tank else []
        self.rows: dict[str, list[Any]] = {name: [] for name in names}

    def add(self, plant: PlantInterface, reference: np.ndarray, command: np.ndarray, energy: float | None, status: str) -> None:
        rows = self.rows
        rows["time"].append(float(plant.time))
        rows["state"].append(_vector("plant.state", plant.state))
        rows["reference"].append(reference)
        rows["wrench"].append(_vector("plant.wrench", plant.wrench))
        rows["tau_ext"].append(_vector("plant.tau_ext", plant.tau_ext))
        rows["tau_ext_measured"].append(_vector("plant.measured_tau_ext", plant.measured_tau_ext))
        rows["contact"].append(bool(plant.contact))
        if "filtered" in rows:
            rows["filtered"].append(command)
            rows["filter_status"].append(status)
        if "tank_energy" in rows:
            rows["tank_energy"].append(np.nan if energy is None else energy)

    def arrays(self, nx: int, nq: int) -> dict[str, Any]:
        widths = {"state": nx, "reference": nq, "wrench": 6, "tau_ext": nq, "tau_ext_measured": nq, "filtered": nq}
        out: dict[str, Any] = {}
        for name, rows in self.rows.items():
            if name == "filter_status":
                out[name] = rows
            elif name == "contact":
                out[name] = np.array(rows, dtype=bool)
            elif name in widths:
                out[name] = np.array(rows, dtype=np.float64).reshape(len(rows), widths[name])
            else:
                out[name] = np.array(rows, dtype=np.float64)
        return out


def inner_cascade(
    low_level: LowLevelController,
    safety: SafetyFilter | None = None,
    tank: EnergyTank | None = None,
    limits: SafetyConfig | None = None,
    **tau_ext: Any,
) -> _core.Cascade:
    """The core's cascade of ``low_level`` with the optional FILTER-QP ``safety`` and energy ``tank`` (their
    state shared with their holders); every command held to the hard joint-limit bound of ``limits``
    (:class:`~sabre.SafetyConfig`'s ``limit_margin``, ``prismatic_limit_margin``, ``limit_deceleration``;
    None: the filter's config, the defaults without a filter); ``tau_ext`` are the core's τ_ext conditioning
    (``tau_ext_cutoff``, ``tau_ext_timeout``, ``wrench_frames``). The one place a cascade is assembled."""
    if limits is not None and not isinstance(limits, SafetyConfig):
        raise TypeError(f"limits must be a sabre.SafetyConfig, got {type(limits).__name__}")
    return _core.Cascade(
        low_level._core,
        None if safety is None else safety._core,
        None if tank is None else tank._core,
        limit_bound=None if limits is None else limits._limit_bound(),
        **tau_ext,
    )


def follow_plant(cascade: _core.Cascade, plant: PlantInterface, steps: int, record_every: int) -> Trace:
    """``steps`` plant steps of ``cascade`` on the plans handed to it: in one call into the core for a
    :class:`sabre.Plant`, else one tick per step at the plant's state, τ_ext reading and time, integrating
    over its step, and a plant step with the torque (a torque plant) or the command (a velocity plant);
    the :class:`Trace` of every ``record_every``-th step."""
    if isinstance(plant, Plant):
        return _trace(cascade.follow(plant._core, steps, record_every))
    velocity = plant.command_interface == "velocity"
    dt = float(plant.dt)
    record = _StepRecord(cascade.filter is not None, cascade.tank is not None)
    for step in range(steps):
        x = _vector("plant.state", plant.state)
        tau_ext = _vector("plant.measured_tau_ext", plant.measured_tau_ext)
        reference, command, torque, energy, status = cascade.tick(x, tau_ext, float(plant.time), dt)
        plant.step(command if velocity else torque)
        if step % record_every == 0:
            record.add(plant, reference, command, energy, status)
    return _trace(record.arrays(plant.scene.nx, plant.scene.nq))


def _trace(d: dict[str, Any]) -> Trace:
    """The :class:`Trace` of a follow's trace dict."""
    status = d.get("filter_status")
    return Trace(
        time=readonly(d["time"]),
        state=readonly(d["state"]),
        reference=readonly(d["reference"]),
        filtered=readonly(d["filtered"]) if "filtered" in d else None,
        filter_status=None if status is None else tuple(status),
        tank_energy=readonly(d["tank_energy"]) if "tank_energy" in d else None,
        wrench=readonly(d["wrench"]),
        tau_ext=readonly(d["tau_ext"]),
        tau_ext_measured=readonly(d["tau_ext_measured"]),
        contact=readonly(d["contact"]),
    )


@dataclass(frozen=True)
class Trace:
    """What :meth:`LowLevelController.follow` recorded, one row per recorded plant step (M rows).

    Attributes:
        time: (M,) plant time after the step (s).
        state: (M, nx) state after the step.
        reference: (M, nq) interpolated reference command of the step.
        filtered: (M, nq) command after the safety filter (what the low-level controller tracked),
            or None without a filter.
        filter_status: (M,) the filter's status per step (``"solved"``, ``"almost_solved"``,
            ``"fallback"``), or None without a filter.
        tank_energy: (M,) tank energy after the step (J), or None without a tank.
        wrench: (M, 6) wrist wrench; tau_ext: (M, nq) external joint torques from the contact
            forces of the step; tau_ext_measured: (M, nq) the plant's τ_ext measurement after the
            step (:attr:`Plant.measured_tau_ext`); contact: (M,) bool.
    """

    time: np.ndarray
    state: np.ndarray
    reference: np.ndarray
    filtered: np.ndarray | None
    filter_status: tuple[str, ...] | None
    tank_energy: np.ndarray | None
    wrench: np.ndarray
    tau_ext: np.ndarray
    tau_ext_measured: np.ndarray
    contact: np.ndarray

    @property
    def fallback(self) -> np.ndarray | None:
        """(M,) bool: the filter fell back to the safe stop in that step (None without a filter)."""
        return None if self.filter_status is None else np.array([s == "fallback" for s in self.filter_status])


@dataclass(frozen=True)
class PlanSnapshot:
    """A plan as a value: what the planner hands the inner loop (:meth:`sabre.Controller.snapshot`, the
    planner process, :meth:`sabre.RealtimeCascade.plan`). Immutable and picklable; the planner moving on
    never changes it.

    ``plan`` (the core's) holds the reference (K, nu) with row k applying at t0 + k·dt, the predicted port
    dissipation (K,) for the tank's refill (None without one) and the low-level gain inertia floor of the
    planned phase (None: the low-level controller's own); the inner loop's tick reads it as is. Next to it:
    the task ``phase`` the plan is for, the planning iteration's wall time (s), the number of iterations
    since the planner's reset (0 before the first) and the nominal's cost (NaN before the first).
    """

    plan: _core.Plan
    phase: str = ""
    iteration_time: float = float("nan")
    iterations: int = 0
    nominal_cost: float = float("nan")

    @staticmethod
    def of(
        nominal: np.ndarray,
        t0: float,
        dt: float,
        *,
        predicted: np.ndarray | None = None,
        gain_inertia_floor: float | None = None,
        phase: str = "",
        iteration_time: float = float("nan"),
        iterations: int = 0,
        nominal_cost: float = float("nan"),
    ) -> PlanSnapshot:
        """The snapshot of the reference ``nominal`` (K, nu) starting at ``t0`` (s) on a grid of ``dt`` (s).

        Raises:
            ShapeError: nominal not (K, nu) with K ≥ 1, predicted not (K,).
            InvalidValueError: non-finite values, dt not positive, a negative floor.
        """
        nominal = as_float_array("nominal", nominal, (None, None))
        if predicted is not None:
            predicted = as_float_array("predicted", predicted, (None,))
        plan = _core.Plan(
            nominal, float(t0), float(dt), predicted, None if gain_inertia_floor is None else float(gain_inertia_floor)
        )
        return PlanSnapshot(plan, str(phase), float(iteration_time), int(iterations), float(nominal_cost))

    @property
    def nominal(self) -> np.ndarray:
        """(K, nu) the reference sequence (a copy)."""
        return self.plan.reference

    @property
    def t0(self) -> float:
        """Time (s) at which row 0 of :attr:`nominal` applies."""
        return self.plan.t0

    @property
    def dt(self) -> float:
        """Time (s) between the rows of :attr:`nominal`."""
        return self.plan.dt

    @property
    def predicted(self) -> np.ndarray | None:
        """(K,) the predicted port dissipation −τ_extᵀu (W) on the grid of :attr:`nominal` (a copy), or None."""
        return self.plan.predicted_dissipation

    @property
    def gain_inertia_floor(self) -> float | None:
        """The low-level gain inertia floor (kg m²) of the planned phase; None: the low-level controller's own."""
        return self.plan.gain_inertia_floor

    def reference(self, t: float) -> np.ndarray:
        """(nu,) the reference at time t (s): linear between rows, held at both ends."""
        return np.asarray(self.plan.reference_at(float(t)), dtype=np.float64)

    def predicted_dissipation(self, t: float) -> float | None:
        """The predicted port dissipation (W) at time t (s), interpolated as :meth:`reference`; None without one."""
        return self.plan.predicted_dissipation_at(float(t))
