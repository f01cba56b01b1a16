"""Command-line subcommands of the viewer and the experiments: ``view`` and ``experiment``, added to
``python -m sabre`` by :func:`register`."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    """Adds the ``view`` and ``experiment`` subcommands to an argparse subparsers object; each sets
    ``run`` (args -> exit code)."""
    view = sub.add_parser("view", help="replay a recorded episode (.npz from Episode.save) in the browser viewer")
    view.add_argument("episode", help="path of the .npz episode")
    view.add_argument("--host", default="127.0.0.1")
    view.add_argument("--port", type=int, default=8080)
    view.add_argument("--speed", type=float, default=1.0, help="playback speed (1 = real time)")
    view.set_defaults(run=_view)

    from ..experiments.runner import NAMES

    exp = sub.add_parser("experiment", help="run one of the paper's experiments over seeds and write its figure")
    exp.add_argument("name", choices=NAMES + ("all",))
    exp.add_argument("--seeds", type=int, default=2, help="seeds per configuration")
    exp.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    exp.add_argument("--ray", default=None, metavar="ADDRESS", help="run on a Ray cluster ('auto' or host:port)")
    exp.add_argument("--out", default="results", help="output folder (results/<name>/ inside)")
    exp.add_argument("--short", action="store_true", help="short durations (smoke test)")
    exp.set_defaults(run=_experiment)


def _view(args: argparse.Namespace) -> int:
    from ..viz.viewer import replay

    replay(args.episode, host=args.host, port=args.port, speed=args.speed)
    return 0


def _experiment(args: argparse.Namespace) -> int:
    from ..experiments.runner import run_experiments

    run_experiments(args.name, seeds=args.seeds, workers=args.workers, ray_address=args.ray, out=args.out,
                    short=args.short)
    return 0
