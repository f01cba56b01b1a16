"""The bridge's subcommands of ``python -m sabre``: ``control`` (the lifecycle controller node),
``sim-robot`` and ``ros-demo`` (both as processes, the controller started by its ``autostart``). The
ROS 2 modules are imported when a command runs, so the parser builds without the ros extra."""

from __future__ import annotations

import argparse
from typing import Any

from .. import OBJECTS, VARIANTS

__all__ = ["register", "control_command", "sim_robot_command", "ros_demo_command"]

_ROS_ARGS_HELP = "everything after it goes to ROS (-p name:=value, --params-file FILE, remappings)"


def register(sub: argparse._SubParsersAction) -> None:
    """Adds ``control``, ``sim-robot`` and ``ros-demo``; each sets ``run`` (args -> exit code). Node
    options given here win over ``--ros-args --params-file``; everything after ``--ros-args`` goes to ROS."""
    ctrl = sub.add_parser("control", help="ROS 2 controller node (needs the extra sabre-mpc[ros])")
    ctrl.add_argument("--object", choices=OBJECTS, default=None)
    ctrl.add_argument("--variant", choices=VARIANTS, default=None)
    ctrl.add_argument("--seed", type=int, default=None)
    ctrl.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None, help=_ROS_ARGS_HELP)
    ctrl.set_defaults(run=control_command)
    sim = sub.add_parser("sim-robot", help="ROS 2 simulated robot: the 1 kHz plant in wall-clock time")
    sim.add_argument("--object", choices=OBJECTS, default=None)
    sim.add_argument("--start", choices=("paper", "default"), default=None)
    sim.add_argument("--plant", choices=("rapier", "mujoco"), default=None)
    sim.add_argument("--robot", default=None, help=_ROBOT_HELP)
    sim.add_argument(
        "--object-pose", dest="object_pose", type=float, nargs=6, default=None, metavar=("X", "Y", "Z", "R", "P", "YAW")
    )
    sim.add_argument("--ros-args", dest="ros_args", nargs=argparse.REMAINDER, default=None, help=_ROS_ARGS_HELP)
    sim.set_defaults(run=sim_robot_command)
    demo = sub.add_parser("ros-demo", help="both ROS 2 nodes as processes: open the object in real time")
    demo.add_argument("--object", choices=OBJECTS, default="shelf")
    demo.add_argument("--variant", choices=VARIANTS, default="IO")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--timeout", type=float, default=60.0, help="wall-clock seconds before giving up")
    demo.add_argument("--plant", choices=("rapier", "mujoco"), default="rapier", help="the simulated robot's plant")
    demo.add_argument("--robot", default=None, help=_ROBOT_HELP)
    demo.add_argument(
        "--object-pose",
        dest="object_pose",
        type=float,
        nargs=6,
        default=None,
        metavar=("X", "Y", "Z", "R", "P", "YAW"),
        help="where the simulated robot places the object (the controller reads it from the pose topic)",
    )
    demo.set_defaults(run=ros_demo_command)


_ROBOT_HELP = (
    "the simulated robot: an example robot (panda_pedestal, ur5_mobile; the object where it opens it) or a URDF "
    "file (default: the RoyalPanda); published as the robot description the controller reads"
)


def _ros_args(args: argparse.Namespace) -> list[str]:
    return [] if args.ros_args is None else ["--ros-args"] + list(args.ros_args)


def _given(**options: Any) -> dict[str, Any]:
    """The node options set on the command line (the others come from ROS parameters)."""
    return {k: v for k, v in options.items() if v is not None}


def control_command(args: argparse.Namespace) -> int:
    """``control``: the controller node until SIGINT or SIGTERM; its exit code."""
    from ..ros.controller_node import run_controller

    return run_controller(_given(object=args.object, variant=args.variant, seed=args.seed), _ros_args(args))


def sim_robot_command(args: argparse.Namespace) -> int:
    """``sim-robot``: the simulated robot node until it stops; its exit code."""
    from ..ros.sim_robot import run_sim_robot

    pose = None if args.object_pose is None else [float(v) for v in args.object_pose]
    robot = None
    if args.robot is not None:
        from ..ros.launch import robot_file

        robot, example_pose = robot_file(args.robot, args.object or "shelf")
        pose = example_pose if pose is None else pose
    options = _given(object=args.object, start=args.start, plant=args.plant, object_pose=pose, robot_description_file=robot)
    return run_sim_robot(options, _ros_args(args))


def ros_demo_command(args: argparse.Namespace) -> int:
    """``ros-demo``: both nodes as processes; 0 if the simulated robot reports the object open, else 1."""
    from ..ros import require_ros
    from ..ros.launch import format_run, run_bridge

    require_ros()
    print(
        f"[{args.object}] variant {args.variant}, seed {args.seed}: simulated robot and controller as two processes "
        f"over ROS 2 (loopback only), up to {args.timeout:.0f} s of wall-clock time"
    )
    run = run_bridge(
        args.object, args.variant, args.seed, args.timeout, object_pose=args.object_pose, plant=args.plant, robot=args.robot
    )
    print(format_run(run))
    return 0 if run.sim.get("success") else 1
