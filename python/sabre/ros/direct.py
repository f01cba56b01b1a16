"""The addresses the core needs to take and publish serialized messages through rcl without Python
(rcl's and rcutils' functions from the libraries rclpy loaded, an rclpy endpoint's rcl handle), and
the checks that make them safe to use: the rcl, rcutils and rmw loaded are the releases whose
headers sabre's layouts were checked against when it was built, and the rclpy is one whose private
handle access is known."""

from __future__ import annotations

import ctypes
import os
import re
from pathlib import Path
from typing import Any

from .. import _core
from ..errors import SabreError

__all__ = ["rcl_functions", "handle_address", "loaded_versions"]

#: The libraries that hold the functions, as rclpy loaded them.
_LIBRARIES = ("librcl.so", "librcutils.so")

#: rclpy releases (major versions) whose publishers and subscriptions give their rcl handle's address
#: as ``endpoint.handle.pointer``, a private attribute: Jazzy's 7 and Kilted's 9, and the Rolling
#: between them.
RCLPY_HANDLE_RELEASES = (7, 8, 9)


def _package_version(prefix: Path, package: str) -> str | None:
    try:
        xml = (prefix / "share" / package / "package.xml").read_text()
    except OSError:
        return None
    found = re.search(r"<version>\s*([^<\s]+)\s*</version>", xml)
    return found.group(1) if found else None


def _major_minor(version: str) -> tuple[str, ...]:
    return tuple(version.split(".")[:2])


def loaded_versions(packages: tuple[str, ...] = ("rcl", "rcutils", "rmw")) -> dict[str, str]:
    """{package: version} of the ROS 2 libraries this process has loaded, read from the
    ``share/<package>/package.xml`` of the prefix each library was loaded from (wheels and apt
    installs alike put the library in ``<prefix>/lib``). Raises SabreError for one not loaded or
    whose version cannot be read."""
    maps = Path("/proc/self/maps").read_text()
    versions = {}
    for package in packages:
        found = re.search(rf"(/\S+)/lib{re.escape(package)}\.so\S*$", maps, re.MULTILINE)
        if not found:
            raise SabreError(f"lib{package}.so is not loaded in this process (import rclpy first)")
        version = _package_version(Path(found.group(1)).parent, package)
        if version is None:
            raise SabreError(f"cannot tell the release of {found.group(0)}: no share/{package}/package.xml beside it")
        versions[package] = version
    return versions


def _check_release() -> None:
    """Raises SabreError unless the rcl, rcutils and rmw loaded are the releases (major.minor) sabre's
    layouts were checked against at build time."""
    prefix, built = _core.rcl_built_against()
    loaded = loaded_versions(tuple(package for package, _ in built))
    for package, version in built:
        if _major_minor(loaded[package]) != _major_minor(version):
            raise SabreError(
                f"sabre's rcl layouts were checked against {package} {version} (the ROS 2 at {prefix}), "
                f"but this process loaded {package} {loaded[package]}: rebuild sabre with this ROS 2 "
                "(`make build` in its environment), or set direct_middleware: false"
            )


def rcl_functions() -> list[int]:
    """The addresses of the functions `_core.rcl_function_names()` names, looked up in the rcl and
    rcutils that this process loaded with rclpy (never another copy). Raises SabreError when sabre
    was built without the ROS 2 headers, when the libraries loaded are another release than those
    headers', or when a function is missing."""
    import rclpy  # noqa: F401  (loads the libraries)

    _check_release()
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
    """The address of an rclpy publisher's or subscription's rcl handle: rclpy's private
    ``handle.pointer``, read only here and only from an rclpy release known to have it (SabreError
    otherwise)."""
    import rclpy

    # site-packages sits in <prefix>/lib/pythonX.Y/, the package.xml in <prefix>/share/rclpy/
    prefix = Path(rclpy.__file__).resolve().parents[4]
    version = _package_version(prefix, "rclpy")
    major = int(version.split(".")[0]) if version and version.split(".")[0].isdigit() else None
    if major not in RCLPY_HANDLE_RELEASES:
        raise SabreError(
            f"rclpy {version or '(release unknown)'} is not one whose endpoints are known to expose their rcl "
            f"handle (majors {', '.join(map(str, RCLPY_HANDLE_RELEASES))}); set direct_middleware: false"
        )
    pointer = getattr(getattr(endpoint, "handle", None), "pointer", None)
    if not isinstance(pointer, int) or pointer == 0:
        raise SabreError(f"{type(endpoint).__name__} gives no rcl handle (handle.pointer); set direct_middleware: false")
    return pointer
