"""Soak: many consecutive episodes in one process (random object, placement, variant and fault), watching
for leaks (peak RSS, OS threads), NaN, filter fallbacks and tank floor violations.

    .venv/bin/python experiments/soak.py --episodes 200 --duration 4 --out results/soak.md

Each episode: a random object of the four, placed at a random offset and yaw, a random variant
(N, I, O, IO), started from the pre-grasp pose (the hooked state for the stuck door) and one fault:
none, the stuck door (held for the middle third of the episode), a sphere obstacle dropped beside
the hand, or an impulsive push of the arm joints. Goals: RSS growth under 5 % between the
end of the warm-up (the first 10 % of episodes) and the end, a constant thread count, zero NaN,
zero tank floor violations. Filter fallbacks are counted and reported.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

import sabre
from sabre.paper import scenarios

OBJECTS = sabre.OBJECTS
VARIANTS = ("N", "I", "O", "IO")
FAULTS = ("none", "stuck", "obstacle", "push")


def rss_mib() -> float:
    """Resident set size now (MiB), from /proc; the peak from getrusage where /proc is missing."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def threads() -> int:
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return -1


def episode(rng: np.random.Generator, index: int, duration: float) -> dict:
    obj = OBJECTS[rng.integers(len(OBJECTS))]
    variant = VARIANTS[rng.integers(len(VARIANTS))]
    fault = FAULTS[rng.integers(len(FAULTS))]
    root = sabre.Scene.load("royalpanda", obj).object_pose
    yaw = float(np.arctan2(root[1, 0], root[0, 0])) + rng.uniform(-0.1, 0.1)
    pose = [root[0, 3] + rng.uniform(-0.05, 0.05), root[1, 3] + rng.uniform(-0.05, 0.05), root[2, 3], 0.0, 0.0, yaw]
    scene = sabre.Scene.load("royalpanda", obj, obj_pose=pose)
    x0 = scenarios.hooked_state(scene) if fault == "stuck" else scene.default_state()
    config = sabre.ControllerConfig(variant=variant, rollouts=20, horizon=0.6, seed=index, threads=2)
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
    if fault == "stuck":
        controller.set_phase("open")
    window = (duration / 3.0, 2.0 * duration / 3.0)
    state = {"pushed": False, "obstacle": None}

    def on_replan(t: float, x: np.ndarray, plant: sabre.Plant, ctl: sabre.Controller) -> None:
        if fault == "stuck":
            plant.hold_object(window[0] <= t < window[1])
        elif fault == "push" and not state["pushed"] and t >= window[0]:
            dv = np.zeros(scene.nq + scene.no)
            dv[3 : scene.nq] = rng.uniform(-0.5, 0.5, scene.nq - 3)
            plant.push(dv)
            state["pushed"] = True
        elif fault == "obstacle" and state["obstacle"] is None and t >= window[0]:
            hand = scene.fk(x[: scene.nq], "grasp")[:3, 3]
            state["obstacle"] = ctl.add_obstacle(hand + np.array([0.0, 0.25, 0.1]), 0.05) or -1

    ep = sabre.run_episode(scene, controller, duration, x0=x0, on_replan=on_replan, progress=False, stop_on_success=False)
    below_floor = 0
    if variant in ("I", "IO"):
        below_floor = int(np.sum(ep.tank_energy < ep.tank_floor - 1e-6))
    nan = int(sum(not np.all(np.isfinite(a)) for a in (ep.state, ep.command, ep.wrench, ep.tank_energy)))
    return {
        "object": obj,
        "variant": variant,
        "fault": fault,
        "nan": nan,
        "fallbacks": ep.filter_fallbacks,
        "below_floor": below_floor,
        "success": ep.success,
        "wall": ep.wall_time,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per episode")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="markdown report")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    warmup = max(1, args.episodes // 10)
    rows, rss, thread_counts = [], [], []
    started = time.perf_counter()
    for i in range(args.episodes):
        rows.append(episode(rng, i, args.duration))
        rss.append(rss_mib())
        thread_counts.append(threads())
        if (i + 1) % 10 == 0 or i + 1 == args.episodes:
            print(
                f"{i + 1}/{args.episodes} episodes, RSS {rss[-1]:.1f} MiB, threads {thread_counts[-1]}, "
                f"{time.perf_counter() - started:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    growth = (rss[-1] - rss[warmup - 1]) / rss[warmup - 1] * 100.0
    nan = sum(r["nan"] for r in rows)
    below = sum(r["below_floor"] for r in rows)
    fallbacks = sum(r["fallbacks"] for r in rows)
    faults = Counter(r["fault"] for r in rows)
    lines = [
        f"# Soak: {args.episodes} episodes of {args.duration} s in one process",
        "",
        f"Command: `python experiments/soak.py --episodes {args.episodes} --duration {args.duration} --seed {args.seed}`",
        f"Wall time: {time.perf_counter() - started:.0f} s. Faults: " + ", ".join(f"{k} {v}" for k, v in sorted(faults.items())),
        "",
        "| measure | value | goal |",
        "|---|---|---|",
        f"| RSS after warm-up ({warmup} episodes) → end | {rss[warmup - 1]:.1f} → {rss[-1]:.1f} MiB ({growth:+.2f} %) | < 5 % |",
        f"| OS threads after warm-up → end (min–max) | {thread_counts[warmup - 1]} → {thread_counts[-1]} "
        f"({min(thread_counts[warmup - 1 :])}–{max(thread_counts[warmup - 1 :])}) | constant |",
        f"| episodes with NaN in a trace | {nan} | 0 |",
        f"| tank samples below the floor (I, IO) | {below} | 0 |",
        f"| filter fallbacks (all episodes) | {fallbacks} | reported |",
    ]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(report)
    ok = growth < 5.0 and nan == 0 and below == 0 and len(set(thread_counts[warmup - 1 :])) == 1
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
