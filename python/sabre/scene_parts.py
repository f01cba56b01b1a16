"""The records a scene hands out: the parts of a state, collision shapes, assumed inertials and visuals."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._validate import readonly

__all__ = ["StateParts", "CollisionShape", "AssumedInertial", "Visual", "collision_shapes"]


def collision_shapes(rows: list) -> tuple[CollisionShape, ...]:
    return tuple(
        CollisionShape(
            link=link,
            kind=kind,
            size=tuple(size),
            pose=readonly(np.asarray(pose, dtype=float).reshape(4, 4)),
            points=readonly(np.asarray(points, dtype=float).reshape(-1, 3)),
        )
        for link, kind, size, pose, points in rows
    )


class StateParts(NamedTuple):
    """The parts of a state ``x = [q, q̇, o, ȯ]`` (:meth:`Scene.split_state`), each a view into x
    with x's leading axes."""

    q: np.ndarray
    """(..., nq) robot joint positions, in the order of :attr:`Scene.joint_names`."""
    q_dot: np.ndarray
    """(..., nq) robot joint velocities."""
    o: np.ndarray
    """(..., no) object joint positions (rad or m)."""
    o_dot: np.ndarray
    """(..., no) object joint velocities."""


@dataclass(frozen=True)
class CollisionShape:
    """One collision primitive of a link.

    Attributes:
        link: the link it belongs to. kind: "box", "sphere", "cylinder", "capsule" or "mesh".
        size: box half extents (x, y, z); sphere (radius,); cylinder and capsule (radius, half
            length along the primitive's z); mesh: half extents of its hull's bounding box; in m.
        pose: (4, 4) pose of the primitive in the link frame (a mesh's: its bounding box's centre).
        points: (M, 3) a mesh's convex-hull vertices in that pose's frame; (0, 3) otherwise.
    """

    link: str
    kind: str
    size: tuple[float, ...]
    pose: np.ndarray
    points: np.ndarray


class AssumedInertial(NamedTuple):
    """The inertial of a moving object link that the file leaves out, filled in from its collision
    geometry (:attr:`Scene.assumed_inertials`)."""

    link: str
    mass: float
    """kg."""
    com: np.ndarray
    """(3,) centre of mass in the link frame (m)."""
    inertia: np.ndarray
    """(3, 3) inertia about the centre of mass, in the link frame (kg m²)."""
    source: str
    """Where the values come from: the collision geometry at the scene's density, and which parts
    (mass, centre of mass, inertia) the file declared and were kept."""


@dataclass(frozen=True)
class Visual:
    """One URDF ``<visual>`` of a link.

    Attributes:
        link: the link it belongs to. kind: "box", "sphere", "cylinder", "capsule" or "mesh".
        size: box extents (x, y, z); sphere (radius,); cylinder and capsule (radius, length); mesh ().
        pose: (4, 4) pose in the link frame. rgba: colour in [0, 1].
        mesh: a mesh's file (None when it was not found or for primitives); scale: its per-axis scale.
    """

    link: str
    kind: str
    size: tuple[float, ...]
    pose: np.ndarray
    rgba: tuple[float, float, float, float]
    mesh: str | None
    scale: tuple[float, float, float]

    @staticmethod
    def of(row: tuple) -> Visual:
        link, kind, size, pose, rgba, mesh, scale = row
        return Visual(
            link, kind, tuple(size), readonly(np.asarray(pose, dtype=float).reshape(4, 4)), tuple(rgba), mesh, tuple(scale)
        )
