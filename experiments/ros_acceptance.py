"""Acceptance across processes: every object opened through the ROS 2 bridge in wall-clock real time,
against `run_episode` of the same seed, plus the stuck door through the bridge.

    .venv/bin/python experiments/ros_acceptance.py --seeds 5 --out results/ros_acceptance.md

Each run starts the simulated robot and the controller as two processes on a private, machine-local
ROS 2 domain (`sabre.ros.launch.run_bridge`: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a free
ROS_DOMAIN_ID per run), the planner as fast as the machine allows, from the paper's start. The same
seed and variant also run in `run_episode` (simulated time, re-planning at 50 Hz) for the time to open.
Goals: at least 4 of 5 per object and variant; time to open within 1.5× of run_episode's;
state-to-command latency p99 at most 1 ms; at least 99.5 % of the 1 kHz commands back; the stuck door
(held 5 s) through the bridge keeps IO's tank above its floor.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import sabre
from sabre import scenarios
from sabre.ros import require_ros
from sabre.ros.launch import run_bridge


def reference_time(obj: str, variant: str, seed: int, duration: float) -> float | None:
    r = scenarios.object_manipulation(variant, obj, seed, duration)
    return r.episode.time_to_success if r.success else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=list(sabre.OBJECTS), choices=sabre.OBJECTS)
    parser.add_argument("--variants", nargs="+", default=["N", "IO"], choices=["N", "I", "O", "IO"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--timeout", type=float, default=60.0, help="wall seconds per bridge run")
    parser.add_argument("--hold", type=float, default=5.0, help="stuck-door hold (s); 0 skips the stuck-door run")
    parser.add_argument("--out", type=Path, default=None, help="markdown report")
    args = parser.parse_args(argv)
    require_ros()

    started = time.perf_counter()
    rows, lines = [], []
    for obj in args.objects:
        for variant in args.variants:
            runs = []
            for seed in range(args.seeds):
                run = run_bridge(obj, variant, seed, timeout=args.timeout)
                s, c = run.sim, run.controller
                reference = reference_time(obj, variant, seed, args.timeout)
                opened = bool(s.get("success"))
                runs.append(
                    {
                        "opened": opened,
                        "time": s.get("time_to_open"),
                        "reference": reference,
                        "p50": s.get("latency_p50_ms", float("nan")),
                        "p99": s.get("latency_p99_ms", float("nan")),
                        "delivered": s.get("delivered_fraction", 0.0),
                        "late_ticks": s.get("late_ticks", 0),
                        "planner_hz": c.get("planner_rate_hz", float("nan")),
                    }
                )
                print(
                    f"{obj} {variant} seed {seed}: opened {opened} in {s.get('time_to_open')} s "
                    f"(run_episode {reference}), latency p99 {runs[-1]['p99']:.2f} ms, "
                    f"delivered {100 * runs[-1]['delivered']:.2f} %",
                    file=sys.stderr,
                    flush=True,
                )
            ratios = [r["time"] / r["reference"] for r in runs if r["opened"] and r["reference"]]
            rows.append((obj, variant, runs, ratios))
    stuck = None
    if args.hold > 0:
        run = run_bridge(
            "shelf",
            "IO",
            0,
            timeout=args.timeout + args.hold,
            sim_params={"hold_at_opening": 0.3, "hold_duration": args.hold, "stop_on_success": True},
        )
        stuck = run.controller

    lines += [
        "| object | variant | opened | time to open, bridge / run_episode (median, max) | latency p50 / p99 (ms, worst run) "
        "| commands back (worst run) | late plant ticks (max) | planner (Hz, median) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for obj, variant, runs, ratios in rows:
        k = sum(r["opened"] for r in runs)
        ratio = f"{statistics.median(ratios):.2f}×, {max(ratios):.2f}×" if ratios else "—"
        lines.append(
            f"| {obj} | {variant} | {k}/{len(runs)} | {ratio} "
            f"| {max(r['p50'] for r in runs):.2f} / {max(r['p99'] for r in runs):.2f} "
            f"| {100 * min(r['delivered'] for r in runs):.2f} % | {max(r['late_ticks'] for r in runs)} "
            f"| {statistics.median(r['planner_hz'] for r in runs):.0f} |"
        )
    if stuck is not None:
        lines += [
            "",
            f"Stuck door through the bridge (shelf, IO, held {args.hold:g} s at 30 % of the range): "
            f"tank minimum {stuck.get('tank_min', float('nan')):.3f} J, "
            f"floor {stuck.get('tank_floor', float('nan')):.3f} J, "
            f"filter fallbacks {stuck.get('filter_fallbacks')}.",
        ]
    command = "python experiments/ros_acceptance.py " + " ".join(sys.argv[1:] if argv is None else argv)
    report = "\n".join([f"Command: `{command}`; wall time {time.perf_counter() - started:.0f} s.", ""] + lines) + "\n"
    print(report)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
