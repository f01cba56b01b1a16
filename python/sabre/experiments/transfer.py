"""The transfer experiment: the controller, planning with sabre's rollout model of the nominal object, opens
each object in sabre's Rapier plant and in MuJoCo's (:class:`sabre.MujocoPlant`), with the object's joint
damping and dry friction scaled in the plant only and a planning delay, from the paper's start.

One run is :func:`transfer_episode` of a configuration (object, variant, simulator, scale) and a seed;
:func:`transfer_configs` lists the configurations and :func:`transfer_table` puts both plants side by side.
``python -m sabre experiment transfer`` runs the default sweep (4 objects × variants N and IO × both plants ×
scales 1, 2, 3).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Sequence

import numpy as np

from ..episode import Episode
from ..errors import InvalidValueError
from ..plants import PlantInterface
from ..poses import pose_to_xyz_rpy
from ..scene import OBJECTS, Scene

__all__ = [
    "SIMULATORS",
    "SCALES",
    "scaled_object_urdf",
    "scaled_plant",
    "transfer_configs",
    "transfer_episode",
    "transfer_metrics",
    "transfer_table",
]

#: The plants the experiment compares: sabre's Rapier :class:`~sabre.Plant` and :class:`~sabre.MujocoPlant`.
SIMULATORS: tuple[str, ...] = ("sabre", "mujoco")
#: Factors on the object joint's damping and dry friction (in the plant only).
SCALES: tuple[float, ...] = (1.0, 2.0, 3.0)


def scaled_object_urdf(text: str, scale: float) -> str:
    """The object URDF ``text`` with the damping and dry friction of every movable joint's ``<dynamics>``
    multiplied by ``scale`` (everything else as it was)."""
    root = ET.fromstring(text)
    for joint in root.iter("joint"):
        dynamics = joint.find("dynamics")
        if joint.get("type") == "fixed" or dynamics is None:
            continue
        for name in ("damping", "friction"):
            if dynamics.get(name) is not None:
                dynamics.set(name, repr(float(dynamics.get(name, "0")) * scale))
    return ET.tostring(root, encoding="unicode")


def scaled_plant(scene: Scene, simulator: str, scale: float) -> PlantInterface:
    """A 1 kHz plant (``simulator``: one of :data:`SIMULATORS`) of the built-in ``scene`` whose object joint has its
    damping and dry friction multiplied by ``scale``; the controller keeps planning with ``scene``."""
    from .. import assets
    from ..mujoco import MujocoPlant
    from ..sim import Plant

    if simulator not in SIMULATORS:
        raise InvalidValueError(f"simulator must be one of {SIMULATORS}, got {simulator!r}")
    robot = assets.urdf_path(scene.robot_name)
    obj = assets.urdf_file(scaled_object_urdf(assets.urdf_text(scene.object_name), scale), f"{scene.object_name}-x{scale:g}")
    scaled = Scene.from_urdf(robot, obj, pose_to_xyz_rpy(scene.object_pose).tolist())
    if simulator == "mujoco":
        return MujocoPlant(scaled, robot_urdf=robot, object_urdf=obj)
    return Plant(scaled)


def transfer_configs(
    *,
    objects: Sequence[str] = OBJECTS,
    variants: Sequence[str] = ("N", "IO"),
    simulators: Sequence[str] = SIMULATORS,
    scales: Sequence[float] = SCALES,
    duration: float = 60.0,
    replan_rate: float = 50.0,
    plan_delay: float = 0.02,
) -> list[dict]:
    """The configuration of every transfer run but the seed: every object, variant, simulator and scale, from the
    paper's start for up to ``duration`` s, re-planning at ``replan_rate`` Hz with ``plan_delay`` s between the
    state a plan is made from and the plan taking over."""
    from ..planner import VARIANTS

    unknown = [o for o in objects if o not in OBJECTS] + [v for v in variants if v not in VARIANTS]
    unknown += [p for p in simulators if p not in SIMULATORS]
    if unknown:
        raise InvalidValueError(f"transfer: unknown objects, variants or simulators {unknown}")
    timing = dict(duration=float(duration), replan_rate=float(replan_rate), plan_delay=float(plan_delay))
    return [
        dict(obj=o, variant=v, simulator=p, scale=float(s), **timing)
        for o in objects
        for v in variants
        for p in simulators
        for s in scales
    ]


def transfer_episode(c: dict, seed: int) -> Episode:
    """The episode of one transfer configuration ``c`` (:func:`transfer_configs`) at ``seed``: the controller plans
    with the nominal object, the plant's object has its damping and friction scaled.

    Raises:
        SabreError: the plant failed (e.g. :class:`~sabre.SimulationError`).
    """
    from .. import tasks
    from ..closed_loop import paper_start_state, run_episode
    from ..planner import Controller, ControllerConfig

    scene = Scene.load(obj=c["obj"])
    controller = Controller(scene, tasks.OpenObject(), ControllerConfig(variant=c["variant"], seed=seed, threads=1))
    return run_episode(
        scene,
        controller,
        c["duration"],
        seed=seed,
        x0=paper_start_state(scene),
        replan_rate=c["replan_rate"],
        plan_delay=c["plan_delay"],
        plant=scaled_plant(scene, c["simulator"], c["scale"]),
        progress=False,
    )


def transfer_metrics(episode: Episode | None) -> dict[str, float]:
    """Whether and when the episode opened, its final opening, the mean wrench in contact, the tank's lowest
    energy and the real-time factor; ``None`` (the plant failed) counts as not opened, with ``failed`` 1."""
    nan = float("nan")
    if episode is None:
        return dict(success=0.0, failed=1.0, time_to_success=nan, final_opening=nan, mean_wrench=nan, tank_min=nan)
    tank = episode.tank_energy
    return {
        "success": float(episode.success),
        "failed": 0.0,
        "time_to_success": nan if episode.time_to_success is None else float(episode.time_to_success),
        "final_opening": float(episode.opening[-1]),
        "mean_wrench": float(episode.mean_wrench()),
        "tank_min": nan if tank is None else float(np.nanmin(tank)),
        "real_time_factor": float(episode.real_time_factor),
    }


def _cell(runs: list[dict]) -> str:
    """One plant's cell: opened n/N, time to open (median), mean wrench (median), tank minimum (lowest)."""
    opened = [r for r in runs if r["metrics"]["success"]]
    times = [r["metrics"]["time_to_success"] for r in opened]
    wrench = [r["metrics"]["mean_wrench"] for r in runs if np.isfinite(r["metrics"]["mean_wrench"])]
    tank = [r["metrics"]["tank_min"] for r in runs if np.isfinite(r["metrics"]["tank_min"])]
    failed = sum(int(r["metrics"].get("failed", 0.0)) for r in runs)
    return " | ".join(
        [
            f"{len(opened)}/{len(runs)}" + (f" ({failed} diverged)" if failed else ""),
            f"{np.median(times):.1f} s" if times else "—",
            f"{np.median(wrench):.1f} N" if wrench else "—",
            f"{min(tank):.2f} J" if tank else "—",
        ]
    )


def _row_order(obj: str, variant: str, scale: float) -> tuple:
    """Rows by object as :data:`~sabre.OBJECTS` lists them, variant N before the others, then by scale."""
    return (OBJECTS.index(obj) if obj in OBJECTS else len(OBJECTS), obj, variant != "N", variant, scale)


def transfer_table(records: list[dict]) -> str:
    """Markdown, one row per object, variant and scale: for each plant the episodes that opened, the median
    time to open, the median of the episodes' mean wrench in contact and the lowest tank energy of any episode."""
    groups: defaultdict[tuple[str, str, float], defaultdict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in records:
        c = r["config"]
        groups[c["obj"], c["variant"], c["scale"]][c["simulator"]].append(r)
    plants = [p for p in SIMULATORS if any(p in g for g in groups.values())]
    head = " | ".join(f"{p}: opened | {p}: time to open | {p}: mean wrench | {p}: tank min" for p in plants)
    lines = [f"| object | variant | damping, friction | {head} |", "|---" * (3 + 4 * len(plants)) + "|"]
    for (obj, variant, scale), by_plant in sorted(groups.items(), key=lambda item: _row_order(*item[0])):
        cells = " | ".join(_cell(by_plant[p]) if by_plant.get(p) else "— | — | — | —" for p in plants)
        lines.append(f"| {obj} | {variant} | ×{scale:g} | {cells} |")
    return "\n".join(lines)
