"""sabre — robust sampling-based control for mobile manipulators that open doors, drawers and dishwashers.

The physics (Rapier), the sampler and the safety filter run in Rust (``sabre._core``, private);
this package is the public API.
"""

from __future__ import annotations

from ._core import __version__
from .errors import (
    InvalidValueError,
    SabreError,
    ShapeError,
    SimulationError,
    MissingExtraError,
    UnknownAssetError,
    UnknownFrameError,
    UrdfError,
)
from . import costs, guides, scenarios, tasks
from .controller import VARIANTS, Controller, ControllerConfig, Episode, likelihood_weights, paper_start_state, run_episode
from .realtime import RealtimeCascade, TickResult
from .scene import OBJECTS, ROBOTS, Scene
from .safety import EnergyTank, FilterResult, Obstacle, SafetyConfig, SafetyFilter, SequenceResult
from .scripted import ScriptedMotion, hook_and_pull
from .sim import Contact, LowLevelController, Plant, RolloutModel, RolloutResult, Trace, default_threads

__all__ = [
    "VARIANTS",
    "RealtimeCascade",
    "TickResult",
    "__version__",
    "Scene",
    "ROBOTS",
    "OBJECTS",
    "RolloutModel",
    "RolloutResult",
    "Plant",
    "Trace",
    "Contact",
    "LowLevelController",
    "SafetyFilter",
    "SafetyConfig",
    "FilterResult",
    "SequenceResult",
    "Obstacle",
    "EnergyTank",
    "default_threads",
    "costs",
    "tasks",
    "scenarios",
    "Controller",
    "ControllerConfig",
    "Episode",
    "run_episode",
    "paper_start_state",
    "likelihood_weights",
    "ScriptedMotion",
    "hook_and_pull",
    "SabreError",
    "ShapeError",
    "InvalidValueError",
    "UnknownAssetError",
    "UrdfError",
    "UnknownFrameError",
    "SimulationError",
    "MissingExtraError",
]
