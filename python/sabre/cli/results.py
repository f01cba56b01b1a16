"""The subcommands over recorded runs: ``view`` (replay a saved episode in the browser) and
``experiment`` (run the paper's experiments over seeds and write their results)."""

from __future__ import annotations

import argparse

from ..experiments.runner import NAMES, run_experiments
from ..robot_examples import EXAMPLE_ROBOTS

__all__ = ["register", "view_command", "experiment_command"]


def register(sub: argparse._SubParsersAction) -> None:
    """Adds ``view`` and ``experiment``; each sets ``run`` (args -> exit code)."""
    view = sub.add_parser(
        "view",
        help="replay a recorded episode (.npz from Episode.save) in the browser viewer",
        description="Serves the episode with a timeline at http://HOST:PORT until interrupted "
        "(Ctrl-C), then stops the server and exits 0.",
    )
    view.add_argument("episode", help="path of the .npz episode")
    view.add_argument("--host", default="127.0.0.1", help="address to serve on")
    view.add_argument("--port", type=int, default=8080, help="port to serve on (0: any free port; the URL is printed)")
    view.add_argument("--speed", type=float, default=1.0, help="playback speed (1 = real time)")
    view.set_defaults(run=view_command)

    exp = sub.add_parser("experiment", help="run one of the paper's experiments over seeds and write its figure")
    exp.add_argument("name", choices=NAMES + ("all",))
    exp.add_argument("--seeds", type=int, default=2, help="seeds per configuration")
    exp.add_argument("--workers", type=int, default=None, help="local worker processes (default: cores)")
    exp.add_argument("--ray", default=None, metavar="ADDRESS", help="run on a Ray cluster ('auto' or host:port)")
    exp.add_argument("--out", default="results", help="output folder (results/<name>/ inside)")
    exp.add_argument("--short", action="store_true", help="short durations (smoke test)")
    exp.add_argument(
        "--plant",
        default="sabre",
        metavar="PLANT",
        help="the 1 kHz plant of every episode: sabre (Rapier), mujoco (sabre.MujocoPlant), or module:factory "
        "naming a callable that builds a sabre.PlantInterface from a scene (transfer runs both plants itself)",
    )
    exp.add_argument(
        "--robot",
        choices=("royalpanda", *EXAMPLE_ROBOTS),
        default="royalpanda",
        help="the acceptance's robot (an example robot opens its own objects, docs/robots.md) and the hook "
        "experiment's (a mobile one)",
    )
    exp.add_argument(
        "--objects",
        type=int,
        default=None,
        help="the hook and unknown experiments' generated objects per family (default 40 and 20, 2 and 0 with --short)",
    )
    exp.set_defaults(run=experiment_command)


def view_command(args: argparse.Namespace) -> int:
    """``view``: serves the episode until interrupted; 0."""
    from ..viz.viewer import replay

    replay(args.episode, host=args.host, port=args.port, speed=args.speed)
    return 0


def experiment_command(args: argparse.Namespace) -> int:
    """``experiment``: runs the named experiment (or all) and writes results/<name>/; 0."""
    plant = {"sabre": None, "mujoco": "sabre.mujoco:MujocoPlant"}.get(args.plant, args.plant)
    run_experiments(
        args.name,
        seeds=args.seeds,
        workers=args.workers,
        ray_address=args.ray,
        out=args.out,
        short=args.short,
        plant=plant,
        robot=args.robot,
        objects=args.objects,
    )
    return 0
