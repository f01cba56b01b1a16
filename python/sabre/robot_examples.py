"""Robots built at run time from public descriptions: the wrappers in ``assets/robots/examples/`` merged with
the robot of the ``example-robot-data`` package they wrap (installed with the ``meshes`` extra).

A wrapper is a URDF of what sabre adds around the arm (a pedestal or a holonomic base, the mount) with a
``<sabre>`` block (the tool, held joints, postures); :func:`example_robot_urdf` merges it with the package's
URDF into one file whose mesh paths point into the package, so no mesh is copied.
"""

from __future__ import annotations

import importlib.metadata
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import MissingExtraError, UnknownAssetError
from .scene import Scene

__all__ = ["EXAMPLE_ROBOTS", "EXAMPLE_OBJECTS", "example_robot_data", "example_robot_urdf", "example_scene"]

_EXAMPLES = Path(__file__).resolve().parents[2] / "assets" / "robots" / "examples"

#: Each example robot: the URDF of ``example-robot-data`` its wrapper merges with.
EXAMPLE_ROBOTS: dict[str, str] = {
    "panda_pedestal": "robots/panda_description/urdf/panda.urdf",
    "ur5_mobile": "robots/ur_description/urdf/ur5_robot.urdf",
}

#: Where each example robot opens the four built-in objects (x, y, z, roll, pitch, yaw): the fixed
#: Panda's in front of the pedestal where the hand can follow the handle all the way open (the drawer
#: turned so that it slides out past the arm rather than into it), the mobile UR5's where the
#: RoyalPanda's stand.
EXAMPLE_OBJECTS: dict[str, dict[str, tuple[float, ...]]] = {
    "panda_pedestal": {
        "drawer": (0.686, -0.235, 0.0, 0.0, 0.0, -1.047),
        "microwave": (0.86, 0.22, 0.0, 0.0, 0.0, 0.0),
        "shelf": (0.86, 0.22, 0.0, 0.0, 0.0, 0.0),
        "dishwasher": (0.9, 0.2, 0.0, 0.0, 0.0, 0.0),
    },
    "ur5_mobile": {
        "shelf": (1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        "dishwasher": (1.2, 0.0, 0.0, 0.0, 0.0, 0.0),
        "drawer": (1.2, 0.0, 0.0, 0.0, 0.0, 0.0),
        "microwave": (1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    },
}

_PACKAGE = "package://example-robot-data/"


def example_robot_data() -> Path:
    """The folder ``share/example-robot-data`` of the installed ``example-robot-data`` package.

    Raises:
        MissingExtraError: the package is not installed.
    """
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        dist = None
    if dist is not None:
        folder = Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data")))
        if folder.is_dir():
            return folder
    raise MissingExtraError("the example robots need 'example-robot-data': pip install 'sabre-mpc[meshes]'")


def _cache_dir() -> Path:
    root = os.environ.get("SABRE_CACHE_DIR")
    if root:
        return Path(root) / "robots"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "sabre" / "robots"


def _merged(wrapper: ET.Element, arm: ET.Element, share: Path) -> ET.Element:
    """The wrapper's elements, then the arm's, as one robot named like the wrapper; the arm's
    ``package://example-robot-data/`` mesh paths made absolute."""
    for mesh in arm.iter("mesh"):
        filename = mesh.get("filename", "")
        if filename.startswith(_PACKAGE):
            mesh.set("filename", str(share / filename[len(_PACKAGE) :]))
    robot = ET.Element("robot", {"name": wrapper.get("name", "robot")})
    robot.extend(list(wrapper))
    robot.extend(child for child in arm if child.tag in ("material", "link", "joint"))
    return robot


def example_robot_urdf(name: str, folder: str | os.PathLike[str] | None = None) -> Path:
    """Writes the URDF of example robot ``name`` (:data:`EXAMPLE_ROBOTS`) into ``folder`` (default:
    ``$SABRE_CACHE_DIR/robots``, else ``~/.cache/sabre/robots``) and returns its path.

    Raises:
        UnknownAssetError: no such example. MissingExtraError: ``example-robot-data`` is not installed.
    """
    if name not in EXAMPLE_ROBOTS:
        raise UnknownAssetError(f"unknown example robot {name!r}; available: {', '.join(EXAMPLE_ROBOTS)}")
    share = example_robot_data()
    wrapper = ET.parse(_EXAMPLES / f"{name}.urdf").getroot()
    arm = ET.parse(share / EXAMPLE_ROBOTS[name]).getroot()
    out = Path(folder) if folder is not None else _cache_dir()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.urdf"
    robot = _merged(wrapper, arm, share)
    ET.indent(robot)
    text = ET.tostring(robot, encoding="unicode")
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text('<?xml version="1.0"?>\n' + text + "\n")
    os.replace(tmp, path)  # a concurrent reader sees the old file or the new one, never half of one
    return path


def example_scene(name: str, obj: str, obj_pose: Sequence[float] | None = None, **options: Any) -> Scene:
    """Example robot ``name`` with built-in object ``obj`` where :data:`EXAMPLE_OBJECTS` puts it (or at
    ``obj_pose``); ``options`` are :meth:`Scene.from_urdf`'s robot options."""
    path = example_robot_urdf(name)
    if obj_pose is None:
        obj_pose = EXAMPLE_OBJECTS[name].get(obj)
    return Scene.from_urdf(path, obj, obj_pose, **options)
