"""The controller's measured inputs as drivers publish them, in plain NumPy (no ROS import): joint
states merged by name from several publishers with a staleness per joint, the base's pose and
rates from odometry, and τ_ext from a wrist wrench in the frame its header names or from a
joint-torque topic."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..estimation import tau_ext_from_wrench
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
    ``timeouts`` (per joint, s): a joint older than its timeout is stale."""

    def __init__(self, names: Sequence[str], tick_joints: Sequence[str], timeouts: float | Sequence[float] | np.ndarray) -> None:
        self.names = tuple(str(n) for n in names)
        if len(set(self.names)) != len(self.names):
            raise MessageError(f"joint names must be distinct, got {self.names}")
        self._index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in tick_joints if n not in self._index]
        if missing:
            raise MessageError(f"tick joints {missing} are not among {self.names}")
        self._tick = frozenset(tick_joints)
        self.timeouts = np.broadcast_to(np.asarray(timeouts, dtype=np.float64), (len(self.names),)).copy()
        self.position = np.zeros(len(self.names))
        self.velocity = np.zeros(len(self.names))
        self.received = np.full(len(self.names), -math.inf)
        # per distinct tuple of names: (positions in the message, positions in sabre's order, drives a tick)
        self._routes: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, bool]] = {}

    def _route(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, bool]:
        key = tuple(names)
        route = self._routes.get(key)
        if route is None:
            pairs = [(k, self._index[n]) for k, n in enumerate(key) if n in self._index]
            src = np.array([k for k, _ in pairs], dtype=np.intp)
            dst = np.array([i for _, i in pairs], dtype=np.intp)
            route = (src, dst, self._tick.issubset(key))
            if len(self._routes) < 64:  # publishers with a fixed order: a few distinct tuples
                self._routes[key] = route
        return route

    def drives_tick(self, names: Sequence[str]) -> bool:
        """Whether a message naming ``names`` drives a tick."""
        return self._route(names)[2]

    def update(self, names: Sequence[str], position: Sequence[float], velocity: Sequence[float], received: float) -> bool:
        """Takes a joint-state message's known joints (an empty velocity field: zeros); returns
        whether it drives a tick."""
        src, dst, ticks = self._route(names)
        n = len(names)
        pos = np.asarray(position, dtype=np.float64)
        vel = np.asarray(velocity, dtype=np.float64)
        if pos.shape != (n,) or (vel.size and vel.shape != (n,)):
            raise MessageError(f"joint state: {pos.size} positions and {vel.size} velocities for {n} names")
        p = pos[src]
        v = vel[src] if vel.size else np.zeros(len(src))
        if not (np.isfinite(p).all() and np.isfinite(v).all()):
            bad = [self.names[i] for i, a, b in zip(dst, p, v) if not (math.isfinite(a) and math.isfinite(b))]
            raise MessageError(f"joint state: non-finite value for {bad}")
        self.position[dst] = p
        self.velocity[dst] = v
        self.received[dst] = received
        return ticks

    def set(self, index: np.ndarray, position: Sequence[float], velocity: Sequence[float], received: float) -> None:
        """Sets joints by their index in sabre's order (the base from odometry)."""
        self.position[index] = position
        self.velocity[index] = velocity
        self.received[index] = received

    def stale(self, now: float) -> list[str]:
        """The joints older than their timeout at ``now`` (never received: stale)."""
        return [self.names[i] for i in np.flatnonzero(now - self.received > self.timeouts)]

    def fresh(self, now: float) -> bool:
        return bool(np.all(now - self.received <= self.timeouts))


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
    :class:`MessageError`."""

    def __init__(self, scene: Scene, world_frame: str, default_frame: str, point_frame: str = "") -> None:
        self.scene = scene
        self.world = {str(world_frame), "world"}
        frames = set(scene.frame_names)
        for label, frame in (("wrench_frame", default_frame), ("wrench_point_frame", point_frame)):
            if frame and frame not in frames and frame not in self.world:
                raise MessageError(f"{label} {frame!r} is neither {world_frame!r} nor a robot frame: {scene.frame_names}")
        self.default_frame = str(default_frame)
        self.point_frame = str(point_frame)
        self._frames = frames

    def resolve(self, frame_id: str) -> tuple[str | None, str]:
        """(axes frame or None for world axes, moment point frame) of a header's frame id."""
        frame = frame_id or self.default_frame
        if frame in self.world:
            axes = None
        elif frame in self._frames:
            axes = frame
        else:
            raise MessageError(f"wrench frame {frame!r} is neither the world frame nor a robot frame")
        point = self.point_frame or (axes if axes is not None else self.default_frame)
        if point in self.world:
            point = "world"
        return axes, point

    def tau_ext(self, q: np.ndarray, wrench: np.ndarray, axes: str | None, point: str) -> np.ndarray:
        """(nq,) J(q)ᵀ w of ``wrench`` (6,) in ``axes`` about ``point``'s origin."""
        return tau_ext_from_wrench(self.scene, q, wrench, point, axes)


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
