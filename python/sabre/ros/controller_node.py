"""The controller node: joint states, wrist wrench and object state in; arm joint velocities
(ros2_control forward velocity controller), base twist (/cmd_vel, base frame) and diagnostics out,
around :class:`sabre.RealtimeCascade` with state and plan watchdogs."""

from __future__ import annotations

import collections
import functools
import json
import math
import threading
import time
from typing import Any

import numpy as np

from .. import tasks
from ..errors import SabreError
from ..planner import Controller, ControllerConfig
from ..realtime import RealtimeCascade
from ..scene import Scene
from . import PeriodicThread, gil_priority, realtime_middleware, realtime_thread, require_ros, spin_node
from .conversions import JointMap, LowPass, MessageError, tau_ext_from_wrench, world_to_base
from .durations import Durations
from .estimator import ObjectStateEstimator
from .params import CONTROLLER_PARAMETERS, declare

__all__ = ["ControllerNode", "run_controller"]

BASE_JOINTS = ("base_x", "base_y", "base_yaw")


def planner_controller(obj: str, variant: str, seed: int, threads: int) -> Controller:
    """The node's controller: OpenObject on the built-in object ``obj``. Module-level, so that the
    planner process can build its own copy (:class:`sabre.RealtimeCascade`'s ``planner_process``)."""
    scene = Scene.load(obj=obj)
    return Controller(scene, tasks.OpenObject(), ControllerConfig(seed=seed, variant=variant, threads=threads or None))


def stamp_seconds(stamp: Any) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class ControllerNode:
    """Builds the rclpy node (``node``) with its subscriptions, publishers and watchdog thread.

    Each accepted joint state runs one inner-loop tick and publishes one command; a rejected one
    (unknown or missing names, wrong lengths, NaN) is logged and answered with a zero command. A
    zero command also goes out when the last accepted state is older than ``state_timeout`` or the
    plan older than its horizon, and on shutdown."""

    def __init__(self, overrides: dict[str, Any] | None = None, node_name: str = "sabre_controller") -> None:
        rclpy = require_ros()
        self._rclpy = rclpy
        self.node = rclpy.create_node(node_name)
        p = self.params = declare(self.node, CONTROLLER_PARAMETERS, overrides)
        self._build_cascade(p)
        names = self._map_joints(p)
        self._init_bookkeeping(p)
        self._create_endpoints(p, names)
        self._start_threads(p)
        self.node.get_logger().info(
            f"sabre controller: {p['object']} variant {p['variant']}, joints {list(self.scene.joint_names)}, "
            f"object state from {p['object_state_topic'] or 'the hand-pose estimator'}"
        )

    # Set-up ----------------------------------------------------------------------------------
    def _build_cascade(self, p: dict[str, Any]) -> None:
        """The controller and the cascade around it (its planner in a process of its own if asked)."""
        factory = functools.partial(planner_controller, str(p["object"]), str(p["variant"]), int(p["seed"]), int(p["threads"]))
        self.controller = factory()
        self.scene = self.controller.scene
        self.task = self.controller.task
        self.cascade = RealtimeCascade(
            self.controller,
            min_replan_period=float(p["min_replan_period"]),
            planner_process=factory if p["planner_process"] else None,
            planner_nice=int(p["planner_nice"]),
            planner_idle=bool(p["planner_idle"]),
            delay_compensation=bool(p["delay_compensation"]),
        )
        self.horizon = float(self.controller.config.horizon)

    def _map_joints(self, p: dict[str, Any]) -> list[str]:
        """Maps the robot's joint names onto sabre's joints, the arm's and the base's commands;
        returns the robot's names in sabre's order."""
        # joint_names: the robot's names for sabre's joints, in sabre's order (Scene.joint_names)
        names = list(p["joint_names"]) or list(self.scene.joint_names)
        if len(names) != self.scene.nq:
            raise SabreError(f"joint_names needs {self.scene.nq} names (for {self.scene.joint_names}), got {names}")
        self.joints = JointMap(names)
        self.arm_joints = list(p["arm_joints"]) or [n for n, s in zip(names, self.scene.joint_names) if s not in BASE_JOINTS]
        self.base_joints = list(p["base_joints"])
        index = {n: i for i, n in enumerate(names)}
        for n in self.arm_joints + self.base_joints:
            if n not in index:
                raise SabreError(f"joint {n!r} is not one of joint_names {names}")
        self.arm_index = np.array([index[n] for n in self.arm_joints], dtype=np.intp)
        self.base_index = np.array([index[n] for n in self.base_joints], dtype=np.intp)
        self.object_joints = JointMap(self.scene.object_joint_names)
        return names

    def _init_bookkeeping(self, p: dict[str, Any]) -> None:
        """Timeouts, the latest inputs, the watchdog's flags and the statistics the summary reports."""
        self.state_timeout = float(p["state_timeout"])
        self.wrench_timeout = float(p["wrench_timeout"])
        self.max_tick_dt = float(p["max_tick_dt"])
        self._lock = threading.Lock()  # publishers and the shared state below
        self._tau_filter = LowPass(float(p["tau_ext_cutoff"]))
        self._wrench: np.ndarray | None = None
        self._wrench_recv = -math.inf
        self._object: tuple[np.ndarray, np.ndarray] | None = None
        self.estimator = None if p["object_state_topic"] else ObjectStateEstimator(self.scene)
        self._last_t: float | None = None
        self._t_origin: float | None = None
        self._last_recv = -math.inf  # monotonic time of the last accepted state
        self._fresh = threading.Event()
        self._stale = False
        self._last_status = "none"
        self._last_tank = float(self.controller.tank.energy)
        self._min_tank = self._last_tank
        self._obstacles: list[tuple[int | None, tuple[float, ...]]] = []
        self.stats: dict[str, Any] = {
            "ticks": 0,
            "rejected": 0,
            "zero_commands": 0,
            "stale_events": 0,
            "plan_stale": 0,
            "wrench_stale": 0,
            "stale_zero_age": [],
            "compute": Durations(),
            "state_age": Durations(),
            "phase_changes": 0,
            "recent_phases": collections.deque(maxlen=100),
        }
        self._phase = self.controller.phase
        self._running = True
        self._planner_started: float | None = None

    def _create_endpoints(self, p: dict[str, Any], names: list[str]) -> None:
        """The command, echo and status publishers (with their reused messages) and the input subscriptions."""
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist, WrenchStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        self._twist = Twist()
        self.arm_pub = self.node.create_publisher(Float64MultiArray, p["arm_command_topic"], 10)
        self.base_pub = self.node.create_publisher(Twist, p["cmd_vel_topic"], 10)
        self.echo_pub = self.node.create_publisher(JointState, p["command_echo_topic"], 10)
        self.status_pub = self.node.create_publisher(DiagnosticArray, p["status_topic"], 10)
        self._echo = JointState()
        self._echo.name = names
        self._arm_msg = Float64MultiArray()
        self.node.create_subscription(JointState, p["joint_state_topic"], self._on_joint_state, 10)
        self.node.create_subscription(WrenchStamped, p["wrench_topic"], self._on_wrench, 10)
        if p["object_state_topic"]:
            self.node.create_subscription(JointState, p["object_state_topic"], self._on_object, 10)
        self.node.create_subscription(Float64MultiArray, p["obstacle_topic"], self._on_obstacles, 10)

    def _start_threads(self, p: dict[str, Any]) -> None:
        """Starts the state watchdog and the periodic status publisher."""
        self._status = PeriodicThread(
            1.0 / float(p["status_rate"]),
            self._publish_status,
            "sabre-status",
            lambda exc: self.node.get_logger().error(f"status not published: {exc}"),
            priority=gil_priority(int(p["realtime_priority"])),
        )
        self._watchdog = threading.Thread(target=self._watch, name="sabre-state-watchdog", daemon=True)
        self._watchdog.start()
        self._status.start()

    # Inputs ----------------------------------------------------------------------------------
    def _on_wrench(self, msg: Any) -> None:
        w = msg.wrench
        v = np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z])
        if not np.all(np.isfinite(v)):
            self.node.get_logger().error("wrench: non-finite values, ignored", throttle_duration_sec=1.0)
            self.stats["rejected"] += 1
            return
        self._wrench = v
        self._wrench_recv = time.monotonic()

    def _on_object(self, msg: Any) -> None:
        try:
            o = self.object_joints.values(msg.name, msg.position, "position")
            od = self.object_joints.values(msg.name, msg.velocity, "velocity", required=False)
        except MessageError as exc:
            self.node.get_logger().error(f"object state rejected: {exc}", throttle_duration_sec=1.0)
            self.stats["rejected"] += 1
            return
        self._object = (o, od)

    def _on_obstacles(self, msg: Any) -> None:
        """The full obstacle set as rows (x, y, z, radius); obstacles are added, moved or removed
        to match (the radius of an existing obstacle is fixed: a new radius re-adds it)."""
        data = np.asarray(msg.data, dtype=np.float64)
        if data.size % 4 or not np.all(np.isfinite(data)):
            self.node.get_logger().error("obstacles: need finite rows of (x, y, z, radius)", throttle_duration_sec=1.0)
            return
        rows = [tuple(r) for r in data.reshape(-1, 4)]
        with self._lock:
            kept: list[tuple[int | None, tuple[float, ...]]] = []
            for i, row in enumerate(rows):
                if i < len(self._obstacles) and self._obstacles[i][1][3] == row[3]:
                    oid = self._obstacles[i][0]
                    if oid is not None:
                        self.cascade.move_obstacle(oid, row[:3])
                else:
                    previous = self._obstacles[i][0] if i < len(self._obstacles) else None
                    if previous is not None:
                        self.cascade.remove_obstacle(previous)
                    oid = self.cascade.add_obstacle(row[:3], row[3])
                kept.append((oid, row))
            for oid, _ in self._obstacles[len(rows) :]:
                if oid is not None:
                    self.cascade.remove_obstacle(oid)
            self._obstacles = kept

    def _on_joint_state(self, msg: Any) -> None:
        """One inner-loop tick on an accepted joint state, answered with its command (or zero)."""
        received = time.monotonic()
        self.stats["state_age"].record(time.time() - stamp_seconds(msg.header.stamp))
        measured = self._accept_joint_state(msg)
        if measured is None:
            return
        q, dq, stamp = measured
        if self._t_origin is None:
            self._t_origin = stamp
        t = stamp - self._t_origin
        object_state = self._object_state(q, t)
        if object_state is None:
            self.publish_zero(msg.header.stamp)  # waiting for the first object state
            return
        x = np.concatenate([q, dq, *object_state])
        if not self.cascade.running:
            self._start_planner(x, t, received, msg.header.stamp)
            return
        if not self.cascade.ready:
            self._observe_or_stop(x, t)
            self._last_t = t
            self._last_recv = received
            self.publish_zero(msg.header.stamp)
            return
        previous = t if self._last_t is None else self._last_t
        dt = min(t - previous, self.max_tick_dt)
        self._last_t = t
        tau_ext = self._external_torque(q, received, dt)
        if self._plan_expired(x, t, received, msg.header.stamp):
            return
        try:
            result = self.cascade.tick(x, tau_ext, t, dt=dt)
        except SabreError as exc:
            self.node.get_logger().error(f"inner loop failed: {exc}; zero command, planner stopped")
            self.cascade.stop()
            self.publish_zero(msg.header.stamp)
            return
        self._answer_tick(result, q, received, msg.header.stamp)
        self._note_phase(t)  # after the command: logging is off the 1 kHz path

    def _accept_joint_state(self, msg: Any) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(q, q̇, stamp) of a valid joint state newer than the last; None, after logging it and
        answering with zero, for any other."""
        try:
            q = self.joints.values(msg.name, msg.position, "position")
            dq = self.joints.values(msg.name, msg.velocity, "velocity")
            stamp = stamp_seconds(msg.header.stamp)
            if self._last_t is not None and self._t_origin is not None and stamp - self._t_origin <= self._last_t:
                raise MessageError(f"joint state stamp {stamp:.6f} is not after the previous one")
        except MessageError as exc:
            self.node.get_logger().error(f"joint state rejected: {exc}; sending zero", throttle_duration_sec=1.0)
            self.stats["rejected"] += 1
            self.publish_zero(msg.header.stamp)
            return None
        return q, dq, stamp

    def _object_state(self, q: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(o, ȯ): the estimator's from the hand pose, else the newest on the object topic (None before one came)."""
        if self.estimator is not None:
            force = 0.0 if self._wrench is None else float(np.linalg.norm(self._wrench[:3]))
            e = self.estimator.update(q, t, force)
            return e.position, e.velocity
        return self._object

    def _start_planner(self, x: np.ndarray, t: float, received: float, stamp: Any) -> None:
        """Starts the planner on the first state and answers with zero; a planner that stopped
        (its error logged) is never restarted."""
        if self._planner_started is not None:
            self.publish_zero(stamp)
            return
        self.node.get_logger().info("first state received: planning")
        # the planner process makes its first plan while this callback answers with zeros
        self.cascade.start(x, t, wait=False)
        self._planner_started = time.monotonic()
        self._last_t = t
        self._last_recv = received
        self.publish_zero(stamp)

    def _external_torque(self, q: np.ndarray, received: float, dt: float) -> np.ndarray:
        """The low-passed joint torques of the wrist wrench (zero while the wrench is stale)."""
        wrench_fresh = self._wrench is not None and received - self._wrench_recv <= self.wrench_timeout
        if not wrench_fresh:
            self.stats["wrench_stale"] += 1
        fresh = self._wrench if wrench_fresh else None
        raw = np.zeros(self.scene.nq) if fresh is None else tau_ext_from_wrench(self.scene, q, fresh)
        return self._tau_filter.update(raw, dt)

    def _plan_expired(self, x: np.ndarray, t: float, received: float, stamp: Any) -> bool:
        """Whether the plan is older than its horizon; if so the state goes to the planner and the
        answer is zero."""
        plan_start = self.cascade.plan_start
        expired = plan_start is not None and t - plan_start > self.horizon
        if expired:
            self._observe_or_stop(x, t)  # the planner re-plans from here, so the plan can become fresh
            self.stats["plan_stale"] += 1
            self.node.get_logger().warning("plan older than its horizon: zero command", throttle_duration_sec=1.0)
            self._last_recv = received
            self.publish_zero(stamp)
        return expired

    def _answer_tick(self, result: Any, q: np.ndarray, received: float, stamp: Any) -> None:
        """Publishes a tick's command and books its filter status, tank energy and compute time."""
        self._last_status = result.status
        self._last_tank = result.tank_energy
        self._min_tank = min(self._min_tank, result.tank_energy)
        with self._lock:
            self._last_recv = received
            self._stale = False
            self._publish_command(result.command, q[self.base_index[2]] if len(self.base_index) == 3 else 0.0, stamp)
        self._fresh.set()
        self.stats["ticks"] += 1
        self.stats["compute"].record(time.monotonic() - received)

    def _note_phase(self, t: float) -> None:
        """Logs and counts a change of the task's phase."""
        if self.cascade.phase != self._phase:
            self.node.get_logger().info(f"phase {self._phase} -> {self.cascade.phase} at t = {t:.3f} s")
            self._phase = self.cascade.phase
            self.stats["phase_changes"] += 1
            self.stats["recent_phases"].append((t, self._phase))

    def _observe_or_stop(self, x: np.ndarray, t: float) -> None:
        """Hands a state the node answers with zero to the planner; stops the planner if it failed."""
        try:
            self.cascade.observe(x, t)
        except SabreError as exc:
            self.node.get_logger().error(f"planner failed: {exc}; zero command, planner stopped")
            self.cascade.stop()

    # Outputs ---------------------------------------------------------------------------------
    def _publish_command(self, u: np.ndarray, yaw: float, stamp: Any) -> None:
        self._arm_msg.data = [float(v) for v in u[self.arm_index]]
        self.arm_pub.publish(self._arm_msg)
        tw = self._twist  # the messages are reused: every caller holds self._lock, publish serializes at once
        if len(self.base_index) == 3:
            vx, vy, wz = world_to_base(u[self.base_index], yaw)
            tw.linear.x, tw.linear.y, tw.angular.z = vx, vy, wz
        self.base_pub.publish(tw)
        self._echo.header.stamp = stamp
        self._echo.velocity = [float(v) for v in u]
        self.echo_pub.publish(self._echo)

    def publish_zero(self, stamp: Any = None) -> None:
        """Zero arm velocities and a zero twist (and the zero echo)."""
        if stamp is None:
            stamp = self.node.get_clock().now().to_msg()
        with self._lock:
            self._publish_command(np.zeros(self.scene.nu), 0.0, stamp)
        self.stats["zero_commands"] += 1

    def _watch(self) -> None:
        """Zeroes the command once the last accepted state is ``state_timeout`` old; resumes
        (nothing to do) when ticks come back."""
        period = float(self.params["watchdog_period"])
        realtime_thread(gil_priority(int(self.params["realtime_priority"])))
        while self._running:
            age = time.monotonic() - self._last_recv
            if self.cascade.ticks and not self._stale and age > self.state_timeout:
                with self._lock:
                    age = time.monotonic() - self._last_recv
                    if age > self.state_timeout:
                        self.stats["stale_events"] += 1
                        self.stats["stale_zero_age"].append(age)
                        self._publish_command(np.zeros(self.scene.nu), 0.0, self.node.get_clock().now().to_msg())
                        self.stats["zero_commands"] += 1
                        self._stale = True
                if self._stale:
                    self.node.get_logger().warning(f"state older than {self.state_timeout} s: zero command")
            wait = self.state_timeout - age if not self._stale else period * 10
            time.sleep(min(max(wait, period), 0.05))

    def _planner_rate(self) -> float:
        """Planning iterations per second of wall time since the planner started."""
        if self._planner_started is None:
            return 0.0
        elapsed = time.monotonic() - self._planner_started
        return self.cascade.iterations / elapsed if elapsed > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        compute = self.stats["compute"]
        fallbacks = self.controller.inner_filter.stats.fallbacks if self.controller.inner_filter is not None else 0
        return {
            "node": "controller",
            "ticks": self.stats["ticks"],
            "rejected": self.stats["rejected"],
            "zero_commands": self.stats["zero_commands"],
            "stale_events": self.stats["stale_events"],
            "stale_zero_age_ms": [a * 1e3 for a in self.stats["stale_zero_age"]],
            "plan_stale": self.stats["plan_stale"],
            "wrench_stale": self.stats["wrench_stale"],
            "planner_iterations": self.cascade.iterations,
            "planner_rate_hz": self._planner_rate(),
            "tick_compute_p50_ms": compute.percentile_ms(50),
            "tick_compute_p99_ms": compute.percentile_ms(99),
            "state_age_p50_ms": self.stats["state_age"].percentile_ms(50),
            "state_age_p99_ms": self.stats["state_age"].percentile_ms(99),
            "state_age_p999_ms": self.stats["state_age"].percentile_ms(99.9),
            "state_age_max_ms": self.stats["state_age"].max_ms(),
            "tick_compute_p999_ms": compute.percentile_ms(99.9),
            "tick_compute_max_ms": compute.max_ms(),
            "tank_energy": self._last_tank,
            "tank_min": self._min_tank,
            "tank_floor": self.controller.tank.floor,
            "filter_fallbacks": int(fallbacks),
            "phase": self.cascade.phase,
            "phase_changes": self.stats["phase_changes"],
            "recent_phases": [[round(t, 3), phase] for t, phase in self.stats["recent_phases"]],  # the last 100
            "planner_process": self.cascade.planner_in_process,
        }

    def _publish_status(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        # Read the flag before the counters: the watchdog books the stale event before it raises
        # the flag, so a status that says stale always carries that event.
        stale = self._stale
        s = self.summary()
        plan_start = self.cascade.plan_start
        values = {
            "phase": s["phase"],
            "tank_energy": f"{s['tank_energy']:.4f}",
            "tank_floor": f"{s['tank_floor']:.4f}",
            "plan_age": "nan" if plan_start is None or self._last_t is None else f"{self._last_t - plan_start:.4f}",
            "filter_status": self._last_status,
            "filter_fallbacks": str(s["filter_fallbacks"]),
            "iteration_time": f"{self.cascade.iteration_time:.5f}",
            "planner_rate": f"{s['planner_rate_hz']:.2f}",
            "ticks": str(s["ticks"]),
            "rejected": str(s["rejected"]),
            "stale_events": str(s["stale_events"]),
            "state_stale": str(stale).lower(),
            "stale_zero_age_ms": json.dumps(s["stale_zero_age_ms"]),
            "estimator_hooked": "n/a" if self.estimator is None else str(self.estimator.hooked).lower(),
        }
        status = DiagnosticStatus(
            name="sabre/controller",
            hardware_id=self.scene.robot_name,
            level=DiagnosticStatus.WARN if stale else DiagnosticStatus.OK,
            message="state stale: commanding zero" if stale else "running",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.status_pub.publish(msg)

    def shutdown(self) -> dict[str, Any]:
        """Sends the final zero command, stops the planner and the watchdog; returns the summary."""
        self._running = False
        self._status.stop()
        self.publish_zero()
        self.cascade.stop()
        return self.summary()


def run_controller(overrides: dict[str, Any] | None = None, ros_args: list[str] | None = None) -> int:
    """Runs the controller node until SIGINT or SIGTERM; prints a one-line JSON summary
    (``SABRE_SUMMARY {...}``) on exit."""
    rclpy = require_ros()
    realtime_middleware()
    rclpy.init(args=["sabre_controller"] + (ros_args or []), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = ControllerNode(overrides)
    spin_node(node, node.shutdown, priority=int(node.params["realtime_priority"]))
    return 0
