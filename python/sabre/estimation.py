"""Estimates a controller on a real robot needs besides its joint states: τ_ext from a wrist
wrench and a first-order low-pass for it (the core's, which the cascade's tick conditions τ_ext with),
and the object's state inferred from the hand pose while the hand holds the handle (no door sensor),
computed in the core (``_core.ObjectStateEstimator``) so that a loop in Rust runs the same estimator."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import _core
from ._validate import as_float_array
from .errors import InvalidValueError
from .handles import handle_offset
from .scene import Scene

__all__ = ["LowPass", "tau_ext_from_wrench", "SENSOR_FRAME", "ObjectEstimate", "ObjectStateEstimator"]

#: The RoyalPanda's wrist-sensor frame: the wrench is measured about its origin, as :attr:`sabre.Plant.wrench`
#: reports it (force and torque in world axes). Any robot's is :attr:`sabre.Scene.wrist_sensor_link`.
SENSOR_FRAME = "panda_link8"


def tau_ext_from_wrench(
    scene: Scene,
    q: Sequence[float] | np.ndarray,
    wrench: Sequence[float] | np.ndarray,
    frame: str | None = None,
    axes: str | None = None,
) -> np.ndarray:
    """(nq,) external joint torques J(q)ᵀ w of a wrist wrench w = [f; m] that the environment
    exerts on the hand, its moment about ``frame``'s origin (None: the scene's wrist sensor,
    :attr:`sabre.Scene.wrist_sensor_link`). ``axes`` names the robot frame whose
    axes the components are given in (a sensor's own frame, as an F/T driver publishes it); None:
    world axes. Contacts on links before the sensor do not show in it. Computed by the core's wrench
    frames (``_core.WrenchFrames``), the cascade's own."""
    w = as_float_array("wrench", wrench, (6,))
    q = as_float_array("q", q, (scene.nq,))
    point = scene.wrist_sensor_link if frame is None else str(frame)
    frames = _core.WrenchFrames(scene._core, "world", point, point)
    return np.asarray(frames.tau_ext(q, w, "world" if axes is None else str(axes)), dtype=np.float64)


class LowPass:
    """First-order low-pass at ``cutoff`` Hz integrated with the measured step dt (exact
    exponential update, so irregular message spacing is handled); None passes through. The core's
    (``_core.LowPass``), on an array of any shape (a new shape starts over)."""

    def __init__(self, cutoff: float | None) -> None:
        self.cutoff = None if cutoff is None or cutoff <= 0 else float(cutoff)
        self.value: np.ndarray | None = None
        self._core: _core.LowPass | None = None

    def update(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if self._core is None or self.value is None or self.value.shape != x.shape:
            self._core = _core.LowPass(x.size, self.cutoff)
        self.value = np.asarray(self._core.update(np.ascontiguousarray(x).reshape(-1), float(dt))).reshape(x.shape)
        return self.value

    def reset(self) -> None:
        self.value, self._core = None, None


@dataclass(frozen=True)
class ObjectEstimate:
    """position (no,) and velocity (no,) of the object's joints; hooked: whether they come from
    the hand (else the last known state, held at rest); residual (m): how far the hand point is
    from where the estimated object puts it, across the handle's bar (a hook sliding along the bar
    does not move the object)."""

    position: np.ndarray
    velocity: np.ndarray
    hooked: bool
    residual: float


class ObjectStateEstimator:
    """Infers the object's joint coordinate o and rate ȯ from the robot's joint positions.

    Assumptions (docs/ros2.md): the object is the scene's single-joint articulation at its known
    pose; once the hand hooks the handle, the hook point stays on the handle's bar (it may slide
    along the bar, the handle frame's x, which does not move o: the bar runs along the hinge or
    across the slide), so o is the coordinate that puts the handle-frame point recorded at hooking
    where the hand's ``hand_frame`` (None: the scene's tool frame) measures it. ``handle`` is the
    object frame or link to grasp, as :class:`sabre.tasks.OpenObject`'s ``handle`` (a link with
    geometry gets its inferred handle frame). Hooking is declared when the hand frame is within
    ``hook_distance`` m of the handle frame and the wrist force reaches ``contact_force`` N; it ends
    when the best fit is still ``release_distance`` m off across the bar (the hand has left the
    handle), the hook slid ``slide_distance`` m along it (off its end), or the force stays below
    ``contact_force`` for ``release_time`` s. Before hooking and after release the last known state
    holds at rest. ȯ is the difference quotient low-passed at ``rate_cutoff`` Hz. A hook that slips
    off the handle reads as motion of the object until the release (a drawer coasts ahead of a hand
    that no longer touches it, so the estimate keeps following the hand meanwhile).

    The estimator is the core's (:attr:`core`): a loop in Rust can take it over."""

    def __init__(
        self,
        scene: Scene,
        initial: np.ndarray | None = None,
        *,
        hand_frame: str | None = None,
        handle: str = "handle_frame",
        hook_distance: float = 0.08,
        release_distance: float = 0.04,
        slide_distance: float = 0.1,
        contact_force: float = 0.2,
        release_time: float = 0.5,
        rate_cutoff: float = 5.0,
    ) -> None:
        if scene.no != 1:  # the fundamental mistake first, before any about the frames
            raise InvalidValueError(f"the estimator handles single-joint objects, this one has {scene.no} joints")
        hand_frame = scene.require_tool_frame("ObjectStateEstimator") if hand_frame is None else hand_frame
        if hand_frame not in scene.frame_names:
            raise InvalidValueError(f"hand_frame {hand_frame!r} is not a robot frame: {scene.frame_names}")
        handle_frame, offset = handle_offset(scene, handle)
        o0 = None if initial is None else float(np.asarray(initial, dtype=np.float64).reshape(-1)[0])
        self._scene = scene
        self._core = _core.ObjectStateEstimator(
            scene._core,
            hand_frame,
            handle_frame,
            np.ascontiguousarray(offset, dtype=np.float64),
            o0,
            hook_distance=float(hook_distance),
            release_distance=float(release_distance),
            slide_distance=float(slide_distance),
            contact_force=float(contact_force),
            release_time=float(release_time),
            rate_cutoff=float(rate_cutoff),
        )

    @property
    def core(self) -> _core.ObjectStateEstimator:
        """The core estimator this class runs (its state is this estimator's)."""
        return self._core

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def hooked(self) -> bool:
        return self._core.hooked

    @property
    def position(self) -> float:
        """The current estimate of o."""
        return self._core.position

    @property
    def velocity(self) -> float:
        """The current estimate of ȯ."""
        return self._core.velocity

    @property
    def residual(self) -> float:
        """The last fit's distance (m) from the hand point; NaN while not hooked."""
        return self._core.residual

    @property
    def hand_frame(self) -> str:
        return self._core.hand_frame

    @property
    def handle_frame(self) -> str:
        return self._core.handle_frame

    @property
    def hook_distance(self) -> float:
        return self._core.hook_distance

    @property
    def release_distance(self) -> float:
        return self._core.release_distance

    @property
    def slide_distance(self) -> float:
        return self._core.slide_distance

    @property
    def contact_force(self) -> float:
        return self._core.contact_force

    @property
    def release_time(self) -> float:
        return self._core.release_time

    @property
    def rate_cutoff(self) -> float:
        return self._core.rate_cutoff

    def update(self, q: Sequence[float] | np.ndarray, t: float, force: float = math.inf, may_hook: bool = True) -> ObjectEstimate:
        """The estimate at time t (s) from the robot's joint positions q (nq,) and the wrist force
        magnitude (N; default: assume contact). A time at or before the previous one counts as no
        time passed. ``may_hook`` False says the task's hook is not seated (a controller passes its
        task's phase): no hook is declared (the hand touches the handle on its way in, where the
        hook point is not yet the one it will pull at), and a hook ends (a task that lost its hook
        moves the hand away, and the object does not follow it). A hook the hand makes where the
        estimate does not put the handle re-acquires the object's coordinate from the hand first
        (an object that moved while nothing held it is hooked where it is).

        Raises:
            ShapeError, InvalidValueError: q of the wrong size or not finite, t not finite, force
                negative or NaN; the estimate is left as it was.
        """
        q = np.ascontiguousarray(q, dtype=np.float64)
        position, velocity, hooked, residual = self._core.update(q, float(t), float(force), bool(may_hook))
        return ObjectEstimate(position=np.array([position]), velocity=np.array([velocity]), hooked=hooked, residual=residual)
