"""The ROS parameters of the two nodes, with their defaults (every topic name, QoS, joint order, limit,
rate and timeout), and the helper that declares them on a node and reads them back.

Topic names are relative, so that ``__ns`` and remappings apply; ``/diagnostics`` stays absolute, as
every diagnostics tool expects it there. Each endpoint ``<name>_topic`` has a ``<name>_qos`` (see
:mod:`sabre.ros.qos`)."""

from __future__ import annotations

import math
from typing import Any

__all__ = [
    "CONTROLLER_PARAMETERS",
    "SIM_ROBOT_PARAMETERS",
    "TOPIC_DEFAULTS",
    "UNSET_DOUBLES",
    "FRANKA_VELOCITY",
    "FRANKA_ACCELERATION",
    "FRANKA_JERK",
    "ROBUST_FRACTION",
    "TRAJECTORY_FRACTION",
    "BASE_ACCELERATION",
    "BASE_JERK",
    "BASE_RAMP_TIME",
    "declare",
]

#: A double-array parameter without a default (read back as []): ``object_pose`` and the limits,
#: whose defaults come from the URDF or the robot's published limits.
UNSET_DOUBLES = "<double array, unset>"

#: Franka's published joint limits (Franka Control Interface specification; libfranka's
#: rate_limiting.h): velocity (rad/s), acceleration (rad/s²), jerk (rad/s³) of joints 1–7.
FRANKA_VELOCITY = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61)
FRANKA_ACCELERATION = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
FRANKA_JERK = (7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0)

#: The share of Franka's jerk bound the default command limits keep, so that commands the robot
#: misses still pass its checks: with m consecutive cycles missed it holds the last command for them
#: and then sees m + 1 steps at once, accelerations a, 0, …, 0, (m + 1)·a, a jerk of (m + 1)·a/dt;
#: so the default acceleration bound is ROBUST_FRACTION·j·dt/(m + 1) (never above a_max), the
#: default jerk bound ROBUST_FRACTION·j, with m the cycles a gap of ``tolerated_gap`` misses.
ROBUST_FRACTION = 0.9
#: The velocity stream's default promise (s): a gap this long between two deliveries (two missed
#: 1 kHz cycles) passes Franka's checks.
TOLERATED_GAP = 0.005
#: The share of Franka's acceleration and jerk bounds the trajectory interface's segments keep by
#: default: JTC reproduces a segment exactly, so the share is left for the position feedback
#: k_p (q_d − q) the robot adds and for a robot's own limits below Franka's.
TRAJECTORY_FRACTION = 0.5

#: The base's command limits: acceleration of vx, vy (m/s²) and ωz (rad/s²), Ridgeback-like (its
#: driver, ridgeback_control's control.yaml, bounds vx and vy at 1 m/s²), and their jerk, which the
#: driver does not bound: the stream reaches its acceleration bound within BASE_RAMP_TIME, one step of
#: the trajectory's filter, as the planner's rollout model assumes (it bounds the base's acceleration,
#: not its jerk; a slower ramp leaves the base behind the plan the arm follows). The velocity bounds
#: come from the URDF.
BASE_ACCELERATION = (1.0, 1.0, 2.0)
BASE_RAMP_TIME = 0.01
BASE_JERK = tuple(a / BASE_RAMP_TIME for a in BASE_ACCELERATION)

#: Topics both nodes share (a real robot's drivers publish and subscribe the same names).
TOPIC_DEFAULTS: dict[str, str] = {
    "robot_description_topic": "robot_description",
    "object_pose_topic": "sabre/object_pose",
    "joint_state_topic": "joint_states",
    "odometry_topic": "odom",
    "wrench_topic": "wrist_wrench",
    "tau_ext_topic": "",
    "object_state_topic": "",
    "arm_command_topic": "forward_velocity_controller/commands",
    "trajectory_topic": "joint_trajectory_controller/joint_trajectory",
    "cmd_vel_topic": "cmd_vel",
    "command_echo_topic": "",
    "obstacle_topic": "sabre/obstacles",
    "estop_topic": "sabre/estop",
}

#: The QoS of each endpoint (:func:`sabre.ros.qos.profile`): sensor inputs best-effort, so that they
#: match reliable and best-effort publishers alike; descriptions latched; commands reliable.
QOS_DEFAULTS: dict[str, str] = {
    "robot_description_qos": "latched",
    "object_pose_qos": "latched",
    "joint_state_qos": "sensor",
    "odometry_qos": "sensor",
    "wrench_qos": "sensor",
    "tau_ext_qos": "sensor",
    "object_state_qos": "sensor",
    "arm_command_qos": "reliable",
    "trajectory_qos": "reliable",
    "cmd_vel_qos": "reliable",
    "command_echo_qos": "sensor",
    "obstacle_qos": "reliable",
    "estop_qos": "reliable",
    "status_qos": "reliable",
    "visualization_qos": "reliable",
}

#: Controller node (``python -m sabre control``). Empty joint lists mean the scene's own.
CONTROLLER_PARAMETERS: dict[str, Any] = {
    # what to open, how
    "variant": "IO",
    "seed": 0,
    "threads": 0,  # 0: sabre.default_threads()
    # descriptions: the robot's from the robot_description topic unless a file is given; the object's
    # from a file, else a string, else the built-in `object`
    "robot_description_file": "",
    "object": "shelf",
    "object_urdf_file": "",
    "object_urdf": "",
    "object_joint": "",  # the joint to open in an object with several ("": its only one)
    "hold_joints": [""],  # the other movable joints, fixed at hold_positions
    "hold_positions": UNSET_DOUBLES,
    "handle": "handle_frame",  # object frame or link to grasp (OpenObject(handle=...))
    "object_pose": UNSET_DOUBLES,  # x, y, z, roll, pitch, yaw in world_frame; unset: from object_pose_topic
    "world_frame": "odom",  # the frame of odometry and the object pose
    # joints
    "joint_names": [""],  # the robot's names for sabre's joints, in sabre's order
    "arm_joints": [""],  # the arm command's joints, in its order (default: all but the base's)
    "base_joints": [""],  # the driver's names of the base's x, y, yaw joints (default: the scene's; none for a fixed base)
    "odometry_twist_in_child_frame": True,  # as nav_msgs/Odometry defines it
    # wrench: moment about wrench_point_frame (default: the header's frame), axes of the header's frame
    "wrench_frame": "",  # the frame of a wrench whose header names none (default: the scene's wrist sensor link)
    "wrench_point_frame": "",
    "tau_ext_sign": 1.0,  # sign of the torque topic's efforts against sabre's τ_ext (environment on robot)
    **TOPIC_DEFAULTS,
    "status_topic": "/diagnostics",
    "hand_path_topic": "sabre/hand_path",
    "base_path_topic": "sabre/base_path",
    "markers_topic": "sabre/markers",
    "object_estimate_topic": "sabre/object_estimate",
    **QOS_DEFAULTS,
    "cmd_vel_stamped": True,
    "cmd_vel_frame": "base_link",
    "cmd_vel_rate": 50.0,  # Hz
    # command limits (unset: velocity from the URDF, acceleration and jerk from Franka's, robust)
    "arm_velocity_limits": UNSET_DOUBLES,
    # the delivery gap (s) the velocity stream's default acceleration and jerk limits tolerate
    "tolerated_gap": TOLERATED_GAP,
    "arm_acceleration_limits": UNSET_DOUBLES,
    "arm_jerk_limits": UNSET_DOUBLES,
    "base_velocity_limits": UNSET_DOUBLES,
    "base_acceleration_limits": UNSET_DOUBLES,
    "base_jerk_limits": UNSET_DOUBLES,
    "command_period": 0.001,  # s: the arm command stream's step (the robot's control cycle)
    # the arm's command interface: "trajectory" (joint_trajectory_controller's topic, trajectory_topic:
    # segments that ride out delivery gaps up to trajectory_tolerated_gap) or "velocity" (a 1 kHz
    # stream on arm_command_topic, robust to delivery gaps up to tolerated_gap only)
    "arm_interface": "trajectory",
    "trajectory_rate": 100.0,  # Hz: segments published
    "trajectory_lead": 0.03,  # s: from a segment's stamp to its splice (the delivery latency it absorbs)
    "trajectory_tolerated_gap": 0.1,  # s: the pause in deliveries a segment rides out before its stop
    "trajectory_filter_step": 0.01,  # s: the sequential filter's step along a segment (whole knots of 2 ms)
    "trajectory_interpolation": "cubic",  # or "quintic" (points with accelerations)
    "trajectory_position_gain": 0.0,  # 1/s: the robot's JTC k_p (0: feedforward, see docs/ros2.md)
    # segment limits (unset: velocity from the URDF, half of Franka's acceleration and jerk)
    "trajectory_acceleration_limits": UNSET_DOUBLES,
    "trajectory_jerk_limits": UNSET_DOUBLES,
    # lifecycle and task
    "autostart": False,  # configure and activate by itself (retrying until the inputs are there)
    "start_on_activate": True,  # activating starts the task (else the start service does)
    # the task ends once its success test passes on the controller's state: ramp to zero, planner stops
    "stop_on_success": True,
    "require_publishers": True,  # configure fails while an input has no publisher
    # timing
    "state_timeout": 0.05,  # s: an arm joint older than this → ramp to zero
    "base_state_timeout": 0.2,  # s: base odometry older than this → ramp to zero
    "wrench_timeout": 0.1,  # s: older wrench → τ_ext taken as zero and reported
    "status_rate": 5.0,  # Hz
    "visualization_rate": 4.0,  # Hz, 0: off
    "tau_ext_cutoff": 10.0,  # Hz, low-pass of the wrench-derived τ_ext the tank reads
    "max_tick_dt": 0.02,  # s: the tank integrates at most this long per state
    # s: the planner's iterations at most this often (50 Hz, as the acceptance's run_episode plans);
    # each takes a step toward the samples' weighted mean, so the rate shapes how fast plans change
    "min_replan_period": 0.02,
    "realtime_priority": 70,
    "planner_process": True,
    "planner_nice": 10,
    "planner_idle": False,
    "delay_compensation": True,
}

#: Simulated robot node (``python -m sabre sim-robot``).
SIM_ROBOT_PARAMETERS: dict[str, Any] = {
    "object": "shelf",
    "object_pose": UNSET_DOUBLES,  # x, y, z, roll, pitch, yaw; unset: the built-in default
    "publish_object_pose": True,  # as a perception node would, on object_pose_topic
    "robot_description_file": "",  # a URDF published on robot_description instead of the built-in robot's
    "plant": "rapier",  # or "mujoco" (sabre.MujocoPlant)
    "start": "paper",  # or "default"
    "world_frame": "odom",
    "base_frame": "base_link",
    "finger_joints": [""],  # gripper joints the arm's driver publishes (default: the scene's held joints at their values)
    "finger_width": 0.04,  # m, published for each joint finger_joints names
    **TOPIC_DEFAULTS,
    **QOS_DEFAULTS,
    "wrench_qos": "sensor",
    "cmd_vel_stamped": True,
    "clock_topic": "clock",
    "sim_status_topic": "sabre/sim/status",
    "error_topic": "sabre/sim/robot_error",
    "hold_topic": "sabre/sim/hold_object",
    "set_obstacles_topic": "sabre/sim/set_obstacles",
    "ground_truth_topic": "sabre/sim/object_joint_states",
    "rate": 1000.0,  # Hz: plant step and arm joint states
    "odometry_rate": 50.0,  # Hz
    "wrench_rate": 250.0,  # Hz (the tank reads τ_ext low-passed at 10 Hz)
    "clock_rate": 100.0,  # Hz
    "ground_truth_rate": 100.0,  # Hz
    "position_noise": 1e-5,  # rad or m, standard deviation on published positions
    "velocity_noise": 1e-3,  # rad/s or m/s
    "force_noise": 0.1,  # N (torque: a tenth of it, N·m)
    "noise_seed": 0,
    "reflexes": True,  # Franka's discontinuity reflexes on the arm command
    # "cycle": the command in effect at each plant tick, delivery included, as the arm checks it (a
    # tick the plant loop itself ran late is excused); "command" (a diagnostic): each arm command
    # against the one before, one plant period apart (the stream as sent)
    "reflex_check": "cycle",
    # the arm's command interface the robot runs: "trajectory" (joint_trajectory_controller's topic
    # interface on trajectory_topic, with the velocity command interface v_d + k_p (q_d − q)) or
    # "velocity" (a forward command controller on arm_command_topic)
    "arm_interface": "trajectory",
    "trajectory_position_gain": 0.0,  # 1/s: JTC's k_p, every arm joint (0: feedforward)
    # the arm's commands and joint states taken and published by the core from the plant loop (no
    # executor callback per command); False: an executor callback per command
    "direct_middleware": True,
    "command_timeout": 0.05,  # s: older commands → the robot is stopped (the robot side's timeout)
    "max_catchup": 0.1,
    "status_rate": 2.0,
    "gain_inertia_floor": 0.03,
    "duration": 0.0,
    "stop_on_success": False,
    "settle_time": 0.5,
    "hold_at_opening": 0.0,
    "hold_duration": 5.0,
    "realtime_priority": 80,
}


def declare(node: Any, defaults: dict[str, Any], overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Declares ``defaults`` as ROS parameters of ``node`` (a ``--params-file`` overrides them),
    applies ``overrides`` (command-line flags, which win), and returns the values; a string list of
    one empty string and an unset double array read back as []."""
    from rclpy.parameter import Parameter

    for name, value in defaults.items():
        if value == UNSET_DOUBLES:
            node.declare_parameter(name, Parameter.Type.DOUBLE_ARRAY)
        else:
            node.declare_parameter(name, value)
    if overrides:
        node.set_parameters([Parameter(k, value=v) for k, v in overrides.items() if v is not None])
    values = {name: node.get_parameter_or(name, None).value for name in defaults}
    for name, value in values.items():
        if value is None:
            values[name] = []
        elif isinstance(value, (list, tuple)) and all(v == "" for v in value):
            values[name] = []
        elif not isinstance(value, (str, bool, int, float)):
            values[name] = list(value)
    return values


def robust_arm_limits(dt: float, tolerated_gap: float = TOLERATED_GAP) -> tuple[list[float], list[float]]:
    """(acceleration, jerk) bounds per arm joint under which a velocity stream at a control cycle of
    ``dt`` s passes Franka's checks when a delivery gap of up to ``tolerated_gap`` s makes the robot
    hold a command (see :data:`ROBUST_FRACTION`). A gap of one cycle is no gap."""
    from ..errors import InvalidValueError

    if not (math.isfinite(dt) and dt > 0 and math.isfinite(tolerated_gap) and tolerated_gap >= dt):
        raise InvalidValueError(f"tolerated_gap must be at least the control cycle {dt} s, got {tolerated_gap}")
    misses = math.ceil(tolerated_gap / dt - 1e-9) - 1
    accel = [min(a, ROBUST_FRACTION * j * dt / (misses + 1)) for a, j in zip(FRANKA_ACCELERATION, FRANKA_JERK)]
    jerk = [ROBUST_FRACTION * j for j in FRANKA_JERK]
    return accel, jerk


def finite_list(name: str, values: list[float], size: int) -> list[float]:
    """``values`` as floats, checked to be ``size`` positive finite numbers (a parameter's limits)."""
    from ..errors import InvalidValueError

    out = [float(v) for v in values]
    if len(out) != size or not all(math.isfinite(v) and v > 0 for v in out):
        raise InvalidValueError(f"parameter {name}: needs {size} positive finite values, got {out}")
    return out
