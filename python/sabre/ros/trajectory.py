"""The arm's trajectory interface on the controller's side: the parameters that choose and tune it, the
segments' limits, and the cascade set to stream them (the core builds, filters and serializes the
segments: ``_core.Cascade.set_trajectory``; docs/ros2.md says how the robot side is configured)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import _core
from ..errors import InvalidValueError
from .commands import Limits
from .params import FRANKA_ACCELERATION, FRANKA_JERK, TRAJECTORY_FRACTION, finite_list

__all__ = [
    "ARM_INTERFACES",
    "INTERPOLATIONS",
    "VELOCITY_FRACTION",
    "arm_interface",
    "command_delay",
    "trajectory_limits",
    "stream_trajectory",
]

#: The arm's command interfaces: joint_trajectory_controller's topic, or a velocity stream.
ARM_INTERFACES = ("trajectory", "velocity")
#: JTC's interpolations the segments are sent for: positions and velocities (cubic), or with
#: accelerations too (quintic); both reproduce the segments exactly.
INTERPOLATIONS = ("cubic", "quintic")
#: The share of the URDF's velocity limits the segments keep by default: the robot adds its position
#: feedback k_p (q_d − q) to the segment's velocity, and an arm that trails its desired positions by a
#: few milliseconds at full speed is commanded a few percent above the segment.
VELOCITY_FRACTION = 0.9
#: The segments' velocity time constant (s): ``_core.Cascade.set_trajectory``'s default.
TIME_CONSTANT = 0.01


def arm_interface(params: dict[str, Any]) -> str:
    """The ``arm_interface`` parameter, checked."""
    value = str(params["arm_interface"])
    if value not in ARM_INTERFACES:
        raise InvalidValueError(f"arm_interface must be one of {ARM_INTERFACES}, got {value!r}")
    return value


def command_delay(params: dict[str, Any]) -> float:
    """How long after the planner's state a command acts on the robot beyond the planning itself
    (``sabre.RealtimeCascade``'s ``command_delay``): on the trajectory interface a segment copies
    the one in force for its lead and is made every period (half of one on average), and its velocity
    follows the filtered command with the segments' time constant; 0 on the velocity stream."""
    if arm_interface(params) != "trajectory":
        return 0.0
    return float(params["trajectory_lead"]) + 0.5 / float(params["trajectory_rate"]) + TIME_CONSTANT


def trajectory_limits(arm_velocity: Sequence[float] | np.ndarray, params: dict[str, Any]) -> Limits:
    """The segments' velocity, acceleration and jerk bounds per arm joint: each given parameter
    (``arm_velocity_limits``, ``trajectory_acceleration_limits``, ``trajectory_jerk_limits``), else
    :data:`VELOCITY_FRACTION` of the URDF's velocity and :data:`TRAJECTORY_FRACTION` of Franka's
    published acceleration and jerk (the slowest Franka joint's for an arm that is not a Panda)."""
    n = len(arm_velocity)
    accel, jerk = list(FRANKA_ACCELERATION), list(FRANKA_JERK)
    if n != len(accel):
        accel, jerk = [min(accel)] * n, [min(jerk)] * n

    def pick(name: str, default: Sequence[float], scale: float = 1.0) -> tuple[float, ...]:
        given = params.get(name) or []
        return tuple(finite_list(name, list(given) if given else [scale * v for v in default], n))

    return Limits(
        pick("arm_velocity_limits", list(arm_velocity), VELOCITY_FRACTION),
        pick("trajectory_acceleration_limits", accel, TRAJECTORY_FRACTION),
        pick("trajectory_jerk_limits", jerk, TRAJECTORY_FRACTION),
    )


def stream_trajectory(cascade: _core.Cascade, limits: Limits, params: dict[str, Any]) -> bool:
    """Sets ``cascade`` (its command shaping set) to stream the arm's commands as segments with
    ``limits`` and the ``trajectory_*`` parameters; returns whether the points carry accelerations
    (``trajectory_interpolation: quintic``)."""
    interpolation = str(params["trajectory_interpolation"])
    if interpolation not in INTERPOLATIONS:
        raise InvalidValueError(f"trajectory_interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    rate = float(params["trajectory_rate"])
    if not (math.isfinite(rate) and rate > 0):
        raise InvalidValueError(f"trajectory_rate must be positive, got {rate}")
    n = len(limits.velocity)
    cascade.set_trajectory(
        list(limits.velocity),
        list(limits.acceleration),
        list(limits.jerk),
        [float(params["trajectory_position_gain"])] * n,
        period=1.0 / rate,
        lead=float(params["trajectory_lead"]),
        tolerated_gap=float(params["trajectory_tolerated_gap"]),
        filter_step=float(params["trajectory_filter_step"]),
    )
    return interpolation == "quintic"
