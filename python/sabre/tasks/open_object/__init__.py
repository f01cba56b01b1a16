"""Opening a door, drawer or dishwasher with a hook finger: the task :class:`OpenObject`, its settings and error measures."""

from __future__ import annotations

from .config import ApproachConfig, GuideConfig, HookConfig, NoiseConfig, OpenConfig, ReleaseConfig
from .geometry import GraspError, PocketError
from .task import OpenObject

__all__ = [
    "OpenObject",
    "ApproachConfig",
    "HookConfig",
    "OpenConfig",
    "ReleaseConfig",
    "NoiseConfig",
    "GuideConfig",
    "GraspError",
    "PocketError",
]
