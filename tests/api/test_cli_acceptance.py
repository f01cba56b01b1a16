"""The acceptance experiment: `python -m sabre experiment acceptance` and experiments/acceptance.py run the
same runs through the same runner and cache, and its table says what opened, when and how."""

from __future__ import annotations

import json
import math
import runpy
from pathlib import Path

import pytest

import sabre
from sabre.experiments import runner
from sabre.experiments.figures import acceptance_table, summary
from sabre.experiments.runner import acceptance_specs, specs

SCRIPT = Path(__file__).resolve().parents[2] / "experiments" / "acceptance.py"


def test_the_script_defaults_are_the_command_runs():
    command = specs("acceptance", 3, short=False)
    assert [s.key for s in acceptance_specs(range(3))] == [s.key for s in command]
    assert {s.options["obj"] for s in command} == set(sabre.OBJECTS)
    assert {(s.options["variant"], s.options["duration"], s.options["replan_rate"]) for s in command} == {("IO", 60.0, 50.0)}
    assert {s.options["duration"] for s in specs("acceptance", 1, short=True)} == {8.0}


def test_unknown_objects_or_variants_are_rejected():
    with pytest.raises(sabre.InvalidValueError, match="cupboard"):
        acceptance_specs(range(1), objects=["cupboard"])
    with pytest.raises(sabre.InvalidValueError, match="'X'"):
        acceptance_specs(range(1), variants=["X"])


def test_the_samples_per_iteration_reach_the_controller_and_a_run_of_their_own(monkeypatch):
    from sabre.experiments import scenarios

    (default,) = acceptance_specs([0], objects=["drawer"], variants=["N"], duration=0.03)
    (more,) = acceptance_specs([0], objects=["drawer"], variants=["N"], duration=0.03, rollouts=16)
    assert "rollouts" not in default.options and more.options["rollouts"] == 16 and more.key != default.key
    built = []

    class Recording(scenarios.Controller):
        def __init__(self, scene, task, config):
            built.append(config.rollouts)
            super().__init__(scene, task, config)

    monkeypatch.setattr(scenarios, "Controller", Recording)
    runner.run_one(more)
    runner.run_one(default)
    assert built == [16, sabre.ControllerConfig().rollouts]
    with pytest.raises(sabre.InvalidValueError, match="rollouts"):
        acceptance_specs(range(1), rollouts=0)


def test_script_runs_caches_and_tabulates_and_a_second_call_reuses_the_runs(tmp_path, capsys, monkeypatch):
    script = runpy.run_path(str(SCRIPT))
    argv = [
        "--objects",
        "drawer",
        "--variant",
        "N",
        "--seeds",
        "1",
        "--first-seed",
        "4",
        "--duration",
        "0.2",
        "--workers",
        "1",
        "--out",
        str(tmp_path),
    ]
    script["main"](argv)
    table = capsys.readouterr().out
    assert "| drawer | N | 0/1 | — | 0.000 (0.371) |" in table  # 0.2 s from the paper's start: nowhere near the handle
    assert table.rstrip().endswith("| 4 |")  # the seed that did not open

    (spec,) = acceptance_specs([4], objects=["drawer"], variants=["N"], duration=0.2)
    record = json.loads((tmp_path / "acceptance" / "runs" / f"{spec.key}.json").read_text())
    metrics = record["metrics"]
    scene, task = sabre.Scene.load(obj="drawer"), sabre.tasks.OpenObject()
    assert metrics["needed_opening"] == pytest.approx(task.open.success_fraction * task.target_opening(scene))
    assert metrics["success"] == 0.0 and math.isnan(metrics["time_to_success"])
    assert metrics["slips"] == metrics["releases"] == 0.0 and metrics["planning_ms_median"] > 0.0
    assert len(record["series"]["opening"]["t"]) > 10

    calls = []
    monkeypatch.setattr(runner, "run_one", lambda s: calls.append(s) or {})
    script["main"](argv)
    assert calls == [] and capsys.readouterr().out == table


def _record(obj: str, variant: str, seed: int, success: bool, when: float, opening: float) -> dict:
    metrics = {
        "success": float(success),
        "time_to_success": when if success else math.nan,
        "final_opening": opening,
        "needed_opening": 1.06,
        "mean_wrench": 20.0 + seed,
        "slips": 0.0,
        "releases": 0.0,
        "real_time_factor": 1.0 + 0.1 * seed,
        "planning_ms_median": 10.0 * (seed + 1),
    }
    return {
        "name": "acceptance",
        "config": {"obj": obj, "variant": variant, "duration": 60.0, "replan_rate": 50.0},
        "seed": seed,
        "metrics": metrics,
        "series": {},
    }


def test_table_counts_openings_with_their_times_and_names_the_seeds_that_did_not_open():
    records = [
        _record("shelf", "IO", 0, True, 11.0, 1.30),
        _record("shelf", "IO", 1, False, 0.0, 0.20),
        _record("shelf", "IO", 2, True, 14.0, 1.28),
        _record("shelf", "N", 0, True, 12.0, 1.40),
    ]
    rows = acceptance_table(records).splitlines()
    assert rows[0].startswith("| object | variant | opened | time to open (median, max) |")
    # medians over the three IO seeds: opening 1.28, wrench 21 N, real-time factor 1.1, planning 20 ms
    assert rows[2] == "| shelf | IO | 2/3 | 12.5 s, 14.0 s | 1.280 (1.060) | 21.0 N | 1.10 | 20.0 ms | 1 |"
    assert rows[3] == "| shelf | N | 1/1 | 12.0 s, 12.0 s | 1.400 (1.060) | 20.0 N | 1.00 | 10.0 ms | — |"
    assert acceptance_table(records) in summary("acceptance", records, seeds=3, short=False)
