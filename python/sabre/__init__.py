"""sabre — robust sampling-based control for mobile manipulators that open doors, drawers and dishwashers.

The physics (Rapier), the sampler and the safety filter run in Rust (``sabre._core``, private);
this package is the public API.
"""

from __future__ import annotations

from . import assets, costs, guides, tasks  # noqa: F401 (modules of the public API)
from ._core import __version__
from .closed_loop import paper_start_state, run_episode
from .episode import Episode
from .errors import (
    AssumedInertialWarning,
    InvalidValueError,
    MissingExtraError,
    PlannerError,
    SabreError,
    ShapeError,
    SimulationError,
    UnknownAssetError,
    UnknownFrameError,
    UrdfError,
)
from .estimation import LowPass, ObjectEstimate, ObjectStateEstimator, tau_ext_from_wrench
from .experiments import scenarios
from .inner_loop import LowLevelController, PlanSnapshot, Trace
from .mujoco import MujocoPlant
from .planner import VARIANTS, Controller, ControllerConfig, IterationStats, likelihood_weights
from .plants import PlantInterface
from .realtime import RealtimeCascade, TickResult
from .robots import TOOLS, Tool
from .safety import (
    ConstraintRows,
    EnergyTank,
    FilterResult,
    FilterStats,
    Obstacle,
    QPMatrices,
    SafetyConfig,
    SafetyFilter,
    SequenceResult,
    TankRefill,
)
from .scene import OBJECTS, ROBOTS, Scene
from .scripted import ScriptedMotion, hook_and_pull
from .sim import CONTACT_MODELS, ContactPoint, Plant, RolloutModel, RolloutResult, default_threads
from .viz.plots import plot_episode

__all__ = [
    "VARIANTS",
    "RealtimeCascade",
    "TickResult",
    "PlanSnapshot",
    "__version__",
    "Scene",
    "ROBOTS",
    "OBJECTS",
    "Tool",
    "TOOLS",
    "RolloutModel",
    "RolloutResult",
    "CONTACT_MODELS",
    "Plant",
    "PlantInterface",
    "MujocoPlant",
    "Trace",
    "ContactPoint",
    "LowLevelController",
    "SafetyFilter",
    "SafetyConfig",
    "FilterResult",
    "SequenceResult",
    "FilterStats",
    "ConstraintRows",
    "QPMatrices",
    "Obstacle",
    "EnergyTank",
    "TankRefill",
    "default_threads",
    "costs",
    "assets",
    "tasks",
    "scenarios",
    "Controller",
    "ControllerConfig",
    "Episode",
    "IterationStats",
    "run_episode",
    "plot_episode",
    "paper_start_state",
    "likelihood_weights",
    "ScriptedMotion",
    "hook_and_pull",
    "LowPass",
    "tau_ext_from_wrench",
    "ObjectEstimate",
    "ObjectStateEstimator",
    "SabreError",
    "ShapeError",
    "InvalidValueError",
    "UnknownAssetError",
    "UrdfError",
    "UnknownFrameError",
    "SimulationError",
    "MissingExtraError",
    "PlannerError",
    "AssumedInertialWarning",
]
