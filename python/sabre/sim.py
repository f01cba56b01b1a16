"""Simulation: the reduced-order rollout model (batched, parallel) and the 1 kHz plant with its contact reports."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import _core
from ._validate import as_accelerations, as_count, as_float_array, as_non_negative, as_positive, core_config, readonly
from .errors import InvalidValueError
from .scene import Scene

#: Default bandwidth (Hz) of :attr:`Plant.measured_tau_ext`.
DEFAULT_TAU_EXT_CUTOFF: float = _core.DEFAULT_TAU_EXT_CUTOFF

# The core's defaults, the one source of every default below.
_ROLLOUT = _core.RolloutConfig()
_PLANT = _core.PlantConfig()

__all__ = [
    "RolloutModel",
    "RolloutResult",
    "Plant",
    "ContactPoint",
    "default_threads",
    "MAX_THREADS",
    "DEFAULT_TAU_EXT_CUTOFF",
    "CONTACT_MODELS",
]

#: The rollout model's contact paths: "reduced" (contacts from parry's manifolds, one small soft
#: solve in sabre against the object's joint coordinates) and "rapier" (Rapier's whole pipeline,
#: the reference the reduced path is validated against; several times slower in contact).
CONTACT_MODELS: tuple[str, ...] = _core.CONTACT_MODELS

#: Largest worker-thread count accepted (pools are cached per size).
MAX_THREADS = 256


def default_threads() -> int:
    """Worker threads used when ``threads=None``: every core available to the process."""
    return _core.default_threads()


@dataclass(frozen=True)
class RolloutResult:
    """Outputs of N rollouts of K steps (all float64 unless noted).

    Attributes:
        states: (N, K+1, nx) states; ``states[:, 0]`` is x0. The object's velocity ȯ after each step
            is the rate at which it moved over that step.
        tau_ext: (N, K, nq) external joint torques τ_ext = Σ J_cᵀ f_c during each step (forces on the robot).
        wrench: (N, K, 6) force (N) and torque (N·m) on the hand and hook about the wrist flange, world frame.
        contact: (N, K) bool, robot–object contact carried force in that step.
        failed: (N,) bool, the physics diverged; that rollout is NaN from the failing step on.
        engine_steps: (N,) int64, steps that went through the contact path (Rapier's pipeline, or
            the reduced detection and solve); the others were skipped because nothing could move
            the object (``skip_quiescent_steps``).
        engine_time: (N,) wall time (s) each rollout spent in those steps, the physics engine's
            own share of the work (the rest is the servo, contact measurement and cost).
            A timing, so it varies from run to run; everything else is deterministic.
    """

    states: np.ndarray
    tau_ext: np.ndarray
    wrench: np.ndarray
    contact: np.ndarray
    failed: np.ndarray
    engine_steps: np.ndarray
    engine_time: np.ndarray


class RolloutModel:
    """The reduced-order model the controller plans with (paper Sec. V-F, eq. 57).

    Robot joints follow the commanded velocities through a PI velocity servo, q̈ = Λ (u − q̇) +
    Λ_I ∫(u − q̇) + M(q)⁻¹ τ_ext, with Λ = ``servo_bandwidth`` (1/s) and Λ_I = ``servo_integral_gain``
    (1/s²) — the structure of the plant's low-level controller — pushed back by contact forces and
    bounded by the joint torque limits; only the hand, hook and forearm colliders touch the object,
    as free bodies carrying the robot's effective mass; the object has joint limits, damping, dry
    friction and gravity. ``contact_model`` (:data:`CONTACT_MODELS`) chooses how their contacts are
    resolved: "reduced" finds them with parry's contact manifolds and solves them in sabre against
    the object's joint coordinates; "rapier" runs Rapier's whole pipeline with the object as a
    multibody, the reference the reduced path is tested against. With ``multibody_robot=True``
    (Rapier only) the servo loop itself is simulated by Rapier's multibody solver (more faithful
    robot compliance, several times slower). While the object is statically held
    (at rest, its dry friction or a limit holding it against gravity) and no contact body can reach
    it within a step, the physics step is skipped — it could not change anything — unless
    ``skip_quiescent_steps=False``.

    ``command_acceleration`` (nq,): per joint, the largest acceleration (rad/s² or m/s²) the robot's
    command path gives it (an arm's trajectory or command stream bound, a base driver's ramp): the
    servo tracks the commands rate-limited at it, starting from the state's velocity. None (the
    default): the commands as given, as for a plant driven directly. A robot whose commands are
    rate-limited needs it: a plan from a faster model asks the slow joints for what they cannot
    follow while the others follow at once.

    Rollouts run in parallel on ``threads`` workers (default: all cores), each with its own physics
    world restored from a pristine snapshot before every rollout; the GIL is released and the
    results are bit-identical for any thread count.
    """

    def __init__(
        self,
        scene: Scene,
        dt: float = _ROLLOUT.dt,
        *,
        servo_bandwidth: float = _ROLLOUT.servo_bandwidth,
        servo_integral_gain: float = _ROLLOUT.servo_integral_gain,
        servo_integral_limit: float = _ROLLOUT.servo_integral_limit,
        contact_friction: float = _ROLLOUT.contact_friction,
        solver_iterations: int = _ROLLOUT.solver_iterations,
        multibody_robot: bool = _ROLLOUT.multibody_robot,
        skip_quiescent_steps: bool = _ROLLOUT.skip_quiescent_steps,
        contact_model: str = _ROLLOUT.contact_model,
        command_acceleration: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        if contact_model not in CONTACT_MODELS:
            raise InvalidValueError(f"contact_model must be one of {CONTACT_MODELS}, got {contact_model!r}")
        self.contact_model = contact_model
        self.scene = scene
        self.dt = as_positive("dt", dt)
        config = core_config(
            _core.RolloutConfig,
            dt=self.dt,
            servo_bandwidth=as_positive("servo_bandwidth", servo_bandwidth),
            servo_integral_gain=as_non_negative("servo_integral_gain", servo_integral_gain),
            servo_integral_limit=as_non_negative("servo_integral_limit", servo_integral_limit),
            contact_friction=as_non_negative("contact_friction", contact_friction),
            solver_iterations=as_count("solver_iterations", solver_iterations),
            multibody_robot=bool(multibody_robot),
            skip_quiescent_steps=bool(skip_quiescent_steps),
            contact_model=contact_model,
            command_acceleration=None
            if command_acceleration is None
            else as_accelerations("command_acceleration", command_acceleration, scene.nq),
        )
        self._core = _core.RolloutModel(scene._core, config)

    def rollout(self, x0: Sequence[float] | np.ndarray, U: np.ndarray, threads: int | None = None) -> RolloutResult:
        """Simulates N input sequences U (N, K, nu) of joint velocities (rad/s, m/s for the base
        translation) from the state x0 (nx,), each step ``dt`` s long, on ``threads`` workers
        (default: :func:`default_threads`).

        Inputs are projected onto the joint velocity limits before they are applied.

        Raises:
            ShapeError: x0 or U of the wrong shape.
            InvalidValueError: non-finite x0 or U, threads outside [1, MAX_THREADS].
        """
        x0 = as_float_array("x0", x0, (self.scene.nx,))
        U = as_float_array("U", U, (None, None, self.scene.nu))
        if threads is not None:
            threads = as_count("threads", threads, maximum=MAX_THREADS)
        r = self._core.rollout(x0, U, threads)
        return RolloutResult(
            states=readonly(r.states),
            tau_ext=readonly(r.tau_ext),
            wrench=readonly(r.wrench),
            contact=readonly(r.contact),
            failed=readonly(r.failed),
            engine_steps=readonly(r.engine_steps.astype(np.int64)),
            engine_time=readonly(r.engine_time),
        )

    def __repr__(self) -> str:
        return f"RolloutModel({self.scene!r}, dt={self.dt}, contact_model={self.contact_model!r})"


@dataclass(frozen=True)
class ContactPoint:
    """One robot–object contact point of a plant step (world frame)."""

    robot_link: str
    object_link: str
    point: np.ndarray
    """(3,) contact point (m)."""
    force: np.ndarray
    """(3,) force acting on the robot at the point (N)."""


class Plant:
    """The stand-in for the real robot: full rigid-body dynamics of robot and object in Rapier.

    Joint-torque input (clamped to the effort limits), gravity, every collider of robot and object,
    a wrist force-torque reading from contact forces, and fault injection (:meth:`hold_object`,
    :meth:`push`). ``dt`` is at most 0.005 s (the robot's 1 kHz loop: 0.001); a step whose joints end
    faster than the divergence bound raises :class:`SimulationError` naming the joint.

    ``tau_ext_cutoff`` (Hz, or None) is the bandwidth of the external-torque measurement
    (:attr:`measured_tau_ext`) that the inner loop's passivity row and energy tank read: a
    first-order low-pass of the contact torques, like a real robot's momentum observer or filtered
    wrist sensor. Rigid contacts in the simulator deliver force as per-step impulses (a finger
    bouncing on a held door reads 0, 300, 0 N·m on consecutive steps); a controller reacting to
    that raw signal lets the full command through between impacts and chatters.

    One implementation of :class:`sabre.PlantInterface`, the one the closed loop drives in Rust.
    """

    #: :meth:`step` takes joint torques (:class:`sabre.PlantInterface`).
    command_interface = "torque"

    def __init__(
        self,
        scene: Scene,
        dt: float = _PLANT.dt,
        *,
        contact_friction: float = _PLANT.contact_friction,
        solver_iterations: int = _PLANT.solver_iterations,
        tau_ext_cutoff: float | None = _PLANT.tau_ext_cutoff,
    ) -> None:
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene, got {type(scene).__name__}")
        self.scene = scene
        config = core_config(
            _core.PlantConfig,
            dt=as_positive("dt", dt),
            contact_friction=as_non_negative("contact_friction", contact_friction),
            solver_iterations=as_count("solver_iterations", solver_iterations),
            tau_ext_cutoff=None if tau_ext_cutoff is None else as_positive("tau_ext_cutoff", tau_ext_cutoff),
        )
        self._core = _core.Plant(scene._core, config)

    @property
    def dt(self) -> float:
        """Plant step (s)."""
        return self._core.dt

    def reset(self, x0: Sequence[float] | np.ndarray | None = None) -> None:
        """Puts the plant at x0 (nx,) (default: the scene's default state), time 0, object released.

        Raises:
            ShapeError: x0 is not (nx,). InvalidValueError: non-finite x0, a joint more than 0.05
            (rad or m) beyond its limits, or a joint faster than the plant's divergence bound
            (20 × its velocity limit; 100 rad/s or m/s for the object).
        """
        x0 = self.scene.default_state() if x0 is None else as_float_array("x0", x0, (self.scene.nx,))
        self._core.reset(x0)

    def step(self, tau: Sequence[float] | np.ndarray) -> None:
        """Advances one step of dt under joint torques tau (nq,) in N·m (N for the base
        translation), clamped to the effort limits.

        Raises:
            ShapeError: tau is not (nq,). InvalidValueError: non-finite tau.
        """
        self._core.step(as_float_array("tau", tau, (self.scene.nq,)))

    @property
    def state(self) -> np.ndarray:
        """(nx,) current state [q, q̇, o, ȯ]."""
        return np.asarray(self._core.state, dtype=np.float64)

    @property
    def wrench(self) -> np.ndarray:
        """(6,) wrist force-torque reading of the last step (on the hand and hook, world frame)."""
        return np.asarray(self._core.wrench, dtype=np.float64)

    @property
    def tau_ext(self) -> np.ndarray:
        """(nq,) external joint torques of the last step, τ_ext = Σ J_cᵀ f_c."""
        return np.asarray(self._core.tau_ext, dtype=np.float64)

    @property
    def measured_tau_ext(self) -> np.ndarray:
        """(nq,) the external-torque measurement after the last step: :attr:`tau_ext` through a
        first-order low-pass at ``tau_ext_cutoff`` Hz (equal to it without a cutoff)."""
        return np.asarray(self._core.measured_tau_ext, dtype=np.float64)

    @property
    def contact(self) -> bool:
        """Whether any robot–object contact carried force in the last step."""
        return self._core.contact

    def contacts(self) -> list[ContactPoint]:
        """Every robot–object contact point of the last step, with the force it put on the robot.

        For diagnosing what the robot touches (which link against which object part); it
        allocates, so call it between steps, not inside a tight loop."""
        return [
            ContactPoint(robot_link=r, object_link=o, point=np.array(p, dtype=np.float64), force=np.array(f, dtype=np.float64))
            for r, o, p, f in self._core.contacts()
        ]

    @property
    def applied_torque(self) -> np.ndarray:
        """(nq,) torques applied in the last step, after the effort limits."""
        return np.asarray(self._core.applied_torque, dtype=np.float64)

    @property
    def time(self) -> float:
        """Simulated time since the last :meth:`reset` (s)."""
        return self._core.time

    @property
    def object_held(self) -> bool:
        """Whether the object is held in place by :meth:`hold_object` (fault injection)."""
        return self._core.object_held

    def hold_object(self, flag: bool) -> None:
        """Fault injection: ``True`` holds the object's joint where it is (stuck door); ``False`` releases it."""
        self._core.hold_object(bool(flag))

    def push(self, dv: Sequence[float] | np.ndarray) -> None:
        """Fault injection: an impulsive push adding ``dv`` (nq + no,: robot joints, then object
        joints; rad/s or m/s) to the joint velocities now, keeping time and contacts. Raises
        InvalidValueError if the resulting speeds leave the plant's range."""
        self._core.push(as_float_array("dv", dv, (self.scene.nq + self.scene.no,)).tolist())

    def object_energy(self) -> float:
        """Kinetic plus gravitational potential energy of the object (J), from its URDF inertials."""
        return self._core.object_energy()
