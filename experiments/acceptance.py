"""Closed-loop acceptance: open each object from the paper's starting condition, many seeds.

Runs the controller (Table I defaults, variant N unless --variant) on the 1 kHz plant for up to
--duration s of simulated time per episode, re-planning at --replan-rate Hz, and prints a
markdown table: successes, time to open, final opening, mean wrench, real-time factor and median
planning time. Episodes stop 0.5 s after success. Results go to experiments/results/acceptance.json.

    .venv/bin/python experiments/acceptance.py --seeds 10
    .venv/bin/python experiments/acceptance.py --objects shelf drawer --seeds 3 --variant IO
"""

from __future__ import annotations

import argparse
import itertools
import json
import pathlib
import time

import numpy as np

import sabre


def run(obj: str, seed: int, args) -> dict:
    scene = sabre.Scene.load(obj=obj)
    task = sabre.tasks.OpenObject()
    config = sabre.ControllerConfig(seed=seed, threads=args.threads, variant=args.variant)
    controller = sabre.Controller(scene, task, config)
    start = time.perf_counter()
    ep = sabre.run_episode(scene, controller, args.duration, seed=seed, replan_rate=args.replan_rate, progress=False)
    wall = time.perf_counter() - start
    phases = [ep.phases[i] for i in ep.phase]
    slips = sum(1 for a, b in itertools.pairwise(phases) if a == "open" and b == "approach")
    releases = sum(1 for a, b in itertools.pairwise(phases) if a != "release" and b == "release")
    return {
        "object": obj,
        "seed": seed,
        "variant": args.variant,
        "success": bool(ep.success),
        "time_to_success": ep.time_to_success,
        "final_opening": float(ep.opening[-1]),
        "target_opening": task.target_opening(scene),
        "mean_wrench": ep.mean_wrench(),
        "slips": slips,
        "releases": releases,
        "simulated": float(ep.duration),
        "wall": wall,
        "real_time_factor": float(ep.real_time_factor),
        "plan_ms_median": 1000.0 * float(np.median(ep.planning_times)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", nargs="+", default=list(sabre.OBJECTS))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--replan-rate", type=float, default=50.0)
    parser.add_argument("--variant", default="N", choices=sabre.VARIANTS)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "acceptance.json"))
    args = parser.parse_args()
    rows = []
    for obj in args.objects:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            r = run(obj, seed, args)
            rows.append(r)
            when = "-" if r["time_to_success"] is None else f"{r['time_to_success']:.1f} s"
            print(f"{obj:10s} seed {seed:2d}: success={r['success']!s:5s} at {when:>7s}"
                  f"  opening {r['final_opening']:.3f}  wrench {r['mean_wrench']:.1f} N"
                  f"  slips {r['slips']}  releases {r['releases']}  rtf {r['real_time_factor']:.2f}"
                  f"  plan {r['plan_ms_median']:.1f} ms", flush=True)
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=1))
    print()
    print(f"variant {args.variant}, {args.duration:.0f} s limit,"
          f" re-planning at {args.replan_rate:.0f} Hz, {args.threads} threads")
    print("| object | success | time to open (median, max) | final opening (needed) | mean wrench"
          " | real-time factor | planning (median) |")
    print("|---|---|---|---|---|---|---|")
    for obj in args.objects:
        rs = [r for r in rows if r["object"] == obj]
        ok = [r for r in rs if r["success"]]
        times = [r["time_to_success"] for r in ok]
        t = f"{np.median(times):.1f} s, {max(times):.1f} s" if times else "-"
        need = 0.9 * rs[0]["target_opening"]
        print(f"| {obj} | {len(ok)}/{len(rs)} | {t} | {np.median([r['final_opening'] for r in rs]):.3f} ({need:.3f}) "
              f"| {np.median([r['mean_wrench'] for r in rs]):.1f} N | {np.median([r['real_time_factor'] for r in rs]):.2f} "
              f"| {np.median([r['plan_ms_median'] for r in rs]):.1f} ms |")


if __name__ == "__main__":
    main()
