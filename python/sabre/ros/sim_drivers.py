"""What the simulated robot publishes, as a Franka arm's and a mobile base's drivers do: the arm's joint
states with the gripper's (held) joints at the plant's rate (serialized, noisy and published by the
core's `SimDriver`, see :mod:`sabre.ros.sim_robot`), the base's odometry with its twist in the
base frame (a robot with a base), the wrist wrench best effort in the sensor frame, measurement noise on all three, the robot
description latched, and (as a perception node would) the object's pose; besides, for evaluation
only, the object's true joint state and a clock."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..scene import Scene
from .conversions import quaternion_of
from .qos import profile

__all__ = ["DriverOutputs", "Noise"]


class Noise:
    """Gaussian samples drawn a thousand rows at a time (one NumPy call per second at 1 kHz)."""

    def __init__(self, seed: int, width: int, scale: np.ndarray) -> None:
        self._rng = np.random.default_rng(seed)
        self._scale = np.asarray(scale, dtype=np.float64)
        self._width = width
        self._rows = np.zeros((0, width))
        self._k = 0

    def next(self) -> np.ndarray:
        if self._k >= len(self._rows):
            self._rows = self._rng.standard_normal((1000, self._width)) * self._scale
            self._k = 0
        row = self._rows[self._k]
        self._k += 1
        return row


class DriverOutputs:
    """The publishers and their reused messages; ``publish_*`` fill and send one message each."""

    def __init__(self, node: Any, p: dict[str, Any], scene: Scene, arm_index: np.ndarray, robot_urdf: str) -> None:
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from nav_msgs.msg import Odometry
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String

        self.node, self.scene, self.arm_index = node, scene, arm_index
        reliable, latched = profile("reliable"), profile("latched")
        # the drivers' own QoS: joint states and odometry reliable, the wrench best effort (franka_ros2)
        self.js_pub = node.create_publisher(JointState, p["joint_state_topic"], reliable)
        base = scene.base_indices
        self.base_index = None if base is None else np.array(list(base), dtype=np.intp)
        self.odom_pub = None if base is None else node.create_publisher(Odometry, p["odometry_topic"], reliable)
        self.wrench_pub = node.create_publisher(WrenchStamped, p["wrench_topic"], profile(p["wrench_qos"]))
        self.truth_pub = node.create_publisher(JointState, p["ground_truth_topic"], reliable)
        self.clock_pub = node.create_publisher(Clock, p["clock_topic"], reliable)
        self.description_pub = node.create_publisher(String, p["robot_description_topic"], latched)
        self.description_pub.publish(String(data=robot_urdf))
        self.pose_pub = node.create_publisher(PoseStamped, p["object_pose_topic"], latched)
        # a gripper's joints: the ones named (at finger_width), else the scene's held joints at their values
        fingers = list(p["finger_joints"])
        held = [float(p["finger_width"])] * len(fingers)
        if not fingers:
            fingers, held = list(scene.held_joints), [float(v) for v in scene.held_joints.values()]
        self.joint_state_names = [scene.joint_names[i] for i in arm_index] + fingers
        self.held_positions = held
        self.position_noise, self.velocity_noise = float(p["position_noise"]), float(p["velocity_noise"])
        self._odom = Odometry()
        self._odom.header.frame_id = str(p["world_frame"])
        self._odom.child_frame_id = str(p["base_frame"])
        self._wrench = WrenchStamped()
        self.sensor_frame = scene.wrist_sensor_link
        self._wrench.header.frame_id = self.sensor_frame
        self._truth = JointState(name=list(scene.object_joint_names))
        self._clock = Clock()
        seed = int(p["noise_seed"])
        self.noise_seed = seed
        self.base_noise = Noise(seed + 1, 6, np.r_[np.full(3, p["position_noise"]), np.full(3, p["velocity_noise"])])
        f = float(p["force_noise"])
        self.wrench_noise = Noise(seed + 2, 6, np.r_[np.full(3, f), np.full(3, 0.1 * f)])

    def publish_object_pose(self, pose: np.ndarray, frame: str) -> None:
        from geometry_msgs.msg import PoseStamped

        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.header.stamp = self.node.get_clock().now().to_msg()
        x, y, z, roll, pitch, yaw = (float(v) for v in pose)
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = x, y, z
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = quaternion_of(roll, pitch, yaw)
        self.pose_pub.publish(msg)

    def publish_odometry(self, q: np.ndarray, dq: np.ndarray, stamp: Any) -> None:
        """The base's pose and its twist in the base frame (as nav_msgs/Odometry defines it)."""
        if self.odom_pub is None or self.base_index is None:
            return  # a fixed base: no base driver, no odometry
        noise = self.base_noise.next()
        x, y, yaw = (float(v) for v in q[self.base_index] + noise[:3])
        vx, vy, wz = (float(v) for v in dq[self.base_index] + noise[3:])
        c, s = math.cos(yaw), math.sin(yaw)
        m = self._odom
        m.header.stamp = stamp
        m.pose.pose.position.x, m.pose.pose.position.y = x, y
        o = m.pose.pose.orientation
        o.x, o.y, o.z, o.w = 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)
        t = m.twist.twist
        t.linear.x, t.linear.y, t.angular.z = c * vx + s * vy, -s * vx + c * vy, wz
        self.odom_pub.publish(m)

    def publish_wrench(self, q: np.ndarray, wrench_world: np.ndarray, stamp: Any) -> None:
        """The wrist wrench in the sensor frame's axes (the plant reports it in world axes)."""
        r = self.scene._core.fk(q, self.sensor_frame)[:3, :3]  # q is the plant's: finite, of size nq
        w = np.concatenate([r.T @ wrench_world[:3], r.T @ wrench_world[3:]]) + self.wrench_noise.next()
        m = self._wrench
        m.header.stamp = stamp
        m.wrench.force.x, m.wrench.force.y, m.wrench.force.z = float(w[0]), float(w[1]), float(w[2])
        m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z = float(w[3]), float(w[4]), float(w[5])
        self.wrench_pub.publish(m)

    def publish_truth(self, o: np.ndarray, od: np.ndarray, stamp: Any) -> None:
        m = self._truth
        m.header.stamp = stamp
        m.position, m.velocity = o.tolist(), od.tolist()
        self.truth_pub.publish(m)

    def publish_clock(self, sim_time: float) -> None:
        self._clock.clock.sec = int(sim_time)
        self._clock.clock.nanosec = int(round((sim_time % 1.0) * 1e9)) % 1_000_000_000
        self.clock_pub.publish(self._clock)
