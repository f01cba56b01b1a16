"""The addresses the core needs to take and publish serialized messages through rcl without Python:
rcl's and rcutils' functions (from the libraries rclpy has loaded) and an rclpy endpoint's handle."""

from __future__ import annotations

import ctypes
import os
from typing import Any

from .. import _core
from ..errors import SabreError

__all__ = ["rcl_functions", "handle_address"]

#: The libraries that hold the functions, as rclpy loaded them.
_LIBRARIES = ("librcl.so", "librcutils.so")


def rcl_functions() -> list[int]:
    """The addresses of the functions `_core.rcl_function_names()` names, looked up in the rcl and
    rcutils that this process loaded with rclpy (never another copy). Raises SabreError when rclpy
    is not imported or a function is missing."""
    import rclpy  # noqa: F401  (loads the libraries)

    libraries = []
    for name in _LIBRARIES:
        try:
            libraries.append(ctypes.CDLL(name, mode=os.RTLD_NOLOAD))
        except OSError as exc:
            raise SabreError(f"{name} is not loaded in this process: {exc}") from exc
    addresses = []
    for function in _core.rcl_function_names():
        for library in libraries:
            pointer = getattr(library, function, None)
            if pointer is not None:
                addresses.append(ctypes.cast(pointer, ctypes.c_void_p).value or 0)
                break
        else:
            raise SabreError(f"{function} is in neither of {', '.join(_LIBRARIES)}")
    return addresses


def handle_address(endpoint: Any) -> int:
    """The address of an rclpy publisher's or subscription's rcl handle."""
    return int(endpoint.handle.pointer)
