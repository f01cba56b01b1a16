"""Stuck door (the paper's Fig. 11 scenario) over many seeds: wrench, tank and whether the bar was kept.

    .venv/bin/python experiments/stuck_door_seeds.py --variant IO --seeds 0 20

Runs ``sabre.paper.scenarios.stuck_door(variant, seed)`` for each seed and prints one JSON line per run:
the mean wrench while the door is held, the lowest tank energy and its floor, the opening in the
10 s after release, whether the task left the open phase during the hold (the bar was lost) and,
if so, whether it was in the open phase again afterwards (hooked again); then a summary line.
"""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

from sabre import VARIANTS
from sabre.paper import scenarios


def run(variant: str, seed: int) -> dict:
    r = scenarios.stuck_door(variant, seed=seed)
    ep = r.episode
    phases = np.array([ep.phases[p] for p in ep.phase])
    hold = (ep.time >= r.hold_start) & (ep.time <= r.hold_start + r.hold_seconds)
    lost = bool(np.any(phases[hold] != "open")) if r.held else None
    rehooked = bool(np.any(phases[ep.time > r.hold_start + r.hold_seconds] == "open")) if lost else None
    return {
        "seed": seed,
        "held": r.held,
        "hold_start": r.hold_start,
        "wrench": r.mean_wrench_stuck,
        "tank_min": r.tank_min,
        "floor": r.tank_floor,
        "opening_after": r.opening_after_release,
        "lost_bar": lost,
        "rehooked": rehooked,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="IO", choices=VARIANTS)
    parser.add_argument("--seeds", type=int, nargs=2, default=(0, 20), metavar=("FIRST", "END"))
    args = parser.parse_args()
    rows = []
    for seed in range(*args.seeds):
        rows.append(run(args.variant, seed))
        print(json.dumps(rows[-1]), flush=True)
    held = [r for r in rows if r["held"]]
    if held:
        wrench = [r["wrench"] for r in held]
        print(
            f"{args.variant}: held {len(held)}/{len(rows)}, wrench mean {statistics.mean(wrench):.1f} N "
            f"(median {statistics.median(wrench):.1f} N), lowest tank {min(r['tank_min'] for r in rows):.4f} J, "
            f"bar lost in {sum(bool(r['lost_bar']) for r in held)}, hooked again in {sum(bool(r['rehooked']) for r in held)}"
        )


if __name__ == "__main__":
    main()
