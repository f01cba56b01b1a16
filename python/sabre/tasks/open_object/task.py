"""OpenObject: opening the scene's object with a hook finger, as phases with their costs, switch rules, guides and noise."""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ... import _core, costs
from ..._validate import as_finite, as_non_negative, as_positive
from ...errors import InvalidValueError
from ...scene import Scene
from .._per_scene import per_scene
from ..base import SafetyWeights, Task, TaskController
from . import geometry
from .config import ApproachConfig, GuideConfig, HookConfig, NoiseConfig, OpenConfig, ReleaseConfig, rules_config
from .geometry import GraspError, PocketError

if TYPE_CHECKING:
    from ...guides import ServoGuidePlan

__all__ = ["OpenObject"]


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
      point) is let go: the finger leaves the pocket and the hand backs off;
    - hold (:class:`OpenConfig`): an opened object that stops following the pull (held, jammed) is
      held with the bar in the pocket, the pose target ``open.hold_pull`` out from the door and no
      object cost, the plan restarted from rest; it opens again when the handle moves, and tries
      every ``open.hold_probe`` s.

    ``noise`` (:class:`NoiseConfig`) shapes the sampling covariance per phase and ``guide``
    (:class:`GuideConfig`) the reaching guides. ``horizon`` (s) is the controller's horizon T,
    used by the power balance of :meth:`object_setpoint`; ``contact_weight`` weighs the contact
    cost (30) while approaching and releasing; ``safety`` the terms every phase carries; ``extra``
    is added to every phase's cost. Success: opening ≥ ``open.success_fraction`` of the target.

    ``handle`` names the object frame or link to grasp: a frame without collision geometry (the
    shipped objects' ``handle_frame``) is used as the handle frame as it is; a link with geometry
    (anyone else's object) gets its handle frame inferred by :func:`sabre.handles.infer_handle_frame`.
    The scene's one movable joint must move it: for a cabinet with several doors and drawers, load
    the scene with ``Scene.from_urdf(..., handle=<the same link>)``, which keeps the joint that moves
    the handle and holds the others (the check says so, naming that joint).

    Example: ``OpenObject(hook=HookConfig(backout=None))`` never restarts a backed-out hook;
    ``OpenObject(handle="pull_bar_link")`` opens an object whose handle is that link.

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

    phases = ("approach", "insert", "hook", "open", "release", "hold")
    #: the world pose the hold pulls toward, set when a hold begins (see :meth:`next_phase`)
    _hold_pose: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    # -- settings ---------------------------------------------------------------------------------
    def __post_init__(self) -> None:
        for name, kind in (
            ("approach", ApproachConfig),
            ("hook", HookConfig),
            ("open", OpenConfig),
            ("release", ReleaseConfig),
            ("noise", NoiseConfig),
            ("guide", GuideConfig),
            ("safety", SafetyWeights),
        ):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"{name} must be a sabre.tasks.{kind.__name__}, got {type(getattr(self, name)).__name__}")
        self.contact_weight = as_non_negative("contact_weight", self.contact_weight)
        self.horizon = as_positive("horizon", self.horizon)
        if self.opening is not None:
            self.opening = as_finite("opening", self.opening)

    # The core's logic of the last scene asked about, dropped whenever a setting changes; never
    # pickled (a task crosses to a planner process without it and makes it there again).
    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)
        self.__dict__.pop("_rules_for", None)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_rules_for", None)
        return state

    def _rules(self, scene: Scene) -> _core.OpenObjectRules:
        """The core's per-iteration logic of this task on ``scene`` (phase switch, probe, noise, guides)."""
        kept = self.__dict__.get("_rules_for")
        if kept is not None and kept[0]() is scene:
            return kept[1]
        groups = (self.approach, self.hook, self.open, self.release, self.noise, self.guide)
        key = ("open-object rules", self.handle, self.opening, self.horizon, self.safety.power, groups)
        rules = per_scene(scene, key, lambda _: self._make_rules(scene))
        self.__dict__["_rules_for"] = (weakref.ref(scene), rules)
        return rules

    def _make_rules(self, scene: Scene) -> _core.OpenObjectRules:
        return _core.OpenObjectRules(
            geometry.core_geometry(scene, self.handle),
            rules_config(self.approach, self.hook, self.open, self.release, self.noise, self.guide),
            self.target_opening(scene),
            self.object_setpoint(scene),
        )

    def check(self, scene: Scene) -> None:
        """The object must have one movable joint, which moves the handle, and the opening must lie
        within its travel; an approach posture must have one entry per robot joint."""
        moved_by = scene.object_joints_moving(self.handle) if self.handle in scene.object_frame_names else ()
        if scene.no != 1:
            swapped = " (are the robot and object files swapped?)" if scene.nq <= 1 < scene.no else ""
            if len(moved_by) == 1:
                pick = (
                    f"the handle {self.handle!r} is moved by {moved_by[0]!r}: load the scene with "
                    f"Scene.from_urdf(..., handle={self.handle!r}) (or joint={moved_by[0]!r}), which keeps that joint"
                )
            else:
                pick = "pick the one to open with Scene.from_urdf(..., joint=<name>) or handle=<its handle link>, which keeps it"
            raise InvalidValueError(
                f"OpenObject needs an object with one movable joint; {scene.object_name!r} has {scene.no}: "
                f"{list(scene.object_joint_names)}{swapped}; {pick} and holds the others"
            )
        geometry.tool_frame(scene)  # the robot has a control frame to steer
        geometry.handle_frame(scene, self.handle)  # the handle exists and its frame can be inferred
        if not moved_by:
            raise InvalidValueError(
                f"handle {self.handle!r} does not move with the scene's joint {scene.object_joint_names[0]!r}: it is on "
                f"a held part or the carcass; load the scene with Scene.from_urdf(..., handle={self.handle!r})"
            )
        lower, upper = float(scene.o_lower[0]), float(scene.o_upper[0])
        if self.opening is not None and not lower < self.opening <= upper:
            raise InvalidValueError(f"opening {self.opening} is outside the object's travel ({lower}, {upper}]")
        if self.approach.posture is not None and len(self.approach.posture) != scene.nq:
            raise InvalidValueError(f"approach.posture has {len(self.approach.posture)} entries, the robot has {scene.nq} joints")
        self._rules(scene)  # the targets fit the handle: a hook that cannot is refused before anything moves

    def handle_fit(self, scene: Scene) -> dict[str, Any] | None:
        """The grasp targets fitted to the handle's collision geometry on ``scene`` and what was
        measured, in the handle frame (m, rad): ``pitch``, ``pregrasp``, ``insert``, ``hook``,
        ``open`` (the targets), ``bar_along``, ``bar_across``, ``bar_front``, ``bar_back`` (the
        bar's extent), ``gap`` (behind the bar where the finger goes), ``widest_gap``, ``need`` (the
        least gap the tool needs) and ``tip_behind`` (how far a pull moves the hooked hand before the
        tip bites). None with ``approach.fit_clearance`` None, or when no bar stands at the handle frame."""
        return self._rules(scene).fit()

    # -- targets and costs ------------------------------------------------------------------------
    def target_opening(self, scene: Scene) -> float:
        """The opening to reach (rad or m): ``opening``, or 75 % of the range."""
        if self.opening is not None:
            return float(self.opening)
        return float(scene.o_lower[0] + 0.75 * (scene.o_upper[0] - scene.o_lower[0]))

    def object_setpoint(self, scene: Scene) -> float:
        """o* of the object cost (34): ``opening`` plus ``open.object_overshoot``.

        The power cost (36) charges w_p·τ_r·ȯ per step for moving the object against its
        resisting torque τ_r (friction, damping), and over a horizon T the object cost's pull
        on the opening rate is worth W_o·(o* − o)·T per step. The two balance at
        o* − o = w_p·τ_r / (W_o·T): with Table I weights and the shelf's 4 N·m friction, 0.47 rad
        before o*. With o* at the requested opening the object would stall that far short of it,
        so by default o* lies twice that gap beyond it (the object ends up a gap past the
        opening, or at its limit).

        o* never lies past the object's travel (its upper limit): a set-point the object cannot
        reach has the plan drive it into its stop at speed and pull on it there (the shelf's
        balance puts o* at 2.12 rad, its stop is at 1.57 rad); at its limit the plan brakes the
        object on its way there.
        """
        upper = float(scene.o_upper[0])
        if self.open.object_overshoot is not None:
            return min(self.target_opening(scene) + float(self.open.object_overshoot), upper)
        # every input besides the scene, for the value kept per scene (asked for every iteration)
        key = (
            "object setpoint",
            self.handle,
            self.opening,
            self.open.speeds[:1],
            self.safety.power,
            self.open.object_weight,
            self.horizon,
        )
        return min(per_scene(scene, key, lambda _: self._object_setpoint(scene)), upper)  # a float: keeps no scene

    def _object_setpoint(self, scene: Scene) -> float:
        speed = self.open.speeds[0] if self.open.speeds else 0.1
        rate = speed / max(self.handle_travel(scene, float(scene.o_lower[0])), 1e-6)
        resisting = float(scene.object_friction[0] + scene.object_damping[0] * rate)
        gap = self.safety.power * resisting / (max(self.open.object_weight, 1e-12) * self.horizon)
        return self.target_opening(scene) + 2.0 * gap

    def lead(self, scene: Scene) -> float:
        """How far ahead (rad or m) of the opening the open-phase pose target sits."""
        return float(self.open.lead)

    def grasp_offset(self, scene: Scene, phase: str) -> np.ndarray:
        """(4, 4) pose of the grasp target in the handle frame for `phase`: the configured offsets and
        pitch as fitted to the handle (see :meth:`handle_fit`)."""
        return self._rules(scene).offset(phase)

    def posture_term(self, scene: Scene) -> costs.Cost:
        """The posture cost of the approach (empty when ``approach.posture_weight`` is 0)."""
        if self.approach.posture_weight <= 0.0:
            return costs.Cost()
        posture = self.approach.posture
        target = scene.home_configuration() if posture is None else np.asarray(posture, dtype=float)
        weights = np.full(scene.nq, self.approach.posture_weight)
        if scene.base_indices is not None:
            weights[list(scene.base_indices)] = 0.0  # the base goes where the handle is
        return costs.Cost([costs.Posture(target, weights)])

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        frame, offset = geometry.handle_frame(scene, self.handle)
        target = offset @ self.grasp_offset(scene, phase)
        tool = geometry.tool_frame(scene)
        pull_object = costs.ObjectState([self.object_setpoint(scene)], self.open.object_weight)
        every_phase = self.safety.terms(scene) + self.extra
        if phase == "release":
            return pull_object + costs.Contact(self.contact_weight) + every_phase
        if phase == "hold":
            # No object cost, and the target fixed in the world where the hold began: the rollout
            # model lets the object follow the hand, so a target on the handle recedes as the hand
            # pulls, and a plan that pulls along the object's path moves the hand out of the
            # pocket sideways when the object does not follow.
            weights = tuple(self.open.pose_weights)
            if self._hold_pose is None:
                return costs.TargetPose(target, tool, frame, weights=weights) + every_phase
            return costs.TargetPose(self._hold_pose, tool, weights=weights) + every_phase
        if phase in ("approach", "insert", "hook"):
            # The object cost also before the hook holds (approaching, hooking): a door that can open
            # by itself (a dishwasher past its balance point, resting on the hand after a slip)
            # should be let go, not held.
            reach = costs.Cost([costs.TargetPose(target, tool, frame, self.approach.weight, self.approach.weight)])
            if phase == "approach":
                reach = reach + costs.Contact(self.contact_weight) + self.posture_term(scene)
            if phase == "insert":
                # Not while inserting: the finger's tip is beside the bar and short of it, and the
                # object cost rewards samples that swing the tip sideways into the bar to drag the
                # door by it, which jams the finger against the bar's side face.
                return reach + every_phase
            return reach + pull_object + every_phase
        hold = costs.TargetPose(
            target,
            tool,
            frame,
            weights=tuple(self.open.pose_weights),
            lead=self.lead(scene),
            lead_limit=self.target_opening(scene),
        )
        return hold + pull_object + every_phase

    # -- where the hand and the handle are (see geometry) -----------------------------------------
    def handle_pose(self, scene: Scene, o: Sequence[float] | np.ndarray) -> np.ndarray:
        """(4, 4) world pose of the handle frame at object configuration o (no,)."""
        return geometry.handle_pose(scene, self.handle, o)

    def handle_poses(self, scene: Scene, o: np.ndarray) -> np.ndarray:
        """(M, 4, 4) world poses of the handle frame at object configurations o (M, no)."""
        return geometry.handle_poses(scene, self.handle, o)

    def handle_travel(self, scene: Scene, o: float) -> float:
        """Distance (m) the handle moves per unit of opening (rad or m) at opening o."""
        return geometry.handle_travel(scene, self.handle, o)

    def handle_speed(self, scene: Scene, x: np.ndarray) -> float:
        """Speed (m/s) of the handle in the opening direction (negative while closing)."""
        return geometry.handle_speed(scene, self.handle, x)

    def handle_from_closed(self, scene: Scene, x: np.ndarray) -> float:
        """Distance (m) of the handle from where it is with the object closed."""
        return geometry.handle_from_closed(scene, self.handle, x)

    def approach_error(self, scene: Scene, x: np.ndarray, phase: str = "insert") -> GraspError:
        """Distance (m) and angle (rad) of the grasp frame from the target of `phase` at state x (nx,)."""
        return geometry.approach_error(scene, self.handle, x, self.grasp_offset(scene, phase))

    def pocket_error(self, scene: Scene, x: np.ndarray, phase: str) -> PocketError:
        """(across, along) distance (m) of the grasp frame from the target of `phase`: across the
        bar (handle frame y and z) and along it (x)."""
        return geometry.pocket_error(scene, self.handle, x, self.grasp_offset(scene, phase))

    def depth_error(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        """Signed distance (m) of the grasp frame from the target of `phase` along the handle
        frame's z axis (into the door): negative while the finger is still short of it."""
        return geometry.depth_error(scene, self.handle, x, self.grasp_offset(scene, phase))

    def lateral_error(self, scene: Scene, x: np.ndarray) -> float:
        """Sideways offset (m) of the grasp frame from its open-phase target, along the handle
        frame's y axis: how far the bar has moved toward leaving the finger's pocket."""
        return geometry.lateral_error(scene, self.handle, x, self.open.offset[1])

    def release_path(self, scene: Scene, x: np.ndarray, steps: int, dt: float) -> np.ndarray:
        """(steps + 1, 4, 4) grasp-frame targets that let go of the handle at ``release.speed``
        (:func:`sabre.tasks.open_object.geometry.release_path`): a finger within
        ``open.slip_distance`` of the pocket leaves the way it came in (across the bar to the insert
        offset's sideways position, then back to the pre-grasp offset's depth), riding on the handle;
        then the hand backs off ``release.distance`` along :meth:`release_direction`."""
        return self._rules(scene).release_path(_state(x), int(steps), float(dt))

    def release_direction(self, scene: Scene, x: np.ndarray) -> np.ndarray:
        """(3,) unit direction in which the hand backs off when releasing: away from the door and,
        for a hinged door, out of its sweep."""
        return geometry.release_direction(scene, self.handle, x)

    def opening_of(self, scene: Scene, x: np.ndarray) -> float:
        """The object's opening (rad or m) at state x."""
        return float(scene.split_state(x).o[0])

    # -- what the object and the finger are doing (each computed in the core) -----------------------
    def self_opening(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object, left alone at rest, opens further by itself (a dishwasher door past
        its balance point): the rollout model run for ``release.probe`` s from x with the robot and
        the object at rest and the robot out of its way (a holonomic base moved 5 m away from the
        object; a fixed-base robot's links taken out of the contact), checked against ``release.rate``."""
        return bool(self._rules(scene).self_opening(_state(x)))

    def pulling(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger already pulls the object open before the hook test passed: the
        handle opens faster than ``hook.drag_speed`` (m/s) while the grasp frame is within the open
        phase's slip bounds (the bar sits in the pocket, just not where the hook target put it),
        and the handle is at least ``hook.drag_distance`` (m) from closed. An object that opens by
        itself is caught by ``self_opening`` first."""
        return bool(self._rules(scene).pulling(_state(x)))

    def backed_out(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the finger, hooking, has backed out in front of the bar and stalled: the grasp frame
        more than ``hook.backout`` (m) short of the hook target's depth, the handle opening no faster
        than ``hook.drag_speed`` (m/s), and either at least ``hook.drag_distance`` (m) from closed (as
        for ``pulling``) or the frame more than ``hook.stall_depth`` (m) short. A finger that catches
        the bar with its tip often drags a free door open that way until the bar slides into the
        pocket (``pulling``), and on a closed door that is how the drag starts; a door that was opened
        and does not move now (held, or stuck) only takes the tank's energy for the catch, and a
        finger too far out for its tip to hold the bar starts over however little it dragged."""
        return bool(self._rules(scene).backed_out(_state(x)))

    def running_ahead(self, scene: Scene, x: np.ndarray) -> bool:
        """Whether the object opens by itself faster than ``release.runaway_speed`` (m/s at the handle), as
        a dishwasher door does past its balance point. The hand then rides along (its finger sits
        in the door's path) instead of starting over from the approach."""
        return bool(self._rules(scene).running_ahead(_state(x)))

    # -- phase switching ----------------------------------------------------------------------------
    def next_phase(self, scene: Scene, x: np.ndarray, t: float, phase: str) -> str:
        """The phase after ``phase`` at state x:

        - approach, insert, hook: release an object that is open and opens by itself; move on
          (approach → insert → hook → open) once the grasp frame is at the phase's target (within
          ``approach.switch_angle``; approach within twice ``approach.switch_position``; insert and
          hook within ``hook.along_tolerance`` along the bar, insert within
          ``approach.switch_position`` across it and ``hook.insert_depth_tolerance`` of its depth
          or blocked short of it (``hook.blocked_depth``, slower than ``hook.blocked_speed``), hook
          within ``hook.tolerance`` across it); insert and hook go to open when :meth:`pulling`, a
          hook starts over (approach) when :meth:`backed_out`;
        - open: stays once successful; releases a door that opens by itself (holding it only makes
          the arm follow it down into its joint limits); starts over when the bar has left the
          pocket (beyond ``open.slip_distance`` of the open target or ``open.slip_lateral``
          sideways of it) and the object is not :meth:`running_ahead` of the hand;
        - release: stays while the object opens by itself, then starts over.
        """
        after = str(self._rules(scene).next_phase(_state(x), phase))
        if after == "hold" and phase != "hold":
            o = scene.split_state(np.asarray(x, dtype=float)).o
            self._hold_pose = self.handle_pose(scene, o) @ self.grasp_offset(scene, "hold")
        return after

    # -- sampling: guides and noise -----------------------------------------------------------------
    def guides(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> np.ndarray | None:
        """Servos (M, steps, nu) for the sampler (:func:`sabre.guides.servo_guide`), or None:

        - approach, insert, hook: toward the phase's target at ``guide.speed`` (approach) or
          ``guide.fine_speed`` (None with ``guide.speed`` 0);
        - open: along the handle's path at each of ``open.speeds`` (and at the object's own pace
          when it opens faster) up to :meth:`object_setpoint` (None without speeds);
        - release: along :meth:`release_path` (None with ``release.speed`` 0).
        """
        return self._rules(scene).guides(_state(x), phase, int(steps), float(dt))

    def guide_plan(self, scene: Scene, x: np.ndarray, phase: str, steps: int, dt: float) -> ServoGuidePlan | None:
        """:meth:`guides` as a plan the controller's rollout workers integrate; None where a
        subclass gives guides of its own."""
        if type(self).guides is not OpenObject.guides:
            return None
        return self._rules(scene).guide_plan(_state(x), phase, int(steps), float(dt))

    def gain_inertia_floor(self, phase: str) -> float | None:
        return self.open.gain_inertia_floor if phase in ("open", "hold") else None

    def on_step(self, scene: Scene, x: np.ndarray, t: float, controller: TaskController) -> None:
        """Holding: when the hold begins its cost pulls toward where it began and the plan restarts
        from rest (the nominal still follows the path the object was expected to take, and the
        sampling noise while opening is too small to turn it round in time); after
        ``open.hold_probe`` s the task pulls along the path again."""
        if controller.phase != "hold":
            return
        if controller.phase_since == t:
            controller.refresh_cost()  # toward where this hold began
            controller.set_nominal(np.zeros_like(controller.nominal), t)
        elif t - controller.phase_since >= self.open.hold_probe - 1e-9:
            controller.set_phase("open", t)

    def noise_scale(self, scene: Scene, x: np.ndarray, phase: str) -> float:
        """``noise.open`` while opening and releasing; while reaching (d / ``noise.distance``)²
        clipped to [``noise.floor``, 1], d the grasp frame's distance (m) to the phase's target."""
        return float(self._rules(scene).noise_scale(_state(x), phase))

    def success(self, scene: Scene, x: np.ndarray) -> bool:
        return bool(self._rules(scene).success(_state(x)))


def _state(x: np.ndarray) -> np.ndarray:
    """x as the core reads it (its shape and values are checked there)."""
    return np.ascontiguousarray(x, dtype=np.float64)
