"""Input checking shared by the public wrappers: float64 arrays of a documented shape, finite values."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .errors import InvalidValueError, ShapeError


def _shape_text(shape: Sequence[int | None]) -> str:
    return "(" + ", ".join("·" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def as_array(name: str, value: Any) -> np.ndarray:
    """`value` as a NumPy array; ragged nested lists and the like raise :class:`ShapeError`."""
    try:
        return np.asarray(value)
    except Exception as exc:
        raise ShapeError(f"{name}: cannot be read as an array ({exc})") from None


def as_float_array(name: str, value: Any, shape: Sequence[int | None]) -> np.ndarray:
    """Returns `value` as a C-contiguous float64 array of `shape` (None = any size), all finite.

    Raises :class:`ShapeError` for a wrong shape or a non-numeric dtype and
    :class:`InvalidValueError` for NaN or infinite entries.
    """
    array = as_array(name, value)
    if array.dtype.kind not in "fiu":
        raise ShapeError(f"{name}: expected a real numeric array, got dtype {array.dtype}")
    if array.ndim != len(shape) or any(e is not None and g != e for g, e in zip(array.shape, shape)):
        raise ShapeError(f"{name}: expected shape {_shape_text(shape)}, got {array.shape}")
    array = np.ascontiguousarray(array, dtype=np.float64)
    if not np.isfinite(array).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        raise InvalidValueError(f"{name}: entry {bad} is {array[bad]}; values must be finite")
    return array


def as_state_vector(name: str, value: Any, size: int) -> np.ndarray:
    """:func:`as_float_array` for a short vector of ``size`` entries (a state, every planning
    iteration), its finiteness checked entry by entry in Python: NumPy's ufunc machinery, run
    right after a batch of rollouts, starts from cold caches and costs tens to hundreds of µs."""
    array = as_array(name, value)
    if array.shape != (size,) or array.dtype.kind not in "fiu":
        return as_float_array(name, value, (size,))  # its error
    array = np.ascontiguousarray(array, dtype=np.float64)
    if not all(map(math.isfinite, array.tolist())):
        return as_float_array(name, array, (size,))  # its error, naming the entry
    return array


def as_pose(name: str, value: Any, tolerance: float = 1e-6) -> np.ndarray:
    """A (4, 4) homogeneous transform: bottom row [0, 0, 0, 1] and a proper rotation (RᵀR = I,
    det R = +1) within ``tolerance``; raises :class:`InvalidValueError` naming what is wrong."""
    pose = as_float_array(name, value, (4, 4))
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=tolerance):
        raise InvalidValueError(f"{name}: the bottom row of a pose must be [0, 0, 0, 1], got {pose[3].tolist()}")
    rotation = pose[:3, :3]
    if not np.allclose(rotation.T @ rotation, np.eye(3), rtol=0.0, atol=tolerance) or np.linalg.det(rotation) < 0.0:
        raise InvalidValueError(f"{name}: the upper-left 3 × 3 block must be a rotation (orthonormal, det +1)")
    return pose


def as_finite(name: str, value: Any) -> float:
    """A finite float (bools, None, strings and complex numbers are refused)."""
    if isinstance(value, (bool, str, bytes)) or value is None:
        raise InvalidValueError(f"{name}: expected a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InvalidValueError(f"{name}: expected a real number, got {value!r}") from None
    if not np.isfinite(number):
        raise InvalidValueError(f"{name}: must be finite, got {number}")
    return number


def as_positive(name: str, value: Any) -> float:
    """A finite, strictly positive float."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(number) or number <= 0.0:
        raise InvalidValueError(f"{name}: must be finite and positive, got {number}")
    return number


def as_non_negative(name: str, value: Any) -> float:
    """A finite float that is zero or positive."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InvalidValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(number) or number < 0.0:
        raise InvalidValueError(f"{name}: must be finite and non-negative, got {number}")
    return number


#: The largest integer the core takes (a 64-bit seed, index or count).
MAX_INTEGER = 2**64 - 1


def as_count(name: str, value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """An integer within [minimum, maximum] (bools are refused; maximum at most :data:`MAX_INTEGER`)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise InvalidValueError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    maximum = MAX_INTEGER if maximum is None else min(maximum, MAX_INTEGER)
    if int(value) > maximum:
        raise InvalidValueError(f"{name}: expected an integer <= {maximum}, got {value!r}")
    return int(value)


def as_accelerations(name: str, value: Any, size: int) -> list[float]:
    """``value`` as ``size`` finite, positive per-joint bounds (rad/s² or m/s²), else InvalidValueError
    (ShapeError for the wrong shape)."""
    a = as_float_array(name, value, (size,))
    if np.any(a <= 0):
        raise InvalidValueError(f"{name} must hold positive bounds, got {a.tolist()}")
    return [float(v) for v in a]


def readonly(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def core_config(config_class: type, **fields: Any) -> Any:
    """A config object of the compiled core (its defaults from Rust) with `fields` set."""
    config = config_class()
    for name, value in fields.items():
        setattr(config, name, value)
    return config
