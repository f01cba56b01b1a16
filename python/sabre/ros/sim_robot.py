"""The simulated robot node: a plant (sabre.Plant, or sabre.MujocoPlant) stepped against the wall clock
behind what a Franka arm's and a mobile base's drivers offer (:mod:`sabre.ros.sim_drivers`): arm
joint velocities in, their stream checked by the arm's discontinuity reflexes
(:mod:`sabre.ros.reflexes`; a violation aborts the motion and publishes the error), a base twist
in, a command timeout on the robot side, and run-time faults (stuck door, obstacles).

The 1 kHz streams (the arm's commands in, its joint states out) run through the core's
`SimDriver`, which takes and publishes them through rcl from the plant loop (:mod:`sabre.ros.direct`)
without an executor callback or a message object per tick (``direct_middleware``)."""

from __future__ import annotations

import json
import math
import threading
import time
from typing import Any

import numpy as np

from .. import _core, tasks
from ..closed_loop import paper_start_state
from ..episode import contact_force_stats, hand_contact_forces
from ..errors import SabreError
from ..inner_loop import LowLevelController
from ..scene import Scene
from ..sim import Plant
from . import PeriodicThread, gil_priority, realtime_middleware, realtime_thread, require_ros, spin_node
from .direct import handle_address, rcl_functions
from .durations import Durations, gap_percentiles
from .params import SIM_ROBOT_PARAMETERS, declare
from .qos import profile
from .reflexes import FrankaReflexes
from .sim_drivers import DriverOutputs

__all__ = ["SimRobotNode", "run_sim_robot", "make_plant"]

#: How many of the newest states an echo is matched against (4 s at 1 kHz).
RECENT_STATES = 4096


def make_plant(kind: str, scene: Scene, dt: float) -> Any:
    """The plant ``kind`` ("rapier": :class:`sabre.Plant`; "mujoco": ``sabre.MujocoPlant``)."""
    if kind == "rapier":
        return Plant(scene, dt=dt)
    if kind == "mujoco":
        import sabre

        plant_class = getattr(sabre, "MujocoPlant", None)
        if plant_class is None:
            raise SabreError("plant 'mujoco' needs sabre.MujocoPlant, which this sabre does not have")
        return plant_class(scene, dt=dt)
    raise SabreError(f"plant must be 'rapier' or 'mujoco', got {kind!r}")


class SimRobotNode:
    """The plant steps on its own thread at ``rate`` Hz of wall-clock time, each due tick with the
    commands in effect at its scheduled time (an arm or base command older than
    ``command_timeout`` stops that part), then publishes what the drivers publish at that tick."""

    def __init__(self, overrides: dict[str, Any] | None = None, node_name: str = "sabre_sim_robot") -> None:
        require_ros()
        import rclpy

        self.node = rclpy.create_node(node_name)
        p = self.params = declare(self.node, SIM_ROBOT_PARAMETERS, overrides)
        self._build_plant(p)
        self._init_bookkeeping(p)
        self.out = DriverOutputs(self.node, p, self.scene, self.arm_index, self._robot_urdf(p))
        self._build_driver(p)
        if p["publish_object_pose"]:
            self.out.publish_object_pose(self.object_pose, str(p["world_frame"]))
        self._create_inputs(p)
        self._status = PeriodicThread(
            1.0 / float(p["status_rate"]),
            self._publish_status,
            "sabre-status",
            self._status_failed,
            priority=gil_priority(int(p["realtime_priority"]) - 10),
        )
        self._thread = threading.Thread(target=self._loop, name="sabre-sim-robot", daemon=True)
        self.done = threading.Event()
        self.error: Exception | None = None

    def _status_failed(self, exc: Exception) -> None:
        self.node.get_logger().error(f"status not published: {exc}")

    # Set-up ----------------------------------------------------------------------------------
    def _build_plant(self, p: dict[str, Any]) -> None:
        pose = list(p["object_pose"])
        robot_file = str(p["robot_description_file"])
        if robot_file:
            scene = Scene.from_urdf(robot_file, str(p["object"]), pose or None)
        else:
            scene = Scene.load(obj=p["object"], obj_pose=pose or None)
        self.scene = scene
        self.object_pose = np.array(pose) if pose else _pose_of(scene.object_pose)
        self.task = tasks.OpenObject()
        self.period = 1.0 / float(p["rate"])
        self.plant = make_plant(str(p["plant"]), scene, self.period)
        torque = getattr(self.plant, "command_interface", "torque") == "torque"
        self.low = (
            LowLevelController(scene, dt=self.period, gain_inertia_floor=float(p["gain_inertia_floor"])) if torque else None
        )
        # Rapier's plant with the low-level controller: one call into the core per tick (the
        # reference is finite by construction: checked commands or zeros)
        self._track = self.low._core.track if self.low is not None and isinstance(self.plant, Plant) else None
        x0 = paper_start_state(scene) if p["start"] == "paper" else scene.default_state()
        self.plant.reset(x0)
        base = scene.base_indices
        self.base_index = np.array([] if base is None else list(base), dtype=np.intp)
        self.arm_index = np.array([i for i in range(scene.nq) if i not in set(self.base_index)], dtype=np.intp)

    @staticmethod
    def _robot_urdf(p: dict[str, Any]) -> str:
        if p["robot_description_file"]:
            with open(str(p["robot_description_file"]), encoding="utf-8") as f:
                return f.read()
        from ..assets import urdf_text

        return urdf_text("royalpanda")

    def _build_driver(self, p: dict[str, Any]) -> None:
        """The core's side of the 1 kHz streams (see :class:`sabre._core.SimDriver`)."""
        self._trajectory = p["arm_interface"] == "trajectory"
        reflexes = FrankaReflexes.for_arm(self.period, self.scene.dq_limit[self.arm_index]) if p["reflexes"] else None
        out = self.out
        self._driver = _core.SimDriver(
            self.scene.nq,
            [int(i) for i in self.arm_index],
            self.scene.base_indices,
            self.command_timeout,
            self.period,
            out.joint_state_names,
            out.held_positions,
            out.position_noise,
            out.velocity_noise,
            out.noise_seed,
            p["reflex_check"] == "command",
            RECENT_STATES,
            None if reflexes is None else reflexes.core,
            [float(p["trajectory_position_gain"])] * len(self.arm_index) if self._trajectory else None,
        )
        self._direct_node: Any = None
        self.direct = False  # whether the core takes the arm commands and publishes the joint states

    def _init_bookkeeping(self, p: dict[str, Any]) -> None:
        self.command_timeout = float(p["command_timeout"])
        self._stamped = bool(p["cmd_vel_stamped"])
        self._hold_request: bool | None = None
        self._running = True
        if p["reflex_check"] not in ("command", "cycle"):
            raise SabreError(f"reflex_check must be 'command' or 'cycle', got {p['reflex_check']!r}")
        if p["arm_interface"] not in ("velocity", "trajectory"):
            raise SabreError(f"arm_interface must be 'velocity' or 'trajectory', got {p['arm_interface']!r}")
        self.stats: dict[str, Any] = {
            "ticks": 0,
            "loops": 0,
            "late_ticks": 0,
            "skipped_ticks": 0,
            "overrun_loops": 0,
            "latency": Durations(),
            "loop_work": Durations(),
            "success_time": None,
            "first_command_time": None,
            "contact": ContactRecord(),
            "hold_started": None,
            "hold_ended": None,
            "reflex_errors": [],
        }
        scene = self.scene
        self._hold_at = float(p["hold_at_opening"]) * float(scene.o_upper[0] - scene.o_lower[0]) + float(scene.o_lower[0])
        self._hold_done = False
        from builtin_interfaces.msg import Time

        self._time_msg = Time

    def _create_inputs(self, p: dict[str, Any]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist, TwistStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, String
        from visualization_msgs.msg import MarkerArray

        node, reliable = self.node, profile("reliable")
        self.status_pub = node.create_publisher(DiagnosticArray, p["sim_status_topic"], reliable)
        self.error_pub = node.create_publisher(String, p["error_topic"], reliable)
        self.obstacle_pub = node.create_publisher(MarkerArray, p["obstacle_topic"], reliable)
        self._arm_commands_in(p)
        if len(self.base_index):
            kind = TwistStamped if self._stamped else Twist
            node.create_subscription(kind, p["cmd_vel_topic"], self._on_twist, reliable, raw=True)
        if p["command_echo_topic"]:
            node.create_subscription(JointState, p["command_echo_topic"], self._on_echo, profile("sensor"))
        node.create_subscription(Bool, p["hold_topic"], self._on_hold, reliable)
        node.create_subscription(MarkerArray, p["set_obstacles_topic"], self.obstacle_pub.publish, reliable)

    def _arm_commands_in(self, p: dict[str, Any]) -> None:
        """The arm's commands (velocities, or trajectories through JTC's topic interface) taken by
        the core at each plant tick and the joint states published by it (``direct_middleware``),
        else an executor callback per command."""
        from std_msgs.msg import Float64MultiArray
        from trajectory_msgs.msg import JointTrajectory

        kind, topic = (
            (JointTrajectory, p["trajectory_topic"]) if self._trajectory else (Float64MultiArray, p["arm_command_topic"])
        )
        # a deep queue: every arm command is checked and recorded, also when this process falls behind
        arm_qos = profile("reliable:1000")
        if p["direct_middleware"]:
            try:
                self._connect_direct(kind, topic, arm_qos)
                return
            except SabreError as exc:
                self.node.get_logger().warning(f"the arm commands go through the executor: {exc}")
        self.node.create_subscription(kind, topic, self._on_arm, arm_qos, raw=True)

    def _connect_direct(self, kind: Any, topic: str, qos: Any) -> None:
        """Hands the arm command subscription and the joint state publisher to the core (SabreError,
        with nothing left behind, when this build or this ROS 2 cannot)."""
        import rclpy

        functions = rcl_functions()
        # on a node of its own, which no executor waits on: only the core takes from it
        node = rclpy.create_node(f"{self.node.get_name()}_direct")
        try:
            arm_sub = node.create_subscription(kind, topic, lambda _: None, qos, raw=True)
            js_pub = self.out.js_pub
            self._driver.connect(functions, (arm_sub, handle_address(arm_sub)), (js_pub, handle_address(js_pub)))
        except SabreError:
            node.destroy_node()
            raise
        self._direct_node = node
        self.direct = True

    def start(self) -> None:
        self._start_wall = time.monotonic()
        self._start_cpu = time.process_time()
        self._thread.start()
        self._status.start()

    # Commands --------------------------------------------------------------------------------
    def _on_arm(self, raw: bytes) -> None:
        self._driver.receive_arm(raw, time.monotonic(), time.time())

    def _on_twist(self, raw: bytes) -> None:
        self._driver.receive_base(raw, self._stamped, time.monotonic())

    def _on_echo(self, msg: Any) -> None:
        self._driver.match_answer(msg.header.stamp.nanosec, time.time())

    def _on_hold(self, msg: Any) -> None:
        self._hold_request = bool(msg.data)

    def _events(self) -> None:
        """Logs refused commands and publishes the reflexes tripped since the last tick."""
        rejected, reflexes = self._driver.take_events()
        if rejected:
            self.node.get_logger().error(f"command rejected: {rejected[-1]}", throttle_duration_sec=1.0)
        for error in reflexes:
            self._on_reflex(error)

    def _on_reflex(self, error: str) -> None:
        from std_msgs.msg import String

        self.stats["reflex_errors"].append([self.plant.time, error])
        self.error_pub.publish(String(data=error))
        self.node.get_logger().error(f"reflex: {error}; the arm stops")

    # The plant loop --------------------------------------------------------------------------
    def _loop(self) -> None:
        p = self.params
        if int(p["realtime_priority"]) > 0 and not realtime_thread(int(p["realtime_priority"])):
            self.node.get_logger().warning("real-time priority not permitted for the plant loop: ticks may run late")
        self._schedule = {
            name: max(1, int(round(float(p["rate"]) / float(p[f"{name}_rate"]))))
            for name in ("odometry", "wrench", "clock", "ground_truth")
        }
        try:
            self._run(p)
        except Exception as exc:  # reported by the main thread; the process exits non-zero
            self.error = exc
        finally:
            self.done.set()

    def _run(self, p: dict[str, Any]) -> None:
        check_every = max(1, int(round(0.01 / self.period)))  # the task's success test is Python: 100 Hz
        next_check = 0
        max_behind = max(1, int(float(p["max_catchup"]) / self.period))
        duration, settle = float(p["duration"]), float(p["settle_time"])
        start, k = self._start_wall, 0
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
                # the ticks this loop catches up on are the robot's own lateness, not the stream's
                self._step(start + (k + 1) * self.period, excused=k + 1 < due)
                k += 1
            if due:
                self._publish(k)
                self.stats["loop_work"].record(time.monotonic() - work)
            self.stats["loops"] += 1
            if k >= next_check and self.stats["success_time"] is None:
                next_check = k + check_every
                if self.stats["first_command_time"] is None and self._driver.counts()["arm_commands"]:
                    # the controller's start as the robot sees it: run_episode's t = 0
                    self.stats["first_command_time"] = self.plant.time
                if self.task.success(self.scene, self.plant.state):
                    self.stats["success_time"] = self.plant.time
            opened_at = self.stats["success_time"]
            if p["stop_on_success"] and opened_at is not None and self.plant.time > opened_at + settle:
                break
            if duration > 0 and now - start > duration:
                break
            rest = start + (k + 1) * self.period - time.monotonic()
            if rest > 0:
                time.sleep(rest)

    def _step(self, tick_time: float, excused: bool = False) -> None:
        self._apply_faults()
        x = np.asarray(self.plant.state)
        yaw = float(x[self.base_index[2]]) if len(self.base_index) else 0.0
        u, events = self._driver.tick(tick_time, yaw, time.monotonic(), time.time(), x[: self.scene.nq], excused)
        if events:
            self._events()
        if self._track is not None:
            self._track(self.plant._core, u, 1)
        elif self.low is not None:
            self.low.track(self.plant, u, 1)
        else:
            self.plant.step(u)
        self.stats["ticks"] += 1
        if self.plant.contact:
            self.stats["contact"].record(self.plant.time, self.plant.wrench)

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

    def _publish(self, k: int) -> None:
        """Publishes tick k's joint state (what the controller answers) first, the rest behind it
        at their own rates."""
        x = np.asarray(self.plant.state)
        nq, no = self.scene.nq, self.scene.no
        q, dq = x[:nq], x[nq : 2 * nq]
        ns = time.time_ns()
        raw = self._driver.publish_state(q, dq, ns)
        if raw is not None:
            self.out.js_pub.publish(raw)
        every = self._schedule
        if k % every["odometry"] and k % every["wrench"] and k % every["ground_truth"] and k % every["clock"]:
            return
        stamp = self._time_msg(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if k % every["odometry"] == 0 and self.out.odom_pub is not None:
            self.out.publish_odometry(q, dq, stamp)
        if k % every["wrench"] == 0:
            self.out.publish_wrench(q, np.asarray(self.plant.wrench), stamp)
        if k % every["ground_truth"] == 0:
            self.out.publish_truth(x[2 * nq : 2 * nq + no], x[2 * nq + no :], stamp)
        if k % every["clock"] == 0:
            self.out.publish_clock(self.plant.time)

    # Reports ---------------------------------------------------------------------------------
    def _cycle_summary(self) -> dict[str, Any]:
        """What the arm saw at its cycles: the gaps between command deliveries and the largest
        acceleration and jerk of the command in effect (the robot's own late ticks excused)."""
        speed, accel, jerk = self._driver.cycle_maxima()
        return {
            "arm_interface": "trajectory" if self._trajectory else "velocity",
            "delivery_gaps": gap_percentiles(self._driver.delivery_gaps(), self.period),
            "cycle_speed_max": speed.tolist(),
            "cycle_accel_max": accel.tolist(),
            "cycle_jerk_max": jerk.tolist(),
        }

    def summary(self) -> dict[str, Any]:
        s = self.stats
        driver = self._driver
        counts = driver.counts()
        s["latency"].record_all(driver.take_latencies())
        step_max, step_change_max, speed_max, command = driver.arm_record()
        if self._trajectory:
            # the commands are JTC's, one per cycle: their extremes are the cycles'
            speed_max, step_max, step_change_max = (np.asarray(m) for m in driver.cycle_maxima())
            step_max, step_change_max = step_max * self.period, step_change_max * self.period**2
        state = self.scene.split_state(np.asarray(self.plant.state))
        lat = s["latency"]
        wall = time.monotonic() - self._start_wall
        first, last = counts["first_answered"], counts["last_answered"]
        window = 0 if first is None or last is None else last - first + 1
        return {
            "node": "sim_robot",
            "object": self.scene.object_name,
            "object_pose": [float(v) for v in self.object_pose],
            "sim_time": self.plant.time,
            "wall_time": wall,
            "cpu_share": (time.process_time() - self._start_cpu) / wall if wall > 0 else 0.0,
            **{k: s[k] for k in ("ticks", "late_ticks", "skipped_ticks", "overrun_loops", "loops")},
            **{
                k: counts[k]
                for k in (
                    "states_published",
                    "arm_commands",
                    "base_commands",
                    "rejected_commands",
                    "echoes",
                    "late_echoes",
                    "unmatched_echoes",
                )
            },
            "loop_work_p50_ms": s["loop_work"].percentile_ms(50),
            "loop_work_p99_ms": s["loop_work"].percentile_ms(99),
            "latency_p50_ms": lat.percentile_ms(50),
            "latency_p99_ms": lat.percentile_ms(99),
            "latency_max_ms": lat.max_ms(),
            "latency_percentiles_ms": {q: lat.percentile_ms(q) for q in (50, 90, 95, 98, 99, 99.5, 99.9)},
            "answered_window": window,
            "delivered_fraction": counts["echoes"] / window if window else 0.0,
            "stop_delays_ms": [d * 1e3 for d in driver.stops()],
            "command_timeout_ms": self.command_timeout * 1e3,
            "period_ms": self.period * 1e3,
            "reflex_aborts": counts["reflex_aborts"],
            "reflex_aborted": counts["reflex_aborted"],
            "direct_middleware": self.direct,
            "reflex_errors": s["reflex_errors"],
            "arm_accel_max": (step_max / self.period).tolist(),
            "arm_jerk_max": (step_change_max / self.period**2).tolist(),
            "arm_speed_max": speed_max.tolist(),
            "last_arm_command": command.tolist(),
            **self._cycle_summary(),
            "opening": float(state.o[0]),
            "success": s["success_time"] is not None,
            # plant time (s) of the success and of the first arm command taken (checked at 100 Hz)
            "success_time": s["success_time"],
            "first_command_time": s["first_command_time"],
            # from the first arm command to the success: the controller's time to open, without the
            # seconds the robot ran before the controller was configured and activated
            "time_to_open": None
            if s["success_time"] is None or s["first_command_time"] is None
            else s["success_time"] - s["first_command_time"],
            **self._contact_summary(),
            "hold_started": s["hold_started"],
            "hold_ended": s["hold_ended"],
            "robot_speed": float(np.linalg.norm(state.q_dot)),
            "configuration": dict(zip(self.scene.joint_names, state.q.tolist())),
        }

    def _contact_summary(self) -> dict[str, Any]:
        """The hand's contact force over the run and from the success on (statistics of
        :func:`sabre.episode.hand_contact_forces`, as :class:`sabre.Episode` reports it)."""
        times, forces = self.stats["contact"].forces()
        opened_at = self.stats["success_time"]
        total = contact_force_stats(forces)
        after = contact_force_stats(forces[times >= opened_at] if opened_at is not None else forces[:0])
        return {
            "mean_wrench": total["mean"] if total["steps"] else 0.0,
            "contact_steps": total["steps"],
            "contact_force_mean": total["mean"],
            "contact_force_p99": total["p99"],
            "contact_force_max": total["max"],
            "contact_force_after_success": after,
        }

    def _publish_status(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        s = self.summary()
        keys = (
            "sim_time",
            "ticks",
            "late_ticks",
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
            "reflex_aborts",
            "stop_delays_ms",
            "arm_accel_max",
            "arm_jerk_max",
            "arm_speed_max",
            "last_arm_command",
        )
        aborted = s["reflex_aborted"]
        status = DiagnosticStatus(
            name="sabre/sim_robot",
            hardware_id="sim",
            level=DiagnosticStatus.ERROR if aborted else DiagnosticStatus.OK,
            message=aborted or "running",
            values=[KeyValue(key=k, value=json.dumps(s[k])) for k in keys],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.status_pub.publish(msg)

    def shutdown(self) -> dict[str, Any]:
        self._running = False
        self._status.stop()
        if self._thread.is_alive():
            self._thread.join()
        summary = self.summary()
        times, forces = self.stats["contact"].forces()
        summary["contact_force_trace"] = [[round(float(t), 4), round(float(f), 3)] for t, f in zip(times, forces)]
        self._driver.disconnect()  # before the endpoints it calls into are destroyed
        if self._direct_node is not None:
            self._direct_node.destroy_node()
            self._direct_node = None
        return summary


class ContactRecord:
    """The plant ticks in robot–object contact: their time and the wrist wrench's force, kept in a
    buffer that doubles when full (a row write per tick on the plant loop)."""

    def __init__(self) -> None:
        self._rows = np.empty((4096, 4))
        self._n = 0

    def record(self, t: float, wrench: np.ndarray) -> None:
        if self._n == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        row = self._rows[self._n]
        row[0] = t
        row[1:] = wrench[:3]
        self._n += 1

    def forces(self) -> tuple[np.ndarray, np.ndarray]:
        """(times (s), the hand's contact forces (N)) of the ticks recorded so far."""
        n = self._n  # before the buffer: a row is counted only once written, into the buffer in place
        rows = self._rows[:n]
        return rows[:, 0].copy(), hand_contact_forces(rows[:, 1:], np.ones(len(rows), dtype=bool))


def _pose_of(t: np.ndarray) -> np.ndarray:
    """(x, y, z, roll, pitch, yaw) of a (4, 4) pose."""
    r = t[:3, :3]
    pitch = math.asin(max(-1.0, min(1.0, -float(r[2, 0]))))
    return np.array([t[0, 3], t[1, 3], t[2, 3], math.atan2(r[2, 1], r[2, 2]), pitch, math.atan2(r[1, 0], r[0, 0])])


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
