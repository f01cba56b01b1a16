"""The settings groups of :class:`~sabre.tasks.OpenObject`, one per phase or concern, each validated when built."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ... import _core, costs
from ..._validate import as_finite, as_float_array, as_non_negative, as_positive, core_config
from ...errors import InvalidValueError

__all__ = ["ApproachConfig", "HookConfig", "OpenConfig", "ReleaseConfig", "NoiseConfig", "GuideConfig", "rules_config"]

# The core's defaults, the one source of every default below that its per-iteration logic reads.
_RULES = _core.OpenObjectConfig()


def xyz(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    """A finite 3-vector (m) as a tuple."""
    x, y, z = as_float_array(name, value, (3,)).tolist()
    return x, y, z


def optional_non_negative(name: str, value: float | None) -> float | None:
    """None, or a finite float that is zero or positive."""
    return None if value is None else as_non_negative(name, value)


@dataclass(frozen=True)
class ApproachConfig:
    """Reaching the handle (phases approach and insert) of :class:`OpenObject`.

    Offsets are grasp-frame positions (m) in the handle frame: x along the bar, y sideways (toward
    the finger), z into the door. The rationale of every default is in docs/design.md.

    Attributes:
        pregrasp_offset: target while approaching, in front of the bar and beside it (m).
        insert_offset: target while inserting, beside the bar with the finger's tip past it (m).
        pitch: the hand points this far (rad) below the handle's normal.
        fit_clearance: clearance (m) the targets keep from the bar and the panel when fitted to the
            handle's collision geometry: the bar's size and the gap behind it are measured, and the
            targets above (and the hook's and the pull's, and the pitch down to level) are kept where
            the tool fits and moved the least where it does not; a handle whose gap is too small for
            the tool is refused before anything moves. None: the targets as given, unmeasured.
        weight: pose weight of the reaching targets (the paper's approach weight).
        switch_position: distance (m) to the target that ends inserting (twice it ends the approach).
        switch_angle: angle (rad) to the target that ends approaching, inserting and hooking.
        posture: preferred arm posture while approaching (nq joint targets), or None for the robot's
            home posture (:meth:`sabre.Scene.home_configuration`); a holonomic base's joints are free.
        posture_weight: its weight per rad² (0: off).

    Raises:
        InvalidValueError: a negative weight or tolerance, a non-finite offset or pitch.
    """

    pregrasp_offset: tuple[float, float, float] = xyz("pregrasp_offset", _RULES.pregrasp_offset)
    insert_offset: tuple[float, float, float] = xyz("insert_offset", _RULES.insert_offset)
    pitch: float = _RULES.pitch
    fit_clearance: float | None = _RULES.fit_clearance
    weight: float = costs.TargetPose.linear_weight
    switch_position: float = _RULES.switch_position
    switch_angle: float = _RULES.switch_angle
    posture: tuple[float, ...] | None = None
    posture_weight: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "pregrasp_offset", xyz("approach.pregrasp_offset", self.pregrasp_offset))
        object.__setattr__(self, "insert_offset", xyz("approach.insert_offset", self.insert_offset))
        object.__setattr__(self, "pitch", as_finite("approach.pitch", self.pitch))
        object.__setattr__(self, "fit_clearance", optional_non_negative("approach.fit_clearance", self.fit_clearance))
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
        blocked_depth: how far (m) short of the insert target's depth a finger that has stopped (its
            grasp frame slower than ``blocked_speed``) may end inserting all the same: something in
            front of the hand holds it there, and this close the tip still clears the bar's back
            face; None: never.
        blocked_speed: grasp-frame speed (m/s) below which an inserting finger counts as stopped.
        backout: how far (m) short of the hook target's depth the grasp frame may back out while
            hooking an opened, unmoving object before the task starts over; None: never.
        along_tolerance: distance (m) along the bar from the target allowed when inserting and hooking.
        drag_speed: handle speed (m/s) that counts as the finger already pulling while inserting or
            hooking (see :meth:`OpenObject.pulling`); 0: off.
        drag_distance: distance (m) of the handle from closed below which pulling never counts.
        stall_depth: how far (m) short of the hook target's depth the grasp frame must be for a stalled
            hook to start over however little the handle moved: that far out the finger's tip cannot
            be holding the bar; None: only past ``drag_distance``.

    Raises:
        InvalidValueError: a negative or non-finite tolerance, speed or distance.
    """

    offset: tuple[float, float, float] = xyz("hook_offset", _RULES.hook_offset)
    tolerance: float = _RULES.hook_tolerance
    insert_depth_tolerance: float | None = _RULES.insert_depth_tolerance
    blocked_depth: float | None = _RULES.blocked_depth
    blocked_speed: float = _RULES.blocked_speed
    backout: float | None = _RULES.backout
    along_tolerance: float = _RULES.along_tolerance
    drag_speed: float = _RULES.drag_speed
    drag_distance: float = _RULES.drag_distance
    stall_depth: float | None = _RULES.stall_depth

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", xyz("hook.offset", self.offset))
        for name in ("tolerance", "along_tolerance", "drag_speed", "drag_distance", "blocked_speed"):
            object.__setattr__(self, name, as_non_negative(f"hook.{name}", getattr(self, name)))
        for name in ("insert_depth_tolerance", "blocked_depth", "backout", "stall_depth"):
            object.__setattr__(self, name, optional_non_negative(f"hook.{name}", getattr(self, name)))


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
        hold_speed: an opened object (beyond ``hook.drag_distance`` from closed, short of success)
            whose handle moves slower than this (m/s) with the bar in the pocket has stopped
            following the pull: the task holds it (phase hold) until the handle moves faster than
            twice this; 0: never.
        hold_pull: the hold target lies this far (m) further out from the door than ``offset``.
        hold_probe: after holding this long (s) the task pulls along the object's path again (phase
            open), and holds again if it still does not follow.
        success_fraction: success once the opening reaches this share of the target, in (0, 1].
        gain_inertia_floor: the low-level controller's gain inertia floor (kg m²) while opening
            (see :class:`sabre.LowLevelController`); None: the controller's own.

    Raises:
        InvalidValueError: a negative weight, speed or bound, a non-finite lead or overshoot, a
            success fraction outside (0, 1], a hold probe that is not positive.
    """

    offset: tuple[float, float, float] = xyz("open_offset", _RULES.open_offset)
    pose_weights: tuple[float, float, float, float, float, float] = (100.0, 10000.0, 1000.0, 1000.0, 1000.0, 1000.0)
    lead: float = 0.0
    object_weight: float = costs.ObjectState.weight
    object_overshoot: float | None = None
    speeds: tuple[float, ...] = tuple(_RULES.open_speeds)
    slip_distance: float = _RULES.slip_distance
    slip_lateral: float = _RULES.slip_lateral
    hold_speed: float = _RULES.hold_speed
    hold_pull: float = _RULES.hold_pull
    hold_probe: float = 1.0
    success_fraction: float = _RULES.success_fraction
    gain_inertia_floor: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", xyz("open.offset", self.offset))
        weights = as_float_array("open.pose_weights", self.pose_weights, (6,))
        if np.any(weights < 0.0):
            raise InvalidValueError(f"open.pose_weights must be non-negative, got {self.pose_weights}")
        object.__setattr__(self, "pose_weights", tuple(weights.tolist()))
        object.__setattr__(self, "lead", as_finite("open.lead", self.lead))
        if self.object_overshoot is not None:
            object.__setattr__(self, "object_overshoot", as_finite("open.object_overshoot", self.object_overshoot))
        speeds = tuple(as_non_negative("open.speeds", s) for s in self.speeds)
        object.__setattr__(self, "speeds", speeds)
        for name in ("object_weight", "slip_distance", "slip_lateral", "hold_speed", "hold_pull"):
            object.__setattr__(self, name, as_non_negative(f"open.{name}", getattr(self, name)))
        object.__setattr__(self, "hold_probe", as_positive("open.hold_probe", self.hold_probe))
        object.__setattr__(self, "gain_inertia_floor", optional_non_negative("open.gain_inertia_floor", self.gain_inertia_floor))
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

    speed: float = _RULES.release_speed
    distance: float = _RULES.release_distance
    rate: float = _RULES.release_rate
    probe: float = _RULES.probe
    runaway_speed: float = _RULES.runaway_speed

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

    distance: float = _RULES.noise_distance
    floor: float = _RULES.noise_floor
    open: float = _RULES.noise_open

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

    speed: float = _RULES.guide_speed
    fine_speed: float = _RULES.fine_speed
    gain: float = _RULES.guide_gain

    def __post_init__(self) -> None:
        for name in ("speed", "fine_speed", "gain"):
            object.__setattr__(self, name, as_non_negative(f"guide.{name}", getattr(self, name)))


def rules_config(
    approach: ApproachConfig, hook: HookConfig, open: OpenConfig, release: ReleaseConfig, noise: NoiseConfig, guide: GuideConfig
) -> _core.OpenObjectConfig:
    """The core's settings of the task's per-iteration logic from its setting groups."""
    return core_config(
        _core.OpenObjectConfig,
        pregrasp_offset=list(approach.pregrasp_offset),
        insert_offset=list(approach.insert_offset),
        hook_offset=list(hook.offset),
        open_offset=list(open.offset),
        pitch=approach.pitch,
        fit_clearance=approach.fit_clearance,
        switch_position=approach.switch_position,
        switch_angle=approach.switch_angle,
        hook_tolerance=hook.tolerance,
        along_tolerance=hook.along_tolerance,
        insert_depth_tolerance=hook.insert_depth_tolerance,
        blocked_depth=hook.blocked_depth,
        blocked_speed=hook.blocked_speed,
        backout=hook.backout,
        drag_speed=hook.drag_speed,
        drag_distance=hook.drag_distance,
        stall_depth=hook.stall_depth,
        open_speeds=list(open.speeds),
        slip_distance=open.slip_distance,
        slip_lateral=open.slip_lateral,
        hold_speed=open.hold_speed,
        hold_pull=open.hold_pull,
        success_fraction=open.success_fraction,
        release_speed=release.speed,
        release_distance=release.distance,
        release_rate=release.rate,
        probe=release.probe,
        runaway_speed=release.runaway_speed,
        noise_distance=noise.distance,
        noise_floor=noise.floor,
        noise_open=noise.open,
        guide_speed=guide.speed,
        fine_speed=guide.fine_speed,
        guide_gain=guide.gain,
    )
