"""Estimates a controller on a real robot needs besides its joint states: τ_ext from a wrist
wrench, a first-order low-pass for it, and the object's state inferred from the hand pose while
the hand holds the handle (no door sensor). Plain NumPy on the scene's kinematics."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ._validate import as_finite, as_float_array, as_non_negative, as_positive
from .errors import InvalidValueError, ShapeError
from .handles import handle_offset
from .scene import Scene

__all__ = ["LowPass", "tau_ext_from_wrench", "SENSOR_FRAME", "ObjectEstimate", "ObjectStateEstimator"]

#: The RoyalPanda's wrist-sensor frame: the wrench is measured about its origin, as :attr:`sabre.Plant.wrench`
#: reports it (force and torque in world axes). Any robot's is :attr:`sabre.Scene.wrist_sensor_link`.
SENSOR_FRAME = "panda_link8"


def tau_ext_from_wrench(
    scene: Scene,
    q: Sequence[float] | np.ndarray,
    wrench: Sequence[float] | np.ndarray,
    frame: str | None = None,
    axes: str | None = None,
) -> np.ndarray:
    """(nq,) external joint torques J(q)ᵀ w of a wrist wrench w = [f; m] that the environment
    exerts on the hand, its moment about ``frame``'s origin (None: the scene's wrist sensor,
    :attr:`sabre.Scene.wrist_sensor_link`). ``axes`` names the robot frame whose
    axes the components are given in (a sensor's own frame, as an F/T driver publishes it); None:
    world axes. Contacts on links before the sensor do not show in it."""
    w = as_float_array("wrench", wrench, (6,))
    q = np.asarray(q, dtype=np.float64)
    if axes is not None:
        rotation = scene.fk(q, axes)[:3, :3]
        w = np.concatenate([rotation @ w[:3], rotation @ w[3:]])
    return scene.jacobian(q, scene.wrist_sensor_link if frame is None else frame).T @ w


class LowPass:
    """First-order low-pass at ``cutoff`` Hz integrated with the measured step dt (exact
    exponential update, so irregular message spacing is handled); None passes through."""

    def __init__(self, cutoff: float | None) -> None:
        self.cutoff = None if cutoff is None or cutoff <= 0 else float(cutoff)
        self.value: np.ndarray | None = None

    def update(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if self.value is None or self.cutoff is None:
            self.value = x.copy()
        else:
            a = 1.0 - math.exp(-2.0 * math.pi * self.cutoff * max(dt, 0.0))
            self.value = self.value + a * (x - self.value)
        return self.value

    def reset(self) -> None:
        self.value = None


@dataclass(frozen=True)
class ObjectEstimate:
    """position (no,) and velocity (no,) of the object's joints; hooked: whether they come from
    the hand (else the last known state, held at rest); residual (m): how far the hand point is
    from where the estimated object puts it."""

    position: np.ndarray
    velocity: np.ndarray
    hooked: bool
    residual: float


class ObjectStateEstimator:
    """Infers the object's joint coordinate o and rate ȯ from the robot's joint positions.

    Assumptions (docs/ros2.md): the object is the scene's single-joint articulation at its known
    pose; once the hand hooks the handle, the hook point stays fixed in the handle frame (no
    sliding), so o is the coordinate that puts the handle-frame point recorded at hooking where the
    hand's ``hand_frame`` (None: the scene's tool frame) measures it. ``handle`` is the object frame or link to grasp, as
    :class:`sabre.tasks.OpenObject`'s ``handle`` (a link with geometry gets its inferred handle
    frame). Hooking is declared when the hand frame is within ``hook_distance`` m of the handle
    frame and the wrist force exceeds ``contact_force`` N; it ends when the best fit is still
    ``release_distance`` m off (the hand has left the handle) or the force stays below
    ``contact_force`` for ``release_time`` s. Before hooking and after release the last known state
    holds at rest. ȯ is the difference quotient low-passed at ``rate_cutoff`` Hz. A hook that slips
    along or off the handle reads as motion of the object until the release (a drawer coasts ahead
    of a hand that no longer touches it, so the estimate keeps following the hand meanwhile)."""

    def __init__(
        self,
        scene: Scene,
        initial: np.ndarray | None = None,
        *,
        hand_frame: str | None = None,
        handle: str = "handle_frame",
        hook_distance: float = 0.08,
        release_distance: float = 0.04,
        contact_force: float = 0.2,
        release_time: float = 0.5,
        rate_cutoff: float = 5.0,
    ) -> None:
        if scene.no != 1:
            raise InvalidValueError(f"the estimator handles single-joint objects, this one has {scene.no} joints")
        hand_frame = scene.require_tool_frame("ObjectStateEstimator") if hand_frame is None else hand_frame
        if hand_frame not in scene.frame_names:
            raise InvalidValueError(f"hand_frame {hand_frame!r} is not a robot frame: {scene.frame_names}")
        self.scene = scene
        self.hand_frame = hand_frame
        self.handle_frame, self._handle_offset = handle_offset(scene, handle)
        self.hook_distance = as_positive("hook_distance", hook_distance)
        self.release_distance = as_positive("release_distance", release_distance)
        self.contact_force = as_non_negative("contact_force", contact_force)
        self.release_time = as_non_negative("release_time", release_time)
        self._rate_filter = LowPass(as_positive("rate_cutoff", rate_cutoff))
        lo, hi = float(scene.o_lower[0]), float(scene.o_upper[0])
        self._limits = (lo, hi)
        o0 = np.asarray(scene.o_lower if initial is None else initial, dtype=np.float64).reshape(-1)
        self._o = float(np.clip(as_finite("initial", o0[0]), lo, hi))
        self._od = 0.0
        self._offset: np.ndarray | None = None  # hook point in the handle frame (homogeneous)
        self._t: float | None = None
        self._since_force: float = 0.0
        self._residual = math.nan

    @property
    def hooked(self) -> bool:
        return self._offset is not None

    @property
    def position(self) -> float:
        """The current estimate of o."""
        return self._o

    # The core's kinematics without the wrappers' checks: update() checks q once, and the fit needs
    # the object's kinematics at three coordinates per step (the controller runs it at 1 kHz).
    def _hand_point(self, q: np.ndarray) -> np.ndarray:
        return self.scene._core.fk(q, self.hand_frame)[:3, 3]

    def _handle(self, o: float) -> np.ndarray:
        return self.scene._core.object_fk(np.array([o]), self.handle_frame) @ self._handle_offset

    def _points(self, o: np.ndarray, local: np.ndarray) -> np.ndarray:
        """(k, 3) where the handle-frame point ``local`` (homogeneous, the handle offset applied)
        is at each of the k object coordinates ``o``, in one call into the core."""
        return (self.scene._core.object_fk_many(o.reshape(-1, 1), self.handle_frame) @ local)[:, :3]

    def _fit(self, p: np.ndarray, offset: np.ndarray) -> tuple[float, float]:
        """o minimising |T(o)·offset − p| by Gauss–Newton from the last estimate, and its residual."""
        lo, hi = self._limits
        o = self._o
        h = 1e-5 if self.scene.object_is_revolute else 1e-6
        local = self._handle_offset @ offset
        for _ in range(4):
            at, ahead, behind = self._points(np.array([o, o + h, o - h]), local)
            r = at - p
            d = (ahead - behind) / (2 * h)
            dd = float(d @ d)
            if dd < 1e-12:
                break
            step = -float(d @ r) / dd
            o = min(max(o + step, lo), hi)
            if abs(step) < 1e-7:
                break
        r = self._points(np.array([o]), local)[0] - p
        return o, math.hypot(*r)

    def update(self, q: Sequence[float] | np.ndarray, t: float, force: float = math.inf, may_hook: bool = True) -> ObjectEstimate:
        """The estimate at time t (s) from the robot's joint positions q (nq,) and the wrist force
        magnitude (N; default: assume contact). A time at or before the previous one counts as no
        time passed. ``may_hook`` False keeps the estimator from declaring a hook now: a controller
        passes it while its task has not yet seated the hook (the hand touches the handle on its way
        in, where the hook point is not yet the one it will pull at).

        Raises:
            ShapeError, InvalidValueError: q of the wrong size or not finite, t not finite, force
                negative or NaN; the estimate is left as it was.
        """
        q = np.asarray(q, dtype=np.float64)  # checked here, cheaper than the general checks at 1 kHz
        if q.shape != (self.scene.nq,):
            raise ShapeError(f"q: expected shape ({self.scene.nq},), got {q.shape}")
        if not np.isfinite(q).all():
            raise InvalidValueError(f"q: non-finite entry in {q}")
        t = float(t)
        if not math.isfinite(t):
            raise InvalidValueError(f"t: must be finite, got {t}")
        force = float(force)
        if not force >= 0.0:
            raise InvalidValueError(f"force: must be a magnitude ≥ 0, got {force}")
        dt = 0.0 if self._t is None else max(t - self._t, 0.0)
        self._t = max(t, self._t if self._t is not None else t)
        p = self._hand_point(q)
        if self._offset is None:
            handle = self._handle(self._o)
            local = np.append(handle[:3, :3].T @ (p - handle[:3, 3]), 1.0)  # p in the handle frame
            if may_hook and math.hypot(*local[:3]) <= self.hook_distance and force >= self.contact_force:
                self._offset = local
                self._since_force = 0.0
                self._rate_filter.reset()
            self._od = 0.0
            self._residual = math.nan
        else:
            self._follow(p, dt, force, self._offset)
        return ObjectEstimate(
            position=np.array([self._o]), velocity=np.array([self._od]), hooked=self.hooked, residual=self._residual
        )

    def _follow(self, p: np.ndarray, dt: float, force: float, offset: np.ndarray) -> None:
        """One update while hooked: the fit, its rate, and the release tests."""
        o, residual = self._fit(p, offset)
        self._since_force = 0.0 if force >= self.contact_force else self._since_force + dt
        if residual > self.release_distance or self._since_force > self.release_time:
            self._offset = None
            self._od = 0.0
        else:
            if dt > 0:
                raw = (o - self._o) / dt
                self._od = float(self._rate_filter.update(np.array([raw]), dt)[0])
            self._o = o
        self._residual = residual
