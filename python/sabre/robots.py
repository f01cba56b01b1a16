"""A robot's options in a scene: the tool to attach (:class:`Tool`), held joints, the base and the postures.

Each option overrides what the robot URDF's ``<sabre>`` block declares; what neither gives is detected from
the kinematic tree (docs/robots.md has the rules).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ._validate import as_finite, as_float_array
from .errors import InvalidValueError

__all__ = ["Tool", "TOOLS", "robot_options"]

#: Tools that ship with sabre, by name: ``"hook"`` is the RoyalPanda's hook finger (root link
#: ``hook_finger``, control frame ``grasp`` 0.0366 m beyond the root, inside the hook's pocket).
TOOLS: tuple[str, ...] = ("hook",)


@dataclass(frozen=True)
class Tool:
    """A tool fixed to robot link ``parent``: a URDF fragment (a ``<robot>`` of links and fixed joints)
    whose root link sits at ``xyz`` (m), ``rpy`` (rad, URDF conventions) in the parent's frame.

    ``urdf`` is a shipped tool's name (:data:`TOOLS`), a path to a URDF file, or URDF text. ``frame``
    names the control frame the tool defines (default: the fragment's own ``<sabre><tool_frame>``;
    the shipped hook's is ``grasp``).

    Example: the RoyalPanda's hook on another Panda's hand, ``Tool("panda_hand", xyz=(0, 0, 0.0584))``.
    """

    parent: str
    urdf: str | os.PathLike[str] = "hook"
    xyz: Sequence[float] = (0.0, 0.0, 0.0)
    rpy: Sequence[float] = (0.0, 0.0, 0.0)
    frame: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.parent, str):
            raise InvalidValueError(f"Tool.parent must be a link name, got {self.parent!r}")
        object.__setattr__(self, "xyz", tuple(as_float_array("Tool.xyz", self.xyz, (3,)).tolist()))
        object.__setattr__(self, "rpy", tuple(as_float_array("Tool.rpy", self.rpy, (3,)).tolist()))

    def source(self) -> tuple[str, str]:
        """(kind, value) for the core: ("builtin", name), ("file", path) or ("text", URDF)."""
        text = os.fspath(self.urdf)
        if isinstance(self.urdf, str) and text in TOOLS:
            return "builtin", text
        if "<robot" in text:
            return "text", text
        if not Path(text).is_file():
            raise InvalidValueError(f"Tool.urdf: {text!r} is neither a shipped tool {TOOLS}, a URDF file nor URDF text")
        return "file", str(Path(text).resolve())


def _joint_values(name: str, values: Mapping[str, float] | None) -> list[tuple[str, float]]:
    if values is None:
        return []
    if not isinstance(values, Mapping):
        raise InvalidValueError(f"{name} must map joint names to values, got {type(values).__name__}")
    return [(str(joint), as_finite(f"{name}[{joint!r}]", value)) for joint, value in values.items()]


def _base(base: str | Sequence[str] | None, base_link: str | None) -> tuple[str, list[str], str | None] | None:
    if base is None:
        if base_link is not None:
            raise InvalidValueError("base_link needs base: 'fixed' or the three planar joints")
        return None
    if base == "fixed":
        return "fixed", [], base_link
    if isinstance(base, str) or len(base) != 3:
        raise InvalidValueError(f"base must be 'fixed' or three joint names (x, y, yaw), got {base!r}")
    return "planar", [str(j) for j in base], base_link


def robot_options(
    *,
    tool: Tool | None = None,
    tool_frame: str | None = None,
    robot_hold: Mapping[str, float] | None = None,
    base: str | Sequence[str] | None = None,
    base_link: str | None = None,
    home: Mapping[str, float] | None = None,
    start: Mapping[str, float] | None = None,
    work: Mapping[str, float] | None = None,
    wrist_sensor: str | None = None,
) -> dict:
    """The robot options as the core takes them (see :meth:`sabre.Scene.from_urdf`)."""
    if tool is not None and not isinstance(tool, Tool):
        raise InvalidValueError(f"tool must be a sabre.Tool, got {type(tool).__name__}")
    for name, value in (("tool_frame", tool_frame), ("wrist_sensor", wrist_sensor), ("base_link", base_link)):
        if value is not None and not isinstance(value, str):
            raise InvalidValueError(f"{name} must be a link name, got {value!r}")
    return {
        "tool": None if tool is None else (tool.parent, *tool.source(), list(tool.xyz), list(tool.rpy), tool.frame),
        "tool_frame": tool_frame,
        "hold": _joint_values("robot_hold", robot_hold),
        "base": _base(base, base_link),
        "home": _joint_values("home", home),
        "start": _joint_values("start", start),
        "work": _joint_values("work", work),
        "wrist_sensor": wrist_sensor,
    }
