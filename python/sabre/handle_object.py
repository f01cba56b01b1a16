"""An object sabre has no model of, known by a detected handle: :class:`DetectedHandle` (the handle's pose,
size and what the user believes is behind it) and the parametric articulated object built around it
for a hypothesis of its articulation (:func:`object_urdf`), which :meth:`sabre.Scene.from_handle` loads.

The object is one moving leaf (a door or a drawer front) carrying the handle: a bar on two standoffs in
front of a panel. Until the hand's path tells door from drawer, the hypothesis is a drawer along the
handle's outward normal: the first pull goes straight out, which is how both start to open."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ._validate import as_float_array, as_positive
from .errors import InvalidValueError
from .poses import pose_to_xyz_rpy, xyz_rpy_to_pose

if TYPE_CHECKING:
    from .articulation import ArticulationEstimate

__all__ = ["DetectedHandle", "object_urdf", "HYPOTHESIS_JOINT", "HANDLE_PRIORS"]

#: What a user may say of a handle before pulling it.
HANDLE_PRIORS = ("door", "drawer", "unknown")
#: The joint of the parametric object (a revolute hinge or a prismatic slide, by the hypothesis).
HYPOTHESIS_JOINT = "articulation"
#: The panel behind the handle: how far it reaches beyond the bar's ends and to either side (m), and
#: its thickness. Only the hand meets it; it keeps the rollouts' hand off the face of the object.
_PANEL_MARGIN, _PANEL_SIDE, _PANEL_THICKNESS = 0.12, 0.17, 0.018
#: The leaf's mass (kg), the joint's damping and dry friction: a light leaf, so that the plan does not count
#: on the weight of a door it has not felt, held by its friction where an estimated axis a few degrees
#: off the true one would tilt it into swinging or sliding open in the model.
_LEAF_MASS, _DAMPING, _FRICTION = 2.0, 1.0, 1.0


@dataclass(frozen=True)
class DetectedHandle:
    """A handle on an object that has no model, as a detector reports it.

    pose: the handle frame in the world, (4, 4) or (x, y, z, roll, pitch, yaw): origin at the bar's
    centre, x along the bar, z into the panel (:mod:`sabre.handles`). prior: "door", "drawer" or
    "unknown" (:data:`HANDLE_PRIORS`), or the probability of a door. length, thickness (m): the bar's;
    standoff (m): the clear gap between the bar and the panel, where the hook goes. door_travel (rad),
    drawer_travel (m): how far the object is assumed to open once its type is known (the task opens to
    a share of it).

    Raises:
        ShapeError: a pose of another shape. InvalidValueError: a pose whose rotation is not one,
            non-positive sizes or travels, an unknown prior.
    """

    pose: np.ndarray
    prior: str | float = "unknown"
    length: float = 0.15
    thickness: float = 0.014
    standoff: float = 0.03
    door_travel: float = math.pi / 2
    drawer_travel: float = 0.5
    first_pull: float = 0.12

    def __post_init__(self) -> None:
        pose = np.asarray(self.pose, dtype=np.float64)
        if pose.shape == (6,):
            pose = xyz_rpy_to_pose(as_float_array("pose", pose, (6,)))
        pose = as_float_array("pose", pose, (4, 4)).copy()
        r = pose[:3, :3]
        if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise InvalidValueError("pose: its rotation block is not a rotation (orthonormal, determinant +1)")
        pose.setflags(write=False)
        object.__setattr__(self, "pose", pose)
        if isinstance(self.prior, str):
            if self.prior not in HANDLE_PRIORS:
                raise InvalidValueError(f"prior must be one of {HANDLE_PRIORS} or a probability, got {self.prior!r}")
        elif not 0.0 <= float(self.prior) <= 1.0:
            raise InvalidValueError(f"prior: a probability must lie in [0, 1], got {self.prior}")
        for name in ("length", "thickness", "standoff", "door_travel", "drawer_travel", "first_pull"):
            object.__setattr__(self, name, as_positive(name, getattr(self, name)))
        if self.thickness >= self.length:
            raise InvalidValueError(f"thickness {self.thickness} m must be less than the bar's length {self.length} m")

    @property
    def position(self) -> np.ndarray:
        """(3,) the bar's centre in the world."""
        return self.pose[:3, 3].copy()

    @property
    def outward(self) -> np.ndarray:
        """(3,) the handle's outward normal (−z): the first pull's direction."""
        return -self.pose[:3, 2].copy()


def _frame(origin: np.ndarray, x: np.ndarray, z_hint: np.ndarray) -> np.ndarray:
    """(4, 4) a frame at ``origin`` with x along ``x`` and z as near ``z_hint`` as is orthogonal to it."""
    x = x / np.linalg.norm(x)
    z = z_hint - (z_hint @ x) * x
    if np.linalg.norm(z) < 1e-6:  # the hint runs along x: any orthogonal direction
        helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        z = helper - (helper @ x) * x
    z /= np.linalg.norm(z)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, origin
    return m


def joint_frame(handle: DetectedHandle, estimate: ArticulationEstimate | None) -> tuple[str, np.ndarray]:
    """(joint type, (4, 4) world frame of the joint at the closed object) of the hypothesis: a slide
    along x from the handle's centre, or a hinge about z through the estimated axis with x toward the
    handle."""
    if estimate is None or estimate.geometry == "prismatic":
        direction = handle.outward if estimate is None else np.asarray(estimate.axis, dtype=np.float64)
        return "prismatic", _frame(handle.position, direction, handle.pose[:3, 0])
    axis = np.asarray(estimate.axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    point = np.asarray(estimate.point, dtype=np.float64)
    foot = point + ((handle.position - point) @ axis) * axis
    radial = handle.position - foot
    if np.linalg.norm(radial) < 1e-3:
        raise InvalidValueError("the estimated hinge runs through the handle: no door turns that way")
    m = _frame(foot, radial, axis)  # x toward the handle, z along the axis (orthogonal to it already)
    return "revolute", m


def _origin(m: np.ndarray) -> str:
    v = pose_to_xyz_rpy(m)
    return f'<origin xyz="{v[0]:.17g} {v[1]:.17g} {v[2]:.17g}" rpy="{v[3]:.17g} {v[4]:.17g} {v[5]:.17g}"/>'


def _box(m: np.ndarray, size: Sequence[float]) -> str:
    geometry = f'<geometry><box size="{size[0]:.17g} {size[1]:.17g} {size[2]:.17g}"/></geometry>'
    return f"<collision>{_origin(m)}{geometry}</collision><visual>{_origin(m)}{geometry}</visual>"


def _at(base: np.ndarray, xyz: Sequence[float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = xyz
    return base @ t


def object_urdf(handle: DetectedHandle, estimate: ArticulationEstimate | None = None) -> str:
    """The URDF of the parametric object for ``estimate``'s geometry (None: the first pull, a drawer
    along the handle's outward normal): a fixed frame, the joint ``articulation``, closed at 0 and
    opening to the travel of its type, a leaf with the panel and the handle (link ``handle`` with the
    bar and standoffs, frame ``handle_frame`` at the detected pose)."""
    kind, joint = joint_frame(handle, estimate)
    in_leaf = np.linalg.inv(joint) @ handle.pose  # the handle frame in the leaf's frame
    L, t, s = handle.length, handle.thickness, handle.standoff
    face = t / 2 + s  # the panel's face, along the handle's z
    panel = _box(
        _at(in_leaf, [0.0, 0.0, face + _PANEL_THICKNESS / 2]), [L + 2 * _PANEL_MARGIN, 2 * _PANEL_SIDE, _PANEL_THICKNESS]
    )
    post = s + t / 2  # a standoff spans from the bar's axis to the panel
    ends = [(sign * (L / 2 - t / 2)) for sign in (-1.0, 1.0)]
    bar = _box(in_leaf, [L, t, t]) + "".join(_box(_at(in_leaf, [e, 0.0, post / 2]), [t, t, post]) for e in ends)
    centre = (in_leaf @ np.array([0.0, 0.0, face + _PANEL_THICKNESS / 2, 1.0]))[:3]
    w, h, d = L + 2 * _PANEL_MARGIN, 2 * _PANEL_SIDE, _PANEL_THICKNESS
    m = _LEAF_MASS
    inertia = (m / 12 * (h * h + d * d), m / 12 * (w * w + d * d), m / 12 * (w * w + h * h))
    if kind == "revolute":
        travel, axis = handle.door_travel, "0 0 1"
    else:
        travel, axis = (handle.first_pull if estimate is None or estimate.kind is None else handle.drawer_travel), "1 0 0"
    return f"""<?xml version="1.0"?>
<robot name="detected_{kind}">
  <link name="frame"/>
  <link name="leaf">
    <inertial><origin xyz="{centre[0]:.17g} {centre[1]:.17g} {centre[2]:.17g}"/><mass value="{m}"/>
      <inertia ixx="{inertia[0]:.17g}" iyy="{inertia[1]:.17g}" izz="{inertia[2]:.17g}" ixy="0" ixz="0" iyz="0"/></inertial>
    {panel}
  </link>
  <link name="handle">
    <inertial><mass value="0.1"/><inertia ixx="1e-5" iyy="1e-5" izz="1e-5" ixy="0" ixz="0" iyz="0"/></inertial>
    {bar}
  </link>
  <link name="handle_frame"/>
  <joint name="{HYPOTHESIS_JOINT}" type="{kind}">
    <parent link="frame"/><child link="leaf"/>{_origin(joint)}
    <axis xyz="{axis}"/><limit lower="0" upper="{travel:.17g}" effort="100" velocity="2"/>
    <dynamics damping="{_DAMPING}" friction="{_FRICTION}"/>
  </joint>
  <joint name="handle_mount" type="fixed"><parent link="leaf"/><child link="handle"/></joint>
  <joint name="handle_frame_joint" type="fixed"><parent link="handle"/><child link="handle_frame"/>{_origin(in_leaf)}</joint>
</robot>
"""
