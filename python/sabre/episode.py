"""Episode files: an :class:`~sabre.Episode` as one ``.npz`` (arrays plus a JSON header), and back."""

from __future__ import annotations

import json
import os
from dataclasses import fields
from typing import TYPE_CHECKING

import numpy as np

from .errors import InvalidValueError, UnknownAssetError
from .scene import OBJECTS, ROBOTS, Scene

if TYPE_CHECKING:
    from .planner import Episode

__all__ = ["save_episode", "load_episode", "pose_to_xyz_rpy"]

_FORMAT = "sabre-episode/1"
_SCALARS = ("phases", "success", "time_to_success", "wall_time", "variant", "filter_fallbacks", "tank_floor",
            "target_opening", "success_opening")


def pose_to_xyz_rpy(pose: np.ndarray) -> np.ndarray:
    """(6,) x, y, z, roll, pitch, yaw of a (4, 4) pose, with R = Rz(yaw) Ry(pitch) Rx(roll) as in URDF."""
    r = np.asarray(pose, dtype=np.float64)[:3, :3]
    roll = np.arctan2(r[2, 1], r[2, 2])
    pitch = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[1, 0], r[0, 0])
    return np.concatenate([np.asarray(pose, dtype=np.float64)[:3, 3], [roll, pitch, yaw]])


def save_episode(episode: Episode, path: str | os.PathLike[str]) -> None:
    """Writes ``episode`` to ``path`` (``.npz``); only scenes built by :meth:`Scene.load` can be saved."""
    scene = episode.scene
    if scene.robot_name not in ROBOTS or scene.object_name not in OBJECTS:
        raise UnknownAssetError(f"Episode.save: scene {scene.robot_name}/{scene.object_name} is not built from "
                                f"built-in assets; only those can be rebuilt on load")
    header = {"format": _FORMAT, "robot": scene.robot_name, "object": scene.object_name,
              "object_pose": pose_to_xyz_rpy(scene.object_pose).tolist()}
    for name in _SCALARS:
        value = getattr(episode, name)
        header[name] = list(value) if isinstance(value, tuple) else value
    arrays = {f.name: np.asarray(getattr(episode, f.name)) for f in fields(episode)
              if f.name != "scene" and f.name not in _SCALARS and getattr(episode, f.name) is not None}
    arrays["header"] = np.array(json.dumps(header))
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]  # numpy's stub types **kwds as bool


def load_episode(path: str | os.PathLike[str]) -> Episode:
    """Reads an episode written by :func:`save_episode`."""
    from .planner import Episode

    with np.load(path, allow_pickle=False) as data:
        if "header" not in data.files:
            raise InvalidValueError(f"{path}: not a sabre episode file (no header)")
        header = json.loads(str(data["header"]))
        if header.get("format") != _FORMAT:
            raise InvalidValueError(f"{path}: unsupported episode format {header.get('format')!r}")
        arrays = {name: data[name] for name in data.files if name != "header"}
    scene = Scene.load(header["robot"], header["object"], obj_pose=header["object_pose"])
    scalars = {name: header.get(name) for name in _SCALARS}
    scalars["phases"] = tuple(scalars["phases"])
    return Episode(scene=scene, **scalars, **arrays)
