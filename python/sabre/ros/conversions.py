"""Message contents ↔ sabre arrays for the bridge, in plain NumPy (no ROS import): joint-name
mapping, world ↔ base frame base rates, quaternions ↔ roll, pitch, yaw; τ_ext from the wrist wrench
and the first-order low-pass are the core's (:mod:`sabre.estimation`), re-exported here."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import InvalidValueError
from ..estimation import SENSOR_FRAME, LowPass, tau_ext_from_wrench

__all__ = [
    "MessageError",
    "JointMap",
    "world_to_base",
    "base_to_world",
    "yaw_of",
    "rpy_of",
    "quaternion_of",
    "tau_ext_from_wrench",
    "LowPass",
    "SENSOR_FRAME",
]


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


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """The yaw (rad, about z) of a unit quaternion (x, y, z, w)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def rpy_of(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad, R = Rz(yaw) Ry(pitch) Rx(roll), of a quaternion (x, y, z, w),
    normalised first; a zero or non-finite quaternion raises :class:`MessageError`."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-9:
        raise MessageError(f"quaternion ({x}, {y}, {z}, {w}) is not a rotation")
    x, y, z, w = x / n, y / n, z / n, w / n
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch, yaw_of(x, y, z, w)


def quaternion_of(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
