"""Acceptance across processes: every object, placed away from its default pose, opened through the
ROS 2 bridge in wall-clock real time, against `run_episode` of the same seed and pose, plus the stuck
door through the bridge; on either arm interface, on a quiet or a loaded machine.

    .venv/bin/python experiments/ros_acceptance.py --seeds 5 --out results/ros_acceptance.md
    .venv/bin/python experiments/ros_acceptance.py --seeds 5 --load --out results/ros_acceptance_loaded.md
    .venv/bin/python experiments/ros_acceptance.py --interface velocity --tolerated-gap 0.005 --load

Each run starts the simulated robot and the controller as two processes on a private, machine-local
ROS 2 domain (`sabre.ros.launch.run_bridge`: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a free
ROS_DOMAIN_ID per run), both on the arm interface `--interface` (joint_trajectory_controller's topic,
or the velocity stream with its `--tolerated-gap`). The simulated robot checks Franka's reflexes on
the command in effect at each of its 1 kHz cycles, delivery included (`reflex_check: cycle`), places
the object at its pose below and publishes it as a perception node would; the controller (autostart)
takes it from the pose topic, its robot description from the robot_description topic, the object's
state from its hand-pose estimator, and ends its task once the task's success test passes on its
state. `--load` runs one busy loop pinned to each core beside the nodes. The same seed, variant, pose
and plant also run in `run_episode` (simulated time, re-planning at 50 Hz, every plant step recorded)
for the time to open and the hand's contact force; its results are kept in `--cache` (they do not
depend on the interface or the load). Both runs end 0.5 s after the object is open.
Goals: at least 38 of 40 opened; median time to open at most 1.2× run_episode's; the hand's contact
force while in contact (`sabre.episode.hand_contact_forces`, per plant tick: the simulated robot's
summary and `Episode.hand_contact_forces`), its mean and its p99 each within 1.5× of run_episode's;
no reflex abort; every command in effect within the interface's limits; the stuck door (held 5 s)
through the bridge keeps IO's tank above its floor. Reports the gaps between deliveries the robot
saw, the CPU the two nodes took (the planner process apart) and the planner's rate.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import sabre
from load import busy_cores
from sabre import tasks
from sabre.episode import contact_force_stats
from sabre.ros import params, require_ros
from sabre.ros.commands import command_limits, joint_accelerations
from sabre.ros.launch import run_bridge
from sabre.ros.sim_robot import make_plant
from sabre.ros.trajectory import trajectory_limits

#: Where each object stands (x, y, z, roll, pitch, yaw): 0.2–0.3 m aside and turned 10–20° from its default.
POSES: dict[str, tuple[float, ...]] = {
    "shelf": (1.0, 0.3, 0.0, 0.0, 0.0, math.radians(20.0)),
    "microwave": (1.0, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
    "dishwasher": (1.2, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
    "drawer": (1.2, 0.2, 0.0, 0.0, 0.0, math.radians(10.0)),
}


#: The goals on the bridge's median time to open and on its contact force, as factors on run_episode's.
TIME_WITHIN = 1.2
WITHIN = 1.5


def command_path(scene: sabre.Scene, interface: str, tolerated_gap: float) -> tuple[float, ...]:
    """Per joint, the acceleration bound (rad/s², m/s²) of the bridge's command path at its default
    parameters: the arm's segments' (trajectory) or stream's (velocity), the base stream's."""
    defaults = {k: [] if v == params.UNSET_DOUBLES else v for k, v in params.CONTROLLER_PARAMETERS.items()}
    p = defaults | {"arm_interface": interface, "tolerated_gap": tolerated_gap}
    base = list(scene.base_indices) if scene.base_indices is not None else []
    arm = [i for i in range(scene.nq) if i not in base]
    dq = np.asarray(scene.dq_limit)
    limits = command_limits(dq[arm], dq[base] if base else None, p)
    arm_acceleration = trajectory_limits(dq[arm], p).acceleration if interface == "trajectory" else limits.arm.acceleration
    return joint_accelerations(scene.nq, arm, arm_acceleration, base or None, limits.base)


def reference(obj: str, variant: str, seed: int, duration: float, plant: str, path: tuple[float, ...] | None = None) -> dict:
    """run_episode on the same object at the same pose and on the same plant: its time to open
    (simulated time; None if it did not) and the hand's contact force while in contact. With ``path``
    (per joint acceleration bounds), on the bridge's command path: the plant's servo tracks commands
    rate-limited at those bounds (`LowLevelController(command_acceleration=...)`) and the planner knows
    them (`ControllerConfig.command_acceleration`), as the bridge's planner does."""
    scene = sabre.Scene.load(obj=obj, obj_pose=POSES[obj])
    config = sabre.ControllerConfig(variant=variant, seed=seed, command_acceleration=path)
    controller = sabre.Controller(scene, tasks.OpenObject(), config)
    low_level = None if path is None else sabre.LowLevelController(scene, dt=0.001, command_acceleration=path)
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
        low_level=low_level,
    )
    force = contact_force_stats(episode.hand_contact_forces)
    return {"time": episode.time_to_success if episode.success else None, "mean": force["mean"], "p99": force["p99"]}


def force_kept(row: dict, ref: str = "reference") -> bool:
    """Whether the bridge's contact force, its mean and its p99, are each within WITHIN× the
    reference's (``reference``: run_episode's; ``on_path``: run_episode's on the command path)."""
    return all(row[f"force_{k}"] <= WITHIN * row[ref][k] for k in ("mean", "p99"))


def within_limits(s: dict, c: dict) -> bool:
    """Whether the command in effect at every robot cycle kept the interface's velocity, acceleration
    and jerk bounds, to rounding (a few parts in 10⁶: the segments and the stream reach their bounds,
    and the robot evaluates them on its own clock)."""
    limits = c.get("limits")
    if not limits or "arm_accel_max" not in s:
        return False
    return all(
        np.all(np.array(s[seen]) <= np.array(limits[bound]) * (1 + 1e-5) + 1e-9)
        for seen, bound in (
            ("arm_speed_max", "arm_velocity"),
            ("arm_accel_max", "arm_acceleration"),
            ("arm_jerk_max", "arm_jerk"),
        )
    )


def cached_reference(
    cache: Path | None, obj: str, variant: str, seed: int, duration: float, plant: str, path: tuple[float, ...] | None = None
) -> dict:
    """:func:`reference`, read from and written to the JSON file ``cache`` (None: always run)."""
    key = f"{obj}/{variant}/{seed}/{duration:g}/{plant}" + ("" if path is None else "/path " + " ".join(f"{a:g}" for a in path))
    known = json.loads(cache.read_text()) if cache is not None and cache.exists() else {}
    if key not in known:
        known[key] = reference(obj, variant, seed, duration, plant, path)
        if cache is not None:
            cache.parent.mkdir(parents=True, exist_ok=True)
            cache.write_text(json.dumps(known, indent=1))
    return known[key]


def one_run(obj: str, variant: str, seed: int, args: argparse.Namespace) -> dict:
    interface = {"arm_interface": args.interface, "tolerated_gap": args.tolerated_gap}
    with busy_cores(args.load):
        run = run_bridge(
            obj,
            variant,
            seed,
            timeout=args.timeout,
            object_pose=list(POSES[obj]),
            plant=args.plant,
            sim_params={"arm_interface": args.interface, "reflex_check": "cycle"},
            controller_params=interface,
        )
    s, c = run.sim, run.controller
    ref = cached_reference(args.cache, obj, variant, seed, args.timeout, args.plant)
    scene = sabre.Scene.load(obj=obj, obj_pose=POSES[obj])
    path = command_path(scene, args.interface, args.tolerated_gap)
    on_path = cached_reference(args.cache, obj, variant, seed, args.timeout, args.plant, path)
    gaps = s.get("delivery_gaps", {})
    row = {
        "opened": bool(s.get("success")),
        "time": s.get("time_to_open"),
        "reference": ref,
        "on_path": on_path,
        "force_mean": s.get("contact_force_mean", float("nan")),
        "force_p99": s.get("contact_force_p99", float("nan")),
        "gap_p99": gaps.get("p99_ms", float("nan")),
        "gap_max": gaps.get("max_ms", float("nan")),
        "reflexes": s.get("reflex_aborts", -1),
        "reflex_errors": s.get("reflex_errors", [])[:1],
        "limits_kept": within_limits(s, c),
        "late_ticks": s.get("late_ticks", 0),
        "planner_hz": c.get("planner_rate_hz", float("nan")),
        "cpu_controller": c.get("cpu_share", float("nan")),
        "cpu_sim": s.get("cpu_share", float("nan")),
    }
    print(
        f"{obj} {variant} seed {seed}: opened {row['opened']} in {row['time']} s (run_episode {ref['time']}), "
        f"contact force mean {row['force_mean']:.1f} N, p99 {row['force_p99']:.1f} N "
        f"(run_episode {ref['mean']:.1f} N, {ref['p99']:.1f} N; on the command path {on_path['time']} s, "
        f"{on_path['mean']:.1f} N, {on_path['p99']:.1f} N), delivery gaps p99 {row['gap_p99']:g} ms, "
        f"max {row['gap_max']:g} ms, reflexes {row['reflexes']} {row['reflex_errors']}, "
        f"limits kept {row['limits_kept']}, CPU {100 * row['cpu_controller']:.0f} % / {100 * row['cpu_sim']:.0f} %",
        file=sys.stderr,
        flush=True,
    )
    return row


def compared(runs: list, ref: str) -> list:
    """The runs that opened through the bridge and in the reference ``ref``."""
    return [r for r in runs if r["opened"] and r[ref]["time"] is not None]


def force_cell(runs: list, key: str, ref: str = "reference") -> str:
    """'bridge / reference' (N, medians over the runs that both opened) of a contact-force statistic."""
    both = compared(runs, ref)
    if not both:
        return "—"
    bridge = statistics.median(r[f"force_{key}"] for r in both)
    return f"{bridge:.0f} / {statistics.median(r[ref][key] for r in both):.0f}"


def ratio_cell(runs: list, ref: str) -> str:
    """The bridge's time to open over the reference's: median and largest."""
    ratios = [r["time"] / r[ref]["time"] for r in compared(runs, ref)]
    return f"{statistics.median(ratios):.2f}×, {max(ratios):.2f}×" if ratios else "—"


def table(rows: list) -> list[str]:
    lines = [
        "| object | variant | opened (bridge; run_episode, on the command path) "
        "| time to open, bridge / run_episode (median, max) "
        "| contact force mean, bridge / run_episode (N, median) | contact force p99, bridge / run_episode (N, median) "
        f"| force within {WITHIN:g}× | time, bridge / on the command path | force mean, p99, bridge / on the command path (N) "
        f"| force within {WITHIN:g}× of the command path | delivery gaps p99 / max (ms, worst run) "
        "| reflex aborts | limits kept | planner (Hz, median) | CPU controller / sim robot (median) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for obj, variant, runs in rows:
        n = len(runs)
        opened = sum(r["opened"] for r in runs)
        references = ", ".join(str(sum(r[ref]["time"] is not None for r in runs)) for ref in ("reference", "on_path"))
        both, on_path = compared(runs, "reference"), compared(runs, "on_path")
        lines.append(
            f"| {obj} | {variant} | {opened}/{n} ({references}) | {ratio_cell(runs, 'reference')} "
            f"| {force_cell(runs, 'mean')} | {force_cell(runs, 'p99')} | {sum(force_kept(r) for r in both)}/{len(both)} "
            f"| {ratio_cell(runs, 'on_path')} | {force_cell(runs, 'mean', 'on_path')}, {force_cell(runs, 'p99', 'on_path')} "
            f"| {sum(force_kept(r, 'on_path') for r in on_path)}/{len(on_path)} "
            f"| {max(r['gap_p99'] for r in runs):g} / {max(r['gap_max'] for r in runs):g} "
            f"| {sum(max(r['reflexes'], 0) for r in runs)} "
            f"| {sum(r['limits_kept'] for r in runs)}/{n} | {statistics.median(r['planner_hz'] for r in runs):.0f} "
            f"| {100 * statistics.median(r['cpu_controller'] for r in runs):.0f} % / "
            f"{100 * statistics.median(r['cpu_sim'] for r in runs):.0f} % |"
        )
    return lines


def totals(rows: list) -> str:
    """The whole run against the goals: opened, median time ratio, aborts, forces; against both references."""
    runs = [r for _, _, rs in rows for r in rs]

    def median_ratio(ref: str) -> str:
        ratios = [r["time"] / r[ref]["time"] for r in compared(runs, ref)]
        return f"{statistics.median(ratios):.2f}×" if ratios else "—"

    aborts = sum(max(r["reflexes"], 0) for r in runs)
    both, on_path = compared(runs, "reference"), compared(runs, "on_path")
    return (
        f"In all: opened {sum(r['opened'] for r in runs)}/{len(runs)} (run_episode "
        f"{sum(r['reference']['time'] is not None for r in runs)}, on the command path "
        f"{sum(r['on_path']['time'] is not None for r in runs)}), median time to open {median_ratio('reference')} "
        f"run_episode's (goal ≤ {TIME_WITHIN:g}×) and {median_ratio('on_path')} its on the command path, reflex aborts "
        f"{aborts}, contact force within {WITHIN:g}× in {sum(force_kept(r) for r in both)} of the {len(both)} runs both "
        f"opened and within {WITHIN:g}× of the command path's in "
        f"{sum(force_kept(r, 'on_path') for r in on_path)} of {len(on_path)}."
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=list(sabre.OBJECTS), choices=sabre.OBJECTS)
    parser.add_argument("--variants", nargs="+", default=["N", "IO"], choices=["N", "I", "O", "IO"])
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. SEEDS-1")
    parser.add_argument("--plant", default="rapier", choices=["rapier", "mujoco"], help="the plant of both runs")
    parser.add_argument("--timeout", type=float, default=60.0, help="wall seconds per bridge run")
    parser.add_argument("--hold", type=float, default=5.0, help="stuck-door hold (s); 0 skips the stuck-door run")
    parser.add_argument("--interface", default="trajectory", choices=["trajectory", "velocity"], help="the arm's interface")
    parser.add_argument("--tolerated-gap", type=float, default=0.005, help="the velocity stream's promise (s)")
    parser.add_argument("--load", action="store_true", help="a busy loop pinned to each core beside the nodes")
    parser.add_argument("--cache", type=Path, default=Path("results/run_episode_references.json"), help="run_episode's results")
    parser.add_argument("--out", type=Path, default=None, help="markdown report")
    args = parser.parse_args(argv)
    require_ros()

    started = time.perf_counter()
    rows: list = []
    for obj in args.objects:
        for variant in args.variants:
            rows.append((obj, variant, [one_run(obj, variant, seed, args) for seed in range(args.seeds)]))
            if args.out is not None:  # the table so far, in case the run is cut short
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text("\n".join(["(partial)", ""] + table(rows)) + "\n")
    lines = [*table(rows), "", totals(rows)]
    if args.hold > 0:
        with busy_cores(args.load):
            run = run_bridge(
                "shelf",
                "IO",
                0,
                timeout=args.timeout + args.hold,
                object_pose=list(POSES["shelf"]),
                sim_params={"hold_at_opening": 0.3, "hold_duration": args.hold, "stop_on_success": True}
                | {"arm_interface": args.interface, "reflex_check": "cycle"},
                controller_params={"arm_interface": args.interface, "tolerated_gap": args.tolerated_gap},
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
    condition = f"arm interface {args.interface}"
    if args.interface == "velocity":
        condition += f" (tolerated_gap {args.tolerated_gap:g} s)"
    condition += ", a busy loop pinned to each core" if args.load else ", quiet machine"
    header = [f"Command: `{command}`; {condition}; wall time {time.perf_counter() - started:.0f} s; CPU: {model}.", ""]
    report = "\n".join(header + lines) + "\n"
    print(report)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
