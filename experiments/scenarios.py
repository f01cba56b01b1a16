"""Runs the paper's Sec. VI-A scenarios for the controller variants and prints a markdown table.

.venv/bin/python experiments/scenarios.py --seeds 1 --duration 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sabre.paper import scenarios as S


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--duration", type=float, default=5.0, help="corridor and manipulation duration (s)")
    ap.add_argument("--hold", type=float, default=5.0, help="stuck-door hold time (s)")
    ap.add_argument("--release", type=float, default=10.0, help="stuck-door time after release (s)")
    ap.add_argument("--drivers", default="scripted,controller")
    args = ap.parse_args()
    seeds = range(args.seeds)
    start = time.perf_counter()
    print("| scenario | driver/variant | metric | value (mean over seeds) |")
    print("|---|---|---|---|")
    for driver in args.drivers.split(","):
        for v in ("N", "IO"):
            every = [S.stuck_door(v, s, args.hold, args.release, driver=driver) for s in seeds]
            rs = [r for r in every if r.held]  # a door never brought to the hold position has no stuck period
            print(
                f"| stuck door | {driver}/{v} | held / mean wrench stuck (N) / tank min (J) / opening after release | "
                f"{len(rs)} of {len(every)} / {np.mean([r.mean_wrench_stuck for r in rs]):.1f} / "
                f"{np.mean([r.tank_min for r in rs]):.2f} / {np.mean([r.opening_after_release for r in rs]):.3f} |"
            )
        for a in (1.0, 1000.0):
            rs = [S.tank_chattering(a, s, args.hold, 0.1, driver=driver) for s in seeds]
            print(
                f"| chattering | {driver}/IO α={a:g} | within 0.5 J of the floor: "
                "s / peak dissipation (W) / power variation (W/s) / tank min (J) | "
                f"{np.mean([r.floor_power.seconds for r in rs]):.2f} / "
                f"{np.mean([r.floor_power.peak_dissipation for r in rs]):.2f} / "
                f"{np.mean([r.floor_power.variation_per_s for r in rs]):.2f} / {np.mean([r.tank_min for r in rs]):.4f} |"
            )
    for v in ("N", "IO"):
        rs = [S.obstacle_corridor(v, s, args.duration) for s in seeds]
        print(
            f"| corridor | {v} | Σ cartesian violation / reached / obstacle appeared | "
            f"{sum(r.cartesian_violation for r in rs):.4f} / {sum(r.reached for r in rs)}/{len(rs)} / "
            f"{sum(r.appeared_at is not None for r in rs)}/{len(rs)} |"
        )
    for v in ("N", "O", "IO"):
        rs = [S.object_manipulation(v, "shelf", s, args.duration) for s in seeds]
        viol = {k: np.mean([r.violations[k] for r in rs]) for k in rs[0].violations}
        print(
            f"| manipulation shelf | {v} | success / violations | {sum(r.success for r in rs)}/{len(rs)} / "
            + ", ".join(f"{k} {val:.3g}" for k, val in viol.items())
            + " |"
        )
    print(f"\n{time.perf_counter() - start:.0f} s wall")


if __name__ == "__main__":
    main()
