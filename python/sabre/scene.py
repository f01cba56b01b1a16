"""The scene: a robot and one articulated object placed in the world, with kinematics and the state layout."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from . import _core
from ._validate import as_array, as_finite, as_float_array, as_positive, readonly
from .errors import AssumedInertialWarning, InvalidValueError, ShapeError, UnknownFrameError, UrdfError
from .handle_object import DetectedHandle, object_urdf
from .robots import Tool, robot_options
from .scene_parts import AssumedInertial, CollisionShape, StateParts, Visual, collision_shapes

if TYPE_CHECKING:
    from .articulation import ArticulationEstimate

__all__ = ["Scene", "StateParts", "CollisionShape", "AssumedInertial", "Visual", "ROBOTS", "OBJECTS", "DEFAULT_DENSITY"]

#: Built-in robots (compiled into the library).
ROBOTS: tuple[str, ...] = ("royalpanda",)
#: Built-in articulated objects.
OBJECTS: tuple[str, ...] = ("shelf", "microwave", "dishwasher", "drawer")
#: Density (kg/m³) of moving object parts whose file gives no inertial: medium-density fibreboard and
#: particle board, which most cabinet doors, drawer fronts and drawer boxes are made of, weigh
#: 600–750 kg/m³ and solid pine about 500 (see :attr:`Scene.assumed_inertials`).
DEFAULT_DENSITY: float = 600.0


def _pose(obj_pose: Sequence[float] | np.ndarray | None) -> list[float] | None:
    if obj_pose is None:
        return None
    return as_float_array("obj_pose", obj_pose, (6,)).tolist()


def _selection(
    joint: str | None, hold: Mapping[str, float] | None, handle: str | None
) -> tuple[str | None, list[tuple[str, float]] | None, str | None]:
    for name, value in (("joint", joint), ("handle", handle)):
        if value is not None and not isinstance(value, str):
            raise InvalidValueError(f"{name} must be a {'joint' if name == 'joint' else 'link'} name, got {type(value).__name__}")
    if hold is None:
        return joint, None, handle
    if not isinstance(hold, Mapping):
        raise InvalidValueError(f"hold must map joint names to positions, got {type(hold).__name__}")
    return joint, [(str(name), as_finite(f"hold[{name!r}]", value)) for name, value in hold.items()], handle


def _density(density: float) -> float:
    return as_positive("density", density)


def _warn_assumed(scene: Scene) -> Scene:
    """One :class:`AssumedInertialWarning` per moving object link whose inertial was filled in."""
    for a in scene.assumed_inertials:
        warnings.warn(
            f"object link {a.link!r} has no complete <inertial>: mass {a.mass:.3g} kg and inertia from its {a.source}",
            AssumedInertialWarning,
            stacklevel=3,
        )
    return scene


def _object_source(obj: str) -> tuple[str, str]:
    """(kind, value) of an object given as a file or a built-in name."""
    if os.path.isfile(obj):
        return "file", obj
    if obj in OBJECTS:
        return "builtin", obj
    raise UrdfError(f"URDF {obj}: object file does not exist (nor is it a built-in object: {', '.join(OBJECTS)})")


class Scene:
    """A robot and an articulated object.

    State layout: ``x = [q, q̇, o, ȯ]`` with ``nq`` robot coordinates (its movable joints in URDF
    order, held joints left out), ``no`` object coordinates (hinge angle in rad or slide in m). Input
    ``u = q̇*`` (``nu = nq``): commanded joint velocities; a holonomic base's velocities are
    world-frame rates (ẋ, ẏ, yaw rate) at :attr:`base_indices`.

    Build one with :meth:`load` (built-in assets) or :meth:`from_urdf` (your own files).
    """

    __slots__ = ("__weakref__", "_core", "_detected", "_roles")

    def __init__(self, core: _core.Scene) -> None:
        if not isinstance(core, _core.Scene):
            raise TypeError("use Scene.load(...) or Scene.from_urdf(...) to build a scene")
        self._core = core
        self._roles = core.roles()
        self._detected: tuple[DetectedHandle, ArticulationEstimate | None] | None = None

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def load(
        cls, robot: str = "royalpanda", obj: str = "shelf", obj_pose: Sequence[float] | None = None, **options: Any
    ) -> Scene:
        """A scene from built-in assets; ``obj_pose`` is (x, y, z, roll, pitch, yaw) of the object.

        Without ``obj_pose`` the object stands in front of the robot's default base pose
        (shelf and microwave at x = 1.0 m, dishwasher and drawer at x = 1.2 m). ``options`` are
        the robot options of :meth:`from_urdf` (``tool``, ``robot_hold``, ...).
        """
        if not options:
            return cls(_core.Scene.load(str(robot), str(obj), _pose(obj_pose)))
        return cls._build(("builtin", str(robot)), ("builtin", str(obj)), obj_pose, (None, None, None, DEFAULT_DENSITY), options)

    @classmethod
    def from_urdf(
        cls,
        robot_path: str | os.PathLike[str],
        obj_path: str | os.PathLike[str],
        obj_pose: Sequence[float] | None = None,
        *,
        joint: str | None = None,
        hold: Mapping[str, float] | None = None,
        handle: str | None = None,
        density: float = DEFAULT_DENSITY,
        tool: Tool | None = None,
        tool_frame: str | None = None,
        robot_hold: Mapping[str, float] | None = None,
        base: str | Sequence[str] | None = None,
        base_link: str | None = None,
        home: Mapping[str, float] | None = None,
        start: Mapping[str, float] | None = None,
        work: Mapping[str, float] | None = None,
        wrist_sensor: str | None = None,
    ) -> Scene:
        """A scene from a robot URDF and an object URDF on disk (or a built-in object's name, see
        :data:`OBJECTS`). Collision geometry: boxes, spheres, cylinders, capsules, and STL, OBJ or
        COLLADA meshes as convex hulls (docs/objects.md says where mesh files are looked for,
        ``package://`` included).

        An object with several movable joints (a cabinet with two doors and two drawers) is opened
        one joint at a time: ``joint`` names the one that stays movable, or ``handle`` names a link
        (the handle to open by) and the joint that moves it stays movable; every other movable
        joint is fixed at its value in ``hold`` (rad or m; default 0 within its limits, i.e. closed).

        A moving object link whose file gives no inertial, or only part of one, gets what is missing
        from its collision geometry filled with material of ``density`` (kg/m³, default
        :data:`DEFAULT_DENSITY`): the plant and the rollout model both use those values, the scene
        lists them (:attr:`assumed_inertials`) and an :class:`~sabre.errors.AssumedInertialWarning`
        names each such link.

        The robot's options override what its URDF's ``<sabre>`` block declares (docs/robots.md):
        ``tool`` attaches a :class:`~sabre.Tool` (e.g. the shipped hook) to one of its links;
        ``tool_frame`` names the control frame tasks steer (default: the tool's, else the one
        frame-only leaf link the most joints move); ``robot_hold`` fixes robot joints at a value
        like the object's ``hold`` (by default every joint that does not move the tool frame, a
        gripper's fingers for instance, is held at its home value); ``base`` is ``"fixed"`` or the
        three planar joints (x, y, yaw) of a holonomic base carrying ``base_link`` (default:
        detected); ``home``, ``start`` and ``work`` give joint values of the home, start and
        working postures (the last: hand forward, what scripted motions pull toward);
        ``wrist_sensor`` names the link of the wrist force-torque sensor.

        Raises:
            UrdfError: a missing or malformed file, a mesh not found (the message lists where it
                looked), a ``joint`` or ``handle`` that does not pick one movable joint (the message
                lists the candidates), a robot role that names what the robot does not have.
            InvalidValueError: a non-finite held value, a non-positive density.
        """
        robot_path = os.fspath(robot_path)
        if not os.path.isfile(robot_path):
            raise UrdfError(f"URDF {robot_path}: robot file does not exist")
        obj_source = _object_source(os.fspath(obj_path))
        options = dict(
            tool=tool,
            tool_frame=tool_frame,
            robot_hold=robot_hold,
            base=base,
            base_link=base_link,
            home=home,
            start=start,
            work=work,
            wrist_sensor=wrist_sensor,
        )
        return cls._build(("file", robot_path), obj_source, obj_pose, (joint, hold, handle, density), options)

    @classmethod
    def from_urdf_strings(
        cls,
        robot_urdf: str,
        obj_urdf: str,
        obj_pose: Sequence[float] | None = None,
        *,
        joint: str | None = None,
        hold: Mapping[str, float] | None = None,
        handle: str | None = None,
        density: float = DEFAULT_DENSITY,
        **options: Any,
    ) -> Scene:
        """A scene from URDF text; ``joint``, ``hold``, ``handle``, ``density`` and the robot ``options``
        as in :meth:`from_urdf` (relative mesh paths resolve against the working directory and
        ``SABRE_MESH_PATH``, ``package://`` only through the package paths)."""
        if options:
            return cls._build(
                ("text", str(robot_urdf)), ("text", str(obj_urdf)), obj_pose, (joint, hold, handle, density), options
            )
        core = _core.Scene.from_urdf_strings(
            robot_urdf, obj_urdf, _pose(obj_pose), *_selection(joint, hold, handle), _density(density)
        )
        return _warn_assumed(cls(core))

    @classmethod
    def from_handle(
        cls,
        robot: str | os.PathLike[str],
        handle: DetectedHandle,
        estimate: ArticulationEstimate | None = None,
        **options: Any,
    ) -> Scene:
        """A scene of the robot (a built-in name, :data:`ROBOTS`, or a URDF file) and an object that
        has no model, known by a detected handle: the parametric object :func:`sabre.handle_object.object_urdf`
        builds around it for ``estimate``'s articulation (None: the first pull, a drawer along the
        handle's outward normal). The object's joint is ``articulation``, its handle frame the detected
        pose. ``options`` are the robot options of :meth:`from_urdf`. :class:`sabre.EstimatedObject`
        keeps such a scene following the estimate while the hand pulls.

        Raises:
            TypeError: ``handle`` is no :class:`~sabre.DetectedHandle`.
            UrdfError: a robot file that does not exist or does not load.
            InvalidValueError: an estimate whose hinge runs through the handle.
        """
        if not isinstance(handle, DetectedHandle):
            raise TypeError(f"handle must be a sabre.DetectedHandle, got {type(handle).__name__}")
        robot = os.fspath(robot)
        if robot in ROBOTS:
            source = ("builtin", robot)
        elif os.path.isfile(robot):
            source = ("file", robot)
        else:
            raise UrdfError(f"URDF {robot}: robot file does not exist (nor is it a built-in robot: {', '.join(ROBOTS)})")
        scene = cls._build(
            source, ("text", object_urdf(handle, estimate)), [0.0] * 6, (None, None, None, DEFAULT_DENSITY), options
        )
        scene._detected = (handle, estimate)
        return scene

    @property
    def detected_handle(self) -> DetectedHandle | None:
        """The detected handle a :meth:`from_handle` scene was built around (None for a modelled object)."""
        return None if self._detected is None else self._detected[0]

    @property
    def hypothesis(self) -> ArticulationEstimate | None:
        """The articulation estimate a :meth:`from_handle` scene's object was built for (None: the first
        pull's drawer along the handle's normal, or a modelled object)."""
        return None if self._detected is None else self._detected[1]

    @classmethod
    def _build(
        cls,
        robot: tuple[str, str],
        obj: tuple[str, str],
        obj_pose: Sequence[float] | None,
        selection: tuple[str | None, Mapping[str, float] | None, str | None, float],
        options: Mapping[str, Any],
    ) -> Scene:
        joint, hold, handle, density = selection
        core = _core.Scene.build(
            robot, obj, robot_options(**options), _pose(obj_pose), *_selection(joint, hold, handle), _density(density)
        )
        return _warn_assumed(cls(core))

    # -- sizes and names ----------------------------------------------------------------------
    @property
    def nq(self) -> int:
        return self._core.nq

    @property
    def no(self) -> int:
        return self._core.no

    @property
    def nx(self) -> int:
        return self._core.nx

    @property
    def nu(self) -> int:
        return self._core.nu

    @property
    def robot_name(self) -> str:
        return self._core.robot_name

    @property
    def object_name(self) -> str:
        return self._core.object_name

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Robot joint names in the order of q."""
        return tuple(self._core.joint_names)

    @property
    def frame_names(self) -> tuple[str, ...]:
        """Every robot link of the URDF, the attached tool's included (and so its control frame)."""
        return tuple(self._core.frame_names)

    @property
    def object_joint_names(self) -> tuple[str, ...]:
        return tuple(self._core.object_joint_names)

    @property
    def object_frame_names(self) -> tuple[str, ...]:
        return tuple(self._core.object_frame_names)

    @property
    def object_collisions(self) -> tuple[CollisionShape, ...]:
        """The object's collision primitives, each with its link and pose in that link's frame."""
        return collision_shapes(self._core.object_collisions())

    @property
    def robot_collisions(self) -> tuple[CollisionShape, ...]:
        """The robot's collision primitives (its tool's included), each with its link and pose in that link's frame."""
        return collision_shapes(self._core.robot_collisions())

    @property
    def density(self) -> float:
        """Density (kg/m³) of the moving object links whose file gives no complete inertial."""
        return self._core.density

    @property
    def assumed_inertials(self) -> tuple[AssumedInertial, ...]:
        """The inertials of moving object links that their file leaves out (wholly or in part),
        filled in from collision geometry at :attr:`density`; empty when the file gives them all."""
        return tuple(
            AssumedInertial(
                link,
                mass,
                readonly(np.asarray(com, dtype=float)),
                readonly(np.asarray(inertia, dtype=float).reshape(3, 3)),
                source,
            )
            for link, mass, com, inertia, source in self._core.assumed_inertials()
        )

    def object_joints_moving(self, frame: str) -> tuple[str, ...]:
        """The movable object joints that move the object frame or link ``frame``, root first (empty
        for a part of the fixed carcass)."""
        return tuple(self._core.object_joints_moving(str(frame)))

    # -- limits ---------------------------------------------------------------------------------
    def _robot_limits(self, i: int) -> np.ndarray:
        return readonly(np.asarray(self._core.robot_limits()[i], dtype=np.float64))

    @property
    def q_lower(self) -> np.ndarray:
        """(nq,) lower joint position limits."""
        return self._robot_limits(0)

    @property
    def q_upper(self) -> np.ndarray:
        """(nq,) upper joint position limits."""
        return self._robot_limits(1)

    @property
    def dq_limit(self) -> np.ndarray:
        """(nq,) joint velocity limits (symmetric); inputs are projected onto them."""
        return self._robot_limits(2)

    @property
    def effort_limit(self) -> np.ndarray:
        """(nq,) joint force/torque limits of the plant."""
        return self._robot_limits(3)

    @property
    def o_lower(self) -> np.ndarray:
        """(no,) object joint lower limits (closed)."""
        return readonly(np.asarray(self._core.object_limits()[0], dtype=np.float64))

    @property
    def o_upper(self) -> np.ndarray:
        """(no,) object joint upper limits (fully open)."""
        return readonly(np.asarray(self._core.object_limits()[1], dtype=np.float64))

    @property
    def object_damping(self) -> np.ndarray:
        return readonly(np.asarray(self._core.object_dynamics()[0], dtype=np.float64))

    @property
    def object_friction(self) -> np.ndarray:
        return readonly(np.asarray(self._core.object_dynamics()[1], dtype=np.float64))

    @property
    def object_is_revolute(self) -> bool:
        return self._core.object_joint_is_revolute()

    @property
    def object_pose(self) -> np.ndarray:
        """(4, 4) pose of the object's root (cabinet) in the world."""
        return readonly(self._core.object_pose)

    @property
    def rollout_contact_links(self) -> tuple[str, ...]:
        """Robot links that touch the object in the rollout model."""
        return tuple(self._core.rollout_contact_links())

    @property
    def self_collision_spheres(self) -> tuple[tuple[str, str, tuple[float, float, float], float], ...]:
        """(name, link, centre in link frame, radius) of each self-collision sphere (one in a pair)."""
        spheres, _ = self._core.self_collision()
        return tuple((name, link, (center[0], center[1], center[2]), radius) for name, link, center, radius in spheres)

    @property
    def obstacle_spheres(self) -> tuple[tuple[str, str, tuple[float, float, float], float], ...]:
        """(name, link, centre in link frame, radius) of each collision sphere that run-time
        obstacles are checked against: the self-collision spheres except those marked
        ``obstacles="false"`` in the URDF extension (sized to keep two links apart rather than to
        cover one), and the obstacle-only spheres (in no pair)."""
        return tuple((name, link, (c[0], c[1], c[2]), r) for name, link, c, r in self._core.obstacle_spheres())

    @property
    def self_collision_pairs(self) -> tuple[tuple[str, str], ...]:
        return tuple((a, b) for a, b in self._core.self_collision()[1])

    @property
    def arm_reach(self) -> tuple[str, str, float] | None:
        """(arm base link, frame, maximum planar reach in m), if the robot declares one."""
        return self._core.arm_reach()

    # -- roles ------------------------------------------------------------------------------------
    @property
    def tool_frame(self) -> str | None:
        """The control frame tasks steer (the attached tool's, declared or detected), or None."""
        return self._roles[0]

    def require_tool_frame(self, user: str) -> str:
        """The tool frame, or an :class:`UnknownFrameError` telling ``user`` (e.g. "OpenObject") how to name one."""
        if self._roles[0] is None:
            raise UnknownFrameError(
                f"{user} needs a tool frame, and the robot declares none and has no single frame-only leaf link "
                f"to take: attach a tool (Scene.from_urdf(..., tool=sabre.Tool(...))) or name one with tool_frame=...; "
                f"its links are: {', '.join(self.frame_names)}"
            )
        return self._roles[0]

    @property
    def base_indices(self) -> tuple[int, int, int] | None:
        """q indices of a holonomic base's (x, y, yaw) joints, or None for a fixed-base robot."""
        base = self._roles[1]
        return None if base is None else (int(base[0]), int(base[1]), int(base[2]))

    @property
    def base_joints(self) -> tuple[str, str, str] | None:
        """Names of a holonomic base's (x, y, yaw) joints, or None for a fixed-base robot."""
        base = self.base_indices
        return None if base is None else (self.joint_names[base[0]], self.joint_names[base[1]], self.joint_names[base[2]])

    @property
    def base_link(self) -> str:
        """The link of the base's body (a planar base's, else the robot's root)."""
        return self._roles[2]

    @property
    def held_joints(self) -> dict[str, float]:
        """Robot joints fixed at a value (rad or m), by name: those held by ``robot_hold`` or the
        ``<sabre>`` block, and those that do not move the tool frame."""
        return dict(self._roles[3])

    @property
    def wrist_sensor_link(self) -> str:
        """The link carrying the wrist force-torque sensor (the plant's wrench is about its origin)."""
        return self._roles[4]

    @property
    def role_origins(self) -> dict[str, str]:
        """How each role was found: "declared", "detected", "tool" (the tool's own declaration),
        "generated" (safety geometry) or "none"; keys ``tool_frame``, ``base``, ``wrist_sensor``,
        ``geometry`` and ``hold:<joint>``."""
        return dict(self._roles[5])

    @property
    def tool(self) -> Tool | None:
        """The tool attached to the robot, or None."""
        row = self._roles[6]
        if row is None:
            return None
        parent, _kind, value, xyz, rpy, frame = row
        return Tool(parent, value, xyz, rpy, frame)

    @property
    def robot_visuals(self) -> tuple[Visual, ...]:
        """The robot links' URDF visuals (with the attached tool's), for viewers."""
        return tuple(Visual.of(row) for row in self._core.visuals()[0])

    @property
    def object_visuals(self) -> tuple[Visual, ...]:
        """The object links' URDF visuals, for viewers."""
        return tuple(Visual.of(row) for row in self._core.visuals()[1])

    # -- states -----------------------------------------------------------------------------------
    def default_state(self) -> np.ndarray:
        """(nx,) base at the origin, arm in its home pose, everything at rest, object closed."""
        return np.asarray(self._core.default_state(), dtype=np.float64)

    def home_configuration(self) -> np.ndarray:
        """(nq,) the robot's home configuration: the ``<home>`` values the robot declares, else 0 where
        0 lies within a joint's limits, else the middle of its limits."""
        return np.asarray(self._core.home_configuration(), dtype=np.float64)

    def start_configuration(self) -> np.ndarray:
        """(nq,) the robot's start configuration: its declared ``<start>`` values over the home configuration."""
        return np.asarray(self._core.start_configuration(), dtype=np.float64)

    def work_configuration(self) -> np.ndarray:
        """(nq,) the robot's working configuration (hand forward, margins on every joint limit), which
        scripted motions pull toward: its declared ``<work>`` values over the home configuration."""
        return np.asarray(self._core.work_configuration(), dtype=np.float64)

    def start_state(self) -> np.ndarray:
        """(nx,) the start configuration at rest, object closed: where episodes begin by default
        (for the RoyalPanda the paper's start, base at (−3, −3) with the arm folded)."""
        x = self.default_state()
        x[: self.nq] = self.start_configuration()
        return x

    def split_state(self, x: np.ndarray) -> StateParts:
        """The parts of a state x (nx,) or of a batch of states (..., nx).

        Returns :class:`StateParts` ``(q, q_dot, o, o_dot)`` with shapes (..., nq), (..., nq),
        (..., no), (..., no); for an array x they are views, so writing to a part writes to x.
        It unpacks like a tuple: ``q, _, o, _ = scene.split_state(x)``.

        Raises:
            ShapeError: x's last axis is not of size nx.
        """
        x = np.asarray(x)
        if x.shape[-1:] != (self.nx,):
            raise ShapeError(f"x: expected last axis of size nx = {self.nx}, got shape {x.shape}")
        nq, no = self.nq, self.no
        return StateParts(x[..., :nq], x[..., nq : 2 * nq], x[..., 2 * nq : 2 * nq + no], x[..., 2 * nq + no :])

    # -- kinematics -------------------------------------------------------------------------------
    def fk(self, q: Sequence[float] | np.ndarray, frame: str) -> np.ndarray:
        """(4, 4) world pose of a robot frame at configuration q (nq,)."""
        return self._core.fk(as_float_array("q", q, (self.nq,)), str(frame))

    def fk_many(self, q: np.ndarray, frame: str) -> np.ndarray:
        """(..., 4, 4) world poses of a robot frame for configurations q (..., nq), computed in Rust."""
        return self._poses_many("q", q, self.nq, self._core.fk_many, frame)

    @staticmethod
    def _poses_many(
        name: str, values: np.ndarray, n: int, batched: Callable[[np.ndarray, str], np.ndarray], frame: str
    ) -> np.ndarray:
        values = as_array(name, values)
        if values.ndim < 1 or values.shape[-1] != n:
            raise ShapeError(f"{name}: expected shape (..., {n}), got {values.shape}")
        flat = as_float_array(name, values.reshape(-1, n), (None, n))
        return batched(flat, str(frame)).reshape(values.shape[:-1] + (4, 4))

    def jacobian(self, q: Sequence[float] | np.ndarray, frame: str) -> np.ndarray:
        """(6, nq) geometric Jacobian of a robot frame's origin: world frame, linear rows first."""
        return self._core.jacobian(as_float_array("q", q, (self.nq,)), str(frame))

    def object_fk(self, o: Sequence[float] | np.ndarray, frame: str) -> np.ndarray:
        """(4, 4) world pose of an object frame (e.g. ``handle_frame``) at object configuration o (no,)."""
        return self._core.object_fk(as_float_array("o", o, (self.no,)), str(frame))

    def object_fk_many(self, o: np.ndarray, frame: str) -> np.ndarray:
        """(..., 4, 4) world poses of an object frame for object configurations o (..., no), computed in Rust."""
        return self._poses_many("o", o, self.no, self._core.object_fk_many, frame)

    def mass_matrix(self, q: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Robot joint-space mass matrix (nq, nq) and gravity torque (nq,) at q."""
        return self._core.mass_matrix_and_gravity(as_float_array("q", q, (self.nq,)))

    def __repr__(self) -> str:
        return f"Scene(robot={self.robot_name!r}, obj={self.object_name!r}, nq={self.nq}, no={self.no})"
