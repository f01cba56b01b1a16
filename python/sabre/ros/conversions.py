"""Message contents ↔ sabre arrays for the bridge, in plain NumPy (no ROS import): joint-name
mapping, world ↔ base frame base rates, τ_ext from the wrist wrench, and a first-order low-pass."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import InvalidValueError
from ..scene import Scene

__all__ = ["MessageError", "JointMap", "world_to_base", "base_to_world", "tau_ext_from_wrench", "LowPass", "SENSOR_FRAME"]

#: The frame the wrist wrench is measured at: force and torque (about this frame's origin) in the
#: world frame, as :attr:`sabre.Plant.wrench` reports them.
SENSOR_FRAME = "panda_link8"


class MessageError(InvalidValueError):
    """A received message cannot be used (unknown or missing joint names, wrong lengths, NaN)."""


class JointMap:
    """Maps the named entries of a JointState-like message onto ``wanted`` names (sabre's order).

    The message may list the joints in any order and carry extra joints (ignored); a wanted joint
    that is absent, a length mismatch between names and values, or a non-finite value raises
    :class:`MessageError`. The index is cached per distinct name tuple, so a publisher with a fixed
    order pays the lookup once."""

    def __init__(self, wanted: Sequence[str]) -> None:
        self.wanted = tuple(str(n) for n in wanted)
        if len(set(self.wanted)) != len(self.wanted):
            raise InvalidValueError(f"joint names must be distinct, got {self.wanted}")
        self._cache: tuple[tuple[str, ...], np.ndarray] | None = None

    def index(self, names: Sequence[str]) -> np.ndarray:
        """(len(wanted),) positions of the wanted joints in ``names``."""
        names = tuple(names)
        if self._cache is not None and self._cache[0] == names:
            return self._cache[1]
        lookup = {n: i for i, n in enumerate(names)}
        missing = [n for n in self.wanted if n not in lookup]
        if missing:
            raise MessageError(f"joint state lacks joints {missing} (it has {list(names)})")
        idx = np.array([lookup[n] for n in self.wanted], dtype=np.intp)
        self._cache = (names, idx)
        return idx

    def values(self, names: Sequence[str], values: Sequence[float], field: str, *, required: bool = True) -> np.ndarray:
        """(len(wanted),) the wanted joints' entries of ``values`` (float64). An empty field is
        zeros unless ``required``."""
        idx = self.index(names)
        arr = np.asarray(values, dtype=np.float64)
        if arr.size == 0 and not required:
            return np.zeros(len(self.wanted))
        if arr.shape != (len(names),):
            raise MessageError(f"joint state {field}: {arr.size} values for {len(names)} names")
        out = arr[idx]
        if not np.isfinite(out).all():
            bad = [self.wanted[i] for i in np.flatnonzero(~np.isfinite(out))]
            raise MessageError(f"joint state {field}: non-finite value for {bad}")
        return out


def world_to_base(rates_world: Sequence[float] | np.ndarray, yaw: float) -> tuple[float, float, float]:
    """(vx, vy, ωz) in the base frame from the planned world-frame base rates (ẋ, ẏ, ψ̇) at yaw ψ."""
    vx, vy, wz = (float(v) for v in rates_world)
    c, s = math.cos(yaw), math.sin(yaw)
    return c * vx + s * vy, -s * vx + c * vy, wz


def base_to_world(twist_base: Sequence[float] | np.ndarray, yaw: float) -> tuple[float, float, float]:
    """(ẋ, ẏ, ψ̇) in the world frame from a base-frame twist (vx, vy, ωz) at yaw ψ."""
    vx, vy, wz = (float(v) for v in twist_base)
    c, s = math.cos(yaw), math.sin(yaw)
    return c * vx - s * vy, s * vx + c * vy, wz


def tau_ext_from_wrench(scene: Scene, q: np.ndarray, wrench: np.ndarray, frame: str = SENSOR_FRAME) -> np.ndarray:
    """(nq,) external joint torques J(q)ᵀ w of a wrist wrench w = [f; m] (world frame, moment about
    ``frame``'s origin). Contacts on links before the sensor do not show in it."""
    return scene.jacobian(q, frame).T @ np.asarray(wrench, dtype=np.float64)


class LowPass:
    """First-order low-pass at ``cutoff`` Hz integrated with the measured step dt (exact
    exponential update, so irregular message spacing is handled); None passes through."""

    def __init__(self, cutoff: float | None) -> None:
        self.cutoff = None if cutoff is None or cutoff <= 0 else float(cutoff)
        self.value: np.ndarray | None = None

    def update(self, x: np.ndarray, dt: float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if self.value is None or self.cutoff is None:
            self.value = x.copy()
        else:
            a = 1.0 - math.exp(-2.0 * math.pi * self.cutoff * max(dt, 0.0))
            self.value = self.value + a * (x - self.value)
        return self.value
