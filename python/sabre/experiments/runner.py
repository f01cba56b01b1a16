"""The paper's experiments as one command: runs over seeds (local process pool or Ray), cached by a
hash of (experiment, configuration, seed), with per-seed CSV, the figure as PNG and ``summary.md``.

Every run is a pure function :func:`run_one` of (experiment, configuration, seed); its result is a
JSON file ``results/<name>/runs/<hash>.json``, so an interrupted sweep resumes where it stopped.
``short=True`` shortens every episode (smoke tests); short and full runs never share a cache entry.
``plant="module:factory"`` runs every episode on ``factory(scene)`` (a :class:`~sabre.PlantInterface`) instead of
the Rapier plant; the name is part of each run's configuration, so those runs are cached apart.
"""

from __future__ import annotations

import csv
import hashlib
import importlib
import itertools
import json
import os
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._validate import as_count
from ..errors import InvalidValueError, require_extra
from ..scene import OBJECTS

__all__ = [
    "NAMES",
    "RunSpec",
    "run_one",
    "run_experiments",
    "run_specs",
    "specs",
    "acceptance_specs",
    "transfer_specs",
    "hook_specs",
]

NAMES: tuple[str, ...] = ("fig3", "fig4", "fig8", "fig10", "fig11", "fig12", "acceptance", "transfer", "hook", "unknown")
#: objects per family of the hook experiment: the full run's and the short (smoke test) run's
_HOOK_OBJECTS = (40, 2)
_SERIES_POINTS = 400


@dataclass(frozen=True)
class RunSpec:
    """One run: experiment name, configuration (JSON-able dict, sorted keys) and seed."""

    name: str
    config: tuple
    seed: int

    @property
    def options(self) -> dict:
        return dict(self.config)

    @property
    def key(self) -> str:
        text = json.dumps({"name": self.name, "config": self.options, "seed": self.seed}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _spec(name: str, seed: int, **config: object) -> RunSpec:
    return RunSpec(name, tuple(sorted(config.items())), int(seed))


def _on_plant(runs: list[RunSpec], plant: str | None) -> list[RunSpec]:
    """``runs`` on the plant ``plant`` ("module:factory") names; as they are for None (the Rapier plant)."""
    if plant is None:
        return runs
    _plant_factory(plant)  # a name that does not resolve fails here, before any run
    return [_spec(r.name, r.seed, **r.options, plant=plant) for r in runs]


def _plant_factory(plant: str | None) -> Callable | None:
    """The callable ``plant`` names as "module:attribute" (None for None)."""
    if plant is None:
        return None
    module, _, attribute = str(plant).partition(":")
    try:
        factory = getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError, ValueError) as exc:
        raise InvalidValueError(f"plant must name a factory as 'module:attribute', got {plant!r} ({exc})") from None
    if not callable(factory):
        raise InvalidValueError(f"plant: {plant!r} is not callable")
    return factory


def specs(
    name: str, seeds: int, short: bool, plant: str | None = None, robot: str = "royalpanda", objects: int | None = None
) -> list[RunSpec]:
    """Every run of one experiment (on the plant ``plant`` names, "module:factory"; None: the Rapier plant;
    ``robot``: the acceptance's and the hook experiment's robot, the other experiments are the
    RoyalPanda's; ``objects``: the hook and unknown experiments' objects per family, None: 40 and 20, 2 and 0 if short)."""
    if name == "acceptance":
        return acceptance_specs(range(seeds), duration=8.0 if short else 60.0, plant=plant, robot=robot)
    if name == "hook":
        count = _HOOK_OBJECTS[bool(short)] if objects is None else objects
        return _on_plant(hook_specs(range(seeds), objects=count, robot=robot, duration=8.0 if short else 60.0), plant)
    if robot != "royalpanda":
        raise InvalidValueError(f"experiment {name!r} runs on the RoyalPanda; only acceptance and hook take another robot")
    if name == "unknown":
        from .unknown import unknown_configs

        count = (0 if short else 20) if objects is None else objects
        # short: a smoke test of every mode on a door and a drawer
        smoke = {"builtins": ("shelf", "drawer"), "variants": ("N",)} if short else {}
        configs = unknown_configs(objects=count, duration=8.0 if short else 60.0, **smoke)
        return _on_plant([_spec(name, seed, **c) for c in configs for seed in range(seeds)], plant)
    if name == "transfer":
        # its runs name their own plants (sabre's and MuJoCo's), so `plant` does not apply; short: a smoke test
        # of every object, variant and plant, nominal damping only
        return transfer_specs(range(seeds), duration=1.0, scales=(1.0,)) if short else transfer_specs(range(seeds))
    runs = _specs(name, seeds, short)
    return runs if name == "fig3" else _on_plant(runs, plant)  # the weights of fig3 need no plant


def _specs(name: str, seeds: int, short: bool) -> list[RunSpec]:
    """Every run of one experiment on the Rapier plant."""
    out: list[RunSpec] = []
    for seed in range(seeds):
        if name == "fig3":
            out += [
                _spec(name, seed, mapping=m, parameter=p, scale=k)
                for m, p in (("naive", 0.2), ("baseline", 0.2), ("invariant", 10.0))
                for k in (1.0, 1000.0)
            ]
        elif name == "fig4":
            out.append(_spec(name, seed, variant="IO", driver="scripted", hold=3.0 if short else 5.0))
        elif name == "fig8":
            out += [_spec(name, seed, variant=v, duration=8.0 if short else 60.0) for v in ("N", "I", "O", "IO")]
        elif name == "fig10":
            out += [_spec(name, seed, variant=v, duration=4.0 if short else 6.0) for v in ("N", "IO")]
        elif name == "fig11":
            # short: the scripted pull with the tank starting near its floor, so that it binds within the hold
            out += [
                _spec(
                    name,
                    seed,
                    variant=v,
                    driver="scripted" if short else "controller",
                    hold=3.0 if short else 5.0,
                    release=0.5 if short else 10.0,
                    tank_initial=2.5 if short else 10.0,
                )
                for v in ("N", "IO")
            ]
        elif name == "fig12":
            out += [
                _spec(
                    name,
                    seed,
                    alpha=a,
                    driver="scripted" if short else "controller",
                    hold=1.5 if short else 5.0,
                    tank_initial=2.5,
                )
                for a in (1.0, 1000.0)
            ]
        else:
            raise InvalidValueError(f"unknown experiment {name!r}; one of {NAMES}")
    return out


def acceptance_specs(
    seeds: Iterable[int],
    *,
    objects: Sequence[str] = OBJECTS,
    variants: Sequence[str] = ("IO",),
    duration: float = 60.0,
    replan_rate: float = 50.0,
    plant: str | None = None,
    robot: str = "royalpanda",
    rollouts: int | None = None,
) -> list[RunSpec]:
    """The acceptance runs: every object opened from the robot's start by every variant at every seed,
    for up to ``duration`` s of simulated time, re-planning at ``replan_rate`` Hz (on the plant ``plant``
    names, "module:factory"; None: the Rapier plant). ``robot``: the RoyalPanda (the paper's start) or
    an example robot (:data:`sabre.robot_examples.EXAMPLE_ROBOTS`), which opens its own objects
    (``objects`` defaults to them). ``rollouts``: samples per iteration (None: the controller's
    default)."""
    from ..planner import VARIANTS
    from ..robot_examples import EXAMPLE_OBJECTS

    if robot != "royalpanda" and robot not in EXAMPLE_OBJECTS:
        raise InvalidValueError(f"acceptance: unknown robot {robot!r}; royalpanda or one of {list(EXAMPLE_OBJECTS)}")
    known = OBJECTS if robot == "royalpanda" else tuple(EXAMPLE_OBJECTS[robot])
    if robot != "royalpanda" and tuple(objects) == OBJECTS:
        objects = known
    unknown = [o for o in objects if o not in known] + [v for v in variants if v not in VARIANTS]
    if unknown:
        raise InvalidValueError(f"acceptance: unknown objects or variants {unknown}; objects {known}, variants {VARIANTS}")
    # the RoyalPanda's runs keep the configuration (and so the cache entries) they always had
    mounted: dict[str, object] = {} if robot == "royalpanda" else {"robot": robot}
    if rollouts is not None:
        mounted["rollouts"] = as_count("rollouts", rollouts)
    runs = [
        _spec("acceptance", seed, obj=o, variant=v, duration=float(duration), replan_rate=float(replan_rate), **mounted)
        for o in objects
        for v in variants
        for seed in seeds
    ]
    return _on_plant(runs, plant)


def transfer_specs(seeds: Iterable[int], **options: Any) -> list[RunSpec]:
    """The transfer runs (:mod:`sabre.experiments.transfer`) at every seed; ``options`` are those of
    :func:`~sabre.experiments.transfer.transfer_configs` (objects, variants, simulators, scales, duration, ...)."""
    from .transfer import transfer_configs

    return [_spec("transfer", seed, **config) for config in transfer_configs(**options) for seed in seeds]


def hook_specs(seeds: Iterable[int], **options: Any) -> list[RunSpec]:
    """The hook experiment's runs (:mod:`sabre.experiments.hook`) at every seed; ``options`` are those of
    :func:`~sabre.experiments.hook.hook_configs` (objects, families, variants, robot, duration, fit, ...)."""
    from .hook import hook_configs

    return [_spec("hook", seed, **config) for config in hook_configs(**options) for seed in seeds]


def _window_share(flags: np.ndarray, width: int) -> np.ndarray:
    """The share of the ``width`` samples around each sample that are set (1.0 for a 0/1 series)."""
    if len(flags) == 0:
        return flags
    return np.convolve(flags, np.ones(width) / width, mode="same")


def _series(t: np.ndarray, y: np.ndarray) -> dict:
    idx = np.linspace(0, len(t) - 1, min(len(t), _SERIES_POINTS)).round().astype(int) if len(t) else []
    return {"t": np.asarray(t)[idx].tolist(), "y": np.asarray(y)[idx].tolist()}


# long: one branch per experiment, each a few lines that turn its scenario's result into the record
def run_one(spec: RunSpec) -> dict:
    """Runs one experiment configuration at one seed; returns scalar ``metrics`` and plot ``series``."""
    from ..planner import likelihood_weights
    from . import scenarios
    from .hook import hook_run

    c, seed = spec.options, spec.seed
    plant = _plant_factory(c.get("plant"))
    if spec.name == "fig3":
        # the same rollouts with costs scaled by `scale`: (55) gives the same weights, exp(−λJ) does not
        costs = c["scale"] * np.sort(np.random.default_rng(seed).gamma(2.0, 5.0, size=64) + 10.0)
        w = likelihood_weights(costs, c["mapping"], c["parameter"])
        ess = float(1.0 / np.sum(w**2)) if w.sum() > 0 else 0.0
        return {
            "metrics": {"effective_samples": ess, "max_weight": float(w.max())},
            "series": {"weights": {"t": list(range(len(w))), "y": w.tolist()}},
        }
    if spec.name in ("fig4", "fig11", "fig12"):
        variant = c.get("variant", "IO")
        door = scenarios.stuck_door(
            variant,
            seed,
            c["hold"],
            c.get("release", 0.5),
            alpha=c.get("alpha", 1.0),
            driver=c["driver"],
            tank_initial=c.get("tank_initial", 10.0),
            plant=plant,
        )
        ep = door.episode
        force = np.linalg.norm(ep.wrench[:, :3], axis=1)
        return {
            "metrics": {
                "mean_wrench_stuck": float(door.mean_wrench_stuck),
                "tank_min": float(door.tank_min),
                "opening_after_release": float(door.opening_after_release),
                "power_sign_changes_per_s": float(door.power_sign_changes_per_s),
                "hold_start": float(door.hold_start),
            },
            "series": {
                "tank": _series(ep.time - door.hold_start, door.tank_energy),
                "wrench": _series(ep.time - door.hold_start, force),
                "contact": _series(ep.time - door.hold_start, _window_share(np.asarray(ep.contact, dtype=float), 100)),
            },
        }
    if spec.name == "acceptance":
        return _acceptance_run(c, seed, plant)
    if spec.name in ("transfer", "hook"):
        return _transfer_run(c, seed) if spec.name == "transfer" else hook_run(c, seed, plant)
    if spec.name == "unknown":
        from .unknown import unknown_run

        return unknown_run(c, seed, plant)
    if spec.name == "fig8":
        manipulation = scenarios.object_manipulation(c["variant"], "shelf", seed, c["duration"], plant=plant)
        ep = manipulation.episode
        metrics = {
            "success": float(manipulation.success),
            "final_opening": float(ep.opening[-1]),
            **{f"violation_{k}": float(v) for k, v in manipulation.violations.items()},
        }
        return {"metrics": metrics, "series": {"opening": _series(ep.time, ep.opening)}}
    if spec.name == "fig10":
        corridor = scenarios.obstacle_corridor(c["variant"], seed, c["duration"], plant=plant)
        ep = corridor.episode
        q = ep.scene.split_state(ep.state).q
        hand = ep.scene.fk_many(q, ep.scene.require_tool_frame("fig10"))[:, :3, 3]
        base = ep.scene.fk_many(q, ep.scene.base_link)[:, :3, 3]
        # the scenario's obstacle sits half-way between the start and the target 0.5 m to the side
        centre = hand[0] + 0.5 * np.array([-0.15, 0.5, 0.0])
        appeared = corridor.appeared_at
        return {
            "metrics": {
                "cartesian_violation": float(corridor.cartesian_violation),
                "reached": float(corridor.reached),
                "appeared_at": float("nan") if appeared is None else float(appeared),
            },
            "series": {
                "hand_xy": _series(hand[:, 0], hand[:, 1]),
                "base_xy": _series(base[:, 0], base[:, 1]),
                "obstacle": {"t": [float(centre[0])], "y": [float(centre[1])]},
            },
        }
    raise InvalidValueError(f"unknown experiment {spec.name!r}")


def _transfer_run(c: dict, seed: int) -> dict:
    """One transfer episode's metrics and opening; a plant that fails (a SabreError) is a run that did not open."""
    from ..errors import SabreError
    from .transfer import transfer_episode, transfer_metrics

    try:
        ep = transfer_episode(c, seed)
    except SabreError as exc:
        return {"metrics": transfer_metrics(None), "series": {}, "error": str(exc)}
    return {"metrics": transfer_metrics(ep), "series": {"opening": _series(ep.time, ep.opening)}}


def _acceptance_run(c: dict, seed: int, plant: Callable | None = None) -> dict:
    """One acceptance episode: whether and when it opened, how hard it pushed, how often the hook
    slipped off (open back to approach) or let go (into release), and how fast it ran."""
    from . import scenarios

    run = scenarios.object_manipulation(
        c["variant"],
        c["obj"],
        seed,
        c["duration"],
        replan_rate=c["replan_rate"],
        plant=plant,
        robot=c.get("robot", "royalpanda"),
        rollouts=c.get("rollouts"),
    )
    ep = run.episode
    phases = [ep.phases[i] for i in ep.phase]
    transitions = list(itertools.pairwise(phases))
    needed = ep.success_opening
    metrics = {
        "success": float(ep.success),
        "time_to_success": float("nan") if ep.time_to_success is None else float(ep.time_to_success),
        "final_opening": float(ep.opening[-1]),
        "needed_opening": float("nan") if needed is None else float(needed),
        "mean_wrench": float(ep.mean_wrench()),
        "slips": float(sum(1 for a, b in transitions if a in ("open", "hold") and b == "approach")),
        "releases": float(sum(1 for a, b in transitions if a != "release" and b == "release")),
        "real_time_factor": float(ep.real_time_factor),
        "planning_ms_median": 1e3 * float(np.median(ep.planning_times)),
    }
    return {"metrics": metrics, "series": {"opening": _series(ep.time, ep.opening)}}


def _cached(spec: RunSpec, folder: Path) -> dict | None:
    path = folder / "runs" / f"{spec.key}.json"
    if path.is_file():
        return json.loads(path.read_text())
    return None


def _store(spec: RunSpec, folder: Path, result: dict) -> dict:
    record = {"name": spec.name, "config": spec.options, "seed": spec.seed, **result}
    path = folder / "runs" / f"{spec.key}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record))
    os.replace(tmp, path)  # a run is either fully cached or not at all
    return record


def _execute(todo: list[RunSpec], folder: Path, workers: int | None, ray_address: str | None) -> list[dict]:
    (tqdm_module,) = require_extra("experiments", "the experiments", "tqdm")
    tqdm = tqdm_module.tqdm
    done = []
    bar = tqdm(total=len(todo), desc=folder.name, unit="run")
    if ray_address is not None:
        (ray,) = require_extra("experiments", "--ray", "ray")
        if not ray.is_initialized():
            ray.init(address=ray_address, ignore_reinit_error=True, log_to_driver=False)
        remote = ray.remote(run_one)
        pending = {remote.remote(s): s for s in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                done.append(_store(pending.pop(ref), folder, ray.get(ref)))
                bar.update(1)
    elif workers == 1 or len(todo) <= 1:
        for s in todo:
            done.append(_store(s, folder, run_one(s)))
            bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(run_one, s): s for s in todo}
            for f in as_completed(futures):
                done.append(_store(futures[f], folder, f.result()))
                bar.update(1)
    bar.close()
    return done


def run_experiments(
    name: str,
    *,
    seeds: int = 2,
    workers: int | None = None,
    ray_address: str | None = None,
    out: str | os.PathLike[str] = "results",
    short: bool = False,
    plant: str | None = None,
    robot: str = "royalpanda",
    objects: int | None = None,
) -> dict[str, list[dict]]:
    """Runs ``name`` (one of :data:`NAMES` or "all") over ``seeds`` seeds, reusing cached runs, and
    writes ``<out>/<name>/runs.csv``, ``<name>.png`` and ``summary.md``. Returns the run records.
    ``plant``: "module:factory" naming a callable that builds the plant of a scene (a
    :class:`~sabre.PlantInterface`, e.g. a class taking the scene); None: the Rapier plant.
    ``robot`` other than the RoyalPanda: the acceptance (or the hook experiment) of that example robot, in
    ``<out>/<name>_<robot>/``. ``objects``: the hook experiment's objects per family (None: 40, 2 if short)."""
    if int(seeds) < 1:
        raise InvalidValueError(f"seeds must be at least 1, got {seeds}")
    names = NAMES if name == "all" else (name,)
    records = {}
    for n in names:
        folder = Path(out) / (n if robot == "royalpanda" else f"{n}_{robot}")
        runs = specs(n, int(seeds), short, plant, robot, objects)
        ordered = run_specs(runs, folder, workers=workers, ray_address=ray_address)
        records[n] = ordered
        _write_csv(folder / "runs.csv", ordered)
        from .figures import draw, summary

        draw(n, ordered, folder / f"{n}.png")
        (folder / "summary.md").write_text(summary(n, ordered, seeds=int(seeds), short=short))
    return records


def run_specs(
    runs: Sequence[RunSpec], folder: str | os.PathLike[str], *, workers: int | None = None, ray_address: str | None = None
) -> list[dict]:
    """The records of ``runs``, in their order: read from ``<folder>/runs/`` where cached, computed
    (and cached) otherwise."""
    folder = Path(folder)
    cached = {s.key: _cached(s, folder) for s in runs}
    todo = [s for s in runs if cached[s.key] is None]
    fresh = {(r["seed"], json.dumps(r["config"], sort_keys=True)): r for r in _execute(todo, folder, workers, ray_address)}
    return [cached[s.key] or fresh[(s.seed, json.dumps(s.options, sort_keys=True))] for s in runs]


def _write_csv(path: Path, records: list[dict]) -> None:
    config_keys = sorted({k for r in records for k in r["config"]})
    metric_keys = sorted({k for r in records for k in r["metrics"]})
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", *config_keys, *metric_keys])
        for r in records:
            writer.writerow(
                [r["seed"], *(r["config"].get(k, "") for k in config_keys), *(r["metrics"].get(k, "") for k in metric_keys)]
            )
