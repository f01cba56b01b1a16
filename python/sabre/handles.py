"""The handle frame of an object, inferred from its handle link's collision geometry and the articulation.

sabre's tasks grasp a handle through a *handle frame*: origin at the bar's centre, x along the bar,
z into the panel the handle is mounted on (the hand approaches along −z from open space) and
y = z × x. The shipped objects carry it as a ``handle_frame`` link; for anyone else's object it is
inferred from the link named as the handle:

- the bar is the handle link's longest collision primitive (a box's longest dimension, a
  cylinder's or capsule's axis, a mesh hull's principal axis), its centre the frame's origin;
- the panel is the collision box of the object's moving links nearest to the bar (the handle link's
  own shapes excluded), and z its thinnest axis, pointing from the bar toward the panel and made
  orthogonal to the bar;
- x points up for a vertical bar (within 45°) and, for any other bar, so that y = z × x points up.

All of it is computed with the object closed (its joint at the lower limit).
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidValueError, UnknownFrameError
from .scene import CollisionShape, Scene

__all__ = ["infer_handle_frame", "handle_offset"]

UP = np.array([0.0, 0.0, 1.0])


def _bar(shapes: list[CollisionShape]) -> tuple[np.ndarray, np.ndarray]:
    """(centre, unit axis) of the longest primitive, in the link frame."""

    def length(s: CollisionShape) -> float:
        if s.kind == "box":
            return 2.0 * max(s.size)
        if s.kind == "cylinder":
            return 2.0 * s.size[1]
        if s.kind == "capsule":
            return 2.0 * (s.size[1] + s.size[0])
        if s.kind == "mesh":
            return float(np.ptp(s.points @ _principal_axis(s.points))) if len(s.points) else 2.0 * max(s.size)
        return 2.0 * s.size[0]

    bar = max(shapes, key=length)
    if bar.kind == "sphere":
        raise InvalidValueError(f"handle link {bar.link!r}: its longest collision shape is a sphere, which has no bar axis")
    if bar.kind == "mesh":
        local = _principal_axis(bar.points)
        centre_local = bar.points.mean(axis=0) if len(bar.points) else np.zeros(3)
        along = bar.points @ local
        centre_local = centre_local + (0.5 * (along.min() + along.max()) - centre_local @ local) * local
        return bar.pose[:3, :3] @ centre_local + bar.pose[:3, 3], bar.pose[:3, :3] @ local
    axis = bar.pose[:3, 2] if bar.kind in ("cylinder", "capsule") else bar.pose[:3, int(np.argmax(bar.size))]
    return bar.pose[:3, 3].copy(), axis / np.linalg.norm(axis)


def _principal_axis(points: np.ndarray) -> np.ndarray:
    """Unit direction of the largest spread of ``points`` (M, 3)."""
    centred = points - points.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return vt[0]


def _box_distance(point: np.ndarray, pose: np.ndarray, half: np.ndarray) -> float:
    local = pose[:3, :3].T @ (point - pose[:3, 3])
    return float(np.linalg.norm(np.maximum(np.abs(local) - half, 0.0)))


def infer_handle_frame(scene: Scene, link: str) -> np.ndarray:
    """(4, 4) the handle frame of object link ``link`` in that link's frame (see the module's rules).

    Raises:
        UnknownFrameError: ``link`` is not an object link (the message lists those with geometry).
        InvalidValueError: the link has no collision geometry, its longest shape is a sphere, or no
            moving panel is found to approach it from.
    """
    by_link: dict[str, list[CollisionShape]] = {}
    for shape in scene.object_collisions:
        by_link.setdefault(shape.link, []).append(shape)
    if link not in scene.object_frame_names:
        raise UnknownFrameError(f"no object link {link!r}; links with collision geometry: {', '.join(sorted(by_link))}")
    if link not in by_link:
        raise InvalidValueError(
            f"object link {link!r} has no collision geometry to infer a handle from; "
            f"links with geometry: {', '.join(sorted(by_link))}"
        )
    closed, opened = np.asarray(scene.o_lower, dtype=float), np.asarray(scene.o_upper, dtype=float)
    link_pose = scene.object_fk(closed, link)
    centre_l, axis_l = _bar(by_link[link])
    centre = link_pose[:3, :3] @ centre_l + link_pose[:3, 3]
    axis = link_pose[:3, :3] @ axis_l

    panels = []
    for name, shapes in by_link.items():
        pose_closed = scene.object_fk(closed, name)
        if name == link or np.allclose(pose_closed, scene.object_fk(opened, name)):
            continue  # the handle itself, or a part that does not move
        for s in shapes:
            if s.kind == "box":
                world = pose_closed @ s.pose
                panels.append((_box_distance(centre, world, np.asarray(s.size)), world, np.asarray(s.size)))
    if not panels:
        raise InvalidValueError(f"no moving collision box to approach handle {link!r} from: the object needs a panel")
    _, panel, half = min(panels, key=lambda p: p[0])
    normal = panel[:3, int(np.argmin(half))]
    if normal @ (panel[:3, 3] - centre) < 0.0:
        normal = -normal
    z = normal - (normal @ axis) * axis
    if np.linalg.norm(z) < 1e-6:
        raise InvalidValueError(f"handle {link!r}: its bar is perpendicular to the panel; cannot tell along from into")
    z /= np.linalg.norm(z)
    if abs(axis @ UP) >= np.sqrt(0.5):
        x = axis if axis @ UP > 0.0 else -axis
    else:
        x = axis if np.cross(z, axis) @ UP >= 0.0 else -axis
    y = np.cross(z, x)
    world = np.eye(4)
    world[:3, 0], world[:3, 1], world[:3, 2], world[:3, 3] = x, y, z, centre
    return np.linalg.inv(link_pose) @ world


def handle_offset(scene: Scene, handle: str) -> tuple[str, np.ndarray]:
    """(object frame, (4, 4) offset) whose composition is the handle frame: a frame without
    collision geometry (such as the shipped ``handle_frame``) is the handle frame itself; a link
    with geometry gets the inferred frame (:func:`infer_handle_frame`)."""
    if handle not in scene.object_frame_names:
        links = sorted({s.link for s in scene.object_collisions})
        raise UnknownFrameError(
            f"no object frame {handle!r} to use as the handle; object frames: {', '.join(scene.object_frame_names)}; "
            f"links with collision geometry: {', '.join(links)}"
        )
    if not any(s.link == handle for s in scene.object_collisions):
        return handle, np.eye(4)
    return handle, infer_handle_frame(scene, handle)
