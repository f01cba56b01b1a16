"""Picklable controller factories for the planner-process tests (a spawned process imports them)."""

from __future__ import annotations

import sabre


def open_shelf(variant: str = "IO", seed: int = 3, rollouts: int = 16) -> sabre.Controller:
    scene = sabre.Scene.load(obj="shelf")
    return sabre.Controller(
        scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant=variant, rollouts=rollouts, seed=seed, threads=1)
    )


def broken() -> sabre.Controller:
    raise RuntimeError("this factory cannot build a controller")
