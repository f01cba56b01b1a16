"""The hook experiment (``python -m sabre experiment hook``): the generated object families opened by a
mobile robot, and the hook's skill per family, handle class, robot and variant.

Each run opens one generated object (:mod:`sabre.experiments.families`, drawn by index from the
generator's seed) with ``OpenObject(handle=<bar link>)`` from the robot's default state, for up to
``duration`` s, success at 90 % of the target opening. From its phase trace (:func:`hook_skill`): whether
the first insert reached the hook phase and how long it took, the slips (open, then back to reaching)
and the re-inserts after them that reached the hook again; the outcome (:func:`classify`) says why an
object did not open. :func:`hook_table` writes the report.
"""

from __future__ import annotations

import itertools
from collections import Counter, defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

from ..closed_loop import run_episode
from ..episode import Episode
from ..errors import InvalidValueError
from ..planner import VARIANTS, Controller, ControllerConfig
from ..safety import SafetyConfig
from ..scene import Scene
from ..tasks import ApproachConfig, OpenObject
from .families import MeshCabinetSpec, ObjectSpec, random_mesh_spec, random_spec, robot_urdf, scene_of

__all__ = ["FAMILIES", "OUTCOMES", "family_spec", "classify", "hook_skill", "hook_configs", "hook_run", "hook_table"]

#: The generated families (:mod:`sabre.experiments.families`).
FAMILIES: tuple[str, ...] = ("box", "mesh")

#: Every outcome of a run: opened, or why not (see :func:`classify`; "refused": the hook does not fit the handle).
OUTCOMES: tuple[str, ...] = (
    "opened",
    "refused",
    "could not reach",
    "could not hook",
    "slipped",
    "stalled at a joint limit",
    "tank spent",
    "stalled",
)


def family_spec(family: str, index: int, generator_seed: int = 0) -> ObjectSpec | MeshCabinetSpec:
    """Object ``index`` of ``family``: the ``index``-th specification drawn from a generator seeded with
    ``generator_seed`` (the generality sweep's objects for seed 0)."""
    if family not in FAMILIES:
        raise InvalidValueError(f"unknown object family {family!r}; one of {FAMILIES}")
    draw = random_mesh_spec if family == "mesh" else random_spec
    rng = np.random.default_rng(int(generator_seed))
    return [draw(rng, i) for i in range(int(index) + 1)][-1]


def classify(episode: Episode, scene: Scene) -> str:
    """Why an episode did not open its object: never inserting (could not reach), never opening (could
    not hook), opening and then back to reaching (slipped), an arm joint within 0.02 rad of a limit for
    more than half of the last 5 s (stalled at a joint limit), the tank within 0.1 J of its floor at
    the end (I/IO: tank spent), or none of these (stalled); "opened" if it did."""
    if episode.success:
        return "opened"
    phases = [episode.phases[p] for p in episode.phase]
    if "insert" not in phases:
        return "could not reach"
    if "open" not in phases:
        return "could not hook"
    first_open = phases.index("open")
    if any(p in ("approach", "insert", "hook") for p in phases[first_open:]):  # hold comes only after open
        return "slipped"
    arm = [i for i in range(scene.nq) if i not in (scene.base_indices or ())]
    tail = episode.time >= episode.time[-1] - 5.0
    q = episode.state[tail][:, arm]
    near = (q - scene.q_lower[arm] < 0.02) | (scene.q_upper[arm] - q < 0.02)
    if np.any(near.mean(axis=0) > 0.5):
        return "stalled at a joint limit"
    if episode.variant in ("I", "IO") and episode.tank_energy is not None and episode.tank_energy[-1] < episode.tank_floor + 0.1:
        return "tank spent"
    return "stalled"


def hook_skill(episode: Episode) -> dict[str, Any]:
    """The hook's skill in one episode, from its phase trace: whether the first insert ended in the
    hook phase and how long it took (s, from entering insert to entering hook), the slips (open, then
    back to reaching), the re-inserts after them that reached the hook again and how long each took."""
    names = [episode.phases[p] for p in episode.phase]
    entries = [(float(t), b) for t, a, b in zip(episode.time[1:], names, names[1:], strict=False) if a != b]
    first_insert = next((t for t, p in entries if p == "insert"), None)
    first_hook = next((t for t, p in entries if p == "hook" and first_insert is not None and t >= first_insert), None)
    slips, reinsert_times, after_slip, insert_start = 0, [], False, None
    for (_, before), (t, after) in itertools.pairwise([(0.0, names[0]), *entries]):
        if before in ("open", "hold") and after in ("approach", "insert", "hook"):
            slips, after_slip = slips + 1, True
        if after_slip and after == "insert":
            insert_start = t
        if after_slip and after == "hook" and before == "insert" and insert_start is not None:
            reinsert_times.append(t - insert_start)
            after_slip, insert_start = False, None
    return {
        "inserted": first_hook is not None,
        "insert_time": None if first_hook is None or first_insert is None else float(first_hook - first_insert),
        "slips": slips,
        "reinserts": len(reinsert_times),
        "reinsert_times": reinsert_times,
    }


def hook_configs(
    *,
    objects: int = 40,
    families: tuple[str, ...] = FAMILIES,
    variants: tuple[str, ...] = ("N", "IO"),
    robot: str = "royalpanda",
    duration: float = 60.0,
    fit: bool = True,
    generator_seed: int = 0,
) -> list[dict[str, Any]]:
    """The configurations of the hook experiment, one per family, object index and variant (the runner
    adds seeds). ``robot`` must have a mobile base: the objects stand 2–4 m away."""
    unknown = [f for f in families if f not in FAMILIES] + [v for v in variants if v not in VARIANTS]
    if unknown:
        raise InvalidValueError(f"hook: unknown families or variants {unknown}; families {FAMILIES}, variants {VARIANTS}")
    if Scene.from_urdf(robot_urdf(robot), "shelf").base_indices is None:
        raise InvalidValueError(f"hook: robot {robot!r} has no mobile base, and the generated objects stand 2–4 m away")
    if int(objects) < 1 or not (np.isfinite(duration) and duration > 0.0):
        raise InvalidValueError(f"hook: objects must be at least 1 and duration positive, got {objects}, {duration}")
    return [
        {
            "family": f,
            "index": i,
            "variant": v,
            "robot": robot,
            "duration": float(duration),
            "fit": bool(fit),
            "generator_seed": int(generator_seed),
        }
        for f in families
        for i in range(int(objects))
        for v in variants
    ]


def hook_run(config: dict[str, Any], seed: int, plant: Callable[[Scene], Any] | None = None) -> dict[str, Any]:
    """One run of the hook experiment (a configuration of :func:`hook_configs` at a controller seed, on
    ``plant(scene)``, None: the Rapier plant):
    ``metrics`` (floats: success, time to open, opening reached as a share of the target, first insert
    hooked and its time, slips, re-inserts and their median time), ``outcome``, ``handle_class``,
    ``describe`` (the object) and the ``series`` of its opening."""
    spec = family_spec(config["family"], config["index"], config.get("generator_seed", 0))
    scene = scene_of(spec, config.get("robot", "royalpanda"))
    approach = ApproachConfig() if config.get("fit", True) else ApproachConfig(fit_clearance=None)
    task = OpenObject(handle=spec.handle_link, approach=approach)
    record: dict[str, Any] = {"handle_class": spec.handle_class, "describe": spec.describe(), "series": {}}
    nan = float("nan")
    try:
        task.check(scene)
    except InvalidValueError as exc:
        metrics = dict.fromkeys(("success", "opening_share", "inserted", "slips", "reinserts"), 0.0)
        metrics |= dict.fromkeys(("time_to_success", "insert_time", "reinsert_time"), nan)
        return record | {"metrics": metrics, "outcome": "refused", "refusal": str(exc)}
    # the filter's base box (the paper's experiments: ±2 m) must hold the way to an object 2–4 m away
    safety = SafetyConfig(base_box=(-5.0, 5.0, -5.0, 5.0))
    controller = Controller(scene, task, ControllerConfig(variant=config["variant"], seed=seed, safety=safety))
    episode = run_episode(
        scene,
        controller,
        config["duration"],
        seed=seed,
        x0=scene.default_state(),
        progress=False,
        plant=None if plant is None else plant(scene),
    )
    skill = hook_skill(episode)
    target = episode.target_opening or nan
    metrics = {
        "success": float(episode.success),
        "time_to_success": nan if episode.time_to_success is None else float(episode.time_to_success),
        "opening_share": float(np.max(episode.opening) / target) if target > 0.0 else nan,
        "inserted": float(skill["inserted"]),
        "insert_time": nan if skill["insert_time"] is None else skill["insert_time"],
        "slips": float(skill["slips"]),
        "reinserts": float(skill["reinserts"]),
        "reinsert_time": float(np.median(skill["reinsert_times"])) if skill["reinsert_times"] else nan,
    }
    step = max(1, len(episode.time) // 400)
    series = {"opening": {"t": episode.time[::step].tolist(), "y": episode.opening[::step].tolist()}}
    return record | {"metrics": metrics, "outcome": classify(episode, scene), "series": series}


def _group_key(record: dict[str, Any]) -> tuple[str, str, str, str]:
    c = record["config"]
    return c["family"], record["handle_class"], c.get("robot", "royalpanda"), c["variant"]


def _median_max(values: list[float]) -> str:
    v = [x for x in values if np.isfinite(x)]
    return f"{np.median(v):.1f} s ({max(v):.1f} s)" if v else "—"


def hook_table(records: list[dict[str, Any]]) -> str:
    """Markdown: the hook's skill per family, handle class, robot and variant (runs that opened, first
    inserts that reached the hook and their time, slips per opening, re-inserts that hooked again and
    their time, the opening reached as a median share of the target), then the outcomes of the same groups."""
    groups: defaultdict[tuple[str, str, str, str], list[dict]] = defaultdict(list)
    for r in records:
        groups[_group_key(r)].append(r)
    lines = [
        "| family | handles | robot | variant | opened | first insert hooked | insert time, median (max) "
        "| slips per opening | re-inserts hooked | re-insert time, median (max) | opening reached, median |",
        "|---" * 11 + "|",
    ]
    for (family, handles, robot, variant), runs in sorted(groups.items()):
        m = [r["metrics"] for r in runs]
        tried = [x for x, r in zip(m, runs, strict=True) if r["outcome"] != "refused"]
        opened = sum(x["success"] for x in m)
        slips, reinserts = sum(x["slips"] for x in m), sum(x["reinserts"] for x in m)
        lines.append(
            f"| {family} | {handles} | {robot} | {variant} | {opened:.0f}/{len(m)} "
            f"| {sum(x['inserted'] for x in tried):.0f}/{len(tried)} | {_median_max([x['insert_time'] for x in tried])} "
            f"| {f'{slips / opened:.2f}' if opened else '—'} | {reinserts:.0f}/{slips:.0f} "
            f"| {_median_max([x['reinsert_time'] for x in tried])} "
            f"| {np.median([x['opening_share'] for x in tried]) if tried else float('nan'):.0%} |"
        )
    lines += ["", "| family | handles | robot | variant | " + " | ".join(OUTCOMES) + " |", "|---" * (4 + len(OUTCOMES)) + "|"]
    for (family, handles, robot, variant), runs in sorted(groups.items()):
        counts = Counter(r["outcome"] for r in runs)
        lines.append(f"| {family} | {handles} | {robot} | {variant} | " + " | ".join(str(counts[o]) for o in OUTCOMES) + " |")
    return "\n".join(lines)
