"""sabre — robust sampling-based control for mobile manipulators that open doors, drawers and dishwashers.

The physics (Rapier), the sampler and the safety filter run in Rust (``sabre._core``, private);
this package is the public API. Its names, by topic:

- the robot and the object: :class:`Scene` (``x = [q, q̇, o, ȯ]``), the built-in :data:`ROBOTS`,
  :data:`OBJECTS` and :data:`TOOLS`, and :mod:`sabre.assets`;
- simulation: :class:`RolloutModel`, the reduced model the controller predicts with; the 1 kHz plants,
  :class:`Plant` (sabre's own, on Rapier) and :class:`MujocoPlant` (the ``mujoco`` extra), both meeting
  :class:`PlantInterface`, the protocol the closed loop drives any simulator or robot through;
- the sampling-based controller (Sec. IV-A): :class:`Controller` with its :class:`ControllerConfig` (Table I
  and the variant), a task from :mod:`sabre.tasks`, costs from :mod:`sabre.costs`, guides from
  :mod:`sabre.guides`;
- the 1 kHz inner loop: :class:`LowLevelController` (53) tracks the plan in force (:class:`PlanSnapshot`);
  :class:`RealtimeCascade` is the deployment loop on any clock;
- the safety filter (41) and the energy tank (49): :class:`SafetyFilter`, :class:`EnergyTank` and their
  results;
- closed-loop episodes: :func:`run_episode`, :class:`Episode`, :func:`plot_episode` (the ``plot`` extra), and
  the scripted open-loop check :func:`hook_and_pull`;
- on a robot without a door sensor, the object's state from the hand: :class:`ObjectStateEstimator`;
- errors: every one derives from :class:`SabreError`.

What exists only to reproduce the paper is in :mod:`sabre.paper`. Every name is imported on first use
(PEP 562), so ``import sabre`` loads neither the closed loop, the experiments, the viewer, MuJoCo nor
ROS 2; type checkers read the imports under ``TYPE_CHECKING``.
"""

from __future__ import annotations

import importlib
import importlib.util
import warnings
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    # What a type checker and an IDE see; the same names, from the same modules, as _HOMES below.
    from . import assets, costs, guides, paper, tasks
    from ._core import __version__
    from .articulation import ArticulationConfig, ArticulationEstimate, ArticulationEstimator
    from .closed_loop import run_episode
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
    from .estimated_object import EstimatedObject
    from .estimation import ObjectEstimate, ObjectStateEstimator
    from .handle_object import DetectedHandle
    from .inner_loop import LowLevelController, PlanSnapshot, Trace
    from .mujoco import MujocoPlant
    from .planner import VARIANTS, Controller, ControllerConfig, IterationStats
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

if TYPE_CHECKING:  # the deprecated names (_DEPRECATED), still typed for the release in which they warn
    from .closed_loop import paper_start_state as paper_start_state
    from .estimation import LowPass as LowPass
    from .estimation import tau_ext_from_wrench as tau_ext_from_wrench
    from .experiments import scenarios as scenarios
    from .planner import likelihood_weights as likelihood_weights

__all__ = [
    "__version__",
    # the robot and the object
    "Scene",
    "ROBOTS",
    "OBJECTS",
    "Tool",
    "TOOLS",
    "assets",
    # simulation: the rollout model, the 1 kHz plants and the protocol they meet
    "RolloutModel",
    "RolloutResult",
    "CONTACT_MODELS",
    "default_threads",
    "PlantInterface",
    "Plant",
    "MujocoPlant",
    "ContactPoint",
    # the sampling-based controller, its task, costs and guides
    "Controller",
    "ControllerConfig",
    "VARIANTS",
    "IterationStats",
    "tasks",
    "costs",
    "guides",
    # the 1 kHz inner loop and the deployment loop
    "LowLevelController",
    "PlanSnapshot",
    "Trace",
    "RealtimeCascade",
    "TickResult",
    # the safety filter and the energy tank
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
    # closed-loop episodes and the scripted check
    "run_episode",
    "Episode",
    "plot_episode",
    "ScriptedMotion",
    "hook_and_pull",
    # the object's state on a robot without a door sensor
    "ObjectEstimate",
    "ObjectStateEstimator",
    "DetectedHandle",
    "EstimatedObject",
    "ArticulationEstimator",
    "ArticulationEstimate",
    "ArticulationConfig",
    # what exists only to reproduce the paper
    "paper",
    # errors
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

# The module each public name is imported from on first use; a module listed under its own name is
# that submodule.
_HOMES: dict[str, tuple[str, ...]] = {
    "._core": ("__version__",),
    ".assets": ("assets",),
    ".costs": ("costs",),
    ".guides": ("guides",),
    ".tasks": ("tasks",),
    ".paper": ("paper",),
    ".scene": ("Scene", "ROBOTS", "OBJECTS"),
    ".robots": ("Tool", "TOOLS"),
    ".sim": ("RolloutModel", "RolloutResult", "CONTACT_MODELS", "default_threads", "Plant", "ContactPoint"),
    ".plants": ("PlantInterface",),
    ".mujoco": ("MujocoPlant",),
    ".planner": ("Controller", "ControllerConfig", "VARIANTS", "IterationStats"),
    ".inner_loop": ("LowLevelController", "PlanSnapshot", "Trace"),
    ".realtime": ("RealtimeCascade", "TickResult"),
    ".safety": (
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
    ),
    ".closed_loop": ("run_episode",),
    ".episode": ("Episode",),
    ".viz.plots": ("plot_episode",),
    ".scripted": ("ScriptedMotion", "hook_and_pull"),
    ".estimation": ("ObjectEstimate", "ObjectStateEstimator"),
    ".handle_object": ("DetectedHandle",),
    ".estimated_object": ("EstimatedObject",),
    ".articulation": ("ArticulationEstimator", "ArticulationEstimate", "ArticulationConfig"),
    ".errors": (
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
    ),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}

# Names that resolve for one more release with a DeprecationWarning: (module, attribute or None for the
# module itself, what to use instead).
_DEPRECATED: dict[str, tuple[str, str | None, str]] = {
    # paper-only: sabre.paper holds them
    "paper_start_state": (
        ".closed_loop",
        "paper_start_state",
        "sabre.paper.paper_start_state, or Scene.start_state(), the same state for any robot",
    ),
    "scenarios": (".experiments.scenarios", None, "sabre.paper.scenarios"),
    "likelihood_weights": (".planner", "likelihood_weights", "sabre.paper.likelihood_weights"),
    # duplicates of the τ_ext conditioning the plants and the ROS 2 bridge run in the core
    "tau_ext_from_wrench": (
        ".estimation",
        "tau_ext_from_wrench",
        "scene.jacobian(q, scene.wrist_sensor_link).T @ wrench (world axes); the ROS 2 bridge converts a "
        "WrenchStamped in any frame itself",
    ),
    "LowPass": (
        ".estimation",
        "LowPass",
        "a band-limited τ_ext from the plant (Plant(tau_ext_cutoff=...)) or the ROS 2 bridge (tau_ext_cutoff); "
        "docs/simulators.md shows the first-order low-pass for a plant of your own",
    ),
}


def _load(module: str, attribute: str | None) -> Any:
    imported = importlib.import_module(module, __name__)
    return imported if attribute is None else getattr(imported, attribute)


def _resolve(name: str) -> Any:
    """The object ``sabre.<name>`` stands for, imported now (a public name is kept, so that it loads once)."""
    if name in _HOME:
        module = _HOME[name]
        value = _load(module, None if module == f".{name}" else name)
        globals()[name] = value
        return value
    if name in _DEPRECATED:
        module, attribute, replacement = _DEPRECATED[name]
        # not kept: every access warns, from the line that made it
        message = f"sabre.{name} is deprecated and will be removed in the next release; use {replacement}"
        warnings.warn(message, DeprecationWarning, stacklevel=3)
        return _load(module, attribute)
    # Any other submodule, as when `import sabre` imported them all (sabre.errors, sabre.experiments, ...).
    if name.isidentifier() and not name.startswith("__") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if not TYPE_CHECKING:  # a type checker would take every misspelt name for Any; it reads the imports above

    def __getattr__(name: str) -> Any:
        return _resolve(name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
