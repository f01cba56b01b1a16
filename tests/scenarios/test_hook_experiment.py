"""The hook experiment (`python -m sabre experiment hook`): the skill read from a phase trace, the
objects it draws, a handle too tight refused before moving, the report's table, and a slip recovered
in closed loop."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import sabre
from sabre import InvalidValueError
from sabre.cli import main
from sabre.experiments import hook
from sabre.experiments.families import random_mesh_spec, random_spec
from sabre.experiments.figures import cpu_name
from sabre.paper import scenarios


def _trace(changes: list[tuple[float, str]], end: float, dt: float = 0.01) -> SimpleNamespace:
    """An episode-like phase trace: phase ``p`` from time ``t`` on, for each (t, p) of ``changes``."""
    phases = ("approach", "insert", "hook", "open", "release")
    time = np.arange(0.0, end, dt)
    index = np.zeros(len(time), dtype=int)
    for t, p in changes:
        index[time >= t - 1e-9] = phases.index(p)
    return SimpleNamespace(time=time, phase=index, phases=phases)


def test_the_skill_of_a_trace_with_one_slip_and_one_re_insert():
    changes = [(0.0, "approach"), (1.0, "insert"), (2.5, "hook"), (3.0, "open"), (5.0, "approach")]
    changes += [(6.0, "insert"), (6.8, "hook"), (7.0, "open")]
    skill = hook.hook_skill(_trace(changes, 9.0))
    assert skill["inserted"] and skill["insert_time"] == pytest.approx(1.5)
    assert skill["slips"] == 1 and skill["reinserts"] == 1
    assert skill["reinsert_times"] == pytest.approx([0.8])
    never = hook.hook_skill(_trace([(0.0, "approach"), (2.0, "insert")], 5.0))
    assert not never["inserted"] and never["insert_time"] is None and never["slips"] == 0


def test_object_i_of_a_family_is_the_ith_drawn_from_the_generator():
    rng = np.random.default_rng(0)
    boxes = [random_spec(rng, i) for i in range(4)]
    rng = np.random.default_rng(0)
    meshes = [random_mesh_spec(rng, i) for i in range(3)]
    assert hook.family_spec("box", 3) == boxes[3] and hook.family_spec("mesh", 2) == meshes[2]
    assert hook.family_spec("box", 3, generator_seed=1) != boxes[3]
    with pytest.raises(InvalidValueError, match="unknown object family"):
        hook.family_spec("glass", 0)


def test_a_handle_too_tight_for_the_hook_is_refused_before_anything_moves(monkeypatch):
    # a 10 mm bar 12 mm in front of the panel: the finger's tip needs more room behind it
    tight = replace(hook.family_spec("box", 0), kind="drawer", bar_size=0.01, standoff=0.012)
    monkeypatch.setattr(hook, "family_spec", lambda *args: tight)
    config = hook.hook_configs(objects=1, families=("box",), variants=("IO",))[0]
    run = hook.hook_run(config, seed=0)
    assert run["outcome"] == "refused" and "mm" in run["refusal"]
    assert run["metrics"]["success"] == 0.0 and run["series"] == {}
    assert "refused" in hook.hook_table([run | {"config": config}])


def test_the_table_counts_openings_slips_and_re_inserts_per_group():
    def record(variant: str, success: bool, slips: int, reinserts: int, outcome: str) -> dict:
        metrics = {"success": float(success), "inserted": 1.0, "insert_time": 2.0, "slips": float(slips)}
        metrics |= {"reinserts": float(reinserts), "reinsert_time": 1.0 if reinserts else float("nan"), "opening_share": 0.5}
        config = {"family": "box", "index": 0, "variant": variant, "robot": "royalpanda"}
        return {"config": config, "metrics": metrics, "outcome": outcome, "handle_class": "standard"}

    rows = [record("IO", True, 1, 1, "opened"), record("IO", True, 0, 0, "opened"), record("IO", False, 2, 1, "slipped")]
    table = hook.hook_table(rows).splitlines()
    skill = next(line for line in table if line.startswith("| box | standard | royalpanda | IO | 2/3"))
    # 3 slips over 2 openings, 2 of the 3 re-inserts hooked again
    assert "| 1.50 | 2/3 |" in skill
    outcomes = table[table.index("") + 3]
    assert outcomes.startswith("| box | standard | royalpanda | IO | 2 | 0 | 0 | 0 | 1 |")


def test_the_command_names_the_cpu_and_rejects_a_robot_without_a_base(tmp_path, capsys):
    assert main(["experiment", "hook", "--robot", "panda_pedestal", "--short", "--out", str(tmp_path)]) == 1
    assert "no mobile base" in capsys.readouterr().err
    args = ["experiment", "hook", "--seeds", "1", "--short", "--objects", "1", "--workers", "1", "--out", str(tmp_path)]
    assert main(args) == 0
    summary = (tmp_path / "hook" / "summary.md").read_text()
    assert "--objects 1" in summary and cpu_name() in summary
    for family in hook.FAMILIES:
        for variant in ("N", "IO"):
            assert sum(line.startswith(f"| {family} |") and f"| {variant} |" in line for line in summary.splitlines()) == 2


def test_a_door_jerked_out_of_the_hook_is_hooked_again_and_opened():
    """Once the shelf is 0.1 rad open, the door is jerked 0.15 rad further (someone pulls it): the bar
    leaves the pocket, the task goes back to reaching, inserts and hooks again as fast as the first
    time at most twice over, and opens the door."""
    scene = sabre.Scene.load(obj="shelf")
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant="IO", seed=0))
    jerked = []

    def jerk(t, x, plant, ctrl):
        if not jerked and ctrl.phase == "open" and x[2 * scene.nq] > 0.1:
            moved = plant.state.copy()
            moved[2 * scene.nq] += 0.15
            moved[2 * scene.nq + scene.no :] = 0.0
            plant.reset(moved)
            jerked.append(t)
        return False

    episode = sabre.run_episode(scene, controller, 40.0, seed=0, x0=scene.start_state(), on_replan=jerk, progress=False)
    skill = hook.hook_skill(episode)
    assert jerked and episode.success
    assert skill["inserted"] and skill["slips"] == 1 and skill["reinserts"] == 1
    assert skill["reinsert_times"][0] <= 2.0 * skill["insert_time"]


def test_the_held_door_is_held_by_the_hook_and_opens_once_released():
    """The paper's stuck door (IO): held at 0.2 rad for 5 s, the hand keeps the bar in the pocket,
    in contact for at least 90 % of the hold and never back to reaching; released, the door opens."""
    door = scenarios.stuck_door("IO", seed=0)
    ep = door.episode
    hold = (ep.time >= door.hold_start) & (ep.time <= door.hold_start + door.hold_seconds)
    phases = np.array([ep.phases[p] for p in ep.phase])
    assert door.held and np.mean(np.asarray(ep.contact, bool)[hold]) >= 0.9
    assert set(phases[hold]) <= {"open", "hold"} and "hold" in set(phases[hold])
    assert door.opening_after_release > 0.5
