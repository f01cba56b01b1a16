"""Generality sweep: objects written the way other tools write them, opened by naming their handle link.

    .venv/bin/python experiments/generality_sweep.py --family box --objects 40 --duration 60 --variants N IO
    .venv/bin/python experiments/generality_sweep.py --family mesh --objects 40 --duration 60 --variants N IO

The objects are sabre.experiments.families' (`python -m sabre experiment hook` runs the same episodes
through the experiment runner, cached and in parallel, per robot). The box family: a URDF each with
its own link and joint names, a `world` root with a fixed joint and no `handle_frame`, varying handle
height, width, hinge side, bar orientation and shape, door or drawer, friction, damping, moving mass and where it stands. The mesh
family: cabinets as robot-learning benchmarks ship them (a ROS package each, every part convex mesh
pieces, no inertials, two doors and two drawers, handles as mesh bars on standoffs); the scene keeps the
joint of the target part's handle (`Scene.from_urdf(..., handle=...)`) and holds the others shut.
`OpenObject(handle=<bar link>)` opens each from the default robot state; success is 90 % of the target
opening within the simulated duration. Half the handles are of the short-standoff class (bars of
10–20 mm on standoffs of 20–40 mm; the others a 10 mm bar on 56 mm standoffs), reported on their own.
Failures are classified: refused (the hook does not fit the handle), could not reach (never
inserting), could not hook (never opening), slipped (opening, then back to reaching), stalled at a
joint limit (an arm joint within 0.02 rad of a limit over the last 5 s), tank spent (I/IO: the tank
within 0.1 J of its floor at the end), or stalled (none of these). ``--first``/``--objects`` split a
sweep over processes; ``--no-fit`` keeps the configured grasp targets instead of fitting them to the
handle's geometry.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

import sabre
from sabre.experiments.families import MeshCabinetSpec, ObjectSpec, random_mesh_spec, random_spec, scene_of
from sabre.experiments.hook import classify, hook_skill


def run_one(
    spec: ObjectSpec | MeshCabinetSpec, variant: str, duration: float, seed: int = 0, fit: bool = True
) -> tuple[str, float | None, dict]:
    scene = scene_of(spec)
    approach = sabre.tasks.ApproachConfig() if fit else sabre.tasks.ApproachConfig(fit_clearance=None)
    task = sabre.tasks.OpenObject(handle=spec.handle_link, approach=approach)
    try:
        task.check(scene)
    except sabre.InvalidValueError:
        return "refused", None, {}
    # The filter's base box (the paper's experiments: ±2 m) must hold the robot's way to an object
    # 2–4 m away: ±5 m here.
    safety = sabre.SafetyConfig(base_box=(-5.0, 5.0, -5.0, 5.0))
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(variant=variant, seed=seed, safety=safety))
    episode = sabre.run_episode(scene, controller, duration, seed=seed, x0=scene.default_state(), progress=False)
    return classify(episode, scene), episode.time_to_success, hook_skill(episode)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--family", choices=["box", "mesh"], default="box", help="which generated objects")
    parser.add_argument("--objects", type=int, default=40)
    parser.add_argument("--first", type=int, default=0, help="index of the first object (to split a sweep)")
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds per episode")
    parser.add_argument("--variants", nargs="+", default=["N", "IO"], choices=["N", "I", "O", "IO"])
    parser.add_argument("--seed", type=int, default=0, help="seed of the object generator")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--no-fit", action="store_true", help="the configured grasp targets, not fitted to the handle")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    draw = random_mesh_spec if args.family == "mesh" else random_spec
    specs = [draw(rng, i) for i in range(args.first + args.objects)][args.first :]
    started = time.perf_counter()
    classes = sorted({spec.handle_class for spec in specs})
    outcomes: dict[tuple[str, str], Counter] = {(v, c): Counter() for v in args.variants for c in ["all", *classes]}
    skills: dict[tuple[str, str], list[dict]] = {key: [] for key in outcomes}
    rows = []
    for spec in specs:
        for variant in args.variants:
            outcome, when, skill = run_one(spec, variant, args.duration, fit=not args.no_fit)
            for group in ("all", spec.handle_class):
                outcomes[variant, group][outcome] += 1
                if skill:
                    skills[variant, group].append(skill | {"opened": outcome == "opened"})
            rows.append((spec, variant, outcome, when))
            print(
                f"object {spec.index} ({spec.describe()}) {variant}: {outcome}"
                + (f" at {when:.1f} s" if when is not None else ""),
                file=sys.stderr,
                flush=True,
            )
    failures = ("refused", "could not reach", "could not hook", "slipped", "stalled at a joint limit", "tank spent", "stalled")
    command = (
        f"python experiments/generality_sweep.py --family {args.family} --objects {args.objects} --first {args.first} "
        f"--duration {args.duration:g} --variants {' '.join(args.variants)} --seed {args.seed}"
        + (" --no-fit" if args.no_fit else "")
    )
    lines = [
        f"Command: `{command}`; wall time {time.perf_counter() - started:.0f} s.",
        "",
        "| variant | handles | opened | " + " | ".join(failures) + " |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (variant, group), counts in outcomes.items():
        total = sum(counts.values())
        opened = f"{counts['opened']}/{total} ({100 * counts['opened'] / max(total, 1):.0f} %)"
        lines.append(f"| {variant} | {group} | {opened} | " + " | ".join(str(counts[c]) for c in failures) + " |")
    lines += [
        "",
        "| variant | handles | first insert hooked | insert time, median (max) | slips per opening | re-inserts hooked |",
        "|---|---|---|---|---|---|",
    ]
    for (variant, group), runs in skills.items():
        hooked = sum(r["inserted"] for r in runs)
        times = [r["insert_time"] for r in runs if r["insert_time"] is not None]
        timing = f"{np.median(times):.1f} s ({max(times):.1f} s)" if times else "—"
        opened = sum(r["opened"] for r in runs)
        slips, reinserts = sum(r["slips"] for r in runs), sum(r["reinserts"] for r in runs)
        per_opening = f"{slips / opened:.2f}" if opened else "—"
        lines.append(f"| {variant} | {group} | {hooked}/{len(runs)} | {timing} | {per_opening} | {reinserts}/{slips} |")
    report = "\n".join(lines) + "\n"
    print(report)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
