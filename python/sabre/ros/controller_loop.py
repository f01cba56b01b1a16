"""The configured controller: the scene and cascade built from the descriptions, the measured inputs,
the command gate and the endpoints of the 1 kHz path, with the watchdog that ramps the commands to
zero when states stop coming. The controller node builds one on configure and drops it on cleanup.

The 1 kHz path runs in the core (``_core.BridgeTick``): each arm joint state arrives serialized,
and one call merges it, estimates the object, runs the cascade's tick (on the deployment loop's
:attr:`~sabre.RealtimeCascade.core`, the same tick every loop runs) and the rate-limited gate, and
returns the serialized commands to publish; Python decides only whether the tick follows the plan."""

from __future__ import annotations

import collections
import functools
import math
import threading
import time
from typing import Any

import numpy as np

from .. import _core
from ..errors import SabreError
from ..estimation import ObjectStateEstimator
from ..realtime import RealtimeCascade
from . import gil_priority, realtime_thread
from .commands import CommandGate, CommandShaper, command_limits, joint_accelerations
from .conversions import MessageError, yaw_of
from .descriptions import Descriptions, build_controller, build_scene
from .durations import Durations
from .inputs import JointStates, JointTorques, base_from_odometry
from .qos import profile
from .trajectory import arm_interface, command_delay, stream_trajectory, trajectory_limits

__all__ = ["ControllerLoop", "TASK_STATES"]

#: The task's phases in which its hook sits on the handle (release: it lets go of a door that opens
#: by itself, along that door's path; hold: it holds an object that stopped following the pull):
#: the estimator declares and keeps a hook only then.
HOOK_SEATED_PHASES = ("hook", "open", "release", "hold")

#: idle: no task; starting: the planner starts on the next state; running; succeeded: the task's
#: success test passed on the controller's state (``stop_on_success``): the commands ramp to zero and
#: the planner stops (start it again for another run); failed: the planner stopped on an error
#: (reset to start again).
TASK_STATES = ("idle", "starting", "running", "succeeded", "failed")

#: How often (s of state time) a running task's success test is asked: the sim robot's rate too.
SUCCESS_CHECK_PERIOD = 0.01


class ControllerLoop:
    """Everything between a configure and a cleanup of the controller node (see the module)."""

    def __init__(self, node: Any, params: dict[str, Any], descriptions: Descriptions) -> None:
        self.node = node
        self.params = p = params
        self.descriptions = descriptions
        self.scene = build_scene(descriptions)
        self._map_joints(p)
        dq = self.scene.dq_limit
        self.limits = command_limits(dq[self.arm_index], dq[self.base_index] if self.has_base else None, p)
        self.arm_interface = arm_interface(p)
        self.trajectory_limits = trajectory_limits(dq[self.arm_index], p) if self.arm_interface == "trajectory" else None
        # the planner's model moves each joint no faster than its command path lets it
        arm = self.trajectory_limits or self.limits.arm
        accelerations = joint_accelerations(self.scene.nq, self.arm_index, arm.acceleration, self.base_index, self.limits.base)
        setup = (descriptions, str(p["variant"]), int(p["seed"]), int(p["threads"]), accelerations)
        factory = functools.partial(build_controller, *setup)
        self.controller = build_controller(*setup, scene=self.scene)
        self._init_inputs(p)
        self.cascade = RealtimeCascade(
            self.controller,
            min_replan_period=float(p["min_replan_period"]),
            planner_process=factory if p["planner_process"] else None,
            planner_nice=int(p["planner_nice"]),
            planner_idle=bool(p["planner_idle"]),
            delay_compensation=bool(p["delay_compensation"]),
            command_delay=command_delay(p),
            tau_ext_cutoff=float(p["tau_ext_cutoff"]),
            tau_ext_timeout=float(p["wrench_timeout"]),
            wrench_frames=self._wrench_frames,
        )
        self.horizon = float(self.controller.config.horizon)
        self._init_tick(p)
        self._lock = threading.Lock()  # the tick's gate and the command publishers
        self._init_state()
        self._create_endpoints(p)
        self._running = True
        self._watchdog = threading.Thread(target=self._watch, name="sabre-command-watchdog", daemon=True)
        self._watchdog.start()

    # Set-up ----------------------------------------------------------------------------------
    def _map_joints(self, p: dict[str, Any]) -> None:
        """The robot's names for sabre's joints, the arm command's joints and the base's, as indices.
        The base is the scene's (its planar joints, or none for a fixed base) unless ``base_joints``
        names the driver's three; the arm command takes every joint that is not the base's."""
        scene = self.scene
        names = list(p["joint_names"]) or list(scene.joint_names)
        if len(names) != scene.nq:
            raise SabreError(f"joint_names needs {scene.nq} names (for {scene.joint_names}), got {names}")
        index = {n: i for i, n in enumerate(names)}
        base = list(p["base_joints"])
        if not base and scene.base_indices is not None:
            base = [names[i] for i in scene.base_indices]
        arm = list(p["arm_joints"]) or [n for n in names if n not in base]
        for n in arm + base:
            if n not in index:
                raise SabreError(f"joint {n!r} is not one of joint_names {names}")
        if base and len(base) != 3:
            raise SabreError(f"base_joints needs the base's x, y and yaw joints, got {base}")
        if base and scene.base_indices is None:
            raise SabreError(f"base_joints {base}: the robot has a fixed base (docs/robots.md says how to declare one)")
        self.has_base = bool(base)
        self.names, self.arm_joints, self.base_joints = names, arm, base
        self.arm_index = np.array([index[n] for n in arm], dtype=np.intp)
        self.base_index = np.array([index[n] for n in base], dtype=np.intp)

    def _init_inputs(self, p: dict[str, Any]) -> None:
        """The merged joint states (the base's from odometry when it has a topic), the wrench or
        torque input and the object state (a topic, else the estimator)."""
        timeouts = np.full(self.scene.nq, float(p["state_timeout"]))
        self.base_from_odometry = self.has_base and bool(p["odometry_topic"])
        if self.base_from_odometry:
            timeouts[self.base_index] = float(p["base_state_timeout"])
        self._timeouts = timeouts
        wrench_frame = str(p["wrench_frame"]) or self.scene.wrist_sensor_link
        self._wrench_frames = (str(p["world_frame"]), wrench_frame, str(p["wrench_point_frame"]))
        self.torques = JointTorques(self.names, self.scene.nq, float(p["tau_ext_sign"])) if p["tau_ext_topic"] else None
        self.estimator = None  # the estimator's settings and frames; a copy of its core runs in the tick
        if not p["object_state_topic"]:
            self.estimator = ObjectStateEstimator(self.scene, handle=self.descriptions.handle)

    def _init_tick(self, p: dict[str, Any]) -> None:
        """The core's tick, on its own copies of the merge and the estimator, and the cascade's command
        shaping: the rate-limited gate on the arm's and the base's joints."""
        joints = JointStates(self.names, self.arm_joints, self._timeouts)
        gate = CommandGate(CommandShaper(self.limits), float(p["state_timeout"]))
        base = [int(i) for i in self.base_index] if self.has_base else None
        self.cascade.core.set_shaping(gate.core, [int(i) for i in self.arm_index], base)
        segments = self.trajectory_limits is not None
        accelerations = self.trajectory_limits is not None and stream_trajectory(self.cascade.core, self.trajectory_limits, p)
        self.tick = _core.BridgeTick(
            self.cascade.core,
            joints.core,
            None if self.estimator is None else self.estimator.core,
            [float(v) for v in self.scene.o_lower],
            [0.0] * self.scene.no,
            float(p["max_tick_dt"]),
            bool(p["cmd_vel_stamped"]),
            str(p["cmd_vel_frame"]),
            list(self.arm_joints) if p["command_echo_topic"] else None,
            list(self.arm_joints) if segments else None,
            accelerations,
        )

    def _init_state(self) -> None:
        """The node's flags, the task's state and the statistics the summary reports."""
        self.active = False
        self.estop = False
        self.task = "idle"
        self.reason: str | None = "inactive"  # why the last tick did not follow the plan (None: it did)
        self.failure = ""
        self._last_status = "none"
        self._last_tank = float(self.controller.tank.energy)
        self._min_tank = self._last_tank
        self._phase = self.controller.phase
        self._planner_started: float | None = None
        self.success_time: float | None = None  # the state time the task succeeded at
        self._success_checked = -math.inf
        self._hooked = False
        self._x: np.ndarray | None = None  # the newest state and its time (the visualization's)
        self._last_t: float | None = None
        self._stopper: threading.Thread | None = None  # stops the planner off the 1 kHz path
        self.stats: dict[str, Any] = {
            "plan_stale": 0,
            "compute": Durations(),
            "state_age": Durations(),
            "phase_changes": 0,
            "recent_phases": collections.deque(maxlen=100),
            "stops": collections.Counter(),
            "cpu_start": (time.monotonic(), time.process_time()),
        }

    def _create_endpoints(self, p: dict[str, Any]) -> None:
        from geometry_msgs.msg import Twist, TwistStamped, WrenchStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        from trajectory_msgs.msg import JointTrajectory

        node = self.node
        self._subs: list[Any] = []
        self._pubs: list[Any] = []
        if self.arm_interface == "trajectory":
            self.arm_pub = node.create_publisher(JointTrajectory, p["trajectory_topic"], profile(p["trajectory_qos"]))
        else:
            self.arm_pub = node.create_publisher(Float64MultiArray, p["arm_command_topic"], profile(p["arm_command_qos"]))
        self.base_pub = None
        if self.has_base:
            kind = TwistStamped if p["cmd_vel_stamped"] else Twist
            self.base_pub = node.create_publisher(kind, p["cmd_vel_topic"], profile(p["cmd_vel_qos"]))
            self._pubs.append(self.base_pub)
        self._pubs.append(self.arm_pub)
        self.echo_pub = None
        if p["command_echo_topic"]:
            self.echo_pub = node.create_publisher(JointState, p["command_echo_topic"], profile(p["command_echo_qos"]))
            self._pubs.append(self.echo_pub)
        sub = node.create_subscription
        # the joint states arrive serialized: the core reads them (no message object at 1 kHz)
        qos = profile(p["joint_state_qos"])
        self._subs.append(sub(JointState, p["joint_state_topic"], self.on_joint_state, qos, raw=True))
        if self.base_from_odometry:
            self._subs.append(sub(Odometry, p["odometry_topic"], self.on_odometry, profile(p["odometry_qos"])))
        if self.torques is not None:
            self._subs.append(sub(JointState, p["tau_ext_topic"], self.on_torques, profile(p["tau_ext_qos"])))
        elif p["wrench_topic"]:
            self._subs.append(sub(WrenchStamped, p["wrench_topic"], self.on_wrench, profile(p["wrench_qos"]), raw=True))
        if p["object_state_topic"]:
            self._subs.append(sub(JointState, p["object_state_topic"], self.on_object, profile(p["object_state_qos"])))

    def input_topics(self) -> dict[str, str]:
        """The inputs that must have a publisher: label → topic name as given."""
        p = self.params
        topics = {"joint states": p["joint_state_topic"]}
        if self.base_from_odometry:
            topics["odometry"] = p["odometry_topic"]
        if self.torques is not None:
            topics["joint torques"] = p["tau_ext_topic"]
        elif p["wrench_topic"]:
            topics["wrench"] = p["wrench_topic"]
        if p["object_state_topic"]:
            topics["object state"] = p["object_state_topic"]
        return topics

    # Inputs besides the joint states ---------------------------------------------------------
    def on_odometry(self, msg: Any) -> None:
        pose, twist = msg.pose.pose, msg.twist.twist
        o = pose.orientation
        try:
            q, rates = base_from_odometry(
                pose.position.x,
                pose.position.y,
                yaw_of(o.x, o.y, o.z, o.w),
                (twist.linear.x, twist.linear.y, twist.angular.z),
                bool(self.params["odometry_twist_in_child_frame"]),
            )
        except MessageError as exc:
            self._log_rejected("odometry", exc)
            return
        self.tick.set_joints([int(i) for i in self.base_index], np.asarray(q), np.asarray(rates), time.monotonic())

    def on_wrench(self, raw: bytes) -> None:
        """A wrist wrench, read serialized in the core: τ_ext at the wrench's rate, not the
        states' (the joints move little between two wrenches, and the tank reads τ_ext low-passed
        at tau_ext_cutoff)."""
        try:
            self.tick.set_wrench(raw, time.monotonic())
        except SabreError as exc:
            self._log_rejected("wrench", exc)

    def on_torques(self, msg: Any) -> None:
        assert self.torques is not None
        try:
            tau = self.torques.update(msg.name, msg.effort)
        except MessageError as exc:
            self._log_rejected("joint torques", exc)
            return
        # torques only: contact assumed (the estimator's hook test is then the distance)
        self.cascade.set_external_torque(tau, math.inf, time.monotonic())

    def on_object(self, msg: Any) -> None:
        names = list(self.scene.object_joint_names)
        try:
            lookup = {n: i for i, n in enumerate(msg.name)}
            if any(n not in lookup for n in names):
                raise MessageError(f"object state lacks {names}")
            o = np.array([msg.position[lookup[n]] for n in names], dtype=np.float64)
            od = np.array([msg.velocity[lookup[n]] if len(msg.velocity) else 0.0 for n in names], dtype=np.float64)
            if not (np.isfinite(o).all() and np.isfinite(od).all()):
                raise MessageError("object state: non-finite value")
        except (MessageError, IndexError) as exc:
            self._log_rejected("object state", exc)
            return
        self.tick.set_object(o, od)

    def _log_rejected(self, what: str, exc: Exception | str) -> None:
        self.node.get_logger().error(f"{what} rejected: {exc}", throttle_duration_sec=1.0)

    # The 1 kHz path --------------------------------------------------------------------------
    def on_joint_state(self, raw: bytes) -> None:
        """One tick per arm joint state: the command that follows the plan, or a ramp step."""
        received = time.monotonic()
        tick = self.tick
        with self._lock:
            kind, t, error = tick.receive(raw, received)
            if kind == "merged":
                return  # fingers, another driver's joints: merged, no tick
            if error is not None:
                self._log_rejected("joint state", error)
                if kind == "rejected-tick":
                    self.reason = "rejected state"
                    self._publish(*tick.stop(received))  # a ramp step, never a step to zero
                    self.stats["stops"]["rejected state"] += 1
                return
            self.reason = self._follow(received, t, kind == "tick")
        self.stats["state_age"].record(time.time() - tick.stamp)
        if self.reason is None:
            self.stats["compute"].record(time.monotonic() - received)
            self._note_phase(t)
        else:
            self.stats["stops"][self.reason] += 1

    def _follow(self, received: float, t: float, fresh: bool) -> str | None:
        """Answers the state at time t: follows the plan if nothing stops it (None), else publishes
        a ramp step and returns the reason. The caller holds the lock."""
        reason = self._blocked(fresh)
        if reason is None:
            reason = self._run_task(received, t)
        if reason is not None:
            self._publish(*self.tick.stop(received))
        return reason

    def _blocked(self, fresh: bool) -> str | None:
        if self.estop:
            return "e-stop"
        if not self.active:
            return "inactive"
        if not fresh:
            return "stale state"
        if self.task in ("idle", "succeeded", "failed"):
            return {"idle": "no task", "succeeded": "task succeeded", "failed": "planner stopped"}[self.task]
        return None

    def _run_task(self, received: float, t: float) -> str | None:
        """The running task's tick at time t: its command published (None), or why not."""
        may_hook = self.cascade.phase in HOOK_SEATED_PHASES
        if self.task == "starting":
            if self._stopper is not None and self._stopper.is_alive():
                return "planning"  # the previous planner is still stopping
            x = self._x = self.tick.observe(t, may_hook)
            self._last_t = t
            self.cascade.start(x, t, wait=False)  # the planner process makes its first plan meanwhile
            self._planner_started = time.monotonic()
            self.task = "running"
            return "planning"
        try:
            self.cascade.poll()  # a newer plan of the planner process takes over
        except SabreError as exc:
            self._fail(f"planner failed: {exc}")
            return "planner stopped"
        try:
            reason, step, x, energy, status = self.tick.follow(t, received, may_hook, self.horizon)
        except SabreError as exc:
            self._fail(f"inner loop failed: {exc}")
            return "planner stopped"
        self._x, self._last_t = x, t
        self._observe(x, t)  # the planner's next starting point
        if reason is not None:
            self.stats["plan_stale"] += reason == "plan stale"
            return reason
        assert step is not None, "a followed tick has its step"
        self._publish(*step)
        self._last_status, self._last_tank = status, float("nan") if energy is None else energy
        self._min_tank = min(self._min_tank, self._last_tank)
        if self.estimator is not None:
            self._note_hook(t)
        self._check_success(x, t)
        return None

    def _check_success(self, x: np.ndarray, t: float) -> None:
        """Ends the task once its success test passes on the state x at time t (``stop_on_success``),
        as :func:`sabre.run_episode` ends its episode: the plan in force would go on pulling (an
        opening task's object set-point lies past its target, up to the object's stop). The caller
        holds the lock and has published this tick's step; the next ticks ramp to zero, and the
        planner stops off the 1 kHz path."""
        if not self.params["stop_on_success"] or t - self._success_checked < SUCCESS_CHECK_PERIOD:
            return
        self._success_checked = t
        if not self.controller.task.success(self.scene, x):
            return
        self.task, self.success_time = "succeeded", t
        estimated = "estimated " if self.estimator is not None else ""
        self.node.get_logger().info(
            f"task succeeded at t = {t:.3f} s ({estimated}opening {self.opening():.3f}): ramping to zero, planner stopped"
        )
        self.stop_planner()

    def _note_hook(self, t: float) -> None:
        """Logs each hook and release of the object estimate."""
        estimate = self.tick.estimate
        if estimate is not None and estimate[2] != self._hooked:
            self._hooked = estimate[2]
            what = "hooked" if estimate[2] else "released"
            residual = f", residual {estimate[3]:.3f} m" if not estimate[2] else ""
            self.node.get_logger().info(f"object estimate: {what} at o = {estimate[0]:.3f} (t = {t:.3f} s{residual})")

    def _observe(self, x: np.ndarray, t: float) -> None:
        try:
            self.cascade.observe(x, t)
        except SabreError as exc:
            self._fail(f"planner failed: {exc}")

    def _fail(self, message: str) -> None:
        self.node.get_logger().error(message + "; ramping to zero, planner stopped (reset to start again)")
        self.failure = message
        self.task = "failed"
        self.stop_planner()

    def _publish(self, arm: bytes | None, base: bytes | None, echo: bytes | None, segment: bytes | None) -> None:
        """Publishes one step of the command streams, serialized by the core tick (the caller holds
        the lock): the arm's velocity command or, on the trajectory interface, its segment when one is
        due (stamped with the answered state's stamp). A velocity command that answers a joint state
        carries that state's stamp's nanoseconds in ``layout.data_offset``, which a velocity
        controller ignores and a robot (or the simulated one) can match to the state, to measure the
        round trip without a message of its own; the watchdog's and the shutdown's carry 0."""
        if arm is not None:
            self.arm_pub.publish(arm)
        elif segment is not None:
            self.arm_pub.publish(segment)
        if base is not None and self.base_pub is not None:
            self.base_pub.publish(base)
        if echo is not None and self.echo_pub is not None:
            self.echo_pub.publish(echo)

    def _note_phase(self, t: float) -> None:
        if self.cascade.phase != self._phase:
            self.node.get_logger().info(f"phase {self._phase} -> {self.cascade.phase} at t = {t:.3f} s")
            self._phase = self.cascade.phase
            self.stats["phase_changes"] += 1
            self.stats["recent_phases"].append((t, self._phase))

    def _watch(self) -> None:
        """Ramps the commands to zero, one step per command period, once no joint state came for
        ``state_timeout``."""
        realtime_thread(gil_priority(int(self.params["realtime_priority"])))
        events = 0
        while self._running:
            with self._lock:
                now = time.monotonic()
                if self.tick.next_look(now) <= 0.0:
                    for step in self.tick.watchdog(now, self.node.get_clock().now().nanoseconds):
                        self._publish(*step)
                wait = self.tick.next_look(time.monotonic())
            if self.tick.stale_events != events:
                events = self.tick.stale_events
                self.node.get_logger().warning(f"no joint state for {self.tick.state_timeout} s: ramping the commands to zero")
            time.sleep(min(max(wait, 2e-4), 0.02))

    def _stop_watchdog(self) -> None:
        self._running = False
        if self._watchdog.is_alive() and self._watchdog is not threading.current_thread():
            self._watchdog.join()

    def stop_planner(self) -> None:
        """Stops the planner on a thread of its own: stopping a planner process takes long enough
        to hold up the ticks behind it, and they must ramp the commands down meanwhile."""
        if self._stopper is not None and self._stopper.is_alive():
            return
        self._stopper = threading.Thread(target=self.cascade.stop, name="sabre-planner-stop", daemon=True)
        self._stopper.start()

    # Task and lifecycle ----------------------------------------------------------------------
    def activate(self) -> None:
        """Commands follow the plan again (ramping in from wherever the streams are)."""
        self.active = True
        if self.params["start_on_activate"] and self.task == "idle":
            self.task = "starting"

    def deactivate(self) -> None:
        """Commands ramp to zero; the planner pauses (stops; activating starts it afresh)."""
        self.active = False
        self.stop_planner()
        if self.task in ("starting", "running"):
            self.task = "idle"

    def latch_estop(self) -> None:
        """The e-stop: the commands ramp to zero from the next tick on, the planner stops, the task
        is idle once reset."""
        self.estop = True
        self.stop_planner()
        if self.task in ("starting", "running"):
            self.task = "idle"

    def start_task(self) -> str:
        """Starts the task (the planner on the next state); '' or why not."""
        if self.estop:
            return "the e-stop is latched: reset first"
        if self.task == "failed":
            return f"the planner stopped ({self.failure}): reset first"
        if not self.active:
            return "not active: activate the node first"
        if self.task in ("starting", "running"):
            return "the task is already running"
        self.task, self.success_time = "starting", None
        return ""

    def cancel_task(self) -> None:
        """Stops the task: the commands ramp to zero, the planner stops."""
        self.stop_planner()
        self.task = "idle"

    def reset_task(self) -> None:
        """Clears the e-stop and a planner failure; the task is idle until started."""
        self.stop_planner()
        self.estop = False
        self.task = "idle"
        self.failure = ""

    def ramp_down(self, deadline: float) -> bool:
        """Publishes the ramp to zero from this thread, one step per period at most, until the
        streams rest (the shutdown's stop: no executor delivers states any more; on the trajectory
        interface the arm's stop segment goes first). The watchdog stops first: two threads stepping
        the limiters would put two steps into one period. A late step delays the next one, never
        brings it forward, so that a late wake-up slows the ramp and never steepens it. Returns
        whether they came to rest."""
        self._stop_watchdog()
        period = self.tick.period
        while time.monotonic() < deadline:
            with self._lock:
                step = self.tick.ramp_step(self.node.get_clock().now().nanoseconds)
                if step is None:
                    return True
                self._publish(*step)
            time.sleep(period)  # from the step just sent: the next is a period later or more
        return bool(self.tick.at_rest)

    def destroy(self) -> None:
        """Stops the watchdog and the planner and removes the endpoints."""
        self._stop_watchdog()
        if self._stopper is not None:
            self._stopper.join()
        self.cascade.stop()
        for s in self._subs:
            self.node.destroy_subscription(s)
        for pub in self._pubs:
            self.node.destroy_publisher(pub)

    # Reports ---------------------------------------------------------------------------------
    def opening(self) -> float:
        """The object's estimated (or received) coordinate."""
        return float(self.tick.opening)

    def planner_rate(self) -> float:
        if self._planner_started is None:
            return 0.0
        elapsed = time.monotonic() - self._planner_started
        return self.cascade.iterations / elapsed if elapsed > 0 else 0.0

    def cpu_share(self) -> float:
        """This process's CPU time over wall time since configure (the planner process not counted)."""
        wall0, cpu0 = self.stats["cpu_start"]
        wall = time.monotonic() - wall0
        return (time.process_time() - cpu0) / wall if wall > 0 else 0.0

    def summary(self) -> dict[str, Any]:
        s = self.stats
        counts = self.tick.counts
        compute, age = s["compute"], s["state_age"]
        f = self.controller.inner_filter
        return {
            "ticks": counts["ticks"],
            "followed": counts["followed"],
            "answered": counts["answered"],
            "rejected": counts["rejected"],
            "stale_events": self.tick.stale_events,
            "stops": dict(s["stops"]),
            "plan_stale": s["plan_stale"],
            "wrench_stale": counts["wrench_stale"],
            "wrench_received": counts["wrench_received"],
            "planner_iterations": self.cascade.iterations,
            "planner_rate_hz": self.planner_rate(),
            "tick_compute_p50_ms": compute.percentile_ms(50),
            "tick_compute_p99_ms": compute.percentile_ms(99),
            "tick_compute_p999_ms": compute.percentile_ms(99.9),
            "tick_compute_max_ms": compute.max_ms(),
            "state_age_p50_ms": age.percentile_ms(50),
            "state_age_p99_ms": age.percentile_ms(99),
            "tank_energy": self._last_tank,
            "tank_min": self._min_tank,
            "tank_floor": self.controller.tank.floor,
            "filter_fallbacks": int(f.stats.fallbacks) if f is not None else 0,
            "phase": self.cascade.phase,
            "phase_changes": s["phase_changes"],
            "recent_phases": [[round(t, 3), ph] for t, ph in s["recent_phases"]],
            "task": self.task,
            "success_time": self.success_time,
            "reason": self.reason,
            "opening": self.opening(),
            "estop": self.estop,
            "cpu_share": self.cpu_share(),
            "planner_process": self.cascade.planner_in_process,
            "arm_interface": self.arm_interface,
            "trajectory": self.cascade.core.trajectory_counts,
            "limits": self._limits_report(),
        }

    def _limits_report(self) -> dict[str, list[float]]:
        """The arm's command limits: the segments' on the trajectory interface, else the stream's."""
        arm = self.trajectory_limits or self.limits.arm
        return {"arm_velocity": list(arm.velocity), "arm_acceleration": list(arm.acceleration), "arm_jerk": list(arm.jerk)}
