"""Tasks: what the controller should achieve, as phases with a cost each, a switch rule and a success test.

Subclass :class:`Task` to script your own: give ``phases``, ``cost(scene, phase)``,
``next_phase(scene, x, t, phase)`` and ``success(scene, x)``; ``on_step`` runs once per planning
iteration for anything else (logging, moving a target, ...).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from .. import costs
from .._validate import as_float_array, as_non_negative, as_pose, as_positive
from ..errors import InvalidValueError, UnknownFrameError
from ..guides import servo_guide
from ..handles import handle_offset
from ..scene import Scene
from ..sim import RolloutModel

if TYPE_CHECKING:
    from ..planner import Controller

__all__ = [
    "Task", "Reach", "OpenObject", "SafetyWeights", "ApproachConfig", "HookConfig", "OpenConfig", "ReleaseConfig",
    "NoiseConfig", "GuideConfig", "GraspError", "PocketError",
]



#: Handle frames per scene and handle name: inferred once, forgotten with the scene.
_HANDLES: weakref.WeakKeyDictionary[Scene, dict[str, tuple[str, np.ndarray]]] = weakref.WeakKeyDictionary()

@dataclass(frozen=True)
class SafetyWeights:
    """Weights of the terms that every phase carries: the defaults of the cost terms themselves
    (Table I, :mod:`sabre.costs`)."""

    joint_limit: float = costs.JointLimits.weight
    joint_limit_slope: float = costs.JointLimits.weight_slope
    reach: float = costs.ArmReach.weight
    reach_slope: float = costs.ArmReach.weight_slope
    self_collision: float = costs.SelfCollision.weight
    self_collision_slope: float = costs.SelfCollision.weight_slope
    power: float = costs.Power.weight
    p_max: float = costs.Power.p_max
    #: Keeps the base out of the sweep of the object's moving parts (not in Table I; see
    #: :class:`sabre.costs.BaseClearance`). Zero weights leave it out.
    base_clearance: float = costs.BaseClearance.weight
    base_clearance_slope: float = costs.BaseClearance.weight_slope
    base_link: str = "base_link"

    def terms(self, scene: Scene) -> costs.Cost:
        """The safety cost terms for the scene (arm reach and base clearance where the scene has them)."""
        out = costs.Cost([
            costs.JointLimits(self.joint_limit, self.joint_limit_slope),
            costs.SelfCollision(self.self_collision, self.self_collision_slope),
            costs.Power(self.power, self.p_max),
        ])
        if scene.arm_reach is not None:
            out = out + costs.ArmReach(weight=self.reach, weight_slope=self.reach_slope)
        if (self.base_clearance > 0.0 or self.base_clearance_slope > 0.0) and self.base_link in scene.frame_names:
            out = out + costs.BaseClearance(self.base_link, weight=self.base_clearance, weight_slope=self.base_clearance_slope)
        return out


class Task:
    """Base class: a sequence of named phases, each with its cost."""

    phases: ClassVar[tuple[str, ...]] = ("main",)

    def initial_phase(self) -> str:
        """The phase a reset starts in (default: the first)."""
        return self.phases[0]

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        """The cost the controller minimises during `phase`."""
        return costs.Cost()

    def check(self, scene: Scene) -> None:
        """Raises a SabreError if this task cannot run on ``scene`` (called when a controller is
        built, before the first update; the controller also compiles every phase's cost then)."""

    def next_phase(self, scene: Scene, x: np.ndarray, t: float, phase: str) -> str:
        """The phase to use from state x at time t (called before every planning iteration)."""
        return phase

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the task is done at state x (nx,)."""
        return False

    def noise_scale(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        """Factor on the sampling covariance Σ for the next batch (1: Σ as configured).

        A fixed Σ cannot both explore across metres and settle within millimetres: near a goal
        almost every fresh sample is worse than the nominal, and the update is dominated by noise.
        Tasks shrink Σ as they close in on their target.
        """
        return 1.0

    def guides(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> np.ndarray | None:
        """Input sequences (M, steps, nu) to put into the next batch, row 0 applying now, or None.

        Guides are samples like any other: the sampler rolls them out and weighs them by their
        cost, so they can only help. A task proposes what it knows and the sampler cannot find by
        chance, e.g. following a handle along its arc (see :func:`sabre.guides.servo_guide`).
        """
        return None

    def on_step(self, scene: Scene, x: np.ndarray, t: float, controller: Controller) -> None:
        """Hook called once per planning iteration, after the phase update."""

    def gain_inertia_floor(self, phase: str) -> float | None:
        """The low-level controller's gain inertia floor (kg m², see
        :class:`sabre.LowLevelController`) to use during `phase`, or None for the controller's own.
        :func:`sabre.run_episode` applies it at every re-plan."""
        return None


@dataclass
class Reach(Task):
    """Bring robot frame ``frame`` to ``target_pose`` (4, 4); success within 2 cm and 0.1 rad."""

    frame: str = "grasp"
    target_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    pose_weight: float = costs.TargetPose.linear_weight
    safety: SafetyWeights = field(default_factory=SafetyWeights)
    position_tolerance: float = 0.02
    angle_tolerance: float = 0.1
    extra: costs.Cost = field(default_factory=costs.Cost)

    phases: ClassVar[tuple[str, ...]] = ("reach",)

    def __post_init__(self) -> None:
        self.target_pose = as_pose("target_pose", self.target_pose)

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        pose = costs.TargetPose(self.target_pose, self.frame, None, self.pose_weight, self.pose_weight)
        return pose + self.safety.terms(scene) + self.extra

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        pose = scene.fk(x[: scene.nq], self.frame)
        dp = np.linalg.norm(pose[:3, 3] - self.target_pose[:3, 3])
        cos = (np.trace(self.target_pose[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
        return bool(dp < self.position_tolerance and np.arccos(np.clip(cos, -1.0, 1.0)) < self.angle_tolerance)


def _offset(xyz: tuple[float, float, float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = xyz
    return t


def _xyz(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    return tuple(as_float_array(name, value, (3,)).tolist())


def _optional_non_negative(name: str, value: float | None) -> float | None:
    return None if value is None else as_non_negative(name, value)


def _finite(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value):
        raise InvalidValueError(f"{name} must be finite, got {value}")
    return value


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


@dataclass(frozen=True)
class ApproachConfig:
    """Reaching the handle (phases approach and insert) of :class:`OpenObject`.

    Offsets are grasp-frame positions (m) in the handle frame: x along the bar, y sideways (toward
    the finger), z into the door. The rationale of every default is in docs/design.md.

    Attributes:
        pregrasp_offset: target while approaching, in front of the bar and beside it (m).
        insert_offset: target while inserting, beside the bar with the finger's tip past it (m).
        pitch: the hand points this far (rad) below the handle's normal.
        weight: pose weight of the reaching targets (the paper's approach weight).
        switch_position: distance (m) to the target that ends inserting (twice it ends the approach).
        switch_angle: angle (rad) to the target that ends approaching, inserting and hooking.
        posture: preferred arm posture while approaching (nq joint targets), or None for a Panda
            posture that holds a hand level with a handle.
        posture_weight: its weight per rad² (0: off).

    Raises:
        InvalidValueError: a negative weight or tolerance, a non-finite offset or pitch.
    """

    pregrasp_offset: tuple[float, float, float] = (0.0, -0.022, -0.07)
    insert_offset: tuple[float, float, float] = (0.0, -0.022, 0.0)
    pitch: float = 0.3
    weight: float = costs.TargetPose.linear_weight
    switch_position: float = 0.015
    switch_angle: float = 0.15
    posture: tuple[float, ...] | None = None
    posture_weight: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "pregrasp_offset", _xyz("approach.pregrasp_offset", self.pregrasp_offset))
        object.__setattr__(self, "insert_offset", _xyz("approach.insert_offset", self.insert_offset))
        object.__setattr__(self, "pitch", _finite("approach.pitch", self.pitch))
        for name in ("weight", "switch_position", "switch_angle", "posture_weight"):
            object.__setattr__(self, name, as_non_negative(f"approach.{name}", getattr(self, name)))
        if self.posture is not None:
            object.__setattr__(self, "posture", tuple(as_float_array("approach.posture", self.posture, (None,)).tolist()))


@dataclass(frozen=True)
class HookConfig:
    """Sliding the bar into the finger's pocket (phase hook, and the end of inserting).

    Attributes:
        offset: grasp-frame target while hooking, in the handle frame (m): the bar in the pocket.
        tolerance: distance (m) across the bar to the target that ends hooking.
        insert_depth_tolerance: distance (m) from the insert target's depth within which inserting
            may end; None: no depth test.
        backout: how far (m) short of the hook target's depth the grasp frame may back out while
            hooking an opened, unmoving object before the task starts over; None: never.
        along_tolerance: distance (m) along the bar from the target allowed when inserting and hooking.
        drag_speed: handle speed (m/s) that counts as the finger already pulling while inserting or
            hooking (see :meth:`OpenObject.pulling`); 0: off.
        drag_distance: distance (m) of the handle from closed below which pulling never counts.

    Raises:
        InvalidValueError: a negative or non-finite tolerance, speed or distance.
    """

    offset: tuple[float, float, float] = (0.0, 0.003, 0.0)
    tolerance: float = 0.006
    insert_depth_tolerance: float | None = 0.005
    backout: float | None = 0.010
    along_tolerance: float = 0.03
    drag_speed: float = 0.02
    drag_distance: float = 0.03

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", _xyz("hook.offset", self.offset))
        for name in ("tolerance", "along_tolerance", "drag_speed", "drag_distance"):
            object.__setattr__(self, name, as_non_negative(f"hook.{name}", getattr(self, name)))
        for name in ("insert_depth_tolerance", "backout"):
            object.__setattr__(self, name, _optional_non_negative(f"hook.{name}", getattr(self, name)))


@dataclass(frozen=True)
class OpenConfig:
    """Pulling the object open (phase open) and the success test.

    Attributes:
        offset: grasp-frame target while opening, in the handle frame (m): in the pocket, pulled
            out from the bar.
        pose_weights: pose weights (x along the bar, y sideways, z into the door, then rotation
            about x, y, z).
        lead: the pose target sits this far (rad or m of opening) ahead of the object's opening.
        object_weight: weight W_o of the object cost (34).
        object_overshoot: o* lies this far (rad or m) beyond the target opening; None: from the
            power balance (:meth:`OpenObject.object_setpoint`).
        speeds: handle speeds (m/s) of the guides that follow the handle along its path; empty: none.
        slip_distance: distance (m) of the grasp frame from its target beyond which the bar has
            left the pocket.
        slip_lateral: sideways offset (m) from the target beyond which the bar has left the pocket.
        success_fraction: success once the opening reaches this share of the target, in (0, 1].
        gain_inertia_floor: the low-level controller's gain inertia floor (kg m²) while opening
            (see :class:`sabre.LowLevelController`); None: the controller's own.

    Raises:
        InvalidValueError: a negative weight, speed or bound, a non-finite lead or overshoot, a
            success fraction outside (0, 1].
    """

    offset: tuple[float, float, float] = (0.0, 0.003, -0.016)
    pose_weights: tuple[float, float, float, float, float, float] = (100.0, 10000.0, 1000.0, 1000.0, 1000.0, 1000.0)
    lead: float = 0.0
    object_weight: float = costs.ObjectState.weight
    object_overshoot: float | None = None
    speeds: tuple[float, ...] = (0.1, 0.05)
    slip_distance: float = 0.05
    slip_lateral: float = 0.01
    success_fraction: float = 0.9
    gain_inertia_floor: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", _xyz("open.offset", self.offset))
        weights = as_float_array("open.pose_weights", self.pose_weights, (6,))
        if np.any(weights < 0.0):
            raise InvalidValueError(f"open.pose_weights must be non-negative, got {self.pose_weights}")
        object.__setattr__(self, "pose_weights", tuple(weights.tolist()))
        object.__setattr__(self, "lead", _finite("open.lead", self.lead))
        if self.object_overshoot is not None:
            object.__setattr__(self, "object_overshoot", _finite("open.object_overshoot", self.object_overshoot))
        speeds = tuple(as_non_negative("open.speeds", s) for s in self.speeds)
        object.__setattr__(self, "speeds", speeds)
        for name in ("object_weight", "slip_distance", "slip_lateral"):
            object.__setattr__(self, name, as_non_negative(f"open.{name}", getattr(self, name)))
        object.__setattr__(self, "gain_inertia_floor", _optional_non_negative("open.gain_inertia_floor", self.gain_inertia_floor))
        if not 0.0 < self.success_fraction <= 1.0:
            raise InvalidValueError(f"open.success_fraction must be in (0, 1], got {self.success_fraction}")


@dataclass(frozen=True)
class ReleaseConfig:
    """Letting go of an object that opens by itself (phase release, :meth:`OpenObject.release_path`).

    Attributes:
        speed: speed (m/s) at which the hand leaves the pocket and backs off; 0: no release guide.
        distance: how far (m) it backs off from the door.
        rate: opening rate (rad/s or m/s) that counts as opening by itself ...
        probe: ... within this many seconds of the object left alone (s, > 0).
        runaway_speed: handle speed (m/s) above which the object is taken to open by itself while
            the bar is out of the pocket (:meth:`OpenObject.running_ahead`).

    Raises:
        InvalidValueError: a negative speed, distance or rate, a non-positive probe.
    """

    speed: float = 0.4
    distance: float = 0.3
    rate: float = 0.05
    probe: float = 0.15
    runaway_speed: float = 0.15

    def __post_init__(self) -> None:
        for name in ("speed", "distance", "rate", "runaway_speed"):
            object.__setattr__(self, name, as_non_negative(f"release.{name}", getattr(self, name)))
        object.__setattr__(self, "probe", as_positive("release.probe", self.probe))


@dataclass(frozen=True)
class NoiseConfig:
    """The sampling-noise schedule (:meth:`OpenObject.noise_scale`): while reaching, Σ is scaled
    by (d / distance)², clipped to [floor, 1], with d the grasp frame's distance (m) to the phase's
    target; opening and releasing use ``open``.

    Raises:
        InvalidValueError: a non-positive distance, a negative floor or open scale.
    """

    distance: float = 0.5
    floor: float = 1e-3
    open: float = 0.01

    def __post_init__(self) -> None:
        object.__setattr__(self, "distance", as_positive("noise.distance", self.distance))
        for name in ("floor", "open"):
            object.__setattr__(self, name, as_non_negative(f"noise.{name}", getattr(self, name)))


@dataclass(frozen=True)
class GuideConfig:
    """Reaching guides (:meth:`OpenObject.guides`): a pose servo toward the phase's target.

    Attributes:
        speed: linear speed cap (m/s) while approaching; 0 turns the reaching guides off.
        fine_speed: linear speed cap (m/s) while inserting and hooking.
        gain: servo gain (1/s) of every guide.

    Raises:
        InvalidValueError: a negative speed or gain.
    """

    speed: float = 0.3
    fine_speed: float = 0.05
    gain: float = 2.0

    def __post_init__(self) -> None:
        for name in ("speed", "fine_speed", "gain"):
            object.__setattr__(self, name, as_non_negative(f"guide.{name}", getattr(self, name)))


@dataclass
class OpenObject(Task):
    """Open the scene's object to ``opening`` (rad or m; None: 75 % of its range).

    The two phases of the paper (reach the handle, then open) with the reaching split into the
    moves a hook finger needs, each set up by its own config (the rationale of every default is
    in docs/design.md, "OpenObject: phases and their settings"):

    - approach (:class:`ApproachConfig`): drive the ``grasp`` frame to a pre-grasp pose in front
      of the handle (``handle_frame``) and beside the bar, touching nothing (contact cost on);
    - insert (:class:`ApproachConfig`, :class:`HookConfig`): move in until the finger is beside
      the bar with its tip past it;
    - hook (:class:`HookConfig`): slide sideways so the bar sits in the finger's pocket;
    - open (:class:`OpenConfig`): the pose target sits in the pocket, pulled out from the bar,
      and follows the handle as the object moves; the object cost (34) pulls toward the target;
    - release (:class:`ReleaseConfig`): an object that opens by itself (a door past its balance
      point) is let go: the finger leaves the pocket and the hand backs off.

    ``noise`` (:class:`NoiseConfig`) shapes the sampling covariance per phase and ``guide``
    (:class:`GuideConfig`) the reaching guides. ``horizon`` (s) is the controller's horizon T,
    used by the power balance of :meth:`object_setpoint`; ``contact_weight`` weighs the contact
    cost (30) while approaching and releasing; ``safety`` the terms every phase carries; ``extra``
    is added to every phase's cost. Success: opening ≥ ``open.success_fraction`` of the target.

    ``handle`` names the object frame or link to grasp: a frame without collision geometry (the
    shipped objects' ``handle_frame``) is used as the handle frame as it is; a link with geometry
    (anyone else's object) gets its handle frame inferred by :func:`sabre.handles.infer_handle_frame`.

    Example: ``OpenObject(hook=HookConfig(backout=None))`` never restarts a backed-out hook;
    ``OpenObject(handle="door_knob_link")`` opens an object whose handle is that link.

    Raises:
        InvalidValueError: a non-finite opening, a non-positive horizon, a negative contact weight.
        TypeError: a group of the wrong type.
    """

    opening: float | None = None
    horizon: float = 1.0
    contact_weight: float = costs.Contact.weight
    approach: ApproachConfig = field(default_factory=ApproachConfig)
    hook: HookConfig = field(default_factory=HookConfig)
    open: OpenConfig = field(default_factory=OpenConfig)
    release: ReleaseConfig = field(default_factory=ReleaseConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    guide: GuideConfig = field(default_factory=GuideConfig)
    safety: SafetyWeights = field(default_factory=SafetyWeights)
    extra: costs.Cost = field(default_factory=costs.Cost)
    handle: str = "handle_frame"

    phases = ("approach", "insert", "hook", "open", "release")

    def _handle(self, scene: Scene) -> tuple[str, np.ndarray]:
        """(object frame, offset) of the handle frame on ``scene`` (see :mod:`sabre.handles`), computed once per scene."""
        per_scene = _HANDLES.setdefault(scene, {})
        if self.handle not in per_scene:
            per_scene[self.handle] = handle_offset(scene, self.handle)
        return per_scene[self.handle]

    def handle_pose(self, scene: Scene, o: Sequence[float] | np.ndarray) -> np.ndarray:
        """(4, 4) world pose of the handle frame at object configuration o (no,)."""
        frame, offset = self._handle(scene)
        return scene.object_fk(o, frame) @ offset

    def handle_poses(self, scene: Scene, o: np.ndarray) -> np.ndarray:
        """(M, 4, 4) world poses of the handle frame at object configurations o (M, no)."""
        frame, offset = self._handle(scene)
        return scene.object_fk_many(o, frame) @ offset

    def __post_init__(self) -> None:
        for name, kind in (("approach", ApproachConfig), ("hook", HookConfig), ("open", OpenConfig),
                           ("release", ReleaseConfig), ("noise", NoiseConfig), ("guide", GuideConfig),
                           ("safety", SafetyWeights)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"{name} must be a sabre.tasks.{kind.__name__}, got {type(getattr(self, name)).__name__}")
        self.contact_weight = as_non_negative("contact_weight", self.contact_weight)
        self.horizon = as_positive("horizon", self.horizon)
        if self.opening is not None:
            self.opening = _finite("opening", self.opening)

    def posture_term(self, scene: Scene) -> costs.Cost:
        """The posture cost of the approach (empty when ``approach.posture_weight`` is 0)."""
        names = scene.joint_names
        if self.approach.posture_weight <= 0.0:
            return costs.Cost()
        if self.approach.posture is not None:
            target = np.asarray(self.approach.posture, dtype=float)
            weights = np.where(np.arange(scene.nq) < 3, 0.0, self.approach.posture_weight)
        elif all(f"panda_joint{i}" in names for i in (2, 4, 6)):
            target = np.zeros(scene.nq)
            weights = np.zeros(scene.nq)
            for joint, value in (("panda_joint2", 1.0), ("panda_joint4", -1.2), ("panda_joint6", 2.9)):
                i = names.index(joint)
                target[i], weights[i] = value, self.approach.posture_weight
        else:
            return costs.Cost()
        return costs.Cost([costs.Posture(target, weights)])

    def lead(self, scene: Scene) -> float:
        """How far ahead (rad or m) of the opening the open-phase pose target sits."""
        return float(self.open.lead)

    def check(self, scene: Scene) -> None:
        """The object must have one movable joint and the opening must lie within its travel; an
        approach posture must have one entry per robot joint."""
        swapped = " (are the robot and object files swapped?)" if scene.nq <= 1 < scene.no else ""
        if scene.no != 1:
            raise InvalidValueError(
                f"OpenObject needs an object with one movable joint; {scene.object_name!r} has {scene.no}: "
                f"{list(scene.object_joint_names)}{swapped}; pick the one to open with "
                f"Scene.from_urdf(..., joint=<name>), which holds the others"
            )
        if "grasp" not in scene.frame_names:
            raise UnknownFrameError(f"OpenObject needs the robot frame 'grasp'; the robot has: {', '.join(scene.frame_names)}")
        self._handle(scene)  # the handle exists and its frame can be inferred
        lower, upper = float(scene.o_lower[0]), float(scene.o_upper[0])
        if self.opening is not None and not lower < self.opening <= upper:
            raise InvalidValueError(f"opening {self.opening} is outside the object's travel ({lower}, {upper}]")
        if self.approach.posture is not None and len(self.approach.posture) != scene.nq:
            raise InvalidValueError(f"approach.posture has {len(self.approach.posture)} entries, the robot has {scene.nq} joints")

    def target_opening(self, scene: Scene) -> float:
        """The opening to reach (rad or m): ``opening``, or 75 % of the range."""
        if self.opening is not None:
            return float(self.opening)
        return float(scene.o_lower[0] + 0.75 * (scene.o_upper[0] - scene.o_lower[0]))

    def handle_travel(self, scene: Scene, o: float) -> float:
        """Distance (m) the handle moves per unit of opening (rad or m) at opening o."""
        h = 1e-4 * (scene.o_upper[0] - scene.o_lower[0])
        lo, hi = np.clip([o - h, o + h], scene.o_lower[0], scene.o_upper[0])
        moved = self.handle_pose(scene, [hi])[:3, 3] - self.handle_pose(scene, [lo])[:3, 3]
        return float(np.linalg.norm(moved) / max(hi - lo, 1e-12))

    def object_setpoint(self, scene: Scene) -> float:
        """o* of the object cost (34): ``opening`` plus ``open.object_overshoot``.

        The power cost (36) charges w_p·τ_r·ȯ per step for moving the object against its
        resisting torque τ_r (friction, damping), and over a horizon T the object cost's pull
        on the opening rate is worth W_o·(o* − o)·T per step. The two balance at
        o* − o = w_p·τ_r / (W_o·T): with Table I weights and the shelf's 4 N·m friction, 0.47 rad
        before o*. With o* at the requested opening the object would stall that far short of it,
        so by default o* lies twice that gap beyond it (the object ends up a gap past the
        opening, or at its limit).
        """
        if self.open.object_overshoot is not None:
            return self.target_opening(scene) + float(self.open.object_overshoot)
        speed = self.open.speeds[0] if self.open.speeds else 0.1
        rate = speed / max(self.handle_travel(scene, float(scene.o_lower[0])), 1e-6)
        resisting = float(scene.object_friction[0] + scene.object_damping[0] * rate)
        gap = self.safety.power * resisting / (max(self.open.object_weight, 1e-12) * self.horizon)
        return self.target_opening(scene) + 2.0 * gap

    def grasp_offset(self, scene: Scene, phase: str) -> np.ndarray:
        """Pose of the grasp target in the handle frame for `phase`."""
        offsets = {"approach": self.approach.pregrasp_offset, "insert": self.approach.insert_offset, "hook": self.hook.offset}
        xyz = offsets.get(phase, self.open.offset)
        closed = self.handle_pose(scene, scene.o_lower)
        # Tilt about whichever handle axis (x or y) is horizontal, so that z points downward.
        axis = 0 if abs(closed[2, 0]) < abs(closed[2, 1]) else 1
        angle = self.approach.pitch
        c, s_ = np.cos(angle), np.sin(angle)
        rot = np.eye(3)
        if axis == 0:
            rot[1:, 1:] = [[c, -s_], [s_, c]]
        else:
            rot[np.ix_([0, 2], [0, 2])] = [[c, s_], [-s_, c]]
        z_world = closed[:3, :3] @ rot[:, 2]
        if z_world[2] > 0.0:  # tilted up: flip the direction
            rot = rot.T
        out = _offset(xyz)
        out[:3, :3] = rot
        return out

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        if phase == "release":
            return (
                costs.ObjectState([self.object_setpoint(scene)], self.open.object_weight)
                + costs.Contact(self.contact_weight)
                + self.safety.terms(scene)
                + self.extra
            )
        if phase in ("approach", "insert", "hook"):
            return (
                costs.TargetPose(
                    self._handle(scene)[1] @ self.grasp_offset(scene, phase), "grasp", self._handle(scene)[0],
                    self.approach.weight, self.approach.weight
                )
                + (costs.Contact(self.contact_weight) + self.posture_term(scene) if phase == "approach" else costs.Cost())
                # Also before the hook holds: a door that can open by itself (a dishwasher past its
                # balance point, resting on the hand after a slip) should be let go, not held.
                + costs.ObjectState([self.object_setpoint(scene)], self.open.object_weight)
                + self.safety.terms(scene)
                + self.extra
            )
        return (
            costs.TargetPose(self._handle(scene)[1] @ self.grasp_offset(scene, phase), "grasp", self._handle(scene)[0],
                             weights=tuple(self.open.pose_weights),
                             lead=self.lead(scene), lead_limit=self.target_opening(scene))
            + costs.ObjectState([self.object_setpoint(scene)], self.open.object_weight)
            + self.safety.terms(scene)
            + self.extra
        )

    def approach_error(self, scene: Scene, x: np.ndarray, phase: str = "insert") -> GraspError:
        """Distance (m) and angle (rad) of the grasp frame from the target of `phase` at state x (nx,)."""
        nq, no = scene.nq, scene.no
        target = self.handle_pose(scene, x[2 * nq : 2 * nq + no]) @ self.grasp_offset(scene, phase)
        pose = scene.fk(x[:nq], "grasp")
        dp = float(np.linalg.norm(pose[:3, 3] - target[:3, 3]))
        cos = (np.trace(target[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
        return GraspError(distance=dp, angle=float(np.arccos(np.clip(cos, -1.0, 1.0))))

    def pocket_error(self, scene: Scene, x: np.ndarray, phase: str) -> PocketError:
        """(across, along) distance (m) of the grasp frame from the target of `phase`: across the
        bar (handle frame y and z) and along it (x). Sliding along the bar does not matter for
        hooking; only the position across it does."""
        handle, offset = self._grasp_from_target(scene, x, phase)
        e = handle[:3, :3].T @ offset
        return PocketError(across=float(np.hypot(e[1], e[2])), along=float(abs(e[0])))

    def depth_error(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        """Signed distance (m) of the grasp frame from the target of `phase` along the handle
        frame's z axis (into the door): negative while the finger is still short of it."""
        handle, offset = self._grasp_from_target(scene, x, phase)
        return float(handle[:3, 2] @ offset)

    def _grasp_from_target(self, scene: Scene, x: np.ndarray, phase: str) -> tuple[np.ndarray, np.ndarray]:
        """The handle's pose (4, 4) and the grasp frame's offset (3,) from the target of `phase`,
        in world axes."""
        nq, no = scene.nq, scene.no
        handle = self.handle_pose(scene, x[2 * nq : 2 * nq + no])
        target = handle @ self.grasp_offset(scene, phase)
        return handle, scene.fk(x[:nq], "grasp")[:3, 3] - target[:3, 3]

    def lateral_error(self, scene: Scene, x: np.ndarray) -> float:
        """Sideways offset (m) of the grasp frame from its open-phase target, along the handle
        frame's y axis: how far the bar has moved toward leaving the finger's pocket."""
        nq, no = scene.nq, scene.no
        handle = self.handle_pose(scene, x[2 * nq : 2 * nq + no])
        grasp = np.linalg.solve(handle, scene.fk(x[:nq], "grasp"))
        return float(grasp[1, 3] - self.open.offset[1])

    def self_opening(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object, left alone at rest, opens further by itself (a dishwasher door past
        its balance point): the rollout model run for ``release.probe`` s from x with the robot and
        the object at rest and the robot moved 5 m away from the object, checked against
        ``release.rate``."""
        nq, no = scene.nq, scene.no
        if self.success(scene, x) or float(x[2 * nq]) >= scene.o_upper[0] - 1e-3:
            return False
        model = self._probe_model(scene)
        free = np.array(x, dtype=np.float64)
        away = free[:2] - scene.object_pose[:2, 3]
        norm = float(np.linalg.norm(away))
        free[:2] = scene.object_pose[:2, 3] + 5.0 * (away / norm if norm > 1e-9 else np.array([-1.0, 0.0]))
        free[nq : 2 * nq] = 0.0
        free[2 * nq + no :] = 0.0  # from rest: a drawer still coasting from a pull does not open by itself
        steps = max(1, int(round(self.release.probe / model.dt)))
        end = model.rollout(free, np.zeros((1, steps, scene.nu))).states[0, -1]
        return float(end[2 * nq + no]) > self.release.rate

    def release_path(self, scene: Scene, x: np.ndarray, steps: int, dt: float) -> np.ndarray:
        """(steps + 1, 4, 4) grasp-frame targets that let go of the handle, at ``release.speed``:
        a finger within ``open.slip_distance`` of the pocket leaves the way it came in, riding on
        the handle as the object keeps opening at its current rate (back across the bar to the
        insert offset's sideways position, then back to the pre-grasp offset's depth, clear of the
        bar); then the hand backs off ``release.distance`` along :meth:`release_direction`, fixed in
        the world. Backing off with the bar still in the pocket drags it, or lifts it against a door
        hinged below, which pushes the door back toward closed; following the handle for longer
        would chase a falling door into the robot."""
        nq, no = scene.nq, scene.no
        handle = self.handle_pose(scene, x[2 * nq : 2 * nq + no])
        relative = np.linalg.solve(handle, scene.fk(x[:nq], "grasp"))
        sideways = float(self.approach.insert_offset[1]) - relative[1, 3]
        hooked = abs(sideways) <= self.open.slip_distance  # else the finger slipped away: just back off
        unhook = abs(sideways) if hooked else 0.0
        clear = max(relative[2, 3] - float(self.approach.pregrasp_offset[2]), 0.0) if hooked else 0.0
        travel = np.minimum(self.release.speed * dt * np.arange(steps + 1), unhook + clear + self.release.distance)
        offsets = np.repeat(relative[None], steps + 1, axis=0)
        offsets[:, 1, 3] += np.sign(sideways) * np.minimum(travel, unhook)
        offsets[:, 2, 3] -= np.clip(travel - unhook, 0.0, clear)
        rate = max(float(x[2 * nq + no]), 0.0)
        openings = np.minimum(float(x[2 * nq]) + rate * dt * np.arange(steps + 1), scene.o_upper[0])
        targets = self.handle_poses(scene, openings[:, None]) @ offsets
        free = travel >= unhook + clear
        out = int(np.argmax(free)) if np.any(free) else steps + 1
        if out <= steps:
            targets[out:] = targets[out]
            away = travel[out:] - unhook - clear
            targets[out:, :3, 3] += away[:, None] * self.release_direction(scene, x)
        return targets

    def release_direction(self, scene: Scene, x: np.ndarray) -> np.ndarray:
        """(3,) unit direction in which the hand backs off when releasing: away from the door
        (the grasp frame's −z) and, for a hinged door, out of its sweep (away from the hinge axis,
        found as the centre of the circle through three handle positions about the current
        opening), half each."""
        nq = scene.nq
        pose = scene.fk(x[:nq], "grasp")
        back = -pose[:3, 2]
        if not scene.object_is_revolute:
            return back
        o = float(x[2 * nq])
        p0, p1, p2 = self.handle_poses(scene, np.array([[o - 0.1], [o], [o + 0.1]]))[:, :3, 3]
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

    def _probe_model(self, scene: Scene) -> RolloutModel:
        cache = self.__dict__.setdefault("_probe_models", {})
        if id(scene) not in cache:
            cache.clear()
            cache[id(scene)] = (scene, RolloutModel(scene))
        return cache[id(scene)][1]

    def next_phase(self, scene: Scene, x: np.ndarray, t: float, phase: str) -> str:
        if phase == "release":
            return "release" if self.self_opening(scene, x) else "approach"
        if phase in ("approach", "insert", "hook") and float(x[2 * scene.nq]) > 0.0 and self.self_opening(scene, x):
            return "release"
        if phase == "approach":
            error = self.approach_error(scene, x, "approach")
            if error.distance < 2.0 * self.approach.switch_position and error.angle < self.approach.switch_angle:
                return "insert"
        if phase == "insert":
            angle = self.approach_error(scene, x, "insert").angle
            pocket = self.pocket_error(scene, x, "insert")
            across, along = pocket.across, pocket.along
            depth = self.hook.insert_depth_tolerance
            deep = depth is None or abs(self.depth_error(scene, x, "insert")) < depth
            aligned = along < self.hook.along_tolerance and angle < self.approach.switch_angle
            if across < self.approach.switch_position and aligned and deep:
                return "hook"
        if phase == "hook":
            angle = self.approach_error(scene, x, "hook").angle
            pocket = self.pocket_error(scene, x, "hook")
            across, along = pocket.across, pocket.along
            if across < self.hook.tolerance and along < self.hook.along_tolerance and angle < self.approach.switch_angle:
                return "open"
        if phase in ("insert", "hook") and self.pulling(scene, x):
            return "open"
        if phase == "hook" and self.backed_out(scene, x):
            return "approach"
        if phase == "open" and not self.success(scene, x):
            # A door past its balance point opens the rest of the way by itself: holding it only
            # makes the arm follow it down into its joint limits.
            if self.self_opening(scene, x):
                return "release"
            dp = self.approach_error(scene, x, "open").distance
            if dp > self.open.slip_distance or abs(self.lateral_error(scene, x)) > self.open.slip_lateral:
                if not self.running_ahead(scene, x):
                    return "approach"
        return phase

    def guides(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> np.ndarray | None:
        nq, no = scene.nq, scene.no
        q, o = x[:nq], x[2 * nq : 2 * nq + no]
        if phase == "release":
            if self.release.speed <= 0.0:
                return None
            targets = self.release_path(scene, x, steps, dt)
            guide = servo_guide(scene, q, targets, dt, gain=self.guide.gain, max_linear=2.0 * self.release.speed, max_angular=1.0)
            return guide[None]
        offset = self.grasp_offset(scene, phase)
        if phase != "open":
            if self.guide.speed <= 0.0:
                return None
            target = self.handle_pose(scene, o) @ offset
            speed = self.guide.speed if phase == "approach" else self.guide.fine_speed
            targets = np.broadcast_to(target, (steps + 1, 4, 4))
            return servo_guide(scene, q, targets, dt, gain=self.guide.gain, max_linear=speed, max_angular=4.0 * speed)[None]
        if not self.open.speeds:
            return None
        travel = self.handle_travel(scene, float(o[0]))
        end = min(self.object_setpoint(scene), scene.o_upper[0])
        out = []
        speeds = list(self.open.speeds)
        own = float(x[2 * nq + no]) * travel
        if own > max(speeds):
            speeds.insert(0, own)  # follow the object at its own pace
        for speed in speeds:
            rate = speed / max(travel, 1e-6)
            openings = np.minimum(o[0] + rate * dt * np.arange(steps + 1), max(end, o[0]))
            targets = self.handle_poses(scene, openings[:, None]) @ offset
            out.append(servo_guide(scene, q, targets, dt, gain=self.guide.gain, max_linear=2.0 * speed + 0.05, max_angular=2.0))
        return np.stack(out)

    def gain_inertia_floor(self, phase: str) -> float | None:
        return self.open.gain_inertia_floor if phase == "open" else None

    def pulling(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger already pulls the object open before the hook test passed: the
        handle opens faster than ``hook.drag_speed`` (m/s) while the grasp frame is within the open
        phase's slip bounds (the bar sits in the pocket, just not where the hook target put it),
        and the handle is at least ``hook.drag_distance`` (m) from closed. An object that opens by
        itself is caught by ``self_opening`` first."""
        if self.hook.drag_speed <= 0.0:
            return False
        if self.handle_from_closed(scene, x) < self.hook.drag_distance:
            return False
        if self.handle_speed(scene, x) <= self.hook.drag_speed:
            return False
        dp = self.approach_error(scene, x, "open").distance
        return dp <= self.open.slip_distance and abs(self.lateral_error(scene, x)) <= self.open.slip_lateral

    def backed_out(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger, hooking an object already opened, has backed out in front of the bar
        without moving it: the grasp frame more than ``hook.backout`` (m) short of the hook target's
        depth, the handle at least ``hook.drag_distance`` (m) from closed (as for ``pulling``) and opening
        no faster than ``hook.drag_speed`` (m/s). A finger that catches the bar with its tip often drags
        a free door open that way until the bar slides into the pocket (``pulling``), and on a closed
        door that is how the drag starts; a door that was opened and does not move now (held, or
        stuck) only takes the tank's energy for the catch."""
        if self.hook.backout is None or self.depth_error(scene, x, "hook") >= -self.hook.backout:
            return False
        if self.handle_from_closed(scene, x) < self.hook.drag_distance:
            return False
        return self.handle_speed(scene, x) <= self.hook.drag_speed

    def handle_speed(self, scene: Scene, x: np.ndarray) -> float:
        """Speed (m/s) of the handle in the opening direction (negative while closing)."""
        nq, no = scene.nq, scene.no
        return float(x[2 * nq + no]) * self.handle_travel(scene, float(x[2 * nq]))

    def handle_from_closed(self, scene: Scene, x: np.ndarray) -> float:
        """Distance (m) of the handle from where it is with the object closed."""
        nq, no = scene.nq, scene.no
        closed = self.handle_pose(scene, scene.o_lower)[:3, 3]
        return float(np.linalg.norm(self.handle_pose(scene, x[2 * nq : 2 * nq + no])[:3, 3] - closed))

    def running_ahead(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object opens by itself faster than ``release.runaway_speed`` (m/s at the handle), as
        a dishwasher door does past its balance point. The hand then rides along (its finger sits
        in the door's path) instead of starting over from the approach."""
        return self.handle_speed(scene, x) > self.release.runaway_speed

    def noise_scale(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        if phase in ("open", "release"):
            return self.noise.open
        d = self.approach_error(scene, x, phase).distance
        return float(np.clip((d / self.noise.distance) ** 2, self.noise.floor, 1.0))

    def opening_of(self, scene: Scene, x: np.ndarray) -> float:
        """The object's opening (rad or m) at state x."""
        return float(x[2 * scene.nq])

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        return self.opening_of(scene, x) >= self.open.success_fraction * self.target_opening(scene)
