"""The simulated robot node: the 1 kHz Rapier plant with the joint velocity controller inside,
stepped against the wall clock, publishing what a robot's drivers would (joint states, object
joint state, wrist wrench, clock) and following the commands a robot's controllers would take,
with a command timeout and run-time fault injection (stuck door, obstacles)."""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import numpy as np

from .. import tasks
from ..closed_loop import paper_start_state
from ..errors import SabreError
from ..inner_loop import LowLevelController
from ..scene import Scene
from ..sim import Plant
from . import PeriodicThread, gil_priority, realtime_middleware, realtime_thread, require_ros, spin_node
from .controller_node import BASE_JOINTS, stamp_seconds
from .conversions import base_to_world
from .durations import Durations
from .params import SIM_ROBOT_PARAMETERS, declare

__all__ = ["SimRobotNode", "run_sim_robot"]

#: How many of the newest states an echo is matched against (4 s at 1 kHz); an older echo is
#: counted as unmatched, not as an answer.
RECENT_STATES = 4096


class SimRobotNode:
    """The plant steps on its own thread at ``rate`` Hz of wall-clock time: each loop steps every
    tick that is due (more than one is an overrun, counted as late ticks), then publishes the
    state once. Commands older than ``command_timeout`` at a tick's scheduled time stop the robot
    (zero velocity reference), so the stop comes at most one tick after the timeout."""

    def __init__(self, overrides: dict[str, Any] | None = None, node_name: str = "sabre_sim_robot") -> None:
        rclpy = require_ros()
        self._rclpy = rclpy
        self.node = rclpy.create_node(node_name)
        p = self.params = declare(self.node, SIM_ROBOT_PARAMETERS, overrides)
        self._build_plant(p)
        names = self._map_joints(p)
        self._init_bookkeeping(p)
        self._create_endpoints(p, names)
        self._status = PeriodicThread(
            1.0 / float(p["status_rate"]),
            self._publish_status,
            "sabre-status",
            lambda exc: self.node.get_logger().error(f"status not published: {exc}"),
            priority=gil_priority(int(p["realtime_priority"]) - 10),
        )
        self._thread = threading.Thread(target=self._loop, name="sabre-sim-robot", daemon=True)
        self.done = threading.Event()
        self.error: Exception | None = None

    # Set-up ----------------------------------------------------------------------------------
    def _build_plant(self, p: dict[str, Any]) -> None:
        """The scene, the plant at its start state and the joint velocity controller inside it."""
        self.scene = scene = Scene.load(obj=p["object"])
        self.task = tasks.OpenObject()
        self.period = 1.0 / float(p["rate"])
        self.plant = Plant(scene, dt=self.period)
        self.low = LowLevelController(scene, dt=self.period, gain_inertia_floor=float(p["gain_inertia_floor"]))
        x0 = paper_start_state(scene) if p["start"] == "paper" else scene.default_state()
        self.plant.reset(x0)
        self._nq = scene.nq

    def _map_joints(self, p: dict[str, Any]) -> list[str]:
        """The order the joint states are published in and the joints the arm and base commands
        drive; returns the robot's names for sabre's joints, in sabre's order."""
        scene = self.scene
        names = list(p["joint_names"]) or list(scene.joint_names)
        if len(names) != scene.nq:
            raise SabreError(f"joint_names needs {scene.nq} names, got {names}")
        order = list(p["publish_order"]) or names
        if sorted(order) != sorted(names):
            raise SabreError(f"publish_order must be a permutation of joint_names {names}, got {order}")
        index = {n: i for i, n in enumerate(names)}
        self.publish_index = np.array([index[n] for n in order], dtype=np.intp)
        self.extra = list(p["extra_joints"])
        arm = list(p["arm_joints"]) or [n for n, s in zip(names, scene.joint_names) if s not in BASE_JOINTS]
        self.arm_index = np.array([index[n] for n in arm], dtype=np.intp)
        self.base_index = np.array([scene.joint_names.index(n) for n in BASE_JOINTS], dtype=np.intp)
        return names

    def _init_bookkeeping(self, p: dict[str, Any]) -> None:
        """The latest commands, the hold fault's schedule and the statistics the summary reports."""
        self.command_timeout = float(p["command_timeout"])
        self._arm_cmd = np.zeros(len(self.arm_index))
        self._arm_recv = -math.inf
        self._base_cmd = np.zeros(3)
        self._base_recv = -math.inf
        self._hold_request: bool | None = None
        self._stopped = True
        self._running = True
        self.stats: dict[str, Any] = {
            "ticks": 0,
            "loops": 0,
            "late_ticks": 0,
            "skipped_ticks": 0,
            "overrun_loops": 0,
            "states_published": 0,
            "arm_commands": 0,
            "base_commands": 0,
            "rejected_commands": 0,
            "echoes": 0,
            "late_echoes": 0,
            "unmatched_echoes": 0,
            "first_answered": None,
            "last_answered": None,
            "latency": Durations(),
            "stops": [],
            "loop_work": Durations(),
            "success_time": None,
            "contact_force_sum": 0.0,
            "contact_steps": 0,
            "hold_started": None,
            "hold_ended": None,
        }
        scene = self.scene
        self._hold_at = float(p["hold_at_opening"]) * float(scene.o_upper[0] - scene.o_lower[0]) + float(scene.o_lower[0])
        self._hold_done = False
        # The recent states by stamp (ns) → their index: an echo names the state it answers
        self._published: dict[int, int] = {}

    def _create_endpoints(self, p: dict[str, Any], names: list[str]) -> None:
        """The state, wrench, clock, status and obstacle publishers (with their reused messages) and
        the command, echo and fault subscriptions."""
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist, WrenchStamped
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64MultiArray

        qos = 10
        self.js_pub = self.node.create_publisher(JointState, p["joint_state_topic"], qos)
        self.obj_pub = self.node.create_publisher(JointState, p["object_state_topic"] or "/sabre/object/joint_states", qos)
        self.wrench_pub = self.node.create_publisher(WrenchStamped, p["wrench_topic"], qos)
        self.clock_pub = self.node.create_publisher(Clock, p["clock_topic"], qos)
        self.status_pub = self.node.create_publisher(DiagnosticArray, p["status_topic"], qos)
        self.obstacle_pub = self.node.create_publisher(Float64MultiArray, p["obstacle_topic"], qos)
        self._js = JointState()
        self._js.name = [names[i] for i in self.publish_index] + self.extra
        self._obj = JointState()
        self._obj.name = list(self.scene.object_joint_names)
        self._wrench = WrenchStamped()
        self._wrench.header.frame_id = "world"
        self._clock = Clock()
        self._obstacles = Float64MultiArray()
        self.node.create_subscription(Float64MultiArray, p["arm_command_topic"], self._on_arm, qos)
        self.node.create_subscription(Twist, p["cmd_vel_topic"], self._on_twist, qos)
        self.node.create_subscription(JointState, p["command_echo_topic"], self._on_echo, qos)
        self.node.create_subscription(Bool, p["hold_topic"], self._on_hold, qos)
        self.node.create_subscription(Float64MultiArray, p["set_obstacles_topic"], self._on_set_obstacles, qos)

    def start(self) -> None:
        self._start_wall = time.monotonic()
        self._thread.start()
        self._status.start()

    # Commands --------------------------------------------------------------------------------
    def _on_arm(self, msg: Any) -> None:
        v = np.asarray(msg.data, dtype=np.float64)
        if v.shape != self._arm_cmd.shape or not np.all(np.isfinite(v)):
            self.stats["rejected_commands"] += 1
            self.node.get_logger().error(
                f"arm command rejected: need {len(self._arm_cmd)} finite values, got {list(v)}", throttle_duration_sec=1.0
            )
            return
        self._arm_cmd = v
        self._arm_recv = time.monotonic()
        self.stats["arm_commands"] += 1

    def _on_twist(self, msg: Any) -> None:
        v = np.array([msg.linear.x, msg.linear.y, msg.angular.z])
        if not np.all(np.isfinite(v)):
            self.stats["rejected_commands"] += 1
            return
        self._base_cmd = v
        self._base_recv = time.monotonic()
        self.stats["base_commands"] += 1

    def _on_echo(self, msg: Any) -> None:
        latency = time.time() - stamp_seconds(msg.header.stamp)
        index = self._published.get(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        if index is None:  # a command the controller sent on its own (watchdog, shutdown), or a very late one
            self.stats["unmatched_echoes"] += 1
            return
        s = self.stats
        s["first_answered"] = index if s["first_answered"] is None else min(s["first_answered"], index)
        s["last_answered"] = index if s["last_answered"] is None else max(s["last_answered"], index)
        self.stats["echoes"] += 1
        self.stats["latency"].record(latency)
        if latency > self.period:
            self.stats["late_echoes"] += 1

    def _on_hold(self, msg: Any) -> None:
        self._hold_request = bool(msg.data)

    def _on_set_obstacles(self, msg: Any) -> None:
        self._obstacles.data = list(msg.data)
        self.obstacle_pub.publish(self._obstacles)

    def _reference(self, tick_time: float, yaw: float) -> np.ndarray:
        """The joint velocity reference (nq,) at a tick's scheduled time: zero once either command
        is older than the timeout (or none came yet)."""
        fresh = tick_time - self._arm_recv <= self.command_timeout and tick_time - self._base_recv <= self.command_timeout
        u = np.zeros(self._nq)
        if not fresh:
            if not self._stopped:
                self._stopped = True
                last = max(self._arm_recv, self._base_recv)
                self.stats["stops"].append(tick_time - min(self._arm_recv, self._base_recv) if math.isfinite(last) else 0.0)
            return u
        self._stopped = False
        u[self.arm_index] = self._arm_cmd
        u[self.base_index] = base_to_world(self._base_cmd, yaw)
        return u

    # The plant loop --------------------------------------------------------------------------
    def _loop(self) -> None:
        p = self.params
        if int(p["realtime_priority"]) > 0 and not realtime_thread(int(p["realtime_priority"])):
            self.node.get_logger().warning("real-time priority not permitted for the plant loop: ticks may run late")
        check_every = max(1, int(round(0.01 / self.period)))  # the task's success test is Python: 100 Hz
        next_check = 0
        max_behind = max(1, int(float(p["max_catchup"]) / self.period))
        duration = float(p["duration"])
        stop_on_success = bool(p["stop_on_success"])
        settle = float(p["settle_time"])
        start = self._start_wall
        k = 0
        try:
            while self._running:
                now = time.monotonic()
                due = int((now - start) / self.period)
                if due - k > max_behind:
                    self.stats["skipped_ticks"] += due - k - 1
                    k = due - 1
                if due - k > 1:
                    self.stats["late_ticks"] += due - k - 1
                    self.stats["overrun_loops"] += 1
                work = time.monotonic()
                while k < due:
                    self._apply_faults()
                    x = self.plant.state
                    u = self._reference(start + (k + 1) * self.period, x[2])
                    self.low.track(self.plant, u, 1)
                    k += 1
                    self.stats["ticks"] += 1
                if due:
                    self._publish_state()
                    self.stats["loop_work"].record(time.monotonic() - work)
                self.stats["loops"] += 1
                if self.plant.contact:
                    self.stats["contact_force_sum"] += float(np.linalg.norm(self.plant.wrench[:3]))
                    self.stats["contact_steps"] += 1
                if k >= next_check and self.stats["success_time"] is None:
                    next_check = k + check_every
                    if self.task.success(self.scene, self.plant.state):
                        self.stats["success_time"] = self.plant.time
                opened_at = self.stats["success_time"]
                if stop_on_success and opened_at is not None and self.plant.time > opened_at + settle:
                    break
                if duration > 0 and now - start > duration:
                    break
                rest = start + (k + 1) * self.period - time.monotonic()
                if rest > 0:
                    time.sleep(rest)
        except Exception as exc:  # reported by the main thread; the process exits non-zero
            self.error = exc
        finally:
            self.done.set()

    def _apply_faults(self) -> None:
        if self._hold_request is not None:
            self.plant.hold_object(self._hold_request)
            self._hold_request = None
        if self._hold_at > 0 and not self._hold_done:
            o = self.scene.split_state(self.plant.state).o[0]
            if self.stats["hold_started"] is None and o >= self._hold_at:
                self.plant.hold_object(True)
                self.stats["hold_started"] = self.plant.time
            elif self.stats["hold_started"] is not None and self.plant.time - self.stats["hold_started"] >= float(
                self.params["hold_duration"]
            ):
                self.plant.hold_object(False)
                self.stats["hold_ended"] = self.plant.time
                self._hold_done = True

    def _publish_state(self) -> None:
        """Publishes the state of this tick, the joint state first: it is what the controller
        answers, and the wrench and object state of the same instant, right behind it, reach
        the controller for its next tick (a robot's drivers publish on their own schedules too)."""
        state = self.scene.split_state(self.plant.state)
        stamp = self.node.get_clock().now().to_msg()
        published = self._published
        published[stamp.sec * 1_000_000_000 + stamp.nanosec] = self.stats["states_published"]  # before an echo can come
        if len(published) > RECENT_STATES:
            del published[next(iter(published))]
        self.stats["states_published"] += 1
        js = self._js
        js.header.stamp = stamp
        extra = [0.0] * len(self.extra)
        js.position = [float(v) for v in state.q[self.publish_index]] + extra
        js.velocity = [float(v) for v in state.q_dot[self.publish_index]] + extra
        self.js_pub.publish(js)
        w = self.plant.wrench
        m = self._wrench
        m.header.stamp = stamp
        m.wrench.force.x, m.wrench.force.y, m.wrench.force.z = float(w[0]), float(w[1]), float(w[2])
        m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z = float(w[3]), float(w[4]), float(w[5])
        self.wrench_pub.publish(m)
        o = self._obj
        o.header.stamp = stamp
        o.position = [float(v) for v in state.o]
        o.velocity = [float(v) for v in state.o_dot]
        self.obj_pub.publish(o)
        seconds = int(self.plant.time)
        self._clock.clock.sec, self._clock.clock.nanosec = seconds, int(round((self.plant.time % 1.0) * 1e9)) % 1_000_000_000
        self.clock_pub.publish(self._clock)

    # Reports ---------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        s = self.stats
        state = self.scene.split_state(self.plant.state)
        lat = s["latency"]
        wall = time.monotonic() - self._start_wall
        # The states published while the controller answered: from the first answered one to the
        # last (before it, the controller was starting; after it, it had stopped)
        window = 0 if s["first_answered"] is None else s["last_answered"] - s["first_answered"] + 1
        return {
            "node": "sim_robot",
            "object": self.scene.object_name,
            "sim_time": self.plant.time,
            "wall_time": wall,
            "ticks": s["ticks"],
            "late_ticks": s["late_ticks"],
            "skipped_ticks": s["skipped_ticks"],
            "overrun_loops": s["overrun_loops"],
            "loops": s["loops"],
            "loop_work_p50_ms": s["loop_work"].percentile_ms(50),
            "loop_work_p99_ms": s["loop_work"].percentile_ms(99),
            "states_published": s["states_published"],
            "arm_commands": s["arm_commands"],
            "base_commands": s["base_commands"],
            "rejected_commands": s["rejected_commands"],
            "echoes": s["echoes"],
            "late_echoes": s["late_echoes"],
            "latency_p50_ms": lat.percentile_ms(50),
            "latency_p99_ms": lat.percentile_ms(99),
            "latency_max_ms": lat.max_ms(),
            "latency_percentiles_ms": {q: lat.percentile_ms(q) for q in (50, 90, 95, 98, 99, 99.5, 99.9)},
            "answered_window": window,
            "unmatched_echoes": s["unmatched_echoes"],
            "delivered_fraction": s["echoes"] / window if window else 0.0,
            "stop_delays_ms": [d * 1e3 for d in s["stops"]],
            "command_timeout_ms": self.command_timeout * 1e3,
            "period_ms": self.period * 1e3,
            "opening": float(state.o[0]),
            "success": s["success_time"] is not None,
            "time_to_open": s["success_time"],
            "mean_wrench": s["contact_force_sum"] / s["contact_steps"] if s["contact_steps"] else 0.0,
            "hold_started": s["hold_started"],
            "hold_ended": s["hold_ended"],
            "robot_speed": float(np.linalg.norm(state.q_dot)),
        }

    def _publish_status(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        s = self.summary()
        keys = (
            "sim_time",
            "ticks",
            "late_ticks",
            "skipped_ticks",
            "states_published",
            "arm_commands",
            "echoes",
            "answered_window",
            "unmatched_echoes",
            "delivered_fraction",
            "latency_p50_ms",
            "latency_p99_ms",
            "opening",
            "success",
            "robot_speed",
        )
        status = DiagnosticStatus(
            name="sabre/sim_robot",
            hardware_id="sim",
            level=DiagnosticStatus.OK,
            message="stopped: commands stale" if self._stopped else "following commands",
            values=[KeyValue(key=k, value=json.dumps(s[k])) for k in keys]
            + [KeyValue(key="stop_delays_ms", value=json.dumps(s["stop_delays_ms"]))],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.status_pub.publish(msg)

    def shutdown(self) -> dict[str, Any]:
        self._running = False
        self._status.stop()
        if self._thread.is_alive():
            self._thread.join()
        return self.summary()


def run_sim_robot(overrides: dict[str, Any] | None = None, ros_args: list[str] | None = None) -> int:
    """Runs the simulated robot until SIGINT/SIGTERM, ``duration`` or success (``stop_on_success``);
    prints a one-line JSON summary (``SABRE_SUMMARY {...}``) on exit."""
    rclpy = require_ros()
    realtime_middleware()
    rclpy.init(args=["sabre_sim_robot"] + (ros_args or []), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = SimRobotNode(overrides)
    node.start()
    spin_node(node, node.shutdown, node.done, priority=max(0, int(node.params["realtime_priority"]) - 10))
    if node.error is not None:
        raise node.error
    return 0
