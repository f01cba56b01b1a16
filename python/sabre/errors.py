"""The exception hierarchy of sabre: every error the library raises derives from :class:`SabreError`; and
the warnings it gives."""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = [
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
    "DISTRIBUTION",
    "require_extra",
]

#: The name of sabre's distribution on PyPI, which the extras belong to: ``pip install 'sabre-mpc[plot]'``.
DISTRIBUTION = "sabre-mpc"


class SabreError(Exception):
    """Base class of every exception raised by sabre."""


class ShapeError(SabreError, ValueError):
    """An array has the wrong shape or dtype."""


class InvalidValueError(SabreError, ValueError):
    """A value is NaN, infinite or outside its admissible range."""


class UnknownAssetError(SabreError, LookupError):
    """A built-in robot or object name that does not exist."""


class UrdfError(SabreError):
    """A URDF file is missing, unreadable, malformed or uses unsupported features."""


class UnknownFrameError(SabreError, KeyError):
    """A frame (link) name the scene does not have."""

    def __str__(self) -> str:  # KeyError would otherwise quote the message
        return str(self.args[0]) if self.args else ""


class SimulationError(SabreError, RuntimeError):
    """The physics engine failed or produced non-finite numbers."""


class MissingExtraError(SabreError, ImportError):
    """An optional feature needs a pip extra that is not installed (the message names it)."""


class PlannerError(SabreError, RuntimeError):
    """The planner running apart from the inner loop (a thread or a process) failed or stopped."""


class AssumedInertialWarning(UserWarning):
    """A moving object link has no complete ``<inertial>``: sabre filled in its mass and inertia from
    its collision geometry (:attr:`sabre.Scene.assumed_inertials` lists the values). Silence it with
    ``warnings.simplefilter("ignore", sabre.errors.AssumedInertialWarning)`` once they are checked."""


def require_extra(extra: str, purpose: str, *modules: str) -> list[ModuleType]:
    """Imports ``modules`` and returns them; if one is missing, raises :class:`MissingExtraError` saying
    that ``purpose`` needs the extra ``extra`` and which module was missing.

    The one way every optional feature of sabre asks for its extra, so that the message always names the
    distribution's extra (``pip install 'sabre-mpc[extra]'``)."""
    loaded = []
    for name in modules:
        try:
            loaded.append(importlib.import_module(name))
        except ImportError as exc:
            raise MissingExtraError(
                f"{purpose} needs the optional extra: pip install '{DISTRIBUTION}[{extra}]' (missing: {exc.name or name})"
            ) from exc
    return loaded
