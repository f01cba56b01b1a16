"""Where the controller node's scene comes from, in plain Python (no ROS import): the robot's URDF
(the ``robot_description`` topic or a file), the object's (a file, a string or a built-in object),
the object's pose (a parameter or a pose topic in the world frame), and the controller built from
them (module-level, so that the planner process builds its own copy)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from .. import tasks
from ..errors import InvalidValueError, UrdfError
from ..planner import Controller, ControllerConfig
from ..scene import Scene
from .conversions import MessageError, rpy_of

__all__ = ["Descriptions", "DescriptionSources", "build_scene", "build_controller"]


@dataclass(frozen=True)
class Descriptions:
    """Everything the scene and the task are built from: the robot's and the object's URDF text, the
    object's pose (x, y, z, roll, pitch, yaw) in the world frame, the object's joint to open and the
    positions its other movable joints are held at, and the handle to grasp."""

    robot_urdf: str
    object_urdf: str
    object_pose: tuple[float, ...]
    joint: str | None = None
    hold: dict[str, float] = field(default_factory=dict)
    handle: str = "handle_frame"


def build_scene(d: Descriptions) -> Scene:
    return Scene.from_urdf_strings(d.robot_urdf, d.object_urdf, d.object_pose, joint=d.joint, hold=d.hold or None)


def build_controller(
    d: Descriptions,
    variant: str,
    seed: int,
    threads: int,
    command_acceleration: tuple[float, ...] | None = None,
    scene: Scene | None = None,
) -> Controller:
    """The node's controller: OpenObject on the described scene (``scene``: that scene built already),
    its rollout model bounded by the robot's ``command_acceleration`` (see :class:`sabre.ControllerConfig`)."""
    scene = build_scene(d) if scene is None else scene
    task = tasks.OpenObject(handle=d.handle)
    config = ControllerConfig(seed=seed, variant=variant, threads=threads or None, command_acceleration=command_acceleration)
    return Controller(scene, task, config)


def _read(path: str, what: str) -> str:
    if not os.path.isfile(path):
        raise UrdfError(f"URDF {path}: {what} file does not exist")
    with open(path, encoding="utf-8") as f:
        return f.read()


class DescriptionSources:
    """Collects the descriptions as they arrive. Files, strings and parameters are read at once;
    the robot description and the pose from their topics when a message comes (the newest wins).
    :meth:`missing` says what is still absent, :meth:`descriptions` returns them once complete."""

    def __init__(self, params: dict[str, Any]) -> None:
        self.world_frame = str(params["world_frame"])
        self.robot_urdf: str | None = None
        self.robot_source = "topic " + str(params["robot_description_topic"])
        if params["robot_description_file"]:
            self.robot_urdf = _read(str(params["robot_description_file"]), "robot")
            self.robot_source = "file " + str(params["robot_description_file"])
        self.object_urdf, self.object_source = self._object(params)
        pose = list(params["object_pose"])
        self.object_pose: tuple[float, ...] | None = None
        self.pose_source = "topic " + str(params["object_pose_topic"])
        if pose:
            if len(pose) != 6 or not all(math.isfinite(v) for v in pose):
                raise InvalidValueError(f"object_pose: needs x, y, z, roll, pitch, yaw (6 finite values), got {pose}")
            self.object_pose = tuple(float(v) for v in pose)
            self.pose_source = "parameter object_pose"
        hold_names, hold_values = list(params["hold_joints"]), list(params["hold_positions"])
        if len(hold_names) != len(hold_values):
            raise InvalidValueError(f"hold_joints {hold_names} and hold_positions {hold_values} differ in length")
        self.joint = str(params["object_joint"]) or None
        self.hold = {str(n): float(v) for n, v in zip(hold_names, hold_values)}
        self.handle = str(params["handle"])

    @staticmethod
    def _object(params: dict[str, Any]) -> tuple[str | None, str]:
        if params["object_urdf_file"]:
            return _read(str(params["object_urdf_file"]), "object"), "file " + str(params["object_urdf_file"])
        if params["object_urdf"]:
            return str(params["object_urdf"]), "parameter object_urdf"
        if params["object"]:
            from ..assets import urdf_text

            return urdf_text(str(params["object"])), f"built-in object {params['object']}"
        return None, "nothing (set object_urdf_file, object_urdf or object)"

    def on_robot_description(self, text: str) -> None:
        if not text.strip():
            raise MessageError("robot_description: empty")
        self.robot_urdf = text

    def on_object_pose(self, frame_id: str, position: Sequence[float], orientation: Sequence[float]) -> tuple[float, ...]:
        """Takes a pose message's pose (position x, y, z; orientation x, y, z, w) in the world frame."""
        if frame_id and frame_id != self.world_frame:
            raise MessageError(f"object pose in frame {frame_id!r}; it must be in the world frame {self.world_frame!r}")
        if not all(math.isfinite(v) for v in position):
            raise MessageError(f"object pose: non-finite position {tuple(position)}")
        pose = (float(position[0]), float(position[1]), float(position[2]), *rpy_of(*orientation))
        self.object_pose = pose
        return pose

    def missing(self) -> list[str]:
        """What the scene still waits for, each with where it is expected from."""
        out = []
        if self.robot_urdf is None:
            out.append(f"the robot description (from {self.robot_source})")
        if self.object_urdf is None:
            out.append(f"the object description (from {self.object_source})")
        if self.object_pose is None:
            out.append(f"the object pose (from {self.pose_source})")
        return out

    def descriptions(self) -> Descriptions:
        missing = self.missing()
        if missing:
            raise InvalidValueError("waiting for " + ", ".join(missing))
        assert self.robot_urdf is not None and self.object_urdf is not None and self.object_pose is not None
        return Descriptions(self.robot_urdf, self.object_urdf, self.object_pose, self.joint, self.hold, self.handle)
