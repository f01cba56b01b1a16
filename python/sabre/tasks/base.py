"""The task interface (:class:`Task`), the safety terms every phase carries, and the simplest task, :class:`Reach`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from .. import costs
from .._validate import as_pose
from ..scene import Scene

if TYPE_CHECKING:
    from ..guides import ServoGuidePlan

__all__ = ["Task", "Reach", "SafetyWeights", "TaskController"]


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
    #: The base's link for the clearance term (None: the scene's :attr:`~sabre.Scene.base_link`, for
    #: a robot with a holonomic base; a fixed base has no clearance term: it cannot get out of the way).
    base_link: str | None = None

    def terms(self, scene: Scene) -> costs.Cost:
        """The safety cost terms for the scene (arm reach and base clearance where the scene has them)."""
        out = costs.Cost(
            [
                costs.JointLimits(self.joint_limit, self.joint_limit_slope),
                costs.SelfCollision(self.self_collision, self.self_collision_slope),
                costs.Power(self.power, self.p_max),
            ]
        )
        if scene.arm_reach is not None:
            out = out + costs.ArmReach(weight=self.reach, weight_slope=self.reach_slope)
        link = self.base_link if self.base_link is not None else scene.base_link if scene.base_indices is not None else None
        if (self.base_clearance > 0.0 or self.base_clearance_slope > 0.0) and link in scene.frame_names:
            out = out + costs.BaseClearance(link, weight=self.base_clearance, weight_slope=self.base_clearance_slope)
        return out


class TaskController(Protocol):
    """The controller that runs a task, as the task's :meth:`Task.on_step` sees it
    (:class:`sabre.Controller` is one): the planner sits above its tasks, so they name it by this."""

    @property
    def scene(self) -> Scene: ...

    @property
    def task(self) -> Task: ...

    @property
    def phase(self) -> str:
        """The phase the controller plans for."""
        ...

    @property
    def phase_since(self) -> float:
        """When (s) the controller entered its phase."""
        ...

    @property
    def nominal(self) -> np.ndarray:
        """(K, nu) the nominal input sequence the next iteration samples around."""
        ...

    def set_nominal(self, U: np.ndarray, t0: float) -> None: ...

    def set_phase(self, phase: str, t: float = 0.0) -> None: ...

    def refresh_cost(self) -> None: ...


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

    def guide_plan(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> ServoGuidePlan | None:
        """The task's guides as a plan (:func:`sabre.guides.servo_guide_plan`) whose guides the
        controller's rollout workers integrate, each the one of the row it rolls out, in parallel
        with the other rollouts; or None, and the controller takes :meth:`guides`. The controller
        asks this first: a task overrides it where its guides are servo guides, with the same
        guides :meth:`guides` gives."""
        return None

    def on_step(self, scene: Scene, x: np.ndarray, t: float, controller: TaskController) -> None:
        """Hook called once per planning iteration, after the phase update."""

    def gain_inertia_floor(self, phase: str) -> float | None:
        """The low-level controller's gain inertia floor (kg m², see
        :class:`sabre.LowLevelController`) to use during `phase`, or None for the controller's own.
        :func:`sabre.run_episode` applies it at every re-plan."""
        return None


@dataclass
class Reach(Task):
    """Bring robot frame ``frame`` (None: the scene's tool frame) to ``target_pose`` (4, 4); success
    within 2 cm and 0.1 rad."""

    frame: str | None = None
    target_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    pose_weight: float = costs.TargetPose.linear_weight
    safety: SafetyWeights = field(default_factory=SafetyWeights)
    position_tolerance: float = 0.02
    angle_tolerance: float = 0.1
    extra: costs.Cost = field(default_factory=costs.Cost)

    phases: ClassVar[tuple[str, ...]] = ("reach",)

    def __post_init__(self) -> None:
        self.target_pose = as_pose("target_pose", self.target_pose)

    def _frame(self, scene: Scene) -> str:
        return self.frame if self.frame is not None else scene.require_tool_frame("Reach")

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        pose = costs.TargetPose(self.target_pose, self._frame(scene), None, self.pose_weight, self.pose_weight)
        return pose + self.safety.terms(scene) + self.extra

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        pose = scene.fk(scene.split_state(x).q, self._frame(scene))
        dp = np.linalg.norm(pose[:3, 3] - self.target_pose[:3, 3])
        cos = (np.trace(self.target_pose[:3, :3].T @ pose[:3, :3]) - 1.0) / 2.0
        return bool(dp < self.position_tolerance and np.arccos(np.clip(cos, -1.0, 1.0)) < self.angle_tolerance)
