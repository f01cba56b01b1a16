"""Tasks: what the controller should achieve, as phases with a cost each, a switch rule and a success test.

Subclass :class:`Task` to script your own: give ``phases``, ``cost(scene, phase)``,
``next_phase(scene, x, t, phase)`` and ``success(scene, x)``; ``on_step`` runs once per planning
iteration for anything else (logging, moving a target, ...).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from . import costs
from ._validate import as_float_array, as_non_negative, as_positive
from .errors import InvalidValueError
from .guides import servo_guide
from .scene import Scene
from .sim import RolloutModel

__all__ = ["Task", "Reach", "OpenObject", "SafetyWeights"]


@dataclass(frozen=True)
class SafetyWeights:
    """Weights of the terms that every phase carries (Table I defaults)."""

    joint_limit: float = 1000.0
    joint_limit_slope: float = 100.0
    reach: float = 1000.0
    reach_slope: float = 100.0
    self_collision: float = 1000.0
    self_collision_slope: float = 100.0
    power: float = 10.0
    p_max: float = 0.0
    #: Keeps the base out of the sweep of the object's moving parts (not in Table I; see
    #: :class:`sabre.costs.BaseClearance`). Zero weights leave it out.
    base_clearance: float = 100.0
    base_clearance_slope: float = 10000.0
    base_link: str = "base_link"

    def terms(self, scene: Scene) -> costs.Cost:
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

    phases: tuple[str, ...] = ("main",)

    def initial_phase(self) -> str:
        return self.phases[0]

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        """The cost the controller minimises during `phase`."""
        return costs.Cost()

    def next_phase(self, scene: Scene, x: np.ndarray, t: float, phase: str) -> str:
        """The phase to use from state x at time t (called before every planning iteration)."""
        return phase

    def success(self, scene: Scene, x: np.ndarray) -> bool:
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

    def on_step(self, scene: Scene, x: np.ndarray, t: float, controller) -> None:
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
    pose_weight: float = 100.0
    safety: SafetyWeights = field(default_factory=SafetyWeights)
    position_tolerance: float = 0.02
    angle_tolerance: float = 0.1
    extra: costs.Cost = field(default_factory=costs.Cost)

    phases = ("reach",)

    def __post_init__(self) -> None:
        self.target_pose = as_float_array("target_pose", self.target_pose, (4, 4))

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        return costs.TargetPose(self.target_pose, self.frame, None, self.pose_weight, self.pose_weight) + self.safety.terms(scene) + self.extra

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        pose = scene.fk(x[: scene.nq], self.frame)
        dp = np.linalg.norm(pose[:3, 3] - self.target_pose[:3, 3])
        cos = (np.trace(self.target_pose[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
        return dp < self.position_tolerance and np.arccos(np.clip(cos, -1.0, 1.0)) < self.angle_tolerance


def _offset(xyz: tuple[float, float, float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = xyz
    return t


@dataclass
class OpenObject(Task):
    """Open the scene's object to ``opening`` (rad or m; default 75 % of its range).

    The two phases of the paper (reach the handle, then open) with the reaching split into the
    moves a hook finger needs:

    - approach: drive the ``grasp`` frame to a pre-grasp pose 7 cm in front of the handle
      (``handle_frame``) and beside the bar, touching nothing (contact cost on);
    - insert: move in until the finger is beside the bar with its tip past it (touching is no
      longer penalised: with the sampling noise, every move that close to the handle brushes it);
    - hook: slide sideways so the bar sits in the finger's pocket, behind the tip;
    - open: the pose target sits in the pocket, 1.6 cm out from the bar (the pull), and follows the
      handle as the object moves; the object cost pulls toward the target opening. The pose weight
      is low along the bar and toward the door (the hand may slide along the handle and take up
      slack) and high sideways (the bar must stay in the pocket).

    Switches happen when the grasp frame is within ``switch_position`` (m) and ``switch_angle``
    (rad) of the current phase's target (twice that for the approach, ``hook_tolerance`` for the
    hook; for inserting and hooking only the distance across the bar counts, and along the bar
    ``along_tolerance``; inserting also ends only within ``insert_depth_tolerance`` of the
    target's depth, so the tip is behind the bar before it slides sideways; a finger that backs out
    more than ``hook_backout`` while hooking an opened object, and does not move the handle,
    starts over from the approach). A handle the finger already drags open while inserting or
    hooking (``pulling``) also switches to opening. If the bar leaves the pocket while opening (the
    grasp frame more than ``slip_distance`` from its target), the task starts over from the
    approach.
    Success: opening ≥ 90 % of the target.
    """

    opening: float | None = None
    approach_weight: float = 100.0
    #: open-phase pose weights (x along the bar, y sideways, z into the door, then rotation).
    open_pose_weights: tuple[float, float, float, float, float, float] = (100.0, 10000.0, 1000.0, 1000.0, 1000.0, 1000.0)
    #: while opening, the pose target sits on the handle this far (rad or m) ahead of the object's
    #: current opening, so the hand is led along the opening path (0: the handle as it is).
    open_lead: float = 0.0
    object_weight: float = 100.0
    #: o* of the object cost lies this far (rad or m) beyond ``opening``; None: from the power
    #: balance (see :meth:`object_setpoint`), with ``horizon`` the controller's horizon T (s).
    object_overshoot: float | None = None
    horizon: float = 1.0
    contact_weight: float = 100.0
    safety: SafetyWeights = field(default_factory=SafetyWeights)
    #: grasp pose in the handle frame while approaching (in front of and beside the bar), inserting
    #: (beside the bar, tip past it), hooking (bar in the pocket) and opening (pulling on the bar).
    pregrasp_offset: tuple[float, float, float] = (0.0, -0.022, -0.07)
    approach_offset: tuple[float, float, float] = (0.0, -0.022, 0.0)
    #: (the bar sits 3 mm toward the finger from the grasp frame: the pocket's middle, clear of the
    #: tip's open end.)
    hook_offset: tuple[float, float, float] = (0.0, 0.003, 0.0)
    open_offset: tuple[float, float, float] = (0.0, 0.003, -0.016)
    #: the hand points this much (rad) below the handle's normal, tilted about the handle's horizontal
    #: axis: a Panda reaches a forward-and-down hand at handle height with margin on its wrist joint,
    #: a level one only at its wrist limit; the hook still closes around the bar.
    approach_pitch: float = 0.3
    switch_position: float = 0.015
    switch_angle: float = 0.15
    hook_tolerance: float = 0.006
    #: how far (m) from the insert target's depth (handle frame z, toward the door) the grasp frame
    #: may be when inserting ends. The hook phase slides the finger sideways, and its tip must pass
    #: behind the bar to do so: at 5 mm short, the tip's nearest corner clears the bar's back face by
    #: about 4.5 mm at the default pitch; at 14 mm short (which ``switch_position`` alone lets
    #: through) it sits level with the bar, and sliding sideways drives the tip's corner into it.
    #: Seen on the stuck door: hooking again under a held door, a finger that jammed this way pulled
    #: the tank down to its floor and never hooked. None: no depth test (the earlier behaviour).
    insert_depth_tolerance: float | None = 0.005
    #: how far (m) short of the hook target's depth the grasp frame may back out while hooking
    #: before the task starts over from the approach, if the object was already opened and the
    #: handle does not move (see ``backed_out``). About 10 mm short the tip's nearest corner reaches
    #: the bar's back face: the finger can no longer pass behind the bar, and the tip's edge catches
    #: on it instead. Seen on the stuck door: hooking under a held door, the hand drifted back while
    #: it slid, and the planner (whose model lets the door open) pulled on that catch until the tank
    #: was spent, then the finger went round to the wrong side of the bar. None: never (the earlier
    #: behaviour).
    hook_backout: float | None = 0.010
    #: how far (m) along the bar the grasp frame may be from its target when inserting and hooking
    along_tolerance: float = 0.03
    slip_distance: float = 0.05
    #: handle speed (m/s, opening direction) that, with the grasp frame within the slip bounds,
    #: counts as the finger already pulling while inserting or hooking (see ``pulling``); 0: off.
    drag_speed: float = 0.02
    #: distance (m) of the handle from closed below which ``pulling`` never fires: a door that
    #: falls open once moved (a dishwasher) is found opening by itself first and released instead.
    drag_distance: float = 0.03
    slip_lateral: float = 0.01
    success_fraction: float = 0.9
    #: optional preferred arm posture while approaching (joint targets; None: a Panda posture that
    #: holds a hand level with a handle) and its weight per rad² (0: off).
    posture: Sequence[float] | None = None
    posture_weight: float = 0.0
    #: noise schedule: while reaching, Σ is scaled by (d / noise_distance)², clipped to
    #: [noise_floor, 1], where d is the grasp frame's distance to the phase's target; opening uses
    #: noise_open (the hand must travel far, but stay hooked).
    noise_distance: float = 0.5
    noise_floor: float = 1e-3
    noise_open: float = 0.01
    #: guides (see ``Task.guides``): a pose servo toward the phase's target, capped at
    #: ``guide_speed`` (m/s) while approaching and ``guide_fine_speed`` when inserting and hooking;
    #: while opening, servos that follow the handle along its path at each of ``open_speeds``
    #: (m/s of the handle). Empty ``open_speeds`` and ``guide_speed = 0`` turn guides off.
    guide_speed: float = 0.3
    guide_fine_speed: float = 0.05
    guide_gain: float = 2.0
    open_speeds: tuple[float, ...] = (0.1, 0.05)
    #: handle speed (m/s) above which the object is taken to open by itself (see running_ahead)
    runaway_speed: float = 0.15
    #: An object that opens by itself once free (see ``self_opening``) and is not held by the hook
    #: is let go: the "release" phase backs the hand off at ``release_speed`` (m/s), up to
    #: ``release_distance`` (m), away from the door and out of its sweep (``release_direction``),
    #: with the object and contact costs.
    release_speed: float = 0.4
    release_distance: float = 0.3
    #: opening rate (rad/s or m/s) that counts as opening by itself, within ``release_probe`` s
    release_rate: float = 0.05
    release_probe: float = 0.15
    #: gain inertia floor (kg m²) of the low-level controller while opening (see
    #: ``gain_inertia_floor`` and :class:`sabre.LowLevelController`), e.g. 0.03: pulling hard on a
    #: held door, the hand's own joint (0.007 kg m²) then no longer lets the finger twist off the
    #: bar, while hooking stays compliant so the finger yields around the bar. None (default): the
    #: controller's own. Measured on the stuck door before ``insert_depth_tolerance`` existed
    #: (README, Scenarios), 0.03 did not make more doors open after release over 20 seeds (14 of 17
    #: held, against 14 of 19 held without); not re-measured since.
    open_gain_inertia_floor: float | None = None
    extra: costs.Cost = field(default_factory=costs.Cost)

    phases = ("approach", "insert", "hook", "open", "release")

    def __post_init__(self) -> None:
        for name in ("approach_weight", "object_weight", "contact_weight", "switch_position", "switch_angle",
                     "hook_tolerance", "along_tolerance", "slip_distance", "slip_lateral", "drag_speed", "drag_distance",
                     "posture_weight", "noise_floor", "noise_open", "guide_speed", "guide_fine_speed",
                     "guide_gain", "runaway_speed", "release_speed", "release_distance", "release_rate"):
            setattr(self, name, as_non_negative(name, getattr(self, name)))
        for name in ("open_gain_inertia_floor", "insert_depth_tolerance", "hook_backout"):
            if getattr(self, name) is not None:
                setattr(self, name, as_non_negative(name, getattr(self, name)))
        for name in ("horizon", "noise_distance", "release_probe"):
            setattr(self, name, as_positive(name, getattr(self, name)))
        for name in ("opening", "object_overshoot", "open_lead", "approach_pitch"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(value):
                raise InvalidValueError(f"{name} must be finite, got {value}")
        if not 0.0 < self.success_fraction <= 1.0:
            raise InvalidValueError(f"success_fraction must be in (0, 1], got {self.success_fraction}")

    def posture_term(self, scene: Scene) -> costs.Cost:
        names = scene.joint_names
        if self.posture_weight <= 0.0:
            return costs.Cost()
        if self.posture is not None:
            target = np.asarray(self.posture, dtype=float)
            weights = np.where(np.arange(scene.nq) < 3, 0.0, self.posture_weight)
        elif all(f"panda_joint{i}" in names for i in (2, 4, 6)):
            target = np.zeros(scene.nq)
            weights = np.zeros(scene.nq)
            for joint, value in (("panda_joint2", 1.0), ("panda_joint4", -1.2), ("panda_joint6", 2.9)):
                i = names.index(joint)
                target[i], weights[i] = value, self.posture_weight
        else:
            return costs.Cost()
        return costs.Cost([costs.Posture(target, weights)])

    def lead(self, scene: Scene) -> float:
        return float(self.open_lead)

    def target_opening(self, scene: Scene) -> float:
        if self.opening is not None:
            return float(self.opening)
        return float(scene.o_lower[0] + 0.75 * (scene.o_upper[0] - scene.o_lower[0]))

    def handle_travel(self, scene: Scene, o: float) -> float:
        """Distance (m) the handle moves per unit of opening (rad or m) at opening o."""
        h = 1e-4 * (scene.o_upper[0] - scene.o_lower[0])
        lo, hi = np.clip([o - h, o + h], scene.o_lower[0], scene.o_upper[0])
        moved = scene.object_fk([hi], "handle_frame")[:3, 3] - scene.object_fk([lo], "handle_frame")[:3, 3]
        return float(np.linalg.norm(moved) / max(hi - lo, 1e-12))

    def object_setpoint(self, scene: Scene) -> float:
        """o* of the object cost (34): ``opening`` plus ``object_overshoot``.

        The power cost (36) charges w_p·τ_r·ȯ per step for moving the object against its
        resisting torque τ_r (friction, damping), and over a horizon T the object cost's pull
        on the opening rate is worth W_o·(o* − o)·T per step. The two balance at
        o* − o = w_p·τ_r / (W_o·T): with Table I weights and the shelf's 4 N·m friction, 0.47 rad
        before o*. With o* at the requested opening the object would stall that far short of it,
        so by default o* lies twice that gap beyond it (the object ends up a gap past the
        opening, or at its limit).
        """
        if self.object_overshoot is not None:
            return self.target_opening(scene) + float(self.object_overshoot)
        speed = self.open_speeds[0] if self.open_speeds else 0.1
        rate = speed / max(self.handle_travel(scene, float(scene.o_lower[0])), 1e-6)
        resisting = float(scene.object_friction[0] + scene.object_damping[0] * rate)
        gap = self.safety.power * resisting / (max(self.object_weight, 1e-12) * self.horizon)
        return self.target_opening(scene) + 2.0 * gap

    def grasp_offset(self, scene: Scene, phase: str) -> np.ndarray:
        """Pose of the grasp target in the handle frame for `phase`."""
        xyz = {"approach": self.pregrasp_offset, "insert": self.approach_offset, "hook": self.hook_offset}.get(phase, self.open_offset)
        closed = scene.object_fk(scene.o_lower, "handle_frame")
        # Tilt about whichever handle axis (x or y) is horizontal, so that z points downward.
        axis = 0 if abs(closed[2, 0]) < abs(closed[2, 1]) else 1
        angle = self.approach_pitch
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
                costs.ObjectState([self.object_setpoint(scene)], self.object_weight)
                + costs.Contact(self.contact_weight)
                + self.safety.terms(scene)
                + self.extra
            )
        if phase in ("approach", "insert", "hook"):
            return (
                costs.TargetPose(self.grasp_offset(scene, phase), "grasp", "handle_frame", self.approach_weight, self.approach_weight)
                + (costs.Contact(self.contact_weight) + self.posture_term(scene) if phase == "approach" else costs.Cost())
                # Also before the hook holds: a door that can open by itself (a dishwasher past its
                # balance point, resting on the hand after a slip) should be let go, not held.
                + costs.ObjectState([self.object_setpoint(scene)], self.object_weight)
                + self.safety.terms(scene)
                + self.extra
            )
        return (
            costs.TargetPose(self.grasp_offset(scene, phase), "grasp", "handle_frame", weights=tuple(self.open_pose_weights),
                             lead=self.lead(scene), lead_limit=self.target_opening(scene))
            + costs.ObjectState([self.object_setpoint(scene)], self.object_weight)
            + self.safety.terms(scene)
            + self.extra
        )

    def approach_error(self, scene: Scene, x: np.ndarray, phase: str = "insert") -> tuple[float, float]:
        """Distance (m) and angle (rad) of the grasp frame from the target of `phase`."""
        nq, no = scene.nq, scene.no
        target = scene.object_fk(x[2 * nq : 2 * nq + no], "handle_frame") @ self.grasp_offset(scene, phase)
        pose = scene.fk(x[:nq], "grasp")
        dp = float(np.linalg.norm(pose[:3, 3] - target[:3, 3]))
        cos = (np.trace(target[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
        return dp, float(np.arccos(np.clip(cos, -1.0, 1.0)))

    def pocket_error(self, scene: Scene, x: np.ndarray, phase: str) -> tuple[float, float]:
        """(across, along) distance (m) of the grasp frame from the target of `phase`: across the
        bar (handle frame y and z) and along it (x). Sliding along the bar does not matter for
        hooking; only the position across it does."""
        handle, offset = self._grasp_from_target(scene, x, phase)
        e = handle[:3, :3].T @ offset
        return float(np.hypot(e[1], e[2])), float(abs(e[0]))

    def depth_error(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        """Signed distance (m) of the grasp frame from the target of `phase` along the handle
        frame's z axis (into the door): negative while the finger is still short of it."""
        handle, offset = self._grasp_from_target(scene, x, phase)
        return float(handle[:3, 2] @ offset)

    def _grasp_from_target(self, scene: Scene, x: np.ndarray, phase: str) -> tuple[np.ndarray, np.ndarray]:
        """The handle's pose (4, 4) and the grasp frame's offset (3,) from the target of `phase`,
        in world axes."""
        nq, no = scene.nq, scene.no
        handle = scene.object_fk(x[2 * nq : 2 * nq + no], "handle_frame")
        target = handle @ self.grasp_offset(scene, phase)
        return handle, scene.fk(x[:nq], "grasp")[:3, 3] - target[:3, 3]

    def lateral_error(self, scene: Scene, x: np.ndarray) -> float:
        """Sideways offset (m) of the grasp frame from its open-phase target, along the handle
        frame's y axis: how far the bar has moved toward leaving the finger's pocket."""
        nq, no = scene.nq, scene.no
        handle = scene.object_fk(x[2 * nq : 2 * nq + no], "handle_frame")
        grasp = np.linalg.solve(handle, scene.fk(x[:nq], "grasp"))
        return float(grasp[1, 3] - self.open_offset[1])

    def self_opening(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object, left alone, opens further by itself (a dishwasher door past its
        balance point): the rollout model run for ``release_probe`` s from x with the robot at rest
        and moved 5 m away from the object, checked against ``release_rate``."""
        nq, no = scene.nq, scene.no
        if self.success(scene, x) or float(x[2 * nq]) >= scene.o_upper[0] - 1e-3:
            return False
        model = self._probe_model(scene)
        free = np.array(x, dtype=np.float64)
        away = free[:2] - scene.object_pose[:2, 3]
        norm = float(np.linalg.norm(away))
        free[:2] = scene.object_pose[:2, 3] + 5.0 * (away / norm if norm > 1e-9 else np.array([-1.0, 0.0]))
        free[nq : 2 * nq] = 0.0
        steps = max(1, int(round(self.release_probe / model.dt)))
        end = model.rollout(free, np.zeros((1, steps, scene.nu))).states[0, -1]
        return float(end[2 * nq + no]) > self.release_rate

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
        p0, p1, p2 = scene.object_fk_many(np.array([[o - 0.1], [o], [o + 0.1]]), "handle_frame")[:, :3, 3]
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
            dp, angle = self.approach_error(scene, x, "approach")
            if dp < 2.0 * self.switch_position and angle < self.switch_angle:
                return "insert"
        if phase == "insert":
            _, angle = self.approach_error(scene, x, "insert")
            across, along = self.pocket_error(scene, x, "insert")
            depth = self.insert_depth_tolerance
            deep = depth is None or abs(self.depth_error(scene, x, "insert")) < depth
            if across < self.switch_position and along < self.along_tolerance and angle < self.switch_angle and deep:
                return "hook"
        if phase == "hook":
            _, angle = self.approach_error(scene, x, "hook")
            across, along = self.pocket_error(scene, x, "hook")
            if across < self.hook_tolerance and along < self.along_tolerance and angle < self.switch_angle:
                return "open"
        if phase in ("insert", "hook") and self.pulling(scene, x):
            return "open"
        if phase == "hook" and self.backed_out(scene, x):
            return "approach"
        if phase == "open" and not self.success(scene, x):
            dp, _ = self.approach_error(scene, x, "open")
            if dp > self.slip_distance or abs(self.lateral_error(scene, x)) > self.slip_lateral:
                if self.self_opening(scene, x):
                    return "release"
                if not self.running_ahead(scene, x):
                    return "approach"
        return phase

    def guides(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> np.ndarray | None:
        nq, no = scene.nq, scene.no
        q, o = x[:nq], x[2 * nq : 2 * nq + no]
        if phase == "release":
            if self.release_speed <= 0.0:
                return None
            pose = scene.fk(q, "grasp")
            way = self.release_direction(scene, x)
            back = np.minimum(self.release_speed * dt * np.arange(steps + 1), self.release_distance)
            targets = np.repeat(pose[None], steps + 1, axis=0)
            targets[:, :3, 3] += back[:, None] * way
            return servo_guide(scene, q, targets, dt, gain=self.guide_gain, max_linear=2.0 * self.release_speed, max_angular=1.0)[None]
        offset = self.grasp_offset(scene, phase)
        if phase != "open":
            if self.guide_speed <= 0.0:
                return None
            target = scene.object_fk(o, "handle_frame") @ offset
            speed = self.guide_speed if phase == "approach" else self.guide_fine_speed
            targets = np.broadcast_to(target, (steps + 1, 4, 4))
            return servo_guide(scene, q, targets, dt, gain=self.guide_gain, max_linear=speed, max_angular=4.0 * speed)[None]
        if not self.open_speeds:
            return None
        travel = self.handle_travel(scene, float(o[0]))
        end = min(self.object_setpoint(scene), scene.o_upper[0])
        out = []
        speeds = list(self.open_speeds)
        own = float(x[2 * nq + no]) * travel
        if own > max(speeds):
            speeds.insert(0, own)  # follow the object at its own pace
        for speed in speeds:
            rate = speed / max(travel, 1e-6)
            openings = np.minimum(o[0] + rate * dt * np.arange(steps + 1), max(end, o[0]))
            targets = scene.object_fk_many(openings[:, None], "handle_frame") @ offset
            out.append(servo_guide(scene, q, targets, dt, gain=self.guide_gain, max_linear=2.0 * speed + 0.05, max_angular=2.0))
        return np.stack(out)

    def gain_inertia_floor(self, phase: str) -> float | None:
        return self.open_gain_inertia_floor if phase == "open" else None

    def pulling(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger already pulls the object open before the hook test passed: the
        handle opens faster than ``drag_speed`` (m/s) while the grasp frame is within the open
        phase's slip bounds (the bar sits in the pocket, just not where the hook target put it),
        and the handle is at least ``drag_distance`` (m) from closed. An object that opens by
        itself is caught by ``self_opening`` first."""
        if self.drag_speed <= 0.0:
            return False
        if self.handle_from_closed(scene, x) < self.drag_distance:
            return False
        if self.handle_speed(scene, x) <= self.drag_speed:
            return False
        dp, _ = self.approach_error(scene, x, "open")
        return dp <= self.slip_distance and abs(self.lateral_error(scene, x)) <= self.slip_lateral

    def backed_out(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger, hooking an object already opened, has backed out in front of the bar
        without moving it: the grasp frame more than ``hook_backout`` (m) short of the hook target's
        depth, the handle at least ``drag_distance`` (m) from closed (as for ``pulling``) and opening
        no faster than ``drag_speed`` (m/s). A finger that catches the bar with its tip often drags
        a free door open that way until the bar slides into the pocket (``pulling``), and on a closed
        door that is how the drag starts; a door that was opened and does not move now (held, or
        stuck) only takes the tank's energy for the catch."""
        if self.hook_backout is None or self.depth_error(scene, x, "hook") >= -self.hook_backout:
            return False
        if self.handle_from_closed(scene, x) < self.drag_distance:
            return False
        return self.handle_speed(scene, x) <= self.drag_speed

    def handle_speed(self, scene: Scene, x: np.ndarray) -> float:
        """Speed (m/s) of the handle in the opening direction (negative while closing)."""
        nq, no = scene.nq, scene.no
        return float(x[2 * nq + no]) * self.handle_travel(scene, float(x[2 * nq]))

    def handle_from_closed(self, scene: Scene, x: np.ndarray) -> float:
        """Distance (m) of the handle from where it is with the object closed."""
        nq, no = scene.nq, scene.no
        closed = scene.object_fk(np.asarray(scene.o_lower, dtype=np.float64), "handle_frame")[:3, 3]
        return float(np.linalg.norm(scene.object_fk(x[2 * nq : 2 * nq + no], "handle_frame")[:3, 3] - closed))

    def running_ahead(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object opens by itself faster than ``runaway_speed`` (m/s at the handle), as
        a dishwasher door does past its balance point. The hand then rides along (its finger sits
        in the door's path) instead of starting over from the approach."""
        return self.handle_speed(scene, x) > self.runaway_speed

    def noise_scale(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        if phase in ("open", "release"):
            return self.noise_open
        d, _ = self.approach_error(scene, x, phase)
        return float(np.clip((d / self.noise_distance) ** 2, self.noise_floor, 1.0))

    def opening_of(self, scene: Scene, x: np.ndarray) -> float:
        return float(x[2 * scene.nq])

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        return self.opening_of(scene, x) >= self.success_fraction * self.target_opening(scene)
