"""Tasks: what the controller should achieve, as phases with a cost each, a switch rule and a success test.

Subclass :class:`Task` to script your own: give ``phases``, ``cost(scene, phase)``,
``next_phase(scene, x, t, phase)`` and ``success(scene, x)``; ``on_step`` runs once per planning
iteration for anything else (logging, moving a target, ...). :class:`Reach` and :class:`OpenObject`
are the tasks that ship (:mod:`sabre.tasks.base`, :mod:`sabre.tasks.open_object`).
"""

from __future__ import annotations

from .base import Reach, SafetyWeights, Task, TaskController
from .open_object import (
    ApproachConfig,
    GraspError,
    GuideConfig,
    HookConfig,
    NoiseConfig,
    OpenConfig,
    OpenObject,
    PocketError,
    ReleaseConfig,
)

__all__ = [
    "Task",
    "TaskController",
    "Reach",
    "OpenObject",
    "SafetyWeights",
    "ApproachConfig",
    "HookConfig",
    "OpenConfig",
    "ReleaseConfig",
    "NoiseConfig",
    "GuideConfig",
    "GraspError",
    "PocketError",
]
