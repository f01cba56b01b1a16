"""The controller node, a managed (lifecycle) node around :class:`sabre.RealtimeCascade`.

configure: the descriptions (robot, object, the object's pose) build the scene and the controller,
and every input must have a publisher; activate: the commands ramp in from zero and the task starts
(``start_on_activate``); deactivate: they ramp to zero, the planner pauses; cleanup: the controller
goes. Before it is configured the node answers nothing; configured but not active, it answers every
arm joint state with zero (a ramp to it). An e-stop (std_msgs/Bool, latched until the reset
service), the start, cancel and reset services (std_srvs/Trigger), obstacles by id
(visualization_msgs/MarkerArray), diagnostics and something to look at
(:mod:`sabre.ros.visualization`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import SabreError
from . import PeriodicThread, gil_priority, realtime_middleware, require_ros, spin_node
from .controller_loop import ControllerLoop
from .conversions import MessageError
from .descriptions import DescriptionSources
from .params import CONTROLLER_PARAMETERS, declare
from .qos import profile
from .visualization import ObstacleRegistry, Visualizer, active_constraints, planned_paths

__all__ = ["ControllerNode", "run_controller"]


def _lifecycle_node(owner: ControllerNode, name: str) -> Any:
    """An rclpy LifecycleNode whose transitions call ``owner``'s."""
    from rclpy.lifecycle import LifecycleNode

    class _Node(LifecycleNode):
        def on_configure(self, state: Any) -> Any:
            return owner.on_configure()

        def on_activate(self, state: Any) -> Any:
            return owner.on_activate()

        def on_deactivate(self, state: Any) -> Any:
            return owner.on_deactivate()

        def on_cleanup(self, state: Any) -> Any:
            return owner.on_cleanup()

        def on_shutdown(self, state: Any) -> Any:
            return owner.on_shutdown_transition()

    return _Node(name)


class ControllerNode:
    """Builds the lifecycle node (``node``) with the endpoints every state has: the descriptions'
    inputs, the e-stop, the obstacles, the task's services and the diagnostics."""

    def __init__(self, overrides: dict[str, Any] | None = None, node_name: str = "sabre_controller") -> None:
        require_ros()
        from rclpy.lifecycle import TransitionCallbackReturn

        self._result = TransitionCallbackReturn
        self.node = _lifecycle_node(self, node_name)
        self.params = p = declare(self.node, CONTROLLER_PARAMETERS, overrides)
        self.sources = DescriptionSources(p)
        self.loop: ControllerLoop | None = None
        self.state = "unconfigured"
        self.problem = ""  # why the last configure failed
        self.estop = False
        self.obstacles = ObstacleRegistry(self._add_obstacle, self._move_obstacle, self._remove_obstacle)
        self._summaries: list[dict[str, Any]] = []
        self._create_endpoints(p)
        self.visualizer = Visualizer(self.node, p, str(p["world_frame"]), profile(p["visualization_qos"]))
        self._status = PeriodicThread(
            1.0 / float(p["status_rate"]),
            self._report,
            "sabre-status",
            lambda exc: self.node.get_logger().error(f"status not published: {exc}"),
            priority=gil_priority(int(p["realtime_priority"])),
        ).start()
        self._autostart = self.node.create_timer(0.5, self._step_autostart) if p["autostart"] else None
        self.node.get_logger().info(
            f"sabre controller: waiting to be configured (robot from {self.sources.robot_source}, object from "
            f"{self.sources.object_source}, its pose from {self.sources.pose_source})"
        )

    def _create_endpoints(self, p: dict[str, Any]) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import Bool, String
        from std_srvs.srv import Trigger
        from visualization_msgs.msg import MarkerArray

        node = self.node
        if not p["robot_description_file"]:
            node.create_subscription(
                String, p["robot_description_topic"], self._on_robot_description, profile(p["robot_description_qos"])
            )
        if not p["object_pose"]:
            node.create_subscription(PoseStamped, p["object_pose_topic"], self._on_object_pose, profile(p["object_pose_qos"]))
        node.create_subscription(Bool, p["estop_topic"], self._on_estop, profile(p["estop_qos"]))
        node.create_subscription(MarkerArray, p["obstacle_topic"], self._on_obstacles, profile(p["obstacle_qos"]))
        node.create_service(Trigger, "~/start", self._on_start)
        node.create_service(Trigger, "~/cancel", self._on_cancel)
        node.create_service(Trigger, "~/reset", self._on_reset)
        self.status_pub = node.create_publisher(DiagnosticArray, p["status_topic"], profile(p["status_qos"]))

    # Inputs of every state -------------------------------------------------------------------
    def _on_robot_description(self, msg: Any) -> None:
        try:
            self.sources.on_robot_description(msg.data)
        except MessageError as exc:
            self.node.get_logger().error(f"robot description rejected: {exc}")

    def _on_object_pose(self, msg: Any) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        try:
            pose = self.sources.on_object_pose(msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w))
        except MessageError as exc:
            self.node.get_logger().error(f"object pose rejected: {exc}", throttle_duration_sec=1.0)
            return
        if self.loop is not None and tuple(self.loop.descriptions.object_pose) != pose:
            self.node.get_logger().warning("a new object pose: it takes effect at the next configure (cleanup, configure)")

    def _on_estop(self, msg: Any) -> None:
        if msg.data and not self.estop:
            self.estop = True
            if self.loop is not None:
                self.loop.latch_estop()
            self.node.get_logger().error("e-stop: ramping to zero; latched until the reset service")

    def _on_obstacles(self, msg: Any) -> None:
        for m in msg.markers:
            try:
                if m.action != 3 and m.header.frame_id and m.header.frame_id != self.params["world_frame"]:
                    raise MessageError(f"frame {m.header.frame_id!r} is not the world frame")
                center = (m.pose.position.x, m.pose.position.y, m.pose.position.z)
                self.obstacles.apply((m.ns, int(m.id)), int(m.action), center, 0.5 * m.scale.x)
            except (MessageError, SabreError) as exc:
                self.node.get_logger().error(f"obstacle rejected: {exc}", throttle_duration_sec=1.0)

    def _add_obstacle(self, center: list[float], radius: float) -> int | None:
        return None if self.loop is None else self.loop.cascade.add_obstacle(center, radius)

    def _move_obstacle(self, oid: int, center: list[float]) -> None:
        if self.loop is not None:
            self.loop.cascade.move_obstacle(oid, center)

    def _remove_obstacle(self, oid: int) -> None:
        if self.loop is not None:
            self.loop.cascade.remove_obstacle(oid)

    # Services --------------------------------------------------------------------------------
    def _on_start(self, request: Any, response: Any) -> Any:
        why = "not configured" if self.loop is None else self.loop.start_task()
        response.success, response.message = not why, why or "task started"
        return response

    def _on_cancel(self, request: Any, response: Any) -> Any:
        if self.loop is not None:
            self.loop.cancel_task()
        response.success, response.message = True, "task cancelled: ramping to zero"
        return response

    def _on_reset(self, request: Any, response: Any) -> Any:
        self.estop = False
        if self.loop is not None:
            self.loop.reset_task()
        response.success, response.message = True, "e-stop and planner failure cleared; start the task again"
        return response

    # Lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> Any:
        try:
            descriptions = self.sources.descriptions()
            loop = ControllerLoop(self.node, self.params, descriptions)
        except SabreError as exc:
            self.problem = str(exc)
            self.node.get_logger().error(f"configure refused: {exc}", throttle_duration_sec=5.0)
            return self._result.FAILURE
        missing = [f"{label} ({topic})" for label, topic in loop.input_topics().items() if not self._has_publisher(topic)]
        if missing and self.params["require_publishers"]:
            loop.destroy()
            self.problem = "no publisher for " + ", ".join(missing)
            self.node.get_logger().error(f"configure refused: {self.problem}", throttle_duration_sec=5.0)
            return self._result.FAILURE
        self.loop = loop
        loop.estop = self.estop
        for obstacle in self.obstacles.obstacles.values():
            obstacle.core_id = loop.cascade.add_obstacle(list(obstacle.center), obstacle.radius)
        self.problem = ""
        self.state = "inactive"
        scene = loop.scene
        self.node.get_logger().info(
            f"configured: {scene.robot_name} with {scene.object_name} at {descriptions.object_pose}, joints {loop.names}, "
            f"arm command {loop.arm_joints}, object state from {self.params['object_state_topic'] or 'the hand-pose estimator'}"
        )
        return self._result.SUCCESS

    def _has_publisher(self, topic: str) -> bool:
        return self.node.count_publishers(self.node.resolve_topic_name(topic)) > 0

    def on_activate(self) -> Any:
        if self.loop is None:
            return self._result.FAILURE
        self.loop.activate()
        self.state = "active"
        self.node.get_logger().info(
            "active: commands ramp in from zero" + (", task started" if self.loop.task == "starting" else "")
        )
        return self._result.SUCCESS

    def on_deactivate(self) -> Any:
        if self.loop is not None:
            self.loop.deactivate()
        self.state = "inactive"
        self.node.get_logger().info("inactive: commands ramp to zero, planner paused")
        return self._result.SUCCESS

    def on_cleanup(self) -> Any:
        self._drop_loop()
        self.state = "unconfigured"
        return self._result.SUCCESS

    def on_shutdown_transition(self) -> Any:
        self._drop_loop()
        self.state = "finalized"
        return self._result.SUCCESS

    def _drop_loop(self) -> None:
        loop, self.loop = self.loop, None
        if loop is not None:
            loop.ramp_down(deadline=_now() + 2.0)
            self._summaries.append(loop.summary())
            loop.destroy()

    def _step_autostart(self) -> None:
        """``autostart``: configure, then activate, retrying every half second until active."""
        if self.state == "unconfigured":
            self.node.trigger_configure()
        elif self.state == "inactive":
            self.node.trigger_activate()
        if self.state == "active" and self._autostart is not None:
            self._autostart.cancel()

    # Reports ---------------------------------------------------------------------------------
    def _report(self) -> None:
        self._publish_status()
        loop = self.loop
        if loop is not None and float(self.params["visualization_rate"]) > 0:
            self._publish_visualization(loop)

    def _publish_visualization(self, loop: ControllerLoop) -> None:
        x = loop._x
        if x is None:
            return
        scene = loop.scene
        q, _, o, od = scene.split_state(x)
        paths = None
        reference = getattr(loop.cascade, "reference", None)
        if loop.task == "running" and loop.cascade.ready and reference is not None and loop._last_t is not None:
            paths = planned_paths(scene, reference, q, loop._last_t, loop.horizon, float(loop.controller.config.dt))
        handle = (
            scene.object_fk(o, loop.estimator.handle_frame) if loop.estimator is not None else scene.object_fk(o, "handle_frame")
        )
        active: list[str] = []
        f = loop.controller.inner_filter
        if f is not None:
            active = active_constraints(f.row_names, f.constraint_rows(x).h)
        obstacles = [(ob.center, ob.radius) for ob in self.obstacles.obstacles.values()]
        self.visualizer.publish(scene, paths, handle, obstacles, active, np.asarray(o), np.asarray(od))

    def status(self) -> tuple[int, str, dict[str, str]]:
        """(level 0 OK, 1 WARN, 2 ERROR; message; values) of the diagnostics."""
        values = {"lifecycle": self.state, "estop": str(self.estop).lower()}
        loop = self.loop
        if loop is None:
            return (
                2,
                f"not configured: {self.problem}" if self.problem else "not configured",
                values | {"problem": self.problem},
            )
        s = loop.summary()
        values |= {
            k: str(s[k])
            for k in (
                "task",
                "phase",
                "reason",
                "ticks",
                "followed",
                "rejected",
                "stale_events",
                "planner_iterations",
                "wrench_received",
            )
        }
        values |= {
            "opening": f"{s['opening']:.4f}",
            "tank_energy": f"{s['tank_energy']:.4f}",
            "tank_floor": f"{s['tank_floor']:.4f}",
            "planner_rate": f"{s['planner_rate_hz']:.2f}",
            "iteration_time": f"{loop.cascade.iteration_time:.5f}",
            "filter_fallbacks": str(s["filter_fallbacks"]),
            "cpu_share": f"{s['cpu_share']:.3f}",
            "at_rest": str(loop.tick.at_rest).lower(),
        }
        silent = [f"{label} ({topic})" for label, topic in loop.input_topics().items() if not self._has_publisher(topic)]
        if self.estop:
            return 2, "e-stop latched: commands at zero until reset", values
        if loop.task == "failed":
            return 2, f"planner stopped: {loop.failure}", values
        if silent:
            return 2, "no publisher for " + ", ".join(silent), values | {"silent_inputs": ", ".join(silent)}
        if loop.reason == "stale state" or loop.tick.ramping_for_stale_state:
            return 1, "state stale: ramping to zero", values
        return 0, f"{self.state}, task {loop.task}" + (f" ({loop.reason})" if loop.reason else ""), values

    def _publish_status(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        level, message, values = self.status()
        status = DiagnosticStatus(
            name="sabre/controller",
            hardware_id=self.loop.scene.robot_name if self.loop is not None else "",
            level=bytes([level]),
            message=message,
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.status_pub.publish(msg)

    def summary(self) -> dict[str, Any]:
        """The run's summary: the current configuration's, else the last one's."""
        base = {"node": "controller", "lifecycle": self.state, "problem": self.problem}
        if self.loop is not None:
            return base | self.loop.summary()
        return base | (self._summaries[-1] if self._summaries else {})

    def shutdown(self) -> dict[str, Any]:
        """SIGINT or SIGTERM: the commands ramp to zero (published from this thread), the planner
        stops; returns the summary."""
        self._status.stop()
        summary = self.summary()
        if self.loop is not None:
            summary["ramped_to_rest"] = self.loop.ramp_down(deadline=_now() + 2.0)
            summary |= {"answered": self.loop.tick.counts["answered"]}
            self.loop.destroy()
            self.loop = None
        return summary


def _now() -> float:
    import time

    return time.monotonic()


def run_controller(overrides: dict[str, Any] | None = None, ros_args: list[str] | None = None) -> int:
    """Runs the controller node until SIGINT or SIGTERM; prints a one-line JSON summary
    (``SABRE_SUMMARY {...}``) on exit."""
    rclpy = require_ros()
    realtime_middleware()
    rclpy.init(args=["sabre_controller"] + (ros_args or []), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = ControllerNode(overrides)
    spin_node(node, node.shutdown, priority=int(node.params["realtime_priority"]))
    return 0
