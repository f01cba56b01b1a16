"""The unknown-object experiment (``python -m sabre experiment unknown``): objects opened from a detected
handle's pose, their joint estimated while pulling, against the same objects opened with their model.

Each run opens one object, a built-in one (from the robot's start) or one of the generated families
(:mod:`sabre.experiments.families`, from the robot's default state), in one mode: "known" (the
controller plans with the object's model), "unknown" (it gets only the handle's pose, with 5 mm and 3°
of error, no prior, and the hand's positions and the wrench with 2 mm and 0.5 N of noise on every
sample) or "wrong prior" (as unknown, the door announced as a drawer and the reverse). Success is the
true object's, at 90 % of its target opening, within ``duration`` s. The estimate is scored against
the true joint when the true object has opened 10°/10 cm (type), 15° (a hinge's axis and position)
or 5 cm (a slide's direction). :func:`unknown_table` writes the report.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import numpy as np

from ..closed_loop import run_episode
from ..errors import InvalidValueError
from ..estimated_object import EstimatedObject
from ..handle_object import DetectedHandle
from ..planner import VARIANTS, Controller, ControllerConfig
from ..safety import SafetyConfig
from ..scene import OBJECTS, Scene
from ..tasks import OpenObject
from .families import robot_urdf, scene_of
from .hook import FAMILIES, family_spec

__all__ = ["MODES", "unknown_configs", "unknown_run", "unknown_table", "true_joint", "noisy_pose"]

#: How the controller is given the object.
MODES: tuple[str, ...] = ("known", "unknown", "wrong prior")
#: Error of the detected handle's pose (m, rad), of every hand position (m) and wrench component (N).
POSE_ERROR, ANGLE_ERROR, HAND_NOISE, WRENCH_NOISE = 0.005, math.radians(3.0), 0.002, 0.5


def unknown_configs(
    *,
    objects: int = 20,
    families: tuple[str, ...] = FAMILIES,
    builtins: tuple[str, ...] = OBJECTS,
    variants: tuple[str, ...] = ("N", "IO"),
    modes: tuple[str, ...] = MODES,
    duration: float = 60.0,
) -> list[dict[str, Any]]:
    """The configurations, one per object, variant and mode (the runner adds seeds): the built-in objects
    and ``objects`` of each generated family, for the RoyalPanda."""
    bad = [f for f in families if f not in FAMILIES] + [v for v in variants if v not in VARIANTS]
    bad += [m for m in modes if m not in MODES] + [b for b in builtins if b not in OBJECTS]
    if bad:
        raise InvalidValueError(f"unknown: unknown families, variants, modes or objects {bad}")
    if int(objects) < 0 or not (np.isfinite(duration) and duration > 0.0):
        raise InvalidValueError(f"unknown: objects must be ≥ 0 and duration positive, got {objects}, {duration}")
    cases = [("builtin", b) for b in builtins] + [(f, i) for f in families for i in range(int(objects))]
    return [
        {"case": case, "object": obj, "variant": v, "mode": m, "duration": float(duration)}
        for case, obj in cases
        for v in variants
        for m in modes
    ]


def true_joint(scene: Scene, task: OpenObject) -> tuple[str, np.ndarray, np.ndarray]:
    """(type, axis or direction, a point on the hinge) of the scene's object, from its handle frame at two
    openings: a rotation's axis and fixed point, or a translation's direction."""
    a, b = task.handle_pose(scene, scene.o_lower), task.handle_pose(scene, scene.o_lower + 0.2)
    if not scene.object_is_revolute:
        d = b[:3, 3] - a[:3, 3]
        return "prismatic", d / np.linalg.norm(d), a[:3, 3]
    r = b[:3, :3] @ a[:3, :3].T
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    point = np.linalg.lstsq(np.eye(3) - r, b[:3, 3] - r @ a[:3, 3], rcond=None)[0]
    return "revolute", w / np.linalg.norm(w), point


def noisy_pose(pose: np.ndarray, rng: np.random.Generator, offset: float = POSE_ERROR, angle: float = ANGLE_ERROR) -> np.ndarray:
    """``pose`` moved by ``offset`` m in a random direction and turned by ``angle`` rad about a random axis."""
    u, k = rng.normal(size=3), rng.normal(size=3)
    u, k = u / np.linalg.norm(u), k / np.linalg.norm(k)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    turn = np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew
    out = np.array(pose, dtype=np.float64)
    out[:3, :3] = turn @ out[:3, :3]
    out[:3, 3] += offset * u
    return out


def _object(config: dict[str, Any]) -> tuple[Scene, OpenObject, np.ndarray | None, SafetyConfig | None, str]:
    """(true scene, its task, start state (None: the paper's), safety, robot for the estimated scene)."""
    if config["case"] == "builtin":
        return Scene.load("royalpanda", config["object"]), OpenObject(), None, None, "royalpanda"
    spec = family_spec(config["case"], config["object"])
    scene = scene_of(spec, "royalpanda")
    # the filter's base box (the paper's experiments: ±2 m) must hold the way to an object 2–4 m away
    return (
        scene,
        OpenObject(handle=spec.handle_link),
        scene.default_state(),
        SafetyConfig(base_box=(-5.0, 5.0, -5.0, 5.0)),
        str(robot_urdf()),
    )


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))))))


def _scores(estimated: EstimatedObject, times: np.ndarray, opening: np.ndarray, truth: tuple) -> dict[str, float]:
    """The estimate against the true joint where the true object first reached each opening."""
    kind, axis, point = truth
    nan = float("nan")
    history = estimated.history
    if not history:
        return {"type_right": nan, "axis_error": nan, "hinge_error": nan}
    at = np.array([t for t, _ in history])
    true_at = np.interp(at, times, opening)

    def first(threshold: float) -> Any:
        i = np.flatnonzero(true_at >= threshold)
        return history[int(i[0])][1] if len(i) else None

    door = kind == "revolute"
    typed = first(math.radians(10) if door else 0.10)
    geometry = first(math.radians(15) if door else 0.05)
    scores = {"type_right": nan if typed is None else float(typed.kind == kind), "axis_error": nan, "hinge_error": nan}
    if geometry is not None and geometry.geometry == kind:
        scores["axis_error"] = _angle(geometry.axis, axis)
        if door:
            off = geometry.point - point
            scores["hinge_error"] = float(np.linalg.norm(off - (off @ axis) * axis))
    return scores


def _error_series(estimated: EstimatedObject, times: np.ndarray, opening: np.ndarray, truth: tuple) -> dict[str, list]:
    """The axis error (deg) of the decided estimate against the true opening."""
    kind, axis, _ = truth
    pts = [(float(np.interp(t, times, opening)), _angle(e.axis, axis)) for t, e in estimated.history[::10] if e.kind == kind]
    return {"t": [p[0] for p in pts], "y": [p[1] for p in pts]}


def unknown_run(config: dict[str, Any], seed: int, plant: Callable[[Scene], Any] | None = None) -> dict[str, Any]:
    """One run (a configuration of :func:`unknown_configs` at a seed, on ``plant(scene)``, None: the
    Rapier plant): ``metrics`` (success, time to open, and for an estimated object: the type right at
    10°/10 cm, the axis error (deg) at 15°/5 cm, the hinge's error (m) at 15°, the scene's rebuilds),
    ``kind`` (the true joint's type) and the ``series`` of the axis error against the opening."""
    scene, task, x0, safety, robot = _object(config)
    truth = true_joint(scene, task)
    cfg = ControllerConfig(variant=config["variant"], seed=seed, safety=safety)
    nan = float("nan")
    record: dict[str, Any] = {"kind": truth[0], "series": {}}
    common: dict[str, Any] = {"seed": seed, "x0": x0, "progress": False, "plant": None if plant is None else plant(scene)}
    if config["mode"] == "known":
        episode = run_episode(scene, Controller(scene, task, cfg), config["duration"], **common)
        metrics = dict.fromkeys(("type_right", "axis_error", "hinge_error", "rebuilds"), nan)
    else:
        rng = np.random.default_rng(10_000 + seed)
        prior = "unknown" if config["mode"] == "unknown" else ("drawer" if truth[0] == "revolute" else "door")
        handle = DetectedHandle(noisy_pose(task.handle_pose(scene, scene.o_lower), rng), prior=prior)
        estimated = EstimatedObject(robot, handle, simulated_noise=(HAND_NOISE, WRENCH_NOISE), seed=seed)
        controller = Controller(estimated.scene, OpenObject(), cfg)
        episode = run_episode(scene, controller, config["duration"], estimated=estimated, judge=task, record_every=1, **common)
        metrics = _scores(estimated, episode.time, episode.opening, truth) | {"rebuilds": float(len(estimated.rebuilds))}
        record["series"] = {"axis_error": _error_series(estimated, episode.time, episode.opening, truth)}
    metrics |= {
        "success": float(episode.success),
        "time_to_success": nan if episode.time_to_success is None else float(episode.time_to_success),
    }
    return record | {"metrics": metrics}


def _median(values: list[float], fmt: str) -> str:
    v = [x for x in values if np.isfinite(x)]
    return format(float(np.median(v)), fmt) if v else "—"


def unknown_table(records: list[dict[str, Any]]) -> str:
    """Markdown: per object group (built-in, each family) and variant, the runs opened in each mode, the
    unknown mode's share of the known one's, the median times, and the estimate's scores."""
    groups: defaultdict[tuple[str, str], dict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        c = r["config"]
        groups[(c["case"], c["variant"])][c["mode"]].append(r)
    lines = [
        "| objects | variant | known opened | unknown opened (share of known) | wrong prior opened "
        "| time, median: known / unknown | type right at 10°/10 cm | hinge axis error at 15°, median (max) "
        "| hinge position error at 15°, median (max) | slide direction error at 5 cm, median (max) |",
        "|---" * 10 + "|",
    ]
    for (case, variant), modes in sorted(groups.items()):
        known, unknown, wrong = (modes.get(m, []) for m in MODES)
        opened = [sum(r["metrics"]["success"] for r in runs) for runs in (known, unknown, wrong)]
        share = f" ({opened[1] / opened[0]:.0%})" if opened[0] else ""
        estimated = unknown + wrong
        doors = [r["metrics"] for r in estimated if r["kind"] == "revolute"]
        slides = [r["metrics"] for r in estimated if r["kind"] == "prismatic"]
        typed = [r["metrics"]["type_right"] for r in estimated if np.isfinite(r["metrics"]["type_right"])]

        def spread(ms: list[dict], key: str, unit: str, scale: float = 1.0) -> str:
            v = [scale * m[key] for m in ms if np.isfinite(m[key])]
            return f"{np.median(v):.1f}{unit} ({max(v):.1f}{unit})" if v else "—"

        lines.append(
            f"| {case} | {variant} | {opened[0]:.0f}/{len(known)} | {opened[1]:.0f}/{len(unknown)}{share} "
            f"| {opened[2]:.0f}/{len(wrong)} "
            f"| {_median([r['metrics']['time_to_success'] for r in known], '.1f')} s / "
            f"{_median([r['metrics']['time_to_success'] for r in unknown], '.1f')} s "
            f"| {sum(typed):.0f}/{len(typed)} | {spread(doors, 'axis_error', '°')} "
            f"| {spread(doors, 'hinge_error', ' cm', 100.0)} | {spread(slides, 'axis_error', '°')} |"
        )
    return "\n".join(lines)
