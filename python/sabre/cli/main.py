"""Command line of sabre: robust sampling-based control for mobile manipulators opening doors,
drawers and dishwashers.

  python -m sabre demo        closed-loop opening from the paper's start, with a figure (--view: in the browser)
  python -m sabre episode     the same, exit code 1 if the object did not open
  python -m sabre scripted    open-loop hook-and-pull check of the rollout model and the plant
  python -m sabre view        replay a saved episode (.npz) in the browser viewer
  python -m sabre experiment  the paper's experiments over seeds: CSV, figure, summary
  python -m sabre robot-check what sabre uses of a robot URDF, written as a <sabre> block to review
  python -m sabre ros-demo    the ROS 2 controller node and a simulated robot as two processes
  python -m sabre control     the ROS 2 controller node alone (sim-robot: the simulated robot)

Run `python -m sabre <command> --help` for the options of each."""

from __future__ import annotations

import argparse
import sys

from ..errors import SabreError
from . import episode, results, robot_check, ros
from ._args import TopHelpFormatter

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand; each subcommand sets ``run`` (args -> exit code)."""
    parser = argparse.ArgumentParser(prog="python -m sabre", description=__doc__, formatter_class=TopHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    for group in (episode, results, robot_check, ros):
        group.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parses ``argv`` (default: the command line) and runs the subcommand; returns its exit code, 1
    with a one-line message for a :class:`sabre.SabreError`. A usage error exits with 2 (SystemExit)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except SabreError as err:
        print(f"python -m sabre {args.command}: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
