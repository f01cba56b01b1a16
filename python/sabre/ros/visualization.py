"""Something to look at while the controller runs, and the obstacles it is given: the planned hand and
base paths (nav_msgs/Path), markers of the handle frame, the obstacles and the active constraints
(visualization_msgs/MarkerArray) and the estimated object JointState, all in the world frame; the
obstacles kept by the id their sender gives them (visualization_msgs/Marker semantics: ADD adds or
moves, DELETE removes, DELETEALL clears)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..poses import pose_to_xyz_rpy
from ..scene import Scene
from .conversions import MessageError, quaternion_of

__all__ = ["ObstacleRegistry", "planned_paths", "active_constraints", "Visualizer"]

#: A constraint row counts as active once its barrier value is below this (its own units).
ACTIVE_BELOW = 0.05


@dataclass
class _Obstacle:
    core_id: int | None
    center: tuple[float, float, float]
    radius: float


class ObstacleRegistry:
    """Sphere obstacles by the sender's key (a marker's namespace and id), added to, moved in and
    removed from the cascade's filters through ``add(center, radius) -> id``, ``move(id, center)``
    and ``remove(id)``. A new radius for a known key re-adds it (a filter's sphere keeps its size)."""

    def __init__(self, add: Callable[..., int | None], move: Callable[..., None], remove: Callable[[int], None]) -> None:
        self._add, self._move, self._remove = add, move, remove
        self.obstacles: dict[tuple[str, int], _Obstacle] = {}

    def apply(self, key: tuple[str, int], action: int, center: tuple[float, float, float], radius: float) -> None:
        """One marker's action: 0 (ADD/MODIFY) adds or moves, 2 (DELETE) removes, 3 (DELETEALL)
        removes every obstacle."""
        if action == 3:
            for old in self.obstacles.values():
                if old.core_id is not None:
                    self._remove(old.core_id)
            self.obstacles.clear()
            return
        known = self.obstacles.get(key)
        if action == 2:
            if known is not None and known.core_id is not None:
                self._remove(known.core_id)
            self.obstacles.pop(key, None)
            return
        if action != 0:
            raise MessageError(f"obstacle {key}: action {action} is not ADD (0), DELETE (2) or DELETEALL (3)")
        if not (all(math.isfinite(c) for c in center) and math.isfinite(radius) and radius > 0):
            raise MessageError(f"obstacle {key}: needs a finite centre and a positive radius, got {center}, {radius}")
        if known is not None and known.radius == radius:
            if known.core_id is not None:
                self._move(known.core_id, list(center))
            known.center = center
            return
        if known is not None and known.core_id is not None:
            self._remove(known.core_id)
        self.obstacles[key] = _Obstacle(self._add(list(center), radius), center, radius)


def planned_paths(
    scene: Scene, reference: Callable[[float], np.ndarray], q: np.ndarray, t: float, horizon: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """The hand's (the tool frame's) and the base link's planned positions, (K, 3) each: the plan's
    reference velocities integrated from q over the horizon."""
    steps = max(2, int(round(horizon / dt)))
    qs = np.empty((steps + 1, scene.nq))
    qs[0] = q
    for k in range(steps):
        qs[k + 1] = qs[k] + dt * np.asarray(reference(t + k * dt))[: scene.nq]
    hand = scene.fk_many(qs, scene.require_tool_frame("the planned hand path"))[:, :3, 3]
    base = scene.fk_many(qs, scene.base_link)[:, :3, 3]
    base[:, 2] = 0.0  # the base's path on the floor
    return hand, base


def active_constraints(names: list[str], h: np.ndarray) -> list[str]:
    """The rows whose barrier value is below :data:`ACTIVE_BELOW` (NaN rows are off)."""
    return [n for n, v in zip(names, h) if math.isfinite(v) and v < ACTIVE_BELOW]


class Visualizer:
    """Builds and publishes the messages on ``node`` (the caller's rclpy node) in ``frame``."""

    def __init__(self, node: Any, params: dict[str, Any], frame: str, qos: Any) -> None:
        from nav_msgs.msg import Path
        from sensor_msgs.msg import JointState
        from visualization_msgs.msg import MarkerArray

        self.node = node
        self.frame = frame
        self.hand_pub = node.create_publisher(Path, params["hand_path_topic"], qos)
        self.base_pub = node.create_publisher(Path, params["base_path_topic"], qos)
        self.marker_pub = node.create_publisher(MarkerArray, params["markers_topic"], qos)
        self.object_pub = node.create_publisher(JointState, params["object_estimate_topic"], qos)

    def _path(self, points: np.ndarray, stamp: Any) -> Any:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path

        path = Path()
        path.header.frame_id, path.header.stamp = self.frame, stamp
        for p in points:
            pose = PoseStamped()
            pose.header = path.header
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in p)
            pose.pose.orientation.w = 1.0
            path.poses.append(pose)
        return path

    def _marker(self, ns: str, mid: int, kind: int, stamp: Any) -> Any:
        from visualization_msgs.msg import Marker

        m = Marker()
        m.header.frame_id, m.header.stamp = self.frame, stamp
        m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
        m.pose.orientation.w = 1.0
        m.color.a = 1.0
        return m

    def publish(
        self,
        scene: Scene,
        paths: tuple[np.ndarray, np.ndarray] | None,
        handle: np.ndarray,
        obstacles: list[tuple[tuple[float, float, float], float]],
        active: list[str],
        o: np.ndarray,
        od: np.ndarray,
    ) -> None:
        """Publishes the paths (if any), the markers and the object estimate."""
        from sensor_msgs.msg import JointState
        from visualization_msgs.msg import Marker, MarkerArray

        stamp = self.node.get_clock().now().to_msg()
        if paths is not None:
            self.hand_pub.publish(self._path(paths[0], stamp))
            self.base_pub.publish(self._path(paths[1], stamp))
        markers = MarkerArray()
        clear = self._marker("sabre", 0, Marker.ARROW, stamp)
        clear.action = Marker.DELETEALL
        markers.markers.append(clear)
        frame = self._marker("sabre/handle", 0, Marker.ARROW, stamp)
        frame.pose.position.x, frame.pose.position.y, frame.pose.position.z = (float(v) for v in handle[:3, 3])
        roll, pitch, yaw = (float(v) for v in pose_to_xyz_rpy(handle)[3:])
        frame.pose.orientation.x, frame.pose.orientation.y, frame.pose.orientation.z, frame.pose.orientation.w = quaternion_of(
            roll, pitch, yaw
        )
        frame.scale.x, frame.scale.y, frame.scale.z = 0.1, 0.01, 0.01
        frame.color.r = 1.0
        markers.markers.append(frame)
        for k, (center, radius) in enumerate(obstacles):
            sphere = self._marker("sabre/obstacles", k, Marker.SPHERE, stamp)
            sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z = center
            sphere.scale.x = sphere.scale.y = sphere.scale.z = 2.0 * radius
            sphere.color.r, sphere.color.g, sphere.color.a = 1.0, 0.4, 0.6
            markers.markers.append(sphere)
        for k, name in enumerate(active):
            text = self._marker("sabre/active_constraints", k, Marker.TEXT_VIEW_FACING, stamp)
            text.pose.position.x, text.pose.position.y = float(handle[0, 3]), float(handle[1, 3])
            text.pose.position.z = float(handle[2, 3]) + 0.3 + 0.06 * k
            text.scale.z = 0.05
            text.color.r, text.color.g, text.color.b = 1.0, 0.2, 0.2
            text.text = name
            markers.markers.append(text)
        self.marker_pub.publish(markers)
        state = JointState(name=list(scene.object_joint_names), position=[float(v) for v in o], velocity=[float(v) for v in od])
        state.header.frame_id, state.header.stamp = self.frame, stamp
        self.object_pub.publish(state)
