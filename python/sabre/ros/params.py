"""The ROS parameters of the two nodes, with their defaults (every topic name, joint order, rate
and timeout), and the helper that declares them on a node and reads them back."""

from __future__ import annotations

from typing import Any

__all__ = ["CONTROLLER_PARAMETERS", "SIM_ROBOT_PARAMETERS", "TOPIC_DEFAULTS", "declare"]

#: Topics shared by both nodes (a real robot's drivers publish and subscribe the same names).
TOPIC_DEFAULTS: dict[str, str] = {
    "joint_state_topic": "/joint_states",
    "wrench_topic": "/wrist_wrench",
    "object_state_topic": "/sabre/object/joint_states",
    "arm_command_topic": "/forward_velocity_controller/commands",
    "cmd_vel_topic": "/cmd_vel",
    "command_echo_topic": "/sabre/command",
    "obstacle_topic": "/sabre/obstacles",
}

#: Controller node (``python -m sabre control``). Empty joint lists mean the scene's own: all
#: robot joints in ``Scene.joint_names`` order, the arm joints (all but base_x, base_y, base_yaw)
#: for the forward velocity controller's array and the three planar base joints.
CONTROLLER_PARAMETERS: dict[str, Any] = {
    "object": "shelf",
    "variant": "IO",
    "seed": 0,
    "threads": 0,  # 0: sabre.default_threads()
    "joint_names": [""],
    "arm_joints": [""],
    "base_joints": ["base_x", "base_y", "base_yaw"],
    **TOPIC_DEFAULTS,
    "status_topic": "/diagnostics",
    "state_timeout": 0.05,  # s: older state → zero command
    "wrench_timeout": 0.1,  # s: older wrench → τ_ext taken as zero and reported
    "watchdog_period": 0.002,  # s
    "status_rate": 5.0,  # Hz
    "tau_ext_cutoff": 10.0,  # Hz, low-pass of the wrench-derived τ_ext the tank reads
    "max_tick_dt": 0.02,  # s: the tank integrates at most this long per state
    "min_replan_period": 0.0,  # s: 0 plans as fast as the machine allows
    "realtime_priority": 70,  # SCHED_FIFO priority of the state callbacks where permitted (0: normal scheduling)
    "planner_process": True,  # plan in a process of its own (False: a thread sharing the interpreter)
    "planner_nice": 10,  # niceness added to the planner process: the middleware's threads come first
    "planner_idle": False,  # the planner process under SCHED_IDLE: only CPU time nothing else wants (a dedicated machine)
    "delay_compensation": True,  # plan from the state predicted for when the plan takes over (its computation time ahead)
}

#: Simulated robot node (``python -m sabre sim-robot``).
SIM_ROBOT_PARAMETERS: dict[str, Any] = {
    "object": "shelf",
    "start": "paper",  # or "default"
    "joint_names": [""],  # the published names of sabre's joints, in sabre's order; empty: the scene's
    "publish_order": [""],  # the order they are published in (a permutation of joint_names); empty: that order
    "extra_joints": [""],  # published with zeros (joints a real robot has and sabre ignores)
    "arm_joints": [""],
    **TOPIC_DEFAULTS,
    "clock_topic": "/clock",
    "status_topic": "/sabre/sim/status",
    "hold_topic": "/sabre/sim/hold_object",
    "set_obstacles_topic": "/sabre/sim/set_obstacles",
    "rate": 1000.0,  # Hz: plant step and state publication
    "command_timeout": 0.05,  # s: older commands → the robot is stopped (zero velocity)
    "max_catchup": 0.1,  # s: further behind the wall clock, the plant skips ahead (counted)
    "status_rate": 2.0,  # Hz
    "gain_inertia_floor": 0.03,  # kg m², the joint velocity controller's gain floor
    "duration": 0.0,  # s of wall time, 0: run until stopped
    "stop_on_success": False,
    "settle_time": 0.5,  # s after success before stopping
    "hold_at_opening": 0.0,  # fraction of the opening range at which the object is held, 0: never
    "hold_duration": 5.0,  # s
    "realtime_priority": 80,  # SCHED_FIFO priority of the plant loop; its command callbacks run 10 below (0: normal)
}


def declare(node: Any, defaults: dict[str, Any], overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Declares ``defaults`` as ROS parameters of ``node`` (a ``--params-file`` overrides them),
    applies ``overrides`` (command-line flags, which win), and returns the values."""
    from rclpy.parameter import Parameter

    for name, value in defaults.items():
        node.declare_parameter(name, value)
    if overrides:
        node.set_parameters([Parameter(k, value=v) for k, v in overrides.items() if v is not None])
    values = {name: node.get_parameter(name).value for name in defaults}
    for name, value in values.items():
        if isinstance(value, (list, tuple)) and all(v == "" for v in value):
            values[name] = []
    return values
