"""Guide sequences: input sequences a task proposes to the sampler.

A guide is one more sample in the batch (see ``Task.guides``): it is rolled out and weighted like
every other, so a poor guide only costs its slot, while a good one pulls the policy mean toward
what the task knows. :func:`servo_guide` is the usual one: a resolved-rate (damped least squares)
servo of a robot frame along a sequence of target poses, integrated on the kinematics over the
horizon.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import _core
from ._validate import as_float_array, core_config
from .errors import InvalidValueError
from .scene import Scene

__all__ = ["ServoGuidePlan", "servo_guide", "servo_guides", "servo_guide_plan", "rotation_log"]

#: Servo guides checked and ready to integrate (:func:`servo_guide_plan`).
ServoGuidePlan = _core.ServoGuidePlan

# The core's defaults, the one source of the servo guide's defaults.
_GUIDE = _core.ServoGuideConfig()


def rotation_log(r: np.ndarray) -> np.ndarray:
    """(3,) rotation vector of a rotation matrix (3, 3)."""
    cos = np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if angle < 1e-9:
        return 0.5 * w
    if np.pi - angle < 1e-6:
        # Near π the antisymmetric part vanishes; take the axis from the symmetric part.
        axis = np.sqrt(np.maximum((np.diag(r) + 1.0) / 2.0, 0.0))
        k = int(np.argmax(axis))
        others = np.arange(3) != k
        axis[others] *= np.sign(r[k, others] + r[others, k])
        return angle * axis / np.linalg.norm(axis)
    return angle / (2.0 * np.sin(angle)) * w


def servo_guide(
    scene: Scene,
    q0: np.ndarray,
    targets: np.ndarray,
    dt: float,
    frame: str | None = None,
    gain: float = _GUIDE.gain,
    max_linear: float = _GUIDE.max_linear,
    max_angular: float = _GUIDE.max_angular,
    velocity_limit: np.ndarray | None = None,
    damping: float = _GUIDE.damping,
    joint_margin: float = _GUIDE.joint_margin,
    limit_weighting: bool = _GUIDE.limit_weighting,
) -> np.ndarray:
    """(K, nu) joint velocities that servo ``frame`` (None: the scene's tool frame) along ``targets``
    (K+1, 4, 4) from q0 (nq,).

    Step k commands v_k = J⁺(ξ_k + gain·e_k): ξ_k the targets' own motion from k to k+1 (feed
    forward), e_k the pose error at k (world frame, linear then rotation vector), the Cartesian
    rate capped at ``max_linear`` (m/s) and ``max_angular`` (rad/s), J⁺ the damped least-squares
    inverse of the frame's Jacobian. With ``limit_weighting`` the inverse is weighted by Chan and
    Dubey's joint-limit gradient (weighted least norm): a joint heading for a limit slows down as
    it nears it and the redundant joints (the base) take over. Velocities are clipped to
    ``velocity_limit`` (default: the URDF limits); a joint that would cross ``joint_margin`` (rad
    or m) inside its limits is held there and the others re-solved for the rest of the rate. q is
    integrated with step dt, so the guide is what the servo would do on the kinematics alone. Runs
    in Rust.
    """
    q0 = as_float_array("q0", q0, (scene.nq,))
    targets = np.ascontiguousarray(targets, dtype=np.float64)
    if targets.ndim != 3 or targets.shape[1:] != (4, 4) or len(targets) < 2:
        raise InvalidValueError(f"targets: expected shape (K+1, 4, 4) with K >= 1, got {targets.shape}")
    config = _config(scene, gain, max_linear, max_angular, velocity_limit, damping, joint_margin, limit_weighting)
    frame = frame if frame is not None else scene.require_tool_frame("servo_guide")
    return _core.servo_guide(scene._core, q0, targets, float(dt), frame, config)


def servo_guides(
    scene: Scene,
    q0: np.ndarray,
    targets: np.ndarray,
    dt: float,
    frame: str | None = None,
    gain: float | Sequence[float] = _GUIDE.gain,
    max_linear: float | Sequence[float] = _GUIDE.max_linear,
    max_angular: float | Sequence[float] = _GUIDE.max_angular,
    velocity_limit: np.ndarray | None = None,
    damping: float = _GUIDE.damping,
    joint_margin: float = _GUIDE.joint_margin,
    limit_weighting: bool = _GUIDE.limit_weighting,
) -> np.ndarray:
    """(M, K, nu) joint velocities: :func:`servo_guide` from q0 (nq,) along each of the M target
    sequences ``targets`` (M, K+1, 4, 4), guide m with ``gain``, ``max_linear`` and ``max_angular``
    (each one value for all or M values, one per guide), in one call into Rust. Each is the guide
    :func:`servo_guide` gives for its sequence alone."""
    plan = servo_guide_plan(
        scene, q0, targets, dt, frame, gain, max_linear, max_angular, velocity_limit, damping, joint_margin, limit_weighting
    )
    return plan.evaluate()


def servo_guide_plan(
    scene: Scene,
    q0: np.ndarray,
    targets: np.ndarray,
    dt: float,
    frame: str | None = None,
    gain: float | Sequence[float] = _GUIDE.gain,
    max_linear: float | Sequence[float] = _GUIDE.max_linear,
    max_angular: float | Sequence[float] = _GUIDE.max_angular,
    velocity_limit: np.ndarray | None = None,
    damping: float = _GUIDE.damping,
    joint_margin: float = _GUIDE.joint_margin,
    limit_weighting: bool = _GUIDE.limit_weighting,
) -> ServoGuidePlan:
    """The guides of :func:`servo_guides`, checked now and integrated where they are used: a task's
    :meth:`~sabre.tasks.Task.guide_plan` returns one, and the controller's rollout workers each
    integrate the guide of the row they roll out, in parallel with the other rollouts.
    ``plan.evaluate()`` gives the (M, K, nu) array :func:`servo_guides` does, ``plan.shape`` its
    shape."""
    q0 = as_float_array("q0", q0, (scene.nq,))
    targets = np.ascontiguousarray(targets, dtype=np.float64)
    if targets.ndim != 4 or targets.shape[2:] != (4, 4) or targets.shape[1] < 2:
        raise InvalidValueError(f"targets: expected shape (M, K+1, 4, 4) with K >= 1, got {targets.shape}")
    count = len(targets)

    def per_guide(name: str, value: float | Sequence[float]) -> list[float]:
        values = np.asarray(value, dtype=np.float64)
        if values.ndim == 0:
            values = np.full(count, float(values))
        if values.shape != (count,):
            raise InvalidValueError(f"{name}: expected one value or {count} (one per guide), got shape {values.shape}")
        return values.tolist()

    gains, linear, angular = per_guide("gain", gain), per_guide("max_linear", max_linear), per_guide("max_angular", max_angular)
    configs = [
        _config(scene, g, lin, ang, velocity_limit, damping, joint_margin, limit_weighting)
        for g, lin, ang in zip(gains, linear, angular, strict=True)
    ]
    frame = frame if frame is not None else scene.require_tool_frame("servo_guides")
    return _core.servo_guide_plan(scene._core, q0, targets, float(dt), frame, configs)


def _config(
    scene: Scene,
    gain: float,
    max_linear: float,
    max_angular: float,
    velocity_limit: np.ndarray | None,
    damping: float,
    joint_margin: float,
    limit_weighting: bool,
) -> _core.ServoGuideConfig:
    """The core's config of one servo guide (its checks in Rust)."""
    if velocity_limit is not None:
        velocity_limit = as_float_array("velocity_limit", velocity_limit, (scene.nq,))
    return core_config(
        _core.ServoGuideConfig,
        gain=float(gain),
        max_linear=float(max_linear),
        max_angular=float(max_angular),
        velocity_limit=None if velocity_limit is None else velocity_limit.tolist(),
        damping=float(damping),
        joint_margin=float(joint_margin),
        limit_weighting=bool(limit_weighting),
    )
