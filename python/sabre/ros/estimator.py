"""Object state without a door sensor: the articulation coordinate and its rate inferred from the
measured hand pose and the object's kinematics while the hand holds the handle."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import as_non_negative, as_positive
from ..errors import InvalidValueError
from ..scene import Scene
from .conversions import LowPass

__all__ = ["ObjectEstimate", "ObjectStateEstimator"]


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
    hand's ``hand_frame`` measures it. Hooking is declared when the hand frame is within
    ``hook_distance`` m of the handle frame and the wrist force exceeds ``contact_force`` N; it ends
    when the best fit is still ``release_distance`` m off (the hand has left the handle) or the
    force stays below ``contact_force`` for ``release_time`` s. Before hooking and after release
    the last known state holds at rest. ȯ is the difference quotient low-passed at
    ``rate_cutoff`` Hz."""

    def __init__(
        self,
        scene: Scene,
        initial: np.ndarray | None = None,
        *,
        hand_frame: str = "grasp",
        handle_frame: str = "handle_frame",
        hook_distance: float = 0.08,
        release_distance: float = 0.04,
        contact_force: float = 0.2,
        release_time: float = 0.5,
        rate_cutoff: float = 5.0,
    ) -> None:
        if scene.no != 1:
            raise InvalidValueError(f"the estimator handles single-joint objects, this one has {scene.no} joints")
        if hand_frame not in scene.frame_names:
            raise InvalidValueError(f"hand_frame {hand_frame!r} is not a robot frame: {scene.frame_names}")
        if handle_frame not in scene.object_frame_names:
            raise InvalidValueError(f"handle_frame {handle_frame!r} is not an object frame: {scene.object_frame_names}")
        self.scene = scene
        self.hand_frame = hand_frame
        self.handle_frame = handle_frame
        self.hook_distance = as_positive("hook_distance", hook_distance)
        self.release_distance = as_positive("release_distance", release_distance)
        self.contact_force = as_non_negative("contact_force", contact_force)
        self.release_time = as_non_negative("release_time", release_time)
        self._rate_filter = LowPass(as_positive("rate_cutoff", rate_cutoff))
        lo, hi = float(scene.o_lower[0]), float(scene.o_upper[0])
        self._limits = (lo, hi)
        o0 = np.asarray(scene.o_lower if initial is None else initial, dtype=np.float64).reshape(-1)
        self._o = float(np.clip(o0[0], lo, hi))
        self._od = 0.0
        self._offset: np.ndarray | None = None  # hook point in the handle frame (homogeneous)
        self._t: float | None = None
        self._since_force: float = 0.0
        self._residual = math.nan

    @property
    def hooked(self) -> bool:
        return self._offset is not None

    def _hand_point(self, q: np.ndarray) -> np.ndarray:
        return self.scene.fk(q, self.hand_frame)[:3, 3]

    def _handle(self, o: float) -> np.ndarray:
        return self.scene.object_fk([o], self.handle_frame)

    def _fit(self, p: np.ndarray) -> tuple[float, float]:
        """o minimising |T(o)·offset − p| by Gauss–Newton from the last estimate, and its residual."""
        lo, hi = self._limits
        o = self._o
        h = 1e-5 if self.scene.object_is_revolute else 1e-6
        for _ in range(4):
            r = (self._handle(o) @ self._offset)[:3] - p
            d = ((self._handle(o + h) @ self._offset)[:3] - (self._handle(o - h) @ self._offset)[:3]) / (2 * h)
            dd = float(d @ d)
            if dd < 1e-12:
                break
            step = -float(d @ r) / dd
            o = min(max(o + step, lo), hi)
            if abs(step) < 1e-7:
                break
        r = (self._handle(o) @ self._offset)[:3] - p
        return o, float(np.linalg.norm(r))

    def update(self, q: np.ndarray, t: float, force: float = math.inf) -> ObjectEstimate:
        """The estimate at time t (s) from the robot's joint positions q (nq,) and the wrist force
        magnitude (N; default: assume contact)."""
        q = np.asarray(q, dtype=np.float64)
        dt = 0.0 if self._t is None else max(float(t) - self._t, 0.0)
        self._t = float(t)
        p = self._hand_point(q)
        if self._offset is None:
            handle = self._handle(self._o)
            local = np.linalg.solve(handle, np.append(p, 1.0))
            if np.linalg.norm(local[:3]) <= self.hook_distance and force >= self.contact_force:
                self._offset = local
                self._since_force = 0.0
                self._rate_filter.value = None
            self._od = 0.0
            self._residual = math.nan
        else:
            o, residual = self._fit(p)
            self._since_force = 0.0 if force >= self.contact_force else self._since_force + dt
            if residual > self.release_distance or self._since_force > self.release_time:
                self._offset = None
                self._od = 0.0
            else:
                raw = (o - self._o) / dt if dt > 0 else self._od
                self._od = float(self._rate_filter.update(np.array([raw]), dt)[0]) if dt > 0 else self._od
                self._o = o
            self._residual = residual
        return ObjectEstimate(
            position=np.array([self._o]), velocity=np.array([self._od]), hooked=self.hooked, residual=self._residual
        )
