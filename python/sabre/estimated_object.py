"""An object known only by its handle, opened while its articulation is estimated: the scene the controller
plans with, rebuilt as the estimate moves, and the object's state read from the estimate."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from ._validate import as_float_array, as_non_negative, as_positive
from .articulation import ArticulationConfig, ArticulationEstimate, ArticulationEstimator
from .errors import InvalidValueError, ShapeError
from .estimation import LowPass
from .handle_object import DetectedHandle
from .scene import Scene

__all__ = ["EstimatedObject", "PULLING_PHASES", "SEATING_PHASE"]

#: The phases of :class:`sabre.tasks.OpenObject` in which the seated hook pulls the handle: the object's
#: opening follows the hand, and the hand's path traces the object's.
PULLING_PHASES = ("open", "hold")
#: Cutoff (Hz) of the low-pass on the wrist force that contact is read from.
FORCE_CUTOFF = 10.0
#: The phase in which the hook seats itself behind the bar.
SEATING_PHASE = "hook"


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


class EstimatedObject:
    """The object behind ``handle`` (:class:`~sabre.DetectedHandle`) for ``robot`` (a built-in name or a
    URDF file, with the robot ``options`` of :meth:`sabre.Scene.from_urdf`), its articulation estimated
    from the hand's path (:class:`~sabre.ArticulationEstimator`, ``config``).

    :attr:`scene` is the scene to plan with: at first the first pull's (a drawer along the handle's
    outward normal, its travel half as long again whenever the type is still open with two thirds of
    it done), rebuilt (:meth:`refresh`) when the estimate decides the type, or when its axis
    turns by more than ``rebuild_angle`` rad or its hinge moves by more than ``rebuild_distance`` m, at
    most every ``rebuild_interval`` s (a type decided rebuilds at once). :meth:`state` is the state the
    controller plans from: the robot's measured joints and the object's opening and rate along the
    estimate. :func:`sabre.run_episode` does this in simulation with ``estimated=``; a robot's loop
    does it with its own measurements.

    The object's opening follows the hand while the task's hook pulls (:data:`PULLING_PHASES`) and the
    wrist force, low-passed at :data:`FORCE_CUTOFF` Hz, reached ``contact_force`` N within the last
    ``release_time`` s (a drawer that coasts
    ahead of the hand for a moment is still where the hand is, near enough, and meets it again); the
    path is recorded while it pulls in contact (a hand that left the handle does not trace the
    object). The opening counts from where the hand holds the handle with the object closed, the
    handle frame's point :attr:`hook_point` (the task's hook target, which :func:`sabre.run_episode`
    sets), so that an object pulled open before the pull began reads as open by as much.

    While the hook seats itself (:data:`SEATING_PHASE`) the model holds the object closed, as the
    task's rules expect. An object the hand already pulls is reported by :attr:`hook_pulls`, and the
    loop lets the pull begin (a model of the object would have shown it moving): the hand within
    ``seat_across`` m of the hook point across the bar, and either ``seat_distance`` m out from it or
    pressed toward the panel by the bar with ``contact_force`` N for ``seat_time`` s.

    ``simulated_noise`` = (σ position in m, σ force in N) adds Gaussian noise (seeded by ``seed``) to
    every hand position and wrench component before use: a simulated robot's sensors, for evaluation.

    Raises:
        TypeError: ``handle`` is no DetectedHandle. InvalidValueError: negative thresholds or noise.
        UrdfError: a robot that does not load.
    """

    def __init__(
        self,
        robot: str | os.PathLike[str],
        handle: DetectedHandle,
        *,
        config: ArticulationConfig | None = None,
        contact_force: float = 1.0,
        release_time: float = 0.5,
        seat_time: float = 0.1,
        seat_distance: float = 0.01,
        seat_across: float = 0.008,
        rebuild_angle: float = math.radians(1.0),
        rebuild_distance: float = 0.01,
        rebuild_interval: float = 0.2,
        simulated_noise: tuple[float, float] | None = None,
        seed: int = 0,
        **options: Any,
    ) -> None:
        self._robot, self._options = robot, options
        self.scene = Scene.from_handle(robot, handle, None, **options)
        self.handle = handle
        self.estimator = ArticulationEstimator(handle.pose, handle.prior, config)
        self.contact_force = as_non_negative("contact_force", contact_force)
        self.release_time = as_non_negative("release_time", release_time)
        self._touched_at = -math.inf
        self._force = LowPass(FORCE_CUTOFF)
        self._force_time: float | None = None
        self.seat_time = as_non_negative("seat_time", seat_time)
        self.seat_distance = as_positive("seat_distance", seat_distance)
        self.seat_across = as_positive("seat_across", seat_across)
        self._pressed_since: float | None = None
        #: Whether the seating hook already pulls the handle (see the class).
        self.hook_pulls = False
        self.rebuild_angle = as_positive("rebuild_angle", rebuild_angle)
        self.rebuild_distance = as_positive("rebuild_distance", rebuild_distance)
        self.rebuild_interval = as_non_negative("rebuild_interval", rebuild_interval)
        if simulated_noise is not None:
            simulated_noise = (
                as_non_negative("simulated_noise[0]", simulated_noise[0]),
                as_non_negative("simulated_noise[1]", simulated_noise[1]),
            )
        self.simulated_noise = simulated_noise
        self._rng = np.random.default_rng(seed)
        self._hand = self.scene.require_tool_frame("EstimatedObject")
        self._rebuilt_at = -math.inf
        #: (time, estimate) after each :meth:`observe`.
        self.history: list[tuple[float, ArticulationEstimate]] = []
        #: Times (s) the scene was rebuilt.
        self.rebuilds: list[float] = []

    @property
    def estimate(self) -> ArticulationEstimate:
        return self.estimator.estimate

    @property
    def hook_point(self) -> np.ndarray:
        """(3,) where the hand holds the handle, in the handle frame (default: its origin)."""
        return (np.linalg.inv(self.handle.pose) @ np.append(self.estimator.reference, 1.0))[:3]

    @hook_point.setter
    def hook_point(self, point: Sequence[float] | np.ndarray) -> None:
        p = as_float_array("hook_point", point, (3,))
        self.estimator.reference = (self.handle.pose @ np.append(p, 1.0))[:3]

    def observe(
        self,
        t: Sequence[float] | np.ndarray,
        q: np.ndarray,
        wrench: np.ndarray | None = None,
        phase: str = "open",
    ) -> ArticulationEstimate:
        """Takes T measured samples: times (T,) s, joint positions (T, nq), wrist wrenches (T, 6) or forces
        (T, 3) in N on the hand, world axes (None: in contact, pulling), and the task's phase meanwhile
        (see the class).

        Raises:
            ShapeError: mismatched shapes.
        """
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        n = len(t)
        q = as_float_array("q", q, (n, self.scene.nq))
        if n == 0:  # nothing measured: the estimate stands
            return self.estimate
        hands = self.scene.fk_many(q, self._hand)[:, :3, 3]
        if wrench is None:  # in contact, the bar pulling the hand toward the panel
            touching = pressing = np.ones(n, dtype=bool)
        else:
            w = np.asarray(wrench, dtype=np.float64)
            if w.ndim != 2 or w.shape[0] != n or w.shape[1] not in (3, 6):
                raise ShapeError(f"wrench: expected ({n}, 6) or ({n}, 3), got {w.shape}")
            f = w[:, :3]
            if self.simulated_noise is not None:
                f = f + self._rng.normal(0.0, self.simulated_noise[1], f.shape)
            # contact on the force low-passed at FORCE_CUTOFF: a sensor's noise crosses a newton's
            # threshold now and then, a hook pulling on a handle stays over it
            dt = np.diff(t, prepend=self._force_time if self._force_time is not None else t[0])
            f = np.array([self._force.update(fi, max(float(di), 0.0)) for fi, di in zip(f, dt, strict=True)])
            self._force_time = float(t[-1])
            touching = np.linalg.norm(f, axis=1) >= self.contact_force
            pressing = f @ self.handle.pose[:3, 2] >= self.contact_force
        if self.simulated_noise is not None:
            hands = hands + self._rng.normal(0.0, self.simulated_noise[0], hands.shape)
        self._seating(t, hands, pressing, phase == SEATING_PHASE)
        pulling = phase in PULLING_PHASES
        # the last contact at or before each sample, carried over from the previous call
        last = np.maximum(np.maximum.accumulate(np.where(touching, t, -math.inf)), self._touched_at)
        self._touched_at = float(last[-1])
        hooked = pulling & (t - last <= self.release_time)
        estimate = self.estimator.update(t, hands, hooked, touching & pulling)
        self.history.append((float(t[-1]), estimate))
        return estimate

    def _seating(self, t: np.ndarray, hands: np.ndarray, pressed: np.ndarray, seating: bool) -> None:
        """Notes whether the seating hook pulls the handle already (see the class)."""
        if not seating:
            self._pressed_since, self.hook_pulls = None, False
            return
        # in the handle frame (x along the bar, y across it, z into the panel), from the hook point: a
        # hand where the hook holds the bar across it, and out from it or pressed toward the panel by
        # the bar for a while, has the bar in its pocket and pulls
        d = (hands - self.estimator.reference) @ self.handle.pose[:3, :3]
        across = np.abs(d[:, 1]) <= self.seat_across
        if across[-1] and np.median(-d[:, 2]) >= self.seat_distance:
            self.hook_pulls = True
            return
        for ti, p in zip(t, pressed & across):
            if not p:
                self._pressed_since = None
            elif self._pressed_since is None:
                self._pressed_since = float(ti)
        self.hook_pulls = self._pressed_since is not None and float(t[-1]) - self._pressed_since >= self.seat_time

    def _differs(self, estimate: ArticulationEstimate) -> bool:
        """Whether ``estimate`` has moved away from the hypothesis the scene was built for."""
        held = self.scene.hypothesis
        if held is None:
            return estimate.kind is not None or _angle(estimate.axis, self.handle.outward) > self.rebuild_angle
        if estimate.geometry != held.geometry or (estimate.kind is None) != (held.kind is None):
            return True
        if _angle(estimate.axis, held.axis) > self.rebuild_angle:
            return True
        if estimate.geometry == "revolute":
            a = held.axis / np.linalg.norm(held.axis)
            d = estimate.point - held.point
            return bool(np.linalg.norm(d - (d @ a) * a) > self.rebuild_distance)
        return False

    def _first_pull_runs_out(self, estimate: ArticulationEstimate, handle: DetectedHandle) -> bool:
        """Whether the type is still open with the first pull two thirds done, and it may go further."""
        return (
            estimate.kind is None
            and handle.first_pull < self.handle.drawer_travel
            and estimate.opening > 2.0 / 3.0 * handle.first_pull
        )

    def refresh(self, t: float) -> Scene | None:
        """Rebuilds :attr:`scene` for the current estimate when it has moved (see the class); returns the
        new scene, or None when the one in force stays."""
        estimate = self.estimate
        held = self.scene.hypothesis
        kind_changed = (held.geometry if held is not None else "prismatic") != estimate.geometry or (
            (held is None or held.kind is None) and estimate.kind is not None
        )
        handle = self.scene.detected_handle or self.handle
        if self._first_pull_runs_out(estimate, handle):
            # still undecided near the first pull's end: pull on, straight, for longer
            handle = replace(handle, first_pull=min(1.5 * handle.first_pull, self.handle.drawer_travel))
        elif not self._differs(estimate):
            return None
        elif not kind_changed and t - self._rebuilt_at < self.rebuild_interval:
            return None
        if estimate.kind is not None:
            handle = self.handle
        self.scene = Scene.from_handle(self._robot, handle, estimate, **self._options)
        self._rebuilt_at = float(t)
        self.rebuilds.append(float(t))
        return self.scene

    def state(self, q: Sequence[float] | np.ndarray, dq: Sequence[float] | np.ndarray) -> np.ndarray:
        """(nx,) the state of :attr:`scene`: the robot's joints q, q̇ (nq,) and the object's opening and rate
        from the estimate (held within the object's travel). Call :meth:`refresh` first.

        Raises:
            InvalidValueError: the estimate's type differs from the scene's (a refresh is due).
        """
        nq = self.scene.nq
        q = as_float_array("q", q, (nq,))
        dq = as_float_array("dq", dq, (nq,))
        e = self.estimate
        held = self.scene.hypothesis
        if ("prismatic" if held is None else held.geometry) != e.geometry:
            raise InvalidValueError("the estimate changed the object's type: refresh() the scene before reading its state")
        lower, upper = float(self.scene.o_lower[0]), float(self.scene.o_upper[0])
        return np.concatenate([q, dq, [min(max(e.opening, lower), upper)], [e.rate]])
