"""The Franka arm's checks of a joint-velocity command stream, emulated for the simulated robot (plain
NumPy): every control cycle the command in effect must keep the joint velocity, acceleration and
jerk limits, the latter two as difference quotients over the cycle; a violation aborts the motion
(libfranka's discontinuity reflexes), and the arm brakes and ignores commands until recovered."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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
        self.v_max = np.asarray(velocity, dtype=np.float64) * (1 + LIMIT_TOLERANCE)
        self.a_max = np.asarray(acceleration, dtype=np.float64) * (1 + LIMIT_TOLERANCE)
        self.j_max = np.asarray(jerk, dtype=np.float64) * (1 + LIMIT_TOLERANCE)
        self._limits = np.concatenate((self.v_max, self.a_max, self.j_max))
        self.aborted: str | None = None
        self.aborts = 0
        self.recover()

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

    def recover(self) -> None:
        """Clears an abort; the next check starts from rest."""
        self.aborted = None
        self._v = np.zeros(len(self.v_max))
        self._a = np.zeros(len(self.v_max))

    def follow(self, v: np.ndarray) -> None:
        """Takes ``v`` as the command in effect without checking it (the robot's own stop)."""
        a = (v - self._v) / self.dt
        self._v, self._a = v.copy(), a

    def check(self, v: np.ndarray) -> str | None:
        """The reflex ``v`` (the command in effect this cycle) trips, if any (then aborted)."""
        if self.aborted is not None:
            return None
        a = (v - self._v) / self.dt
        jerk = (a - self._a) / self.dt
        self._v, self._a = v.copy(), a
        if (np.abs(np.concatenate((v, a, jerk))) <= self._limits).all():
            return None  # the common case, in one comparison
        for name, reflex, value, limit in (
            ("velocity", "velocity_limits_violation", v, self.v_max),
            ("acceleration", "velocity_discontinuity", a, self.a_max),
            ("jerk", "acceleration_discontinuity", jerk, self.j_max),
        ):
            over = np.flatnonzero(np.abs(value) > limit)
            if over.size:
                i = int(over[0])
                self.aborted = (
                    f"joint_motion_generator_{reflex}: joint {i + 1} commanded {name} {value[i]:.4g} beyond {limit[i]:.4g}"
                )
                self.aborts += 1
                return self.aborted
        return None
