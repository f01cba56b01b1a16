"""The ROS 2 hardware bridge: a controller node around :class:`sabre.RealtimeCascade`, a simulated
robot node around the 1 kHz :class:`sabre.Plant`, the object-state estimator and the launcher of
both (``python -m sabre control | sim-robot | ros-demo``); see docs/ros2.md.

Needs the optional extra ``sabre-mpc[ros]`` (ROS 2 from pip wheels, no system ROS). ``import
sabre`` works without it; the node modules raise :class:`RosUnavailableError` (a
:class:`sabre.MissingExtraError`) naming the extra. The estimator and the message conversions are
plain NumPy and import without ROS.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Callable
from typing import Any

from ..errors import MissingExtraError

__all__ = ["RosUnavailableError", "require_ros", "spin_node", "ROS_EXTRA"]

ROS_EXTRA = "sabre-mpc[ros]"


class RosUnavailableError(MissingExtraError):
    """The ROS 2 Python packages (rclpy and the message packages) are not installed."""


def require_ros():
    """Imports and returns ``rclpy`` after choosing the DDS implementation the extra installs
    (Fast DDS, unless ``RMW_IMPLEMENTATION`` is already set); raises :class:`RosUnavailableError`
    naming the extra when the wheels are missing."""
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    try:
        import diagnostic_msgs.msg  # noqa: F401
        import geometry_msgs.msg  # noqa: F401
        import rclpy
        import rosgraph_msgs.msg  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import std_msgs.msg  # noqa: F401
    except ImportError as exc:
        raise RosUnavailableError(
            f"the ROS 2 bridge needs the optional extra: pip install '{ROS_EXTRA}' "
            f"(ROS 2 from pip wheels; missing: {exc.name or exc})") from exc
    return rclpy


def spin_node(node: Any, shutdown: Callable[[], dict[str, Any]], done: threading.Event | None = None) -> None:
    """Spins ``node.node`` (built after ``rclpy.init``) until SIGINT or
    SIGTERM, ``done`` or rclpy's shutdown; then calls ``shutdown`` and prints its summary as one
    line ``SABRE_SUMMARY {json}`` (what the launcher and the tests read), and tears ROS down."""
    rclpy = require_ros()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node.node)
    try:
        while not stop.is_set() and not (done is not None and done.is_set()) and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
    finally:
        summary = shutdown()
        print("SABRE_SUMMARY " + json.dumps(summary), flush=True)
        executor.shutdown()
        node.node.destroy_node()
        rclpy.try_shutdown()
