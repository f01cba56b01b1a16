"""MuJoCo as a second, independent 1 kHz plant (:class:`MujocoPlant`), built by MuJoCo's own URDF importer
from the same robot and object files as the scene (needs the ``mujoco`` extra)."""

from __future__ import annotations

from .model import OBJECT_PREFIX
from .plant import MujocoPlant

__all__ = ["MujocoPlant", "OBJECT_PREFIX"]
