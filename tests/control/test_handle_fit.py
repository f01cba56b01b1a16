"""The hook's targets fitted to a handle's geometry, from Python: a bar on short standoffs opened in
closed loop, the refusal of a gap too tight for the tool, and the fit reported and turned off."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre import tasks
from sabre.experiments.families import ObjectSpec, scene_of


def door(bar: float, standoff: float, vertical: bool = True, kind: str = "door") -> ObjectSpec:
    """A box-family object 2.5 m ahead, its bar `bar` thick on standoffs `standoff` long (m)."""
    return ObjectSpec(
        index=0,
        kind=kind,
        width=0.45,
        handle_height=0.7,
        hinge_left=True,
        vertical_bar=vertical,
        bar_shape="box",
        damping_scale=1.0,
        friction_scale=1.0,
        mass_scale=1.0,
        distance=2.5,
        bearing=0.0,
        facing=0.2,
        bar_size=bar,
        standoff=standoff,
    )


def test_a_thick_bar_on_short_standoffs_is_hooked_and_opened_in_closed_loop():
    """A 20 mm bar on 20 mm standoffs: the configured insert depth would put the tip into the door, so
    the fit moves it out; the controller inserts, hooks and opens the door from the default start."""
    spec = door(0.02, 0.02)
    scene = scene_of(spec)
    task = tasks.OpenObject(handle=spec.handle_link)
    fit = task.handle_fit(scene)
    assert fit is not None
    # measured against the sizes written into the object (the frame's origin at the bar's centre)
    assert fit["bar_back"] == pytest.approx(0.01, abs=1e-6) and fit["gap"] == pytest.approx(0.02, abs=1e-6)
    assert fit["need"] <= fit["gap"] and fit["insert"][2] < task.approach.insert_offset[2]
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(variant="N", seed=0, threads=1))
    episode = sabre.run_episode(scene, controller, 30.0, seed=0, x0=scene.default_state(), progress=False)
    phases = [episode.phases[p] for p in episode.phase]
    assert "open" in phases and episode.success, sorted(set(phases))
    assert np.all(np.isfinite(episode.state))


def test_a_gap_too_tight_for_the_hook_is_refused_before_anything_moves_with_both_sizes():
    spec = door(0.014, 0.012, vertical=False, kind="drawer")
    scene = scene_of(spec)
    task = tasks.OpenObject(handle=spec.handle_link)
    with pytest.raises(sabre.InvalidValueError, match=r"12\.0 mm deep.*needs 1\d\.\d mm"):
        sabre.Controller(scene, task, sabre.ControllerConfig(variant="N", seed=0, threads=1))
    # the user's own targets, unmeasured, are taken as given
    given = tasks.OpenObject(handle=spec.handle_link, approach=tasks.ApproachConfig(fit_clearance=None))
    assert given.handle_fit(scene) is None
    sabre.Controller(scene, given, sabre.ControllerConfig(variant="N", seed=0, threads=1))


def test_the_shipped_objects_keep_the_configured_targets_and_the_task_steers_to_the_fitted_ones():
    scene = sabre.Scene.load("royalpanda", "shelf")
    task = tasks.OpenObject()
    fit = task.handle_fit(scene)
    assert fit["insert"] == list(task.approach.insert_offset) and fit["pitch"] == task.approach.pitch
    moved = scene_of(door(0.02, 0.02))
    short = tasks.OpenObject(handle="grip_0")
    fitted = short.handle_fit(moved)
    # the cost's target is the fitted pose: its depth is the fit's, not the configured one
    assert short.grasp_offset(moved, "insert")[2, 3] == pytest.approx(fitted["insert"][2])
    with pytest.raises(sabre.InvalidValueError, match="fit_clearance"):
        tasks.ApproachConfig(fit_clearance=-0.001)
