"""Where a handle is and where the hand is relative to it: pure functions of a scene, a handle name and a state, run in the core.

``handle`` is the object frame or link named as the handle (:attr:`OpenObject.handle
<sabre.tasks.OpenObject.handle>`); its handle frame has x along the bar, y sideways (toward the
finger) and z into the door (:mod:`sabre.handles`). ``offset`` is a (4, 4) grasp target in that
frame (:func:`grasp_offset`). States x are (nx,) as laid out by :class:`~sabre.Scene`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ... import _core
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


def core_geometry(scene: Scene, handle: str) -> _core.HandleGeometry:
    """The core's handle geometry of ``scene`` for ``handle`` (which the core resolves and infers
    itself), made once per scene."""
    return per_scene(scene, ("handle geometry", handle), lambda _: _make_geometry(scene, handle))


def _make_geometry(scene: Scene, handle: str) -> _core.HandleGeometry:
    return _core.HandleGeometry(scene._core, handle, tool_frame(scene))


def _state(x: Sequence[float] | np.ndarray) -> np.ndarray:
    """x as the core reads it (its shape and values are checked there)."""
    return np.ascontiguousarray(x, dtype=np.float64)


def handle_pose(scene: Scene, handle: str, o: Sequence[float] | np.ndarray) -> np.ndarray:
    """(4, 4) world pose of the handle frame at object configuration o (no,)."""
    return core_geometry(scene, handle).handle_pose(_state(o))


def handle_poses(scene: Scene, handle: str, o: np.ndarray) -> np.ndarray:
    """(M, 4, 4) world poses of the handle frame at object configurations o (M, no)."""
    return core_geometry(scene, handle).handle_poses(_state(o))


def grasp_offset(scene: Scene, handle: str, xyz: Sequence[float], pitch: float) -> np.ndarray:
    """(4, 4) pose of a grasp target in the handle frame: at ``xyz`` (m), the hand pointing ``pitch``
    (rad) below the handle's normal.

    The tilt is about whichever handle axis (x or y) is horizontal with the object closed, in the
    sense that makes the grasp frame's z point downward."""
    x, y, z = (float(v) for v in xyz)
    return core_geometry(scene, handle).grasp_offset([x, y, z], float(pitch))


def approach_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> GraspError:
    """Distance (m) and angle (rad) of the grasp frame from the target ``offset`` at state x."""
    distance, angle = core_geometry(scene, handle).approach_error(_state(x), _state(offset))
    return GraspError(distance=distance, angle=angle)


def pocket_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> PocketError:
    """Distance (m) of the grasp frame from the target ``offset`` across the bar (handle frame y
    and z) and along it (x): sliding along the bar does not matter for hooking, only the position
    across it does."""
    across, along = core_geometry(scene, handle).pocket_error(_state(x), _state(offset))
    return PocketError(across=across, along=along)


def depth_error(scene: Scene, handle: str, x: np.ndarray, offset: np.ndarray) -> float:
    """Signed distance (m) of the grasp frame from the target ``offset`` along the handle frame's
    z axis (into the door): negative while the finger is still short of it."""
    return float(core_geometry(scene, handle).depth_error(_state(x), _state(offset)))


def lateral_error(scene: Scene, handle: str, x: np.ndarray, sideways: float) -> float:
    """Sideways position (m) of the grasp frame along the handle frame's y axis, from ``sideways``."""
    return float(core_geometry(scene, handle).lateral_error(_state(x), float(sideways)))


def handle_travel(scene: Scene, handle: str, o: float) -> float:
    """Distance (m) the handle moves per unit of opening (rad or m) at opening o: a central
    difference over 10⁻⁴ of the range, within the limits."""
    return float(core_geometry(scene, handle).travel(float(o)))


def handle_speed(scene: Scene, handle: str, x: np.ndarray) -> float:
    """Speed (m/s) of the handle in the opening direction at state x (negative while closing)."""
    return float(core_geometry(scene, handle).speed(_state(x)))


def handle_from_closed(scene: Scene, handle: str, x: np.ndarray) -> float:
    """Distance (m) of the handle at state x from where it is with the object closed."""
    return float(core_geometry(scene, handle).distance_from_closed(_state(x)))


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
    return core_geometry(scene, handle).release_path(
        _state(x),
        int(steps),
        float(dt),
        entry_side=float(entry_side),
        entry_depth=float(entry_depth),
        hooked_within=float(hooked_within),
        speed=float(speed),
        distance=float(distance),
    )


def release_direction(scene: Scene, handle: str, x: np.ndarray) -> np.ndarray:
    """(3,) unit direction in which the hand backs off when releasing: away from the door (the
    grasp frame's −z) and, for a hinged door, out of its sweep (away from the hinge axis, found as
    the centre of the circle through three handle positions about the current opening), half each."""
    return np.array(core_geometry(scene, handle).release_direction(_state(x)))
