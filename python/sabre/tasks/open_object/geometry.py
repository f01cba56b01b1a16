"""Where a handle is and where the hand is relative to it: pure functions of a scene, a handle name and a state.

``handle`` is the object frame or link named as the handle (:attr:`OpenObject.handle
<sabre.tasks.OpenObject.handle>`); its handle frame has x along the bar, y sideways (toward the
finger) and z into the door (:mod:`sabre.handles`). ``offset`` is a (4, 4) grasp target in that
frame (:func:`grasp_offset`). States x are (nx,) as laid out by :class:`~sabre.Scene`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...handles import handle_offset
from ...scene import Scene
from .._per_scene import per_scene

__all__ = [
    "tool_frame",
    "GraspError",
    "PocketError",
    "handle_frame",
    "handle_pose",
    "handle_poses",
    "grasp_offset",
    "approach_error",
    "pocket_error",
    "depth_error",
    "lateral_error",
    "handle_travel",
    "handle_speed",
    "handle_from_closed",
    "release_path",
    "release_direction",
]


@dataclass(frozen=True)
class GraspError:
    """How far the grasp frame is from a phase's target: ``distance`` (m) and ``angle`` (rad)."""

    distance: float
    angle: float


@dataclass(frozen=True)
class PocketError:
    """Position of the grasp frame relative to a phase's target in the handle frame (m):
    ``across`` the bar (y and z) and ``along`` it (x)."""

    across: float
    along: float


def tool_frame(scene: Scene) -> str:
    """The robot's control frame (its tool's "grasp frame"), which every function here measures."""
    return scene.require_tool_frame("OpenObject")


def handle_frame(scene: Scene, handle: str) -> tuple[str, np.ndarray]:
    """(object frame, (4, 4) offset) whose composition is the handle frame on ``scene`` (see
    :func:`sabre.handles.handle_offset`), inferred once per scene."""
    return per_scene(scene, ("handle frame", handle), lambda s: handle_offset(s, handle))


def handle_pose(scene: Scene, handle: str, o: Sequence[float] | np.ndarray) -> np.ndarray:
    """(4, 4) world pose of the handle frame at object configuration o (no,)."""
    frame, offset = handle_frame(scene, handle)
    return scene.object_fk(o, frame) @ offset


def handle_poses(scene: Scene, handle: str, o: np.ndarray) -> np.ndarray:
    """(M, 4, 4) world poses of the handle frame at object configurations o (M, no)."""
    frame, offset = handle_frame(scene, handle)
    return scene.object_fk_many(o, frame) @ offset


def grasp_offset(scene: Scene, handle: str, xyz: Sequence[float], pitch: float) -> np.ndarray:
    """(4, 4) pose of a grasp target in the handle frame: at ``xyz`` (m), the hand pointing ``pitch``
    (rad) below the handle's normal.

    The tilt is about whichever handle axis (x or y) is horizontal with the object closed, in the
    sense that makes the grasp frame's z point downward. Made once per scene and arguments (the
    planner asks for it several times per iteration); the array is read-only."""
    key = ("grasp offset", handle, tuple(float(v) for v in xyz), float(pitch))
    # made on the scene itself (not the weak proxy per_scene hands over: the handle frame is cached
    # per scene too); the value, an array, keeps no reference to it
    return per_scene(scene, key, lambda _: _grasp_offset(scene, handle, xyz, pitch))


def _grasp_offset(scene: Scene, handle: str, xyz: Sequence[float], pitch: float) -> np.ndarray:
    closed = handle_pose(scene, handle, scene.o_lower)
    axis = 0 if abs(closed[2, 0]) < abs(closed[2, 1]) else 1
    c, s = np.cos(pitch), np.sin(pitch)
    rot = np.eye(3)
    if axis == 0:
        rot[1:, 1:] = [[c, -s], [s, c]]
    else:
        rot[np.ix_([0, 2], [0, 2])] = [[c, s], [-s, c]]
    if (closed[:3, :3] @ rot[:, 2])[2] > 0.0:  # tilted up: the other way
        rot = rot.T
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = xyz
    out.setflags(write=False)
    return out


def _handle_and_tool(scene: Scene, handle: str, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The handle's pose and the grasp frame's pose (4, 4, read-only) at state x. The last state's
    are kept per scene: a planning iteration's phase test measures the same state several ways."""
    last: dict[bytes, tuple[np.ndarray, np.ndarray]] = per_scene(scene, ("poses at the last state", handle), lambda _: {})
    key = np.asarray(x, dtype=np.float64).tobytes()
    if key not in last:
        q, _, o, _ = scene.split_state(x)
        poses = (handle_pose(scene, handle, o), scene.fk(q, tool_frame(scene)))
        for pose in poses:
            pose.setflags(write=False)
        last.clear()
        last[key] = poses
    return last[key]


def approach_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> GraspError:
    """Distance (m) and angle (rad) of the grasp frame from the target ``offset`` at state x."""
    handle_at, pose = _handle_and_tool(scene, handle, x)
    target = handle_at @ offset
    dp = float(np.linalg.norm(pose[:3, 3] - target[:3, 3]))
    cos = (np.trace(target[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
    return GraspError(distance=dp, angle=float(np.arccos(np.clip(cos, -1.0, 1.0))))


def _grasp_from_target(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The handle's pose (4, 4) and the grasp frame's offset (3,) from the target ``offset``, in world axes."""
    pose, tool = _handle_and_tool(scene, handle, x)
    target = pose @ offset
    return pose, tool[:3, 3] - target[:3, 3]


def pocket_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> PocketError:
    """Distance (m) of the grasp frame from the target ``offset`` across the bar (handle frame y
    and z) and along it (x): sliding along the bar does not matter for hooking, only the position
    across it does."""
    pose, error = _grasp_from_target(scene, handle, x, offset)
    e = pose[:3, :3].T @ error
    return PocketError(across=float(np.hypot(e[1], e[2])), along=float(abs(e[0])))


def depth_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> float:
    """Signed distance (m) of the grasp frame from the target ``offset`` along the handle frame's
    z axis (into the door): negative while the finger is still short of it."""
    pose, error = _grasp_from_target(scene, handle, x, offset)
    return float(pose[:3, 2] @ error)


def lateral_error(scene: Scene, handle: str, x: np.ndarray, sideways: float) -> float:
    """Sideways position (m) of the grasp frame along the handle frame's y axis, from ``sideways``."""
    handle_at, tool = _handle_and_tool(scene, handle, x)
    grasp = np.linalg.solve(handle_at, tool)
    return float(grasp[1, 3] - sideways)


def handle_travel(scene: Scene, handle: str, o: float) -> float:
    """Distance (m) the handle moves per unit of opening (rad or m) at opening o (the last opening's
    kept per scene: the phase test and the guides ask at the same one)."""
    o = float(o)
    last: dict[float, float] = per_scene(scene, ("travel at the last opening", handle), lambda _: {})
    if o not in last:
        h = 1e-4 * (scene.o_upper[0] - scene.o_lower[0])
        lo, hi = np.clip([o - h, o + h], scene.o_lower[0], scene.o_upper[0])
        moved = handle_pose(scene, handle, [hi])[:3, 3] - handle_pose(scene, handle, [lo])[:3, 3]
        last.clear()
        last[o] = float(np.linalg.norm(moved) / max(hi - lo, 1e-12))
    return last[o]


def handle_speed(scene: Scene, handle: str, x: np.ndarray) -> float:
    """Speed (m/s) of the handle in the opening direction at state x (negative while closing)."""
    _, _, o, o_dot = scene.split_state(x)
    return float(o_dot[0]) * handle_travel(scene, handle, float(o[0]))


def handle_from_closed(scene: Scene, handle: str, x: np.ndarray) -> float:
    """Distance (m) of the handle at state x from where it is with the object closed."""
    closed = handle_pose(scene, handle, scene.o_lower)[:3, 3]
    return float(np.linalg.norm(handle_pose(scene, handle, scene.split_state(x).o)[:3, 3] - closed))


def release_path(
    scene: Scene,
    handle: str,
    x: np.ndarray,
    steps: int,
    dt: float,
    *,
    entry_side: float,
    entry_depth: float,
    hooked_within: float,
    speed: float,
    distance: float,
) -> np.ndarray:
    """(steps + 1, 4, 4) grasp-frame targets that let go of the handle, at ``speed`` (m/s).

    A finger within ``hooked_within`` (m) sideways of ``entry_side`` (the handle-frame y it came in
    at) leaves the way it came in, riding on the handle as the object keeps opening at its current
    rate: back across the bar to ``entry_side``, then back to ``entry_depth`` (handle-frame z, clear
    of the bar). Then the hand backs off ``distance`` (m) along :func:`release_direction`, fixed in
    the world. Backing off with the bar still in the pocket drags it, or lifts it against a door
    hinged below, which pushes the door back toward closed; following the handle for longer would
    chase a falling door into the robot.
    """
    q, _, o, o_dot = scene.split_state(x)
    relative = np.linalg.solve(handle_pose(scene, handle, o), scene.fk(q, tool_frame(scene)))
    sideways = entry_side - relative[1, 3]
    hooked = abs(sideways) <= hooked_within  # else the finger slipped away: just back off
    unhook = abs(sideways) if hooked else 0.0
    clear = max(relative[2, 3] - entry_depth, 0.0) if hooked else 0.0
    travel = np.minimum(speed * dt * np.arange(steps + 1), unhook + clear + distance)
    offsets = np.repeat(relative[None], steps + 1, axis=0)
    offsets[:, 1, 3] += np.sign(sideways) * np.minimum(travel, unhook)
    offsets[:, 2, 3] -= np.clip(travel - unhook, 0.0, clear)
    rate = max(float(o_dot[0]), 0.0)
    openings = np.minimum(float(o[0]) + rate * dt * np.arange(steps + 1), scene.o_upper[0])
    targets = handle_poses(scene, handle, openings[:, None]) @ offsets
    free = travel >= unhook + clear
    out = int(np.argmax(free)) if np.any(free) else steps + 1
    if out <= steps:
        targets[out:] = targets[out]
        away = travel[out:] - unhook - clear
        targets[out:, :3, 3] += away[:, None] * release_direction(scene, handle, x)
    return targets


def release_direction(scene: Scene, handle: str, x: np.ndarray) -> np.ndarray:
    """(3,) unit direction in which the hand backs off when releasing: away from the door (the
    grasp frame's −z) and, for a hinged door, out of its sweep (away from the hinge axis, found as
    the centre of the circle through three handle positions about the current opening), half each."""
    q, _, o, _ = scene.split_state(x)
    pose = scene.fk(q, tool_frame(scene))
    back = -pose[:3, 2]
    if not scene.object_is_revolute:
        return back
    now = float(o[0])
    p0, p1, p2 = handle_poses(scene, handle, np.array([[now - 0.1], [now], [now + 0.1]]))[:, :3, 3]
    a, b = p0 - p1, p2 - p1
    normal = np.cross(a, b)
    nn = float(normal @ normal)
    if nn < 1e-12:
        return back
    centre = p1 + (float(a @ a) * np.cross(b, normal) + float(b @ b) * np.cross(normal, a)) / (2.0 * nn)
    radial = pose[:3, 3] - centre
    axis = normal / np.sqrt(nn)
    radial -= float(radial @ axis) * axis
    norm = float(np.linalg.norm(radial))
    if norm < 1e-9:
        return back
    way = back + radial / norm
    return way / float(np.linalg.norm(way))
