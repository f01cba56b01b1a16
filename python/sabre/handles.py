"""The handle frame of an object, inferred from its handle link's collision geometry and the articulation.

sabre's tasks grasp a handle through a *handle frame*: origin at the bar's centre, x along the bar,
z into the panel the handle is mounted on (the hand approaches along −z from open space) and
y = z × x. The shipped objects carry it as a ``handle_frame`` link; for anyone else's object it is
inferred from the link named as the handle, whatever its geometry (boxes, cylinders, capsules,
meshes as their convex hulls, several convex pieces), with the object closed (its joints at their
lower limits):

- the handle is the union of the link's collision shapes; its centre, for a start, the centre of
  their bounding box;
- the panel is the surface of the moving geometry of other links nearest to that centre (a door
  leaf, a drawer front, in whatever pieces): z points from the centre to its nearest point;
- seen from the front (along z), the handle's outline has a smallest bounding rectangle: the bar
  runs along its long side (x up to sign) and is as thick as the short side. An outline less than
  twice as long as it is thick is a knob, which the hook finger cannot catch: refused, saying so;
- the bar is the part of the handle farthest from the panel (standoffs and a U handle's legs stand
  between): its centre lies half its thickness behind the handle's front face, midway along and
  across the part of the handle within one thickness of that face;
- x points up for a bar within 45° of vertical and, for any other bar, so that y = z × x points up.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidValueError, UnknownFrameError
from .scene import CollisionShape, Scene

__all__ = ["infer_handle_frame", "handle_offset"]

UP = np.array([0.0, 0.0, 1.0])

#: Points per circle where round primitives (cylinders, capsules, spheres) are sampled: the extent of
#: a sampled circle is short of the true one by at most 1 − cos(π/64), 0.12 % of its radius.
_ROUND_SAMPLES = 64
_ANGLES = 2.0 * np.pi * np.arange(_ROUND_SAMPLES) / _ROUND_SAMPLES
_CIRCLE = np.stack([np.cos(_ANGLES), np.sin(_ANGLES), np.zeros(_ROUND_SAMPLES)], axis=1)
_SPHERE = np.concatenate(
    [
        np.stack([np.cos(lat) * _CIRCLE[:, 0], np.cos(lat) * _CIRCLE[:, 1], np.full(_ROUND_SAMPLES, np.sin(lat))], axis=1)
        for lat in np.linspace(-np.pi / 2, np.pi / 2, 9)
    ]
)
#: A bar is at least this many times as long as it is thick, seen from the front.
_BAR_ASPECT = 2.0


def _shape_points(shape: CollisionShape) -> np.ndarray:
    """(M, 3) points in the link frame whose convex hull is the shape (round shapes sampled)."""
    size = np.asarray(shape.size, dtype=float)
    if shape.kind == "box":
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float) * size
    elif shape.kind == "mesh":
        local = np.asarray(shape.points, dtype=float).reshape(-1, 3)
    elif shape.kind == "sphere":
        local = size[0] * _SPHERE
    else:  # cylinder and capsule: radius, half length along the primitive's z
        radius, half = size[0], size[1]
        ends = [np.array([0.0, 0.0, h]) for h in (-half, half)]
        rims = [end + radius * _CIRCLE for end in ends]
        caps = [end + radius * _SPHERE for end in ends] if shape.kind == "capsule" else []
        local = np.concatenate(rims + caps)
    return local @ shape.pose[:3, :3].T + shape.pose[:3, 3]


def _turn(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Twice the signed area of the triangle a, b, c: positive for a left turn."""
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def _hull_2d(points: np.ndarray) -> np.ndarray:
    """The convex hull (K, 2) of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    unique = np.unique(np.round(points, 12), axis=0)
    if len(unique) < 3:
        return unique

    def half(rows: np.ndarray) -> list[np.ndarray]:
        chain: list[np.ndarray] = []
        for p in rows:
            while len(chain) >= 2 and _turn(chain[-2], chain[-1], p) <= 0.0:
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(unique), half(unique[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _front_outline(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(unit bar axis ⊥ normal, length, thickness): the long side of the smallest-area rectangle
    around the points seen along ``normal``, and the rectangle's two sides (m)."""
    seed = np.eye(3)[int(np.argmin(np.abs(normal)))]
    u = seed - (seed @ normal) * normal
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    hull = _hull_2d(np.stack([points @ u, points @ v], axis=1))
    if len(hull) < 2:
        return u, 0.0, 0.0
    edges = np.roll(hull, -1, axis=0) - hull
    lengths = np.linalg.norm(edges, axis=1)
    directions = edges[lengths > 1e-12] / lengths[lengths > 1e-12, None]
    best: tuple[float, np.ndarray, float, float] | None = None
    for d in directions:
        along, across = hull @ d, hull @ np.array([-d[1], d[0]])
        sides = (float(np.ptp(along)), float(np.ptp(across)))
        if best is None or sides[0] * sides[1] < best[0] - 1e-15:
            long_side = d if sides[0] >= sides[1] else np.array([-d[1], d[0]])
            best = (sides[0] * sides[1], long_side, max(sides), min(sides))
    assert best is not None
    _, axis_2d, length, thickness = best
    return axis_2d[0] * u + axis_2d[1] * v, length, thickness


def _surface_behind(scene: Scene, link: str, centre: np.ndarray, closed: np.ndarray) -> np.ndarray:
    """Unit direction from ``centre`` to the nearest point of the moving collision geometry of the
    object's other links: into the panel the handle is mounted on."""
    shapes = scene.object_collisions
    moving = {s.link for s in shapes if s.link != link and scene.object_joints_moving(s.link)}
    if not moving:
        raise InvalidValueError(
            f"handle {link!r}: no moving collision geometry besides the handle's own to approach it from; the handle "
            f"must be its own link, fixed to a moving part (a door leaf or drawer front) that has collision geometry"
        )
    nearest = scene.object_closest_points(closed, centre)
    candidates = [i for i, s in enumerate(shapes) if s.link in moving]
    distances = np.linalg.norm(nearest[candidates] - centre, axis=1)
    best = candidates[int(np.argmin(distances))]
    gap = float(distances.min())
    if gap < 1e-6:
        raise InvalidValueError(
            f"handle {link!r}: its centre lies inside the collision geometry of {shapes[best].link!r}; cannot tell "
            f"which side of that part the hand approaches from"
        )
    return (nearest[best] - centre) / gap


def infer_handle_frame(scene: Scene, link: str) -> np.ndarray:
    """(4, 4) the handle frame of object link ``link`` in that link's frame (see the module's rules).

    Raises:
        UnknownFrameError: ``link`` is not an object link (the message lists those with geometry).
        InvalidValueError: the link has no collision geometry, no moving part to approach it from,
            or is a knob rather than a bar (the message says why and what would work).
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
    closed = np.asarray(scene.o_lower, dtype=float)
    link_pose = scene.object_fk(closed, link)
    local = np.concatenate([_shape_points(s) for s in by_link[link]])
    points = local @ link_pose[:3, :3].T + link_pose[:3, 3]
    z = _surface_behind(scene, link, 0.5 * (points.min(axis=0) + points.max(axis=0)), closed)
    axis, length, thickness = _front_outline(points, z)
    if length < _BAR_ASPECT * thickness:
        raise InvalidValueError(
            f"handle {link!r} is a knob, not a bar: seen from the front it measures {1000 * length:.0f} × "
            f"{1000 * thickness:.0f} mm, with no long axis for the hook finger to catch. What works: a bar at least "
            f"{_BAR_ASPECT:g} times as long as it is thick (a pull bar, a U handle); or name as the handle a link "
            f"without collision geometry whose frame is the handle frame (origin where the finger hooks, x along the "
            f"bar, z into the door)"
        )
    side = np.cross(z, axis)
    out = -(points @ z)  # how far each point stands out from the panel
    front = points[out >= out.max() - thickness - 1e-9]
    along, across = front @ axis, front @ side
    centre = (
        0.5 * (along.min() + along.max()) * axis + 0.5 * (across.min() + across.max()) * side - (out.max() - 0.5 * thickness) * z
    )
    if abs(axis @ UP) >= np.sqrt(0.5):
        x = axis if axis @ UP > 0.0 else -axis
    else:
        x = axis if np.cross(z, axis) @ UP >= 0.0 else -axis
    world = np.eye(4)
    world[:3, 0], world[:3, 1], world[:3, 2], world[:3, 3] = x, np.cross(z, x), z, centre
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
