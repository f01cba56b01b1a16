"""``python -m sabre robot-check``: what sabre makes of a robot URDF, printed and written as a ``<sabre>`` block."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InvalidValueError
from ..robot_block import describe, sabre_block, with_sabre_block
from ..robots import TOOLS, Tool
from ..scene import OBJECTS, Scene
from ._args import HelpFormatter

__all__ = ["register", "robot_check_command"]


def register(sub: argparse._SubParsersAction) -> None:
    """Adds the ``robot-check`` subcommand."""
    check = sub.add_parser(
        "robot-check",
        help="what sabre uses of a robot URDF (joints, limits, tool frame, spheres, pairs, reach), written as a <sabre> block",
        description=(
            "Loads a robot URDF as sabre does (attaching a tool, holding joints, detecting the base and the tool "
            "frame, generating the safety geometry the URDF does not declare), prints what it found, and writes the "
            "URDF with a <sabre> block that declares all of it, to review and edit."
        ),
        formatter_class=HelpFormatter,
    )
    check.add_argument("urdf", help="the robot's URDF file")
    check.add_argument("--out", default=None, help="where to write the URDF with the block (default: <urdf stem>.sabre.urdf)")
    check.add_argument("--tool", default=None, help=f"attach a tool: a shipped one {TOOLS} or a URDF fragment file")
    check.add_argument("--tool-parent", default=None, help="the link the tool is fixed to (needed with --tool)")
    check.add_argument("--tool-xyz", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    check.add_argument("--tool-rpy", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "P", "Y"))
    check.add_argument("--tool-frame", default=None, help="the control frame (default: the tool's, else detected)")
    check.add_argument("--hold", action="append", default=[], metavar="JOINT=VALUE", help="hold a joint (repeatable)")
    base = check.add_mutually_exclusive_group()
    base.add_argument("--fixed-base", action="store_true", help="the robot has no base to move")
    base.add_argument("--base-joints", nargs=3, default=None, metavar=("X", "Y", "YAW"), help="a holonomic base's joints")
    check.add_argument("--object", choices=OBJECTS, default="shelf", help="the built-in object of the scene it is loaded in")
    check.set_defaults(run=robot_check_command)


def _holds(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        joint, sep, value = item.partition("=")
        if not sep:
            raise InvalidValueError(f"--hold {item!r}: expected JOINT=VALUE")
        try:
            out[joint] = float(value)
        except ValueError:
            raise InvalidValueError(f"--hold {item!r}: {value!r} is not a number") from None
    return out


def robot_check_command(args: argparse.Namespace) -> int:
    """Prints the robot's report and writes its URDF with the declaring block; exit code 0."""
    tool = None
    if args.tool is not None:
        if args.tool_parent is None:
            raise InvalidValueError("--tool needs --tool-parent: the link it is fixed to")
        tool = Tool(args.tool_parent, args.tool, args.tool_xyz, args.tool_rpy)
    base = "fixed" if args.fixed_base else args.base_joints
    scene = Scene.from_urdf(
        args.urdf, args.object, tool=tool, tool_frame=args.tool_frame, robot_hold=_holds(args.hold) or None, base=base
    )
    print(describe(scene))
    source = Path(args.urdf)
    out = Path(args.out) if args.out is not None else source.with_name(f"{source.stem}.sabre.urdf")
    out.write_text(with_sabre_block(source.read_text(), sabre_block(scene)))
    print(f"wrote {out}: the URDF with a <sabre> block declaring all of the above")
    return 0
