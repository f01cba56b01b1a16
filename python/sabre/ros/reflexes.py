"""The Franka arm's checks of a joint-velocity command stream, emulated for the simulated robot (in
the core): every control cycle the command in effect must keep the joint velocity, acceleration and
jerk limits, the latter two as difference quotients over the cycle; a violation aborts the motion
(libfranka's discontinuity reflexes), and the arm brakes and ignores commands until recovered."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .. import _core
from .params import FRANKA_ACCELERATION, FRANKA_JERK, FRANKA_VELOCITY

__all__ = ["FrankaReflexes", "LIMIT_TOLERANCE"]

#: Relative slack on each limit (libfranka's checks allow the limit itself, within rounding).
LIMIT_TOLERANCE = 1e-6


class FrankaReflexes:
    """Checks the command in effect at each cycle of ``dt`` s against the limits (defaults: Franka's
    published ones). :meth:`check` returns the violation that aborted the motion, once; after it
    :attr:`aborted` stays set until :meth:`recover`."""

    def __init__(
        self,
        dt: float,
        velocity: Sequence[float] = FRANKA_VELOCITY,
        acceleration: Sequence[float] = FRANKA_ACCELERATION,
        jerk: Sequence[float] = FRANKA_JERK,
    ) -> None:
        self.dt = float(dt)
        self.core = _core.FrankaReflexes(
            self.dt, [float(v) for v in velocity], [float(a) for a in acceleration], [float(j) for j in jerk]
        )

    @classmethod
    def for_arm(cls, dt: float, velocity: Sequence[float] | np.ndarray) -> FrankaReflexes:
        """Franka's checks for an arm with joint velocity limits ``velocity`` (its URDF's): a
        seven-joint arm gets Franka's published limits; any other the slowest Franka joint's
        acceleration and jerk on every joint and its own velocity limits (the controller's default
        rate limits follow the same rule)."""
        if len(velocity) == len(FRANKA_VELOCITY):
            return cls(dt)
        n = len(velocity)
        return cls(dt, list(velocity), [min(FRANKA_ACCELERATION)] * n, [min(FRANKA_JERK)] * n)

    @property
    def aborted(self) -> str | None:
        return self.core.aborted

    @property
    def aborts(self) -> int:
        return self.core.aborts

    def recover(self) -> None:
        """Clears an abort; the next check starts from rest."""
        self.core.recover()

    def follow(self, v: np.ndarray) -> None:
        """Takes ``v`` as the command in effect without checking it (the robot's own stop)."""
        self.core.follow(np.asarray(v, dtype=np.float64))

    def check(self, v: np.ndarray) -> str | None:
        """The reflex ``v`` (the command in effect this cycle) trips, if any (then aborted)."""
        return self.core.check(np.asarray(v, dtype=np.float64))
