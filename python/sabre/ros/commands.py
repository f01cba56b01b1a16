"""What the controller node commands, on the core's command streams and gate (no ROS import): the
arm's and the base's command streams through per-joint velocity, acceleration and jerk limits, and
the gate that decides when they follow the plan and when they ramp to zero (the core tick of the
controller node runs a copy of the same gate). Time comes in as an
argument, so that the stop logic is tested with a fake clock."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .. import _core
from ..errors import InvalidValueError
from .params import BASE_ACCELERATION, BASE_JERK, TOLERATED_GAP, finite_list, robust_arm_limits

__all__ = ["Limits", "CommandLimits", "CommandShaper", "Command", "CommandGate", "command_limits", "joint_accelerations"]


@dataclass(frozen=True)
class Limits:
    """Per-joint velocity, acceleration and jerk bounds of one command stream."""

    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    jerk: tuple[float, ...]


@dataclass(frozen=True)
class CommandLimits:
    """The arm's limits (step ``period``) and the base's (step ``base_period``; None: a fixed base)."""

    arm: Limits
    base: Limits | None
    period: float
    base_period: float


def command_limits(
    arm_velocity: Sequence[float] | np.ndarray,
    base_velocity: Sequence[float] | np.ndarray | None,
    params: dict,
) -> CommandLimits:
    """The limits from the node's parameters, each unset one from its default: velocities from the
    URDF (``arm_velocity``, ``base_velocity``; None: the robot has no base), the arm's acceleration
    and jerk from Franka's published limits kept robust to a delivery gap of ``tolerated_gap``
    (:func:`sabre.ros.params.robust_arm_limits`), the base's Ridgeback-like ones."""
    period = float(params["command_period"])
    rate = float(params["cmd_vel_rate"])
    if not (period > 0 and math.isfinite(period)) or not (rate > 0 and math.isfinite(rate)):
        raise InvalidValueError(f"command_period and cmd_vel_rate must be positive, got {period}, {rate}")
    n = len(arm_velocity)
    accel, jerk = robust_arm_limits(period, float(params.get("tolerated_gap", TOLERATED_GAP)))
    if n != len(accel):
        # not a Panda: the same robust rule on the slowest Franka joint's bounds
        accel, jerk = [min(accel)] * n, [min(jerk)] * n

    def pick(name: str, default: Sequence[float] | np.ndarray, size: int) -> tuple[float, ...]:
        given = params.get(name) or []
        return tuple(finite_list(name, list(given) if given else list(default), size))

    arm = Limits(
        pick("arm_velocity_limits", arm_velocity, n), pick("arm_acceleration_limits", accel, n), pick("arm_jerk_limits", jerk, n)
    )
    base = None
    if base_velocity is not None:
        base = Limits(
            pick("base_velocity_limits", base_velocity, 3),
            pick("base_acceleration_limits", BASE_ACCELERATION, 3),
            pick("base_jerk_limits", BASE_JERK, 3),
        )
    return CommandLimits(arm=arm, base=base, period=period, base_period=max(period, 1.0 / rate))


def joint_accelerations(
    nq: int,
    arm_index: Sequence[int] | np.ndarray,
    arm_acceleration: Sequence[float],
    base_index: Sequence[int] | np.ndarray | None,
    base: Limits | None,
) -> tuple[float, ...]:
    """Per joint (nq), the largest acceleration the robot's command path gives it, for the rollout
    model (:class:`sabre.ControllerConfig`'s ``command_acceleration``): the arm's joints ``arm_index``
    their stream's or segments' ``arm_acceleration``; the base's x and y (world rates) the smaller of
    its stream's (``base``) two linear bounds, which it reaches at any heading, and its yaw its own.
    Every joint must be the arm's or the base's."""
    out = [math.nan] * nq
    for i, a in zip(arm_index, arm_acceleration):
        out[int(i)] = float(a)
    if base_index is not None and len(base_index) and base is not None:
        ix, iy, iyaw = (int(i) for i in base_index)
        linear = min(float(base.acceleration[0]), float(base.acceleration[1]))
        out[ix], out[iy], out[iyaw] = linear, linear, float(base.acceleration[2])
    missing = [i for i, a in enumerate(out) if math.isnan(a)]
    if missing:
        raise InvalidValueError(f"joints {missing} are neither the arm's nor the base's: no command bound for them")
    return tuple(out)


@dataclass(frozen=True)
class Command:
    """One step of the command streams: the arm's (na,), and the base's twist (vx, vy, ωz) in the
    base frame when a base command is due this step (else None, and always None without a base)."""

    arm: np.ndarray
    base: np.ndarray | None


class CommandShaper:
    """The arm's and the base's command streams through their rate limiters: the arm steps every
    call (``period``), the base every ``base_every``-th call (its own limiter at that step); a robot
    without a base has the arm's stream only. The streams run in the core
    (:class:`sabre._core.CommandGate`); a :class:`CommandGate` made on this shaper puts its clock on
    them, and the shaper's steps are that gate's from then on (a shaper serves one gate)."""

    def __init__(self, limits: CommandLimits) -> None:
        self.limits = limits
        a, b = limits.arm, limits.base
        self.base_every = max(1, int(round(limits.base_period / limits.period)))
        arm = _core.RateLimiter(list(a.velocity), list(a.acceleration), list(a.jerk), limits.period)
        base = (
            None
            if b is None
            else _core.RateLimiter(list(b.velocity), list(b.acceleration), list(b.jerk), limits.period * self.base_every)
        )
        # without a gate the streams have no clock: an infinite timeout, a watchdog that never ramps
        self._core = _core.CommandGate(arm, base, self.base_every, math.inf)

    @property
    def arm(self) -> _core.RateLimiter:
        """A copy of the arm's limiter (its bounds and state)."""
        return self._core.arm

    @property
    def base(self) -> _core.RateLimiter | None:
        """A copy of the base's limiter (None: a fixed base)."""
        return self._core.base

    def step(self, arm: np.ndarray | None, base: np.ndarray | None) -> Command:
        """One step toward the targets: ``arm`` None ramps both streams to zero; ``base`` None
        keeps the base's last target."""
        return Command(*self._core.step(arm, base))

    @property
    def at_rest(self) -> bool:
        return self._core.at_rest

    @property
    def steps_to_rest(self) -> int:
        """A bound on the arm steps a ramp to rest takes (the base's counted in arm steps)."""
        return self._core.steps_to_rest

    def reset(self) -> None:
        self._core.reset()

    def _gated(self, state_timeout: float) -> _core.CommandGate:
        """These streams, in their current state, under a gate's clock with ``state_timeout``."""
        self._core = self._core.with_state_timeout(state_timeout)
        return self._core


class CommandGate:
    """Decides what the node commands on each tick and, between ticks, on each look of its watchdog.

    A tick with targets follows them through the limiters; a tick without (a reason to stop holds:
    e-stop, not active, stale joint, rejected message, stale plan, stopped planner) is one step of a
    ramp to zero. When no tick has come for ``state_timeout`` s, :meth:`watchdog` returns the ramp's
    steps that are due, one per ``period`` s counted from the last command, until the streams are at
    rest: the ramp starts at most one period after the timeout and never steps. The gate runs in the
    core (:class:`sabre._core.CommandGate`) on ``shaper``'s streams."""

    def __init__(self, shaper: CommandShaper, state_timeout: float) -> None:
        self.shaper = shaper
        self._core = shaper._gated(float(state_timeout))

    @property
    def core(self) -> _core.CommandGate:
        """The core gate this class runs: a loop in the core (``_core.BridgeTick``) takes a copy."""
        return self._core

    @property
    def period(self) -> float:
        return self._core.period

    @property
    def state_timeout(self) -> float:
        return self._core.state_timeout

    @property
    def last_tick(self) -> float:
        """When the last tick came (-inf before the first)."""
        return self._core.last_tick

    @property
    def last_command(self) -> float:
        """When the last command was due (a tick's, or a ramp step's one period after the one before)."""
        return self._core.last_command

    @property
    def stale_since(self) -> float | None:
        """When the watchdog found the ticks stopped (None while they come)."""
        return self._core.stale_since

    @property
    def stale_events(self) -> int:
        """How many times the ticks stopped for ``state_timeout``."""
        return self._core.stale_events

    def on_tick(self, now: float, arm: np.ndarray | None, base: np.ndarray | None) -> Command:
        """The command answering a tick at ``now`` (targets None: a ramp step toward zero)."""
        return Command(*self._core.on_tick(now, arm, base))

    def watchdog(self, now: float, limit: int = 10) -> list[Command]:
        """The ramp steps due at ``now`` because no tick came for ``state_timeout`` (at most
        ``limit`` at once: a late look catches up over the next ones); none before the first tick
        (nothing commanded, nothing to ramp)."""
        return [Command(arm, base) for arm, base in self._core.watchdog(now, limit)]

    def next_look(self, now: float) -> float:
        """Seconds until the watchdog has something to do (a caller's sleep)."""
        return self._core.next_look(now)
