"""Acceptance across processes: every object, placed away from its default pose, opened through the
ROS 2 bridge in wall-clock real time, against `run_episode` of the same seed and pose, plus the stuck
door through the bridge.

    .venv/bin/python experiments/ros_acceptance.py --seeds 5 --out results/ros_acceptance.md

Each run starts the simulated robot and the controller as two processes on a private, machine-local
ROS 2 domain (`sabre.ros.launch.run_bridge`: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a free
ROS_DOMAIN_ID per run). The simulated robot places the object at its pose below and publishes it as a
perception node would; the controller (autostart) takes it from the pose topic, its robot description
from the robot_description topic, the object's state from its hand-pose estimator, and ends its task
once the task's success test passes on its state. The same seed, variant, pose and plant also run in
`run_episode` (simulated time, re-planning at 50 Hz, every plant step recorded) for the time to open
and the hand's contact force. Both runs end 0.5 s after the object is open.
Goals: at least 4 of 5 per object and variant; time to open within 1.5× of run_episode's; the hand's
contact force while in contact (`sabre.episode.hand_contact_forces`, per plant tick: the simulated
robot's summary and `Episode.hand_contact_forces`), its mean and its p99 each within 1.5× of
run_episode's; no reflex abort; state-to-command latency p99 at most 1 ms; at least 99.5 % of the
1 kHz states answered; every arm command within the command limits; the stuck door (held 5 s)
through the bridge keeps IO's tank above its floor. Reports the CPU the two nodes took (the planner
process apart) and the planner's rate.
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import sabre
from sabre import tasks
from sabre.episode import contact_force_stats
from sabre.ros import require_ros
from sabre.ros.launch import run_bridge
from sabre.ros.sim_robot import make_plant

#: Where each object stands (x, y, z, roll, pitch, yaw): 0.2–0.3 m aside and turned 10–20° from its default.
POSES: dict[str, tuple[float, ...]] = {
    "shelf": (1.0, 0.3, 0.0, 0.0, 0.0, math.radians(20.0)),
    "microwave": (1.0, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
    "dishwasher": (1.2, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
    "drawer": (1.2, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
}


#: The goal on the bridge's time to open and contact force, as a factor on run_episode's.
WITHIN = 1.5


def reference(obj: str, variant: str, seed: int, duration: float, plant: str) -> dict:
    """run_episode on the same object at the same pose and on the same plant: its time to open
    (simulated time; None if it did not) and the hand's contact force while in contact."""
    scene = sabre.Scene.load(obj=obj, obj_pose=POSES[obj])
    controller = sabre.Controller(scene, tasks.OpenObject(), sabre.ControllerConfig(variant=variant, seed=seed))
    episode = sabre.run_episode(
        scene,
        controller,
        duration,
        seed=seed,
        x0=sabre.paper.paper_start_state(scene),
        replan_rate=50.0,
        progress=False,
        record_every=1,  # the force at every plant step, as the simulated robot records it
        plant=make_plant(plant, scene, 0.001),
    )
    force = contact_force_stats(episode.hand_contact_forces)
    return {"time": episode.time_to_success if episode.success else None, "mean": force["mean"], "p99": force["p99"]}


def force_kept(row: dict) -> bool:
    """Whether the bridge's contact force, its mean and its p99, are each within WITHIN× run_episode's."""
    ref = row["reference"]
    return all(row[f"force_{k}"] <= WITHIN * ref[k] for k in ("mean", "p99"))


def within_limits(s: dict, c: dict) -> bool:
    limits = c.get("limits")
    if not limits or "arm_accel_max" not in s:
        return False
    return bool(
        np.all(np.array(s["arm_accel_max"]) <= np.array(limits["arm_acceleration"]) * (1 + 1e-6) + 1e-6)
        and np.all(np.array(s["arm_jerk_max"]) <= np.array(limits["arm_jerk"]) * (1 + 1e-6) + 1e-3)
        and np.all(np.array(s["arm_speed_max"]) <= np.array(limits["arm_velocity"]) + 1e-9)
    )


def one_run(obj: str, variant: str, seed: int, timeout: float, plant: str) -> dict:
    run = run_bridge(obj, variant, seed, timeout=timeout, object_pose=list(POSES[obj]), plant=plant)
    s, c = run.sim, run.controller
    ref = reference(obj, variant, seed, timeout, plant)
    row = {
        "opened": bool(s.get("success")),
        "time": s.get("time_to_open"),
        "reference": ref,
        "force_mean": s.get("contact_force_mean", float("nan")),
        "force_p99": s.get("contact_force_p99", float("nan")),
        "p50": s.get("latency_p50_ms", float("nan")),
        "p99": s.get("latency_p99_ms", float("nan")),
        "delivered": s.get("delivered_fraction", 0.0),
        "reflexes": s.get("reflex_aborts", -1),
        "limits_kept": within_limits(s, c),
        "late_ticks": s.get("late_ticks", 0),
        "planner_hz": c.get("planner_rate_hz", float("nan")),
        "cpu_controller": c.get("cpu_share", float("nan")),
        "cpu_sim": s.get("cpu_share", float("nan")),
    }
    print(
        f"{obj} {variant} seed {seed}: opened {row['opened']} in {row['time']} s (run_episode {ref['time']}), "
        f"contact force mean {row['force_mean']:.1f} N, p99 {row['force_p99']:.1f} N "
        f"(run_episode {ref['mean']:.1f} N, {ref['p99']:.1f} N), "
        f"p99 {row['p99']:.2f} ms, answered {100 * row['delivered']:.2f} %, reflexes {row['reflexes']}, "
        f"limits kept {row['limits_kept']}, CPU {100 * row['cpu_controller']:.0f} % / {100 * row['cpu_sim']:.0f} %",
        file=sys.stderr,
        flush=True,
    )
    return row


def force_cell(runs: list, key: str) -> str:
    """'bridge / run_episode' (N, medians over the runs that both opened) of a contact-force statistic."""
    both = [r for r in runs if r["opened"] and r["reference"]["time"] is not None]
    if not both:
        return "—"
    bridge = statistics.median(r[f"force_{key}"] for r in both)
    return f"{bridge:.0f} / {statistics.median(r['reference'][key] for r in both):.0f}"


def table(rows: list) -> list[str]:
    lines = [
        "| object | variant | opened | time to open, bridge / run_episode (median, max) "
        "| contact force mean, bridge / run_episode (N, median) | contact force p99, bridge / run_episode (N, median) "
        f"| force within {WITHIN:g}× | latency p50 / p99 (ms, worst run) "
        "| states answered (worst run) | reflex aborts | limits kept | planner (Hz, median) "
        "| CPU controller / sim robot (median) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for obj, variant, runs in rows:
        k = sum(r["opened"] for r in runs)
        ratios = [r["time"] / r["reference"]["time"] for r in runs if r["opened"] and r["reference"]["time"]]
        ratio = f"{statistics.median(ratios):.2f}×, {max(ratios):.2f}×" if ratios else "—"
        compared = [r for r in runs if r["opened"] and r["reference"]["time"] is not None]
        lines.append(
            f"| {obj} | {variant} | {k}/{len(runs)} | {ratio} "
            f"| {force_cell(runs, 'mean')} | {force_cell(runs, 'p99')} | {sum(force_kept(r) for r in compared)}/{len(compared)} "
            f"| {max(r['p50'] for r in runs):.2f} / {max(r['p99'] for r in runs):.2f} "
            f"| {100 * min(r['delivered'] for r in runs):.2f} % | {sum(max(r['reflexes'], 0) for r in runs)} "
            f"| {sum(r['limits_kept'] for r in runs)}/{len(runs)} | {statistics.median(r['planner_hz'] for r in runs):.0f} "
            f"| {100 * statistics.median(r['cpu_controller'] for r in runs):.0f} % / "
            f"{100 * statistics.median(r['cpu_sim'] for r in runs):.0f} % |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=list(sabre.OBJECTS), choices=sabre.OBJECTS)
    parser.add_argument("--variants", nargs="+", default=["N", "IO"], choices=["N", "I", "O", "IO"])
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. SEEDS-1")
    parser.add_argument("--plant", default="rapier", choices=["rapier", "mujoco"], help="the plant of both runs")
    parser.add_argument("--timeout", type=float, default=60.0, help="wall seconds per bridge run")
    parser.add_argument("--hold", type=float, default=5.0, help="stuck-door hold (s); 0 skips the stuck-door run")
    parser.add_argument("--out", type=Path, default=None, help="markdown report")
    args = parser.parse_args(argv)
    require_ros()

    started = time.perf_counter()
    rows: list = []
    for obj in args.objects:
        for variant in args.variants:
            rows.append((obj, variant, [one_run(obj, variant, seed, args.timeout, args.plant) for seed in range(args.seeds)]))
            if args.out is not None:  # the table so far, in case the run is cut short
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text("\n".join(["(partial)", ""] + table(rows)) + "\n")
    lines = table(rows)
    if args.hold > 0:
        run = run_bridge(
            "shelf",
            "IO",
            0,
            timeout=args.timeout + args.hold,
            object_pose=list(POSES["shelf"]),
            sim_params={"hold_at_opening": 0.3, "hold_duration": args.hold, "stop_on_success": True},
        )
        stuck = run.controller
        lines += [
            "",
            f"Stuck door through the bridge (shelf, IO, held {args.hold:g} s at 30 % of the range): "
            f"tank minimum {stuck.get('tank_min', float('nan')):.3f} J, floor {stuck.get('tank_floor', float('nan')):.3f} J, "
            f"filter fallbacks {stuck.get('filter_fallbacks')}, reflex aborts {run.sim.get('reflex_aborts')}, "
            f"opened {run.sim.get('success')}.",
        ]
    cpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
    model = next((ln.split(":", 1)[1].strip() for ln in cpu.splitlines() if ln.startswith("Model name")), "unknown")
    command = "python experiments/ros_acceptance.py " + " ".join(sys.argv[1:] if argv is None else argv)
    header = [f"Command: `{command}`; wall time {time.perf_counter() - started:.0f} s; CPU: {model}.", ""]
    report = "\n".join(header + lines) + "\n"
    print(report)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
