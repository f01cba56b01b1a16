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
- for a bar within 45° of vertical, x points so that the finger, which hooks from the frame's −y
  side, comes in from the hinge's side when the part turns about a vertical hinge (a door: the
  side of the free edge may hold the neighbouring door and its handle, the hinge's side is the
  door's own), and x points up on anything else (a drawer); for any other bar, so that y = z × x
  points up.

The core infers it (the geometry stays there, where the hulls are); this module is its Python face.
"""

from __future__ import annotations

import numpy as np

from .scene import Scene

__all__ = ["infer_handle_frame", "handle_offset"]


def infer_handle_frame(scene: Scene, link: str) -> np.ndarray:
    """(4, 4) the handle frame of object link ``link`` in that link's frame (see the module's rules).

    Raises:
        UnknownFrameError: ``link`` is not an object link (the message lists those with geometry).
        InvalidValueError: the link has no collision geometry, no moving part to approach it from,
            or is a knob rather than a bar (the message says why and what would work).
    """
    return scene._core.infer_handle_frame(str(link))


def handle_offset(scene: Scene, handle: str) -> tuple[str, np.ndarray]:
    """(object frame, (4, 4) offset) whose composition is the handle frame: a frame without
    collision geometry (such as the shipped ``handle_frame``) is the handle frame itself; a link
    with geometry gets the inferred frame (:func:`infer_handle_frame`).

    Raises:
        UnknownFrameError: the object has no frame ``handle`` (the message lists its frames and the
            links with collision geometry).
        InvalidValueError: as :func:`infer_handle_frame`.
    """
    return scene._core.handle_frame(str(handle))
