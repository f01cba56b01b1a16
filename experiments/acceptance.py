"""Closed-loop acceptance over a chosen set of objects, variants and seeds, as a markdown table.

The runs are those of ``python -m sabre experiment acceptance`` (:func:`sabre.experiments.runner.acceptance_specs`,
run and cached by the same runner under ``<out>/acceptance/runs/``): each opens one object from the
paper's start with the controller (Table I defaults) on the 1 kHz plant, for up to --duration s of
simulated time, re-planning at --replan-rate Hz, stopping 0.5 s after success. With the defaults
they are the experiment's own runs, so each script and command reuses what the other computed.
The table lists, per object and variant: episodes that opened, time to open, final opening (and the
one success needs), mean wrench, real-time factor, planning time, and the seeds that did not open.

    .venv/bin/python experiments/acceptance.py --seeds 10
    .venv/bin/python experiments/acceptance.py --objects shelf drawer --seeds 3 --variant N IO
    .venv/bin/python experiments/acceptance.py --robot panda_pedestal --seeds 5 --variant N IO
    .venv/bin/python experiments/acceptance.py --rollouts 160 --seeds 10 --variant N IO
"""

from __future__ import annotations

import argparse
from pathlib import Path

import sabre
from sabre.experiments.figures import acceptance_table
from sabre.experiments.runner import acceptance_specs, run_specs
from sabre.robot_examples import EXAMPLE_ROBOTS


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--robot", choices=("royalpanda", *EXAMPLE_ROBOTS), default="royalpanda", help="the robot")
    parser.add_argument("--objects", nargs="+", choices=sabre.OBJECTS, default=None, help="default: the robot's objects")
    parser.add_argument("--variant", nargs="+", choices=sabre.VARIANTS, default=["IO"], help="one or more variants")
    parser.add_argument("--seeds", type=int, default=10, help="seeds per object and variant")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=60.0, help="longest episode, s of simulated time")
    parser.add_argument("--replan-rate", type=float, default=50.0, help="re-planning rate, Hz of simulated time")
    parser.add_argument("--rollouts", type=int, default=None, help="samples per iteration (default: the controller's)")
    parser.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    parser.add_argument("--out", default="results", help="output folder (runs cached in <out>/acceptance/runs/)")
    args = parser.parse_args(argv)
    runs = acceptance_specs(
        range(args.first_seed, args.first_seed + args.seeds),
        objects=args.objects or sabre.OBJECTS,
        variants=args.variant,
        duration=args.duration,
        replan_rate=args.replan_rate,
        robot=args.robot,
        rollouts=args.rollouts,
    )
    records = run_specs(runs, Path(args.out) / "acceptance", workers=args.workers)
    print(
        f"\n{args.duration:g} s limit, re-planning at {args.replan_rate:g} Hz, seeds {args.first_seed}–"
        f"{args.first_seed + args.seeds - 1}\n"
    )
    print(acceptance_table(records))


if __name__ == "__main__":
    main()
