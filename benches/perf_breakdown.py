"""Groups a `perf` profile of a planning loop by where the time goes (the tables in docs/results.md).

    perf record -e cpu-clock -F 999 -g -o /tmp/contact.perf -- .venv/bin/python benches/profile_contact.py --iterations 300
    .venv/bin/python benches/perf_breakdown.py /tmp/contact.perf

Reads `perf report --no-children --sort dso,symbol` (self time per symbol) and sums the shares of
the symbols by the part of the program they belong to: Rapier's pipeline by stage, parry's
geometry, sabre's reduced contact step, kinematics and dynamics, cost, sampler, the rest of the
process. Prints a markdown table, largest share first.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections import defaultdict

# (category, pattern on "dso symbol"), first match wins.
CATEGORIES: tuple[tuple[str, str], ...] = (
    ("Rapier broad phase (BVH, AABBs)", r"rapier3d_f64::geometry::broad_phase|compute_aabb|bvh"),
    ("Rapier narrow phase (pairs, manifold upkeep)", r"rapier3d_f64::geometry::"),
    ("Rapier multibody (the object's joint)", r"rapier3d_f64::dynamics::joint::multibody"),
    ("Rapier constraint setup and solver", r"rapier3d_f64::dynamics::solver"),
    ("Rapier islands, pipeline upkeep, CCD, integration", r"rapier3d_f64::"),
    # sabre's box–box generator is inlined into the detection: the two count as one.
    (
        "contact detection and manifolds (screens, SAT, clipping, reduction; parry's and sabre's)",
        r"parry3d_f64::|sabre::sim::reduced::(geometry|box_box)",
    ),
    ("sabre contact solve (rows, sweeps)", r"sabre::sim::reduced::solver"),
    ("sabre contact step (object terms, proxies, τ_ext)", r"sabre::sim::reduced"),
    ("sabre kinematics, dynamics and servo", r"sabre::model::|sabre::sim::servo|nalgebra::|__sincos|libm\.so"),
    ("sabre cost", r"sabre::cost"),
    ("sabre world step, quiescence, rollout loop", r"sabre::sim::"),
    ("sabre sampler and update", r"sabre::mppi"),
    ("allocation and memory copies (libc)", r"libc\.so"),
    ("Python, NumPy, BLAS, kernel and the rest", r"."),
)

LINE = re.compile(r"^\s*([0-9.]+)%\s+(\S+)\s+\[[.k]\]\s+(.*?)\s*(?:-\s+-\s*)?$")


def breakdown(perf_data: str) -> dict[str, float]:
    report = subprocess.run(
        [
            "perf",
            "report",
            "-i",
            perf_data,
            "--no-children",
            "--sort",
            "dso,symbol",
            "--stdio",
            "-g",
            "none",
            "--percent-limit",
            "0",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    shares: dict[str, float] = defaultdict(float)
    for line in report.splitlines():
        m = LINE.match(line)
        if not m:
            continue
        share, dso, symbol = float(m.group(1)), m.group(2), m.group(3)
        for category, pattern in CATEGORIES:
            if re.search(pattern, f"{dso} {symbol}"):
                shares[category] += share
                break
    return dict(shares)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("perf_data", nargs="+", help="perf.data files; several give one column each")
    args = parser.parse_args(argv)
    columns = [breakdown(p) for p in args.perf_data]
    order = sorted({c for col in columns for c in col}, key=lambda c: -max(col.get(c, 0.0) for col in columns))
    print("| where | " + " | ".join(args.perf_data) + " |")
    print("|---|" + "---|" * len(columns))
    for category in order:
        print(f"| {category} | " + " | ".join(f"{col.get(category, 0.0):.1f} %" for col in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
