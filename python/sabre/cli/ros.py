"""The bridge's subcommands of ``python -m sabre``: ``control``, ``sim-robot`` and ``ros-demo``."""

from __future__ import annotations

import argparse
from typing import Any

from ..planner import VARIANTS
from ..scene import OBJECTS

__all__ = ["add_commands"]


def _ros_args(args: argparse.Namespace) -> list[str]:
    return [] if args.ros_args is None else ["--ros-args"] + list(args.ros_args)


def _control(args: argparse.Namespace) -> int:
    from ..ros.controller_node import run_controller

    overrides: dict[str, Any] = {"object": args.object, "variant": args.variant, "seed": args.seed}
    return run_controller({k: v for k, v in overrides.items() if v is not None}, _ros_args(args))


def _sim_robot(args: argparse.Namespace) -> int:
    from ..ros.sim_robot import run_sim_robot

    overrides: dict[str, Any] = {"object": args.object, "start": args.start}
    return run_sim_robot({k: v for k, v in overrides.items() if v is not None}, _ros_args(args))


def _ros_demo(args: argparse.Namespace) -> int:
    from ..ros import require_ros
    from ..ros.launch import format_run, run_bridge

    require_ros()
    print(f"[{args.object}] variant {args.variant}, seed {args.seed}: simulated robot and controller as two processes "
          f"over ROS 2 (loopback only), up to {args.timeout:.0f} s of wall-clock time")
    run = run_bridge(args.object, args.variant, args.seed, args.timeout)
    print(format_run(run))
    return 0 if run.sim.get("success") else 1


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Registers ``control``, ``sim-robot`` and ``ros-demo``. Node options given here win over
    ``--ros-args --params-file``; everything after ``--ros-args`` goes to ROS."""
    ctrl = subparsers.add_parser("control", help="ROS 2 controller node (needs the extra sabre-mpc[ros])")
    ctrl.add_argument("--object", choices=OBJECTS, default=None)
    ctrl.add_argument("--variant", choices=VARIANTS, default=None)
    ctrl.add_argument("--seed", type=int, default=None)
    ctrl.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None,
                      help="everything after it goes to ROS (-p name:=value, --params-file FILE, remappings)")
    ctrl.set_defaults(handler=_control)
    sim = subparsers.add_parser("sim-robot", help="ROS 2 simulated robot: the 1 kHz plant in wall-clock time")
    sim.add_argument("--object", choices=OBJECTS, default=None)
    sim.add_argument("--start", choices=("paper", "default"), default=None)
    sim.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None,
                      help="everything after it goes to ROS (-p name:=value, --params-file FILE, remappings)")
    sim.set_defaults(handler=_sim_robot)
    demo = subparsers.add_parser("ros-demo", help="both ROS 2 nodes as processes: open the object in real time")
    demo.add_argument("--object", choices=OBJECTS, default="shelf")
    demo.add_argument("--variant", choices=VARIANTS, default="IO")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--timeout", type=float, default=60.0, help="wall-clock seconds before giving up")
    demo.set_defaults(handler=_ros_demo)
