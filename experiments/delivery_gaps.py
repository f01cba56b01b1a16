"""The velocity stream's delivery gaps as the arm sees them, quiet and under load, and the reflex
aborts each tolerance (`tolerated_gap`) gives: the shelf at its moved pose opened through the bridge
(the simulated robot checking the command in effect at each cycle, its own late ticks excused).

    .venv/bin/python experiments/delivery_gaps.py --tolerances 0.003 0.005 0.01 --seeds 2

"Loaded" runs one busy loop pinned to each core beside the nodes (`taskset`), for the run only.
Each run starts both nodes on a private, machine-local ROS 2 domain (`sabre.ros.launch.run_bridge`).
Prints one row per condition, tolerance and seed: opened, time to open, reflex aborts, and the gaps
between deliveries (count, p50, p99, p99.9, largest) the robot saw.
"""

from __future__ import annotations

import argparse

from load import busy_cores
from sabre.ros import params
from sabre.ros.launch import run_bridge

POSE = [1.0, 0.3, 0.0, 0.0, 0.0, 0.349]


def run(obj: str, variant: str, seed: int, gap: float, loaded: bool, timeout: float) -> dict:
    velocity = {"arm_interface": "velocity"}
    sensor = {"object_state_topic": params.SIM_ROBOT_PARAMETERS["ground_truth_topic"], "tolerated_gap": gap} | velocity
    with busy_cores(loaded):
        sim = {"reflex_check": "cycle"} | velocity
        result = run_bridge(obj, variant, seed, timeout=timeout, object_pose=POSE, sim_params=sim, controller_params=sensor)
    s = result.sim or {}
    return {
        "opened": bool(s.get("success")),
        "time": s.get("time_to_open"),
        "aborts": s.get("reflex_aborts"),
        "errors": s.get("reflex_errors", [])[:1],
        "gaps": s.get("delivery_gaps", {}),
        "late_ticks": s.get("late_ticks"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.003, 0.005, 0.01])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--conditions", nargs="+", default=["quiet", "loaded"], choices=["quiet", "loaded"])
    parser.add_argument("--timeout", type=float, default=90.0)
    args = parser.parse_args(argv)
    print("| condition | tolerated_gap (ms) | seed | opened | time (s) | aborts | gaps: count | p50 | p99 | p99.9 | max (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for condition in args.conditions:
        for gap in args.tolerances:
            for seed in range(args.seeds):
                r = run("shelf", "IO", seed, gap, condition == "loaded", args.timeout)
                g = r["gaps"]
                time = f"{r['time']:.1f}" if r["time"] is not None else "-"
                print(
                    f"| {condition} | {gap * 1e3:g} | {seed} | {r['opened']} | {time} | {r['aborts']} | "
                    f"{g.get('count', 0):.0f} | {g.get('p50_ms', float('nan')):g} | {g.get('p99_ms', float('nan')):g} | "
                    f"{g.get('p99.9_ms', float('nan')):g} | {g.get('max_ms', float('nan')):g} |",
                    flush=True,
                )
                if r["errors"]:
                    print(f"  reflex: {r['errors'][0]}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
