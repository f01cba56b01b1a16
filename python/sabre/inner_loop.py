"""The inner loop: the low-level joint-velocity controller (53) and the 1 kHz loop that makes the
plant follow a planned reference, optionally through the FILTER-QP and the energy tank."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import _core
from ._validate import as_count, as_float_array, as_non_negative, as_positive, core_config, readonly
from .errors import InvalidValueError
from .safety import EnergyTank, SafetyFilter
from .scene import Scene
from .sim import Plant

__all__ = ["LowLevelController", "Trace"]

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

    def track(self, plant: Plant, u_ref: Sequence[float] | np.ndarray, steps: int = 1) -> None:
        """Runs ``steps`` plant steps (default 1) with this controller tracking the constant joint
        velocity reference u_ref (nq,) in rad/s (m/s for the prismatic base joints).

        Raises:
            ShapeError: u_ref is not (nq,). InvalidValueError: non-finite u_ref or negative steps.
        """
        self._check_plant(plant)
        self._core.track(plant._core, as_float_array("u_ref", u_ref, (plant.scene.nq,)), as_count("steps", steps, 0))

    def follow(
        self,
        plant: Plant,
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
        time and tracked by this controller.

        With ``safety`` each step's command goes through the FILTER-QP (41) first; with ``tank`` too,
        its passivity row (56) uses the plant's last measured τ_ext and the tank's energy, and the
        tank integrates the filtered command against the newly measured τ_ext after the step (49).
        A tank without a filter only keeps the books. ``predicted_dissipation`` (K,), on the
        reference's time grid, is the plan's predicted port dissipation −τ_extᵀu (W) that a tank with a refill
        (:class:`~sabre.TankRefill`) is refilled by while the measurement agrees. Records every
        ``record_every``-th step (default: every step).

        Raises:
            TypeError: plant, safety or tank of the wrong type.
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
        d = self._core.follow(
            plant._core,
            reference,
            t0,
            as_positive("dt", dt),
            as_count("steps", steps, 0),
            as_count("record_every", record_every, 1),
            None if safety is None else safety._core,
            None if tank is None else tank._core,
            None if predicted_dissipation is None else as_float_array("predicted_dissipation", predicted_dissipation, (None,)),
        )
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

    def _check_plant(self, plant: Plant) -> None:
        if not isinstance(plant, Plant):
            raise TypeError(f"plant must be a sabre.Plant, got {type(plant).__name__}")
        if plant.scene.nq != self.scene.nq:
            raise InvalidValueError("plant: the controller was built for a different scene than the plant's")


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
