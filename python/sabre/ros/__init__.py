"""The ROS 2 hardware bridge: a managed controller node around :class:`sabre.RealtimeCascade`, a
simulated robot that behaves like a Franka arm's and a mobile base's drivers, and the launcher of
both (``python -m sabre control | sim-robot | ros-demo``); see docs/ros2.md.

Needs the optional extra ``sabre-mpc[ros]`` (Kilted) or ``sabre-mpc[ros-jazzy]`` (ROS 2 from pip
wheels, no system ROS). ``import sabre`` works without it; the node modules raise
:class:`sabre.MissingExtraError` naming the extra. The message conversions, the inputs, the command
limits and their stop logic, the descriptions and the QoS parsing are plain Python and import
without ROS.
"""

from __future__ import annotations

import gc
import json
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

from ..errors import DISTRIBUTION, require_extra

__all__ = [
    "require_ros",
    "spin_node",
    "make_executor",
    "realtime_thread",
    "realtime_middleware",
    "gil_priority",
    "MIDDLEWARE_PROFILE",
    "PeriodicThread",
    "ROS_EXTRA",
]

ROS_EXTRA = f"{DISTRIBUTION}[ros]"


def require_ros():
    """Imports and returns ``rclpy`` after choosing the DDS implementation the extra installs
    (Fast DDS, unless ``RMW_IMPLEMENTATION`` is already set); raises :class:`sabre.MissingExtraError`
    naming the extra when the wheels are missing."""
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    modules = (
        "diagnostic_msgs.msg",
        "geometry_msgs.msg",
        "nav_msgs.msg",
        "rosgraph_msgs.msg",
        "sensor_msgs.msg",
        "std_msgs.msg",
        "std_srvs.srv",
        "trajectory_msgs.msg",
        "visualization_msgs.msg",
        "threadpoolctl",
        "rclpy.lifecycle",
        "rclpy",
    )
    return require_extra("ros", "the ROS 2 bridge (ROS 2 from pip wheels)", *modules)[-1]


#: Seconds between the interpreter's GIL hand-overs in a bridge process (see :func:`spin_node`).
GIL_SWITCH_INTERVAL = 1e-4

#: Seconds between :func:`spin_node`'s looks at its stop conditions besides a signal.
SPIN_CHECK_PERIOD = 0.1


def realtime_thread(priority: int) -> bool:
    """Puts the calling thread under SCHED_FIFO at ``priority`` (1–99), as a robot's control loop
    runs, so that the 1 kHz path preempts the planner's threads on a machine with few cores.
    Threads it starts afterwards (the planner, its workers) keep the normal policy
    (SCHED_RESET_ON_FORK). Returns False, changing nothing, where the OS does not permit it
    (no CAP_SYS_NICE or rtprio limit) or for ``priority <= 0``."""
    fifo = getattr(os, "SCHED_FIFO", None)
    if priority <= 0 or fifo is None:
        return False
    try:
        os.sched_setscheduler(0, fifo | getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_param(min(int(priority), 99)))
    except OSError:
        return False
    return True


#: sabre's Fast DDS profile: the default transports with their receive threads under SCHED_FIFO.
MIDDLEWARE_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fastdds_realtime.xml")

#: The receive threads' SCHED_FIFO priority in :data:`MIDDLEWARE_PROFILE`.
MIDDLEWARE_PRIORITY = 65


def realtime_middleware() -> bool:
    """Points Fast DDS at :data:`MIDDLEWARE_PROFILE` for the participants this process creates
    afterwards (call it before ``rclpy.init``): its receive threads then run under SCHED_FIFO,
    so that a message reaches a 1 kHz callback without waiting for the planner or any other
    normally scheduled thread to give up a core. Changes nothing and returns False where a
    profile is already chosen (``FASTDDS_DEFAULT_PROFILES_FILE``: the user's own wins), where
    another middleware is selected, where the installed Fast DDS does not apply a profile's thread
    settings (before 3.0: ROS 2 Jazzy's 2.14 reads them and leaves its threads as they were), or
    where the OS does not permit SCHED_FIFO (probed on a short-lived thread, so that Fast DDS never
    logs a refused priority)."""
    if os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE") or not middleware_thread_settings():
        return False
    if os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        return False
    permitted: list[bool] = []
    probe = threading.Thread(target=lambda: permitted.append(realtime_thread(MIDDLEWARE_PRIORITY)), name="sabre-rt-probe")
    probe.start()
    probe.join()
    if not permitted[0]:
        return False
    os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = MIDDLEWARE_PROFILE
    return True


def middleware_thread_settings() -> bool:
    """Whether the installed Fast DDS applies a profile's thread settings (version 3 or later, the
    one ROS 2 Kilted's wheels bring)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major = int(version("ros-fastdds").split(".")[0])
    except (PackageNotFoundError, ValueError):
        return False
    return major >= 3


class PeriodicThread:
    """Calls ``work()`` every ``period`` s on a thread of its own until :meth:`stop`. The nodes
    publish their status this way: its percentiles take a millisecond or more of Python, which on
    the executor's thread would hold up the 1 kHz callbacks queued behind it. The thread runs at
    real-time ``priority`` where permitted (see :func:`gil_priority`). An exception in ``work``
    goes to ``on_error`` and the thread carries on."""

    def __init__(
        self,
        period: float,
        work: Callable[[], None],
        name: str,
        on_error: Callable[[Exception], None] | None = None,
        priority: int = 0,
    ) -> None:
        self._priority = int(priority)
        self._period = float(period)
        self._work = work
        self._on_error = on_error
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> PeriodicThread:
        self._thread.start()
        return self

    def _run(self) -> None:
        realtime_thread(self._priority)
        while not self._stop.wait(self._period):
            try:
                self._work()
            except Exception as exc:
                if self._on_error is not None:
                    self._on_error(exc)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()


def single_threaded_blas() -> None:
    """Limits this process's BLAS (NumPy's OpenBLAS) to the calling thread. A BLAS call on the
    1 kHz path would otherwise hand work to BLAS's own, normally scheduled threads and wait for
    them (a priority inversion that showed as multi-millisecond stalls), and between calls those
    threads spin on the cores the plant loop and the planner need."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def gil_priority(callback_priority: int) -> int:
    """The real-time priority for a node's other Python threads (status, watchdog), given its
    1 kHz callbacks' ``callback_priority`` (0: none). They hold the GIL now and then; under
    normal scheduling on a machine whose cores the real-time threads fill, such a thread can be
    preempted while it holds the GIL and the callback then waits for it (priority inversion).
    Just below the callbacks, it gets a core whenever it holds what they need."""
    return max(1, int(callback_priority) - 20) if int(callback_priority) > 0 else 0


def make_executor(rclpy: Any) -> Any:
    """rclpy's events executor where the installed rclpy has a settled one (Kilted's, rclpy 9): it
    dispatches each message from C++ instead of rebuilding a Python wait set per message; else the
    single-threaded executor (Jazzy's experimental events executor crashed a node's shutdown)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        settled = int(version("ros-rclpy").split(".")[0]) >= 9
        from rclpy.experimental import EventsExecutor
    except (ImportError, PackageNotFoundError, ValueError):
        settled = False
    return EventsExecutor() if settled else rclpy.executors.SingleThreadedExecutor()


def spin_node(node: Any, shutdown: Callable[[], dict[str, Any]], done: threading.Event | None = None, priority: int = 0) -> None:
    """Spins ``node.node`` (built after ``rclpy.init``), at real-time ``priority`` if permitted
    (:func:`realtime_thread`; 0: normal), until SIGINT or
    SIGTERM, ``done`` or rclpy's shutdown; then calls ``shutdown`` and prints its summary as one
    line ``SABRE_SUMMARY {json}`` (what the launcher and the tests read), and tears ROS down."""
    rclpy = require_ros()
    # The 1 kHz callbacks share the GIL with a planner thread (the controller) or the plant loop
    # (the simulated robot); Python hands the GIL over only every switch interval (5 ms by
    # default), which would delay a waiting callback by up to that much.
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)
    if priority > 0 and not realtime_thread(priority):
        node.node.get_logger().warning(
            f"real-time priority {priority} not permitted (needs CAP_SYS_NICE or an rtprio limit): "
            "the 1 kHz callbacks compete with the planner for the cores"
        )
    # The nodes' long-lived objects (modules, scene, controller) leave the collector's scans: a
    # full collection on the 1 kHz path then walks only what was made since, not milliseconds' worth.
    gc.collect()
    gc.freeze()
    single_threaded_blas()
    from rclpy.task import Future

    stop: Future[bool] = Future()  # completed by SIGINT or SIGTERM (their handlers run on this thread)

    def on_signal(*_: object) -> None:
        if not stop.done():
            stop.set_result(True)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    executor = make_executor(rclpy)
    executor.add_node(node.node)
    try:
        # The executor's own loop between the checks (a tenth of a second), not one Python call
        # and one check per message.
        while not stop.done() and not (done is not None and done.is_set()) and rclpy.ok():
            executor.spin_until_future_complete(stop, timeout_sec=SPIN_CHECK_PERIOD)
    finally:
        summary = shutdown()
        print("SABRE_SUMMARY " + json.dumps(summary), flush=True)
        executor.shutdown()
        node.node.destroy_node()
        rclpy.try_shutdown()
