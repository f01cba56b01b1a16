"""What the bad-input tests share: the shipped URDFs' paths, the public objects every entry point is
called on, and the check that an exception is the documented sabre one."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import sabre
from sabre.errors import SabreError

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT_PATH = ASSETS / "robots" / "royalpanda.urdf"
SHELF_PATH = ASSETS / "objects" / "shelf.urdf"


def make_objs() -> SimpleNamespace:
    """A scene with the shelf and one of each public object built on it."""
    scene = sabre.Scene.load("royalpanda", "shelf")
    model = sabre.RolloutModel(scene)
    plant = sabre.Plant(scene)
    controller = sabre.LowLevelController(scene)
    planner = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=4, horizon=0.06))
    return SimpleNamespace(scene=scene, model=model, plant=plant, controller=controller, planner=planner)


def check(excinfo, cls, *also):
    """The exception is exactly of the documented class family, a SabreError and the extra bases."""
    err = excinfo.value
    assert isinstance(err, cls), f"expected {cls.__name__}, got {type(err).__name__}: {err}"
    assert isinstance(err, SabreError)
    for base in also:
        assert isinstance(err, base)
    assert str(err), "the message must say what was wrong"
