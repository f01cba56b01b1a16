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
from ._validate import as_float_array
from .scene import Scene

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

    def terms(self, scene: Scene) -> costs.Cost:
        out = costs.Cost([
            costs.JointLimits(self.joint_limit, self.joint_limit_slope),
            costs.SelfCollision(self.self_collision, self.self_collision_slope),
            costs.Power(self.power, self.p_max),
        ])
        if scene.arm_reach is not None:
            out = out + costs.ArmReach(weight=self.reach, weight_slope=self.reach_slope)
        return out


class Task:
    """Base class: a sequence of named phases, each with its cost."""

    phases: tuple[str, ...] = ("main",)

    def initial_phase(self) -> str:
        return self.phases[0]

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        """The cost the controller minimises during `phase`."""
        return costs.Cost()

    def lateral_error(self, scene: Scene, x: np.ndarray) -> float:
        """Sideways offset (m) of the grasp frame from its open-phase target, along the handle
        frame's y axis: how far the bar has moved toward leaving the finger's pocket."""
        nq, no = scene.nq, scene.no
        handle = scene.object_fk(x[2 * nq : 2 * nq + no], "handle_frame")
        grasp = np.linalg.solve(handle, scene.fk(x[:nq], "grasp"))
        return float(grasp[1, 3] - self.open_offset[1])

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

    def on_step(self, scene: Scene, x: np.ndarray, t: float, controller) -> None:
        """Hook called once per planning iteration, after the phase update."""


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
    hook). If the bar leaves the pocket while opening (the grasp frame more than
    ``slip_distance`` from its target), the task starts over from the approach. Success: opening
    ≥ 90 % of the target.
    """

    opening: float | None = None
    approach_weight: float = 100.0
    #: open-phase pose weights (x along the bar, y sideways, z into the door, then rotation).
    open_pose_weights: tuple[float, float, float, float, float, float] = (100.0, 10000.0, 1000.0, 1000.0, 1000.0, 1000.0)
    #: while opening, the pose target sits on the handle this far (rad or m) ahead of the object's
    #: current opening, so the hand is led along the opening path (0: the handle as it is).
    open_lead: float = 0.0
    object_weight: float = 100.0
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
    slip_distance: float = 0.05
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
    extra: costs.Cost = field(default_factory=costs.Cost)

    phases = ("approach", "insert", "hook", "open")

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
        if phase in ("approach", "insert", "hook"):
            return (
                costs.TargetPose(self.grasp_offset(scene, phase), "grasp", "handle_frame", self.approach_weight, self.approach_weight)
                + (costs.Contact(self.contact_weight) + self.posture_term(scene) if phase == "approach" else costs.Cost())
                + self.safety.terms(scene)
                + self.extra
            )
        return (
            costs.TargetPose(self.grasp_offset(scene, phase), "grasp", "handle_frame", weights=tuple(self.open_pose_weights),
                             lead=self.lead(scene), lead_limit=self.target_opening(scene))
            + costs.ObjectState([self.target_opening(scene)], self.object_weight)
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

    def next_phase(self, scene: Scene, x: np.ndarray, t: float, phase: str) -> str:
        if phase == "approach":
            dp, angle = self.approach_error(scene, x, "approach")
            if dp < 2.0 * self.switch_position and angle < self.switch_angle:
                return "insert"
        if phase == "insert":
            dp, angle = self.approach_error(scene, x, "insert")
            if dp < self.switch_position and angle < self.switch_angle:
                return "hook"
        if phase == "hook":
            dp, angle = self.approach_error(scene, x, "hook")
            if dp < self.hook_tolerance and angle < self.switch_angle:
                return "open"
        if phase == "open" and not self.success(scene, x):
            dp, _ = self.approach_error(scene, x, "open")
            if dp > self.slip_distance or abs(self.lateral_error(scene, x)) > self.slip_lateral:
                return "approach"
        return phase

    def noise_scale(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        if phase == "open":
            return self.noise_open
        d, _ = self.approach_error(scene, x, phase)
        return float(np.clip((d / self.noise_distance) ** 2, self.noise_floor, 1.0))

    def opening_of(self, scene: Scene, x: np.ndarray) -> float:
        return float(x[2 * scene.nq])

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        return self.opening_of(scene, x) >= self.success_fraction * self.target_opening(scene)
