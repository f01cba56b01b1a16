"""The controller's measured inputs as drivers publish them (no ROS import): joint states merged by
name from several publishers with a staleness per joint (the core's merge), the base's pose and
rates from odometry, and τ_ext from a wrist wrench in the frame its header names (the core's frame
reading) or from a joint-torque topic."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .. import _core
from ..errors import InvalidValueError, ShapeError
from ..scene import Scene
from .conversions import MessageError, base_to_world

__all__ = ["JointStates", "WrenchFrames", "JointTorques"]


class JointStates:
    """The newest position and velocity of each of sabre's joints (``names``: the robot's names for
    them, in sabre's order), merged from every message that names them, with the time each arrived.

    A message may carry any subset of the joints, in any order, and joints sabre does not know
    (fingers, another arm): those are ignored. A message whose names and values differ in length,
    or with a non-finite value for a known joint, raises :class:`MessageError` and changes nothing.
    ``tick_joints``: a message that carries all of them drives a tick (the arm's joint states).
    ``timeouts`` (per joint, s): a joint older than its timeout is stale. The merge runs in the core
    (:class:`sabre._core.JointMerge`); the arrays are copies of its state."""

    def __init__(self, names: Sequence[str], tick_joints: Sequence[str], timeouts: float | Sequence[float] | np.ndarray) -> None:
        self.names = tuple(str(n) for n in names)
        per_joint = np.broadcast_to(np.asarray(timeouts, dtype=np.float64), (len(self.names),))
        try:
            self._core = _core.JointMerge(list(self.names), [str(n) for n in tick_joints], per_joint.copy())
        except (ShapeError, InvalidValueError) as exc:
            raise MessageError(str(exc)) from exc

    @property
    def core(self) -> _core.JointMerge:
        """The core merge this class runs: a loop in the core (``_core.BridgeTick``) takes a copy."""
        return self._core

    @property
    def timeouts(self) -> np.ndarray:
        return self._core.timeouts

    @property
    def position(self) -> np.ndarray:
        return self._core.position

    @property
    def velocity(self) -> np.ndarray:
        return self._core.velocity

    @property
    def received(self) -> np.ndarray:
        """When each joint's newest value arrived (-inf: never)."""
        return self._core.received

    def _route(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, bool]:
        """(positions in a message naming ``names`` of the joints sabre knows, their positions in
        sabre's order, whether it drives a tick)."""
        return self._core.route(names)

    def drives_tick(self, names: Sequence[str]) -> bool:
        """Whether a message naming ``names`` drives a tick."""
        return self._core.drives_tick(names)

    def update(self, names: Sequence[str], position: Sequence[float], velocity: Sequence[float], received: float) -> bool:
        """Takes a joint-state message's known joints (an empty velocity field: zeros); returns
        whether it drives a tick."""
        try:
            return self._core.update(names, position, velocity, received)
        except (ShapeError, InvalidValueError) as exc:
            raise MessageError(str(exc)) from exc

    def set(self, index: np.ndarray, position: Sequence[float], velocity: Sequence[float], received: float) -> None:
        """Sets joints by their index in sabre's order (the base from odometry); a bad index, length
        or value raises :class:`MessageError` and changes nothing."""
        try:
            self._core.set(index, position, velocity, received)
        except (ShapeError, InvalidValueError) as exc:
            raise MessageError(str(exc)) from exc

    def stale(self, now: float) -> list[str]:
        """The joints older than their timeout at ``now`` (never received: stale)."""
        return self._core.stale(now)

    def fresh(self, now: float) -> bool:
        """Whether every joint is within its timeout at ``now``."""
        return self._core.fresh(now)


def base_from_odometry(
    x: float, y: float, yaw: float, twist: Sequence[float], twist_in_child_frame: bool
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The base's (x, y, ψ) and world rates (ẋ, ẏ, ψ̇) from an Odometry's pose and twist (vx, vy,
    ωz); nav_msgs/Odometry gives the twist in its child (base) frame, rotated here by ψ."""
    values = (x, y, yaw, *twist)
    if not all(math.isfinite(v) for v in values):
        raise MessageError(f"odometry: non-finite value in pose {x, y, yaw} or twist {tuple(twist)}")
    rates = base_to_world(twist, yaw) if twist_in_child_frame else (float(twist[0]), float(twist[1]), float(twist[2]))
    return (float(x), float(y), float(yaw)), rates


class WrenchFrames:
    """τ_ext from a wrist wrench in the frame its header names.

    The header's frame gives the axes: ``world_frame`` (or the scene's ``world``) means world axes,
    a robot frame of the scene (a sensor's, panda_link8, panda_link0) its axes at the measured
    configuration, an empty one ``default_frame``. The moment is about ``point_frame``'s origin if
    given, else about the axes frame's (world axes: ``default_frame``'s). Any other frame raises
    :class:`MessageError`. The core reads the frames and computes τ_ext (``_core.WrenchFrames``, the
    cascade's own)."""

    def __init__(self, scene: Scene, world_frame: str, default_frame: str, point_frame: str = "") -> None:
        self.scene = scene
        try:
            self._core = _core.WrenchFrames(scene._core, str(world_frame), str(default_frame), str(point_frame))
        except InvalidValueError as exc:
            raise MessageError(str(exc)) from exc

    def resolve(self, frame_id: str) -> tuple[str | None, str]:
        """(axes frame or None for world axes, moment point frame) of a header's frame id."""
        try:
            return self._core.resolve(str(frame_id))
        except InvalidValueError as exc:
            raise MessageError(str(exc)) from exc

    def tau_ext(self, q: np.ndarray, wrench: np.ndarray, frame_id: str) -> np.ndarray:
        """(nq,) J(q)ᵀ w of ``wrench`` (6,) given in the header frame ``frame_id``."""
        try:
            tau = self._core.tau_ext(
                np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(wrench, dtype=np.float64), str(frame_id)
            )
        except InvalidValueError as exc:
            raise MessageError(str(exc)) from exc
        return np.asarray(tau, dtype=np.float64)


class JointTorques:
    """τ_ext directly from a joint-torque topic (franka's external joint torques: a JointState with
    the efforts): the arm joints' efforts by name, times ``sign``; the base's stay zero."""

    def __init__(self, names: Sequence[str], nq: int, sign: float = 1.0) -> None:
        self._joints = JointStates(names, (), math.inf)
        self.nq = nq
        self.sign = float(sign)
        self._names = tuple(names)

    def update(self, names: Sequence[str], effort: Sequence[float]) -> np.ndarray:
        """(nq,) τ_ext of one message (joints it does not name: zero)."""
        values_all = np.asarray(effort, dtype=np.float64)
        if values_all.shape != (len(names),):
            raise MessageError(f"joint torques: {values_all.size} efforts for {len(names)} names")
        src, dst, _ = self._joints._route(names)
        values = values_all[src]
        if not np.isfinite(values).all():
            raise MessageError("joint torques: non-finite effort")
        tau = np.zeros(self.nq)
        tau[dst] = self.sign * values
        return tau
