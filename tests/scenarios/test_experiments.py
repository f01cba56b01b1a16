"""Tests of the experiments command: run identity and caching, resuming, the process pool and Ray
giving the same runs, Fig. 3's weights against a NumPy re-implementation, and a one-seed smoke run
of every experiment with short durations."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import sabre
from sabre import experiments
from sabre.experiments import NAMES, run_experiments, run_one, specs


def test_run_key_is_a_function_of_experiment_config_and_seed():
    a = specs("fig12", 2, short=True)
    assert len({s.key for s in a}) == len(a)
    assert [s.key for s in a] == [s.key for s in specs("fig12", 2, short=True)]
    assert {s.key for s in specs("fig12", 1, short=True)}.isdisjoint({s.key for s in specs("fig12", 1, short=False)})


def test_fig3_invariant_weights_match_numpy_and_do_not_depend_on_the_cost_scale():
    runs = {(s.options["mapping"], s.options["scale"]): run_one(s) for s in specs("fig3", 1, short=True)}
    costs = np.sort(np.random.default_rng(0).gamma(2.0, 5.0, size=64) + 10.0)
    h = 10.0
    expected = np.exp(-h * (costs - costs.min()) / (costs.max() - costs.min()))
    expected /= expected.sum()
    for scale in (1.0, 1000.0):
        np.testing.assert_allclose(runs["invariant", scale]["series"]["weights"]["y"], expected, rtol=1e-12)
    # exp(−λJ) underflows to all-zero weights once every cost is large
    assert runs["naive", 1000.0]["metrics"]["effective_samples"] == 0.0
    assert runs["naive", 1.0]["metrics"]["effective_samples"] > 1.0


def test_command_writes_csv_figure_summary_and_reuses_cached_runs(tmp_path, monkeypatch):
    records = run_experiments("fig3", seeds=2, workers=1, out=tmp_path, short=True)["fig3"]
    folder = tmp_path / "fig3"
    assert (folder / "fig3.png").stat().st_size > 10_000
    rows = list(csv.DictReader(open(folder / "runs.csv")))
    assert len(rows) == len(records) == len(specs("fig3", 2, short=True))
    assert {r["seed"] for r in rows} == {"0", "1"}
    text = (folder / "summary.md").read_text()
    assert "effective_samples" in text and "Paper:" in text

    calls = []

    def counting(spec):
        calls.append(spec)
        return run_one(spec)

    monkeypatch.setattr(experiments.runner, "run_one", counting)
    # an interrupted sweep: one run's result is missing; only that run is computed again
    victim = specs("fig3", 2, short=True)[3]
    (folder / "runs" / f"{victim.key}.json").unlink()
    again = run_experiments("fig3", seeds=2, workers=1, out=tmp_path, short=True)["fig3"]
    assert calls == [victim]
    assert again == records


def test_process_pool_gives_the_same_runs_as_one_process(tmp_path):
    one = run_experiments("fig12", seeds=1, workers=1, out=tmp_path / "a", short=True)["fig12"]
    pool = run_experiments("fig12", seeds=1, workers=2, out=tmp_path / "b", short=True)["fig12"]
    assert json.dumps(one, sort_keys=True) == json.dumps(pool, sort_keys=True)


def test_ray_on_a_local_two_worker_instance_gives_the_same_runs(tmp_path):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = run_experiments("fig3", seeds=1, ray_address="auto", out=tmp_path / "ray", short=True)["fig3"]
    finally:
        ray.shutdown()
    local = run_experiments("fig3", seeds=1, workers=1, out=tmp_path / "local", short=True)["fig3"]
    assert json.dumps(remote, sort_keys=True) == json.dumps(local, sort_keys=True)


def test_unknown_experiment_and_zero_seeds_are_rejected(tmp_path):
    with pytest.raises(sabre.InvalidValueError):
        run_experiments("fig99", seeds=1, out=tmp_path)
    with pytest.raises(sabre.InvalidValueError):
        run_experiments("fig3", seeds=0, out=tmp_path)


@pytest.mark.parametrize("name", [n for n in NAMES if n != "fig3"])
def test_every_experiment_runs_at_one_seed_with_short_durations(name, tmp_path):
    records = run_experiments(name, seeds=1, workers=1, out=tmp_path, short=True)[name]
    assert len(records) == len(specs(name, 1, short=True))
    for r in records:
        assert all(isinstance(v, float) for v in r["metrics"].values())
    assert (tmp_path / name / f"{name}.png").is_file()
    if name in ("fig4", "fig12"):
        # the tank never goes (materially) below its floor ε = 2 J
        assert min(min(r["series"]["tank"]["y"]) for r in records) > 2.0 - 1e-3


def test_experiment_command_line_writes_the_results_folder(tmp_path):
    from sabre.cli import main

    assert main(["experiment", "fig3", "--seeds", "1", "--short", "--workers", "1", "--out", str(tmp_path)]) == 0
    assert {p.name for p in (tmp_path / "fig3").iterdir()} >= {"runs", "runs.csv", "fig3.png", "summary.md"}
